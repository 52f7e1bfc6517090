//! Settings epochs: each [`Pipeline::apply`](super::Pipeline::apply) publishes a new one,
//! the synthesiser stamps it on the first block it synthesises under it, and the DSP thread
//! takes up that epoch's plan with that very block. So a change lands on one sample
//! boundary for the whole chain, and the control side learns which one: the simulated time
//! a `set` took effect.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Shared between the control side and the synthesiser thread.
#[derive(Debug, Default)]
pub struct Epochs {
    /// The newest epoch published by the control side (after its plans were queued).
    pub(crate) requested: AtomicU64,
    /// The newest epoch the synthesiser has stamped on a block…
    effective: AtomicU64,
    /// …and the stream index of that block's first sample.
    effective_index: AtomicU64,
    /// The epoch of the newest plan the DSP thread took up…
    dsp_epoch: AtomicU64,
    /// …and the stream index of the block it took it up with.
    dsp_index: AtomicU64,
}

impl Epochs {
    /// Synthesiser side: blocks from sample `index` on run under `epoch`. Lock-free; the
    /// index is written before the epoch that makes it visible.
    pub(crate) fn took_effect(&self, epoch: u64, index: u64) {
        self.effective_index.store(index, Ordering::Relaxed);
        self.effective.store(epoch, Ordering::Release);
    }

    /// DSP side: the plan of `epoch` runs from the block at sample `index` on.
    pub(crate) fn dsp_took_up(&self, epoch: u64, index: u64) {
        self.dsp_index.store(index, Ordering::Relaxed);
        self.dsp_epoch.store(epoch, Ordering::Release);
    }

    /// The epoch of the newest DSP plan taken up and the sample index it took over at, for
    /// tests that both threads switch at one sample boundary.
    pub fn dsp_taken_up(&self) -> (u64, u64) {
        let epoch = self.dsp_epoch.load(Ordering::Acquire);
        (epoch, self.dsp_index.load(Ordering::Relaxed))
    }

    /// Control side: the first sample index synthesised under `epoch` or a later one,
    /// waiting for it up to `timeout` (`None` if the synthesiser did not get there, e.g. a
    /// free-running one whose DSP is held). Exact for `epoch` as long as no later epoch was
    /// published meanwhile, which the control side's lock ensures.
    pub fn wait_effective(&self, epoch: u64, timeout: Duration) -> Option<u64> {
        let since = Instant::now();
        loop {
            if self.effective.load(Ordering::Acquire) >= epoch {
                return Some(self.effective_index.load(Ordering::Relaxed));
            }
            if since.elapsed() >= timeout {
                return None;
            }
            // A block lasts 0.4 ms at 10 MS/s: poll at a fraction of that.
            std::thread::sleep(Duration::from_micros(100));
        }
    }
}
