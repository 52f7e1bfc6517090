//! The live PID units in the synthesiser (`/pids/N/*`, docs/loops.md): closed loops around
//! modelled demodulators of the photodiode samples, run on the real-time thread once per
//! drive period, as the scan's amplitude feedback is ([`super::scan`]).
//!
//! Once per drive period, at the drive phase where the free tip is highest (half a period
//! from the tap, so a move of the surface never cuts a contact): each enabled unit's
//! demodulator (a one-period boxcar of the finished photodiode samples, ADC filter, detector
//! noise and quantisation included, mixed with k times the drive phase the samples were
//! taken at, so that x, y and the phase read as the `demods` stream's) gives its input; its
//! [`Pid`] updates; the output takes effect from the next sample on. On the surface
//! distance (the coupled engine's): the surface the integrated tip meets moves there, so
//! the loop closes around the real contact, not a table of it.
//!
//! The loop's dead time: the boxcar's one period T (its mean delay T/2), the ADC filter's
//! delay (21.5 samples with `/synth/anti_alias`), and the output held for one period from
//! the update's sample boundary (a zero-order hold, mean delay T/2): about T + 21.5 h.
//!
//! Nothing here allocates, locks, logs or blocks (`tests/synth_no_alloc.rs`).

use std::f64::consts::TAU;

use rustfft::num_complex::Complex64;

use super::coupled::CoupledKernel;
use super::plan::SynthPlan;
use super::scan::samples_until;
use super::synthesizer::{Output, SynthState};
use crate::config::{PID_COUNT, PidInput, PidTarget};
use crate::control::{Pid, PidSettings};
use crate::timebase::{TWO_POW_64, harmonic_phase, phase_to_radians};

/// One update of one unit, handed out of the synthesiser as it happens.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PidReading {
    /// The unit: N of `/pids/N`.
    pub unit: usize,
    /// Index of the sample from which the output takes effect (the update's boundary).
    pub sample: u64,
    /// The input its demodulator read over the period just ended (m, or rad).
    pub measurement: f64,
    /// Set-point minus measurement (the input's unit).
    pub error: f64,
    /// The output from `sample` on (the output's unit: m for the surface distance).
    pub output: f64,
    /// Whether a limit held the output (its limits or its rate limit).
    pub limited: bool,
}

/// One unit's state on the real-time thread.
#[derive(Clone, Debug)]
struct Unit {
    pid: Pid,
    /// Whether the unit regulates (its plan has it enabled).
    enabled: bool,
    input: PidInput,
    harmonic: u32,
    output: PidTarget,
    /// The boxcar's sum Σ s·e^{−ikθ} over the period in progress.
    acc: Complex64,
    /// Whether the unit started, or changed its harmonic, during the period in progress:
    /// its boxcar then holds part of a period (or of another harmonic), which the next
    /// update does not feed to its controller.
    partial: bool,
}

/// The mutable side of the PID units: controllers, demodulators and the output they hold.
/// Owned by the synthesiser thread; built off it.
#[derive(Clone, Debug)]
pub struct PidRuntime {
    units: [Unit; PID_COUNT],
    /// The coupled engine's kernel with the surface the loops set (a copy of the plan's).
    coupled: Option<CoupledKernel>,
    /// The surface distance in force (m).
    distance: f64,
    /// Whether a loop moved the surface distance away from the plan's `/surface/distance`:
    /// a disabled loop leaves it where it was (bumpless), until `/surface/distance` is set.
    held: bool,
    /// Whether the loops ran on the last block (else the boxcars restart).
    running: bool,
    acc_count: u32,
    next_update: u64,
    /// Samples per drive period, 2^64/word: a period shorter than this less one (after a
    /// restart) is not a whole period, and the loops skip it.
    period: f64,
}

