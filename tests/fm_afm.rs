//! FM-AFM live on the coupled engine: a PLL keeps the lever at its resonance and an
//! amplitude loop on the drive keeps its amplitude, while the surface approaches in steps;
//! the frequency shift Δf(z) the PLL reports, inverted by Sader–Jarvis, returns the force
//! law the sample was configured with (DMT: van der Waals above the surface, Hertz less
//! the pull-off in contact).

mod common;

use std::f64::consts::PI;

use common::loops::{change, mean, pi_unit, run, start};
use ftafm::config::{Oscillator, PidInput, PidTarget, Settings, default_settings};
use ftafm::physics::fm::{FmLever, invert};
use ftafm::synth::{PidRuntime, ScanLoops, ScanRuntime, SynthPlan, SynthState};

/// Tip amplitude the amplitude loop holds (m, peak).
const AMPLITUDE: f64 = 5e-9;

/// The default lever and silicon sample with adhesion, driven at f1, PID 0 a 500 Hz PLL on
/// harmonic 1's phase (π, the resonance), PID 1 an amplitude loop on the drive holding the
/// photodiode amplitude of a tip amplitude `AMPLITUDE`.
fn fm_afm(calibration: f64) -> Settings {
    let mut s = default_settings();
    s.adhesion.enable = true;
    s.drive.free_amplitude = AMPLITUDE;
    let f1 = s.cantilever.f1;
    let q = s.cantilever.q[0];
    let route = (
        Oscillator::Drive,
        PidInput::Phase,
        PidTarget::DriveFrequency,
    );
    let plant = (500.0, -2.0 * q / f1, q / (PI * f1));
    pi_unit(&mut s, 0, route, PI, plant, (0.95 * f1, 1.05 * f1));
    let amplitude = &mut s.pids[1];
    amplitude.enable = true;
    amplitude.input = PidInput::R;
    amplitude.harmonic = 1;
    amplitude.setpoint = AMPLITUDE * calibration;
    amplitude.p = 0.0;
    amplitude.i = 3000.0;
    amplitude.output = PidTarget::DriveAmplitude;
    amplitude.output_min = 0.0;
    amplitude.output_max = 100e-9;
    s
}

/// An approach in FM-AFM: the closest approach z = distance − A from 4 nm to 0.3 nm in
/// steps of 50 pm, then to `deepest` into the sample in steps of 10 pm (where a contact's
/// force rises steeply), each point settled for 4 ms and then averaged over `average`
/// (s); Δf from the free lever's lock. Returns the inverted curve with the configured law
/// at each z, the measured Δf and amplitude.
fn approach(mut settings: Settings, deepest: f64, average: f64, calibration: f64) -> Approach {
    settings.surface.distance = AMPLITUDE + 20e-9;
    let (mut plan, mut state, mut rt) = start(&settings, 7);
    let _ = run(&plan, &mut state, &mut rt, 0.02);
    let free = run(&plan, &mut state, &mut rt, 0.05);
    let f_free = mean(free.iter().filter(|r| r.unit == 0).map(|r| r.output));
    let (mut z, mut df, mut amplitude) = (Vec::new(), Vec::new(), Vec::new());
    let coarse = (0..=74).map(|n| 4e-9 - 50e-12 * n as f64);
    let fine_steps = ((0.3e-9 + deepest) / 10e-12).round() as usize;
    let fine = (1..=fine_steps).map(|n| 0.3e-9 - 10e-12 * n as f64);
    for closest in coarse.chain(fine) {
        settings.surface.distance = closest + AMPLITUDE;
        change(&mut plan, &mut state, &mut rt, &settings);
        let _ = run(&plan, &mut state, &mut rt, 0.004);
        let r = run(&plan, &mut state, &mut rt, average);
        assert!(
            r.iter().all(|r| !r.limited),
            "a loop saturated at z = {closest:e} m"
        );
        z.push(closest);
        df.push(mean(r.iter().filter(|r| r.unit == 0).map(|r| r.output)) - f_free);
        amplitude.push(mean(r.iter().filter(|r| r.unit == 1).map(|r| r.measurement)) / calibration);
    }
    z.reverse();
    df.reverse();
    amplitude.reverse();
    // Mode 1's stiffness at the tip: its generalised stiffness over φ1(L)² (3 % above the
    // lever's static k: the higher modes' share of the static deflection).
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let mode = &cantilever.modes[0];
    let k1 = mode.stiffness / (mode.tip_value * mode.tip_value);
    let lever = FmLever::new(k1, f_free, AMPLITUDE).unwrap();
    let curve = invert(&z, &df, &lever).unwrap();
    // The configured law: DMT.
    let contact = ftafm::model::impact_oscillator(&settings, &cantilever, settings.sample).contact;
    let adhesion = ftafm::model::adhesion(&settings).unwrap();
    let law = |d: f64| contact.force(-d) + adhesion.force(contact.radius, -d);
    let single_mode = ftafm::physics::fm::frequency_shift_curve(&lever, law, &curve.z);
    let points = curve
        .z
        .iter()
        .enumerate()
        .map(|(n, &z)| Point {
            z,
            df: df[n],
            single_mode: single_mode[n],
            amplitude: amplitude[n],
            force: curve.force[n],
            law: law(z),
        })
        .collect();
    Approach { points }
}

