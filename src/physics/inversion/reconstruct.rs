//! Full inversion (Stark et al., PNAS 2002 style): force coefficients c_k = S_k/T(kΩ) from
//! the complex photodiode harmonics, and the force over one period by Fourier series.
//!
//! Division by the light-lever transfer T amplifies noise wherever |T(kΩ)| is small (its
//! zeros near 2.8, 11.2 and 25.3·f1 for the paper's beam, found here from |T| by
//! [`light_lever_minima`]) and wherever the force itself has little power (past the first
//! spectral zero of the pulse). The rule used here is a hard, prior-based floor: a measured
//! harmonic k is used if its *expected* signal |T(kΩ)|·|c_k,prior| is at least
//! [`InversionOptions::min_snr`] times its noise σ_k; otherwise — and for k = 1, whose
//! photodiode signal is the drive response rather than the tap force, and for every harmonic
//! not measured (k = 0 typically) — c_k is taken from the cut-cosine prior. The floor is set
//! on the prior, not on the measured |S_k|, so that selecting harmonics does not favour
//! those where the noise happened to add.
//!
//! The prior is the two-harmonic cut-cosine fit ([`super::fit_two_harmonics`]) of a pair of
//! measured harmonics, centred at the pulse phase that best matches the measured phases.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::InversionError;
use super::two_harmonic::{
    AMBIGUITY_SCAN_END, AmplitudeMeasurement, CutCosineFit, cut_cosine_value, fit_inner,
};
use crate::physics::beam::Cantilever;
use crate::physics::spectrum::photodiode_transfer;

/// With [`InversionOptions::max_harmonic`] = `None`, the series runs to at least
/// ⌈TAIL_LOBES/τ⌉ harmonics: ten periods (2/τ harmonics each) of the cos(πτk) in the cut
/// cosine's coefficients. For the paper's τ = 0.0518 that is 386 harmonics, and peak and τ
/// are then within 0.03 % of the infinite series (the coefficients fall only as 1/k²).
pub const TAIL_LOBES: f64 = 20.0;

/// Upper bound of the automatic series length.
pub const MAX_AUTO_HARMONIC: usize = 4096;

/// One complex photodiode harmonic, as the lock-in measures it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicSample {
    /// Harmonic number k (0 is the mean deflection).
    pub harmonic: usize,
    /// Two-sided coefficient S_k (m, nominal light-lever metres): the lock-in's X + iY is
    /// 2·S_k for k ≥ 1.
    pub value: Complex64,
    /// Standard deviation (m) of Re S_k and of Im S_k each (circular Gaussian noise); the
    /// peak amplitude 2|S_k| then has σ ≈ 2·sigma. 0 for exact data.
    pub sigma: f64,
}

/// Parameters of [`reconstruct_force`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InversionOptions {
    /// Noise floor: a measured harmonic is used when |T(kΩ)|·|c_k,prior| ≥ min_snr·σ_k, and
    /// replaced by the prior otherwise. 0 uses every measured harmonic (except k = 1).
    pub min_snr: f64,
    /// Harmonics (a, b), both ≥ 2 and measured, for the cut-cosine prior. `None` chooses
    /// the pair automatically (see [`reconstruct_force`]).
    pub pair: Option<(usize, usize)>,
    /// Highest harmonic K of the reconstructed series. Harmonics above the measured ones
    /// come from the prior. `None`: max(highest measured, ⌈[`TAIL_LOBES`]/τ_prior⌉), at
    /// most [`MAX_AUTO_HARMONIC`] — the cut cosine's coefficients fall only as 1/k², so a
    /// series cut at the 32 measured harmonics misplaces the peak by a few percent.
    pub max_harmonic: Option<usize>,
    /// Points N of the force grid over one period (θ_j = 2πj/N).
    pub grid_points: usize,
}

impl Default for InversionOptions {
    fn default() -> Self {
        Self {
            min_snr: 3.0,
            pair: None,
            max_harmonic: None,
            grid_points: 1024,
        }
    }
}

/// Where a force coefficient of the reconstruction comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CoefficientSource {
    /// S_k/T(kΩ) of the measured harmonic.
    Measured,
    /// Not measured: the cut-cosine prior.
    NotMeasured,
    /// k = 1: excluded (its signal is the drive response); the cut-cosine prior.
    Fundamental,
    /// Measured, but the expected signal is below the noise floor: the cut-cosine prior.
    BelowNoiseFloor,
}

