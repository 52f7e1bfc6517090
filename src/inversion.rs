//! Live FT-AFM force reconstruction from the lock-in outputs (`/inversion/...`, the `force`
//! stream): the maths of [`crate::physics::inversion`] applied to demodulator frames.
//!
//! Per estimate (every `/inversion/averaging` frames, or one call of
//! [`ForceEstimator::estimate_frame`] for phasors averaged elsewhere, e.g. over a scan
//! pixel):
//!
//! - every harmonic's noise σ is *predicted* from the instrument's noise settings (thermal
//!   motion of every mode through the light lever, detector, ADC) and the demodulator's
//!   equivalent noise bandwidth, including the correlation of the averaged frames
//!   ([`crate::physics::inversion::NoiseModel`], [`LowPassNoise`]); noise off gives σ = 0;
//! - what each demodulator reads is modelled through the ADC's anti-alias filter with the
//!   harmonics that alias onto it (all of them with `/synth/anti_alias = false`;
//!   [`LockInModel::with_front_end`]);
//! - **two-harmonic** (the paper's method): τ and F of the cut cosine from the amplitudes of
//!   `/inversion/harmonic_a` and `_b`, less their aliases;
//! - **full**: τ, F and the pulse phase of the cut cosine fitted to *every* demodulated
//!   harmonic ≥ 2 by weighted least squares (maximum likelihood; [`fit_cut_cosine`]), which
//!   for the default noise is the Cramér–Rao-efficient estimate (docs/ft-afm.md);
//! - the modulus: (F, τ) with their covariance through a table ([`ModulusTable`]) built
//!   when the estimator is: of the 1-DOF Hertz model on the paper engine, of what the
//!   method reads off coupled orbits on the coupled engine; there the reported F and τ are
//!   the pulse's own (the table's ratio at the estimated E);
//! - the waveform: every harmonic whose expected signal is above 3σ divided by the transfer
//!   function (Stark et al. 2002), the rest from the method's cut cosine.

use serde::Serialize;

use crate::config::{Engine, InversionMethod, Material, Oscillator, Settings};
use crate::model;
use crate::physics::inversion::{
    ALIAS_HARMONICS, CutCosineFit, CutCosinePrior, CutCosineStart, HarmonicSample,
    InversionOptions, LockInModel, LowPassNoise, ModulusTable, NoiseModel, PulseMeasure, TableNode,
    TableRange, cut_cosine_from_coefficients, fit_cut_cosine, lockin_sigma, reconstruct_force_with,
    two_harmonic_prior,
};
use crate::physics::{Cantilever, Continuation, CoupledOrbit, SearchLimits};
use crate::pipeline::DemodFrame;
use crate::timebase::PREDECIMATION;
use rustfft::num_complex::Complex64;
use std::sync::atomic::{AtomicBool, Ordering};

/// Range of the modulus table (Pa) and its nodes.
const TABLE_RANGE: (f64, f64) = (1e5, 1e12);
const TABLE_POINTS: usize = 64;
/// Expected signal-to-noise ratio below which a harmonic of the waveform comes from the cut
/// cosine rather than from its measurement.
const MIN_SNR: f64 = 3.0;

/// One force estimate, as the `force` stream sends it. SI units.
#[derive(Clone, Debug, Serialize)]
pub struct ForceEstimate {
    /// Newest input sample reflected (index).
    #[serde(skip)]
    pub sample_index: u64,
    /// Simulated time (s).
    #[serde(skip)]
    pub t: f64,
    /// Unix time (ns) its newest sample was synthesised.
    #[serde(skip)]
    pub t_synth_ns: u64,
    /// "two_harmonic" or "full".
    pub method: &'static str,
    /// τ (1) and its standard deviation.
    pub contact_time_ratio: f64,
    pub contact_time_ratio_sigma: f64,
    /// Peak force F (N) and its standard deviation.
    pub max_force: f64,
    pub max_force_sigma: f64,
    /// Young's modulus of the sample (Pa) and its standard deviation: half the width of
    /// `youngs_modulus_interval`, which is the first-order σ where E is linear in (F, τ)
    /// over it.
    pub youngs_modulus: f64,
    pub youngs_modulus_sigma: f64,
    /// The 68 % profile interval of E (Pa, low and high), asymmetric where the table's
    /// (F, τ) flattens with E (a soft lever on a stiff sample reads a low E with a narrow
    /// first-order σ while the interval reaches the true one).
    pub youngs_modulus_interval: [f64; 2],
    /// "inside", "below_table" or "above_table".
    pub table_range: TableRange,
    /// Drive phase (rad) of the force peak.
    pub pulse_phase: f64,
    /// The force over one period at equally spaced drive phases from 0 (N).
    pub waveform: Vec<f64>,
    /// The settings epoch the estimate reflects: of the settings its model was built for,
    /// and of the frames it averaged (set by the daemon; 0 offline).
    pub epoch: u64,
    /// True when settings the model depends on changed since it was built: the estimate
    /// belongs to the old settings and is not to be read as current (set by the daemon).
    pub stale: bool,
    /// Why the estimate may be biased or poor, each with what to change
    /// ([`ForceEstimator::warnings`]); empty when nothing is known to be wrong.
    pub warnings: Vec<String>,
}

/// The periodic orbits of a coupled engine's modulus table, node by node: where the next
/// table's orbit searches start ([`ForceEstimator::seeded`]).
#[derive(Clone, Debug)]
pub struct TableSeed {
    /// (modulus in Pa, orbit) per node.
    orbits: Vec<(f64, Continuation)>,
}

