//! Bimodal AM-FM with its loops (`/pids/N/oscillator = "drive2"`, outputs
//! `drive2_frequency` and `drive2_amplitude`): a PLL on mode 2 finds its resonance from
//! off it, as the lever's own steady response puts it (no synthesis in the prediction);
//! an amplitude loop on the second excitation holds mode 2's amplitude; with mode 1 under
//! amplitude feedback on the surface distance beside them, the three loops' readings give
//! the sample's modulus by the bimodal AM-FM expressions; the motion stays continuous when
//! the loops move the second excitation; the same seed gives the same trace; and the
//! settings checks refuse a unit on the second excitation without it, naming the node.

mod common;

use common::bimodal::{f2_of, mode_two_amplitude, mode_two_pll, second_reading};

use std::f64::consts::PI;

use common::loops::{
    assert_step_as_advised, change, mean_and_spread, measured_step, refused, run_traced, start,
};
use ftafm::config::{Oscillator, PidInput, PidTarget, Settings, default_settings};
use ftafm::physics::bimodal::{self, BimodalLever, BimodalReading};
use ftafm::synth::PidReading;
use ftafm::timebase::phase_to_radians;
use rustfft::num_complex::Complex64;
use serde_json::json;

/// Unit `unit`'s readings from sample `from` on.
fn after(readings: &[PidReading], unit: usize, from: u64) -> Vec<PidReading> {
    readings
        .iter()
        .filter(|r| r.unit == unit && r.sample >= from)
        .copied()
        .collect()
}

/// The free lever (surface out of reach, noise on) with the second excitation 0.4 % above
/// mode 2's resonance (2.7 of its linewidths): the PLL holding the phase mode 2 has at its
/// resonance settles there, and the reference changes it makes are the second
/// oscillator's. The first excitation's tone, 527 kHz from f2, does not disturb it.
#[test]
fn a_pll_on_mode_two_locks_to_its_resonance() {
    let mut s = default_settings();
    s.surface.distance = 1e-6;
    let f2 = f2_of(&s);
    let setpoint = second_reading(&s, f2, 1e-9).arg();
    s.drive2.enable = true;
    s.drive2.frequency = 1.004 * f2;
    s.drive2.free_amplitude = 1e-9;
    mode_two_pll(&mut s, 0, setpoint, 300.0);
    let (plan, mut state, mut rt) = start(&s, 7);
    let (readings, changes, _) = run_traced(&plan, &mut state, &mut rt, 0.02);
    let settled = (0.012 * plan.sample_rate) as u64;
    let tail = after(&readings, 0, settled);
    let (f, spread) = mean_and_spread(tail.iter().map(|r| r.output));
    let (error, error_spread) = mean_and_spread(tail.iter().map(|r| r.error));
    let first = readings
        .first()
        .expect("the unit updates after its low-pass settles");
    eprintln!(
        "mode-2 PLL from f2 + 0.4 %: {f} Hz (f2 {:+.3} Hz, spread {spread:.3} Hz), phase error \
         {error:+.2e} ± {error_spread:.2e} rad; first update at sample {}, {} reference changes",
        f - f2,
        first.sample,
        changes.len()
    );
    assert!(tail.iter().all(|r| !r.limited), "locked within its range");
    assert!(
        (f - f2).abs() < 2.0,
        "the PLL sits at {f} Hz, {} Hz from mode 2's resonance",
        f - f2
    );
    assert!(error.abs() < 0.01, "mean phase error {error} rad");
    assert!(
        !changes.is_empty() && changes.iter().all(|c| c.oscillator == Oscillator::Drive2),
        "the reference changes are the second oscillator's"
    );
    // The unit waits for its low-pass (ten section time constants) before its first update.
    let alpha = ftafm::synth::pid_plan::low_pass_alpha(s.pids[0].input_bandwidth, plan.sample_rate);
    assert!(
        first.sample as f64 >= 10.0 / alpha,
        "first update at {}",
        first.sample
    );
}

/// Bimodal AM-FM on tap150 tapping a 1 GPa sample: unit 0 holds mode 1's amplitude at 2/3
/// of its free one by the surface distance, unit 1 is mode 2's PLL (300 Hz), unit 2 holds
/// mode 2's amplitude at its free 0.2 nm by the second excitation (200 Hz). With f2 and the
/// free readings at harmonic 1 of each excitation.
fn am_fm() -> (Settings, f64, Complex64, Complex64) {
    am_fm_on(&AmFm::on("tap150", 1e9, 0.2e-9))
}

