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

/// The DSP stage split over three threads ([`DspPlan`] with `/dsp/threads` = 3 and a
/// [`DspTeam`] of two workers): warmed-up blocks allocate nothing on the calling thread (the
/// counter is per thread); the workers' own allocations are counted by
/// `pipeline_no_alloc`, where they run in the pipeline.
#[test]
fn threaded_dsp_plan_allocates_nothing_on_the_calling_thread() {
    use ftafm::config::default_settings;
    use ftafm::pipeline::{DemodValue, DspPlan, DspSink, DspTeam};

    struct Count(usize, usize, f64);
    impl DspSink for Count {
        fn demod(&mut self, _: u64, v: DemodValue) {
            self.0 += 1;
            self.2 += v.x;
        }
        fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, _: u64, _: f64, bins: I) {
            self.1 += 1;
            self.2 += bins.sum::<f64>();
        }
    }

    let mut settings = default_settings();
    settings.dsp.threads = 3;
    settings.spectrum.size = 4096;
    settings.spectrum.rate = 1000.0;
    for d in &mut settings.demods {
        d.rate = 20e3;
    }
    let mut plan = DspPlan::new(&settings).unwrap();
    assert_eq!(plan.shards(), 3);
    let mut team = DspTeam::spawn(2, false).unwrap();
    let (fs, fd) = (settings.synth.sample_rate, settings.drive.frequency);
    let word = ftafm::timebase::frequency_word(fd, fs).unwrap();
    let signal: Vec<f64> = (0..400_000)
        .map(|m| 1e-8 * (std::f64::consts::TAU * fd / fs * m as f64).cos())
        .collect();
    let mut sink = Count(0, 0, 0.0);
    // Blocks as the ring gives them, then longer than a hand-off piece.
    let mut run = |range: std::ops::Range<usize>, len: usize, sink: &mut Count| {
        for (i, block) in signal[range.clone()].chunks(len).enumerate() {
            let first = (range.start + i * len) as u64;
            plan.process_block(&mut team, word.wrapping_mul(first), word, block, sink);
        }
    };
    run(0..40_960, 4096, &mut sink);
    let before = allocations();
    run(40_960..400_000, 9000, &mut sink);
    let during = allocations() - before;
    assert!(
        sink.0 > 10_000 && sink.1 > 30,
        "the test did work: {} {}",
        sink.0,
        sink.1
    );
    assert_eq!(during, 0, "allocations during warmed-up threaded blocks");
}