/// Why no estimate came out of a frame (counted, not fatal).
#[derive(Debug, thiserror::Error)]
pub enum EstimateError {
    /// A harmonic the method needs is not in the frame.
    #[error("harmonic {0} is not demodulated")]
    MissingHarmonic(usize),
    /// The maths refused the measurement (e.g. no contact, amplitude ratio impossible).
    #[error("{0}")]
    Maths(String),
}

/// Noise of one demodulator.
#[derive(Clone, Copy, Debug)]
struct DemodNoise {
    harmonic: u32,
    /// One-sided photodiode noise density around its harmonic (m²/Hz).
    density: f64,
    /// Equivalent noise bandwidth of one output (Hz).
    bandwidth: f64,
    /// Equivalent noise bandwidth of the mean of `averaging` successive outputs (Hz).
    averaged_bandwidth: f64,
}

/// Builds estimates from demodulator frames. Construct it off any latency-sensitive path:
/// the modulus table takes about 0.1 s on the paper engine, 0.8–2.1 s on the coupled one
/// (docs/ft-afm.md). [`Self::push`] keeps the running average of the
/// live stream; [`Self::estimate_frame`] takes `&self` and estimates from any phasors.
pub struct ForceEstimator {
    fitter: Fitter,
    /// The coupled table's orbits, for the next estimator to start from.
    seed: Option<TableSeed>,
    averaging: usize,
    points: usize,
    noise: NoiseModel,
    /// Per demodulator index (`None`: disabled, or on `/drive2`).
    demods: Vec<Option<DemodNoise>>,
    /// F(E) and τ(E) as the method measures them. With the paper engine the tap force *is*
    /// the cut cosine of the 1-DOF (F, τ), so both methods measure exactly the 1-DOF pulse's
    /// (`PulseMeasure::Shape`). The coupled engine's Hertz pulse is not a cut cosine: its
    /// table holds what the method's fit reads off the coupled orbit's noise-free readings
    /// (`PulseMeasure::CoupledFit`), and the pulse's own F and τ beside them.
    table: ModulusTable,
    /// Why its estimates may be biased or poor, with what to change: harmonics it relies on
    /// out of band or not demodulated ([`Settings::force_warnings`]), under the noise floor,
    /// a modulus table short of its range. Sent with every estimate.
    warnings: Vec<String>,
    /// Running sums of X + iY per demodulator for averaging.
    sum: Vec<Complex64>,
    summed: usize,
}

impl ForceEstimator {
    /// The estimator for `settings`; `None` when `/inversion/enable` is false.
    pub fn new(settings: &Settings) -> Result<Option<Self>, String> {
        Self::seeded(settings, None)
    }

    /// [`Self::new`], starting the coupled engine's table from the orbits of `seed` (an
    /// earlier estimator's [`Self::seed`], e.g. for the previous point of a sweep): each node
    /// is continued from the same node of the earlier table, a few periods instead of a
    /// transient when the settings moved a little, and solved afresh where that fails. The
    /// table is the same to the orbits' tolerance whatever the seed.
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn seeded(settings: &Settings, seed: Option<&TableSeed>) -> Result<Option<Self>, String> {
        Self::build(settings, seed, None)
    }

