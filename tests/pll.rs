//! PID units on the drive (`/pids/N/output = "drive_frequency"`, `"drive_amplitude"`): a PLL
//! on the phase of harmonic 1 finds the lever's resonance from 1 % off it, as the physics
//! of a driven damped oscillator puts it (independent of our orbit); it tracks a step of
//! the resonance; an amplitude loop on the drive holds the amplitude it is asked for; the
//! motion stays continuous through every change of the drive; the same seed gives the same
//! loop trace; and the settings checks refuse bad drive limits, naming the node.

mod common;

use std::f64::consts::PI;

use common::loops::{
    assert_step_as_advised, change, mean_and_spread, measured_step, pi_unit, run_traced,
    setpoint_step, start,
};
use ftafm::config::{Oscillator, PidInput, PidTarget, Settings, default_settings};
use ftafm::control::loop_model::ADC_DELAY_SAMPLES;
use ftafm::control::{Demodulator, Kind, LoopModel, Plant, advise};
use ftafm::synth::PidReading;

/// The free lever (surface out of reach) at the default drive, `detuning` (1) off its
/// first resonance, with PID 0 a PLL: the phase of harmonic 1 held at π (the resonance:
/// see `the_pll_locks_to_the_resonance_from_one_per_cent_off`), the drive frequency
/// within ±2 % of f1, PI gains for a crossover of `bandwidth` (Hz) on the lever's phase
/// response (−2Q/f1 rad/Hz, one pole at 1/τ = πf1/Q cancelled by the PI's zero).
fn pll(detuning: f64, bandwidth: f64) -> Settings {
    let mut s = default_settings();
    s.surface.distance = 1e-6;
    s.drive.free_amplitude = 10e-9;
    let f1 = s.cantilever.f1;
    s.drive.follow_f1 = false;
    s.drive.frequency = f1 * (1.0 + detuning);
    let q = s.cantilever.q[0];
    let route = (
        Oscillator::Drive,
        PidInput::Phase,
        PidTarget::DriveFrequency,
    );
    let plant = (bandwidth, -2.0 * q / f1, q / (PI * f1)); // rad per Hz, s
    pi_unit(&mut s, 0, route, PI, plant, (0.98 * f1, 1.02 * f1));
    s
}

/// Where the lever's steady photodiode response at harmonic 1 has phase π (Hz), the
/// frequency a PLL holding π must settle at: from the analytic steady state of every mode
/// (`free_reading`, no synthesis, no loop), by the secant method from f1. Mode 1 alone is
/// in quadrature with its drive at f1 exactly; the higher modes, far below their
/// resonances, follow the base's acceleration in phase with it and so add a part in
/// quadrature with mode 1's, 4.5e-4 rad at the default lever: the lock sits 0.23 Hz below.
fn phase_pi_frequency(settings: &Settings) -> f64 {
    let offset = |f: f64| {
        let mut s = settings.clone();
        s.drive.frequency = f;
        let z = ftafm::synth::plan::free_reading(&s).unwrap();
        // The phase's distance from π, on the circle.
        z.arg().rem_euclid(2.0 * PI) - PI
    };
    let (mut a, mut b) = (settings.cantilever.f1, settings.cantilever.f1 + 1.0);
    for _ in 0..20 {
        let (fa, fb) = (offset(a), offset(b));
        if fb == fa {
            break;
        }
        (a, b) = (b, b - fb * (b - a) / (fb - fa));
    }
    b
}

/// The readings of the last `seconds` of a run that ended at sample `end`.
fn tail(readings: &[PidReading], end: u64, samples: u64) -> Vec<PidReading> {
    readings
        .iter()
        .filter(|r| r.sample + samples >= end)
        .copied()
        .collect()
}

#[test]
fn the_pll_locks_to_the_resonance_from_one_per_cent_off() {
    // The physics: mode 1 driven at its resonance responds in quadrature with the base
    // acceleration G·sin θ that drives it, Y = −P·G/(2γω1²)·cos θ; the light lever reads
    // it with the positive tip slope, so the photodiode's harmonic 1 has phase π there,
    // shifted by the higher modes to `phase_pi_frequency`. A PLL holding π sits there.
    let settings = pll(0.01, 500.0);
    let f1 = settings.cantilever.f1;
    let expected = phase_pi_frequency(&settings);
    let (plan, mut state, mut rt) = start(&settings, 5);
    let (readings, changes, _) = run_traced(&plan, &mut state, &mut rt, 0.02);
    let end = state.sample_index();
    let last = tail(&readings, end, (0.005 * plan.sample_rate) as u64);
    let frequencies: Vec<f64> = last.iter().map(|r| r.output).collect();
    let (f, spread) = mean_and_spread(frequencies.iter().copied());
    let phases: Vec<f64> = last.iter().map(|r| r.error).collect();
    let (error, error_spread) = mean_and_spread(phases.iter().copied());
    eprintln!(
        "PLL from f1 + 1 %: {f} Hz (f1 {:+.3} Hz, spread {spread:.3} Hz; phase π at f1 \
         {:+.3} Hz), phase error {error:+.2e} ± {error_spread:.2e} rad, {} reference changes",
        f - f1,
        expected - f1,
        changes.len()
    );
    assert!(
        last.iter().all(|r| !r.limited),
        "the lock is within its range"
    );
    // The mean of 5 ms of a 500 Hz loop's noise: within 1 Hz.
    assert!(
        (f - expected).abs() < 1.0,
        "the PLL sits at {f} Hz, {} Hz from where the phase is π ({expected} Hz)",
        f - expected
    );
    assert!(error.abs() < 0.01, "mean phase error {error} rad");
    // Each update that moved the frequency changed the reference once.
    let moved = readings
        .windows(2)
        .filter(|w| w[0].output != w[1].output)
        .count();
    assert!(
        changes.len() >= moved,
        "{} changes for {moved} moves",
        changes.len()
    );
}