/// One bimodal AM-FM case: the lever preset, the sample's Young's modulus (Pa), mode 2's
/// free amplitude A2 (m), mode 1's A01 (m) and its set-point A1/A01.
#[derive(Clone, Copy, Debug)]
struct AmFm {
    lever: &'static str,
    modulus: f64,
    a2: f64,
    a01: f64,
    ratio: f64,
}

impl AmFm {
    /// The preset's A01 (30 nm) at A1/A01 = 2/3.
    fn on(lever: &'static str, modulus: f64, a2: f64) -> Self {
        Self {
            lever,
            modulus,
            a2,
            a01: 30e-9,
            ratio: 2.0 / 3.0,
        }
    }
}

/// [`am_fm`] for `case`.
fn am_fm_on(case: &AmFm) -> (Settings, f64, Complex64, Complex64) {
    let AmFm {
        lever,
        modulus,
        a2,
        a01,
        ratio,
    } = *case;
    let mut s = ftafm::config::load_with_presets(&[lever.to_owned()], None).unwrap();
    s.sample.youngs_modulus = modulus;
    s.drive.free_amplitude = a01;
    s.surface.distance = 0.8 * a01;
    let f2 = f2_of(&s);
    let free2 = second_reading(&s, f2, a2);
    let free1 = ftafm::synth::plan::free_reading(&s).unwrap();
    s.drive2.enable = true;
    s.drive2.frequency = f2;
    s.drive2.free_amplitude = a2;
    let pid = &mut s.pids[0];
    pid.enable = true;
    pid.input = PidInput::R;
    pid.harmonic = 1;
    pid.setpoint = free1.norm() * ratio;
    pid.output = PidTarget::SurfaceDistance;
    mode_two_pll(&mut s, 1, free2.arg(), 300.0);
    mode_two_amplitude(&mut s, 2, free2.norm(), free2.norm() / a2, 200.0);
    (s, f2, free1, free2)
}

/// The bimodal AM-FM set-up with its three loops on the coupled engine (noise on), each
/// sample with the lever matched to it: unit 0 holds mode 1's amplitude at its set-point
/// (2/3 of its free one; 0.95 on 1 MPa, where the soft contact detunes the lever too little
/// to take it to 2/3 before the surface reaches the tip's rest position) by the surface
/// distance, unit 1 is mode 2's PLL, unit 2 holds mode 2's amplitude at its free one by the
/// second excitation (small against the indentation, large enough that Δf2 over the last
/// 75 ms stands clear of the thermal noise on the softest samples, whose Δf2 is tens of Hz).
/// The PLL's Δf2 from the free resonance, with A1 and φ1 from the photodiode, give E* by the
/// bimodal expressions, the Hertz swing solved whole, within 10 % of the configured
/// contact's from 1 MPa to 100 GPa (on 100 GPa the stiffest lever, tap525: tap300 there,
/// whose mode 2 reads the short, stiff tap's mean stiffness short, is held within 15 %,
/// docs/loops.md); the amplitude loops hold their set-points. With noise off the two softest
/// read within 1 %: what the live figures add there is the thermal noise on Δf2.
#[test]
fn am_fm_loops_give_the_modulus_live() {
    let soft = AmFm {
        ratio: 0.95,
        ..AmFm::on("ac240", 1e6, 1e-9)
    };
    for (case, within) in [
        (soft, 0.1),
        (AmFm::on("ac240", 10e6, 0.5e-9), 0.1),
        (AmFm::on("multi75", 100e6, 0.2e-9), 0.1),
        (AmFm::on("tap150", 1e9, 0.2e-9), 0.1),
        (AmFm::on("tap300", 10e9, 0.1e-9), 0.1),
        (AmFm::on("tap525", 100e9, 0.05e-9), 0.1),
        (AmFm::on("tap300", 100e9, 0.05e-9), 0.15),
    ] {
        let error = live_modulus_error(&case, true);
        assert!(
            error.abs() < within,
            "{case:?}: E* off by {:+.1} %",
            100.0 * error
        );
    }
    for case in [soft, AmFm::on("ac240", 10e6, 0.5e-9)] {
        let error = live_modulus_error(&case, false);
        assert!(
            error.abs() < 0.01,
            "{case:?}, noise off: E* off by {:+.2} %",
            100.0 * error
        );
    }
}

