//! The clamped–free Euler–Bernoulli cantilever (the paper's Appendix A and B).
//!
//! Mode shapes are those of Eq. (A.7) in the dimensionless coordinate ξ = x/L, normalised
//! so that ∫₀¹ φn² dξ = 1. With that normalisation φn(L) = 2(−1)ⁿ, the generalised mass is
//! the beam's mass and the generalised stiffness is Kn = k·λn⁴/3 (k = 3EI/L³).

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

/// Largest number of modes a [`Cantilever`] may carry. Eigenvalues are exact (to rounding)
/// for any n; the cap only bounds the cost of the synthesiser.
pub const MAX_MODES: usize = 16;

/// Eigenvalue λn = kn·L of mode `n` (1-based): the n-th positive root of
/// `1 + cos λ cosh λ = 0`, to full double precision.
///
/// # Panics
/// If `n` is zero.
pub fn eigenvalue(n: usize) -> f64 {
    assert!(n >= 1, "modes are numbered from 1");
    // cos λ + sech λ = 0 is the same equation without overflow, and it changes sign
    // across ((n − 1)π, nπ) with exactly one root inside (near (n − ½)π).
    let f = |l: f64| l.cos() + 1.0 / l.cosh();
    let (mut lo, mut hi) = ((n as f64 - 1.0) * PI, n as f64 * PI);
    if n == 1 {
        lo = 1.0; // f(0) = 2 > 0 and f(π) < 0; start away from 0 for clarity.
    }
    let flo = f(lo);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        let fm = f(mid);
        if fm == 0.0 || (hi - lo) < 4.0 * f64::EPSILON * mid {
            return mid;
        }
        if (fm > 0.0) == (flo > 0.0) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Shape function of Eq. (A.7) for eigenvalue `lambda`: value φ(ξ) and slope dφ/dξ.
///
/// Written so that the hyperbolic terms never overflow or cancel catastrophically:
/// `cosh x − σ sinh x = ((1 − σ)eˣ + (1 + σ)e⁻ˣ)/2`, with 1 − σ evaluated in closed form.
pub fn shape(lambda: f64, xi: f64) -> (f64, f64) {
    let l = lambda;
    let (s, c) = l.sin_cos();
    let em = (-l).exp();
    // sin λ + sinh λ scaled by e^{-λ}: finite for every λ.
    let denom_scaled = s * em + 0.5 * (1.0 - em * em);
    // σ = (cos λ + cosh λ)/(sin λ + sinh λ); 1 − σ = (sin λ − cos λ − e^{−λ})/(sin λ + sinh λ).
    let one_minus_sigma_scaled = (s - c - em) / denom_scaled; // (1 − σ)·e^{λ}
    let sigma = 1.0 - one_minus_sigma_scaled * em;
    let x = l * xi;
    let (sx, cx) = x.sin_cos();
    let ep = (l * (xi - 1.0)).exp(); // e^{x} · e^{−λ}
    let en = (-x).exp();
    let cosh_part = 0.5 * (one_minus_sigma_scaled * ep + (1.0 + sigma) * en);
    let sinh_part = 0.5 * (one_minus_sigma_scaled * ep - (1.0 + sigma) * en);
    let value = cx - sigma * sx - cosh_part;
    let slope = l * (-sx - sigma * cx - sinh_part);
    (value, slope)
}

/// Participation ∫₀¹ φ(ξ) dξ of the mode with eigenvalue `lambda`: the share of a uniform
/// inertial load (base acceleration) that drives it. Closed form for Eq. (A.7):
/// (sin λ + σ(cos λ − 1) − sinh λ + σ(cosh λ − 1))/λ, written without cancellation.
pub fn participation(lambda: f64) -> f64 {
    // ∫ cos − cosh − σ(sin − sinh) = [sin λ − sinh λ + σ(cos λ − 1) + σ(cosh λ − 1)]/λ; with
    // σ·cosh λ − sinh λ = ((σ − 1)e^λ + (σ + 1)e^{−λ})/2 evaluated through 1 − σ.
    let l = lambda;
    let (s, c) = l.sin_cos();
    let em = (-l).exp();
    let denom_scaled = s * em + 0.5 * (1.0 - em * em);
    let one_minus_sigma_scaled = (s - c - em) / denom_scaled;
    let sigma = 1.0 - one_minus_sigma_scaled * em;
    let hyperbolic = 0.5 * (-one_minus_sigma_scaled + (sigma + 1.0) * em); // σ cosh λ − sinh λ
    (s + sigma * (c - 1.0) + hyperbolic - sigma) / l
}

/// One flexural mode of the cantilever, all quantities SI.
#[derive(Clone, Debug, PartialEq)]
pub struct Mode {
    /// Mode number n (1-based).
    pub n: usize,
    /// Eigenvalue λn = kn·L (1).
    pub lambda: f64,
    /// Resonance frequency fn (Hz).
    pub frequency: f64,
    /// Angular resonance frequency ωn (rad/s).
    pub omega: f64,
    /// Quality factor Qn (1).
    pub q: f64,
    /// Damping ratio γn = 1/(2Qn) (1).
    pub gamma: f64,
    /// Shape at the free end φn(L) (1); ±2 in this normalisation.
    pub tip_value: f64,
    /// Tip slope L·φn′(L) (1).
    pub tip_slope: f64,
    /// Generalised stiffness Kn = k·λn⁴/3 (N/m).
    pub stiffness: f64,
    /// ∫₀¹ φn dξ (1): how strongly base motion drives the mode.
    pub participation: f64,
}

impl Mode {
    /// Photodiode signal per metre of this mode's tip deflection: (2/3)·L·φn′(L)/φn(L).
    /// 1 would be a quasi-static deflection; mode 1 reads 0.9177.
    pub fn light_lever_factor(&self) -> f64 {
        (2.0 / 3.0) * self.tip_slope / self.tip_value
    }

    /// Tip-referred stiffness Kn/φn(L)² (N/m): the spring a point force at the tip sees.
    pub fn tip_stiffness(&self) -> f64 {
        self.stiffness / (self.tip_value * self.tip_value)
    }

    /// Complex transfer function Hn(β) = 1/(1 − β² + i·2γnβ) at angular frequency `omega`
    /// (rad/s), Eq. (4)/(7): modal response = Hn·Fn/Kn for a force Fn·e^{iωt}.
    pub fn transfer(&self, omega: f64) -> Complex64 {
        let beta = omega / self.omega;
        Complex64::new(1.0 - beta * beta, 2.0 * self.gamma * beta).inv()
    }
}

/// Why a cantilever cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BeamError {
    /// No quality factor was given.
    #[error("at least one quality factor is needed")]
    NoQ,
    /// More modes than [`MAX_MODES`].
    #[error("{0} modes requested; at most {MAX_MODES} are supported")]
    TooManyModes(usize),
    /// The Rayleigh extension gives a non-physical damping for an extra mode.
    #[error(
        "the Rayleigh damping fitted to the last two quality factors gives Q = {q} for mode {n}; \
         give that mode's Q explicitly"
    )]
    RayleighUnphysical { n: usize, q: f64 },
}

