//! `ftafm soak`: many real WebSocket clients against a running daemon, measured.
//!
//! Each client connects, subscribes to the chosen streams (JSON format) and, for every data
//! message, records the receive latency (receipt Unix time − `t_synth_ns`) in an HDR
//! histogram and counts the gaps in `seq`. Before and after the run the server's own
//! counters are read from `/metrics` (overruns, messages dropped for slow clients, clients,
//! the daemon's resident memory). Clients that lose their connection are counted and
//! reconnect. The report keeps the latency histogram and a per-second timeline, which
//! [`html::render`] draws as a self-contained HTML page.
//!
//! A stall meter ([`StallMeter`]) runs beside the clients, and the daemon runs its own: the
//! report says how long this machine (and the daemon's) failed to run a ready thread, and
//! how many of the slow messages were in flight during such a stall.

pub mod html;

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::server::status::LatencySummary;
use futures_util::{SinkExt, StreamExt};
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

use super::EXIT_USAGE;
use crate::pipeline::{StallEvent, StallMeter, unix_ns as now_ns};
use crate::server::protocol::StreamKind;

/// Largest number of clients a soak may open.
pub const MAX_CLIENTS: usize = 1024;
/// Longest soak, in seconds.
pub const MAX_SECONDS: f64 = 86_400.0;
/// Largest latency the histogram resolves (60 s); larger values are clamped to it.
const MAX_LATENCY_NS: u64 = 60_000_000_000;
/// Bins per decade of the report's latency histogram.
const BINS_PER_DECADE: u32 = 10;
/// How long connecting and subscribing may take per client.
const SETUP_TIMEOUT: Duration = Duration::from_secs(10);
/// A message this late is slow: the max-latency goal of docs/benchmarks.md (20 ms).
pub const SLOW_NS: u64 = 20_000_000;
/// A slow message counts as held up by the machine when a stall at least this long (half
/// the slow threshold) of the soak's stall meter fell within its flight.
pub const MACHINE_STALL_NS: u64 = 10_000_000;
/// Slow messages kept per client for that comparison; more are only counted.
const SLOW_KEPT: usize = 10_000;
/// Machine stalls listed in the report, longest first.
const STALLS_LISTED: usize = 100;

/// What to run.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    /// WebSocket URL of the daemon, `ws://HOST:PORT/ws`.
    pub url: String,
    /// Number of concurrent clients (1 ≤ N ≤ 1024).
    pub clients: usize,
    /// Duration of the measurement in seconds (0 < S ≤ 86400).
    pub seconds: f64,
    /// Streams every client subscribes to (names of the protocol: `demods`, `status`, ...).
    pub streams: Vec<String>,
}

impl SoakOptions {
    /// Options for `clients` clients on `url` for `seconds`, subscribed to `demods`.
    pub fn new(url: impl Into<String>, clients: usize, seconds: f64) -> Self {
        Self {
            url: url.into(),
            clients,
            seconds,
            streams: vec!["demods".into()],
        }
    }

    /// Checks every option; the error names the flag.
    pub fn validate(&self) -> Result<Target, SoakError> {
        let invalid =
            |flag: &'static str, message: String| SoakError::InvalidOption { flag, message };
        if self.clients == 0 || self.clients > MAX_CLIENTS {
            return Err(invalid(
                "--clients",
                format!(
                    "--clients = {} is out of range: allowed 1 ≤ N ≤ {MAX_CLIENTS}",
                    self.clients
                ),
            ));
        }
        if !(self.seconds.is_finite() && self.seconds > 0.0 && self.seconds <= MAX_SECONDS) {
            return Err(invalid(
                "--seconds",
                format!(
                    "--seconds = {} is out of range: allowed 0 < S ≤ 86400",
                    self.seconds
                ),
            ));
        }
        if self.streams.is_empty() {
            return Err(invalid(
                "--streams",
                "--streams is empty: give at least one stream".into(),
            ));
        }
        for s in &self.streams {
            if StreamKind::from_name(s).is_none() {
                let names: Vec<_> = StreamKind::ALL.iter().map(|k| k.name()).collect();
                return Err(invalid(
                    "--streams",
                    format!(
                        "--streams: unknown stream {s:?}; streams: {}",
                        names.join(", ")
                    ),
                ));
            }
        }
        Target::parse(&self.url)
            .map_err(|e| invalid("--url", format!("--url = {:?} {e}", self.url)))
    }
}

/// Where the daemon is, from the `ws://` URL.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Target {
    /// Host as written in the URL (IPv6 in brackets).
    pub host: String,
    /// TCP port (80 if the URL has none).
    pub port: u16,
    /// The WebSocket URL.
    pub ws_url: String,
    /// `http://HOST:PORT/metrics`.
    pub metrics_url: String,
}

impl Target {
    /// Parses `ws://HOST[:PORT][/PATH]`.
    pub fn parse(url: &str) -> Result<Self, String> {
        let rest = url
            .strip_prefix("ws://")
            .ok_or("is not a ws:// URL: expected ws://HOST:PORT/ws")?;
        let authority = rest.split(['/', '?', '#']).next().unwrap_or("");
        if authority.is_empty() || authority.contains('@') {
            return Err("has no host: expected ws://HOST:PORT/ws".into());
        }
        let (host, port) = if let Some(v6) = authority.strip_prefix('[') {
            let (h, after) = v6
                .split_once(']')
                .ok_or("has an unterminated IPv6 address")?;
            let port = match after {
                "" => None,
                p => Some(
                    p.strip_prefix(':')
                        .ok_or("has junk after the IPv6 address")?,
                ),
            };
            (format!("[{h}]"), port)
        } else {
            match authority.rsplit_once(':') {
                Some((h, p)) => (h.to_string(), Some(p)),
                None => (authority.to_string(), None),
            }
        };
        if host.is_empty() || host == "[]" {
            return Err("has no host: expected ws://HOST:PORT/ws".into());
        }
        let port = match port {
            None => 80,
            Some(p) => p
                .parse::<u16>()
                .ok()
                .filter(|&p| p != 0)
                .ok_or_else(|| format!("has a bad port {p:?}"))?,
        };
        let ws_url = if rest.len() == authority.len() {
            format!("{url}/ws")
        } else {
            url.to_string()
        };
        Ok(Self {
            metrics_url: format!("http://{host}:{port}/metrics"),
            host,
            port,
            ws_url,
        })
    }

    fn connect_host(&self) -> &str {
        self.host.trim_start_matches('[').trim_end_matches(']')
    }
}

/// Why a soak could not run.
#[derive(Debug, thiserror::Error)]
pub enum SoakError {
    /// A bad option; `flag` names it (exit status 2).
    #[error("{message}")]
    InvalidOption {
        /// The flag, e.g. `--clients`.
        flag: &'static str,
        /// What was wrong and what is allowed.
        message: String,
    },
    /// The daemon could not be reached or the handshake failed.
    #[error("cannot connect: {0}")]
    Connect(String),
    /// The daemon answered something unexpected (e.g. refused a subscription).
    #[error("protocol error: {0}")]
    Protocol(String),
}

