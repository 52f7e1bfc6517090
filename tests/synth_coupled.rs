//! The real-time coupled engine (physics.md §6) against the offline coupled orbit (a
//! tight-tolerance Runge–Kutta with shooting, `src/physics/coupled.rs`, itself checked by
//! energy balance and Liouville in `tests/physics_coupled.rs`), and against its own
//! promises: a settled start, the paper engine's exact free motion and noise where the tip
//! does not touch, a physical transient when the engine is switched while running.

use std::f64::consts::PI;

use ftafm::config::{Engine, Settings, default_settings};
use ftafm::model;
use ftafm::physics::{CoupledOrbit, CoupledProblem, HertzContact};
use ftafm::synth::{SynthPlan, SynthState};
use rustfft::num_complex::Complex64;

fn coupled(mut s: Settings) -> Settings {
    s.synth.engine = Engine::Coupled;
    s.noise.enable = false;
    s
}

/// The offline periodic orbit at the plan's realised drive frequency.
fn reference(settings: &Settings, plan: &SynthPlan) -> CoupledOrbit {
    let cantilever = model::cantilever(settings).unwrap();
    CoupledProblem::new(
        &cantilever,
        plan.drive_frequency,
        settings.drive.free_amplitude,
        settings.surface.distance,
        HertzContact::new(
            model::elastic(settings.tip),
            model::elastic(settings.sample),
            settings.cantilever.tip_radius,
        ),
    )
    .solve(24)
    .unwrap()
}

/// Peak-amplitude phasor of harmonic k (k = 0: the mean) over whole periods.
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
    let scale = if k == 0 { 1.0 } else { 2.0 };
    sum * (scale / samples.len() as f64)
}

/// The photodiode's response to the tap force alone: the samples minus the free drive
/// response, which the offline orbit's spectrum describes.
fn tap_response(plan: &SynthPlan, state: &mut SynthState, n: usize) -> (u64, Vec<f64>) {
    // The drive phase at which the first sample was taken (the ADC filter's delay before).
    let start = plan.output_phase(state.phase());
    let mut out = vec![0.0; n];
    plan.process(state, &mut out);
    let free = plan.free_signal();
    let turn = 2f64.powi(64);
    for (i, s) in out.iter_mut().enumerate() {
        let word = start.wrapping_add(plan.frequency_word.wrapping_mul(i as u64));
        *s -= (free * Complex64::from_polar(1.0, word as f64 / turn * 2.0 * PI)).re;
    }
    (start, out)
}

/// Samples in `periods` drive periods, which must be a whole number of samples (else the
/// fundamental leaks into the harmonics' bins).
fn whole_periods(plan: &SynthPlan, periods: usize) -> usize {
    let n = plan.sample_rate / plan.drive_frequency * periods as f64;
    assert!(
        (n - n.round()).abs() < 1e-6,
        "{periods} periods are {n} samples"
    );
    n.round() as usize
}

/// Harmonics next to the light-lever zeros at 2.807·f1 and 11.23·f1 (the drive at f1): the
/// signal there is ~100× below its neighbours and is compared against H6 instead.
const NEAR_ZEROS: [u64; 3] = [3, 11, 12];

/// F, τ = 1.5·FWHM/T and θ of the engine's own integration over `periods` periods.
fn measured_contact(plan: &SynthPlan, state: &mut SynthState, periods: usize) -> (f64, f64, f64) {
    let n = whole_periods(plan, periods);
    let trace = plan.coupled_trace(state, n).expect("coupled engine");
    let f = &trace.force;
    let (peak_at, &peak) = f
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .unwrap();
    // Half maximum crossings either side of the peak, linearly interpolated.
    let half = peak / 2.0;
    let mut left = peak_at;
    while f[left - 1] >= half {
        left -= 1;
    }
    let mut right = peak_at;
    while f[right + 1] >= half {
        right += 1;
    }
    let rise = (left - 1) as f64 + (half - f[left - 1]) / (f[left] - f[left - 1]);
    let fall = right as f64 + (f[right] - half) / (f[right] - f[right + 1]);
    let tau = 1.5 * (fall - rise) * trace.dt * plan.drive_frequency;
    let z1 = harmonic(&trace.tip, plan, trace.start_phase, 1);
    // θ as the paper prints it (and the offline orbit reports it): the lag, negative.
    let theta = -(z1 / trace.free_tip).arg();
    (peak, tau, theta)
}

