//! The machine's own stalls, measured (after jHiccup): a thread asks to sleep [`NAP`], over
//! and over, and records how much later than asked it woke up.
//!
//! A latency spike in the chain is either the chain's doing or the machine's: a busy or
//! descheduled CPU (another process, a virtual machine's host, the kernel) holds up every
//! thread alike. The meter's thread does almost nothing, so its delays are the machine's;
//! a spike in the signal chain that coincides with one of them was not made by the chain.
//! The daemon runs one (`/metrics`, `status`), and so does `ftafm soak` on the client side.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;

use super::block::unix_ns;

/// The sleep asked for each time.
pub const NAP: Duration = Duration::from_millis(1);
/// Stalls at least this long are kept as events, with their time.
pub const EVENT_THRESHOLD_NS: u64 = 5_000_000;
/// Most events kept; later ones are only counted ([`StallMeter::stalls`]).
pub const MAX_EVENTS: usize = 100_000;
/// Largest stall the histogram resolves (60 s); longer ones are clamped to it.
const MAX_NS: u64 = 60_000_000_000;

/// One stall of at least [`EVENT_THRESHOLD_NS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct StallEvent {
    /// Unix time the meter woke up (ns): the stall covers `[end_ns − stall_ns, end_ns]`.
    pub end_ns: u64,
    /// How much later than asked it woke up (ns).
    pub stall_ns: u64,
}

struct Shared {
    stop: AtomicBool,
    /// Every nap's oversleep (ns), since the start.
    histogram: Mutex<Histogram<u64>>,
    /// Largest oversleep since [`StallMeter::take_interval_max`] last looked (ns).
    interval_max: AtomicU64,
    events: Mutex<Vec<StallEvent>>,
    /// Stalls of at least [`EVENT_THRESHOLD_NS`], kept or not.
    stalls: AtomicU64,
}

/// A running stall meter; it stops when dropped.
pub struct StallMeter {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl StallMeter {
    /// Starts the meter's thread, named `name`.
    pub fn start(name: &str) -> std::io::Result<Self> {
        Self::start_with(name, || {
            let asleep = Instant::now();
            std::thread::sleep(NAP);
            asleep.elapsed()
        })
    }

    /// The same with `nap` in place of the timed sleep: it returns how long the nap took
    /// (tests script a stalled machine, whatever the machine running them does).
    fn start_with(
        name: &str,
        nap: impl FnMut() -> Duration + Send + 'static,
    ) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            histogram: Mutex::new(
                Histogram::new_with_bounds(1, MAX_NS, 3).expect("static bounds are valid"),
            ),
            interval_max: AtomicU64::new(0),
            events: Mutex::new(Vec::new()),
            stalls: AtomicU64::new(0),
        });
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || measure(&s, nap))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Every nap's oversleep since the start (ns).
    pub fn histogram(&self) -> Histogram<u64> {
        self.shared
            .histogram
            .lock()
            .map(|h| h.clone())
            .unwrap_or_else(|e| e.into_inner().clone())
    }

    /// The largest oversleep since the last call (ns), which starts a new interval.
    pub fn take_interval_max(&self) -> u64 {
        self.shared.interval_max.swap(0, Ordering::Relaxed)
    }

    /// The first [`MAX_EVENTS`] stalls of at least [`EVENT_THRESHOLD_NS`], oldest first.
    pub fn events(&self) -> Vec<StallEvent> {
        self.shared
            .events
            .lock()
            .map(|e| e.clone())
            .unwrap_or_default()
    }

    /// Stalls of at least [`EVENT_THRESHOLD_NS`] since the start, kept or not.
    pub fn stalls(&self) -> u64 {
        self.shared.stalls.load(Ordering::Relaxed)
    }
}