/// E*'s relative error from the three loops' readings in `case`, with the default noise or
/// none, the loops checked to hold.
fn live_modulus_error(case: &AmFm, noise: bool) -> f64 {
    let (mut s, f2, free1, free2) = am_fm_on(case);
    s.noise.enable = noise;
    let (preset, modulus) = (case.lever, case.modulus);
    let (plan, mut state, mut rt) = start(&s, 3);
    let seconds = 0.1;
    let (readings, _, samples) = run_traced(&plan, &mut state, &mut rt, seconds);
    let from = (0.025 * plan.sample_rate) as u64;
    let (r1, _) = mean_and_spread(after(&readings, 0, from).iter().map(|r| r.measurement));
    let (distance, _) = mean_and_spread(after(&readings, 0, from).iter().map(|r| r.output));
    let (f, f_spread) = mean_and_spread(after(&readings, 1, from).iter().map(|r| r.output));
    let (r2, _) = mean_and_spread(after(&readings, 2, from).iter().map(|r| r.measurement));
    let (drive2, _) = mean_and_spread(after(&readings, 2, from).iter().map(|r| r.output));
    // φ1: the photodiode's harmonic 1 over the same stretch against the drive's phase at
    // each sample (the drive's word is fixed here), relative to the free lever's.
    let word = plan.frequency_word;
    let mut s1 = Complex64::new(0.0, 0.0);
    for (i, &v) in samples.iter().enumerate().skip(from as usize) {
        s1 += Complex64::from_polar(v, -phase_to_radians(word.wrapping_mul(i as u64)));
    }
    // The ADC front end's delay is the same for the free reading, so the ratio is clean.
    let s01 = free1 * plan.front_end_gain(word as f64 / 2f64.powi(64));
    let s1 = s1
        * (2.0 / (samples.len() - from as usize) as f64)
        * Complex64::from_polar(1.0, 2.0 * PI * (word as f64 / 2f64.powi(64)) * 21.5);
    let modes = &plan.cantilever.modes;
    let lever = BimodalLever {
        k1: modes[0].tip_stiffness(),
        q1: modes[0].q,
        k2: modes[1].tip_stiffness(),
        f2,
        tip_radius: s.cantilever.tip_radius,
    };
    let a01 = s.drive.free_amplitude;
    let reading = BimodalReading {
        free_amplitude: a01,
        amplitude: a01 * r1 / free1.norm(),
        phase_lag: PI / 2.0 - (s1 / s01).arg(),
        frequency_shift: f - f2,
    };
    let e = bimodal::estimate(&lever, &reading).unwrap();
    let truth = {
        let (t, m) = (&s.tip, &s.sample);
        1.0 / ((1.0 - t.poisson * t.poisson) / t.youngs_modulus
            + (1.0 - m.poisson * m.poisson) / m.youngs_modulus)
    };
    let error = e.reduced_modulus / truth - 1.0;
    eprintln!(
        "AM-FM loops, {preset} on {modulus:.0e} Pa, noise {noise}: surface at {:.3} nm, A1/A01 {:.4}, φ1 {:.2} deg, Δf2 {:+.1} Hz (± {:.1}), \
         mode 2 at {:.4} of its set-point by a drive of {:.4} nm; E* {:.4e} against {truth:.4e} Pa \
         ({:+.1} %), d {:.3} nm; by the short-tap closed forms {:+.1} %, d {:.3} nm",
        distance * 1e9,
        r1 / free1.norm(),
        reading.phase_lag.to_degrees(),
        f - f2,
        f_spread,
        r2 / free2.norm(),
        drive2 * 1e9,
        e.reduced_modulus,
        100.0 * error,
        e.indentation * 1e9,
        100.0 * (e.short_tap_modulus / truth - 1.0),
        e.short_tap_indentation * 1e9
    );
    assert!(
        (r1 / free1.norm() - case.ratio).abs() < 0.01,
        "mode 1 held at {}",
        r1 / free1.norm()
    );
    assert!(
        (r2 / free2.norm() - 1.0).abs() < 0.02,
        "mode 2 held at {}",
        r2 / free2.norm()
    );
    assert!(
        f - f2 > 0.0,
        "the contact stiffens mode 2: Δf2 = {}",
        f - f2
    );
    error
}