#[test]
fn the_pll_tracks_a_step_of_the_resonance_as_its_linear_model_predicts() {
    // With the PI's zero on the lever's pole (P = I·τ), the loop is an integrator of
    // crossover ω_c = 2π·500 Hz: the closed loop is first order, e^{−ω_c t} with no
    // overshoot, behind the loop's dead time (about a period and the ADC filter's delay).
    let bandwidth = 500.0;
    let mut settings = pll(0.0, bandwidth);
    // Without noise, so that the overshoot is the loop's alone.
    settings.noise.enable = false;
    let f1 = settings.cantilever.f1;
    let (mut plan, mut state, mut rt) = start(&settings, 9);
    let _ = run_traced(&plan, &mut state, &mut rt, 0.01);
    // The resonance steps up by 50 Hz, a fifth of its half width f1/(2Q).
    let step = 50.0;
    settings.cantilever.f1 = f1 + step;
    change(&mut plan, &mut state, &mut rt, &settings);
    let from = state.sample_index();
    let (readings, _, _) = run_traced(&plan, &mut state, &mut rt, 0.01);
    let t = |r: &PidReading| (r.sample - from) as f64 / plan.sample_rate;
    let settled: Vec<f64> = readings
        .iter()
        .filter(|r| t(r) > 0.006)
        .map(|r| r.output)
        .collect();
    let (end, spread) = mean_and_spread(settled.iter().copied());
    // The time to 1 − 1/e of the step, and the overshoot.
    let rise = readings
        .iter()
        .find(|r| r.output - f1 >= (1.0 - (-1.0f64).exp()) * step)
        .map(t)
        .unwrap();
    let peak = readings.iter().map(|r| r.output).fold(f64::MIN, f64::max);
    let overshoot = (peak - end) / step;
    let model = 1.0 / (2.0 * PI * bandwidth);
    let dead = 1.0 / f1 + 21.5 / plan.sample_rate;
    eprintln!(
        "resonance step +{step} Hz: settles at {:+.3} Hz (± {spread:.3}), 63 % at {:.1} µs \
         (model {:.1} µs + dead time {:.1} µs), overshoot {:.1} %",
        end - f1,
        rise * 1e6,
        model * 1e6,
        dead * 1e6,
        overshoot * 100.0
    );
    let expected = phase_pi_frequency(&settings);
    assert!(
        (end - expected).abs() < 0.01,
        "settles at {end} Hz, the phase is π at {expected} Hz"
    );
    assert!(spread < 0.01, "no ripple: {spread} Hz");
    assert!(
        (rise - (model + dead)).abs() < 0.1 * model + 0.1 * dead,
        "63 % after {rise} s, the model's {} s",
        model + dead
    );
    assert!(overshoot < 0.1, "overshoot {overshoot}");
}

#[test]
fn an_amplitude_loop_on_the_drive_holds_the_amplitude_it_is_asked_for() {
    // Free lever at resonance: the photodiode's harmonic-1 amplitude is in proportion to
    // the drive. Asked for 1.5 times the amplitude it has, the loop settles with the drive
    // at 1.5 times /drive/free_amplitude.
    let mut s = default_settings();
    s.surface.distance = 1e-6;
    s.drive.free_amplitude = 10e-9;
    let free = ftafm::synth::plan::free_reading(&s).unwrap().norm();
    let pid = &mut s.pids[1];
    pid.enable = true;
    pid.input = PidInput::R;
    pid.harmonic = 1;
    pid.setpoint = 1.5 * free;
    pid.p = 0.0;
    pid.i = 2000.0;
    pid.output = PidTarget::DriveAmplitude;
    pid.output_min = 0.0;
    pid.output_max = 50e-9;
    let (plan, mut state, mut rt) = start(&s, 4);
    let (readings, changes, _) = run_traced(&plan, &mut state, &mut rt, 0.03);
    assert!(
        changes.is_empty(),
        "the amplitude leaves the reference alone"
    );
    let end = state.sample_index();
    let last = tail(&readings, end, (0.005 * plan.sample_rate) as u64);
    let (drive, spread) = mean_and_spread(last.iter().map(|r| r.output));
    let (measured, _) = mean_and_spread(last.iter().map(|r| r.measurement));
    eprintln!(
        "amplitude loop: drive {:.4} nm (± {:.4}) for 1.5 × the free {free:e} m; reads \
         {measured:e} m",
        drive * 1e9,
        spread * 1e9
    );
    assert!((drive / 15e-9 - 1.0).abs() < 0.01, "drive {drive} m");
    assert!((measured / (1.5 * free) - 1.0).abs() < 0.01);
}

