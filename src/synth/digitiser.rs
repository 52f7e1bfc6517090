//! The ADC's back half: its FIRs ([`super::adc`]), the detector noise, clipping and
//! quantisation, as a stage of its own, so that the DSP thread can run it on the signal
//! through the ADC's window that the synthesiser hands over ([`WindowSample`]).
//!
//! Why: the synthesiser is the busier of the two real-time threads (at 25 MS/s on the
//! AVX2 build it was 93 % busy against the DSP's 68 %), and these steps need nothing of the
//! modal states. The synthesiser keeps the filter's histories as if it had filtered
//! ([`super::adc::AdcFilter::pass`]) and sends them with each block
//! ([`DigitiserInput`]), so every block can be finished on its own, gaps in the stream
//! included, and the samples are those of [`super::SynthPlan::process`] bit for bit.
//! The detector's deviates are a stream of their own for each page of samples
//! ([`super::noise_pages::draw_detector`]), so this stage draws them itself.

use super::adc::{Adc, AdcFilter, AdcHistory, GRID_TAPS, WindowSample};
use super::noise_pages::{PAGE, draw_detector};

/// How a block's window samples become samples: the plan's settings of the ADC's back
/// half, and the filter's histories at the block's first sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DigitiserInput {
    /// Whether the anti-alias filter is on (`/synth/anti_alias`); off, the window samples'
    /// `grid` is the signal.
    pub filter: bool,
    /// Standard deviation of the detector noise per sample (m).
    pub detector_sigma: f64,
    /// Clipping and quantisation, if on.
    pub adc: Option<Adc>,
    /// The noise seed, whose pages hold the detector's deviates.
    pub seed: u64,
    /// The filter's histories before the block's first sample.
    pub history: AdcHistory,
}

/// The stage's buffers, allocated once, off the real-time thread.
#[derive(Clone, Debug)]
pub struct Digitiser {
    filter: AdcFilter,
    taps: [f64; GRID_TAPS],
    /// The detector's deviates of page `page.1` of seed `page.0`.
    detector: Box<[f32]>,
    page: Option<(u64, u64)>,
    /// Whether the CPU has AVX2 (and `FTAFM_ISA` allows it).
    avx2: bool,
}

impl Digitiser {
    /// A stage for blocks of up to `block` samples.
    pub fn new(block: usize) -> Self {
        Self {
            filter: AdcFilter::new(block, |_| 0.0),
            taps: super::adc::grid_taps(),
            detector: vec![0.0; PAGE].into_boxed_slice(),
            page: None,
            avx2: crate::cpu::avx2_available(),
        }
    }

    /// Finishes the window samples of stream samples `index` … (the concatenation of
    /// `window`'s two slices, as a ring holds them) into `out`, as long; returns the
    /// samples clipped. Allocation-free.
    ///
    /// # Panics
    /// If the block is longer than the stage was built for, or `out` is not as long.
    pub fn finish(
        &mut self,
        input: &DigitiserInput,
        index: u64,
        window: [&[WindowSample]; 2],
        out: &mut [f64],
    ) -> u64 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only where the CPU has AVX2.
            return unsafe { self.finish_avx2(input, index, window, out) };
        }
        self.finish_with(input, index, window, out)
    }

    /// [`finish`](Self::finish) compiled for AVX2 (the copies and the quantiser are wider;
    /// no multiply-add is fused, so the same bits). The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn finish_avx2(
        &mut self,
        input: &DigitiserInput,
        index: u64,
        window: [&[WindowSample]; 2],
        out: &mut [f64],
    ) -> u64 {
        self.finish_with(input, index, window, out)
    }

    #[inline(always)]
    fn finish_with(
        &mut self,
        input: &DigitiserInput,
        index: u64,
        window: [&[WindowSample]; 2],
        out: &mut [f64],
    ) -> u64 {
        let n = out.len();
        assert!(n <= self.filter.chunk() && window[0].len() + window[1].len() == n);
        let (head, tail) = (window[0].len(), window[1].len());
        if input.filter {
            self.filter.set_history(&input.history);
            let (grid, mid) = self.filter.chunk_mut(n);
            for (range, part) in [(0..head, window[0]), (head..head + tail, window[1])] {
                for ((g, m), s) in grid[range.clone()]
                    .iter_mut()
                    .zip(&mut mid[range])
                    .zip(part)
                {
                    (*g, *m) = (s.grid, s.mid);
                }
            }
            self.filter.decimate(&self.taps, out);
        } else {
            for (range, part) in [(0..head, window[0]), (head..head + tail, window[1])] {
                for (o, s) in out[range].iter_mut().zip(part) {
                    *o = s.grid;
                }
            }
        }
        let mut clipped = 0;
        let mut done = 0;
        while done < n {
            let at = index + done as u64;
            let within = (at % PAGE as u64) as usize;
            let len = (n - done).min(PAGE - within);
            let chunk = &mut out[done..done + len];
            let detector = if input.detector_sigma > 0.0 {
                let key = (input.seed, at / PAGE as u64);
                if self.page != Some(key) {
                    draw_detector(key.0, key.1, &mut self.detector);
                    self.page = Some(key);
                }
                &self.detector[within..within + len]
            } else {
                &[][..]
            };
            clipped += detect_and_quantise(chunk, input.detector_sigma, detector, input.adc);
            done += len;
        }
        clipped
    }
}