/// Compares the engine's stream with the offline orbit as issue 14's goals state them:
/// F and τ within 0.5 %, θ within 0.05°, H1 within 0.1 %, H2–H18 within 1 % (those next to
/// a light-lever zero against H6's size).
fn check_against_reference(settings: &Settings, periods: usize) {
    let plan = SynthPlan::new(settings).unwrap();
    let orbit = reference(settings, &plan);
    let mut state = SynthState::steady(&plan, 1);
    let n = whole_periods(&plan, periods);
    let (start, samples) = tap_response(&plan, &mut state, n);
    let h6 = orbit.spectrum[6];
    let mut worst = (0, 0.0f64);
    for k in 1..=18u64 {
        let got = harmonic(&samples, &plan, start, k).norm();
        let want = orbit.spectrum[k as usize];
        let (err, tolerance) = match k {
            1 => ((got / want - 1.0).abs(), 0.001),
            k if NEAR_ZEROS.contains(&k) => ((got - want).abs() / h6, 0.01),
            _ => ((got / want - 1.0).abs(), 0.01),
        };
        assert!(
            err < tolerance,
            "H{k}: real-time {got:.6e} m, offline {want:.6e} m ({:.3} %)",
            err * 100.0
        );
        if k > 1 && !NEAR_ZEROS.contains(&k) && err > worst.1 {
            worst = (k, err);
        }
    }
    let (force, tau, theta) = measured_contact(&plan, &mut state, periods / 10);
    assert!(
        (force / orbit.max_force - 1.0).abs() < 0.005,
        "F {force:e} N vs {:e} N",
        orbit.max_force
    );
    assert!(
        (tau / orbit.contact_time_ratio - 1.0).abs() < 0.005,
        "τ {tau} vs {}",
        orbit.contact_time_ratio
    );
    let dtheta = (theta - orbit.phase_shift).to_degrees();
    // The figures docs/ft-afm.md quotes (`cargo test --release --test synth_coupled --
    // --nocapture`).
    eprintln!(
        "F {:+.3} %, τ {:+.3} %, θ {dtheta:+.4}°, worst of H2–H18 H{} {:.3} %",
        (force / orbit.max_force - 1.0) * 100.0,
        (tau / orbit.contact_time_ratio - 1.0) * 100.0,
        worst.0,
        worst.1 * 100.0
    );
    assert!(
        dtheta.abs() < 0.05,
        "θ {:.4}° vs {:.4}°",
        theta.to_degrees(),
        orbit.phase_shift.to_degrees()
    );
}

#[test]
fn the_table_1_silicon_orbit_matches_the_offline_reference() {
    // 100 samples per period, 200 periods.
    check_against_reference(&coupled(default_settings()), 200);
}

#[test]
fn hard_tapping_matches_the_offline_reference() {
    // Where the paper's 1-DOF method is off by tens of per cent at H17/H18.
    let mut s = coupled(default_settings());
    s.surface.distance = 10e-9;
    check_against_reference(&s, 200);
}

#[test]
fn a_soft_polymer_with_long_contact_matches_the_offline_reference() {
    let mut s = coupled(default_settings());
    s.sample.youngs_modulus = 3e9;
    s.sample.poisson = 0.35;
    check_against_reference(&s, 200);
}

#[test]
fn a_300_khz_lever_on_fused_silica_matches_the_offline_reference() {
    let mut s = coupled(default_settings());
    s.cantilever.f1 = 300e3;
    s.cantilever.k = 40.0;
    s.drive.frequency = 300e3;
    s.synth.sample_rate = 25e6;
    s.sample.youngs_modulus = 72e9;
    s.sample.poisson = 0.17;
    // 83⅓ samples per period: 3 periods are 250 samples.
    check_against_reference(&s, 210);
}

