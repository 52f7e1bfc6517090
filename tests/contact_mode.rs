//! Contact mode: a PID unit on the mean deflection (`/pids/N/input = "mean_deflection"`)
//! holds the lever's static deflection by the surface distance. At its set-point the
//! contact's force, the tip's deflection and the indentation are those of a Hertz contact
//! in static balance with the lever's modes, derived here from the modes alone; as the
//! scan's feedback it images a step's height less the indentations' difference; and the
//! settings refuse what it cannot read, naming the node.

mod common;

use common::loops::{assert_step_as_advised, mean_and_spread, refused, run, setpoint_step, start};
use ftafm::config::{Oscillator, PidInput, PidTarget, Settings, default_settings};
use ftafm::control::{Kind, advise};
use ftafm::instrument::unit_loop::unit_loop;
use ftafm::synth::scan::PixelTopography;
use ftafm::synth::{PidRuntime, ScanLoops, ScanRuntime, SynthPlan, SynthState};
use serde_json::json;

/// The default lever barely driven (1 pm), resting 2 nm above the surface, noise off; unit
/// 0 holds the mean deflection at `setpoint` (m of photodiode signal) by the surface
/// distance: an integrator of `bandwidth` Hz on the static plant, whose slope is about −1
/// (the deflection falls as the surface recedes).
fn contact_mode(setpoint: f64, bandwidth: f64) -> Settings {
    let mut s = default_settings();
    s.noise.enable = false;
    s.drive.free_amplitude = 1e-12;
    s.surface.distance = 2e-9;
    let pid = &mut s.pids[0];
    pid.enable = true;
    pid.input = PidInput::MeanDeflection;
    pid.oscillator = Oscillator::Drive;
    pid.output = PidTarget::SurfaceDistance;
    pid.setpoint = setpoint;
    (pid.p, pid.i, pid.d) = (0.0, -2.0 * std::f64::consts::PI * bandwidth, 0.0);
    (pid.output_min, pid.output_max) = (-100e-9, 100e-9);
    s
}

/// The static balance at a photodiode deflection `reading` (m) on a sample of Young's
/// modulus `youngs` (Pa) and Poisson ratio `poisson`: the lever's modes each deflect by F/k_n at the tip (k_n
/// tip-referred) and the photodiode reads Σ λ_n·F/k_n (λ_n the light-lever factors), so
/// F = reading / Σ λ_n/k_n and the tip rises by F·Σ 1/k_n; the Hertz contact takes
/// δ = (3F/(4E*√R))^{2/3}. The surface then stands z + δ above the tip's rest position:
/// the distance is −(z + δ). Returns (F, z, δ, distance).
fn balance(s: &Settings, reading: f64, youngs: f64, poisson: f64) -> (f64, f64, f64, f64) {
    let lever = ftafm::model::cantilever(s).unwrap();
    let per_force: f64 = lever
        .modes
        .iter()
        .map(|m| m.light_lever_factor() / m.tip_stiffness())
        .sum();
    let compliance: f64 = lever.modes.iter().map(|m| 1.0 / m.tip_stiffness()).sum();
    let force = reading / per_force;
    let z = force * compliance;
    let (t, nu) = (&s.tip, poisson);
    let reduced =
        1.0 / ((1.0 - t.poisson * t.poisson) / t.youngs_modulus + (1.0 - nu * nu) / youngs);
    let delta = (3.0 * force / (4.0 * reduced * s.cantilever.tip_radius.sqrt())).powf(2.0 / 3.0);
    (force, z, delta, -(z + delta))
}

/// From 2 nm above the surface the loop takes it up until the photodiode reads the
/// set-point; the surface then stands where the static Hertz balance puts it, within 0.1 %
/// of the deflection (the quantiser's half step of 1.5 pm is 0.15 % of 1 nm), at two
/// set-points a factor 4 apart.
#[test]
fn a_deflection_loop_holds_the_hertz_balance() {
    for setpoint in [0.5e-9, 2e-9] {
        let s = contact_mode(setpoint, 2000.0);
        let (plan, mut state, mut rt) = start(&s, 1);
        let readings = run(&plan, &mut state, &mut rt, 0.005);
        let tail: Vec<_> = readings
            .iter()
            .filter(|r| r.sample as f64 > 0.003 * plan.sample_rate)
            .collect();
        let (measured, _) = mean_and_spread(tail.iter().map(|r| r.measurement));
        let (distance, spread) = mean_and_spread(tail.iter().map(|r| r.output));
        let (force, z, delta, want) =
            balance(&s, setpoint, s.sample.youngs_modulus, s.sample.poisson);
        eprintln!(
            "deflection {:.4} nm (set-point {:.4} nm): surface at {:.5} nm (± {:.1e}), the \
             balance's {:.5} nm (F {:.3} nN, tip up {:.4} nm, δ {:.4} nm)",
            measured * 1e9,
            setpoint * 1e9,
            distance * 1e9,
            spread,
            want * 1e9,
            force * 1e9,
            z * 1e9,
            delta * 1e9
        );
        assert!(
            (measured / setpoint - 1.0).abs() < 1e-3,
            "held at {measured}"
        );
        assert!(
            (distance - want).abs() < 1e-3 * setpoint,
            "surface at {distance}, the balance puts it at {want}"
        );
        assert!(tail.iter().all(|r| !r.limited));
    }
}

