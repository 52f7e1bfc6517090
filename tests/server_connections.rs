//! No peer can hold the daemon: a subscriber that stops reading is dropped and frees its
//! slot, a WebSocket that answers no keep-alive ping is cut, a client's unread replies cost
//! a bounded number of bytes, a client's close is answered at once, a half-sent request
//! header is closed after the header timeout, connections beyond the handshake limit get a
//! 503 at once, and shutdown returns with half-open connections still there. Every wait is
//! on an event; the deadlines only turn a hang into a failure.

use std::time::{Duration, Instant};

use ftafm::server::ConnectionLimits;
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::CloseFrame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;

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
        ..ConnectionLimits::default()
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

/// A client that closes while it is subscribed to busy streams gets the server's close
/// frame (its own code echoed) at once, not a dropped connection (1006) after the data the
/// server had queued for it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_close_is_answered_with_a_close_frame() {
    let mut s = light();
    s.scope.length = 60_000;
    s.scope.rate = 30.0;
    let d = Daemon::start(s).await;
    for round in 0..3 {
        let mut ws = connect(d.addr).await;
        for stream in ["demods", "spectrum", "scope"] {
            call(
                &mut ws,
                json!({"id": round, "op": "subscribe", "stream": stream}),
            )
            .await;
        }
        next_of(&mut ws, "demods").await;
        next_of(&mut ws, "scope").await;
        ws.close(Some(CloseFrame {
            code: CloseCode::Normal,
            reason: "done".into(),
        }))
        .await
        .unwrap();
        // Data the server sent before it read the close may come first; then its close.
        let answer = loop {
            match tokio::time::timeout(HANG, ws.next())
                .await
                .expect("an answer to the close")
            {
                Some(Ok(Message::Close(frame))) => break frame,
                Some(Ok(_)) => continue,
                Some(Err(e)) => panic!("round {round}: the connection failed instead: {e}"),
                None => panic!("round {round}: the connection ended without a close frame"),
            }
        };
        let answer = answer.expect("a close code");
        assert_eq!(answer.code, CloseCode::Normal, "round {round}: {answer:?}");
        // The close handshake is complete: the stream ends cleanly.
        assert!(
            tokio::time::timeout(HANG, ws.next())
                .await
                .expect("the end")
                .is_none()
        );
    }
    d.shutdown().await;
}

