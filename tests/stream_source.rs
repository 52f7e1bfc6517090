//! A streamed source over a real WebSocket (`/source/kind = "stream"`): a client's binary
//! frames of samples go through the same lock-in bank as the synthesiser's, on a reference
//! tied to the writer's sample count; gaps, drops and bad frames are counted or refused
//! with their reason, and nothing else changes.

use std::time::Duration;

use futures_util::SinkExt;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use ftafm::pipeline::{FrameHeader, SampleType};
use ftafm::timebase::{PhaseAccumulator, TWO_POW_64};

mod common;
use common::*;

/// The chain's rate in these tests (S/s) and the frames' length (samples).
const RATE: f64 = 2e6;
const FRAME: usize = 20_000;
/// Two tones: (harmonic, peak amplitude in m, phase in rad).
const TONES: [(u32, f64, f64); 2] = [(1, 12e-9, 0.7), (3, 0.8e-9, -2.1)];

/// Samples `first … first + n` of the two tones, in nm (the frames' scale is 1e-9 m), on
/// the drive phase the daemon's reference takes at the writer's index: the drive's phase
/// word times the index.
fn tones(step: u64, first: u64, n: usize) -> Vec<f64> {
    (0..n as u64)
        .map(|i| {
            let word = step.wrapping_mul(first + i);
            let theta = word as f64 / TWO_POW_64 * std::f64::consts::TAU;
            TONES
                .iter()
                .map(|&(k, a, phi)| a / 1e-9 * (f64::from(k) * theta + phi).cos())
                .sum()
        })
        .collect()
}

fn frame(id: u64, first: u64, samples: &[f64], rate: f64) -> Vec<u8> {
    let data: Vec<u8> = samples.iter().flat_map(|x| x.to_le_bytes()).collect();
    FrameHeader {
        id,
        sample_type: SampleType::F64,
        sample_rate: rate,
        scale: 1e-9,
        first_index: first,
    }
    .frame(&data)
}

/// Sends a binary frame and waits for its reply (the message with "ok" and this id),
/// keeping the demodulator frames that come before it.
async fn push(ws: &mut Ws, bytes: Vec<u8>, id: u64, frames: &mut Vec<Value>) -> Value {
    ws.send(Message::Binary(bytes.into())).await.unwrap();
    loop {
        let v = next_json(ws).await;
        if v.get("ok").is_some() {
            assert_eq!(v["id"], id, "{v}");
            return v;
        }
        if v["stream"] == "demods" {
            frames.push(v);
        }
    }
}

async fn next_json(ws: &mut Ws) -> Value {
    use futures_util::StreamExt;
    loop {
        let m = tokio::time::timeout(Duration::from_secs(20), ws.next())
            .await
            .expect("a message within 20 s")
            .unwrap()
            .unwrap();
        if let Message::Text(t) = m {
            return serde_json::from_str(&t).unwrap();
        }
    }
}

/// The value of demodulator `harmonic` in a frame.
fn demod(frame: &Value, harmonic: u32) -> (f64, f64) {
    let d = frame["demods"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["harmonic"] == harmonic)
        .unwrap_or_else(|| panic!("harmonic {harmonic} in {frame}"));
    (d["r"].as_f64().unwrap(), d["phase"].as_f64().unwrap())
}

