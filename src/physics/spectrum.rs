//! Force spectra and the photodiode signal in the frequency domain (Eq. 4–9, 20–21).
//!
//! Convention: a periodic quantity q(t) = Σ_k c_k e^{ikΩt} (two-sided, Eq. 5) has peak
//! amplitude 2|c_k| at harmonic k ≥ 1 and mean c_0. Phases are relative to cos(kΩt), where
//! Ωt is the drive phase (the base moves as A_d·sin Ωt).

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::beam::Cantilever;

/// Fourier coefficient c_k (N) of the cut cosine h(t) = F·cos(πt/(τT)) for |t| < τT/2 and
/// zero elsewhere in the period (Eq. 20–21): (2Fτ/π)·cos(πτk)/(1 − 4τ²k²), with its finite
/// limit Fτ/2 at 2τk = 1.
pub fn cut_cosine_coefficient(max_force: f64, tau: f64, k: usize) -> f64 {
    let u = 2.0 * tau * k as f64;
    let eps = u - 1.0;
    // cos(πu/2)/(1 − u²) is smooth at u = 1; near it use the series
    // (π/2)·(1 − π²ε²/24)/(2 + ε), accurate to O(ε⁴) there.
    let shape = if eps.abs() < 1e-4 {
        (PI / 2.0) * (1.0 - PI * PI * eps * eps / 24.0) / (2.0 + eps)
    } else {
        (PI * u / 2.0).cos() / (1.0 - u * u)
    };
    2.0 * max_force * tau / PI * shape
}

/// Two-sided coefficients c_k (N), k = 0..=kmax, of a cut-cosine pulse train whose pulses
/// are centred at drive phase `pulse_phase` (rad): c_k = c_k^h·e^{−ik·pulse_phase}.
pub fn cut_cosine_train(max_force: f64, tau: f64, pulse_phase: f64, kmax: usize) -> Vec<Complex64> {
    (0..=kmax)
        .map(|k| {
            cut_cosine_coefficient(max_force, tau, k)
                * Complex64::from_polar(1.0, -(k as f64) * pulse_phase)
        })
        .collect()
}

/// Light-lever transfer (m/N) from a tip force at angular frequency `omega` (rad/s) to the
/// photodiode signal in nominal metres (Eq. 9 with φn(L) forcing, physics.md §2):
/// (2/3)·Σn L·φn′(L)·φn(L)·Hn/Kn. Tends to 1/k at ω → 0 for many modes.
pub fn photodiode_transfer(cantilever: &Cantilever, omega: f64) -> Complex64 {
    cantilever
        .modes
        .iter()
        .map(|m| m.transfer(omega) * (2.0 / 3.0 * m.tip_slope * m.tip_value / m.stiffness))
        .sum()
}

/// Tip-deflection transfer (m/N) from a tip force at `omega` (rad/s): Σn φn(L)²·Hn/Kn.
pub fn tip_transfer(cantilever: &Cantilever, omega: f64) -> Complex64 {
    cantilever
        .modes
        .iter()
        .map(|m| m.transfer(omega) * (m.tip_value * m.tip_value / m.stiffness))
        .sum()
}

/// One harmonic of a periodic signal.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Harmonic {
    /// Harmonic number k of the drive.
    pub harmonic: usize,
    /// Peak amplitude (the signal's unit): 2|c_k| for k ≥ 1, |c_0| for the mean.
    pub amplitude: f64,
    /// Phase (rad) relative to cos(kΩt).
    pub phase: f64,
}

impl Harmonic {
    /// The harmonic with two-sided coefficient `c` (signal unit).
    pub fn from_coefficient(harmonic: usize, c: Complex64) -> Self {
        let scale = if harmonic == 0 { 1.0 } else { 2.0 };
        Self {
            harmonic,
            amplitude: scale * c.norm(),
            phase: c.arg(),
        }
    }
}

/// Photodiode spectrum (m, nominal) of the tap force with two-sided coefficients
/// `force` (N, index = harmonic) at drive frequency `drive_frequency` (Hz), Eq. (9).
pub fn photodiode_spectrum(
    cantilever: &Cantilever,
    drive_frequency: f64,
    force: &[Complex64],
) -> Vec<Harmonic> {
    let omega = 2.0 * PI * drive_frequency;
    force
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            Harmonic::from_coefficient(k, photodiode_transfer(cantilever, k as f64 * omega) * c)
        })
        .collect()
}

/// Relative contrast 1 − S_a/S_b of the amplitudes, harmonic by harmonic (signed; NaN where
/// S_b is zero).
pub fn relative_contrast(a: &[Harmonic], b: &[Harmonic]) -> Vec<f64> {
    a.iter()
        .zip(b)
        .map(|(a, b)| 1.0 - a.amplitude / b.amplitude)
        .collect()
}
