//! The photodiode synthesiser against `ftafm paper`'s spectrum (Eq. 9), textbook noise
//! physics (equipartition) and its own promises: steady start, no jumps, determinism.

use std::f64::consts::PI;

use ftafm::cli::paper;
use ftafm::config::{Engine, Settings, default_settings};

/// The defaults on the paper engine, whose spectrum is exactly the 1-DOF model's (this file's
/// reference; the coupled engine, the default, is tests/synth_coupled.rs's, and clear of the
/// surface it is this engine's stream bit for bit).
fn paper_defaults() -> Settings {
    let mut s = default_settings();
    s.synth.engine = Engine::Paper;
    s
}
use ftafm::physics::spectrum::{cut_cosine_train, photodiode_transfer};
use ftafm::synth::{BOLTZMANN, SynthPlan, SynthState};
use rustfft::num_complex::Complex64;

fn quiet(mut s: Settings) -> Settings {
    s.noise.enable = false;
    s
}

/// Peak-amplitude phasor of harmonic k over whole periods: (2/N)·Σ s_n e^{−ikθ_n}.
fn harmonic(samples: &[f64], plan: &SynthPlan, start_phase: u64, k: u64) -> Complex64 {
    let turn = 2f64.powi(64);
    let sum: Complex64 = samples
        .iter()
        .enumerate()
        .map(|(n, &s)| {
            let word = start_phase
                .wrapping_add(plan.frequency_word.wrapping_mul(n as u64))
                .wrapping_mul(k);
            s * Complex64::from_polar(1.0, -(word as f64) / turn * 2.0 * PI)
        })
        .sum();
    sum * (2.0 / samples.len() as f64)
}

/// The largest sample-to-sample change of `samples` (m).
fn largest_step(samples: &[f64]) -> f64 {
    samples
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max)
}

fn run(plan: &SynthPlan, state: &mut SynthState, n: usize) -> Vec<f64> {
    let mut out = vec![0.0; n];
    plan.process(state, &mut out);
    out
}

/// What exact sampling of the continuous Eq. (9) signal gives in the DFT bin of harmonic k
/// over a window of `window` samples holding `periods` periods: the two-sided coefficient
/// S_j of every harmonic j whose bin folds onto k's (aliases), each through the ADC's
/// anti-alias filter at its own frequency, summed to |j| = 3000.
fn aliased_eq9(plan: &SynthPlan, window: i64, periods: i64, k: i64) -> Complex64 {
    let tap = plan.tap.expect("in contact").train;
    let omega = 2.0 * PI * plan.drive_frequency;
    let c = cut_cosine_train(tap.max_force, tap.tau, tap.centre_phase, 3000);
    let mut sum = Complex64::new(0.0, 0.0);
    for j in -3000i64..=3000 {
        if (j * periods - k * periods).rem_euclid(window) != 0 {
            continue;
        }
        let cj = if j >= 0 {
            c[j as usize]
        } else {
            c[(-j) as usize].conj()
        };
        let filter = plan.front_end_gain(j as f64 * plan.drive_frequency / plan.sample_rate);
        sum += photodiode_transfer(&plan.cantilever, j as f64 * omega) * cj * filter;
    }
    sum * 2.0
}

fn check_against_paper(settings: &Settings, samples_per_window: usize, periods: i64) {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    // The drive phase at which the first sample was taken (the ADC filter's delay before).
    let start = plan.output_phase(state.phase());
    let samples = run(&plan, &mut state, samples_per_window);
    let report = paper::compute(settings, 0.9).unwrap();
    let expected = &report.materials[0].spectrum;
    let reference = expected[6].amplitude;
    for k in 2..=20u64 {
        let got = harmonic(&samples, &plan, start, k);
        // The criterion: within 0.5 % of `ftafm paper`'s amplitude.
        let want = expected[k as usize];
        let rel = got.norm() / want.amplitude - 1.0;
        assert!(
            rel.abs() < 0.005,
            "H{k}: {:.6e} vs {:.6e} ({:.3} %)",
            got.norm(),
            want.amplitude,
            rel * 100.0
        );
        // Stronger: the samples are the continuous signal sampled exactly, aliases and all.
        let exact = aliased_eq9(&plan, samples_per_window as i64, periods, k as i64);
        let err = (got - exact).norm() / exact.norm().max(1e-3 * reference);
        assert!(
            err < 1e-4,
            "H{k}: {got} vs exact {exact} (relative error {err:e})"
        );
    }
    // Self-consistency: the photodiode fundamental is the 1-DOF tapping amplitude seen
    // through mode 1's light lever (0.9177), to within a few percent.
    let h1 = harmonic(&samples, &plan, start, 1).norm();
    let lever = plan.cantilever.modes[0].light_lever_factor().abs();
    let one_dof = report.materials[0].tapping_amplitude * lever;
    assert!(
        (h1 / one_dof - 1.0).abs() < 0.03,
        "H1 {h1:e} vs 1-DOF {one_dof:e}"
    );
}

