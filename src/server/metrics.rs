//! `/metrics` in the Prometheus text exposition format (version 0.0.4).

use std::fmt::Write as _;
use std::sync::atomic::Ordering;

use super::protocol::StreamKind;
use super::state::{AppState, stream_index};

/// Renders every counter, gauge and latency summary.
pub(crate) fn render(state: &AppState) -> String {
    let (counters, realtime) = state
        .control
        .lock()
        .map(|c| (c.counters(), c.settings.synth.realtime))
        .unwrap_or_default();
    let mut out = String::with_capacity(4096);
    let mut metric = |name: &str, kind: &str, help: &str, samples: &[(String, f64)]| {
        let _ = writeln!(out, "# HELP ftafm_{name} {help}");
        let _ = writeln!(out, "# TYPE ftafm_{name} {kind}");
        for (labels, value) in samples {
            let _ = writeln!(out, "ftafm_{name}{labels} {value}");
        }
    };
    let one = |v: u64| vec![(String::new(), v as f64)];
    metric(
        "samples_synthesized_total",
        "counter",
        "Photodiode samples synthesised.",
        &one(counters.samples_synthesized),
    );
    metric(
        "samples_processed_total",
        "counter",
        "Samples the DSP consumed.",
        &one(counters.samples_processed),
    );
    metric(
        "overrun_samples_total",
        "counter",
        "Samples dropped because the ring was full.",
        &one(counters.overrun_samples),
    );
    metric(
        "overrun_blocks_total",
        "counter",
        "Blocks dropped because the ring was full.",
        &one(counters.overrun_blocks),
    );
    metric(
        "discontinuities_total",
        "counter",
        "Jumps in the sample index seen by the DSP.",
        &one(counters.discontinuities),
    );
    metric(
        "clipped_samples_total",
        "counter",
        "Samples clipped by the ADC's full scale.",
        &one(counters.clipped_samples),
    );
    metric(
        "ring_fill_samples",
        "gauge",
        "Samples waiting in the ring.",
        &one(counters.ring_fill),
    );
    metric(
        "ring_fill_max_samples",
        "gauge",
        "Largest ring fill seen.",
        &one(counters.ring_fill_max),
    );
    metric(
        "realtime",
        "gauge",
        "1 when paced by the wall clock.",
        &one(u64::from(realtime)),
    );
    metric(
        "frames_total",
        "counter",
        "Frames the DSP produced, by stream.",
        &[
            ("{stream=\"demods\"}".into(), counters.demod_frames as f64),
            (
                "{stream=\"spectrum\"}".into(),
                counters.spectrum_frames as f64,
            ),
            ("{stream=\"scope\"}".into(), counters.scope_frames as f64),
        ],
    );
    metric(
        "frames_dropped_total",
        "counter",
        "Frames the DSP dropped because the server did not take them, by stream.",
        &[
            (
                "{stream=\"demods\"}".into(),
                counters.demod_frames_dropped as f64,
            ),
            (
                "{stream=\"spectrum\"}".into(),
                counters.spectrum_frames_dropped as f64,
            ),
            (
                "{stream=\"scope\"}".into(),
                counters.scope_frames_dropped as f64,
            ),
        ],
    );
    let per_stream = |f: &dyn Fn(usize) -> u64| -> Vec<(String, f64)> {
        StreamKind::ALL
            .iter()
            .map(|s| {
                (
                    format!("{{stream=\"{}\"}}", s.name()),
                    f(stream_index(*s)) as f64,
                )
            })
            .collect()
    };
    metric(
        "messages_sent_total",
        "counter",
        "Messages queued to clients, by stream.",
        &per_stream(&|i| state.streams[i].sent.load(Ordering::Relaxed)),
    );
    metric(
        "messages_dropped_total",
        "counter",
        "Messages dropped for slow clients, by stream.",
        &per_stream(&|i| state.streams[i].dropped.load(Ordering::Relaxed)),
    );
    metric(
        "clients",
        "gauge",
        "WebSocket clients connected.",
        &one(state.client_count() as u64),
    );
    metric(
        "connections_refused_total",
        "counter",
        "WebSocket handshakes refused, by reason.",
        &[
            (
                "{reason=\"origin\"}".into(),
                state.refused_origin.load(Ordering::Relaxed) as f64,
            ),
            (
                "{reason=\"capacity\"}".into(),
                state.refused_capacity.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    metric(
        "clients_stalled_total",
        "counter",
        "Clients disconnected for not reading.",
        &one(state.closed_stalled.load(Ordering::Relaxed)),
    );
    let f = &state.force.counters;
    metric(
        "force_estimates_total",
        "counter",
        "FT-AFM force estimates, by outcome (dropped: frames the inversion could not take in time).",
        &[
            (
                "{outcome=\"ok\"}".into(),
                f.estimates.load(Ordering::Relaxed) as f64,
            ),
            (
                "{outcome=\"failed\"}".into(),
                f.failed.load(Ordering::Relaxed) as f64,
            ),
            (
                "{outcome=\"dropped\"}".into(),
                f.dropped.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    let totals = state.latency_totals.lock().map(|t| *t).unwrap_or_default();
    let mut latency = Vec::new();
    for (path, s) in [("synth_to_dsp", totals[0]), ("synth_to_send", totals[1])] {
        for (q, v) in [
            ("0.5", s.p50),
            ("0.9", s.p90),
            ("0.99", s.p99),
            ("0.999", s.p999),
            ("1", s.max),
        ] {
            latency.push((
                format!("{{path=\"{path}\",quantile=\"{q}\"}}"),
                v as f64 * 1e-9,
            ));
        }
        latency.push((format!("_count{{path=\"{path}\"}}"), s.count as f64));
    }
    // The `_count` lines share the summary's name with a suffix.
    let _ = writeln!(
        out,
        "# HELP ftafm_latency_seconds Latency of demodulator frames since start, by path."
    );
    let _ = writeln!(out, "# TYPE ftafm_latency_seconds summary");
    for (labels, value) in latency {
        let _ = writeln!(out, "ftafm_latency_seconds{labels} {value}");
    }
    let _ = writeln!(
        out,
        "# HELP ftafm_uptime_seconds Seconds since the daemon started."
    );
    let _ = writeln!(out, "# TYPE ftafm_uptime_seconds gauge");
    let _ = writeln!(
        out,
        "ftafm_uptime_seconds {}",
        state.started.elapsed().as_secs_f64()
    );
    out
}
