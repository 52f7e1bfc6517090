//! `Pid::update` allocates nothing: the counting global allocator of `dsp_no_alloc` watches
//! warmed-up calls, through saturation, the rate limit, disable and a bumpless enable. The
//! count is per thread, so the test harness's other threads cannot disturb it.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ftafm::control::{Pid, PidSettings};

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
fn update_allocates_nothing() {
    let mut pid = Pid::new(PidSettings {
        setpoint: 0.5,
        p: 4.0,
        i: 200.0,
        d: 1e-3,
        d_bandwidth: 1e3,
        output_min: -1.0,
        output_max: 1.0,
        rate_limit: Some(500.0),
        center: 0.0,
        dt: 1e-4,
    })
    .unwrap();
    // A first-order plant, and a measurement step that saturates the output.
    let mut y = 0.0_f64;
    let mut sum = 0.0;
    let mut run = |pid: &mut Pid, steps: usize, offset: f64| {
        for _ in 0..steps {
            let u = pid.update(y + offset);
            y = 0.99 * y + 0.01 * u;
            sum += u + pid.error() + pid.output();
        }
    };
    run(&mut pid, 1000, 0.0);
    let before = allocations();
    run(&mut pid, 10_000, 0.0);
    run(&mut pid, 10_000, -5.0);
    pid.disable();
    run(&mut pid, 100, 0.0);
    let held = pid.output();
    pid.enable(held);
    run(&mut pid, 10_000, 0.0);
    pid.reset();
    run(&mut pid, 100, 0.0);
    let during = allocations() - before;
    assert!(sum.is_finite() && sum != 0.0, "the loop ran: {sum}");
    assert_eq!(during, 0, "allocations during warmed-up updates");
    // The counter does count: this allocates.
    let v = vec![0u8; 10];
    assert!(allocations() > before, "{v:?}");
}
