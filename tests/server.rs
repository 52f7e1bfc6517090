//! The daemon over real sockets: real WebSocket clients (tokio-tungstenite) and plain
//! HTTP on 127.0.0.1:0, the server started as mini-redis does, `run(listener, ...)`.

use std::time::{Duration, Instant};

use ftafm::config::{Engine, Settings, default_settings};
use ftafm::pipeline::BLOCK_SAMPLES;
use ftafm::server::protocol::decode_header;
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::{self, Message};

mod common;
use common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_op_answers_and_ids_are_echoed() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let hello = call(&mut ws, json!({"id": 1, "op": "hello"})).await;
    assert_eq!(hello["id"], 1);
    assert_eq!(hello["ok"], true);
    assert_eq!(hello["server"], "ftafm");
    assert_eq!(hello["protocol"], 1);
    assert_eq!(hello["sample_rate"], 2e6);

    let list = call(&mut ws, json!({"id": "all", "op": "list"})).await;
    let nodes = list["nodes"].as_array().unwrap();
    assert!(
        nodes.len() > 100,
        "every node, the 160 demodulator nodes included"
    );
    let modulus = nodes
        .iter()
        .find(|n| n["path"] == "/sample/youngs_modulus")
        .unwrap();
    assert_eq!(modulus["unit"], "Pa");
    assert_eq!(modulus["writable"], true);
    assert_eq!(modulus["value"], 129e9);
    assert!(modulus["max"].is_number() && modulus["description"].is_string());
    assert_eq!(modulus["type"], "float");
    assert!(modulus.get("allowed").is_none());
    let window = nodes
        .iter()
        .find(|n| n["path"] == "/spectrum/window")
        .unwrap();
    assert_eq!(window["type"], "text");
    assert_eq!(
        window["allowed"],
        json!(["rectangular", "hann", "blackman_harris", "flat_top"])
    );
    let types: std::collections::BTreeSet<&str> =
        nodes.iter().map(|n| n["type"].as_str().unwrap()).collect();
    assert_eq!(
        types,
        [
            "bool",
            "float",
            "float_list",
            "integer",
            "text",
            "text_list"
        ]
        .into()
    );
    let demod3 = call(
        &mut ws,
        json!({"id": [1, 2], "op": "list", "path": "/demods/3"}),
    )
    .await;
    assert_eq!(demod3["id"], json!([1, 2]));
    assert_eq!(demod3["nodes"].as_array().unwrap().len(), 6);

    let set = call(
        &mut ws,
        json!({"id": 3, "op": "set", "path": "/sample/youngs_modulus", "value": 116.1e9}),
    )
    .await;
    assert_eq!(set["ok"], true, "{set}");
    assert_eq!(set["value"], 116.1e9);
    let get = call(
        &mut ws,
        json!({"op": "get", "path": "/sample/youngs_modulus"}),
    )
    .await;
    assert_eq!(get["id"], Value::Null);
    assert_eq!(get["value"], 116.1e9);

    let sub = call(
        &mut ws,
        json!({"id": 4, "op": "subscribe", "stream": "status"}),
    )
    .await;
    assert_eq!(
        (sub["ok"].clone(), sub["stream"].clone()),
        (json!(true), json!("status"))
    );
    let status = next_of(&mut ws, "status").await;
    assert_eq!(status["sample_rate"], 2e6);
    let unsub = call(
        &mut ws,
        json!({"id": 5, "op": "unsubscribe", "stream": "status"}),
    )
    .await;
    assert_eq!(unsub["ok"], true);
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_the_right_error_and_the_connection_goes_on() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let cases = [
        ("{not json", "bad_request"),
        ("[1, 2]", "bad_request"),
        (r#"{"id": 7}"#, "bad_request"),
        (r#"{"id": 7, "op": 5}"#, "bad_request"),
        (r#"{"id": 7, "op": "explode"}"#, "unknown_op"),
        (r#"{"id": 7, "op": "get"}"#, "bad_request"),
        (r#"{"id": 7, "op": "get", "path": 3}"#, "bad_request"),
        (
            r#"{"id": 7, "op": "get", "path": "/sample/colour"}"#,
            "unknown_path",
        ),
        (
            r#"{"id": 7, "op": "list", "path": "/nowhere"}"#,
            "unknown_path",
        ),
        (
            r#"{"id": 7, "op": "set", "path": "/synth/sample_rate", "value": 1e6}"#,
            "read_only",
        ),
        (
            r#"{"id": 7, "op": "set", "path": "/sample/youngs_modulus", "value": -1}"#,
            "invalid_value",
        ),
        (
            r#"{"id": 7, "op": "set", "path": "/sample/youngs_modulus", "value": "hard"}"#,
            "invalid_value",
        ),
        (
            r#"{"id": 7, "op": "set", "path": "/sample/poisson", "value": 0.5}"#,
            "invalid_value",
        ),
        (
            r#"{"id": 7, "op": "set", "path": "/synth/engine", "value": "quantum"}"#,
            "invalid_value",
        ),
        (
            r#"{"id": 7, "op": "subscribe", "stream": "gossip"}"#,
            "unknown_stream",
        ),
        (
            r#"{"id": 7, "op": "subscribe", "stream": "demods", "format": "xml"}"#,
            "bad_request",
        ),
    ];
    for (text, expected) in cases {
        ws.send(Message::Text(text.into())).await.unwrap();
        let r = reply(&mut ws).await;
        assert_eq!(r["ok"], false, "{text}");
        assert_eq!(code(&r), expected, "{text}: {r}");
        assert!(
            r["error"]["message"]
                .as_str()
                .is_some_and(|m| !m.is_empty())
        );
        let expected_id = if text.starts_with("{not") || text.starts_with('[') {
            Value::Null
        } else {
            json!(7)
        };
        assert_eq!(r["id"], expected_id, "{text}");
    }
    // The messages say what is allowed.
    ws.send(Message::Text(
        r#"{"id": 8, "op": "set", "path": "/sample/poisson", "value": 0.7}"#.into(),
    ))
    .await
    .unwrap();
    let r = reply(&mut ws).await;
    let msg = r["error"]["message"].as_str().unwrap();
    assert!(
        msg.contains("/sample/poisson") && msg.contains("0.5"),
        "{msg}"
    );
    // A failed set changed nothing, and the connection still works.
    let get = call(
        &mut ws,
        json!({"id": 9, "op": "get", "path": "/sample/poisson"}),
    )
    .await;
    assert_eq!(get["value"], 0.28);
    let hello = call(&mut ws, json!({"id": 10, "op": "hello"})).await;
    assert_eq!(hello["ok"], true);
    // Binary requests are refused with a reply, not a hang-up.
    ws.send(Message::Binary(vec![1, 2, 3].into()))
        .await
        .unwrap();
    assert_eq!(code(&reply(&mut ws).await), "bad_request");
    // An oversized message closes the connection with 1009 and a reason.
    let big = format!(r#"{{"op":"hello","pad":"{}"}}"#, "x".repeat(70 * 1024));
    let _ = ws.send(Message::Text(big.into())).await;
    let closed = tokio::time::timeout(Duration::from_secs(5), async {
        while let Some(m) = ws.next().await {
            match m {
                Ok(Message::Close(Some(f))) => return Some(u16::from(f.code)),
                Ok(_) => continue,
                Err(_) => return None,
            }
        }
        None
    })
    .await
    .unwrap();
    assert_eq!(closed, Some(1009));
    // Another client is unaffected.
    let mut other = connect(d.addr).await;
    assert_eq!(call(&mut other, json!({"op": "hello"})).await["ok"], true);
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_carry_seq_time_and_synthesis_time() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    for stream in ["demods", "spectrum", "scope", "status"] {
        let r = call(
            &mut ws,
            json!({"id": stream, "op": "subscribe", "stream": stream}),
        )
        .await;
        assert_eq!(r["ok"], true);
    }
    let mut seen = std::collections::HashMap::<String, Vec<Value>>::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while seen.get("status").map_or(0, |v| v.len()) < 3
        || seen.get("demods").map_or(0, |v| v.len()) < 50
    {
        let msg = tokio::time::timeout_at(deadline.into(), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        if let Message::Text(t) = msg {
            let v: Value = serde_json::from_str(&t).unwrap();
            if v.get("ok").is_none() {
                seen.entry(v["stream"].as_str().unwrap().to_string())
                    .or_default()
                    .push(v);
            }
        }
    }
    let now_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as f64;
    for (stream, msgs) in &seen {
        for w in msgs.windows(2) {
            assert_eq!(
                w[1]["seq"].as_u64().unwrap(),
                w[0]["seq"].as_u64().unwrap() + 1,
                "{stream}: contiguous seq"
            );
            assert!(
                w[1]["t"].as_f64() >= w[0]["t"].as_f64(),
                "{stream}: time goes forward"
            );
        }
        let last = msgs.last().unwrap();
        let synth = last["t_synth_ns"].as_f64().unwrap();
        assert!(
            (now_ns - synth).abs() < 5e9,
            "{stream}: t_synth_ns is a recent Unix time"
        );
    }
    let demods = &seen["demods"].last().unwrap()["demods"];
    let d0 = &demods[0];
    assert_eq!(d0["index"], 0);
    assert_eq!(d0["harmonic"], 1);
    let (x, y, r) = (
        d0["x"].as_f64().unwrap(),
        d0["y"].as_f64().unwrap(),
        d0["r"].as_f64().unwrap(),
    );
    assert!(
        (x.hypot(y) - r).abs() < 1e-15 && r > 15e-9 && r < 25e-9,
        "fundamental ≈ 19 nm: {r}"
    );
    let spectrum = seen["spectrum"].last().unwrap();
    assert_eq!(
        spectrum["magnitudes"].as_array().unwrap().len(),
        4096 / 2 + 1
    );
    let scope = seen["scope"].last().unwrap();
    assert_eq!(scope["samples"].as_array().unwrap().len(), 2000);
    assert_eq!(scope["dt"], 1.0 / 2e6);

    // The binary format of the same stream decodes to the documented header.
    let r = call(
        &mut ws,
        json!({"id": 1, "op": "subscribe", "stream": "demods", "format": "binary"}),
    )
    .await;
    assert_eq!(r["ok"], true);
    let bin = loop {
        if let Message::Binary(b) = ws.next().await.unwrap().unwrap() {
            break b;
        }
    };
    let header = decode_header(&bin).expect("a valid header");
    assert_eq!(header.count, 32);
    assert_eq!(bin.len(), 40 + 32 * 40);
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn foreign_origins_are_refused_unless_allowed() {
    let d = Daemon::start(light()).await;
    let with_origin = |origin: &str| {
        let mut req = format!("ws://{}/ws", d.addr).into_client_request().unwrap();
        req.headers_mut()
            .insert("Origin", HeaderValue::from_str(origin).unwrap());
        req
    };
    match tokio_tungstenite::connect_async(with_origin("http://evil.example")).await {
        Err(tungstenite::Error::Http(resp)) => assert_eq!(resp.status(), 403),
        other => panic!("expected 403, got {other:?}"),
    }
    // The server's own origin is fine, and so is one added to /server/allowed_origins.
    let own = format!("http://{}", d.addr);
    let (_own, _) = tokio_tungstenite::connect_async(with_origin(&own))
        .await
        .expect("own origin");
    let mut ws = connect(d.addr).await;
    match tokio_tungstenite::connect_async(with_origin("http://lab.example:3000")).await {
        Err(tungstenite::Error::Http(resp)) => assert_eq!(resp.status(), 403),
        other => panic!("not allowed yet, expected 403, got {other:?}"),
    }
    let r = call(&mut ws, json!({"op": "set", "path": "/server/allowed_origins", "value": ["http://lab.example:3000"]})).await;
    assert_eq!(r["ok"], true, "{r}");
    let (_lab, _) = tokio_tungstenite::connect_async(with_origin("http://lab.example:3000"))
        .await
        .expect("allowed now");
    // And a limit on clients: with 3 connected and a limit of 4, one more gets in and the
    // next handshake is refused with 503.
    let r = call(
        &mut ws,
        json!({"op": "set", "path": "/server/max_clients", "value": 4}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let _b = connect(d.addr).await;
    match tokio_tungstenite::connect_async(format!("ws://{}/ws", d.addr)).await {
        Err(tungstenite::Error::Http(resp)) => assert_eq!(resp.status(), 503),
        other => panic!("expected 503, got {other:?}"),
    }
    let (status, metrics) = http_get(d.addr, "/metrics").await;
    assert_eq!(status, 200);
    assert!(
        metrics.contains("ftafm_connections_refused_total{reason=\"origin\"} 2"),
        "{metrics}"
    );
    assert!(metrics.contains("ftafm_connections_refused_total{reason=\"capacity\"} 1"));
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sixty_four_clients_all_receive() {
    let d = Daemon::start(light()).await;
    let mut clients = Vec::new();
    for i in 0..64 {
        let mut ws = connect(d.addr).await;
        let r = call(
            &mut ws,
            json!({"id": i, "op": "subscribe", "stream": "demods"}),
        )
        .await;
        assert_eq!(r["ok"], true);
        clients.push(ws);
    }
    let tasks: Vec<_> = clients
        .into_iter()
        .map(|mut ws| {
            tokio::spawn(async move {
                let mut seqs = Vec::new();
                while seqs.len() < 100 {
                    let v = next_of(&mut ws, "demods").await;
                    seqs.push(v["seq"].as_u64().unwrap());
                }
                seqs
            })
        })
        .collect();
    for t in tasks {
        let seqs = t.await.unwrap();
        assert!(
            seqs.windows(2).all(|w| w[1] == w[0] + 1),
            "every client gets every message"
        );
    }
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_client_loses_its_own_messages_and_is_cut_off_not_the_others() {
    let mut settings = light();
    settings.spectrum.size = 65536;
    settings.spectrum.rate = 200.0; // ≈ 0.5 MB of JSON per spectrum, 200 a second
    settings.server.client_queue = 16;
    settings.server.stall_timeout = 2.0;
    let d = Daemon::start(settings).await;
    let mut slow = connect(d.addr).await;
    assert_eq!(
        call(&mut slow, json!({"op": "subscribe", "stream": "spectrum"})).await["ok"],
        true
    );
    let mut good = connect(d.addr).await;
    assert_eq!(
        call(&mut good, json!({"op": "subscribe", "stream": "demods"})).await["ok"],
        true
    );
    // `slow` reads nothing from here on; `good` keeps reading. Wait for the events (the
    // slow client's drops counted, then its cut-off), not for a time: a busy machine only
    // makes them come later.
    let metric = |text: &str, name: &str| -> f64 {
        text.lines()
            .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
            .and_then(|l| l.rsplit(' ').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {name}"))
    };
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut received = 0u64;
    let metrics = loop {
        for _ in 0..50 {
            next_of(&mut good, "demods").await;
            received += 1;
        }
        let (_, metrics) = http_get(d.addr, "/metrics").await;
        // Counted as stalled, and gone from the clients (the slot is free).
        if metric(&metrics, "ftafm_clients_stalled_total") >= 1.0
            && metric(&metrics, "ftafm_clients") == 1.0
        {
            break metrics;
        }
        assert!(
            Instant::now() < deadline,
            "the slow client was never cut off"
        );
    };
    assert!(
        metric(
            &metrics,
            "ftafm_messages_dropped_total{stream=\"spectrum\"}"
        ) > 0.0,
        "the slow client's messages were dropped and counted, in its own stream"
    );
    // The good client was not cut off: it goes on receiving, in order.
    let mut last = next_of(&mut good, "demods").await["seq"].as_u64().unwrap();
    for _ in 0..100 {
        let seq = next_of(&mut good, "demods").await["seq"].as_u64().unwrap();
        assert!(seq > last, "seq {seq} after {last}");
        last = seq;
    }
    assert!(received >= 50);
    drop(slow);
    d.shutdown().await;
}

async fn harmonic_amplitude(ws: &mut Ws, index: usize, frames: usize) -> f64 {
    let mut sum = 0.0;
    for _ in 0..frames {
        sum += next_of(ws, "demods").await["demods"][index]["r"]
            .as_f64()
            .unwrap();
    }
    sum / frames as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_softer_sample_lowers_the_high_harmonics() {
    // The paper's case at its 10 MS/s, noise off, demodulators at 200 Hz.
    let mut settings = default_settings();
    settings.noise.enable = false;
    for d in &mut settings.demods {
        d.rate = 200.0;
    }
    let d = Daemon::start(settings.clone()).await;
    let mut ws = connect(d.addr).await;
    call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let h17 = 16; // demodulator 16 is harmonic 17
    let before = harmonic_amplitude(&mut ws, h17, 20).await;
    let r = call(
        &mut ws,
        json!({"op": "set", "path": "/sample/youngs_modulus", "value": 116.1e9}),
    )
    .await;
    assert_eq!(r["ok"], true);
    tokio::time::sleep(Duration::from_millis(300)).await;
    // Skip what was queued before the change had settled.
    for _ in 0..100 {
        next_of(&mut ws, "demods").await;
    }
    let after = harmonic_amplitude(&mut ws, h17, 20).await;
    // physics: the 10 % softer inhomogeneity lowers H17 by ≈ 3 % (`ftafm paper`, on the
    // configured engine: the coupled one by default).
    let report = ftafm::cli::paper::compute_with(&settings, 0.9, settings.synth.engine).unwrap();
    let (expect_before, expect_after) = (
        report.materials[0].spectrum[17].amplitude,
        report.materials[1].spectrum[17].amplitude,
    );
    assert!(
        (before / expect_before - 1.0).abs() < 0.005,
        "H17 {before:e} vs paper {expect_before:e}"
    );
    assert!(
        (after / expect_after - 1.0).abs() < 0.005,
        "H17 {after:e} vs paper {expect_after:e}"
    );
    assert!(
        after < before * 0.98,
        "H17 falls by the paper's ≈ 3 %: {before:e} → {after:e}"
    );
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_seed_gives_the_same_values_at_the_same_time() {
    async fn frames(settings: Settings) -> std::collections::BTreeMap<u64, Value> {
        let d = Daemon::start(settings).await;
        let mut ws = connect(d.addr).await;
        call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
        let mut out = std::collections::BTreeMap::new();
        while out.len() < 100 {
            let v = next_of(&mut ws, "demods").await;
            // Key by simulated time in ns (exact: sample index / 2 MS/s).
            out.insert(
                (v["t"].as_f64().unwrap() * 1e9).round() as u64,
                v["demods"].clone(),
            );
        }
        d.shutdown().await;
        out
    }
    let settings = light(); // noise on: thermal, detector, ADC — all seeded
    let a = frames(settings.clone()).await;
    let b = frames(settings.clone()).await;
    let common: Vec<_> = a.keys().filter(|t| b.contains_key(t)).collect();
    assert!(common.len() > 20, "the runs overlap in simulated time");
    for t in common {
        assert_eq!(a[t], b[t], "t = {t} ns");
    }
    let mut other = settings;
    other.synth.seed = 2;
    let c = frames(other).await;
    let t = c.keys().find(|t| a.contains_key(t)).expect("overlap");
    assert_ne!(a[t], c[t], "another seed, other noise");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_endpoints_and_clean_shutdown() {
    let d = Daemon::start(light()).await;
    let (status, page) = http_get(d.addr, "/").await;
    assert_eq!(status, 200);
    assert!(page.contains("<title>ftafm"));
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let (status, body) = http_get(d.addr, "/healthz").await;
        if status == 200 {
            assert_eq!(body, "ok\n");
            break;
        }
        assert_eq!(status, 503);
        assert!(Instant::now() < deadline);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (_, metrics) = http_get(d.addr, "/metrics").await;
    for name in [
        "ftafm_samples_processed_total",
        "ftafm_overrun_samples_total",
        "ftafm_messages_sent_total{stream=\"demods\"}",
        "ftafm_messages_dropped_total{stream=\"demods\"}",
        "ftafm_clients",
        "ftafm_latency_seconds{path=\"synth_to_send\",quantile=\"0.99\"}",
    ] {
        assert!(metrics.contains(name), "{name} missing from /metrics");
    }
    let mut ws = connect(d.addr).await;
    call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    let took = d.shutdown().await;
    assert!(took < Duration::from_secs(2), "shutdown took {took:?}");
    // The client was told: a close frame with 1001.
    let mut code = None;
    while let Some(Ok(m)) = ws.next().await {
        if let Message::Close(Some(f)) = m {
            code = Some(u16::from(f.code));
            break;
        }
    }
    assert_eq!(code, Some(1001));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_flood_is_answered_and_limited_not_dropped() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    // 600 requests at once: the burst allowance (400) is answered, the rest is refused
    // with rate_limited — and every request gets exactly one reply.
    for i in 0..600 {
        ws.send(Message::Text(
            json!({"id": i, "op": "hello"}).to_string().into(),
        ))
        .await
        .unwrap();
    }
    let mut ids = Vec::new();
    let mut limited = 0;
    while ids.len() < 600 {
        let r = reply(&mut ws).await;
        if r["ok"] == false {
            assert_eq!(code(&r), "rate_limited", "{r}");
            limited += 1;
        }
        ids.push(r["id"].as_u64().unwrap());
    }
    assert_eq!(
        ids,
        (0..600).collect::<Vec<_>>(),
        "one reply per request, in order"
    );
    assert!((100..=250).contains(&limited), "{limited} refused");
    // The connection goes on once the client slows down.
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(call(&mut ws, json!({"op": "hello"})).await["ok"], true);
    d.shutdown().await;
}

/// `ftafm_force_estimates_total{outcome=…}` from `/metrics`.
async fn force_count(addr: std::net::SocketAddr, outcome: &str) -> u64 {
    let (_, metrics) = http_get(addr, "/metrics").await;
    metric(
        &metrics,
        &format!("ftafm_force_estimates_total{{outcome=\"{outcome}\"}}"),
    ) as u64
}

/// The next `n` seqs of force messages on `ws`.
async fn force_seqs(ws: &mut Ws, n: usize) -> Vec<u64> {
    let mut seqs = Vec::with_capacity(n);
    while seqs.len() < n {
        let m = next_within(ws, "force", Duration::from_secs(60)).await;
        seqs.push(m["seq"].as_u64().unwrap());
    }
    seqs
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn force_estimates_nobody_takes_are_not_fitted_and_no_taker_sees_a_gap() {
    let mut settings = default_settings();
    settings.noise.enable = false;
    let d = Daemon::start(settings).await;
    // A page's subscription: every 20th estimate. Only those are fitted.
    let mut page = connect(d.addr).await;
    let r = call(
        &mut page,
        json!({"op": "subscribe", "stream": "force", "every": 20}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let seqs = force_seqs(&mut page, 5).await;
    assert!(
        seqs.iter().all(|s| s % 20 == 0) && seqs.windows(2).all(|w| w[1] == w[0] + 20),
        "{seqs:?}"
    );
    let (ok, skipped) = (
        force_count(d.addr, "ok").await,
        force_count(d.addr, "skipped").await,
    );
    assert!(skipped >= 10 * ok, "fitted {ok}, skipped {skipped}");

    // A script taking every estimate: from its reply's next_seq on, all of them, no gap;
    // the page still gets its every 20th, 20 apart.
    let mut script = connect(d.addr).await;
    let r = call(&mut script, json!({"op": "subscribe", "stream": "force"})).await;
    assert_eq!(r["ok"], true, "{r}");
    let from = r["next_seq"].as_u64().unwrap();
    let seqs = force_seqs(&mut script, 100).await;
    assert!(seqs[0] >= from, "{from} → {seqs:?}");
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    let skipped_while_taken = force_count(d.addr, "skipped").await;
    let seqs = force_seqs(&mut page, 8).await;
    assert!(
        seqs.iter().all(|s| s % 20 == 0) && seqs.windows(2).all(|w| w[1] == w[0] + 20),
        "{seqs:?}"
    );

    // The script leaves: skipping resumes.
    let r = call(&mut script, json!({"op": "unsubscribe", "stream": "force"})).await;
    assert_eq!(r["ok"], true, "{r}");
    force_seqs(&mut page, 3).await;
    let skipped = force_count(d.addr, "skipped").await;
    assert!(
        skipped > skipped_while_taken,
        "{skipped_while_taken} → {skipped}"
    );
    assert_eq!(force_count(d.addr, "failed").await, 0);
    d.shutdown().await;
}

/// Mean of `n` force estimates' field, of estimates that reflect settings epoch `epoch` or
/// later and are not stale (made with the model of the settings in force: docs/protocol.md,
/// "Settings epochs").
async fn force_mean(ws: &mut Ws, n: usize, field: &str, epoch: u64) -> f64 {
    let mut sum = 0.0;
    let mut taken = 0;
    while taken < n {
        let f = next_of(ws, "force").await;
        if f["epoch"].as_u64().unwrap() >= epoch && f["stale"] != true {
            sum += f[field].as_f64().unwrap();
            taken += 1;
        }
    }
    sum / n as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_force_stream_recovers_contact_time_force_and_modulus() {
    // Noise off, the paper's case: the FT-AFM inversion of the live lock-in outputs must
    // give back the τ and F that `ftafm paper` computes and the modulus that was set, with
    // the demodulators at their default 1 kHz (where the full method once read +1.6 % at
    // 129 GPa and +3.5 % at 60 GPa: the harmonics folded from above Nyquist) and at 200 Hz.
    for rate in [1000.0, 200.0] {
        let mut settings = default_settings();
        settings.noise.enable = false;
        for d in &mut settings.demods {
            d.rate = rate;
        }
        for method in ["full", "two_harmonic"] {
            let d = Daemon::start(settings.clone()).await;
            let mut ws = connect(d.addr).await;
            assert_eq!(
                call(
                    &mut ws,
                    json!({"op": "set", "path": "/inversion/method", "value": method})
                )
                .await["ok"],
                true
            );
            for stream in ["force", "status"] {
                assert_eq!(
                    call(&mut ws, json!({"op": "subscribe", "stream": stream})).await["ok"],
                    true
                );
            }
            for modulus in [129e9, 60e9, 50e9, 200e9] {
                let r = call(
                    &mut ws,
                    json!({"op": "set", "path": "/sample/youngs_modulus", "value": modulus}),
                )
                .await;
                assert_eq!(r["ok"], true);
                let replied_ns = ftafm::pipeline::unix_ns();
                // Frames made before the change took effect may still be queued behind the
                // reply (replies go first), however far behind a busy machine runs. A
                // status made after the reply arrived counts the samples synthesised by
                // then; the change (queued before the reply) took effect at the next block
                // at the latest. Skip 250 ms of simulated time from there: the mode
                // transients and 4th-order filters settle in ≈ 30 ms. And wait for the
                // estimator of the method just set (rebuilt off the request path).
                let effective = loop {
                    let st = next_of(&mut ws, "status").await;
                    if st["t_synth_ns"].as_u64().unwrap() > replied_ns {
                        let synthesised = st["counters"]["samples_synthesized"].as_f64().unwrap();
                        break (synthesised + BLOCK_SAMPLES as f64) / settings.synth.sample_rate;
                    }
                };
                // The first estimate waits for the estimator's build at nice 10 (the coupled
                // engine's table: ~1 s of work, which a loaded machine stretches many times):
                // a hang guard, not a measure.
                // And an estimate of the model of these settings: the epoch of the change or
                // later, not stale (the estimator of the new modulus, whose table is dense
                // about it, is built off the request path).
                let epoch = r["epoch"].as_u64().unwrap();
                let first = loop {
                    let f = next_within(&mut ws, "force", Duration::from_secs(180)).await;
                    if f["t"].as_f64().unwrap() >= effective + 0.25
                        && f["method"] == method
                        && f["epoch"].as_u64().unwrap() >= epoch
                        && f["stale"] != true
                    {
                        break f;
                    }
                };
                assert_eq!(first["method"], method);
                assert_eq!(first["waveform"].as_array().unwrap().len(), 256);
                let tau = force_mean(&mut ws, 10, "contact_time_ratio", epoch).await;
                let force = force_mean(&mut ws, 10, "max_force", epoch).await;
                let e = force_mean(&mut ws, 10, "youngs_modulus", epoch).await;
                let mut s = settings.clone();
                s.sample.youngs_modulus = modulus;
                // The configured engine's own pulse (the coupled orbit by default).
                let paper = &ftafm::cli::paper::compute_with(&s, 1.0, s.synth.engine)
                    .unwrap()
                    .materials[0];
                let (dt, df, de) = (
                    tau / paper.contact_time_ratio - 1.0,
                    force / paper.max_force - 1.0,
                    e / modulus - 1.0,
                );
                // The goals (1 %, 1 %, 2 %), and what is achieved, so a regression shows.
                let at = format!("{method} at {modulus:e} Pa, {rate} Hz");
                assert!(
                    dt.abs() < 0.01,
                    "{at}: τ {tau} vs {}",
                    paper.contact_time_ratio
                );
                assert!(
                    df.abs() < 0.01,
                    "{at}: F {force:e} vs {:e}",
                    paper.max_force
                );
                assert!(de.abs() < 0.02, "{at}: E {e:e}");
                // The paper engine's pulse is the cut cosine the methods fit; the coupled
                // engine's is read through its table of coupled orbits (docs/ft-afm.md).
                let (tight_shape, tight_e) = match s.synth.engine {
                    Engine::Paper => (1e-4, 1e-3),
                    Engine::Coupled => (5e-4, 3e-3),
                };
                assert!(
                    dt.abs() < tight_shape && df.abs() < tight_shape && de.abs() < tight_e,
                    "{at}: τ {dt:+e}, F {df:+e}, E {de:+e}"
                );
            }
            let (_, metrics) = http_get(d.addr, "/metrics").await;
            assert!(
                metrics.contains("ftafm_force_estimates_total{outcome=\"failed\"} 0"),
                "{metrics}"
            );
            d.shutdown().await;
        }
    }
}

/// Collects the `image` lines of one whole frame (the first frame that starts at line 0).
async fn image_frame(ws: &mut Ws, pixels: usize) -> Vec<Value> {
    let mut lines: Vec<Value> = Vec::new();
    loop {
        let v = next_of(ws, "image").await;
        if v["line"] == 0 {
            lines.clear();
        }
        if lines.is_empty() && v["line"] != 0 {
            continue;
        }
        lines.push(v);
        if lines.len() == pixels {
            return lines;
        }
    }
}

fn channel(line: &Value, name: &str) -> Vec<f64> {
    line["channels"][name]
        .as_array()
        .unwrap_or_else(|| panic!("channel {name}"))
        .iter()
        .map(|x| x.as_f64().unwrap_or(f64::NAN))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_small_scan_images_the_softer_disc_in_the_high_harmonics() {
    let mut s = default_settings();
    s.noise.enable = false;
    s.scan.enable = true;
    s.scan.pixels = 16;
    s.scan.line_rate = 20.0;
    // Light on the shared cores (the other tests run alongside): only the harmonics the
    // test reads, the two-harmonic inversion, no spectrum or scope.
    for d in &mut s.demods {
        d.enable = [1, 6, 17, 18].contains(&d.harmonic);
    }
    s.inversion.method = ftafm::config::InversionMethod::TwoHarmonic;
    s.spectrum.enable = false;
    s.scope.enable = false;
    let daemon = Daemon::start(s).await;
    let mut ws = connect(daemon.addr).await;
    // No frame has finished yet: the export says so.
    let (status, body) = http_get(daemon.addr, "/image/h17.gsf").await;
    assert_eq!(status, 404, "{body}");
    assert!(body.contains("no scan frame"), "{body}");

    assert_eq!(
        call(&mut ws, json!({"op": "subscribe", "stream": "image"})).await["ok"],
        true
    );
    let lines = image_frame(&mut ws, 16).await;
    let first = &lines[0];
    assert_eq!(first["pixels"], 16);
    assert_eq!(first["direction"], "trace");
    assert_eq!(first["units"]["h17"], "m");
    assert_eq!(first["units"]["youngs_modulus"], "Pa");
    for name in [
        "height",
        "amplitude",
        "phase",
        "h6",
        "h17",
        "h18",
        "contact_time_ratio",
        "max_force",
        "youngs_modulus",
    ] {
        assert_eq!(channel(first, name).len(), 16, "{name}");
    }
    // The disc (radius 167 nm at the centre, pixels 62.5 nm): line 7 crosses its middle.
    let middle = &lines[7];
    let inside = |name: &str| {
        let c = channel(middle, name);
        (c[7] + c[8]) / 2.0
    };
    let outside = |name: &str| {
        let c = channel(middle, name);
        (c[0] + c[1] + c[14] + c[15]) / 4.0
    };
    let contrast = |name: &str| 1.0 - outside(name) / inside(name);
    let (c6, c17, c18) = (contrast("h6"), contrast("h17"), contrast("h18"));
    eprintln!(
        "scan contrast (1 - S_Si/S_Inh): h6 {:.3} %, h17 {:.2} %, h18 {:.2} %; E inside {:.1} GPa, outside {:.1} GPa",
        c6 * 100.0,
        c17 * 100.0,
        c18 * 100.0,
        inside("youngs_modulus") / 1e9,
        outside("youngs_modulus") / 1e9
    );
    // The paper: ≈ 3 % at 17/18 (silicon brighter), ≈ 0.3 % at 6; `ftafm paper`: −2.7, −3.2, −0.30 %.
    assert!((-0.035..-0.020).contains(&c17), "c17 {c17}");
    assert!((-0.040..-0.025).contains(&c18), "c18 {c18}");
    assert!((-0.005..-0.0015).contains(&c6), "c6 {c6}");
    // The modulus channel tells the materials apart.
    assert!((inside("youngs_modulus") / 116.1e9 - 1.0).abs() < 0.03);
    assert!((outside("youngs_modulus") / 129e9 - 1.0).abs() < 0.03);
    // Sharp edges: along the middle line, at most one pixel per edge lies between the two
    // materials' values (the pixel the edge crosses).
    let h17 = channel(middle, "h17");
    let (lo, hi) = (inside("h17"), outside("h17"));
    let between = h17
        .iter()
        .filter(|&&v| v > lo + 0.1 * (hi - lo) && v < hi - 0.1 * (hi - lo))
        .count();
    assert!(
        between <= 2,
        "pixels between the levels: {between} in {h17:?}"
    );

    // The finished frame exports (once the image worker has stored it: wait for that, not
    // for a time).
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let body = loop {
        let (status, body) = http_get(daemon.addr, "/image/h17.gsf").await;
        if status == 200 {
            break body;
        }
        assert!(std::time::Instant::now() < deadline, "{status}: {body}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(
        body.starts_with("Gwyddion Simple Field 1.0\nXRes = 16\nYRes = 16\n"),
        "{}",
        &body[..80.min(body.len())]
    );
    // With the instrument's settings, version and date in the header.
    for key in [
        "ftafm.version = ",
        "ftafm.date = 20",
        "ftafm:/sample/youngs_modulus = ",
    ] {
        assert!(body.contains(key), "no {key} in the .gsf header");
    }
    let (status, body) = http_get(daemon.addr, "/image/h17.json").await;
    assert_eq!(status, 200, "{body}");
    let companion: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(companion["unit"], "m");
    assert_eq!(companion["shape"], json!([16, 16]));
    assert_eq!(companion["settings"]["/scan/pixels"], 16);
    assert!(companion["date"].as_str().unwrap().ends_with('Z'));
    let (status, body) = http_get(daemon.addr, "/image/nothing.gsf").await;
    assert_eq!(status, 404);
    assert!(body.contains("h17"), "{body}");
    // A change that leaves the images as they are (the spectrum's rate): the lines that
    // follow reflect it, so they carry its epoch, not stale, within a frame; before, they
    // kept the epoch of the last change that concerned them, and a client waiting for its
    // own epoch waited for ever.
    let r = call(
        &mut ws,
        json!({"op": "set", "path": "/spectrum/rate", "value": 5.0}),
    )
    .await;
    let epoch = r["epoch"].as_u64().expect("the set's epoch");
    let mut seen = 0;
    loop {
        let v = next_of(&mut ws, "image").await;
        if v["epoch"].as_u64().unwrap() >= epoch {
            assert_eq!(v["stale"], false, "{v}");
            break;
        }
        seen += 1;
        assert!(
            seen <= 32,
            "{seen} lines after epoch {epoch} still carry {}",
            v["epoch"]
        );
    }
    daemon.shutdown().await;
}

/// A chain that cannot keep real time says so in `status`: what it lost, which thread was
/// the busier, and what lightens it. Here the DSP is made far slower than real time (a
/// 2^20-point spectrum 1000 times a second), so the ring overruns on any machine, and the
/// synthesiser light (the paper engine at 1 MS/s: a fifth of a core even in the portable
/// build, `FTAFM_ISA=portable`), so that the DSP is the busier thread on any machine.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_warns_when_the_chain_falls_behind_real_time_and_names_the_remedy() {
    let mut s = default_settings();
    s.synth.realtime = true;
    s.synth.sample_rate = 1e6;
    s.synth.engine = Engine::Paper;
    s.spectrum.size = 1 << 20;
    s.spectrum.rate = 1000.0;
    let d = Daemon::start(s).await;
    let mut ws = connect(d.addr).await;
    let r = call(
        &mut ws,
        json!({"id": 1, "op": "subscribe", "stream": "status"}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let behind = |w: &Value| {
        w.as_str()
            .is_some_and(|w| w.contains("fell behind real time"))
    };
    let status = first_of(&mut ws, "status", |m| {
        m["warnings"]
            .as_array()
            .is_some_and(|w| w.iter().any(behind))
    })
    .await;
    let warning = status["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .find(|w| behind(w))
        .and_then(Value::as_str)
        .unwrap()
        .to_owned();
    assert!(warning.contains("samples overrun"), "{warning}");
    assert!(
        warning.contains("to lighten the DSP") && warning.contains("/spectrum/rate"),
        "{warning}"
    );
    d.shutdown().await;
}