    /// [`Self::seeded`], stopped with an error as soon as `cancel` is set (between the
    /// coupled table's nodes, and inside its first orbit search): a builder whose settings
    /// were superseded does not finish a table nobody will use.
    ///
    /// # Errors
    /// As [`Self::new`], and when cancelled.
    pub fn build(
        settings: &Settings,
        seed: Option<&TableSeed>,
        cancel: Option<&AtomicBool>,
    ) -> Result<Option<Self>, String> {
        let inv = &settings.inversion;
        if !inv.enable {
            return Ok(None);
        }
        let cantilever = model::cantilever(settings).map_err(|e| e.to_string())?;
        let oscillator = model::impact_oscillator(settings, &cantilever, settings.sample);
        // The configured harmonics, or in-band ones in place of those out of band.
        let pair = settings.inversion_harmonics().ok_or_else(|| {
            settings
                .node_warning("/inversion/harmonic_a")
                .unwrap_or_else(|| "no two harmonics in band".to_owned())
        })?;
        let pair = (pair.0 as usize, pair.1 as usize);
        let fs = settings.synth.sample_rate;
        // The tapping's harmonics: those of demodulators on /drive (one on /drive2 reads
        // another excitation's, which the inversion does not model).
        let on_drive = |i: usize| {
            settings.demod_active(i) && settings.demods[i].oscillator == Oscillator::Drive
        };
        let harmonics: Vec<usize> = (0..settings.demods.len())
            .filter(|&i| on_drive(i))
            .map(|i| settings.demods[i].harmonic as usize)
            .collect();
        let mut lockin =
            LockInModel::new(&cantilever, settings.drive.frequency, Some(fs), &harmonics)
                .map_err(|e| e.to_string())?;
        if settings.synth.anti_alias {
            // The lock-in reads the harmonics through the ADC's anti-alias filter.
            let taps = crate::synth::adc::grid_taps();
            lockin = lockin.with_front_end(|f| crate::synth::adc::gain(&taps, f));
        }
        let n = &settings.noise;
        let noise = if n.enable {
            NoiseModel {
                temperature: n.temperature,
                detector_density: n.detector_density,
                adc_lsb: if n.adc_bits > 0 {
                    2.0 * n.adc_range / 2f64.powi(n.adc_bits as i32)
                } else {
                    0.0
                },
                sample_rate: Some(fs),
            }
        } else {
            NoiseModel::NONE
        };
        let averaging = inv.averaging.max(1) as usize;
        let decimated = fs / PREDECIMATION as f64;
        let demods: Vec<Option<DemodNoise>> = settings
            .demods
            .iter()
            .enumerate()
            .map(|(i, d)| {
                on_drive(i).then(|| {
                    let filter = LowPassNoise {
                        order: d.order,
                        time_constant: d.timeconstant,
                    };
                    // The bank's realised output period: a whole number of decimated samples.
                    let period = (decimated / d.rate).round().max(1.0) / decimated;
                    DemodNoise {
                        harmonic: d.harmonic,
                        density: noise
                            .density(&cantilever, d.harmonic as f64 * settings.drive.frequency),
                        bandwidth: filter.bandwidth(),
                        averaged_bandwidth: filter.averaged_bandwidth(averaging, period),
                    }
                })
            })
            .collect();
        let fitter = Fitter {
            model: lockin,
            method: inv.method,
            pair,
        };
        let mut seed_out = None;
        let mut warnings = settings.force_warnings();
        let table = match settings.synth.engine {
            Engine::Paper => ModulusTable::with_measure(
                &oscillator,
                model::elastic(settings.tip),
                settings.sample.poisson,
                TABLE_RANGE,
                TABLE_POINTS,
                PulseMeasure::Shape,
            )
            .map_err(|e| e.to_string())?,
            Engine::Coupled => {
                // The σ of a live estimate (the mean of `averaging` frames): the nodes are
                // fitted with the weights and noise floor the live fit uses, so that where
                // the cut cosine is only an approximation of the orbit's pulse (a long
                // pulse on a soft sample) both make the same approximation.
                let sigmas: Vec<(u32, f64)> = demods
                    .iter()
                    .flatten()
                    .map(|d: &DemodNoise| {
                        (d.harmonic, lockin_sigma(d.density, d.averaged_bandwidth))
                    })
                    .collect();
                let built = coupled_table(settings, &cantilever, &fitter, &sigmas, seed, cancel)?;
                seed_out = Some(TableSeed {
                    orbits: built.orbits,
                });
                warnings.extend(built.note);
                warnings.extend(noise_floor_warning(&built.quiet, pair, inv.averaging));
                let readings = expected_samples(&fitter, &built.set_coefficients, &sigmas);
                warnings.extend(resolution_warning(
                    &fitter,
                    &built.table,
                    &readings,
                    settings.sample.youngs_modulus,
                    inv.averaging,
                ));
                built.table
            }
        };
        Ok(Some(Self {
            fitter,
            seed: seed_out,
            averaging,
            points: inv.points as usize,
            noise,
            demods,
            table,
            warnings,
            sum: vec![Complex64::new(0.0, 0.0); settings.demods.len()],
            summed: 0,
        }))
    }

    /// What the next estimator can start its coupled table from ([`Self::seeded`]); `None`
    /// on the paper engine.
    pub fn seed(&self) -> Option<&TableSeed> {
        self.seed.as_ref()
    }

    /// Whether the estimators of `a` and `b` are the same: every setting the estimator
    /// models is equal (the cantilever, tip, sample Poisson ratio, drive, setpoint,
    /// demodulators, inversion and noise settings, sample rate, anti-alias filter, engine and
    /// adhesion). A caller that sees other settings change keeps its estimator: with the
    /// coupled engine a build takes seconds.
    pub fn same_model(a: &Settings, b: &Settings) -> bool {
        a.cantilever == b.cantilever
            && a.tip == b.tip
            && a.sample.poisson == b.sample.poisson
            && a.drive == b.drive
            && a.surface == b.surface
            && a.demods == b.demods
            && a.inversion == b.inversion
            && a.noise == b.noise
            && a.synth.sample_rate == b.synth.sample_rate
            && a.synth.anti_alias == b.synth.anti_alias
            && a.synth.engine == b.synth.engine
            && a.adhesion == b.adhesion
    }

    /// Whether the estimator built for `built_for` serves `now`: the same model
    /// ([`Self::same_model`]) and, on the coupled engine, every material modulus of `now`
    /// (the sample's and each enabled inclusion's) within [`DENSE_REACH`] of one of
    /// `built_for`'s, where its table's nodes are 0.2 decade apart. Farther, the table is
    /// sparse there, and its warnings at the set modulus are of another sample.
    pub fn covers(built_for: &Settings, now: &Settings) -> bool {
        if !Self::same_model(built_for, now) {
            return false;
        }
        if built_for.synth.engine != Engine::Coupled {
            return true;
        }
        let built: Vec<f64> = material_moduli(built_for).map(f64::log10).collect();
        material_moduli(now).all(|e| built.iter().any(|b| (e.log10() - b).abs() <= DENSE_REACH))
    }

    /// The noise model the estimator assumes.
    pub fn noise_model(&self) -> &NoiseModel {
        &self.noise
    }

    /// The forward model (transfer and aliases) the estimator fits.
    pub fn lockin_model(&self) -> &LockInModel {
        &self.fitter.model
    }

    /// The modulus table.
    pub fn table(&self) -> &ModulusTable {
        &self.table
    }

    /// Standard deviation (m) of each of X and Y of a reading at `harmonic` ≥ 1 whose
    /// one-sided equivalent noise bandwidth is `bandwidth` (Hz): √(2·G·B) with G the
    /// photodiode noise density there. For a boxcar average over T seconds (a scan pixel)
    /// B = 1/(2T).
    pub fn phasor_sigma(&self, harmonic: u32, bandwidth: f64) -> f64 {
        let model = &self.fitter.model;
        let frequency = harmonic as f64 * model.drive_frequency();
        lockin_sigma(self.noise.density(model.cantilever(), frequency), bandwidth)
    }

