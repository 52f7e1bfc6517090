//! The DSP stage on several threads (`/dsp/threads`) gives, bit for bit, what it gives on
//! one: every demodulator output and every spectrum, on the same synthesised stream. The
//! waits are on events (the workers' "done"), never on the clock, so a loaded machine only
//! makes the test slower.

use std::time::{Duration, Instant};

use ftafm::config::{Settings, default_settings};
use ftafm::dsp::{Demodulator, LockInBank, LockInSample};
use ftafm::pipeline::{DemodValue, DspPlan, DspSink, DspTeam, Pipeline, PipelineError};
use ftafm::synth::{SynthPlan, SynthState};
use ringbuf::traits::Consumer;

/// Everything the DSP stage put out, as bits.
#[derive(Default)]
struct Outputs {
    /// (stream index, demodulator, harmonic, x bits, y bits).
    demods: Vec<(u64, u8, u32, u64, u64)>,
    /// (stream index, bin width bits, magnitude bits).
    spectra: Vec<(u64, u64, Vec<u64>)>,
}

impl DspSink for Outputs {
    fn demod(&mut self, index: u64, v: DemodValue) {
        self.demods
            .push((index, v.index, v.harmonic, v.x.to_bits(), v.y.to_bits()));
    }

    fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, index: u64, bin_width: f64, bins: I) {
        self.spectra
            .push((index, bin_width.to_bits(), bins.map(f64::to_bits).collect()));
    }
}

/// A bank that leaves the defaults: low-pass orders 1–7 and one 8 (so most shards' own
/// highest order is not the bank's), rates from 1 kHz to the decimated rate, some demodulators off,
/// noise on, a spectrum every 5 000 samples.
fn mixed_settings() -> Settings {
    let mut s = default_settings();
    s.synth.realtime = false;
    s.spectrum.size = 4096;
    s.spectrum.rate = 2000.0;
    let rates = [1e3, 7e3, 20e3, 625e3];
    for (i, d) in s.demods.iter_mut().enumerate() {
        // Only the first shard holds the highest order.
        d.order = if i == 0 { 8 } else { 1 + (i as u32 * 5) % 7 };
        d.rate = rates[i % rates.len()];
        d.timeconstant = 2e-5 * (1 + i % 3) as f64;
        d.enable = i % 7 != 3;
    }
    s
}

/// Lengths of the blocks the stream is cut into: the pipeline's 4096, and others that cut
/// the bank's pieces, decimation steps and spectra at odd places.
const BLOCKS: [usize; 8] = [4096, 4096, 1000, 9000, 17, 4096, 12_289, 3];

/// The stream of `settings`, synthesised as the pipeline does, with each block's drive
/// phase word as the synthesiser stamps it.
fn stream(settings: &Settings, rounds: usize) -> (u64, Vec<(u64, Vec<f64>)>) {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, settings.synth.seed);
    let mut blocks = Vec::new();
    for _ in 0..rounds {
        for len in BLOCKS {
            let phase = plan.output_phase(state.phase());
            let mut block = vec![0.0; len];
            plan.process(&mut state, &mut block);
            blocks.push((phase, block));
        }
    }
    (plan.frequency_word, blocks)
}

/// The DSP stage of `settings` on `threads` threads over the stream.
fn run(settings: &Settings, threads: u32, word: u64, blocks: &[(u64, Vec<f64>)]) -> Outputs {
    let mut settings = settings.clone();
    settings.dsp.threads = threads;
    let mut plan = DspPlan::new(&settings).unwrap();
    assert_eq!(
        plan.shards(),
        threads as usize,
        "forced, whatever the cores"
    );
    let mut team = DspTeam::spawn(plan.shards() - 1, false).unwrap();
    assert_eq!(team.workers(), threads as usize - 1);
    let mut out = Outputs::default();
    for (phase, block) in blocks {
        plan.process_block(&mut team, *phase, word, block, &mut out);
    }
    out
}

