//! The synthesiser's hot loop allocates nothing: a counting global allocator around
//! `process` (and the pipeline's `process_window` with the DSP thread's `Digitiser`) on
//! warmed-up state, for every noise configuration and both engines, and across
//! plan changes, a switch of engine included.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ftafm::config::{Engine, default_settings};
use ftafm::synth::{
    Digitiser, PidRuntime, ScanLoops, ScanRuntime, SynthPlan, SynthState, WindowSample,
};

struct Counting;

thread_local! {
    // Per thread, so tests running side by side do not count each other's allocations;
    // const-initialised, so reading it allocates nothing itself.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    ALLOCATIONS.with(|a| a.set(a.get() + 1));
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f` on this thread (where the synthesiser runs).
fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

#[test]
fn process_and_retarget_allocate_nothing() {
    // The counter does see allocations (so a zero below means something).
    assert!(allocations_in(|| drop(std::hint::black_box(vec![1u8; 64]))) >= 1);
    let mut configurations = Vec::new();
    for noise in [false, true] {
        for modes in [
            vec![100.0],
            vec![100.0, 417.0, 340.0, 200.0, 26.0],
            vec![100.0; 12],
        ] {
            for engine in [Engine::Paper, Engine::Coupled] {
                let mut s = default_settings();
                s.noise.enable = noise;
                s.cantilever.q = modes.clone();
                s.synth.engine = engine;
                configurations.push(s);
            }
        }
    }
    for settings in &configurations {
        let plan = SynthPlan::new(settings).unwrap();
        let mut state = SynthState::steady(&plan, 1);
        let mut block = vec![0.0; 4096];
        plan.process(&mut state, &mut block);
        let n = allocations_in(|| {
            for len in [4096, 1, 777, 4096] {
                plan.process(&mut state, &mut block[..len]);
            }
        });
        assert_eq!(
            n,
            0,
            "process allocated {n} times ({} modes, noise {}, {:?} engine)",
            plan.mode_count(),
            settings.noise.enable,
            settings.synth.engine
        );
        // The pipeline's split: the signal through the ADC's window here, finished by the
        // DSP thread's stage (its first page of detector deviates drawn in its buffer).
        let mut window = vec![WindowSample::default(); 4096];
        let mut digitiser = Digitiser::new(4096);
        let n = allocations_in(|| {
            for len in [4096, 1, 777, 4096] {
                let index = state.sample_index();
                let input = plan.process_window(&mut state, &mut window[..len]);
                let (a, b) = window[..len].split_at(len / 2);
                digitiser.finish(&input, index, [a, b], &mut block[..len]);
            }
        });
        assert_eq!(
            n,
            0,
            "process_window or finish allocated {n} times ({} modes, noise {}, {:?} engine)",
            plan.mode_count(),
            settings.noise.enable,
            settings.synth.engine
        );
        // A plan change is applied on the real-time thread too (the plan itself is built
        // elsewhere): the state hand-over must not allocate either.
        let mut softer = settings.clone();
        softer.sample.youngs_modulus = 100e9;
        let next = SynthPlan::new(&softer).unwrap();
        let n = allocations_in(|| {
            state.retarget(&plan, &next);
            next.process(&mut state, &mut block);
        });
        assert_eq!(n, 0, "retarget allocated {n} times");
        // And a switch of engine while running.
        let mut other = settings.clone();
        other.synth.engine = match settings.synth.engine {
            Engine::Paper => Engine::Coupled,
            Engine::Coupled => Engine::Paper,
        };
        let switched = SynthPlan::new(&other).unwrap();
        let n = allocations_in(|| {
            state.retarget(&next, &switched);
            switched.process(&mut state, &mut block);
        });
        assert_eq!(n, 0, "an engine switch allocated {n} times");
    }
}

/// A running scan (raster, feedback, the tap force or the coupled surface following the
/// sample) and its start on the real-time thread allocate nothing, on either engine.
#[test]
fn a_scan_allocates_nothing() {
    for engine in [Engine::Paper, Engine::Coupled] {
        let mut s = default_settings();
        s.synth.engine = engine;
        s.scan.enable = true;
        s.scan.pixels = 16;
        s.scan.line_rate = 1000.0;
        let plan = SynthPlan::new(&s).unwrap();
        let mut state = SynthState::steady(&plan, 1);
        let mut rt = ScanRuntime::new(&plan);
        let mut block = vec![0.0; 4096];
        let mut pixels = 0usize;
        let n = allocations_in(|| {
            rt.retarget(&plan, &plan, 0);
            // 20 ms: 20 lines over both regions.
            for _ in 0..50 {
                plan.process_scan(&mut state, &mut rt, None, &mut block, &mut |_| pixels += 1);
            }
        });
        assert!(pixels > 100, "{engine:?}: the scan ran ({pixels} pixels)");
        assert_eq!(n, 0, "{engine:?}: the scan allocated {n} times");
    }
}

/// A scan with bimodal AFM's mode-2 loops beside it (a PLL moving the second excitation
/// and the reference, an amplitude loop) allocates nothing, started with the scan.
#[test]
fn a_scan_with_mode_two_loops_allocates_nothing() {
    use ftafm::config::{Oscillator, PidInput, PidTarget};
    let mut s = default_settings();
    s.scan.enable = true;
    s.scan.pixels = 16;
    s.scan.line_rate = 1000.0;
    s.drive2.enable = true;
    let f2 = s.drive2.frequency;
    for (unit, input, output, (min, max), setpoint) in [
        (
            0,
            PidInput::Phase,
            PidTarget::Drive2Frequency,
            (0.99 * f2, 1.01 * f2),
            0.3,
        ),
        (
            1,
            PidInput::R,
            PidTarget::Drive2Amplitude,
            (0.0, 5e-9),
            1e-10,
        ),
    ] {
        let pid = &mut s.pids[unit];
        pid.enable = true;
        pid.oscillator = Oscillator::Drive2;
        (pid.input, pid.output, pid.setpoint) = (input, output, setpoint);
        (pid.output_min, pid.output_max) = (min, max);
        (pid.p, pid.i) = (0.0, if unit == 0 { -2e5 } else { 1e3 });
    }
    let plan = SynthPlan::new(&s).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut rt = ScanRuntime::new(&plan);
    let mut loops = PidRuntime::new(&plan);
    let mut block = vec![0.0; 4096];
    let (mut pixels, mut updates, mut references) = (0usize, 0usize, 0usize);
    let n = allocations_in(|| {
        rt.retarget(&plan, &plan, 0);
        loops.retarget(&plan, &plan, 0, &mut state);
        for _ in 0..50 {
            let sinks = ScanLoops {
                runtime: &mut loops,
                reading: &mut |_| updates += 1,
                reference: &mut |_| references += 1,
            };
            plan.process_scan(&mut state, &mut rt, Some(sinks), &mut block, &mut |_| {
                pixels += 1
            });
        }
    });
    assert!(pixels > 100, "the scan ran ({pixels} pixels)");
    assert!(updates > 1000, "the loops ran ({updates} updates)");
    assert!(
        references > 10,
        "the PLL moved the reference ({references} times)"
    );
    assert_eq!(n, 0, "the scan with loops allocated {n} times");
}

/// The PID units on the real-time thread allocate nothing: a loop running (its
/// demodulator, controller and the coupled surface it moves), started, retuned, stopped
/// and restarted by plan changes, a PLL and an amplitude loop moving the drive (the modes
/// re-based, the reference following), with every noise source on.
#[test]
fn running_pids_allocate_nothing() {
    use ftafm::config::PidInput;
    let mut s = default_settings();
    s.pids[0].enable = true;
    s.pids[0].setpoint = 15e-9;
    let plan = SynthPlan::new(&s).unwrap();
    let mut retuned = s.clone();
    retuned.pids[0].i = 2400.0;
    retuned.pids[0].rate = 1e-3;
    retuned.pids[0].d = 1e-6;
    retuned.pids[0].harmonic = 2;
    retuned.pids[0].input = PidInput::Phase;
    retuned.pids[0].setpoint = 0.5;
    let retuned = SynthPlan::new(&retuned).unwrap();
    let mut stopped = s.clone();
    stopped.pids[0].enable = false;
    let stopped = SynthPlan::new(&stopped).unwrap();
    // A PLL on harmonic 1's phase and an amplitude loop on the drive.
    let mut drive = stopped_settings_with_drive_loops(&s);
    let driven = SynthPlan::new(&drive).unwrap();
    drive.pids[1].enable = false;
    drive.pids[2].enable = false;
    let released = SynthPlan::new(&drive).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut rt = PidRuntime::new(&plan);
    let mut block = vec![0.0; 4096];
    let mut updates = 0usize;
    let mut references = 0usize;
    let n = allocations_in(|| {
        rt.retarget(&plan, &plan, 0, &mut state);
        let mut run = |plan: &SynthPlan, state: &mut SynthState, rt: &mut PidRuntime, len| {
            plan.process_pids(
                state,
                rt,
                &mut block[..len],
                &mut |_| updates += 1,
                &mut |_| references += 1,
            );
        };
        for _ in 0..10 {
            run(&plan, &mut state, &mut rt, 4096);
        }
        let mut from = &plan;
        for (to, lengths) in [
            (&retuned, &[4096, 1, 777][..]),
            (&stopped, &[4096][..]),
            (&plan, &[4096][..]),
            (&driven, &[4096, 4096, 3, 4096][..]),
            (&released, &[4096][..]),
        ] {
            rt.release_drive(from, &mut state);
            state.retarget(from, to);
            let index = state.sample_index();
            rt.retarget(from, to, index, &mut state);
            for &len in lengths {
                run(to, &mut state, &mut rt, len);
            }
            from = to;
        }
    });
    assert!(
        references > 50,
        "the PLL moved the reference ({references} times)"
    );
    assert!(updates > 400, "the loops ran ({updates} updates)");
    assert_eq!(n, 0, "the PIDs allocated {n} times");
}

/// `s` with PID 0 off, PID 1 a PLL on harmonic 1's phase driving the drive frequency
/// within ±1 %, and PID 2 an amplitude loop driving the drive's amplitude.
fn stopped_settings_with_drive_loops(s: &ftafm::config::Settings) -> ftafm::config::Settings {
    use ftafm::config::{PidInput, PidTarget};
    let mut s = s.clone();
    s.pids[0].enable = false;
    let f = s.drive.frequency;
    let pll = &mut s.pids[1];
    pll.enable = true;
    pll.input = PidInput::Phase;
    pll.harmonic = 1;
    // Held at π, the resonance (tests/pll.rs), with a 500 Hz loop.
    pll.setpoint = std::f64::consts::PI;
    pll.i = -1.57e6;
    pll.p = -500.0;
    pll.output = PidTarget::DriveFrequency;
    pll.output_min = 0.99 * f;
    pll.output_max = 1.01 * f;
    let amplitude = &mut s.pids[2];
    amplitude.enable = true;
    amplitude.input = PidInput::R;
    amplitude.harmonic = 1;
    amplitude.setpoint = 10e-9;
    amplitude.i = 1000.0;
    amplitude.output = PidTarget::DriveAmplitude;
    amplitude.output_min = 0.0;
    amplitude.output_max = 100e-9;
    s
}