    /// One-sided equivalent noise bandwidth (Hz) of one output of demodulator `index`
    /// (`None` if it is disabled or absent): 156.25 Hz for order 4 and τ = 0.5 ms.
    pub fn frame_bandwidth(&self, index: usize) -> Option<f64> {
        self.demods
            .get(index)
            .copied()
            .flatten()
            .map(|d| d.bandwidth)
    }

    /// One-sided equivalent noise bandwidth (Hz) of a live estimate's reading of
    /// demodulator `index`, the mean of `/inversion/averaging` outputs (`None` if it is
    /// disabled or absent): [`Self::frame_bandwidth`] for one.
    pub fn estimate_bandwidth(&self, index: usize) -> Option<f64> {
        self.demods
            .get(index)
            .copied()
            .flatten()
            .map(|d| d.averaged_bandwidth)
    }

    /// Takes one demodulator frame; every `averaging` frames returns an estimate.
    pub fn push(&mut self, frame: &DemodFrame) -> Option<Result<ForceEstimate, EstimateError>> {
        self.push_or_skip(frame, true)?
    }

    /// [`Self::push`], but at the end of an averaging window the fit (nearly all of the
    /// cost) is made only if `fit`: `Some(None)` is a window whose estimate nobody wanted.
    pub fn push_or_skip(
        &mut self,
        frame: &DemodFrame,
        fit: bool,
    ) -> Option<Option<Result<ForceEstimate, EstimateError>>> {
        for v in frame.values() {
            if let Some(s) = self.sum.get_mut(v.index as usize) {
                *s += Complex64::new(v.x, v.y);
            }
        }
        self.summed += 1;
        if self.summed < self.averaging {
            return None;
        }
        if !fit {
            self.sum.fill(Complex64::new(0.0, 0.0));
            self.summed = 0;
            return Some(None);
        }
        let n = self.summed as f64;
        let mut samples = Vec::with_capacity(frame.len);
        for v in frame.values().iter().filter(|v| v.on_drive()) {
            let i = v.index as usize;
            let (Some(sum), Some(Some(noise))) = (self.sum.get(i), self.demods.get(i)) else {
                continue;
            };
            let sigma = lockin_sigma(noise.density, noise.averaged_bandwidth);
            push_sample(&mut samples, noise.harmonic, sum / n, sigma);
        }
        for s in &mut self.sum {
            *s = Complex64::new(0.0, 0.0);
        }
        self.summed = 0;
        Some(Some(self.estimate(frame, &samples)))
    }

    /// An estimate from the phasors in `frame` (X + iY per demodulator, as the lock-in
    /// reports them; e.g. one scan pixel's boxcar averages) whose one-sided equivalent noise
    /// bandwidth is `bandwidth` (Hz) for every demodulator (1/(2T) for a boxcar of T
    /// seconds). Does not touch the running average of [`Self::push`].
    pub fn estimate_frame(
        &self,
        frame: &DemodFrame,
        bandwidth: f64,
    ) -> Result<ForceEstimate, EstimateError> {
        let mut samples = Vec::with_capacity(frame.len);
        for v in frame.values().iter().filter(|v| v.on_drive()) {
            let Some(Some(noise)) = self.demods.get(v.index as usize) else {
                continue;
            };
            let sigma = lockin_sigma(noise.density, bandwidth);
            push_sample(&mut samples, v.harmonic, Complex64::new(v.x, v.y), sigma);
        }
        self.estimate(frame, &samples)
    }

    /// The estimate from harmonics `samples` (two-sided S_k with σ per quadrature).
    fn estimate(
        &self,
        frame: &DemodFrame,
        samples: &[HarmonicSample],
    ) -> Result<ForceEstimate, EstimateError> {
        let maths = |e: &dyn std::fmt::Display| EstimateError::Maths(e.to_string());
        let Fitted {
            method,
            tau,
            sigma_tau,
            force,
            sigma_force,
            covariance,
            prior,
        } = self.fitter.fit(samples, true)?;
        let modulus = self
            .table
            .estimate_unbiased(force, tau, covariance)
            .map_err(|e| maths(&e))?;
        // From the cut cosine the method reads to the pulse's own peak and width (1 with
        // the paper engine, whose pulse is that cut cosine).
        let (to_force, to_tau) = self.table.pulse_ratios(modulus.youngs_modulus);
        let options = InversionOptions {
            min_snr: MIN_SNR,
            pair: Some(self.fitter.pair),
            grid_points: self.points,
            transfer_minima: false,
            ..InversionOptions::default()
        };
        let reconstruction =
            reconstruct_force_with(&self.fitter.model, samples, &options, Some(prior))
                .map_err(|e| maths(&e))?;
        Ok(ForceEstimate {
            sample_index: frame.sample_index,
            t: frame.t,
            t_synth_ns: frame.t_synth_ns,
            method,
            contact_time_ratio: tau * to_tau,
            contact_time_ratio_sigma: sigma_tau * to_tau,
            max_force: force * to_force,
            max_force_sigma: sigma_force * to_force,
            youngs_modulus: modulus.youngs_modulus,
            youngs_modulus_sigma: modulus.interval_sigma(),
            youngs_modulus_interval: [modulus.interval.0, modulus.interval.1],
            table_range: modulus.range,
            pulse_phase: reconstruction.pulse_phase,
            waveform: reconstruction.force,
            epoch: 0,
            stale: false,
            warnings: self.warnings.clone(),
        })
    }

