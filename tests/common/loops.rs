//! The live PID units driven as the synthesiser thread drives them, for the tests of the
//! loops (`tests/pids.rs`, `pll.rs`, `fm_afm.rs`, `bimodal_loops.rs`): a plan, its state and
//! the units' runtime, run for simulated time and moved to new settings between blocks; a
//! step response measured against the advisor's prediction; settings refused.

use std::f64::consts::PI;

use ftafm::config::{NodeError, Oscillator, PidInput, PidTarget, Settings};
use ftafm::control::Advice;
use ftafm::synth::{PidReading, PidRuntime, ReferenceChange, SynthPlan, SynthState};

/// A running loop: plan, state and runtime at sample 0 with `settings`.
pub fn start(settings: &Settings, seed: u64) -> (SynthPlan, SynthState, PidRuntime) {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, seed);
    let mut rt = PidRuntime::new(&plan);
    rt.retarget(&plan, &plan, 0, &mut state);
    (plan, state, rt)
}

/// Runs `plan` for `seconds` of simulated time in blocks of 4096: every update of every
/// unit, every change of the lock-in's reference, and the samples.
pub fn run_traced(
    plan: &SynthPlan,
    state: &mut SynthState,
    rt: &mut PidRuntime,
    seconds: f64,
) -> (Vec<PidReading>, Vec<ReferenceChange>, Vec<f64>) {
    let mut block = vec![0.0; 4096];
    let (mut readings, mut changes, mut samples) = (Vec::new(), Vec::new(), Vec::new());
    let end = state.sample_index() + (seconds * plan.sample_rate) as u64;
    while state.sample_index() < end {
        let n = ((end - state.sample_index()) as usize).min(block.len());
        plan.process_pids(
            state,
            rt,
            &mut block[..n],
            &mut |r| readings.push(r),
            &mut |c| changes.push(c),
        );
        samples.extend_from_slice(&block[..n]);
    }
    (readings, changes, samples)
}

/// [`run_traced`]'s updates alone.
pub fn run(
    plan: &SynthPlan,
    state: &mut SynthState,
    rt: &mut PidRuntime,
    seconds: f64,
) -> Vec<PidReading> {
    run_traced(plan, state, rt, seconds).0
}

/// Moves a running loop to `settings` at the next sample, as the synthesiser thread does:
/// the modes back under the plan's own drive, the change of plan, then the loops'.
pub fn change(
    plan: &mut SynthPlan,
    state: &mut SynthState,
    rt: &mut PidRuntime,
    settings: &Settings,
) {
    let next = SynthPlan::new(settings).unwrap();
    rt.release_drive(plan, state);
    state.retarget(plan, &next);
    let index = state.sample_index();
    rt.retarget(plan, &next, index, state);
    *plan = next;
}

/// The measured overshoot (a fraction of the step) and 2 % settling time (s) of the
/// readings' output after a step at sample `from`, from `start` to `end` (the output's
/// unit), at `rate` samples a second: the settling time is that of the first update after
/// the last one outside ±2 % of the step.
pub fn measured_step(
    readings: &[PidReading],
    from: u64,
    rate: f64,
    start: f64,
    end: f64,
) -> (f64, f64) {
    let step = end - start;
    let peak = readings
        .iter()
        .map(|r| (r.output - start) / step)
        .fold(f64::MIN, f64::max);
    let last_out = readings
        .iter()
        .rposition(|r| ((r.output - start) / step - 1.0).abs() > 0.02)
        .expect("the step leaves the band");
    let settled = readings[last_out + 1].sample;
    ((peak - 1.0).max(0.0), (settled - from) as f64 / rate)
}

/// The measured step of unit `unit`'s input when its set-point steps from `settings`' to
/// `to` after `settle` s of simulated time (seed `seed`), followed for `follow` s: the
/// overshoot and 2 % settling time of what its demodulator reads ([`measured_step`]).
pub fn setpoint_step(
    settings: &Settings,
    unit: usize,
    to: f64,
    seed: u64,
    (settle, follow): (f64, f64),
) -> (f64, f64) {
    let mut settings = settings.clone();
    let before = settings.pids[unit].setpoint;
    let (mut plan, mut state, mut rt) = start(&settings, seed);
    let _ = run(&plan, &mut state, &mut rt, settle);
    settings.pids[unit].setpoint = to;
    change(&mut plan, &mut state, &mut rt, &settings);
    let from = state.sample_index();
    // What the unit read, as the step's output.
    let read: Vec<PidReading> = run(&plan, &mut state, &mut rt, follow)
        .iter()
        .filter(|r| r.unit == unit)
        .map(|r| PidReading {
            output: r.measurement,
            ..*r
        })
        .collect();
    measured_step(&read, from, plan.sample_rate, before, to)
}

/// A measured step against `advice`'s linear model: the overshoot within 10 % of the
/// prediction (or 1 % of the step where it predicts under 10 %), the settling time within
/// 10 % (or two update periods of `update` s: the loop's output moves once a period).
pub fn assert_step_as_advised(
    what: &str,
    advice: &Advice,
    overshoot: f64,
    settling: f64,
    update: f64,
) {
    assert!(
        (overshoot - advice.step.overshoot).abs() <= 0.1 * advice.step.overshoot.max(0.1),
        "{what}: overshoot {overshoot}, predicted {}",
        advice.step.overshoot
    );
    assert!(
        (settling - advice.step.settling_time).abs()
            <= (0.1 * advice.step.settling_time).max(2.0 * update),
        "{what}: settling {settling} s, predicted {}",
        advice.step.settling_time
    );
}

/// The error of `changes` applied together to `settings`: by `set_many`'s checks, or by
/// the model's.
pub fn refused(settings: &Settings, changes: &[(&str, serde_json::Value)]) -> NodeError {
    let mut next = settings.clone();
    let values: Vec<(String, serde_json::Value)> = changes
        .iter()
        .map(|(p, v)| (p.to_string(), v.clone()))
        .collect();
    match next.set_many(&values) {
        Err(e) => e,
        Ok(_) => ftafm::model::check(&next).expect_err("accepted"),
    }
}

/// The mean of `values`.
pub fn mean(values: impl IntoIterator<Item = f64>) -> f64 {
    mean_and_spread(values).0
}

/// The mean of `values` and their standard deviation about it (population).
pub fn mean_and_spread(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let v: Vec<f64> = values.into_iter().collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// What a PI unit reads and drives: its oscillator (harmonic 1 of it), its input and its
/// output.
pub type Route = (Oscillator, PidInput, PidTarget);

/// Unit `index` of `s` enabled as a PI on `route`: the input held at `setpoint`, gains for a
/// crossover of `bandwidth` (Hz) on a plant of gain `slope` (input unit per output unit; a
/// negative one, as a PLL's phase against frequency, signs the gains) and time constant
/// `tau` (s), whose pole the PI's zero cancels: i = 2π·bandwidth/slope, p = i·tau; the
/// output within `limits`.
pub fn pi_unit(
    s: &mut Settings,
    index: usize,
    route: Route,
    setpoint: f64,
    (bandwidth, slope, tau): (f64, f64, f64),
    limits: (f64, f64),
) {
    let i = 2.0 * PI * bandwidth / slope;
    let pid = &mut s.pids[index];
    pid.enable = true;
    (pid.oscillator, pid.input, pid.output) = route;
    pid.harmonic = 1;
    pid.setpoint = setpoint;
    (pid.p, pid.i, pid.d) = (i * tau, i, 0.0);
    (pid.output_min, pid.output_max) = limits;
}