/// Per-stream figures seen by the clients.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct StreamReport {
    /// Data messages received (all clients).
    pub messages: u64,
    /// Missing messages (sum of `seq` gaps, all clients).
    pub gaps: u64,
    /// Bytes of payload received.
    pub bytes: u64,
    /// Messages per second (all clients).
    pub messages_per_s: f64,
}

/// The server's counters from `/metrics`: differences over the run, gauges at its end.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ServerReport {
    /// Samples dropped because the ring was full, during the run.
    pub overruns: u64,
    /// Blocks dropped because the ring was full, during the run.
    pub overrun_blocks: u64,
    /// Times the paced synthesiser fell more than 0.1 s behind the wall clock during the
    /// run and restarted its pacing, skipping that stretch of signal time (no frames are
    /// made for it, so clients see no gap).
    #[serde(default)]
    pub late_blocks: u64,
    /// Samples synthesised during the run per second of the run, divided by the sample
    /// rate: 1 when the synthesiser kept up with the wall clock (0 if unknown).
    #[serde(default)]
    pub synthesis_realtime_fraction: f64,
    /// Messages dropped for slow clients during the run, all streams.
    pub messages_dropped: u64,
    /// The same by stream.
    pub messages_dropped_by_stream: BTreeMap<String, u64>,
    /// Demodulator/spectrum/scope frames the DSP dropped during the run.
    pub frames_dropped: u64,
    /// Clients the server saw with all soak clients connected (not counting the soak's own
    /// connection that follows the daemon's `status`).
    pub clients_during: u64,
    /// Clients after the soak clients closed.
    pub clients_after: u64,
    /// Clients the server disconnected for stalling, during the run.
    pub clients_stalled: u64,
    /// Overrun samples since the daemon started (absolute, at the end).
    pub overruns_total: u64,
    /// Seconds the daemon had been up at the end.
    pub uptime_s: f64,
    /// The daemon's resident memory in bytes at the end, if `/metrics` reports it.
    pub memory_bytes: Option<u64>,
    /// Where `memory_bytes` came from, or why it is unavailable.
    pub memory: String,
    /// The daemon's resident memory (bytes) when the measurement started (clients
    /// connected and subscribed).
    #[serde(default)]
    pub rss_bytes_before: Option<u64>,
    /// The same when it ended (clients still connected).
    #[serde(default)]
    pub rss_bytes_after: Option<u64>,
    /// The daemon's largest resident memory since it started (bytes), at the end.
    #[serde(default)]
    pub rss_peak_bytes: Option<u64>,
    /// `rss_bytes_after − rss_bytes_before` (bytes; negative if it shrank).
    #[serde(default)]
    pub memory_growth_bytes: Option<i64>,
    /// The daemon's own latency summaries of demodulator frames since it started (ns), by
    /// path as in `/metrics` (`synth_to_dsp`, `synth_to_send`, `dsp_to_socket`,
    /// `synth_to_socket`); paths with no data are left out.
    #[serde(default)]
    pub latency_ns: BTreeMap<String, LatencySummary>,
    /// The daemon's stall meter since it started (ns), if `/metrics` reports it
    /// (`ftafm_machine_stall_seconds`).
    #[serde(default)]
    pub machine_stall_ns: Option<LatencySummary>,
}

/// How the machine itself behaved during the run: the soak's stall meter, the slow messages
/// that a stall explains, and the CPU time the hypervisor took.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct MachineReport {
    /// Oversleep of the soak's 1 ms naps (ns): how late this machine ran a ready thread.
    pub stall_ns: LatencySummary,
    /// Stalls of at least 5 ms, longest first (at most 100), with their times.
    pub stalls: Vec<StallEvent>,
    /// Stalls of at least 5 ms in all.
    pub stalls_over_5ms: u64,
    /// Messages at least [`SLOW_NS`] late.
    pub slow_messages: u64,
    /// Of those, the ones in flight while this machine stalled for at least
    /// [`MACHINE_STALL_NS`] (among the first 10 000 slow messages of each client).
    pub slow_messages_in_stalls: u64,
    /// Slow messages not compared (over 10 000 at one client).
    pub slow_messages_not_compared: u64,
    /// Seconds of the timeline whose largest latency was at least [`SLOW_NS`].
    pub slow_seconds: u64,
    /// Of those, the ones next to a stall of at least [`MACHINE_STALL_NS`] of this machine
    /// or the daemon's: in the second before, the same or the next. (A message can be late
    /// after the stall has ended, while the backlog drains; the daemon reports its stalls
    /// every 0.5 s, so its figure can land in the next second.)
    pub slow_seconds_with_stall: u64,
    /// Whether the daemon reported its stalls (`machine_stall_max_ns` in `status`).
    pub daemon_stalls_reported: bool,
    /// CPU time stolen by the hypervisor during the run, all CPUs (s; Linux `/proc/stat`).
    pub cpu_steal_s: Option<f64>,
}

/// What `ftafm soak` reports; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SoakReport {
    /// The WebSocket URL.
    pub url: String,
    /// The CPU the clients ran on (`crate::cpu::machine`: model with its family and model
    /// numbers, CPUs, vector build); empty in reports written before it was kept.
    #[serde(default)]
    pub cpu: String,
    /// Clients run.
    pub clients: usize,
    /// Streams each client subscribed to.
    pub streams: Vec<String>,
    /// Measured duration (s).
    pub seconds: f64,
    /// Data messages received, all clients and streams.
    pub messages: u64,
    /// Missing messages (sum of `seq` gaps).
    pub gaps: u64,
    /// Connections lost during the run (each client reconnects).
    pub disconnects: u64,
    /// Payload bytes received.
    pub bytes: u64,
    /// Messages per second, all clients.
    pub messages_per_s: f64,
    /// Payload bytes per second, all clients.
    pub bytes_per_s: f64,
    /// Receive latency: receipt Unix time − `t_synth_ns`, all messages (ns).
    pub latency_ns: LatencySummary,
    /// Per-stream counts.
    pub per_stream: BTreeMap<String, StreamReport>,
    /// The server's counters over the run.
    pub server: ServerReport,
    /// The receive latency histogram: logarithmic bins (10 per decade), from the first to
    /// the last non-empty one.
    #[serde(default)]
    pub latency_histogram: Vec<HistogramBin>,
    /// One point per second of the measurement (the last may be shorter).
    #[serde(default)]
    pub timeline: Vec<TimelinePoint>,
    /// The machine's own stalls during the run.
    #[serde(default)]
    pub machine: MachineReport,
}

/// One bin of the latency histogram: latencies in `[lo_ns, hi_ns)`.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct HistogramBin {
    /// Lower edge (ns).
    pub lo_ns: u64,
    /// Upper edge (ns).
    pub hi_ns: u64,
    /// Messages whose latency fell in the bin.
    pub count: u64,
}

