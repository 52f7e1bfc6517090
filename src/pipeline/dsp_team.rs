//! Worker threads that run shards of the lock-in bank beside the DSP thread.
//!
//! The DSP thread (the "leader") owns the work: the shards ([`LockInBank::split`]) and
//! their output buffers live in the [`DspPlan`](super::DspPlan), built off the real-time
//! thread. For each piece of input the leader hands one shard to each worker, runs the
//! first shard and the spectrum itself, and waits until every worker is done; only then
//! does it read the shards' outputs. A worker touches a shard only between the hand-off
//! and its "done", so a plan may be swapped or freed whenever the leader is not inside
//! [`DspTeam::run`], and the same workers serve every plan.
//!
//! Hand-off and wait are atomics, no lock: a job number per worker (release/acquire), a
//! "taken" flag per job, a count of jobs not finished, and for each side a "sleeping"
//! flag. Whoever takes a job runs it: its worker, or the leader once its own work is done
//! and the worker has not started (descheduled on a loaded machine), so a split stage is
//! never held up by a worker that does not get a core. A waiting thread spins
//! briefly ([`SPIN`]), then raises its flag, looks once more and parks; the other side
//! unparks it only if the flag is up (sequentially consistent on both sides, so one of
//! them always sees the other). Nothing is allocated, locked or logged per piece; an
//! `unpark` is a futex wake only when the thread really sleeps.

use std::cell::UnsafeCell;
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::thread::{JoinHandle, Thread};

use crate::dsp::{LockInBank, LockInSample};

/// Spins of a waiting thread before it parks: tens of microseconds, a fraction of the
/// time a 4096-sample piece takes, so a busy chain never sleeps between pieces while an
/// idle one does not burn a core that two threads share.
const SPIN: u32 = 1 << 11;
/// Job number that tells a worker to return.
const STOP: u64 = u64::MAX;

/// One piece of work: run `bank` over `input`, outputs into `out`.
#[derive(Clone, Copy)]
struct Job {
    bank: *mut LockInBank,
    input: *const f64,
    len: usize,
    out: *mut Vec<LockInSample>,
}

impl Job {
    const NONE: Job = Job {
        bank: std::ptr::null_mut(),
        input: std::ptr::null(),
        len: 0,
        out: std::ptr::null_mut(),
    };
}

/// A worker's mailbox, on its own cache lines.
#[repr(align(128))]
struct Slot {
    /// Number of the latest job handed over ([`STOP`]: return).
    seq: AtomicU64,
    /// The worker is (about to be) parked: the leader must unpark it.
    sleeping: AtomicBool,
    /// The current job has been taken, by the worker or by the leader.
    taken: AtomicBool,
    /// Written by the leader before `seq` is raised, read by the worker after it sees it.
    job: UnsafeCell<Job>,
}

/// What the leader and the workers share.
struct Shared {
    slots: Box<[Slot]>,
    /// Jobs handed out and not finished.
    busy: AtomicUsize,
    /// The leader is (about to be) parked: the last worker to finish must unpark it.
    leader_sleeping: AtomicBool,
    /// The leader thread of the current jobs, written by it before it hands them out.
    leader: UnsafeCell<Option<Thread>>,
    /// A job panicked (the leader panics in turn, rather than use a half-run shard).
    panicked: AtomicBool,
}

// SAFETY: the `UnsafeCell`s are written only by the leader while no worker reads them
// (before the release store that hands the jobs over, after the acquire load that sees
// every worker done), and read by a worker only between the two. The raw pointers in the
// jobs point into data the leader holds borrowed for that whole span.
unsafe impl Sync for Shared {}
// SAFETY: as above; nothing in it is tied to a thread.
unsafe impl Send for Shared {}

/// The DSP thread's helpers: `workers` threads that each run one shard of the lock-in bank
/// per piece of input. With none, [`DspPlan`](super::DspPlan) runs every shard on the
/// calling thread. Dropping the team stops and joins its threads.
pub struct DspTeam {
    shared: Arc<Shared>,
    threads: Vec<(Thread, JoinHandle<()>)>,
    /// Number of the latest jobs.
    seq: u64,
}

