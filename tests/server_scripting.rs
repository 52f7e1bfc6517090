//! What scripts and the Python package need from the daemon, over a real WebSocket: the
//! simulated time a change took effect, batch sets at one sample boundary, the latest
//! measured value of a demodulator by path, and the settings as a config file.

use serde_json::{Value, json};

mod common;
use common::*;

/// Demodulator frames until one reflects samples at or after `t` (s).
async fn demods_from(ws: &mut Ws, t: f64) -> Value {
    loop {
        let frame = next_of(ws, "demods").await;
        if frame["t"].as_f64().unwrap() >= t {
            return frame;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_set_says_when_it_took_effect_and_a_batch_is_all_or_nothing() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let one = call(
        &mut ws,
        json!({"id": 1, "op": "set", "path": "/surface/distance", "value": 1.8e-8}),
    )
    .await;
    assert_eq!(one["ok"], true, "{one}");
    let t1 = one["t"].as_f64().expect("t of the change");
    assert!(t1 > 0.0, "{one}");

    // Data from samples after t shows the change; data before it cannot.
    call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    let batch = call(
        &mut ws,
        json!({"id": 2, "op": "set", "values": {
            "/surface/distance": 1.5e-8, "/demods/1/harmonic": 5.0, "/demods/1/rate": 200}}),
    )
    .await;
    assert_eq!(batch["ok"], true, "{batch}");
    assert_eq!(
        batch["values"],
        json!({"/surface/distance": 1.5e-8, "/demods/1/harmonic": 5, "/demods/1/rate": 200.0})
    );
    let t2 = batch["t"].as_f64().unwrap();
    assert!(t2 > t1, "{t2} after {t1}");
    let after = demods_from(&mut ws, t2 + 0.05).await;
    let demod1 = after["demods"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["index"] == 1)
        .unwrap();
    assert_eq!(demod1["harmonic"], 5, "{after}");

    // A refused batch names its node and changes nothing, the good nodes in it included.
    for (values, code_wanted, names) in [
        (
            json!({"/surface/distance": 1e-8, "/demods/1/harmonic": -1}),
            "invalid_value",
            "/demods/1/harmonic",
        ),
        (
            json!({"/surface/distance": 1e-8, "/synth/sample_rate": 4e6}),
            "read_only",
            "/synth/sample_rate",
        ),
        (
            json!({"/surface/distance": 1e-8, "/surface/distanse": 1}),
            "unknown_path",
            "/surface/distanse",
        ),
    ] {
        let r = call(&mut ws, json!({"id": 9, "op": "set", "values": values})).await;
        assert_eq!((r["id"].clone(), code(&r)), (json!(9), code_wanted), "{r}");
        assert!(
            r["error"]["message"].as_str().unwrap().contains(names),
            "{r}"
        );
        let get = call(&mut ws, json!({"op": "get", "path": "/surface/distance"})).await;
        assert_eq!(get["value"], 1.5e-8, "a refused batch changed a node");
    }
    for bad in [
        json!({"op": "set", "values": {}}),
        json!({"op": "set", "values": [1, 2]}),
        json!({"op": "set", "values": {"surface/distance": 1e-8}}),
        json!({"op": "set", "path": "/surface/distance", "value": 1e-8,
               "values": {"/surface/distance": 1e-8}}),
    ] {
        let r = call(&mut ws, bad.clone()).await;
        assert_eq!(code(&r), "bad_request", "{bad} → {r}");
    }
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_latest_output_of_a_demodulator_is_read_by_path() {
    let mut settings = light();
    settings.demods[4].enable = false;
    let d = Daemon::start(settings).await;
    let mut ws = connect(d.addr).await;
    // The first output may not be there yet: no_data until it is.
    let sample = loop {
        let r = call(&mut ws, json!({"op": "get", "path": "/demods/0/sample"})).await;
        if r["ok"] == true {
            break r;
        }
        assert_eq!(code(&r), "no_data", "{r}");
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    };
    let v = &sample["value"];
    assert_eq!(v["harmonic"], 1);
    let (x, y, r) = (
        v["x"].as_f64().unwrap(),
        v["y"].as_f64().unwrap(),
        v["r"].as_f64().unwrap(),
    );
    assert!((x.hypot(y) - r).abs() <= 1e-12 * r, "{v}");
    assert!(r > 1e-9, "the tapping amplitude, {r} m");

    // It is the newest: after a change, the value comes from samples after it.
    let set = call(
        &mut ws,
        json!({"op": "set", "path": "/surface/distance", "value": 1.6e-8}),
    )
    .await;
    let t = set["t"].as_f64().unwrap();
    let later = loop {
        let r = call(&mut ws, json!({"op": "get", "path": "/demods/0/sample"})).await;
        if r["value"]["t"].as_f64().unwrap() > t {
            break r;
        }
    };
    assert!(later["value"]["t"].as_f64().unwrap() > v["t"].as_f64().unwrap());

    let disabled = call(
        &mut ws,
        json!({"id": 5, "op": "get", "path": "/demods/4/sample"}),
    )
    .await;
    assert_eq!(
        (disabled["id"].clone(), code(&disabled)),
        (json!(5), "no_data")
    );
    assert!(
        disabled["error"]["message"]
            .as_str()
            .unwrap()
            .contains("/demods/4/enable"),
        "{disabled}"
    );
    let beyond = call(&mut ws, json!({"op": "get", "path": "/demods/32/sample"})).await;
    assert_eq!(code(&beyond), "unknown_path", "{beyond}");

    // Many paths in one request: every node of `list` and every demodulator's sample, read
    // together; a disabled demodulator's sample is null with the reason, not a refusal.
    let list = call(&mut ws, json!({"op": "list"})).await;
    let nodes = list["nodes"].as_array().unwrap();
    let mut paths: Vec<String> = nodes
        .iter()
        .map(|n| n["path"].as_str().unwrap().to_owned())
        .collect();
    paths.extend((0..32).map(|n| format!("/demods/{n}/sample")));
    let all = call(&mut ws, json!({"id": 6, "op": "get", "paths": paths})).await;
    assert_eq!(
        (all["id"].clone(), all["ok"].clone()),
        (json!(6), json!(true))
    );
    let values = all["values"].as_object().unwrap();
    assert_eq!(values.len(), paths.len());
    for node in nodes {
        assert_eq!(
            values[node["path"].as_str().unwrap()],
            node["value"],
            "{node}"
        );
    }
    assert_eq!(
        all["epoch"], set["epoch"],
        "the settings of the last change"
    );
    assert!(values["/demods/0/sample"]["t"].as_f64().unwrap() > t);
    assert_eq!(values["/demods/4/sample"], Value::Null);
    let why = all["no_data"]["/demods/4/sample"].as_str().unwrap();
    assert!(why.contains("/demods/4/enable"), "{all}");
    assert_eq!(all["no_data"].as_object().unwrap().len(), 1, "{all}");
    // One path that names nothing refuses the request, naming it.
    let bad = call(
        &mut ws,
        json!({"op": "get", "paths": ["/drive/frequency", "/drive/frequncy"]}),
    )
    .await;
    assert_eq!(code(&bad), "unknown_path", "{bad}");
    assert!(
        bad["error"]["message"]
            .as_str()
            .unwrap()
            .contains("/drive/frequncy")
    );
    let beyond = call(
        &mut ws,
        json!({"op": "get", "paths": ["/demods/32/sample"]}),
    )
    .await;
    assert_eq!(code(&beyond), "unknown_path", "{beyond}");

    // `list` says whether each end of a range is itself allowed.
    let node = |path: &str| nodes.iter().find(|n| n["path"] == path).unwrap().clone();
    let modulus = node("/sample/youngs_modulus");
    assert_eq!(
        (modulus["min"].as_f64(), modulus["max"].as_f64()),
        (Some(0.0), Some(1e13))
    );
    assert_eq!(
        (&modulus["min_inclusive"], &modulus["max_inclusive"]),
        (&json!(false), &json!(true))
    );
    let drive = node("/drive/frequency");
    assert_eq!(
        drive["max"].as_f64(),
        Some(1e6),
        "Nyquist at 2 MHz sampling"
    );
    assert_eq!(drive["max_inclusive"], false, "{drive}");
    let harmonic = node("/demods/3/harmonic");
    assert_eq!(
        (&harmonic["min_inclusive"], &harmonic["max_inclusive"]),
        (&json!(true), &json!(true))
    );
    let enable = node("/demods/3/enable");
    assert!(enable.get("min_inclusive").is_none() && enable.get("max_inclusive").is_none());
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn settings_go_out_as_a_config_file_and_come_back() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let saved = call(&mut ws, json!({"id": 1, "op": "settings"})).await;
    let toml = saved["toml"].as_str().unwrap().to_owned();
    // It is the running settings, whole: what `--config` reads back to the same.
    let running = ftafm::config::load_str(&toml, "saved").unwrap();
    assert_eq!(running, light());

    call(
        &mut ws,
        json!({"op": "set", "values": {"/surface/distance": 1.2e-8, "/sample/youngs_modulus": 3e9}}),
    )
    .await;
    let loaded = call(
        &mut ws,
        json!({"id": 2, "op": "load_settings", "toml": toml}),
    )
    .await;
    assert_eq!(loaded["ok"], true, "{loaded}");
    assert!(loaded["t"].as_f64().unwrap() > 0.0);
    for (path, value) in [
        ("/surface/distance", 2e-8),
        ("/sample/youngs_modulus", 129e9),
    ] {
        let get = call(&mut ws, json!({"op": "get", "path": path})).await;
        assert_eq!(get["value"], value, "{path} restored");
    }

    // A partial file changes its nodes only; a bad one names the key and changes nothing.
    let partial = call(
        &mut ws,
        json!({"op": "load_settings", "toml": "[surface]\ndistance = 1.9e-8\n"}),
    )
    .await;
    assert_eq!(partial["ok"], true, "{partial}");
    for (text, code_wanted, names) in [
        (
            "[surface]\ndistance = -1.0\n",
            "invalid_value",
            "/surface/distance",
        ),
        ("[surface]\ndistanse = 1e-8\n", "invalid_value", "distanse"),
        (
            "[synth]\nsample_rate = 4e6\n",
            "read_only",
            "/synth/sample_rate",
        ),
        ("[surface\n", "invalid_value", "settings"),
    ] {
        let r = call(&mut ws, json!({"op": "load_settings", "toml": text})).await;
        assert_eq!(code(&r), code_wanted, "{text} → {r}");
        assert!(
            r["error"]["message"].as_str().unwrap().contains(names),
            "{r}"
        );
    }
    let get = call(&mut ws, json!({"op": "get", "path": "/surface/distance"})).await;
    assert_eq!(get["value"], 1.9e-8);
    let missing = call(&mut ws, json!({"op": "load_settings"})).await;
    assert_eq!(code(&missing), "bad_request");
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_can_take_every_nth_message_and_still_sees_its_losses_as_gaps() {
    // A page that draws at 50 Hz takes every 20th frame of the 1 kHz demodulator stream:
    // the seqs it gets are the multiples of 20, consecutive ones 20 apart, so a loss would
    // still show as a gap (of a multiple of 20).
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let reply = call(
        &mut ws,
        json!({"id": 1, "op": "subscribe", "stream": "demods", "every": 20}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    assert_eq!(reply["every"], 20, "{reply}");
    let mut last: Option<u64> = None;
    for _ in 0..10 {
        let seq = next_of(&mut ws, "demods").await["seq"].as_u64().unwrap();
        assert_eq!(seq % 20, 0, "seq {seq}");
        if let Some(last) = last {
            assert_eq!(seq - last, 20, "{last} → {seq}");
        }
        last = Some(seq);
    }
    // Subscribing again with the default takes every message from then on.
    call(
        &mut ws,
        json!({"id": 2, "op": "subscribe", "stream": "demods"}),
    )
    .await;
    let mut seqs = Vec::new();
    while seqs.len() < 30 {
        let seq = next_of(&mut ws, "demods").await["seq"].as_u64().unwrap();
        if seq > last.unwrap() {
            seqs.push(seq);
        }
    }
    // Frames already queued before the change may still be 20 apart; after them, all.
    assert!(
        seqs.windows(2).rev().take(20).all(|w| w[1] == w[0] + 1),
        "{seqs:?}"
    );
    // A bad value changes nothing and names the field and its range.
    let bad = call(
        &mut ws,
        json!({"id": 3, "op": "subscribe", "stream": "demods", "every": 0}),
    )
    .await;
    assert_eq!(bad["ok"], false, "{bad}");
    assert!(
        bad["error"]["message"]
            .as_str()
            .unwrap()
            .contains("\"every\" must be an integer 1 … 1000000"),
        "{bad}"
    );
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn batched_demods_carry_every_point_of_the_stream_byte_for_byte() {
    use ftafm::server::protocol::{BINARY_HEADER_BYTES, batched_points, decode_header};
    use std::collections::BTreeMap;

    let d = Daemon::start(light()).await;
    // One client takes the stream point by point, the other 7 points a message.
    let mut single = connect(d.addr).await;
    let mut batched = connect(d.addr).await;
    let r = call(
        &mut single,
        json!({"id": 1, "op": "subscribe", "stream": "demods", "format": "binary"}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(r["batch"], 1, "{r}");
    let r = call(
        &mut batched,
        json!({"id": 1, "op": "subscribe", "stream": "demods", "format": "binary", "batch": 7}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(r["batch"], 7, "{r}");

    let mut points: BTreeMap<u64, (f64, u64, Vec<u8>)> = BTreeMap::new();
    let mut counts = Vec::new();
    while points.len() < 60 {
        let bytes = next_binary(&mut batched).await;
        let header = decode_header(&bytes).expect("a header");
        assert_eq!(header.batched_records, Some(32), "32 demodulators a point");
        let p = batched_points(&bytes).expect("the announced length");
        assert_eq!(p.len(), header.count as usize);
        assert!((1..=7).contains(&p.len()), "{} points", p.len());
        // The header speaks for the newest point.
        let newest = p.last().unwrap();
        assert_eq!(
            (header.seq, header.t, header.t_synth_ns),
            (newest.seq, newest.t, newest.t_synth_ns)
        );
        counts.push(p.len());
        for q in p {
            points.insert(q.seq, (q.t, q.t_synth_ns, q.records.to_vec()));
        }
    }
    // No point is missing between the first and the last.
    let (first, last) = (
        *points.keys().next().unwrap(),
        *points.keys().last().unwrap(),
    );
    assert_eq!(last - first + 1, points.len() as u64, "consecutive seqs");
    assert!(
        counts.iter().filter(|&&n| n == 7).count() >= 5,
        "{counts:?}"
    );
    // Each point is what the unbatched message of the same seq holds, byte for byte.
    let mut compared = 0;
    while compared < 20 {
        let bytes = next_binary(&mut single).await;
        let header = decode_header(&bytes).unwrap();
        assert_eq!(header.batched_records, None);
        if let Some((t, t_synth_ns, records)) = points.get(&header.seq) {
            assert_eq!((header.t, header.t_synth_ns), (*t, *t_synth_ns));
            assert_eq!(
                &bytes[BINARY_HEADER_BYTES..],
                &records[..],
                "seq {}",
                header.seq
            );
            compared += 1;
        } else {
            assert!(
                header.seq < first,
                "seq {} not in {first}…{last}",
                header.seq
            );
        }
    }

    // Back to one point a message: what was gathered comes first, and no point is lost.
    let mut next = last + 1;
    let r = call(
        &mut batched,
        json!({"id": 2, "op": "subscribe", "stream": "demods", "format": "binary"}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let mut unbatched = 0;
    while unbatched < 10 {
        let bytes = next_binary(&mut batched).await;
        let header = decode_header(&bytes).unwrap();
        let seqs: Vec<u64> = match batched_points(&bytes) {
            Some(p) => {
                assert_eq!(unbatched, 0, "no batch after an unbatched message");
                p.iter().map(|q| q.seq).collect()
            }
            None => {
                unbatched += 1;
                vec![header.seq]
            }
        };
        for seq in seqs {
            assert_eq!(seq, next, "no gap across the change");
            next += 1;
        }
    }

    // A batch that does not fill goes out 0.1 s after its first point: at 200 points a
    // second, 1000 would take 5 s.
    call(
        &mut batched,
        json!({"id": 3, "op": "subscribe", "stream": "demods", "format": "binary", "batch": 1000}),
    )
    .await;
    let mut sizes = Vec::new();
    while sizes.len() < 5 {
        if let Some(p) = batched_points(&next_binary(&mut batched).await) {
            sizes.push(p.len());
        }
    }
    assert!(sizes.iter().all(|&n| n < 1000), "{sizes:?}");

    // Bad values change nothing and name the field and what it allows.
    for (request, expect) in [
        (
            json!({"id": 4, "op": "subscribe", "stream": "demods", "format": "binary", "batch": 0}),
            "\"batch\" must be an integer 1 … 1000",
        ),
        (
            json!({"id": 5, "op": "subscribe", "stream": "demods", "format": "binary", "batch": 1001}),
            "\"batch\" must be an integer 1 … 1000",
        ),
        (
            json!({"id": 6, "op": "subscribe", "stream": "demods", "batch": 5}),
            "\"batch\" above 1 is for the stream \"demods\" in \"format\": \"binary\" only",
        ),
        (
            json!({"id": 7, "op": "subscribe", "stream": "spectrum", "format": "binary", "batch": 5}),
            "(got stream \"spectrum\", format \"binary\")",
        ),
    ] {
        let bad = call(&mut batched, request).await;
        assert_eq!(bad["ok"], false, "{bad}");
        assert_eq!(bad["error"]["code"], "bad_request", "{bad}");
        let message = bad["error"]["message"].as_str().unwrap();
        assert!(message.contains(expect), "{message}");
    }
    // Still 1000 a message, not JSON, after the refused requests.
    let mut seen = 0;
    while seen < 2 {
        let bytes = next_binary(&mut batched).await;
        assert!(batched_points(&bytes).is_some(), "still batched");
        seen += 1;
    }
    d.shutdown().await;
}

/// The largest seed `set` takes comes back from `settings` through `load_settings` (and
/// `--config`): TOML's integers end at 2⁶³ − 1, so the file carries it as its digits.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_largest_seed_survives_settings_and_load_settings() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let set = call(
        &mut ws,
        json!({"op": "set", "path": "/synth/seed", "value": u64::MAX}),
    )
    .await;
    assert_eq!(set["value"], u64::MAX, "{set}");
    let saved = call(&mut ws, json!({"op": "settings"})).await;
    let toml = saved["toml"].as_str().expect("the settings").to_owned();
    assert_eq!(
        ftafm::config::load_str(&toml, "saved").unwrap().synth.seed,
        u64::MAX,
        "--config reads it"
    );
    call(
        &mut ws,
        json!({"op": "set", "path": "/synth/seed", "value": 7}),
    )
    .await;
    let loaded = call(&mut ws, json!({"op": "load_settings", "toml": toml})).await;
    assert_eq!(loaded["ok"], true, "{loaded}");
    let get = call(&mut ws, json!({"op": "get", "path": "/synth/seed"})).await;
    assert_eq!(get["value"], u64::MAX, "{get}");
    d.shutdown().await;
}
