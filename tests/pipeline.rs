//! The running signal chain: synth thread → ring → DSP thread → frames, end to end.

use std::time::{Duration, Instant};

use ftafm::cli::paper;
use ftafm::config::{Settings, default_settings};
use ftafm::pipeline::{DemodFrame, Pipeline, PipelineOutput, ScopeBuffer};
use ftafm::synth::{SynthPlan, SynthState};
use ringbuf::traits::Consumer;

/// The defaults, noise off, free-running, on the paper engine: its spectrum is exactly the
/// 1-DOF model's, to 0.5 % at every harmonic (the coupled engine's own accuracy against its
/// orbit is tests/synth_coupled.rs's).
fn free_running_quiet() -> Settings {
    let mut s = default_settings();
    s.synth.engine = ftafm::config::Engine::Paper;
    s.noise.enable = false;
    s.synth.realtime = false;
    s
}

/// Collects demod frames until `t` (simulated s) is reached; returns the last one.
fn run_until(output: &mut PipelineOutput, t: f64) -> DemodFrame {
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut last = None;
    loop {
        while let Some(f) = output.demods.try_pop() {
            last = Some(f);
        }
        while let Some(b) = output.spectra.try_pop() {
            output.recycle(b);
        }
        if let Some(f) = last
            && f.t >= t
        {
            return f;
        }
        assert!(
            Instant::now() < deadline,
            "the pipeline stalled at {:?}",
            last.map(|f| f.t)
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn lock_in_reads_the_paper_spectrum_in_steady_state() {
    let settings = free_running_quiet();
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    // 4th-order 0.5 ms filters settle to 1e-6 in ≈ 15 ms; take 50 ms.
    let frame = run_until(&mut output, 0.05);
    let report = paper::compute(&settings, 0.9).unwrap();
    let expected = &report.materials[0].spectrum;
    assert_eq!(frame.len, 32);
    for v in frame.values() {
        let k = v.harmonic as usize;
        if !(2..=20).contains(&k) {
            continue;
        }
        let rel = v.r() / expected[k].amplitude - 1.0;
        assert!(
            rel.abs() < 0.005,
            "H{k}: lock-in {:e} vs paper {:e} ({:.3} %)",
            v.r(),
            expected[k].amplitude,
            rel * 100.0
        );
        let dphi = (v.phase() - expected[k].phase + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        assert!(
            dphi.abs() < 0.01,
            "H{k}: phase {} vs {}",
            v.phase(),
            expected[k].phase
        );
    }
    let c = pipeline.counters();
    assert_eq!(c.overrun_samples, 0, "free-running never overruns");
    assert!(c.samples_processed > 0 && c.samples_processed <= c.samples_synthesized);
    assert!(c.spectrum_frames > 0, "spectra are produced");
    pipeline.stop();
}

#[test]
fn on_the_coupled_engine_the_lock_in_reads_the_coupled_orbit() {
    use ftafm::physics::spectrum::photodiode_transfer;
    use ftafm::physics::{CoupledProblem, HertzContact};
    use rustfft::num_complex::Complex64;
    let mut settings = free_running_quiet();
    settings.synth.engine = ftafm::config::Engine::Coupled;
    let plan = ftafm::synth::SynthPlan::new(&settings).unwrap();
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let orbit = CoupledProblem::new(
        &cantilever,
        plan.drive_frequency,
        settings.drive.free_amplitude,
        settings.surface.distance,
        HertzContact::new(
            ftafm::model::elastic(settings.tip),
            ftafm::model::elastic(settings.sample),
            settings.cantilever.tip_radius,
        ),
    )
    .solve(32)
    .unwrap();
    let omega = 2.0 * std::f64::consts::PI * plan.drive_frequency;
    // Peak phasors of the photodiode at each harmonic (the free response is at H1 only).
    let expected = |k: usize| -> Complex64 {
        let tap =
            photodiode_transfer(&cantilever, k as f64 * omega) * orbit.force_coefficients[k] * 2.0;
        if k == 1 {
            tap + plan.free_signal()
        } else {
            tap
        }
    };
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let frame = run_until(&mut output, 0.05);
    let h6 = expected(6).norm();
    for v in frame.values() {
        let k = v.harmonic as usize;
        let got = Complex64::new(v.x, v.y);
        let want = expected(k);
        let err = (got - want).norm();
        // H1 within 0.2 %; H2–H18 within 1 % (next to a light-lever zero, of H6).
        let (scale, tolerance) = match k {
            1 => (want.norm(), 0.002),
            3 | 11 | 12 => (h6, 0.01),
            2..=18 => (want.norm(), 0.01),
            // H19–H32 (the goal: 3 %) within 1 % of their own amplitude through the ADC's
            // anti-alias filter, by the force's spectral zero too (H26–H28, < 1.4e-4 of
            // H6: 0.1–0.6 % measured).
            _ => (want.norm(), 0.01),
        };
        println!(
            "H{k}: lock-in {:.4e} m, orbit {:.4e} m (error {:.3} % of the scale)",
            got.norm(),
            want.norm(),
            err / scale * 100.0
        );
        assert!(
            err < tolerance * scale,
            "H{k}: lock-in {got} vs orbit {want} (error {:.3} %)",
            err / scale * 100.0
        );
    }
    assert_eq!(pipeline.counters().overrun_samples, 0);
    pipeline.stop();
}

#[test]
fn settings_changes_reach_the_running_chain() {
    let settings = free_running_quiet();
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let before = run_until(&mut output, 0.03);
    let h17 = |f: &DemodFrame| f.values().iter().find(|v| v.harmonic == 17).map(|v| v.r());
    let silicon = h17(&before).unwrap();

    let mut softer = settings.clone();
    softer.sample.youngs_modulus = 60e9;
    let epoch = pipeline.apply(&softer).unwrap();
    let index = pipeline
        .effective_index(epoch, Duration::from_secs(60))
        .unwrap();
    let t_switch = index as f64 / settings.synth.sample_rate;
    let after = run_until(&mut output, t_switch + 0.05);
    let expected = paper::compute(&softer, 1.0).unwrap().materials[0].spectrum[17].amplitude;
    let got = h17(&after).unwrap();
    assert!(
        got < silicon,
        "a softer sample lowers H17: {got:e} vs {silicon:e}"
    );
    assert!(
        (got / expected - 1.0).abs() < 0.005,
        "H17 {got:e} vs paper {expected:e}"
    );

    // A demodulator moved to another harmonic reports it.
    let mut moved = softer.clone();
    moved.demods[0].harmonic = 40;
    let epoch = pipeline.apply(&moved).unwrap();
    // The lock-in switches with the synthesis, at the sample the change took effect: in a
    // free-running chain up to a ring's length after the samples the DSP works on now.
    let index = pipeline
        .effective_index(epoch, Duration::from_secs(60))
        .unwrap();
    let t_switch = index as f64 / settings.synth.sample_rate;
    let frame = run_until(&mut output, t_switch + 0.02);
    assert_eq!(frame.values()[0].harmonic, 40);
    let c = pipeline.counters();
    assert_eq!((c.synth_plans_applied, c.dsp_plans_applied), (1, 1));
    assert_eq!(c.discontinuities, 0);
    pipeline.stop();
}

/// Every node the synthesis plan is built from rebuilds it when it changes while running:
/// adhesion, the ADC's anti-alias filter, the contact's sub-steps (each once was taken by
/// `set` and never reached the running chain).
#[test]
fn every_synthesis_node_reaches_the_running_chain() {
    let settings = free_running_quiet();
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let mut next = settings.clone();
    let changes: [fn(&mut Settings); 4] = [
        |s| s.adhesion.enable = !s.adhesion.enable,
        |s| s.synth.anti_alias = !s.synth.anti_alias,
        |s| s.synth.contact_substeps += 2,
        |s| s.synth.realtime = !s.synth.realtime,
    ];
    for (i, change) in changes.iter().enumerate() {
        change(&mut next);
        let epoch = pipeline.apply(&next).unwrap();
        let plans = pipeline.counters().synth_plans_applied;
        if i < 3 {
            // Taken up by the synthesiser: an event, with a guard against a hang.
            pipeline
                .effective_index(epoch, Duration::from_secs(60))
                .unwrap_or_else(|| panic!("change {i} never took effect"));
            output.drain();
        } else {
            // The pacing is a flag the threads read: no new plan.
            assert_eq!(plans, 3, "the pacing rebuilt the plan");
        }
    }
    assert_eq!(pipeline.counters().synth_plans_applied, 3);
    pipeline.stop();
}

/// The second excitation's nodes changed by themselves (`/drive2/enable`, then
/// `/drive2/free_amplitude`) reach the running chain: each builds a synthesis plan, and a
/// demodulator on `drive2` reads mode 2 rung up at f2, then at twice the amplitude (once a
/// change of `/drive2` alone was no input of the plan, and mode 2 stayed still).
#[test]
fn a_change_of_the_second_excitation_alone_reaches_the_running_chain() {
    let mut settings = default_settings(); // the coupled engine, which drives /drive2
    settings.noise.enable = false;
    settings.synth.realtime = false;
    settings.surface.distance = 1e-6;
    settings.demods[7].enable = true;
    settings.demods[7].harmonic = 1;
    settings.demods[7].oscillator = ftafm::config::Oscillator::Drive2;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let r2 = |f: &DemodFrame| f.values()[7].r();
    let still = r2(&run_until(&mut output, 0.01));
    let mut next = settings.clone();
    let mut readings = vec![];
    for change in [
        (|s: &mut Settings| s.drive2.enable = true) as fn(&mut Settings),
        |s| s.drive2.free_amplitude *= 2.0,
    ] {
        change(&mut next);
        let epoch = pipeline.apply(&next).unwrap();
        let index = pipeline
            .effective_index(epoch, Duration::from_secs(60))
            .unwrap_or_else(|| panic!("the change of /drive2 never took effect"));
        // 10 ms: fifty of mode 2's envelope time constants (0.21 ms) and the filters'.
        let t = index as f64 / settings.synth.sample_rate + 0.01;
        readings.push(r2(&run_until(&mut output, t)));
    }
    eprintln!("mode 2 at f2: {still:e} m still, {readings:?} m");
    assert!(
        still < 1e-11,
        "mode 2 still before the excitation: {still:e} m"
    );
    assert!(
        readings[0] > 1e-9,
        "mode 2 rings at f2: {:e} m",
        readings[0]
    );
    assert!(
        (readings[1] / readings[0] - 2.0).abs() < 0.01,
        "twice the free amplitude, twice the reading: {readings:?}"
    );
    assert_eq!(pipeline.counters().synth_plans_applied, 2);
    pipeline.stop();
}

/// A change applied at once after the start, before the synthesiser's thread may have run
/// at all, still takes effect and says where: the thread stamps it on its first block
/// rather than taking it for the epoch it started with.
#[test]
fn a_change_applied_before_the_threads_run_takes_effect() {
    let settings = free_running_quiet();
    for round in 0..20 {
        let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
        let mut next = settings.clone();
        // A lock-in-only change: no plan to build, so it is published within microseconds.
        next.demods[3].harmonic = 7 + round;
        let epoch = pipeline.apply(&next).unwrap();
        assert!(
            pipeline
                .effective_index(epoch, Duration::from_secs(60))
                .is_some(),
            "round {round}: the change never took effect"
        );
        output.drain();
        pipeline.stop();
    }
}

/// Every change lands on one sample boundary for the whole chain: the synthesiser reports
/// the first sample it made under the new settings, and the DSP thread takes up its plan of
/// the same change with the block that starts at that very sample — for synthesis-only,
/// lock-in-only and combined changes, applied back to back.
#[test]
fn a_change_takes_effect_at_one_sample_boundary_in_both_threads() {
    let settings = free_running_quiet();
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    run_until(&mut output, 0.002);
    let mut next = settings.clone();
    let mut last_index = 0;
    for round in 0..12 {
        let dsp_too = round % 3 != 0;
        match round % 3 {
            0 => next.surface.distance = 18e-9 + round as f64 * 1e-10,
            1 => next.demods[5].harmonic = 6 + round,
            _ => {
                next.drive.follow_f1 = false;
                next.drive.frequency = 99e3 + round as f64 * 100.0;
                next.demods[7].rate = 500.0 + round as f64;
            }
        }
        let epoch = pipeline.apply(&next).unwrap();
        let index = pipeline
            .effective_index(epoch, Duration::from_secs(60))
            .expect("the free-running synthesiser reaches the change");
        assert!(
            index > last_index,
            "round {round}: {index} after {last_index}"
        );
        assert_eq!(
            index % ftafm::pipeline::BLOCK_SAMPLES as u64,
            0,
            "a block boundary"
        );
        last_index = index;
        if dsp_too {
            let deadline = Instant::now() + Duration::from_secs(60);
            while pipeline.epochs().dsp_taken_up().0 < epoch {
                assert!(
                    Instant::now() < deadline,
                    "round {round}: the DSP took no plan"
                );
                run_until(&mut output, 0.0);
            }
            assert_eq!(
                pipeline.epochs().dsp_taken_up(),
                (epoch, index),
                "round {round}: the lock-in switched at another sample than the synthesis"
            );
        }
    }
    // Demodulator 7 now runs at its own rate: frames hold whichever demodulators had an
    // output at their time, so look demodulator 5 up by its index.
    let deadline = Instant::now() + Duration::from_secs(60);
    let demod5 = loop {
        assert!(Instant::now() < deadline, "no frame of demodulator 5");
        let t = last_index as f64 / settings.synth.sample_rate + 0.01;
        if let Some(v) = run_until(&mut output, t)
            .values()
            .iter()
            .find(|v| v.index == 5)
        {
            break *v;
        }
    };
    assert_eq!(demod5.harmonic, 6 + 10);
    let c = pipeline.counters();
    assert_eq!(c.discontinuities, 0);
    assert_eq!(c.overrun_samples, 0);
    pipeline.stop();
}

/// A change that leaves the lock-in bank's settings alone (the spectrum's window, the
/// scope) keeps the demodulators' filters running: no output drops back towards zero and
/// settles again, as it does when the bank itself changes.
#[test]
fn a_change_beside_the_lock_in_keeps_its_filters_running() {
    let settings = free_running_quiet();
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let steady = run_until(&mut output, 0.02).values()[0].r();
    let mut next = settings.clone();
    next.spectrum.window = ftafm::config::SpectrumWindow::BlackmanHarris;
    next.scope.length = 512;
    let epoch = pipeline.apply(&next).unwrap();
    let index = pipeline
        .effective_index(epoch, Duration::from_secs(60))
        .unwrap();
    let t_change = index as f64 / settings.synth.sample_rate;
    // Every frame of the next 5 ms (50 filter time constants would be needed to recover
    // from a restart at zero) stays at the steady amplitude.
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut seen = 0;
    while seen < 5 {
        assert!(Instant::now() < deadline, "no frames after the change");
        while let Some(f) = output.demods.try_pop() {
            if f.t > t_change && f.t < t_change + 0.005 {
                let r = f.values()[0].r();
                assert!(
                    (r / steady - 1.0).abs() < 1e-3,
                    "H1 {r:e} vs {steady:e} at t = {}",
                    f.t
                );
                seen += 1;
            }
        }
        while let Some(b) = output.spectra.try_pop() {
            output.recycle(b);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(pipeline.counters().dsp_plans_applied, 1);

    // The bank changed: its filters start again (the check above can fail).
    next.demods[0].timeconstant *= 2.0;
    let epoch = pipeline.apply(&next).unwrap();
    let index = pipeline
        .effective_index(epoch, Duration::from_secs(60))
        .unwrap();
    let t_change = index as f64 / settings.synth.sample_rate;
    let deadline = Instant::now() + Duration::from_secs(60);
    let first = 'found: loop {
        assert!(Instant::now() < deadline, "no frames after the change");
        while let Some(f) = output.demods.try_pop() {
            if f.t > t_change {
                break 'found f;
            }
        }
        while let Some(b) = output.spectra.try_pop() {
            output.recycle(b);
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    assert!(
        first.values()[0].r() < 0.5 * steady,
        "a new bank starts from zero"
    );
    pipeline.stop();
}

/// Paced, the synthesiser never runs ahead of the wall clock, and falls behind it only
/// where it reports so (a late block: more than 100 ms behind, when it starts pacing
/// afresh). Measured over half a second from its first block, so that start-up, which is
/// slower on a slower machine, is not counted against it.
#[test]
fn real_time_pacing_follows_the_wall_clock() {
    let mut settings = default_settings();
    settings.synth.sample_rate = 1e6;
    settings.synth.realtime = true;
    for d in &mut settings.demods {
        d.rate = 100.0;
        d.harmonic = d.harmonic.min(4);
    }
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while pipeline.counters().samples_synthesized == 0 {
        assert!(Instant::now() < deadline, "no block synthesised in 60 s");
        output.drain();
        std::thread::sleep(Duration::from_millis(1));
    }
    let (start, before) = (Instant::now(), pipeline.counters());
    while start.elapsed() < Duration::from_millis(500) {
        output.drain();
        std::thread::sleep(Duration::from_millis(10));
    }
    let (elapsed, after) = (start.elapsed().as_secs_f64(), pipeline.counters());
    let simulated = (after.samples_synthesized - before.samples_synthesized) as f64 / 1e6;
    // At either end the count may be one block ahead of the clock or one block short of
    // the block being made.
    let block = ftafm::pipeline::BLOCK_SAMPLES as f64 / 1e6;
    assert!(
        simulated <= elapsed + 2.0 * block,
        "ran ahead: simulated {simulated} s in {elapsed} s of wall time"
    );
    if after.late_blocks == before.late_blocks {
        assert!(
            simulated >= elapsed - 0.1 - 2.0 * block,
            "fell behind without a late block: simulated {simulated} s in {elapsed} s"
        );
    }
    assert_eq!(after.overrun_samples, 0);
    pipeline.stop();
}

#[test]
fn an_overrun_is_counted_and_nothing_is_lost_silently() {
    // A DSP far slower than real time (a 2^20-point FFT 1000 times a second at 10 MS/s):
    // the ring fills, the synthesiser drops blocks, and every sample is accounted for.
    let mut settings = default_settings();
    settings.synth.realtime = true;
    settings.spectrum.size = 1 << 20;
    settings.spectrum.rate = 1000.0;
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    // A guard against a hang, not a timing margin: the DSP works through a ring of 0.5 s of
    // samples at a few hundred kS/s here, 2–20 s depending on the machine and its load.
    let deadline = Instant::now() + Duration::from_secs(180);
    // Wait until blocks were dropped and the DSP, working through the backlog, met the gap.
    while pipeline.counters().overrun_blocks < 3 || pipeline.counters().discontinuities < 1 {
        output.drain();
        assert!(
            Instant::now() < deadline,
            "no overrun happened: {:?}",
            pipeline.counters()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let c = pipeline.stop();
    assert!(
        c.overrun_samples >= 3 * 4096 && c.overrun_samples % 4096 == 0,
        "{c:?}"
    );
    assert!(c.discontinuities >= 1, "the DSP saw the gap: {c:?}");
    assert_eq!(
        c.samples_synthesized,
        c.samples_processed + c.overrun_samples + c.ring_fill,
        "every sample is processed, dropped-and-counted, or still in the ring: {c:?}"
    );
}

/// Scope traces of a running pipeline, the other outputs drained, until `done` (60 s at most).
fn collect_traces(
    pipeline: &Pipeline,
    output: &mut PipelineOutput,
    mut done: impl FnMut(&[ScopeBuffer]) -> bool,
) -> Vec<ScopeBuffer> {
    let mut traces = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !done(&traces) {
        output.demods.skip(usize::MAX);
        while let Some(b) = output.spectra.try_pop() {
            output.recycle(b);
        }
        while let Some(t) = output.scopes.try_pop() {
            traces.push(t);
        }
        assert!(Instant::now() < deadline, "{:?}", pipeline.counters());
        std::thread::sleep(Duration::from_millis(1));
    }
    traces
}

/// The stream of `settings` up to the last trace's newest sample, synthesised here, with
/// the plan and the state it ends in.
fn offline_stream(
    settings: &Settings,
    traces: &[ScopeBuffer],
) -> (SynthPlan, SynthState, Vec<f64>) {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, settings.synth.seed);
    let last = traces.last().unwrap().sample_index as usize;
    let mut stream = vec![0.0; last + 1];
    plan.process(&mut state, &mut stream);
    (plan, state, stream)
}

#[test]
fn scope_traces_are_the_synthesised_samples_with_their_drive_phase() {
    let mut settings = free_running_quiet();
    settings.scope.length = 500;
    settings.scope.decimation = 3;
    settings.scope.rate = 100.0;
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let traces = collect_traces(&pipeline, &mut output, |t| t.len() >= 5);
    pipeline.stop();
    // The same stream, synthesised here: noise off, so it is the same whatever the seed.
    let (plan, _, stream) = offline_stream(&settings, &traces);
    for t in &traces {
        assert_eq!(t.samples.len(), 500);
        assert_eq!(t.dt, 3.0 / settings.synth.sample_rate);
        let first = t.sample_index as usize - 499 * 3;
        for (j, &s) in t.samples.iter().enumerate() {
            assert_eq!(
                s,
                stream[first + 3 * j] as f32,
                "trace at {first}, sample {j}"
            );
        }
        // The drive phase at which the sample was taken: the ADC filter's delay before.
        let phase = ftafm::timebase::phase_to_radians(
            plan.output_phase(plan.frequency_word.wrapping_mul(first as u64)),
        );
        assert!(
            (t.start_phase - phase).abs() < 1e-12,
            "start phase {} vs {phase}",
            t.start_phase
        );
        // Traces start every f_s / rate = 100 000 samples.
        assert_eq!(first % 100_000, 0, "trace starts on the rate grid: {first}");
    }
}

#[test]
fn with_noise_the_chain_streams_the_offline_synthesis_whoever_draws_the_deviates() {
    use ftafm::synth::noise_pages::PAGE;
    // Noise on: the DSP thread draws pages of deviates ahead, the synthesiser the ones it
    // finds missing; the stream must be the offline synthesiser's bit for bit either way.
    let mut settings = default_settings();
    settings.synth.realtime = false;
    settings.synth.seed = 12345;
    settings.scope.length = 500;
    settings.scope.decimation = 1;
    settings.scope.rate = 100.0;
    let (pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let traces = collect_traces(&pipeline, &mut output, |t| {
        t.len() >= 4 && pipeline.counters().noise_pages_taken >= 2
    });
    let c = pipeline.stop();
    assert_eq!(
        c.noise_pages_taken + c.noise_pages_drawn_inline,
        c.samples_synthesized / PAGE as u64,
        "every block's page was taken or drawn in place: {c:?}"
    );
    assert!(
        c.noise_pages_drawn_ahead >= c.noise_pages_taken + c.noise_pages_discarded,
        "{c:?}"
    );
    let (_, state, stream) = offline_stream(&settings, &traces);
    // Alone, the synthesiser draws every page itself.
    assert_eq!(
        state.noise_pages().drawn,
        (stream.len() as u64).div_ceil(PAGE as u64)
    );
    for t in &traces {
        let first = t.sample_index as usize - 499;
        for (j, &s) in t.samples.iter().enumerate() {
            assert_eq!(s, stream[first + j] as f32, "trace at {first}, sample {j}");
        }
    }
}

#[test]
fn a_live_change_of_spectrum_size_gives_whole_spectra() {
    let mut settings = free_running_quiet();
    settings.spectrum.size = 1024;
    settings.spectrum.rate = 200.0;
    let (mut pipeline, mut output) = Pipeline::start(&settings).unwrap();
    let mut bigger = settings.clone();
    bigger.spectrum.size = 1 << 18;
    bigger.scope.length = 700; // a scope change reaches the DSP too
    pipeline.apply(&bigger).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut lengths = std::collections::BTreeSet::new();
    let mut traces = std::collections::BTreeSet::new();
    while !lengths.contains(&((1 << 17) + 1)) || !traces.contains(&700) {
        output.demods.skip(usize::MAX);
        while let Some(b) = output.spectra.try_pop() {
            lengths.insert(b.magnitudes.len());
            output.recycle(b);
        }
        while let Some(b) = output.scopes.try_pop() {
            traces.insert(b.samples.len());
            output.recycle_scope(b);
        }
        assert!(
            Instant::now() < deadline,
            "no full-size spectrum after the change: {lengths:?}"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // Every spectrum is whole: N/2 + 1 bins of the size in force.
    assert!(
        lengths.iter().all(|&n| n == 513 || n == (1 << 17) + 1),
        "{lengths:?}"
    );
    pipeline.stop();
}
