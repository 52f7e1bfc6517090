//! The drive as the per-sample loop takes it: the phase step per sample and the steady
//! response of every mode and of the photodiode to the base excitation u = U·sin θ.
//!
//! A plan builds its drive from `/drive/frequency` and `/drive/free_amplitude`; the PID units
//! that drive the excitation's frequency (a PLL) or amplitude build another on the real-time
//! thread once per drive period ([`Drive::new`] allocates nothing), and the modes' states are
//! re-based onto it ([`super::SynthState::redrive`]) so the motion stays continuous.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use crate::config::Oscillator;
use crate::physics::beam::{Cantilever, MAX_MODES, Mode};
use crate::timebase::TWO_POW_64;

/// The drive: its phase step and steady responses (all amplitudes peak, phases against
/// the drive phase θ, 0 at the cosine's peak).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drive {
    /// Drive phase words per sample (2^64 = one period).
    pub word: u64,
    /// Realised drive frequency f_s·word/2^64 (Hz).
    pub frequency: f64,
    /// Base (dither piezo) amplitude U (m): u = U·sin θ, whose acceleration G·sin θ with
    /// G = U·Ω² drives every mode.
    pub base_amplitude: f64,
    /// Steady response of each mode, Y_n = Re[Ŷ_n·e^{iθ}] (m); zero past the lever's modes.
    pub response: [Complex64; MAX_MODES],
    /// Steady response of the photodiode, Re[Ŝ·e^{iθ}] (nominal m).
    pub signal: Complex64,
    /// The photodiode's response through the ADC's window ([`super::window`]) at a grid
    /// sample, Ŝ·W(Ω); and half a sample on, Ŝ·W(Ω)·e^{iΩh/2}.
    pub grid: Complex64,
    pub mid: Complex64,
}

impl Drive {
    /// The drive at phase step `word` with the base amplitude that gives the free tip the
    /// amplitude `free_amplitude` (m, peak) at that frequency: what `/drive/*` configure.
    pub fn with_free_amplitude(
        cantilever: &Cantilever,
        sample_rate: f64,
        word: u64,
        free_amplitude: f64,
    ) -> Self {
        let omega = omega_of(word, sample_rate);
        let unit = unit_response(cantilever, omega);
        let tip: Complex64 = cantilever
            .modes
            .iter()
            .zip(&unit)
            .map(|(m, u)| u * m.tip_value)
            .sum();
        let gain = free_amplitude / tip.norm();
        Self::from_unit(cantilever, sample_rate, word, &unit, gain)
    }

    /// The drive at phase step `word` with base amplitude `base_amplitude` (m): what a PLL
    /// or an amplitude loop sets. Allocation-free, so the real-time thread may call it.
    pub fn new(cantilever: &Cantilever, sample_rate: f64, word: u64, base_amplitude: f64) -> Self {
        let omega = omega_of(word, sample_rate);
        let unit = unit_response(cantilever, omega);
        Self::from_unit(
            cantilever,
            sample_rate,
            word,
            &unit,
            base_amplitude * omega * omega,
        )
    }

    /// The drive from each mode's response per unit base acceleration `unit` and the base
    /// acceleration `gain` G (m/s²).
    fn from_unit(
        cantilever: &Cantilever,
        sample_rate: f64,
        word: u64,
        unit: &[Complex64; MAX_MODES],
        gain: f64,
    ) -> Self {
        let frequency = word as f64 / TWO_POW_64 * sample_rate;
        let omega = 2.0 * PI * frequency;
        let response = unit.map(|u| u * gain);
        let signal: Complex64 = cantilever
            .modes
            .iter()
            .zip(&response)
            .map(|(m, y)| y * (2.0 / 3.0 * m.tip_slope))
            .sum();
        let grid = signal * super::window::gain(frequency / sample_rate);
        Self {
            word,
            frequency,
            // The modes' drive is the base acceleration G·sin θ = −ü, so U = G/Ω².
            base_amplitude: gain / (omega * omega),
            response,
            signal,
            grid,
            mid: grid * Complex64::from_polar(1.0, 0.5 * word as f64 / TWO_POW_64 * 2.0 * PI),
        }
    }

    /// Angular frequency Ω (rad/s).
    pub fn omega(&self) -> f64 {
        2.0 * PI * self.frequency
    }

    /// Mode `m`'s steady displacement (m) and velocity (m/s) at drive phasor `rho` = e^{iθ}.
    #[inline]
    pub fn particular(&self, m: usize, rho: Complex64) -> (f64, f64) {
        let y = self.response[m] * rho;
        (y.re, (y * Complex64::new(0.0, self.omega())).re)
    }

    /// The free tip position z⁰ = Re[free_tip·e^{iθ}] (m): the base plus every mode's
    /// steady deflection at the tip.
    pub fn free_tip(&self, modes: &[Mode]) -> Complex64 {
        // u = U sin θ = Re[−iU e^{iθ}].
        let mut free_tip = Complex64::new(0.0, -self.base_amplitude);
        for (mode, y) in modes.iter().zip(&self.response) {
            free_tip += y * mode.tip_value;
        }
        free_tip
    }
}

/// Ω (rad/s) of phase step `word` at `sample_rate` (Hz).
fn omega_of(word: u64, sample_rate: f64) -> f64 {
    2.0 * PI * (word as f64 / TWO_POW_64 * sample_rate)
}

/// Each mode's steady response at `omega` (rad/s) per unit base acceleration (m per m/s²):
/// a uniform inertial load G·Pn·sin θ on mode n (Pn = ∫φn dξ).
fn unit_response(cantilever: &Cantilever, omega: f64) -> [Complex64; MAX_MODES] {
    let mut unit = [Complex64::new(0.0, 0.0); MAX_MODES];
    for (u, m) in unit.iter_mut().zip(&cantilever.modes) {
        *u = Complex64::new(0.0, -m.participation) * m.transfer(omega) / (m.omega * m.omega);
    }
    unit
}

/// A change of the lock-in's reference of one oscillator: from output sample `index` on,
/// the reference is at phase `phase` (2^64 = one period) and steps `word` per sample. A
/// loop that moves the oscillator's frequency at sample i makes one at i + ⌈D⌉ (D the ADC
/// filter's delay, 21.5 samples; 0 without it), where the samples taken under the new
/// frequency begin.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReferenceChange {
    /// The oscillator whose reference changes: `/drive`'s or the second excitation's.
    pub oscillator: Oscillator,
    /// Index of the first output sample of the new reference.
    pub index: u64,
    /// The drive phase at which that sample was taken.
    pub phase: u64,
    /// Drive phase words per sample from there on.
    pub word: u64,
}
