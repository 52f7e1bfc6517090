//! `ftafm replay FILE --url URL`: a recorded photodiode signal replayed into a running
//! daemon as its streamed source (`/source/kind = "stream"`), in real time or as fast as
//! the daemon takes it, once or looping: the live chain (streams, dashboard, sweeper,
//! recordings) on a real signal, and a soak test with a recorded one. A client of the
//! protocol's sample frames (docs/protocol.md, "Streaming samples in"); the file is read in
//! pieces, as `ftafm analyse` reads it.

use std::collections::VecDeque;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use serde::Serialize;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use super::analyse::RecordingArgs;
use super::{EXIT_USAGE, print_report};
use crate::analyse::{self, Options};
use crate::pipeline::{FrameHeader, SampleType};

/// Samples a frame (0.1 s at 655 kS/s, 6.6 ms at 10 MS/s) and frames unanswered at a time.
const FRAME: usize = 1 << 16;
const WINDOW: usize = 8;
/// Longest wait for one reply.
const REPLY_TIMEOUT: Duration = Duration::from_secs(30);

/// `ftafm replay`'s flags.
#[derive(clap::Args)]
pub struct ReplayArgs {
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// The daemon's WebSocket endpoint.
    #[arg(long, default_value = "ws://127.0.0.1:8700/ws")]
    pub url: String,
    /// As fast as the daemon takes the samples, not paced by the wall clock.
    #[arg(long)]
    pub fast: bool,
    /// Start again at the file's end (the writer's count goes on: the seam is where the
    /// file's end meets its start), until --seconds or Ctrl-C.
    #[arg(long = "loop")]
    pub looping: bool,
    /// Stop after this long of the signal (s).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// Print exactly one JSON object on stdout (progress still goes to stderr).
    #[arg(long)]
    pub json: bool,
}

/// What the replay sent and what became of it.
#[derive(Debug, Default, Serialize)]
pub struct ReplayReport {
    pub file: String,
    pub url: String,
    pub sample_rate: f64,
    pub scale: String,
    /// Passes over the file (the last one possibly partial).
    pub passes: u64,
    /// Samples sent, and what the daemon did with them (its replies).
    pub samples: u64,
    pub frames: u64,
    pub accepted: u64,
    pub dropped: u64,
    pub gap: u64,
    /// Wall time (s) and the signal's time over it.
    pub elapsed: f64,
    pub realtime_factor: f64,
}