fn assert_identical(reference: &Outputs, other: &Outputs, what: &str) {
    assert_eq!(
        reference.demods.len(),
        other.demods.len(),
        "{what}: outputs"
    );
    if let Some(i) = (0..reference.demods.len()).find(|&i| reference.demods[i] != other.demods[i]) {
        panic!(
            "{what}: output {i} differs: {:?} vs {:?}",
            reference.demods[i], other.demods[i]
        );
    }
    assert_eq!(
        reference.spectra.len(),
        other.spectra.len(),
        "{what}: spectra"
    );
    for (i, (a, b)) in reference.spectra.iter().zip(&other.spectra).enumerate() {
        assert!(a == b, "{what}: spectrum {i} (ending at {}) differs", a.0);
    }
}

#[test]
fn two_three_and_four_threads_give_the_single_threaded_outputs_bit_for_bit() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (name, rounds, settings) in [
        ("mixed bank", 3, mixed_settings()),
        ("defaults", 8, {
            let mut s = default_settings();
            s.synth.realtime = false;
            s.spectrum.size = 8192;
            s.spectrum.rate = 1000.0;
            s
        }),
    ] {
        let (word, blocks) = stream(&settings, rounds);
        let reference = run(&settings, 1, word, &blocks);
        let samples: usize = blocks.iter().map(|(_, b)| b.len()).sum();
        assert!(
            reference.demods.len() > 500 && reference.spectra.len() >= 10,
            "{name}: the test did work ({} outputs, {} spectra over {samples} samples)",
            reference.demods.len(),
            reference.spectra.len()
        );
        // Each demodulator's outputs come in time order, then index order.
        assert!(
            reference
                .demods
                .windows(2)
                .all(|w| (w[0].0, w[0].1) < (w[1].0, w[1].1)),
            "{name}: order"
        );
        for threads in [2, 3, 4] {
            let other = run(&settings, threads, word, &blocks);
            assert_identical(&reference, &other, &format!("{name}, {threads} threads"));
        }
    }
}

/// The same for the bank alone, with both kernels and every split `split` allows.
#[test]
fn bank_shards_compute_the_whole_banks_lanes_with_either_kernel() {
    let (fs, fd) = (10e6, 100.0123e3);
    let demods: Vec<Demodulator> = (0..32u32)
        .map(|i| Demodulator {
            enable: i % 5 != 2,
            ..Demodulator::new(
                i + 1,
                1 + (i * 3) % 8,
                3e-5,
                [2e4, 625e3, 5e3][i as usize % 3],
            )
        })
        .collect();
    let signal: Vec<f64> = (0..60_000)
        .map(|m| {
            let theta = std::f64::consts::TAU * fd / fs * m as f64;
            (1..=32)
                .map(|k| 1e-9 / k as f64 * (k as f64 * theta + 0.3 * k as f64).cos())
                .sum()
        })
        .collect();
    for portable in [false, true] {
        let make = || {
            let bank = LockInBank::new(fs, fd, &demods).unwrap();
            if portable {
                bank.with_portable_kernel()
            } else {
                bank
            }
        };
        let mut whole = make();
        let mut reference: Vec<LockInSample> = Vec::new();
        for block in signal.chunks(7000) {
            whole.process(block, |s| reference.push(s));
        }
        let lanes = whole.lanes();
        for parts in 2..=8 {
            let mut shards = make().split(parts).unwrap();
            assert_eq!(shards.len(), parts.min(lanes.div_ceil(4)));
            assert_eq!(shards.iter().map(LockInBank::lanes).sum::<usize>(), lanes);
            assert!(shards.iter().all(|s| s.kernel() == whole.kernel()));
            let mut outs = vec![Vec::new(); shards.len()];
            for block in signal.chunks(7000) {
                for (shard, out) in shards.iter_mut().zip(&mut outs) {
                    shard.process(block, |s| out.push(s));
                }
            }
            // Merge: by time, shard by shard within one time.
            let mut merged = Vec::new();
            let mut heads = vec![0; outs.len()];
            while let Some(t) = outs
                .iter()
                .zip(&heads)
                .filter_map(|(o, &h)| o.get(h).map(|s: &LockInSample| s.sample_index))
                .min()
            {
                for (o, h) in outs.iter().zip(&mut heads) {
                    while o.get(*h).is_some_and(|s| s.sample_index == t) {
                        merged.push(o[*h]);
                        *h += 1;
                    }
                }
            }
            assert_eq!(
                merged.len(),
                reference.len(),
                "{parts} parts, portable {portable}"
            );
            for (a, b) in reference.iter().zip(&merged) {
                assert_eq!(
                    (a.demod, a.sample_index, a.x.to_bits(), a.y.to_bits()),
                    (b.demod, b.sample_index, b.x.to_bits(), b.y.to_bits()),
                    "{parts} parts, portable {portable}"
                );
            }
        }
    }
}

