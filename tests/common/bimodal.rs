//! Bimodal AFM's mode-2 loops as the tests set them up: the second excitation's free
//! reading, the lever's f2, mode 2's PLL and its amplitude loop.

use std::f64::consts::PI;

use ftafm::config::{Oscillator, PidInput, PidTarget, Settings};
use rustfft::num_complex::Complex64;

use super::loops::pi_unit;

/// The photodiode's steady response to the second excitation alone at `frequency` (Hz)
/// with free amplitude `free` (m), as a demodulator on "drive2" reads it: the lever's
/// modes' analytic response, no synthesis.
pub fn second_reading(settings: &Settings, frequency: f64, free: f64) -> Complex64 {
    let mut s = settings.clone();
    s.drive2.frequency = frequency;
    s.drive2.free_amplitude = free;
    ftafm::synth::plan::free_reading_of(&s, Oscillator::Drive2).unwrap()
}

/// The lever's second resonance (Hz).
pub fn f2_of(settings: &Settings) -> f64 {
    ftafm::model::cantilever(settings).unwrap().modes[1].frequency
}

/// Mode 2's PLL in unit `index`: the phase of harmonic 1 of "drive2" held at `setpoint`,
/// PI gains for a crossover of `bandwidth` (Hz) on mode 2's phase response (−2Q2/f2 rad/Hz,
/// its pole at πf2/Q2 cancelled by the PI's zero), within ±1 % of f2.
pub fn mode_two_pll(s: &mut Settings, index: usize, setpoint: f64, bandwidth: f64) {
    let lever = ftafm::model::cantilever(s).unwrap();
    let (f2, q2) = (lever.modes[1].frequency, lever.modes[1].q);
    let route = (
        Oscillator::Drive2,
        PidInput::Phase,
        PidTarget::Drive2Frequency,
    );
    let plant = (bandwidth, -2.0 * q2 / f2, q2 / (PI * f2));
    pi_unit(s, index, route, setpoint, plant, (0.99 * f2, 1.01 * f2));
}

/// Mode 2's amplitude loop in unit `index`: the photodiode amplitude at harmonic 1 of
/// "drive2" held at `setpoint` (m) by the second excitation's free amplitude, PI gains for
/// a crossover of `bandwidth` (Hz) on the plant G0/(1 + sτ2), G0 = `gain` (m of photodiode
/// per m of free amplitude).
pub fn mode_two_amplitude(
    s: &mut Settings,
    index: usize,
    setpoint: f64,
    gain: f64,
    bandwidth: f64,
) {
    let lever = ftafm::model::cantilever(s).unwrap();
    let tau = lever.modes[1].q / (PI * lever.modes[1].frequency);
    let route = (Oscillator::Drive2, PidInput::R, PidTarget::Drive2Amplitude);
    pi_unit(
        s,
        index,
        route,
        setpoint,
        (bandwidth, gain, tau),
        (0.0, 20e-9),
    );
}
