//! The loop a live PID unit (`/pids/N`) closes, as the advisor models it: the plant for
//! its input and output at the settings in force and its demodulator, for op `pid_advise`
//! (docs/loops.md, "The PID advisor") and for the tests that hold the live loops to it.
//!
//! Modelled loops:
//! - a PLL: input `phase` on harmonic 1, output `drive_frequency`. The plant is the driven
//!   lever's phase, slope 2Q/f1 rad/Hz through τ_c = Q/(π·f1) ([`Plant::resonator`]); the
//!   lever's phase falls as the frequency rises, so the gains come back negated;
//! - an amplitude loop on the drive: input `r` on harmonic 1, output `drive_amplitude`. The
//!   plant is the free lever's photodiode amplitude per metre of drive amplitude, through the
//!   envelope's τ_c ([`Plant::amplitude`]); the surface out of reach (a tapping lever's
//!   amplitude answers its drive far less);
//! - contact mode's deflection loop: input `mean_deflection`, output `surface_distance`. The
//!   plant is the lever pressed on the sample in static balance ([`deflection_plant`]): its
//!   deflection falls as the surface recedes, at once on the loop's time scale
//!   ([`Plant::quasi_static`]), so the gains come back negated.
//!
//! All behind the units' own demodulator ([`Demodulator::pid_unit`]): no filter, one update
//! per drive period, a period and the ADC filter's delay of dead time. The PLL and the
//! amplitude loop on the second excitation (oscillator `drive2`, outputs `drive2_frequency`
//! and `drive2_amplitude`: bimodal AFM's mode-2 loops) take mode 2's Q and f2, behind the
//! unit's low-pass of four sections at `/pids/N/input_bandwidth` ([`Demodulator::new`] run
//! per sample) read once per drive period.

use crate::config::{Oscillator, PidInput, PidTarget, Settings};
use crate::control::loop_model::ADC_DELAY_SAMPLES;
use crate::control::{Demodulator, LoopModel, Plant};
use crate::physics::beam::Cantilever;

/// A unit's loop as the advisor models it.
#[derive(Clone, Debug)]
pub struct UnitLoop {
    /// The plant and the unit's demodulator.
    pub model: LoopModel,
    /// The sign the unit's actuator takes the advice's gains with: −1 where its input falls
    /// as its output rises (a PLL, the deflection loop).
    pub sign: f64,
    /// The plant in words, with its numbers.
    pub plant: String,
}