/// Names of this process's threads that are DSP workers.
fn worker_threads() -> usize {
    std::fs::read_dir("/proc/self/task")
        .map(|tasks| {
            tasks
                .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
                .filter(|name| name.starts_with("ftafm-dsp-w"))
                .count()
        })
        .unwrap_or(0)
}

/// One pipeline at a time: the worker count is per process.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn the_pipeline_on_three_threads_gives_the_frames_of_one_and_joins_its_workers() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let settings = mixed_settings();
    let frames = |threads: u32| {
        let mut s = settings.clone();
        s.dsp.threads = threads;
        let (mut pipeline, mut output) = Pipeline::start(&s).unwrap();
        // A new plan (another spectrum) is taken up by the same workers.
        let mut next = s.clone();
        next.spectrum.size = 2048;
        pipeline.apply(&next).unwrap();
        // The thread count is fixed while running.
        next.dsp.threads = threads + 1;
        assert!(matches!(
            pipeline.apply(&next),
            Err(PipelineError::Restart("/dsp/threads"))
        ));
        let mut got = std::collections::BTreeMap::new();
        let deadline = Instant::now() + Duration::from_secs(120);
        // Until the new plan is in (an event: the DSP thread counts it) and enough frames.
        while got.len() < 300 || pipeline.counters().dsp_plans_applied == 0 {
            while let Some(f) = output.demods.try_pop() {
                let values: Vec<_> = f
                    .values()
                    .iter()
                    .map(|v| (v.index, v.x.to_bits(), v.y.to_bits()))
                    .collect();
                got.insert(f.sample_index, values);
            }
            while let Some(b) = output.spectra.try_pop() {
                output.recycle(b);
            }
            output.scopes.skip(usize::MAX);
            assert!(Instant::now() < deadline, "the pipeline stalled");
            std::thread::sleep(Duration::from_millis(1));
        }
        if cfg!(target_os = "linux") {
            // (A thread names itself when it starts: by now every worker has run.)
            assert_eq!(worker_threads(), threads as usize - 1);
        }
        let c = pipeline.stop();
        if cfg!(target_os = "linux") {
            assert_eq!(worker_threads(), 0, "workers joined");
        }
        (got, c)
    };
    let (one, c1) = frames(1);
    let (three, c3) = frames(3);
    assert_eq!(c3.dsp_plans_applied, 1, "{c3:?}");
    assert_eq!(
        (c1.discontinuities, c3.discontinuities),
        (0, 0),
        "free-running never overruns"
    );
    // Frames the consumer missed (a full queue drops them, counted) are not compared; the
    // ones both runs delivered must agree, and most do.
    let common: Vec<_> = one.keys().filter(|k| three.contains_key(k)).collect();
    assert!(common.len() > 100, "{} frames in common", common.len());
    for k in common {
        assert_eq!(one[k], three[k], "frame at sample {k}");
    }
}

/// A panic on the DSP thread while the workers run their shards (here a sink's) waits for
/// them before it unwinds, and the team still stops and joins.
#[test]
fn a_panic_beside_the_workers_waits_for_them_and_the_team_still_joins() {
    let _serial = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    struct Fails;
    impl DspSink for Fails {
        fn demod(&mut self, _: u64, _: DemodValue) {}
        fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, _: u64, _: f64, _: I) {
            panic!("a sink that fails");
        }
    }
    let mut settings = mixed_settings();
    settings.dsp.threads = 4;
    let (word, blocks) = stream(&settings, 1);
    let mut plan = DspPlan::new(&settings).unwrap();
    let mut team = DspTeam::spawn(3, false).unwrap();
    let failed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        for (phase, block) in &blocks {
            plan.process_block(&mut team, *phase, word, block, &mut Fails);
        }
    }));
    assert!(failed.is_err(), "the sink's panic comes through");
    drop(plan);
    drop(team);
    if cfg!(target_os = "linux") {
        assert_eq!(worker_threads(), 0, "workers joined");
    }
}
