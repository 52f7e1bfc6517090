//! The signal chain's threads and what connects them.
//!
//! ```text
//! control (any thread) ──plans──► synth thread ──window samples + headers (SPSC rings)──► dsp thread ──frames──► output
//!        ◄──old plans (freed here)──┘                                                        │
//!        ◄──────────────────────────────────────────old plans────────────────────────────────┘
//! ```
//!
//! With `/source/kind = "stream"` the synthesiser thread passes a client's samples on from
//! the [`SampleInlet`] (`feed`) instead of synthesising: the same ring, headers and DSP,
//! on a reference tied to the writer's sample count.
//!
//! New settings become plans off the real-time threads ([`Pipeline::apply`]); the threads
//! swap them in between blocks and send the old ones back, so nothing is allocated or freed
//! on a real-time thread. The synthesiser never waits in real time: a full ring drops the
//! block and counts it. Every header carries the exact drive phase, so the lock-in
//! reference follows the synthesiser through frequency changes and overruns.
//!
//! The ring carries the signal through the ADC's window, not samples: the DSP thread runs
//! the ADC's FIRs, detector noise and quantiser ([`crate::synth::digitiser`]) from the
//! filter's histories in each header, which takes them off the busier synthesiser and
//! leaves every block self-contained. A scan's blocks are the exception: its feedback reads
//! the samples, so the synthesiser finishes them and the header says so.

mod block;
mod counters;
mod dsp_plan;
mod dsp_team;
mod dsp_worker;
mod epochs;
mod feed;
mod frame_signal;
mod frames;
mod pid_board;
pub mod realtime;
mod scope;
pub mod stall;
mod synth_worker;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use ringbuf::traits::{Consumer, Observer, Producer, Split};
use ringbuf::{HeapCons, HeapProd, HeapRb};

pub use block::{BlockHeader, unix_ns};
pub use counters::{Counters, CountersSnapshot};
pub use dsp_plan::{DspPlan, DspSink, MAX_DSP_THREADS, demodulators, dsp_threads};
pub use dsp_team::DspTeam;
pub use epochs::Epochs;
pub use feed::{
    FRAME_HEADER_BYTES, FRAME_MAGIC, FrameError, FrameHeader, FrameReceipt, SampleInlet, SampleType,
};
pub use frame_signal::FrameSignal;
pub use frames::{DemodFrame, DemodValue, PixelHarmonics, ScopeBuffer, SpectrumBuffer};
pub use pid_board::{PID_EVENT_QUEUE, PID_EVENTS_PER_BLOCK, PidBoard, PidEvent, PidUpdate};
pub use scope::MAX_SCOPE_SAMPLES;
pub use stall::{StallEvent, StallMeter};
pub use synth_worker::BLOCK_SAMPLES;

use crate::config::{MAX_SPECTRUM_SIZE, Settings};
use crate::dsp::DspError;
use crate::synth::{
    Digitiser, PENDING_REFERENCES, PidRuntime, PixelTopography, PlanError, ReferenceChange,
    ScanRuntime, SynthPlan, SynthState, TapTables, WindowSample,
};
use dsp_worker::DspWorker;
use synth_worker::SynthWorker;

/// The sample ring holds at least this long of the stream (s): the DSP thread may fall half
/// a second behind the synthesiser (descheduled beside a browser on two vCPUs, say) before
/// anything is lost. Only a DSP that is behind makes its outputs late; one that keeps up
/// keeps the ring nearly empty.
pub const RING_SECONDS: f64 = 0.5;
/// The sample ring's least capacity (samples): 1.05 s at 2 MS/s.
pub const SAMPLE_RING: usize = 1 << 21;
/// The sample ring's largest capacity (samples, 256 MiB of window samples): 0.67 s at
/// 25 MS/s, 0.17 s at 100 MS/s (rates that run in real time nowhere yet).
pub const SAMPLE_RING_MAX: usize = 1 << 24;

