//! The instrument's timebase, below both real-time stages: the drive phase as an integer
//! accumulator, the frequency words of the drive and its harmonics, and the lock-in's
//! pre-decimation that fixes the grid of demodulator (and scan pixel) times. The
//! synthesiser and the DSP both import it and otherwise meet only through the ring.
//!
//! The phase lives in a `u64` word where 2^64 is one full cycle. Advancing by the frequency
//! word is exact modular integer arithmetic, so the phase after n samples is exactly
//! `phase₀ + n·word (mod 2^64)` however long the instrument runs: no rounding accumulates.
//! Harmonic k of the drive has the phase word `k · phase (mod 2^64)`, again exact.

use std::f64::consts::PI;

/// Decimation factor D of the lock-in's shared pre-decimator (input samples per decimated
/// sample): demodulator outputs, and so scan pixels, fall on multiples of it.
pub const PREDECIMATION: usize = 16;

/// Why a frequency word could not be formed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum WordError {
    /// Sample rate not finite and positive (Hz).
    #[error("sample rate must be finite and > 0 Hz, got {0}")]
    SampleRate(f64),
    /// Frequency not finite (Hz).
    #[error("frequency must be finite, got {0} Hz")]
    Frequency(f64),
}

/// 2^64 as an `f64` (exact): the phase words of one cycle.
pub const TWO_POW_64: f64 = 18_446_744_073_709_551_616.0;

/// Drive phase and frequency of one oscillator as integer words (2^64 = one cycle).
///
/// [`phase`](Self::phase) is the phase of the *current* sample, the one that the next call
/// to [`advance`](Self::advance) moves past. Phase word 0 is the positive peak of the
/// reference cosine: a signal `A·cos(k·θ + φ)`, with θ the phase of this accumulator, has
/// phase φ at harmonic k.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PhaseAccumulator {
    phase: u64,
    step: u64,
}

impl PhaseAccumulator {
    /// An accumulator at phase 0 advancing at `frequency` (Hz) for samples at `sample_rate`
    /// (Hz). The realised frequency is f_s·word/2^64 (see [`frequency_word`]).
    pub fn new(frequency: f64, sample_rate: f64) -> Result<Self, WordError> {
        Ok(Self {
            phase: 0,
            step: frequency_word(frequency, sample_rate)?,
        })
    }

    /// An accumulator from raw words: `phase` of the current sample and `step` per sample
    /// (both in units of 2^-64 cycle).
    pub const fn from_words(phase: u64, step: u64) -> Self {
        Self { phase, step }
    }

    /// Phase word of the current sample (2^-64 cycle).
    pub const fn phase(&self) -> u64 {
        self.phase
    }

    /// Phase of the current sample in radians, in [−π, π).
    pub fn phase_radians(&self) -> f64 {
        phase_to_radians(self.phase)
    }

    /// Frequency word: phase advance per sample (2^-64 cycle).
    pub const fn frequency_word(&self) -> u64 {
        self.step
    }

    /// Realised frequency (Hz) for samples at `sample_rate` (Hz).
    pub fn frequency(&self, sample_rate: f64) -> f64 {
        self.step as f64 / TWO_POW_64 * sample_rate
    }

    /// Phase word `offset` samples after the current one (before it if negative), exact.
    pub const fn phase_at(&self, offset: i64) -> u64 {
        self.phase
            .wrapping_add((offset as u64).wrapping_mul(self.step))
    }

    /// Move `samples` samples on.
    pub const fn advance(&mut self, samples: u64) {
        self.phase = self.phase.wrapping_add(samples.wrapping_mul(self.step));
    }

    /// Set the phase word of the current sample.
    pub const fn set_phase(&mut self, phase: u64) {
        self.phase = phase;
    }

    /// Change the frequency (Hz) keeping the phase of the current sample: the phase is
    /// continuous across the change, only its slope changes.
    pub fn set_frequency(&mut self, frequency: f64, sample_rate: f64) -> Result<(), WordError> {
        self.step = frequency_word(frequency, sample_rate)?;
        Ok(())
    }
}

