//! What every part of the server shares: the control plane (settings and pipeline), the
//! client registry with per-stream statistics, and the shutdown signal.

use std::sync::atomic::{AtomicU8, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::ws::Message;
use hdrhistogram::Histogram;
use tokio::sync::mpsc::error::TrySendError;
use tokio::sync::{mpsc, watch};

use super::latency::Latency;
use super::protocol::{Format, StreamKind};
use super::status::{ClientReport, LatencySummary, ProcessMemory, StatusReport};
use crate::instrument::Control;

/// Streams in the order of [`StreamKind::ALL`]; indexes per-stream arrays.
pub(crate) const STREAMS: usize = 9;

pub(crate) fn stream_index(s: StreamKind) -> usize {
    match s {
        StreamKind::Demods => 0,
        StreamKind::Spectrum => 1,
        StreamKind::Scope => 2,
        StreamKind::Status => 3,
        StreamKind::Force => 4,
        StreamKind::Image => 5,
        StreamKind::Sweep => 6,
        StreamKind::Bimodal => 7,
        StreamKind::Pids => 8,
    }
}

/// When a data message's newest sample was synthesised and when the DSP finished its frame
/// (Unix ns, 0 = unknown), and its stream: what the latency at the socket is measured from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Stamps {
    /// Index of the stream ([`stream_index`]), if known.
    pub stream: Option<usize>,
    /// Unix time (ns) at which the newest sample was synthesised.
    pub t_synth_ns: u64,
    /// Unix time (ns) at which the DSP finished the frame.
    pub t_dsp_ns: u64,
}

/// A client's batched `demods` message being gathered (see [`ClientHandle::pending`]).
#[derive(Debug, Default)]
pub(crate) struct PendingBatch {
    pub batch: super::protocol::DemodBatch,
    /// When its first point was offered.
    pub since: Option<Instant>,
    /// Its newest point's stamps.
    pub stamps: Stamps,
}

/// A data message queued for one client, with its stamps and size.
pub(crate) struct Outgoing {
    pub msg: Message,
    pub stamps: Stamps,
    /// Payload bytes, counted against the queue's byte bound until the writer takes it.
    size: usize,
}

/// The payload bytes of a data message.
fn payload_bytes(msg: &Message) -> usize {
    match msg {
        Message::Text(t) => t.len(),
        Message::Binary(b) => b.len(),
        _ => 0,
    }
}

/// Messages the lane of a client holds: scan lines (a 1024-line frame), status, sweep points
/// and force estimates of a paced (`every` > 1) subscription; its bytes have a bound of
/// their own, the queue's.
const LANE: usize = 4096;

/// A client's queue of data messages, bounded in messages and in bytes (a slow client loses
/// its own, never anyone else's and never the pipeline's), and beside it a lane for the
/// small, rare messages that must not be lost behind bulk data: scan lines and status.
pub(crate) struct DataQueue {
    tx: mpsc::Sender<Outgoing>,
    lane: mpsc::Sender<Outgoing>,
    bytes: Arc<AtomicUsize>,
    /// The lane's share of `bytes`.
    lane_bytes: Arc<AtomicUsize>,
}

/// The writer's end of a [`DataQueue`].
pub(crate) struct DataReceiver {
    rx: mpsc::Receiver<Outgoing>,
    lane: mpsc::Receiver<Outgoing>,
    bytes: Arc<AtomicUsize>,
    lane_bytes: Arc<AtomicUsize>,
}

impl DataReceiver {
    /// The next message, the lane's first; its bytes leave the queue's count.
    pub async fn recv(&mut self) -> Option<Outgoing> {
        let o = tokio::select! {
            biased;
            Some(o) = self.lane.recv() => {
                self.lane_bytes.fetch_sub(o.size, Ordering::Relaxed);
                o
            }
            Some(o) = self.rx.recv() => o,
            else => return None,
        };
        self.bytes.fetch_sub(o.size, Ordering::Relaxed);
        Some(o)
    }
}

