//! What the live PID units need, built off the real-time thread from the settings
//! ([`PidPlan`]): each enabled unit's controller, already validated, its input and the
//! harmonic its demodulator reads, and the drive phase at which the loops update. The
//! synthesiser's side (the demodulators, the controllers' state, the output moving the
//! surface) is [`super::pids`]'s.

use std::f64::consts::TAU;

use crate::config::{PID_COUNT, PidInput, PidTarget, Settings};
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
    /// Harmonic k of the drive its demodulator reads.
    pub harmonic: u32,
    /// What it drives.
    pub output: PidTarget,
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
    /// The base amplitude per metre of that free amplitude (1).
    pub base_per_free: f64,
}

impl PidPlan {
    /// The units of `settings`; `free_tip` is the coupled engine's free tip motion
    /// (z⁰ = Re[free_tip·e^{iθ}], m) that places the update phase, `None` on the paper
    /// engine (where the settings checks allow no enabled unit), and `base_amplitude` the
    /// drive's base amplitude (m) at `/drive/free_amplitude`. A unit whose settings the
    /// controller refuses is refused here too (`model::check_pids` refuses them first).
    pub fn new(
        settings: &Settings,
        free_tip: Option<rustfft::num_complex::Complex64>,
        base_amplitude: f64,
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
                harmonic: unit.harmonic,
                output: unit.output,
            });
        }
        Ok(Self {
            units,
            surface_distance: settings.surface.distance,
            update_phase: free_tip.map_or(0, highest_phase),
            free_amplitude: settings.drive.free_amplitude,
            base_per_free: base_amplitude / settings.drive.free_amplitude,
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
