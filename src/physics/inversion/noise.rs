//! How much noise each lock-in output carries: the photodiode's noise density (thermal
//! motion of every mode through the light lever, detector, quantisation) and the lock-in
//! low-pass's equivalent noise bandwidth, including the correlation of successive outputs.
//!
//! A lock-in output at harmonic k ≥ 1 is X + iY = 2·LP[s·e^{−ikθ}]. For noise of one-sided
//! density G (m²/Hz) that is flat across the filter's band around kf, X and Y are
//! independent with variance 2·G·B each, B = ∫₀^∞|H(f)|² df the filter's one-sided
//! equivalent noise bandwidth (for a boxcar average over T seconds, B = 1/(2T)); the
//! two-sided coefficient S_k = (X + iY)/2 then has σ = √(G·B/2) per quadrature.

use std::f64::consts::PI;

use crate::physics::beam::Cantilever;

/// Boltzmann's constant (J/K), exact in the SI.
pub const BOLTZMANN: f64 = 1.380_649e-23;

/// Folds about multiples of the sample rate summed in the thermal density.
const FOLDS: usize = 8;

/// The photodiode's noise sources.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseModel {
    /// Temperature of the cantilever (K); 0: no thermal noise.
    pub temperature: f64,
    /// One-sided white detector noise density (m/√Hz); 0: none.
    pub detector_density: f64,
    /// ADC step (m); 0: no quantisation.
    pub adc_lsb: f64,
    /// Sample rate (Hz): the thermal spectrum folds about its multiples and the
    /// quantisation noise LSB²/12 spreads over 0…f_s/2. `None`: continuous time (no
    /// folding, no quantisation noise).
    pub sample_rate: Option<f64>,
}

impl NoiseModel {
    /// No noise at all.
    pub const NONE: Self = Self {
        temperature: 0.0,
        detector_density: 0.0,
        adc_lsb: 0.0,
        sample_rate: None,
    };

    /// One-sided density (m²/Hz) of the photodiode noise at `frequency` (Hz):
    ///
    /// - thermal, by fluctuation–dissipation for each mode n independently: the modal
    ///   coordinate has G_Y = 4k_BT·2γn/(Kn·ωn)·|Hn(ω)|² (which integrates to k_BT/Kn, the
    ///   equipartition value), seen through the light lever's (2/3)·Lφn′(L); with a sample
    ///   rate, summed over the frequencies that fold onto this one;
    /// - detector: white, `detector_density`²;
    /// - quantisation: LSB²/12 spread evenly over 0…f_s/2, i.e. LSB²/(6f_s) (the thermal
    ///   motion of mode 1, several LSB, dithers it).
    pub fn density(&self, cantilever: &Cantilever, frequency: f64) -> f64 {
        let mut total = self.detector_density * self.detector_density;
        if let Some(fs) = self.sample_rate
            && self.adc_lsb > 0.0
        {
            total += self.adc_lsb * self.adc_lsb / (6.0 * fs);
        }
        if self.temperature > 0.0 {
            let thermal = |f: f64| -> f64 {
                cantilever
                    .modes
                    .iter()
                    .map(|m| {
                        let gain = 2.0 / 3.0 * m.tip_slope;
                        gain * gain * 4.0 * BOLTZMANN * self.temperature * 2.0 * m.gamma
                            / (m.stiffness * m.omega)
                            * m.transfer(2.0 * PI * f).norm_sqr()
                    })
                    .sum()
            };
            total += match self.sample_rate {
                None => thermal(frequency.abs()),
                Some(fs) => {
                    // The frequencies m·f_s ± f (≥ 0) that sample to ±f.
                    let f = frequency.abs().rem_euclid(fs);
                    (0..=FOLDS)
                        .map(|m| {
                            let base = m as f64 * fs;
                            thermal(base + f) + thermal(base + fs - f)
                        })
                        .sum()
                }
            };
        }
        total
    }
}

/// Standard deviation (m) of each of X and Y of a lock-in output at a harmonic k ≥ 1, for
/// noise of one-sided density `density` (m²/Hz) around kf and a filter of one-sided
/// equivalent noise bandwidth `bandwidth` (Hz): √(2·G·B).
pub fn lockin_sigma(density: f64, bandwidth: f64) -> f64 {
    (2.0 * density * bandwidth).sqrt()
}

/// The lock-in's low-pass as far as noise goes: `order` identical first-order sections of
/// time constant `time_constant` (s), h(t) = t^{n−1}e^{−t/τ}/((n−1)!τⁿ).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LowPassNoise {
    /// Number of sections n ≥ 1.
    pub order: u32,
    /// Time constant τ of each section (s).
    pub time_constant: f64,
}

fn factorial(n: u32) -> f64 {
    (1..=n).map(f64::from).product()
}

impl LowPassNoise {
    /// One-sided equivalent noise bandwidth (Hz): ∫₀^∞|H|² df = ½∫h² dt =
    /// (2n−2)!/((n−1)!²·2²ⁿ·τ). Order 4 with τ = 0.5 ms: 156.25 Hz.
    pub fn bandwidth(&self) -> f64 {
        let n = self.order.max(1);
        factorial(2 * n - 2)
            / (factorial(n - 1).powi(2) * 2f64.powi(2 * n as i32) * self.time_constant)
    }

    /// Correlation coefficient of the output noise `lag` seconds apart (white input):
    /// ∫h(t)h(t+s)dt / ∫h² = e^{−u}·Σ_{m<n} C(n−1, m)·(n−1+m)!/(2n−2)!·(2u)^{n−1−m},
    /// u = |lag|/τ.
    pub fn correlation(&self, lag: f64) -> f64 {
        let n = self.order.max(1);
        let u = lag.abs() / self.time_constant;
        let norm = factorial(2 * n - 2);
        let sum: f64 = (0..n)
            .map(|m| {
                let binomial = factorial(n - 1) / (factorial(m) * factorial(n - 1 - m));
                binomial * factorial(n - 1 + m) / norm * (2.0 * u).powi((n - 1 - m) as i32)
            })
            .sum();
        (-u).exp() * sum
    }

    /// Equivalent noise bandwidth (Hz) of the mean of `frames` successive outputs spaced
    /// `period` seconds: B/N·[1 + 2Σ_{l<N}(1 − l/N)·ρ(l·period)]. Successive outputs of
    /// the default bank (1 ms apart, order 4, τ = 0.5 ms) are correlated by 0.69, so the
    /// mean of N of them has about 3.2/N of one output's variance, not 1/N.
    pub fn averaged_bandwidth(&self, frames: usize, period: f64) -> f64 {
        let n = frames.max(1);
        let mut sum = 1.0;
        for l in 1..n {
            let rho = self.correlation(l as f64 * period);
            if rho < 1e-15 {
                break;
            }
            sum += 2.0 * (1.0 - l as f64 / n as f64) * rho;
        }
        self.bandwidth() * sum / n as f64
    }
}
