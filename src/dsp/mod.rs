//! Real-time signal processing blocks: lock-in demodulators and the sliding spectrum.
//! Blocks take preallocated state and never allocate, lock, log or block in `process`.
//!
//! The drive phase ([`crate::timebase::PhaseAccumulator`]) and the pre-decimation factor
//! come from [`crate::timebase`], which the synthesiser shares.
//! - [`LockInBank`]: up to 32 [`Demodulator`]s at harmonics of the drive or of a second
//!   excitation ([`Oscillator`]), sharing one pre-decimator ([`Predecimator`]) and each
//!   followed by its own [`LowPass`].
//! - [`SlidingSpectrum`]: windowed ([`Window`]), amplitude-calibrated, hop-based real FFT.
//!
//! Construction (planning, tables, buffers) allocates and belongs off the real-time thread;
//! `process` does not.

mod lockin;
mod lowpass;
mod predecimator;
mod simd;
mod spectrum;
mod window;

pub use lockin::{
    Demodulator, LockInBank, LockInSample, MAX_DEMODULATORS, Oscillator, PREDECIMATION_ORDER,
    SPLIT_LANES,
};
pub use lowpass::{LowPass, LowPassState, MAX_ORDER};
pub use predecimator::Predecimator;
pub use realfft::num_complex::Complex;
pub use spectrum::{SlidingSpectrum, SpectrumConfig, SpectrumFrame};
pub use window::Window;

/// Why a DSP block could not be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DspError {
    /// Sample rate not finite and positive (Hz).
    #[error("sample rate must be finite and > 0 Hz, got {0}")]
    SampleRate(f64),
    /// A frequency word could not be formed (sample rate or frequency not finite).
    #[error(transparent)]
    Word(#[from] crate::timebase::WordError),
    /// Low-pass order outside 1–8.
    #[error("low-pass order must be 1–{MAX_ORDER}, got {0}")]
    Order(u32),
    /// Time constant not finite and positive (s).
    #[error("time constant must be finite and > 0 s, got {0}")]
    TimeConstant(f64),
    /// Output rate not finite and positive (Hz).
    #[error("output rate must be finite and > 0 Hz, got {0}")]
    OutputRate(f64),
    /// More demodulators than the bank holds.
    #[error("at most {MAX_DEMODULATORS} demodulators, got {0}")]
    TooManyDemodulators(usize),
    /// One demodulator's settings are invalid.
    #[error("demodulator {index}: {source}")]
    Demodulator {
        /// Index of the demodulator in the bank.
        index: usize,
        /// What is wrong with it.
        source: Box<DspError>,
    },
    /// Spectrum size below 2 samples.
    #[error("spectrum size must be at least 2 samples, got {0}")]
    SpectrumSize(usize),
    /// Spectrum hop of 0 samples.
    #[error("spectrum hop must be at least 1 sample, got {0}")]
    Hop(usize),
}