    /// Why this estimator's estimates may be biased or poor, with what to change (empty
    /// when nothing is known to be wrong).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Drops the running average: the next estimate averages only frames pushed from now on
    /// (after a settings change, so no estimate mixes frames of two settings).
    pub fn reset_window(&mut self) {
        self.sum.fill(Complex64::new(0.0, 0.0));
        self.summed = 0;
    }
}

/// Adds the lock-in reading `z` = X + iY at `harmonic` with σ per quadrature `sigma` (of a
/// harmonic k ≥ 1, [`lockin_sigma`]) as a two-sided sample: S_k = z/2 with σ/2 for k ≥ 1;
/// for k = 0 the mean itself, whose single quadrature has σ/√2 (mixing with 1 instead of
/// 2e^{−ikθ}). A second demodulator at a harmonic already present is skipped (its noise is
/// not independent of the first's).
fn push_sample(samples: &mut Vec<HarmonicSample>, harmonic: u32, z: Complex64, sigma: f64) {
    let k = harmonic as usize;
    if samples.iter().any(|s| s.harmonic == k) {
        return;
    }
    let (scale, sigma_scale) = if k == 0 {
        (1.0, std::f64::consts::FRAC_1_SQRT_2)
    } else {
        (0.5, 0.5)
    };
    samples.push(HarmonicSample {
        harmonic: k,
        value: z * scale,
        sigma: sigma * sigma_scale,
    });
}

/// The method's reading of the pulse: τ and F of the cut cosine, from the harmonics.
struct Fitter {
    model: LockInModel,
    method: InversionMethod,
    pair: (usize, usize),
}

/// What [`Fitter::fit`] reads: (τ, F) of the cut cosine, their σ and covariance, and the
/// cut cosine the waveform is completed with.
struct Fitted {
    method: &'static str,
    tau: f64,
    sigma_tau: f64,
    force: f64,
    sigma_force: f64,
    covariance: [[f64; 2]; 2],
    prior: CutCosinePrior,
}

impl Fitter {
    /// (τ, F) of the cut cosine from harmonics `samples` (two-sided S_k with σ per
    /// quadrature), by the configured method; with `debias`, less the estimate's
    /// second-order bias under the samples' noise (for live readings; a table of noise-free
    /// readings wants the plain fit).
    fn fit(&self, samples: &[HarmonicSample], debias: bool) -> Result<Fitted, EstimateError> {
        for k in [self.pair.0, self.pair.1] {
            if !samples.iter().any(|s| s.harmonic == k) {
                return Err(EstimateError::MissingHarmonic(k));
            }
        }
        let maths = |e: &dyn std::fmt::Display| EstimateError::Maths(e.to_string());
        let paired = match two_harmonic_prior(&self.model, samples, Some(self.pair), MIN_SNR, false)
        {
            Ok(paired) => paired,
            // The full method only needs a start: where the configured pair fits no cut
            // cosine (a long pulse puts H17 past the cut cosine's first spectral zero, so
            // |c6|/|c17| < 1 has no root), the pair the prior chooses among the harmonics
            // above the noise, before that zero.
            Err(first) if matches!(self.method, InversionMethod::Full) => {
                two_harmonic_prior(&self.model, samples, None, MIN_SNR, false).map_err(
                    |chosen| {
                        maths(&format!(
                            "{first}; from the pair chosen among the harmonics above the \
                             noise: {chosen}"
                        ))
                    },
                )?
            }
            Err(e) => return Err(maths(&e)),
        };
        Ok(match self.method {
            InversionMethod::TwoHarmonic => {
                let fit = paired.fit.as_ref().ok_or(EstimateError::Maths(
                    "the two-harmonic fit is missing".into(),
                ))?;
                let (tau, force) = if debias {
                    self.debiased_pair(fit, samples)
                } else {
                    (fit.tau, fit.max_force)
                };
                Fitted {
                    method: "two_harmonic",
                    tau,
                    sigma_tau: fit.sigma_tau,
                    force,
                    sigma_force: fit.sigma_force,
                    covariance: fit.force_tau_covariance(),
                    prior: CutCosinePrior::new(tau, force, paired.pulse_phase),
                }
            }
            InversionMethod::Full => {
                let from = |p: &CutCosinePrior| {
                    fit_cut_cosine(
                        &self.model,
                        samples,
                        CutCosineStart {
                            tau: p.tau,
                            max_force: p.max_force,
                            pulse_phase: p.pulse_phase,
                        },
                    )
                };
                let mut lsq = from(&paired).map_err(|e| maths(&e))?;
                // The pair's root assumes both harmonics before the pulse's first spectral
                // zero (τ < 1.5/b). A fit that ends past it started from a root that may be
                // the wrong one (a long pulse on a soft sample: the fit from (6, 17) ends
                // at τ ≈ 0.56 with χ² twice the other's, where the pulse has τ ≈ 0.24):
                // the fit from the pair the prior chooses among the harmonics above the
                // noise, before that zero, is tried too, and the better kept.
                if lsq.tau >= 1.5 / self.pair.1.max(self.pair.0) as f64
                    && let Ok(chosen) =
                        two_harmonic_prior(&self.model, samples, None, MIN_SNR, false)
                    && let Ok(other) = from(&chosen)
                    && other.chi_squared < lsq.chi_squared
                {
                    lsq = other;
                }
                // Second-order bias removed (Box): tiny against σ, but E is steep in (F, τ).
                let (tau, force) = if debias {
                    (lsq.tau - lsq.bias[0], lsq.max_force - lsq.bias[1])
                } else {
                    (lsq.tau, lsq.max_force)
                };
                Fitted {
                    method: "full",
                    tau,
                    sigma_tau: lsq.sigma_tau,
                    force,
                    sigma_force: lsq.sigma_force,
                    covariance: lsq.force_tau_covariance(),
                    prior: CutCosinePrior::new(tau, force, lsq.pulse_phase),
                }
            }
        })
    }