impl PidRuntime {
    /// Idle units for `plan`, the surface at its `/surface/distance`.
    pub fn new(plan: &SynthPlan) -> Self {
        let idle = Pid::new(PidSettings::default()).expect("the default PID settings are valid");
        let unit = Unit {
            pid: idle,
            enabled: false,
            input: PidInput::R,
            harmonic: 1,
            output: PidTarget::SurfaceDistance,
            acc: Complex64::new(0.0, 0.0),
            partial: false,
        };
        Self {
            units: std::array::from_fn(|_| unit.clone()),
            coupled: plan.coupled.clone(),
            distance: plan.pids.surface_distance,
            held: false,
            running: false,
            acc_count: 0,
            next_update: 0,
            period: TWO_POW_64 / plan.frequency_word.max(1) as f64,
        }
    }

    /// Whether the synthesiser must run [`SynthPlan::process_pids`] for `plan`: a unit is
    /// enabled, or a loop left the surface where the plan's engine would not put it.
    pub fn active(&self, plan: &SynthPlan) -> bool {
        plan.coupled.is_some() && (plan.pids.any_enabled() || self.held)
    }

    /// The surface distance in force (m): where the loops put it, else the plan's.
    pub fn distance(&self) -> f64 {
        self.distance
    }

    /// Follows a change of plan at sample `index`. A unit that starts takes the plan's
    /// controller and starts from the output's present value (bumpless); one that keeps
    /// running takes the new gains, limits and set-point and keeps its integrator; one that
    /// stops holds its output. A new `/surface/distance` takes over the surface from the
    /// loops that no longer run. Allocation-free.
    pub fn retarget(&mut self, old: &SynthPlan, new: &SynthPlan, index: u64) {
        // A copy: fixed-size lanes, no allocation.
        self.coupled.clone_from(&new.coupled);
        // A new `/surface/distance` moves the surface unless a loop that keeps running
        // holds it (one that starts with the change starts from the new value).
        let continuing = self.units.iter().zip(&new.pids.units).any(|(u, plan)| {
            u.enabled
                && u.output == PidTarget::SurfaceDistance
                && plan
                    .as_ref()
                    .is_some_and(|p| p.output == PidTarget::SurfaceDistance)
        });
        if new.pids.surface_distance != old.pids.surface_distance && !continuing {
            self.distance = new.pids.surface_distance;
            self.held = false;
        }
        for (unit, plan) in self.units.iter_mut().zip(&new.pids.units) {
            match plan {
                Some(plan) => {
                    if unit.enabled {
                        unit.pid.retune(&plan.pid);
                    } else {
                        unit.pid.clone_from(&plan.pid);
                        unit.enabled = true;
                        let present = match plan.output {
                            PidTarget::SurfaceDistance => self.distance,
                        };
                        unit.pid.enable(present);
                        unit.partial = true;
                    }
                    unit.partial |= unit.harmonic != plan.harmonic;
                    unit.input = plan.input;
                    unit.harmonic = plan.harmonic;
                    unit.output = plan.output;
                }
                None => {
                    if unit.enabled {
                        unit.pid.disable();
                        unit.enabled = false;
                    }
                }
            }
        }
        if self
            .units
            .iter()
            .any(|u| u.enabled && u.output == PidTarget::SurfaceDistance)
        {
            self.held = true;
        }
        // Another engine, or a scan (which sets the surface itself), takes the surface
        // back to `/surface/distance`.
        if !self.held || new.coupled.is_none() || new.scan.is_some() {
            self.held = false;
            self.distance = new.pids.surface_distance;
        }
        if let Some(coupled) = &mut self.coupled {
            coupled.distance = self.distance;
        }
        // A change of the drive frequency or a start restarts the boxcars; any other
        // change leaves the period in progress running (its samples are the chain's).
        let period = TWO_POW_64 / new.frequency_word.max(1) as f64;
        if !self.running || new.frequency_word != old.frequency_word {
            self.restart(index);
        }
        self.period = period;
    }

