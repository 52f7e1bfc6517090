//! `ftafm bench`: the whole chain on its threads, measured.
//!
//! Free-running (the default) the chain goes as fast as its slower thread allows, which
//! gives the throughputs and the real-time factor. With `realtime` it is paced by the wall
//! clock, as the daemon runs, which is the soak test: it must finish with zero overruns.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use serde::Serialize;

use super::{ConfigArg, EXIT_USAGE, load, print_report};
use crate::config::Settings;
use crate::pipeline::{CountersSnapshot, Pipeline, PipelineError};

/// What `ftafm bench` reports; `--json` prints it as one object.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    /// The machine: CPU model (family and model numbers), CPUs, vector build
    /// (`crate::cpu::machine`), so that a figure carries where it was measured.
    pub machine: String,
    /// The core's clock (GHz), `null` where it cannot be had: with it a CPU time reads as
    /// cycles, which compare across machines. How it was obtained: `clock_source`.
    pub clock_ghz: Option<f64>,
    /// Where `clock_ghz` comes from: `"dependent adds"` (measured before the run by a chain
    /// of dependent integer additions, one a cycle: `crate::cpu::clock_ghz`; under a
    /// hypervisor the only measure of the clock the core runs at) or `"/proc/cpuinfo"` (its
    /// `cpu MHz`, often only the nominal clock in a virtual machine), `"none"`.
    pub clock_source: &'static str,
    /// `/proc/cpuinfo`'s `cpu MHz` of the first CPU, for comparison (MHz), `null` without it.
    pub cpuinfo_mhz: Option<f64>,
    /// Tip-force engine, and the coupled engine's sub-steps per sample in contact.
    pub engine: &'static str,
    pub contact_substeps: u32,
    /// Photodiode sample rate (Hz).
    pub sample_rate: f64,
    /// Enabled demodulators.
    pub demodulators: usize,
    /// Whether the run was paced by the wall clock.
    pub realtime: bool,
    /// Wall-clock duration of the run (s).
    pub seconds: f64,
    /// Samples the synthesiser produces per second of its own compute time (one core).
    pub synth_samples_per_s: f64,
    /// Samples the DSP consumes per second of its own compute time (one core).
    pub dsp_samples_per_s: f64,
    /// Samples through the whole chain per wall-clock second.
    pub chain_samples_per_s: f64,
    /// chain_samples_per_s / sample_rate: how many times faster than real time the chain
    /// runs (free-running), or ≈ 1 when paced.
    pub realtime_factor: f64,
    /// Fraction of wall time the synthesiser thread computed (1 = a whole core).
    pub synth_load: f64,
    /// Fraction of wall time the DSP thread computed.
    pub dsp_load: f64,
    /// CPU time of the chain's threads per sample through it (ns): the synthesiser, the DSP
    /// thread and its lock-in workers, each thread's own CPU clock (`CLOCK_THREAD_CPUTIME_ID`),
    /// so time the thread waited or was descheduled does not count. Free-running, the DSP
    /// thread fills its waits by drawing the synthesiser's noise deviates: that work is
    /// counted here, on the DSP's side. `null` where the thread clocks cannot be read.
    pub cpu_ns_per_sample: Option<f64>,
    /// The synthesiser thread's part of `cpu_ns_per_sample` (ns).
    pub synth_cpu_ns_per_sample: Option<f64>,
    /// The DSP threads' part of `cpu_ns_per_sample` (ns).
    pub dsp_cpu_ns_per_sample: Option<f64>,
    /// `cpu_ns_per_sample` × `clock_ghz`: the chain's thread-cycles per sample, the figure
    /// that compares across machines (cycles at the clock measured, not counted by hardware).
    pub cycles_per_sample: Option<f64>,
    /// Whether this machine keeps real time with these settings, with how much margin, and
    /// what to lower if not ([`verdict`]).
    pub verdict: String,
    /// Demodulator frames delivered per second.
    pub demod_frames_per_s: f64,
    /// The pipeline's counters at the end (overruns, drops, ring fill, ...).
    pub counters: CountersSnapshot,
}