/// Receive latency and counts over one interval of the run (about a second).
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct TimelinePoint {
    /// Seconds since the measurement started, at the interval's end.
    pub t: f64,
    /// Messages received in the interval (all clients).
    pub messages: u64,
    /// Missing messages (seq gaps) found in the interval.
    pub gaps: u64,
    /// Median latency in the interval (ns; 1 µs resolution, 2 significant digits).
    pub p50_ns: u64,
    /// 99th percentile (ns).
    pub p99_ns: u64,
    /// Largest (ns).
    pub max_ns: u64,
    /// The soak machine's longest stall in the interval (ns): how late its stall meter
    /// woke from a 1 ms nap.
    #[serde(default)]
    pub stall_max_ns: u64,
    /// The daemon's longest stall reported in the interval (`machine_stall_max_ns` of its
    /// `status` messages; 0 if none arrived).
    #[serde(default)]
    pub daemon_stall_max_ns: u64,
}

impl SoakReport {
    /// Whether anything was lost: overruns or late blocks (signal time skipped) on the
    /// server, or gaps at a client.
    pub fn lost_anything(&self) -> bool {
        self.gaps > 0
            || self.server.overruns > 0
            || self.server.overrun_blocks > 0
            || self.server.late_blocks > 0
    }
}

/// What the progress callback sees, about once a second.
#[derive(Clone, Copy, Debug)]
pub struct SoakProgress {
    /// Seconds since the measurement started.
    pub elapsed: f64,
    /// Messages so far.
    pub messages: u64,
    /// Gaps so far.
    pub gaps: u64,
    /// Disconnects so far.
    pub disconnects: u64,
    /// p99 receive latency so far (ns).
    pub p99_ns: u64,
}

/// One client's tallies, shared with the collector.
struct ClientStats {
    histogram: Histogram<u64>,
    /// Latencies since the collector last looked (for the timeline): coarser, to keep a
    /// client small.
    interval: Histogram<u32>,
    interval_gaps: u64,
    per_stream: Vec<(u64, u64, u64)>, // messages, gaps, bytes; index of `streams`
    disconnects: u64,
    /// Slow messages as (received Unix ns, latency ns), the first [`SLOW_KEPT`].
    slow: Vec<(u64, u64)>,
    /// Slow messages in all.
    slow_count: u64,
}

/// The histogram of one timeline interval: 1 µs resolution, 2 significant digits.
fn interval_histogram() -> Histogram<u32> {
    Histogram::new_with_bounds(1_000, MAX_LATENCY_NS, 2).expect("valid histogram bounds")
}

impl ClientStats {
    fn new(streams: usize) -> Self {
        Self {
            histogram: Histogram::new_with_bounds(1, MAX_LATENCY_NS, 3)
                .expect("valid histogram bounds"),
            interval: interval_histogram(),
            interval_gaps: 0,
            per_stream: vec![(0, 0, 0); streams],
            disconnects: 0,
            slow: Vec::new(),
            slow_count: 0,
        }
    }
}

const WARMING: u8 = 0;
const MEASURING: u8 = 1;
const DONE: u8 = 2;

#[derive(Deserialize)]
struct Envelope {
    stream: Option<String>,
    seq: Option<u64>,
    t_synth_ns: Option<u64>,
    ok: Option<serde::de::IgnoredAny>,
    error: Option<serde_json::Value>,
}

type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<TcpStream>>;

/// A connected, subscribed client and its per-stream last `seq`.
struct Conn {
    ws: Ws,
    last_seq: Vec<Option<u64>>,
}

async fn open(url: &str, streams: &[String]) -> Result<Conn, SoakError> {
    let (mut ws, _) = tokio::time::timeout(SETUP_TIMEOUT, tokio_tungstenite::connect_async(url))
        .await
        .map_err(|_| SoakError::Connect(format!("{url}: no handshake within 10 s")))?
        .map_err(|e| SoakError::Connect(format!("{url}: {e}")))?;
    for (i, s) in streams.iter().enumerate() {
        let request = serde_json::json!({"id": i, "op": "subscribe", "stream": s});
        ws.send(Message::Text(request.to_string().into()))
            .await
            .map_err(|e| SoakError::Connect(format!("{url}: {e}")))?;
    }
    Ok(Conn {
        ws,
        last_seq: vec![None; streams.len()],
    })
}

/// Handles one text frame: a reply (checked) or a data message (counted).
fn on_text(
    text: &str,
    received_ns: u64,
    streams: &[String],
    conn: &mut Conn,
    stats: &Mutex<ClientStats>,
    measuring: bool,
    replies: &mut usize,
) -> Result<(), SoakError> {
    let Ok(env) = serde_json::from_str::<Envelope>(text) else {
        return Ok(());
    };
    if env.ok.is_some() {
        if let Some(e) = env.error {
            return Err(SoakError::Protocol(format!("subscribe refused: {e}")));
        }
        *replies += 1;
        return Ok(());
    }
    let (Some(stream), Some(seq)) = (env.stream, env.seq) else {
        return Ok(());
    };
    let Some(index) = streams.iter().position(|s| *s == stream) else {
        return Ok(());
    };
    let gap = match conn.last_seq[index] {
        Some(last) if seq > last + 1 => seq - last - 1,
        _ => 0,
    };
    conn.last_seq[index] = Some(seq);
    if measuring {
        let mut s = stats.lock().unwrap_or_else(|e| e.into_inner());
        let entry = &mut s.per_stream[index];
        entry.0 += 1;
        entry.1 += gap;
        entry.2 += text.len() as u64;
        s.interval_gaps += gap;
        if let Some(t) = env.t_synth_ns {
            let latency = received_ns.saturating_sub(t).clamp(1, MAX_LATENCY_NS);
            s.histogram.saturating_record(latency);
            s.interval.saturating_record(latency);
            if latency >= SLOW_NS {
                s.slow_count += 1;
                if s.slow.len() < SLOW_KEPT {
                    s.slow.push((received_ns, latency));
                }
            }
        }
    }
    Ok(())
}

/// Connects and subscribes, waiting for every subscribe reply.
async fn setup(
    url: &str,
    streams: &[String],
    stats: &Mutex<ClientStats>,
) -> Result<Conn, SoakError> {
    let mut conn = open(url, streams).await?;
    let deadline = tokio::time::Instant::now() + SETUP_TIMEOUT;
    let mut replies = 0;
    while replies < streams.len() {
        let msg = tokio::time::timeout_at(deadline, conn.ws.next())
            .await
            .map_err(|_| SoakError::Protocol("no reply to subscribe within 10 s".into()))?;
        match msg {
            Some(Ok(Message::Text(t))) => {
                on_text(&t, now_ns(), streams, &mut conn, stats, false, &mut replies)?
            }
            Some(Ok(_)) => {}
            Some(Err(e)) => return Err(SoakError::Connect(format!("{url}: {e}"))),
            None => return Err(SoakError::Connect(format!("{url}: closed during setup"))),
        }
    }
    Ok(conn)
}

/// The daemon's stalls as its `status` messages report them.
#[derive(Default)]
struct DaemonStalls {
    /// Largest `machine_stall_max_ns` since the collector last took it.
    max: AtomicU64,
    /// Whether any status message carried the figure.
    reported: AtomicBool,
}