impl DataQueue {
    /// A queue of `capacity` messages, its lane, and their receiving end (the session's
    /// writer).
    pub fn new(capacity: usize) -> (Self, DataReceiver) {
        let (tx, rx) = mpsc::channel(capacity);
        let (lane_tx, lane_rx) = mpsc::channel(LANE);
        let bytes = Arc::new(AtomicUsize::new(0));
        let lane_bytes = Arc::new(AtomicUsize::new(0));
        (
            Self {
                tx,
                lane: lane_tx,
                bytes: bytes.clone(),
                lane_bytes: lane_bytes.clone(),
            },
            DataReceiver {
                rx,
                lane: lane_rx,
                bytes,
                lane_bytes,
            },
        )
    }

    /// Bytes queued now.
    pub fn queued_bytes(&self) -> usize {
        self.bytes.load(Ordering::Relaxed)
    }

    /// Queues `msg` with `stamps` without waiting. A full queue refuses it: all its
    /// messages, or `max_bytes` (unless the queue is empty, so one message larger than the
    /// bound still goes). Messages for the `lane` (scan lines, status, sweep points, paced
    /// force estimates) bypass the bulk's bounds and have their own: [`LANE`] messages and
    /// `max_bytes`, so they never starve behind spectra.
    pub fn offer(
        &self,
        msg: Message,
        stamps: Stamps,
        max_bytes: usize,
        lane: bool,
    ) -> Result<(), TrySendError<Message>> {
        let size = payload_bytes(&msg);
        let queued = if lane {
            self.lane_bytes.load(Ordering::Relaxed)
        } else {
            self.bytes.load(Ordering::Relaxed)
        };
        if queued > 0 && queued.saturating_add(size) > max_bytes {
            return Err(TrySendError::Full(msg));
        }
        self.bytes.fetch_add(size, Ordering::Relaxed);
        if lane {
            self.lane_bytes.fetch_add(size, Ordering::Relaxed);
        }
        let queue = if lane { &self.lane } else { &self.tx };
        queue.try_send(Outgoing { msg, stamps, size }).map_err(|e| {
            self.bytes.fetch_sub(size, Ordering::Relaxed);
            if lane {
                self.lane_bytes.fetch_sub(size, Ordering::Relaxed);
            }
            match e {
                TrySendError::Full(o) => TrySendError::Full(o.msg),
                TrySendError::Closed(o) => TrySendError::Closed(o.msg),
            }
        })
    }
}

/// The bytes of a client's replies held by the server: made, not yet handed to its socket.
/// Replies are never dropped, so they are bounded by holding back the client's requests:
/// its session reads the next request only once the replies it holds fit under
/// `/server/client_queue_bytes` (a bound of their own, beside the data queue's), so a
/// client that sends requests and reads nothing costs that bound and one reply, not what
/// its requests would make.
#[derive(Debug, Default)]
pub(crate) struct ReplyBytes {
    held: AtomicUsize,
    freed: tokio::sync::Notify,
}

impl ReplyBytes {
    /// Bytes held now.
    pub fn held(&self) -> usize {
        self.held.load(Ordering::Relaxed)
    }

    /// Waits until a reply of `size` bytes fits under `max_bytes` (one larger reply goes
    /// when none is held, so nothing waits for ever), then counts it; the bytes leave the
    /// count when the returned hold is dropped. One task (the session's reader) admits.
    pub async fn admit(self: &Arc<Self>, size: usize, max_bytes: usize) -> ReplyHold {
        loop {
            // Registered before the check, so a release between the two is not missed.
            let freed = self.freed.notified();
            tokio::pin!(freed);
            freed.as_mut().enable();
            let held = self.held();
            if held == 0 || held.saturating_add(size) <= max_bytes {
                self.held.fetch_add(size, Ordering::Relaxed);
                return ReplyHold {
                    bytes: size,
                    owner: self.clone(),
                };
            }
            freed.await;
        }
    }
}