/// Loops moving the second excitation keep the motion continuous, and the same seed and
/// settings give the same trace, bit for bit. Noise off, so the stream with the loops less
/// the stream without them is the second excitation's change of motion alone, near f2: a
/// smooth function whose second difference stays within its amplitude times (ω2·h)²,
/// where a jump of the motion (a change of the excitation that did not carry the modes'
/// displacement and velocity over) would show whole.
#[test]
fn mode_two_loops_are_continuous_and_deterministic() {
    let mut s = default_settings();
    s.noise.enable = false;
    s.surface.distance = 1e-6;
    let f2 = f2_of(&s);
    let setpoint = second_reading(&s, f2, 1e-9).arg();
    s.drive2.enable = true;
    s.drive2.frequency = 1.002 * f2;
    s.drive2.free_amplitude = 1e-9;
    mode_two_pll(&mut s, 0, setpoint, 300.0);
    // An amplitude loop asking for three times the free amplitude with a large P: its
    // first update takes the second excitation from 1 nm to its output_max of 3 nm at once.
    let free2 = second_reading(&s, f2, 1e-9).norm();
    mode_two_amplitude(&mut s, 1, 3.0 * free2, free2 / 1e-9, 200.0);
    s.pids[1].p = 100.0 * 1e-9 / free2;
    s.pids[1].i = 0.0;
    s.pids[1].output_max = 3e-9;
    let trace = |settings: &Settings| {
        let (plan, mut state, mut rt) = start(settings, 11);
        run_traced(&plan, &mut state, &mut rt, 0.006)
    };
    let (a, changes_a, samples_a) = trace(&s);
    let (b, changes_b, samples_b) = trace(&s);
    assert_eq!(a, b, "same seed, same loop trace");
    assert_eq!(changes_a, changes_b);
    assert!(
        samples_a
            .iter()
            .zip(&samples_b)
            .all(|(x, y)| x.to_bits() == y.to_bits())
    );
    let mut still = s.clone();
    still.pids[0].enable = false;
    still.pids[1].enable = false;
    let (_, _, samples_still) = trace(&still);
    let d: Vec<f64> = samples_a
        .iter()
        .zip(&samples_still)
        .map(|(x, y)| x - y)
        .collect();
    let amplitude = d.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let curvature = d
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .fold(0.0, f64::max);
    let wh = 2.0 * PI * 1.01 * f2 / 10e6;
    let bound = amplitude * wh * wh * 1.05;
    eprintln!(
        "the loops' share of the stream: amplitude {amplitude:e} m, largest second difference \
         {curvature:e} m (bound {bound:e} m), {} reference changes",
        changes_a.len()
    );
    assert!(!changes_a.is_empty(), "the PLL moved the second excitation");
    assert!(
        a.iter().any(|r| r.unit == 1 && r.output == 3e-9),
        "the amplitude loop jumped to its limit"
    );
    assert!(curvature < bound, "{curvature:e} against {bound:e}");
}

#[test]
fn a_unit_on_the_second_excitation_needs_it_and_names_the_node() {
    let s = default_settings();
    let e = refused(
        &s,
        &[
            ("/pids/1/oscillator", json!("drive2")),
            ("/pids/1/enable", json!(true)),
        ],
    );
    assert_eq!(e.path(), "/pids/1/oscillator", "{e}");
    assert!(e.to_string().contains("/drive2/enable = true"), "{e}");
    let e = refused(
        &s,
        &[
            ("/pids/2/output", json!("drive2_amplitude")),
            ("/pids/2/output_max", json!(5e-9)),
            ("/pids/2/enable", json!(true)),
        ],
    );
    assert_eq!(e.path(), "/pids/2/output", "{e}");
    let mut on = s.clone();
    on.drive2.enable = true;
    let e = refused(
        &on,
        &[
            ("/pids/0/oscillator", json!("drive2")),
            ("/pids/0/input_bandwidth", json!(30e3)),
            ("/pids/0/enable", json!(true)),
        ],
    );
    assert_eq!(e.path(), "/pids/0/input_bandwidth", "{e}");
    assert!(e.to_string().contains("25 kHz"), "names the limit: {e}");
    let e = refused(
        &on,
        &[
            ("/pids/0/oscillator", json!("drive2")),
            ("/pids/0/harmonic", json!(8)),
            ("/pids/0/enable", json!(true)),
        ],
    );
    assert_eq!(e.path(), "/pids/0/harmonic", "{e}");
    assert!(e.to_string().contains("/drive2/frequency"), "{e}");
}

