//! The instrument's health as clients see it (`status` stream, `/metrics`).

use serde::Serialize;

use crate::pipeline::CountersSnapshot;

/// Latency percentiles (ns) of one path, over the status interval's histogram.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
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
