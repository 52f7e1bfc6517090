//! The two-harmonic method: τ and F of the cut cosine from the amplitudes of two higher
//! photodiode harmonics (the paper's "only the amplitudes of two higher harmonics").
//!
//! The force coefficient of harmonic k is |c_k| = A_k/(2|T(kΩ)|) with T the light-lever
//! transfer ([`photodiode_transfer`]). For the cut cosine (Eq. 21),
//! c_k = (2Fτ/π)·s(2τk) with s(w) = cos(πw/2)/(1 − w²), so the ratio |c_a|/|c_b| depends on
//! τ alone. Both harmonics are assumed to lie before the pulse's first spectral zero
//! (2τk = 3, i.e. τ < τ_max = 1.5/max(a, b)); there s > 0 and, for a < b, the ratio
//! s(2aτ)/s(2bτ) rises strictly from 1 (τ → 0) to ∞ (τ → τ_max), so the root is unique. A
//! longer pulse can give the same ratio further out: those roots are listed as
//! [`CutCosineFit::alternatives`] and a third harmonic (or the phases) must decide.

use std::f64::consts::PI;

use super::InversionError;
use crate::physics::beam::Cantilever;
use crate::physics::spectrum::photodiode_transfer;

/// Upper end (1) of the scan for alternative roots beyond the primary bracket: a pulse
/// covering half the period. Tapping pulses are far shorter (the paper's τ ≈ 0.05).
pub const AMBIGUITY_SCAN_END: f64 = 0.5;

/// One measured photodiode amplitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AmplitudeMeasurement {
    /// Harmonic number k ≥ 2.
    pub harmonic: usize,
    /// Peak amplitude A_k = 2|S_k| (m, nominal light-lever metres).
    pub amplitude: f64,
    /// Standard deviation of A_k (m); 0 for exact data.
    pub sigma: f64,
}

/// The cut cosine found by [`fit_two_harmonics`].
#[derive(Clone, Debug, PartialEq)]
pub struct CutCosineFit {
    /// The two harmonics, in the order given.
    pub harmonics: (usize, usize),
    /// Contact time ratio τ (1) of the cut cosine, Eq. (20).
    pub tau: f64,
    /// Peak force F (N).
    pub max_force: f64,
    /// First-order standard deviation of τ (1).
    pub sigma_tau: f64,
    /// First-order standard deviation of F (N).
    pub sigma_force: f64,
    /// Correlation coefficient of τ and F (1); NaN when both σ are zero.
    pub correlation: f64,
    /// Covariance matrix of (τ, F), units 1 and N.
    pub covariance: [[f64; 2]; 2],
    /// ∂(τ, F)/∂(A_a, A_b): row 0 is τ, row 1 is F; columns follow [`Self::harmonics`].
    pub jacobian: [[f64; 2]; 2],
    /// Upper end of the bracket searched for τ: 1.5/max(a, b).
    pub tau_max: f64,
    /// Force-coefficient magnitudes |c_a|, |c_b| (N) from the measured amplitudes.
    pub force_coefficients: (f64, f64),
    /// Other τ in (τ_max, [`AMBIGUITY_SCAN_END`]] with the same ratio |c_a|/|c_b| (pulses
    /// long enough to put a harmonic past a spectral zero of the cut cosine). Empty when
    /// the pair is unambiguous up to that length.
    pub alternatives: Vec<f64>,
}

impl CutCosineFit {
    /// Two-sided coefficient c_k (N) of the fitted pulse, centred at phase 0.
    pub fn coefficient(&self, k: usize) -> f64 {
        cut_cosine_value(self.max_force, self.tau, k)
    }

    /// The covariance reordered to (F, τ), as [`super::ModulusTable::estimate_with_covariance`]
    /// takes it.
    pub fn force_tau_covariance(&self) -> [[f64; 2]; 2] {
        let c = self.covariance;
        [[c[1][1], c[1][0]], [c[0][1], c[0][0]]]
    }
}

/// Harmonic number (real) of the first spectral zero of a cut cosine of ratio τ: 1.5/τ.
pub fn first_spectral_zero(tau: f64) -> f64 {
    1.5 / tau
}