impl Drop for StallMeter {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn measure(shared: &Shared, mut nap: impl FnMut() -> Duration) {
    while !shared.stop.load(Ordering::Relaxed) {
        let late = nap().saturating_sub(NAP).as_nanos() as u64;
        let late = late.clamp(1, MAX_NS);
        if let Ok(mut h) = shared.histogram.lock() {
            let _ = h.record(late);
        }
        shared.interval_max.fetch_max(late, Ordering::Relaxed);
        if late >= EVENT_THRESHOLD_NS {
            shared.stalls.fetch_add(1, Ordering::Relaxed);
            if let Ok(mut e) = shared.events.lock()
                && e.len() < MAX_EVENTS
            {
                e.push(StallEvent {
                    end_ns: unix_ns(),
                    stall_ns: late,
                });
            }
        }
    }
}

/// How many of `spans` (each `[end − len, end]`, ns) overlap a stall of at least
/// `min_stall_ns` among `events` (sorted by `end_ns`, as [`StallMeter::events`] returns
/// them).
pub fn overlapping(spans: &[(u64, u64)], events: &[StallEvent], min_stall_ns: u64) -> usize {
    let big: Vec<(u64, u64)> = events
        .iter()
        .filter(|e| e.stall_ns >= min_stall_ns)
        .map(|e| (e.end_ns.saturating_sub(e.stall_ns), e.end_ns))
        .collect();
    spans
        .iter()
        .filter(|&&(end, len)| {
            let start = end.saturating_sub(len);
            // First stall ending at or after the span's start; it overlaps if it began
            // before the span ended.
            let i = big.partition_point(|&(_, e)| e < start);
            big.get(i).is_some_and(|&(s, _)| s <= end)
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_overlap_stalls() {
        let events = [
            StallEvent {
                end_ns: 100,
                stall_ns: 50,
            },
            StallEvent {
                end_ns: 1_000,
                stall_ns: 5,
            },
            StallEvent {
                end_ns: 2_000,
                stall_ns: 500,
            },
        ];
        // [40, 60] meets [50, 100]; [200, 300] meets nothing; [995, 1000] meets only the
        // 5 ns stall, which is too short; [1400, 1600] meets [1500, 2000].
        let spans = [(60, 20), (300, 100), (1_000, 5), (1_600, 200)];
        assert_eq!(overlapping(&spans, &events, 10), 2);
        assert_eq!(overlapping(&spans, &events, 1), 3);
        assert_eq!(overlapping(&spans, &events, 1_000), 0);
    }

    #[test]
    fn a_stall_is_measured_and_kept_with_its_time() {
        // The first 50 naps are scripted: every 10th oversleeps by 12 ms, as if the machine
        // had not run the thread; the rest take exactly NAP. Then naps are real sleeps that
        // report NAP, so nothing the test machine does shows up.
        let before = unix_ns();
        let mut n = 0;
        let meter = StallMeter::start_with("stall-test", move || {
            n += 1;
            std::thread::sleep(Duration::from_micros(100));
            let extra = if n <= 50 && n % 10 == 0 { 12 } else { 0 };
            NAP + Duration::from_millis(extra)
        })
        .unwrap();
        while meter.histogram().len() < 60 {
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(meter.take_interval_max(), 12_000_000);
        let events = meter.events();
        assert_eq!(events.len(), 5);
        assert_eq!(meter.stalls(), 5);
        for e in &events {
            assert!(e.stall_ns == 12_000_000 && e.end_ns >= before, "{e:?}");
        }
        // Most naps were not stalled: the median is well under the stall.
        assert!(meter.histogram().value_at_quantile(0.5) < 10_000_000);
        drop(meter);
    }

    #[test]
    fn the_real_meter_runs_and_stops() {
        let meter = StallMeter::start("stall-test").unwrap();
        // Five naps, however long a busy machine takes to run them.
        let deadline = Instant::now() + Duration::from_secs(60);
        while meter.histogram().len() < 5 {
            assert!(Instant::now() < deadline, "the meter never napped");
            std::thread::sleep(Duration::from_millis(1));
        }
        drop(meter);
    }
}
