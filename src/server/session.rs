//! One WebSocket connection: requests in, exactly one reply each; data messages out.
//!
//! Replies and data share the socket through a writer task that sends replies first. A
//! peer that accepts nothing for `/server/stall_timeout` is disconnected (1008 "stalled");
//! at shutdown every client gets a close frame (1001).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Map, Value, json};
use tokio::sync::mpsc;

use super::protocol::{self, ErrorCode, Op, ProtocolError, Request, StreamKind};
use super::state::{AppState, ClientHandle, Control, DataQueue, DataReceiver};
use crate::pipeline::unix_ns;

/// Requests a client may make per second on average, and in a burst.
const REQUESTS_PER_SECOND: f64 = 200.0;
const REQUEST_BURST: f64 = 400.0;
/// Close codes.
const GOING_AWAY: u16 = 1001;
const POLICY: u16 = 1008;
const TOO_BIG: u16 = 1009;

fn close(code: u16, reason: &'static str) -> Message {
    Message::Close(Some(CloseFrame {
        code,
        reason: Utf8Bytes::from_static(reason),
    }))
}

/// Token bucket for a connection's requests.
struct RateLimit {
    tokens: f64,
    at: Instant,
}

impl RateLimit {
    fn new() -> Self {
        Self {
            tokens: REQUEST_BURST,
            at: Instant::now(),
        }
    }

