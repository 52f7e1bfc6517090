//! A lever whose harmonics reach past the Nyquist frequency, live: the demodulators out of
//! band are kept but produce no frames, `get` and `status` say so, the inversion runs on
//! in-band harmonics, and a change of `/cantilever/f1` moves the drive and the band with it.

use std::collections::BTreeSet;

use ftafm::config::default_settings;
use serde_json::{Value, json};

mod common;
use common::*;

fn harmonics(demods: &Value) -> BTreeSet<u64> {
    demods["demods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["harmonic"].as_u64().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn demodulators_out_of_band_are_named_and_silent_and_follow_the_drive() {
    // At 2 MS/s and a 100 kHz drive, harmonics 1 … 9 lie below the 1 MHz Nyquist frequency
    // and the bank's 10 … 32 above it; the inversion asks for 6 and 17.
    let mut s = default_settings();
    s.synth.sample_rate = 2e6;
    s.spectrum.size = 4096;
    for d in &mut s.demods {
        d.rate = 200.0;
    }
    s.validate()
        .expect("out-of-band demodulators are not an error");
    assert_eq!(s.inversion_harmonics(), Some((6, 9)));
    let d = Daemon::start(s).await;
    let mut ws = connect(d.addr).await;

    let got = call(
        &mut ws,
        json!({"id": 1, "op": "get", "path": "/demods/16/harmonic"}),
    )
    .await;
    assert_eq!(got["value"], 17);
    let warning = got["warning"]
        .as_str()
        .expect("a warning on an out-of-band demodulator");
    assert!(
        warning.contains("out of band") && warning.contains("1 MHz"),
        "{warning}"
    );
    let got = call(
        &mut ws,
        json!({"id": 2, "op": "get", "path": "/demods/8/harmonic"}),
    )
    .await;
    assert!(got.get("warning").is_none(), "{got}");
    let got = call(
        &mut ws,
        json!({"id": 3, "op": "get", "path": "/inversion/harmonic_b"}),
    )
    .await;
    assert!(
        got["warning"].as_str().unwrap().contains("uses harmonic 9"),
        "{got}"
    );

    for (id, stream) in [(4, "demods"), (5, "status"), (6, "force")] {
        let r = call(
            &mut ws,
            json!({"id": id, "op": "subscribe", "stream": stream}),
        )
        .await;
        assert_eq!(r["ok"], true, "{r}");
    }
    let frame = first_of(&mut ws, "demods", |_| true).await;
    assert_eq!(harmonics(&frame), (1..=9).collect());
    let status = first_of(&mut ws, "status", |_| true).await;
    let warnings: Vec<&str> = status["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap())
        .collect();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("out of band") && w.contains("9 (H10)") && w.contains("31 (H32)")),
        "{warnings:?}"
    );
    // The inversion runs on the in-band pair.
    let force = first_of(&mut ws, "force", |_| true).await;
    let f = force["max_force"].as_f64().unwrap();
    assert!(f.is_finite() && f > 0.0, "{force}");

    // f1 halved: the drive follows it, and harmonics up to 19 come into band.
    let r = call(
        &mut ws,
        json!({"id": 7, "op": "set", "path": "/cantilever/f1", "value": 50e3}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let drive = call(
        &mut ws,
        json!({"id": 8, "op": "get", "path": "/drive/frequency"}),
    )
    .await;
    assert_eq!(drive["value"], 50e3);
    let frame = first_of(&mut ws, "demods", |m| harmonics(m).contains(&19)).await;
    assert_eq!(harmonics(&frame), (1..=19).collect());
    d.shutdown().await;
}

/// A preset loads at runtime as one change: the lever's nodes together, the drive following
/// its f1, the inclusions following a new sample; an unknown name changes nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn presets_load_while_running() {
    let mut s = default_settings();
    s.synth.sample_rate = 2e6;
    s.spectrum.size = 4096;
    for d in &mut s.demods {
        d.rate = 200.0;
    }
    let d = Daemon::start(s).await;
    let mut ws = connect(d.addr).await;
    let list = call(&mut ws, json!({"id": 1, "op": "presets"})).await;
    let names: Vec<&str> = list["presets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"tap300") && names.contains(&"polystyrene"),
        "{list}"
    );
    let r = call(&mut ws, json!({"id": 2, "op": "preset", "name": "tap150"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(r["kind"], "cantilever");
    let get = |path: &'static str| json!({"id": 3, "op": "get", "path": path});
    assert_eq!(call(&mut ws, get("/cantilever/f1")).await["value"], 150e3);
    assert_eq!(call(&mut ws, get("/drive/frequency")).await["value"], 150e3);
    assert_eq!(call(&mut ws, get("/cantilever/k")).await["value"], 5.0);
    let r = call(
        &mut ws,
        json!({"id": 4, "op": "preset", "name": "polystyrene"}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(
        call(&mut ws, get("/sample/youngs_modulus")).await["value"],
        3.2e9
    );
    assert_eq!(
        call(&mut ws, get("/inclusions/0/youngs_modulus")).await["value"],
        0.9 * 3.2e9
    );
    let r = call(&mut ws, json!({"id": 5, "op": "preset", "name": "tap3000"})).await;
    assert_eq!(code(&r), "invalid_value", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("tap300, tap150"),
        "{r}"
    );
    assert_eq!(call(&mut ws, get("/cantilever/f1")).await["value"], 150e3);
    // A soft elastomer: the operating point leaves the Hertz model's range, and status says so.
    let r = call(&mut ws, json!({"id": 6, "op": "preset", "name": "pdms"})).await;
    assert_eq!(r["ok"], true, "{r}");
    call(
        &mut ws,
        json!({"id": 7, "op": "subscribe", "stream": "status"}),
    )
    .await;
    let status = first_of(&mut ws, "status", |m| {
        m["warnings"].as_array().is_some_and(|w| {
            w.iter()
                .any(|w| w.as_str().unwrap().contains("small-strain"))
        })
    })
    .await;
    assert!(status["warnings"].is_array());
    d.shutdown().await;
}
