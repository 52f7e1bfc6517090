//! A client that stops reading large messages costs the daemon its byte bound
//! (`/server/client_queue_bytes`), not what its message count allows. Its own binary: the
//! test measures this process's resident memory, which other tests would share.

use std::time::{Duration, Instant};

use ftafm::server::status::ProcessMemory;
use serde_json::json;

mod common;
use common::*;

/// A client that stops reading 2^20-point spectra costs the daemon at most its byte bound,
/// not the hundreds of MB a queue bounded in messages held; `status` still reaches it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_reader_of_the_largest_spectra_costs_its_byte_bound() {
    let mut s = light();
    s.spectrum.size = 1 << 20; // 524289 bins: ≈ 7 MB of JSON each
    s.spectrum.rate = 5.0;
    s.server.stall_timeout = 600.0; // keep it connected while it does not read
    let bound = s.server.client_queue_bytes;
    assert_eq!(bound, 8 << 20, "the default bound");
    let d = Daemon::start(s).await;
    let mut slow = connect(d.addr).await;
    call(
        &mut slow,
        json!({"id": 1, "op": "subscribe", "stream": "spectrum"}),
    )
    .await;
    // The baseline: the daemon in its steady state, every buffer of the 2^20 spectrum
    // allocated, the client keeping up.
    for _ in 0..10 {
        next_of(&mut slow, "spectrum").await;
    }
    let before = ProcessMemory::read().map(|m| m.resident_bytes);
    // From here on `slow` reads nothing. Wait for the event: its queue full and spectra
    // dropped for it, a good many of them.
    let deadline = Instant::now() + Duration::from_secs(300);
    let metric = |text: &str, name: &str| -> f64 {
        text.lines()
            .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
            .and_then(|l| l.rsplit(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0)
    };
    loop {
        let (_, metrics) = http_get(d.addr, "/metrics").await;
        if metric(
            &metrics,
            "ftafm_messages_dropped_total{stream=\"spectrum\"}",
        ) >= 20.0
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no spectra dropped for the slow reader"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let after = ProcessMemory::read().map(|m| m.resident_bytes);
    // The queue (8 MiB, plus one message over it) and the socket buffers: well under
    // 100 MB. A queue bounded only by its 1024 messages would hold 7 GB.
    if let (Some(before), Some(after)) = (before, after) {
        let growth = after.saturating_sub(before);
        eprintln!(
            "RSS {} MB -> {} MB (+{} MB) with a slow reader of 2^20-point spectra",
            before >> 20,
            after >> 20,
            growth >> 20
        );
        assert!(growth < 100 << 20, "RSS grew by {} MB", growth >> 20);
    }
    // `status` is not starved behind the spectra: another client gets it at once, and the
    // slow client's report shows its queue at its bound.
    let mut other = connect(d.addr).await;
    call(
        &mut other,
        json!({"id": 1, "op": "subscribe", "stream": "status"}),
    )
    .await;
    let status = next_of(&mut other, "status").await;
    let queued = status["clients_detail"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["queued_bytes"].as_u64().unwrap())
        .max()
        .unwrap();
    assert!(queued > 0 && queued <= 2 * bound, "queued {queued} bytes");
    drop(slow);
    d.shutdown().await;
}