    /// The boxcars start afresh at `index`; the first, partial period is not fed to the
    /// loops.
    fn restart(&mut self, index: u64) {
        for unit in &mut self.units {
            unit.acc = Complex64::new(0.0, 0.0);
        }
        self.acc_count = 0;
        self.next_update = index;
    }

    /// Marks the loops idle: the synthesiser ran a block without them, so their boxcars
    /// missed it.
    pub fn pause(&mut self) {
        self.running = false;
    }
}

impl SynthPlan {
    /// Fills `out` with the next finished samples (the ADC's FIRs, detector noise and
    /// quantisation done here, as [`process`](Self::process) does) under the PID units (see
    /// the module docs), handing each unit's update to `reading`. Allocation-free,
    /// lock-free.
    pub fn process_pids(
        &self,
        state: &mut SynthState,
        rt: &mut PidRuntime,
        out: &mut [f64],
        reading: &mut impl FnMut(PidReading),
    ) {
        if !rt.running {
            rt.restart(state.sample_index());
            rt.running = true;
        }
        let word = self.frequency_word;
        let mut done = 0;
        while done < out.len() {
            let index = state.sample_index();
            if index >= rt.next_update {
                self.update_pids(state.phase(), index, rt, reading);
            }
            let n = ((rt.next_update - index) as usize).min(out.len() - done);
            let segment = &mut out[done..done + n];
            // The drive phase at which the segment's first sample was taken (behind the
            // synthesis by the ADC filter's delay), as the lock-in takes it.
            let taken = self.output_phase(state.phase());
            self.process_with(
                self.pulse.as_ref(),
                rt.coupled.as_ref(),
                state,
                Output::Samples(segment),
            );
            for unit in rt.units.iter_mut().filter(|u| u.enabled) {
                let k = u64::from(unit.harmonic);
                let mut rho = Complex64::from_polar(
                    1.0,
                    -phase_to_radians(harmonic_phase(taken, unit.harmonic)),
                );
                let step =
                    Complex64::from_polar(1.0, -(word.wrapping_mul(k) as f64) / TWO_POW_64 * TAU);
                let mut acc = unit.acc;
                for &s in segment.iter() {
                    acc += rho * s;
                    rho *= step;
                }
                unit.acc = acc;
            }
            rt.acc_count += n as u32;
            done += n;
        }
    }

    /// Once per drive period: each enabled unit reads its demodulator and updates; the
    /// output moves the surface from sample `index` on.
    fn update_pids(
        &self,
        phase: u64,
        index: u64,
        rt: &mut PidRuntime,
        reading: &mut impl FnMut(PidReading),
    ) {
        // A whole period has ⌊2^64/word⌋ or ⌈2^64/word⌉ samples; fewer after a restart.
        let whole = rt.acc_count > 0 && f64::from(rt.acc_count) >= rt.period - 1.0;
        if whole {
            let scale = 2.0 / f64::from(rt.acc_count);
            for (unit_index, unit) in rt.units.iter_mut().enumerate() {
                if !unit.enabled || unit.partial {
                    continue;
                }
                let z = unit.acc * scale;
                let measurement = match unit.input {
                    PidInput::R => z.norm(),
                    PidInput::Phase => z.im.atan2(z.re),
                    PidInput::X => z.re,
                    PidInput::Y => z.im,
                };
                let output = unit.pid.update(measurement);
                match unit.output {
                    PidTarget::SurfaceDistance => rt.distance = output,
                }
                reading(PidReading {
                    unit: unit_index,
                    sample: index,
                    measurement,
                    error: unit.pid.error(),
                    output,
                    limited: unit.pid.is_limited(),
                });
            }
        }
        for unit in &mut rt.units {
            unit.acc = Complex64::new(0.0, 0.0);
            unit.partial = false;
        }
        rt.acc_count = 0;
        rt.next_update = index + samples_until(phase, self.pids.update_phase, self.frequency_word);
        if let Some(coupled) = &mut rt.coupled {
            coupled.distance = rt.distance;
        }
    }
}
