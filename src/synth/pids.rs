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
//! On the second excitation (`/pids/N/oscillator = "drive2"`: bimodal AFM's mode-2 loops)
//! a unit's demodulator is a low-pass of four first-order sections per sample
//! (`/pids/N/input_bandwidth`) of the samples mixed with k times θ₂ as they were taken:
//! a boxcar of the drive's period would pass the tapping's harmonics of f1 that lie
//! beside f2. It is read at the same updates, once its sections have settled from the
//! unit's start (ten section time constants). Its outputs (`drive2_frequency`,
//! `drive2_amplitude`) move the second excitation as those on the drive move the first, and
//! its reference changes are the second oscillator's.
//!
//! Nothing here allocates, locks, logs or blocks (`tests/synth_no_alloc.rs`).

use std::f64::consts::{PI, TAU};

use rustfft::num_complex::Complex64;

use super::coupled::CoupledKernel;
use super::drive::{Drive, ReferenceChange};
use super::period::{mix, samples_until};
use super::pid_plan::LOW_PASS_SECTIONS;
use super::plan::SynthPlan;
use super::synthesizer::{Output, SynthState};
use crate::config::{Oscillator, PID_COUNT, PidInput, PidTarget};
use crate::control::{Pid, PidSettings};
use crate::timebase::{TWO_POW_64, frequency_word, harmonic_phase, phase_to_radians};

/// Reference changes made and not yet reached: at most one an oscillator per update, and
/// the updates are at least two samples apart, so ⌈D⌉ = 22 samples hold at most 22.
pub const PENDING_REFERENCES: usize = 32;

/// A PLL is in lock while its phase error stays within this of its set-point (rad) and no
/// limit holds its output.
pub const PLL_LOCK_PHASE: f64 = 0.1;

/// Consecutive updates within [`PLL_LOCK_PHASE`] (and not limited) that acquire the lock:
/// a PLL sweeping through its set-point on the way is not yet locked.
pub const PLL_LOCK_UPDATES: u32 = 16;

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
    /// A PLL's lock after this update (a unit on the phase driving an excitation's
    /// frequency): acquired after [`PLL_LOCK_UPDATES`] updates in a row within
    /// [`PLL_LOCK_PHASE`] of the set-point and not limited, lost at the first that is not.
    /// `None` for other units.
    pub locked: Option<bool>,
    /// The PLL's losses of lock since the pipeline started (0 for other units).
    pub lock_losses: u64,
}

/// A PLL's lock detector ([`PidReading::locked`]).
#[derive(Clone, Copy, Debug, Default)]
struct Lock {
    locked: bool,
    /// Updates in a row in the lock window.
    streak: u32,
    losses: u64,
}

impl Lock {
    /// Takes one update: `inside` whether it is within the window and not limited.
    fn update(&mut self, inside: bool) {
        if inside {
            self.streak = self.streak.saturating_add(1);
            self.locked |= self.streak >= PLL_LOCK_UPDATES;
        } else {
            if self.locked {
                self.losses += 1;
            }
            (self.locked, self.streak) = (false, 0);
        }
    }
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
    oscillator: Oscillator,
    output: PidTarget,
    /// On `Drive2`: the low-pass's section coefficient and its sections' states, the
    /// mixed samples s·e^{−ikθ₂} filtered ([`super::pid_plan::LOW_PASS_SECTIONS`]).
    alpha: f64,
    low_pass: [Complex64; LOW_PASS_SECTIONS],
    /// Samples the low-pass still needs to settle before the unit reads it.
    settling: u32,
    /// The boxcar's sum Σ s·e^{−ikθ} over the period in progress.
    acc: Complex64,
    /// Σ e^{−2ikθ} over the same samples: the boxcar's image of −kΩ, which a period of a
    /// whole number of samples cancels and a fractional one does not.
    image: Complex64,
    /// Every update's sums.
    sums: PidSums,
    /// A PLL's lock (kept through a stop and a start: its losses count from the start of
    /// the pipeline).
    lock: Lock,
    /// Whether the unit started, or changed its harmonic, during the period in progress:
    /// its boxcar then holds part of a period (or of another harmonic), which the next
    /// update does not feed to its controller.
    partial: bool,
}