    /// (τ, F) of the two-harmonic fit less its second-order bias: the pair's solution is a
    /// curved function of the two force-coefficient magnitudes, so noise biases it (F by
    /// +0.2 % at the default 1 kHz noise). The mean over the sigma points |c_a| ± √2·σ_a,
    /// |c_b| ± √2·σ_b (the unscented transform) estimates the expectation; the excess over
    /// the fit is subtracted. Unchanged without noise or when a sigma point has no solution.
    fn debiased_pair(&self, fit: &CutCosineFit, samples: &[HarmonicSample]) -> (f64, f64) {
        let (a, b) = fit.harmonics;
        let (ca, cb) = fit.force_coefficients;
        let sigma = |k: usize| {
            let s = samples
                .iter()
                .find(|s| s.harmonic == k)
                .map_or(0.0, |s| s.sigma);
            s / self.model.transfer(k).map_or(f64::INFINITY, |t| t.norm())
        };
        let (sa, sb) = (sigma(a), sigma(b));
        if !(sa > 0.0 || sb > 0.0) {
            return (fit.tau, fit.max_force);
        }
        let h = std::f64::consts::SQRT_2;
        let mut mean = (0.0, 0.0);
        for (da, db) in [(h * sa, 0.0), (-h * sa, 0.0), (0.0, h * sb), (0.0, -h * sb)] {
            match cut_cosine_from_coefficients(a, ca + da, b, cb + db) {
                Ok((tau, force)) => {
                    mean.0 += 0.25 * tau;
                    mean.1 += 0.25 * force;
                }
                Err(_) => return (fit.tau, fit.max_force),
            }
        }
        (2.0 * fit.tau - mean.0, 2.0 * fit.max_force - mean.1)
    }
}

/// The error of a [`ForceEstimator::build`] stopped by its cancel flag (and of nothing else).
pub const BUILD_CANCELLED: &str = "the modulus table's build was cancelled (newer settings wait)";

/// The ratio of the 68 % interval's ends above which the estimator warns that E is poorly
/// resolved (the default lever on silicon at one 1 kHz frame: 1.4).
const POOR_RESOLUTION: f64 = 2.0;

/// The lock-in's readings of an orbit's force coefficients `c` at the harmonics of
/// `sigmas` ((harmonic, σ per quadrature)), noise-free, as the fit takes them.
fn expected_samples(
    fitter: &Fitter,
    c: &[Complex64],
    sigmas: &[(u32, f64)],
) -> Vec<HarmonicSample> {
    let mut samples = Vec::with_capacity(sigmas.len());
    for &(k, sigma) in sigmas {
        let read = fitter
            .model
            .read(k as usize, |j| c.get(j).copied().unwrap_or_default())
            .unwrap_or_default();
        // The lock-in's X + iY is twice S_k for k ≥ 1 and S_0 itself for k = 0.
        let z = if k == 0 { read } else { 2.0 * read };
        push_sample(&mut samples, k, z, sigma);
    }
    samples
}

/// A warning when an estimate at the set modulus, from the noise-free `readings` with the
/// σ of a live estimate, has a 68 % interval spanning more than [`POOR_RESOLUTION`]: the
/// single number then says little, and estimates scatter far (a soft lever on a stiff
/// sample: F and τ barely change with E).
fn resolution_warning(
    fitter: &Fitter,
    table: &ModulusTable,
    readings: &[HarmonicSample],
    set: f64,
    averaging: u32,
) -> Option<String> {
    let fitted = fitter.fit(readings, false).ok()?;
    let modulus = table
        .estimate_with_covariance(fitted.force, fitted.tau, fitted.covariance)
        .ok()?;
    let (lo, hi) = modulus.interval;
    (hi > POOR_RESOLUTION * lo).then(|| {
        let q = |v| crate::config::quantity::quantity_rounded(v, "Pa", 3);
        format!(
            "E is poorly resolved with these settings: at the set modulus {} an estimate's \
             68 % interval is predicted to span {} to {} (F and τ change little with E \
             here), so single estimates scatter widely; raise /inversion/averaging (now \
             {averaging}) or, for a stiff sample, use a stiffer lever",
            q(set),
            q(lo),
            q(hi),
        )
    })
}

/// The moduli (Pa) of the sample and of every enabled inclusion: the coupled table's
/// anchors.
fn material_moduli(settings: &Settings) -> impl Iterator<Item = f64> + '_ {
    std::iter::once(settings.sample.youngs_modulus)
        .chain(
            settings
                .inclusions
                .iter()
                .filter(|i| i.enable)
                .map(|i| i.youngs_modulus),
        )
        .filter(|e| e.is_finite() && *e > 0.0)
}

/// How far (decades) a material's modulus may move from the one a coupled table was built
/// about before the table is rebuilt ([`ForceEstimator::covers`]): inside the 0.6 decade
/// of 0.2-decade nodes about it, with a margin.
const DENSE_REACH: f64 = 0.4;