/// One force coefficient of the reconstruction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceCoefficient {
    /// Harmonic number k.
    pub harmonic: usize,
    /// The coefficient c_k (N) used in the series.
    pub value: Complex64,
    /// S_k/T(kΩ) (N) when harmonic k was measured, whether or not it is used.
    pub measured: Option<Complex64>,
    /// The cut-cosine prior's c_k (N).
    pub prior: Complex64,
    /// Standard deviation (N) of Re and of Im of `value`: σ_k/|T(kΩ)| when measured and
    /// used, 0 when from the prior (the prior's own uncertainty is not propagated here).
    pub sigma: f64,
    /// Light-lever transfer T(kΩ) (m/N).
    pub transfer: Complex64,
    /// Expected signal-to-noise ratio |T(kΩ)|·|c_k,prior|/σ_k (∞ for σ_k = 0, NaN when not
    /// measured).
    pub expected_snr: f64,
    /// Where `value` comes from.
    pub source: CoefficientSource,
}

/// The cut cosine used to fill the missing and dropped harmonics.
#[derive(Clone, Debug, PartialEq)]
pub struct CutCosinePrior {
    /// The two-harmonic fit (τ, F and their uncertainties).
    pub fit: CutCosineFit,
    /// Drive phase (rad, in [0, 2π)) of the pulse centre: the maximum of the correlation of
    /// the measured coefficients with the fitted pulse.
    pub pulse_phase: f64,
}

impl CutCosinePrior {
    /// Two-sided coefficient c_k (N) of the prior pulse train.
    pub fn coefficient(&self, k: usize) -> Complex64 {
        self.fit.coefficient(k) * Complex64::from_polar(1.0, -(k as f64) * self.pulse_phase)
    }
}

/// A minimum of the light-lever transfer |T|: where a harmonic's force information is lost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransferMinimum {
    /// Frequency (Hz).
    pub frequency: f64,
    /// |T| there (m/N).
    pub magnitude: f64,
}

/// The reconstructed tip–sample force over one period.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceReconstruction {
    /// c_k for k = 0..=max_harmonic.
    pub coefficients: Vec<ForceCoefficient>,
    /// The cut cosine the missing and dropped harmonics come from.
    pub prior: CutCosinePrior,
    /// F(θ_j) (N) at θ_j = 2πj/N, j = 0..N: c_0 + Σ_{k≥1} 2·Re(c_k e^{ikθ}).
    pub force: Vec<f64>,
    /// Standard deviation (N) of F(θ) at any θ from the noise of the measured coefficients:
    /// √(σ_0² + 4·Σ_{k≥1} σ_k²) over the used ones.
    pub force_sigma: f64,
    /// Peak of the reconstructed force (N), refined off the grid by Newton's method on the
    /// series.
    pub peak_force: f64,
    /// Drive phase (rad, in [0, 2π)) of the peak.
    pub pulse_phase: f64,
    /// Full width at half maximum (fraction of the period), from zero force to the peak;
    /// crossings refined on the series.
    pub fwhm: f64,
    /// τ of the cut cosine with the same FWHM: 1.5·FWHM (the paper's Table 1 τ).
    pub contact_time_ratio: f64,
    /// Mean force Re c_0 (N).
    pub mean_force: f64,
    /// Most negative (attractive) force on the grid (N).
    pub min_force: f64,
    /// Minima of |T| up to the highest harmonic of the series.
    pub transfer_minima: Vec<TransferMinimum>,
}

/// F(θ) = Re c_0 + Σ_{k≥1} 2·Re(c_k e^{ikθ}) for two-sided coefficients c_0, c_1, ….
pub fn force_series(coefficients: &[Complex64], theta: f64) -> f64 {
    series(coefficients, theta).0
}

/// F, dF/dθ and d²F/dθ² of the series at θ.
fn series(c: &[Complex64], theta: f64) -> (f64, f64, f64) {
    let mut f = c.first().map_or(0.0, |c0| c0.re);
    let (mut d1, mut d2) = (0.0, 0.0);
    // e^{ikθ} by recurrence, re-anchored every 64 terms to keep rounding at ~1e-15.
    let step = Complex64::from_polar(1.0, theta);
    let mut rot = Complex64::new(1.0, 0.0);
    for (k, ck) in c.iter().enumerate().skip(1) {
        let kf = k as f64;
        rot = if k % 64 == 0 {
            Complex64::from_polar(1.0, kf * theta)
        } else {
            rot * step
        };
        let z = ck * rot;
        f += 2.0 * z.re;
        d1 -= 2.0 * kf * z.im;
        d2 -= 2.0 * kf * kf * z.re;
    }
    (f, d1, d2)
}

