//! Photodiode synthesis throughput (goal: ≥ 50 MS/s on one core, 5 modes, noise on), for
//! both engines at the default (Table 1) operating point, with the ADC's anti-alias filter
//! (the default) and sampling directly (`_direct`); and the pipeline's split of it: the
//! synthesiser thread's part (`_window`) and the DSP thread's (`digitise`).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ftafm::config::{Engine, default_settings};
use ftafm::synth::normals::NormalSource;
use ftafm::synth::{Digitiser, SynthPlan, SynthState, WindowSample};

fn synth(c: &mut Criterion) {
    let mut group = c.benchmark_group("synth");
    const BLOCK: usize = 4096;
    group.throughput(Throughput::Elements(BLOCK as u64));
    for (name, noise, engine, anti_alias) in [
        ("5_modes_noise_on", true, Engine::Paper, true),
        ("5_modes_noise_off", false, Engine::Paper, true),
        ("coupled_5_modes_noise_on", true, Engine::Coupled, true),
        ("coupled_5_modes_noise_off", false, Engine::Coupled, true),
        ("5_modes_noise_on_direct", true, Engine::Paper, false),
        (
            "coupled_5_modes_noise_on_direct",
            true,
            Engine::Coupled,
            false,
        ),
        // The tip clear of the surface (A_set 100 nm): the free samples' cost alone, so
        // that the contact's (its sub-steps) is the difference.
        (
            "coupled_5_modes_noise_on_clear",
            true,
            Engine::Coupled,
            true,
        ),
        // Half the default's sub-steps in contact (`/synth/contact_substeps` = 6, with
        // `/synth/substep_budget` = 0.1, the slow machine's setting).
        (
            "coupled_5_modes_noise_on_6_substeps",
            true,
            Engine::Coupled,
            true,
        ),
    ] {
        let mut settings = default_settings();
        settings.noise.enable = noise;
        settings.synth.engine = engine;
        settings.synth.anti_alias = anti_alias;
        if name.ends_with("_clear") {
            settings.surface.distance = 100e-9;
        }
        if name.ends_with("_6_substeps") {
            settings.synth.contact_substeps = 6;
            settings.synth.substep_budget = 0.1;
        }
        let plan = SynthPlan::new(&settings).expect("default plan");
        let mut state = SynthState::steady(&plan, 1);
        let mut block = vec![0.0; BLOCK];
        group.bench_function(name, |b| b.iter(|| plan.process(&mut state, &mut block)));
    }
    // The synthesiser thread's part in the pipeline: the signal through the ADC's window,
    // whose FIRs, detector noise and quantiser the DSP thread runs (`_digitise`).
    let plan = SynthPlan::new(&default_settings()).expect("default plan");
    let mut state = SynthState::steady(&plan, 1);
    let mut window = vec![WindowSample::default(); BLOCK];
    group.bench_function("coupled_5_modes_noise_on_window", |b| {
        b.iter(|| plan.process_window(&mut state, &mut window))
    });
    let mut at = state.sample_index();
    let input = plan.process_window(&mut state, &mut window);
    let mut digitiser = Digitiser::new(BLOCK);
    let mut out = vec![0.0; BLOCK];
    let (a, b) = window.split_at(BLOCK / 2);
    // A new page of the detector's deviates every block, as in the pipeline.
    group.bench_function("digitise", |bench| {
        bench.iter(|| {
            at += BLOCK as u64;
            digitiser.finish(&input, at, [a, b], &mut out)
        })
    });
    // The noise sources' standard normal deviates alone (vectorised where the CPU has
    // AVX2), in the synthesiser's chunks of 256 samples of five modes.
    let mut source = NormalSource::new(1);
    let mut deviates = vec![0.0; 5 * 256];
    group.throughput(Throughput::Elements(deviates.len() as u64));
    group.bench_function("normal_deviates", |b| b.iter(|| source.fill(&mut deviates)));
    group.finish();
}

criterion_group!(benches, synth);
criterion_main!(benches);