/// Where mode 2's steady photodiode phase at harmonic 1 of "drive2" is `phase` (Hz): the
/// frequency a PLL holding that phase settles at, by the secant method from `guess`, from
/// the lever's analytic response (no synthesis, no loop).
fn phase_frequency(settings: &Settings, phase: f64, guess: f64) -> f64 {
    let offset = |f: f64| {
        let z = second_reading(settings, f, 1e-9);
        // The phase's distance from `phase`, on the circle.
        (z.arg() - phase + PI).rem_euclid(2.0 * PI) - PI
    };
    let (mut a, mut b) = (guess, guess + 1.0);
    for _ in 0..30 {
        let (fa, fb) = (offset(a), offset(b));
        if fb == fa {
            break;
        }
        (a, b) = (b, b - fb * (b - a) / (fb - fa));
    }
    b
}

/// The advisor's gains for mode 2's PLL (the model `pid_advise` builds for a unit on
/// "drive2": mode 2's resonator behind the unit's low-pass of four sections, read once a
/// drive period), then mode 2's resonance steps by about 50 Hz (f1 moves by 8 Hz, the drive
/// held): the live loop's overshoot and 2 % settling time against the advice's linear model.
/// Noise off, so the loop's own response is measured.
#[test]
fn the_advised_mode_two_pll_steps_as_the_advisor_predicts() {
    use ftafm::control::{Demodulator, Kind, LoopModel, Plant, advise};
    let mut base = default_settings();
    base.noise.enable = false;
    base.surface.distance = 1e-6;
    base.drive.follow_f1 = false;
    let lever = ftafm::model::cantilever(&base).unwrap();
    let (f2, q2) = (lever.modes[1].frequency, lever.modes[1].q);
    let setpoint = second_reading(&base, f2, 1e-9).arg();
    base.drive2.enable = true;
    base.drive2.frequency = f2;
    base.drive2.free_amplitude = 1e-9;
    mode_two_pll(&mut base, 0, setpoint, 300.0);
    let fs = base.synth.sample_rate;
    let alpha = ftafm::synth::pid_plan::low_pass_alpha(base.pids[0].input_bandwidth, fs);
    let model = LoopModel {
        plant: Plant::resonator(q2, f2).unwrap(),
        demodulator: Demodulator::new(
            4,
            -1.0 / ((1.0 - alpha).ln() * fs),
            base.drive.frequency,
            ftafm::control::loop_model::ADC_DELAY_SAMPLES / fs,
        )
        .unwrap()
        .with_filter_rate(fs)
        .unwrap(),
    };
    let update = 1.0 / base.drive.frequency;
    for (target, kind) in [(100.0, Kind::Pi), (300.0, Kind::Pi), (700.0, Kind::Pi)] {
        let mut settings = base.clone();
        let advice = advise(&model, target, kind).unwrap();
        let pid = &mut settings.pids[0];
        pid.p = -advice.gains.p;
        pid.i = -advice.gains.i;
        pid.d = -advice.gains.d;
        pid.d_bandwidth = advice.gains.d_bandwidth;
        let (mut plan, mut state, mut rt) = start(&settings, 9);
        let (settled, _, _) = run_traced(&plan, &mut state, &mut rt, 0.01);
        let before = settled.last().unwrap().output;
        settings.cantilever.f1 += 8.0;
        let after = phase_frequency(&settings, setpoint, f2 + 50.0);
        change(&mut plan, &mut state, &mut rt, &settings);
        let from = state.sample_index();
        let (readings, _, _) = run_traced(
            &plan,
            &mut state,
            &mut rt,
            (10.0 * advice.step.settling_time).max(0.01),
        );
        let step = after - before;
        let (overshoot, settling) = measured_step(&readings, from, plan.sample_rate, before, after);
        let last = readings.last().unwrap().output;
        eprintln!(
            "advised mode-2 PLL {kind:?} {target} Hz: step {step:.2} Hz; bandwidth {:.1} Hz, \
             margin {:.1}°; overshoot measured {:.2} % predicted {:.2} %; settling measured \
             {:.1} µs predicted {:.1} µs; ends {:+.4} Hz from the new lock",
            advice.bandwidth,
            advice.phase_margin,
            100.0 * overshoot,
            100.0 * advice.step.overshoot,
            1e6 * settling,
            1e6 * advice.step.settling_time,
            last - after
        );
        assert!((before - f2).abs() < 0.01, "locked at {before}, not {f2}");
        assert!((last - after).abs() < 0.05, "ends at {last}, not {after}");
        assert_step_as_advised(
            &format!("mode 2's PLL, {kind:?} {target} Hz"),
            &advice,
            overshoot,
            settling,
            update,
        );
    }
}