/// One point of an approach: closest approach z (m), Δf (Hz) measured and from the
/// single-mode theory of the law, the amplitude held (m), the force inverted and the
/// law's (N).
struct Point {
    z: f64,
    df: f64,
    single_mode: f64,
    amplitude: f64,
    force: f64,
    law: f64,
}

struct Approach {
    points: Vec<Point>,
}

impl Approach {
    /// The largest |F − law| over the points where the law is at most `up_to` (N), as a
    /// fraction of the law's range there, and that range (N).
    fn worst_up_to(&self, up_to: f64) -> (f64, f64) {
        let points: Vec<&Point> = self.points.iter().filter(|p| p.law <= up_to).collect();
        let (lo, hi) = points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
            (lo.min(p.law), hi.max(p.law))
        });
        let worst = points
            .iter()
            .map(|p| (p.force - p.law).abs())
            .fold(0.0, f64::max);
        (worst / (hi - lo), hi - lo)
    }

    fn print(&self, every: usize) {
        for p in self.points.iter().step_by(every) {
            eprintln!(
                "z {:+.2} nm  Δf {:+9.2} Hz (single-mode theory {:+9.2})  A {:.3} nm  F {:+.3} \
                 nN  law {:+.3} nN",
                p.z * 1e9,
                p.df,
                p.single_mode,
                p.amplitude * 1e9,
                p.force * 1e9,
                p.law * 1e9
            );
        }
    }
}

/// Photodiode metres per metre of free tip amplitude at the resonance (harmonic 1).
fn calibration() -> f64 {
    let mut probe = default_settings();
    probe.drive.free_amplitude = AMPLITUDE;
    ftafm::synth::plan::free_reading(&probe).unwrap().norm() / AMPLITUDE
}

/// The repulsion up to which the tests compare (N): 6 % of k·A. Beyond it the tap
/// disturbs the tip's harmonic motion, which Sader–Jarvis assumes: it excites the higher
/// modes, and the inverted force falls below the law (by 7 % of the range at 1 nm into
/// the polymer, 20 % at 0.2 nm into silicon).
fn harmonic_limit(settings: &Settings) -> f64 {
    0.06 * settings.cantilever.k * AMPLITUDE
}

#[test]
fn a_polymers_force_law_comes_back_from_its_frequency_shift() {
    // A 3 GPa sample (a glassy polymer) under the silicon tip, with every noise source:
    // 16 ms of the 500 Hz PLL per point. From 4 nm above the surface to 1 nm into it.
    let calibration = calibration();
    let mut settings = fm_afm(calibration);
    settings.sample.youngs_modulus = 3e9;
    settings.sample.poisson = 0.35;
    let limit = harmonic_limit(&settings);
    let approach = approach(settings, 1.0e-9, 0.016, calibration);
    approach.print(10);
    let (worst, range) = approach.worst_up_to(limit);
    let (all, all_range) = approach.worst_up_to(f64::MAX);
    eprintln!(
        "polymer (3 GPa), noise on: worst |F − law| {:.2} % of the law's range {:.3} nN up to \
         {:.1} nN of repulsion; {:.2} % of {:.3} nN to 1 nm into the surface",
        worst * 100.0,
        range * 1e9,
        limit * 1e9,
        all * 100.0,
        all_range * 1e9
    );
    assert!(worst < 0.05, "worst {worst}");
}

#[test]
fn silicons_force_law_comes_back_until_the_tap_disturbs_the_motion() {
    // The default silicon sample, noise off: from 4 nm above the surface to 0.2 nm into it.
    let calibration = calibration();
    let mut settings = fm_afm(calibration);
    settings.noise.enable = false;
    let limit = harmonic_limit(&settings);
    let approach = approach(settings, 0.2e-9, 0.004, calibration);
    approach.print(5);
    let (worst, range) = approach.worst_up_to(limit);
    let (all, all_range) = approach.worst_up_to(f64::MAX);
    eprintln!(
        "silicon, noise off: worst |F − law| {:.2} % of the law's range {:.3} nN up to {:.1} nN \
         of repulsion; {:.2} % of {:.3} nN to 0.2 nm into the surface",
        worst * 100.0,
        range * 1e9,
        limit * 1e9,
        all * 100.0,
        all_range * 1e9
    );
    assert!(worst < 0.05, "worst {worst}");
}

