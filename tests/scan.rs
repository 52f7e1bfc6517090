//! The scan in the synthesiser: tap tables over distance, the amplitude feedback's step
//! response, and the material and height under the tip reaching the signal.

use std::time::Instant;

use ftafm::config::{Engine, Settings, default_settings};
use ftafm::model;
use ftafm::synth::{PidRuntime, PixelTopography, ScanLoops, ScanRuntime, SynthPlan, SynthState};

fn quiet(mut s: Settings) -> Settings {
    s.noise.enable = false;
    s
}

fn scanning(mut s: Settings) -> Settings {
    s.scan.enable = true;
    s
}

/// Runs `plan` for `seconds` of simulated time in blocks, returning per-period
/// (time, distance, amplitude) every `every` samples and the pixels' topography.
fn run(
    plan: &SynthPlan,
    state: &mut SynthState,
    rt: &mut ScanRuntime,
    seconds: f64,
    every: usize,
) -> (Vec<(f64, f64, f64)>, Vec<PixelTopography>) {
    let mut block = vec![0.0; every];
    let mut trace = Vec::new();
    let mut pixels = Vec::new();
    let n = (seconds * plan.sample_rate) as usize / every;
    for _ in 0..n {
        plan.process_scan(state, rt, None, &mut block, &mut |p| pixels.push(p));
        trace.push((
            state.sample_index() as f64 / plan.sample_rate,
            rt.distance,
            rt.amplitude,
        ));
    }
    (trace, pixels)
}

#[test]
fn tap_tables_cover_the_operating_range_and_match_direct_solves() {
    // The tap tables are the paper engine's (the coupled one integrates the scan directly).
    let mut settings = scanning(quiet(default_settings()));
    settings.synth.engine = ftafm::config::Engine::Paper;
    let started = Instant::now();
    let plan = SynthPlan::new(&settings).unwrap();
    let built = started.elapsed();
    let tables = plan.scan.as_ref().unwrap().tables.as_ref().unwrap();
    assert_eq!(tables.regions.len(), 2, "base + the default disc");
    assert_eq!(tables.failed, 0, "every grid point solves");
    eprintln!("plan with tap tables built in {built:?}");
    let cantilever = model::cantilever(&settings).unwrap();
    // Off the grid nodes, interpolation agrees with a direct solve to 0.2 %.
    for (region, material) in [
        (0, settings.sample),
        (1, {
            let mut m = settings.sample;
            m.youngs_modulus = 116.1e9;
            m
        }),
    ] {
        for d in [17.3e-9, 20.0e-9, 21.7e-9] {
            let mut s = settings.clone();
            s.surface.distance = d;
            let direct = model::impact_oscillator(&s, &cantilever, material)
                .solve()
                .unwrap();
            let t = tables.regions[region].at(d);
            let rel = |a: f64, b: f64| (a - b).abs() / b;
            assert!(
                rel(t.max_force, direct.max_force) < 2e-3,
                "F at {d}: {} vs {}",
                t.max_force,
                direct.max_force
            );
            assert!(rel(t.tau, direct.contact_time_ratio) < 2e-3, "τ at {d}");
            assert!(
                (t.centre_phase - direct.pulse_phase).abs() < 2e-3,
                "phase at {d}"
            );
        }
    }
    // Beyond the free amplitude the tip does not reach the surface.
    assert_eq!(tables.regions[0].at(31e-9).max_force, 0.0);
}

#[test]
fn the_feedback_holds_the_setpoint_and_settles_after_a_step_without_ringing() {
    for engine in Engine::ALL {
        feedback_step(engine);
    }
}

