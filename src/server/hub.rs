//! Fan-out: takes frames from the pipeline, serialises each once per format that someone
//! subscribed to, and offers the shared bytes to every subscriber's bounded queue. A full
//! queue drops that client's copy (counted; the client sees a seq gap) and never holds up
//! the others or the pipeline.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use serde_json::{Map, Value, json};

use axum::extract::ws::{Message, Utf8Bytes};
use bytes::Bytes;
use ringbuf::traits::Consumer;
use tokio::sync::mpsc::error::TrySendError;

use super::latency::Latency;
use super::memory::release_freed_memory;
use super::protocol::{self, Format, StreamKind};
use super::state::{AppState, ClientHandle, PendingBatch, Stamps, stream_index};
use super::status::StatusReport;
use crate::config::Engine;
use crate::pipeline::{CountersSnapshot, FrameSignal, PipelineOutput, ring_samples, unix_ns};

/// How often the hub looks for frames without being woken: the demodulators' 1 kHz output
/// period. The DSP thread wakes it as soon as it has demodulator frames (where the system
/// allows, [`FrameSignal`](crate::pipeline::FrameSignal)); the tick serves the other
/// streams and the status.
const TICK: Duration = Duration::from_millis(1);
/// Every how many status periods freed memory is handed back to the system (10 s).
const TRIM_EVERY: u64 = 20;

/// Most demodulator frames the hub takes in one pass before it serves the other streams
/// and yields to the sessions: 64 ms of frames at the default 1 kHz, far more than one
/// pass ever finds there.
const DEMOD_FRAMES_PER_PASS: usize = 64;

/// How often a `status` message goes out.
const STATUS_PERIOD: Duration = Duration::from_millis(500);

/// Offers one message of `stream` to its subscribers; `json` and `binary` build the two
/// encodings, each at most once. `(t_synth_ns, t_dsp_ns)` go with it to every client's
/// socket, where its latency is measured (0 = unknown).
pub(crate) fn distribute(
    state: &AppState,
    stream: StreamKind,
    stamps: (u64, u64),
    json: impl FnOnce(u64) -> String,
    binary: impl FnOnce(u64) -> Vec<u8>,
) {
    distribute_points(
        state,
        stream,
        None,
        stamps,
        json,
        binary,
        None::<fn(u64) -> Vec<u8>>,
    );
}

/// [`distribute`], with the message's `seq` when its producer numbers them (the force
/// worker: its skipped windows take theirs), and `point` building the message's time point
/// for the clients that take `demods` batched ([`protocol::demods_point`]), at most once.
fn distribute_points(
    state: &AppState,
    stream: StreamKind,
    seq: Option<u64>,
    (t_synth_ns, t_dsp_ns): (u64, u64),
    json: impl FnOnce(u64) -> String,
    binary: impl FnOnce(u64) -> Vec<u8>,
    point: Option<impl FnOnce(u64) -> Vec<u8>>,
) {
    let s = stream_index(stream);
    let seq = match seq {
        Some(seq) => {
            state.streams[s]
                .produced
                .fetch_max(seq + 1, Ordering::Relaxed);
            seq
        }
        None => state.streams[s].produced.fetch_add(1, Ordering::Relaxed),
    };
    let clients = match state.clients.lock() {
        Ok(c) => c.clone(),
        Err(_) => return,
    };
    let stamps = Stamps {
        stream: Some(s),
        t_synth_ns,
        t_dsp_ns,
    };
    let (mut json, mut binary, mut point) = (Some(json), Some(binary), point);
    let max_bytes = state.queue_bytes.load(Ordering::Relaxed);
    // Scan lines, status and sweep points are small and rare: they take the lane, never
    // lost behind bulk; so do force estimates for a client that paces them (`every`), as the
    // dashboard does for its trends.
    let lane = matches!(
        stream,
        StreamKind::Status | StreamKind::Image | StreamKind::Sweep
    );
    let paced_lane = stream == StreamKind::Force;
    let (mut text_msg, mut bin_msg): (Option<Message>, Option<Message>) = (None, None);
    let mut point_bytes: Option<Vec<u8>> = None;
    for client in clients.iter() {
        let Some(format) = client.format(s) else {
            continue;
        };
        if !client.takes(s, seq) || (stream == StreamKind::Force && seq < client.force_from()) {
            // Skipped at the client's request (`every`), not lost: no gap, no drop.
            continue;
        }
        // Batched demods: held while the point is added, so that a change of the
        // subscription (which flushes under the same lock) is seen whole.
        let mut pending = match (&point, format) {
            (Some(_), Format::Binary) => client.pending.lock().ok(),
            _ => None,
        };
        if let Some(pending) = pending.as_mut() {
            let batch = client.batch();
            if batch > 1 {
                let bytes = point_bytes
                    .get_or_insert_with(|| point.take().map(|f| f(seq)).unwrap_or_default());
                add_point(state, client, pending, bytes, stamps, batch, max_bytes);
                continue;
            }
            // Unbatched now: what was gathered before goes first.
            flush_batch(state, client, pending, max_bytes);
        }
        let msg = match format {
            Format::Json => text_msg
                .get_or_insert_with(|| {
                    let text = json.take().map(|f| f(seq)).unwrap_or_default();
                    Message::Text(Utf8Bytes::from(text))
                })
                .clone(),
            Format::Binary => bin_msg
                .get_or_insert_with(|| {
                    let bytes = binary.take().map(|f| f(seq)).unwrap_or_default();
                    Message::Binary(Bytes::from(bytes))
                })
                .clone(),
        };
        let lane = lane || (paced_lane && client.paced(s));
        offer(state, client, s, msg, stamps, max_bytes, lane);
    }
}

