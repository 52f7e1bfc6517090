//! `/metrics` in the Prometheus text exposition format (version 0.0.4).

use std::fmt::Write as _;
use std::sync::atomic::Ordering;

use super::protocol::StreamKind;
use super::state::{AppState, stream_index};
use super::status::{ClientReport, ProcessMemory};

/// Renders every counter, gauge and latency summary.
pub(crate) fn render(state: &AppState) -> String {
    let counters = state.control.counters().unwrap_or_default();
    let realtime = state.control.settings().synth.realtime;
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
        "sample_rate_hertz",
        "gauge",
        "Photodiode sample rate.",
        &[(String::new(), state.sample_rate)],
    );
    metric(
        "late_blocks_total",
        "counter",
        "Times the paced synthesiser fell more than 0.1 s behind the wall clock and restarted its pacing (that stretch of signal time is skipped, not queued).",
        &one(counters.late_blocks),
    );
    metric(
        "discontinuities_total",
        "counter",
        "Jumps in the sample index seen by the DSP.",
        &one(counters.discontinuities),
    );
    metric(
        "stream_samples_total",
        "counter",
        "Samples streamed in by a client (/source/kind = \"stream\"), by what became of them: taken into the feed, skipped by the writer (a gap in its frames' indices), dropped for want of room in the feed (the chain behind the writer), or discarded when the source changed.",
        &[
            (
                "{outcome=\"accepted\"}".to_owned(),
                counters.stream_samples as f64,
            ),
            (
                "{outcome=\"gap\"}".to_owned(),
                counters.stream_gap_samples as f64,
            ),
            (
                "{outcome=\"dropped\"}".to_owned(),
                counters.stream_dropped_samples as f64,
            ),
            (
                "{outcome=\"discarded\"}".to_owned(),
                counters.stream_discarded_samples as f64,
            ),
        ],
    );
    metric(
        "stream_frames_total",
        "counter",
        "Frames of streamed samples the daemon took.",
        &one(counters.stream_frames),
    );
    metric(
        "clipped_samples_total",
        "counter",
        "Samples clipped by the ADC's full scale.",
        &one(counters.clipped_samples),
    );
    metric(
        "substep_samples_total",
        "counter",
        "Samples in contact the coupled engine integrated at more sub-steps than /synth/contact_substeps to keep within its error budget (outcome=\"refined\"), and those over the budget even at 8 times the count (outcome=\"over_budget\").",
        &[
            (
                "{outcome=\"refined\"}".into(),
                counters.refined_samples as f64,
            ),
            (
                "{outcome=\"over_budget\"}".into(),
                counters.over_budget_samples as f64,
            ),
        ],
    );
    metric(
        "noise_pages_total",
        "counter",
        "Pages of noise deviates (4096 samples) the synthesiser used, by the thread that drew them: the DSP thread ahead, or the synthesiser itself when none was ready.",
        &[
            (
                "{drawn_by=\"dsp\"}".into(),
                counters.noise_pages_taken as f64,
            ),
            (
                "{drawn_by=\"synth\"}".into(),
                counters.noise_pages_drawn_inline as f64,
            ),
        ],
    );
    metric(
        "noise_pages_discarded_total",
        "counter",
        "Pages of noise deviates drawn ahead and not used (the synthesiser had passed them, or the seed or the number of modes changed).",
        &one(counters.noise_pages_discarded),
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
        "http_requests_refused_total",
        "counter",
        "HTTP requests refused because their Host header does not name this server (DNS rebinding) or is missing.",
        &one(state.refused_host.load(Ordering::Relaxed)),
    );
    metric(
        "clients_stalled_total",
        "counter",
        "Clients disconnected for not reading.",
        &one(state.closed_stalled.load(Ordering::Relaxed)),
    );
    metric(
        "clients_unresponsive_total",
        "counter",
        "Clients disconnected for answering no keep-alive ping within /server/stall_timeout (half-open or silent connections).",
        &one(state.closed_unresponsive.load(Ordering::Relaxed)),
    );
    metric(
        "http_connections_open",
        "gauge",
        "HTTP connections open that have not upgraded to a WebSocket.",
        &one(state.http.open.load(Ordering::Relaxed) as u64),
    );
    metric(
        "http_connections_dropped_total",
        "counter",
        "HTTP connections dropped, by reason (header_timeout: headers not complete in time; limit: too many open before their request; shutdown: still open when the shutdown grace ran out).",
        &state
            .http
            .dropped()
            .iter()
            .map(|(reason, n)| (format!("{{reason=\"{reason}\"}}"), *n as f64))
            .collect::<Vec<_>>(),
    );
    let f = &state.force.counters;
    metric(
        "force_estimates_total",
        "counter",
        "FT-AFM force estimates, by outcome (dropped: frames the inversion could not take in time; skipped: averaging windows not fitted because no client or sweep was to take their estimate).",
        &[
            (
                "{outcome=\"ok\"}".into(),
                f.estimates.load(Ordering::Relaxed) as f64,
            ),
            (
                "{outcome=\"skipped\"}".into(),
                f.skipped.load(Ordering::Relaxed) as f64,
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
    metric(
        "estimator_rebuilds_total",
        "counter",
        "FT-AFM estimator rebuilds after settings changes, by worker and outcome (coalesced: a change superseded by a newer one before it was built; cancelled: a build stopped because newer settings arrived while it ran).",
        &[
            (
                "{worker=\"force\",outcome=\"built\"}".into(),
                f.rebuilds.load(Ordering::Relaxed) as f64,
            ),
            (
                "{worker=\"force\",outcome=\"coalesced\"}".into(),
                state.force.pending.coalesced.load(Ordering::Relaxed) as f64,
            ),
            (
                "{worker=\"force\",outcome=\"cancelled\"}".into(),
                f.builds_cancelled.load(Ordering::Relaxed) as f64,
            ),
            (
                "{worker=\"image\",outcome=\"built\"}".into(),
                state.image.counters.rebuilds.load(Ordering::Relaxed) as f64,
            ),
            (
                "{worker=\"image\",outcome=\"coalesced\"}".into(),
                state.image.pending.coalesced.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    metric(
        "estimator_rests_total",
        "counter",
        "Rests of the force stream's estimator builder while its budget of build time is spent (a quarter of a core on average under a flood of changes), by outcome (cut: a sweep was waiting for its estimates).",
        &[
            (
                "{outcome=\"taken\"}".into(),
                f.rests_taken.load(Ordering::Relaxed) as f64,
            ),
            (
                "{outcome=\"cut\"}".into(),
                f.rests_cut.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    metric(
        "estimator_rebuild_seconds_total",
        "counter",
        "CPU time spent rebuilding the force stream's FT-AFM estimator (its builder runs at nice 10 and at most a quarter of a core on average beyond a 4 s burst, but without rests while a sweep waits for its estimates).",
        &[(
            String::new(),
            f.rebuild_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        )],
    );
    let i = &state.image.counters;
    metric(
        "scan_pixels_total",
        "counter",
        "Scan pixels, by source and outcome: harmonics from the DSP and topography from the synthesiser (dropped: no consumer took them in time, or cut by an overrun), and pixels the image worker's queue refused.",
        &[
            (
                "{source=\"dsp\",outcome=\"ok\"}".into(),
                counters.pixels as f64,
            ),
            (
                "{source=\"dsp\",outcome=\"dropped\"}".into(),
                counters.pixels_dropped as f64,
            ),
            (
                "{source=\"synth\",outcome=\"ok\"}".into(),
                counters.topography_pixels as f64,
            ),
            (
                "{source=\"synth\",outcome=\"dropped\"}".into(),
                counters.topography_pixels_dropped as f64,
            ),
            (
                "{source=\"image_worker\",outcome=\"dropped\"}".into(),
                i.dropped.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    metric(
        "image_lines_total",
        "counter",
        "Scan image lines and frames finished, and pixels whose FT-AFM inversion failed.",
        &[
            (
                "{kind=\"line\"}".into(),
                i.lines.load(Ordering::Relaxed) as f64,
            ),
            (
                "{kind=\"frame\"}".into(),
                i.frames.load(Ordering::Relaxed) as f64,
            ),
            (
                "{kind=\"inversion_failed_pixel\"}".into(),
                i.inversion_failed.load(Ordering::Relaxed) as f64,
            ),
        ],
    );
    let threads = crate::pipeline::realtime::promotions();
    metric(
        "thread_fifo_priority",
        "gauge",
        "SCHED_FIFO priority of each real-time thread (0: normal policy), by thread, policy and what was requested (FTAFM_SCHED).",
        &threads
            .iter()
            .map(|p| {
                (
                    format!(
                        "{{thread=\"{}\",policy=\"{}\",requested=\"{}\"}}",
                        p.thread,
                        p.policy.name(),
                        p.requested
                    ),
                    f64::from(p.priority),
                )
            })
            .collect::<Vec<_>>(),
    );
    metric(
        "thread_nice",
        "gauge",
        "Nice value of each real-time thread.",
        &threads
            .iter()
            .map(|p| (format!("{{thread=\"{}\"}}", p.thread), f64::from(p.nice)))
            .collect::<Vec<_>>(),
    );
    // Absent where the kernel does not say (not Linux).
    if let Some(m) = ProcessMemory::read() {
        metric(
            "process_resident_bytes",
            "gauge",
            "Resident memory of the daemon process (VmRSS).",
            &one(m.resident_bytes),
        );
        metric(
            "process_resident_peak_bytes",
            "gauge",
            "Largest resident memory of the daemon process so far (VmHWM).",
            &one(m.resident_peak_bytes),
        );
    }
    let clients = state.client_reports();
    let per_client = |f: &dyn Fn(&ClientReport) -> u64| -> Vec<(String, f64)> {
        clients
            .iter()
            .map(|c| (format!("{{client=\"{}\"}}", c.id), f(c) as f64))
            .collect()
    };
    metric(
        "client_messages_written_total",
        "counter",
        "Data messages handed to each connected client's socket, by client id.",
        &per_client(&|c| c.written),
    );
    metric(
        "client_messages_dropped_total",
        "counter",
        "Data messages dropped for each connected client (its queue was full), by client id.",
        &per_client(&|c| c.dropped),
    );
    let mut client_latency = Vec::new();
    for c in &clients {
        for (path, l) in [
            ("dsp_to_socket", c.dsp_to_socket),
            ("synth_to_socket", c.synth_to_socket),
        ] {
            for (q, v) in [("0.5", l.p50), ("0.99", l.p99), ("1", l.max)] {
                client_latency.push((
                    format!("{{client=\"{}\",path=\"{path}\",quantile=\"{q}\"}}", c.id),
                    v as f64 * 1e-9,
                ));
            }
        }
    }
    metric(
        "client_latency_seconds",
        "gauge",
        "Latency of demodulator messages at each connected client's socket since it connected (1 µs resolution, 2 digits), by client id and path.",
        &client_latency,
    );

    let [synth_to_dsp, synth_to_send] = state.latency_totals.lock().map(|t| *t).unwrap_or_default();
    let (synth_to_socket, dsp_to_socket) =
        state.streams[stream_index(StreamKind::Demods)].socket_totals();
    let mut latency = Vec::new();
    for (path, s) in [
        ("synth_to_dsp", synth_to_dsp),
        ("synth_to_send", synth_to_send),
        ("dsp_to_socket", dsp_to_socket),
        ("synth_to_socket", synth_to_socket),
    ] {
        for (q, v) in s.quantiles() {
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
        "# HELP ftafm_latency_seconds Latency of demodulator frames since start, by path: synth_to_dsp (synthesised -> DSP done), synth_to_send (synthesised -> queued to every client), dsp_to_socket and synth_to_socket (DSP done / synthesised -> handed to a client's socket, all clients)."
    );
    let _ = writeln!(out, "# TYPE ftafm_latency_seconds summary");
    for (labels, value) in latency {
        let _ = writeln!(out, "ftafm_latency_seconds{labels} {value}");
    }
    if let Some(meter) = &state.stall {
        let s = super::status::LatencySummary::from_histogram(&meter.histogram());
        let _ = writeln!(
            out,
            "# HELP ftafm_machine_stall_seconds How much later than asked a thread that naps 1 ms at a time woke up, since start: the machine's own scheduling stalls (other processes, the hypervisor)."
        );
        let _ = writeln!(out, "# TYPE ftafm_machine_stall_seconds summary");
        for (q, v) in s.quantiles() {
            let _ = writeln!(
                out,
                "ftafm_machine_stall_seconds{{quantile=\"{q}\"}} {}",
                v as f64 * 1e-9
            );
        }
        let _ = writeln!(out, "ftafm_machine_stall_seconds_count {}", s.count);
        let _ = writeln!(
            out,
            "# HELP ftafm_machine_stalls_total Stalls of the machine of at least 5 ms since start."
        );
        let _ = writeln!(out, "# TYPE ftafm_machine_stalls_total counter");
        let _ = writeln!(out, "ftafm_machine_stalls_total {}", meter.stalls());
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
