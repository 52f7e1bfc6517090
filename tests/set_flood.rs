//! A flood of valid `set`s at the request rate limit must not break real time: the
//! expensive rebuilds it causes (synthesis plan, force estimator, image worker) are
//! coalesced, one at a time, latest wins, off the real-time threads.
//!
//! `FLOOD_DEFAULTS=1 cargo test --release --test set_flood -- --nocapture` runs it at the
//! default settings and prints the late blocks and overruns: a measurement for a quiet
//! machine (docs/benchmarks.md), not an assertion.

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;

mod common;
use common::*;

fn threads() -> usize {
    std::fs::read_dir("/proc/self/task")
        .map(|d| d.count())
        .unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_set_flood_costs_one_estimator_build_at_a_time() {
    let settings = if std::env::var("FLOOD_DEFAULTS").is_ok() {
        ftafm::config::default_settings()
    } else {
        let mut s = light();
        s.inversion.enable = true;
        s.inversion.harmonic_b = 9; // in band at 2 MS/s
        s
    };
    let d_start = Instant::now();
    let d = Daemon::start(settings).await;
    let before = threads();
    let mut conns = Vec::new();
    for _ in 0..3 {
        conns.push(connect(d.addr).await);
    }
    let start = Instant::now();
    let mut tasks = Vec::new();
    for (c, mut ws) in conns.into_iter().enumerate() {
        tasks.push(tokio::spawn(async move {
            let mut n = 0u64;
            let mut max_threads = 0;
            while start.elapsed() < Duration::from_secs(5) {
                // 150 per second per connection: below the limit of 200 (and all different,
                // so that none is a no-op).
                for _ in 0..15 {
                    let v = 29.5e-9 + 1e-12 * ((n * 3 + c as u64) % 1000) as f64;
                    ws.send(Message::Text(
                        json!({"id": n, "op": "set", "path": "/drive/free_amplitude", "value": v})
                            .to_string()
                            .into(),
                    ))
                    .await
                    .unwrap();
                    n += 1;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
                max_threads = max_threads.max(threads());
            }
            // Every request gets its reply.
            let mut replies = 0;
            let mut errors = std::collections::BTreeMap::new();
            while replies < n {
                let m = tokio::time::timeout(Duration::from_secs(60), ws.next())
                    .await
                    .expect("replies in time")
                    .unwrap()
                    .unwrap();
                if let Message::Text(t) = m {
                    let v: serde_json::Value = serde_json::from_str(&t).unwrap();
                    if v.get("ok").is_some() {
                        replies += 1;
                        if v["ok"] != true {
                            *errors.entry(v["error"]["code"].to_string()).or_insert(0) += 1;
                        }
                    }
                }
            }
            assert!(errors.is_empty(), "{errors:?}");
            (n, max_threads)
        }));
    }
    let mut sent = 0;
    let mut max_threads = 0;
    for t in tasks {
        let (n, m) = t.await.unwrap();
        sent += n;
        max_threads = max_threads.max(m);
    }
    let elapsed = start.elapsed();
    // The newest change is built in the end (latest wins): wait for it, not for a time.
    let deadline = Instant::now() + Duration::from_secs(120);
    let metrics = loop {
        let (_, metrics) = http_get(d.addr, "/metrics").await;
        let m = |name: &str| metric(&metrics, name);
        // A build stopped because newer settings arrived was taken up too.
        let force = m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"built\"}")
            + m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"coalesced\"}")
            + m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"cancelled\"}");
        let image = m("ftafm_estimator_rebuilds_total{worker=\"image\",outcome=\"built\"}")
            + m("ftafm_estimator_rebuilds_total{worker=\"image\",outcome=\"coalesced\"}");
        // The force stream's start-up build is the +1.
        if force == sent as f64 + 1.0 && image == sent as f64 {
            break metrics;
        }
        assert!(
            Instant::now() < deadline,
            "{sent} sets, {force} force and {image} image changes taken up"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let since_start = d_start.elapsed().as_secs_f64();
    let m = |name: &str| metric(&metrics, name);
    let built = m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"built\"}");
    let coalesced = m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"coalesced\"}");
    let cancelled = m("ftafm_estimator_rebuilds_total{worker=\"force\",outcome=\"cancelled\"}");
    let build_s = m("ftafm_estimator_rebuild_seconds_total");
    let image_built = m("ftafm_estimator_rebuilds_total{worker=\"image\",outcome=\"built\"}");
    let image_coalesced =
        m("ftafm_estimator_rebuilds_total{worker=\"image\",outcome=\"coalesced\"}");
    eprintln!(
        "{sent} sets in {elapsed:?}; threads {before} -> max {max_threads}; force estimator: \
         {built} built ({build_s:.2} s), {coalesced} coalesced, {cancelled} cancelled; image: \
         {image_built} built, \
         {image_coalesced} coalesced; late blocks {}, overruns {}",
        m("ftafm_late_blocks_total"),
        m("ftafm_overrun_samples_total"),
    );
    // Every change was either built or superseded by a newer one (before or while it was
    // built), and the builder never
    // spent more than its quarter of the wall time since the start, beyond its 4 s burst
    // (src/instrument/build_budget.rs; the last build may end the interval), whatever the
    // machine's speed.
    assert!(
        build_s <= 0.25 * since_start + 4.0 + build_s / built,
        "{build_s} s of builds in {since_start} s"
    );
    // The old way ran one blocking thread per build (70 threads at the defaults).
    assert!(
        max_threads <= before + 16,
        "threads {before} -> {max_threads}"
    );
    d.shutdown().await;
}