/// Queues `msg` for `client`, counting it as sent or dropped.
fn offer(
    state: &AppState,
    client: &ClientHandle,
    stream: usize,
    msg: Message,
    stamps: Stamps,
    max_bytes: usize,
    lane: bool,
) {
    match client.data.offer(msg, stamps, max_bytes, lane) {
        Ok(()) => {
            state.streams[stream].sent.fetch_add(1, Ordering::Relaxed);
        }
        Err(TrySendError::Full(_)) => {
            client.dropped.fetch_add(1, Ordering::Relaxed);
            state.streams[stream]
                .dropped
                .fetch_add(1, Ordering::Relaxed);
        }
        Err(TrySendError::Closed(_)) => {}
    }
}

/// Adds a time point to the client's batched `demods` message, and queues the message once
/// it holds `batch` points. A point with another number of records than those gathered
/// (a demodulator was switched) sends those first.
fn add_point(
    state: &AppState,
    client: &ClientHandle,
    pending: &mut PendingBatch,
    point: &[u8],
    stamps: Stamps,
    batch: u32,
    max_bytes: usize,
) {
    let records =
        ((point.len() - protocol::POINT_HEADER_BYTES) / protocol::DEMOD_RECORD_BYTES) as u32;
    if pending.batch.points() > 0 && pending.batch.records() != records {
        flush_batch(state, client, pending, max_bytes);
    }
    if pending.batch.points() == 0 {
        pending.since = Some(Instant::now());
    }
    pending.batch.push(point);
    pending.stamps = stamps;
    if pending.batch.points() >= batch {
        flush_batch(state, client, pending, max_bytes);
    }
}

/// Queues what the client's batched `demods` message holds, if anything. The message's
/// stamps are its newest point's.
pub(crate) fn flush_batch(
    state: &AppState,
    client: &ClientHandle,
    pending: &mut PendingBatch,
    max_bytes: usize,
) {
    pending.since = None;
    if let Some(bytes) = pending.batch.take() {
        let s = stream_index(StreamKind::Demods);
        let msg = Message::Binary(Bytes::from(bytes));
        offer(state, client, s, msg, pending.stamps, max_bytes, false);
    }
}

/// How long a batched `demods` message waits for its points at most, from its first.
const BATCH_WAIT: Duration = Duration::from_millis(100);

/// Queues every batched `demods` message whose first point has waited [`BATCH_WAIT`].
fn flush_aged_batches(state: &AppState, now: Instant) {
    let Ok(clients) = state.clients.lock() else {
        return;
    };
    let max_bytes = state.queue_bytes.load(Ordering::Relaxed);
    for client in clients.iter() {
        if let Ok(mut pending) = client.pending.lock()
            && pending
                .since
                .is_some_and(|since| now.duration_since(since) >= BATCH_WAIT)
        {
            flush_batch(state, client, &mut pending, max_bytes);
        }
    }
}