/// Follows the daemon's `status` stream on a connection of its own until `done`.
async fn follow_daemon_stalls(
    mut conn: Conn,
    stalls: Arc<DaemonStalls>,
    mut done: tokio::sync::watch::Receiver<bool>,
) {
    #[derive(Deserialize)]
    struct Status {
        stream: Option<String>,
        machine_stall_max_ns: Option<u64>,
    }
    loop {
        let msg = tokio::select! {
            m = conn.ws.next() => m,
            _ = done.wait_for(|d| *d) => break,
        };
        match msg {
            Some(Ok(Message::Text(t))) => {
                if let Ok(Status {
                    stream: Some(stream),
                    machine_stall_max_ns: Some(v),
                }) = serde_json::from_str(&t)
                    && stream == "status"
                {
                    stalls.max.fetch_max(v, Ordering::Relaxed);
                    stalls.reported.store(true, Ordering::Relaxed);
                }
            }
            Some(Ok(_)) => {}
            // Lost: the daemon's figures stop; the soak goes on.
            _ => return,
        }
    }
    let _ = tokio::time::timeout(Duration::from_secs(2), conn.ws.close(None)).await;
}

/// Receives until the state is DONE, reconnecting after a lost connection.
async fn client_loop(
    url: String,
    streams: Arc<Vec<String>>,
    mut conn: Conn,
    stats: Arc<Mutex<ClientStats>>,
    state: Arc<AtomicU8>,
    mut done: tokio::sync::watch::Receiver<bool>,
) {
    let mut replies = 0;
    loop {
        let msg = tokio::select! {
            m = conn.ws.next() => m,
            _ = done.wait_for(|d| *d) => break,
        };
        let received = now_ns();
        let measuring = state.load(Ordering::Acquire) == MEASURING;
        let lost = match msg {
            Some(Ok(Message::Text(t))) => on_text(
                &t,
                received,
                &streams,
                &mut conn,
                &stats,
                measuring,
                &mut replies,
            )
            .is_err(),
            Some(Ok(Message::Close(_))) | Some(Err(_)) | None => true,
            Some(Ok(_)) => false,
        };
        if lost {
            if state.load(Ordering::Acquire) == DONE {
                break;
            }
            if measuring {
                stats.lock().unwrap_or_else(|e| e.into_inner()).disconnects += 1;
            }
            // Reconnect until it works or the run ends; seq counting restarts.
            loop {
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_millis(200)) => {}
                    _ = done.wait_for(|d| *d) => return,
                }
                if let Ok(c) = open(&url, &streams).await {
                    conn = c;
                    break;
                }
            }
        }
    }
    let _ = tokio::time::timeout(Duration::from_secs(2), conn.ws.close(None)).await;
}

/// The counters of `/metrics` the report uses, parsed from the Prometheus text.
#[derive(Clone, Debug, Default)]
struct Metrics {
    values: BTreeMap<String, f64>,
}

impl Metrics {
    fn parse(text: &str) -> Self {
        let values = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| {
                let (name, value) = l.rsplit_once(' ')?;
                Some((name.trim().to_string(), value.trim().parse().ok()?))
            })
            .collect();
        Self { values }
    }

    fn get(&self, name: &str) -> Option<f64> {
        self.values.get(name).copied()
    }

    fn int(&self, name: &str) -> u64 {
        self.get(name).unwrap_or(0.0).max(0.0) as u64
    }

    /// Sum over every labelled series of `name` (e.g. `name{stream="x"}`).
    fn sum(&self, name: &str) -> u64 {
        let prefix = format!("{name}{{");
        self.values
            .iter()
            .filter(|(k, _)| *k == name || k.starts_with(&prefix))
            .map(|(_, v)| v.max(0.0) as u64)
            .sum()
    }

    /// The `ftafm_latency_seconds` summaries (converted to ns), by path, if not empty.
    fn latencies(&self) -> BTreeMap<String, LatencySummary> {
        let mut out = BTreeMap::new();
        for (key, &v) in &self.values {
            let Some(labels) = key
                .strip_prefix("ftafm_latency_seconds_count{path=\"")
                .and_then(|r| r.strip_suffix("\"}"))
            else {
                continue;
            };
            if v < 1.0 {
                continue;
            }
            let summary = self.summary(v, |q| {
                format!("ftafm_latency_seconds{{path=\"{labels}\",quantile=\"{q}\"}}")
            });
            out.insert(labels.to_string(), summary);
        }
        out
    }

    /// The daemon's stall meter (`ftafm_machine_stall_seconds`, converted to ns).
    fn stall(&self) -> Option<LatencySummary> {
        let count = self.get("ftafm_machine_stall_seconds_count")?;
        Some(self.summary(count, |q| {
            format!("ftafm_machine_stall_seconds{{quantile=\"{q}\"}}")
        }))
    }

    /// A summary of `count` values whose quantile `q` (in seconds) is at `key(q)`, in ns.
    fn summary(&self, count: f64, key: impl Fn(&str) -> String) -> LatencySummary {
        let q = |q: &str| (self.get(&key(q)).unwrap_or(0.0) * 1e9).round() as u64;
        LatencySummary {
            count: count as u64,
            p50: q("0.5"),
            p90: q("0.9"),
            p99: q("0.99"),
            p999: q("0.999"),
            max: q("1"),
        }
    }

    /// The daemon's resident memory, under any of the usual names.
    fn memory(&self) -> Option<(u64, &'static str)> {
        [
            "ftafm_process_resident_bytes",
            "ftafm_process_resident_memory_bytes",
            "ftafm_resident_memory_bytes",
            "ftafm_memory_bytes",
            "process_resident_memory_bytes",
        ]
        .into_iter()
        .find_map(|n| self.get(n).map(|v| (v as u64, n)))
    }
}

