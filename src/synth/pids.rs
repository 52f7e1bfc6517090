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
//! On the drive (`drive_frequency`: a PLL; `drive_amplitude`): the excitation changes from
//! the update's sample on, phase-continuous, and the modes keep their displacement and
//! velocity ([`SynthState::redrive`]). The lock-in's reference follows the drive exactly:
//! a sample is demodulated against the drive phase at which it was taken, so the reference
//! changes its frequency the ADC filter's delay after the drive does
//! ([`ReferenceChange`]); the units' own demodulators and the DSP thread's bank read the
//! same changes.
//!
//! Nothing here allocates, locks, logs or blocks (`tests/synth_no_alloc.rs`).

use std::f64::consts::{PI, TAU};

use rustfft::num_complex::Complex64;

use super::coupled::CoupledKernel;
use super::drive::{Drive, ReferenceChange};
use super::plan::SynthPlan;
use super::scan::samples_until;
use super::synthesizer::{Output, SynthState};
use crate::config::{PID_COUNT, PidInput, PidTarget};
use crate::control::{Pid, PidSettings};
use crate::timebase::{TWO_POW_64, frequency_word, harmonic_phase, phase_to_radians};

/// Reference changes made and not yet reached: at most one per update, and the updates
/// are at least two samples apart, so ⌈D⌉ = 22 samples hold at most 11.
pub const PENDING_REFERENCES: usize = 16;

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

/// A unit's running sums since the pipeline started: means over any stretch are the
/// differences of two of them over the difference of `updates` ([`PidSums::since`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PidSums {
    /// Updates so far.
    pub updates: u64,
    /// Σ measurement (the input's unit).
    pub measurement: f64,
    /// Σ error (the input's unit).
    pub error: f64,
    /// Σ output (the output's unit).
    pub output: f64,
}

impl PidSums {
    fn add(&mut self, measurement: f64, error: f64, output: f64) {
        self.updates += 1;
        self.measurement += measurement;
        self.error += error;
        self.output += output;
    }

    /// The means of the updates since `earlier` (measurement, error, output) and their
    /// count; `None` when there were none.
    pub fn since(&self, earlier: &PidSums) -> Option<(f64, f64, f64, u64)> {
        let n = self
            .updates
            .checked_sub(earlier.updates)
            .filter(|&n| n > 0)?;
        let mean = |a: f64, b: f64| (a - b) / n as f64;
        Some((
            mean(self.measurement, earlier.measurement),
            mean(self.error, earlier.error),
            mean(self.output, earlier.output),
            n,
        ))
    }
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
    /// Σ e^{−2ikθ} over the same samples: the boxcar's image of −kΩ, which a period of a
    /// whole number of samples cancels and a fractional one does not.
    image: Complex64,
    /// Every update's sums.
    sums: PidSums,
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
    /// The drive in force: the plan's, unless a loop moved it.
    drive: Drive,
    /// The drive phase word a loop set: kept (held) until `/drive/frequency` changes while
    /// no loop drives it; `None`: the plan's.
    word_held: Option<u64>,
    /// The base amplitude a loop set (m), held alike; `None`: the plan's.
    base_held: Option<f64>,
    /// Drive phase word at which the loops update ([`super::PidPlan::update_phase`],
    /// moved with the drive).
    update_phase: u64,
    /// The lock-in's reference at the next output sample: the drive phase it was taken at
    /// and the word per sample.
    reference_phase: u64,
    reference_word: u64,
    /// Reference changes ahead of the next output sample, oldest first (a ring).
    pending: [ReferenceChange; PENDING_REFERENCES],
    pending_head: usize,
    pending_len: usize,
    /// Whether the reference must be taken afresh from the drive (after a change of plan,
    /// whose block header carries it).
    reference_stale: bool,
}