#[test]
fn a_change_of_the_drive_keeps_the_motion_continuous() {
    // Without noise: the samples around each update that moves the drive continue the
    // motion (no step beyond what a period's motion has between neighbours), and the loop
    // trace is the same bits for the same seed.
    let mut settings = pll(0.01, 500.0);
    settings.noise.enable = false;
    let (plan, mut state, mut rt) = start(&settings, 1);
    let (readings, _, samples) = run_traced(&plan, &mut state, &mut rt, 0.005);
    let largest_step = samples
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max);
    // A sinusoid of amplitude A sampled N times a period steps at most 2πA/N.
    let amplitude = samples.iter().fold(0.0f64, |m, s| m.max(s.abs()));
    let bound = 2.0 * PI * amplitude / (plan.sample_rate / plan.drive_frequency) * 1.05;
    eprintln!("largest step between samples {largest_step:e} m (bound {bound:e} m)");
    assert!(largest_step < bound);
    let (again, _, _) = {
        let (plan, mut state, mut rt) = start(&settings, 1);
        run_traced(&plan, &mut state, &mut rt, 0.005)
    };
    assert_eq!(readings, again, "same settings and seed, same trace");
}

#[test]
fn drive_limits_are_refused_naming_the_node_and_the_range() {
    let s = pll(0.0, 500.0);
    let refused = |changes: &[(&str, serde_json::Value)]| common::loops::refused(&s, changes);
    use serde_json::json;
    // Demodulator 0 at harmonic 49 would read up to 49 × output_max = 5.1 MHz, over
    // Nyquist (it is in band at the 100 kHz the drive starts from).
    let e = refused(&[
        ("/demods/0/harmonic", json!(49)),
        ("/pids/0/output_max", json!(104e3)),
    ]);
    eprintln!("{e}");
    assert_eq!(e.path(), "/pids/0/output_max");
    assert!(e.to_string().contains("/synth/sample_rate / 2 / 49"), "{e}");
    let e = refused(&[("/pids/0/output_min", json!(0.0))]);
    assert_eq!(e.path(), "/pids/0/output_min");
    assert!(e.to_string().contains("0 < value"), "{e}");
    let e = refused(&[
        ("/pids/0/output", json!("drive_amplitude")),
        ("/pids/0/output_min", json!(0.0)),
        ("/pids/0/output_max", json!(2e-6)),
    ]);
    assert_eq!(e.path(), "/pids/0/output_max");
    assert!(e.to_string().contains("1 µm"), "{e}");
    let e = refused(&[("/scan/enable", json!(true))]);
    assert_eq!(e.path(), "/pids/0/output");
    assert!(e.to_string().contains("/scan/enable"), "{e}");
    let e = refused(&[
        ("/sweeper/parameter", json!("/drive/frequency")),
        ("/sweeper/start", json!(99e3)),
        ("/sweeper/stop", json!(101e3)),
        ("/sweeper/enable", json!(true)),
    ]);
    assert_eq!(e.path(), "/pids/0/output");
    assert!(e.to_string().contains("/sweeper/parameter"), "{e}");
    let e = refused(&[("/synth/engine", json!("paper"))]);
    assert_eq!(e.path(), "/pids/0/output");
}

/// The daemon with a PLL from the start: `status` reports it locked with its frequency
/// shift, and the lock-in bank's own reference follows the PLL's drive: the `demods`
/// stream's harmonic 1 holds the PLL's phase (π) instead of turning at the 1 kHz between
/// the PLL's frequency and `/drive/frequency`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_reports_the_lock_and_its_lock_in_follows_the_drive() {
    use serde_json::json;
    let mut settings = common::light();
    let pll = pll(0.01, 500.0);
    settings.surface = pll.surface.clone();
    settings.drive = pll.drive.clone();
    settings.pids = pll.pids.clone();
    let expected = phase_pi_frequency(&settings);
    let daemon = common::Daemon::start(settings.clone()).await;
    let mut ws = common::connect(daemon.addr).await;
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "status"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    // 20 ms of simulated time: 2000 updates, forty loop time constants.
    let status = common::first_of(&mut ws, "status", |s| {
        s["pids"][0]["latest"]["updates"]
            .as_u64()
            .is_some_and(|n| n >= 2000)
    })
    .await;
    let unit = &status["pids"][0];
    eprintln!("status: {unit} held {}", status["pid_held"]);
    assert_eq!(unit["output"], "drive_frequency");
    assert_eq!(unit["locked"], true, "{unit}");
    let shift = unit["frequency_shift"].as_f64().unwrap();
    assert!(
        (shift - (expected - settings.drive.frequency)).abs() < 5.0,
        "Δf {shift} Hz, expected {} Hz",
        expected - settings.drive.frequency
    );
    assert_eq!(status["pid_held"], json!(["drive_frequency"]));
    let after = status["t"].as_f64().unwrap();
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    let mut phases = Vec::new();
    while phases.len() < 20 {
        let frame = common::next_of(&mut ws, "demods").await;
        if frame["t"].as_f64().unwrap() < after {
            continue;
        }
        let h1 = harmonic_1(&frame);
        phases.push(h1["phase"].as_f64().unwrap());
    }
    // Distance from π on the circle.
    let off: Vec<f64> = phases.iter().map(|p| p.rem_euclid(2.0 * PI) - PI).collect();
    eprintln!("demods harmonic 1, phase − π over 100 ms: {off:.4?}");
    assert!(off.iter().all(|d| d.abs() < 0.01), "{off:?}");
    daemon.shutdown().await;
}