#[test]
fn the_higher_modes_soften_a_hard_tap() {
    // 0.2 nm into silicon, noise off: the five-mode lever's Δf against a one-mode lever's
    // (the same mode 1) and the single-mode theory of the law. The one-mode lever follows
    // the theory; the five-mode lever's tap excites its higher modes and its Δf falls short.
    let calibration = calibration();
    let shift = |modes: Option<Vec<f64>>| {
        let mut settings = fm_afm(calibration);
        settings.noise.enable = false;
        if let Some(q) = modes {
            settings.cantilever.q = q;
        }
        settings.surface.distance = AMPLITUDE + 20e-9;
        let (mut plan, mut state, mut rt) = start(&settings, 7);
        let _ = run(&plan, &mut state, &mut rt, 0.02);
        let free = run(&plan, &mut state, &mut rt, 0.004);
        let f_free = mean(free.iter().filter(|r| r.unit == 0).map(|r| r.output));
        // An approach in steps of 10 pm from 0.5 nm above (a jump straight in lands the
        // tip on another branch of its motion, as on an instrument).
        for n in 0..=70 {
            settings.surface.distance = AMPLITUDE + 0.5e-9 - 10e-12 * f64::from(n);
            change(&mut plan, &mut state, &mut rt, &settings);
            let _ = run(&plan, &mut state, &mut rt, 0.002);
        }
        let r = run(&plan, &mut state, &mut rt, 0.004);
        let df = mean(r.iter().filter(|r| r.unit == 0).map(|r| r.output)) - f_free;
        let cantilever = ftafm::model::cantilever(&settings).unwrap();
        let mode = &cantilever.modes[0];
        let lever = FmLever::new(mode.stiffness / mode.tip_value.powi(2), f_free, AMPLITUDE);
        let contact =
            ftafm::model::impact_oscillator(&settings, &cantilever, settings.sample).contact;
        let adhesion = ftafm::model::adhesion(&settings).unwrap();
        let law = |d: f64| contact.force(-d) + adhesion.force(contact.radius, -d);
        let theory = ftafm::physics::fm::frequency_shift(
            &lever.unwrap(),
            law,
            -0.2e-9,
            ftafm::physics::fm::DEFAULT_NODES,
        );
        (df, theory)
    };
    let (five, theory) = shift(None);
    let (one, theory_one) = shift(Some(vec![100.0]));
    eprintln!(
        "0.2 nm into silicon: Δf {five:.1} Hz (five modes), {one:.1} Hz (one mode), single-mode \
         theory {theory:.1} Hz ({theory_one:.1} Hz)"
    );
    assert!((one / theory_one - 1.0).abs() < 0.15, "one mode: {one} Hz");
    assert!(five < 0.85 * theory, "five modes: {five} Hz");
}