impl Unit {
    /// Empties the demodulator's sums for the next period.
    fn clear(&mut self) {
        self.acc = Complex64::new(0.0, 0.0);
        self.image = Complex64::new(0.0, 0.0);
    }
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
            image: Complex64::new(0.0, 0.0),
            sums: PidSums::default(),
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
            drive: plan.drive,
            word_held: None,
            base_held: None,
            update_phase: plan.pids.update_phase,
            reference_phase: 0,
            reference_word: plan.frequency_word,
            pending: [ReferenceChange::default(); PENDING_REFERENCES],
            pending_head: 0,
            pending_len: 0,
            reference_stale: true,
        }
    }

    /// Whether the synthesiser must run [`SynthPlan::process_pids`] for `plan`: a unit is
    /// enabled, or a loop left the surface where the plan's engine would not put it.
    pub fn active(&self, plan: &SynthPlan) -> bool {
        plan.coupled.is_some() && (plan.pids.any_enabled() || self.held || self.drive_held())
    }

    /// Whether a loop holds the drive away from the plan's `/drive/*`.
    fn drive_held(&self) -> bool {
        self.word_held.is_some() || self.base_held.is_some()
    }

    /// Each unit's running sums (by index).
    pub fn sums(&self) -> [PidSums; PID_COUNT] {
        std::array::from_fn(|i| self.units[i].sums)
    }

    /// The outputs the loops hold away from the plan's nodes, bit `PidTarget as usize`
    /// each.
    pub fn held_outputs(&self) -> u64 {
        let bit = |on: bool, target: PidTarget| u64::from(on) << target as u64;
        bit(self.held, PidTarget::SurfaceDistance)
            | bit(self.word_held.is_some(), PidTarget::DriveFrequency)
            | bit(self.base_held.is_some(), PidTarget::DriveAmplitude)
    }

    /// Readies the loops for the next block of `plan` from `state`'s next sample, and
    /// returns the lock-in's reference there: the drive phase word at which that sample is
    /// taken and the word per sample (what the block's header carries).
    pub fn begin(&mut self, plan: &SynthPlan, state: &SynthState) -> (u64, u64) {
        if !self.running || self.reference_stale {
            if !self.running {
                self.restart(state.sample_index());
            }
            self.reference_stale = false;
            self.reference_phase = plan.output_phase_at(state.phase(), self.drive.word);
            self.reference_word = self.drive.word;
            self.pending_len = 0;
            self.running = true;
        }
        (self.reference_phase, self.reference_word)
    }

    /// Puts the modes back under `plan`'s own drive before a change of plan, which moves
    /// them from that drive to the next plan's ([`SynthState::retarget`]); the loops' drive
    /// is taken up again by [`retarget`](Self::retarget). Allocation-free.
    pub fn release_drive(&mut self, plan: &SynthPlan, state: &mut SynthState) {
        if self.drive != plan.drive {
            state.redrive(&plan.modes, &self.drive, &plan.drive);
            self.drive = plan.drive;
        }
    }

    /// The surface distance in force (m): where the loops put it, else the plan's.
    pub fn distance(&self) -> f64 {
        self.distance
    }

    /// Follows a change of plan at sample `index`, `state` already moved to `new`'s own
    /// drive ([`release_drive`](Self::release_drive), then [`SynthState::retarget`]). A
    /// unit that starts takes the plan's controller and starts from the output's present
    /// value (bumpless); one that keeps running takes the new gains, limits and set-point
    /// and keeps its integrator; one that stops holds its output. A new `/surface/distance`
    /// (`/drive/frequency`, `/drive/free_amplitude`) takes over the surface (the drive's
    /// frequency, its amplitude) from the loops that no longer run. Allocation-free.
    pub fn retarget(
        &mut self,
        old: &SynthPlan,
        new: &SynthPlan,
        index: u64,
        state: &mut SynthState,
    ) {
        // A copy: fixed-size lanes, no allocation.
        self.coupled.clone_from(&new.coupled);
        self.drive = new.drive;
        // A loop that keeps running on an output holds it through the change (one that
        // starts with it starts from the new value).
        let continuing = |target: PidTarget| {
            self.units.iter().zip(&new.pids.units).any(|(u, plan)| {
                u.enabled && u.output == target && plan.as_ref().is_some_and(|p| p.output == target)
            })
        };
        if new.pids.surface_distance != old.pids.surface_distance
            && !continuing(PidTarget::SurfaceDistance)
        {
            self.distance = new.pids.surface_distance;
            self.held = false;
        }
        if new.drive.word != old.drive.word && !continuing(PidTarget::DriveFrequency) {
            self.word_held = None;
        }
        if new.pids.free_amplitude != old.pids.free_amplitude
            && !continuing(PidTarget::DriveAmplitude)
        {
            self.base_held = None;
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
                            PidTarget::DriveFrequency => {
                                let word = self.word_held.unwrap_or(new.drive.word);
                                word as f64 / TWO_POW_64 * new.sample_rate
                            }
                            PidTarget::DriveAmplitude => {
                                let base = self.base_held.unwrap_or(new.drive.base_amplitude);
                                base / new.pids.base_per_free
                            }
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
        for unit in self.units.iter().filter(|u| u.enabled) {
            match unit.output {
                PidTarget::SurfaceDistance => self.held = true,
                PidTarget::DriveFrequency => {
                    self.word_held.get_or_insert(new.drive.word);
                }
                PidTarget::DriveAmplitude => {
                    self.base_held.get_or_insert(new.drive.base_amplitude);
                }
            }
        }
        // Another engine, or a scan (which sets the surface itself and reads the drive
        // as configured), takes the outputs back to the plan's.
        if new.coupled.is_none() || new.scan.is_some() {
            (self.held, self.word_held, self.base_held) = (false, None, None);
        }
        if !self.held {
            self.distance = new.pids.surface_distance;
        }
        if let Some(coupled) = &mut self.coupled {
            coupled.distance = self.distance;
        }
        self.update_phase = new.pids.update_phase;
        // The loops' drive, from the next sample on; the block's header carries its
        // reference, so no change is recorded for it.
        self.take_drive(new, state, index, &mut |_| {});
        self.pending_len = 0;
        // A change of the drive frequency or a start restarts the boxcars; any other
        // change leaves the period in progress running (its samples are the chain's).
        if !self.running || new.frequency_word != old.frequency_word {
            self.restart(index);
        }
        self.reference_stale = true;
        self.period = TWO_POW_64 / self.drive.word.max(1) as f64;
    }

    /// Moves the modes, the contact's kernel and the update phase to the drive the loops
    /// hold (the plan's where they hold none), from `state`'s next sample (index `index`)
    /// on; a new frequency records the lock-in's [`ReferenceChange`] in the pending ring and
    /// hands it to `reference`. Allocation-free.
    fn take_drive(
        &mut self,
        plan: &SynthPlan,
        state: &mut SynthState,
        index: u64,
        reference: &mut impl FnMut(ReferenceChange),
    ) {
        let word = self.word_held.unwrap_or(plan.drive.word);
        let base = self.base_held.unwrap_or(plan.drive.base_amplitude);
        if word == self.drive.word && base == self.drive.base_amplitude {
            return;
        }
        let to = if word == plan.drive.word && base == plan.drive.base_amplitude {
            plan.drive
        } else {
            Drive::new(&plan.cantilever, plan.sample_rate, word, base)
        };
        state.redrive(&plan.modes, &self.drive, &to);
        if let Some(coupled) = &mut self.coupled {
            coupled.set_drive(&plan.cantilever.modes, plan.h, &to);
            self.update_phase = super::pid_plan::highest_phase(coupled.free_tip);
        }
        if to.word != self.drive.word {
            let change = plan.reference_change(state.phase(), index, to.word);
            if self.pending_len < PENDING_REFERENCES {
                self.pending[(self.pending_head + self.pending_len) % PENDING_REFERENCES] = change;
                self.pending_len += 1;
            }
            reference(change);
            self.period = TWO_POW_64 / to.word.max(1) as f64;
        }
        self.drive = to;
    }

    /// The boxcars start afresh at `index`; the first, partial period is not fed to the
    /// loops.
    fn restart(&mut self, index: u64) {
        for unit in &mut self.units {
            unit.clear();
        }
        self.acc_count = 0;
        self.next_update = index;
    }

    /// Marks the loops idle: the synthesiser ran a block without them, so their boxcars
    /// missed it.
    pub fn pause(&mut self) {
        self.running = false;
    }

    /// Mixes `segment` (output samples from index `index` on, the reference's next) into
    /// the enabled units' boxcars, against the reference and its pending changes.
    fn demodulate(&mut self, segment: &[f64], index: u64) {
        let mut done = 0;
        while done < segment.len() {
            let at = index + done as u64;
            while self.pending_len > 0 && self.pending[self.pending_head].index <= at {
                let change = self.pending[self.pending_head];
                self.reference_phase = change.phase;
                self.reference_word = change.word;
                self.pending_head = (self.pending_head + 1) % PENDING_REFERENCES;
                self.pending_len -= 1;
            }
            let until = if self.pending_len > 0 {
                ((self.pending[self.pending_head].index - index) as usize).min(segment.len())
            } else {
                segment.len()
            };
            let piece = &segment[done..until];
            let word = self.reference_word;
            // Units at one harmonic share their sums (a PLL and an amplitude loop both read
            // harmonic 1): each harmonic's mixing runs once.
            let mut harmonics = [0u32; PID_COUNT];
            let mut count = 0;
            for unit in self.units.iter().filter(|u| u.enabled) {
                if !harmonics[..count].contains(&unit.harmonic) {
                    harmonics[count] = unit.harmonic;
                    count += 1;
                }
            }
            for &harmonic in &harmonics[..count] {
                let theta = harmonic_phase(self.reference_phase, harmonic);
                let turn = word.wrapping_mul(u64::from(harmonic));
                let rho0 = Complex64::from_polar(1.0, -phase_to_radians(theta));
                let step = Complex64::from_polar(1.0, -(turn as f64) / TWO_POW_64 * TAU);
                let mut rho = rho0;
                let mut acc = Complex64::new(0.0, 0.0);
                for &s in piece {
                    acc += rho * s;
                    rho *= step;
                }
                let image = image_sum(rho0, step, turn, piece.len() as u64);
                for unit in self.units.iter_mut() {
                    if unit.enabled && unit.harmonic == harmonic {
                        unit.acc += acc;
                        unit.image += image;
                    }
                }
            }
            self.reference_phase = self
                .reference_phase
                .wrapping_add(word.wrapping_mul(piece.len() as u64));
            done = until;
        }
        self.acc_count += segment.len() as u32;
    }
}

