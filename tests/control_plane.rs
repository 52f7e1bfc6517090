//! The control plane over real WebSockets: a heavy change blocks no reader, every change
//! answers its epoch, no estimate of the old settings is presented as current, a sweep
//! aborted and restarted at once runs the new request, and random batches of nodes (range
//! ends included) each get their reply while `/healthz` stays alive.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

mod common;
use common::*;

/// A reply, an answer to `/healthz`: bounds that only a wedged daemon misses (a change's
/// model check takes at most the orbit solver's transient budget, about a second).
const ANSWER: Duration = Duration::from_secs(60);

/// Sends `request` without waiting for its reply.
async fn send(ws: &mut Ws, request: Value) {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .unwrap();
}

/// The reply with `id`, data messages skipped.
async fn reply_to(ws: &mut Ws, id: u64) -> Value {
    loop {
        let m = tokio::time::timeout(ANSWER, ws.next())
            .await
            .expect("a reply within the bound")
            .unwrap()
            .unwrap();
        if let Message::Text(t) = m {
            let v: Value = serde_json::from_str(t.as_str()).unwrap();
            if v["id"] == id {
                return v;
            }
        }
    }
}

/// A change whose model check is the heaviest there is (Q = 1e7 spends the solver's whole
/// transient budget) is in flight on one connection while another reads: the reader's
/// `get` and `/healthz` are answered before the change's reply, and the `get` answers the
/// settings before it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_heavy_change_blocks_no_reader() {
    let d = Daemon::start(light()).await;
    let mut writer = connect(d.addr).await;
    let mut reader = connect(d.addr).await;
    send(
        &mut writer,
        json!({"id": 1, "op": "set", "values": {"/cantilever/q": [1e7], "/drive/free_amplitude": 1e-6}}),
    )
    .await;
    let got = call(&mut reader, json!({"op": "get", "path": "/cantilever/q"})).await;
    let (status, body) = tokio::time::timeout(ANSWER, http_get(d.addr, "/healthz"))
        .await
        .expect("/healthz answers");
    // The reader is done before the writer's reply is read: had the change held a lock the
    // reader needs, its replies would have waited for the whole model check.
    let changed = reply_to(&mut writer, 1).await;
    assert_eq!(got["value"][0], 100.0, "{got}");
    assert_eq!(got["epoch"], 0, "{got}");
    assert_eq!(status, 200, "{body}");
    assert_eq!(changed["ok"], true, "{changed}");
    assert_eq!(changed["epoch"], 1, "{changed}");
    // Now the reader sees the change, with its epoch.
    let got = call(&mut reader, json!({"op": "get", "path": "/cantilever/q"})).await;
    assert_eq!(
        (got["value"].clone(), got["epoch"].clone()),
        (json!([1e7]), json!(1))
    );
    d.shutdown().await;
}

/// After `/surface/distance` 20 → 18 nm at 60 GPa, every force estimate of the old model is
/// sent `"stale": true` with its old epoch, and the current ones (the change's epoch or
/// later, not stale) come from frames after the change took effect and read the modulus
/// that is set (the old model read +36 % for seconds).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_estimate_of_the_old_model_is_presented_as_current() {
    let mut settings = ftafm::config::default_settings();
    settings.noise.enable = false;
    settings.sample.youngs_modulus = 60e9;
    let d = Daemon::start(settings).await;
    let mut ws = connect(d.addr).await;
    assert_eq!(
        call(&mut ws, json!({"op": "subscribe", "stream": "force"})).await["ok"],
        true
    );
    // The first estimator is built (a hang guard, not a measure).
    let first = next_within(&mut ws, "force", Duration::from_secs(180)).await;
    assert_eq!(
        (first["epoch"].as_u64(), first["stale"].as_bool()),
        (Some(0), Some(false))
    );
    let mut early = Vec::new();
    let r = call_keeping(
        &mut ws,
        json!({"op": "set", "path": "/surface/distance", "value": 18e-9}),
        "force",
        &mut early,
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let (epoch, t_set) = (r["epoch"].as_u64().unwrap(), r["t"].as_f64().unwrap());
    let mut current = Vec::new();
    let mut stale = 0;
    let mut early = early.into_iter();
    while current.len() < 5 {
        let f = match early.next() {
            Some(f) => f,
            None => next_within(&mut ws, "force", Duration::from_secs(180)).await,
        };
        let (e, is_stale) = (f["epoch"].as_u64().unwrap(), f["stale"].as_bool().unwrap());
        let t = f["t"].as_f64().unwrap();
        if is_stale {
            assert!(
                e < epoch,
                "a stale estimate names its old epoch: {e} vs {epoch}"
            );
            stale += 1;
        } else if e >= epoch {
            assert!(
                t > t_set,
                "a current estimate at t = {t} before the change at {t_set}"
            );
            current.push(f);
        } else {
            // Made before the change was committed, sent before its reply: at most the
            // few estimates in flight then, all from frames before the change.
            assert!(
                t <= t_set + 0.1,
                "an old estimate at {t}, the change at {t_set}"
            );
        }
    }
    for f in &current {
        let e = f["youngs_modulus"].as_f64().unwrap();
        assert!((e / 60e9 - 1.0).abs() < 0.02, "E = {e:e} after the change");
    }
    println!(
        "{stale} stale estimates; the first current one {:.3} s of simulated time after the change",
        current[0]["t"].as_f64().unwrap() - t_set
    );
    d.shutdown().await;
}

