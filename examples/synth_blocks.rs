//! The synthesiser alone for a number of 4096-sample blocks, for profilers: instruction
//! counts (`benches/synth_instructions.sh`, callgrind), `perf record`, or a quick look at
//! the throughput.
//!
//! `cargo run --release --example synth_blocks -- ENGINE A_SET NOISE BLOCKS [SUBSTEPS] [window] [hash]`:
//! ENGINE `paper` or `coupled`, A_SET the surface distance in metres (the defaults' 20e-9
//! taps, 50e-9 is clear of the surface), NOISE `on` or `off`, BLOCKS how many, SUBSTEPS
//! `/synth/contact_substeps` (default 12; also as a flag `substeps=N` anywhere, for
//! `benches/synth_instructions.sh`, which appends BLOCKS). Everything else is the default configuration.
//! Prints the samples made, the throughput, and the fastest, tenth-fastest and median
//! block's: on a shared machine the fastest blocks are the steadier figure for an A/B of
//! two builds. With `hash`, also an FNV-1a hash of every sample's bits, to check that two
//! builds give the same stream (it costs a few instructions a sample, so leave it out when
//! counting instructions). With the coupled engine, also the share of samples with a tip
//! force (those it sub-steps), from a noise-free trace after the timing. With `window`, the
//! synthesiser thread's part in the pipeline: the signal through the ADC's window, its FIRs,
//! detector noise and quantiser left to the DSP thread (`SynthPlan::process_window`); the
//! hash is then of the window samples.

use std::time::Instant;

use ftafm::config::{Engine, default_settings};
use ftafm::synth::{SynthPlan, SynthState, WindowSample};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: synth_blocks paper|coupled A_SET on|off BLOCKS [SUBSTEPS] [window] [hash] [substeps=N]";
    // The flags may stand anywhere after ENGINE (`benches/synth_instructions.sh` appends
    // BLOCKS to whatever it is given).
    let hash = args.iter().any(|a| a == "hash");
    let window = args.iter().any(|a| a == "window");
    let flag_substeps = args
        .iter()
        .find_map(|a| a.strip_prefix("substeps=").map(str::to_owned));
    let args: Vec<String> = args
        .into_iter()
        .filter(|a| a != "hash" && a != "window" && !a.starts_with("substeps="))
        .collect();
    let (engine, distance, noise, blocks, substeps) = match args.as_slice() {
        [e, d, n, b] => (e, d, n, b, flag_substeps.as_ref()),
        [e, d, n, b, s] if flag_substeps.is_none() => (e, d, n, b, Some(s)),
        _ => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
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
    if let Some(n) = substeps {
        // Through the node, so that a bad count gets the daemon's error.
        let n: u64 = n.parse().unwrap_or_else(|_| {
            eprintln!("SUBSTEPS must be a whole number; {usage}");
            std::process::exit(2);
        });
        if let Err(e) = settings.apply("/synth/contact_substeps", &n.into()) {
            eprintln!("{e}");
            std::process::exit(2);
        }
    }
    let plan = SynthPlan::new(&settings).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2);
    });
    let mut state = SynthState::steady(&plan, 1);
    let mut block = vec![0.0; 4096];
    let mut through_window = vec![WindowSample::default(); block.len()];
    let mut times = Vec::with_capacity(blocks);
    let mut fnv: u64 = 0xcbf2_9ce4_8422_2325;
    for _ in 0..blocks {
        let start = Instant::now();
        if window {
            plan.process_window(&mut state, &mut through_window);
        } else {
            plan.process(&mut state, &mut block);
        }
        times.push(start.elapsed().as_secs_f64());
        if hash {
            let bits = through_window.iter().flat_map(|w| [w.grid, w.mid]);
            for x in block
                .iter()
                .copied()
                .filter(|_| !window)
                .chain(bits.filter(|_| window))
            {
                fnv = (fnv ^ x.to_bits()).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    let samples = blocks * block.len();
    let seconds: f64 = times.iter().sum();
    println!(
        "{samples} samples in {seconds:.3} s: {:.1} MS/s",
        samples as f64 / seconds / 1e6
    );
    if blocks > 0 {
        times.sort_by(f64::total_cmp);
        let rate = |t: f64| block.len() as f64 / t / 1e6;
        println!(
            "blocks of {}: fastest {:.1}, tenth-fastest {:.1}, median {:.1} MS/s",
            block.len(),
            rate(times[0]),
            rate(times[blocks / 10]),
            rate(times[blocks / 2])
        );
    }
    if hash {
        println!("stream hash {fnv:016x}");
    }
    // Where the coupled engine's cost goes: the samples with a tip force sub-step, the rest
    // are one step. Counted on a noise-free copy of the state, after the timing.
    let counted = 100 * block.len();
    if let Some(trace) = plan.coupled_trace(&mut state.clone(), counted) {
        let forced = trace
            .force
            .chunks_exact(trace.substeps)
            .filter(|sample| sample.iter().any(|&g| g != 0.0))
            .count();
        println!(
            "samples with a tip force: {:.2} % ({} sub-steps each)",
            100.0 * forced as f64 / counted as f64,
            trace.substeps
        );
    }
}
