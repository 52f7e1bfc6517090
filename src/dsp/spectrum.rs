//! Sliding (hop-based) FFT of the photodiode signal.
//!
//! Each frame is an independent windowed real FFT of the last `size` samples, so nothing
//! recursive can drift; a frame is due every `hop` samples.

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};

use super::{DspError, Window};

/// Configuration of a [`SlidingSpectrum`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpectrumConfig {
    /// Input sample rate f_s (Hz).
    pub sample_rate: f64,
    /// FFT length N (samples, ≥ 2); the bin width is f_s/N.
    pub size: usize,
    /// Samples between the starts of consecutive frames (≥ 1); the frame rate is f_s/hop.
    /// A hop larger than `size` skips samples.
    pub hop: usize,
    /// Window applied to each frame.
    pub window: Window,
}

/// One spectrum, lent to the sink for the duration of the call.
#[derive(Clone, Copy, Debug)]
pub struct SpectrumFrame<'a> {
    /// Index of the frame's first input sample (counted from the first sample the spectrum
    /// was given); the frame covers samples `start_index .. start_index + size`.
    pub start_index: u64,
    /// Bins 0…N/2, amplitude-calibrated: a tone `A·cos(2π f t + φ)` with f on bin b (0 < b
    /// < N/2) reads `A·e^{iφ}` there, with t = 0 at `start_index`; bin 0 reads the mean,
    /// and bin N/2 (N even) reads a Nyquist tone's `A·cos φ`. Off-bin tones read low by
    /// at most the window's [`scallop_loss`](Window::scallop_loss).
    pub bins: &'a [Complex<f64>],
    /// Bin spacing f_s/N (Hz).
    pub bin_width: f64,
}

/// Windowed, amplitude-calibrated FFT over the last `size` samples, every `hop` samples.
///
/// Built off the real-time thread (plans the FFT and allocates every buffer once);
/// [`process`](Self::process) neither allocates nor locks.
pub struct SlidingSpectrum {
    config: SpectrumConfig,
    fft: Arc<dyn RealToComplex<f64>>,
    /// Window times the calibration 2/Σw, so no pass over the bins is needed but for the
    /// DC and Nyquist bins, which are halved.
    scaled_window: Vec<f64>,
    /// Last `size` input samples; `write` is where the next one goes (the oldest one).
    ring: Vec<f64>,
    write: usize,
    /// FFT input (destroyed by the FFT), output and scratch.
    frame: Vec<f64>,
    bins: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    /// Samples consumed since construction or [`reset`](Self::reset).
    samples: u64,
    /// Sample count at which the next frame is complete.
    next_frame_end: u64,
}

impl SlidingSpectrum {
    /// Plan the FFT and allocate every buffer.
    pub fn new(config: SpectrumConfig) -> Result<Self, DspError> {
        if !(config.sample_rate.is_finite() && config.sample_rate > 0.0) {
            return Err(DspError::SampleRate(config.sample_rate));
        }
        if config.size < 2 {
            return Err(DspError::SpectrumSize(config.size));
        }
        if config.hop == 0 {
            return Err(DspError::Hop(config.hop));
        }
        let fft = RealFftPlanner::<f64>::new().plan_fft_forward(config.size);
        let mut scaled_window = vec![0.0; config.size];
        config.window.fill(&mut scaled_window);
        let gain = 2.0 / scaled_window.iter().sum::<f64>();
        for w in &mut scaled_window {
            *w *= gain;
        }
        Ok(Self {
            fft: fft.clone(),
            scaled_window,
            ring: vec![0.0; config.size],
            write: 0,
            frame: fft.make_input_vec(),
            bins: fft.make_output_vec(),
            scratch: fft.make_scratch_vec(),
            samples: 0,
            next_frame_end: config.size as u64,
            config,
        })
    }

    /// The configuration it was built with.
    pub const fn config(&self) -> &SpectrumConfig {
        &self.config
    }

    /// Frame rate f_s/hop (Hz).
    pub fn output_rate(&self) -> f64 {
        self.config.sample_rate / self.config.hop as f64
    }

    /// Bin spacing f_s/N (Hz).
    pub fn bin_width(&self) -> f64 {
        self.config.sample_rate / self.config.size as f64
    }

    /// Number of bins per frame, N/2 + 1.
    pub fn bin_count(&self) -> usize {
        self.config.size / 2 + 1
    }