/// An abort and a new sweep sent back to back, without waiting for the first reply: the old
/// sweep ends aborted, the new request's sweep runs to its end (its messages carry the
/// request: the epoch of the `set` that asked for it) and the sweep is off afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_abort_then_a_new_sweep_runs_the_new_sweep() {
    let mut s = light();
    s.synth.realtime = false;
    for d in &mut s.demods {
        d.rate = 1000.0;
    }
    let d = Daemon::start(s).await;
    let mut ws = connect(d.addr).await;
    assert_eq!(
        call(&mut ws, json!({"op": "subscribe", "stream": "sweep"})).await["ok"],
        true
    );
    let tune = |points: u32| {
        json!({"/surface/distance": 200e-9, "/sweeper/parameter": "/drive/frequency",
               "/sweeper/start": 99e3, "/sweeper/stop": 101e3, "/sweeper/points": points,
               "/sweeper/enable": true})
    };
    for round in 0..4 {
        send(&mut ws, json!({"id": 10, "op": "set", "values": tune(400)})).await;
        let first = reply_to(&mut ws, 10).await;
        assert_eq!(first["ok"], true, "{first}");
        // Back to back: the abort and the new request.
        send(
            &mut ws,
            json!({"id": 11, "op": "set", "path": "/sweeper/enable", "value": false}),
        )
        .await;
        send(&mut ws, json!({"id": 12, "op": "set", "values": tune(5)})).await;
        let mut replies = Vec::new();
        let mut done = Vec::new();
        while replies.len() < 2 || !done.iter().any(|m: &Value| m["request"] == replies[1]) {
            let m = tokio::time::timeout(ANSWER, ws.next())
                .await
                .expect("a message within the bound")
                .unwrap()
                .unwrap();
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(t.as_str()).unwrap();
            if v["id"] == 11 || v["id"] == 12 {
                assert_eq!(v["ok"], true, "{v}");
                replies.push(v["epoch"].clone());
            } else if v["stream"] == "sweep" && v["done"] == true {
                done.push(v);
            }
        }
        let new = done.iter().find(|m| m["request"] == replies[1]).unwrap();
        assert_eq!(new["outcome"], "done", "round {round}: {new}");
        assert_eq!(new["measured"], 5, "round {round}: {new}");
        let old = done.iter().find(|m| m["request"] == first["epoch"]);
        if let Some(old) = old {
            assert_eq!(old["outcome"], "aborted", "round {round}: {old}");
        }
        let enabled = call(&mut ws, json!({"op": "get", "path": "/sweeper/enable"})).await;
        assert_eq!(enabled["value"], false, "round {round}");
    }
    d.shutdown().await;
}