/// The detector noise (`sigma` times `detector`'s deviates, one per sample) and the ADC
/// (`adc`), which act on the signal only, not on the modes: a branch-free pass over the
/// chunk. Returns the samples clipped.
#[inline(always)]
pub(crate) fn detect_and_quantise(
    chunk: &mut [f64],
    sigma: f64,
    detector: &[f32],
    adc: Option<Adc>,
) -> u64 {
    if sigma > 0.0 {
        for (out, z) in chunk.iter_mut().zip(detector) {
            *out += sigma * f64::from(*z);
        }
    }
    let mut clipped = 0;
    if let Some(adc) = adc {
        for out in chunk.iter_mut() {
            let s = out.clamp(-adc.range, adc.range);
            clipped += u64::from(s != *out);
            *out = round_to_step(s, adc.lsb, adc.codes_per_metre);
        }
    }
    clipped
}

/// `x` rounded to the nearest multiple of `step` = 1/`inverse` (ties to even). Adding and
/// subtracting 1.5·2^52 rounds in the FPU's default mode; `f64::round` is a library call on
/// baseline x86-64. Valid while |x/step| < 2^51, far beyond any ADC's 2^32 codes.
#[inline]
fn round_to_step(x: f64, step: f64, inverse: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5·2^52
    ((x * inverse + MAGIC) - MAGIC) * step
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Engine, default_settings};
    use crate::synth::{SynthPlan, SynthState};

    /// Blocks of window samples finished here are [`SynthPlan::process`]'s samples bit for
    /// bit: both engines, filter on and off, detector noise and a quantiser that clips;
    /// blocks of any length, handed over in two slices as a ring holds them, each finished
    /// by a fresh stage (so nothing but the block's input carries over); across live
    /// changes that turn the filter off and on again, and blocks finished in place (a
    /// scan's) between them.
    #[test]
    fn finished_window_blocks_are_the_processed_stream_bit_for_bit() {
        // Without the quantiser every last bit shows; with it, some samples clip.
        for (engine, bits) in [
            (Engine::Paper, 0),
            (Engine::Coupled, 0),
            (Engine::Paper, 16),
            (Engine::Coupled, 16),
        ] {
            let mut settings = default_settings();
            settings.synth.engine = engine;
            settings.noise.adc_bits = bits;
            // A full scale inside the oscillation.
            settings.noise.adc_range = 10e-9;
            let on = SynthPlan::new(&settings).unwrap();
            assert!(on.detector_sigma > 0.0 && on.adc.is_some() == (bits > 0));
            assert!(on.anti_alias.is_some());
            settings.synth.anti_alias = false;
            let off = SynthPlan::new(&settings).unwrap();
            let mut here = SynthState::steady(&on, 3);
            let mut there = here.clone();
            let (mut clipped, mut compared) = (0, 0);
            let mut plan = &on;
            // 269: chunks of 256 and 13, the last too short to hold
            // the compensator's history alone.
            for (round, len) in [4096, 1, 255, 4096, 5000, 37, 4096, 300, 3840, 269, 4096]
                .into_iter()
                .enumerate()
            {
                // Off for rounds 4 … 6, on again after.
                let next = if (4..7).contains(&round) { &off } else { &on };
                if !std::ptr::eq(next, plan) {
                    here.retarget(plan, next);
                    there.retarget(plan, next);
                    plan = next;
                }
                let index = there.sample_index();
                let mut want = vec![0.0; len];
                plan.process(&mut here, &mut want);
                let mut got = vec![0.0; len];
                if round % 4 == 2 {
                    // Finished in place, as a scan's blocks are, between window blocks.
                    plan.process(&mut there, &mut got);
                } else {
                    let mut window = vec![WindowSample::default(); len];
                    let input = plan.process_window(&mut there, &mut window);
                    let (a, b) = window.split_at(len / 3);
                    clipped += Digitiser::new(5000).finish(&input, index, [a, b], &mut got);
                }
                for (i, (w, g)) in want.iter().zip(&got).enumerate() {
                    assert_eq!(
                        w.to_bits(),
                        g.to_bits(),
                        "{engine:?}, round {round}, sample {i}: {w:e} vs {g:e}"
                    );
                }
                compared += len;
                assert_eq!(here.sample_index(), there.sample_index());
            }
            assert_eq!(
                clipped + there.counters.clipped,
                here.counters.clipped,
                "{engine:?}"
            );
            if bits > 0 {
                assert!(clipped > 100, "{engine:?}: {clipped} of {compared} clipped");
            }
        }
    }
}
