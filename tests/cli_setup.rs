//! Setting up as a user does, from the command line: bare `ftafm` takes `serve`'s flags,
//! `--bind` takes a host name, `info` describes the instrument it would run, and a common
//! 300 kHz lever works with every command from its cantilever alone.

use std::io::{BufRead, BufReader};
use std::process::{Command, Output, Stdio};

mod common;
use common::TempToml;

fn ftafm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(args)
        .output()
        .unwrap()
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Whether `text` names a year of publication (1900–2099), as a citation does.
fn has_year(text: &str) -> bool {
    text.as_bytes()
        .windows(4)
        .any(|w| (w.starts_with(b"19") || w.starts_with(b"20")) && w.iter().all(u8::is_ascii_digit))
}

/// Starts the binary with `args`, returns the first stdout line (the URL banner) and stops
/// it.
fn banner_of(args: &[&str]) -> String {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    child.kill().unwrap();
    child.wait().unwrap();
    line
}

#[test]
fn bare_ftafm_takes_the_serve_flags_and_a_host_name() {
    let config = TempToml::new("bare", "[sample]\nyoungs_modulus = 60e9\n");
    let line = banner_of(&["--config", config.path(), "--bind", "localhost:0"]);
    // localhost resolves IPv4 first: the address a browser on this machine uses.
    assert!(line.contains("http://127.0.0.1:"), "{line:?}");
    assert!(line.contains("/ws"), "{line:?}");
    // A subcommand and serve's flags do not mix: a clear usage error.
    let out = ftafm(&["--bind", "127.0.0.1:0", "info"]);
    assert_eq!(out.status.code(), Some(2));
    // A bind address without a port names the flag and the forms it takes.
    let out = ftafm(&["--bind", "localhost"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("HOST:PORT"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn info_lists_every_mode_and_the_drive() {
    let out = ftafm(&["info"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(!stdout.contains("not built yet"), "{stdout}");
    // One row per mode: number, frequency (with its SI prefix), Q.
    for (n, f, q) in [
        (1, "100 kHz", "100.0"),
        (2, "626.", "417.0"),
        (5, "5.68", "26.0"),
    ] {
        assert!(
            stdout.lines().any(|l| {
                let cols: Vec<&str> = l.split_whitespace().collect();
                cols.len() >= 4
                    && cols[0] == n.to_string()
                    && format!("{} {}", cols[1], cols[2]).starts_with(f)
                    && cols[3] == q
            }),
            "no row for mode {n}: {stdout}"
        );
    }
    assert!(stdout.contains("drive 100 kHz (follows f1)"), "{stdout}");
    // The paper's case is inside the Hertz model's range (δ ≈ 0.37 nm of R = 10 nm) ...
    assert!(!stdout.contains("small-strain"), "{stdout}");
    // ... a soft elastomer under the same lever is not, and info says so.
    let out = ftafm(&["info", "--preset", "pdms"]);
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("warning: the tip indents the sample by")
            && stdout.contains("small-strain"),
        "{stdout}"
    );
}

/// The repro: `/cantilever/f1 = 300e3` with `k = 40` refused every command.
#[test]
fn a_300_khz_lever_runs_every_offline_command() {
    let lever = TempToml::new("lever300", "[cantilever]\nf1 = 300e3\nk = 40\n");
    let out = ftafm(&["info", "--config", lever.path()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("drive 300 kHz (follows f1)"), "{stdout}");
    assert!(
        stdout.contains("warning: demodulators out of band"),
        "{stdout}"
    );
    let out = ftafm(&["paper", "--config", lever.path(), "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let force = report["materials"][0]["max_force"].as_f64().unwrap();
    // Driven on resonance, it taps gently: tens of nN, not the 2442 nN of a lever driven at
    // a third of its resonance.
    assert!(force > 1e-9 && force < 500e-9, "F = {force} N");
    // And a (small) scan records with the in-band harmonics only.
    let scan = TempToml::new(
        "lever300-scan",
        "[cantilever]\nf1 = 300e3\nk = 40\n[scan]\npixels = 8\nline_rate = 20\n",
    );
    let out = ftafm(&["scan", "--config", scan.path(), "--frames", "1", "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let channels: Vec<&str> = report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert!(channels.contains(&"h16"), "{channels:?}");
    assert!(
        !channels.contains(&"h17"),
        "an out-of-band harmonic imaged: {channels:?}"
    );
    // Without adhesion the tip–sample force only pushes: every region on the repulsive
    // branch, none flagged as imaged across branches.
    let branches = report["branches"].as_array().unwrap();
    assert_eq!(branches[0]["regime"], "repulsive", "the base: {report}");
    // At 8 pixels a small inclusion has no interior pixel, hence no regime.
    for b in branches.iter().filter(|b| !b["regime"].is_null()) {
        assert_eq!(b["regime"], "repulsive", "{b}");
        assert_eq!(b["across_branches"], false, "{b}");
    }
}

#[test]
fn presets_are_listed_and_load_in_order_before_the_config() {
    let out = ftafm(&["presets", "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let list: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let names: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    for want in [
        "tap300",
        "tap150",
        "multi75",
        "ac240",
        "tap525",
        "silicon",
        "fused_silica",
    ] {
        assert!(names.contains(&want), "{names:?}");
    }
    // Every preset's file cites a source.
    for p in list.as_array().unwrap() {
        let toml = p["toml"].as_str().unwrap();
        assert!(
            toml.contains("data sheet") || has_year(toml),
            "{} cites no source",
            p["name"]
        );
    }
    // A lever and a sample together; the file after them wins where it speaks.
    let config = TempToml::new("after-presets", "[sample]\npoisson = 0.3\n");
    let out = ftafm(&[
        "paper",
        "--preset",
        "tap300",
        "--preset",
        "polystyrene",
        "--config",
        config.path(),
        "--json",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let modes = report["modes"].as_array().unwrap();
    assert!((modes[0]["frequency"].as_f64().unwrap() - 300e3).abs() < 1e-6);
    let out = ftafm(&["info", "--preset", "tap300", "--preset", "polystyrene"]);
    let stdout = text(&out.stdout);
    assert!(stdout.contains("sample E = 3.2 GPa"), "{stdout}");
    // An unknown preset names the known ones and exits 2.
    let out = ftafm(&["info", "--preset", "tap3000"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("unknown preset \"tap3000\"")
            && text(&out.stderr).contains("tap300, tap150"),
        "{}",
        text(&out.stderr)
    );
}

fn sigterm(child: &std::process::Child) {
    // SAFETY: kill(2) on our own child's pid has no memory-safety preconditions.
    let rc = unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    assert_eq!(rc, 0);
}

/// Waits for the child to exit (a hang guard, not a margin) and returns its status.
fn wait_exit(child: &mut std::process::Child) -> std::process::ExitStatus {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            panic!("the daemon did not exit on SIGTERM");
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// A SIGTERM during start-up (before the banner: config, orbit, pipeline) stops the daemon
/// cleanly, exit status 0, rather than killing it by signal.
#[test]
fn sigterm_during_start_up_exits_cleanly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Give the process a moment to reach main (a SIGTERM before that is the kernel's).
    std::thread::sleep(std::time::Duration::from_millis(30));
    sigterm(&child);
    let status = wait_exit(&mut child);
    assert_eq!(status.code(), Some(0), "{status:?}");
}

/// Raises this process's open-file limit to its hard limit (the daemon inherits it) and
/// returns it.
fn raise_fd_limit() -> u64 {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit write/read the struct we pass, nothing else.
    unsafe {
        libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit);
        limit.rlim_cur = limit.rlim_max;
        libc::setrlimit(libc::RLIMIT_NOFILE, &limit);
        libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit);
    }
    limit.rlim_cur
}

/// SIGTERM with 1500 half-open connections: the daemon exits 0, with a 1 s grace for them.
#[test]
fn sigterm_with_1500_half_open_connections_exits_cleanly() {
    // Each connection is a descriptor here and one in the daemon: a machine whose hard
    // limit is below that runs the test with as many as fit, and says so.
    let fds = raise_fd_limit();
    let count = 1500.min((fds.saturating_sub(200) / 2) as usize);
    if count < 1500 {
        eprintln!("open-file limit {fds}: {count} half-open connections instead of 1500");
    }
    let mut child = Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .unwrap()
        .to_owned();
    let mut open = Vec::new();
    for _ in 0..count {
        let mut s = std::net::TcpStream::connect(&addr).unwrap();
        std::io::Write::write_all(&mut s, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n").unwrap();
        open.push(s);
    }
    let start = std::time::Instant::now();
    sigterm(&child);
    let status = wait_exit(&mut child);
    eprintln!(
        "exit after SIGTERM with {count} half-open connections: {:?}",
        start.elapsed()
    );
    assert_eq!(status.code(), Some(0), "{status:?}");
}

/// `ftafm paper --engine coupled` prints the same schema from the coupled orbit, with its
/// residual and period; the text shows both engines side by side.
#[test]
fn paper_reports_either_engine_and_both_side_by_side() {
    // The configured engine by default: the coupled one.
    let out = ftafm(&["paper", "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let coupled: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let out = ftafm(&["paper", "--engine", "paper", "--json"]);
    let paper: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(coupled["engine"], "coupled");
    assert_eq!(paper["engine"], "paper");
    let (c, p) = (&coupled["materials"][0], &paper["materials"][0]);
    // The same keys (the coupled rows add their orbit's residual and period).
    for key in p.as_object().unwrap().keys() {
        assert!(c.get(key).is_some(), "coupled lacks {key}");
    }
    assert_eq!(c["period_one"], true);
    assert!(c["residual"].as_f64().unwrap() < 1e-9);
    // §6: in the paper's case they agree to about a per cent in F.
    let rel = c["max_force"].as_f64().unwrap() / p["max_force"].as_f64().unwrap() - 1.0;
    assert!(rel.abs() < 0.015, "F differs by {rel}");
    let out = ftafm(&["paper"]);
    let stdout = text(&out.stdout);
    assert!(stdout.contains("Engines side by side"), "{stdout}");
    assert!(stdout.contains("period 1, stable"), "{stdout}");
    let out = ftafm(&["paper", "--engine", "fast"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("--engine"),
        "{}",
        text(&out.stderr)
    );
}
