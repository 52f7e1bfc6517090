//! The `image` stream's worker: a thread that joins the synthesiser's topography and the
//! DSP's pixel harmonics into image lines, adds the FT-AFM channels (contact time, peak
//! force, modulus per pixel, by the live inversion's estimator), sends each finished trace
//! line and keeps the last finished frame for export (`GET /image/<channel>.gsf|.npy`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{
    Receiver, RecvTimeoutError, SyncSender, TrySendError, channel, sync_channel,
};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::build_budget::BuildBudget;
use super::latest::Latest;
use crate::config::Settings;
use crate::imaging::{Assembler, ImageFrame, ImageLine};
use crate::pipeline::PixelHarmonics;
use crate::synth::PixelTopography;

/// Pixels waiting for the worker: 16 s at the default scan's 256 pixels/s (trace and
/// retrace), 0.8 s at the fastest allowed.
const QUEUE: usize = 1 << 14;

#[allow(clippy::large_enum_variant)]
enum Input {
    Pixel(PixelHarmonics),
    Topography(PixelTopography),
    /// New settings wait in [`ImageLink::pending`]: wake up and take them.
    Reconfigure,
}

/// Counts of the worker's work.
#[derive(Default)]
pub(crate) struct ImageCounters {
    pub lines: AtomicU64,
    pub frames: AtomicU64,
    /// Pixel records the worker's queue refused.
    pub dropped: AtomicU64,
    /// Pixels whose inversion failed (their FT-AFM channels are missing).
    pub inversion_failed: AtomicU64,
    /// Settings changes taken up (while a scan runs, one that changes what the per-pixel
    /// estimator models rebuilds it: 0.1 s on the paper engine, 0.5–1.6 s on the coupled).
    pub rebuilds: AtomicU64,
}

/// The hub's and the HTTP handlers' ends of the worker.
pub(crate) struct ImageLink {
    input: SyncSender<Input>,
    pub counters: Arc<ImageCounters>,
    /// The last finished frame.
    pub last_frame: Arc<Mutex<Option<Arc<ImageFrame>>>>,
    /// The newest settings not yet taken up: a flood of changes costs one rebuild at a
    /// time, never a queue of them.
    pub pending: Arc<Latest<(Box<Settings>, u64)>>,
    /// The newest settings epoch committed, whether or not its change concerns the images:
    /// a line made once every change that does is taken up reflects it.
    committed: Arc<AtomicU64>,
}

impl ImageLink {
    /// Starts the worker for `settings`; lines come out of the returned receiver.
    pub fn start(settings: &Settings) -> (Self, Receiver<ImageLine>) {
        let (input, rx) = sync_channel::<Input>(QUEUE);
        let (out, lines) = channel();
        let counters = Arc::new(ImageCounters::default());
        let last_frame = Arc::new(Mutex::new(None));
        let mut assembler = Assembler::new(settings);
        let pending: Arc<Latest<(Box<Settings>, u64)>> = Arc::new(Latest::new());
        let committed = Arc::new(AtomicU64::new(0));
        let (c, done, waiting) = (counters.clone(), last_frame.clone(), pending.clone());
        let newest = committed.clone();
        std::thread::Builder::new()
            .name("image".into())
            .spawn(move || {
                // Rebuilds are rationed like the force stream's: a flood of changes must not
                // take a core from the real-time threads.
                let mut budget = BuildBudget::new();
                // The epoch of the settings the assembler was configured for.
                let mut epoch = 0;
                loop {
                    let rest = if waiting.is_pending() {
                        budget.wait(Instant::now())
                    } else {
                        Duration::ZERO
                    };
                    let msg = if !rest.is_zero() {
                        match rx.recv_timeout(rest) {
                            Ok(m) => m,
                            Err(RecvTimeoutError::Timeout) => Input::Reconfigure,
                            Err(RecvTimeoutError::Disconnected) => return,
                        }
                    } else {
                        match rx.recv() {
                            Ok(m) => m,
                            Err(_) => return,
                        }
                    };
                    // Settings come before the message that follows them.
                    if budget.wait(Instant::now()).is_zero()
                        && let Some((s, e)) = waiting.take()
                    {
                        let start = Instant::now();
                        c.rebuilds.fetch_add(1, Ordering::Relaxed);
                        assembler.configure(&s);
                        epoch = e;
                        budget.spend(start.elapsed(), Instant::now());
                    }
                    match msg {
                        Input::Reconfigure => {}
                        Input::Topography(t) => assembler.topography(t),
                        Input::Pixel(p) => {
                            let (before, misplaced) =
                                (assembler.inversion_failed, assembler.misplaced);
                            let lines = assembler.pixel(&p);
                            let failed = assembler.inversion_failed - before;
                            c.inversion_failed.fetch_add(failed, Ordering::Relaxed);
                            c.dropped
                                .fetch_add(assembler.misplaced - misplaced, Ordering::Relaxed);
                            for mut line in lines {
                                c.lines.fetch_add(1, Ordering::Relaxed);
                                // The newest epoch first: a change that concerns the
                                // images is pending before its epoch is committed here.
                                let seen = newest.load(Ordering::SeqCst);
                                line.stale = waiting.is_pending();
                                // Taken up all that concern it, the line reflects every
                                // later change too (they leave it as it is).
                                line.epoch = if line.stale { epoch } else { epoch.max(seen) };
                                if let Some(frame) = assembler.take_finished() {
                                    c.frames.fetch_add(1, Ordering::Relaxed);
                                    if let Ok(mut last) = done.lock() {
                                        *last = Some(Arc::new(frame));
                                    }
                                }
                                if out.send(line).is_err() {
                                    return;
                                }
                            }
                        }
                    }
                }
            })
            .expect("the image thread starts");
        (
            Self {
                input,
                counters,
                last_frame,
                pending,
                committed,
            },
            lines,
        )
    }

    fn offer(&self, msg: Input) {
        if let Err(TrySendError::Full(_)) = self.input.try_send(msg) {
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Offers a pixel's harmonics; a full queue drops it (counted).
    pub fn pixel(&self, p: &PixelHarmonics) {
        self.offer(Input::Pixel(*p));
    }

    /// Offers a pixel's topography.
    pub fn topography(&self, t: &PixelTopography) {
        self.offer(Input::Topography(*t));
    }

    /// Settings of epoch `epoch` committed, whatever they changed: called after
    /// [`configure`](Self::configure) for a change that concerns the images.
    pub fn committed(&self, epoch: u64) {
        self.committed.fetch_max(epoch, Ordering::SeqCst);
    }

    /// New settings, of epoch `epoch`: the worker rebuilds its estimator for the newest of
    /// them (blocking only itself).
    pub fn configure(&self, settings: &Settings, epoch: u64) {
        // One wake-up per settings taken up; if the queue is full the worker takes the
        // settings with the next message it handles anyway.
        if self.pending.put((Box::new(settings.clone()), epoch)) {
            let _ = self.input.try_send(Input::Reconfigure);
        }
    }
}

/// Whether a change of `path` concerns the image worker.
pub(crate) fn affects_images(path: &str) -> bool {
    super::force::affects_estimator(path)
        || path.starts_with("/scan")
        || path.starts_with("/sample")
}