/// The one-sided power spectral density (unit²/Hz) of `x` sampled at `rate` (Hz): Welch's
/// method, Hann windows of `size` samples overlapping by half, the mean removed per window.
/// Bin i is at i·rate/size.
fn welch(x: &[f64], rate: f64, size: usize) -> Vec<f64> {
    use rustfft::FftPlanner;
    use rustfft::num_complex::Complex64;
    let fft = FftPlanner::new().plan_fft_forward(size);
    let window: Vec<f64> = (0..size)
        .map(|i| 0.5 - 0.5 * (2.0 * PI * i as f64 / size as f64).cos())
        .collect();
    let power: f64 = window.iter().map(|w| w * w).sum();
    let mut psd = vec![0.0; size / 2 + 1];
    let mut segments = 0;
    let mut start = 0;
    while start + size <= x.len() {
        let piece = &x[start..start + size];
        let mean = piece.iter().sum::<f64>() / size as f64;
        let mut buf: Vec<Complex64> = piece
            .iter()
            .zip(&window)
            .map(|(v, w)| Complex64::new((v - mean) * w, 0.0))
            .collect();
        fft.process(&mut buf);
        for (p, b) in psd.iter_mut().zip(&buf) {
            *p += 2.0 * b.norm_sqr() / (rate * power);
        }
        segments += 1;
        start += size / 2;
    }
    psd.iter_mut().for_each(|p| *p /= f64::from(segments));
    psd
}

#[test]
fn the_pll_frequency_noise_is_the_thermal_and_detector_limit() {
    // The free lever at its resonance with the default 30 nm, every noise source on, a
    // 500 Hz PLL. Inside the loop's bandwidth the PLL's frequency is the lever's frequency
    // as its phase shows it: f = φ·(1 + s·τ)/(2πτ) (the phase slope 2Q/f0 = 2πτ rad/Hz),
    // so a phase noise S_φ becomes S_φ·(f_c² + f_m²) with f_c = f0/(2Q) = 1/(2πτ). One-sided
    // PSDs, A the tip's peak amplitude, k1 mode 1's stiffness at the tip, n the detector's
    // one-sided density in tip metres:
    //   thermal (Albrecht et al. 1991; Kobayashi et al. 2009, flat):  f0·k_B·T/(π·k1·Q·A²)
    //   detector (white phase noise 2n²/A²):                           2n²·(f_c² + f_m²)/A²
    // (Kobayashi's 2n²·f_m²/A² is a self-excited lever's; the driven lever's finite phase
    // slope adds f_c²).
    let mut settings = pll(0.0, 500.0);
    settings.drive.free_amplitude = 30e-9;
    let (plan, mut state, mut rt) = start(&settings, 21);
    let _ = run_traced(&plan, &mut state, &mut rt, 0.02);
    let (readings, _, _) = run_traced(&plan, &mut state, &mut rt, 0.6);
    let f0 = settings.cantilever.f1;
    let frequencies: Vec<f64> = readings.iter().map(|r| r.output).collect();
    let rate = plan.drive_frequency;
    let size = 4096;
    let psd = welch(&frequencies, rate, size);
    // The tip amplitude: the photodiode's harmonic 1 over its metres per tip metre.
    let calibration =
        ftafm::synth::plan::free_reading(&settings).unwrap().norm() / settings.drive.free_amplitude;
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let mode = &cantilever.modes[0];
    let k1 = mode.stiffness / (mode.tip_value * mode.tip_value);
    let q = mode.q;
    let a = settings.drive.free_amplitude;
    let n = settings.noise.detector_density / calibration;
    let kt = ftafm::synth::BOLTZMANN * settings.noise.temperature;
    let fc = f0 / (2.0 * q);
    let thermal = f0 * kt / (PI * k1 * q * a * a);
    let detector = |fm: f64| 2.0 * n * n * (fc * fc + fm * fm) / (a * a);
    // The band 25–250 Hz: inside the loop, above the lowest bins; the closed loop passes
    // |T|² = 1/(1 + (f_m/B)²) of it (first order, B = 500 Hz).
    let passed = |fm: f64| 1.0 / (1.0 + (fm / 500.0) * (fm / 500.0));
    let bin = rate / size as f64;
    let (mut measured, mut predicted, mut bins) = (0.0, 0.0, 0);
    for (i, p) in psd.iter().enumerate() {
        let fm = i as f64 * bin;
        if (25.0..=250.0).contains(&fm) {
            measured += p;
            predicted += (thermal + detector(fm)) * passed(fm);
            bins += 1;
        }
    }
    let ratio = measured / predicted;
    eprintln!(
        "PLL Δf noise 25–250 Hz ({bins} bins): {:.3e} Hz²/Hz measured, {:.3e} predicted \
         (thermal {thermal:.3e}, detector {:.3e} at 100 Hz; A {a:e} m, k1 {k1:.3} N/m, Q {q}, \
         n {n:.3e} m/√Hz): ratio {ratio:.3}",
        measured / f64::from(bins),
        predicted / f64::from(bins),
        detector(100.0)
    );
    assert!(
        (1.0 / 1.5..=1.5).contains(&ratio),
        "measured/predicted {ratio}"
    );
}