/// Runs the sweep `sweeper` (set with the other values, `/sweeper/enable` last) on the
/// daemon and returns its points: (the swept value, PID 0's mean frequency shift).
async fn sweep_points(ws: &mut common::Ws, values: serde_json::Value) -> Vec<(f64, f64)> {
    use serde_json::json;
    let reply = common::call(ws, json!({"op": "set", "values": values})).await;
    assert_eq!(reply["ok"], true, "{reply}");
    let request = reply["epoch"].as_u64().unwrap();
    let mut points = Vec::new();
    loop {
        let m = common::first_of(ws, "sweep", |m| m["request"].as_u64() == Some(request)).await;
        if m["done"] == true {
            assert_eq!(m["outcome"], "done", "{m}");
            return points;
        }
        let unit = m["pids"]
            .as_array()
            .and_then(|u| u.iter().find(|u| u["index"] == 0))
            .unwrap_or_else(|| panic!("no PID 0 in {m}"));
        points.push((
            m["value"].as_f64().unwrap(),
            unit["frequency_shift"].as_f64().unwrap(),
        ));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_approach_through_the_sweeper_gives_the_frequency_shift_to_invert() {
    // The daemon at 2 MS/s, every noise source on, the polymer sample with adhesion, a
    // PLL and an amplitude loop from the start with the surface far away; the sweeper steps
    // /surface/distance and each point carries the PLL's mean Δf. Inverted, it returns the
    // configured law.
    use serde_json::json;
    let mut settings = common::light();
    let pdms_free = fm_afm(calibration());
    settings.adhesion = pdms_free.adhesion.clone();
    settings.drive.free_amplitude = pdms_free.drive.free_amplitude;
    settings.pids = pdms_free.pids.clone();
    settings.sample.youngs_modulus = 3e9;
    settings.sample.poisson = 0.35;
    settings.surface.distance = AMPLITUDE + 20e-9;
    for d in &mut settings.demods {
        d.rate = 1000.0;
    }
    let daemon = common::Daemon::start(settings.clone()).await;
    let mut ws = common::connect(daemon.addr).await;
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "sweep"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    let sweep = |start: f64, stop: f64, points: u32| {
        json!({
            "/sweeper/parameter": "/surface/distance",
            "/sweeper/start": start,
            "/sweeper/stop": stop,
            "/sweeper/points": points,
            "/sweeper/direction": "up",
            "/sweeper/settling": 0.004,
            "/sweeper/averaging": 24,
            "/sweeper/enable": true,
        })
    };
    // The free lever's lock: far from the surface.
    let far = sweep_points(&mut ws, sweep(AMPLITUDE + 20e-9, AMPLITUDE + 19e-9, 3)).await;
    let free = far.iter().map(|p| p.1).sum::<f64>() / far.len() as f64;
    // The approach: closest approach from 2 nm to 0.6 nm into the sample, 20 pm apart.
    let approach = sweep_points(&mut ws, sweep(AMPLITUDE + 2e-9, AMPLITUDE - 0.6e-9, 131)).await;
    daemon.shutdown().await;
    let mut z: Vec<f64> = approach.iter().map(|p| p.0 - AMPLITUDE).collect();
    let mut df: Vec<f64> = approach.iter().map(|p| p.1 - free).collect();
    z.reverse();
    df.reverse();
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let mode = &cantilever.modes[0];
    let k1 = mode.stiffness / (mode.tip_value * mode.tip_value);
    let lever = FmLever::new(k1, settings.cantilever.f1, AMPLITUDE).unwrap();
    let curve = invert(&z, &df, &lever).unwrap();
    let contact = ftafm::model::impact_oscillator(&settings, &cantilever, settings.sample).contact;
    let adhesion = ftafm::model::adhesion(&settings).unwrap();
    let law = |d: f64| contact.force(-d) + adhesion.force(contact.radius, -d);
    let limit = harmonic_limit(&settings);
    let compared: Vec<(f64, f64, f64)> = curve
        .z
        .iter()
        .zip(&curve.force)
        .map(|(&d, &f)| (d, f, law(d)))
        .filter(|p| p.2 <= limit)
        .collect();
    let (lo, hi) = compared.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
        (lo.min(p.2), hi.max(p.2))
    });
    let worst = compared
        .iter()
        .map(|p| (p.1 - p.2).abs())
        .fold(0.0, f64::max)
        / (hi - lo);
    for (d, f, l) in compared.iter().step_by(10) {
        eprintln!(
            "z {:+.2} nm  F {:+.3} nN  law {:+.3} nN",
            d * 1e9,
            f * 1e9,
            l * 1e9
        );
    }
    eprintln!(
        "through the sweeper (2 MS/s, noise on): worst |F − law| {:.2} % of the law's range \
         {:.3} nN; free lock {free:+.3} Hz from /drive/frequency",
        worst * 100.0,
        (hi - lo) * 1e9
    );
    assert!(worst < 0.05, "worst {worst}");
}

