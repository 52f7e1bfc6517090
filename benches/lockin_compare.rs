//! The Rust half of `benches/lockin_numpy.py`: synthesises photodiode samples with the
//! instrument's default configuration, writes them for the NumPy/SciPy lock-in, times the
//! lock-in bank (32 demodulators, order 4, 1 kHz, as configured) on exactly those samples,
//! and prints one JSON line (`LOCKIN_RUST {...}`) with the throughput and the bank's outputs.
//!
//! It is an ignored test of a bench target, so neither `cargo test` nor `cargo bench` runs
//! it by accident; the script runs
//! `cargo test --release --bench lockin_compare -- --ignored --nocapture` with
//! `FTAFM_LOCKIN_SAMPLES=FILE` (little-endian f64 samples are written there),
//! `FTAFM_LOCKIN_LEN` (samples, default 2^21) and `FTAFM_LOCKIN_REPEATS` (default 20).

use std::time::Instant;

use ftafm::config::default_settings;
use ftafm::dsp::LockInBank;
use ftafm::synth::{SynthPlan, SynthState};

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[test]
#[ignore = "run by benches/lockin_numpy.py"]
fn lockin_bank_on_synthesised_samples() {
    let path = std::env::var("FTAFM_LOCKIN_SAMPLES").expect("FTAFM_LOCKIN_SAMPLES=FILE");
    let len = env_usize("FTAFM_LOCKIN_LEN", 1 << 21);
    let repeats = env_usize("FTAFM_LOCKIN_REPEATS", 20).max(1);

    let settings = default_settings();
    let fs = settings.synth.sample_rate;
    let plan = SynthPlan::new(&settings).expect("default plan");
    let mut state = SynthState::steady(&plan, settings.synth.seed);
    let phase0 = state.phase();
    let mut samples = vec![0.0; len];
    for block in samples.chunks_mut(4096) {
        plan.process(&mut state, block);
    }
    let bytes: Vec<u8> = samples.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(&path, bytes).expect("write the samples");

    let demods = ftafm::pipeline::demodulators(&settings);
    let new_bank = || {
        let mut bank = LockInBank::new(fs, settings.drive.frequency, &demods).expect("bank");
        bank.align_drive(phase0, plan.frequency_word);
        bank
    };
    // The outputs of one pass, for the script's cross-check.
    let mut outputs: Vec<(usize, u32, u64, f64, f64)> = Vec::new();
    let mut bank = new_bank();
    for block in samples.chunks(4096) {
        bank.process(block, |s| {
            outputs.push((s.demod, s.harmonic, s.sample_index, s.x, s.y))
        });
    }
    // Timed passes: a fresh bank each (construction not timed), input in 4096-sample
    // blocks as the DSP thread gets it.
    let mut times = Vec::with_capacity(repeats);
    let mut sink = 0.0;
    for _ in 0..repeats {
        let mut bank = new_bank();
        let start = Instant::now();
        for block in samples.chunks(4096) {
            bank.process(block, |s| sink += s.x);
        }
        times.push(start.elapsed().as_secs_f64());
    }
    std::hint::black_box(sink);
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let demod_json: Vec<_> = settings
        .demods
        .iter()
        .filter(|d| d.enable)
        .map(|d| {
            serde_json::json!({
                "harmonic": d.harmonic, "order": d.order,
                "time_constant": d.timeconstant, "rate": d.rate,
            })
        })
        .collect();
    let out = serde_json::json!({
        "sample_rate": fs,
        "drive_frequency": settings.drive.frequency,
        "phase0": phase0.to_string(),
        "frequency_word": plan.frequency_word.to_string(),
        "samples": len,
        "repeats": repeats,
        "kernel": bank.kernel(),
        "seconds_median": median,
        "seconds_min": times[0],
        "samples_per_s_median": len as f64 / median,
        "demods": demod_json,
        "outputs": outputs,
    });
    println!("LOCKIN_RUST {out}");
}
