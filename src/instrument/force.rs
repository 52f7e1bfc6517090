//! The `force` stream's worker: a thread that owns the [`ForceEstimator`] and turns the
//! demodulator frames the hub forwards into force estimates. Its own thread, so an
//! expensive inversion never delays the other streams; frames it cannot take in time are
//! dropped and counted.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, channel, sync_channel};
use std::time::{Duration, Instant};

use super::build_budget::BuildBudget;
use super::latest::Latest;

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
    /// A new estimator (from the one builder thread, so in the order requested), the
    /// generation of the request it was built for, and why there is none if there is none.
    Replace(Option<Box<ForceEstimator>>, u64, String),
}

/// What the worker makes of the frames, tagged with the generation of the estimator that
/// made it ([`ForceLink::rebuild`] numbers the requests), so a sweep can tell an estimate
/// for its point's settings from one still made for the previous point's.
#[derive(Clone, Debug)]
pub(crate) enum ForceOutcome {
    /// Generation, the estimate, and its `seq` in the `force` stream.
    Estimate(u64, ForceEstimate, u64),
    /// An estimate failed (e.g. no contact) at the frame of simulated time t (s).
    Failed(u64, f64, String),
    /// There is no estimator for these settings (the inversion is off, or it failed).
    Unavailable(u64, String),
}

/// Counts of the worker's work.
#[derive(Default)]
pub(crate) struct ForceCounters {
    pub estimates: AtomicU64,
    pub failed: AtomicU64,
    pub dropped: AtomicU64,
    /// Averaging windows whose fit was not made: no client and no sweep was to take it.
    pub skipped: AtomicU64,
    /// Frames left out because the settings had changed and their effect not yet settled.
    pub unsettled: AtomicU64,
    /// Estimates made by an estimator of older settings than the newest (sent with
    /// `"stale": true`).
    pub stale: AtomicU64,
    pub rebuilds: AtomicU64,
    /// Time spent building estimators, in ns (the builder's CPU budget, measured).
    pub rebuild_ns: AtomicU64,
    /// The builder's rests while its [`BuildBudget`] is spent: taken in full, and cut short
    /// because a sweep waits for its estimates (or the link closed).
    pub rests_taken: AtomicU64,
    pub rests_cut: AtomicU64,
    /// Builds stopped because newer settings arrived while they ran (their estimator would
    /// have been replaced at once; the newer settings are built next).
    pub builds_cancelled: AtomicU64,
    /// Why the estimator or the last estimate failed, if it did (for logs).
    pub last_error: std::sync::Mutex<String>,
}

/// The hub's and the control plane's ends of the worker.
pub(crate) struct ForceLink {
    input: SyncSender<Input>,
    pub counters: Arc<ForceCounters>,
    /// The newest settings to build an estimator for, with their generation; a flood of
    /// changes costs one build at a time (the rest are counted in its `coalesced`).
    pub pending: Arc<Latest<(Settings, u64)>>,
    /// The settings epoch of the newest estimator asked for (its generation), shared with
    /// the worker, which marks estimates of an older estimator stale.
    generation: Arc<AtomicU64>,
    /// What the worker must know of each committed change.
    follow: Arc<Follow>,
    /// The worker fits only the windows whose `seq` is a multiple of this: the greatest
    /// common divisor of the subscribers' `every` (1 while a sweep takes the estimates).
    stride: Arc<AtomicU32>,
    /// The `seq` the worker gives its next window (fitted or skipped).
    next_seq: Arc<AtomicU64>,
    /// A sweep waits for each point's estimate: the builder does not rest between builds.
    awaited: Arc<AtomicBool>,
    /// The settings of the newest estimator asked for (control side only): whether a
    /// change of the sample's moduli outgrew its table ([`ForceEstimator::covers`]).
    built_for: std::sync::Mutex<Option<Settings>>,
}

impl Drop for ForceLink {
    fn drop(&mut self) {
        // Ends the builder, which ends the worker once the hub's sender is gone too.
        self.pending.close();
    }
}

/// What the worker learns of each committed settings change, lock-free.
#[derive(Default)]
struct Follow {
    /// The newest epoch committed (written last).
    epoch: AtomicU64,
    /// Counts the changes after which the running average starts afresh.
    resets: AtomicU64,
    /// Simulated time (s, as f64 bits) from which frames reflect the newest such change
    /// settled: earlier frames are left out.
    settle_from: AtomicU64,
}