/// The advisor's model of the live PLL at `settings`: the driven lever's phase
/// (−(2Q/f1)/(1 + s·τ_c), taken positive) through the unit's demodulator (no filter, one
/// update a period, T + 21.5/f_s of delay), as the op `pid_advise` builds it.
fn advised_pll(settings: &Settings) -> LoopModel {
    LoopModel {
        plant: Plant::resonator(settings.cantilever.q[0], settings.cantilever.f1).unwrap(),
        demodulator: Demodulator::pid_unit(
            settings.drive.frequency,
            settings.synth.sample_rate,
            ADC_DELAY_SAMPLES,
        )
        .unwrap(),
    }
}

#[test]
fn the_advised_pll_steps_as_the_advisor_predicts() {
    // The advisor's gains for the default lever's PLL (negated: the phase falls as the
    // frequency rises), then the resonance steps by 50 Hz (a fifth of its half width): the
    // live loop's overshoot and 2 % settling time against the advice's, from its linear
    // model. Noise off, so the loop's own response is measured.
    let base = pll(0.0, 500.0);
    let update = 1.0 / base.drive.frequency;
    for (target, kind) in [
        (500.0, Kind::Pi),
        (2000.0, Kind::Pi),
        (2000.0, Kind::Pid),
        (10e3, Kind::Pi),
    ] {
        let mut settings = base.clone();
        settings.noise.enable = false;
        // Locked from the start: the drive (the PLL's centre) where the phase is π.
        let before = phase_pi_frequency(&settings);
        settings.drive.frequency = before;
        let advice = advise(&advised_pll(&settings), target, kind).unwrap();
        let pid = &mut settings.pids[0];
        pid.p = -advice.gains.p;
        pid.i = -advice.gains.i;
        pid.d = -advice.gains.d;
        pid.d_bandwidth = advice.gains.d_bandwidth;
        let (mut plan, mut state, mut rt) = start(&settings, 9);
        let _ = run_traced(&plan, &mut state, &mut rt, 0.005);
        settings.cantilever.f1 += 50.0;
        let after = phase_pi_frequency(&settings);
        change(&mut plan, &mut state, &mut rt, &settings);
        let from = state.sample_index();
        // Ten predicted settling times, and at least 5 ms.
        let (readings, _, _) = run_traced(
            &plan,
            &mut state,
            &mut rt,
            (10.0 * advice.step.settling_time).max(0.005),
        );
        let (overshoot, settling) = measured_step(&readings, from, plan.sample_rate, before, after);
        let tail = &readings[readings.len() - 100..];
        let (last, _) = mean_and_spread(tail.iter().map(|r| r.output));
        eprintln!(
            "advised PLL {kind:?} {target} Hz: P {:.2} Hz/rad I {:.4e} Hz/(rad·s) D {:.3e}; \
             bandwidth {:.1} Hz, margin {:.1}°; overshoot measured {:.2} % predicted {:.2} %; \
             settling measured {:.1} µs predicted {:.1} µs; settles {:+.4} Hz from the phase-π \
             frequency",
            -advice.gains.p,
            -advice.gains.i,
            -advice.gains.d,
            advice.bandwidth,
            advice.phase_margin,
            100.0 * overshoot,
            100.0 * advice.step.overshoot,
            1e6 * settling,
            1e6 * advice.step.settling_time,
            last - after
        );
        assert!(
            (last - after).abs() < 0.01,
            "settles at {last} Hz, not {after} Hz"
        );
        assert_step_as_advised(
            &format!("{kind:?} {target} Hz"),
            &advice,
            overshoot,
            settling,
            update,
        );
    }
}

#[test]
fn the_advised_amplitude_loop_steps_as_the_advisor_predicts() {
    // An amplitude loop on the drive of the free lever (at resonance, noise off) with the
    // advisor's gains for the plant `pid_advise` models (the photodiode amplitude per metre
    // of drive amplitude, through the envelope's τ_c): its set-point steps by 10 %, and the
    // amplitude it reads is followed.
    let mut base = default_settings();
    base.surface.distance = 1e-6;
    base.drive.free_amplitude = 10e-9;
    base.noise.enable = false;
    let free = ftafm::synth::plan::free_reading(&base).unwrap().norm();
    let update = 1.0 / base.drive.frequency;
    for (target, kind) in [(500.0, Kind::Pi), (3000.0, Kind::Pi)] {
        let mut settings = base.clone();
        let model = LoopModel {
            plant: Plant::amplitude(
                free / settings.drive.free_amplitude,
                settings.cantilever.q[0],
                settings.cantilever.f1,
            )
            .unwrap(),
            demodulator: Demodulator::pid_unit(
                settings.drive.frequency,
                settings.synth.sample_rate,
                ADC_DELAY_SAMPLES,
            )
            .unwrap(),
        };
        let advice = advise(&model, target, kind).unwrap();
        let pid = &mut settings.pids[1];
        pid.enable = true;
        pid.input = PidInput::R;
        pid.harmonic = 1;
        pid.setpoint = free;
        pid.p = advice.gains.p;
        pid.i = advice.gains.i;
        pid.d = advice.gains.d;
        pid.d_bandwidth = advice.gains.d_bandwidth;
        pid.output = PidTarget::DriveAmplitude;
        pid.output_min = 0.0;
        pid.output_max = 50e-9;
        let (overshoot, settling) = setpoint_step(
            &settings,
            1,
            1.1 * free,
            3,
            (0.005, (10.0 * advice.step.settling_time).max(0.005)),
        );
        eprintln!(
            "advised amplitude loop {kind:?} {target} Hz: P {:.4e} I {:.4e} /s; bandwidth \
             {:.1} Hz, margin {:.1}°; overshoot measured {:.2} % predicted {:.2} %; settling \
             measured {:.1} µs predicted {:.1} µs",
            advice.gains.p,
            advice.gains.i,
            advice.bandwidth,
            advice.phase_margin,
            100.0 * overshoot,
            100.0 * advice.step.overshoot,
            1e6 * settling,
            1e6 * advice.step.settling_time,
        );
        assert_step_as_advised(
            &format!("{kind:?} {target} Hz"),
            &advice,
            overshoot,
            settling,
            update,
        );
    }
}