/// A reply's share of [`ReplyBytes`], released when dropped: when the writer has handed the
/// reply to the socket, or when the session ends with it unsent.
#[derive(Debug)]
pub(crate) struct ReplyHold {
    bytes: usize,
    owner: Arc<ReplyBytes>,
}

impl Drop for ReplyHold {
    fn drop(&mut self) {
        self.owner.held.fetch_sub(self.bytes, Ordering::Relaxed);
        self.owner.freed.notify_waiters();
    }
}

/// Latency at the socket of one client's demodulator messages (ns): 1 µs resolution,
/// two significant digits, so a client costs little memory.
pub(crate) struct ClientLatency {
    pub dsp_to_socket: Histogram<u32>,
    pub synth_to_socket: Histogram<u32>,
}

impl ClientLatency {
    fn new() -> Self {
        let h = || {
            Histogram::new_with_bounds(1_000, super::latency::MAX_NS, 2)
                .expect("static bounds are valid")
        };
        Self {
            dsp_to_socket: h(),
            synth_to_socket: h(),
        }
    }
}

/// One connected WebSocket client as the fan-out sees it.
pub(crate) struct ClientHandle {
    pub id: u64,
    /// Per stream: 0 = not subscribed, 1 = JSON, 2 = binary.
    subs: [AtomicU8; STREAMS],
    /// Per stream: deliver only messages whose seq is a multiple of this (0 or 1: all).
    every: [AtomicU32; STREAMS],
    /// Time points per `demods` message (0 or 1: one per message; more only in binary).
    batch: AtomicU32,
    /// See [`Self::force_from`].
    force_from: AtomicU64,
    /// The batched `demods` message being gathered, and when its first point came and the
    /// stamps of its newest. Held while points are added and while the subscription
    /// changes, so that a change sends what was gathered under the old one first.
    pub pending: Mutex<PendingBatch>,
    /// Data messages for this client (bounded: a slow client loses its own).
    pub data: DataQueue,
    /// This client's replies not yet handed to its socket (bounded by holding back its
    /// requests).
    pub replies: Arc<ReplyBytes>,
    /// Messages dropped for this client.
    pub dropped: AtomicU64,
    /// Data messages handed to this client's socket.
    pub written: AtomicU64,
    /// Latency at this client's socket; allocated with its first demodulator message.
    latency: Mutex<Option<Box<ClientLatency>>>,
}

impl ClientHandle {
    pub fn new(id: u64, data: DataQueue) -> Self {
        Self {
            id,
            subs: Default::default(),
            every: Default::default(),
            batch: AtomicU32::new(1),
            force_from: AtomicU64::new(0),
            pending: Mutex::default(),
            data,
            replies: Arc::default(),
            dropped: AtomicU64::new(0),
            written: AtomicU64::new(0),
            latency: Mutex::new(None),
        }
    }

    /// Records that a message stamped `stamps` was handed to this client's socket at
    /// `now_ns`: the client's and the stream's latency at the socket.
    pub fn written(&self, state: &AppState, stamps: Stamps, now_ns: u64) {
        self.written.fetch_add(1, Ordering::Relaxed);
        let Some(stream) = stamps.stream else {
            return;
        };
        let since = |t: u64| (t != 0).then(|| now_ns as i64 - t as i64);
        let (synth, dsp) = (since(stamps.t_synth_ns), since(stamps.t_dsp_ns));
        if synth.is_none() && dsp.is_none() {
            return;
        }
        if let Some(s) = state.streams.get(stream) {
            s.socket_latency(synth, dsp);
        }
        if stream != stream_index(StreamKind::Demods) {
            return;
        }
        let record = |h: &mut Histogram<u32>, ns: Option<i64>| {
            if let Some(ns) = ns {
                h.saturating_record((ns.max(1) as u64).min(super::latency::MAX_NS));
            }
        };
        if let Ok(mut l) = self.latency.lock() {
            let l = l.get_or_insert_with(|| Box::new(ClientLatency::new()));
            record(&mut l.synth_to_socket, synth);
            record(&mut l.dsp_to_socket, dsp);
        }
    }