impl DspTeam {
    /// A team without workers: everything runs on the calling thread.
    pub fn none() -> Self {
        Self::spawn(0, false).expect("no thread to start")
    }

    /// Starts `workers` threads (named `ftafm-dsp-w1` …), promoted as the DSP thread is
    /// when the chain is `paced` by the wall clock ([`super::realtime::promote`]).
    pub fn spawn(workers: usize, paced: bool) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            slots: (0..workers)
                .map(|_| Slot {
                    seq: AtomicU64::new(0),
                    sleeping: AtomicBool::new(false),
                    taken: AtomicBool::new(true),
                    job: UnsafeCell::new(Job::NONE),
                })
                .collect(),
            busy: AtomicUsize::new(0),
            leader_sleeping: AtomicBool::new(false),
            leader: UnsafeCell::new(None),
            panicked: AtomicBool::new(false),
        });
        let mut team = Self {
            shared,
            threads: Vec::with_capacity(workers),
            seq: 0,
        };
        for w in 0..workers {
            let shared = team.shared.clone();
            // On failure the team drops, which stops the threads already started.
            let handle = std::thread::Builder::new()
                .name(format!("ftafm-dsp-w{}", w + 1))
                .spawn(move || {
                    super::realtime::promote("dsp-worker", paced);
                    work(&shared, w);
                })?;
            team.threads.push((handle.thread().clone(), handle));
        }
        Ok(team)
    }

    /// Number of worker threads (besides the calling one).
    pub fn workers(&self) -> usize {
        self.threads.len()
    }

    /// Runs `shards[i]` over `input` with its outputs into `outputs[i]` (cleared first; the
    /// caller sized them so they never grow): shards 1 … workers on the workers, the others
    /// and then `beside` on the calling thread, then any shard whose worker has not started
    /// it yet, and returns when all are done. Real-time
    /// safe: allocates nothing (given the capacities), takes no lock.
    pub(crate) fn run(
        &mut self,
        shards: &mut [LockInBank],
        outputs: &mut [Vec<LockInSample>],
        input: &[f64],
        beside: impl FnOnce(),
    ) {
        assert_eq!(shards.len(), outputs.len());
        let banks = shards.as_mut_ptr();
        let outs = outputs.as_mut_ptr();
        let job = |i: usize| Job {
            // SAFETY: i < shards.len() == outputs.len() (callers below).
            bank: unsafe { banks.add(i) },
            input: input.as_ptr(),
            len: input.len(),
            // SAFETY: as above.
            out: unsafe { outs.add(i) },
        };
        let handed = shards.len().saturating_sub(1).min(self.threads.len());
        if handed > 0 {
            let me = std::thread::current();
            // SAFETY: no worker runs a job now (the previous ones all finished before the
            // last `run` returned), so none reads `leader`.
            let leader = unsafe { &mut *self.shared.leader.get() };
            if leader.as_ref().map(Thread::id) != Some(me.id()) {
                *leader = Some(me);
            }
            self.seq += 1;
            self.shared.busy.store(handed, Ordering::SeqCst);
            for w in 0..handed {
                let slot = &self.shared.slots[w];
                // SAFETY: no one runs a job now (see above), and the job is read only by
                // whoever takes it, after the stores below.
                unsafe { *slot.job.get() = job(w + 1) };
                slot.taken.store(false, Ordering::SeqCst);
                slot.seq.store(self.seq, Ordering::SeqCst);
                if slot.sleeping.load(Ordering::SeqCst) {
                    self.threads[w].0.unpark();
                }
            }
        }
        // A panic here (a sink's, say) must not unwind past the workers' jobs while they
        // still use the shards: it is held until they are done.
        let mine = std::panic::catch_unwind(AssertUnwindSafe(|| {
            run_job(job(0));
            for i in handed + 1..shards.len() {
                run_job(job(i));
            }
            beside();
        }));
        if handed > 0 {
            for w in 0..handed {
                if !self.shared.slots[w].taken.swap(true, Ordering::SeqCst) {
                    // Not started by its worker: run here (unless unwinding anyway).
                    if mine.is_ok()
                        && std::panic::catch_unwind(AssertUnwindSafe(|| run_job(job(w + 1))))
                            .is_err()
                    {
                        self.shared.panicked.store(true, Ordering::Relaxed);
                    }
                    self.shared.busy.fetch_sub(1, Ordering::SeqCst);
                }
            }
            self.wait();
        }
        if let Err(panic) = mine {
            std::panic::resume_unwind(panic);
        }
        assert!(
            !self.shared.panicked.load(Ordering::Relaxed),
            "a DSP worker thread panicked"
        );
    }

    /// Waits until every job taken by a worker is finished.
    fn wait(&self) {
        let shared = &self.shared;
        let mut spins = 0;
        while shared.busy.load(Ordering::SeqCst) != 0 {
            if spins < SPIN {
                spins += 1;
                std::hint::spin_loop();
                continue;
            }
            shared.leader_sleeping.store(true, Ordering::SeqCst);
            if shared.busy.load(Ordering::SeqCst) != 0 {
                std::thread::park();
            }
            shared.leader_sleeping.store(false, Ordering::SeqCst);
        }
    }
}

