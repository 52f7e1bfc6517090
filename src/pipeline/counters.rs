//! Counters of the signal chain: atomics the real-time threads bump with relaxed stores,
//! read as a [`CountersSnapshot`] by anyone. Every lost thing is counted here.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use serde::Serialize;

/// Nanoseconds on the monotonic clock since the process's first call (made off the
/// real-time threads, by [`super::Pipeline::start`]); 0 is never returned, so a stamp of 0
/// means "never". Lock-free after that first call.
pub(crate) fn monotonic_ns() -> u64 {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    (EPOCH.get_or_init(Instant::now).elapsed().as_nanos() as u64).max(1)
}

/// Live counters shared by the pipeline's threads.
#[derive(Debug, Default)]
pub struct Counters {
    pub(crate) samples_synthesized: AtomicU64,
    pub(crate) samples_processed: AtomicU64,
    pub(crate) overrun_samples: AtomicU64,
    pub(crate) overrun_blocks: AtomicU64,
    pub(crate) clipped_samples: AtomicU64,
    pub(crate) refined_samples: AtomicU64,
    pub(crate) over_budget_samples: AtomicU64,
    pub(crate) discontinuities: AtomicU64,
    pub(crate) demod_frames: AtomicU64,
    pub(crate) demod_frames_dropped: AtomicU64,
    pub(crate) spectrum_frames: AtomicU64,
    pub(crate) spectrum_frames_dropped: AtomicU64,
    pub(crate) scope_frames: AtomicU64,
    pub(crate) scope_frames_dropped: AtomicU64,
    pub(crate) synth_plans_applied: AtomicU64,
    pub(crate) dsp_plans_applied: AtomicU64,
    pub(crate) synth_busy_ns: AtomicU64,
    pub(crate) dsp_busy_ns: AtomicU64,
    pub(crate) late_blocks: AtomicU64,
    pub(crate) ring_fill: AtomicU64,
    pub(crate) ring_fill_max: AtomicU64,
    pub(crate) topography_pixels: AtomicU64,
    pub(crate) topography_pixels_dropped: AtomicU64,
    pub(crate) pid_updates: AtomicU64,
    pub(crate) pid_updates_dropped: AtomicU64,
    pub(crate) pixels: AtomicU64,
    pub(crate) pixels_dropped: AtomicU64,
    pub(crate) noise_pages_drawn_ahead: AtomicU64,
    pub(crate) noise_pages_taken: AtomicU64,
    pub(crate) noise_pages_drawn_inline: AtomicU64,
    pub(crate) noise_pages_discarded: AtomicU64,
    pub(crate) synth_beat_ns: AtomicU64,
    pub(crate) dsp_beat_ns: AtomicU64,
    pub(crate) stream_frames: AtomicU64,
    pub(crate) stream_samples: AtomicU64,
    pub(crate) stream_gap_samples: AtomicU64,
    pub(crate) stream_dropped_samples: AtomicU64,
    pub(crate) stream_discarded_samples: AtomicU64,
    /// The PID units' latest updates (not counters, but published the same way: by the
    /// real-time thread, without waiting, for anyone to read).
    pub(crate) pids: super::pid_board::PidBoard,
}

impl Counters {
    #[inline]
    pub(crate) fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    /// The PID units' latest updates.
    pub fn pids(&self) -> &super::pid_board::PidBoard {
        &self.pids
    }

    /// A consistent-enough copy (each counter read once, relaxed).
    pub fn snapshot(&self) -> CountersSnapshot {
        let r = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let now = monotonic_ns();
        let idle = |beat: &AtomicU64| match beat.load(Ordering::Relaxed) {
            0 => 0,
            t => now.saturating_sub(t),
        };
        CountersSnapshot {
            samples_synthesized: r(&self.samples_synthesized),
            samples_processed: r(&self.samples_processed),
            overrun_samples: r(&self.overrun_samples),
            overrun_blocks: r(&self.overrun_blocks),
            clipped_samples: r(&self.clipped_samples),
            refined_samples: r(&self.refined_samples),
            over_budget_samples: r(&self.over_budget_samples),
            discontinuities: r(&self.discontinuities),
            demod_frames: r(&self.demod_frames),
            demod_frames_dropped: r(&self.demod_frames_dropped),
            spectrum_frames: r(&self.spectrum_frames),
            spectrum_frames_dropped: r(&self.spectrum_frames_dropped),
            scope_frames: r(&self.scope_frames),
            scope_frames_dropped: r(&self.scope_frames_dropped),
            synth_plans_applied: r(&self.synth_plans_applied),
            dsp_plans_applied: r(&self.dsp_plans_applied),
            synth_busy_ns: r(&self.synth_busy_ns),
            dsp_busy_ns: r(&self.dsp_busy_ns),
            late_blocks: r(&self.late_blocks),
            ring_fill: r(&self.ring_fill),
            ring_fill_max: r(&self.ring_fill_max),
            topography_pixels: r(&self.topography_pixels),
            topography_pixels_dropped: r(&self.topography_pixels_dropped),
            pid_updates: r(&self.pid_updates),
            pid_updates_dropped: r(&self.pid_updates_dropped),
            pixels: r(&self.pixels),
            pixels_dropped: r(&self.pixels_dropped),
            noise_pages_drawn_ahead: r(&self.noise_pages_drawn_ahead),
            noise_pages_taken: r(&self.noise_pages_taken),
            noise_pages_drawn_inline: r(&self.noise_pages_drawn_inline),
            noise_pages_discarded: r(&self.noise_pages_discarded),
            stream_frames: r(&self.stream_frames),
            stream_samples: r(&self.stream_samples),
            stream_gap_samples: r(&self.stream_gap_samples),
            stream_dropped_samples: r(&self.stream_dropped_samples),
            stream_discarded_samples: r(&self.stream_discarded_samples),
            synth_idle_ns: idle(&self.synth_beat_ns),
            dsp_idle_ns: idle(&self.dsp_beat_ns),
        }
    }
}

