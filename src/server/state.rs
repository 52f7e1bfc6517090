//! What every part of the server shares: the control plane (settings and pipeline), the
//! client registry with per-stream statistics, and the shutdown signal.

use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::ws::Message;
use serde_json::Value;
use tokio::sync::{mpsc, watch};

use super::protocol::{ErrorCode, Format, ProtocolError, StreamKind};
use crate::config::Settings;
use crate::pipeline::{CountersSnapshot, Pipeline, PipelineError};

/// Streams in the order of [`StreamKind::ALL`]; indexes per-stream arrays.
pub(crate) const STREAMS: usize = 5;

pub(crate) fn stream_index(s: StreamKind) -> usize {
    match s {
        StreamKind::Demods => 0,
        StreamKind::Spectrum => 1,
        StreamKind::Scope => 2,
        StreamKind::Status => 3,
        StreamKind::Force => 4,
    }
}

/// The settings in force and the pipeline that runs them.
pub(crate) struct Control {
    pub settings: Settings,
    pub pipeline: Option<Pipeline>,
}

impl Control {
    /// Validates and applies one node change; on error nothing changes.
    pub fn set(&mut self, path: &str, value: &Value) -> Result<Value, ProtocolError> {
        let mut next = self.settings.clone();
        let applied = next.set(path, value).map_err(|e| ProtocolError::from(&e))?;
        if let Some(p) = &mut self.pipeline {
            p.apply(&next).map_err(|e| match e {
                PipelineError::Busy => ProtocolError {
                    code: ErrorCode::Busy,
                    message: format!("{path}: {e}; retry shortly"),
                },
                other => ProtocolError {
                    code: ErrorCode::InvalidValue,
                    message: format!("{path} = {value}: {other}"),
                },
            })?;
        }
        self.settings = next;
        Ok(applied)
    }

    pub fn counters(&self) -> CountersSnapshot {
        self.pipeline
            .as_ref()
            .map(|p| p.counters())
            .unwrap_or_default()
    }
}

/// One connected WebSocket client as the fan-out sees it.
pub(crate) struct ClientHandle {
    pub id: u64,
    /// Per stream: 0 = not subscribed, 1 = JSON, 2 = binary.
    subs: [AtomicU8; STREAMS],
    /// Data messages for this client (bounded: a slow client loses its own).
    pub data: mpsc::Sender<Message>,
    /// Messages dropped for this client.
    pub dropped: AtomicU64,
}

impl ClientHandle {
    pub fn new(id: u64, data: mpsc::Sender<Message>) -> Self {
        Self {
            id,
            subs: Default::default(),
            data,
            dropped: AtomicU64::new(0),
        }
    }

    pub fn subscribe(&self, stream: StreamKind, format: Format) {
        let v = match format {
            Format::Json => 1,
            Format::Binary => 2,
        };
        self.subs[stream_index(stream)].store(v, Ordering::Relaxed);
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
}

/// Shared by the router, the sessions and the hub.
pub(crate) struct AppState {
    pub control: Mutex<Control>,
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
    /// Latency summaries since start (ns), refreshed by the hub for `/metrics`.
    pub latency_totals: Mutex<[super::status::LatencySummary; 2]>,
    /// The `force` stream's worker.
    pub force: super::force::ForceLink,
}

impl AppState {
    pub fn client_count(&self) -> usize {
        self.clients.lock().map(|c| c.len()).unwrap_or(0)
    }

    /// Whether any client is subscribed to `stream`.
    pub fn subscribed(&self, stream: StreamKind) -> bool {
        let s = stream_index(stream);
        self.clients
            .lock()
            .map(|c| c.iter().any(|c| c.format(s).is_some()))
            .unwrap_or(false)
    }

    pub fn dropped_total(&self) -> u64 {
        self.streams
            .iter()
            .map(|s| s.dropped.load(Ordering::Relaxed))
            .sum()
    }
}