/// `pid_advise` over a WebSocket: the advice for a unit set up as a PLL is the advisor's on
/// the settings in force, signed for the unit, and `set` takes it; contact mode's deflection
/// loop gets an integrator alone; a bad unit, bandwidth or kind, an unreachable bandwidth,
/// a PID for the deflection loop and a unit the advisor does not model are refused naming
/// the key and what is allowed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pid_advise_replies_with_the_gains_and_refuses_naming_the_key() {
    use serde_json::json;
    let settings = common::light();
    let daemon = common::Daemon::start(settings.clone()).await;
    let mut ws = common::connect(daemon.addr).await;
    let f1 = settings.cantilever.f1;
    let reply = common::call(
        &mut ws,
        json!({"op": "set", "values": {
            "/pids/0/input": "phase",
            "/pids/0/output": "drive_frequency",
            "/pids/0/setpoint": PI,
            "/pids/0/output_min": 0.98 * f1,
            "/pids/0/output_max": 1.02 * f1,
        }}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    let epoch = reply["epoch"].as_u64().unwrap();
    let advice = common::call(
        &mut ws,
        json!({"op": "pid_advise", "unit": 0, "bandwidth": 500.0}),
    )
    .await;
    eprintln!("{advice}");
    assert_eq!(advice["ok"], true, "{advice}");
    assert_eq!(advice["unit"], 0);
    assert_eq!(advice["kind"], "pi");
    assert_eq!(advice["epoch"].as_u64(), Some(epoch));
    // The advisor on the same model, negated for the PLL.
    let expected = advise(&advised_pll(&settings), 500.0, Kind::Pi).unwrap();
    let number = |key: &str| advice[key].as_f64().unwrap();
    assert_eq!(number("p"), -expected.gains.p);
    assert_eq!(number("i"), -expected.gains.i);
    assert_eq!(number("d"), 0.0);
    assert!((number("bandwidth") / 500.0 - 1.0).abs() < 0.01);
    assert!(number("phase_margin") >= 45.0);
    assert_eq!(number("overshoot"), expected.step.overshoot);
    assert_eq!(number("settling_time"), expected.step.settling_time);
    // Near the hand formula: P = −500 Hz/rad, I = −2π·500·f1/(2Q).
    assert!((number("p") / -500.0 - 1.0).abs() < 0.2, "{advice}");
    // An amplitude loop on the drive: the amplitude rises with it, the gains positive.
    let reply = common::call(
        &mut ws,
        json!({"op": "set", "values": {"/pids/2/output": "drive_amplitude"}}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    let amplitude = common::call(
        &mut ws,
        json!({"op": "pid_advise", "unit": 2, "bandwidth": 1000.0}),
    )
    .await;
    eprintln!("{amplitude}");
    assert_eq!(amplitude["ok"], true, "{amplitude}");
    assert!(amplitude["i"].as_f64().unwrap() > 0.0, "{amplitude}");
    assert!(amplitude["p"].as_f64().unwrap() > 0.0, "{amplitude}");
    let pid = common::call(
        &mut ws,
        json!({"op": "pid_advise", "unit": 0, "bandwidth": 2000.0, "kind": "pid"}),
    )
    .await;
    assert_eq!(pid["ok"], true, "{pid}");
    assert!(pid["d"].as_f64().unwrap() < 0.0, "{pid}");
    // The advice is not applied; `set` takes it.
    let set = common::call(
        &mut ws,
        json!({"op": "set", "values": {
            "/pids/0/p": pid["p"],
            "/pids/0/i": pid["i"],
            "/pids/0/d": pid["d"],
            "/pids/0/d_bandwidth": pid["d_bandwidth"],
            "/pids/0/enable": true,
        }}),
    )
    .await;
    assert_eq!(set["ok"], true, "{set}");
    // Contact mode's deflection loop: an integrator alone, negated; no PID for it.
    let reply = common::call(
        &mut ws,
        json!({"op": "set", "values": {
            "/pids/3/input": "mean_deflection",
            "/pids/3/setpoint": 1e-9,
        }}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    let contact = common::call(
        &mut ws,
        json!({"op": "pid_advise", "unit": 3, "bandwidth": 1000.0}),
    )
    .await;
    eprintln!("{contact}");
    let mut pressed = settings.clone();
    pressed.pids[3].input = ftafm::config::PidInput::MeanDeflection;
    pressed.pids[3].setpoint = 1e-9;
    let model = ftafm::instrument::unit_loop::unit_loop(&pressed, 3)
        .unwrap()
        .model;
    let expected = advise(&model, 1000.0, Kind::Pi).unwrap();
    assert_eq!(contact["p"].as_f64(), Some(0.0), "{contact}");
    assert_eq!(contact["i"].as_f64(), Some(-expected.gains.i), "{contact}");
    assert!(
        contact["plant"]
            .as_str()
            .unwrap()
            .contains("pressed on the sample")
    );
    let e = common::call(
        &mut ws,
        json!({"op": "pid_advise", "unit": 3, "bandwidth": 1000.0, "kind": "pid"}),
    )
    .await;
    assert_eq!(common::code(&e), "invalid_value", "{e}");
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("field \"kind\""),
        "{e}"
    );
    for (request, code, words) in [
        (
            json!({"op": "pid_advise", "unit": 4, "bandwidth": 500.0}),
            "bad_request",
            vec!["\"unit\"", "0 … 3"],
        ),
        (
            json!({"op": "pid_advise", "bandwidth": 500.0}),
            "bad_request",
            vec!["\"unit\"", "0 … 3"],
        ),
        (
            json!({"op": "pid_advise", "unit": 0, "bandwidth": -1.0}),
            "bad_request",
            vec!["\"bandwidth\"", "> 0"],
        ),
        (
            json!({"op": "pid_advise", "unit": 0, "bandwidth": 500.0, "kind": "pd"}),
            "bad_request",
            vec!["\"kind\"", "\"pi\" or \"pid\""],
        ),
        (
            json!({"op": "pid_advise", "unit": 0, "bandwidth": 1e6}),
            "invalid_value",
            vec!["\"bandwidth\"", "allowed 0 < bandwidth ≤", "out of reach"],
        ),
        (
            json!({"op": "pid_advise", "unit": 1, "bandwidth": 500.0}),
            "invalid_value",
            vec![
                "/pids/1",
                "surface_distance",
                "drive_frequency",
                "drive_amplitude",
            ],
        ),
    ] {
        let e = common::call(&mut ws, request.clone()).await;
        eprintln!("{request} → {e}");
        assert_eq!(common::code(&e), code, "{e}");
        let message = e["error"]["message"].as_str().unwrap_or_default();
        for w in words {
            assert!(message.contains(w), "{w}: {message}");
        }
    }
    daemon.shutdown().await;
}

/// The lock detector: a PLL at its resonance acquires the lock after
/// `PLL_LOCK_UPDATES` updates in the window; when the resonance leaves its range (the lever's
/// f1 moved 3 % up, the output limits at ±2 %) it pins at `output_max`, limited, and the loss
/// is counted once; back in range it locks again, the count kept.
#[test]
fn a_pll_reports_the_loss_of_its_lock_and_locks_again() {
    use ftafm::synth::PLL_LOCK_UPDATES;
    let mut settings = pll(0.0, 500.0);
    settings.drive.frequency = phase_pi_frequency(&settings);
    let (mut plan, mut state, mut rt) = start(&settings, 13);
    let locked = run_traced(&plan, &mut state, &mut rt, 0.005).0;
    let first = locked
        .iter()
        .position(|r| r.locked == Some(true))
        .expect("locks");
    assert!(
        first + 1 >= PLL_LOCK_UPDATES as usize,
        "locked at update {first}"
    );
    assert!(locked[first..].iter().all(|r| r.locked == Some(true)));
    assert_eq!(locked.last().unwrap().lock_losses, 0);

    let f1 = settings.cantilever.f1;
    let mut away = settings.clone();
    away.cantilever.f1 = 1.03 * f1;
    change(&mut plan, &mut state, &mut rt, &away);
    let lost = run_traced(&plan, &mut state, &mut rt, 0.01).0;
    let last = lost.last().unwrap();
    assert_eq!(
        last.output, settings.pids[0].output_max,
        "pinned at the range's end"
    );
    assert!(last.limited);
    assert_eq!(last.locked, Some(false));
    assert_eq!(last.lock_losses, 1, "one loss, counted once");

    change(&mut plan, &mut state, &mut rt, &settings);
    let again = run_traced(&plan, &mut state, &mut rt, 0.01).0;
    let last = again.last().unwrap();
    eprintln!(
        "lock at update {first}; away: pinned at {} Hz; back: locked {:?} at {} Hz, {} loss(es)",
        lost.last().unwrap().output,
        last.locked,
        last.output,
        last.lock_losses
    );
    assert_eq!(last.locked, Some(true), "locks again");
    assert_eq!(last.lock_losses, 1, "the count is kept");
    // Units that are no PLL have no lock.
    let mut amplitude = settings.clone();
    amplitude.pids[0].enable = false;
    amplitude.pids[1] = settings.pids[0].clone();
    amplitude.pids[1].input = PidInput::R;
    amplitude.pids[1].setpoint = 1e-9;
    amplitude.pids[1].output = PidTarget::DriveAmplitude;
    amplitude.pids[1].output_min = 0.0;
    amplitude.pids[1].output_max = 20e-9;
    amplitude.pids[1].p = 0.0;
    amplitude.pids[1].i = 100.0;
    let (plan, mut state, mut rt) = start(&amplitude, 13);
    let other = run_traced(&plan, &mut state, &mut rt, 0.001).0;
    assert!(!other.is_empty() && other.iter().all(|r| r.locked.is_none()));
}

/// Harmonic 1's reading in a `demods` frame.
fn harmonic_1(frame: &serde_json::Value) -> serde_json::Value {
    frame["demods"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["harmonic"] == 1)
        .unwrap()
        .clone()
}

/// The mean of harmonic 1's x + iy over `frames` `demods` frames from simulated time
/// `from` (s) on.
async fn mean_h1(ws: &mut common::Ws, from: f64, frames: usize) -> (f64, f64) {
    let (mut x, mut y, mut n) = (0.0, 0.0, 0);
    while n < frames {
        let frame = common::next_of(ws, "demods").await;
        if frame["t"].as_f64().unwrap() < from {
            continue;
        }
        let h1 = harmonic_1(&frame);
        x += h1["x"].as_f64().unwrap();
        y += h1["y"].as_f64().unwrap();
        n += 1;
    }
    (x / n as f64, y / n as f64)
}

/// A stopped PLL holds the drive where it locked, away from `/drive/frequency`, through
/// writes of other nodes. A write of the node takes the drive back even with the value it
/// already has, as does a `load_settings` (whole settings, as a preset): back at the node,
/// harmonic 1 reads the lever's analytic steady state there.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_of_the_node_takes_the_drive_back_from_a_stopped_pll() {
    use serde_json::json;
    let mut settings = common::light();
    let pll = pll(0.01, 500.0);
    settings.surface = pll.surface.clone();
    settings.drive = pll.drive.clone();
    settings.pids = pll.pids.clone();
    let node = settings.drive.frequency;
    let daemon = common::Daemon::start(settings.clone()).await;
    let mut ws = common::connect(daemon.addr).await;
    for stream in ["status", "demods"] {
        let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": stream})).await;
        assert_eq!(sub["ok"], true, "{sub}");
    }
    // Each request, then the first status of its epoch or later: what the synthesiser
    // holds once it runs the change.
    async fn held_after(
        ws: &mut common::Ws,
        request: serde_json::Value,
    ) -> (serde_json::Value, f64) {
        let reply = common::call(ws, request).await;
        assert_eq!(reply["ok"], true, "{reply}");
        let epoch = reply["epoch"].as_u64().unwrap();
        let t = reply["t"].as_f64().unwrap();
        let status = common::first_of(ws, "status", |s| {
            s["epoch"].as_u64().is_some_and(|e| e >= epoch)
        })
        .await;
        (status["pid_held"].clone(), t)
    }
    // The first status with the PLL locked after `updates` updates of its count.
    async fn locked(ws: &mut common::Ws, updates: u64) -> u64 {
        let status = common::first_of(ws, "status", |s| {
            s["pids"][0]["latest"]["updates"]
                .as_u64()
                .is_some_and(|n| n >= updates)
                && s["pids"][0]["locked"] == true
        })
        .await;
        status["pids"][0]["latest"]["updates"].as_u64().unwrap()
    }
    let updates = locked(&mut ws, 2000).await;
    let (held, t) = held_after(
        &mut ws,
        json!({"op": "set", "path": "/pids/0/enable", "value": false}),
    )
    .await;
    assert_eq!(held, json!(["drive_frequency"]));
    // Held at the lock: harmonic 1 at phase π.
    let (x, y) = mean_h1(&mut ws, t + 0.1, 10).await;
    let off = (y.atan2(x).rem_euclid(2.0 * PI) - PI).abs();
    assert!(off < 0.01, "held at the lock: phase − π = {off}");
    // A write of another node leaves the drive held.
    let amplitude = settings.drive.free_amplitude;
    let (held, _) = held_after(
        &mut ws,
        json!({"op": "set", "path": "/drive/free_amplitude", "value": amplitude}),
    )
    .await;
    assert_eq!(
        held,
        json!(["drive_frequency"]),
        "after a set of another node"
    );
    // A set of its present value takes it back.
    let (held, t) = held_after(
        &mut ws,
        json!({"op": "set", "path": "/drive/frequency", "value": node}),
    )
    .await;
    assert_eq!(held, json!([]), "after a set of the present value");
    let z = ftafm::synth::plan::free_reading(&settings).unwrap();
    let (x, y) = mean_h1(&mut ws, t + 0.1, 10).await;
    let error = ((x - z.re).powi(2) + (y - z.im).powi(2)).sqrt() / z.norm();
    eprintln!(
        "back at {node} Hz: h1 {x:.4e} + {y:.4e}i against the steady state {z:.4e}: {error:.2e}"
    );
    assert!(error < 0.03, "h1 {x} + {y}i against {z}: {error}");
    // Again, taken back by a load of the same value.
    let (held, _) = held_after(
        &mut ws,
        json!({"op": "set", "path": "/pids/0/enable", "value": true}),
    )
    .await;
    assert_eq!(held, json!(["drive_frequency"]));
    let _ = locked(&mut ws, updates + 2000).await;
    let (held, _) = held_after(
        &mut ws,
        json!({"op": "set", "path": "/pids/0/enable", "value": false}),
    )
    .await;
    assert_eq!(held, json!(["drive_frequency"]));
    let text = format!("[drive]\nfree_amplitude = {amplitude:e}\n");
    let (held, _) = held_after(&mut ws, json!({"op": "load_settings", "toml": text})).await;
    assert_eq!(held, json!([]), "after a load");
    daemon.shutdown().await;
}