/// Frequency word `round(2^64 · f / f_s) mod 2^64` for `frequency` f (Hz) at `sample_rate`
/// f_s (Hz). Negative frequencies and frequencies above f_s wrap, as sampling does.
///
/// The word is exactly 2^64 times the `f64` value of f/f_s (rounded to an integer when
/// f/f_s < 2^-11), so the realised frequency is within a relative 2^-53 of the request,
/// or f_s/2^65 absolute for the lowest frequencies: 10⁻¹¹ Hz at 100 kHz, 10⁻¹⁰ rad of
/// phase after 10⁸ samples at 10 MS/s.
pub fn frequency_word(frequency: f64, sample_rate: f64) -> Result<u64, WordError> {
    if !(sample_rate.is_finite() && sample_rate > 0.0) {
        return Err(WordError::SampleRate(sample_rate));
    }
    if !frequency.is_finite() {
        return Err(WordError::Frequency(frequency));
    }
    // Reducing to one cycle first keeps the scaled value inside u64 range; rem_euclid of
    // an f64 by 1 is exact.
    let cycles = (frequency / sample_rate).rem_euclid(1.0);
    let word = (cycles * TWO_POW_64).round();
    // cycles < 1 but may round up to exactly 2^64, which is one full cycle: phase 0.
    Ok(if word >= TWO_POW_64 { 0 } else { word as u64 })
}

/// Phase word (2^-64 cycle) in radians, in [−π, π). The error is below 2^-53·π.
#[inline]
pub fn phase_to_radians(word: u64) -> f64 {
    // Reading the word as signed centres the range on 0, where f64 is densest.
    (word as i64) as f64 * (PI / 9_223_372_036_854_775_808.0)
}

/// Phase word of harmonic `k` of a drive phase word, exact: `k · phase (mod 2^64)`.
#[inline]
pub const fn harmonic_phase(phase: u64, k: u32) -> u64 {
    phase.wrapping_mul(k as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn word_of_commensurate_frequency_is_exact_after_a_period() {
        let mut acc = PhaseAccumulator::new(100e3, 10e6).unwrap();
        // 100 kHz at 10 MS/s: 100 samples per period, but 0.01 is not exact in binary, so
        // the phase after 100 samples is a few thousand words (~1e-15 cycle) from zero.
        acc.advance(100);
        assert!(((acc.phase() as i64).unsigned_abs() as f64) < 1e-15 * 2f64.powi(64));
    }

    #[test]
    fn radians_and_words() {
        assert_eq!(phase_to_radians(0), 0.0);
        assert!((phase_to_radians(1 << 62) - PI / 2.0).abs() < 1e-15);
        assert!((phase_to_radians(1 << 63) + PI).abs() < 1e-15);
        assert_eq!(frequency_word(0.0, 1.0).unwrap(), 0);
        assert_eq!(frequency_word(0.25, 1.0).unwrap(), 1 << 62);
        assert_eq!(frequency_word(-0.25, 1.0).unwrap(), 3 << 62);
        assert_eq!(frequency_word(1.0, 1.0).unwrap(), 0);
        assert!(frequency_word(1.0, 0.0).is_err());
        assert!(frequency_word(f64::NAN, 1.0).is_err());
    }

    #[test]
    fn phase_at_negative_offset_undoes_advance() {
        let mut acc = PhaseAccumulator::new(137e3, 10e6).unwrap();
        acc.advance(12_345);
        let p = acc.phase();
        acc.advance(678);
        assert_eq!(acc.phase_at(-678), p);
        assert_eq!(acc.phase_at(0), acc.phase());
    }

    #[test]
    fn set_frequency_keeps_phase() {
        let mut acc = PhaseAccumulator::new(100e3, 10e6).unwrap();
        acc.advance(17);
        let p = acc.phase();
        acc.set_frequency(100.0123e3, 10e6).unwrap();
        assert_eq!(acc.phase(), p);
        assert!((acc.frequency(10e6) - 100.0123e3).abs() < 1e-9);
    }

    #[test]
    fn harmonic_phase_wraps() {
        assert_eq!(harmonic_phase(1 << 62, 4), 0);
        assert_eq!(harmonic_phase(1 << 62, 3), 3 << 62);
    }
}