/// A rectangular cantilever: its static spring constant, its first resonance and its modes.
#[derive(Clone, Debug, PartialEq)]
pub struct Cantilever {
    /// Static spring constant at the tip k = 3EI/L³ (N/m).
    pub k: f64,
    /// First flexural resonance f1 (Hz).
    pub f1: f64,
    /// Modes 1..=N, in order.
    pub modes: Vec<Mode>,
}

impl Cantilever {
    /// Builds the modes from f1 (Hz), k (N/m) and the per-mode quality factors `q`, plus
    /// `extra_modes` more whose damping follows the Rayleigh form (B.7),
    /// γn = a0/(2ωn) + a1·ωn/2, with a0, a1 fitted to the last two given Qs (with a single
    /// given Q, every extra mode gets that Q).
    pub fn new(f1: f64, k: f64, q: &[f64], extra_modes: usize) -> Result<Self, BeamError> {
        if q.is_empty() {
            return Err(BeamError::NoQ);
        }
        let count = q.len() + extra_modes;
        if count > MAX_MODES {
            return Err(BeamError::TooManyModes(count));
        }
        let lambda1 = eigenvalue(1);
        let omega1 = 2.0 * PI * f1;
        let omega_of = |lambda: f64| omega1 * (lambda / lambda1).powi(2);
        let rayleigh = rayleigh_coefficients(q, |n| omega_of(eigenvalue(n)));
        let mut modes = Vec::with_capacity(count);
        for n in 1..=count {
            let lambda = eigenvalue(n);
            let omega = omega_of(lambda);
            let q_n = match q.get(n - 1) {
                Some(&q) => q,
                None => match rayleigh {
                    Some((a0, a1)) => 1.0 / (a0 / omega + a1 * omega),
                    None => q[0],
                },
            };
            if !(q_n.is_finite() && q_n > 0.5) {
                return Err(BeamError::RayleighUnphysical { n, q: q_n });
            }
            let (tip_value, tip_slope) = shape(lambda, 1.0);
            modes.push(Mode {
                n,
                lambda,
                frequency: omega / (2.0 * PI),
                omega,
                q: q_n,
                gamma: 0.5 / q_n,
                tip_value,
                tip_slope,
                stiffness: k * lambda.powi(4) / 3.0,
                participation: participation(lambda),
            });
        }
        Ok(Self { k, f1, modes })
    }

    /// First mode.
    pub fn fundamental(&self) -> &Mode {
        &self.modes[0]
    }
}

/// (a0, a1) of γ = a0/(2ω) + a1·ω/2 through the last two given modes, if there are two.
fn rayleigh_coefficients(q: &[f64], omega_of: impl Fn(usize) -> f64) -> Option<(f64, f64)> {
    if q.len() < 2 {
        return None;
    }
    let (m, n) = (q.len() - 1, q.len());
    let (wm, wn) = (omega_of(m), omega_of(n));
    let (gm, gn) = (0.5 / q[m - 1], 0.5 / q[n - 1]);
    // Two linear equations in (a0, a1); the determinant is (wn/wm − wm/wn)/4 ≠ 0.
    let det = 0.25 * (wn / wm - wm / wn);
    let a0 = (gm * wn / 2.0 - gn * wm / 2.0) / det;
    let a1 = (gn / (2.0 * wm) - gm / (2.0 * wn)) / det;
    Some((a0, a1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rayleigh_reproduces_the_two_modes_it_was_fitted_to() {
        let q = [100.0, 417.0, 340.0];
        let c = Cantilever::new(100e3, 20.0, &q, 0).unwrap();
        let (a0, a1) = rayleigh_coefficients(&q, |n| c.modes[n - 1].omega).unwrap();
        for n in [2, 3] {
            let w = c.modes[n - 1].omega;
            let gamma = a0 / (2.0 * w) + a1 * w / 2.0;
            assert!((gamma - 0.5 / q[n - 1]).abs() < 1e-12 * gamma.abs().max(1.0));
        }
    }
}
