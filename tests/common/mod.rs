//! What the daemon's socket tests share: a daemon on 127.0.0.1:0 started as mini-redis
//! does (`run(listener, settings, shutdown)`), real WebSocket clients and plain HTTP.
//! Each test binary uses a part of it.
#![allow(dead_code)]

pub mod bimodal;
pub mod loops;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use ftafm::config::{Settings, default_settings};
use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

pub type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

pub struct Daemon {
    pub addr: SocketAddr,
    pub stop: Option<oneshot::Sender<()>>,
    pub task: JoinHandle<Result<(), ftafm::server::ServerError>>,
}

impl Daemon {
    pub async fn start(settings: Settings) -> Self {
        Self::start_with(settings, ftafm::server::ConnectionLimits::default()).await
    }

    /// A daemon with the accept loop's limits given.
    pub async fn start_with(settings: Settings, limits: ftafm::server::ConnectionLimits) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(ftafm::server::run_with(
            listener,
            settings,
            async move {
                let _ = stopped.await;
            },
            limits,
        ));
        Self {
            addr,
            stop: Some(stop),
            task,
        }
    }

    pub async fn shutdown(mut self) -> Duration {
        let start = Instant::now();
        let _ = self.stop.take().unwrap().send(());
        (&mut self.task).await.unwrap().unwrap();
        start.elapsed()
    }
}

/// Instrument settings for tests: real time at 2 MS/s (cheap), demodulators at 200 Hz.
pub fn light() -> Settings {
    let mut s = default_settings();
    s.synth.sample_rate = 2e6;
    for d in &mut s.demods {
        d.harmonic = d.harmonic.min(9);
        d.rate = 200.0;
    }
    s.demods[16].harmonic = 9; // stays valid below Nyquist
    s.spectrum.size = 4096;
    // Its harmonic 17 is not measured here; the force stream has its own test.
    s.inversion.enable = false;
    s
}

pub async fn connect(addr: SocketAddr) -> Ws {
    let (ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
        .await
        .unwrap();
    ws
}

/// Sends `request` and returns its reply (skipping data messages).
pub async fn call(ws: &mut Ws, request: Value) -> Value {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .unwrap();
    reply(ws).await
}

/// Sends `request` and returns its reply, keeping the data messages of `stream` that came
/// before it in `early` (a change can make data at once, and its messages may overtake the
/// reply).
pub async fn call_keeping(
    ws: &mut Ws,
    request: Value,
    stream: &str,
    early: &mut Vec<Value>,
) -> Value {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .unwrap();
    reply_keeping(ws, |v| {
        if v["stream"] == stream {
            early.push(v);
        }
    })
    .await
}

/// The next reply, skipping data messages, within 10 s.
pub async fn reply(ws: &mut Ws) -> Value {
    reply_keeping(ws, |_| {}).await
}

/// The next reply (a message with "ok"; data messages never have one), within 10 s,
/// handing the JSON data messages before it to `other`.
async fn reply_keeping(ws: &mut Ws, mut other: impl FnMut(Value)) -> Value {
    next_where(ws, Duration::from_secs(10), "a reply", |msg| {
        let Message::Text(t) = msg else { return None };
        let v: Value = serde_json::from_str(&t).unwrap();
        if v.get("ok").is_some() {
            return Some(v);
        }
        other(v);
        None
    })
    .await
}

/// Next data message of `stream` (JSON), within 10 s: a guard against a hang, not a
/// measure of speed.
pub async fn next_of(ws: &mut Ws, stream: &str) -> Value {
    next_within(ws, stream, Duration::from_secs(10)).await
}

/// Next data message of `stream` (JSON) within `limit`: for messages that wait on work
/// off the real-time threads (a sweep point waits for its force estimator, built at low
/// priority), which a loaded machine may slow down many times over.
pub async fn next_within(ws: &mut Ws, stream: &str, limit: Duration) -> Value {
    next_where(ws, limit, "data", |msg| {
        let Message::Text(t) = msg else { return None };
        let v: Value = serde_json::from_str(&t).unwrap();
        (v["stream"] == stream && v.get("ok").is_none()).then_some(v)
    })
    .await
}

/// Next binary data message, within 10 s (a guard against a hang, not a measure of speed).
pub async fn next_binary(ws: &mut Ws) -> Vec<u8> {
    next_where(
        ws,
        Duration::from_secs(10),
        "binary data",
        |msg| match msg {
            Message::Binary(b) => Some(b.to_vec()),
            _ => None,
        },
    )
    .await
}

/// The first message within `limit` that `pick` takes (`Some`); panics naming `what` if
/// none comes in time (a hang guard).
async fn next_where<T>(
    ws: &mut Ws,
    limit: Duration,
    what: &str,
    mut pick: impl FnMut(Message) -> Option<T>,
) -> T {
    let deadline = Instant::now() + limit;
    loop {
        let msg = tokio::time::timeout_at(deadline.into(), ws.next())
            .await
            .unwrap_or_else(|_| panic!("{what} in time"))
            .unwrap()
            .unwrap();
        if let Some(v) = pick(msg) {
            return v;
        }
    }
}

/// The value of the sample `name` (with its labels, as printed) in a `/metrics` text.
pub fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in metrics"))
}

pub async fn http_get(addr: SocketAddr, path: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(
        format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .await
    .unwrap();
    // Bodies may be binary (image export): read bytes, show them lossily.
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).await.unwrap();
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let status = text[9..12].parse().unwrap();
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    (status, body)
}

pub fn code(v: &Value) -> &str {
    v["error"]["code"].as_str().unwrap_or("")
}

/// A config file that lives as long as the test (removed when dropped).
pub struct TempToml(std::path::PathBuf);

impl TempToml {
    pub fn new(name: &str, contents: &str) -> Self {
        let path = std::env::temp_dir().join(format!("ftafm-{}-{name}.toml", std::process::id()));
        std::fs::write(&path, contents).unwrap();
        Self(path)
    }

    pub fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempToml {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Waits (on messages, not on time: the deadline only guards a hang) for the first message
/// of `stream` that satisfies `accept`.
pub async fn first_of(ws: &mut Ws, stream: &str, accept: impl Fn(&Value) -> bool) -> Value {
    let what = format!("a matching {stream} message");
    next_where(ws, Duration::from_secs(120), &what, |msg| match msg {
        Message::Text(t) => {
            let v: Value = serde_json::from_str(&t).unwrap();
            (v["stream"] == stream && v.get("ok").is_none() && accept(&v)).then_some(v)
        }
        _ => None,
    })
    .await
}