/// Minima of the light-lever transfer |T(ω)| between 0 and `max_frequency` (Hz), found from
/// |T| itself: each stretch between consecutive resonances (and beyond the last one) is
/// sampled on 512 points, and every interior local minimum is refined by golden-section
/// search. For the paper's beam these are the zeros near 2.81, 11.2, 25.3 and 44·f1 (not
/// exactly zero: the damping keeps |T| finite).
pub fn light_lever_minima(cantilever: &Cantilever, max_frequency: f64) -> Vec<TransferMinimum> {
    let magnitude = |f: f64| photodiode_transfer(cantilever, 2.0 * PI * f).norm();
    let mut edges = vec![0.0];
    edges.extend(
        cantilever
            .modes
            .iter()
            .map(|m| m.frequency)
            .filter(|&f| f < max_frequency),
    );
    edges.push(max_frequency);
    let mut minima = Vec::new();
    const SAMPLES: usize = 512;
    for w in edges.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        if hi <= lo {
            continue;
        }
        let at = |i: usize| lo + (hi - lo) * (i as f64 + 0.5) / SAMPLES as f64;
        let values: Vec<f64> = (0..SAMPLES).map(|i| magnitude(at(i))).collect();
        for i in 1..SAMPLES - 1 {
            if values[i] < values[i - 1] && values[i] <= values[i + 1] {
                let frequency = golden_minimum(magnitude, at(i - 1), at(i + 1));
                minima.push(TransferMinimum {
                    frequency,
                    magnitude: magnitude(frequency),
                });
            }
        }
    }
    minima
}

/// Minimum of a unimodal `f` on [a, b] by golden-section search, to rounding.
fn golden_minimum(f: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let (a, b) = super::golden_section(&f, a, b, |a, b| {
        b - a <= 4.0 * f64::EPSILON * b.abs().max(a.abs())
    });
    0.5 * (a + b)
}

fn validate(
    drive_frequency: f64,
    samples: &[HarmonicSample],
    options: &InversionOptions,
) -> Result<(), InversionError> {
    if !(drive_frequency.is_finite() && drive_frequency > 0.0) {
        return Err(InversionError::InvalidDriveFrequency(drive_frequency));
    }
    if !(options.min_snr.is_finite() && options.min_snr >= 0.0) {
        return Err(InversionError::InvalidSnr(options.min_snr));
    }
    const MIN_GRID: usize = 16;
    if options.grid_points < MIN_GRID {
        return Err(InversionError::GridTooSmall {
            minimum: MIN_GRID,
            got: options.grid_points,
        });
    }
    for (i, s) in samples.iter().enumerate() {
        if !(s.value.re.is_finite() && s.value.im.is_finite()) {
            return Err(InversionError::NonFiniteHarmonic(s.harmonic));
        }
        if !(s.sigma.is_finite() && s.sigma >= 0.0) {
            return Err(InversionError::InvalidSigma {
                harmonic: s.harmonic,
                sigma: s.sigma,
            });
        }
        if samples[..i].iter().any(|o| o.harmonic == s.harmonic) {
            return Err(InversionError::DuplicateHarmonic(s.harmonic));
        }
    }
    Ok(())
}

