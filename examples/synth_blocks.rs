//! The synthesiser alone for a number of 4096-sample blocks, for profilers: instruction
//! counts (`benches/synth_instructions.sh`, callgrind), `perf record`, or a quick look at
//! the throughput.
//!
//! `cargo run --release --example synth_blocks -- ENGINE A_SET NOISE BLOCKS`:
//! ENGINE `paper` or `coupled`, A_SET the surface distance in metres (the defaults' 20e-9
//! taps, 50e-9 is clear of the surface), NOISE `on` or `off`, BLOCKS how many. Everything
//! else is the default configuration. Prints the samples made and the throughput.

use std::time::Instant;

use ftafm::config::{Engine, default_settings};
use ftafm::synth::{SynthPlan, SynthState};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: synth_blocks paper|coupled A_SET on|off BLOCKS";
    let [engine, distance, noise, blocks] = args.as_slice() else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let mut settings = default_settings();
    settings.synth.engine = match engine.as_str() {
        "paper" => Engine::Paper,
        "coupled" => Engine::Coupled,
        _ => {
            eprintln!("ENGINE must be paper or coupled; {usage}");
            std::process::exit(2);
        }
    };
    settings.surface.distance = distance.parse().unwrap_or_else(|_| {
        eprintln!("A_SET must be a number of metres; {usage}");
        std::process::exit(2);
    });
    settings.noise.enable = match noise.as_str() {
        "on" => true,
        "off" => false,
        _ => {
            eprintln!("NOISE must be on or off; {usage}");
            std::process::exit(2);
        }
    };
    let blocks: usize = blocks.parse().unwrap_or_else(|_| {
        eprintln!("BLOCKS must be a whole number; {usage}");
        std::process::exit(2);
    });
    let plan = SynthPlan::new(&settings).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2);
    });
    let mut state = SynthState::steady(&plan, 1);
    let mut block = vec![0.0; 4096];
    let start = Instant::now();
    for _ in 0..blocks {
        plan.process(&mut state, &mut block);
    }
    let samples = blocks * block.len();
    let seconds = start.elapsed().as_secs_f64();
    println!(
        "{samples} samples in {seconds:.3} s: {:.1} MS/s",
        samples as f64 / seconds / 1e6
    );
}