    /// This client's figures now.
    pub fn report(&self) -> ClientReport {
        let (dsp_to_socket, synth_to_socket) = match self.latency.lock().as_deref() {
            Ok(Some(l)) => (
                LatencySummary::from_histogram(&l.dsp_to_socket),
                LatencySummary::from_histogram(&l.synth_to_socket),
            ),
            _ => Default::default(),
        };
        ClientReport {
            id: self.id,
            written: self.written.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            queued_bytes: (self.data.queued_bytes() + self.replies.held()) as u64,
            dsp_to_socket,
            synth_to_socket,
        }
    }

    /// Receive `stream` in `format`, only the messages whose seq is a multiple of `every`,
    /// `batch` time points a message (`demods` in binary only). Call with
    /// [`Self::pending`] held and flushed, so no point gathered before changes its batch.
    pub fn subscribe(&self, stream: StreamKind, format: Format, every: u32, batch: u32) {
        let v = match format {
            Format::Json => 1,
            Format::Binary => 2,
        };
        if stream == StreamKind::Demods {
            self.batch.store(batch.max(1), Ordering::Relaxed);
        }
        self.every[stream_index(stream)].store(every.max(1), Ordering::Relaxed);
        self.subs[stream_index(stream)].store(v, Ordering::Relaxed);
    }

    /// The `every` of this client's subscription to `stream` (1: every message).
    pub fn every(&self, stream: usize) -> u32 {
        self.every[stream].load(Ordering::Relaxed).max(1)
    }

    /// The first `seq` of the `force` stream this client takes (its subscription began
    /// there; `u64::MAX` while it is being made).
    pub fn force_from(&self) -> u64 {
        self.force_from.load(Ordering::SeqCst)
    }

    pub fn set_force_from(&self, seq: u64) {
        self.force_from.store(seq, Ordering::SeqCst);
    }

    /// Time points per `demods` message (1: unbatched).
    pub fn batch(&self) -> u32 {
        self.batch.load(Ordering::Relaxed).max(1)
    }

    /// Whether this client's subscription to `stream` is paced (`every` > 1).
    pub fn paced(&self, stream: usize) -> bool {
        self.every[stream].load(Ordering::Relaxed) > 1
    }

    /// Whether this client takes message `seq` of stream `stream` (by its `every`).
    pub fn takes(&self, stream: usize, seq: u64) -> bool {
        let every = u64::from(self.every[stream].load(Ordering::Relaxed).max(1));
        seq.is_multiple_of(every)
    }

    pub fn unsubscribe(&self, stream: StreamKind) {
        self.subs[stream_index(stream)].store(0, Ordering::Relaxed);
    }

    pub fn format(&self, stream: usize) -> Option<Format> {
        match self.subs[stream].load(Ordering::Relaxed) {
            1 => Some(Format::Json),
            2 => Some(Format::Binary),
            _ => None,
        }
    }
}

/// Per-stream message statistics.
#[derive(Default)]
pub(crate) struct StreamStats {
    /// Messages produced (the stream's seq counter).
    pub produced: AtomicU64,
    /// Messages queued to clients.
    pub sent: AtomicU64,
    /// Messages dropped for slow clients.
    pub dropped: AtomicU64,
    /// Latency of the stream's messages when handed to a client's socket, all clients;
    /// allocated with the first stamped message.
    socket: Mutex<Option<Box<SocketLatency>>>,
}

/// synth → socket and DSP → socket of one stream, all clients (interval and since start).
pub(crate) struct SocketLatency {
    pub synth_to_socket: Latency,
    pub dsp_to_socket: Latency,
}