/// Runs the chain on `settings` for `seconds`, paced by the wall clock if `realtime`.
/// `progress` is called about once a second with the elapsed time and the counters.
pub fn run(
    settings: &Settings,
    seconds: f64,
    realtime: bool,
    mut progress: impl FnMut(f64, &CountersSnapshot),
) -> Result<BenchReport, PipelineError> {
    let mut settings = settings.clone();
    settings.synth.realtime = realtime;
    // Before the threads start, so that it has a core to itself.
    let measured_ghz = crate::cpu::clock_ghz();
    let cpuinfo_mhz = cpuinfo_mhz();
    let (clock_ghz, clock_source) = match (measured_ghz, cpuinfo_mhz) {
        (Some(g), _) => (Some(g), "dependent adds"),
        (None, Some(m)) => (Some(m / 1e3), "/proc/cpuinfo"),
        (None, None) => (None, "none"),
    };
    let (pipeline, mut output) = Pipeline::start(&settings)?;
    let start = Instant::now();
    let duration = Duration::from_secs_f64(seconds);
    let mut next_report = Duration::from_secs(1);
    let mut warm = None;
    while start.elapsed() < duration {
        output.drain();
        let elapsed = start.elapsed();
        if elapsed >= next_report {
            progress(elapsed.as_secs_f64(), &pipeline.counters());
            next_report += Duration::from_secs(1);
        }
        // Measure from after the first 10 % (thread start, page faults, FFT warm-up).
        if warm.is_none() && elapsed >= duration / 10 {
            warm = Some((Instant::now(), pipeline.counters(), chain_thread_cpu_ns()));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let end = pipeline.counters();
    let end_cpu = chain_thread_cpu_ns();
    let end_time = Instant::now();
    let _ = pipeline.stop();
    let (t0, c0, cpu0) = warm.unwrap_or((start, CountersSnapshot::default(), None));
    let wall = (end_time - t0).as_secs_f64();
    let per_busy = |samples: u64, busy_ns: u64| {
        if busy_ns == 0 {
            0.0
        } else {
            samples as f64 / (busy_ns as f64 * 1e-9)
        }
    };
    let synthesized = end.samples_synthesized - c0.samples_synthesized;
    let processed = end.samples_processed - c0.samples_processed;
    let synth_busy = end.synth_busy_ns - c0.synth_busy_ns;
    let dsp_busy = end.dsp_busy_ns - c0.dsp_busy_ns;
    let chain = processed as f64 / wall;
    let per_sample = |ns: u64| (processed > 0).then(|| ns as f64 / processed as f64);
    let (synth_cpu, dsp_cpu) = match (cpu0, end_cpu) {
        (Some(a), Some(b)) => (
            per_sample(b.synth_ns.saturating_sub(a.synth_ns)),
            per_sample(b.dsp_ns.saturating_sub(a.dsp_ns)),
        ),
        _ => (None, None),
    };
    let cpu_ns_per_sample = synth_cpu.zip(dsp_cpu).map(|(s, d)| s + d);
    let mut report = BenchReport {
        machine: crate::cpu::machine(),
        clock_ghz,
        clock_source,
        cpuinfo_mhz,
        engine: settings.synth.engine.name(),
        contact_substeps: settings.synth.contact_substeps,
        sample_rate: settings.synth.sample_rate,
        demodulators: settings.demods.iter().filter(|d| d.enable).count(),
        realtime,
        seconds: start.elapsed().as_secs_f64(),
        synth_samples_per_s: per_busy(synthesized, synth_busy),
        dsp_samples_per_s: per_busy(processed, dsp_busy),
        chain_samples_per_s: chain,
        realtime_factor: chain / settings.synth.sample_rate,
        synth_load: synth_busy as f64 * 1e-9 / wall,
        dsp_load: dsp_busy as f64 * 1e-9 / wall,
        cpu_ns_per_sample,
        synth_cpu_ns_per_sample: synth_cpu,
        dsp_cpu_ns_per_sample: dsp_cpu,
        cycles_per_sample: cpu_ns_per_sample.zip(clock_ghz).map(|(ns, g)| ns * g),
        verdict: String::new(),
        demod_frames_per_s: (end.demod_frames - c0.demod_frames) as f64 / wall,
        counters: end,
    };
    report.verdict = verdict(&report);
    Ok(report)
}

/// The real-time factor a free-running chain needs to keep real time "with margin": on a
/// 2-vCPU machine two busy processes each run 1.2–1.5× slower together than alone, so a
/// chain at twice real time alone still keeps up beside a browser or a build.
pub const MARGIN: f64 = 2.0;

/// In words: whether this machine keeps real time with these settings, with margin, and
/// what to lower if not, the thread that limits first. Free-running it reads the
/// real-time factor against [`MARGIN`]; paced, the overruns and late blocks and the busier
/// thread's load (below 1 ÷ [`MARGIN`] is the same margin).
pub fn verdict(r: &BenchReport) -> String {
    let (keeps, margin) = if r.realtime {
        let lost = r.counters.overrun_samples > 0 || r.counters.late_blocks > 0;
        let load = r.synth_load.max(r.dsp_load);
        (!lost, !lost && load * MARGIN <= 1.0)
    } else {
        (r.realtime_factor >= 1.0, r.realtime_factor >= MARGIN)
    };
    let head = match (keeps, margin) {
        (_, true) if r.realtime => {
            "keeps real time with margin: no overruns, each thread busy at most half the time"
                .to_owned()
        }
        (_, true) => format!(
            "keeps real time with margin ({:.2}× real time alone; at least {MARGIN}× keeps up \
             beside other work on 2 vCPUs)",
            r.realtime_factor
        ),
        (true, false) if r.realtime => format!(
            "keeps real time, without margin (a thread busy {:.0} % of the time): other work \
             on the machine can make it fall behind",
            100.0 * r.synth_load.max(r.dsp_load)
        ),
        (true, false) => format!(
            "keeps real time only while nothing else runs ({:.2}× real time alone; {MARGIN}× \
             keeps up beside other work on 2 vCPUs)",
            r.realtime_factor
        ),
        (false, _) if r.realtime => format!(
            "does not keep real time: {} samples overrun, {} late blocks",
            r.counters.overrun_samples, r.counters.late_blocks
        ),
        (false, _) => format!(
            "does not keep real time ({:.2}× real time)",
            r.realtime_factor
        ),
    };
    if margin {
        return head;
    }
    // The factor the work must shrink by for the margin (paced: from the busier thread).
    let short = if r.realtime {
        (r.synth_load.max(r.dsp_load) * MARGIN).max(1.0)
    } else {
        MARGIN / r.realtime_factor.max(1e-9)
    };
    let rate = format!(
        "/synth/sample_rate to {:.3} MS/s or less",
        r.sample_rate / short / 1e6
    );
    let engine = if r.engine == "coupled" {
        "/synth/contact_substeps (6, with /synth/substep_budget 0.1), or /synth/engine = \"paper\""
    } else {
        "the number of modes"
    };
    let dsp = format!(
        "fewer demodulators (now {}), a smaller or rarer spectrum (/spectrum/size, \
         /spectrum/rate) or /spectrum/enable = false",
        r.demodulators
    );
    // The thread with the lower throughput per core of its own work limits first.
    let synth_first = r.synth_samples_per_s <= r.dsp_samples_per_s;
    let (first, second) = if synth_first {
        (format!("{rate}, {engine}"), dsp)
    } else {
        (dsp, format!("{rate}, {engine}"))
    };
    format!(
        "{head}. To cut the work {short:.2}×, lower first ({} thread limits) {first}; then {second}",
        if synth_first {
            "the synthesiser"
        } else {
            "the DSP"
        }
    )
}

/// `/proc/cpuinfo`'s `cpu MHz` of the first CPU listed.
fn cpuinfo_mhz() -> Option<f64> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    info.lines()
        .find(|l| l.split(':').next().is_some_and(|k| k.trim() == "cpu MHz"))
        .and_then(|l| l.split_once(':'))
        .and_then(|(_, v)| v.trim().parse().ok())
}
/// CPU time (ns) of the chain's threads so far, by role: the synthesiser (`ftafm-synth`)
/// and the DSP stage (`ftafm-dsp` and its lock-in workers `ftafm-dsp-w…`), each summed
/// over its threads. Read from outside the threads, so the real-time threads do nothing
/// for it: each thread is found by its name in `/proc/self/task` and read through its
/// thread CPU clock (`CLOCK_THREAD_CPUTIME_ID`'s per-thread form, which Linux builds from
/// the thread id). `None` where there is no `/proc` or the clock cannot be read.
#[cfg(target_os = "linux")]
pub fn chain_thread_cpu_ns() -> Option<ThreadCpu> {
    let mut cpu = ThreadCpu::default();
    for entry in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        let Some(tid) = entry
            .file_name()
            .to_str()
            .and_then(|s| s.parse::<i32>().ok())
        else {
            continue;
        };
        let Ok(comm) = std::fs::read_to_string(entry.path().join("comm")) else {
            continue;
        };
        let slot = match comm.trim_end() {
            "ftafm-synth" => &mut cpu.synth_ns,
            name if name == "ftafm-dsp" || name.starts_with("ftafm-dsp-w") => &mut cpu.dsp_ns,
            _ => continue,
        };
        // The thread CPU clock of thread `tid` (the kernel's MAKE_THREAD_CPUCLOCK, what
        // glibc's pthread_getcpuclockid returns): (!tid << 3) | per-thread (4) | sched (2).
        let clock = ((!tid) << 3) | 4 | 2;
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; a clock id of a thread that has
        // exited makes the call fail with EINVAL, which is checked, not undefined.
        if unsafe { libc::clock_gettime(clock as libc::clockid_t, &mut ts) } != 0 {
            continue;
        }
        *slot += ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64;
    }
    Some(cpu)
}