/// Contact mode imaging: with the scan's own feedback off, the deflection loop is its
/// feedback. Over a 2 nm step of a 10 GPa disc on silicon (129 GPa) it reads the step less
/// the deeper indentation of the softer disc at the same force, as the balance gives it:
/// the height lines over the disc and off it differ by that within 5 pm.
#[test]
fn constant_deflection_images_height_less_indentation() {
    let mut s = contact_mode(1e-9, 1000.0);
    s.scan.enable = true;
    s.feedback.enable = false;
    s.scan.pixels = 16;
    s.scan.line_rate = 10.0;
    let disc = &mut s.inclusions[0];
    (disc.height, disc.relative_modulus, disc.youngs_modulus) = (2e-9, 0.0, 10e9);
    ftafm::model::check(&s).expect("contact mode as the scan's feedback");
    let plan = SynthPlan::new(&s).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut scan = ScanRuntime::new(&plan);
    let mut loops = PidRuntime::new(&plan);
    scan.retarget(&plan, &plan, 0);
    loops.retarget(&plan, &plan, 0, &mut state);
    let mut block = vec![0.0; 4096];
    let mut pixels: Vec<PixelTopography> = Vec::new();
    for _ in 0..(0.9 * plan.sample_rate) as usize / block.len() {
        let sinks = ScanLoops {
            runtime: &mut loops,
            reading: &mut |_| {},
            reference: &mut |_| {},
        };
        plan.process_scan(&mut state, &mut scan, Some(sinks), &mut block, &mut |p| {
            pixels.push(p)
        });
    }
    let line: Vec<f64> = pixels
        .iter()
        .filter(|p| p.pixel.line == 7 && !p.pixel.retrace)
        .map(|p| p.height)
        .collect();
    let (_, _, on_silicon, _) = balance(&s, 1e-9, s.sample.youngs_modulus, s.sample.poisson);
    let (_, _, on_disc, _) = balance(&s, 1e-9, 10e9, s.inclusions[0].poisson);
    let want = 2e-9 - (on_disc - on_silicon);
    let silicon = (line[0] + line[1] + line[14] + line[15]) / 4.0;
    let step = (line[7] + line[8]) / 2.0 - silicon;
    eprintln!(
        "line 7 (nm): {:?}; step {:.4} nm, the balance's {:.4} nm (δ {:.4} nm on the disc, \
         {:.4} nm on silicon)",
        line.iter()
            .map(|h| (h * 1e12).round() / 1000.0)
            .collect::<Vec<_>>(),
        step * 1e9,
        want * 1e9,
        on_disc * 1e9,
        on_silicon * 1e9
    );
    assert_eq!(line.len(), 16);
    assert!((step - want).abs() < 0.005e-9, "step {step}, want {want}");
}