/// The DSP thread's wake-up, as a future.
struct Wake {
    #[cfg(target_os = "linux")]
    fd: Option<tokio::io::unix::AsyncFd<Arc<FrameSignal>>>,
}

impl Wake {
    fn new(signal: Option<Arc<FrameSignal>>) -> Self {
        #[cfg(target_os = "linux")]
        {
            let fd = signal.and_then(|s| {
                // SAFETY: the descriptor is the eventfd that `FrameSignal` owns and closes
                // only when dropped; the Arc held here keeps it open, and its `as_raw_fd`
                // always returns that one descriptor.
                unsafe {
                    tokio::io::unix::AsyncFd::register_with_interest(
                        s,
                        tokio::io::Interest::READABLE,
                    )
                }
                .inspect_err(|e| tracing::warn!(error = %e, "polling for frames: no wake-up"))
                .ok()
            });
            Self { fd }
        }
        #[cfg(not(target_os = "linux"))]
        {
            let _ = signal;
            Self {}
        }
    }

    /// Resolves when the DSP thread has signalled (never, without a signal).
    async fn wait(&self) {
        #[cfg(target_os = "linux")]
        if let Some(fd) = &self.fd
            && let Ok(mut guard) = fd.readable().await
        {
            // Take the wake-ups; `drain` ends with WouldBlock, which clears the readiness
            // until the DSP thread signals again.
            let _ = guard.try_io(|s| s.get_ref().drain());
            return;
        }
        // No signal (or the reactor is gone): only the tick wakes the hub.
        std::future::pending::<()>().await
    }
}

