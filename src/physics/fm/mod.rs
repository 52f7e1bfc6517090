//! FM-AFM: the frequency shift Δf of a cantilever oscillating at amplitude A over a force
//! law ([`frequency_shift`]), and the Sader–Jarvis inversion of a measured Δf(z) back to
//! the force F(z) ([`sader_jarvis::invert`]).
//!
//! Conventions (Giessibl 1997; Sader & Jarvis 2004): the force F(d) acts on the tip at
//! distance d from the sample, positive when repulsive, negative when attractive; z (or d)
//! is the distance of closest approach of the oscillating tip, which swings over
//! [z, z + 2A]; an attractive force lowers the resonance (Δf < 0). In the small-amplitude
//! limit Δf = −f0/(2k)·dF/dz at the orbit's centre z + A.

pub mod sader_jarvis;

use std::f64::consts::PI;

pub use sader_jarvis::{ForceCurve, invert};

/// Quadrature nodes [`frequency_shift`] uses by default: enough for 0.1 % on a force law
/// with a kink (Hertz contact) at amplitudes up to 10⁴ times its decay length.
pub const DEFAULT_NODES: usize = 4096;

/// The oscillating lever of FM-AFM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FmLever {
    /// Spring constant k (N/m).
    pub stiffness: f64,
    /// Free resonance frequency f0 (Hz).
    pub resonance: f64,
    /// Oscillation amplitude A (m, zero to peak).
    pub amplitude: f64,
}

/// A bad input of the FM-AFM maths, named.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FmError {
    /// A scalar parameter out of its range.
    #[error("{name} = {value} is out of range: allowed {allowed}")]
    Parameter {
        /// Which parameter (`k`, `f0`, `amplitude`).
        name: &'static str,
        /// The value given.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// z and Δf of different lengths.
    #[error("z has {z} samples but df has {df}: give one frequency shift per distance")]
    Lengths {
        /// Samples of z.
        z: usize,
        /// Samples of Δf.
        df: usize,
    },
    /// Too few samples to invert.
    #[error("{len} samples given: at least 3 are needed")]
    TooShort {
        /// Samples given.
        len: usize,
    },
    /// A sample that is NaN or infinite.
    #[error("{name}[{index}] = {value} is not finite")]
    NotFinite {
        /// `z` or `df`.
        name: &'static str,
        /// Its index.
        index: usize,
        /// The value.
        value: f64,
    },
    /// z not strictly increasing.
    #[error("z must increase strictly: z[{index}] = {value} follows z[{}] = {previous}", index - 1)]
    NotIncreasing {
        /// The index of the offending sample.
        index: usize,
        /// Its value (m).
        value: f64,
        /// The sample before it (m).
        previous: f64,
    },
}

impl FmLever {
    /// A lever of stiffness `k` (N/m) and resonance `f0` (Hz) oscillating at `amplitude`
    /// (m); each must be finite and > 0.
    pub fn new(k: f64, f0: f64, amplitude: f64) -> Result<Self, FmError> {
        for (name, value, allowed) in [
            ("k", k, "a finite stiffness > 0 N/m"),
            ("f0", f0, "a finite frequency > 0 Hz"),
            ("amplitude", amplitude, "a finite amplitude > 0 m"),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(FmError::Parameter {
                    name,
                    value,
                    allowed,
                });
            }
        }
        Ok(Self {
            stiffness: k,
            resonance: f0,
            amplitude,
        })
    }
}

