//! One WebSocket connection: requests in, exactly one reply each; data messages out. What
//! a request does is its op's (`protocol::ops`); the session is the transport: the socket,
//! the queues, the rate limit and the bookkeeping of the client's subscriptions.
//!
//! Replies and data share the socket through a writer task that sends replies first. A
//! peer that accepts nothing for `/server/stall_timeout` is disconnected (1008 "stalled");
//! one that sends nothing for the ping interval is pinged, and disconnected (1008 "no pong")
//! if nothing at all comes back within `/server/stall_timeout`. A peer's close frame is
//! answered at once, ahead of the data still queued for it. At shutdown every client gets a
//! close frame (1001).

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket};
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use tokio::sync::mpsc;

use super::protocol::ops::{Context, Subscribe, Subscriptions};
use super::protocol::{self, ErrorCode, ProtocolError, Request, StreamKind};
use super::state::{AppState, ClientHandle, DataQueue, DataReceiver, ReplyHold};
use crate::pipeline::unix_ns;

/// Requests a client may make per second on average, and in a burst.
const REQUESTS_PER_SECOND: f64 = 200.0;
const REQUEST_BURST: f64 = 400.0;
/// Close codes.
const GOING_AWAY: u16 = 1001;
const POLICY: u16 = 1008;
const TOO_BIG: u16 = 1009;
/// Longest the answer to a peer's close frame waits for the socket. It goes after what the
/// socket already holds and the one message being sent (never after the data still
/// queued), which a peer that closed and then stopped reading never takes; a peer that
/// reads, on a machine busy with other work, takes it well within this.
const CLOSE_ANSWER_WAIT: Duration = Duration::from_secs(5);
/// Longest a close frame the server starts (a peer that answered no ping) waits for the
/// socket: a silent peer's socket may be full, and its slot must free either way.
const CLOSE_WAIT: Duration = Duration::from_millis(200);

fn close(code: u16, reason: &'static str) -> Message {
    Message::Close(Some(CloseFrame {
        code,
        reason: Utf8Bytes::from_static(reason),
    }))
}

/// What the reader asks of the writer ahead of replies and data, even while a send waits on
/// a full socket.
enum Urgent {
    /// Send a keep-alive ping.
    Ping,
    /// The peer sent a close frame: answer it and end the connection.
    AnswerClose,
    /// End the connection with this close frame.
    Close(Message),
}

/// A message for the reply channel: a reply with its share of the client's reply bytes
/// (none for a close frame).
type Reply = (Message, Option<ReplyHold>);

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
    let (reply_tx, reply_rx) = mpsc::channel::<Reply>(64);
    // At most one ping is outstanding and the reader stops after a close, so this channel
    // holds a message or two.
    let (urgent_tx, urgent_rx) = mpsc::unbounded_channel::<Urgent>();
    let stall = stall_timeout(&state);
    let mut writer = tokio::spawn(write(
        sink,
        urgent_rx,
        reply_rx,
        data_rx,
        state.clone(),
        client.clone(),
        stall,
    ));

    let mut limit = RateLimit::new();
    let mut writer_done = false;
    // The keep-alive: when the peer last sent anything, and when it was pinged since. A
    // peer that answers no ping for the stall timeout is as dead as one whose socket takes
    // nothing for it (a half-open connection, or one that never reads).
    let mut heard = Instant::now();
    let mut pinged: Option<Instant> = None;
    loop {
        let wake = match pinged {
            Some(at) => at + stall,
            None => heard + state.ping_interval,
        };
        // The writer ends when the peer stalls (or on shutdown): then the connection is
        // dropped at once, whether or not the peer sends anything, so its slot frees and a
        // peer that resumes reading finds the connection closed, not a silent gap.
        let incoming = tokio::select! {
            // What the peer sent counts before the keep-alive's verdict.
            biased;
            m = stream.next() => match m {
                Some(m) => m,
                None => break,
            },
            _ = &mut writer => {
                writer_done = true;
                break;
            }
            _ = tokio::time::sleep_until(wake.into()) => {
                if pinged.is_none() {
                    let _ = urgent_tx.send(Urgent::Ping);
                    pinged = Some(Instant::now());
                    continue;
                }
                state.closed_unresponsive.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    client = id,
                    stall_timeout_s = stall.as_secs_f64(),
                    "closing a client that answered no ping within /server/stall_timeout"
                );
                let _ = urgent_tx.send(Urgent::Close(close(POLICY, "no pong")));
                break;
            }
        };
        // Any frame, a pong or a request, shows the peer is there.
        heard = Instant::now();
        pinged = None;
        let reply = match incoming {
            Ok(Message::Text(text)) if text.len() > protocol::MAX_MESSAGE_BYTES => {
                let _ = reply_tx
                    .send((close(TOO_BIG, "message too big (limit 64 KiB)"), None))
                    .await;
                break;
            }
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
            // Frames of samples for a streamed source: no rate limit (their pace is the
            // stream's; a full feed drops them, counted), one reply each.
            Ok(Message::Binary(bytes)) => Message::Text(stream_frame(&bytes, &state, id).into()),
            Ok(Message::Close(_)) => {
                // The library has queued the answer, echoing the peer's code; the writer
                // sends it ahead of the data and replies still queued, then the session ends.
                let _ = urgent_tx.send(Urgent::AnswerClose);
                break;
            }
            Ok(_) => continue, // pings are answered by the library; pongs only count as heard
            Err(e) => {
                let too_big = e.to_string().to_lowercase().contains("too long")
                    || e.to_string().to_lowercase().contains("too big")
                    || e.to_string().to_lowercase().contains("capacity");
                if too_big {
                    let _ = reply_tx
                        .send((close(TOO_BIG, "message too big (limit 64 KiB)"), None))
                        .await;
                }
                tracing::debug!(client = id, error = %e, "receive failed");
                break;
            }
        };
        if !send_reply(&reply_tx, reply, &state, &client).await {
            break; // the writer ended (stalled peer or shutdown)
        }
    }
    drop(reply_tx);
    state.inlet.release(id);
    if let Ok(mut clients) = state.clients.lock() {
        clients.retain(|c| c.id != id);
    }
    // The force worker may skip again what this client took.
    state.update_force_stride();
    // Let the writer flush a final close frame, but not forever.
    if !writer_done {
        let _ = tokio::time::timeout(CLOSE_ANSWER_WAIT, writer).await;
    }
    drop(stream);
    tracing::debug!(
        client = id,
        dropped = client.dropped.load(Ordering::Relaxed),
        "disconnected"
    );
}