    fn allow(&mut self) -> bool {
        let now = Instant::now();
        let refill = (now - self.at).as_secs_f64() * REQUESTS_PER_SECOND;
        self.tokens = (self.tokens + refill).min(REQUEST_BURST);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// Serves one upgraded connection until either side closes it.
pub(crate) async fn run(socket: WebSocket, state: Arc<AppState>, queue: usize) {
    let id = state.next_client.fetch_add(1, Ordering::Relaxed);
    let (data_tx, data_rx) = DataQueue::new(queue);
    let client = Arc::new(ClientHandle::new(id, data_tx));
    if let Ok(mut clients) = state.clients.lock() {
        clients.push(client.clone());
    }
    tracing::debug!(client = id, "connected");
    let (sink, mut stream) = socket.split();
    let (reply_tx, reply_rx) = mpsc::channel::<Message>(64);
    let stall = stall_timeout(&state);
    let mut writer = tokio::spawn(write(
        sink,
        reply_rx,
        data_rx,
        state.clone(),
        client.clone(),
        stall,
    ));

    let mut limit = RateLimit::new();
    let mut writer_done = false;
    loop {
        // The writer ends when the peer stalls (or on shutdown): then the connection is
        // dropped at once, whether or not the peer sends anything, so its slot frees and a
        // peer that resumes reading finds the connection closed, not a silent gap.
        let incoming = tokio::select! {
            m = stream.next() => match m {
                Some(m) => m,
                None => break,
            },
            _ = &mut writer => {
                writer_done = true;
                break;
            }
        };
        let reply = match incoming {
            Ok(Message::Text(text)) => {
                if limit.allow() {
                    handle(text.as_str(), &state, &client).await
                } else {
                    let id =
                        protocol::parse_request(text.as_str()).map_or_else(|(id, _)| id, |r| r.id);
                    let err = ProtocolError {
                        code: ErrorCode::RateLimited,
                        message: format!(
                            "more than {REQUESTS_PER_SECOND} requests per second (burst {REQUEST_BURST}); slow down"
                        ),
                    };
                    Message::Text(protocol::error_reply(&id, &err).into())
                }
            }
            Ok(Message::Binary(_)) => {
                let err = ProtocolError {
                    code: ErrorCode::BadRequest,
                    message: "requests are JSON text frames; binary frames are not accepted".into(),
                };
                Message::Text(protocol::error_reply(&Value::Null, &err).into())
            }
            Ok(Message::Close(_)) => break,
            Ok(_) => continue, // ping/pong are answered by the library
            Err(e) => {
                let too_big = e.to_string().to_lowercase().contains("too long")
                    || e.to_string().to_lowercase().contains("too big")
                    || e.to_string().to_lowercase().contains("capacity");
                if too_big {
                    let _ = reply_tx
                        .send(close(TOO_BIG, "message too big (limit 64 KiB)"))
                        .await;
                }
                tracing::debug!(client = id, error = %e, "receive failed");
                break;
            }
        };
        if reply_tx.send(reply).await.is_err() {
            break; // the writer ended (stalled peer or shutdown)
        }
    }
    drop(reply_tx);
    if let Ok(mut clients) = state.clients.lock() {
        clients.retain(|c| c.id != id);
    }
    // The force worker may skip again what this client took.
    state.update_force_stride();
    // Let the writer flush a final close frame, but not forever.
    if !writer_done {
        let _ = tokio::time::timeout(Duration::from_secs(1), writer).await;
    }
    drop(stream);
    tracing::debug!(
        client = id,
        dropped = client.dropped.load(Ordering::Relaxed),
        "disconnected"
    );
}

/// Whether a change of `path` moves the 1-DOF operating point (and so the model-range check).
fn affects_physics(path: &str) -> bool {
    ["/cantilever", "/tip", "/sample", "/drive", "/surface"]
        .iter()
        .any(|p| path.starts_with(p))
}

fn stall_timeout(state: &AppState) -> Duration {
    let seconds = state
        .control
        .lock()
        .map(|c| c.settings.server.stall_timeout)
        .unwrap_or(60.0);
    Duration::from_secs_f64(seconds)
}

/// Sends replies (first) and data until the peer stalls, the session ends or the server
/// shuts down. Each data message handed to the socket is counted and its latency recorded
/// on `client`.
async fn write(
    mut sink: futures_util::stream::SplitSink<WebSocket, Message>,
    mut replies: mpsc::Receiver<Message>,
    mut data: DataReceiver,
    state: Arc<AppState>,
    client: Arc<ClientHandle>,
    stall: Duration,
) {
    let mut shutdown = state.shutdown.clone();
    loop {
        let (msg, stamps) = tokio::select! {
            biased;
            _ = shutdown.changed() => {
                let _ = tokio::time::timeout(Duration::from_millis(500), sink.send(close(GOING_AWAY, "server shutting down"))).await;
                return;
            }
            r = replies.recv() => match r {
                Some(m) => (m, None),
                None => return,
            },
            Some(o) = data.recv() => (o.msg, Some(o.stamps)),
        };
        let closing = matches!(msg, Message::Close(_));
        let sent = tokio::time::timeout(stall, sink.send(msg)).await;
        if let (Ok(Ok(())), Some(stamps)) = (&sent, stamps) {
            client.written(&state, stamps, unix_ns());
        }
        match sent {
            Ok(Ok(())) if !closing => {}
            Ok(Ok(())) => return,
            Ok(Err(_)) => return,
            Err(_) => {
                state.closed_stalled.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    client = client.id,
                    stall_timeout_s = stall.as_secs_f64(),
                    "closing a client whose socket accepted nothing for /server/stall_timeout"
                );
                let _ = tokio::time::timeout(
                    Duration::from_millis(200),
                    sink.send(close(POLICY, "stalled")),
                )
                .await;
                return;
            }
        }
    }
}

/// Runs a settings change under the control lock, off the async workers (the 1-DOF solve
/// of a physics change takes milliseconds), then brings along what follows the settings:
/// the queue bound, the force estimator, the images and the model-range warnings. `f`
/// returns the paths it changed (`None`: possibly any) and its result.
pub(crate) async fn change<R: Send + 'static>(
    state: &Arc<AppState>,
    f: impl FnOnce(&mut Control) -> Result<(Option<Vec<String>>, R), ProtocolError> + Send + 'static,
) -> Result<R, ProtocolError> {
    let state = state.clone();
    let internal = |m: &str| ProtocolError {
        code: ErrorCode::Internal,
        message: m.to_string(),
    };
    tokio::task::spawn_blocking(move || {
        let mut control = state
            .control
            .lock()
            .map_err(|_| internal("control lock poisoned"))?;
        let (paths, result) = f(&mut control)?;
        state.changes.send_modify(|n| *n += 1);
        let touched = |affects: fn(&str) -> bool| {
            paths
                .as_ref()
                .is_none_or(|paths| paths.iter().any(|p| affects(p)))
        };
        state.queue_bytes.store(
            control.settings.server.client_queue_bytes as usize,
            Ordering::Relaxed,
        );
        if touched(super::force::affects_estimator) {
            state.force.rebuild(control.settings.clone());
        }
        if touched(super::image::affects_images) {
            state.image.configure(&control.settings);
        }
        if touched(affects_physics) {
            let warnings = crate::model::range_warnings(&control.settings);
            if let Ok(mut w) = state.range_warnings.lock() {
                *w = warnings;
            }
        }
        Ok(result)
    })
    .await
    .map_err(|_| internal("the settings task failed"))?
}