/// The frequency shift Δf (Hz) at closest approach `d` (m) over the force law `force` (N of
/// the distance in m, repulsive positive):
///
/// Δf(d) = −f0/(π·k·A) · ∫₋₁¹ F(d + A(1 + u)) · u/√(1 − u²) du,
///
/// by Gauss–Chebyshev quadrature of `nodes` points (u = cos θ at the midpoints of [0, π]
/// in θ), which takes the weight 1/√(1 − u²) exactly, so the endpoint singularity costs
/// nothing; its nodes cluster at the turning points, where the tip meets the force.
pub fn frequency_shift(lever: &FmLever, force: impl Fn(f64) -> f64, d: f64, nodes: usize) -> f64 {
    let nodes = nodes.max(1);
    let a = lever.amplitude;
    let step = PI / nodes as f64;
    let sum: f64 = (0..nodes)
        .map(|m| {
            let u = ((m as f64 + 0.5) * step).cos();
            force(d + a * (1.0 + u)) * u
        })
        .sum();
    -lever.resonance / (PI * lever.stiffness * a) * sum * step
}

/// [`frequency_shift`] at each distance of `z` (m), with [`DEFAULT_NODES`].
pub fn frequency_shift_curve(lever: &FmLever, force: impl Fn(f64) -> f64, z: &[f64]) -> Vec<f64> {
    z.iter()
        .map(|&d| frequency_shift(lever, &force, d, DEFAULT_NODES))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The modified Bessel function I₁(x) by its power series (x up to ~50).
    fn bessel_i1(x: f64) -> f64 {
        let mut term = x / 2.0;
        let mut sum = term;
        let q = x * x / 4.0;
        for m in 1..200 {
            term *= q / (m as f64 * (m as f64 + 1.0));
            sum += term;
            if term < 1e-17 * sum {
                break;
            }
        }
        sum
    }

    #[test]
    fn the_exponential_law_gives_giessibls_closed_form_at_any_amplitude() {
        // F = −F0·exp(−d/λ): Δf = −f0/(k·A)·F0·exp(−(d + A)/λ)·I₁(A/λ) (Giessibl 1997).
        let (f0_force, lambda) = (1e-9, 0.2e-9);
        let force = |d: f64| -f0_force * (-d / lambda).exp();
        for a in [1e-12, 0.1e-9, 1e-9, 5e-9] {
            let lever = FmLever::new(30.0, 300e3, a).unwrap();
            for d in [0.1e-9, 0.5e-9] {
                let got = frequency_shift(&lever, force, d, DEFAULT_NODES);
                let want = -300e3 / (30.0 * a)
                    * f0_force
                    * (-(d + a) / lambda).exp()
                    * bessel_i1(a / lambda);
                assert!(want < 0.0, "attraction lowers the frequency");
                assert!(
                    (got / want - 1.0).abs() < 1e-9,
                    "A = {a}, d = {d}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn small_amplitudes_give_the_force_gradient() {
        // Δf → −f0/(2k)·dF/dz at the orbit's centre when A ≪ λ.
        let (f0_force, lambda) = (1e-9, 0.5e-9);
        let force = |d: f64| -f0_force * (-d / lambda).exp();
        let gradient = |d: f64| f0_force / lambda * (-d / lambda).exp();
        let a = 1e-13;
        let lever = FmLever::new(2.0, 70e3, a).unwrap();
        for d in [0.2e-9, 1e-9, 2e-9] {
            let got = frequency_shift(&lever, force, d, 64);
            let want = -70e3 / (2.0 * 2.0) * gradient(d + a);
            assert!((got / want - 1.0).abs() < 1e-6, "d = {d}: {got} vs {want}");
        }
    }

    #[test]
    fn bad_lever_parameters_are_refused_by_name() {
        for (k, f0, a, name) in [
            (0.0, 1e5, 1e-9, "k"),
            (f64::NAN, 1e5, 1e-9, "k"),
            (1.0, -1e5, 1e-9, "f0"),
            (1.0, 1e5, 0.0, "amplitude"),
            (1.0, 1e5, f64::INFINITY, "amplitude"),
        ] {
            let e = FmLever::new(k, f0, a).unwrap_err();
            assert!(
                matches!(e, FmError::Parameter { name: n, .. } if n == name),
                "{e}"
            );
            assert!(e.to_string().starts_with(name), "{e}");
        }
    }
}