/// Runs until shutdown: frames in, messages out, a status message every 0.5 s.
pub(crate) async fn run(
    state: Arc<AppState>,
    mut output: PipelineOutput,
    estimates: std::sync::mpsc::Receiver<crate::instrument::force::ForceOutcome>,
    image_lines: std::sync::mpsc::Receiver<crate::imaging::ImageLine>,
) {
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let wake = Wake::new(output.signal.clone());
    let mut shutdown = state.shutdown.clone();
    let mut synth_to_dsp = Latency::new();
    let mut synth_to_send = Latency::new();
    let mut last_status = Instant::now();
    let mut status_count: u64 = 0;
    let mut swept = false;
    let mut last_counters = CountersSnapshot::default();
    let mut calibration: Option<crate::instrument::bimodal::Calibration> = None;
    // Mode 2's PLL's updates as the hub sees them, for the bimodal frames' pairing.
    let mut pll_history = crate::instrument::bimodal::PllHistory::default();
    // Frames left in the ring when the last pass spent its budget.
    let mut more = false;
    loop {
        if more {
            // Take the rest at once, but after everyone else had a turn.
            tokio::task::yield_now().await;
            if *shutdown.borrow() {
                return;
            }
        } else {
            tokio::select! {
                _ = tick.tick() => {}
                _ = wake.wait() => {}
                _ = shutdown.changed() => return,
            }
        }
        let sweeping = state.sweep_force.is_active();
        if sweeping != swept {
            // A sweep takes every estimate while it runs.
            swept = sweeping;
            state.update_force_stride();
        }
        let force_wanted = state.subscribed(StreamKind::Force) || sweeping;
        // The bimodal estimate's calibration, for the settings in force.
        let bimodal = if state.subscribed(StreamKind::Bimodal) {
            let current = state.control.current();
            if calibration
                .as_ref()
                .is_none_or(|c| c.epoch != current.epoch || c.t_known() != current.t.is_some())
            {
                calibration = Some(crate::instrument::bimodal::Calibration::of(&current));
            }
            // Mode 2's PLL's latest update, once a pass: the history the frames, behind
            // the synthesiser, are paired from.
            if let Some(unit) = calibration.as_ref().and_then(|c| c.pll_unit())
                && let Some(latest) = state.control.pid_updates()[unit]
            {
                pll_history.record(unit, latest);
            }
            calibration.as_ref()
        } else {
            None
        };
        let mut newest = None;
        // A budget per pass: at a demodulator's top rate the frames come faster than they
        // are serialised, and an unbounded drain would starve the other streams, the
        // status, the sessions' replies and shutdown. What the hub does not take waits in
        // the frame ring, whose overflow the DSP thread counts (`demod_frames_dropped`).
        let mut budget = DEMOD_FRAMES_PER_PASS;
        while budget > 0
            && let Some(frame) = output.demods.try_pop()
        {
            budget -= 1;
            newest = Some(frame);
            state.sweep_frames.offer(&frame);
            if force_wanted {
                state.force.offer(&frame);
            }
            if let Some(c) = bimodal {
                // The PLL's update in force at the frame's sample, not its latest: the
                // synthesiser runs ahead of the frames.
                let pll = c
                    .pll_unit()
                    .and_then(|unit| pll_history.at(unit, frame.sample_index));
                let fields = c.fields(&frame, pll);
                publish_envelope(
                    &state,
                    StreamKind::Bimodal,
                    frame.t,
                    (frame.t_synth_ns, frame.t_dsp_ns),
                    fields,
                );
            }
            synth_to_dsp.record(frame.t_dsp_ns as i64 - frame.t_synth_ns as i64);
            distribute_points(
                &state,
                StreamKind::Demods,
                None,
                (frame.t_synth_ns, frame.t_dsp_ns),
                |seq| protocol::demods_json(seq, &frame),
                |seq| protocol::demods_binary(seq, &frame),
                Some(|seq| protocol::demods_point(seq, &frame)),
            );
            synth_to_send.record(unix_ns() as i64 - frame.t_synth_ns as i64);
        }
        more = budget == 0;
        flush_aged_batches(&state, Instant::now());
        if newest.is_some()
            && let Ok(mut latest) = state.latest_demods.lock()
        {
            *latest = newest;
        }
        // Every PID update, while the stream has subscribers; the synthesiser queues them only
        // then, and what it queued before the last one left is dropped here.
        let pids_wanted = state.subscribed(StreamKind::Pids);
        state.control.stream_pid_updates(pids_wanted);
        publish_pid_events(&state, &mut output.pid_events, pids_wanted);
        // Topography first: a pixel's height is handed out before its harmonics.
        while let Some(t) = output.topography.try_pop() {
            state.image.topography(&t);
        }
        while let Some(p) = output.pixels.try_pop() {
            state.image.pixel(&p);
        }
        while let Ok(line) = image_lines.try_recv() {
            distribute(
                &state,
                StreamKind::Image,
                (line.t_synth_ns, 0),
                |seq| protocol::image_json(seq, &line),
                |seq| protocol::image_binary(seq, &line),
            );
        }
        while let Ok(outcome) = estimates.try_recv() {
            state.sweep_force.offer(&outcome);
            let crate::instrument::force::ForceOutcome::Estimate(_, estimate, seq) = outcome else {
                continue;
            };
            distribute_points(
                &state,
                StreamKind::Force,
                Some(seq),
                (estimate.t_synth_ns, 0),
                |seq| protocol::force_json(seq, &estimate),
                |seq| protocol::force_binary(seq, &estimate),
                None::<fn(u64) -> Vec<u8>>,
            );
        }
        while let Some(buffer) = output.spectra.try_pop() {
            distribute(
                &state,
                StreamKind::Spectrum,
                (buffer.t_synth_ns, buffer.t_dsp_ns),
                |seq| protocol::spectrum_json(seq, &buffer),
                |seq| protocol::spectrum_binary(seq, &buffer),
            );
            output.recycle(buffer);
        }
        while let Some(buffer) = output.scopes.try_pop() {
            distribute(
                &state,
                StreamKind::Scope,
                (buffer.t_synth_ns, buffer.t_dsp_ns),
                |seq| protocol::scope_json(seq, &buffer),
                |seq| protocol::scope_binary(seq, &buffer),
            );
            output.recycle_scope(buffer);
        }
        let elapsed = last_status.elapsed();
        if elapsed >= STATUS_PERIOD {
            let current = state.control.current();
            let c = &current.settings;
            let counters = state.control.counters().unwrap_or_default();
            let (realtime, adc_range) = (c.synth.realtime, c.noise.adc_range);
            let substeps = (c.synth.engine == Engine::Coupled).then_some(c.synth.contact_substeps);
            let mut warnings = c.warnings();
            warnings.extend(current.range_warnings.iter().cloned());
            let retired = state.control.take_retired().unwrap_or_default();
            let processed = counters.samples_processed - last_counters.samples_processed;
            let clipped = counters.clipped_samples - last_counters.clipped_samples;
            if clipped > 0 {
                warnings.push(format!(
                    "the photodiode signal clipped: {clipped} of {processed} samples in the last \
                     {:.1} s beyond the ADC's full scale ±{} m (/noise/adc_range); the \
                     operating point is outside what the detector measures (check \
                     /drive/frequency against /cantilever/f1, /drive/free_amplitude)",
                    elapsed.as_secs_f64(),
                    adc_range
                ));
            }
            let over_budget = counters.over_budget_samples - last_counters.over_budget_samples;
            if over_budget > 0 {
                warnings.push(format!(
                    "the coupled engine's contact is stiffer than its sub-steps resolve: \
                     {over_budget} samples in the last {:.1} s were over the error budget even \
                     at 8 × /synth/contact_substeps ({}), so the harmonics may be off by more \
                     than 0.1 % (docs/ft-afm.md); raise /synth/contact_substeps",
                    elapsed.as_secs_f64(),
                    c.synth.contact_substeps
                ));
            }
            if realtime
                && let Some(w) = behind_warning(&last_counters, &counters, elapsed, substeps)
            {
                warnings.push(w);
            }
            // The frame copied out: the regime's model is not computed under the lock `get`
            // reads it through.
            let newest = state.latest_demods.lock().ok().and_then(|f| *f);
            let regime = newest.and_then(|f| live_regime(&f, &current));
            let report = StatusReport {
                sample_rate: state.sample_rate,
                realtime_factor: processed as f64 / elapsed.as_secs_f64() / state.sample_rate,
                realtime,
                ring_fill: counters.ring_fill,
                ring_capacity: ring_samples(state.sample_rate) as u64,
                source: current.settings.source.kind.name(),
                stream_fill: state.inlet.fill() as u64,
                stream_capacity: state.inlet.capacity() as u64,
                clients: state.client_count() as u64,
                messages_dropped: state.dropped_total(),
                latency_synth_to_dsp: synth_to_dsp.take_interval(),
                latency_synth_to_send: synth_to_send.take_interval(),
                counters,
                warnings,
                regime: regime.map(crate::sweep::Regime::name),
                pids: pid_reports(c, state.control.pid_updates()),
                pid_held: state.control.pid_held().iter().map(|t| t.name()).collect(),
                epoch: current.epoch,
                ..state.status_fields()
            };
            if let Ok(mut totals) = state.latency_totals.lock() {
                *totals = [synth_to_dsp.total(), synth_to_send.total()];
            }
            let t = counters.samples_processed as f64 / state.sample_rate;
            let t_synth = unix_ns();
            distribute(
                &state,
                StreamKind::Status,
                (t_synth, 0),
                |seq| protocol::status_json(seq, t, t_synth, &report),
                |seq| protocol::status_binary(seq, t, t_synth, &report),
            );
            last_counters = counters;
            last_status = Instant::now();
            status_count += 1;
            if !retired.is_empty() || status_count.is_multiple_of(TRIM_EVERY) {
                // Plans the threads gave back are freed, and memory freed after large
                // settings (a 2^20-point spectrum's plan and messages) goes back to the
                // system, not only to the allocator; off the hub, which must not stall.
                tokio::task::spawn_blocking(move || {
                    drop(retired);
                    release_freed_memory();
                });
            }
        }
    }
}