impl Drop for DspTeam {
    fn drop(&mut self) {
        for slot in &self.shared.slots {
            slot.seq.store(STOP, Ordering::SeqCst);
        }
        for (thread, handle) in self.threads.drain(..) {
            thread.unpark();
            let _ = handle.join();
        }
    }
}

/// Runs one job. Its pointers are valid and unaliased for the call (see [`DspTeam::run`]).
fn run_job(job: Job) {
    // SAFETY: `run` builds jobs from live, distinct shards and buffers and a live input
    // slice, and keeps them borrowed until every job is done.
    let (bank, input, out) = unsafe {
        (
            &mut *job.bank,
            std::slice::from_raw_parts(job.input, job.len),
            &mut *job.out,
        )
    };
    out.clear();
    bank.process(input, |s| {
        debug_assert!(out.len() < out.capacity(), "shard output buffer too small");
        if out.len() < out.capacity() {
            out.push(s);
        }
    });
}

/// A worker thread's loop: wait for a job, run it, report it done.
fn work(shared: &Shared, w: usize) {
    let slot = &shared.slots[w];
    let mut seen = 0;
    loop {
        let mut spins = 0;
        let seq = loop {
            let seq = slot.seq.load(Ordering::SeqCst);
            if seq != seen {
                break seq;
            }
            if spins < SPIN {
                spins += 1;
                std::hint::spin_loop();
                continue;
            }
            slot.sleeping.store(true, Ordering::SeqCst);
            if slot.seq.load(Ordering::SeqCst) == seen {
                std::thread::park();
            }
            slot.sleeping.store(false, Ordering::SeqCst);
        };
        if seq == STOP {
            return;
        }
        seen = seq;
        if slot.taken.swap(true, Ordering::SeqCst) {
            // The leader ran it (or this is a job number already served: a job taken
            // under an earlier look at `seq` was the newest one).
            continue;
        }
        // SAFETY: the leader wrote the job before clearing `taken`, and leaves it alone
        // until every job taken is reported done, which this one is not yet.
        let job = unsafe { *slot.job.get() };
        if std::panic::catch_unwind(AssertUnwindSafe(|| run_job(job))).is_err() {
            shared.panicked.store(true, Ordering::Relaxed);
        }
        // SAFETY: `leader` was written before the jobs were handed out and is not written
        // again before every worker is done, which this one is not yet.
        let leader = unsafe { (*shared.leader.get()).clone() };
        if shared.busy.fetch_sub(1, Ordering::SeqCst) == 1
            && shared.leader_sleeping.load(Ordering::SeqCst)
            && let Some(leader) = leader
        {
            leader.unpark();
        }
    }
}