impl StreamStats {
    fn socket_latency(&self, synth_ns: Option<i64>, dsp_ns: Option<i64>) {
        if let Ok(mut s) = self.socket.lock() {
            let s = s.get_or_insert_with(|| {
                Box::new(SocketLatency {
                    synth_to_socket: Latency::new(),
                    dsp_to_socket: Latency::new(),
                })
            });
            if let Some(ns) = synth_ns {
                s.synth_to_socket.record(ns);
            }
            if let Some(ns) = dsp_ns {
                s.dsp_to_socket.record(ns);
            }
        }
    }

    /// (synth → socket, DSP → socket) since the last call, all clients; the interval then
    /// starts afresh.
    pub fn take_socket_interval(&self) -> (LatencySummary, LatencySummary) {
        match self.socket.lock().as_deref_mut() {
            Ok(Some(s)) => (
                s.synth_to_socket.take_interval(),
                s.dsp_to_socket.take_interval(),
            ),
            _ => Default::default(),
        }
    }

    /// (synth → socket, DSP → socket) since start, all clients.
    pub fn socket_totals(&self) -> (LatencySummary, LatencySummary) {
        match self.socket.lock().as_deref() {
            Ok(Some(s)) => (s.synth_to_socket.total(), s.dsp_to_socket.total()),
            _ => Default::default(),
        }
    }
}

/// Shared by the router, the sessions and the hub.
pub(crate) struct AppState {
    /// The settings, their epoch and their one writer.
    pub control: Arc<Control>,
    pub clients: Mutex<Vec<Arc<ClientHandle>>>,
    /// WebSocket connections holding a slot: reserved at the handshake, released when the
    /// session ends, so handshakes in flight count against `/server/max_clients`.
    pub connections: std::sync::atomic::AtomicUsize,
    pub next_client: AtomicU64,
    pub streams: [StreamStats; STREAMS],
    pub shutdown: watch::Receiver<bool>,
    pub sample_rate: f64,
    pub started: Instant,
    /// Connections refused (origin, capacity) and closed for misbehaviour.
    pub refused_origin: AtomicU64,
    pub refused_capacity: AtomicU64,
    pub closed_stalled: AtomicU64,
    /// Connections closed because nothing came back within `/server/stall_timeout` of a
    /// keep-alive ping (half-open, or a peer that reads nothing).
    pub closed_unresponsive: AtomicU64,
    /// How long a WebSocket may send nothing before the server pings it
    /// ([`super::listen::ConnectionLimits::ping_interval`]).
    pub ping_interval: std::time::Duration,
    /// Requests refused for their `Host` (not a name of this server, or none).
    pub refused_host: AtomicU64,
    /// `/server/client_queue_bytes`, for the fan-out (which must not take the settings lock
    /// per message).
    pub queue_bytes: AtomicUsize,
    /// The accept loop's counters (open HTTP connections, dropped ones by reason).
    pub http: Arc<super::listen::ConnectionCounters>,
    /// Latency summaries since start (ns), refreshed by the hub for `/metrics`.
    pub latency_totals: Mutex<[super::status::LatencySummary; 2]>,
    /// The `force` stream's worker.
    pub force: Arc<crate::instrument::force::ForceLink>,
    /// The newest demodulator frame, for reads of measured values (`/demods/N/sample`).
    pub latest_demods: Mutex<Option<crate::pipeline::DemodFrame>>,
    /// Demodulator frames for a running sweep (the hub forwards them while one runs).
    pub sweep_frames: Arc<crate::instrument::tap::FrameTap>,
    /// The force worker's outcomes handed to a running sweep.
    pub sweep_force: Arc<crate::instrument::tap::Tap<crate::instrument::force::ForceOutcome>>,
    pub image: crate::instrument::image::ImageLink,
    /// The machine's stalls, measured beside the server (None if its thread would not
    /// start; the daemon runs without it).
    pub stall: Option<crate::pipeline::StallMeter>,
    /// Where a client's binary frames of samples go (`/source/kind = "stream"`).
    pub inlet: Arc<crate::pipeline::SampleInlet>,
}

impl AppState {
    pub fn client_count(&self) -> usize {
        self.clients.lock().map(|c| c.len()).unwrap_or(0)
    }

