//! What the live PID units need, built off the real-time thread from the settings
//! ([`PidPlan`]): each enabled unit's controller, already validated, its input and the
//! harmonic its demodulator reads, and the drive phase at which the loops update. The
//! synthesiser's side (the demodulators, the controllers' state, the output moving the
//! surface) is [`super::pids`]'s.

use std::f64::consts::TAU;

use crate::config::{Oscillator, PID_COUNT, PidInput, PidTarget, Settings};
use crate::control::{Pid, PidError};
use crate::model;
use crate::timebase::TWO_POW_64;

/// One enabled unit: `/pids/N/*` as the synthesiser runs it.
#[derive(Clone, Debug)]
pub struct PidUnitPlan {
    /// The controller at its settings, enabled, its output at its centre: the runtime
    /// copies it when the unit starts and takes its gains when they change.
    pub pid: Pid,
    /// The part of the demodulator's reading it regulates.
    pub input: PidInput,
    /// Harmonic k of the oscillator its demodulator reads.
    pub harmonic: u32,
    /// The oscillator: on `Drive` its demodulator is a boxcar of one drive period, on
    /// `Drive2` a low-pass of [`LOW_PASS_SECTIONS`] sections of coefficient `alpha`.
    pub oscillator: Oscillator,
    /// Each low-pass section's y += α(x − y) per sample, for `/pids/N/input_bandwidth`
    /// ([`low_pass_alpha`]); unused on `Drive`.
    pub alpha: f64,
    /// What it drives.
    pub output: PidTarget,
}

/// First-order sections of a unit's low-pass on the second excitation: four, as a
/// lock-in's demodulator of a PLL is usually set (LabOne's default order).
pub const LOW_PASS_SECTIONS: usize = 4;

/// The section coefficient α = 1 − e^{−2π f_c/f_s} of a low-pass of
/// [`LOW_PASS_SECTIONS`] equal sections whose whole −3 dB bandwidth is `bandwidth` (Hz) at
/// `sample_rate` f_s (Hz): each section's corner f_c = B/√(2^{1/n} − 1).
pub fn low_pass_alpha(bandwidth: f64, sample_rate: f64) -> f64 {
    let corner = bandwidth / (2f64.powf(1.0 / LOW_PASS_SECTIONS as f64) - 1.0).sqrt();
    1.0 - (-TAU * corner / sample_rate).exp()
}

/// The PID units of a plan.
#[derive(Clone, Debug, Default)]
pub struct PidPlan {
    /// Unit N at index N, `None` where `/pids/N/enable` is false.
    pub units: [Option<PidUnitPlan>; PID_COUNT],
    /// `/surface/distance` (m): the surface distance while no loop holds it.
    pub surface_distance: f64,
    /// Drive phase word at which the loops update: where the free tip is highest, half a
    /// period from the tap, so that a move of the surface never cuts a contact.
    pub update_phase: u64,
    /// `/drive/free_amplitude` (m): a unit on `drive_amplitude` drives the excitation in
    /// these terms, the free amplitude it gives at `/drive/frequency`.
    pub free_amplitude: f64,
    /// `/drive2/free_amplitude` (m), alike for `drive2_amplitude`.
    pub free_amplitude2: f64,
    /// The base amplitude per metre of that free amplitude (1).
    pub base_per_free: f64,
    /// The same of the second excitation at `/drive2/frequency` (1), where it drives;
    /// `None` where it does not (the settings then allow no unit on it).
    pub base_per_free2: Option<f64>,
}

impl PidPlan {
    /// The units of `settings`; `free_tip` is the coupled engine's free tip motion
    /// (z⁰ = Re[free_tip·e^{iθ}], m) that places the update phase, `None` on the paper
    /// engine (where the settings checks allow no enabled unit), and `base_amplitude` the
    /// drive's base amplitude (m) at `/drive/free_amplitude`, `base_amplitude2` the second
    /// excitation's at `/drive2/free_amplitude` where it drives. A unit whose settings the
    /// controller refuses is refused here too (`model::check_pids` refuses them first).
    pub fn new(
        settings: &Settings,
        free_tip: Option<rustfft::num_complex::Complex64>,
        base_amplitude: f64,
        base_amplitude2: Option<f64>,
    ) -> Result<Self, PidError> {
        let mut units: [Option<PidUnitPlan>; PID_COUNT] = Default::default();
        for (index, unit) in settings.pids.iter().enumerate().take(PID_COUNT) {
            if !unit.enable {
                continue;
            }
            let Some(pid_settings) = model::pid_settings(settings, index) else {
                continue;
            };
            units[index] = Some(PidUnitPlan {
                pid: Pid::new(pid_settings)?,
                input: unit.input,
                // The mean deflection is the boxcar's DC: its harmonic 0.
                harmonic: if unit.input == PidInput::MeanDeflection {
                    0
                } else {
                    unit.harmonic
                },
                oscillator: unit.oscillator,
                alpha: low_pass_alpha(unit.input_bandwidth, settings.synth.sample_rate),
                output: unit.output,
            });
        }
        Ok(Self {
            units,
            surface_distance: settings.surface.distance,
            update_phase: free_tip.map_or(0, highest_phase),
            free_amplitude: settings.drive.free_amplitude,
            free_amplitude2: settings.drive2.free_amplitude,
            base_per_free: base_amplitude / settings.drive.free_amplitude,
            base_per_free2: base_amplitude2.map(|b| b / settings.drive2.free_amplitude),
        })
    }

    /// Whether any unit is enabled.
    pub fn any_enabled(&self) -> bool {
        self.units.iter().any(Option::is_some)
    }
}

/// The drive phase word where the free tip z⁰ = Re[free_tip·e^{iθ}] (m) is highest:
/// θ = −arg(free_tip).
pub(crate) fn highest_phase(free_tip: rustfft::num_complex::Complex64) -> u64 {
    ((-free_tip.arg() / TAU).rem_euclid(1.0) * TWO_POW_64) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four sections of the coefficient give −3 dB at the bandwidth asked for: the
    /// discrete sections' gain |α/(1 − (1 − α)e^{−iωh})|⁴ there is 1/√2.
    #[test]
    fn the_low_pass_has_its_bandwidth() {
        for (bandwidth, rate) in [(2e3, 1e7), (100.0, 1e7), (20e3, 2.5e7)] {
            let alpha = low_pass_alpha(bandwidth, rate);
            let w = TAU * bandwidth / rate;
            let z = rustfft::num_complex::Complex64::from_polar(1.0, -w);
            let section = alpha / (1.0 - (1.0 - alpha) * z).norm();
            let gain = section.powi(LOW_PASS_SECTIONS as i32);
            assert!(
                (gain - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-3,
                "{bandwidth} Hz at {rate} S/s: gain {gain}"
            );
        }
    }
}
