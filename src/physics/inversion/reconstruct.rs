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
//! A sampled signal also carries the harmonics above the Nyquist frequency folded onto the
//! measured ones ([`LockInModel`]); what the prior predicts for them is subtracted from each
//! reading before the division (near the pulse's spectral zero the folded harmonics
//! outweigh the measured one).
//!
//! The prior is the two-harmonic cut-cosine fit ([`super::fit_two_harmonics`]) of a pair of
//! measured harmonics, centred at the pulse phase that best matches the measured phases
//! ([`two_harmonic_prior`]), or one given by the caller (e.g. the least-squares fit of every
//! harmonic, [`super::fit_cut_cosine`]).

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::InversionError;
use super::forward::{ALIAS_HARMONICS, LockInModel, cut_cosine_phasor, cut_cosine_spectrum};
use super::two_harmonic::{
    AMBIGUITY_SCAN_END, AmplitudeMeasurement, CutCosineFit, cut_cosine_value, fit_inner,
};
use crate::physics::beam::Cantilever;
use crate::physics::spectrum::photodiode_transfer;

/// With [`InversionOptions::max_harmonic`] = `None`, the coefficients listed run to at least
/// ⌈TAIL_LOBES/τ⌉ harmonics: ten periods (2/τ harmonics each) of the cos(πτk) in the cut
/// cosine's coefficients (386 for the paper's τ = 0.0518). The force itself then sums the
/// prior's tail to infinity in closed form (the cut cosine in the time domain plus the
/// measured harmonics' departures from it); a series cut at 386 harmonics would be off by
/// 0.002 % in peak and 0.03 % in τ (the coefficients fall only as 1/k²).
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
    /// come from the prior. `None`: the prior's tail summed to infinity (the coefficients
    /// listed run to max(highest measured, ⌈[`TAIL_LOBES`]/τ_prior⌉), at most
    /// [`MAX_AUTO_HARMONIC`]) — the cut cosine's coefficients fall only as 1/k², so a series
    /// cut at the 32 measured harmonics misplaces the peak by a few percent. `Some(K)`: the
    /// series cut at K.
    pub max_harmonic: Option<usize>,
    /// Points N of the force grid over one period (θ_j = 2πj/N).
    pub grid_points: usize,
    /// Whether to find the light-lever minima ([`ForceReconstruction::transfer_minima`]);
    /// a few thousand evaluations of the transfer function, so a live estimator skips it.
    pub transfer_minima: bool,
}