/// The counters at one moment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CountersSnapshot {
    /// Samples the synthesiser produced (including dropped ones).
    pub samples_synthesized: u64,
    /// Samples the DSP consumed.
    pub samples_processed: u64,
    /// Samples dropped because the ring was full (real-time pacing only).
    pub overrun_samples: u64,
    /// Blocks dropped because the ring was full.
    pub overrun_blocks: u64,
    /// Samples clipped by the ADC's full scale.
    pub clipped_samples: u64,
    /// Samples in contact the coupled engine integrated at more sub-steps than
    /// `/synth/contact_substeps`, their contact being stiffer than that count resolves
    /// within its error budget (docs/ft-afm.md).
    pub refined_samples: u64,
    /// Samples in contact over that error budget even at 8× `/synth/contact_substeps`
    /// sub-steps: their harmonics may be off by more than 0.1 %.
    pub over_budget_samples: u64,
    /// Times the DSP saw a jump in the sample index (after an overrun).
    pub discontinuities: u64,
    /// Demodulator frames produced.
    pub demod_frames: u64,
    /// Demodulator frames dropped because no consumer took them in time.
    pub demod_frames_dropped: u64,
    /// Spectrum frames produced.
    pub spectrum_frames: u64,
    /// Spectrum frames dropped (no free buffer or full queue).
    pub spectrum_frames_dropped: u64,
    /// Scope traces produced.
    pub scope_frames: u64,
    /// Scope traces dropped (no free buffer).
    pub scope_frames_dropped: u64,
    /// Synthesiser plans (settings changes) applied.
    pub synth_plans_applied: u64,
    /// DSP plans (demodulator or spectrum changes) applied.
    pub dsp_plans_applied: u64,
    /// Time the synthesiser spent computing (ns).
    pub synth_busy_ns: u64,
    /// Time the DSP spent computing (ns).
    pub dsp_busy_ns: u64,
    /// Blocks the real-time pacing found already late (the synthesiser fell behind).
    pub late_blocks: u64,
    /// Samples in the ring when the DSP last looked.
    pub ring_fill: u64,
    /// Largest ring fill seen.
    pub ring_fill_max: u64,
    /// Scan pixels whose topography (height, amplitude) the synthesiser handed out.
    pub topography_pixels: u64,
    /// Scan pixels whose topography no consumer took in time.
    pub topography_pixels_dropped: u64,
    /// PID updates the synthesiser handed to the `pids` stream (while it has subscribers).
    pub pid_updates: u64,
    /// PID updates for the `pids` stream that found its queue full.
    pub pid_updates_dropped: u64,
    /// Scan pixels whose harmonics the DSP handed out.
    pub pixels: u64,
    /// Scan pixels the DSP lost: cut or skipped by a gap in the stream (an overrun), left
    /// without a single decimated sample, or not taken in time.
    pub pixels_dropped: u64,
    /// Pages of noise deviates (4096 samples each) the DSP thread drew ahead while it
    /// waited for blocks.
    pub noise_pages_drawn_ahead: u64,
    /// Pages the synthesiser took from those drawn ahead.
    pub noise_pages_taken: u64,
    /// Pages the synthesiser drew itself, none being ready (the DSP thread was busy).
    pub noise_pages_drawn_inline: u64,
    /// Pages drawn ahead and thrown away: drawn for samples already past (the DSP thread
    /// fell behind) or for a seed or number of modes that changed.
    pub noise_pages_discarded: u64,
    /// Sample frames a client streamed in and the inlet took (`/source/kind = "stream"`).
    pub stream_frames: u64,
    /// Streamed samples that entered the feed.
    pub stream_samples: u64,
    /// Samples the writer's frames skipped (a frame's first index beyond the next one
    /// expected: lost before they reached the daemon); the chain jumps them.
    pub stream_gap_samples: u64,
    /// Streamed samples dropped because the feed was full (the chain behind the writer);
    /// the chain jumps them.
    pub stream_dropped_samples: u64,
    /// Streamed samples still in the feed when the source changed away from the stream.
    pub stream_discarded_samples: u64,
    /// Time since the synthesiser last finished a block (ns; 0 before its first).
    pub synth_idle_ns: u64,
    /// Time since the DSP thread last finished a block (ns; 0 before its first): grows
    /// without bound when the pipeline stops producing, which `/healthz` reports.
    pub dsp_idle_ns: u64,
}
