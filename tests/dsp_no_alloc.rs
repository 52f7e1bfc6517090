//! `process` of the real-time blocks allocates nothing: a counting global allocator watches
//! warmed-up calls. The count is per thread, so the test harness's other threads cannot
//! disturb it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ftafm::dsp::{
    Demodulator, LockInBank, LowPass, LowPassState, SlidingSpectrum, SpectrumConfig, Window,
};

struct Counting;

thread_local! {
    // Const-initialised and without destructor: using it cannot itself allocate.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: defers every operation to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as ours.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as ours.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn process_allocates_nothing() {
    let fs = 10e6;
    let fd = 100.0123e3;
    let demods: Vec<Demodulator> = (0..32)
        .map(|k| Demodulator::new(k, 1 + k % 8, 50e-6, 100e3))
        .collect();
    let signal: Vec<f64> = (0..40_000)
        .map(|m| 1e-8 * (std::f64::consts::TAU * fd / fs * m as f64).cos())
        .collect();
    let mut fast = LockInBank::new(fs, fd, &demods).unwrap();
    let mut portable = LockInBank::new(fs, fd, &demods)
        .unwrap()
        .with_portable_kernel();
    let mut spectra: Vec<SlidingSpectrum> = Window::ALL
        .iter()
        .map(|&window| {
            SlidingSpectrum::new(SpectrumConfig {
                sample_rate: fs,
                size: 4096,
                hop: 1000,
                window,
            })
            .unwrap()
        })
        .collect();
    let lowpass = LowPass::new(8, 1e-4, 1e6).unwrap();
    let mut lp_state = LowPassState::default();
    let mut lp_out = vec![0.0; 4096];

    let mut outputs = 0usize;
    let mut frames = 0usize;
    let mut run = |range: std::ops::Range<usize>, outputs: &mut usize, frames: &mut usize| {
        for block in signal[range].chunks(4096) {
            fast.process(block, |s| *outputs += (s.x != 0.0) as usize);
            portable.process(block, |s| *outputs += (s.y != 0.0) as usize);
            for s in &mut spectra {
                s.process(block, |f| *frames += f.bins.len().min(1));
            }
            lowpass.process(&mut lp_state, block, &mut lp_out[..block.len()]);
        }
        fast.set_drive_frequency(fd * 1.001).unwrap();
        fast.set_drive_frequency(fd).unwrap();
    };

    // Warm up: the first blocks, frames and outputs.
    run(0..10_000, &mut outputs, &mut frames);
    let before = allocations();
    run(10_000..40_000, &mut outputs, &mut frames);
    let during = allocations() - before;

    assert!(
        outputs > 1000 && frames > 50,
        "the test did work: {outputs} outputs, {frames} frames"
    );
    assert_eq!(during, 0, "allocations during warmed-up process calls");
    // The counter does count: this allocates.
    let v = vec![0u8; 10];
    assert!(allocations() > before, "{v:?}");
}