/// Steps (decades) from each material's modulus to the coupled table's nodes about it:
/// 0.2 decade near it (the spacing at which the monotone cubic reproduces the orbits
/// between nodes, tests), growing far from it, where an estimate only has to say how far
/// off the sample is.
const COUPLED_TABLE_STEPS: [f64; 8] = [0.0, 0.2, 0.4, 0.6, 1.0, 1.6, 2.5, 4.0];
/// Nodes closer than this (decades) are merged.
const COUPLED_TABLE_MIN_STEP: f64 = 0.12;

/// The moduli (Pa, increasing) of the coupled engine's table: both ends of [`TABLE_RANGE`],
/// and [`COUPLED_TABLE_STEPS`] either side of the base material's modulus and of every
/// enabled inclusion's (each clamped into the range), merged where closer than
/// [`COUPLED_TABLE_MIN_STEP`]. 12–16 nodes for the presets, as many as the 16 evenly spread
/// nodes of a 1 GPa–1 TPa table: the range grew four decades at the same cost.
pub fn coupled_table_moduli(settings: &Settings) -> Vec<f64> {
    let (lo, hi) = (TABLE_RANGE.0.log10(), TABLE_RANGE.1.log10());
    let mut decades = vec![lo, hi];
    for e in material_moduli(settings) {
        let centre = e.log10().clamp(lo, hi);
        for step in COUPLED_TABLE_STEPS {
            for d in [centre - step, centre + step] {
                if d > lo && d < hi {
                    decades.push(d);
                }
            }
        }
    }
    decades.sort_by(f64::total_cmp);
    let mut kept: Vec<f64> = Vec::with_capacity(decades.len());
    for d in decades {
        match kept.last() {
            Some(&last) if d - last < COUPLED_TABLE_MIN_STEP => {
                // The upper end stays; the node just below it goes.
                if d == hi {
                    kept.pop();
                    kept.push(d);
                }
            }
            _ => kept.push(d),
        }
    }
    kept.into_iter().map(|d| 10f64.powf(d)).collect()
}