/// Reconstructs the tip–sample force from complex photodiode harmonics `samples` measured on
/// `cantilever` driven at `drive_frequency` (Hz).
///
/// 1. **Prior.** The cut cosine of the two-harmonic method on `options.pair`. Without a
///    pair, the candidates are the measured harmonics k ≥ 2 with |S_k| ≥ min_snr·σ_k; a
///    least-squares cut cosine over all of them (τ scanned on (0, 0.5], F linear) gives a
///    rough τ_ls, pairs with both harmonics below 0.9·1.5/τ_ls (safely before the first
///    spectral zero, which removes the ambiguity of [`super::CutCosineFit::alternatives`])
///    are fitted, and the pair with the smallest propagated σ_τ/τ wins (with equal σ on all
///    harmonics when none is given). The pulse phase maximises the correlation
///    Σ w_k·c_k^prior·Re(c_k e^{ikφ}) over the candidates (w_k = |T_k|²/σ_k², or 1 when
///    some σ_k is 0): a grid of 4096 phases, then Newton.
/// 2. **Coefficients.** c_k = S_k/T(kΩ) for every measured k ≠ 1 that passes the noise
///    floor (module docs); the prior elsewhere, up to `max_harmonic`.
/// 3. **Force.** F(θ) on the grid; the peak by Newton on the series; the half-maximum
///    crossings by bisection on the series; τ = 1.5·FWHM.
///
/// # Errors
/// [`InversionError`] for invalid inputs, when no usable pair exists, or when the
/// reconstructed force has no positive peak.
pub fn reconstruct_force(
    cantilever: &Cantilever,
    drive_frequency: f64,
    samples: &[HarmonicSample],
    options: &InversionOptions,
) -> Result<ForceReconstruction, InversionError> {
    validate(drive_frequency, samples, options)?;
    let omega = 2.0 * PI * drive_frequency;
    let highest_measured = samples.iter().map(|s| s.harmonic).max().unwrap_or(0);
    let transfer = |k: usize| photodiode_transfer(cantilever, k as f64 * omega);

    // Candidates for the prior: harmonics ≥ 2 measured above the noise.
    let candidates: Vec<&HarmonicSample> = samples
        .iter()
        .filter(|s| s.harmonic >= 2 && s.value.norm() > 0.0)
        .filter(|s| s.value.norm() >= options.min_snr * s.sigma)
        .collect();
    let all_sigma = candidates.iter().all(|s| s.sigma > 0.0);
    let amplitude = |s: &HarmonicSample, uniform: bool| AmplitudeMeasurement {
        harmonic: s.harmonic,
        amplitude: 2.0 * s.value.norm(),
        sigma: if uniform { 1.0 } else { 2.0 * s.sigma },
    };

    let fit = match options.pair {
        Some((a, b)) => {
            let find = |k: usize| {
                samples
                    .iter()
                    .find(|s| s.harmonic == k)
                    .ok_or(InversionError::PairNotMeasured(k))
            };
            let (sa, sb) = (find(a)?, find(b)?);
            super::fit_two_harmonics(
                cantilever,
                drive_frequency,
                amplitude(sa, false),
                amplitude(sb, false),
            )?
        }
        None => {
            let (a, b) = choose_pair(cantilever, omega, &candidates, all_sigma)?;
            super::fit_two_harmonics(
                cantilever,
                drive_frequency,
                amplitude(a, false),
                amplitude(b, false),
            )?
        }
    };

    // Pulse phase: correlation of the measured coefficients with the prior's template.
    let template: Vec<(usize, f64, Complex64, f64)> = candidates
        .iter()
        .map(|s| {
            let t = transfer(s.harmonic);
            let weight = if all_sigma {
                t.norm_sqr() / (s.sigma * s.sigma)
            } else {
                1.0
            };
            (s.harmonic, fit.coefficient(s.harmonic), s.value / t, weight)
        })
        .collect();
    let pulse_phase = correlation_peak(&template);
    let prior = CutCosinePrior { fit, pulse_phase };
    let kmax = options.max_harmonic.unwrap_or_else(|| {
        let tail = (TAIL_LOBES / prior.fit.tau)
            .ceil()
            .min(MAX_AUTO_HARMONIC as f64) as usize;
        highest_measured.max(tail)
    });

    // Coefficients.
    let mut coefficients = Vec::with_capacity(kmax + 1);
    for k in 0..=kmax {
        let t = transfer(k);
        let prior_k = prior.coefficient(k);
        let sample = samples.iter().find(|s| s.harmonic == k);
        let measured = sample.map(|s| s.value / t);
        let expected_snr = match sample {
            Some(s) if s.sigma > 0.0 => t.norm() * prior_k.norm() / s.sigma,
            Some(_) => f64::INFINITY,
            None => f64::NAN,
        };
        let (value, sigma, source) = match sample {
            None => (prior_k, 0.0, CoefficientSource::NotMeasured),
            Some(_) if k == 1 => (prior_k, 0.0, CoefficientSource::Fundamental),
            Some(s) if s.sigma == 0.0 || expected_snr >= options.min_snr => {
                (s.value / t, s.sigma / t.norm(), CoefficientSource::Measured)
            }
            Some(_) => (prior_k, 0.0, CoefficientSource::BelowNoiseFloor),
        };
        // The mean is real: only its real part enters the series.
        let value = if k == 0 {
            Complex64::new(value.re, 0.0)
        } else {
            value
        };
        coefficients.push(ForceCoefficient {
            harmonic: k,
            value,
            measured,
            prior: prior_k,
            sigma,
            transfer: t,
            expected_snr,
            source,
        });
    }
    let c: Vec<Complex64> = coefficients.iter().map(|c| c.value).collect();
    let force_sigma = coefficients
        .iter()
        .map(|c| {
            if c.harmonic == 0 {
                c.sigma * c.sigma
            } else {
                4.0 * c.sigma * c.sigma
            }
        })
        .sum::<f64>()
        .sqrt();

    // Force on the grid, its peak and its half-maximum width.
    let n = options.grid_points;
    let step = 2.0 * PI / n as f64;
    let force: Vec<f64> = (0..n).map(|j| force_series(&c, j as f64 * step)).collect();
    let jmax = (0..n)
        .max_by(|&a, &b| force[a].total_cmp(&force[b]))
        .unwrap_or(0);
    let (theta_peak, peak_force) = refine_peak(&c, jmax as f64 * step, step);
    if peak_force.is_nan() || peak_force <= 0.0 {
        return Err(InversionError::NoPulse);
    }
    let half = 0.5 * peak_force;
    let crossing = |direction: f64| -> Option<f64> {
        // Walk from the peak along the grid until the series drops below half maximum.
        let mut inside = theta_peak;
        for i in 1..=n {
            let theta = theta_peak + direction * i as f64 * step;
            if force_series(&c, theta) < half {
                let (lo, hi) = if direction > 0.0 {
                    (inside, theta)
                } else {
                    (theta, inside)
                };
                return Some(super::two_harmonic::bisect(
                    |x| direction * (half - force_series(&c, x)),
                    lo,
                    hi,
                ));
            }
            inside = theta;
        }
        None
    };
    let (right, left) = match (crossing(1.0), crossing(-1.0)) {
        (Some(r), Some(l)) => (r, l),
        _ => return Err(InversionError::NoPulse),
    };
    let fwhm = (right - left) / (2.0 * PI);
    let min_force = force.iter().copied().fold(f64::INFINITY, f64::min);
    Ok(ForceReconstruction {
        transfer_minima: light_lever_minima(cantilever, (kmax as f64 + 0.5) * drive_frequency),
        coefficients,
        prior,
        force,
        force_sigma,
        peak_force,
        pulse_phase: theta_peak.rem_euclid(2.0 * PI),
        fwhm,
        contact_time_ratio: 1.5 * fwhm,
        mean_force: c.first().map_or(0.0, |c0| c0.re),
        min_force,
    })
}