    /// Frequency of bin `bin` (Hz).
    pub fn bin_frequency(&self, bin: usize) -> f64 {
        bin as f64 * self.bin_width()
    }

    /// Forget all input: the next frame is due once `size` new samples have arrived.
    pub fn reset(&mut self) {
        self.ring.fill(0.0);
        self.write = 0;
        self.samples = 0;
        self.next_frame_end = self.config.size as u64;
    }

    /// Consume `input` (the photodiode signal, any unit; bins come out in the same unit)
    /// and hand every frame that completes to `sink`, in time order. Real-time safe.
    pub fn process<F>(&mut self, input: &[f64], mut sink: F)
    where
        F: FnMut(SpectrumFrame<'_>),
    {
        let size = self.config.size;
        let mut rest = input;
        while !rest.is_empty() {
            // Only the last `size` samples before a frame end matter: skip the others
            // without copying (matters when hop ≫ size).
            let until_frame = self.next_frame_end - self.samples;
            let skip = until_frame.saturating_sub(size as u64);
            if skip > 0 {
                let n = skip.min(rest.len() as u64) as usize;
                rest = &rest[n..];
                self.samples += n as u64;
                continue;
            }
            let n = (until_frame as usize).min(rest.len());
            self.push(&rest[..n]);
            rest = &rest[n..];
            self.samples += n as u64;
            if self.samples == self.next_frame_end {
                self.transform();
                sink(SpectrumFrame {
                    start_index: self.samples - size as u64,
                    bins: &self.bins,
                    bin_width: self.bin_width(),
                });
                self.next_frame_end += self.config.hop as u64;
            }
        }
    }

    /// Append at most `size` samples to the ring.
    fn push(&mut self, input: &[f64]) {
        let size = self.ring.len();
        let first = input.len().min(size - self.write);
        self.ring[self.write..self.write + first].copy_from_slice(&input[..first]);
        let second = input.len() - first;
        self.ring[..second].copy_from_slice(&input[first..]);
        self.write = (self.write + input.len()) % size;
    }

    /// Window the ring (oldest sample first) into the FFT input and transform it.
    fn transform(&mut self) {
        let (newer, older) = self.ring.split_at(self.write);
        let (w_old, w_new) = self.scaled_window.split_at(older.len());
        let (f_old, f_new) = self.frame.split_at_mut(older.len());
        for ((f, x), w) in f_old.iter_mut().zip(older).zip(w_old) {
            *f = x * w;
        }
        for ((f, x), w) in f_new.iter_mut().zip(newer).zip(w_new) {
            *f = x * w;
        }
        let done =
            self.fft
                .process_with_scratch(&mut self.frame, &mut self.bins, &mut self.scratch);
        // The buffers were made by the plan itself, so their lengths cannot be wrong.
        debug_assert!(done.is_ok());
        // The one-sided doubling applies to neither DC nor Nyquist: they have no mirror.
        self.bins[0] *= 0.5;
        if self.config.size.is_multiple_of(2) {
            let last = self.bins.len() - 1;
            self.bins[last] *= 0.5;
        }
    }
}

impl std::fmt::Debug for SlidingSpectrum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlidingSpectrum")
            .field("config", &self.config)
            .field("samples", &self.samples)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_arrive_every_hop_whatever_the_block_size() {
        for hop in [1usize, 7, 64, 100, 300] {
            for block in [1usize, 13, 64, 1000] {
                let mut s = SlidingSpectrum::new(SpectrumConfig {
                    sample_rate: 1.0,
                    size: 64,
                    hop,
                    window: Window::Hann,
                })
                .unwrap();
                let signal: Vec<f64> = (0..2000).map(|i| i as f64).collect();
                let mut starts = Vec::new();
                for chunk in signal.chunks(block) {
                    s.process(chunk, |f| starts.push(f.start_index));
                }
                let expect: Vec<u64> = (0..)
                    .map(|i| i * hop as u64)
                    .take_while(|s| s + 64 <= 2000)
                    .collect();
                assert_eq!(starts, expect, "hop {hop} block {block}");
            }
        }
    }

    #[test]
    fn dc_reads_the_mean() {
        let mut s = SlidingSpectrum::new(SpectrumConfig {
            sample_rate: 1.0,
            size: 256,
            hop: 256,
            window: Window::BlackmanHarris,
        })
        .unwrap();
        let mut dc = 0.0;
        s.process(&[0.7; 256], |f| dc = f.bins[0].re);
        assert!((dc - 0.7).abs() < 1e-12);
    }
}
