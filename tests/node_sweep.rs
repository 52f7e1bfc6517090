//! Every numeric node at its edges, through a running daemon: a `set` is refused with
//! `invalid_value` (and changes nothing) or applied, and either way the real-time threads
//! keep producing demodulator frames; `/healthz` says when they do not.
//!
//! Each test runs its daemon on a runtime of its own in a thread of its own, under a
//! watchdog: a wedged pipeline (whose shutdown would wait for it for ever) fails the test
//! instead of hanging it.

mod common;
use common::*;

use std::future::Future;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

/// The tests of this binary share the process-wide DSP hold (the health test stops the
/// DSP threads): one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// Runs `body` on its own runtime; fails if it has not finished within `limit`.
fn within<F>(limit: Duration, body: impl FnOnce() -> F + Send + 'static)
where
    F: Future<Output = ()> + 'static,
{
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| runtime.block_on(body())));
        let _ = tx.send(result);
        // A wedged pipeline's blocking task would keep a plain drop waiting.
        runtime.shutdown_timeout(Duration::from_secs(1));
    });
    match rx.recv_timeout(limit) {
        Ok(Ok(())) => {}
        Ok(Err(panic)) => std::panic::resume_unwind(panic),
        Err(_) => panic!("not finished within {limit:?}: something is wedged"),
    }
}