/// Takes a binary frame of samples from client `client` into the streamed source; the
/// reply names the frame by the id in its header (null if the header is unreadable) and
/// says what became of its samples (docs/protocol.md, "Streaming samples in").
fn stream_frame(bytes: &[u8], state: &AppState, client: u64) -> String {
    use crate::pipeline::FrameError;
    match state.inlet.push_frame(client, bytes) {
        Ok((header, receipt)) => {
            let mut fields = serde_json::Map::new();
            if let Ok(Value::Object(r)) = serde_json::to_value(receipt) {
                fields.extend(r);
            }
            protocol::ok_reply(&Value::from(header.id), fields)
        }
        Err(e) => {
            // The id, where the header got that far.
            let id = bytes
                .get(8..16)
                .filter(|_| bytes.starts_with(&crate::pipeline::FRAME_MAGIC))
                .and_then(|b| b.try_into().ok())
                .map_or(Value::Null, |b| Value::from(u64::from_le_bytes(b)));
            let code = match e {
                FrameError::Malformed(_) => ErrorCode::BadRequest,
                FrameError::Refused(_) => ErrorCode::InvalidValue,
            };
            protocol::error_reply(&id, &ProtocolError::new(code, e.to_string()))
        }
    }
}

/// Hands `reply` to the writer once the client's replies fit under
/// `/server/client_queue_bytes` (waiting holds back its next request: replies are never
/// dropped, so a client that does not read them is bounded by not being served). False if
/// the writer has ended.
async fn send_reply(
    replies: &mpsc::Sender<Reply>,
    reply: Message,
    state: &AppState,
    client: &ClientHandle,
) -> bool {
    let size = match &reply {
        Message::Text(text) => text.len(),
        _ => 0,
    };
    let max_bytes = state.queue_bytes.load(Ordering::Relaxed);
    // The writer releases the bytes as it sends; if it ends, the replies it held are
    // dropped and released too, so this wait ends either way.
    let hold = client.replies.admit(size, max_bytes).await;
    replies.send((reply, Some(hold))).await.is_ok()
}

fn stall_timeout(state: &AppState) -> Duration {
    let seconds = state.control.settings().server.stall_timeout;
    Duration::from_secs_f64(seconds)
}

