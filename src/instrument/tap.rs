//! What the hub hands a running sweep: demodulator frames and force outcomes, through a
//! bounded queue that is open only while a sweep runs. Its own module, so that the shared
//! state holds the taps without depending on the sweeper that drains them.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use tokio::sync::mpsc;

use crate::pipeline::DemodFrame;

/// Items queued for a running sweep: 4 s of frames at 1 kHz.
const QUEUE: usize = 4096;

/// A queue from the hub to a running sweep, and the count of the items it could not take.
pub(crate) struct Tap<T> {
    active: AtomicBool,
    tx: mpsc::Sender<T>,
    rx: Mutex<Option<mpsc::Receiver<T>>>,
    /// Items a sweep missed because its queue was full (counted, never silent).
    pub dropped: AtomicU64,
}

/// The demodulator frames' tap.
pub(crate) type FrameTap = Tap<DemodFrame>;

impl<T: Clone> Tap<T> {
    pub fn new() -> Self {
        let (tx, rx) = mpsc::channel(QUEUE);
        Self {
            active: AtomicBool::new(false),
            tx,
            rx: Mutex::new(Some(rx)),
            dropped: AtomicU64::new(0),
        }
    }

    /// Hub side: an item, kept while a sweep runs.
    pub fn offer(&self, item: &T) {
        if self.active.load(Ordering::Relaxed) && self.tx.try_send(item.clone()).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Whether a sweep is taking items.
    pub fn is_active(&self) -> bool {
        self.active.load(Ordering::Relaxed)
    }

    /// Sweep side: items are kept (true) or not (false) from now on.
    pub fn set_active(&self, active: bool) {
        self.active.store(active, Ordering::Relaxed);
    }

    /// The receiving end, for the one sweeper task (`None` once taken).
    pub fn take_receiver(&self) -> Option<mpsc::Receiver<T>> {
        self.rx.lock().ok().and_then(|mut r| r.take())
    }
}
