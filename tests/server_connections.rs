//! No peer can hold the daemon: a subscriber that stops reading is dropped and frees its
//! slot, a half-sent request header is closed after the header timeout, connections beyond
//! the handshake limit get a 503 at once, and shutdown returns with half-open connections
//! still there. Every wait is on an event; the deadlines only turn a hang into a failure.

use std::time::{Duration, Instant};

use ftafm::server::ConnectionLimits;
use futures_util::SinkExt;
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

mod common;
use common::*;

/// Guard against a hang, never a margin the test relies on.
const HANG: Duration = Duration::from_secs(120);

/// Reads until the peer closes (EOF or reset); returns what came.
async fn read_to_close(s: &mut TcpStream) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match tokio::time::timeout(HANG, s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return out,
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
            Err(_) => panic!("the connection stayed open"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscribers_that_stop_reading_are_dropped_and_free_their_slots() {
    let mut s = light();
    s.server.max_clients = 4;
    s.server.stall_timeout = 1.0;
    // Long scope traces at the highest rate they allow: MB per second per client, so a
    // reader that stops fills its socket quickly.
    s.scope.length = 60_000;
    s.scope.rate = 30.0;
    let d = Daemon::start(s).await;
    let mut silent = Vec::new();
    for id in 0..4 {
        let mut ws = connect(d.addr).await;
        ws.send(Message::Text(
            json!({"id": id, "op": "subscribe", "stream": "scope"})
                .to_string()
                .into(),
        ))
        .await
        .unwrap();
        // From here on this client reads nothing.
        silent.push(ws);
    }
    // A fifth client is refused while the four hold their slots, and gets in once the
    // daemon has dropped them for stalling.
    let deadline = Instant::now() + HANG;
    let mut refused = 0;
    let mut fifth = loop {
        match tokio_tungstenite::connect_async(format!("ws://{}/ws", d.addr)).await {
            Ok((ws, _)) => break ws,
            Err(_) => refused += 1,
        }
        assert!(
            Instant::now() < deadline,
            "the four stalled clients kept their slots"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(
        refused > 0,
        "the fifth client got in before any slot was freed"
    );
    let r = call(&mut fifth, json!({"id": 1, "op": "hello"})).await;
    assert_eq!(r["ok"], true);
    let (_, metrics) = http_get(d.addr, "/metrics").await;
    assert!(
        metric(&metrics, "ftafm_clients_stalled_total") >= 1.0,
        "stalls are counted"
    );
    // The stalled clients' TCP connections are closed by the daemon: the unread data drains,
    // then EOF (no 1008 waits on a full socket).
    for ws in silent {
        let mut tcp = match ws.into_inner() {
            tokio_tungstenite::MaybeTlsStream::Plain(tcp) => tcp,
            _ => unreachable!("plain TCP"),
        };
        read_to_close(&mut tcp).await;
    }
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_sent_headers_are_closed_and_cannot_hold_the_shutdown() {
    let limits = ConnectionLimits {
        header_timeout: Duration::from_secs(1),
        max_handshaking: 64,
        shutdown_grace: Duration::from_secs(1),
    };
    let d = Daemon::start_with(light(), limits).await;
    // 100 connections that start a request and never finish its headers.
    let mut trickling = Vec::new();
    for _ in 0..100 {
        let mut s = TcpStream::connect(d.addr).await.unwrap();
        s.write_all(b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            .await
            .unwrap();
        trickling.push(s);
    }
    // Beyond the 64 the daemon answers 503 at once and closes.
    let refused = read_to_close(trickling.last_mut().unwrap()).await;
    let text = String::from_utf8_lossy(&refused);
    assert!(text.starts_with("HTTP/1.1 503"), "{text}");
    assert!(text.contains("at most 64"), "{text}");
    // The first ones are closed when their header timeout runs out.
    read_to_close(&mut trickling[0]).await;
    let (status, metrics) = http_get(d.addr, "/metrics").await;
    assert_eq!(status, 200);
    assert!(
        metric(
            &metrics,
            "ftafm_http_connections_dropped_total{reason=\"limit\"}"
        ) >= 1.0
    );
    assert!(
        metric(
            &metrics,
            "ftafm_http_connections_dropped_total{reason=\"header_timeout\"}"
        ) >= 1.0
    );
    // New half-open connections, then shutdown: it returns (the old server waited for them
    // for ever). The bound is a hang guard, far above the 1 s grace.
    let mut more = Vec::new();
    for _ in 0..50 {
        let mut s = TcpStream::connect(d.addr).await.unwrap();
        s.write_all(b"GET / HTTP/1.1\r\n").await.unwrap();
        more.push(s);
    }
    let took = tokio::time::timeout(HANG, d.shutdown())
        .await
        .expect("shutdown returned");
    eprintln!("shutdown with 50 half-open connections took {took:?}");
}