/// Sends replies (first) and data until the peer stalls, the session ends or the server
/// shuts down; what the reader asks (a ping, the answer to the peer's close, a close of
/// ours) goes ahead of both, even while a send waits on the socket. Each data message
/// handed to the socket is counted and its latency recorded on `client`.
async fn write(
    mut sink: SplitSink<WebSocket, Message>,
    mut urgent: mpsc::UnboundedReceiver<Urgent>,
    mut replies: mpsc::Receiver<Reply>,
    mut data: DataReceiver,
    state: Arc<AppState>,
    client: Arc<ClientHandle>,
    stall: Duration,
) {
    let mut shutdown = state.shutdown.clone();
    // A ping asked for while a send waited on the socket: it goes next.
    let mut ping_due = false;
    loop {
        let (msg, stamps, hold) = if std::mem::take(&mut ping_due) {
            (Message::Ping(Default::default()), None, None)
        } else {
            tokio::select! {
                biased;
                _ = shutdown.changed() => {
                    let _ = tokio::time::timeout(Duration::from_millis(500), sink.send(close(GOING_AWAY, "server shutting down"))).await;
                    return;
                }
                Some(u) = urgent.recv() => match u {
                    Urgent::Ping => (Message::Ping(Default::default()), None, None),
                    end => {
                        finish(&mut sink, end).await;
                        return;
                    }
                },
                r = replies.recv() => match r {
                    Some((m, hold)) => (m, None, hold),
                    None => return,
                },
                Some(o) = data.recv() => (o.msg, Some(o.stamps), None),
            }
        };
        let closing = matches!(msg, Message::Close(_));
        // A send waits while the socket is full. The send in flight is finished (a frame
        // cut short would break the stream), but what the reader asks meanwhile is noted:
        // the answer to the peer's close goes right after it, ahead of the data and
        // replies queued behind it.
        let mut end = None;
        let sent = {
            let send = tokio::time::timeout(stall, sink.send(msg));
            tokio::pin!(send);
            loop {
                tokio::select! {
                    biased;
                    r = &mut send => break r,
                    // A peer whose socket takes nothing must not hold up the shutdown for
                    // its stall timeout: the connection is dropped as it stands.
                    _ = shutdown.changed() => return,
                    Some(u) = urgent.recv(), if end.is_none() => match u {
                        Urgent::Ping => ping_due = true,
                        other => end = Some(other),
                    },
                }
            }
        };
        // A reply's bytes leave the client's count once the socket has taken it.
        drop(hold);
        if let Some(end) = end {
            // Also where the send failed: a send the reader overtook with the peer's close
            // fails (the library refuses data after it), and the answer it queued must
            // still go out. Not where the socket took nothing for the stall timeout.
            if sent.is_ok() {
                finish(&mut sink, end).await;
            }
            return;
        }
        if let (Ok(Ok(())), Some(stamps)) = (&sent, stamps) {
            client.written(&state, stamps, unix_ns());
        }
        match sent {
            Ok(Ok(())) if !closing => {}
            Ok(Ok(())) => return,
            Ok(Err(_)) => {
                // The reader may have read the peer's close while this send waited (the
                // library then refuses data and queues its answer), before it could say so:
                // flush that answer, bounded, rather than drop the connection without it (the
                // peer saw "reset without closing handshake"). On a broken socket this ends
                // at once.
                let _ = tokio::time::timeout(CLOSE_ANSWER_WAIT, sink.close()).await;
                return;
            }
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

/// Ends the connection as the reader asked, each way bounded (the socket may be full).
async fn finish(sink: &mut SplitSink<WebSocket, Message>, end: Urgent) {
    match end {
        // The library queued the answer when it read the peer's close; closing the sink
        // writes it out (after what the socket already holds) and ends the connection.
        Urgent::AnswerClose => {
            let _ = tokio::time::timeout(CLOSE_ANSWER_WAIT, sink.close()).await;
        }
        Urgent::Close(frame) => {
            let _ = tokio::time::timeout(CLOSE_WAIT, sink.send(frame)).await;
        }
        Urgent::Ping => {}
    }
}

/// One request → one reply: the op parsed, then carried out against a context holding
/// what ops need (the control plane, the newest demodulator output, this client's
/// subscriptions).
async fn handle(text: &str, state: &Arc<AppState>, client: &ClientHandle) -> Message {
    let reply = match protocol::parse_request(text) {
        Err((id, err)) => protocol::error_reply(&id, &err),
        Ok(Request { id, op }) => {
            let subscriptions = ClientStreams { state, client };
            let ctx = Context {
                control: &state.control,
                sample_rate: state.sample_rate,
                latest_demods: &state.latest_demods,
                subscriptions: &subscriptions,
            };
            match op.apply(&ctx).await {
                Ok(fields) => protocol::ok_reply(&id, fields),
                Err(err) => protocol::error_reply(&id, &err),
            }
        }
    };
    Message::Text(reply.into())
}

/// A client's subscriptions, kept on its handle, and what goes with them: the `demods`
/// points it has gathered go out (in the old layout) before its subscription changes, and
/// the force worker fits what its subscribers take.
struct ClientStreams<'a> {
    state: &'a AppState,
    client: &'a ClientHandle,
}

impl Subscriptions for ClientStreams<'_> {
    fn subscribe(&self, subscription: Subscribe) -> u64 {
        let Self { state, client } = *self;
        let Subscribe {
            stream,
            format,
            every,
            batch,
        } = subscription;
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
        if stream == StreamKind::Force {
            client.force_from()
        } else {
            state.streams[super::state::stream_index(stream)]
                .produced
                .load(Ordering::Relaxed)
        }
    }

    fn unsubscribe(&self, stream: StreamKind) {
        let Self { state, client } = *self;
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
    }
}
