//! `ftafm soak` against the daemon started in-process on 127.0.0.1:0, and the command's
//! exit codes through the binary.

use std::process::{Command, Output};

use ftafm::config::{Settings, default_settings};
use ftafm::soak::{SoakOptions, SoakReport};
use tokio::net::TcpListener;
use tokio::sync::oneshot;

/// Instrument settings for tests (as in tests/server.rs): 2 MS/s, demodulators at 200 Hz.
fn light() -> Settings {
    let mut s = default_settings();
    s.synth.sample_rate = 2e6;
    for d in &mut s.demods {
        d.harmonic = d.harmonic.min(9);
        d.rate = 200.0;
    }
    s.demods[16].harmonic = 9;
    s.spectrum.size = 4096;
    s.inversion.enable = false;
    s
}

fn ftafm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ftafm"))
        .args(args)
        .output()
        .expect("the binary runs")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn four_clients_for_five_seconds_lose_nothing() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = oneshot::channel::<()>();
    let server = tokio::spawn(ftafm::server::run(listener, light(), async move {
        let _ = stopped.await;
    }));

    let (clients, seconds, rate) = (4usize, 5.0, 200.0);
    let options = SoakOptions::new(format!("ws://{addr}/ws"), clients, seconds);
    let mut ticks = 0;
    let report = ftafm::soak::run(&options, |_| ticks += 1).await.unwrap();
    let _ = stop.send(());
    server.await.unwrap().unwrap();

    assert!(ticks >= 3, "progress about once a second, got {ticks}");
    assert_eq!(report.clients, clients);
    assert_eq!(report.gaps, 0, "{report:?}");
    assert_eq!(report.disconnects, 0, "{report:?}");
    assert_eq!(report.server.overruns, 0, "{report:?}");
    assert_eq!(report.server.overrun_blocks, 0, "{report:?}");
    assert_eq!(report.server.messages_dropped, 0, "{report:?}");
    assert_eq!(report.server.clients_during, clients as u64, "{report:?}");
    let expected = clients as f64 * rate * report.seconds;
    let ratio = report.messages as f64 / expected;
    assert!(
        (0.85..=1.15).contains(&ratio),
        "{} messages, expected ≈ {expected:.0}",
        report.messages
    );
    assert_eq!(report.latency_ns.count, report.messages);
    assert!(report.latency_ns.p50 > 0);
    assert!(
        report.latency_ns.p50 < 10_000_000,
        "{:?}",
        report.latency_ns
    );
    assert!(
        report.latency_ns.p99 < 50_000_000,
        "{:?}",
        report.latency_ns
    );
    assert!(report.server.memory_bytes.is_none());
    assert!(report.server.memory.contains("unavailable"));
    assert!(!report.lost_anything());

    // The JSON report has the documented fields and reads back.
    let v = serde_json::to_value(&report).unwrap();
    for key in [
        "messages",
        "gaps",
        "disconnects",
        "clients",
        "seconds",
        "messages_per_s",
        "bytes_per_s",
    ] {
        assert!(v[key].is_number(), "{key} missing: {v}");
    }
    for key in ["p50", "p90", "p99", "p999", "max"] {
        assert!(v["latency_ns"][key].is_u64(), "latency_ns.{key} missing");
    }
    for key in [
        "overruns",
        "overrun_blocks",
        "messages_dropped",
        "clients_during",
    ] {
        assert!(v["server"][key].is_u64(), "server.{key} missing");
    }
    assert!(v["server"]["messages_dropped_by_stream"]["demods"].is_u64());
    assert!(v["server"]["memory_bytes"].is_null());
    let back: SoakReport = serde_json::from_value(v).unwrap();
    assert_eq!(back, report);
    assert!(ftafm::soak::render_text(&report).contains("memory    unavailable"));
}

#[test]
fn bad_flags_exit_2_naming_the_flag() {
    for (args, flag) in [
        (&["--clients", "0"][..], "--clients"),
        (&["--clients", "1025"], "--clients"),
        (&["--clients", "-3"], "--clients"),
        (&["--seconds", "0"], "--seconds"),
        (&["--seconds", "-1"], "--seconds"),
        (&["--seconds", "86401"], "--seconds"),
        (&["--seconds", "NaN"], "--seconds"),
        (&["--streams", "demods,bogus"], "--streams"),
        (&["--streams", ","], "--streams"),
        (&["--url", "http://127.0.0.1:8700/ws"], "--url"),
        (&["--url", "ws://127.0.0.1:notaport/ws"], "--url"),
        (&["--bogus"], "--bogus"),
    ] {
        let mut all = vec!["soak", "--seconds", "1", "--clients", "1"];
        all.extend_from_slice(args);
        let out = ftafm(&all);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(flag), "{args:?}: {stderr}");
    }
}

#[test]
fn nothing_listening_exits_1() {
    // A port that was just free: bind, note it, release it.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let url = format!("ws://127.0.0.1:{port}/ws");
    let out = ftafm(&["soak", "--url", &url, "--seconds", "1", "--clients", "1"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot connect"), "{stderr}");
}