/// Runs `ftafm replay`.
pub fn command(args: ReplayArgs) -> Result<ExitCode, ExitCode> {
    let usage = |e: String| {
        eprintln!("ftafm replay: {e}");
        ExitCode::from(EXIT_USAGE)
    };
    if let Some(s) = args.seconds
        && !(s.is_finite() && s > 0.0)
    {
        return Err(usage(format!("--seconds must be finite and > 0, got {s}")));
    }
    if args.looping && args.recording.file.as_os_str() == "-" {
        return Err(usage(
            "--loop needs a file: standard input cannot be read twice".into(),
        ));
    }
    let opts = args.recording.options().map_err(usage)?;
    // The file's errors before the daemon is touched.
    let opened = analyse::open(&opts).map_err(usage)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| usage(format!("cannot start the runtime: {e}")))?;
    let report = runtime
        .block_on(replay(&args, &opts, opened))
        .map_err(|e| {
            eprintln!("ftafm replay: {e}");
            ExitCode::FAILURE
        })?;
    print_report(args.json, &report, text);
    let lost = report.dropped + report.gap;
    Ok(if lost == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn text(r: &ReplayReport) -> String {
    format!(
        "{} → {}: {} samples at {} Hz in {} frames ({} pass(es)), {:.3} s, {:.2}× real time\n\
         scale: {}\n\
         daemon: {} accepted, {} dropped (its feed full), {} skipped\n",
        r.file,
        r.url,
        r.samples,
        r.sample_rate,
        r.frames,
        r.passes,
        r.elapsed,
        r.realtime_factor,
        r.scale,
        r.accepted,
        r.dropped,
        r.gap
    )
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The next reply (a message with `ok`), skipping anything else.
async fn reply(ws: &mut Ws) -> Result<Value, String> {
    loop {
        let m = tokio::time::timeout(REPLY_TIMEOUT, ws.next())
            .await
            .map_err(|_| format!("no reply within {} s", REPLY_TIMEOUT.as_secs()))?
            .ok_or("the daemon closed the connection")?
            .map_err(|e| format!("the connection failed: {e}"))?;
        if let Message::Text(t) = m {
            let v: Value = serde_json::from_str(&t).map_err(|e| format!("bad reply: {e}"))?;
            if v.get("ok").is_some() {
                return Ok(v);
            }
        }
    }
}

/// A request's reply, or its error in words.
async fn call(ws: &mut Ws, request: Value) -> Result<Value, String> {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .map_err(|e| format!("cannot send: {e}"))?;
    let r = reply(ws).await?;
    if r["ok"] == true {
        Ok(r)
    } else {
        Err(format!("{}: {}", r["error"]["code"], r["error"]["message"]))
    }
}

async fn replay(
    args: &ReplayArgs,
    opts: &Options,
    mut opened: analyse::Opened,
) -> Result<ReplayReport, String> {
    let (mut ws, _) = tokio_tungstenite::connect_async(args.url.as_str())
        .await
        .map_err(|e| format!("no daemon at {}: {e}", args.url))?;
    let hello = call(&mut ws, json!({"id": "hello", "op": "hello"})).await?;
    let rate = hello["sample_rate"].as_f64().unwrap_or(f64::NAN);
    if opened.sample_rate != rate {
        return Err(format!(
            "{} is at {} Hz (from {}) but the daemon runs at {rate} Hz (/synth/sample_rate, \
             fixed while running): start the daemon with the recording's rate",
            opened.name, opened.sample_rate, opened.sample_rate_from
        ));
    }
    call(
        &mut ws,
        json!({"id": "source", "op": "set", "path": "/source/kind", "value": "stream"}),
    )
    .await?;
    let mut report = ReplayReport {
        file: opened.name.clone(),
        url: args.url.clone(),
        sample_rate: rate,
        scale: opened.scale_text.clone(),
        passes: 1,
        ..ReplayReport::default()
    };
    let limit = args.seconds.map(|s| (s * rate).round() as u64);
    let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
        let total = limit.or(opened.src.frames.filter(|_| !args.looping));
        let bar = indicatif::ProgressBar::new(total.unwrap_or(0));
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {human_pos}/{human_len} samples, {per_sec}, ETA {eta}",
            )
            .expect("a valid template"),
        );
        bar
    });
    let chans = opened.src.channels;
    let mut piece = Vec::with_capacity(FRAME * chans);
    let mut bytes = Vec::with_capacity(FRAME * 8);
    let mut unanswered: VecDeque<u64> = VecDeque::new();
    let start = Instant::now();
    let mut index: u64 = 0;
    loop {
        let want = limit.map_or(FRAME, |l| FRAME.min((l - index) as usize));
        if want == 0 {
            break;
        }
        let n = opened.src.read(&mut piece, want)?;
        if n == 0 {
            if !args.looping || index == 0 {
                break;
            }
            opened = analyse::open(opts)?;
            report.passes += 1;
            continue;
        }
        bytes.clear();
        for v in piece.iter().skip(opts.signal_channel).step_by(chans) {
            bytes.extend_from_slice(&(v * opened.scale).to_le_bytes());
        }
        if !args.fast {
            let due = start + Duration::from_secs_f64(index as f64 / rate);
            tokio::time::sleep_until(due.into()).await;
        }
        let frame = FrameHeader {
            id: index,
            sample_type: SampleType::F64,
            sample_rate: rate,
            scale: 1.0,
            first_index: index,
        }
        .frame(&bytes);
        ws.send(Message::Binary(frame.into()))
            .await
            .map_err(|e| format!("cannot send: {e}"))?;
        unanswered.push_back(index);
        index += n as u64;
        report.samples += n as u64;
        while unanswered.len() >= WINDOW {
            settle(&mut ws, &mut unanswered, &mut report).await?;
        }
        if let Some(bar) = &bar {
            bar.set_position(index);
        }
    }
    while !unanswered.is_empty() {
        settle(&mut ws, &mut unanswered, &mut report).await?;
    }
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    report.elapsed = start.elapsed().as_secs_f64();
    report.realtime_factor = report.samples as f64 / rate / report.elapsed;
    let _ = ws.close(None).await;
    Ok(report)
}

/// Takes the reply to the oldest frame unanswered.
async fn settle(
    ws: &mut Ws,
    unanswered: &mut VecDeque<u64>,
    report: &mut ReplayReport,
) -> Result<(), String> {
    let r = reply(ws).await?;
    let id = unanswered.pop_front().unwrap_or(0);
    if r["ok"] != true {
        return Err(format!(
            "the daemon refused the frame at sample {id}: {}: {}",
            r["error"]["code"], r["error"]["message"]
        ));
    }
    let n = |k: &str| r[k].as_u64().unwrap_or(0);
    report.frames += 1;
    report.accepted += n("accepted");
    report.dropped += n("dropped");
    report.gap += n("gap");
    Ok(())
}
