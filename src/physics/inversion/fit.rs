//! The cut cosine (τ, F, pulse phase φ) fitted to every measured harmonic by weighted least
//! squares: the efficient use of all the harmonics that the two-harmonic method and the
//! division by the transfer function leave on the table.
//!
//! Model, for each measured harmonic k ≥ 2 (what [`LockInModel::read`] gives):
//! S_k(τ, F, φ) = T(kΩ)·c_k(F, τ)·e^{−ikφ} + A_k, with c_k the cut cosine's coefficient
//! (Eq. 21) and A_k the harmonics aliased onto k. Misfit χ² = Σ_k |S_k,meas − S_k|²/σ_k²,
//! σ_k the standard deviation of each quadrature of S_k: the negative log-likelihood of
//! circular Gaussian noise, so the minimum is the maximum-likelihood estimate and its
//! inverse Hessian (JᵀWJ)⁻¹ the Cramér–Rao covariance. Harmonics near the light-lever zeros
//! or the pulse's spectral zeros need no special rule: their derivatives are small, so they
//! weigh little, and none is dropped.
//!
//! Levenberg–Marquardt in (ln τ, F, φ) from a start (the two-harmonic fit and the
//! correlation phase); the aliases A_k, which hardly depend on the parameters, are held
//! fixed within a pass and updated between passes.

use rustfft::num_complex::Complex64;

use super::forward::{ALIAS_HARMONICS, LockInModel, cut_cosine_spectrum};
use super::reconstruct::HarmonicSample;
use super::two_harmonic::cut_cosine_shape;
use super::{InversionError, forward::cut_cosine_phasor};

/// Relative floor on the noise, as a fraction of the largest measured |S_k|: with exact data
/// (σ = 0) the harmonics are weighted equally in absolute terms at this level.
const EXACT_FLOOR: f64 = 1e-9;
/// Levenberg–Marquardt iterations per pass at most.
const MAX_ITERATIONS: usize = 100;
/// Passes (alias updates) at most.
const MAX_PASSES: usize = 4;

/// Where the fit starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CutCosineStart {
    /// τ (1), in (0, 1).
    pub tau: f64,
    /// F (N).
    pub max_force: f64,
    /// Pulse phase φ (rad).
    pub pulse_phase: f64,
}

/// The least-squares cut cosine.
#[derive(Clone, Debug, PartialEq)]
pub struct CutCosineLsq {
    /// Contact time ratio τ (1).
    pub tau: f64,
    /// Peak force F (N).
    pub max_force: f64,
    /// Drive phase of the pulse centre φ (rad, in [0, 2π)).
    pub pulse_phase: f64,
    /// Covariance of (τ, F, φ), units 1, N, rad: (JᵀWJ)⁻¹ at the minimum.
    pub covariance: [[f64; 3]; 3],
    /// Standard deviations of τ (1), F (N) and φ (rad).
    pub sigma_tau: f64,
    pub sigma_force: f64,
    pub sigma_phase: f64,
    /// Second-order bias of (τ, F, φ) (units 1, N, rad): the expected excess of the
    /// estimate over the truth for Gaussian noise of the given σ, by Box's formula (J. Roy.
    /// Stat. Soc. B 33, 1971) at the estimate. Subtract it for (nearly) mean-unbiased
    /// values; it is small against the standard deviations (τ: 10⁻³σ, F: 0.03σ at the
    /// default 1 kHz noise) but matters for quantities as steep in (F, τ) as the modulus.
    pub bias: [f64; 3],
    /// χ² at the minimum (with the floor on σ for exact data).
    pub chi_squared: f64,
    /// Degrees of freedom: 2 per harmonic used, minus 3.
    pub degrees_of_freedom: usize,
    /// Harmonics used, ascending.
    pub harmonics: Vec<usize>,
    /// Levenberg–Marquardt iterations over all passes.
    pub iterations: usize,
}

impl CutCosineLsq {
    /// Covariance of (F, τ), as [`super::ModulusTable::estimate_with_covariance`] takes it.
    pub fn force_tau_covariance(&self) -> [[f64; 2]; 2] {
        let c = self.covariance;
        [[c[1][1], c[1][0]], [c[0][1], c[0][0]]]
    }

    /// Two-sided coefficient c_k (N) of the fitted pulse train.
    pub fn coefficient(&self, k: usize) -> Complex64 {
        cut_cosine_phasor(self.max_force, self.tau, self.pulse_phase, k)
    }
}

/// One harmonic in the fit.
struct Point {
    k: usize,
    transfer: Complex64,
    measured: Complex64,
    weight: f64,
    alias: Complex64,
}

/// Model S_k and its derivatives with respect to (ln τ, F, φ).
fn predict(p: &Point, params: [f64; 3]) -> (Complex64, [Complex64; 3]) {
    let [log_tau, force, phase] = params;
    let tau = log_tau.exp();
    let kf = p.k as f64;
    let (s, ds) = cut_cosine_shape(2.0 * tau * kf);
    let rot = Complex64::from_polar(1.0, -kf * phase) * p.transfer;
    let scale = 2.0 / std::f64::consts::PI;
    let direct = rot * (scale * force * tau * s);
    let d_log_tau = rot * (scale * force * tau * (s + 2.0 * tau * kf * ds));
    let d_force = rot * (scale * tau * s);
    let d_phase = direct * Complex64::new(0.0, -kf);
    (direct + p.alias, [d_log_tau, d_force, d_phase])
}

