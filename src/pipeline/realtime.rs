//! Real-time scheduling for the signal chain's threads.
//!
//! [`promote`] runs first on each real-time thread (synthesiser, DSP). With
//! `FTAFM_SCHED=fifo` it asks the kernel for `SCHED_FIFO` at a modest priority
//! ([`FIFO_PRIORITY`]) and, if that is refused, for a better nice value ([`NICE`]); with
//! `FTAFM_SCHED=nice` only for the nice value. It never fails: what the thread got is
//! logged once (`tracing`, target `ftafm::pipeline::realtime`), kept for [`promotions`]
//! (`/metrics`) and returned.
//!
//! The default (`FTAFM_SCHED` unset, or `off`) changes nothing. On the 2-core development
//! machine promotion does not pay (docs/benchmarks.md): it shortens the chain's own path
//! (synth → DSP p99 0.40 → 0.26 ms) but not the clients' latency, which the server's async
//! threads set, and those it delays (receive p99 1.81 → 2.56 ms in a 16-client soak).
//! When the DSP thread still polled the ring every 50 µs, promotion made a slow-client
//! test fail; it now sleeps until the synthesiser wakes it, and that test passes either
//! way. On a machine with cores to spare, or with the chain pinned away from the server,
//! try `fifo`.
//!
//! Only a chain that starts paced by the wall clock is promoted: a free-running chain
//! (`ftafm bench` without `--realtime`) keeps both threads busy all the time, and two
//! `SCHED_FIFO` threads that never sleep would leave the rest of a 2-core machine 5 % of
//! its time (the kernel's real-time throttling).

use std::sync::Mutex;

use serde::Serialize;

/// `SCHED_FIFO` priority asked for (1–99): above every normal thread, below the kernel's
/// own real-time threads (interrupt threads run at 50).
pub const FIFO_PRIORITY: i32 = 10;
/// Nice value asked for when `SCHED_FIFO` is refused (−20 highest … 19 lowest).
pub const NICE: i32 = -10;
/// Environment variable that chooses what [`promote`] tries.
pub const ENV: &str = "FTAFM_SCHED";

/// The scheduling a thread ended up with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Policy {
    /// `SCHED_FIFO` at [`Promotion::priority`].
    Fifo,
    /// The normal time-sharing policy (`SCHED_OTHER`) at [`Promotion::nice`].
    #[default]
    Other,
    /// Not known (not Linux).
    Unknown,
}

impl Policy {
    /// `fifo`, `other` or `unknown`.
    pub fn name(self) -> &'static str {
        match self {
            Policy::Fifo => "fifo",
            Policy::Other => "other",
            Policy::Unknown => "unknown",
        }
    }
}

/// What [`promote`] asked for and what the thread got.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Promotion {
    /// The thread (`synth`, `dsp`).
    pub thread: &'static str,
    /// What was asked for: `fifo`, `nice`, `off` (from `FTAFM_SCHED`; `off` by default)
    /// or `none` (chain not paced by the wall clock).
    pub requested: &'static str,
    /// The policy the thread runs with now.
    pub policy: Policy,
    /// Its `SCHED_FIFO` priority (0 under the normal policy).
    pub priority: i32,
    /// Its nice value.
    pub nice: i32,
    /// What was refused and why, empty if everything asked for was granted.
    pub note: String,
}

static PROMOTIONS: Mutex<Vec<Promotion>> = Mutex::new(Vec::new());

/// The latest promotion of each thread name in this process, in the order first seen.
pub fn promotions() -> Vec<Promotion> {
    PROMOTIONS.lock().map(|p| p.clone()).unwrap_or_default()
}

/// What `FTAFM_SCHED` asks for: `fifo`, `nice` or `off` (the default; also for anything
/// else).
fn requested() -> &'static str {
    match std::env::var(ENV).as_deref().map(str::trim) {
        Ok("fifo") => "fifo",
        Ok("nice") => "nice",
        _ => "off",
    }
}