/// The PID units run beside a scan ([`SynthPlan::process_scan`]), and where their updates
/// and the lock-in's reference changes go.
pub struct ScanLoops<'a> {
    /// The units.
    pub runtime: &'a mut PidRuntime,
    /// Each unit's update, as it happens.
    pub reading: &'a mut dyn FnMut(PidReading),
    /// Each change of the lock-in's reference.
    pub reference: &'a mut dyn FnMut(ReferenceChange),
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
    /// The second excitation in force (the plan's, unless a loop moved it) and what the
    /// loops hold of it, alike.
    drive2: Option<Drive>,
    word2_held: Option<u64>,
    base2_held: Option<f64>,
    /// Drive phase word at which the loops update ([`super::PidPlan::update_phase`],
    /// moved with the drive).
    update_phase: u64,
    /// The lock-in's reference at the next output sample: the drive phase it was taken at
    /// and the word per sample.
    reference_phase: u64,
    reference_word: u64,
    /// The same of the second excitation's θ₂.
    reference_phase2: u64,
    reference_word2: u64,
    /// Reference changes ahead of the next output sample, oldest first (a ring).
    pending: [ReferenceChange; PENDING_REFERENCES],
    pending_head: usize,
    pending_len: usize,
    /// Whether the reference must be taken afresh from the drive (after a change of plan,
    /// whose block header carries it).
    reference_stale: bool,
}

impl Unit {
    /// Whether it reads its own demodulator (not a value derived from another unit).
    fn demodulates(&self) -> bool {
        self.input != PidInput::FrequencyShift
    }

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
            oscillator: Oscillator::Drive,
            output: PidTarget::SurfaceDistance,
            alpha: 0.0,
            low_pass: [Complex64::new(0.0, 0.0); LOW_PASS_SECTIONS],
            settling: 0,
            acc: Complex64::new(0.0, 0.0),
            image: Complex64::new(0.0, 0.0),
            sums: PidSums::default(),
            lock: Lock::default(),
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
            drive2: plan.drive2,
            word2_held: None,
            base2_held: None,
            update_phase: plan.pids.update_phase,
            reference_phase: 0,
            reference_word: plan.frequency_word,
            reference_phase2: 0,
            reference_word2: plan.frequency_word2,
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

    /// Whether a loop holds either excitation away from the plan's `/drive/*`, `/drive2/*`.
    fn drive_held(&self) -> bool {
        self.word_held.is_some()
            || self.base_held.is_some()
            || self.word2_held.is_some()
            || self.base2_held.is_some()
    }

    /// Each unit's running sums (by index).
    pub fn sums(&self) -> [PidSums; PID_COUNT] {
        std::array::from_fn(|i| self.units[i].sums)
    }

    /// The outputs the loops hold away from the plan's nodes, [`PidTarget::bit`] each.
    pub fn held_outputs(&self) -> u64 {
        let bit = |on: bool, target: PidTarget| if on { target.bit() } else { 0 };
        bit(self.held, PidTarget::SurfaceDistance)
            | bit(self.word_held.is_some(), PidTarget::DriveFrequency)
            | bit(self.base_held.is_some(), PidTarget::DriveAmplitude)
            | bit(self.word2_held.is_some(), PidTarget::Drive2Frequency)
            | bit(self.base2_held.is_some(), PidTarget::Drive2Amplitude)
    }

    /// Readies the loops for the next block of `plan` from `state`'s next sample, and
    /// returns the lock-in's references there, the drive's and θ₂'s: the phase word at
    /// which that sample is taken and the word per sample (what the block's header
    /// carries).
    pub fn begin(&mut self, plan: &SynthPlan, state: &SynthState) -> [(u64, u64); 2] {
        if !self.running || self.reference_stale {
            if !self.running {
                self.restart(state.sample_index());
            }
            self.reference_stale = false;
            self.reference_phase = plan.output_phase_at(state.phase(), self.drive.word);
            self.reference_word = self.drive.word;
            self.reference_word2 = self.word2(plan);
            self.reference_phase2 = plan.output_phase_at(state.phase2(), self.reference_word2);
            self.pending_len = 0;
            self.running = true;
        }
        [
            (self.reference_phase, self.reference_word),
            (self.reference_phase2, self.reference_word2),
        ]
    }