/// Maximum of the series near `theta` (within a grid step either side) by Newton's method
/// on F′ = 0, falling back to the grid point if Newton leaves the bracket.
fn refine_peak(c: &[Complex64], theta: f64, step: f64) -> (f64, f64) {
    let (f0, _, _) = series(c, theta);
    let mut x = theta;
    for _ in 0..50 {
        let (_, d1, d2) = series(c, x);
        if d2.is_nan() || d2 >= 0.0 {
            break;
        }
        let next = x - d1 / d2;
        if (next - theta).abs() > step {
            break;
        }
        let done = (next - x).abs() < 1e-15;
        x = next;
        if done {
            break;
        }
    }
    let fx = series(c, x).0;
    if fx >= f0 { (x, fx) } else { (theta, f0) }
}

/// Phase φ maximising Σ w_k·t_k·Re(m_k e^{ikφ}) for entries (k, t_k, m_k, w_k).
fn correlation_peak(entries: &[(usize, f64, Complex64, f64)]) -> f64 {
    let eval = |phi: f64| {
        let (mut f, mut d1, mut d2) = (0.0, 0.0, 0.0);
        for &(k, t, m, w) in entries {
            let kf = k as f64;
            let z = m * Complex64::from_polar(w * t, kf * phi);
            f += z.re;
            d1 -= kf * z.im;
            d2 -= kf * kf * z.re;
        }
        (f, d1, d2)
    };
    const GRID: usize = 4096;
    let step = 2.0 * PI / GRID as f64;
    // The grid by rotation: term k advances by e^{ik·step} per point, re-anchored every
    // 256 points.
    let rotations: Vec<Complex64> = entries
        .iter()
        .map(|&(k, ..)| Complex64::from_polar(1.0, k as f64 * step))
        .collect();
    let mut terms: Vec<Complex64> = Vec::with_capacity(entries.len());
    let (mut best, mut best_value) = (0.0, f64::NEG_INFINITY);
    for i in 0..GRID {
        let phi = i as f64 * step;
        if i % 256 == 0 {
            terms.clear();
            terms.extend(
                entries
                    .iter()
                    .map(|&(k, t, m, w)| m * Complex64::from_polar(w * t, k as f64 * phi)),
            );
        }
        let value: f64 = terms.iter().map(|z| z.re).sum();
        if value > best_value {
            (best, best_value) = (phi, value);
        }
        for (z, r) in terms.iter_mut().zip(&rotations) {
            *z *= r;
        }
    }
    let mut x = best;
    for _ in 0..50 {
        let (_, d1, d2) = eval(x);
        if d2.is_nan() || d2 >= 0.0 {
            break;
        }
        let next = x - d1 / d2;
        if (next - best).abs() > step {
            break;
        }
        let done = (next - x).abs() < 1e-15;
        x = next;
        if done {
            break;
        }
    }
    if eval(x).0 >= eval(best).0 {
        x.rem_euclid(2.0 * PI)
    } else {
        best
    }
}

