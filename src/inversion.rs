//! Live FT-AFM force reconstruction from the lock-in outputs (`/inversion/...`, the `force`
//! stream): the maths of [`crate::physics::inversion`] applied to demodulator frames.
//!
//! Per estimate (every `/inversion/averaging` frames): the two harmonics' amplitudes give the
//! cut cosine's τ and F (the paper's method); with `"full"` every demodulated harmonic is
//! divided by the cantilever's transfer function and the force is rebuilt over one period
//! (Stark et al. 2002). The modulus follows from (F, τ) through a table of the 1-DOF Hertz
//! model built when the estimator is. Amplitude noise σ per harmonic is the scatter of the
//! recent frames, so the uncertainties reflect the lock-in noise actually present.

use std::f64::consts::PI;

use serde::Serialize;

use crate::config::{InversionMethod, Settings};
use crate::model;
use crate::physics::Cantilever;
use crate::physics::inversion::{
    AmplitudeMeasurement, HarmonicSample, InversionOptions, ModulusTable, PulseMeasure, TableRange,
    fit_two_harmonics, reconstruct_force,
};
use crate::pipeline::DemodFrame;
use rustfft::num_complex::Complex64;

/// Frames over which the amplitude scatter (σ) is estimated (exponential memory).
const NOISE_MEMORY: f64 = 50.0;
/// Range of the modulus table (Pa) and its nodes.
const TABLE_RANGE: (f64, f64) = (1e9, 1e12);
const TABLE_POINTS: usize = 64;

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
    /// Young's modulus of the sample (Pa) and its standard deviation.
    pub youngs_modulus: f64,
    pub youngs_modulus_sigma: f64,
    /// "inside", "below_table" or "above_table".
    pub table_range: TableRange,
    /// Drive phase (rad) of the force peak.
    pub pulse_phase: f64,
    /// The force over one period at equally spaced drive phases from 0 (N).
    pub waveform: Vec<f64>,
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

/// Builds estimates from demodulator frames. Construct it off any latency-sensitive path:
/// the modulus table takes about 0.1 s.
pub struct ForceEstimator {
    cantilever: Cantilever,
    drive_frequency: f64,
    method: InversionMethod,
    pair: (usize, usize),
    averaging: usize,
    points: usize,
    /// F(E) and τ(E) of the 1-DOF pulse. With the paper engine the tap force *is* the cut
    /// cosine of the 1-DOF (F, τ), so both methods measure exactly these. (A coupled
    /// engine's Hertz pulse would call for a table of what the two-harmonic fit reads off a
    /// real pulse: `PulseMeasure::TwoHarmonic`.)
    table: ModulusTable,
    /// Running sums of X and Y per demodulator for averaging.
    sum: Vec<Complex64>,
    summed: usize,
    /// Exponentially weighted mean and variance of X and Y per demodulator.
    mean: Vec<Complex64>,
    variance: Vec<f64>,
    seen: usize,
}

impl ForceEstimator {
    /// The estimator for `settings`; `None` when `/inversion/enable` is false.
    pub fn new(settings: &Settings) -> Result<Option<Self>, String> {
        let inv = &settings.inversion;
        if !inv.enable {
            return Ok(None);
        }
        let cantilever = model::cantilever(settings).map_err(|e| e.to_string())?;
        let oscillator = model::impact_oscillator(settings, &cantilever, settings.sample);
        let pair = (
            inv.harmonic_a.min(inv.harmonic_b) as usize,
            inv.harmonic_a.max(inv.harmonic_b) as usize,
        );
        let tip = model::elastic(settings.tip);
        let table = ModulusTable::with_measure(
            &oscillator,
            tip,
            settings.sample.poisson,
            TABLE_RANGE,
            TABLE_POINTS,
            PulseMeasure::Shape,
        )
        .map_err(|e| e.to_string())?;
        let n = settings.demods.len();
        Ok(Some(Self {
            cantilever,
            drive_frequency: settings.drive.frequency,
            method: inv.method,
            pair,
            averaging: inv.averaging.max(1) as usize,
            points: inv.points as usize,
            table,
            sum: vec![Complex64::new(0.0, 0.0); n],
            summed: 0,
            mean: vec![Complex64::new(0.0, 0.0); n],
            variance: vec![0.0; n],
            seen: 0,
        }))
    }