fn feedback_step(engine: Engine) {
    let mut settings = scanning(quiet(default_settings()));
    settings.synth.engine = engine;
    // A scan area far from the inclusion: the base material only.
    settings.scan.x = 5e-6;
    let plan = SynthPlan::new(&settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut rt = ScanRuntime::new(&plan);
    rt.retarget(&plan, &plan, 0);
    let setpoint = plan.scan.as_ref().unwrap().setpoint;
    let (trace, _) = run(&plan, &mut state, &mut rt, 0.01, 1000);
    // The auto setpoint is the steady amplitude at /surface/distance: the controller stays
    // there (the synthesised fundamental matches the model it was computed from).
    let (_, d, a) = *trace.last().unwrap();
    eprintln!(
        "{engine:?}: amplitude {a:e} vs setpoint {setpoint:e}, distance {:.4} nm",
        d * 1e9
    );
    assert!(
        (a - setpoint).abs() / setpoint < 1e-3,
        "{engine:?}: amplitude {a} vs setpoint {setpoint}"
    );
    assert!((d - 20e-9).abs() < 0.2e-9, "{engine:?}: distance {d}");

    // Step the setpoint down by 1 nm.
    let mut stepped = settings.clone();
    stepped.feedback.setpoint = setpoint - 1e-9;
    let next =
        SynthPlan::with_tables(&stepped, plan.scan.as_ref().unwrap().tables.as_ref()).unwrap();
    state.retarget(&plan, &next);
    rt.retarget(&plan, &next, state.sample_index());
    let t0 = state.sample_index() as f64 / next.sample_rate;
    let (trace, _) = run(&next, &mut state, &mut rt, 0.02, 500);
    let (_, d_end, a_end) = *trace.last().unwrap();
    let target = setpoint - 1e-9;
    assert!(
        (a_end - target).abs() < 5e-12,
        "settles to the new setpoint: {a_end} vs {target}"
    );
    let step = 20e-9 - d_end;
    assert!(step > 0.5e-9, "the sample comes closer: {step}");
    // Settling: within 2 % of the step after 5 ms; overshoot below 10 %.
    let overshoot = trace
        .iter()
        .map(|&(_, d, _)| (d_end - d) / step)
        .fold(0.0f64, f64::max);
    let settle = trace
        .iter()
        .rev()
        .find(|&&(_, d, _)| ((d - d_end) / step).abs() > 0.02)
        .map_or(t0, |&(t, _, _)| t)
        - t0;
    eprintln!(
        "{engine:?}: setpoint step -1 nm: distance step {:.3} nm, settled (2 %) after {:.2} ms, overshoot {:.1} %",
        step * 1e9,
        settle * 1e3,
        overshoot * 100.0
    );
    assert!(settle < 5e-3, "settling time {settle}");
    assert!(overshoot < 0.10, "overshoot {overshoot}");
}

#[test]
fn a_raised_inclusion_shows_as_height_and_the_softer_one_not_at_all() {
    for engine in Engine::ALL {
        raised_inclusion(engine);
    }
}

fn raised_inclusion(engine: Engine) {
    let mut settings = scanning(quiet(default_settings()));
    settings.synth.engine = engine;
    settings.scan.pixels = 16;
    settings.scan.line_rate = 10.0;
    settings.inclusions[0].height = 2e-9;
    settings.inclusions[0].youngs_modulus = 129e9;
    let plan = SynthPlan::new(&settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut rt = ScanRuntime::new(&plan);
    rt.retarget(&plan, &plan, 0);
    // Lines 7 and 8 cross the centre of the disc.
    let (_, pixels) = run(&plan, &mut state, &mut rt, 9.0 / 10.0, 4096);
    let line: Vec<&PixelTopography> = pixels
        .iter()
        .filter(|p| p.pixel.line == 7 && !p.pixel.retrace)
        .collect();
    assert_eq!(line.len(), 16);
    let heights: Vec<f64> = line.iter().map(|p| p.height).collect();
    eprintln!(
        "{engine:?}: line 7 heights (nm): {:?}",
        heights
            .iter()
            .map(|h| (h * 1e11).round() / 100.0)
            .collect::<Vec<_>>()
    );
    // Columns 6–9 lie in the disc (radius 167 nm around the centre, pixels 62.5 nm); 7
    // and 8 are clear of the edges, where the feedback is still catching up.
    for (c, h) in heights.iter().enumerate().take(9).skip(7) {
        assert!((h - 2e-9).abs() < 0.1e-9, "{engine:?}: column {c}: {h}");
    }
    for c in [0, 1, 14, 15] {
        assert!(
            heights[c].abs() < 0.1e-9,
            "{engine:?}: column {c}: {}",
            heights[c]
        );
    }
}

/// With `/feedback/enable = false`, a PID unit on the surface distance is the scan's
/// feedback: the same PI (i = 1200 /s) on the same amplitude set-point, as a unit, images
/// the 2 nm disc as the scan's own feedback does (its pixels within 0.1 nm of 2 nm on the
/// disc and of 0 off it), and the two height lines agree within 0.1 nm everywhere; the
/// unit's updates run beside the scan.
#[test]
fn a_pid_unit_is_the_scans_feedback() {
    let mut settings = scanning(quiet(default_settings()));
    settings.scan.pixels = 16;
    settings.scan.line_rate = 10.0;
    settings.inclusions[0].height = 2e-9;
    settings.inclusions[0].youngs_modulus = 129e9;
    let own = SynthPlan::new(&settings).unwrap();
    let setpoint = own.scan.as_ref().unwrap().setpoint;
    settings.feedback.enable = false;
    let pid = &mut settings.pids[0];
    pid.enable = true;
    (pid.p, pid.i, pid.setpoint) = (0.0, 1200.0, setpoint);
    (pid.output_min, pid.output_max) = (0.0, 100e-9);
    ftafm::model::check(&settings).expect("a unit on the surface with the feedback off");
    let plan = SynthPlan::new(&settings).unwrap();
    let line7 = |pixels: &[PixelTopography]| -> Vec<f64> {
        pixels
            .iter()
            .filter(|p| p.pixel.line == 7 && !p.pixel.retrace)
            .map(|p| p.height)
            .collect()
    };
    let (_, reference) = {
        let mut state = SynthState::steady(&own, 1);
        let mut rt = ScanRuntime::new(&own);
        rt.retarget(&own, &own, 0);
        run(&own, &mut state, &mut rt, 0.9, 4096)
    };
    let mut state = SynthState::steady(&plan, 1);
    let mut rt = ScanRuntime::new(&plan);
    let mut loops = PidRuntime::new(&plan);
    rt.retarget(&plan, &plan, 0);
    loops.retarget(&plan, &plan, 0, &mut state);
    let mut block = vec![0.0; 4096];
    let (mut pixels, mut updates) = (Vec::new(), 0usize);
    for _ in 0..(0.9 * plan.sample_rate) as usize / block.len() {
        let sinks = ScanLoops {
            runtime: &mut loops,
            reading: &mut |_| updates += 1,
            reference: &mut |_| {},
        };
        plan.process_scan(&mut state, &mut rt, Some(sinks), &mut block, &mut |p| {
            pixels.push(p)
        });
    }
    let (want, got) = (line7(&reference), line7(&pixels));
    eprintln!(
        "line 7 (nm), the scan's feedback: {:?}\n             a PID unit:      {:?}",
        want.iter()
            .map(|h| (h * 1e11).round() / 100.0)
            .collect::<Vec<_>>(),
        got.iter()
            .map(|h| (h * 1e11).round() / 100.0)
            .collect::<Vec<_>>()
    );
    assert_eq!(got.len(), 16);
    assert!(
        updates as f64 > 0.8 * 0.9 * settings.drive.frequency,
        "{updates} updates"
    );
    for c in [7, 8] {
        assert!((got[c] - 2e-9).abs() < 0.1e-9, "column {c}: {}", got[c]);
    }
    for c in [0, 1, 14, 15] {
        assert!(got[c].abs() < 0.1e-9, "column {c}: {}", got[c]);
    }
    for (c, (a, b)) in want.iter().zip(&got).enumerate() {
        assert!((a - b).abs() < 0.1e-9, "column {c}: {a} against {b}");
    }
}

/// Drains the pipeline's output; returns the serials of the scan pixels whose harmonics
/// came out.
fn drain_pixels(output: &mut ftafm::pipeline::PipelineOutput, serials: &mut Vec<u64>) {
    use ringbuf::traits::Consumer;
    while let Some(p) = output.pixels.try_pop() {
        serials.push(p.pixel.serial);
    }
    output.topography.skip(usize::MAX);
    output.demods.skip(usize::MAX);
    while let Some(b) = output.spectra.try_pop() {
        output.recycle(b);
    }
    while let Some(b) = output.scopes.try_pop() {
        output.recycle_scope(b);
    }
}

/// Waits (bounded, generously) until `done` says so, draining the output meanwhile.
fn drain_until(
    pipeline: &ftafm::pipeline::Pipeline,
    output: &mut ftafm::pipeline::PipelineOutput,
    serials: &mut Vec<u64>,
    what: &str,
    mut done: impl FnMut(&ftafm::pipeline::CountersSnapshot, &[u64]) -> bool,
) {
    let deadline = Instant::now() + std::time::Duration::from_secs(120);
    while !done(&pipeline.counters(), serials) {
        drain_pixels(output, serials);
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
}

/// A DSP thread held until the ring overruns loses the pixels of the gap; every one of
/// them is counted in `pixels_dropped`, so the count equals the serials missing from what
/// came out (each one a `NaN` pixel of the image).
#[test]
fn pixels_lost_to_an_overrun_are_counted() {
    let mut s = quiet(scanning(default_settings()));
    s.synth.sample_rate = 2e6;
    for d in &mut s.demods {
        d.harmonic = d.harmonic.min(9);
    }
    s.inversion.enable = false;
    s.scope.enable = false;
    s.spectrum.enable = false;
    s.scan.pixels = 8;
    // 1250 samples (0.625 ms) per pixel: a one-second gap holds some 1600.
    s.scan.line_rate = 100.0;
    let (pipeline, mut output) = ftafm::pipeline::Pipeline::start(&s).unwrap();
    let mut serials = Vec::new();
    drain_until(&pipeline, &mut output, &mut serials, "pixels", |_, got| {
        got.len() >= 50
    });
    let overruns = pipeline.counters().overrun_blocks;
    pipeline.hold_dsp(true);
    drain_until(
        &pipeline,
        &mut output,
        &mut serials,
        "an overrun",
        |c, _| c.overrun_blocks >= overruns + 8,
    );
    pipeline.hold_dsp(false);
    // The DSP first works through the full ring, then meets the gap.
    drain_until(&pipeline, &mut output, &mut serials, "the gap", |c, _| {
        c.discontinuities > 0
    });
    let after = serials.len() + 200;
    drain_until(
        &pipeline,
        &mut output,
        &mut serials,
        "pixels after",
        |_, got| got.len() >= after,
    );
    let counters = pipeline.stop();
    drain_pixels(&mut output, &mut serials);
    assert!(serials.windows(2).all(|w| w[0] < w[1]), "in scan order");
    let last = *serials.last().unwrap();
    let missing = last + 1 - serials.len() as u64;
    assert!(missing > 0, "the overrun cost no pixel: {counters:?}");
    assert_eq!(
        counters.pixels_dropped, missing,
        "pixels missing from 0 … {last} against pixels_dropped (overrun {} blocks)",
        counters.overrun_blocks
    );
}

/// A soft disc (3 GPa, no height) under amplitude feedback: the tip indents it deeper, so
/// the height image shows it as a dip, on either engine, and the two engines agree on its
/// depth as far as their tap forces agree.
#[test]
fn a_soft_inclusion_shows_as_its_extra_indentation() {
    let mut depths = Vec::new();
    for engine in Engine::ALL {
        let mut settings = scanning(quiet(default_settings()));
        settings.synth.engine = engine;
        settings.scan.pixels = 16;
        settings.scan.line_rate = 10.0;
        settings.inclusions[0].height = 0.0;
        settings.inclusions[0].youngs_modulus = 3e9;
        settings.inclusions[0].relative_modulus = 0.0;
        let plan = SynthPlan::new(&settings).unwrap();
        let mut state = SynthState::steady(&plan, 1);
        let mut rt = ScanRuntime::new(&plan);
        rt.retarget(&plan, &plan, 0);
        let (_, pixels) = run(&plan, &mut state, &mut rt, 9.0 / 10.0, 4096);
        let heights: Vec<f64> = pixels
            .iter()
            .filter(|p| p.pixel.line == 7 && !p.pixel.retrace)
            .map(|p| p.height)
            .collect();
        eprintln!(
            "{engine:?}: line 7 heights over a 3 GPa disc (nm): {:?}",
            heights
                .iter()
                .map(|h| (h * 1e12).round() / 1000.0)
                .collect::<Vec<_>>()
        );
        let inside = 0.5 * (heights[7] + heights[8]);
        let outside = 0.25 * (heights[0] + heights[1] + heights[14] + heights[15]);
        depths.push(outside - inside);
    }
    eprintln!(
        "dip: paper {:.4} nm, coupled {:.4} nm",
        depths[0] * 1e9,
        depths[1] * 1e9
    );
    for d in &depths {
        assert!(*d > 0.1e-9, "the soft disc shows as a dip: {d}");
    }
    // Measured 1.359 and 1.348 nm: the fundamental the feedback holds is where the paper's
    // approximation is closest (issue 14's reference: F within 1 %).
    assert!(
        (depths[0] - depths[1]).abs() < 0.03 * depths[1],
        "the engines disagree on the dip: {depths:?}"
    );
}