fn stream_settings() -> ftafm::config::Settings {
    let mut s = light();
    assert_eq!(s.synth.sample_rate, RATE);
    s.source.kind = ftafm::config::SourceKind::Stream;
    // The chain runs at the stream's pace: nothing here is paced by the wall clock.
    s.synth.realtime = false;
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streamed_tones_are_measured_on_the_writers_reference_across_a_gap() {
    let d = Daemon::start(stream_settings()).await;
    let mut ws = connect(d.addr).await;
    let f = call(&mut ws, json!({"op": "get", "path": "/drive/frequency"})).await["value"]
        .as_f64()
        .unwrap();
    let step = PhaseAccumulator::new(f, RATE).unwrap().frequency_word();
    call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;

    // 0.2 s of the tones from the writer's sample 1003 (not a whole number of drive periods),
    // then a gap of 12 345 samples, then
    // 0.2 s more: the reference follows the writer's count across the gap.
    let mut frames = Vec::new();
    let mut first = 1003;
    let mut id = 1;
    for part in 0..2 {
        let before = frames.len();
        for _ in 0..20 {
            let samples = tones(step, first, FRAME);
            let r = push(&mut ws, frame(id, first, &samples, RATE), id, &mut frames).await;
            assert_eq!(r["ok"], true, "{r}");
            let gap = if part == 1 && first == 1003 + 20 * FRAME as u64 + 12_345 {
                12_345
            } else {
                0
            };
            assert_eq!(r["gap"], gap, "{r}");
            assert_eq!(r["accepted"], FRAME as u64, "{r}");
            assert_eq!(r["dropped"], 0, "{r}");
            first += FRAME as u64;
            id += 1;
        }
        // Frames of this part, past the filters' settling (order 4, τ 0.5 ms: 20 ms).
        while frames.len() < before + 30 {
            let v = next_json(&mut ws).await;
            if v["stream"] == "demods" {
                frames.push(v);
            }
        }
        let settled = &frames[before + 10..before + 30];
        for (k, a, phi) in TONES {
            for fr in settled {
                let (r, phase) = demod(fr, k);
                assert!((r / a - 1.0).abs() < 1e-3, "H{k}: r {r} against {a}: {fr}");
                let dphi = (phase - phi + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                assert!(dphi.abs() < 1e-3, "H{k}: phase {phase} against {phi}");
            }
        }
        first += 12_345;
    }

    // The status names the source and counts what came and what was skipped.
    call(&mut ws, json!({"op": "subscribe", "stream": "status"})).await;
    let status = loop {
        let v = next_json(&mut ws).await;
        if v["stream"] == "status" && v["counters"]["stream_frames"] == 40 {
            break v;
        }
    };
    assert_eq!(status["source"], "stream", "{status}");
    let c = &status["counters"];
    assert_eq!(c["stream_samples"], 40 * FRAME as u64, "{c}");
    assert_eq!(c["stream_gap_samples"], 12_345, "{c}");
    assert_eq!(c["stream_dropped_samples"], 0, "{c}");
    // The DSP restarted at the gap (the stream's start was the chain's first block).
    assert_eq!(c["discontinuities"], 1, "{c}");
    let (_, metrics) = http_get(d.addr, "/metrics").await;
    assert_eq!(
        metric(&metrics, "ftafm_stream_samples_total{outcome=\"gap\"}"),
        12_345.0
    );
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_frames_are_refused_with_their_reason_and_change_nothing() {
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let mut frames = Vec::new();
    let one = tones(1, 0, 100);

    // The synthesiser is the source: no frame is taken.
    let r = push(&mut ws, frame(1, 0, &one, RATE), 1, &mut frames).await;
    assert_eq!(code(&r), "invalid_value", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("/source/kind"),
        "{r}"
    );
    let set = call(
        &mut ws,
        json!({"op": "set", "path": "/source/kind", "value": "stream"}),
    )
    .await;
    assert_eq!(set["ok"], true, "{set}");
    let list = call(
        &mut ws,
        json!({"op": "list", "path": "/sample/youngs_modulus"}),
    )
    .await;
    assert!(
        list["nodes"][0]["warning"]
            .as_str()
            .is_some_and(|w| w.contains("the source is a stream")),
        "{list}"
    );

    let r = push(&mut ws, frame(2, 0, &one, 1e6), 2, &mut frames).await;
    let m = r["error"]["message"].as_str().unwrap();
    assert!(m.contains("1000000") && m.contains("2000000"), "{r}");
    let mut short = frame(3, 0, &one, RATE);
    short.truncate(45);
    let r = push(&mut ws, short, 3, &mut frames).await;
    assert_eq!(code(&r), "bad_request", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("whole number"),
        "{r}"
    );
    ws.send(Message::Binary(b"nonsense".to_vec().into()))
        .await
        .unwrap();
    let r = next_reply(&mut ws).await;
    assert_eq!(r["id"], Value::Null, "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("40-byte header"),
        "{r}"
    );

    let r = push(&mut ws, frame(4, 500, &one, RATE), 4, &mut frames).await;
    assert_eq!(r["ok"], true, "{r}");
    let r = push(&mut ws, frame(5, 550, &one, RATE), 5, &mut frames).await;
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("frames go forward"),
        "{r}"
    );
    let mut nan = one.clone();
    nan[7] = f64::NAN;
    let r = push(&mut ws, frame(6, 600, &nan, RATE), 6, &mut frames).await;
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("sample 7 of the frame (stream index 607)"),
        "{r}"
    );
    // One stream at a time: another connection is refused while this one streams, and
    // takes over once it has gone.
    let mut other = connect(d.addr).await;
    let r = push(&mut other, frame(7, 0, &one, RATE), 7, &mut frames).await;
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("another connection"),
        "{r}"
    );
    let r = push(&mut ws, frame(8, 600, &one, RATE), 8, &mut frames).await;
    assert_eq!(r["ok"], true, "{r}");
    drop(ws);
    let taken = loop {
        let r = push(&mut other, frame(9, 0, &one, RATE), 9, &mut frames).await;
        if r["ok"] == true {
            break r;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(taken["accepted"], 100, "{taken}");
    let status = call(&mut other, json!({"op": "get", "paths": ["/source/kind"]})).await;
    assert_eq!(status["values"]["/source/kind"], "stream", "{status}");
    d.shutdown().await;
}

/// The next reply (a message with "ok").
async fn next_reply(ws: &mut Ws) -> Value {
    loop {
        let v = next_json(ws).await;
        if v.get("ok").is_some() {
            return v;
        }
    }
}

/// `ftafm replay` (a second process) streams a WAV written by another library into the
/// daemon as fast as it takes it: each tone read on the writer's reference, the file's
/// sample 0 at phase 0, nothing lost; a file at another rate is refused before anything is
/// sent, naming both rates.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ftafm_replay_streams_a_recording_into_the_daemon() {
    let dir = std::env::temp_dir().join(format!("ftafm-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let d = Daemon::start(light()).await;
    let mut ws = connect(d.addr).await;
    let f = call(&mut ws, json!({"op": "get", "path": "/drive/frequency"})).await["value"]
        .as_f64()
        .unwrap();
    let step = PhaseAccumulator::new(f, RATE).unwrap().frequency_word();
    let write = |name: &str, rate: u32| {
        let path = dir.join(name);
        let spec = hound::WavSpec {
            channels: 1,
            sample_rate: rate,
            bits_per_sample: 32,
            sample_format: hound::SampleFormat::Float,
        };
        let mut w = hound::WavWriter::create(&path, spec).unwrap();
        // 0.3 s of the tones in nm.
        for x in tones(step, 0, 600_000) {
            w.write_sample(x as f32).unwrap();
        }
        w.finalize().unwrap();
        path
    };
    let good = write("tones.wav", RATE as u32);
    let bad = write("slow.wav", 1_000_000);
    let url = format!("ws://{}/ws", d.addr);
    let run = |file: std::path::PathBuf, url: String| {
        tokio::task::spawn_blocking(move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_ftafm"))
                .args([
                    "replay", "--fast", "--json", "--invols", "1e-9", "--url", &url,
                ])
                .arg(&file)
                .output()
                .unwrap()
        })
    };
    let out = run(bad, url.clone()).await.unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("1000000 Hz") && err.contains("2000000 Hz"),
        "{err}"
    );
    assert_eq!(
        call(&mut ws, json!({"op": "get", "path": "/source/kind"})).await["value"],
        "synth"
    );

    call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    let out = run(good, url).await.unwrap();
    assert!(out.status.success(), "{out:?}");
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["samples"], 600_000, "{report}");
    assert_eq!(report["accepted"], 600_000, "{report}");
    assert_eq!((&report["dropped"], &report["gap"]), (&json!(0), &json!(0)));
    // Frames of the replayed signal, settled (the stream starts a sample after the
    // synthesiser's last: a restart of the filters), until its end.
    let mut seen = 0;
    let mut stream_frames = 0;
    while stream_frames < 30 {
        let v = next_json(&mut ws).await;
        if v["stream"] != "demods" {
            continue;
        }
        seen += 1;
        let (r, phase) = demod(&v, 3);
        // The synthesiser's frames before the stream's are told apart by their H3.
        if (r / TONES[1].1 - 1.0).abs() > 0.05 {
            assert!(stream_frames == 0, "a frame off the tones mid-stream: {v}");
            continue;
        }
        stream_frames += 1;
        if stream_frames < 10 {
            continue;
        }
        for (k, a, phi) in TONES {
            let (r, ph) = if k == 3 { (r, phase) } else { demod(&v, k) };
            assert!((r / a - 1.0).abs() < 1e-3, "H{k}: {r} against {a}: {v}");
            let dphi = (ph - phi + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(dphi.abs() < 1e-3, "H{k}: phase {ph} against {phi}");
        }
    }
    assert!(seen >= 30, "{seen}");
    std::fs::remove_dir_all(&dir).ok();
    d.shutdown().await;
}