/// Σ (ρ0·rⁿ)² over n = 0 … `len` − 1 for the mixing phasor ρ0 = e^{−iθ} and its step
/// r = e^{−iω}, ω the phase word `turn` (2^64 = one turn): the boxcar's image of −kΩ over a
/// piece of `len` samples, the geometric series summed in closed form (its terms do not
/// depend on the signal, so no sample need add them).
fn image_sum(rho0: Complex64, step: Complex64, turn: u64, len: u64) -> Complex64 {
    let start = rho0 * rho0;
    let ratio = step * step;
    let last = Complex64::from_polar(1.0, -phase_to_radians(turn.wrapping_mul(2 * len)));
    let denominator = Complex64::new(1.0, 0.0) - ratio;
    // At 2kΩ a whole number of turns a sample, every term is the first.
    if denominator.norm() < 1e-9 {
        start * len as f64
    } else {
        start * (Complex64::new(1.0, 0.0) - last) / denominator
    }
}

impl SynthPlan {
    /// Fills `out` with the next finished samples (the ADC's FIRs, detector noise and
    /// quantisation done here, as [`process`](Self::process) does) under the PID units (see
    /// the module docs), handing each unit's update to `reading` and each change of the
    /// lock-in's reference to `reference`. Call [`PidRuntime::begin`] first. Allocation-free,
    /// lock-free.
    pub fn process_pids(
        &self,
        state: &mut SynthState,
        rt: &mut PidRuntime,
        out: &mut [f64],
        reading: &mut impl FnMut(PidReading),
        reference: &mut impl FnMut(ReferenceChange),
    ) {
        rt.begin(self, state);
        let mut done = 0;
        while done < out.len() {
            let index = state.sample_index();
            if index >= rt.next_update {
                self.update_pids(state, index, rt, reading, reference);
            }
            let n = ((rt.next_update - index) as usize).min(out.len() - done);
            let segment = &mut out[done..done + n];
            self.process_with(
                &rt.drive,
                self.pulse.as_ref(),
                rt.coupled.as_ref(),
                state,
                Output::Samples(segment),
            );
            rt.demodulate(segment, index);
            done += n;
        }
    }