/// The cut-cosine shape s(w) = cos(πw/2)/(1 − w²) and its derivative ds/dw, written as
/// (π/2)·sinc(π(w − 1)/2)/(1 + w) so that w = 1 (2τk = 1) needs no special case. The
/// coefficient of harmonic k is c_k = (2Fτ/π)·s(2τk).
pub fn cut_cosine_shape(w: f64) -> (f64, f64) {
    let x = 0.5 * PI * (w - 1.0);
    let (sinc, dsinc) = if x.abs() < 1e-2 {
        let x2 = x * x;
        (
            1.0 - x2 / 6.0 + x2 * x2 / 120.0 - x2 * x2 * x2 / 5040.0,
            x * (-1.0 / 3.0 + x2 / 30.0 - x2 * x2 / 840.0),
        )
    } else {
        let (s, c) = x.sin_cos();
        (s / x, (x * c - s) / (x * x))
    };
    let inv = 1.0 / (1.0 + w);
    let value = 0.5 * PI * sinc * inv;
    let slope = 0.5 * PI * (0.5 * PI * dsinc * inv - sinc * inv * inv);
    (value, slope)
}

/// c_k (N) of a cut cosine centred at phase 0.
pub(super) fn cut_cosine_value(max_force: f64, tau: f64, k: usize) -> f64 {
    2.0 * max_force * tau / PI * cut_cosine_shape(2.0 * tau * k as f64).0
}

/// ln s(2aτ) − ln s(2bτ), the log of the model ratio |c_a|/|c_b| (with absolute values, so
/// it is defined past the spectral zeros too).
fn log_ratio(a: usize, b: usize, tau: f64) -> f64 {
    let sa = cut_cosine_shape(2.0 * tau * a as f64).0.abs();
    let sb = cut_cosine_shape(2.0 * tau * b as f64).0.abs();
    sa.ln() - sb.ln()
}