/// Promotes the calling thread, named `thread`, if the chain is `paced` by the wall clock
/// (see the module documentation). Call it once, first thing on the thread; it never fails.
pub fn promote(thread: &'static str, paced: bool) -> Promotion {
    let requested = if paced { requested() } else { "none" };
    let mut p = imp::apply(requested);
    p.thread = thread;
    p.requested = requested;
    tracing::info!(
        thread,
        requested,
        policy = p.policy.name(),
        priority = p.priority,
        nice = p.nice,
        note = %p.note,
        "real-time thread scheduling"
    );
    if let Ok(mut all) = PROMOTIONS.lock() {
        match all.iter_mut().find(|q| q.thread == thread) {
            Some(q) => *q = p.clone(),
            None => all.push(p.clone()),
        }
    }
    p
}

#[cfg(target_os = "linux")]
mod imp {
    use super::{FIFO_PRIORITY, NICE, Policy, Promotion};

    fn os_error(code: i32) -> String {
        std::io::Error::from_raw_os_error(code).to_string()
    }

    /// The calling thread's kernel id (setpriority on it affects only this thread).
    fn tid() -> libc::id_t {
        // SAFETY: gettid has no preconditions and cannot fail.
        unsafe { libc::syscall(libc::SYS_gettid) as libc::id_t }
    }

    fn try_fifo() -> Result<(), String> {
        let param = libc::sched_param {
            sched_priority: FIFO_PRIORITY,
        };
        // SAFETY: pthread_self is the calling thread; `param` is a valid sched_param.
        let rc =
            unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
        if rc == 0 {
            Ok(())
        } else {
            Err(format!(
                "SCHED_FIFO {FIFO_PRIORITY} refused: {}",
                os_error(rc)
            ))
        }
    }

    fn try_nice() -> Result<(), String> {
        // SAFETY: plain system call on this thread's id.
        let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, tid(), NICE) };
        if rc == 0 {
            Ok(())
        } else {
            let e = std::io::Error::last_os_error();
            Err(format!("nice {NICE} refused: {e}"))
        }
    }

    /// The calling thread's policy, FIFO priority and nice value as the kernel reports them.
    fn current() -> (Policy, i32, i32) {
        let mut policy = 0;
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: valid out-pointers for the calling thread.
        let rc =
            unsafe { libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) };
        let policy = match (rc, policy) {
            (0, libc::SCHED_FIFO) => Policy::Fifo,
            (0, _) => Policy::Other,
            _ => Policy::Unknown,
        };
        // getpriority may legitimately return −1; errno tells, but −1 is a fine report.
        // SAFETY: plain system call on this thread's id.
        let nice = unsafe { libc::getpriority(libc::PRIO_PROCESS, tid()) };
        (policy, param.sched_priority, nice)
    }

    pub(super) fn apply(requested: &str) -> Promotion {
        let mut notes = Vec::new();
        let fifo = requested == "fifo" && try_fifo().map_err(|e| notes.push(e)).is_ok();
        if !fifo && matches!(requested, "fifo" | "nice") {
            let _ = try_nice().map_err(|e| notes.push(e));
        }
        let (policy, priority, nice) = current();
        Promotion {
            policy,
            priority,
            nice,
            note: notes.join("; "),
            ..Promotion::default()
        }
    }
}

#[cfg(not(target_os = "linux"))]
mod imp {
    use super::{Policy, Promotion};

    pub(super) fn apply(requested: &str) -> Promotion {
        Promotion {
            policy: Policy::Unknown,
            note: if requested == "off" || requested == "none" {
                String::new()
            } else {
                "thread priorities are only set on Linux".into()
            },
            ..Promotion::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unpaced_thread_is_left_alone_and_recorded() {
        let p = std::thread::spawn(|| promote("test-unpaced", false))
            .join()
            .unwrap();
        assert_eq!(p.requested, "none");
        assert_eq!(p.thread, "test-unpaced");
        assert!(p.note.is_empty(), "{p:?}");
        #[cfg(target_os = "linux")]
        assert_eq!((p.policy, p.priority), (Policy::Other, 0));
        assert!(promotions().iter().any(|q| q.thread == "test-unpaced"));
    }
}