/// Second derivatives of the model S_k with respect to (ln τ, F, φ).
fn hessian(p: &Point, params: [f64; 3]) -> [[Complex64; 3]; 3] {
    let [log_tau, force, phase] = params;
    let tau = log_tau.exp();
    let kf = p.k as f64;
    let w = 2.0 * tau * kf;
    let (s, ds) = cut_cosine_shape(w);
    let h = 1e-4 * w.max(1.0);
    let d2s = (cut_cosine_shape(w + h).1 - cut_cosine_shape(w - h).1) / (2.0 * h);
    // A = τ·s(2kτ) and its derivatives in ln τ (dw/d ln τ = w).
    let a0 = tau * s;
    let a1 = tau * (s + w * ds);
    let a2 = tau * (s + 3.0 * w * ds + w * w * d2s);
    let c = Complex64::from_polar(1.0, -kf * phase) * p.transfer * (2.0 / std::f64::consts::PI);
    let ik = Complex64::new(0.0, -kf);
    let uu = c * (force * a2);
    let uf = c * a1;
    let up = c * (force * a1) * ik;
    let ff = Complex64::new(0.0, 0.0);
    let fp = c * a0 * ik;
    let pp = c * (force * a0) * (ik * ik);
    [[uu, uf, up], [uf, ff, fp], [up, fp, pp]]
}

fn chi_squared(points: &[Point], params: [f64; 3]) -> f64 {
    points
        .iter()
        .map(|p| (p.measured - predict(p, params).0).norm_sqr() * p.weight)
        .sum()
}

/// Normal equations JᵀWJ and JᵀWr at `params`.
fn normal(points: &[Point], params: [f64; 3]) -> ([[f64; 3]; 3], [f64; 3]) {
    let mut h = [[0.0; 3]; 3];
    let mut g = [0.0; 3];
    for p in points {
        let (m, d) = predict(p, params);
        let r = p.measured - m;
        for a in 0..3 {
            g[a] += p.weight * (d[a].conj() * r).re;
            for b in 0..3 {
                h[a][b] += p.weight * (d[a].conj() * d[b]).re;
            }
        }
    }
    (h, g)
}

/// Inverse of a symmetric positive-definite 3×3 matrix (None if singular).
pub(super) fn invert3(m: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if !(det.is_finite() && det != 0.0) {
        return None;
    }
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, entry) in row.iter_mut().enumerate() {
            let (i1, i2) = ((j + 1) % 3, (j + 2) % 3);
            let (j1, j2) = ((i + 1) % 3, (i + 2) % 3);
            *entry = (m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]) / det;
        }
    }
    Some(r)
}