    /// Once per drive period: each enabled unit reads its demodulator and updates; the
    /// outputs take effect from sample `index` (`state`'s next) on.
    fn update_pids(
        &self,
        state: &mut SynthState,
        index: u64,
        rt: &mut PidRuntime,
        reading: &mut impl FnMut(PidReading),
        reference: &mut impl FnMut(ReferenceChange),
    ) {
        // A whole period has ⌊2^64/word⌋ or ⌈2^64/word⌉ samples; fewer after a restart.
        let whole = rt.acc_count > 0 && f64::from(rt.acc_count) >= rt.period - 1.0;
        if whole {
            let scale = 2.0 / f64::from(rt.acc_count);
            for (unit_index, unit) in rt.units.iter_mut().enumerate() {
                if !unit.enabled || unit.partial {
                    continue;
                }
                // The least-squares sinusoid at kΩ over the period's samples: the boxcar
                // z = a + ā·c, c its image's share (zero over a whole number of samples
                // per period, up to 1/N otherwise, which would ripple a PLL's phase as
                // the drive frequency moves), solved for a.
                let z = unit.acc * scale;
                let c = unit.image / f64::from(rt.acc_count);
                let z = (z - c * z.conj()) / (1.0 - c.norm_sqr());
                let measurement = match unit.input {
                    PidInput::R => z.norm(),
                    PidInput::Phase => z.im.atan2(z.re),
                    PidInput::X => z.re,
                    PidInput::Y => z.im,
                };
                // A phase is read on the circle: the controller sees it within half a
                // turn of its set-point, so the error never jumps by 2π where the phase
                // wraps (a PLL's set-point near ±π is common).
                let fed = match unit.input {
                    PidInput::Phase => {
                        let setpoint = unit.pid.settings().setpoint;
                        setpoint - (setpoint - measurement + PI).rem_euclid(TAU) + PI
                    }
                    _ => measurement,
                };
                let output = unit.pid.update(fed);
                match unit.output {
                    PidTarget::SurfaceDistance => rt.distance = output,
                    PidTarget::DriveFrequency => {
                        // The limits keep it a valid frequency; should one not be, the
                        // drive keeps its word.
                        if let Ok(word) = frequency_word(output, self.sample_rate) {
                            rt.word_held = Some(word);
                        }
                    }
                    PidTarget::DriveAmplitude => {
                        rt.base_held = Some(output * self.pids.base_per_free);
                    }
                }
                let error = unit.pid.error();
                unit.sums.add(measurement, error, output);
                reading(PidReading {
                    unit: unit_index,
                    sample: index,
                    measurement,
                    error,
                    output,
                    limited: unit.pid.is_limited(),
                });
            }
        }
        for unit in &mut rt.units {
            unit.clear();
            unit.partial = false;
        }
        rt.acc_count = 0;
        if let Some(coupled) = &mut rt.coupled {
            coupled.distance = rt.distance;
        }
        rt.take_drive(self, state, index, reference);
        rt.next_update = index + samples_until(state.phase(), rt.update_phase, rt.drive.word);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form against the terms summed one by one: fractional periods, many
    /// turns, and 2kΩ a whole turn a sample (the series' degenerate case).
    #[test]
    fn image_sum_is_the_series() {
        for (theta, turn, len) in [
            (0u64, 1u64 << 57, 100u64),
            (0x1234_5678_9abc_def0, 0x0290_0000_1234_5678, 97),
            (1 << 63, 1 << 63, 40),
            (12345, 0, 7),
        ] {
            let mut direct = Complex64::new(0.0, 0.0);
            for n in 0..len {
                let phase = theta.wrapping_add(turn.wrapping_mul(n)).wrapping_mul(2);
                direct += Complex64::from_polar(1.0, -phase_to_radians(phase));
            }
            let rho0 = Complex64::from_polar(1.0, -phase_to_radians(theta));
            let step = Complex64::from_polar(1.0, -phase_to_radians(turn));
            let closed = image_sum(rho0, step, turn, len);
            assert!(
                (closed - direct).norm() < 1e-9 * len as f64,
                "θ {theta:#x}, ω {turn:#x}, {len}: {closed} against {direct}"
            );
        }
    }
}