/// The chain's thread CPU time (never measured off Linux).
#[cfg(not(target_os = "linux"))]
pub fn chain_thread_cpu_ns() -> Option<ThreadCpu> {
    None
}

/// CPU time of the chain's threads (ns), by role ([`chain_thread_cpu_ns`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ThreadCpu {
    /// The synthesiser thread.
    pub synth_ns: u64,
    /// The DSP thread and its lock-in workers.
    pub dsp_ns: u64,
}

/// Readable summary.
pub fn render_text(r: &BenchReport) -> String {
    let ms = |x: f64| x / 1e6;
    let ns = |x: Option<f64>| x.map_or("–".to_owned(), |v| format!("{v:.1} ns"));
    let c = &r.counters;
    format!(
        "ftafm bench: {} s {} at {} MS/s, {} demodulators, {}\n\
         machine {}{}\n\
         synth  {:>8.1} MS/s per core (load {:.0} %)\n\
         dsp    {:>8.1} MS/s per core (load {:.0} %)\n\
         chain  {:>8.1} MS/s   realtime_factor {:.2}\n\
         cpu    {} per sample through the chain (synth {}, dsp {}); {}\n\
         verdict: {}\n\
         noise  {} pages of deviates drawn ahead by the DSP thread, {} by the synthesiser, {} in vain\n\
         frames {:.0}/s demod; overruns {} samples in {} blocks; dropped frames {} demod, {} spectrum; ring max {} samples\n",
        r.seconds.round(),
        if r.realtime {
            "paced by the wall clock"
        } else {
            "free-running"
        },
        ms(r.sample_rate),
        r.demodulators,
        if r.engine == "coupled" {
            format!(
                "coupled engine, {} contact sub-steps ({} samples refined to more, {} over the \
                 error budget)",
                r.contact_substeps, r.counters.refined_samples, r.counters.over_budget_samples
            )
        } else {
            format!("{} engine", r.engine)
        },
        r.machine,
        r.clock_ghz.map_or(String::new(), |g| format!(
            ", clock {g:.2} GHz by {}{}",
            r.clock_source,
            r.cpuinfo_mhz.map_or(String::new(), |m| format!(
                " (/proc/cpuinfo says {m:.0} MHz)"
            ))
        )),
        ms(r.synth_samples_per_s),
        r.synth_load * 100.0,
        ms(r.dsp_samples_per_s),
        r.dsp_load * 100.0,
        ms(r.chain_samples_per_s),
        r.realtime_factor,
        ns(r.cpu_ns_per_sample),
        ns(r.synth_cpu_ns_per_sample),
        ns(r.dsp_cpu_ns_per_sample),
        match (r.cycles_per_sample, r.clock_ghz) {
            (Some(c), Some(g)) => format!(
                "{c:.0} thread-cycles per sample at {g:.2} GHz ({})",
                r.clock_source
            ),
            _ => "no clock, so no cycles".to_owned(),
        },
        r.verdict,
        c.noise_pages_taken,
        c.noise_pages_drawn_inline,
        c.noise_pages_discarded,
        r.demod_frames_per_s,
        c.overrun_samples,
        c.overrun_blocks,
        c.demod_frames_dropped,
        c.spectrum_frames_dropped,
        c.ring_fill_max,
    )
}