/// Fits the cut cosine to `samples` (two-sided S_k with σ per quadrature) through `model`,
/// from `start`. Uses every sample with k ≥ 2 that the model knows (k = 1 carries the drive
/// response, k = 0 the static deflection; neither is the tap force alone).
///
/// # Errors
/// [`InversionError::NoUsablePair`] with fewer than two usable harmonics,
/// [`InversionError::NonFiniteHarmonic`]/[`InversionError::InvalidSigma`] for bad samples,
/// [`InversionError::FitFailed`] when the start is not usable or the normal matrix is
/// singular at the minimum.
pub fn fit_cut_cosine(
    model: &LockInModel,
    samples: &[HarmonicSample],
    start: CutCosineStart,
) -> Result<CutCosineLsq, InversionError> {
    for s in samples {
        if !(s.value.re.is_finite() && s.value.im.is_finite()) {
            return Err(InversionError::NonFiniteHarmonic(s.harmonic));
        }
        if !(s.sigma.is_finite() && s.sigma >= 0.0) {
            return Err(InversionError::InvalidSigma {
                harmonic: s.harmonic,
                sigma: s.sigma,
            });
        }
    }
    let usable = start.tau > 0.0
        && start.tau < 1.0
        && start.max_force.is_finite()
        && start.max_force > 0.0
        && start.pulse_phase.is_finite();
    if !usable {
        return Err(InversionError::FitFailed("the start is not a cut cosine"));
    }
    let used: Vec<&HarmonicSample> = samples
        .iter()
        .filter(|s| s.harmonic >= 2 && model.transfer(s.harmonic).is_some())
        .collect();
    if used.len() < 2 {
        return Err(InversionError::NoUsablePair);
    }
    let largest = used.iter().map(|s| s.value.norm()).fold(0.0, f64::max);
    let floor = EXACT_FLOOR * largest;
    let mut points: Vec<Point> = used
        .iter()
        .map(|s| Point {
            k: s.harmonic,
            transfer: model.transfer(s.harmonic).unwrap_or_default(),
            measured: s.value,
            weight: 1.0 / (s.sigma * s.sigma + floor * floor),
            alias: Complex64::new(0.0, 0.0),
        })
        .collect();
    if points.iter().any(|p| !p.weight.is_finite()) {
        return Err(InversionError::FitFailed("all harmonics are zero"));
    }

    let mut params = [start.tau.ln(), start.max_force, start.pulse_phase];
    let mut iterations = 0;
    let update_aliases = |points: &mut [Point], params: [f64; 3]| {
        let spectrum = cut_cosine_spectrum(params[1], params[0].exp(), params[2], ALIAS_HARMONICS);
        for p in points.iter_mut() {
            p.alias = model.aliased_spectrum(p.k, &spectrum);
        }
    };
    let aliased = model.sample_rate().is_some();
    if aliased {
        update_aliases(&mut points, params);
    }
    for pass in 0..MAX_PASSES {
        let mut chi2 = chi_squared(&points, params);
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            iterations += 1;
            let (h, g) = normal(&points, params);
            // Some(converged) once a step is taken; None when no damping helps.
            let mut outcome = None;
            while lambda < 1e12 {
                let mut damped = h;
                for (i, row) in damped.iter_mut().enumerate() {
                    row[i] *= 1.0 + lambda;
                }
                let Some(inv) = invert3(damped) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut step = [0.0; 3];
                for (i, s) in step.iter_mut().enumerate() {
                    *s = (0..3).map(|j| inv[i][j] * g[j]).sum();
                }
                // τ stays in (0, 1), changing by at most a factor e per step.
                step[0] = step[0].clamp(-1.0, 1.0);
                let next = [
                    (params[0] + step[0]).min(-1e-12),
                    params[1] + step[1],
                    params[2] + step[2],
                ];
                let chi_next = chi_squared(&points, next);
                if chi_next.is_finite() && chi_next <= chi2 {
                    outcome = Some(chi2 - chi_next <= 1e-10 * chi2);
                    params = next;
                    chi2 = chi_next;
                    lambda = (lambda * 0.1).max(1e-12);
                    break;
                }
                lambda *= 10.0;
            }
            if outcome != Some(false) {
                break;
            }
        }
        if !aliased || pass + 1 == MAX_PASSES {
            break;
        }
        // Another pass only if the aliases moved noticeably.
        let before: Vec<Complex64> = points.iter().map(|p| p.alias).collect();
        update_aliases(&mut points, params);
        let moved = points
            .iter()
            .zip(&before)
            .map(|(p, b)| (p.alias - b).norm_sqr() * p.weight)
            .sum::<f64>();
        if moved <= 1e-6 {
            break;
        }
    }

    let (h, _) = normal(&points, params);
    let inv = invert3(h).ok_or(InversionError::FitFailed("singular normal matrix"))?;
    let tau = params[0].exp();
    // (ln τ, F, φ) → (τ, F, φ).
    let scale = [tau, 1.0, 1.0];
    let mut covariance = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            covariance[i][j] = inv[i][j] * scale[i] * scale[j];
        }
    }
    if params[1] <= 0.0 || !params.iter().all(|v| v.is_finite()) {
        return Err(InversionError::FitFailed("no pulse fits the harmonics"));
    }
    // Box's (1971) second-order bias of nonlinear least squares,
    // b = −½·Σ·Σ_k w_k·Re(∂S_k* · tr(Σ·∂²S_k)), Σ = (JᵀWJ)⁻¹, in (ln τ, F, φ).
    let mut sum = [0.0; 3];
    for p in &points {
        let (_, d) = predict(p, params);
        let hk = hessian(p, params);
        let mut trace = Complex64::new(0.0, 0.0);
        for a in 0..3 {
            for b in 0..3 {
                trace += hk[a][b] * inv[a][b];
            }
        }
        for (a, s) in sum.iter_mut().enumerate() {
            *s += p.weight * (d[a].conj() * trace).re;
        }
    }
    let mut box_bias = [0.0; 3];
    for (a, b) in box_bias.iter_mut().enumerate() {
        *b = -0.5 * (0..3).map(|c| inv[a][c] * sum[c]).sum::<f64>();
    }
    // In τ itself: E[e^{û}] − e^u = τ·(b_u + σ_u²/2) to second order.
    let bias = [
        tau * (box_bias[0] + 0.5 * inv[0][0]),
        box_bias[1],
        box_bias[2],
    ];
    let mut harmonics: Vec<usize> = points.iter().map(|p| p.k).collect();
    harmonics.sort_unstable();
    Ok(CutCosineLsq {
        tau,
        max_force: params[1],
        pulse_phase: params[2].rem_euclid(2.0 * std::f64::consts::PI),
        sigma_tau: covariance[0][0].sqrt(),
        sigma_force: covariance[1][1].sqrt(),
        sigma_phase: covariance[2][2].sqrt(),
        covariance,
        bias,
        chi_squared: chi_squared(&points, params),
        degrees_of_freedom: (2 * points.len()).saturating_sub(3),
        harmonics,
        iterations,
    })
}