/// FM-AFM's topography: the PLL and the amplitude loop on the drive, and a third unit on
/// the PLL's frequency shift (`input = "frequency_shift"`) driving the surface distance as
/// the scan's feedback (`/feedback/enable = false`), held at the Δf of 0.8 nm into a 3 GPa
/// sample (noise off; there Δf > 0, so a tip that lost the surface reads a Δf below the
/// set-point and the loop approaches again). Over a disc raised 0.5 nm (same material)
/// the loop holds Δf, so the height image reads the disc's 0.5 nm and 0 off it, as
/// constant-Δf imaging does.
#[test]
fn constant_frequency_shift_images_the_topography() {
    let calibration = calibration();
    let mut settings = fm_afm(calibration);
    settings.noise.enable = false;
    settings.sample.youngs_modulus = 3e9;
    settings.sample.poisson = 0.35;
    // Δf and its slope against the distance, the PLL and the amplitude loop alone.
    let closest = -0.8e-9;
    let delta_f = |closest: f64| {
        let mut s = settings.clone();
        s.surface.distance = AMPLITUDE + closest;
        let (plan, mut state, mut rt) = start(&s, 7);
        let f_free = s.drive.frequency;
        let r = run(&plan, &mut state, &mut rt, 0.01);
        let settled = r.iter().filter(|r| r.unit == 0 && r.sample > 60_000);
        mean(settled.map(|r| r.output)) - f_free
    };
    let (at, slope) = (
        delta_f(closest),
        (delta_f(closest - 0.05e-9) - delta_f(closest + 0.05e-9)) / -0.1e-9,
    );
    // Δf rises as the surface comes closer (the adhesion's pull keeps it below 0 here).
    assert!(slope < 0.0, "Δf {at} Hz, slope {slope} Hz/m");
    // The scan, its feedback off: the PLL locks at the operating distance first, then the
    // topography loop (an integrator for a 100 Hz crossover on that slope) starts, as an
    // FM-AFM is engaged; a loop started before the PLL would read the free Δf = 0 and
    // retract.
    settings.surface.distance = AMPLITUDE + closest;
    settings.scan.enable = true;
    settings.feedback.enable = false;
    settings.scan.pixels = 8;
    settings.scan.line_rate = 1.0 / (2.0 * 8.0 * 10e-3);
    settings.inclusions[0].height = 0.5e-9;
    settings.inclusions[0].youngs_modulus = 3e9;
    settings.inclusions[0].poisson = 0.35;
    let locking = SynthPlan::new(&settings).unwrap();
    let z = &mut settings.pids[2];
    z.enable = true;
    z.input = ftafm::config::PidInput::FrequencyShift;
    (z.setpoint, z.p, z.i) = (at, 0.0, 2.0 * PI * 100.0 / slope);
    (z.output_min, z.output_max) = (0.0, 100e-9);
    ftafm::model::check(&settings).expect("FM-AFM imaging settings");
    let plan = SynthPlan::new(&settings).unwrap();
    let mut state = SynthState::steady(&locking, 7);
    let mut rt = ScanRuntime::new(&locking);
    let mut loops = PidRuntime::new(&locking);
    rt.retarget(&locking, &locking, 0);
    loops.retarget(&locking, &locking, 0, &mut state);
    let mut block = vec![0.0; 4096];
    let (mut pixels, mut shifts) = (Vec::new(), Vec::new());
    // Lines 3 and 4 cross the disc's centre; to the end of line 4's trace and retrace.
    let engage = (0.01 * plan.sample_rate) as u64;
    let end = (5.0 * 2.0 * 8.0 * 10e-3 * plan.sample_rate) as u64;
    let mut current = &locking;
    while state.sample_index() < end {
        if state.sample_index() >= engage && std::ptr::eq(current, &locking) {
            loops.release_drive(current, &mut state);
            state.retarget(current, &plan);
            let index = state.sample_index();
            rt.retarget(current, &plan, index);
            loops.retarget(current, &plan, index, &mut state);
            current = &plan;
        }
        let sinks = ScanLoops {
            runtime: &mut loops,
            reading: &mut |r| {
                if r.unit == 2 {
                    shifts.push(r.measurement);
                }
            },
            reference: &mut |_| {},
        };
        current.process_scan(&mut state, &mut rt, Some(sinks), &mut block, &mut |p| {
            pixels.push(p)
        });
    }
    let line = |n: u32| -> Vec<f64> {
        pixels
            .iter()
            .filter(|p| p.pixel.line == n && !p.pixel.retrace)
            .map(|p| p.height)
            .collect()
    };
    for n in [3, 4] {
        let heights = line(n);
        eprintln!(
            "constant Δf = {at:.2} Hz (slope {:.3} Hz/pm): line {n} heights (nm) {:?}",
            slope * 1e-12,
            heights
                .iter()
                .map(|h| (h * 1e11).round() / 100.0)
                .collect::<Vec<_>>()
        );
        assert_eq!(heights.len(), 8);
        // Columns 3 and 4 lie inside the disc (radius 167 nm, pixels 125 nm), 0 and 7 off
        // it; column 3 holds the loop's step response to the edge (its overshoot).
        for (c, within) in [(3, 0.1e-9), (4, 0.02e-9)] {
            assert!(
                (heights[c] - 0.5e-9).abs() < within,
                "line {n}, column {c}: {}",
                heights[c]
            );
        }
        for c in [0, 7] {
            assert!(
                heights[c].abs() < 0.1e-9,
                "line {n}, column {c}: {}",
                heights[c]
            );
        }
    }
    let late = &shifts[shifts.len() / 2..];
    let held = mean(late.iter().copied());
    assert!(
        (held - at).abs() < 0.02 * at.abs(),
        "Δf held at {held} Hz for {at} Hz"
    );
}