/// The regime (`crate::sweep::regime`) of `frame` against the free lever at `current`'s
/// settings, if the frame was synthesised under them and measures harmonic 1.
fn live_regime(
    frame: &crate::pipeline::DemodFrame,
    current: &crate::instrument::Current,
) -> Option<crate::sweep::Regime> {
    if current.t.is_none_or(|t| frame.t < t) {
        return None;
    }
    // A harmonic of /drive2 is none of the tapping's.
    let at = |k: u32| {
        frame
            .values()
            .iter()
            .find(|v| v.on_drive() && v.harmonic == k)
    };
    let h1 = at(1)?;
    let point = crate::sweep::ApproachPoint {
        r: h1.r(),
        phase: crate::sweep::phase_to_drive(h1.phase()),
        mean: at(0).map(|v| v.x),
    };
    let free = crate::sweep::free_point(&current.settings)?;
    Some(crate::sweep::regime(
        point,
        free,
        crate::sweep::FREE_DROP,
        crate::sweep::FREE_TWIST,
        crate::sweep::MEAN_FLOOR,
    ))
}

/// The warning of a status interval in which the paced chain fell behind real time
/// (samples overrun or blocks late, from `before` to `now` over `elapsed`): what was lost,
/// which thread was the busier, and what lightens it. `substeps`: the coupled engine's
/// `/synth/contact_substeps` (`None` with the paper engine). `None` if nothing fell behind.
fn behind_warning(
    before: &CountersSnapshot,
    now: &CountersSnapshot,
    elapsed: Duration,
    substeps: Option<u32>,
) -> Option<String> {
    let overrun = now.overrun_samples - before.overrun_samples;
    let late = now.late_blocks - before.late_blocks;
    if overrun == 0 && late == 0 {
        return None;
    }
    let seconds = elapsed.as_secs_f64();
    let busy = |after: u64, before: u64| (after - before) as f64 * 1e-9 / seconds * 100.0;
    let synth = busy(now.synth_busy_ns, before.synth_busy_ns);
    let dsp = busy(now.dsp_busy_ns, before.dsp_busy_ns);
    let remedy = if synth >= dsp {
        let fewer = match substeps {
            Some(n) if n > 6 => format!(
                "fewer contact sub-steps (/synth/contact_substeps, now {n}; at 6 with \
                 /synth/substep_budget 0.1 the coupled engine stays within its accuracy goals, \
                 docs/ft-afm.md), "
            ),
            _ => String::new(),
        };
        format!("to lighten the synthesiser: {fewer}a lower /synth/sample_rate (config file)")
    } else {
        "to lighten the DSP: a smaller or less frequent spectrum (/spectrum/size, \
         /spectrum/rate) or fewer demodulators (/demods/N/enable)"
            .to_owned()
    };
    Some(format!(
        "the chain fell behind real time in the last {seconds:.1} s: {overrun} samples \
         overrun (dropped before the DSP: the outputs skip them) and {late} blocks late \
         (synthesised after their time); busy: synthesis {synth:.0} %, DSP {dsp:.0} % of \
         the time; {remedy}, or fewer other programs on this machine"
    ))
}