    /// θ₂'s word per sample in force: the loops' second excitation's, else
    /// `/drive2/frequency`'s.
    fn word2(&self, plan: &SynthPlan) -> u64 {
        self.drive2.map_or(plan.frequency_word2, |d| d.word)
    }

    /// Puts the modes back under `plan`'s own drive before a change of plan, which moves
    /// them from that drive to the next plan's ([`SynthState::retarget`]); the loops' drive
    /// is taken up again by [`retarget`](Self::retarget). Allocation-free.
    pub fn release_drive(&mut self, plan: &SynthPlan, state: &mut SynthState) {
        if self.drive != plan.drive {
            state.redrive(&plan.modes, &self.drive, &plan.drive);
            self.drive = plan.drive;
        }
        if self.drive2 != plan.drive2 {
            state.redrive2(&plan.modes, self.drive2.as_ref(), plan.drive2.as_ref());
            self.drive2 = plan.drive2;
        }
    }

    /// The surface distance in force (m): where the loops put it, else the plan's.
    pub fn distance(&self) -> f64 {
        self.distance
    }

    /// The second excitation in force: the plan's, unless a loop moved it.
    pub(super) fn drive2(&self) -> Option<Drive> {
        self.drive2
    }

    /// The index of the sample at which the units next update.
    pub(super) fn next_update(&self) -> u64 {
        self.next_update
    }

    /// The surface distance a unit sets (m), while one drives it.
    pub(super) fn held_distance(&self) -> Option<f64> {
        self.held.then_some(self.distance)
    }

    /// Puts a scan's surface under the tip (`distance` from the tip's rest position, m, and
    /// the region's Hertz `stiffness`) into the loops' kernel, which carries the
    /// excitations the loops move.
    pub(super) fn set_surface(&mut self, distance: f64, stiffness: f64) {
        if let Some(coupled) = &mut self.coupled {
            coupled.distance = distance;
            coupled.stiffness = stiffness;
        }
    }

    /// The excitations in force and the kernel that meets the surface under them.
    pub(super) fn drives(&self) -> (&Drive, Option<&Drive>, Option<&CoupledKernel>) {
        (&self.drive, self.drive2.as_ref(), self.coupled.as_ref())
    }