impl Default for InversionOptions {
    fn default() -> Self {
        Self {
            min_snr: 3.0,
            pair: None,
            max_harmonic: None,
            grid_points: 1024,
            transfer_minima: true,
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
    /// Contact time ratio τ (1).
    pub tau: f64,
    /// Peak force F (N).
    pub max_force: f64,
    /// Drive phase (rad, in [0, 2π)) of the pulse centre: the maximum of the correlation of
    /// the measured coefficients with the fitted pulse, or the given one.
    pub pulse_phase: f64,
    /// The two-harmonic fit it came from (τ, F and their uncertainties), if it did; `None`
    /// for a prior given to [`reconstruct_force_with`] (e.g. from [`super::fit_cut_cosine`]).
    pub fit: Option<CutCosineFit>,
}

impl CutCosinePrior {
    /// A prior from given values (no two-harmonic fit behind it).
    pub fn new(tau: f64, max_force: f64, pulse_phase: f64) -> Self {
        Self {
            tau,
            max_force,
            pulse_phase,
            fit: None,
        }
    }

    /// Two-sided coefficient c_k (N) of the prior pulse train.
    pub fn coefficient(&self, k: usize) -> Complex64 {
        cut_cosine_phasor(self.max_force, self.tau, self.pulse_phase, k)
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
    /// F(θ_j) (N) at θ_j = 2πj/N, j = 0..N: c_0 + Σ_{k≥1} 2·Re(c_k e^{ikθ}) (with the
    /// prior's part summed to infinity unless [`InversionOptions::max_harmonic`] is set).
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
    /// Minima of |T| up to the highest harmonic of the series (empty unless
    /// [`InversionOptions::transfer_minima`]).
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
/// `cantilever` driven at `drive_frequency` (Hz), with no aliasing (an ideal anti-alias
/// filter): [`reconstruct_force_with`] on a [`LockInModel`] without a sample rate and the
/// two-harmonic prior.
///
/// # Errors
/// As [`reconstruct_force_with`].
pub fn reconstruct_force(
    cantilever: &Cantilever,
    drive_frequency: f64,
    samples: &[HarmonicSample],
    options: &InversionOptions,
) -> Result<ForceReconstruction, InversionError> {
    validate(drive_frequency, samples, options)?;
    let harmonics: Vec<usize> = samples.iter().map(|s| s.harmonic).collect();
    let model = LockInModel::new(cantilever, drive_frequency, None, &harmonics)?;
    reconstruct_force_with(&model, samples, options, None)
}

/// The cut-cosine prior of the two-harmonic method, with the pulse phase and the aliases
/// accounted for (step 1 of [`reconstruct_force_with`]).
///
/// The pair is `pair`, or chosen automatically: the candidates are the measured harmonics
/// k ≥ 2 with |S_k| ≥ min_snr·σ_k; a least-squares cut cosine over all of them (τ scanned on
/// (0, 0.5], F linear) gives a rough τ_ls, pairs with both harmonics below 0.9·1.5/τ_ls
/// (safely before the first spectral zero, which removes the ambiguity of
/// [`super::CutCosineFit::alternatives`]) are fitted, and the pair with the smallest
/// propagated σ_τ/τ wins (with equal σ on all harmonics when none is given). The pulse phase
/// maximises the correlation Σ w_k·c_k^prior·Re(c_k e^{ikφ}) over the candidates
/// (w_k = |T_k|²/σ_k², or 1 when some σ_k is 0): a grid of 4096 phases, then Newton. When
/// the model has aliases, the fit is repeated once on the readings less the aliases the
/// first fit predicts. The amplitudes are corrected for the mean the noise adds to a
/// magnitude (|S| → √(|S|² − σ²)). `alternatives`: whether to scan for the pair's other roots
/// ([`super::CutCosineFit::alternatives`]; most of the cost when a pair is given).
///
/// # Errors
/// [`InversionError`] when a harmonic of the pair is not measured, no usable pair exists or
/// the pair's amplitudes fit no cut cosine.
pub fn two_harmonic_prior(
    model: &LockInModel,
    samples: &[HarmonicSample],
    pair: Option<(usize, usize)>,
    min_snr: f64,
    alternatives: bool,
) -> Result<CutCosinePrior, InversionError> {
    let cantilever = model.cantilever();
    let omega = 2.0 * PI * model.drive_frequency();
    let transfer = |k: usize| {
        model
            .transfer(k)
            .unwrap_or_else(|| photodiode_transfer(cantilever, k as f64 * omega))
    };
    // Candidates for the prior: harmonics ≥ 2 measured above the noise.
    let candidates: Vec<HarmonicSample> = samples
        .iter()
        .filter(|s| s.harmonic >= 2 && s.value.norm() > 0.0)
        .filter(|s| s.value.norm() >= min_snr * s.sigma)
        .copied()
        .collect();
    let all_sigma = candidates.iter().all(|s| s.sigma > 0.0);
    // The noise adds to |S| on average: E|S + n| ≈ |S| + σ²/(2|S|) for circular noise of σ
    // per quadrature. √(|S|² − σ²) removes that to first order (floored at |S|/2 where the
    // signal is lost in the noise anyway); exact data are untouched.
    let amplitude = |s: &HarmonicSample| AmplitudeMeasurement {
        harmonic: s.harmonic,
        amplitude: 2.0
            * (s.value.norm_sqr() - s.sigma * s.sigma)
                .max(0.25 * s.value.norm_sqr())
                .sqrt(),
        sigma: 2.0 * s.sigma,
    };
    let pair = match pair {
        Some(p) => p,
        None => {
            let refs: Vec<&HarmonicSample> = candidates.iter().collect();
            let (a, b) = choose_pair(cantilever, omega, &refs, all_sigma)?;
            (a.harmonic, b.harmonic)
        }
    };
    let fit_phase = |corrected: &dyn Fn(&HarmonicSample) -> HarmonicSample,
                     first: Option<&CutCosinePrior>| {
        let find = |k: usize| {
            samples
                .iter()
                .find(|s| s.harmonic == k)
                .ok_or(InversionError::PairNotMeasured(k))
        };
        let (sa, sb) = (corrected(find(pair.0)?), corrected(find(pair.1)?));
        let mut fit = fit_inner(
            cantilever,
            omega,
            amplitude(&sa),
            amplitude(&sb),
            alternatives && first.is_none(),
        )?;
        if let Some(f) = first.and_then(|f| f.fit.as_ref()) {
            fit.alternatives.clone_from(&f.alternatives);
        }
        // Pulse phase: correlation of the measured coefficients with the prior's template.
        let template: Vec<(usize, f64, Complex64, f64)> = candidates
            .iter()
            .map(|s| {
                let s = corrected(s);
                let t = transfer(s.harmonic);
                let weight = if all_sigma {
                    t.norm_sqr() / (s.sigma * s.sigma)
                } else {
                    1.0
                };
                (s.harmonic, fit.coefficient(s.harmonic), s.value / t, weight)
            })
            .collect();
        let pulse_phase = correlation_peak(&template, first.map(|f| f.pulse_phase));
        Ok::<_, InversionError>(CutCosinePrior {
            tau: fit.tau,
            max_force: fit.max_force,
            pulse_phase,
            fit: Some(fit),
        })
    };
    let first = fit_phase(&|s: &HarmonicSample| *s, None)?;
    if model.sample_rate().is_none() {
        return Ok(first);
    }
    let spectrum = cut_cosine_spectrum(
        first.max_force,
        first.tau,
        first.pulse_phase,
        ALIAS_HARMONICS,
    );
    fit_phase(
        &|s: &HarmonicSample| HarmonicSample {
            value: s.value - model.aliased_spectrum(s.harmonic, &spectrum),
            ..*s
        },
        Some(&first),
    )
}

/// Reconstructs the tip–sample force from complex photodiode harmonics `samples` (each a
/// harmonic of `model`) read through `model`.
///
/// 1. **Prior.** `prior` if given, else [`two_harmonic_prior`] on `options.pair`.
/// 2. **Coefficients.** c_k = (S_k − A_k)/T(kΩ) for every measured k ≠ 1 that passes the
///    noise floor (module docs), A_k the aliases of k computed from the prior; the prior
///    elsewhere, up to `max_harmonic`.
/// 3. **Force.** F(θ) on the grid; the peak by Newton on the series; the half-maximum
///    crossings by bisection on the series; τ = 1.5·FWHM.
///
/// # Errors
/// [`InversionError`] for invalid inputs, a sample the model does not know, when no usable
/// pair exists, or when the reconstructed force has no positive peak.
pub fn reconstruct_force_with(
    model: &LockInModel,
    samples: &[HarmonicSample],
    options: &InversionOptions,
    prior: Option<CutCosinePrior>,
) -> Result<ForceReconstruction, InversionError> {
    let drive_frequency = model.drive_frequency();
    validate(drive_frequency, samples, options)?;
    if let Some(s) = samples
        .iter()
        .find(|s| model.transfer(s.harmonic).is_none())
    {
        return Err(InversionError::HarmonicNotModelled(s.harmonic));
    }
    let highest_measured = samples.iter().map(|s| s.harmonic).max().unwrap_or(0);
    let transfer = |k: usize| model.transfer_any(k);
    let prior = match prior {
        Some(p) => p,
        None => two_harmonic_prior(model, samples, options.pair, options.min_snr, true)?,
    };
    let kmax = options.max_harmonic.unwrap_or_else(|| {
        let tail = (TAIL_LOBES / prior.tau)
            .ceil()
            .min(MAX_AUTO_HARMONIC as f64) as usize;
        highest_measured.max(tail)
    });

    // Coefficients.
    let spectrum = cut_cosine_spectrum(
        prior.max_force,
        prior.tau,
        prior.pulse_phase,
        kmax.max(ALIAS_HARMONICS),
    );
    let mut coefficients = Vec::with_capacity(kmax + 1);
    for k in 0..=kmax {
        let t = transfer(k);
        let prior_k = spectrum[k];
        let sample = samples.iter().find(|s| s.harmonic == k);
        let measured = sample.map(|s| (s.value - model.aliased_spectrum(k, &spectrum)) / t);
        let expected_snr = match sample {
            Some(s) if s.sigma > 0.0 => t.norm() * prior_k.norm() / s.sigma,
            Some(_) => f64::INFINITY,
            None => f64::NAN,
        };
        let (value, sigma, source) = match (sample, measured) {
            (Some(_), _) if k == 1 => (prior_k, 0.0, CoefficientSource::Fundamental),
            (Some(s), Some(m)) if s.sigma == 0.0 || expected_snr >= options.min_snr => {
                (m, s.sigma / t.norm(), CoefficientSource::Measured)
            }
            (Some(_), _) => (prior_k, 0.0, CoefficientSource::BelowNoiseFloor),
            (None, _) => (prior_k, 0.0, CoefficientSource::NotMeasured),
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
    let mean_force = c.first().map_or(0.0, |c0| c0.re);
    // With the automatic length, the prior's tail is summed to infinity in closed form: the
    // force is the prior pulse itself plus the measured harmonics' departures from it.
    let wave = if options.max_harmonic.is_none() {
        let mut departures: Vec<Complex64> = coefficients[..=highest_measured.min(kmax)]
            .iter()
            .map(|c| c.value - c.prior)
            .collect();
        if let Some(d0) = departures.first_mut() {
            *d0 = Complex64::new(d0.re, 0.0);
        }
        Waveform {
            series: departures,
            pulse: Some(prior.clone()),
        }
    } else {
        Waveform {
            series: c,
            pulse: None,
        }
    };
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
    let force: Vec<f64> = (0..n).map(|j| wave.value(j as f64 * step)).collect();
    let jmax = (0..n)
        .max_by(|&a, &b| force[a].total_cmp(&force[b]))
        .unwrap_or(0);
    let (theta_peak, peak_force) = refine_peak(&wave, jmax as f64 * step, step);
    if peak_force.is_nan() || peak_force <= 0.0 {
        return Err(InversionError::NoPulse);
    }
    let half = 0.5 * peak_force;
    let crossing = |direction: f64| -> Option<f64> {
        // Walk from the peak along the grid until the series drops below half maximum.
        let mut inside = theta_peak;
        for i in 1..=n {
            let theta = theta_peak + direction * i as f64 * step;
            if wave.value(theta) < half {
                let (lo, hi) = if direction > 0.0 {
                    (inside, theta)
                } else {
                    (theta, inside)
                };
                return Some(super::two_harmonic::bisect(
                    |x| direction * (half - wave.value(x)),
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
        transfer_minima: if options.transfer_minima {
            light_lever_minima(model.cantilever(), (kmax as f64 + 0.5) * drive_frequency)
        } else {
            Vec::new()
        },
        coefficients,
        prior,
        force,
        force_sigma,
        peak_force,
        pulse_phase: theta_peak.rem_euclid(2.0 * PI),
        fwhm,
        contact_time_ratio: 1.5 * fwhm,
        mean_force,
        min_force,
    })
}

/// The reconstructed force as a function of the drive phase: a Fourier series, plus the
/// prior's cut cosine in closed form when the series holds departures from it.
struct Waveform {
    series: Vec<Complex64>,
    pulse: Option<CutCosinePrior>,
}

impl Waveform {
    /// F at θ.
    fn value(&self, theta: f64) -> f64 {
        let mut f = force_series(&self.series, theta);
        if let Some(p) = &self.pulse {
            let delta = (theta - p.pulse_phase + PI).rem_euclid(2.0 * PI) - PI;
            if delta.abs() < PI * p.tau {
                f += p.max_force * (0.5 * delta / p.tau).cos();
            }
        }
        f
    }

    /// F, dF/dθ and d²F/dθ² at θ.
    fn eval(&self, theta: f64) -> (f64, f64, f64) {
        let (mut f, mut d1, mut d2) = series(&self.series, theta);
        if let Some(p) = &self.pulse {
            // F·cos(δ/(2τ)) for |δ| < πτ, δ the phase from the pulse centre in (−π, π].
            let delta = (theta - p.pulse_phase + PI).rem_euclid(2.0 * PI) - PI;
            if delta.abs() < PI * p.tau {
                let a = 0.5 / p.tau;
                let (sin, cos) = (a * delta).sin_cos();
                f += p.max_force * cos;
                d1 -= p.max_force * a * sin;
                d2 -= p.max_force * a * a * cos;
            }
        }
        (f, d1, d2)
    }
}

/// Maximum of the force near `theta` (within a grid step either side) by Newton's method
/// on F′ = 0, falling back to the grid point if Newton leaves the bracket.
fn refine_peak(wave: &Waveform, theta: f64, step: f64) -> (f64, f64) {
    let (f0, _, _) = wave.eval(theta);
    let mut x = theta;
    for _ in 0..50 {
        let (_, d1, d2) = wave.eval(x);
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
    let fx = wave.eval(x).0;
    if fx >= f0 { (x, fx) } else { (theta, f0) }
}

/// Phase φ maximising Σ w_k·t_k·Re(m_k e^{ikφ}) for entries (k, t_k, m_k, w_k): Newton's
/// method from `start` when it is given and lands on a maximum within a quarter period of
/// the highest harmonic; otherwise a grid of 16 points per period of the highest harmonic
/// (at least 256), its three largest local maxima refined by Newton.
fn correlation_peak(entries: &[(usize, f64, Complex64, f64)], start: Option<f64>) -> f64 {
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
    let highest = entries.iter().map(|e| e.0).max().unwrap_or(1).max(1);
    if let Some(x0) = start {
        let reach = 0.25 * 2.0 * PI / highest as f64;
        let mut x = x0;
        let mut ok = false;
        for _ in 0..50 {
            let (_, d1, d2) = eval(x);
            if d2.is_nan() || d2 >= 0.0 {
                break;
            }
            let next = x - d1 / d2;
            if (next - x0).abs() > reach {
                break;
            }
            let done = (next - x).abs() < 1e-15;
            x = next;
            if done {
                ok = true;
                break;
            }
        }
        if ok {
            return x.rem_euclid(2.0 * PI);
        }
    }
    // A grid of 16 points per period of the highest harmonic (at least 256), the three
    // largest local maxima on it refined by Newton's method, the best one kept.
    let grid = (16 * highest).max(256);
    let step = 2.0 * PI / grid as f64;
    // The grid by rotation: term k advances by e^{ik·step} per point, re-anchored every
    // 256 points.
    let rotations: Vec<Complex64> = entries
        .iter()
        .map(|&(k, ..)| Complex64::from_polar(1.0, k as f64 * step))
        .collect();
    let mut terms: Vec<Complex64> = Vec::with_capacity(entries.len());
    let mut values = Vec::with_capacity(grid);
    for i in 0..grid {
        let phi = i as f64 * step;
        if i % 256 == 0 {
            terms.clear();
            terms.extend(
                entries
                    .iter()
                    .map(|&(k, t, m, w)| m * Complex64::from_polar(w * t, k as f64 * phi)),
            );
        }
        values.push(terms.iter().map(|z| z.re).sum::<f64>());
        for (z, r) in terms.iter_mut().zip(&rotations) {
            *z *= r;
        }
    }
    let mut peaks: Vec<usize> = (0..grid)
        .filter(|&i| {
            let (prev, next) = (values[(i + grid - 1) % grid], values[(i + 1) % grid]);
            values[i] >= prev && values[i] >= next
        })
        .collect();
    peaks.sort_by(|&a, &b| values[b].total_cmp(&values[a]));
    let refine = |i: usize| {
        let start = i as f64 * step;
        let mut x = start;
        for _ in 0..50 {
            let (_, d1, d2) = eval(x);
            if d2.is_nan() || d2 >= 0.0 {
                break;
            }
            let next = x - d1 / d2;
            if (next - start).abs() > step {
                break;
            }
            let done = (next - x).abs() < 1e-15;
            x = next;
            if done {
                break;
            }
        }
        if eval(x).0 >= values[i] {
            (x, eval(x).0)
        } else {
            (start, values[i])
        }
    };
    peaks
        .iter()
        .take(3)
        .map(|&i| refine(i))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0.0, |(x, _)| x.rem_euclid(2.0 * PI))
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