#[test]
fn the_stream_starts_on_the_periodic_orbit() {
    let settings = coupled(default_settings());
    let plan = SynthPlan::new(&settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut first = vec![0.0; 100];
    plan.process(&mut state, &mut first);
    let mut skip = vec![0.0; 100 * 999];
    plan.process(&mut state, &mut skip);
    let mut later = vec![0.0; 100];
    plan.process(&mut state, &mut later);
    let scale = first.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    for (a, b) in first.iter().zip(&later) {
        assert!((a - b).abs() < 1e-5 * scale, "{a} vs {b}");
    }
}

#[test]
fn clear_of_the_surface_it_is_the_paper_engines_stream_bit_for_bit() {
    // Noise on (thermal, detector, ADC): where g = 0 a coupled step is the exact modal
    // propagator with the same held thermal input, so the streams are identical.
    let mut s = default_settings();
    s.surface.distance = 1e-6;
    let paper = SynthPlan::new(&s).unwrap();
    s.synth.engine = Engine::Coupled;
    let coupled = SynthPlan::new(&s).unwrap();
    let (mut a, mut b) = (
        SynthState::steady(&paper, 5),
        SynthState::steady(&coupled, 5),
    );
    let (mut x, mut y) = (vec![0.0; 50_000], vec![0.0; 50_000]);
    paper.process(&mut a, &mut x);
    coupled.process(&mut b, &mut y);
    assert_eq!(x, y);
}

#[test]
fn switching_engines_while_running_is_a_transient_that_settles_on_the_coupled_orbit() {
    let paper_settings = {
        let mut s = default_settings();
        s.noise.enable = false;
        s.surface.distance = 10e-9;
        s
    };
    let coupled_settings = coupled(paper_settings.clone());
    let old = SynthPlan::new(&paper_settings).unwrap();
    let new = SynthPlan::new(&coupled_settings).unwrap();
    let mut state = SynthState::steady(&old, 1);
    let mut before = vec![0.0; 10_000];
    old.process(&mut state, &mut before);
    state.retarget(&old, &new);
    let mut after = vec![0.0; 200];
    new.process(&mut state, &mut after);
    let max_step = before
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max);
    let across = (after[0] - before[before.len() - 1]).abs();
    assert!(
        across <= max_step * 1.05,
        "step across the switch {across:e} vs {max_step:e}"
    );
    // Hard tapping: the engines differ; after 2000 periods the stream is the coupled orbit.
    let mut settle = vec![0.0; 200_000];
    new.process(&mut state, &mut settle);
    let orbit = reference(&coupled_settings, &new);
    let (start, samples) = tap_response(&new, &mut state, 20_000);
    for k in [1u64, 6, 17, 18] {
        let got = harmonic(&samples, &new, start, k).norm();
        let want = orbit.spectrum[k as usize];
        assert!(
            (got / want - 1.0).abs() < 0.01,
            "H{k}: {got:.6e} vs {want:.6e}"
        );
    }
}

#[test]
fn the_material_contrast_matches_the_offline_reference() {
    // c = 1 − S_Si/S_Inh (the paper's sign) at H6, H17, H18, for the Table 1 pair.
    let silicon = coupled(default_settings());
    let mut inclusion = silicon.clone();
    inclusion.sample.youngs_modulus = 116.1e9;
    let measure = |s: &Settings| -> (Vec<f64>, Vec<f64>) {
        let plan = SynthPlan::new(s).unwrap();
        let orbit = reference(s, &plan);
        let mut state = SynthState::steady(&plan, 1);
        let (start, samples) = tap_response(&plan, &mut state, whole_periods(&plan, 200));
        let live = (0..=18)
            .map(|k| harmonic(&samples, &plan, start, k).norm())
            .collect();
        (live, orbit.spectrum)
    };
    let (si_live, si_ref) = measure(&silicon);
    let (inh_live, inh_ref) = measure(&inclusion);
    for (k, tolerance) in [(6, 0.02), (17, 0.1), (18, 0.1)] {
        let live = (1.0 - si_live[k] / inh_live[k]) * 100.0;
        let offline = (1.0 - si_ref[k] / inh_ref[k]) * 100.0;
        eprintln!("H{k} contrast: real-time {live:+.4} %, offline {offline:+.4} %");
        assert!(
            (live - offline).abs() < tolerance,
            "H{k} contrast {live:.4} % vs {offline:.4} % (percentage points, within {tolerance})"
        );
    }
}