/// Automatic pair for the prior (see [`reconstruct_force`]).
fn choose_pair<'a>(
    cantilever: &Cantilever,
    omega: f64,
    candidates: &[&'a HarmonicSample],
    all_sigma: bool,
) -> Result<(&'a HarmonicSample, &'a HarmonicSample), InversionError> {
    if candidates.len() < 2 {
        return Err(InversionError::NoUsablePair);
    }
    // Amplitudes, their transfer magnitudes and least-squares weights.
    let data: Vec<(usize, f64, f64, f64)> = candidates
        .iter()
        .map(|s| {
            let a = 2.0 * s.value.norm();
            let t = photodiode_transfer(cantilever, s.harmonic as f64 * omega).norm();
            let w = if all_sigma {
                1.0 / (4.0 * s.sigma * s.sigma)
            } else {
                1.0 / (a * a)
            };
            (s.harmonic, a, t, w)
        })
        .collect();
    // Rough τ: least squares over all candidates, F linear for each τ on a scan.
    const SCAN: usize = 2000;
    let mut tau_ls = f64::NAN;
    let mut best = f64::INFINITY;
    for i in 1..=SCAN {
        let tau = AMBIGUITY_SCAN_END * i as f64 / SCAN as f64;
        let q: Vec<f64> = data
            .iter()
            .map(|&(k, _, t, _)| 2.0 * t * cut_cosine_value(1.0, tau, k).abs())
            .collect();
        let num: f64 = data.iter().zip(&q).map(|(d, q)| d.3 * d.1 * q).sum();
        let den: f64 = data.iter().zip(&q).map(|(d, q)| d.3 * q * q).sum();
        if den <= 0.0 {
            continue;
        }
        let force = num / den;
        let residual: f64 = data
            .iter()
            .zip(&q)
            .map(|(d, q)| d.3 * (d.1 - force * q).powi(2))
            .sum();
        if residual < best {
            best = residual;
            tau_ls = tau;
        }
    }
    let limit = 0.9 * 1.5 / tau_ls;
    let mut choice = None;
    let mut best_rel = f64::INFINITY;
    for (i, a) in candidates.iter().enumerate() {
        for b in &candidates[i + 1..] {
            if (a.harmonic.max(b.harmonic) as f64) >= limit {
                continue;
            }
            let measure = |s: &HarmonicSample| AmplitudeMeasurement {
                harmonic: s.harmonic,
                amplitude: 2.0 * s.value.norm(),
                sigma: if all_sigma { 2.0 * s.sigma } else { 1.0 },
            };
            let Ok(fit) = fit_inner(cantilever, omega, measure(a), measure(b), false) else {
                continue;
            };
            let rel = fit.sigma_tau / fit.tau;
            if rel < best_rel {
                best_rel = rel;
                choice = Some((*a, *b));
            }
        }
    }
    choice.ok_or(InversionError::NoUsablePair)
}
