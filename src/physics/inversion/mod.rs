//! FT-AFM force reconstruction (the paper's Sec. 3, last part): from the photodiode harmonics
//! back to the tip–sample force, and from the force to the sample's Young's modulus.
//!
//! Three steps, all pure functions (no threads, no I/O):
//!
//! - [`fit_two_harmonics`]: "only the amplitudes of two higher harmonics" — the contact time
//!   ratio τ and peak force F of the cut cosine (Eq. 20) from two photodiode amplitudes, with
//!   first-order uncertainties.
//! - [`reconstruct_force`]: the "more sophisticated approach" — every usable harmonic divided
//!   by the light-lever transfer, the rest filled from the cut-cosine fit, and the force over
//!   one period by inverse Fourier series.
//! - [`fit_cut_cosine`]: τ, F and the pulse phase of the cut cosine fitted to every measured
//!   harmonic by weighted least squares (maximum likelihood for Gaussian lock-in noise), with
//!   its covariance.
//! - [`ModulusTable`]: Young's modulus from (F, τ) through the 1-DOF Hertz impact oscillator.
//!
//! What the lock-in reads for a given force — the light-lever transfer and the harmonics
//! aliased by sampling — is [`LockInModel`]; how much noise each reading carries,
//! [`NoiseModel`] and [`LowPassNoise`].
//!
//! Conventions are those of [`super::spectrum`]: two-sided coefficients q(t) = Σ c_k e^{ikΩt},
//! peak amplitude 2|c_k| for k ≥ 1, phases relative to cos(kθ) with θ the drive phase.

mod fit;
mod forward;
mod modulus;
mod noise;
mod reconstruct;
mod two_harmonic;

pub use fit::{CutCosineLsq, CutCosineStart, fit_cut_cosine};
pub use forward::{
    ALIAS_HARMONICS, AliasTerm, LockInModel, cut_cosine_phasor, cut_cosine_spectrum,
};
pub use noise::{BOLTZMANN, LowPassNoise, NoiseModel, lockin_sigma};

pub use modulus::{
    DEFAULT_TABLE_POINTS, DEFAULT_TABLE_RANGE, ModulusError, ModulusEstimate, ModulusTable,
    PulseMeasure, TableNode, TableRange,
};
pub use reconstruct::{
    CoefficientSource, CutCosinePrior, ForceCoefficient, ForceReconstruction, HarmonicSample,
    InversionOptions, MAX_AUTO_HARMONIC, TAIL_LOBES, TransferMinimum, force_series,
    light_lever_minima, reconstruct_force, reconstruct_force_with, two_harmonic_prior,
};
pub use two_harmonic::{
    AMBIGUITY_SCAN_END, AmplitudeMeasurement, CutCosineFit, cut_cosine_from_coefficients,
    cut_cosine_shape, first_spectral_zero, fit_two_harmonics,
};

/// Why an inversion cannot be done. Impossible inputs are errors, never panics.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InversionError {
    /// The two harmonics of the two-harmonic method are the same.
    #[error("the two harmonics must differ (both are {0})")]
    SameHarmonic(usize),
    /// Harmonics 0 and 1 cannot be used by the two-harmonic method.
    #[error(
        "harmonic {0} cannot be used: the two-harmonic method needs harmonics ≥ 2 (the \
         fundamental is dominated by the drive response)"
    )]
    HarmonicTooLow(usize),
    /// An amplitude is zero, negative or not finite.
    #[error("the amplitude of harmonic {harmonic} must be positive and finite (got {amplitude})")]
    InvalidAmplitude { harmonic: usize, amplitude: f64 },
    /// A standard deviation is negative or not finite.
    #[error("the standard deviation of harmonic {harmonic} must be ≥ 0 and finite (got {sigma})")]
    InvalidSigma { harmonic: usize, sigma: f64 },
    /// The drive frequency is not positive and finite.
    #[error("the drive frequency must be positive and finite (got {0} Hz)")]
    InvalidDriveFrequency(f64),
    /// The sample rate is not positive and finite.
    #[error("the sample rate must be positive and finite (got {0} Hz)")]
    InvalidSampleRate(f64),
    /// A harmonic is not one the forward model was built for.
    #[error("harmonic {0} is not in the lock-in model")]
    HarmonicNotModelled(usize),
    /// The least-squares fit of the cut cosine did not find a pulse.
    #[error("the cut-cosine fit failed: {0}")]
    FitFailed(&'static str),
    /// No cut cosine with both harmonics before its first spectral zero has this ratio.
    #[error(
        "the force-coefficient ratio |c_{low}|/|c_{high}| = {ratio} is out of range: a cut \
         cosine with both harmonics before its first spectral zero (τ < 1.5/{high}) has a \
         ratio in (1, ∞)"
    )]
    RatioOutOfRange { low: usize, high: usize, ratio: f64 },
    /// A harmonic appears twice in the input of the full inversion.
    #[error("harmonic {0} is given twice")]
    DuplicateHarmonic(usize),
    /// A complex harmonic is not finite.
    #[error("harmonic {0} is not finite")]
    NonFiniteHarmonic(usize),
    /// Fewer than two harmonics ≥ 2 are measured above the noise, so no cut cosine can be
    /// fitted.
    #[error("no pair of harmonics ≥ 2 above the noise floor to fit the cut cosine with")]
    NoUsablePair,
    /// A harmonic of the requested pair was not measured.
    #[error("harmonic {0} of the requested pair is not among the measured harmonics")]
    PairNotMeasured(usize),
    /// The reconstruction grid is too coarse.
    #[error("the reconstruction grid needs at least {minimum} points (got {got})")]
    GridTooSmall { minimum: usize, got: usize },
    /// The minimum signal-to-noise ratio is negative or not finite.
    #[error("the minimum signal-to-noise ratio must be ≥ 0 and finite (got {0})")]
    InvalidSnr(f64),
    /// The reconstructed force has no positive peak.
    #[error("the reconstructed force has no positive peak")]
    NoPulse,
}

/// Golden-section search for a minimum of a unimodal `f` on [a, b]: narrows the bracket until
/// `done(a, b)` (or 200 steps) and returns it.
fn golden_section(
    f: &impl Fn(f64) -> f64,
    mut a: f64,
    mut b: f64,
    done: impl Fn(f64, f64) -> bool,
) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..200 {
        if done(a, b) {
            break;
        }
        if f1 <= f2 {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - g * (b - a);
            f1 = f(x1);
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + g * (b - a);
            f2 = f(x2);
        }
    }
    (a, b)
}