/// Sends one `sweep` message with `fields` after the envelope (the sweeper's messages).
pub(crate) fn publish_sweep(state: &AppState, t: f64, t_synth_ns: u64, fields: Map<String, Value>) {
    publish_envelope(
        state,
        StreamKind::Sweep,
        t,
        (t_synth_ns, 0),
        Value::Object(fields),
    );
}

/// Updates a `pids` message gathers at most (one pass of the hub takes the rest next).
const PID_EVENTS_PER_MESSAGE: usize = 4096;

/// Sends the queued PID updates as `pids` messages of at most [`PID_EVENTS_PER_MESSAGE`],
/// each a column per field; without subscribers they are taken and dropped.
fn publish_pid_events(
    state: &AppState,
    events: &mut ringbuf::HeapCons<crate::pipeline::PidEvent>,
    wanted: bool,
) {
    use ringbuf::traits::{Consumer, Observer};
    while !events.is_empty() {
        let batch: Vec<crate::pipeline::PidEvent> =
            events.pop_iter().take(PID_EVENTS_PER_MESSAGE).collect();
        if !wanted {
            continue;
        }
        let Some(last) = batch.last() else {
            break;
        };
        let rate = state.control.current().settings.synth.sample_rate;
        let column = |f: &dyn Fn(&crate::pipeline::PidEvent) -> Value| -> Value {
            Value::Array(batch.iter().map(f).collect())
        };
        let fields = json!({
            "unit": column(&|e| json!(e.reading.unit)),
            "sample": column(&|e| json!(e.reading.sample)),
            "epoch": column(&|e| json!(e.epoch)),
            "measurement": column(&|e| json!(e.reading.measurement)),
            "error": column(&|e| json!(e.reading.error)),
            "output": column(&|e| json!(e.reading.output)),
            "limited": column(&|e| json!(e.reading.limited)),
            "locked": column(&|e| json!(e.reading.locked)),
            "dropped": state
                .control
                .counters()
                .map_or(0, |c| c.pid_updates_dropped),
        });
        let t = last.reading.sample as f64 / rate;
        publish_envelope(state, StreamKind::Pids, t, (last.t_synth_ns, 0), fields);
    }
}

