//! The `force` stream's worker: a thread that owns the [`ForceEstimator`] and turns the
//! demodulator frames the hub forwards into force estimates. Its own thread, so an
//! expensive inversion never delays the other streams; frames it cannot take in time are
//! dropped and counted.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, channel, sync_channel};

use crate::config::Settings;
use crate::inversion::{ForceEstimate, ForceEstimator};
use crate::pipeline::DemodFrame;

/// Frames waiting for the worker: 0.25 s at 1 kHz.
const QUEUE: usize = 256;

// Frames travel by value: boxing them would allocate a thousand times a second, and the
// queue's 256 slots of ~1.3 kB are allocated once.
#[allow(clippy::large_enum_variant)]
pub(crate) enum Input {
    Frame(DemodFrame),
    /// A new estimator and its generation: builds finish in any order, the newest wins.
    Replace(u64, Option<Box<ForceEstimator>>),
}

/// Counts of the worker's work.
#[derive(Default)]
pub(crate) struct ForceCounters {
    pub estimates: AtomicU64,
    pub failed: AtomicU64,
    pub dropped: AtomicU64,
    pub rebuilds: AtomicU64,
    /// Why the estimator or the last estimate failed, if it did (for logs).
    pub last_error: std::sync::Mutex<String>,
}

/// The hub's and the control plane's ends of the worker.
pub(crate) struct ForceLink {
    input: SyncSender<Input>,
    pub counters: Arc<ForceCounters>,
    /// Generation of the latest rebuild requested.
    generation: AtomicU64,
}

impl ForceLink {
    /// Starts the worker thread; estimates come out of the returned receiver.
    pub fn start() -> (Self, Receiver<ForceEstimate>) {
        let (input, rx) = sync_channel::<Input>(QUEUE);
        let (out, estimates) = channel();
        let counters = Arc::new(ForceCounters::default());
        let c = counters.clone();
        std::thread::Builder::new()
            .name("inversion".into())
            .spawn(move || {
                let mut estimator: Option<Box<ForceEstimator>> = None;
                let mut applied = 0;
                while let Ok(msg) = rx.recv() {
                    match msg {
                        Input::Replace(generation, next) => {
                            if generation > applied {
                                applied = generation;
                                estimator = next;
                            }
                        }
                        Input::Frame(frame) => {
                            let Some(e) = estimator.as_mut() else {
                                continue;
                            };
                            match e.push(&frame) {
                                Some(Ok(estimate)) => {
                                    c.estimates.fetch_add(1, Ordering::Relaxed);
                                    if out.send(estimate).is_err() {
                                        return;
                                    }
                                }
                                Some(Err(err)) => {
                                    c.failed.fetch_add(1, Ordering::Relaxed);
                                    if let Ok(mut last) = c.last_error.lock() {
                                        *last = err.to_string();
                                    }
                                }
                                None => {}
                            }
                        }
                    }
                }
            })
            .expect("the inversion thread starts");
        (
            Self {
                input,
                counters,
                generation: AtomicU64::new(0),
            },
            estimates,
        )
    }

    /// Offers a frame; a full queue drops it (counted).
    pub fn offer(&self, frame: &DemodFrame) {
        if let Err(TrySendError::Full(_)) = self.input.try_send(Input::Frame(*frame)) {
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Builds the estimator for `settings` on a blocking thread and hands it over
    /// (the modulus table and the lock-in model take ~0.1 s).
    pub fn rebuild(&self, settings: Settings) {
        let generation = self.generation.fetch_add(1, Ordering::SeqCst) + 1;
        let input = self.input.clone();
        let counters = self.counters.clone();
        tokio::task::spawn_blocking(move || {
            let next = match ForceEstimator::new(&settings) {
                Ok(e) => e.map(Box::new),
                Err(err) => {
                    tracing::warn!(error = %err, "force estimator unavailable");
                    if let Ok(mut last) = counters.last_error.lock() {
                        *last = err;
                    }
                    None
                }
            };
            counters.rebuilds.fetch_add(1, Ordering::Relaxed);
            let _ = input.send(Input::Replace(generation, next));
        });
    }
}

/// Whether a change of `path` changes the estimator (its cantilever, drive, setpoint, tip,
/// sample Poisson ratio, demodulators, inversion settings, the noise it predicts for each
/// harmonic or the sample rate that sets the aliases; not the sample's modulus, which is
/// what it measures).
pub(crate) fn affects_estimator(path: &str) -> bool {
    [
        "/inversion",
        "/cantilever",
        "/tip",
        "/sample/poisson",
        "/drive",
        "/surface",
        "/demods",
        "/noise",
        "/synth/sample_rate",
    ]
    .iter()
    .any(|p| path.starts_with(p))
}
