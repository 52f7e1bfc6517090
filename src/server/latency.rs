//! Latency histograms (HDR, ns): one for the current status interval, one since start.

use hdrhistogram::Histogram;

use super::status::LatencySummary;

/// Highest latency recorded exactly: 60 s; larger values are clamped to it.
pub(crate) const MAX_NS: u64 = 60_000_000_000;

/// Interval and total histograms of one latency path.
pub(crate) struct Latency {
    interval: Histogram<u64>,
    total: Histogram<u64>,
}

impl Latency {
    pub fn new() -> Self {
        let h = || Histogram::new_with_bounds(1, MAX_NS, 3).expect("static bounds are valid");
        Self {
            interval: h(),
            total: h(),
        }
    }

    /// Records one latency (ns); values ≤ 0 (clock steps) count as 1 ns.
    pub fn record(&mut self, ns: i64) {
        let v = (ns.max(1) as u64).min(MAX_NS);
        let _ = self.interval.record(v);
        let _ = self.total.record(v);
    }

    /// Percentiles of the interval, which then starts afresh.
    pub fn take_interval(&mut self) -> LatencySummary {
        let s = LatencySummary::from_histogram(&self.interval);
        self.interval.reset();
        s
    }

    /// Percentiles since start.
    pub fn total(&self) -> LatencySummary {
        LatencySummary::from_histogram(&self.total)
    }
}
