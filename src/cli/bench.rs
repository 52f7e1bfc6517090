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
    /// The core's clock measured before the run (GHz; `crate::cpu::clock_ghz`), `null` where
    /// it cannot be: with it a throughput reads as cycles a sample.
    pub clock_ghz: Option<f64>,
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
    let clock_ghz = crate::cpu::clock_ghz();
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
            warm = Some((Instant::now(), pipeline.counters()));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let end = pipeline.counters();
    let end_time = Instant::now();
    let _ = pipeline.stop();
    let (t0, c0) = warm.unwrap_or((start, CountersSnapshot::default()));
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
    Ok(BenchReport {
        machine: crate::cpu::machine(),
        clock_ghz,
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
        demod_frames_per_s: (end.demod_frames - c0.demod_frames) as f64 / wall,
        counters: end,
    })
}

/// Readable summary.
pub fn render_text(r: &BenchReport) -> String {
    let ms = |x: f64| x / 1e6;
    let c = &r.counters;
    format!(
        "ftafm bench: {} s {} at {} MS/s, {} demodulators, {}\n\
         machine {}{}\n\
         synth  {:>8.1} MS/s per core (load {:.0} %)\n\
         dsp    {:>8.1} MS/s per core (load {:.0} %)\n\
         chain  {:>8.1} MS/s   realtime_factor {:.2}\n\
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
            format!("coupled engine, {} contact sub-steps", r.contact_substeps)
        } else {
            format!("{} engine", r.engine)
        },
        r.machine,
        r.clock_ghz
            .map_or(String::new(), |g| format!(", clock {g:.2} GHz")),
        ms(r.synth_samples_per_s),
        r.synth_load * 100.0,
        ms(r.dsp_samples_per_s),
        r.dsp_load * 100.0,
        ms(r.chain_samples_per_s),
        r.realtime_factor,
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