/// GET `http://HOST:PORT/metrics` over a plain TCP stream (HTTP/1.1, `Connection: close`).
async fn fetch_metrics(target: &Target) -> Result<Metrics, SoakError> {
    let err = |e: String| SoakError::Connect(format!("{}: {e}", target.metrics_url));
    let request = async {
        let mut s = TcpStream::connect((target.connect_host(), target.port))
            .await
            .map_err(|e| err(e.to_string()))?;
        let host = format!("{}:{}", target.host, target.port);
        s.write_all(
            format!("GET /metrics HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )
        .await
        .map_err(|e| err(e.to_string()))?;
        let mut raw = Vec::new();
        s.read_to_end(&mut raw)
            .await
            .map_err(|e| err(e.to_string()))?;
        Ok::<_, SoakError>(raw)
    };
    let raw = tokio::time::timeout(SETUP_TIMEOUT, request)
        .await
        .map_err(|_| err("no answer within 10 s".into()))??;
    let text = String::from_utf8_lossy(&raw);
    let (head, body) = text
        .split_once("\r\n\r\n")
        .ok_or_else(|| err("not an HTTP response".into()))?;
    let status = head.split(' ').nth(1).unwrap_or("");
    if status != "200" {
        return Err(err(format!("HTTP status {status}")));
    }
    let chunked = head.lines().any(|l| {
        let l = l.to_ascii_lowercase();
        l.starts_with("transfer-encoding:") && l.contains("chunked")
    });
    let body = if chunked {
        dechunk(body)
    } else {
        body.to_string()
    };
    Ok(Metrics::parse(&body))
}

fn dechunk(mut body: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = body.split_once("\r\n") {
        let Ok(n) = usize::from_str_radix(size.split(';').next().unwrap_or("").trim(), 16) else {
            break;
        };
        if n == 0 || rest.len() < n {
            break;
        }
        out.push_str(&rest[..n]);
        body = rest[n..].trim_start_matches("\r\n");
    }
    out
}

fn server_report(before: &Metrics, during: &Metrics, after: &Metrics) -> ServerReport {
    let delta = |name: &str| after.int(name).saturating_sub(before.int(name));
    let mut by_stream = BTreeMap::new();
    for k in StreamKind::ALL {
        let name = format!("ftafm_messages_dropped_total{{stream=\"{}\"}}", k.name());
        by_stream.insert(k.name().to_string(), delta(&name));
    }
    let (memory_bytes, memory) = match after.memory() {
        Some((v, name)) => (Some(v), format!("from /metrics {name}")),
        None => (
            None,
            "unavailable: the daemon's /metrics reports no memory figure".to_string(),
        ),
    };
    let rss_bytes_before = before.memory().map(|m| m.0);
    let memory_growth_bytes = rss_bytes_before
        .zip(memory_bytes)
        .map(|(b, a)| a as i64 - b as i64);
    ServerReport {
        overruns: delta("ftafm_overrun_samples_total"),
        overrun_blocks: delta("ftafm_overrun_blocks_total"),
        late_blocks: delta("ftafm_late_blocks_total"),
        synthesis_realtime_fraction: 0.0,
        messages_dropped: by_stream.values().sum(),
        messages_dropped_by_stream: by_stream,
        frames_dropped: after
            .sum("ftafm_frames_dropped_total")
            .saturating_sub(before.sum("ftafm_frames_dropped_total")),
        clients_during: during.int("ftafm_clients"),
        clients_after: after.int("ftafm_clients"),
        clients_stalled: delta("ftafm_clients_stalled_total"),
        overruns_total: after.int("ftafm_overrun_samples_total"),
        uptime_s: after.get("ftafm_uptime_seconds").unwrap_or(0.0),
        memory_bytes,
        memory,
        rss_bytes_before,
        rss_bytes_after: memory_bytes,
        rss_peak_bytes: after
            .get("ftafm_process_resident_peak_bytes")
            .map(|v| v as u64),
        memory_growth_bytes,
        latency_ns: after.latencies(),
        machine_stall_ns: after.stall(),
    }
}

/// Logarithmic bins of `h` (`BINS_PER_DECADE` per decade from 1 µs), from the first to the
/// last non-empty one.
fn histogram_bins(h: &Histogram<u64>) -> Vec<HistogramBin> {
    if h.is_empty() {
        return Vec::new();
    }
    let per = f64::from(BINS_PER_DECADE);
    let edge = |i: usize| (1e3 * 10f64.powf(i as f64 / per)).round() as u64;
    // Bin 0 is [0, edge(1)): everything below 1 µs joins the first bin.
    let bin = |v: u64| ((v.max(1_000) as f64 / 1e3).log10() * per).floor().max(0.0) as usize;
    let mut counts = vec![0u64; bin(h.max()) + 1];
    for v in h.iter_recorded() {
        // Each recorded HDR bucket goes whole into the bin of its lowest value.
        let value = h.lowest_equivalent(v.value_iterated_to());
        let last = counts.len() - 1;
        counts[bin(value).min(last)] += v.count_at_value();
    }
    let first = counts.iter().position(|&c| c > 0).unwrap_or(0);
    (first..counts.len())
        .map(|i| HistogramBin {
            lo_ns: if i == 0 { 0 } else { edge(i) },
            hi_ns: edge(i + 1),
            count: counts[i],
        })
        .collect()
}

/// Runs the soak: connects `options.clients` clients, measures for `options.seconds`, and
/// reads `/metrics` before and after. `progress` is called about once a second.
pub async fn run(
    options: &SoakOptions,
    mut progress: impl FnMut(&SoakProgress),
) -> Result<SoakReport, SoakError> {
    let target = options.validate()?;
    let streams = Arc::new(options.streams.clone());
    // Fail fast (exit 1) when nothing listens there.
    fetch_metrics(&target).await?;

    let state = Arc::new(AtomicU8::new(WARMING));
    let (done_tx, done_rx) = tokio::sync::watch::channel(false);
    let all_stats: Vec<_> = (0..options.clients)
        .map(|_| Arc::new(Mutex::new(ClientStats::new(streams.len()))))
        .collect();
    // Connect in parallel batches so that 1024 clients do not take forever.
    let mut conns = Vec::with_capacity(options.clients);
    for chunk in all_stats.chunks(64) {
        let batch = chunk.iter().map(|s| setup(&target.ws_url, &streams, s));
        for c in futures_util::future::join_all(batch).await {
            conns.push(c?);
        }
    }
    let mut tasks = Vec::with_capacity(options.clients);
    for (conn, stats) in conns.into_iter().zip(&all_stats) {
        tasks.push(tokio::spawn(client_loop(
            target.ws_url.clone(),
            streams.clone(),
            conn,
            stats.clone(),
            state.clone(),
            done_rx.clone(),
        )));
    }

    // The daemon's own stalls, from its status stream (an older daemon has none).
    let daemon_stalls = Arc::new(DaemonStalls::default());
    let follower: Option<tokio::task::JoinHandle<()>> =
        match open(&target.ws_url, &["status".to_string()]).await {
            Ok(conn) => Some(tokio::spawn(follow_daemon_stalls(
                conn,
                daemon_stalls.clone(),
                done_rx.clone(),
            ))),
            Err(_) => None,
        };
    let follower_connected = follower.is_some();

    let before = fetch_metrics(&target).await?;
    let steal_before = cpu_steal_s();
    let meter = StallMeter::start("ftafm-soak-stall")
        .map_err(|e| SoakError::Connect(format!("cannot start the stall meter's thread: {e}")))?;
    let start = Instant::now();
    state.store(MEASURING, Ordering::Release);
    let duration = Duration::from_secs_f64(options.seconds);
    let mut during = Metrics::default();
    let mut next = Duration::from_secs(1);
    let summarize = || {
        let mut h = Histogram::<u64>::new_with_bounds(1, MAX_LATENCY_NS, 3).expect("bounds");
        let mut per = vec![(0u64, 0u64, 0u64); streams.len()];
        let mut disconnects = 0;
        for s in &all_stats {
            let s = s.lock().unwrap_or_else(|e| e.into_inner());
            let _ = h.add(&s.histogram);
            for (acc, v) in per.iter_mut().zip(&s.per_stream) {
                acc.0 += v.0;
                acc.1 += v.1;
                acc.2 += v.2;
            }
            disconnects += s.disconnects;
        }
        (h, per, disconnects)
    };
    // Takes every client's interval histogram (starting them afresh): one timeline point.
    let mut interval = interval_histogram();
    let mut timeline = Vec::new();
    let mut take_interval = |t: f64| {
        interval.reset();
        let mut gaps = 0;
        for s in &all_stats {
            let mut s = s.lock().unwrap_or_else(|e| e.into_inner());
            let _ = interval.add(&s.interval);
            s.interval.reset();
            gaps += std::mem::take(&mut s.interval_gaps);
        }
        let q = |q: f64| {
            if interval.is_empty() {
                0
            } else {
                interval.value_at_quantile(q)
            }
        };
        timeline.push(TimelinePoint {
            t,
            messages: interval.len(),
            gaps,
            p50_ns: q(0.5),
            p99_ns: q(0.99),
            max_ns: if interval.is_empty() {
                0
            } else {
                interval.max()
            },
            stall_max_ns: meter.take_interval_max(),
            daemon_stall_max_ns: daemon_stalls.max.swap(0, Ordering::Relaxed),
        });
    };
    // A point for every whole second that falls within the run, however late the
    // collector wakes on a busy machine (a late tick is taken late, not skipped), then the
    // last part second's.
    while next < duration {
        tokio::time::sleep(next.saturating_sub(start.elapsed())).await;
        if during.values.is_empty() {
            // Once, with every client connected: the server's view of the clients.
            during = fetch_metrics(&target).await.unwrap_or_default();
        }
        take_interval(start.elapsed().as_secs_f64());
        let (h, per, disconnects) = summarize();
        progress(&SoakProgress {
            elapsed: start.elapsed().as_secs_f64(),
            messages: per.iter().map(|p| p.0).sum(),
            gaps: per.iter().map(|p| p.1).sum(),
            disconnects,
            p99_ns: if h.is_empty() {
                0
            } else {
                h.value_at_quantile(0.99)
            },
        });
        next += Duration::from_secs(1);
    }
    tokio::time::sleep(duration.saturating_sub(start.elapsed())).await;
    state.store(DONE, Ordering::Release);
    let seconds = start.elapsed().as_secs_f64();
    take_interval(seconds);
    let (histogram, per, disconnects) = summarize();
    let machine = machine_report(
        &meter,
        &all_stats,
        &timeline,
        steal_before,
        daemon_stalls.reported.load(Ordering::Relaxed),
    );
    drop(meter);
    if during.values.is_empty() {
        during = fetch_metrics(&target).await.unwrap_or_default();
    }
    // Read the server's counters before the clients close, then let them close.
    let after_open = fetch_metrics(&target).await;
    let _ = done_tx.send(true);
    for t in tasks {
        let _ = t.await;
    }
    if let Some(f) = follower {
        let _ = f.await;
    }
    let mut after = after_open.unwrap_or_default();
    // The clients gauge once the soak's own clients have gone.
    tokio::time::sleep(Duration::from_millis(100)).await;
    if let Ok(m) = fetch_metrics(&target).await {
        after.values.insert(
            "ftafm_clients".into(),
            m.get("ftafm_clients").unwrap_or(0.0),
        );
    }

    let mut server = server_report(&before, &during, &after);
    if follower_connected {
        server.clients_during = server.clients_during.saturating_sub(1);
    }
    if let Some(rate) = after.get("ftafm_sample_rate_hertz").filter(|r| *r > 0.0) {
        let synthesised = after
            .int("ftafm_samples_synthesized_total")
            .saturating_sub(before.int("ftafm_samples_synthesized_total"));
        server.synthesis_realtime_fraction = synthesised as f64 / seconds / rate;
    }
    let per_stream: BTreeMap<_, _> = streams
        .iter()
        .zip(&per)
        .map(|(name, &(messages, gaps, bytes))| {
            (
                name.clone(),
                StreamReport {
                    messages,
                    gaps,
                    bytes,
                    messages_per_s: messages as f64 / seconds,
                },
            )
        })
        .collect();
    let messages = per.iter().map(|p| p.0).sum::<u64>();
    let bytes = per.iter().map(|p| p.2).sum::<u64>();
    Ok(SoakReport {
        url: target.ws_url.clone(),
        cpu: crate::cpu::machine(),
        clients: options.clients,
        streams: options.streams.clone(),
        seconds,
        messages,
        gaps: per.iter().map(|p| p.1).sum(),
        disconnects,
        bytes,
        messages_per_s: messages as f64 / seconds,
        bytes_per_s: bytes as f64 / seconds,
        latency_ns: LatencySummary::from_histogram(&histogram),
        per_stream,
        server,
        latency_histogram: histogram_bins(&histogram),
        timeline,
        machine,
    })
}

/// The machine's side of the run: the stall meter's figures and the slow messages that a
/// stall explains.
fn machine_report(
    meter: &StallMeter,
    clients: &[Arc<Mutex<ClientStats>>],
    timeline: &[TimelinePoint],
    steal_before: Option<f64>,
    daemon_stalls_reported: bool,
) -> MachineReport {
    let mut slow = Vec::new();
    let mut slow_messages = 0;
    for c in clients {
        let c = c.lock().unwrap_or_else(|e| e.into_inner());
        slow.extend_from_slice(&c.slow);
        slow_messages += c.slow_count;
    }
    let events = meter.events();
    let (slow_seconds, slow_seconds_with_stall) = slow_seconds(timeline);
    MachineReport {
        stall_ns: LatencySummary::from_histogram(&meter.histogram()),
        stalls: longest_stalls(&events),
        stalls_over_5ms: meter.stalls(),
        slow_messages,
        slow_messages_in_stalls: crate::pipeline::stall::overlapping(
            &slow,
            &events,
            MACHINE_STALL_NS,
        ) as u64,
        slow_messages_not_compared: slow_messages - slow.len() as u64,
        slow_seconds,
        slow_seconds_with_stall,
        daemon_stalls_reported,
        cpu_steal_s: steal_since(steal_before),
    }
}

/// Seconds of `timeline` with a slow message, and how many of them are next to a stall of
/// this machine or the daemon's (in the second before, the same or the next).
fn slow_seconds(timeline: &[TimelinePoint]) -> (u64, u64) {
    let mut slow = 0;
    let mut with_stall = 0;
    for (i, p) in timeline.iter().enumerate() {
        if p.max_ns < SLOW_NS {
            continue;
        }
        slow += 1;
        let near = &timeline[i.saturating_sub(1)..(i + 2).min(timeline.len())];
        if near
            .iter()
            .any(|q| q.stall_max_ns.max(q.daemon_stall_max_ns) >= MACHINE_STALL_NS)
        {
            with_stall += 1;
        }
    }
    (slow, with_stall)
}

/// The [`STALLS_LISTED`] longest of `events`, longest first.
fn longest_stalls(events: &[StallEvent]) -> Vec<StallEvent> {
    let mut top = events.to_vec();
    top.sort_by_key(|e| std::cmp::Reverse(e.stall_ns));
    top.truncate(STALLS_LISTED);
    top
}

/// CPU steal since `before` (a reading of [`cpu_steal_s`]), in seconds.
fn steal_since(before: Option<f64>) -> Option<f64> {
    cpu_steal_s()
        .zip(before)
        .map(|(after, before)| after - before)
}

/// CPU time the hypervisor has taken from this machine since boot, all CPUs (s): the
/// `steal` column of `/proc/stat` (Linux; `None` elsewhere).
fn cpu_steal_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let ticks: f64 = stat
        .lines()
        .next()?
        .split_whitespace()
        .nth(8)?
        .parse()
        .ok()?;
    // The kernel reports in USER_HZ, 100 on every Linux ABI.
    Some(ticks / 100.0)
}

/// What `ftafm stalls` reports: the machine's stalls with nothing of ftafm running.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StallReport {
    /// Measured duration (s).
    pub seconds: f64,
    /// Oversleep of the 1 ms naps (ns).
    pub stall_ns: LatencySummary,
    /// Stalls of at least 5 ms.
    pub stalls_over_5ms: u64,
    /// Stalls of at least [`SLOW_NS`] (20 ms).
    pub stalls_over_20ms: u64,
    /// The longest stalls of at least 5 ms, longest first (at most 100), with their times.
    pub longest: Vec<StallEvent>,
    /// CPU time the hypervisor took during the run, all CPUs (s; Linux `/proc/stat`).
    pub cpu_steal_s: Option<f64>,
}