/// Random batches of two to five writable numeric nodes, at the ends of their ranges as
/// `list` gives them or inside: every `set` gets its reply (applied or refused), and
/// `/healthz` answers after each. A sweep of one node at a time missed the combination
/// that once wedged the daemon.
#[test]
fn random_batches_each_get_their_reply_and_the_daemon_stays_alive() {
    use proptest::prelude::*;
    use proptest::test_runner::{Config, TestRunner};
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (d, ws, nodes) = rt.block_on(async {
        let d = Daemon::start(light()).await;
        let mut ws = connect(d.addr).await;
        let list = call(&mut ws, json!({"op": "list"})).await;
        let nodes: Vec<(String, f64, f64, bool)> = list["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|n| n["writable"] == true)
            .filter(|n| {
                n["path"]
                    .as_str()
                    .is_some_and(|p| !p.starts_with("/server"))
            })
            .filter_map(|n| {
                let (lo, hi) = (n["min"].as_f64()?, n["max"].as_f64()?);
                let path = n["path"].as_str()?.to_owned();
                Some((path, lo, hi, n["value"].is_array()))
            })
            .collect();
        (d, ws, nodes)
    });
    assert!(nodes.len() > 50, "{} numeric nodes", nodes.len());
    let n = nodes.len();
    // (node, where in its range: 0 = min, 1 = max, else inside).
    let batch = proptest::collection::vec((0..n, 0u8..4, 0.0f64..1.0), 2..=5);
    let mut runner = TestRunner::new(Config {
        cases: 24,
        failure_persistence: None,
        ..Config::default()
    });
    let (ws, id) = (std::cell::RefCell::new(ws), std::cell::Cell::new(100u64));
    runner
        .run(&batch, |batch| {
            let mut values = serde_json::Map::new();
            for (i, at, x) in batch {
                let (path, lo, hi, array) = &nodes[i];
                let v = match at {
                    0 => *lo,
                    1 => *hi,
                    _ => lo + (hi - lo) * x,
                };
                let v = if lo.fract() == 0.0 && hi.fract() == 0.0 {
                    v.round()
                } else {
                    v
                };
                values.insert(path.clone(), if *array { json!([v]) } else { json!(v) });
            }
            id.set(id.get() + 1);
            let id = id.get();
            let mut ws = ws.borrow_mut();
            let (reply, health) = rt.block_on(async {
                send(&mut ws, json!({"id": id, "op": "set", "values": values})).await;
                let reply = reply_to(&mut ws, id).await;
                let health = tokio::time::timeout(ANSWER, http_get(d.addr, "/healthz")).await;
                (reply, health)
            });
            prop_assert!(reply["ok"].is_boolean(), "{}", reply);
            prop_assert!(health.is_ok(), "/healthz did not answer");
            Ok(())
        })
        .unwrap();
    rt.block_on(d.shutdown());
}

/// One demodulator at its top rate (the sample rate: 10 M frames a second) beside the
/// scope, the spectrum and a `get`: over the same simulated time the scope and the spectrum
/// keep at least half their rate (what the client misses shows as seq gaps, counted), a
/// `get` is answered, and the daemon shuts down with a client that stopped reading.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_demodulator_at_its_top_rate_starves_no_other_stream() {
    let mut s = ftafm::config::default_settings();
    s.demods[0].rate = s.synth.sample_rate;
    let (scope_rate, spectrum_rate) = (s.scope.rate, s.spectrum.rate);
    let d = Daemon::start(s).await;
    let mut ws = connect(d.addr).await;
    for stream in ["demods", "scope", "spectrum"] {
        let r = call(&mut ws, json!({"op": "subscribe", "stream": stream})).await;
        assert_eq!(r["ok"], true, "{r}");
    }
    // A second client subscribed to everything that never reads again.
    let mut idle = connect(d.addr).await;
    for stream in ["demods", "scope", "spectrum", "status"] {
        send(&mut idle, json!({"op": "subscribe", "stream": stream})).await;
    }
    let (mut scopes, mut spectra) = (Vec::new(), Vec::new());
    let mut demods = 0u64;
    let mut t0 = None;
    let mut t_last = 0.0;
    // Two seconds of simulated time, by the messages' own clock.
    while t0.is_none_or(|t0| t_last < t0 + 2.0) {
        let m = tokio::time::timeout(ANSWER, ws.next())
            .await
            .expect("data within the bound")
            .unwrap()
            .unwrap();
        let Message::Text(t) = m else { continue };
        let v: Value = serde_json::from_str(t.as_str()).unwrap();
        let Some(t) = v["t"].as_f64() else { continue };
        t0.get_or_insert(t);
        t_last = t_last.max(t);
        match v["stream"].as_str() {
            Some("scope") => scopes.push(t),
            Some("spectrum") => spectra.push(t),
            Some("demods") => demods += 1,
            _ => {}
        }
    }
    let span = t_last - t0.unwrap();
    println!(
        "over {span:.2} s simulated: {} scopes, {} spectra, {demods} demods frames",
        scopes.len(),
        spectra.len()
    );
    assert!(
        scopes.len() as f64 >= 0.5 * scope_rate * span,
        "{} scopes",
        scopes.len()
    );
    assert!(
        spectra.len() as f64 >= 0.5 * spectrum_rate * span,
        "{} spectra",
        spectra.len()
    );
    send(
        &mut ws,
        json!({"id": 77, "op": "get", "path": "/demods/0/rate"}),
    )
    .await;
    let got = reply_to(&mut ws, 77).await;
    assert_eq!(got["ok"], true, "{got}");
    let took = tokio::time::timeout(ANSWER, d.shutdown())
        .await
        .expect("shutdown with a client that stopped reading");
    println!("shutdown took {took:?}");
    drop(idle);
}