/// The advisor's model of the deflection loop (op `pid_advise`'s, `unit_loop`): its plant's
/// slope is the balance's, the change of deflection with the surface distance measured on
/// the coupled engine within 1 %; with its gains (negated: the deflection falls as the
/// surface recedes) a 5 % step of the set-point settles as the linear model predicts at
/// 300 Hz and 2 kHz (within 10 % or two updates), and within 30 % at 4 and 6 kHz. The plant
/// answers at once, so the advice is an integrator alone, and a PID is refused naming the
/// kind.
#[test]
fn the_advised_deflection_loop_steps_as_the_advisor_predicts() {
    let base = contact_mode(1e-9, 1000.0);
    let unit = unit_loop(&base, 0).expect("the deflection loop is modelled");
    assert_eq!(unit.sign, -1.0);
    eprintln!("{}", unit.plant);
    // The slope against two balances 1 % apart on the engine itself.
    let slope = unit.model.plant.gain().unwrap();
    let held = |setpoint: f64| {
        let s = contact_mode(setpoint, 2000.0);
        let (plan, mut state, mut rt) = start(&s, 1);
        let readings = run(&plan, &mut state, &mut rt, 0.004);
        readings.last().unwrap().output
    };
    let measured = 0.01e-9 / (held(0.995e-9) - held(1.005e-9));
    eprintln!("slope: modelled {slope:.5}, measured {measured:.5} m/m");
    assert!((measured / slope - 1.0).abs() < 0.01);
    let update = 1.0 / base.drive.frequency;
    assert!(
        advise(&unit.model, 1000.0, Kind::Pid)
            .unwrap_err()
            .to_string()
            .contains("kind \"pid\" does not fit")
    );
    for target in [300.0, 2000.0, 4000.0, 6000.0] {
        let kind = Kind::Pi;
        let advice = advise(&unit.model, target, kind).unwrap();
        assert_eq!(advice.gains.p, 0.0, "an integrator alone");
        let mut settings = base.clone();
        let pid = &mut settings.pids[0];
        (pid.p, pid.i, pid.d) = (-advice.gains.p, -advice.gains.i, -advice.gains.d);
        pid.d_bandwidth = advice.gains.d_bandwidth;
        let (overshoot, settling) = setpoint_step(
            &settings,
            0,
            1.05e-9,
            1,
            (
                0.004 + 20.0 / target,
                (10.0 * advice.step.settling_time).max(0.004),
            ),
        );
        eprintln!(
            "advised deflection loop {kind:?} {target} Hz: P {:.4e} I {:.4e} /s; bandwidth \
             {:.1} Hz, margin {:.1}°; overshoot measured {:.2} % predicted {:.2} %; settling \
             measured {:.1} µs predicted {:.1} µs",
            -advice.gains.p,
            -advice.gains.i,
            advice.bandwidth,
            advice.phase_margin,
            100.0 * overshoot,
            100.0 * advice.step.overshoot,
            1e6 * settling,
            1e6 * advice.step.settling_time,
        );
        if target > 3000.0 {
            // Above a few kHz the live loop settles up to a quarter later than the linear
            // model (docs/loops.md); held to that.
            assert!(overshoot < 0.01 && settling < 1.3 * advice.step.settling_time);
            continue;
        }
        assert_step_as_advised(
            &format!("{kind:?} {target} Hz"),
            &advice,
            overshoot,
            settling,
            update,
        );
    }
}

/// What the mean deflection cannot be: read over drive2's low-pass (the boxcar of the
/// drive's period is its mean), a surface beyond ±1 µm; and what it does not need: a
/// harmonic in band.
#[test]
fn the_settings_refuse_what_it_cannot_read_naming_the_node() {
    let s = contact_mode(1e-9, 1000.0);
    let mut second = s.clone();
    second.drive2.enable = true;
    let e = refused(&second, &[("/pids/0/oscillator", json!("drive2"))]);
    assert_eq!(e.path(), "/pids/0/oscillator", "{e}");
    assert!(e.to_string().contains("mean_deflection"), "{e}");
    let e = refused(&s, &[("/pids/0/output_min", json!(-2e-6))]);
    assert_eq!(e.path(), "/pids/0/output_min", "{e}");
    assert!(e.to_string().contains("-1 µm ≤ value"), "{e}");
    let mut high = s.clone();
    high.pids[0].harmonic = 10_000;
    ftafm::model::check(&high).expect("the mean deflection reads no harmonic");
}

/// `config/examples/contact_mode.toml` runs contact mode as it says: its unit is the scan's
/// feedback on the mean deflection, with the advisor's integrator for a 2 kHz loop at its
/// own settings to the digits the file gives; the polystyrene island's step in the height
/// image, by the balance, is printed for docs/loops.md.
#[test]
fn the_contact_mode_example_carries_the_advisors_gains() {
    let example = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/examples/contact_mode.toml"
    );
    let s = ftafm::config::load_with_presets(&[], Some(example.as_ref())).unwrap();
    ftafm::model::check(&s).expect("the example runs");
    assert!(s.scan.enable && !s.feedback.enable);
    let pid = &s.pids[0];
    assert_eq!(
        (pid.input, pid.output),
        (PidInput::MeanDeflection, PidTarget::SurfaceDistance)
    );
    let unit = unit_loop(&s, 0).unwrap();
    let advice = advise(&unit.model, 2000.0, Kind::Pi).unwrap();
    assert_eq!(pid.p, 0.0);
    assert!(
        (pid.i / (unit.sign * advice.gains.i) - 1.0).abs() < 1e-4,
        "i {} against the advisor's {}",
        pid.i,
        unit.sign * advice.gains.i
    );
    let disc = &s.inclusions[0];
    let (_, _, on_silicon, _) =
        balance(&s, pid.setpoint, s.sample.youngs_modulus, s.sample.poisson);
    let (_, _, on_disc, _) = balance(&s, pid.setpoint, disc.youngs_modulus, disc.poisson);
    eprintln!(
        "the island's step by the balance: {:.4} nm (δ {:.4} nm on it, {:.4} nm on silicon)",
        (disc.height - (on_disc - on_silicon)) * 1e9,
        on_disc * 1e9,
        on_silicon * 1e9
    );
}
