//! The synthesiser's hot loop allocates nothing: a counting global allocator around
//! `process` on warmed-up state, for every noise configuration and both engines, and across
//! plan changes, a switch of engine included.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use ftafm::config::{Engine, default_settings};
use ftafm::synth::{SynthPlan, SynthState};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f` (the test runs single-threaded in this binary's only test).
fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    f();
    ALLOCATIONS.load(Ordering::SeqCst) - before
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