/// The command line.
pub fn command(
    config: &ConfigArg,
    seconds: f64,
    realtime: bool,
    json: bool,
) -> Result<ExitCode, ExitCode> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 86_400.0) {
        eprintln!("ftafm: --seconds = {seconds} is out of range: allowed 0 < S ≤ 86400");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let settings = load(config)?;
    let report = crate::cli::bench::run(&settings, seconds, realtime, |t, c| {
        eprintln!(
            "[{t:>5.0} s] {:.1} M samples processed, overruns {}, ring {} samples",
            c.samples_processed as f64 / 1e6,
            c.overrun_samples,
            c.ring_fill
        );
    })
    .map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, crate::cli::bench::render_text);
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(realtime_factor: f64, synth: f64, dsp: f64) -> BenchReport {
        BenchReport {
            machine: String::new(),
            clock_ghz: Some(2.0),
            clock_source: "dependent adds",
            cpuinfo_mhz: None,
            engine: "coupled",
            contact_substeps: 12,
            sample_rate: 10e6,
            demodulators: 32,
            realtime: false,
            seconds: 1.0,
            synth_samples_per_s: synth,
            dsp_samples_per_s: dsp,
            chain_samples_per_s: realtime_factor * 10e6,
            realtime_factor,
            synth_load: 1.0,
            dsp_load: 1.0,
            cpu_ns_per_sample: None,
            synth_cpu_ns_per_sample: None,
            dsp_cpu_ns_per_sample: None,
            cycles_per_sample: None,
            verdict: String::new(),
            demod_frames_per_s: 0.0,
            counters: CountersSnapshot::default(),
        }
    }

    #[test]
    fn the_verdict_names_the_margin_and_what_to_lower() {
        let fast = verdict(&report(2.5, 30e6, 40e6));
        assert!(fast.starts_with("keeps real time with margin"), "{fast}");
        assert!(!fast.contains("lower"), "{fast}");
        let thin = verdict(&report(1.25, 30e6, 40e6));
        assert!(thin.starts_with("keeps real time only while"), "{thin}");
        // 2 / 1.25 = 1.6× too much work: 10 MS/s ÷ 1.6 = 6.25 MS/s, the synthesiser first.
        assert!(
            thin.contains("the synthesiser thread limits) /synth/sample_rate to 6.250 MS/s"),
            "{thin}"
        );
        let slow = verdict(&report(0.5, 40e6, 20e6));
        assert!(slow.starts_with("does not keep real time"), "{slow}");
        assert!(
            slow.contains("the DSP thread limits) fewer demodulators"),
            "{slow}"
        );
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn a_named_threads_cpu_time_is_read() {
        use std::sync::atomic::{AtomicBool, Ordering};
        let own_cpu_ns = || {
            let mut ts = libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            };
            // SAFETY: `ts` is a valid, writable timespec.
            assert_eq!(
                unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) },
                0
            );
            ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
        };
        let spun = std::sync::Arc::new(AtomicBool::new(false));
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let (spun2, stop2) = (spun.clone(), stop.clone());
        let spin = std::thread::Builder::new()
            .name("ftafm-synth".into())
            .spawn(move || {
                // Busy for 50 ms of its own CPU, however long that takes, then wait.
                while own_cpu_ns() < 50_000_000 {
                    std::hint::black_box(0);
                }
                spun2.store(true, Ordering::Release);
                while !stop2.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(1));
                }
            })
            .unwrap();
        while !spun.load(Ordering::Acquire) {
            std::thread::sleep(Duration::from_millis(1));
        }
        let cpu = chain_thread_cpu_ns().expect("Linux has /proc");
        stop.store(true, Ordering::Relaxed);
        spin.join().unwrap();
        assert!(cpu.synth_ns >= 50_000_000, "{cpu:?}");
    }
}
