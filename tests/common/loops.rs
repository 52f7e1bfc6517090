//! The live PID units driven as the synthesiser thread drives them, for the tests of the
//! loops (`tests/pids.rs`, `pll.rs`, `fm_afm.rs`): a plan, its state and the units'
//! runtime, run for simulated time and moved to new settings between blocks.

use ftafm::config::Settings;
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
