//! `ftafm soak`: many real WebSocket clients against a running daemon, measured.
//!
//! Each client connects, subscribes to the chosen streams (JSON format) and, for every data
//! message, records the receive latency (receipt Unix time − `t_synth_ns`) in an HDR
//! histogram and counts the gaps in `seq`. Before and after the run the server's own
//! counters are read from `/metrics` (overruns, messages dropped for slow clients, clients).
//! Clients that lose their connection are counted and reconnect.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::server::status::LatencySummary;
use futures_util::{SinkExt, StreamExt};
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;

use crate::server::protocol::StreamKind;

/// Largest number of clients a soak may open.
pub const MAX_CLIENTS: usize = 1024;
/// Longest soak, in seconds.
pub const MAX_SECONDS: f64 = 86_400.0;
/// Largest latency the histogram resolves (60 s); larger values are clamped to it.
const MAX_LATENCY_NS: u64 = 60_000_000_000;
/// How long connecting and subscribing may take per client.
const SETUP_TIMEOUT: Duration = Duration::from_secs(10);

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
    /// Messages dropped for slow clients during the run, all streams.
    pub messages_dropped: u64,
    /// The same by stream.
    pub messages_dropped_by_stream: BTreeMap<String, u64>,
    /// Demodulator/spectrum/scope frames the DSP dropped during the run.
    pub frames_dropped: u64,
    /// Clients the server saw with all soak clients connected.
    pub clients_during: u64,
    /// Clients after the soak clients closed.
    pub clients_after: u64,
    /// Clients the server disconnected for stalling, during the run.
    pub clients_stalled: u64,
    /// Overrun samples since the daemon started (absolute, at the end).
    pub overruns_total: u64,
    /// Seconds the daemon had been up at the end.
    pub uptime_s: f64,
    /// The daemon's resident memory in bytes, if `/metrics` reports it.
    pub memory_bytes: Option<u64>,
    /// Where `memory_bytes` came from, or why it is unavailable.
    pub memory: String,
}

/// What `ftafm soak` reports; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SoakReport {
    /// The WebSocket URL.
    pub url: String,
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
}

impl SoakReport {
    /// Whether anything was lost: overruns on the server or gaps at a client.
    pub fn lost_anything(&self) -> bool {
        self.gaps > 0 || self.server.overruns > 0 || self.server.overrun_blocks > 0
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
    per_stream: Vec<(u64, u64, u64)>, // messages, gaps, bytes; index of `streams`
    disconnects: u64,
}

impl ClientStats {
    fn new(streams: usize) -> Self {
        Self {
            histogram: Histogram::new_with_bounds(1, MAX_LATENCY_NS, 3)
                .expect("valid histogram bounds"),
            per_stream: vec![(0, 0, 0); streams],
            disconnects: 0,
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

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
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
        if let Some(t) = env.t_synth_ns {
            let latency = received_ns.saturating_sub(t).clamp(1, MAX_LATENCY_NS);
            s.histogram.saturating_record(latency);
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

    /// The daemon's resident memory, under any of the usual names.
    fn memory(&self) -> Option<(u64, &'static str)> {
        [
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
    ServerReport {
        overruns: delta("ftafm_overrun_samples_total"),
        overrun_blocks: delta("ftafm_overrun_blocks_total"),
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
    }
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

    let before = fetch_metrics(&target).await?;
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
    loop {
        let elapsed = start.elapsed();
        if elapsed >= duration {
            break;
        }
        let wake = next.min(duration);
        tokio::time::sleep(wake.saturating_sub(elapsed)).await;
        if wake == next && wake < duration {
            if during.values.is_empty() {
                // Once, with every client connected: the server's view of the clients.
                during = fetch_metrics(&target).await.unwrap_or_default();
            }
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
    }
    state.store(DONE, Ordering::Release);
    let seconds = start.elapsed().as_secs_f64();
    let (histogram, per, disconnects) = summarize();
    if during.values.is_empty() {
        during = fetch_metrics(&target).await.unwrap_or_default();
    }
    // Read the server's counters before the clients close, then let them close.
    let after_open = fetch_metrics(&target).await;
    let _ = done_tx.send(true);
    for t in tasks {
        let _ = t.await;
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
        server: server_report(&before, &during, &after),
    })
}

/// Readable summary.
pub fn render_text(r: &SoakReport) -> String {
    let ms = |ns: u64| ns as f64 / 1e6;
    let l = &r.latency_ns;
    let s = &r.server;
    let mut out = format!(
        "ftafm soak: {} clients on {} for {:.1} s, streams {}\n\
         messages  {} ({:.0}/s), {:.2} MB/s, gaps {}, disconnects {}\n\
         latency   p50 {:.3} ms  p90 {:.3} ms  p99 {:.3} ms  p99.9 {:.3} ms  max {:.3} ms ({} messages)\n",
        r.clients,
        r.url,
        r.seconds,
        r.streams.join(","),
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
        "server    overruns {} samples in {} blocks; messages dropped {} ({}); frames dropped {}; \
         clients {} during, {} after; stalled {}\n",
        s.overruns,
        s.overrun_blocks,
        s.messages_dropped,
        dropped.join(", "),
        s.frames_dropped,
        s.clients_during,
        s.clients_after,
        s.clients_stalled,
    );
    out += &match s.memory_bytes {
        Some(b) => format!("memory    {:.1} MiB ({})\n", b as f64 / 1048576.0, s.memory),
        None => format!("memory    {}\n", s.memory),
    };
    out
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
    fn metrics_text_parses_and_dechunks() {
        let m = Metrics::parse(
            "# HELP x\nftafm_overrun_samples_total 3\nftafm_messages_dropped_total{stream=\"demods\"} 2\n",
        );
        assert_eq!(m.int("ftafm_overrun_samples_total"), 3);
        assert_eq!(m.sum("ftafm_messages_dropped_total"), 2);
        assert_eq!(m.memory(), None);
        assert_eq!(dechunk("5\r\nhello\r\n3\r\nabc\r\n0\r\n\r\n"), "helloabc");
    }
}
