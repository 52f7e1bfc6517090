//! The instrument's health as clients see it (`status` stream, `/metrics`).

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

use crate::pipeline::CountersSnapshot;

/// Latency percentiles (ns) of one path: the daemon's (status interval or since start) and
/// `ftafm soak`'s receive latency.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// Samples in the histogram.
    pub count: u64,
    /// Median (ns).
    pub p50: u64,
    /// 90th percentile (ns).
    pub p90: u64,
    /// 99th percentile (ns).
    pub p99: u64,
    /// 99.9th percentile (ns).
    pub p999: u64,
    /// Largest (ns).
    pub max: u64,
}

impl LatencySummary {
    /// Percentiles of `h` (ns); all zero when it is empty.
    pub fn from_histogram(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        Self {
            count: h.len(),
            p50: h.value_at_quantile(0.5),
            p90: h.value_at_quantile(0.9),
            p99: h.value_at_quantile(0.99),
            p999: h.value_at_quantile(0.999),
            max: h.max(),
        }
    }
}

/// One `status` message's content.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StatusReport {
    /// Photodiode sample rate (Hz).
    pub sample_rate: f64,
    /// Samples processed per wall-clock second over the last interval / sample rate.
    pub realtime_factor: f64,
    /// Whether the chain is paced by the wall clock.
    pub realtime: bool,
    /// Samples waiting in the ring.
    pub ring_fill: u64,
    /// Ring capacity (samples).
    pub ring_capacity: u64,
    /// WebSocket clients connected.
    pub clients: u64,
    /// Messages dropped for slow clients, all clients and streams, since start.
    pub messages_dropped: u64,
    /// synth → DSP-done latency of demodulator frames.
    pub latency_synth_to_dsp: LatencySummary,
    /// synth → handed to a client's socket.
    pub latency_synth_to_send: LatencySummary,
    /// The pipeline's counters.
    pub counters: CountersSnapshot,
}