/// The coupled engine's modulus table: at each node ([`coupled_table_moduli`]) the coupled
/// orbit (physics.md §6) of the settings with that modulus under the tip, the noise-free
/// readings of every active demodulator through `fitter`'s lock-in model (aliases
/// included), and what the method's fit reads off them, beside the pulse's own F and τ.
/// `sigmas` are the demodulators' (harmonic, σ per quadrature of X and Y): they weight the
/// full method's fit as they weight it live.
///
/// The node at the set modulus is solved first, by an approach from far (the branch the
/// live engine reaches) or continued from the seed's orbit at the same modulus; two chains
/// then continue from it down and up on two threads. A chain that loses the orbit ends
/// there: the table is narrower (estimates beyond it say `below_table` / `above_table`),
/// and the returned note says where and why. Setting `cancel` stops the build between
/// nodes (and inside the first search) with an error.
fn coupled_table(
    settings: &Settings,
    cantilever: &Cantilever,
    fitter: &Fitter,
    sigmas: &[(u32, f64)],
    seed: Option<&TableSeed>,
    cancel: Option<&AtomicBool>,
) -> Result<CoupledTable, String> {
    let moduli = coupled_table_moduli(settings);
    // The aliases reach far above the demodulated harmonics; without sampling, no further
    // than the highest of them.
    let harmonics = if fitter.model.sample_rate().is_some() {
        ALIAS_HARMONICS
    } else {
        sigmas.iter().map(|&(k, _)| k as usize).max().unwrap_or(0)
    };
    let cancelled = || cancel.is_some_and(|c| c.load(Ordering::Relaxed));
    let seeded = |youngs_modulus: f64| {
        seed.and_then(|s| {
            s.orbits
                .iter()
                .find(|(e, _)| (e / youngs_modulus - 1.0).abs() < 1e-9)
                .map(|(_, c)| c)
        })
    };
    let problem_at = |youngs_modulus: f64| {
        let material = Material {
            youngs_modulus,
            poisson: settings.sample.poisson,
        };
        model::coupled_problem(settings, cantilever, material, settings.drive.frequency)
    };
    // The node of an orbit: what the method reads off it.
    let node_of = |youngs_modulus: f64, orbit: &CoupledOrbit| -> Result<TableNode, String> {
        if orbit.max_force <= 0.0 {
            return Err(format!(
                "the tip does not touch the sample at E = {youngs_modulus:.4e} Pa (coupled \
                 engine)"
            ));
        }
        let samples = expected_samples(fitter, &orbit.force_coefficients, sigmas);
        let fitted = fitter.fit(&samples, false).map_err(|err| {
            format!("the fit to the coupled orbit at E = {youngs_modulus:.4e} Pa: {err}")
        })?;
        Ok(TableNode {
            youngs_modulus,
            force: fitted.force,
            tau: fitted.tau,
            pulse_force: orbit.max_force,
            pulse_tau: orbit.contact_time_ratio,
        })
    };
    // The start: the node nearest the set modulus.
    let target = settings.sample.youngs_modulus.log10();
    let start = (0..moduli.len())
        .min_by(|&a, &b| {
            (moduli[a].log10() - target)
                .abs()
                .total_cmp(&(moduli[b].log10() - target).abs())
        })
        .ok_or("the modulus table has no nodes")?;
    let e0 = moduli[start];
    let problem = problem_at(e0);
    let limits = SearchLimits {
        cancel,
        ..SearchLimits::default()
    };
    let (orbit, first) = seeded(e0)
        .ok_or(())
        .and_then(|c| problem.solve_continued(harmonics, c).map_err(drop))
        .or_else(|()| problem.solve_with(harmonics, limits))
        .map_err(|err| {
            if cancelled() {
                BUILD_CANCELLED.to_owned()
            } else {
                format!("the coupled orbit at the set modulus E = {e0:.4e} Pa for the modulus table: {err}")
            }
        })?;
    let first_node = node_of(e0, &orbit)?;
    // The harmonics whose predicted reading at the set modulus is under the noise floor.
    let quiet: Vec<u32> = sigmas
        .iter()
        .filter(|&&(k, sigma)| {
            let c = &orbit.force_coefficients;
            let read = fitter
                .model
                .read(k as usize, |j| c.get(j).copied().unwrap_or_default())
                .unwrap_or_default();
            k >= 2 && 2.0 * read.norm() < MIN_SNR * sigma
        })
        .map(|&(k, _)| k)
        .collect();
    // One chain of nodes from the start outwards; it ends where the orbit is lost.
    type Chain = (Vec<(TableNode, (f64, Continuation))>, Option<String>);
    let chain = |indices: Vec<usize>| -> Result<Chain, String> {
        let mut nodes = Vec::with_capacity(indices.len());
        let mut from = first.clone();
        for i in indices {
            if cancelled() {
                return Err(BUILD_CANCELLED.to_owned());
            }
            let youngs_modulus = moduli[i];
            let problem = problem_at(youngs_modulus);
            // From the chain's previous node (the same settings, a nearby modulus), else
            // from the seed's same node (the same modulus, earlier settings).
            let solved = problem
                .solve_continued(harmonics, &from)
                .or_else(|err| match seeded(youngs_modulus) {
                    Some(c) => problem.solve_continued(harmonics, c),
                    None => Err(err),
                })
                // Else afresh (a branch may end between two nodes), as the first node.
                .or_else(|_| problem.solve_with(harmonics, limits));
            let ended = match solved {
                Ok((orbit, next)) => match node_of(youngs_modulus, &orbit) {
                    Ok(node) => {
                        from = next.clone();
                        nodes.push((node, (youngs_modulus, next)));
                        continue;
                    }
                    Err(why) => why,
                },
                Err(_) if cancelled() => return Err(BUILD_CANCELLED.to_owned()),
                Err(err) => format!("the coupled orbit at E = {youngs_modulus:.4e} Pa: {err}"),
            };
            return Ok((nodes, Some(ended)));
        }
        Ok((nodes, None))
    };
    let (lower, upper) = std::thread::scope(|scope| {
        let upper = scope.spawn(|| chain((start + 1..moduli.len()).collect()));
        let lower = chain((0..start).rev().collect());
        (lower, upper.join())
    });
    let (upper, upper_end) =
        upper.map_err(|_| "the modulus table's thread panicked".to_owned())??;
    let (mut nodes, lower_end) = lower?;
    nodes.reverse();
    nodes.push((first_node, (e0, first)));
    nodes.extend(upper);
    let notes: Vec<String> = [lower_end, upper_end].into_iter().flatten().collect();
    let (nodes, orbits): (Vec<TableNode>, Vec<(f64, Continuation)>) = nodes.into_iter().unzip();
    let table = ModulusTable::from_nodes(&nodes, PulseMeasure::CoupledFit).map_err(|e| {
        format!(
            "{e} ({} of {} nodes; {})",
            nodes.len(),
            moduli.len(),
            notes.join("; ")
        )
    })?;
    let note = (!notes.is_empty()).then(|| {
        format!(
            "the modulus table covers {:.3e}–{:.3e} Pa only (of {:.0e}–{:.0e} Pa): {}",
            nodes[0].youngs_modulus,
            nodes[nodes.len() - 1].youngs_modulus,
            TABLE_RANGE.0,
            TABLE_RANGE.1,
            notes.join("; ")
        )
    });
    Ok(CoupledTable {
        table,
        orbits,
        note,
        quiet,
        set_coefficients: orbit.force_coefficients.clone(),
    })
}

/// The warning for the inversion's harmonics `pair` among the `quiet` ones (under the noise
/// floor at the set modulus), or `None`.
fn noise_floor_warning(quiet: &[u32], pair: (usize, usize), averaging: u32) -> Option<String> {
    let under: Vec<String> = [pair.0, pair.1]
        .iter()
        .filter(|&&k| quiet.contains(&(k as u32)))
        .map(|k| format!("H{k}"))
        .collect();
    (!under.is_empty()).then(|| {
        let (noun, verb) = if under.len() > 1 {
            ("harmonics", "are")
        } else {
            ("harmonic", "is")
        };
        format!(
            "the force estimate is noise-limited: the inversion's {noun} {} {verb} predicted \
             under the noise floor at the set modulus (below {MIN_SNR} σ of a live \
             estimate; {} of the demodulated harmonics ≥ 2 are): raise /inversion/averaging \
             (now {averaging}) or /drive/free_amplitude, or choose /inversion/harmonic_a and \
             _b among stronger harmonics",
            under.join(" and "),
            quiet.len()
        )
    })
}

/// What [`coupled_table`] builds.
struct CoupledTable {
    table: ModulusTable,
    /// (modulus, orbit) of every node, for the next build to start from.
    orbits: Vec<(f64, Continuation)>,
    /// Where the table ends short of [`TABLE_RANGE`], and why.
    note: Option<String>,
    /// The demodulated harmonics ≥ 2 whose predicted reading at the set modulus is below
    /// [`MIN_SNR`] × σ of a live estimate.
    quiet: Vec<u32>,
    /// The force's Fourier coefficients of the orbit at the node nearest the set modulus.
    set_coefficients: Vec<Complex64>,
}