/// Runs a stall meter alone for `seconds`; `progress(elapsed s, longest stall so far ns,
/// stalls ≥ 5 ms so far)` is called about once a second.
pub fn measure_stalls(
    seconds: f64,
    mut progress: impl FnMut(f64, u64, u64),
) -> std::io::Result<StallReport> {
    let steal_before = cpu_steal_s();
    let meter = StallMeter::start("ftafm-stall")?;
    let start = Instant::now();
    let duration = Duration::from_secs_f64(seconds);
    let mut longest = 0;
    let mut next = Duration::from_secs(1);
    while start.elapsed() < duration {
        std::thread::sleep(next.min(duration).saturating_sub(start.elapsed()));
        longest = longest.max(meter.take_interval_max());
        if next < duration {
            progress(start.elapsed().as_secs_f64(), longest, meter.stalls());
        }
        next += Duration::from_secs(1);
    }
    let seconds = start.elapsed().as_secs_f64();
    let events = meter.events();
    let histogram = meter.histogram();
    let stalls_over_5ms = meter.stalls();
    drop(meter);
    Ok(StallReport {
        seconds,
        stall_ns: LatencySummary::from_histogram(&histogram),
        stalls_over_5ms,
        stalls_over_20ms: events.iter().filter(|e| e.stall_ns >= SLOW_NS).count() as u64,
        longest: longest_stalls(&events),
        cpu_steal_s: steal_since(steal_before),
    })
}