/// The sample ring's capacity (samples) at `sample_rate` (S/s): [`RING_SECONDS`] of the
/// stream in whole blocks, within [`SAMPLE_RING`] … [`SAMPLE_RING_MAX`]. 5 001 216 samples
/// (80 MB of 16-byte window samples) at the defaults' 10 MS/s, 12 500 992 (200 MB) at
/// 25 MS/s.
pub fn ring_samples(sample_rate: f64) -> usize {
    let blocks = (RING_SECONDS * sample_rate / BLOCK_SAMPLES as f64).ceil();
    // `as` saturates a NaN or huge product, which the clamp then bounds.
    (blocks as usize)
        .saturating_mul(BLOCK_SAMPLES)
        .clamp(SAMPLE_RING, SAMPLE_RING_MAX)
}
/// Plans in flight per thread (queued plus waiting to be freed).
const PLAN_SLOTS: usize = 4;
/// How long [`Pipeline::apply`] waits for the threads to take queued plans before it
/// answers busy: many blocks, even on a loaded machine.
const PLAN_WAIT: std::time::Duration = std::time::Duration::from_millis(250);
/// Demodulator frames queued for the consumer: 4 s at 1 kHz.
const DEMOD_QUEUE: usize = 4096;
/// Scan pixels queued for the consumer, from each thread: 2 s at the fastest scan.
pub const PIXEL_QUEUE: usize = 1 << 15;
/// Buffers in each pool (spectra, scope traces).
const POOL_BUFFERS: usize = 8;

/// Holds every DSP thread of the process idle while set: see [`hold_all_dsp`].
static HOLD_ALL_DSP: AtomicBool = AtomicBool::new(false);

/// Fault injection for tests and drills, never used by the daemon itself: while `hold` is
/// true every DSP thread of the process takes no samples (as if wedged), so the ring
/// overruns and `/healthz` must report the stall; it still stops when asked. Prefer
/// [`Pipeline::hold_dsp`] where the pipeline is at hand.
#[doc(hidden)]
pub fn hold_all_dsp(hold: bool) {
    HOLD_ALL_DSP.store(hold, Ordering::Relaxed);
}