/// Bisection for the sign change of `f` in [lo, hi] (f(lo) < 0 < f(hi) or the reverse), to
/// adjacent doubles.
pub(super) fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let flo_negative = f(lo) < 0.0;
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if (f(mid) < 0.0) == flo_negative {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

fn check(m: &AmplitudeMeasurement) -> Result<(), InversionError> {
    if m.harmonic < 2 {
        return Err(InversionError::HarmonicTooLow(m.harmonic));
    }
    if !(m.amplitude.is_finite() && m.amplitude > 0.0) {
        return Err(InversionError::InvalidAmplitude {
            harmonic: m.harmonic,
            amplitude: m.amplitude,
        });
    }
    if !(m.sigma.is_finite() && m.sigma >= 0.0) {
        return Err(InversionError::InvalidSigma {
            harmonic: m.harmonic,
            sigma: m.sigma,
        });
    }
    Ok(())
}

/// τ and F of the cut cosine whose photodiode harmonics `a` and `b` have the measured peak
/// amplitudes, on `cantilever` driven at `drive_frequency` (Hz).
///
/// τ is the unique root of ln s(2aτ) − ln s(2bτ) = ln(|c_a|/|c_b|) in (0, 1.5/max(a, b)),
/// found by bisection to adjacent doubles; F = π|c_a|/(2τ·s(2aτ)) (harmonic b gives the
/// same F, since the ratio is matched exactly). The uncertainties are first-order:
/// cov(τ, F) = J⁻¹·diag(σ_a², σ_b²)·J⁻ᵀ with J = ∂(A_a, A_b)/∂(τ, F) of the model
/// A_k = 2|T(kΩ)|·(2Fτ/π)·s(2kτ).
///
/// # Errors
/// [`InversionError`] for a == b, a harmonic < 2, a non-positive amplitude, a negative σ, a
/// bad drive frequency, or a ratio no cut cosine in the bracket has.
pub fn fit_two_harmonics(
    cantilever: &Cantilever,
    drive_frequency: f64,
    a: AmplitudeMeasurement,
    b: AmplitudeMeasurement,
) -> Result<CutCosineFit, InversionError> {
    if !(drive_frequency.is_finite() && drive_frequency > 0.0) {
        return Err(InversionError::InvalidDriveFrequency(drive_frequency));
    }
    fit_inner(cantilever, 2.0 * PI * drive_frequency, a, b, true)
}

/// [`fit_two_harmonics`] at angular drive frequency `omega`, optionally without the scan
/// for alternative roots (used when many pairs are tried).
pub(super) fn fit_inner(
    cantilever: &Cantilever,
    omega: f64,
    a: AmplitudeMeasurement,
    b: AmplitudeMeasurement,
    with_alternatives: bool,
) -> Result<CutCosineFit, InversionError> {
    check(&a)?;
    check(&b)?;
    if a.harmonic == b.harmonic {
        return Err(InversionError::SameHarmonic(a.harmonic));
    }
    let transfer = |k: usize| photodiode_transfer(cantilever, k as f64 * omega).norm();
    let (ta, tb) = (transfer(a.harmonic), transfer(b.harmonic));
    let (ca, cb) = (a.amplitude / (2.0 * ta), b.amplitude / (2.0 * tb));

    let (tau, max_force) = solve_pair(a.harmonic, ca, b.harmonic, cb)?;
    let (lo, hi) = (a.harmonic.min(b.harmonic), a.harmonic.max(b.harmonic));
    let tau_max = 1.5 / hi as f64;
    let log_target = (if a.harmonic < b.harmonic {
        ca / cb
    } else {
        cb / ca
    })
    .ln();

    // J = ∂(A_a, A_b)/∂(τ, F), A_k = 2|T_k|·(2Fτ/π)·s(2kτ).
    let row = |k: usize, t: f64| {
        let (s, ds) = cut_cosine_shape(2.0 * tau * k as f64);
        let d_tau = 2.0 * t * (2.0 * max_force / PI) * (s + 2.0 * k as f64 * tau * ds);
        let d_force = 2.0 * t * (2.0 * tau / PI) * s;
        [d_tau, d_force]
    };
    let j = [row(a.harmonic, ta), row(b.harmonic, tb)];
    let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
    // Inverse: ∂(τ, F)/∂(A_a, A_b).
    let jinv = [
        [j[1][1] / det, -j[0][1] / det],
        [-j[1][0] / det, j[0][0] / det],
    ];
    let var = [a.sigma * a.sigma, b.sigma * b.sigma];
    let mut cov = [[0.0; 2]; 2];
    for (r, cov_row) in cov.iter_mut().enumerate() {
        for (c, entry) in cov_row.iter_mut().enumerate() {
            *entry = jinv[r][0] * jinv[c][0] * var[0] + jinv[r][1] * jinv[c][1] * var[1];
        }
    }
    let sigma_tau = cov[0][0].sqrt();
    let sigma_force = cov[1][1].sqrt();
    let correlation = cov[0][1] / (sigma_tau * sigma_force);

    Ok(CutCosineFit {
        harmonics: (a.harmonic, b.harmonic),
        tau,
        max_force,
        sigma_tau,
        sigma_force,
        correlation,
        covariance: cov,
        jacobian: jinv,
        tau_max,
        force_coefficients: (ca, cb),
        alternatives: if with_alternatives {
            alternatives(lo, hi, log_target, tau_max)
        } else {
            Vec::new()
        },
    })
}

/// τ (1) and F (N) of the cut cosine whose force coefficients of harmonics `a` and `b`
/// have magnitudes `ca` and `cb` (N): the core of [`fit_two_harmonics`] without the light
/// lever (τ in (0, 1.5/max(a, b)), see there).
///
/// # Errors
/// [`InversionError`] for a == b, a harmonic < 2, a non-positive magnitude or a ratio out of
/// range.
pub fn cut_cosine_from_coefficients(
    a: usize,
    ca: f64,
    b: usize,
    cb: f64,
) -> Result<(f64, f64), InversionError> {
    for (k, c) in [(a, ca), (b, cb)] {
        check(&AmplitudeMeasurement {
            harmonic: k,
            amplitude: c,
            sigma: 0.0,
        })?;
    }
    if a == b {
        return Err(InversionError::SameHarmonic(a));
    }
    solve_pair(a, ca, b, cb)
}

/// (τ, F) from validated magnitudes |c_a|, |c_b| of distinct harmonics.
fn solve_pair(a: usize, ca: f64, b: usize, cb: f64) -> Result<(f64, f64), InversionError> {
    // Order the pair: lo < hi; the ratio |c_lo|/|c_hi| must exceed 1.
    let swapped = a > b;
    let (lo, hi, c_lo, c_hi) = if swapped {
        (b, a, cb, ca)
    } else {
        (a, b, ca, cb)
    };
    let ratio = c_lo / c_hi;
    let log_target = ratio.ln();
    if !(log_target.is_finite() && log_target > 0.0) {
        return Err(InversionError::RatioOutOfRange {
            low: lo,
            high: hi,
            ratio,
        });
    }
    let tau_max = 1.5 / hi as f64;
    let f = |tau: f64| log_ratio(lo, hi, tau) - log_target;
    // f(0⁺) = −ln r < 0 and f → +∞ at τ_max; the upper end is the pole itself, which the
    // bisection never evaluates exactly (the midpoint of a non-empty interval is inside).
    let tau = bisect(
        |t| if t >= tau_max { f64::INFINITY } else { f(t) },
        0.0,
        tau_max,
    );

    let shape_a = cut_cosine_shape(2.0 * tau * a as f64);
    let max_force = PI * ca / (2.0 * tau * shape_a.0);

    Ok((tau, max_force))
}

/// Roots of |s(2·lo·τ)|/|s(2·hi·τ)| = r for τ in (τ_max, [`AMBIGUITY_SCAN_END`]].
///
/// The interval is cut at every spectral zero of either harmonic (2kτ = 3, 5, 7, …), where
/// the log ratio has a pole; each piece is sampled on 64 points plus points 1e-9 of its
/// width inside its ends, and every sign change is bisected. A root closer than that to a
/// pole (only for ratios above ~1e8) is missed.
fn alternatives(lo: usize, hi: usize, log_target: f64, tau_max: f64) -> Vec<f64> {
    let mut cuts = vec![tau_max, AMBIGUITY_SCAN_END];
    for k in [lo, hi] {
        let mut odd = 3.0;
        loop {
            let t = odd / (2.0 * k as f64);
            if t >= AMBIGUITY_SCAN_END {
                break;
            }
            if t > tau_max {
                cuts.push(t);
            }
            odd += 2.0;
        }
    }
    cuts.sort_by(f64::total_cmp);
    cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-14);
    let f = |tau: f64| log_ratio(lo, hi, tau) - log_target;
    let mut roots = Vec::new();
    for w in cuts.windows(2) {
        let (start, end) = (w[0], w[1]);
        let width = end - start;
        let mut points = vec![start + 1e-9 * width];
        points.extend((1..64).map(|i| start + width * i as f64 / 64.0));
        points.push(end - 1e-9 * width);
        for p in points.windows(2) {
            let (fa, fb) = (f(p[0]), f(p[1]));
            if fa.is_finite() && fb.is_finite() && (fa < 0.0) != (fb < 0.0) {
                roots.push(bisect(f, p[0], p[1]));
            }
        }
    }
    roots
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_matches_the_printed_form_and_its_derivative() {
        for w in [0.0, 0.3, 0.9, 0.999, 1.0, 1.001, 1.02, 2.0, 2.9, 4.5] {
            let (s, ds) = cut_cosine_shape(w);
            if (w - 1.0f64).abs() > 1e-2 {
                let printed = (PI * w / 2.0).cos() / (1.0 - w * w);
                assert!((s - printed).abs() < 1e-14, "w {w}: {s} vs {printed}");
            }
            let h = 1e-6;
            let fd = (cut_cosine_shape(w + h).0 - cut_cosine_shape(w - h).0) / (2.0 * h);
            assert!((ds - fd).abs() < 1e-8, "w {w}: {ds} vs {fd}");
        }
        assert!((cut_cosine_shape(1.0).0 - PI / 4.0).abs() < 1e-15);
    }

    #[test]
    fn u_times_log_slope_decreases_so_the_ratio_is_monotone() {
        // h(u) = u·d ln s(2u)/du must fall strictly on (0, 1.5) for the bracket to hold a
        // single root for every pair a < b.
        let h = |u: f64| {
            let (s, ds) = cut_cosine_shape(2.0 * u);
            u * 2.0 * ds / s
        };
        let mut prev = h(1e-6);
        for i in 1..15_000 {
            let u = 1.5 * i as f64 / 15_000.0;
            let v = h(u);
            assert!(v < prev, "h not decreasing at u = {u}");
            prev = v;
        }
    }
}