/// The loop of `/pids/{unit}` at `settings`, or why the advisor has no model of it (the
/// message names the unit's nodes and what is modelled).
pub fn unit_loop(settings: &Settings, unit: usize) -> Result<UnitLoop, String> {
    let u = &settings.pids[unit];
    let unsupported = || {
        format!(
            "/pids/{unit} reads \"{}\" on harmonic {} of \"{}\" and drives \"{}\", which op \
             \"pid_advise\" does not model: it advises a PLL (/pids/{unit}/input = \
             \"phase\", harmonic 1, output \"drive_frequency\", or on oscillator \
             \"drive2\" \"drive2_frequency\"), an amplitude loop on an excitation (input \
             \"r\", harmonic 1, output \"drive_amplitude\", or on \"drive2\" \
             \"drive2_amplitude\") and contact mode's deflection loop (input \
             \"mean_deflection\", output \"surface_distance\"); a loop on the surface in \
             tapping has the tapping orbit's plant, which it has no model of",
            u.input.name(),
            u.harmonic,
            u.oscillator.name(),
            u.output.name()
        )
    };
    let contact = u.input == PidInput::MeanDeflection;
    if u.harmonic != 1 && !contact {
        return Err(unsupported());
    }
    let second = u.oscillator == Oscillator::Drive2;
    if second != u.output.on_drive2() {
        return Err(unsupported());
    }
    let invalid =
        |e: &dyn std::fmt::Display| format!("the loop of /pids/{unit} cannot be modelled: {e}");
    let adc = if settings.synth.anti_alias {
        ADC_DELAY_SAMPLES
    } else {
        0.0
    };
    // The mode the loop acts on: the first, or the second for the second excitation.
    let (mode, free) = if second {
        (1, settings.drive2.free_amplitude)
    } else {
        (0, settings.drive.free_amplitude)
    };
    let lever = crate::model::cantilever(settings).map_err(|e| invalid(&e))?;
    let Some(m) = lever.modes.get(mode) else {
        return Err(unsupported());
    };
    let (q, f0) = (m.q, m.frequency);
    let (demodulator, filter) = if second {
        // Four sections of the unit's low-pass, run per sample, read once per drive period
        // behind the ADC's delay.
        let alpha =
            crate::synth::pid_plan::low_pass_alpha(u.input_bandwidth, settings.synth.sample_rate);
        let tau = -1.0 / ((1.0 - alpha).ln() * settings.synth.sample_rate);
        let d = Demodulator::new(
            crate::synth::pid_plan::LOW_PASS_SECTIONS as u32,
            tau,
            settings.drive.frequency,
            adc / settings.synth.sample_rate,
        )
        .and_then(|d| d.with_filter_rate(settings.synth.sample_rate))
        .map_err(|e| invalid(&e))?;
        let words = format!(
            "a low-pass of {} sections of τ {tau:.4e} s ({} Hz)",
            crate::synth::pid_plan::LOW_PASS_SECTIONS,
            u.input_bandwidth
        );
        (d, words)
    } else {
        let d = Demodulator::pid_unit(settings.drive.frequency, settings.synth.sample_rate, adc)
            .map_err(|e| invalid(&e))?;
        (d, "no filter".to_owned())
    };
    let oscillator = if second { "f2" } else { "f1" };
    let (plant, sign, words) = match (u.input, u.output) {
        (PidInput::Phase, PidTarget::DriveFrequency | PidTarget::Drive2Frequency) => {
            let plant = Plant::resonator(q, f0).map_err(|e| invalid(&e))?;
            let words = format!(
                "the driven lever's phase, −(2Q/{oscillator})/(1 + s·τ_c) rad/Hz (Q {q}, \
                 {oscillator} {f0} Hz, τ_c {:.4e} s), through the unit's demodulator \
                 ({filter}, updates at {} Hz, delay {:.4e} s)",
                plant.time_constant().unwrap_or(f64::NAN),
                settings.drive.frequency,
                demodulator.total_delay()
            );
            (plant, -1.0, words)
        }
        (PidInput::R, PidTarget::DriveAmplitude | PidTarget::Drive2Amplitude) => {
            let reading = crate::synth::plan::free_reading_of(settings, u.oscillator)
                .map(|z| z.norm())
                .unwrap_or(f64::NAN);
            let plant = Plant::amplitude(reading / free, q, f0).map_err(|e| invalid(&e))?;
            let words = format!(
                "the free lever's amplitude, G0/(1 + s·τ_c) with G0 {:.4e} m of photodiode \
                 amplitude per m of drive (Q {q}, {oscillator} {f0} Hz, τ_c {:.4e} s), \
                 through the unit's demodulator ({filter}, updates at {} Hz, delay {:.4e} s)",
                reading / free,
                plant.time_constant().unwrap_or(f64::NAN),
                settings.drive.frequency,
                demodulator.total_delay()
            );
            (plant, 1.0, words)
        }
        (PidInput::MeanDeflection, PidTarget::SurfaceDistance) => {
            let (plant, force, stiffness) =
                deflection_plant(settings, &lever, u.setpoint).map_err(|e| invalid(&e))?;
            let words = format!(
                "the lever pressed on the sample, its mean deflection falling by G0 {:.4e} m \
                 per m of surface distance at once (Σλ_n/k_n ÷ (Σ1/k_n + 1/k_c), the \
                 contact's stiffness k_c {stiffness:.4e} N/m under the set-point's \
                 {force:.4e} N), through the unit's demodulator ({filter}, updates at {} Hz, \
                 delay {:.4e} s)",
                plant.gain().unwrap_or(f64::NAN),
                settings.drive.frequency,
                demodulator.total_delay()
            );
            (plant, -1.0, words)
        }
        _ => return Err(unsupported()),
    };
    Ok(UnitLoop {
        model: LoopModel { plant, demodulator },
        sign,
        plant: words,
    })
}

/// Contact mode's plant at the set-point `reading` (m of photodiode deflection): the lever
/// pressed up by the contact's force F in static balance, each mode deflecting by F/k_n at
/// the tip (k_n tip-referred) and the photodiode reading Σλ_n·F/k_n (λ_n the light-lever
/// factors), so F = reading/Σλ_n/k_n; the Hertz contact of the base sample under F plus
/// the DMT adhesion's pull where it is on has the stiffness k_c = 2E*·a (a the contact
/// radius). A change dD of the surface distance moves the deflection by
/// −Σλ_n/k_n ÷ (Σ1/k_n + 1/k_c)·dD. Returns that slope's magnitude as a quasi-static plant,
/// with F (N) and k_c (N/m).
pub fn deflection_plant(
    settings: &Settings,
    lever: &Cantilever,
    reading: f64,
) -> Result<(Plant, f64, f64), String> {
    let per_force: f64 = lever
        .modes
        .iter()
        .map(|m| m.light_lever_factor() / m.tip_stiffness())
        .sum();
    let compliance: f64 = lever.modes.iter().map(|m| 1.0 / m.tip_stiffness()).sum();
    let force = reading / per_force;
    let radius = settings.cantilever.tip_radius;
    let pull = crate::model::adhesion(settings).map_or(0.0, |a| a.pull_off(radius));
    let contact = crate::model::impact_oscillator(settings, lever, settings.sample).contact;
    let hertz = force + pull;
    if hertz.is_nan() || hertz <= 0.0 {
        return Err(format!(
            "the set-point {reading} m of deflection presses no contact (a load of {force:.4e} N \
             against an adhesion of {pull:.4e} N): contact mode holds a set-point above {} m",
            -pull * per_force
        ));
    }
    let stiffness = 2.0 * contact.reduced_modulus * contact.contact_radius(hertz);
    let slope = per_force / (compliance + 1.0 / stiffness);
    let plant = Plant::quasi_static(slope).map_err(|e| e.to_string())?;
    Ok((plant, force, stiffness))
}