/// Readable form of [`StallReport`].
pub fn render_stalls(r: &StallReport) -> String {
    let ms = |ns: u64| ns as f64 / 1e6;
    let l = &r.stall_ns;
    let longest: Vec<_> = r
        .longest
        .iter()
        .take(10)
        .map(|e| format!("{:.1}", ms(e.stall_ns)))
        .collect();
    format!(
        "ftafm stalls: {} naps of 1 ms in {:.1} s\n\
         oversleep p50 {:.3} ms  p90 {:.3} ms  p99 {:.3} ms  p99.9 {:.3} ms  max {:.3} ms\n\
         stalls    {} of at least 5 ms, {} of at least 20 ms; longest (ms): {}\n\
         steal     {}\n",
        l.count,
        r.seconds,
        ms(l.p50),
        ms(l.p90),
        ms(l.p99),
        ms(l.p999),
        ms(l.max),
        r.stalls_over_5ms,
        r.stalls_over_20ms,
        if longest.is_empty() {
            "none".to_string()
        } else {
            longest.join(", ")
        },
        r.cpu_steal_s
            .map(|t| format!("{t:.2} s of CPU time taken by the hypervisor"))
            .unwrap_or_else(|| "unknown (no /proc/stat)".into()),
    )
}

/// Readable summary.
pub fn render_text(r: &SoakReport) -> String {
    let ms = |ns: u64| ns as f64 / 1e6;
    let l = &r.latency_ns;
    let s = &r.server;
    let mut out = format!(
        "ftafm soak: {} clients on {} for {:.1} s, streams {}\n\
         cpu       {}\n\
         messages  {} ({:.0}/s), {:.2} MB/s, gaps {}, disconnects {}\n\
         latency   p50 {:.3} ms  p90 {:.3} ms  p99 {:.3} ms  p99.9 {:.3} ms  max {:.3} ms ({} messages)\n",
        r.clients,
        r.url,
        r.seconds,
        r.streams.join(","),
        if r.cpu.is_empty() {
            "not recorded"
        } else {
            &r.cpu
        },
        r.messages,
        r.messages_per_s,
        r.bytes_per_s / 1e6,
        r.gaps,
        r.disconnects,
        ms(l.p50),
        ms(l.p90),
        ms(l.p99),
        ms(l.p999),
        ms(l.max),
        l.count,
    );
    for (name, st) in &r.per_stream {
        out += &format!(
            "  {name:<9} {} messages ({:.0}/s), gaps {}, {} bytes\n",
            st.messages, st.messages_per_s, st.gaps, st.bytes
        );
    }
    let dropped: Vec<_> = s
        .messages_dropped_by_stream
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    out += &format!(
        "server    overruns {} samples in {} blocks; late blocks {} (synthesis at {:.3} of real time); \
         messages dropped {} ({}); frames dropped {}; clients {} during, {} after; stalled {}\n",
        s.overruns,
        s.overrun_blocks,
        s.late_blocks,
        s.synthesis_realtime_fraction,
        s.messages_dropped,
        dropped.join(", "),
        s.frames_dropped,
        s.clients_during,
        s.clients_after,
        s.clients_stalled,
    );
    for (path, l) in &s.latency_ns {
        out += &format!(
            "daemon    {path:<15} p50 {:.3} ms  p99 {:.3} ms  p99.9 {:.3} ms  max {:.3} ms ({} frames since start)\n",
            ms(l.p50),
            ms(l.p99),
            ms(l.p999),
            ms(l.max),
            l.count
        );
    }
    let m = &r.machine;
    out += &format!(
        "machine   stalls of this machine (1 ms naps): p99 {:.3} ms  max {:.3} ms, {} over 5 ms{}{}\n\
         slow      {} messages over {:.0} ms, {} of them in flight during a stall ≥ {:.0} ms of this machine{}; \
         {} seconds had one, {} of them next to a stall ≥ {:.0} ms of this machine or the daemon's\n",
        ms(m.stall_ns.p99),
        ms(m.stall_ns.max),
        m.stalls_over_5ms,
        s.machine_stall_ns
            .map(|d| format!(
                "; the daemon's: p99 {:.3} ms  max {:.3} ms since it started, {:.3} ms during the run",
                ms(d.p99),
                ms(d.max),
                ms(r.timeline.iter().map(|p| p.daemon_stall_max_ns).max().unwrap_or(0))
            ))
            .unwrap_or_default(),
        m.cpu_steal_s
            .map(|t| format!("; CPU steal {t:.2} s"))
            .unwrap_or_default(),
        m.slow_messages,
        ms(SLOW_NS),
        m.slow_messages_in_stalls,
        ms(MACHINE_STALL_NS),
        if m.slow_messages_not_compared > 0 {
            format!(" ({} not compared)", m.slow_messages_not_compared)
        } else {
            String::new()
        },
        m.slow_seconds,
        m.slow_seconds_with_stall,
        ms(MACHINE_STALL_NS),
    );
    let mib = |b: u64| b as f64 / 1048576.0;
    out += &match (s.rss_bytes_before, s.memory_bytes, s.memory_growth_bytes) {
        (Some(before), Some(after), Some(growth)) => format!(
            "memory    {:.1} MiB before, {:.1} MiB after: growth {growth} bytes ({:+.2} MiB){} ({})\n",
            mib(before),
            mib(after),
            growth as f64 / 1048576.0,
            s.rss_peak_bytes
                .map(|p| format!(", peak {:.1} MiB", mib(p)))
                .unwrap_or_default(),
            s.memory
        ),
        (_, Some(b), _) => format!("memory    {:.1} MiB ({})\n", mib(b), s.memory),
        _ => format!("memory    {}\n", s.memory),
    };
    out
}