/// Why the pipeline could not start or take new settings.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The synthesiser's plan could not be built.
    #[error(transparent)]
    Synth(#[from] PlanError),
    /// The DSP stage could not be built.
    #[error(transparent)]
    Dsp(#[from] DspError),
    /// Too many settings changes are still being taken up; try again.
    #[error("settings changes are arriving faster than the real-time threads take them up")]
    Busy,
    /// A setting that only takes effect on restart changed.
    #[error("{0} cannot change while the pipeline runs")]
    Restart(&'static str),
    /// A thread could not be started.
    #[error("cannot start the {0} thread: {1}")]
    Thread(&'static str, std::io::Error),
}

/// Returns the whole pages of `v`'s spare capacity to the system (`MADV_DONTNEED`): the
/// pools' buffers are sized for the largest spectrum and trace (so the real-time threads never
/// allocate), and after a large spectrum they would otherwise keep it resident for good. The
/// capacity stays; a page touched again later is a fresh zero page. Called off the real-time
/// threads, when a buffer comes back to its pool.
fn release_spare_pages<T>(v: &mut Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let size = std::mem::size_of::<T>();
        let base = v.as_mut_ptr() as usize;
        let start = (base + v.len() * size).div_ceil(PAGE) * PAGE;
        let end = (base + v.capacity() * size) / PAGE * PAGE;
        if end > start {
            // SAFETY: [start, end) lies inside the Vec's allocation, beyond its initialised
            // elements (spare capacity holds no values); MADV_DONTNEED on private anonymous
            // memory only makes those pages read as zeros when next touched.
            unsafe {
                libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_DONTNEED);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
}

/// Frames for the consumer (the server, a bench, a test).
pub struct PipelineOutput {
    /// Demodulator frames, in time order.
    pub demods: HeapCons<DemodFrame>,
    /// Spectrum frames, in time order; return each buffer with [`recycle`](Self::recycle).
    pub spectra: HeapCons<SpectrumBuffer>,
    free_spectra: HeapProd<SpectrumBuffer>,
    /// Scope traces, in time order; return each buffer with
    /// [`recycle_scope`](Self::recycle_scope).
    pub scopes: HeapCons<ScopeBuffer>,
    free_scopes: HeapProd<ScopeBuffer>,
    /// Scan pixels' harmonics from the DSP thread, in scan order.
    pub pixels: HeapCons<PixelHarmonics>,
    /// Scan pixels' height and amplitude from the synthesiser, in scan order.
    pub topography: HeapCons<PixelTopography>,
    /// Every PID update while the `pids` stream has subscribers
    /// ([`PidBoard::set_streaming`]), in time order.
    pub pid_events: HeapCons<PidEvent>,
    /// Signalled by the DSP thread after each block that produced demodulator frames
    /// (`None` where the system has no such signal: poll instead).
    pub signal: Option<Arc<FrameSignal>>,
    /// Where a client's streamed samples go in (`/source/kind = "stream"`).
    pub inlet: Arc<SampleInlet>,
}

impl PipelineOutput {
    /// Gives a spectrum buffer back to the pool, the pages of its unused capacity back to
    /// the system.
    pub fn recycle(&mut self, mut buffer: SpectrumBuffer) {
        release_spare_pages(&mut buffer.magnitudes);
        let _ = self.free_spectra.try_push(buffer);
    }

    /// Gives a scope buffer back to the pool, the pages of its unused capacity back to the
    /// system.
    pub fn recycle_scope(&mut self, mut buffer: ScopeBuffer) {
        release_spare_pages(&mut buffer.samples);
        let _ = self.free_scopes.try_push(buffer);
    }

    /// Drains every queued frame (recycling buffers), pixel and PID update; returns
    /// (demod, spectrum, scope) counts.
    pub fn drain(&mut self) -> (usize, usize, usize) {
        let demods = self.demods.skip(usize::MAX);
        let mut spectra = 0;
        while let Some(b) = self.spectra.try_pop() {
            self.recycle(b);
            spectra += 1;
        }
        let mut scopes = 0;
        while let Some(b) = self.scopes.try_pop() {
            self.recycle_scope(b);
            scopes += 1;
        }
        self.pixels.skip(usize::MAX);
        self.topography.skip(usize::MAX);
        self.pid_events.skip(usize::MAX);
        (demods, spectra, scopes)
    }
}

/// Control ends of one real-time thread's plan hand-off.
struct PlanLink<P> {
    to_thread: HeapProd<Box<P>>,
    from_thread: HeapCons<Box<P>>,
}

impl<P> PlanLink<P> {
    /// Frees what the thread gave back; whether another plan may be queued. Plans in
    /// flight (queued, held by the thread until their epoch arrives, and not yet returned)
    /// stay within the capacity, so the thread's return push always has room and never
    /// has to free anything itself. One slot is kept for the plan the thread may hold.
    fn has_room(&mut self) -> bool {
        drop(self.take_returned());
        self.to_thread.occupied_len() + self.from_thread.occupied_len() < PLAN_SLOTS - 1
    }

    /// The plans the thread has given back since the last call.
    fn take_returned(&mut self) -> Vec<Box<P>> {
        self.from_thread.pop_iter().collect()
    }

    /// Queues `plan`; call only after [`has_room`](Self::has_room) said yes.
    fn send(&mut self, plan: Box<P>) {
        let _ = self.to_thread.try_push(plan);
    }
}

/// A pool of `POOL_BUFFERS` buffers: the queue to the consumer (producer, consumer) and the
/// free list back (producer, consumer), the free list filled by `make`.
fn pool<T>(make: impl Fn() -> T) -> (HeapProd<T>, HeapCons<T>, HeapProd<T>, HeapCons<T>) {
    let (full_in, full_out) = HeapRb::<T>::new(POOL_BUFFERS).split();
    let (mut free_in, free_out) = HeapRb::<T>::new(POOL_BUFFERS).split();
    for _ in 0..POOL_BUFFERS {
        let _ = free_in.try_push(make());
    }
    (full_in, full_out, free_in, free_out)
}

fn plan_link<P>() -> (PlanLink<P>, HeapCons<Box<P>>, HeapProd<Box<P>>) {
    let (to_thread, thread_in) = HeapRb::new(PLAN_SLOTS).split();
    let (thread_out, from_thread) = HeapRb::new(PLAN_SLOTS).split();
    (
        PlanLink {
            to_thread,
            from_thread,
        },
        thread_in,
        thread_out,
    )
}

/// The running signal chain: a synthesiser thread and a DSP thread (with the DSP's worker
/// threads, if `/dsp/threads` asks for them).
pub struct Pipeline {
    settings: Settings,
    counters: Arc<Counters>,
    stop_synth: Arc<AtomicBool>,
    stop_dsp: Arc<AtomicBool>,
    hold_dsp: Arc<AtomicBool>,
    realtime: Arc<AtomicBool>,
    synth_link: PlanLink<SynthPlan>,
    dsp_link: PlanLink<DspPlan>,
    synth_thread: Option<JoinHandle<()>>,
    dsp_thread: Option<JoinHandle<()>>,
    /// The scan's tap tables, kept so that a change of the raster or the gains does not
    /// solve them again.
    tap_tables: Option<Arc<TapTables>>,
    /// Published settings epochs and where they took effect.
    epochs: Arc<Epochs>,
    /// The last epoch published.
    epoch: u64,
    /// Where streamed samples go in: open while `/source/kind` is `stream`.
    inlet: Arc<SampleInlet>,
}

/// Plans the real-time threads have given back, to be freed by whoever holds them. A large
/// plan (a 2^20-point spectrum's buffers: ≈ 40 MB) would otherwise wait in the return queue
/// until the next change of settings.
#[derive(Default)]
// The boxes come off the return rings as they are: kept boxed, nothing is moved.
#[allow(clippy::vec_box)]
pub struct RetiredPlans {
    synth: Vec<Box<SynthPlan>>,
    dsp: Vec<Box<DspPlan>>,
}

impl RetiredPlans {
    /// Whether there is nothing to free.
    pub fn is_empty(&self) -> bool {
        self.synth.is_empty() && self.dsp.is_empty()
    }
}

impl Pipeline {
    /// Takes the plans the threads have given back, so the caller frees them where freeing
    /// costs nothing that matters (off the real-time threads, and outside any lock).
    pub fn take_retired(&mut self) -> RetiredPlans {
        RetiredPlans {
            synth: self.synth_link.take_returned(),
            dsp: self.dsp_link.take_returned(),
        }
    }

    /// Builds the plans for `settings` and starts both threads.
    pub fn start(settings: &Settings) -> Result<(Self, PipelineOutput), PipelineError> {
        let synth_plan = Box::new(SynthPlan::new(settings)?);
        let tap_tables = synth_plan.scan.as_ref().and_then(|s| s.tables.clone());
        let dsp_plan = Box::new(DspPlan::new(settings)?);
        // Workers for the shards beyond the DSP thread's own, as many as `/dsp/threads` asks
        // (fixed while running): a later plan with more demodulators enabled than this one
        // may have more shards than this plan's, and its shards still get a thread each.
        // A worker without a shard stays parked.
        let team = DspTeam::spawn(dsp_plan::dsp_threads(settings) - 1, settings.synth.realtime)
            .map_err(|e| PipelineError::Thread("dsp worker", e))?;
        let mut state = SynthState::steady(&synth_plan, settings.synth.seed);
        let (noise_supply, noise_factory) = crate::synth::noise_pages::page_queue();
        state.attach_noise_supply(noise_supply);

        let ring = ring_samples(settings.synth.sample_rate);
        let (samples_in, samples_out) = HeapRb::<WindowSample>::new(ring).split();
        let (headers_in, headers_out) =
            HeapRb::<BlockHeader>::new(ring / BLOCK_SAMPLES + 1).split();
        let (demods_in, demods_out) = HeapRb::<DemodFrame>::new(DEMOD_QUEUE).split();
        // One change of each oscillator's reference per drive period at most, for drives
        // up to a sixteenth of the sample rate, for the whole sample ring.
        let (references_in, references_out) =
            HeapRb::<ReferenceChange>::new(ring / 8 + PENDING_REFERENCES).split();
        // Pools sized for the largest spectrum and trace the settings allow, so a live change
        // of /spectrum/size or /scope/length never needs a bigger buffer on the DSP thread.
        let (spectra_in, spectra_out, free_in, free_out) = pool(|| SpectrumBuffer {
            sample_index: 0,
            t: 0.0,
            t_synth_ns: 0,
            t_dsp_ns: 0,
            bin_width: 0.0,
            magnitudes: Vec::with_capacity(MAX_SPECTRUM_SIZE as usize / 2 + 1),
        });
        let (scopes_in, scopes_out, free_scopes_in, free_scopes_out) =
            pool(|| ScopeBuffer::with_capacity(MAX_SCOPE_SAMPLES));
        let (pixels_in, pixels_out) = HeapRb::<PixelHarmonics>::new(PIXEL_QUEUE).split();
        let (topography_in, topography_out) = HeapRb::<PixelTopography>::new(PIXEL_QUEUE).split();
        let (pid_events_in, pid_events_out) = HeapRb::<PidEvent>::new(PID_EVENT_QUEUE).split();
        let (synth_link, synth_plans_in, synth_plans_out) = plan_link();
        let (dsp_link, dsp_plans_in, dsp_plans_out) = plan_link();

        let counters = Arc::new(Counters::default());
        // The feed holds as long of a stream as the sample ring does.
        let (inlet, feed) = feed::feed(ring, settings.synth.sample_rate, counters.clone());
        let inlet = Arc::new(inlet);
        inlet.accept(settings.source.kind == crate::config::SourceKind::Stream);
        let signal = FrameSignal::new().map(Arc::new);
        let stop_synth = Arc::new(AtomicBool::new(false));
        let stop_dsp = Arc::new(AtomicBool::new(false));
        let hold_dsp = Arc::new(AtomicBool::new(false));
        // The heartbeats' clock starts here, off the real-time threads.
        counters::monotonic_ns();
        let realtime = Arc::new(AtomicBool::new(settings.synth.realtime));
        let epochs = Arc::new(Epochs::default());
        let scan = ScanRuntime::new(&synth_plan);
        let pids = PidRuntime::new(&synth_plan);
        let mut synth = SynthWorker {
            plan: synth_plan,
            state,
            scan,
            pids,
            topography: topography_in,
            pid_events: pid_events_in,
            block_pid_readings: Vec::with_capacity(PID_EVENTS_PER_BLOCK),
            samples: samples_in,
            headers: headers_in,
            references: references_in,
            reference_changes: Vec::with_capacity(BLOCK_SAMPLES + PENDING_REFERENCES),
            plans_in: synth_plans_in,
            plans_out: synth_plans_out,
            counters: counters.clone(),
            stop: stop_synth.clone(),
            realtime: realtime.clone(),
            consumer: None,
            epochs: epochs.clone(),
            pending: None,
            feed,
        };
        let dsp = DspWorker {
            plan: dsp_plan,
            samples: samples_out,
            headers: headers_out,
            references: references_out,
            plans_in: dsp_plans_in,
            plans_out: dsp_plans_out,
            demods: demods_in,
            spectra: spectra_in,
            free_spectra: free_out,
            counters: counters.clone(),
            stop: stop_dsp.clone(),
            spare: None,
            scopes: scopes_in,
            free_scopes: free_scopes_out,
            scope_current: None,
            scope_spare: None,
            pixels: pixels_in,
            pixel_open: None,
            pixel_next: None,
            hold: hold_dsp.clone(),
            pixel_frame: DemodFrame::empty(),
            signal: signal.clone(),
            pending: None,
            epochs: epochs.clone(),
            team,
            noise: noise_factory,
            digitiser: Digitiser::new(BLOCK_SAMPLES),
            finished: vec![0.0; BLOCK_SAMPLES],
        };
        let mut pipeline = Self {
            settings: settings.clone(),
            counters,
            stop_synth,
            stop_dsp,
            hold_dsp,
            realtime,
            synth_link,
            dsp_link,
            synth_thread: None,
            dsp_thread: None,
            tap_tables,
            epochs,
            epoch: 0,
            inlet: inlet.clone(),
        };
        let spawn = |name: &'static str, f: Box<dyn FnOnce() + Send>| {
            let paced = settings.synth.realtime;
            std::thread::Builder::new()
                .name(format!("ftafm-{name}"))
                .spawn(move || {
                    realtime::promote(name, paced);
                    f()
                })
                .map_err(|e| PipelineError::Thread(name, e))
        };
        let dsp_thread = spawn("dsp", Box::new(move || dsp.run()))?;
        synth.consumer = Some(dsp_thread.thread().clone());
        pipeline.dsp_thread = Some(dsp_thread);
        pipeline.synth_thread = Some(spawn("synth", Box::new(move || synth.run()))?);
        let output = PipelineOutput {
            demods: demods_out,
            spectra: spectra_out,
            free_spectra: free_in,
            scopes: scopes_out,
            free_scopes: free_scopes_in,
            pixels: pixels_out,
            topography: topography_out,
            pid_events: pid_events_out,
            signal,
            inlet,
        };
        Ok((pipeline, output))
    }

    /// The settings in force.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The counters now.
    pub fn counters(&self) -> CountersSnapshot {
        self.counters.snapshot()
    }

    /// The counters themselves, to read without holding the pipeline.
    pub fn counters_handle(&self) -> Arc<Counters> {
        self.counters.clone()
    }

    /// Fault injection for tests: while `hold` is true the DSP thread takes no samples (as
    /// if wedged; the synthesiser overruns the ring, counted), and it still stops when asked.
    #[doc(hidden)]
    pub fn hold_dsp(&self, hold: bool) {
        self.hold_dsp.store(hold, Ordering::Relaxed);
        if let Some(t) = &self.dsp_thread {
            t.thread().unpark();
        }
    }

    /// Where settings epoch `epoch` (from [`apply`](Self::apply)) took effect: the stream
    /// index of its first sample, waiting up to `timeout` for the synthesiser to get there
    /// (`None` if it did not, e.g. free-running with the DSP held).
    pub fn effective_index(&self, epoch: u64, timeout: std::time::Duration) -> Option<u64> {
        self.epochs.wait_effective(epoch, timeout)
    }

    /// The settings epochs and where they took effect in each thread.
    pub fn epochs(&self) -> &Epochs {
        &self.epochs
    }

    /// Takes up new settings: rebuilds (here, off the real-time threads) the plans whose
    /// inputs changed and hands them over; both threads switch at the same block boundary.
    /// The 1-DOF solve of a physics change takes a few milliseconds. Returns the settings
    /// epoch it published, for [`effective_index`](Self::effective_index). On error nothing
    /// changes.
    pub fn apply(&mut self, settings: &Settings) -> Result<u64, PipelineError> {
        self.apply_writing(settings, 0)
    }

    /// [`apply`](Self::apply) for a change that wrote the nodes of the outputs `written`
    /// ([`PidTarget::written`](crate::config::PidTarget::written)): an output a stopped
    /// unit holds goes back to its node even where the node's value is unchanged.
    pub fn apply_writing(
        &mut self,
        settings: &Settings,
        written: u64,
    ) -> Result<u64, PipelineError> {
        // Only what a unit holds needs the synthesiser (the mask is the one it published
        // with the plan in force).
        let release = written & self.counters.pids.held_mask();
        let old = &self.settings;
        if settings.synth.sample_rate != old.synth.sample_rate {
            return Err(PipelineError::Restart("/synth/sample_rate"));
        }
        if settings.dsp != old.dsp {
            return Err(PipelineError::Restart("/dsp/threads"));
        }
        // Everything the synthesis plan is built from; the pacing (`/synth/realtime`) is a
        // flag the threads read, not part of the plan.
        let unpaced = |s: &Settings| crate::config::SynthSettings {
            realtime: false,
            ..s.synth.clone()
        };
        let synth_changed = settings.cantilever != old.cantilever
            || settings.tip != old.tip
            || settings.sample != old.sample
            || settings.drive != old.drive
            // The second excitation: its steady motion, and the phase word every
            // demodulator on it is aligned to at each block (no DSP plan needed).
            || settings.drive2 != old.drive2
            || settings.surface != old.surface
            || settings.adhesion != old.adhesion
            || settings.noise != old.noise
            || unpaced(settings) != unpaced(old)
            || settings.scan != old.scan
            || settings.feedback != old.feedback
            || settings.inclusions != old.inclusions
            || settings.pids != old.pids
            || settings.source != old.source
            || release != 0;
        // A drive change can move demodulators in or out of band, which the bank must follow.
        let dsp_changed = settings.demods != old.demods
            || settings.demods_out_of_band() != old.demods_out_of_band()
            || settings.spectrum != old.spectrum
            || settings.scope != old.scope;
        // Build both and check both links before sending either, so a failure changes
        // nothing.
        let synth = synth_changed
            .then(|| SynthPlan::with_tables(settings, self.tap_tables.as_ref()))
            .transpose()?;
        let mut dsp = dsp_changed.then(|| DspPlan::new(settings)).transpose()?;
        let epoch = self.epoch + 1;
        if let Some(plan) = &mut dsp {
            plan.epoch = epoch;
        }
        // The threads take a plan between blocks: a burst of changes waits for them a
        // little rather than failing at once.
        let waiting_since = std::time::Instant::now();
        loop {
            let synth_room = synth.is_none() || self.synth_link.has_room();
            let dsp_room = dsp.is_none() || self.dsp_link.has_room();
            if synth_room && dsp_room {
                break;
            }
            if waiting_since.elapsed() > PLAN_WAIT {
                return Err(PipelineError::Busy);
            }
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
        let stream = settings.source.kind == crate::config::SourceKind::Stream;
        // Closed before the plan goes (nothing enters after the synthesiser empties the
        // feed), opened after it (what comes waits in the feed for the plan).
        if !stream {
            self.inlet.accept(false);
        }
        if let Some(mut plan) = synth {
            plan.epoch = epoch;
            plan.release = release;
            if let Some(tables) = plan.scan.as_ref().and_then(|s| s.tables.clone()) {
                self.tap_tables = Some(tables);
            }
            self.synth_link.send(Box::new(plan));
        }
        if let Some(plan) = dsp {
            self.dsp_link.send(Box::new(plan));
        }
        if stream {
            self.inlet.accept(true);
        }
        // Published after the plans are queued: the synthesiser takes them all up with the
        // first block it stamps with this epoch.
        self.epoch = epoch;
        self.epochs.requested.store(epoch, Ordering::Release);
        self.realtime
            .store(settings.synth.realtime, Ordering::Relaxed);
        self.settings = settings.clone();
        Ok(epoch)
    }

    /// Stops both threads, waits for them and returns the final counters, for which
    /// `samples_synthesized = samples_processed + overrun_samples + ring_fill` holds exactly.
    pub fn stop(mut self) -> CountersSnapshot {
        self.shutdown();
        self.counters.snapshot()
    }

    fn shutdown(&mut self) {
        // The synthesiser first, so nothing enters the ring after the DSP's last look.
        self.stop_synth.store(true, Ordering::Relaxed);
        if let Some(t) = self.synth_thread.take() {
            let _ = t.join();
        }
        self.stop_dsp.store(true, Ordering::Relaxed);
        if let Some(t) = self.dsp_thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod ring_tests {
    use super::*;

    /// Half a second of the stream in whole blocks, within the least and largest ring.
    #[test]
    fn the_sample_ring_holds_half_a_second_within_its_bounds() {
        for rate in [1e3, 2e6, 10e6, 25e6, 40e6, 1e9] {
            let ring = ring_samples(rate);
            assert_eq!(ring % BLOCK_SAMPLES, 0, "{rate}");
            assert!((SAMPLE_RING..=SAMPLE_RING_MAX).contains(&ring), "{rate}");
            let seconds = ring as f64 / rate;
            if ring > SAMPLE_RING && ring < SAMPLE_RING_MAX {
                assert!(seconds >= RING_SECONDS, "{rate}: {seconds} s");
                assert!(
                    seconds < RING_SECONDS + BLOCK_SAMPLES as f64 / rate,
                    "{rate}"
                );
            }
        }
        assert_eq!(ring_samples(10e6), 5_001_216);
        assert_eq!(ring_samples(25e6), 12_500_992);
        assert_eq!(ring_samples(2e6), SAMPLE_RING);
        assert_eq!(ring_samples(1e9), SAMPLE_RING_MAX);
    }
}