/// One request → one reply.
async fn handle(text: &str, state: &Arc<AppState>, client: &ClientHandle) -> Message {
    let reply = match protocol::parse_request(text) {
        Err((id, err)) => protocol::error_reply(&id, &err),
        Ok(Request { id, op }) => match respond(op, state, client).await {
            Ok(fields) => protocol::ok_reply(&id, fields),
            Err(err) => protocol::error_reply(&id, &err),
        },
    };
    Message::Text(reply.into())
}

fn fields(v: Value) -> Map<String, Value> {
    match v {
        Value::Object(m) => m,
        _ => Map::new(),
    }
}

async fn respond(
    op: Op,
    state: &Arc<AppState>,
    client: &ClientHandle,
) -> Result<Map<String, Value>, ProtocolError> {
    let internal = |m: &str| ProtocolError {
        code: ErrorCode::Internal,
        message: m.to_string(),
    };
    match op {
        Op::Hello => Ok(fields(json!({
            "server": "ftafm",
            "version": env!("CARGO_PKG_VERSION"),
            "protocol": protocol::PROTOCOL_VERSION,
            "sample_rate": state.sample_rate,
        }))),
        Op::List { path } => {
            let control = state
                .control
                .lock()
                .map_err(|_| internal("control lock poisoned"))?;
            let nodes = match &path {
                Some(p) => control
                    .settings
                    .list(p)
                    .map_err(|e| ProtocolError::from(&e))?,
                None => control.settings.nodes(),
            };
            Ok(fields(json!({ "nodes": nodes })))
        }
        Op::Get { path } if super::measured::is_measured(&path) => {
            let value = super::measured::read(state, &path)?;
            Ok(fields(json!({ "path": path, "value": value })))
        }
        Op::Get { path } => {
            let control = state
                .control
                .lock()
                .map_err(|_| internal("control lock poisoned"))?;
            let value = control
                .settings
                .get(&path)
                .map_err(|e| ProtocolError::from(&e))?;
            let mut reply = json!({ "path": path, "value": value });
            if let Some(warning) = control.settings.node_warning(&path) {
                reply["warning"] = Value::from(warning);
            }
            Ok(fields(reply))
        }
        Op::Set { path, value } => {
            let (path, applied, t) = change(state, move |control| {
                let (applied, t) = control.set(&path, &value)?;
                Ok((Some(vec![path.clone()]), (path, applied, t)))
            })
            .await?;
            Ok(fields(json!({ "path": path, "value": applied, "t": t })))
        }
        Op::SetMany { values } => {
            let (applied, t) = change(state, move |control| {
                let (applied, t) = control.set_many(&values)?;
                let paths: Vec<String> = values.iter().map(|(p, _)| p.clone()).collect();
                let applied: Map<String, Value> = paths.iter().cloned().zip(applied).collect();
                Ok((Some(paths), (applied, t)))
            })
            .await?;
            Ok(fields(json!({ "values": applied, "t": t })))
        }
        Op::Settings => {
            let control = state
                .control
                .lock()
                .map_err(|_| internal("control lock poisoned"))?;
            let toml = crate::config::settings_toml(&control.settings).map_err(|e| internal(&e))?;
            Ok(fields(json!({ "toml": toml })))
        }
        Op::LoadSettings { toml } => {
            change(state, move |control| {
                let next = crate::config::overlay_str(control.settings.clone(), &toml, "settings")
                    .map_err(|e| ProtocolError {
                        code: ErrorCode::InvalidValue,
                        message: e.to_string(),
                    })?;
                if next.synth.sample_rate != control.settings.synth.sample_rate {
                    return Err(ProtocolError {
                        code: ErrorCode::ReadOnly,
                        message: format!(
                            "/synth/sample_rate is read-only at runtime: these settings have {} \
                             Hz, the instrument runs at {} Hz; start the daemon with them \
                             (ftafm --config FILE) instead",
                            next.synth.sample_rate, control.settings.synth.sample_rate
                        ),
                    });
                }
                let t = control.replace(next, "settings")?;
                Ok((
                    None,
                    fields(json!({ "t": t, "warnings": control.settings.warnings() })),
                ))
            })
            .await
        }
        Op::Presets => Ok(fields(json!({ "presets": crate::config::PRESETS
            .iter()
            .map(|p| json!({ "name": p.name, "kind": p.kind, "summary": p.summary() }))
            .collect::<Vec<_>>() }))),
        Op::Preset { name } => {
            change(state, move |control| {
                let preset = crate::config::preset(&name).map_err(|e| ProtocolError {
                    code: ErrorCode::InvalidValue,
                    message: e.to_string(),
                })?;
                let origin = format!("preset {}", preset.name);
                let next =
                    crate::config::overlay_str(control.settings.clone(), preset.toml, &origin)
                        .map_err(|e| ProtocolError {
                            code: ErrorCode::InvalidValue,
                            message: e.to_string(),
                        })?;
                let t = control.replace(next, &origin)?;
                Ok((
                    None,
                    fields(json!({
                        "preset": preset.name,
                        "kind": preset.kind,
                        "t": t,
                        "warnings": control.settings.warnings(),
                    })),
                ))
            })
            .await
        }
        Op::Subscribe {
            stream,
            format,
            every,
            batch,
        } => {
            if stream == StreamKind::Demods {
                // Points gathered under the old subscription go out first, in its layout.
                if let Ok(mut pending) = client.pending.lock() {
                    let max_bytes = state.queue_bytes.load(Ordering::Relaxed);
                    super::hub::flush_batch(state, client, &mut pending, max_bytes);
                    client.subscribe(stream, format, every, batch);
                }
            } else if stream == StreamKind::Force {
                // The worker fits only what some client takes: this one's estimates begin
                // where the stride that counts it does.
                client.set_force_from(u64::MAX);
                client.subscribe(stream, format, every, batch);
                let from = state.update_force_stride();
                client.set_force_from(from);
            } else {
                client.subscribe(stream, format, every, batch);
            }
            let next_seq = if stream == StreamKind::Force {
                client.force_from()
            } else {
                state.streams[super::state::stream_index(stream)]
                    .produced
                    .load(Ordering::Relaxed)
            };
            Ok(fields(json!({
                "stream": stream.name(),
                "next_seq": next_seq,
                "every": every,
                "batch": batch,
            })))
        }
        Op::Unsubscribe { stream } => {
            if stream == StreamKind::Demods {
                if let Ok(mut pending) = client.pending.lock() {
                    let max_bytes = state.queue_bytes.load(Ordering::Relaxed);
                    super::hub::flush_batch(state, client, &mut pending, max_bytes);
                    client.unsubscribe(stream);
                }
            } else {
                client.unsubscribe(stream);
                if stream == StreamKind::Force {
                    state.update_force_stride();
                }
            }
            Ok(fields(json!({ "stream": stream.name() })))
        }
    }
}