    /// Whether any client is subscribed to `stream`.
    /// Tells the force worker which windows to fit: the greatest common divisor of the
    /// `every` of the clients subscribed to `force`, 1 while a sweep takes the estimates.
    /// Returns the seq of the worker's next window (see [`ForceLink::set_stride`]).
    ///
    /// [`ForceLink::set_stride`]: crate::instrument::force::ForceLink::set_stride
    pub fn update_force_stride(&self) -> u64 {
        let s = stream_index(StreamKind::Force);
        let mut stride = 0u32;
        if let Ok(clients) = self.clients.lock() {
            for c in clients.iter().filter(|c| c.format(s).is_some()) {
                stride = gcd(stride, c.every(s));
            }
        }
        if self.sweep_force.is_active() || stride == 0 {
            stride = 1;
        }
        self.force.set_stride(stride)
    }

    pub fn subscribed(&self, stream: StreamKind) -> bool {
        let s = stream_index(stream);
        self.clients
            .lock()
            .map(|c| c.iter().any(|c| c.format(s).is_some()))
            .unwrap_or(false)
    }

    /// The `status` fields measured outside the hub: latency at the sockets over the
    /// interval since the last call, memory, thread scheduling and the clients.
    pub fn status_fields(&self) -> StatusReport {
        let (synth, dsp) = self.streams[stream_index(StreamKind::Demods)].take_socket_interval();
        StatusReport {
            latency_dsp_to_socket: dsp,
            latency_synth_to_socket: synth,
            memory: ProcessMemory::read(),
            threads: crate::pipeline::realtime::promotions(),
            machine_stall_max_ns: self
                .stall
                .as_ref()
                .map(|m| m.take_interval_max())
                .unwrap_or(0),
            clients_detail: self.client_reports(),
            ..StatusReport::default()
        }
    }

    /// Every connected client's figures, by id.
    pub fn client_reports(&self) -> Vec<ClientReport> {
        let clients = self.clients.lock().map(|c| c.clone()).unwrap_or_default();
        let mut reports: Vec<_> = clients.iter().map(|c| c.report()).collect();
        reports.sort_by_key(|r| r.id);
        reports
    }

    pub fn dropped_total(&self) -> u64 {
        self.streams
            .iter()
            .map(|s| s.dropped.load(Ordering::Relaxed))
            .sum()
    }
}

/// Greatest common divisor (gcd(0, n) = n).
fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 { a } else { gcd(b, a % b) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(bytes: usize) -> Message {
        Message::Binary(vec![0u8; bytes].into())
    }

    #[tokio::test]
    async fn the_lane_has_a_byte_bound_of_its_own_and_goes_first() {
        let (queue, mut rx) = DataQueue::new(64);
        let stamps = Stamps::default();
        // Bulk up to its bound…
        assert!(queue.offer(message(1000), stamps, 2500, false).is_ok());
        assert!(queue.offer(message(1000), stamps, 2500, false).is_ok());
        assert!(queue.offer(message(1000), stamps, 2500, false).is_err());
        // …does not shut out the lane, which has a bound of its own.
        assert!(queue.offer(message(700), stamps, 2500, true).is_ok());
        assert!(queue.offer(message(700), stamps, 2500, true).is_ok());
        assert!(queue.offer(message(700), stamps, 2500, true).is_ok());
        assert!(queue.offer(message(700), stamps, 2500, true).is_err());
        assert_eq!(queue.queued_bytes(), 2000 + 2100);
        // The lane goes first, and its bytes leave both counts.
        assert_eq!(rx.recv().await.unwrap().size, 700);
        assert!(queue.offer(message(700), stamps, 2500, true).is_ok());
        for _ in 0..3 {
            assert_eq!(rx.recv().await.unwrap().size, 700);
        }
        assert_eq!(rx.recv().await.unwrap().size, 1000);
        assert_eq!(queue.queued_bytes(), 1000);
    }
}
