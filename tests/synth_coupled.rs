//! The real-time coupled engine (physics.md §6) against the offline coupled orbit (a
//! tight-tolerance Runge–Kutta with shooting, `src/physics/coupled/`, itself checked by
//! energy balance and Liouville in `tests/physics_coupled.rs`), and against its own
//! promises: a settled start, the paper engine's exact free motion and noise where the tip
//! does not touch, a physical transient when the engine is switched while running.

use std::f64::consts::PI;

use ftafm::config::{Engine, Settings, default_settings};
use ftafm::model;
use ftafm::physics::{CoupledOrbit, HertzContact};
use ftafm::synth::{SynthPlan, SynthState};
use rustfft::num_complex::Complex64;

fn coupled(mut s: Settings) -> Settings {
    s.synth.engine = Engine::Coupled;
    s.noise.enable = false;
    s
}

/// The offline periodic orbit at the plan's realised drive frequency (with the settings'
/// adhesion).
fn reference(settings: &Settings, plan: &SynthPlan) -> CoupledOrbit {
    let cantilever = model::cantilever(settings).unwrap();
    model::coupled_problem(settings, &cantilever, settings.sample, plan.drive_frequency)
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
    let (mut worst, mut h1) = ((0, 0.0f64), 0.0);
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
        if k == 1 {
            h1 = err;
        } else if !NEAR_ZEROS.contains(&k) && err > worst.1 {
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
        "F {:+.3} %, τ {:+.3} %, θ {dtheta:+.4}°, H1 {:.4} %, worst of H2–H18 H{} {:.3} %",
        (force / orbit.max_force - 1.0) * 100.0,
        (tau / orbit.contact_time_ratio - 1.0) * 100.0,
        h1 * 100.0,
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

/// Hard tapping, where the paper's 1-DOF method is off by tens of per cent at H17/H18.
fn hard_tapping() -> Settings {
    let mut s = coupled(default_settings());
    s.surface.distance = 10e-9;
    s
}

/// A soft polymer: long contact.
fn soft_polymer() -> Settings {
    let mut s = coupled(default_settings());
    s.sample.youngs_modulus = 3e9;
    s.sample.poisson = 0.35;
    s
}

/// A 300 kHz, 40 N/m lever on fused silica at 25 MS/s: 83⅓ samples per period (3 periods
/// are 250 samples, so 210 periods are whole samples).
fn lever_300_khz() -> Settings {
    let mut s = coupled(default_settings());
    s.cantilever.f1 = 300e3;
    s.cantilever.k = 40.0;
    s.drive.frequency = 300e3;
    s.synth.sample_rate = 25e6;
    s.sample.youngs_modulus = 72e9;
    s.sample.poisson = 0.17;
    s
}

#[test]
fn the_table_1_silicon_orbit_matches_the_offline_reference() {
    // 100 samples per period, 200 periods.
    check_against_reference(&coupled(default_settings()), 200);
}

#[test]
fn hard_tapping_matches_the_offline_reference() {
    check_against_reference(&hard_tapping(), 200);
}

#[test]
fn a_soft_polymer_with_long_contact_matches_the_offline_reference() {
    check_against_reference(&soft_polymer(), 200);
}

#[test]
fn a_300_khz_lever_on_fused_silica_matches_the_offline_reference() {
    check_against_reference(&lever_300_khz(), 210);
}

/// `/synth/contact_substeps` trades accuracy for speed: at 6, half the default's sub-steps
/// (docs/ft-afm.md has the errors and the speeds per count), every case still meets the
/// goals against the offline orbit; at the default the stream is the one the tests above
/// check.
#[test]
fn half_the_contact_substeps_still_meet_the_goals() {
    for (name, settings, periods) in [
        ("Table 1", coupled(default_settings()), 200),
        ("hard tapping", hard_tapping(), 200),
        ("polymer", soft_polymer(), 200),
        ("300 kHz", lever_300_khz(), 210),
        (
            "adhesion",
            with_adhesion(coupled(default_settings()), None),
            200,
        ),
        (
            "adhesion, polymer",
            with_adhesion(soft_polymer(), Some(15e-9)),
            200,
        ),
    ] {
        let mut s = settings;
        assert_eq!(s.synth.contact_substeps, 12, "the default");
        s.synth.contact_substeps = 6;
        eprint!("{name}, 6 sub-steps: ");
        check_against_reference(&s, periods);
    }
}

/// The worst error of H2–`last` of the engine's stream against the offline orbit over
/// `periods` periods (relative to each to H18, or against H6 next to a light-lever zero;
/// past H18, where the spectrum falls by up to 50× towards zeros of its own, against H18),
/// that harmonic, and the samples the engine refined and left over its error budget.
fn worst_harmonic(settings: &Settings, periods: usize, last: u64) -> (u64, f64, u64, u64) {
    let plan = SynthPlan::new(settings).unwrap();
    let cantilever = model::cantilever(settings).unwrap();
    let orbit =
        model::coupled_problem(settings, &cantilever, settings.sample, plan.drive_frequency)
            .solve(last as usize)
            .unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let (start, samples) = tap_response(&plan, &mut state, whole_periods(&plan, periods));
    let mut worst = (0, 0.0f64);
    for k in 2..=last {
        let got = harmonic(&samples, &plan, start, k).norm();
        let want = orbit.spectrum[k as usize];
        let err = if NEAR_ZEROS.contains(&k) {
            (got - want).abs() / orbit.spectrum[6]
        } else if k > 18 {
            (got - want).abs() / orbit.spectrum[18]
        } else {
            (got / want - 1.0).abs()
        };
        if err > worst.1 {
            worst = (k, err);
        }
    }
    (
        worst.0,
        worst.1,
        state.counters.refined,
        state.counters.over_budget,
    )
}

/// The sub-steps follow the contact's stiffness (`SUBSTEP_BUDGET`): levers with 10 and 16
/// modes in hard tapping, whose tips are lighter than the 5-mode lever's, stay within
/// 0.1 % to H18 (and H19–H30 within 0.1 % of H18) at the default
/// `/synth/contact_substeps` without it being touched (at a fixed 12 the 16-mode lever's
/// H18 is 0.16 % off); the defaults are not refined (their speed is the default count's).
#[test]
fn the_sub_steps_follow_the_contacts_stiffness_within_a_tenth_of_a_per_cent() {
    // The two levers on threads of their own: each is an offline orbit and a run.
    let results: Vec<_> = std::thread::scope(|scope| {
        let runs: Vec<_> = [5, 11]
            .map(|extra| {
                scope.spawn(move || {
                    let mut s = hard_tapping();
                    s.cantilever.extra_modes = extra;
                    (5 + extra, worst_harmonic(&s, 200, 30))
                })
            })
            .into_iter()
            .collect();
        runs.into_iter().map(|r| r.join().unwrap()).collect()
    });
    for (modes, (k, err, refined, over)) in results {
        eprintln!(
            "{modes} modes, hard tapping: worst of H2–H30 H{k} {:.4} %, {refined} samples refined",
            err * 100.0
        );
        assert!(err < 1e-3, "{modes} modes: H{k} {:.3} %", err * 100.0);
        assert!(refined > 1000, "{refined} samples refined");
        assert_eq!(over, 0);
    }
    let (_, _, refined, _) = worst_harmonic(&coupled(default_settings()), 20, 18);
    assert_eq!(refined, 0, "the defaults refined");
}

/// `s` with DMT adhesion on, and the surface at `distance` (m) if given.
fn with_adhesion(mut s: Settings, distance: Option<f64>) -> Settings {
    s.adhesion.enable = true;
    if let Some(d) = distance {
        s.surface.distance = d;
    }
    s
}

#[test]
fn with_dmt_adhesion_the_silicon_orbit_matches_the_offline_reference() {
    check_against_reference(&with_adhesion(coupled(default_settings()), None), 200);
}

#[test]
fn with_adhesion_in_hard_tapping_on_a_polymer_it_matches_the_offline_reference() {
    // The pull (3.9 nN) against a soft contact's smaller repulsion, the tip deep in it.
    check_against_reference(&with_adhesion(soft_polymer(), Some(15e-9)), 200);
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

/// Frequency (Hz) of the largest peak of `samples`' power spectrum within `band` (Hz):
/// Welch's average over 2^15-point Hann segments, then a parabola through 1/PSD of the bins
/// within a third of the peak's half width (a Lorentzian's 1/PSD is a parabola near f0).
fn spectral_peak(samples: &[f64], sample_rate: f64, band: (f64, f64)) -> f64 {
    let n = 1 << 15;
    let fft = rustfft::FftPlanner::<f64>::new().plan_fft_forward(n);
    let window: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * PI * i as f64 / n as f64).cos())
        .collect();
    let mut psd = vec![0.0; n / 2];
    let mut buffer = vec![Complex64::new(0.0, 0.0); n];
    for segment in samples.chunks_exact(n / 2).collect::<Vec<_>>().windows(2) {
        for (i, b) in buffer.iter_mut().enumerate() {
            let s = if i < n / 2 {
                segment[0][i]
            } else {
                segment[1][i - n / 2]
            };
            *b = Complex64::new(s * window[i], 0.0);
        }
        fft.process(&mut buffer);
        for (p, b) in psd.iter_mut().zip(&buffer) {
            *p += b.norm_sqr();
        }
    }
    let df = sample_rate / n as f64;
    let (lo, hi) = ((band.0 / df) as usize, (band.1 / df) as usize);
    let peak = (lo..hi).max_by(|&a, &b| psd[a].total_cmp(&psd[b])).unwrap();
    let half = (peak..hi).find(|&i| psd[i] < 0.5 * psd[peak]).unwrap() - peak;
    let reach = (half / 3).max(2);
    // Least squares of 1/PSD = c0 + c1·x + c2·x² over the bins x = i − peak.
    let mut m = [[0.0; 3]; 3];
    let mut v = [0.0; 3];
    for (i, p) in psd
        .iter()
        .enumerate()
        .take(peak + reach + 1)
        .skip(peak - reach)
    {
        let x = i as f64 - peak as f64;
        let basis = [1.0, x, x * x];
        for r in 0..3 {
            v[r] += basis[r] / p;
            for c in 0..3 {
                m[r][c] += basis[r] * basis[c];
            }
        }
    }
    // Cramer's rule for c1 and c2.
    let det3 = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let with = |col: usize| {
        let mut a = m;
        for r in 0..3 {
            a[r][col] = v[r];
        }
        det3(a)
    };
    let (c1, c2) = (with(1), with(2));
    (peak as f64 - c1 / (2.0 * c2)) * df
}

/// The tip pressed into a 3 GPa polymer and left there (the surface above the tip's rest
/// position: contact mode, thermal noise only): the modes the thermal spectrum shows are
/// those of the lever with the linearised contact stiffness k_c = dF/dδ = (3/2)·κ√R·δ0^½
/// at the static indentation δ0 on its tip. The prediction solves the modal model with that
/// spring, 1 + k_c·Σ φn(L)²/(Kn − ω²Mn) = 0, with the static equilibrium from the modes'
/// compliance; the engine never linearises anything.
#[test]
fn contact_shifts_the_modes_as_the_linearised_contact_stiffness_predicts() {
    let mut s = default_settings();
    s.synth.engine = Engine::Coupled;
    s.synth.sample_rate = 4e6;
    s.noise.enable = true;
    s.noise.detector_density = 0.0;
    s.noise.adc_bits = 0;
    s.sample.youngs_modulus = 3e9;
    s.sample.poisson = 0.35;
    s.drive.free_amplitude = 1e-13;
    // Not a configurable state (the node is a distance above the sample): built directly.
    s.surface.distance = -1.7e-9;
    let plan = SynthPlan::new(&s).unwrap();
    let modes = &plan.cantilever.modes;
    let hertz = HertzContact::new(
        model::elastic(s.tip),
        model::elastic(s.sample),
        s.cantilever.tip_radius,
    )
    .stiffness_coefficient();
    // Static equilibrium: the tip deflection w = C·F(δ) with C = Σ φn²/Kn, δ = −A_set − w.
    let compliance: f64 = modes
        .iter()
        .map(|m| m.tip_value.powi(2) / m.stiffness)
        .sum();
    let (mut lo, mut hi) = (0.0, -s.surface.distance);
    for _ in 0..200 {
        let delta = 0.5 * (lo + hi);
        let w = compliance * hertz * delta.powf(1.5);
        if -s.surface.distance - w > delta {
            lo = delta;
        } else {
            hi = delta;
        }
    }
    let delta0 = 0.5 * (lo + hi);
    let k_c = 1.5 * hertz * delta0.sqrt();
    let secular = |omega2: f64| {
        1.0 + k_c
            * modes
                .iter()
                .map(|m| {
                    m.tip_value.powi(2) / (m.stiffness - omega2 * m.stiffness / m.omega.powi(2))
                })
                .sum::<f64>()
    };
    let predicted: Vec<f64> = (0..2)
        .map(|n| {
            let (mut a, mut b) = (modes[n].omega.powi(2), modes[n + 1].omega.powi(2));
            for _ in 0..200 {
                let c = 0.5 * (a + b);
                // Just above ω_n² the sum is dominated by −φn²/(…)→ −∞: negative there.
                if secular(c) < 0.0 { a = c } else { b = c }
            }
            (0.5 * (a + b)).sqrt() / (2.0 * PI)
        })
        .collect();

    let mut state = SynthState::steady(&plan, 7);
    let mut samples = vec![0.0; 2_000_000];
    plan.process(&mut state, &mut samples);
    let mut measured = Vec::new();
    for (n, f) in predicted.iter().enumerate() {
        let free = modes[n].frequency;
        let peak = spectral_peak(
            &samples,
            s.synth.sample_rate,
            (0.9 * free, 1.6 * f.max(free)),
        );
        eprintln!(
            "mode {}: free {:.0} Hz, in contact (δ0 = {:.3} nm, k_c = {:.2} N/m) predicted {:.0} Hz \
             (+{:.2} %), measured {:.0} Hz (+{:.2} %), difference {:+.3} %",
            n + 1,
            free,
            delta0 * 1e9,
            k_c,
            f,
            (f / free - 1.0) * 100.0,
            peak,
            (peak / free - 1.0) * 100.0,
            (peak / f - 1.0) * 100.0
        );
        measured.push(peak);
    }
    for n in 0..2 {
        let shift = predicted[n] - modes[n].frequency;
        assert!(shift > 0.01 * modes[n].frequency, "mode {} shifts", n + 1);
        // Measured: +0.018 % and −0.027 % (the latter 2 % of mode 2's shift: the Strang
        // splitting's own phase error at the sub-step, (ω·dt)²/24 ≈ 3e-4).
        assert!(
            (measured[n] - predicted[n]).abs() < (0.05 * shift).min(1e-3 * predicted[n]),
            "mode {}: measured {} Hz, predicted {} Hz (free {} Hz)",
            n + 1,
            measured[n],
            predicted[n],
            modes[n].frequency
        );
    }
}
