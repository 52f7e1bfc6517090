//! The `ftafm` binary as a user runs it: exit codes, messages on stderr, `paper --json`.

use std::io::Write;
use std::process::{Command, Output};

fn ftafm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(args)
        .output()
        .expect("the binary runs")
}

fn config_file(contents: &str) -> tempfile_path::TempToml {
    tempfile_path::TempToml::new(contents)
}

/// A TOML file in the target directory, removed when dropped.
mod tempfile_path {
    use super::*;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    pub struct TempToml(pub PathBuf);

    impl TempToml {
        pub fn new(contents: &str) -> Self {
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path =
                std::env::temp_dir().join(format!("ftafm-cli-{}-{n}.toml", std::process::id()));
            std::fs::File::create(&path)
                .and_then(|mut f| f.write_all(contents.as_bytes()))
                .expect("temp file");
            Self(path)
        }

        pub fn path(&self) -> &str {
            self.0.to_str().expect("utf-8 temp path")
        }
    }

    impl Drop for TempToml {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn paper_json_is_one_object_with_the_contract_schema_and_the_papers_numbers() {
    let out = ftafm(&["paper", "--engine", "paper", "--json"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.trim().lines().count(), 1, "exactly one line of JSON");
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    let modes = v["modes"].as_array().unwrap();
    assert_eq!(modes.len(), 5);
    for key in ["n", "lambda", "frequency", "q", "tip_slope", "stiffness"] {
        assert!(modes[0][key].is_number(), "modes[0].{key}");
    }
    assert!((modes[0]["tip_slope"].as_f64().unwrap() + 2.7530).abs() < 1e-4);
    assert!((modes[0]["stiffness"].as_f64().unwrap() - 82.416).abs() < 1e-2);
    let materials = v["materials"].as_array().unwrap();
    assert_eq!(materials[0]["name"], "sample");
    assert_eq!(materials[1]["name"], "inhomogeneity");
    let expected = [
        (129e9, 66.1e-9, 8.6e9, 0.0518, -47.19),
        (116.1e9, 65.1e-9, 8.2e9, 0.0526, -47.23),
    ];
    for (m, (e, f, p, tau, theta)) in materials.iter().zip(expected) {
        let get = |k: &str| m[k].as_f64().unwrap_or_else(|| panic!("{k} missing"));
        assert!((get("youngs_modulus") / e - 1.0).abs() < 1e-12);
        assert_eq!(get("poisson"), 0.28);
        assert!((get("max_force") / f - 1.0).abs() < 0.01);
        assert!((get("max_pressure") / p - 1.0).abs() < 0.01);
        assert!((get("contact_time_ratio") / tau - 1.0).abs() < 0.01);
        assert!((get("phase_shift_deg") - theta).abs() < 0.3);
        assert!((3.5e-10..4.0e-10).contains(&get("max_indentation")));
        let spectrum = m["spectrum"].as_array().unwrap();
        assert!(spectrum.len() >= 31, "harmonics 0..=30 at least");
        for (k, h) in spectrum.iter().enumerate() {
            assert_eq!(h["harmonic"].as_u64(), Some(k as u64));
            assert!(h["amplitude"].as_f64().unwrap() >= 0.0);
        }
    }
    let h6 = materials[0]["spectrum"][6]["amplitude"].as_f64().unwrap();
    assert!((0.185e-9..0.195e-9).contains(&h6), "H6 {h6}");
    let contrast = v["contrast"].as_array().unwrap();
    let c17 = contrast[17]["relative"].as_f64().unwrap();
    assert_eq!(contrast[17]["harmonic"], 17);
    assert!((-0.035..-0.025).contains(&c17), "c17 {c17}");
}

#[test]
fn paper_text_shows_the_printed_values_beside_ours() {
    let out = ftafm(&["paper"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("[66.1]") && text.contains("[-47.19]") && text.contains("[0.0518]"),
        "{text}"
    );
    assert!(text.contains("Fig. 3"));
}

#[test]
fn inhomogeneity_factor_changes_the_second_material_and_is_validated() {
    let out = ftafm(&["paper", "--json", "--inhomogeneity-factor", "0.5"]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["materials"][1]["youngs_modulus"].as_f64(), Some(64.5e9));
    for bad in ["-1", "0", "nan", "inf", "1e9"] {
        let out = ftafm(&["paper", "--inhomogeneity-factor", bad]);
        assert_eq!(out.status.code(), Some(2), "factor {bad}");
        assert!(
            stderr(&out).contains("--inhomogeneity-factor"),
            "factor {bad}: {}",
            stderr(&out)
        );
    }
    let out = ftafm(&["paper", "--inhomogeneity-factor", "soft"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--inhomogeneity-factor"));
}

#[test]
fn a_partial_config_overlays_the_default() {
    let file = config_file("[sample]\nyoungs_modulus = 50e9\n");
    let out = ftafm(&["paper", "--json", "--config", file.path()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["materials"][0]["youngs_modulus"].as_f64(), Some(50e9));
    // Untouched nodes keep their defaults: still the paper's cantilever.
    assert_eq!(v["modes"].as_array().unwrap().len(), 5);
    // A softer sample: smaller peak force than silicon's 66 nN.
    assert!(v["materials"][0]["max_force"].as_f64().unwrap() < 60e-9);
    let text = ftafm(&["paper", "--config", file.path()]);
    assert!(
        !String::from_utf8(text.stdout).unwrap().contains("[66.1]"),
        "printed values only for the paper's case"
    );
}

#[test]
fn bad_configs_exit_2_and_name_the_key() {
    let cases: &[(&str, &[&str])] = &[
        (
            "[sample]\nyoungs_moduls = 1e9\n",
            &["/sample/youngs_moduls", "youngs_modulus"],
        ),
        ("[samples]\nyoungs_modulus = 1e9\n", &["samples"]),
        (
            "[sample]\nyoungs_modulus = -1e9\n",
            &["/sample/youngs_modulus", "-1"],
        ),
        (
            "[sample]\nyoungs_modulus = 0\n",
            &["/sample/youngs_modulus"],
        ),
        (
            "[sample]\nyoungs_modulus = \"hard\"\n",
            &["/sample/youngs_modulus"],
        ),
        ("[sample]\npoisson = 0.5\n", &["/sample/poisson", "0.5"]),
        ("[tip]\npoisson = -1.0\n", &["/tip/poisson"]),
        ("[cantilever]\nq = []\n", &["/cantilever/q"]),
        ("[cantilever]\nk = nan\n", &["/cantilever/k", "NaN"]),
        (
            "[drive]\nfree_amplitude = inf\n",
            &["/drive/free_amplitude"],
        ),
        ("[demods.3]\norder = 9\n", &["/demods/3/order", "8"]),
        ("[synth]\nengine = \"magic\"\n", &["/synth/engine", "paper"]),
        ("[sample\nyoungs_modulus = 1e9\n", &["line"]),
    ];
    for (toml, needles) in cases {
        let file = config_file(toml);
        for sub in [&["paper"][..], &["info"][..]] {
            let mut args = sub.to_vec();
            args.extend(["--config", file.path()]);
            let out = ftafm(&args);
            assert_eq!(out.status.code(), Some(2), "{toml:?}: {}", stderr(&out));
            let err = stderr(&out);
            for needle in *needles {
                assert!(
                    err.to_lowercase().contains(&needle.to_lowercase()),
                    "{toml:?}: {err:?} lacks {needle:?}"
                );
            }
            assert!(out.stdout.is_empty(), "nothing on stdout for a bad config");
        }
    }
}

#[test]
fn missing_config_file_and_bad_flags_exit_2() {
    let out = ftafm(&["paper", "--config", "/nonexistent/ftafm.toml"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("/nonexistent/ftafm.toml"));
    let out = ftafm(&["paper", "--jsn"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--jsn"));
    let out = ftafm(&["frobnicate"]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn info_summarises_the_embedded_default() {
    let out = ftafm(&["info"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    // The daemon's engine (/synth/engine = coupled) computes the force; values carry the SI
    // prefix that fits them.
    assert!(
        text.contains("5 modes")
            && text.contains("f1 = 100 kHz")
            && text.contains("sample E = 129 GPa")
            && text.contains("by the coupled engine (/synth/engine): F = 66"),
        "{text}"
    );
    let paper = config_file("[synth]\nengine = \"paper\"\n");
    let out = ftafm(&["info", "--config", paper.path()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("by the paper engine (/synth/engine): F = 65.95 nN"),
        "{text}"
    );
}

#[test]
fn preset_and_config_go_before_or_after_the_command_in_order() {
    // Before the command, as README shows it: PDMS's modulus with the prefix that fits.
    let out = ftafm(&["--preset", "pdms", "info"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("sample E = 2 MPa"), "{text}");
    // Both sides: the lever before, the sample after; a file before is applied after both.
    let file = config_file("[cantilever]\nk = 41.0\n");
    let out = ftafm(&[
        "--preset",
        "tap300",
        "--config",
        file.path(),
        "info",
        "--preset",
        "pdms",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("f1 = 300 kHz, k = 41 N/m, sample E = 2 MPa"),
        "{text}"
    );
    // Where they mean nothing, or twice a file: refused, naming why.
    for args in [
        &["--preset", "pdms", "presets"][..],
        &["--config", file.path(), "stalls"][..],
        &["--config", file.path(), "info", "--config", file.path()][..],
        &["--bind", "127.0.0.1:9", "info"][..],
    ] {
        let out = ftafm(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("--preset and --config do not apply")
                || stderr(&out).contains("--config is given twice")
                || stderr(&out).contains("--bind is serve's flag"),
            "{args:?}: {}",
            stderr(&out)
        );
    }
}

#[test]
fn a_reader_that_closes_early_ends_the_command_quietly() {
    use std::io::{BufRead, BufReader};
    use std::os::unix::process::ExitStatusExt;
    use std::process::Stdio;
    // `paper` prints its first engine's tables, then runs the other engine for a second or
    // more before it prints again: by then the reader below has closed the pipe.
    let mut child = Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .arg("paper")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary runs");
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    assert!(first.starts_with("Engine: "), "{first}");
    drop(stdout);
    let out = child.wait_with_output().unwrap();
    let err = stderr(&out);
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        out.status.success() || out.status.signal() == Some(libc::SIGPIPE),
        "{:?}: {err}",
        out.status
    );
}

#[test]
fn serve_prints_its_url_answers_and_stops_cleanly_on_sigterm() {
    use std::io::{BufRead, BufReader, Read};
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(["serve", "--bind", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
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
        .unwrap_or_else(|| panic!("no URL in {line:?}"))
        .to_string();
    assert!(line.contains("ws://") && line.contains("/ws"), "{line}");
    // /healthz answers over plain HTTP (200 once the pipeline runs).
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        let mut s = std::net::TcpStream::connect(&addr).unwrap();
        std::io::Write::write_all(
            &mut s,
            format!("GET /healthz HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )
        .unwrap();
        let mut text = String::new();
        s.read_to_string(&mut text).unwrap();
        if text.starts_with("HTTP/1.1 200") {
            break;
        }
        assert!(std::time::Instant::now() < deadline, "{text}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let stopped_at = std::time::Instant::now();
    let kill = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    assert!(
        stopped_at.elapsed() < std::time::Duration::from_secs(2),
        "took {:?}",
        stopped_at.elapsed()
    );
    assert_eq!(status.code(), Some(0), "clean exit on SIGTERM");
}

#[test]
fn serve_rejects_a_bad_bind_address() {
    let out = ftafm(&["serve", "--bind", "localhost"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--bind"), "{}", stderr(&out));
}

#[test]
fn bench_json_reports_throughputs_and_the_realtime_factor() {
    let file = config_file("[synth]\nsample_rate = 8e6\n");
    let out = ftafm(&[
        "bench",
        "--seconds",
        "1.5",
        "--json",
        "--config",
        file.path(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(text.trim().lines().count(), 1, "one JSON object on stdout");
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    assert_eq!(v["sample_rate"].as_f64(), Some(8e6));
    assert_eq!(v["demodulators"].as_u64(), Some(32));
    // Where and on what it was measured, so that the figure carries it.
    let machine = v["machine"].as_str().unwrap();
    assert!(
        machine.contains(" CPUs, vector build "),
        "machine: {machine}"
    );
    assert_eq!(v["engine"], "coupled");
    assert_eq!(v["contact_substeps"].as_u64(), Some(12));
    for key in [
        "synth_samples_per_s",
        "dsp_samples_per_s",
        "chain_samples_per_s",
        "realtime_factor",
    ] {
        assert!(
            v[key].as_f64().is_some_and(|x| x > 0.0),
            "{key}: {}",
            v[key]
        );
    }
    let chain = v["chain_samples_per_s"].as_f64().unwrap();
    assert!((v["realtime_factor"].as_f64().unwrap() - chain / 8e6).abs() < 1e-9);
    // The chain's CPU time per sample, by thread, and as cycles at the clock it names.
    let cpu = v["cpu_ns_per_sample"]
        .as_f64()
        .expect("thread clocks on Linux");
    let (s, d) = (
        v["synth_cpu_ns_per_sample"].as_f64().unwrap(),
        v["dsp_cpu_ns_per_sample"].as_f64().unwrap(),
    );
    assert!(s > 0.0 && d > 0.0 && (cpu - (s + d)).abs() < 1e-9, "{v}");
    let source = v["clock_source"].as_str().unwrap();
    match v["clock_ghz"].as_f64() {
        Some(g) => {
            assert!(
                ["dependent adds", "/proc/cpuinfo"].contains(&source),
                "{source}"
            );
            assert!((v["cycles_per_sample"].as_f64().unwrap() - cpu * g).abs() < 1e-6);
        }
        None => assert_eq!(source, "none"),
    }
    assert!(
        v["verdict"]
            .as_str()
            .is_some_and(|t| t.contains("real time")),
        "{v}"
    );
    // Where the pages of noise deviates came from is reported (their accounting against
    // the samples is tested on a stopped pipeline, tests/pipeline.rs).
    let c = &v["counters"];
    let pages = |k: &str| c[k].as_u64().unwrap_or_else(|| panic!("{k}: {c}"));
    assert!(
        pages("noise_pages_taken") + pages("noise_pages_drawn_inline") > 0,
        "{c}"
    );
    pages("noise_pages_discarded");
    assert_eq!(
        v["counters"]["overrun_samples"].as_u64(),
        Some(0),
        "free-running never overruns"
    );
    // Progress goes to stderr while it runs.
    assert!(
        stderr(&out).contains("samples processed"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn bench_rejects_bad_durations() {
    for bad in ["0", "-3", "nan", "1e9"] {
        let out = ftafm(&["bench", "--seconds", bad]);
        assert_eq!(out.status.code(), Some(2), "--seconds {bad}");
        assert!(stderr(&out).contains("--seconds"), "{}", stderr(&out));
    }
}

/// `FTAFM_ISA` caps the vector builds (docs/benchmarks.md): a value it does not know is an
/// error that names the variable and its values, before anything runs; a known one runs.
#[test]
fn an_unknown_instruction_set_cap_is_refused_by_name() {
    let run = |isa: &str| {
        Command::new(env!("CARGO_BIN_EXE_ftafm"))
            .args(["paper", "--engine", "paper", "--json"])
            .env("FTAFM_ISA", isa)
            .output()
            .expect("the binary runs")
    };
    let out = run("sse4");
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty());
    let err = stderr(&out);
    assert!(
        err.contains("FTAFM_ISA") && err.contains("avx512, avx2, portable") && err.contains("sse4"),
        "{err}"
    );
    for isa in ["avx512", "avx2", "portable"] {
        let out = run(isa);
        assert!(out.status.success(), "FTAFM_ISA={isa}: {}", stderr(&out));
    }
}