    /// Takes one demodulator frame; every `averaging` frames returns an estimate.
    pub fn push(&mut self, frame: &DemodFrame) -> Option<Result<ForceEstimate, EstimateError>> {
        let alpha = 1.0 / NOISE_MEMORY.min(self.seen as f64 + 1.0);
        for v in frame.values() {
            let i = v.index as usize;
            if i >= self.sum.len() {
                continue;
            }
            let z = Complex64::new(v.x, v.y);
            self.sum[i] += z;
            // Welford-style exponential update of the scatter of X + iY about its mean.
            let d = z - self.mean[i];
            self.mean[i] += d * alpha;
            self.variance[i] = (1.0 - alpha) * (self.variance[i] + alpha * d.norm_sqr());
        }
        self.seen += 1;
        self.summed += 1;
        if self.summed < self.averaging {
            return None;
        }
        let averaged: Vec<(u32, Complex64, f64)> = frame
            .values()
            .iter()
            .filter(|v| (v.index as usize) < self.sum.len())
            .map(|v| {
                let i = v.index as usize;
                // σ of one component of the average: the per-frame scatter of X + iY is
                // 2σ² for σ per component, and averaging n frames divides it by n.
                let sigma = (self.variance[i] / 2.0 / self.summed as f64).sqrt();
                (v.harmonic, self.sum[i] / self.summed as f64, sigma)
            })
            .collect();
        for s in &mut self.sum {
            *s = Complex64::new(0.0, 0.0);
        }
        self.summed = 0;
        Some(self.estimate(frame, &averaged))
    }

    fn estimate(
        &self,
        frame: &DemodFrame,
        harmonics: &[(u32, Complex64, f64)],
    ) -> Result<ForceEstimate, EstimateError> {
        let find = |k: usize| {
            harmonics
                .iter()
                .find(|(h, _, _)| *h as usize == k)
                .ok_or(EstimateError::MissingHarmonic(k))
        };
        let measurement = |k: usize| -> Result<AmplitudeMeasurement, EstimateError> {
            let (_, z, sigma) = find(k)?;
            Ok(AmplitudeMeasurement {
                harmonic: k,
                amplitude: z.norm(),
                sigma: *sigma,
            })
        };
        let maths = |e: &dyn std::fmt::Display| EstimateError::Maths(e.to_string());
        let fit = fit_two_harmonics(
            &self.cantilever,
            self.drive_frequency,
            measurement(self.pair.0)?,
            measurement(self.pair.1)?,
        )
        .map_err(|e| maths(&e))?;
        // The lock-in reads X + iY = 2·S_k; the inversion takes two-sided S_k.
        let samples: Vec<HarmonicSample> = harmonics
            .iter()
            .filter(|(h, _, _)| *h >= 2)
            .map(|(h, z, sigma)| HarmonicSample {
                harmonic: *h as usize,
                value: z / 2.0,
                sigma: sigma / 2.0,
            })
            .collect();
        let options = InversionOptions {
            pair: Some(self.pair),
            grid_points: self.points,
            ..InversionOptions::default()
        };
        let reconstruction =
            reconstruct_force(&self.cantilever, self.drive_frequency, &samples, &options)
                .map_err(|e| maths(&e))?;
        let (method, tau, sigma_tau, force, sigma_force, modulus) = match self.method {
            InversionMethod::Full => {
                // σ of τ from the reconstruction is not propagated; the two-harmonic fit's
                // is the conservative stand-in (the full series adds harmonics, not noise).
                let sigma_f = reconstruction.force_sigma;
                let e = self
                    .table
                    .estimate(
                        reconstruction.peak_force,
                        reconstruction.contact_time_ratio,
                        sigma_f,
                        fit.sigma_tau,
                    )
                    .map_err(|e| maths(&e))?;
                (
                    "full",
                    reconstruction.contact_time_ratio,
                    fit.sigma_tau,
                    reconstruction.peak_force,
                    sigma_f,
                    e,
                )
            }
            InversionMethod::TwoHarmonic => {
                let e = self
                    .table
                    .estimate_with_covariance(fit.max_force, fit.tau, fit.force_tau_covariance())
                    .map_err(|e| maths(&e))?;
                (
                    "two_harmonic",
                    fit.tau,
                    fit.sigma_tau,
                    fit.max_force,
                    fit.sigma_force,
                    e,
                )
            }
        };
        Ok(ForceEstimate {
            sample_index: frame.sample_index,
            t: frame.t,
            t_synth_ns: frame.t_synth_ns,
            method,
            contact_time_ratio: tau,
            contact_time_ratio_sigma: sigma_tau,
            max_force: force,
            max_force_sigma: sigma_force,
            youngs_modulus: modulus.youngs_modulus,
            youngs_modulus_sigma: modulus.uncertainty,
            table_range: modulus.range,
            pulse_phase: reconstruction.pulse_phase.rem_euclid(2.0 * PI),
            waveform: reconstruction.force,
        })
    }
}