    /// Follows a change of plan at sample `index`, `state` already moved to `new`'s own
    /// drive ([`release_drive`](Self::release_drive), then [`SynthState::retarget`]). A
    /// unit that starts takes the plan's controller and starts from the output's present
    /// value (bumpless); one that keeps running takes the new gains, limits and set-point
    /// and keeps its integrator; one that stops holds its output. A new or written
    /// `/surface/distance` (`/drive/frequency`, `/drive/free_amplitude`, …; `new.release`)
    /// takes over the surface (the drive's frequency, its amplitude) from the loops that no
    /// longer run. Allocation-free.
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
        self.drive2 = new.drive2;
        // A loop that keeps running on an output holds it through the change (one that
        // starts with it starts from the new value).
        let continuing = |target: PidTarget| {
            self.units.iter().zip(&new.pids.units).any(|(u, plan)| {
                u.enabled && u.output == target && plan.as_ref().is_some_and(|p| p.output == target)
            })
        };
        // A node that changed, or was written, takes its output back.
        let released = |changed: bool, target: PidTarget| {
            (changed || new.release & target.bit() != 0) && !continuing(target)
        };
        if released(
            new.pids.surface_distance != old.pids.surface_distance,
            PidTarget::SurfaceDistance,
        ) {
            self.distance = new.pids.surface_distance;
            self.held = false;
        }
        if released(new.drive.word != old.drive.word, PidTarget::DriveFrequency) {
            self.word_held = None;
        }
        if released(
            new.pids.free_amplitude != old.pids.free_amplitude,
            PidTarget::DriveAmplitude,
        ) {
            self.base_held = None;
        }
        if released(
            new.frequency_word2 != old.frequency_word2,
            PidTarget::Drive2Frequency,
        ) {
            self.word2_held = None;
        }
        if released(
            new.pids.free_amplitude2 != old.pids.free_amplitude2,
            PidTarget::Drive2Amplitude,
        ) {
            self.base2_held = None;
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
                            // The settings allow these only while the second excitation
                            // drives; were it not to, the controller's centre stands.
                            PidTarget::Drive2Frequency => self
                                .word2_held
                                .or(new.drive2.map(|d| d.word))
                                .map_or(plan.pid.output(), |word| {
                                    word as f64 / TWO_POW_64 * new.sample_rate
                                }),
                            PidTarget::Drive2Amplitude => {
                                match (new.drive2, new.pids.base_per_free2) {
                                    (Some(d), Some(per)) => {
                                        self.base2_held.unwrap_or(d.base_amplitude) / per
                                    }
                                    _ => plan.pid.output(),
                                }
                            }
                        };
                        unit.pid.enable(present);
                        unit.partial = true;
                        // A start acquires the lock afresh.
                        (unit.lock.locked, unit.lock.streak) = (false, 0);
                    }
                    let reread = unit.harmonic != plan.harmonic
                        || unit.oscillator != plan.oscillator
                        || unit.alpha != plan.alpha;
                    unit.partial |= reread;
                    if plan.oscillator == Oscillator::Drive2 && (reread || unit.partial) {
                        unit.low_pass = [Complex64::new(0.0, 0.0); LOW_PASS_SECTIONS];
                        // Ten section time constants: e^{−10}·(a polynomial of degree 3)
                        // of the start's step is left, under 1 % of it.
                        unit.settling = (10.0 / plan.alpha.max(1e-12)).ceil() as u32;
                    }
                    unit.input = plan.input;
                    unit.harmonic = plan.harmonic;
                    unit.oscillator = plan.oscillator;
                    unit.alpha = plan.alpha;
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
                PidTarget::Drive2Frequency => {
                    if let Some(d) = &new.drive2 {
                        self.word2_held.get_or_insert(d.word);
                    }
                }
                PidTarget::Drive2Amplitude => {
                    if let Some(d) = &new.drive2 {
                        self.base2_held.get_or_insert(d.base_amplitude);
                    }
                }
            }
        }
        // Another engine, or a scan's own feedback (which sets the surface itself and
        // reads the drive as configured), takes the outputs back to the plan's; without
        // the second excitation, nothing of it is held.
        if new.coupled.is_none() || new.scan.as_ref().is_some_and(|s| s.feedback.enable) {
            (self.held, self.word_held, self.base_held) = (false, None, None);
        }
        if new.coupled.is_none() || new.drive2.is_none() {
            (self.word2_held, self.base2_held) = (None, None);
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
        self.take_drive2(plan, state, index, reference);
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
            let change = plan.reference_change(Oscillator::Drive, state.phase(), index, to.word);
            self.pend(change);
            reference(change);
            self.period = TWO_POW_64 / to.word.max(1) as f64;
        }
        self.drive = to;
    }

    /// [`take_drive`](Self::take_drive) for the second excitation, where it drives.
    fn take_drive2(
        &mut self,
        plan: &SynthPlan,
        state: &mut SynthState,
        index: u64,
        reference: &mut impl FnMut(ReferenceChange),
    ) {
        let (Some(own), Some(from)) = (plan.drive2, self.drive2) else {
            return;
        };
        let word = self.word2_held.unwrap_or(own.word);
        let base = self.base2_held.unwrap_or(own.base_amplitude);
        if word == from.word && base == from.base_amplitude {
            return;
        }
        let to = if word == own.word && base == own.base_amplitude {
            own
        } else {
            Drive::new(&plan.cantilever, plan.sample_rate, word, base)
        };
        state.redrive2(&plan.modes, Some(&from), Some(&to));
        if let Some(coupled) = &mut self.coupled {
            coupled.set_second_drive(&plan.cantilever.modes, plan.h, Some(&to));
        }
        if to.word != from.word {
            let change = plan.reference_change(Oscillator::Drive2, state.phase2(), index, to.word);
            self.pend(change);
            reference(change);
        }
        self.drive2 = Some(to);
    }

    /// Queues `change` for the units' own demodulators.
    fn pend(&mut self, change: ReferenceChange) {
        if self.pending_len < PENDING_REFERENCES {
            self.pending[(self.pending_head + self.pending_len) % PENDING_REFERENCES] = change;
            self.pending_len += 1;
        }
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
    pub(super) fn demodulate(&mut self, segment: &[f64], index: u64) {
        let mut done = 0;
        while done < segment.len() {
            let at = index + done as u64;
            while self.pending_len > 0 && self.pending[self.pending_head].index <= at {
                let change = self.pending[self.pending_head];
                match change.oscillator {
                    Oscillator::Drive => {
                        self.reference_phase = change.phase;
                        self.reference_word = change.word;
                    }
                    Oscillator::Drive2 => {
                        self.reference_phase2 = change.phase;
                        self.reference_word2 = change.word;
                    }
                }
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
            for unit in self
                .units
                .iter()
                .filter(|u| u.enabled && u.demodulates() && u.oscillator == Oscillator::Drive)
            {
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
                let acc = mix(piece, rho0, step);
                let image = image_sum(rho0, step, turn, piece.len() as u64);
                for unit in self.units.iter_mut() {
                    if unit.enabled
                        && unit.oscillator == Oscillator::Drive
                        && unit.harmonic == harmonic
                    {
                        unit.acc += acc;
                        unit.image += image;
                    }
                }
            }
            self.low_pass2(piece);
            self.reference_phase = self
                .reference_phase
                .wrapping_add(word.wrapping_mul(piece.len() as u64));
            self.reference_phase2 = self
                .reference_phase2
                .wrapping_add(self.reference_word2.wrapping_mul(piece.len() as u64));
            done = until;
        }
        self.acc_count += segment.len() as u32;
    }

    /// Runs the low-passes of the units on the second excitation over `piece`, output
    /// samples from θ₂'s reference on. Units at one harmonic and bandwidth share one filter:
    /// the later unit takes the earlier's sections.
    fn low_pass2(&mut self, piece: &[f64]) {
        for i in 0..PID_COUNT {
            let unit = &self.units[i];
            if !unit.enabled || !unit.demodulates() || unit.oscillator != Oscillator::Drive2 {
                continue;
            }
            let shared = (0..i).find(|&j| {
                let other = &self.units[j];
                other.enabled
                    && other.demodulates()
                    && other.oscillator == Oscillator::Drive2
                    && other.harmonic == unit.harmonic
                    && other.alpha == unit.alpha
            });
            if let Some(j) = shared {
                let (low_pass, settling) = (self.units[j].low_pass, self.units[j].settling);
                let unit = &mut self.units[i];
                (unit.low_pass, unit.settling) = (low_pass, settling);
                continue;
            }
            let unit = &mut self.units[i];
            let theta = harmonic_phase(self.reference_phase2, unit.harmonic);
            let turn = self.reference_word2.wrapping_mul(u64::from(unit.harmonic));
            let mut rho = Complex64::from_polar(1.0, -phase_to_radians(theta));
            let step = Complex64::from_polar(1.0, -phase_to_radians(turn));
            let alpha = unit.alpha;
            let mut y = unit.low_pass;
            for &s in piece {
                let mut x = rho * s;
                for section in &mut y {
                    *section += (x - *section) * alpha;
                    x = *section;
                }
                rho *= step;
            }
            unit.low_pass = y;
            unit.settling = unit.settling.saturating_sub(piece.len() as u32);
        }
    }
}

impl PidRuntime {
    /// Unit `i`'s reading of its demodulator over the period just ended (its input's
    /// unit), or `None` while its low-pass settles.
    fn read(&self, i: usize) -> Option<f64> {
        let unit = &self.units[i];
        if unit.input == PidInput::MeanDeflection {
            // Mixed at harmonic 0, the boxcar's sum is the samples' own.
            return Some(unit.acc.re / f64::from(self.acc_count));
        }
        let z = match unit.oscillator {
            Oscillator::Drive => {
                // The least-squares sinusoid at kΩ over the period's samples: the boxcar
                // z = a + ā·c, c its image's share (zero over a whole number of samples per
                // period, up to 1/N otherwise, which would ripple a PLL's phase as the drive
                // frequency moves), solved for a.
                let z = unit.acc * (2.0 / f64::from(self.acc_count));
                let c = unit.image / f64::from(self.acc_count);
                (z - c * z.conj()) / (1.0 - c.norm_sqr())
            }
            Oscillator::Drive2 => {
                if unit.settling > 0 {
                    return None;
                }
                // The low-pass holds half the phasor (the image at −kΩ₂ is filtered out).
                unit.low_pass[LOW_PASS_SECTIONS - 1] * 2.0
            }
        };
        Some(match unit.input {
            PidInput::R => z.norm(),
            PidInput::Phase => z.im.atan2(z.re),
            PidInput::X => z.re,
            PidInput::Y => z.im,
            PidInput::FrequencyShift | PidInput::MeanDeflection => {
                unreachable!("read above, or from another unit")
            }
        })
    }

    /// The frequency shift of `oscillator` in force (Hz): where a loop holds its frequency,
    /// that less the plan's (`/drive/frequency`, `/drive2/frequency`); 0 where none does.
    fn frequency_shift(&self, plan: &SynthPlan, oscillator: Oscillator) -> f64 {
        let (held, own) = match oscillator {
            Oscillator::Drive => (self.word_held, plan.drive.word),
            Oscillator::Drive2 => (self.word2_held, plan.frequency_word2),
        };
        held.map_or(0.0, |word| {
            (word as f64 - own as f64) / TWO_POW_64 * plan.sample_rate
        })
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
                rt.drive2.as_ref(),
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
    pub(super) fn update_pids(
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
            // The units on their demodulators first, then those on a value derived from
            // them (a PLL's Δf), which read it after its update.
            for derived in [false, true] {
                for unit_index in 0..PID_COUNT {
                    let unit = &rt.units[unit_index];
                    if !unit.enabled || unit.partial || unit.demodulates() == derived {
                        continue;
                    }
                    let measurement = if derived {
                        rt.frequency_shift(self, unit.oscillator)
                    } else {
                        match rt.read(unit_index) {
                            Some(m) => m,
                            None => continue,
                        }
                    };
                    self.update_unit(rt, unit_index, index, measurement, reading);
                }
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

    /// Updates unit `i` with `measurement` (its input's unit) at sample `index`: its
    /// controller, the output it drives from `index` on, its sums and lock, and `reading`.
    fn update_unit(
        &self,
        rt: &mut PidRuntime,
        i: usize,
        index: u64,
        measurement: f64,
        reading: &mut impl FnMut(PidReading),
    ) {
        let unit = &mut rt.units[i];
        // A phase is read on the circle: the controller sees it within half a turn of its
        // set-point, so the error never jumps by 2π where the phase wraps (a PLL's
        // set-point near ±π is common).
        let fed = match unit.input {
            PidInput::Phase => {
                let setpoint = unit.pid.settings().setpoint;
                setpoint - (setpoint - measurement + PI).rem_euclid(TAU) + PI
            }
            _ => measurement,
        };
        let output = unit.pid.update(fed);
        let error = unit.pid.error();
        let limited = unit.pid.is_limited();
        unit.sums.add(measurement, error, output);
        let pll = unit.input == PidInput::Phase && unit.output.frequency_of().is_some();
        if pll {
            unit.lock.update(!limited && error.abs() < PLL_LOCK_PHASE);
        }
        reading(PidReading {
            unit: i,
            sample: index,
            measurement,
            error,
            output,
            limited,
            locked: pll.then_some(unit.lock.locked),
            lock_losses: unit.lock.losses,
        });
        match unit.output {
            PidTarget::SurfaceDistance => rt.distance = output,
            PidTarget::DriveFrequency => {
                // The limits keep it a valid frequency; should one not be, the drive keeps
                // its word.
                if let Ok(word) = frequency_word(output, self.sample_rate) {
                    rt.word_held = Some(word);
                }
            }
            PidTarget::DriveAmplitude => {
                rt.base_held = Some(output * self.pids.base_per_free);
            }
            PidTarget::Drive2Frequency => {
                if let Ok(word) = frequency_word(output, self.sample_rate) {
                    rt.word2_held = Some(word);
                }
            }
            PidTarget::Drive2Amplitude => {
                if let Some(per) = self.pids.base_per_free2 {
                    rt.base2_held = Some(output * per);
                }
            }
        }
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