/// Sends one message of a JSON-only `stream` with `fields` (an object) after the envelope
/// (`stream`, `seq`, `t`, `t_synth_ns`); in binary, the same JSON behind the header.
fn publish_envelope(
    state: &AppState,
    stream: StreamKind,
    t: f64,
    stamps: (u64, u64),
    fields: Value,
) {
    let Value::Object(fields) = fields else {
        return;
    };
    let t_synth_ns = stamps.0;
    distribute(
        state,
        stream,
        stamps,
        |seq| envelope(stream, seq, t, t_synth_ns, &fields),
        |seq| {
            protocol::json_binary(
                stream,
                seq,
                t,
                t_synth_ns,
                &envelope(stream, seq, t, t_synth_ns, &fields),
            )
        },
    );
}

fn envelope(
    stream: StreamKind,
    seq: u64,
    t: f64,
    t_synth_ns: u64,
    fields: &Map<String, Value>,
) -> String {
    let mut m = Map::new();
    m.insert("stream".into(), json!(stream.name()));
    m.insert("seq".into(), json!(seq));
    m.insert("t".into(), json!(t));
    m.insert("t_synth_ns".into(), json!(t_synth_ns));
    m.extend(fields.clone());
    Value::Object(m).to_string()
}

/// The PID units for `status`: their settings in `settings`, their latest updates.
fn pid_reports(
    settings: &crate::config::Settings,
    updates: [Option<crate::pipeline::PidUpdate>; crate::config::PID_COUNT],
) -> Vec<super::status::PidReport> {
    settings
        .pids
        .iter()
        .zip(updates)
        .enumerate()
        .map(|(index, (pid, latest))| {
            // A unit on an oscillator's frequency: Δf from that oscillator's node.
            let centre = pid
                .output
                .frequency_of()
                .map(|o| settings.oscillator_frequency(o));
            let on_frequency = centre.is_some();
            let pll = on_frequency && pid.input == crate::config::PidInput::Phase;
            super::status::PidReport {
                index,
                enable: pid.enable,
                input: pid.input.name(),
                harmonic: pid.harmonic,
                oscillator: pid.oscillator.name(),
                output: pid.output.name(),
                setpoint: pid.setpoint,
                latest,
                locked: latest.filter(|_| pll).and_then(|u| u.locked),
                lock_losses: latest.filter(|_| pll).map(|u| u.lock_losses),
                frequency_shift: latest.zip(centre).map(|(u, centre)| u.output - centre),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn snapshot(overrun: u64, late: u64, synth_ns: u64, dsp_ns: u64) -> CountersSnapshot {
        CountersSnapshot {
            overrun_samples: overrun,
            late_blocks: late,
            synth_busy_ns: synth_ns,
            dsp_busy_ns: dsp_ns,
            ..CountersSnapshot::default()
        }
    }

    #[test]
    fn a_chain_in_time_has_no_warning() {
        let a = snapshot(4096, 1, 0, 0);
        let b = snapshot(4096, 1, 400_000_000, 100_000_000);
        assert_eq!(
            behind_warning(&a, &b, Duration::from_secs(1), Some(12)),
            None
        );
    }

    #[test]
    fn a_late_synthesiser_is_told_its_remedies() {
        let a = snapshot(0, 0, 0, 0);
        let b = snapshot(0, 3, 490_000_000, 150_000_000);
        let w = behind_warning(&a, &b, Duration::from_millis(500), Some(12)).unwrap();
        assert!(w.contains("in the last 0.5 s"), "{w}");
        assert!(
            w.contains("0 samples overrun") && w.contains("3 blocks late"),
            "{w}"
        );
        // Busy fractions of the interval: 0.49 s and 0.15 s of computing in 0.5 s.
        assert!(w.contains("synthesis 98 %, DSP 30 %"), "{w}");
        assert!(w.contains("/synth/contact_substeps, now 12"), "{w}");
        assert!(w.contains("/synth/sample_rate"), "{w}");
        // The paper engine has no sub-steps to lower; neither has a count already at 6.
        for substeps in [None, Some(6)] {
            let w = behind_warning(&a, &b, Duration::from_millis(500), substeps).unwrap();
            assert!(!w.contains("contact_substeps"), "{w}");
            assert!(w.contains("/synth/sample_rate"), "{w}");
        }
    }
}