/// The handshake of a WebSocket over plain TCP; returns once the 101 has come.
async fn raw_websocket(addr: std::net::SocketAddr) -> TcpStream {
    let mut tcp = TcpStream::connect(addr).await.unwrap();
    tcp.write_all(
        format!(
            "GET /ws HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    // Byte by byte, so that nothing after the response's head is taken from the socket.
    let mut head = Vec::new();
    let mut byte = [0u8];
    while !head.ends_with(b"\r\n\r\n") {
        tcp.read_exact(&mut byte).await.unwrap();
        head.push(byte[0]);
    }
    let head = String::from_utf8_lossy(&head);
    assert!(head.starts_with("HTTP/1.1 101"), "{head}");
    tcp
}

/// The keep-alive: a connection that did the handshake and then neither reads nor sends
/// (half-open, or a wedged client) is pinged, cut when no pong comes and its slot freed; a
/// client that reads, and so answers the pings, is not.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_websockets_are_cut_and_reading_ones_are_kept() {
    let mut s = light();
    s.server.max_clients = 2;
    s.server.stall_timeout = 1.0; // the time a pinged peer has to answer
    let limits = ConnectionLimits {
        ping_interval: Duration::from_millis(100),
        ..ConnectionLimits::default()
    };
    let d = Daemon::start_with(s, limits).await;
    // A client that sends nothing but reads: its library answers each ping as it reads.
    // A new ping comes only after the answer to the last (one is outstanding at a time), so
    // a third ping shows two were answered; a peer that answers none gets one, then a close.
    let mut reader = connect(d.addr).await;
    let (answered_tx, answered) = tokio::sync::oneshot::channel();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let reading = tokio::spawn(async move {
        let mut answered_tx = Some(answered_tx);
        let mut pings = 0;
        tokio::pin!(stopped);
        loop {
            tokio::select! {
                _ = &mut stopped => return reader,
                m = reader.next() => match m {
                    Some(Ok(Message::Ping(_))) => pings += 1,
                    Some(Ok(_)) => {}
                    other => panic!("the reading client lost its connection: {other:?}"),
                },
            }
            if pings == 3 {
                let _ = answered_tx.take().map(|tx| tx.send(()));
            }
        }
    });
    tokio::time::timeout(HANG, answered)
        .await
        .expect("three pings")
        .unwrap();
    // A peer that does the handshake and then nothing at all, not even reading.
    let mut silent = raw_websocket(d.addr).await;
    // Both slots are taken; a third client gets in once the silent one is cut.
    let deadline = Instant::now() + HANG;
    let mut refused = 0;
    let mut third = loop {
        match tokio_tungstenite::connect_async(format!("ws://{}/ws", d.addr)).await {
            Ok((ws, _)) => break ws,
            Err(_) => refused += 1,
        }
        assert!(Instant::now() < deadline, "the silent peer kept its slot");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert!(
        refused > 0,
        "the third client got in before any slot was freed"
    );
    let r = call(&mut third, json!({"id": 1, "op": "hello"})).await;
    assert_eq!(r["ok"], true);
    // The reader, read all along, is still connected and served.
    stop.send(()).unwrap();
    let mut reader = reading.await.unwrap();
    let r = call(&mut reader, json!({"id": 2, "op": "hello"})).await;
    assert_eq!(r["ok"], true, "{r}");
    let (_, metrics) = http_get(d.addr, "/metrics").await;
    assert_eq!(
        metric(&metrics, "ftafm_clients_unresponsive_total"),
        1.0,
        "the silent peer, and only it, is counted"
    );
    // What the silent peer was sent: pings, then the close 1008 "no pong", then EOF.
    let sent = read_to_close(&mut silent).await;
    let close = sent
        .windows(2)
        .position(|w| w == [0x88, 2 + "no pong".len() as u8])
        .map(|at| &sent[at + 2..])
        .expect("a close frame");
    assert_eq!(u16::from_be_bytes([close[0], close[1]]), 1008);
    assert!(close[2..].starts_with(b"no pong"));
    d.shutdown().await;
}

/// The `queued_bytes` of client `id` in a `status` message.
fn queued_bytes(status: &Value, id: u64) -> u64 {
    status["clients_detail"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == id)
        .map(|c| c["queued_bytes"].as_u64().unwrap())
        .expect("the client in clients_detail")
}

/// A client that sends requests and reads none of the replies costs the server
/// `/server/client_queue_bytes` of replies and one more (it is then not served until it
/// reads), not the replies of every request it sent; its `queued_bytes` counts them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replies_a_client_does_not_read_are_bounded_in_bytes() {
    let mut s = light();
    s.server.client_queue_bytes = 1 << 16; // the smallest bound
    s.server.stall_timeout = 600.0; // keep it connected while it does not read
    let bound = s.server.client_queue_bytes;
    let d = Daemon::start(s).await;
    let mut observer = connect(d.addr).await;
    let list = call(&mut observer, json!({"id": 0, "op": "list"})).await;
    let reply_bytes = list.to_string().len() as u64;
    assert!(
        reply_bytes > bound / 2,
        "a list reply is large: {reply_bytes}"
    );
    call(
        &mut observer,
        json!({"id": 1, "op": "subscribe", "stream": "status"}),
    )
    .await;
    // A small receive buffer, so that the sockets fill after a few replies whatever the
    // machine's buffer sizes.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(1 << 16).unwrap();
    let tcp = socket.connect(d.addr).await.unwrap();
    let (mut silent, _) = tokio_tungstenite::client_async(format!("ws://{}/ws", d.addr), tcp)
        .await
        .unwrap();
    let clients = first_of(&mut observer, "status", |s| {
        s["clients_detail"].as_array().unwrap().len() == 2
    })
    .await;
    let silent_id = clients["clients_detail"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_u64().unwrap())
        .max()
        .unwrap();
    // 400 lists (the rate limit's burst): ≈ 30 MB of replies, far more than the socket
    // buffers between the two take, and more than 64 (the reply channel's length) times
    // the bound.
    for id in 0..400 {
        silent
            .send(Message::Text(
                json!({"id": id, "op": "list"}).to_string().into(),
            ))
            .await
            .unwrap();
    }
    // Once the sockets are full the server holds replies for it: wait for that, then for
    // it to stay put (the server serves it no further), checking the bound all along.
    let deadline = Instant::now() + HANG;
    let mut last = 0;
    let mut steady = 0;
    while steady < 4 {
        assert!(
            Instant::now() < deadline,
            "the server never held replies for the client that reads none (last {last} bytes)"
        );
        let status = next_of(&mut observer, "status").await;
        let held = queued_bytes(&status, silent_id);
        assert!(
            held <= bound + reply_bytes,
            "the server holds {held} bytes of replies for a client that reads none (bound \
             {bound} and one reply of {reply_bytes})"
        );
        steady = if held > 0 && held == last {
            steady + 1
        } else {
            0
        };
        last = held;
    }
    // The others are served meanwhile.
    let r = call(&mut observer, json!({"id": 2, "op": "hello"})).await;
    assert_eq!(r["ok"], true);
    drop(silent);
    d.shutdown().await;
}
