//! The real-time threads (`ftafm-synth`, `ftafm-dsp` and its workers `ftafm-dsp-w1` …)
//! allocate nothing once running, also while settings change: a global allocator that
//! counts allocations made on them.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use ftafm::config::default_settings;
use ftafm::pipeline::Pipeline;

struct Counting;

static REALTIME_ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Whether this thread is one of the pipeline's real-time threads (decided once).
    static REALTIME: Cell<Option<bool>> = const { Cell::new(None) };
}

fn on_realtime_thread() -> bool {
    REALTIME
        .try_with(|flag| match flag.get() {
            Some(v) => v,
            None => {
                // Decided on the thread's first allocation, which is before its loop runs.
                let v = std::thread::current().name().is_some_and(|n| {
                    matches!(n, "ftafm-synth" | "ftafm-dsp" | "ftafm-probe")
                        || n.starts_with("ftafm-dsp-w")
                });
                flag.set(Some(v));
                v
            }
        })
        .unwrap_or(false)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if on_realtime_thread() {
            REALTIME_ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if on_realtime_thread() {
            // Freeing on a real-time thread is as bad as allocating.
            REALTIME_ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if on_realtime_thread() {
            REALTIME_ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The counter is per thread name, not per pipeline: one pipeline at a time, or a starting
/// pipeline's threads would count against a running test.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn realtime_threads_do_not_allocate_or_free_while_running() {
    realtime_threads_do_not_allocate_or_free_on(1);
}

/// The same with the bank split over the DSP thread and two workers (forced, whatever the
/// machine's cores): the hand-offs, the shards' output buffers and the merge allocate
/// nothing either, also across new plans.
#[test]
fn dsp_workers_do_not_allocate_or_free_while_running() {
    realtime_threads_do_not_allocate_or_free_on(3);
}

fn realtime_threads_do_not_allocate_or_free_on(threads: u32) {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut settings = default_settings();
    settings.synth.realtime = false;
    settings.dsp.threads = threads;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    // Let both threads pass their start-up (buffers are allocated before the loops).
    while pipeline.counters().demod_frames < 20 {
        output.drain();
        std::thread::sleep(Duration::from_millis(1));
    }
    let before = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let processed = pipeline.counters().samples_processed;
    let pages_taken = pipeline.counters().noise_pages_taken;
    for step in 0..6 {
        let mut next = settings.clone();
        next.sample.youngs_modulus = 100e9 + step as f64 * 5e9;
        next.demods[3].harmonic = 5 + step;
        next.drive.frequency = 100e3 + step as f64 * 10.0;
        // A new seed makes the pages of noise drawn ahead stale: thrown away, not freed.
        next.synth.seed = 1 + step as u64 / 2;
        pipeline.apply(&next).unwrap();
        // Until both threads have taken the plan up (an event, not a time: a slow build
        // takes longer).
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let c = pipeline.counters();
            if c.synth_plans_applied > step as u64 && c.dsp_plans_applied > step as u64 {
                break;
            }
            assert!(Instant::now() < deadline, "plan {step} not taken up: {c:?}");
            output.drain();
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    // A consumer that stops taking frames: the queues fill and frames are dropped (and
    // counted) on the DSP thread, still without allocating or freeing there. Stalled
    // until spectra were dropped and ten million samples more went through.
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let c = pipeline.counters();
        // The DSP thread draws noise ahead when it is ahead of the synthesiser: on a busy
        // machine that may take a while, so it is waited for too.
        if c.spectrum_frames_dropped > 0
            && c.samples_processed > processed + 10_000_000
            && c.noise_pages_taken > pages_taken
        {
            break;
        }
        assert!(Instant::now() < deadline, "stalled 120 s: {c:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    output.drain();
    let after = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let c = pipeline.counters();
    assert!(
        c.spectrum_frames_dropped > 0,
        "the stalled consumer made spectra drop: {c:?}"
    );
    assert!(
        c.samples_processed > processed + 10_000_000,
        "the chain ran: {c:?}"
    );
    assert_eq!((c.synth_plans_applied, c.dsp_plans_applied), (6, 6));
    assert!(
        c.noise_pages_taken > pages_taken,
        "the DSP thread drew pages of noise ahead and the synthesiser took them: {c:?}"
    );
    assert_eq!(
        after - before,
        0,
        "allocations or frees on the real-time threads"
    );
    drop(pipeline);
    // Sanity of the instrument: a thread of such a name that does allocate is seen.
    for name in ["ftafm-probe", "ftafm-dsp-w9"] {
        let seen = std::thread::Builder::new()
            .name(name.into())
            .spawn(|| {
                let before = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
                drop(std::hint::black_box(vec![0u8; 32]));
                REALTIME_ALLOCATIONS.load(Ordering::SeqCst) - before
            })
            .unwrap()
            .join()
            .unwrap();
        assert!(seen >= 1, "{name}");
    }
}

#[test]
fn a_running_scan_allocates_nothing_on_the_realtime_threads() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut settings = default_settings();
    settings.synth.realtime = false;
    settings.scan.enable = true;
    settings.scan.pixels = 16;
    settings.scan.line_rate = 50.0;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    while pipeline.counters().pixels < 40 {
        output.drain();
        std::thread::sleep(Duration::from_millis(1));
    }
    let before = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let pixels = pipeline.counters().pixels;
    // Raster restarts, gains, setpoint, a new inclusion modulus (new tap tables, built
    // here), the scan off and on again.
    let mut next = settings.clone();
    let changes: [&dyn Fn(&mut ftafm::config::Settings); 6] = [
        &|s| s.scan.line_rate = 40.0,
        &|s| s.feedback.integral = 800.0,
        &|s| s.feedback.setpoint = 17e-9,
        &|s| s.inclusions[0].youngs_modulus = 60e9,
        &|s| s.scan.enable = false,
        &|s| s.scan.enable = true,
    ];
    for change in changes {
        change(&mut next);
        pipeline.apply(&next).unwrap();
        for _ in 0..50 {
            output.drain();
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    let after = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let c = pipeline.counters();
    assert!(c.pixels > pixels + 200, "the scan ran: {c:?}");
    assert!(c.topography_pixels > 200, "{c:?}");
    assert_eq!(c.synth_plans_applied, 6);
    assert_eq!(
        after - before,
        0,
        "allocations or frees on the real-time threads while scanning"
    );
}

/// The PID units on the synthesiser thread (their demodulators, controllers, the coupled
/// surface they move, the board their updates go to and the `pids` stream's queue) allocate
/// and free nothing, through a start, new gains, a stop with the surface held, a restart
/// and a new `/surface/distance`.
#[test]
fn running_pids_allocate_nothing_on_the_realtime_threads() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut settings = default_settings();
    settings.synth.realtime = false;
    settings.pids[0].setpoint = 17e-9;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let board = pipeline.counters_handle();
    // Every update queued as for the `pids` stream's subscribers too.
    board.pids().set_streaming(true);
    while pipeline.counters().samples_processed < 1_000_000 {
        output.drain();
        std::thread::sleep(Duration::from_millis(1));
    }
    let before = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let mut next = settings.clone();
    let changes: [&dyn Fn(&mut ftafm::config::Settings); 5] = [
        &|s| s.pids[0].enable = true,
        &|s| s.pids[0].i = 2000.0,
        &|s| s.pids[0].enable = false,
        &|s| s.pids[0].enable = true,
        &|s| {
            s.pids[0].enable = false;
            s.surface.distance = 21e-9;
        },
    ];
    let mut updates = Vec::new();
    for change in changes {
        change(&mut next);
        pipeline.apply(&next).unwrap();
        for _ in 0..50 {
            output.drain();
            std::thread::sleep(Duration::from_millis(2));
        }
        updates.push(board.pids().latest(0).map_or(0, |u| u.updates));
    }
    let after = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    assert!(updates[0] > 100, "the loop ran: {updates:?}");
    assert!(
        updates[1] > updates[0] && updates[3] > updates[2],
        "{updates:?}"
    );
    assert_eq!(pipeline.counters().synth_plans_applied, 5);
    assert!(
        pipeline.counters().pid_updates > 100,
        "queued for the stream"
    );
    assert_eq!(
        after - before,
        0,
        "allocations or frees on the real-time threads while the PIDs ran"
    );
}

/// A streamed source (`/source/kind = "stream"`): the synthesiser thread passing a client's
/// samples on, across gaps, a start, a full feed and a change back to the synthesiser with
/// samples still in the feed, allocates and frees nothing on the real-time threads.
#[test]
fn a_streamed_source_allocates_nothing_on_the_realtime_threads() {
    use ftafm::pipeline::{FrameHeader, SampleType};
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut settings = default_settings();
    settings.synth.realtime = false;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    while pipeline.counters().demod_frames < 20 {
        output.drain();
        std::thread::sleep(Duration::from_millis(1));
    }
    let before = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let inlet = output.inlet.clone();
    let frame = |first: u64, n: usize| {
        let data: Vec<u8> = (0..n)
            .flat_map(|i| ((i as f64 * 0.37).sin()).to_le_bytes())
            .collect();
        FrameHeader {
            id: first,
            sample_type: SampleType::F64,
            sample_rate: settings.synth.sample_rate,
            scale: 1e-8,
            first_index: first,
        }
        .frame(&data)
    };
    let mut stream = settings.clone();
    stream.source.kind = ftafm::config::SourceKind::Stream;
    let wait = |pipeline: &Pipeline,
                output: &mut ftafm::pipeline::PipelineOutput,
                what: &str,
                done: &dyn Fn(&ftafm::pipeline::CountersSnapshot) -> bool| {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let c = pipeline.counters();
            if done(&c) {
                return;
            }
            assert!(Instant::now() < deadline, "{what}: {c:?}");
            output.drain();
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    for round in 0..2u64 {
        pipeline.apply(&stream).unwrap();
        let processed = pipeline.counters().samples_processed;
        // Frames with a gap every fourth, as fast as the test can make them: where the feed
        // fills, frames drop whole (counted) and become gaps.
        let mut first = 17;
        let mut sent = 0;
        for i in 0..400u64 {
            let r = inlet.push_frame(1, &frame(first, 65_536));
            let (_, receipt) = r.unwrap();
            sent += receipt.accepted;
            first += 65_536 + if i % 4 == 3 { 1000 } else { 0 };
        }
        wait(
            &pipeline,
            &mut output,
            "the streamed samples went through",
            &|c| c.samples_processed >= processed + sent,
        );
        // Samples left in the feed when the source changes back: discarded, counted.
        inlet.push_frame(1, &frame(first, 65_536)).unwrap();
        pipeline.apply(&settings).unwrap();
        wait(&pipeline, &mut output, "back to the synthesiser", &|c| {
            c.synth_plans_applied >= 2 * round + 2
        });
        inlet.release(1);
    }
    let after = REALTIME_ALLOCATIONS.load(Ordering::SeqCst);
    let c = pipeline.counters();
    assert!(c.stream_gap_samples > 0, "{c:?}");
    assert!(c.discontinuities > 0, "{c:?}");
    assert_eq!(
        after - before,
        0,
        "allocations or frees on the real-time threads with a streamed source: {c:?}"
    );
}