/// The command line.
pub fn command(
    url: String,
    clients: i64,
    seconds: f64,
    streams: &str,
    json: bool,
    fail_on_loss: bool,
    html: Option<std::path::PathBuf>,
) -> Result<ExitCode, ExitCode> {
    let usage = |message: String| {
        eprintln!("ftafm: {message}");
        ExitCode::from(EXIT_USAGE)
    };
    let clients = usize::try_from(clients)
        .ok()
        .filter(|&n| n <= crate::cli::soak::MAX_CLIENTS)
        .ok_or_else(|| {
            usage(format!(
                "--clients = {clients} is out of range: allowed 1 ≤ N ≤ {}",
                crate::cli::soak::MAX_CLIENTS
            ))
        })?;
    let options = crate::cli::soak::SoakOptions {
        url,
        clients,
        seconds,
        streams: streams
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(String::from)
            .collect(),
    };
    options.validate().map_err(|e| usage(e.to_string()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("ftafm-soak")
        .build()
        .map_err(|e| {
            eprintln!("ftafm: cannot start the async runtime: {e}");
            ExitCode::FAILURE
        })?;
    let report = runtime
        .block_on(crate::cli::soak::run(&options, |p| {
            eprintln!(
                "[{:>5.0} s] {} messages, gaps {}, disconnects {}, p99 {:.3} ms",
                p.elapsed,
                p.messages,
                p.gaps,
                p.disconnects,
                p.p99_ns as f64 / 1e6
            );
        }))
        .map_err(|e| match e {
            crate::cli::soak::SoakError::InvalidOption { .. } => usage(e.to_string()),
            _ => {
                eprintln!("ftafm: {e}");
                ExitCode::FAILURE
            }
        })?;
    let html = html.unwrap_or_else(|| {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        std::env::temp_dir().join(format!("ftafm-soak-{now}.html"))
    });
    match crate::cli::soak::html::write(&report, &html) {
        Ok(()) => eprintln!("ftafm: report written to {}", html.display()),
        Err(e) => eprintln!("ftafm: cannot write the report {}: {e}", html.display()),
    }
    if json {
        println!("{}", serde_json::to_string(&report).expect("plain numbers"));
    } else {
        print!("{}", crate::cli::soak::render_text(&report));
    }
    if fail_on_loss && report.lost_anything() {
        eprintln!(
            "ftafm: loss: {} seq gaps, {} overrun samples in {} blocks, {} late blocks",
            report.gaps,
            report.server.overruns,
            report.server.overrun_blocks,
            report.server.late_blocks
        );
        return Err(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_parse_to_host_port_and_metrics() {
        let t = Target::parse("ws://127.0.0.1:8700/ws").unwrap();
        assert_eq!((t.host.as_str(), t.port), ("127.0.0.1", 8700));
        assert_eq!(t.metrics_url, "http://127.0.0.1:8700/metrics");
        let t = Target::parse("ws://[::1]:9000/ws").unwrap();
        assert_eq!((t.connect_host(), t.port), ("::1", 9000));
        let t = Target::parse("ws://localhost").unwrap();
        assert_eq!((t.port, t.ws_url.as_str()), (80, "ws://localhost/ws"));
        for bad in [
            "http://x:1/ws",
            "ws://",
            "ws://:80/ws",
            "ws://h:0/ws",
            "ws://h:99999",
            "wss://h/ws",
        ] {
            assert!(Target::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn slow_seconds_are_matched_to_stalls_next_to_them() {
        let p = |max_ms: u64, stall_ms: u64| TimelinePoint {
            max_ns: max_ms * 1_000_000,
            stall_max_ns: stall_ms * 1_000_000,
            ..Default::default()
        };
        // Slow seconds: 1 (stall in it), 3 (stall the second before), 5 (none near).
        let timeline = [p(2, 1), p(60, 55), p(3, 40), p(25, 2), p(1, 1), p(30, 9)];
        assert_eq!(slow_seconds(&timeline), (3, 2));
        assert_eq!(slow_seconds(&[]), (0, 0));
        // The daemon's stall, reported in the next second, explains second 0; nothing
        // explains second 3, two seconds after it.
        let mut timeline = [p(25, 1), p(1, 1), p(1, 1), p(25, 1)];
        timeline[1].daemon_stall_max_ns = 30_000_000;
        assert_eq!(slow_seconds(&timeline), (2, 1));
    }

    #[test]
    fn metrics_text_parses_and_dechunks() {
        let m = Metrics::parse(
            "# HELP x\nftafm_overrun_samples_total 3\nftafm_messages_dropped_total{stream=\"demods\"} 2\n",
        );
        assert_eq!(m.int("ftafm_overrun_samples_total"), 3);
        assert_eq!(m.sum("ftafm_messages_dropped_total"), 2);
        assert_eq!(m.memory(), None);
        assert_eq!(m.stall(), None);
        let m = Metrics::parse(
            "ftafm_machine_stall_seconds{quantile=\"0.99\"} 0.0004\nftafm_machine_stall_seconds{quantile=\"1\"} 0.05\nftafm_machine_stall_seconds_count 10\n",
        );
        let stall = m.stall().unwrap();
        assert_eq!(
            (stall.count, stall.p99, stall.max),
            (10, 400_000, 50_000_000)
        );
        assert_eq!(dechunk("5\r\nhello\r\n3\r\nabc\r\n0\r\n\r\n"), "helloabc");
    }
}