/// `call`, waiting out the server's request rate limit (the sweep sends thousands).
async fn ask(ws: &mut Ws, request: Value) -> Value {
    loop {
        let r = call(ws, request.clone()).await;
        if code(&r) != "rate_limited" {
            return r;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Reads messages until a `demods` frame whose simulated time is at least `t` arrives;
/// returns its time. Fails after `limit` of wall time (generous: only a dead pipeline
/// reaches it).
async fn demods_until(ws: &mut Ws, t: f64, limit: Duration, what: &str) -> f64 {
    let deadline = Instant::now() + limit;
    loop {
        let msg = tokio::time::timeout_at(deadline.into(), ws.next())
            .await
            .unwrap_or_else(|_| panic!("no demodulator frame reached t = {t} s after {what}"))
            .expect("the socket stays open")
            .expect("the socket stays open");
        if let Message::Text(text) = msg {
            let v: Value = serde_json::from_str(&text).unwrap();
            if v["stream"] == "demods"
                && let Some(frame_t) = v["t"].as_f64()
                && frame_t >= t
            {
                return frame_t;
            }
        }
    }
}

/// The pipeline is alive: after a fresh subscription, frames keep coming whose simulated
/// time advances by 10 ms past the first one (one from before a wedge could only be a
/// frame already on its way).
async fn assert_frames_advance(ws: &mut Ws, what: &str) {
    let r = ask(ws, json!({"op": "subscribe", "stream": "demods"})).await;
    assert_eq!(r["ok"], true, "{r}");
    let first = demods_until(ws, 0.0, Duration::from_secs(20), what).await;
    demods_until(ws, first + 0.01, Duration::from_secs(20), what).await;
}

/// The sweep's instrument: `light()` with every demodulator at 1 kHz, so that 10 ms of
/// simulated time is ten frames.
fn sweep_settings() -> ftafm::config::Settings {
    let mut s = light();
    for d in &mut s.demods {
        d.rate = 1e3;
    }
    s
}

fn next_up(x: f64) -> f64 {
    if x == 0.0 {
        return f64::from_bits(1);
    }
    let bits = x.to_bits();
    f64::from_bits(if x > 0.0 { bits + 1 } else { bits - 1 })
}

fn next_down(x: f64) -> f64 {
    -next_up(-x)
}

/// The values to try on a node with `list`'s `min` and `max`: both ends, the values just
/// outside them, the smallest positive double and 1e-300.
fn candidates(node: &Value) -> Vec<Value> {
    let (min, max) = (&node["min"], &node["max"]);
    let mut out: Vec<Value> = Vec::new();
    if let (Some(lo), Some(hi)) = (min.as_u64(), max.as_u64()) {
        out.extend([json!(lo), json!(hi)]);
        if lo > 0 {
            out.push(json!(lo - 1));
        }
        out.push(match hi.checked_add(1) {
            Some(above) => json!(above),
            None => json!(hi as f64 * 2.0),
        });
    } else {
        let lo = min.as_f64().expect("a numeric node has a numeric min");
        let hi = max.as_f64().expect("a numeric node has a numeric max");
        out.extend([
            json!(lo),
            json!(hi),
            json!(next_down(lo)),
            json!(next_up(hi)),
        ]);
    }
    out.extend([json!(5e-324), json!(1e-300)]);
    if node["value"].is_array() {
        out = out.into_iter().map(|v| json!([v])).collect();
    }
    out
}

#[test]
fn every_numeric_node_at_its_edges_leaves_the_pipeline_running() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    within(Duration::from_secs(600), || async {
        let daemon = Daemon::start(sweep_settings()).await;
        let mut ws = connect(daemon.addr).await;
        let listed = ask(&mut ws, json!({"op": "list"})).await;
        let nodes = listed["nodes"].as_array().unwrap().clone();
        let numeric: Vec<&Value> = nodes
            .iter()
            .filter(|n| !n["min"].is_null() && !n["max"].is_null())
            .collect();
        // Every node with a numeric range: the scalars, 8 inclusions, 32 demodulators.
        assert!(numeric.len() > 150, "only {} numeric nodes", numeric.len());
        assert_frames_advance(&mut ws, "the start").await;
        let (mut applied, mut refused) = (0, 0);
        for node in numeric {
            let path = node["path"].as_str().unwrap();
            let default = node["value"].clone();
            let mut current = default.clone();
            for value in candidates(node) {
                let what = format!("set {path} = {value}");
                let r = ask(
                    &mut ws,
                    json!({"op": "set", "path": path, "value": value.clone()}),
                )
                .await;
                if node["writable"] == false {
                    assert_eq!(code(&r), "read_only", "{what}: {r}");
                } else if r["ok"] == true {
                    applied += 1;
                    let now = ask(&mut ws, json!({"op": "get", "path": path})).await;
                    assert_eq!(now["value"], r["value"], "{what}: get after set");
                    current = r["value"].clone();
                } else {
                    refused += 1;
                    assert_eq!(code(&r), "invalid_value", "{what}: {r}");
                    let message = r["error"]["message"].as_str().unwrap();
                    assert!(message.contains(path), "{what}: {message}");
                    let after = ask(&mut ws, json!({"op": "get", "path": path})).await;
                    assert_eq!(after["value"], current, "{what} changed the node");
                }
                assert_frames_advance(&mut ws, &what).await;
            }
            if node["writable"] == true {
                let r = ask(
                    &mut ws,
                    json!({"op": "set", "path": path, "value": default.clone()}),
                )
                .await;
                assert_eq!(r["ok"], true, "restoring {path} = {default}: {r}");
                assert_frames_advance(&mut ws, &format!("restoring {path}")).await;
            }
        }
        assert!(
            applied > 0 && refused > 0,
            "{applied} applied, {refused} refused"
        );
        let (status, body) = http_get(daemon.addr, "/healthz").await;
        assert_eq!(status, 200, "{body}");
        drop(ws);
        tokio::time::timeout(Duration::from_secs(30), daemon.shutdown())
            .await
            .expect("the daemon shuts down");
    });
}

/// Releases the process-wide DSP hold however the test ends.
struct Release;

impl Drop for Release {
    fn drop(&mut self) {
        ftafm::pipeline::hold_all_dsp(false);
    }
}

/// Polls `/healthz` until its status is `want`; returns the body. Fails after `limit`.
async fn health_becomes(addr: std::net::SocketAddr, want: u16, limit: Duration) -> String {
    let deadline = Instant::now() + limit;
    loop {
        let (status, body) = http_get(addr, "/healthz").await;
        if status == want {
            return body;
        }
        assert!(
            Instant::now() < deadline,
            "/healthz still {status} ({body:?}) after {limit:?}, expected {want}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[test]
fn healthz_reports_a_stalled_pipeline_and_its_recovery() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    within(Duration::from_secs(120), || async {
        let daemon = Daemon::start(light()).await;
        health_becomes(daemon.addr, 200, Duration::from_secs(30)).await;
        let release = Release;
        ftafm::pipeline::hold_all_dsp(true);
        let reason = health_becomes(daemon.addr, 503, Duration::from_secs(30)).await;
        assert!(
            reason.contains("stalled") && reason.contains("DSP thread"),
            "{reason}"
        );
        drop(release);
        health_becomes(daemon.addr, 200, Duration::from_secs(30)).await;
        let mut ws = connect(daemon.addr).await;
        assert_frames_advance(&mut ws, "the hold's release").await;
        drop(ws);
        tokio::time::timeout(Duration::from_secs(30), daemon.shutdown())
            .await
            .expect("the daemon shuts down");
    });
}

/// One rule for paths in `get`, `set` and `list`: `/` then names, no empty name, no
/// trailing slash; anything else is `unknown_path` saying so.
#[test]
fn malformed_paths_are_refused_alike_by_every_op() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    within(Duration::from_secs(120), || async {
        let daemon = Daemon::start(light()).await;
        let mut ws = connect(daemon.addr).await;
        for path in ["//", "/drive/", "/drive//frequency", "/drive/frequency/"] {
            for request in [
                json!({"op": "list", "path": path}),
                json!({"op": "get", "path": path}),
                json!({"op": "set", "path": path, "value": 1e5}),
            ] {
                let r = call(&mut ws, request.clone()).await;
                assert_eq!(code(&r), "unknown_path", "{request}: {r}");
                let message = r["error"]["message"].as_str().unwrap();
                assert!(
                    message.starts_with("malformed path"),
                    "{request}: {message}"
                );
            }
        }
        let all = call(&mut ws, json!({"op": "list", "path": "/"})).await;
        let none = call(&mut ws, json!({"op": "list"})).await;
        assert_eq!(all["nodes"], none["nodes"]);
        let drive = call(&mut ws, json!({"op": "list", "path": "/drive"})).await;
        assert_eq!(drive["nodes"].as_array().unwrap().len(), 3, "{drive}");
        let r = call(&mut ws, json!({"op": "list", "path": "/drive/nothing"})).await;
        assert_eq!(code(&r), "unknown_path", "{r}");
        drop(ws);
        tokio::time::timeout(Duration::from_secs(30), daemon.shutdown())
            .await
            .expect("the daemon shuts down");
    });
}