/// Nice value of the estimator builder: it yields the CPU to the real-time threads and the
/// hub when they need it (a build is ~0.1 s of work on the paper engine, 0.8–2.1 s on the
/// coupled one, that nothing waits on in real time).
const BUILDER_NICE: i32 = 10;
/// Longest the builder's rest goes without looking whether a sweep now waits. The builder
/// rests when its [`BuildBudget`] is spent, except while a sweep waits for each point's
/// estimate ([`ForceLink::await_estimates`]): the sweep asks for one build per point and
/// waits for it, so it bounds the rate itself, and a rest would be most of each point's time
/// (at nice 10 the real-time threads still come first).
const REST_SLICE: Duration = Duration::from_millis(20);

impl ForceLink {
    /// Starts the worker thread; its outcomes come out of the returned receiver.
    pub fn start() -> (Self, Receiver<ForceOutcome>) {
        let (input, rx) = sync_channel::<Input>(QUEUE);
        let (out, estimates) = channel();
        let counters = Arc::new(ForceCounters::default());
        let c = counters.clone();
        let stride = Arc::new(AtomicU32::new(1));
        let next_seq = Arc::new(AtomicU64::new(0));
        let (worker_stride, worker_seq) = (stride.clone(), next_seq.clone());
        let generation = Arc::new(AtomicU64::new(0));
        let follow = Arc::new(Follow::default());
        let (requested, seen) = (generation.clone(), follow.clone());
        std::thread::Builder::new()
            .name("inversion".into())
            .spawn(move || {
                let mut estimator: Option<Box<ForceEstimator>> = None;
                let mut generation = 0;
                let mut resets = 0;
                while let Ok(msg) = rx.recv() {
                    let outcome = match msg {
                        Input::Replace(next, g, why) => {
                            estimator = next;
                            generation = g;
                            estimator
                                .is_none()
                                .then_some(ForceOutcome::Unavailable(g, why))
                        }
                        Input::Frame(frame) => {
                            let Some(e) = estimator.as_mut() else {
                                continue;
                            };
                            // The epoch first: a change is published resets-then-epoch, so
                            // an estimate stamped with an epoch has seen its reset.
                            let epoch = seen.epoch.load(Ordering::Acquire);
                            let r = seen.resets.load(Ordering::Acquire);
                            if r != resets {
                                resets = r;
                                e.reset_window();
                            }
                            if frame.t < f64::from_bits(seen.settle_from.load(Ordering::Acquire)) {
                                c.unsettled.fetch_add(1, Ordering::Relaxed);
                                continue;
                            }
                            // Read before the window's seq moves on (SeqCst, as the
                            // subscriber's store of the stride and read of the seq).
                            let seq = worker_seq.load(Ordering::SeqCst);
                            let stride = u64::from(worker_stride.load(Ordering::SeqCst).max(1));
                            match e.push_or_skip(&frame, seq.is_multiple_of(stride)) {
                                Some(None) => {
                                    c.skipped.fetch_add(1, Ordering::Relaxed);
                                    worker_seq.store(seq + 1, Ordering::SeqCst);
                                    None
                                }
                                Some(Some(Ok(mut estimate))) => {
                                    c.estimates.fetch_add(1, Ordering::Relaxed);
                                    // An estimator older than the newest asked for measures
                                    // with the old settings' model: say so, and whose.
                                    estimate.stale = generation < requested.load(Ordering::SeqCst);
                                    estimate.epoch =
                                        if estimate.stale { generation } else { epoch };
                                    if estimate.stale {
                                        c.stale.fetch_add(1, Ordering::Relaxed);
                                    }
                                    worker_seq.store(seq + 1, Ordering::SeqCst);
                                    Some(ForceOutcome::Estimate(generation, estimate, seq))
                                }
                                // A failed fit is no message: its seq goes to the next.
                                Some(Some(Err(err))) => {
                                    c.failed.fetch_add(1, Ordering::Relaxed);
                                    let err = err.to_string();
                                    if let Ok(mut last) = c.last_error.lock() {
                                        last.clone_from(&err);
                                    }
                                    Some(ForceOutcome::Failed(generation, frame.t, err))
                                }
                                None => None,
                            }
                        }
                    };
                    if let Some(outcome) = outcome
                        && out.send(outcome).is_err()
                    {
                        return;
                    }
                }
            })
            .expect("the inversion thread starts");
        let pending = Arc::new(Latest::new());
        let awaited = Arc::new(AtomicBool::new(false));
        let (p, c, to_worker, a) = (
            pending.clone(),
            counters.clone(),
            input.clone(),
            awaited.clone(),
        );
        std::thread::Builder::new()
            .name("force-build".into())
            .spawn(move || build_loop(&p, &c, &to_worker, &a, BuildBudget::new()))
            .expect("the estimator builder thread starts");
        (
            Self {
                input,
                counters,
                pending,
                generation,
                follow,
                stride,
                next_seq,
                awaited,
                built_for: std::sync::Mutex::new(None),
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

    /// Fit only the windows whose seq is a multiple of `stride` from now on, and return the
    /// seq of the next window: a client subscribing now takes estimates from there on, all
    /// of them fitted under the new stride.
    pub fn set_stride(&self, stride: u32) -> u64 {
        self.stride.store(stride.max(1), Ordering::SeqCst);
        self.next_seq.load(Ordering::SeqCst)
    }

    /// Follows the settings change of `epoch`: frames before `settle_from` (s of simulated
    /// time; `None`: the change leaves the measured physics alone) are left out and the
    /// running average starts afresh; with `rebuild`, the estimator of those settings is
    /// built off the request path (the modulus table and the lock-in model take 0.1–3 s;
    /// only the newest of the changes made meanwhile is built), and until it is, estimates
    /// are marked stale.
    pub fn follow(&self, epoch: u64, settle_from: Option<f64>, rebuild: Option<Settings>) {
        if let Some(settings) = rebuild {
            if let Ok(mut built_for) = self.built_for.lock() {
                *built_for = Some(settings.clone());
            }
            self.generation.store(epoch, Ordering::SeqCst);
            self.pending.put((settings, epoch));
        }
        if let Some(t) = settle_from {
            self.follow
                .settle_from
                .store(t.to_bits(), Ordering::Release);
            self.follow.resets.fetch_add(1, Ordering::Release);
        }
        self.follow.epoch.store(epoch, Ordering::Release);
    }

    /// Whether the estimator asked for last no longer serves `settings` though no setting
    /// it models changed: a material's modulus moved out of its table's dense nodes
    /// ([`ForceEstimator::covers`]). True when none was asked for.
    pub fn outgrown(&self, settings: &Settings) -> bool {
        self.built_for.lock().map_or(true, |built| {
            built
                .as_ref()
                .is_none_or(|b| !ForceEstimator::covers(b, settings))
        })
    }

    /// Whether a sweep waits for each point's estimate (the builder then does not rest
    /// while its [`BuildBudget`] is spent).
    pub fn await_estimates(&self, on: bool) {
        self.awaited.store(on, Ordering::Relaxed);
    }

    /// Generation of the newest estimator asked for: outcomes of this generation or later
    /// come from settings at least as new as those of the last [`rebuild`](Self::rebuild).
    pub fn requested(&self) -> u64 {
        self.generation.load(Ordering::SeqCst)
    }
}

/// The builder thread: one estimator at a time for the newest settings, at a low priority
/// and a bounded duty cycle, until the link is dropped.
fn build_loop(
    pending: &Latest<(Settings, u64)>,
    counters: &ForceCounters,
    worker: &SyncSender<Input>,
    awaited: &AtomicBool,
    mut budget: BuildBudget,
) {
    lower_priority(BUILDER_NICE);
    // The last coupled table's orbits: the next build starts from them (a sweep's next
    // point is a small change).
    let mut seed = None;
    loop {
        if !pending.wait_pending(Duration::from_secs(1)) {
            if pending.is_closed() {
                return;
            }
            continue;
        }
        // Rest while the budget is spent; changes meanwhile wait in `pending`, the newest
        // superseding the others (counted as coalesced).
        let mut rested = false;
        loop {
            let wait = budget.wait(Instant::now());
            if wait.is_zero() {
                if rested {
                    counters.rests_taken.fetch_add(1, Ordering::Relaxed);
                }
                break;
            }
            if pending.is_closed() || awaited.load(Ordering::Relaxed) {
                counters.rests_cut.fetch_add(1, Ordering::Relaxed);
                break;
            }
            rested = true;
            std::thread::sleep(wait.min(REST_SLICE));
        }
        let Some((settings, generation)) = pending.take() else {
            continue;
        };
        let start = Instant::now();
        // Newer settings stop the build: its estimator would be replaced at once.
        let built = ForceEstimator::build(&settings, seed.as_ref(), Some(&pending.superseded));
        // Only a build its flag stopped: one that failed on its own says why like any other.
        if matches!(&built, Err(e) if e == crate::inversion::BUILD_CANCELLED) {
            counters.builds_cancelled.fetch_add(1, Ordering::Relaxed);
            budget.spend(start.elapsed(), Instant::now());
            continue;
        }
        let (next, why) = match built {
            Ok(Some(e)) => {
                if let Some(s) = e.seed() {
                    seed = Some(s.clone());
                }
                (Some(Box::new(e)), String::new())
            }
            Ok(None) => (
                None,
                "the inversion is off (/inversion/enable = false)".into(),
            ),
            Err(err) => {
                tracing::warn!(error = %err, "force estimator unavailable");
                if let Ok(mut last) = counters.last_error.lock() {
                    last.clone_from(&err);
                }
                (None, err)
            }
        };
        let took = start.elapsed();
        counters.rebuilds.fetch_add(1, Ordering::Relaxed);
        counters
            .rebuild_ns
            .fetch_add(took.as_nanos() as u64, Ordering::Relaxed);
        if worker.send(Input::Replace(next, generation, why)).is_err() {
            return;
        }
        budget.spend(took, Instant::now());
    }
}

/// Lowers the calling thread's scheduling priority to `nice` (Linux: per thread); a
/// refusal only leaves it where it was.
pub(crate) fn lower_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    // SAFETY: gettid has no preconditions; setpriority on our own thread id only changes
    // this thread's nice value (raising it needs no privilege).
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        let _ = libc::setpriority(libc::PRIO_PROCESS, tid, nice);
    }
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

/// Whether a change of `path` moves a material's modulus: the coupled engine's table is
/// dense about each, and is rebuilt where one moved far ([`ForceLink::outgrown`]).
pub(crate) fn moves_a_modulus(path: &str) -> bool {
    path.starts_with("/sample/youngs_modulus") || path.starts_with("/inclusions")
}

/// Whether a change of `path` changes the estimator (its cantilever, drive, setpoint, tip,
/// sample Poisson ratio, demodulators, inversion settings, the noise it predicts for each
/// harmonic, the sample rate and anti-alias filter that set the aliases, or the engine and
/// adhesion its modulus table models; not the sample's modulus, which is what it
/// measures).
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
        "/synth/anti_alias",
        "/synth/engine",
        "/adhesion",
    ]
    .iter()
    .any(|p| path.starts_with(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_waiting_sweep_cuts_the_rest_of_a_spent_budget() {
        let pending = Latest::new();
        let counters = ForceCounters::default();
        let (to_worker, from_builder) = sync_channel(4);
        let awaited = AtomicBool::new(true);
        // Hundreds of seconds of rest owed.
        let mut budget = BuildBudget::new();
        budget.spend(Duration::from_secs(100), Instant::now());
        let mut settings = crate::config::default_settings();
        settings.synth.engine = crate::config::Engine::Paper;
        pending.put((settings, 7));
        std::thread::scope(|scope| {
            scope.spawn(|| build_loop(&pending, &counters, &to_worker, &awaited, budget));
            // A guard against a hang, not a timing margin (the rest would be 400 s).
            let built = from_builder.recv_timeout(Duration::from_secs(120));
            pending.close();
            assert!(
                matches!(built, Ok(Input::Replace(Some(_), 7, _))),
                "the estimator for generation 7 is built while the sweep waits"
            );
        });
        assert_eq!(counters.rests_taken.load(Ordering::Relaxed), 0);
        assert!(counters.rests_cut.load(Ordering::Relaxed) >= 1);
    }
}