#[test]
fn steady_state_harmonics_match_the_paper_spectrum() {
    // 100 samples per period; 200 whole periods.
    check_against_paper(&quiet(paper_defaults()), 20_000, 200);
}

#[test]
fn the_pulse_is_placed_to_a_fraction_of_a_sample() {
    // 97.3 samples per period: the pulse (≈ 5 samples wide) lands at a different sub-sample
    // offset every period; 973 samples hold exactly 10 periods.
    let mut s = quiet(paper_defaults());
    s.synth.sample_rate = 9.73e6;
    check_against_paper(&s, 973 * 20, 200);
}

#[test]
fn the_stream_starts_in_steady_state() {
    let settings = quiet(paper_defaults());
    let plan = SynthPlan::new(&settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let first = run(&plan, &mut state, 100);
    let _ = run(&plan, &mut state, 100 * 499);
    let later = run(&plan, &mut state, 100);
    let scale = first.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    for (a, b) in first.iter().zip(&later) {
        assert!((a - b).abs() < 1e-6 * scale, "{a} vs {b}");
    }
}

/// A lever with many modes, thermal noise and the ADC's filter on starts settled on both
/// engines: its heavily damped high modes (Rayleigh damping) do not overflow the filter's
/// history (they did: the 8-, 10- and 16-mode levers' first samples clipped at the ADC's
/// full scale, then turned NaN). The stream stays within the free swing's photodiode
/// amplitude, as a 5-mode lever's does.
#[test]
fn a_lever_with_many_modes_starts_settled_with_noise() {
    for engine in [Engine::Paper, Engine::Coupled] {
        for extra in [0, 3, 5, 11] {
            let mut s = default_settings();
            s.synth.engine = engine;
            s.cantilever.extra_modes = extra;
            let plan = SynthPlan::new(&s).unwrap();
            let mut state = SynthState::steady(&plan, 1);
            let out = run(&plan, &mut state, 20_000);
            let largest = out.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(
                out.iter().all(|x| x.is_finite()) && largest < 0.5 * s.noise.adc_range,
                "{engine:?}, {} modes: largest sample {largest:e} m",
                5 + extra
            );
        }
    }
}

#[test]
fn same_seed_same_stream_whatever_the_block_size() {
    let settings = paper_defaults();
    let plan = SynthPlan::new(&settings).unwrap();
    let mut a = SynthState::steady(&plan, 7);
    let whole = run(&plan, &mut a, 10_000);
    let mut b = SynthState::steady(&plan, 7);
    let mut pieces = Vec::new();
    for len in [1, 255, 256, 1000, 3, 4096, 4389] {
        pieces.extend(run(&plan, &mut b, len));
    }
    assert_eq!(whole.len(), pieces.len());
    assert!(
        whole
            .iter()
            .zip(&pieces)
            .all(|(x, y)| x.to_bits() == y.to_bits()),
        "bit-identical"
    );
    let mut c = SynthState::steady(&plan, 8);
    let other = run(&plan, &mut c, 10_000);
    assert!(
        whole.iter().zip(&other).any(|(x, y)| x != y),
        "another seed differs"
    );
}

/// The coupled engine tapping, with noise and the ADC's filter: its runs of samples clear of
/// the surface are taken in a loop of their own, which stops at a block's end. One sample
/// a call never enters it; the stream must not change.
#[test]
fn the_coupled_stream_is_the_same_one_sample_at_a_time() {
    let settings = default_settings();
    assert_eq!(settings.synth.engine, Engine::Coupled);
    let plan = SynthPlan::new(&settings).unwrap();
    let mut a = SynthState::steady(&plan, 11);
    let whole = run(&plan, &mut a, 6_000);
    let mut b = SynthState::steady(&plan, 11);
    let mut pieces = Vec::new();
    for _ in 0..700 {
        pieces.extend(run(&plan, &mut b, 1));
    }
    for len in [255, 256, 3, 1000, 3786] {
        pieces.extend(run(&plan, &mut b, len));
    }
    assert_eq!(whole.len(), pieces.len());
    let first_difference = whole
        .iter()
        .zip(&pieces)
        .position(|(x, y)| x.to_bits() != y.to_bits());
    assert_eq!(first_difference, None, "bit-identical");
    // The stream taps: the samples clear of the surface come in runs between taps.
    let trace = plan.coupled_trace(&mut SynthState::steady(&plan, 11), 700);
    let forced = trace
        .expect("coupled")
        .force
        .iter()
        .filter(|f| **f != 0.0)
        .count();
    assert!(forced > 0, "the defaults tap");
}

#[test]
fn thermal_noise_obeys_equipartition() {
    for engine in [Engine::Paper, Engine::Coupled] {
        equipartition(engine);
    }
}

fn equipartition(engine: Engine) {
    // No contact, no drive to speak of, thermal noise only. Each mode contributes
    // (light-lever factor)²·φn(L)²·k_B·T/Kn to the photodiode variance, on either engine.
    let mut s = paper_defaults();
    s.synth.engine = engine;
    s.surface.distance = 1e-6;
    s.drive.free_amplitude = 1e-15;
    s.cantilever.q = vec![10.0, 20.0, 20.0];
    s.synth.sample_rate = 2e6;
    s.noise.enable = true;
    s.noise.temperature = 300.0;
    s.noise.detector_density = 0.0;
    s.noise.adc_bits = 0;
    for d in &mut s.demods {
        d.enable = false;
    }
    let plan = SynthPlan::new(&s).unwrap();
    let expected: f64 = plan
        .cantilever
        .modes
        .iter()
        .map(|m| (m.light_lever_factor() * m.tip_value).powi(2) * BOLTZMANN * 300.0 / m.stiffness)
        .sum();
    let mut state = SynthState::steady(&plan, 3);
    let mut block = vec![0.0; 1 << 16];
    let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
    for _ in 0..300 {
        plan.process(&mut state, &mut block);
        for &x in &block {
            sum += x;
            sum2 += x * x;
            n += 1.0;
        }
    }
    let variance = sum2 / n - (sum / n).powi(2);
    println!(
        "{engine:?}: variance {variance:e} m², equipartition {expected:e} m² ({:+.2} %)",
        (variance / expected - 1.0) * 100.0
    );
    assert!(
        (variance / expected - 1.0).abs() < 0.02,
        "{engine:?}: variance {variance:e} vs {expected:e}"
    );
}

#[test]
fn a_live_change_is_a_physical_transient_not_a_jump() {
    let silicon = quiet(paper_defaults());
    let mut softer = silicon.clone();
    softer.sample.youngs_modulus = 60e9;
    let old = SynthPlan::new(&silicon).unwrap();
    let new = SynthPlan::new(&softer).unwrap();
    let mut state = SynthState::steady(&old, 1);
    let before = run(&old, &mut state, 10_000);
    state.retarget(&old, &new);
    let after = run(&new, &mut state, 200);
    // No jump at the switch: the step across it is no larger than the steady signal's
    // largest sample-to-sample step.
    let max_step = largest_step(&before);
    let across = (after[0] - before[before.len() - 1]).abs();
    assert!(
        across <= max_step * 1.05,
        "step across the switch {across:e} vs {max_step:e}"
    );
    // Settled (mode 1 decays with Q/π ≈ 32 periods; wait 2000), the spectrum is the new
    // sample's, and H17 has moved by the amount `ftafm paper` predicts.
    let _ = run(&new, &mut state, 200_000 - 200);
    let start = state.phase();
    let settled = run(&new, &mut state, 20_000);
    let expected = paper::compute(&softer, 1.0).unwrap().materials[0]
        .spectrum
        .clone();
    let old_h17 = paper::compute(&silicon, 1.0).unwrap().materials[0].spectrum[17].amplitude;
    let h17 = harmonic(&settled, &new, start, 17).norm();
    assert!(
        (h17 / expected[17].amplitude - 1.0).abs() < 0.005,
        "H17 {h17:e} vs {:e}",
        expected[17].amplitude
    );
    assert!(
        h17 < old_h17 * 0.9,
        "softer sample: H17 falls ({h17:e} vs {old_h17:e})"
    );
}

#[test]
fn the_adc_quantises_clips_and_counts() {
    let mut s = paper_defaults();
    s.noise.enable = true;
    s.noise.temperature = 0.0;
    s.noise.detector_density = 0.0;
    s.noise.adc_bits = 12;
    s.noise.adc_range = 10e-9; // the ≈ 19 nm fundamental overdrives it
    let plan = SynthPlan::new(&s).unwrap();
    let adc = plan.adc.expect("quantisation on");
    assert_eq!(adc.lsb, 20e-9 / 4096.0);
    let mut state = SynthState::steady(&plan, 1);
    let samples = run(&plan, &mut state, 10_000);
    let clipped = samples.iter().filter(|x| x.abs() >= 10e-9).count() as u64;
    assert!(clipped > 1000, "the overdriven ADC clips often: {clipped}");
    assert_eq!(
        state.counters.clipped, clipped,
        "every clipped sample is counted"
    );
    for x in &samples {
        assert!(x.abs() <= 10e-9);
        let codes = x / adc.lsb;
        assert!(
            (codes - codes.round()).abs() < 1e-6,
            "{x} is not on the {:e} m grid",
            adc.lsb
        );
    }
}

#[test]
fn detector_noise_has_the_configured_density() {
    // White noise of one-sided density ρ over 0…f_s/2 has variance ρ²·f_s/2.
    let mut s = paper_defaults();
    s.surface.distance = 1e-6;
    s.drive.free_amplitude = 1e-15;
    s.noise.enable = true;
    s.noise.temperature = 0.0;
    s.noise.adc_bits = 0;
    s.noise.detector_density = 1e-13;
    let plan = SynthPlan::new(&s).unwrap();
    let mut state = SynthState::steady(&plan, 5);
    let samples = run(&plan, &mut state, 1 << 20);
    let variance = samples.iter().map(|x| x * x).sum::<f64>() / samples.len() as f64;
    let expected = 1e-26 * 10e6 / 2.0;
    // 2^20 independent samples: the estimate's relative spread is √(2/2^20) ≈ 0.14 %.
    assert!(
        (variance / expected - 1.0).abs() < 0.01,
        "{variance:e} vs {expected:e}"
    );
}

#[test]
fn a_new_seed_restarts_the_noise_from_that_seed() {
    // Detector noise only (no thermal state carried in the modes), so after the reseed two
    // streams must agree to the bit.
    let mut settings = paper_defaults();
    settings.noise.temperature = 0.0;
    let mut reseeded = settings.clone();
    reseeded.synth.seed = 99;
    let a = SynthPlan::new(&settings).unwrap();
    let b = SynthPlan::new(&reseeded).unwrap();
    // Two streams that differ in their first 1000 samples switch to seed 99 at the same
    // point; from there on their noise is identical, so their difference is deterministic.
    let mut one = SynthState::steady(&a, 1);
    let mut two = SynthState::steady(&a, 2);
    let (x1, x2) = (run(&a, &mut one, 1000), run(&a, &mut two, 1000));
    assert!(x1.iter().zip(&x2).any(|(p, q)| p != q));
    one.retarget(&a, &b);
    two.retarget(&a, &b);
    let (y1, y2) = (run(&b, &mut one, 1000), run(&b, &mut two, 1000));
    assert!(
        y1.iter().zip(&y2).all(|(p, q)| p.to_bits() == q.to_bits()),
        "same noise after the reseed"
    );
}

#[test]
fn turning_the_anti_alias_filter_on_and_off_while_running_is_seamless() {
    // The filter's delay (21.5 samples) shifts the stream when it turns on or off, by at
    // most the signal's change over that time; it must not start from a stale history.
    let off = {
        let mut s = quiet(paper_defaults());
        s.synth.anti_alias = false;
        s
    };
    let on = quiet(paper_defaults());
    let (p_off, p_on) = (SynthPlan::new(&off).unwrap(), SynthPlan::new(&on).unwrap());
    let mut state = SynthState::steady(&p_off, 1);
    let before = run(&p_off, &mut state, 10_000);
    state.retarget(&p_off, &p_on);
    let after = run(&p_on, &mut state, 10_000);
    state.retarget(&p_on, &p_off);
    let back = run(&p_off, &mut state, 1_000);
    let max_step = largest_step(&before);
    // On: the delay appears, so the stream steps back by 21.5 samples once, at most the
    // signal's change over that time (a stale or zero history would step by up to the full
    // 30 nm amplitude); from then on it is as smooth as before.
    let on_step = (after[0] - before[before.len() - 1]).abs();
    assert!(on_step <= 23.0 * max_step, "{on_step:e} vs {max_step:e}");
    let step = largest_step(&after);
    assert!(step <= max_step * 1.05, "step {step:e} vs {max_step:e}");
    // Off again: the delay goes, the stream steps forward once by as much.
    let across = (back[0] - after[after.len() - 1]).abs();
    assert!(across <= 23.0 * max_step, "{across:e} vs {max_step:e}");
}
