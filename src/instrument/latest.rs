//! A slot that keeps only the newest value put into it, for work where only the latest
//! request matters (rebuilding an estimator for new settings): a producer never blocks or
//! queues behind a slow consumer, and a flood of requests costs one build at a time.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Duration;

/// The newest value not yet taken, and whether the slot was closed.
pub(crate) struct Latest<T> {
    slot: Mutex<(Option<T>, bool)>,
    ready: Condvar,
    /// Values replaced before anyone took them.
    pub coalesced: AtomicU64,
    /// Set by every [`put`](Self::put), cleared by [`take`](Self::take): whether the value
    /// taken last has been superseded, so work on it can stop (a cancel flag).
    pub superseded: AtomicBool,
}

impl<T> Latest<T> {
    pub fn new() -> Self {
        Self {
            slot: Mutex::new((None, false)),
            ready: Condvar::new(),
            coalesced: AtomicU64::new(0),
            superseded: AtomicBool::new(false),
        }
    }

    /// Puts `value`, replacing (and counting) one that was not taken yet. Returns whether
    /// the slot was empty, i.e. whether the consumer may need a wake-up.
    pub fn put(&self, value: T) -> bool {
        let Ok(mut slot) = self.slot.lock() else {
            return false;
        };
        let was_empty = slot.0.is_none();
        if !was_empty {
            self.coalesced.fetch_add(1, Ordering::Relaxed);
        }
        slot.0 = Some(value);
        self.superseded.store(true, Ordering::Relaxed);
        self.ready.notify_one();
        was_empty
    }

    /// Takes the newest value, if any, without waiting.
    pub fn take(&self) -> Option<T> {
        self.slot.lock().ok().and_then(|mut s| {
            // Under the lock, so a put after this take is never missed.
            self.superseded.store(false, Ordering::Relaxed);
            s.0.take()
        })
    }

    /// Waits until a value waits to be taken (`true`), without taking it; `false` once the
    /// slot is closed with nothing in it, or after `timeout`.
    pub fn wait_pending(&self, timeout: Duration) -> bool {
        let Ok(slot) = self.slot.lock() else {
            return false;
        };
        self.ready
            .wait_timeout_while(slot, timeout, |s| s.0.is_none() && !s.1)
            .is_ok_and(|(s, _)| s.0.is_some())
    }

    /// Whether a value waits to be taken.
    pub fn is_pending(&self) -> bool {
        self.slot.lock().map(|s| s.0.is_some()).unwrap_or(false)
    }

    /// Whether [`close`](Self::close) was called.
    pub fn is_closed(&self) -> bool {
        self.slot.lock().map(|s| s.1).unwrap_or(true)
    }

    /// Wakes the consumer for good: [`wait`](Self::wait) returns at once from now on.
    pub fn close(&self) {
        if let Ok(mut s) = self.slot.lock() {
            s.1 = true;
        }
        self.ready.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::Latest;
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn only_the_newest_value_is_taken_and_the_rest_are_counted() {
        let l = Latest::new();
        assert!(l.put(1));
        assert!(!l.put(2));
        assert!(!l.put(3));
        assert_eq!(l.take(), Some(3));
        assert_eq!(l.take(), None);
        assert_eq!(l.coalesced.load(std::sync::atomic::Ordering::Relaxed), 2);
    }

    #[test]
    fn a_waiting_consumer_is_woken_by_a_value_and_by_close() {
        let l = Arc::new(Latest::new());
        let c = l.clone();
        let t = std::thread::spawn(move || {
            // Waits, then takes (as the estimator's builder does).
            let first = c.wait_pending(Duration::from_secs(600)).then(|| c.take());
            let second = c.wait_pending(Duration::from_secs(600)).then(|| c.take());
            (first.flatten(), second.flatten())
        });
        l.put(7);
        // Whether or not the consumer took 7 before the close, it gets 7 first (a value
        // put before the close is still pending) and then nothing.
        l.close();
        let (first, second) = t.join().unwrap();
        assert_eq!(first, Some(7));
        assert_eq!(second, None);
    }
}