/// Through the daemon: the `bimodal` stream turns each demodulator frame and mode 2's PLL
/// into the estimate, stamped with the settings epoch; over 10 frames after the loops settle,
/// its E* is the configured contact's within 10 %, as the synthesiser-level test finds,
/// each frame paired with the PLL's update in force at its sample (`pll_sample` at or
/// before it, `pll_age` the time between). Before mode 2's PLL runs, each message says why
/// there is no estimate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bimodal_stream_gives_the_modulus_live() {
    let (mut s, _, _, _) = am_fm();
    // Only what the estimate reads: harmonic 1 of the drive, no spectrum or scope.
    for (i, d) in s.demods.iter_mut().enumerate() {
        d.enable = i == 0;
    }
    s.demods[0].harmonic = 1;
    s.spectrum.enable = false;
    s.scope.enable = false;
    s.inversion.enable = false;
    let truth = {
        let (t, m) = (&s.tip, &s.sample);
        1.0 / ((1.0 - t.poisson * t.poisson) / t.youngs_modulus
            + (1.0 - m.poisson * m.poisson) / m.youngs_modulus)
    };
    let rate = s.synth.sample_rate;
    let mut idle = s.clone();
    idle.pids[1].enable = false;
    let daemon = common::Daemon::start(idle).await;
    let mut ws = common::connect(daemon.addr).await;
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "bimodal"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    let first = common::first_of(&mut ws, "bimodal", |_| true).await;
    assert!(first["reduced_modulus"].is_null(), "{first}");
    assert!(
        first["reason"].as_str().unwrap().contains("mode 2's PLL"),
        "{first}"
    );
    let set = common::call(
        &mut ws,
        json!({"op": "set", "path": "/pids/1/enable", "value": true}),
    )
    .await;
    assert_eq!(set["ok"], true, "{set}");
    let epoch = set["epoch"].as_u64().unwrap();
    let start = common::first_of(&mut ws, "bimodal", |m| m["epoch"] == epoch).await;
    let t0 = start["t"].as_f64().unwrap();
    let mut moduli = Vec::new();
    let mut last = json!(null);
    while moduli.len() < 10 {
        // Frames paired with the PLL past its settling (the frame is no earlier).
        let m = common::first_of(&mut ws, "bimodal", |m| {
            m["pll_sample"]
                .as_u64()
                .is_some_and(|s| s as f64 / rate > t0 + 0.03)
        })
        .await;
        assert_eq!(m["epoch"], epoch, "{m}");
        assert!(m["reason"].is_null(), "{m}");
        // Paired with the PLL's update in force at the frame's sample, never a later one,
        // and saying which.
        let sample = (m["t"].as_f64().unwrap() * rate).round() as u64;
        let pll_sample = m["pll_sample"].as_u64().unwrap();
        assert!(pll_sample <= sample, "PLL update after the frame: {m}");
        let age = m["pll_age"].as_f64().unwrap();
        assert!(
            (age - (sample - pll_sample) as f64 / rate).abs() < 1e-12,
            "{m}"
        );
        moduli.push(m["reduced_modulus"].as_f64().unwrap());
        last = m;
    }
    let mean = moduli.iter().sum::<f64>() / moduli.len() as f64;
    eprintln!("a bimodal message: {last}");
    eprintln!(
        "bimodal stream: E* {mean:.4e} Pa over {} frames against {truth:.4e} Pa ({:+.1} %)",
        moduli.len(),
        100.0 * (mean / truth - 1.0)
    );
    assert!(
        (mean / truth - 1.0).abs() < 0.1,
        "E* {mean:e} against {truth:e}"
    );
    daemon.shutdown().await;
}
