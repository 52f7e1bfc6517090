//! FT-AFM inversion: two-harmonic cut-cosine fit, full force reconstruction and the Young's
//! modulus estimate, against synthetic harmonics from the forward model (physics.md §2–4).
//!
//! The paper's case throughout: f1 = 100 kHz, k = 20 N/m, Q = 100, 417, 340, 200, 26,
//! R = 10 nm, silicon tip and sample (129 GPa, ν = 0.28), A_free = 30 nm, A_set = 20 nm,
//! driven at f1.

use std::f64::consts::PI;
use std::sync::OnceLock;

use ftafm::physics::inversion::{
    AmplitudeMeasurement, CoefficientSource, DEFAULT_TABLE_POINTS, DEFAULT_TABLE_RANGE,
    HarmonicSample, InversionError, InversionOptions, ModulusTable, PulseMeasure, TableRange,
    fit_two_harmonics, force_series, light_lever_minima, reconstruct_force,
};
use ftafm::physics::spectrum::{cut_cosine_train, photodiode_transfer};
use ftafm::physics::{Cantilever, Elastic, HertzContact, ImpactOscillator, ImpactSolution};
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rand_xoshiro::rand_core::SeedableRng;
use rustfft::num_complex::Complex64;

const F1: f64 = 100e3;
const SI: Elastic = Elastic {
    youngs_modulus: 129e9,
    poisson: 0.28,
};
/// Highest harmonic of the synthetic spectra (the instrument has 32 demodulators).
const KMAX: usize = 32;

fn beam() -> Cantilever {
    Cantilever::new(F1, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap()
}

fn oscillator(modulus: f64) -> ImpactOscillator {
    let sample = Elastic {
        youngs_modulus: modulus,
        poisson: 0.28,
    };
    ImpactOscillator {
        k: 20.0,
        f1: F1,
        q: 100.0,
        drive_frequency: F1,
        free_amplitude: 30e-9,
        surface_distance: 20e-9,
        contact: HertzContact::new(SI, sample, 10e-9),
    }
}

fn solve(modulus: f64) -> ImpactSolution {
    oscillator(modulus).solve().unwrap()
}

fn silicon() -> &'static ImpactSolution {
    static S: OnceLock<ImpactSolution> = OnceLock::new();
    S.get_or_init(|| solve(129e9))
}

fn table() -> &'static ModulusTable {
    static T: OnceLock<ModulusTable> = OnceLock::new();
    T.get_or_init(|| {
        ModulusTable::new(
            &oscillator(129e9),
            SI,
            0.28,
            DEFAULT_TABLE_RANGE,
            DEFAULT_TABLE_POINTS,
        )
        .unwrap()
    })
}

/// Two-sided photodiode coefficients S_k (m), k = 0..=KMAX, of the cut-cosine train.
fn photodiode(beam: &Cantilever, force: f64, tau: f64, phase: f64) -> Vec<Complex64> {
    cut_cosine_train(force, tau, phase, KMAX)
        .iter()
        .enumerate()
        .map(|(k, c)| photodiode_transfer(beam, 2.0 * PI * F1 * k as f64) * c)
        .collect()
}

fn amplitude(s: &[Complex64], k: usize, sigma: f64) -> AmplitudeMeasurement {
    AmplitudeMeasurement {
        harmonic: k,
        amplitude: 2.0 * s[k].norm(),
        sigma,
    }
}

/// Harmonics 1..=KMAX as the lock-in bank measures them (no mean), each with σ per
/// quadrature of S_k.
fn samples(s: &[Complex64], sigma: f64) -> Vec<HarmonicSample> {
    (1..=KMAX)
        .map(|k| HarmonicSample {
            harmonic: k,
            value: s[k],
            sigma,
        })
        .collect()
}

/// Adds circular Gaussian noise of σ per quadrature to the lock-in output X + iY = 2·S_k of
/// every harmonic, i.e. σ/2 per quadrature of S_k.
fn noisy(s: &[Complex64], sigma: f64, rng: &mut Xoshiro256PlusPlus) -> Vec<Complex64> {
    s.iter()
        .map(|&c| {
            let re: f64 = StandardNormal.sample(rng);
            let im: f64 = StandardNormal.sample(rng);
            c + Complex64::new(re, im) * (0.5 * sigma)
        })
        .collect()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

#[test]
fn two_harmonic_method_recovers_tau_and_force() {
    let beam = beam();
    let si = silicon();
    let (force, tau) = (si.max_force, si.contact_time_ratio);
    let s = photodiode(&beam, force, tau, si.pulse_phase);
    for (a, b) in [(2, 17), (6, 17), (4, 18), (17, 2), (3, 5), (2, 28)] {
        let fit =
            fit_two_harmonics(&beam, F1, amplitude(&s, a, 0.0), amplitude(&s, b, 0.0)).unwrap();
        println!(
            "({a}, {b}): τ rel err {:.2e}, F rel err {:.2e}, τ_max {:.4}, alternatives {:?}",
            rel(fit.tau, tau),
            rel(fit.max_force, force),
            fit.tau_max,
            fit.alternatives
        );
        assert!(rel(fit.tau, tau) < 1e-6, "({a}, {b}) τ {}", fit.tau);
        assert!(
            rel(fit.max_force, force) < 1e-6,
            "({a}, {b}) F {}",
            fit.max_force
        );
        assert_eq!(fit.sigma_tau, 0.0);
        assert_eq!(fit.harmonics, (a, b));
    }
}

#[test]
fn two_harmonic_method_reports_impossible_inputs() {
    let beam = beam();
    let si = silicon();
    let s = photodiode(&beam, si.max_force, si.contact_time_ratio, si.pulse_phase);
    let m = |k: usize| amplitude(&s, k, 0.0);
    let fit = |a, b| fit_two_harmonics(&beam, F1, a, b);
    assert_eq!(fit(m(6), m(6)), Err(InversionError::SameHarmonic(6)));
    assert_eq!(fit(m(1), m(6)), Err(InversionError::HarmonicTooLow(1)));
    let zero = AmplitudeMeasurement {
        amplitude: 0.0,
        ..m(17)
    };
    assert!(matches!(
        fit(m(2), zero),
        Err(InversionError::InvalidAmplitude { harmonic: 17, .. })
    ));
    // Swapped amplitudes: |c_2| < |c_17| is no cut cosine before its first zero.
    let a2 = AmplitudeMeasurement {
        harmonic: 2,
        ..m(17)
    };
    let a17 = AmplitudeMeasurement {
        harmonic: 17,
        ..m(2)
    };
    assert!(matches!(
        fit(a2, a17),
        Err(InversionError::RatioOutOfRange {
            low: 2,
            high: 17,
            ..
        })
    ));
    let negative = AmplitudeMeasurement {
        sigma: -1.0,
        ..m(17)
    };
    assert!(matches!(
        fit(m(2), negative),
        Err(InversionError::InvalidSigma { .. })
    ));
    assert!(matches!(
        fit_two_harmonics(&beam, f64::NAN, m(2), m(17)),
        Err(InversionError::InvalidDriveFrequency(_))
    ));
}

/// Zeros of the undamped light-lever transfer Σ (2/3)·Lφn′(L)·φn(L)/(Kn·(1 − ω²/ωn²))
/// between consecutive resonances, by bisection: an oracle independent of |T|.
fn undamped_zeros(beam: &Cantilever) -> Vec<f64> {
    let t = |f: f64| -> f64 {
        beam.modes
            .iter()
            .map(|m| {
                let b = f / m.frequency;
                (2.0 / 3.0) * m.tip_slope * m.tip_value / m.stiffness / (1.0 - b * b)
            })
            .sum()
    };
    beam.modes
        .windows(2)
        .map(|w| {
            let (mut lo, mut hi) = (w[0].frequency * (1.0 + 1e-9), w[1].frequency * (1.0 - 1e-9));
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if (t(mid) < 0.0) == (t(lo) < 0.0) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        })
        .collect()
}

#[test]
fn light_lever_minima_are_found_from_the_transfer_function() {
    let five = beam();
    let minima = light_lever_minima(&five, 40.0 * F1);
    let ratios: Vec<f64> = minima.iter().map(|m| m.frequency / F1).collect();
    let oracle: Vec<f64> = undamped_zeros(&five).iter().map(|f| f / F1).collect();
    println!("|T| minima / f1 (5 modes): {ratios:?}; undamped zeros {oracle:?}");
    assert_eq!(minima.len(), 3, "{ratios:?}");
    for (r, z) in ratios.iter().zip(&oracle) {
        assert!(rel(*r, *z) < 1e-3, "{r} vs {z}");
    }
    let static_t = photodiode_transfer(&five, 0.0).norm();
    for m in &minima {
        assert!(m.magnitude < 0.05 * static_t, "{m:?}");
    }
    // With more modes the zeros converge to physics.md's 2.807, 11.23, 25.26·f1.
    let sixteen = Cantilever::new(F1, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 11).unwrap();
    let many: Vec<f64> = light_lever_minima(&sixteen, 40.0 * F1)
        .iter()
        .map(|m| m.frequency / F1)
        .collect();
    println!("|T| minima / f1 (16 modes): {many:?}");
    for ((r, r5), expected) in many.iter().zip(&ratios).zip([2.807, 11.23, 25.26]) {
        assert!(rel(*r, expected) < 0.006, "{r} vs {expected}");
        assert!((r - expected).abs() < (r5 - expected).abs());
    }
}

#[test]
fn two_harmonic_method_lists_the_other_roots_of_an_ambiguous_pair() {
    // A long pulse puts harmonic 28 past the first spectral zero (τ·28 > 1.5): the bracket
    // root is then wrong, and the true τ is among the alternatives.
    let beam = beam();
    let (force, tau) = (60e-9, 0.07);
    let s = photodiode(&beam, force, tau, 1.0);
    let fit = fit_two_harmonics(&beam, F1, amplitude(&s, 2, 0.0), amplitude(&s, 28, 0.0)).unwrap();
    println!(
        "τ = 0.07 with (2, 28): bracket root {:.5} (< τ_max {:.5}), alternatives {:?}",
        fit.tau, fit.tau_max, fit.alternatives
    );
    assert!(fit.tau < fit.tau_max && fit.tau_max < tau);
    assert!(fit.alternatives.iter().any(|&t| rel(t, tau) < 1e-9));
    // The paper's pair with the paper's pulse has no other root up to τ = 0.5.
    let si = silicon();
    let s = photodiode(&beam, si.max_force, si.contact_time_ratio, si.pulse_phase);
    let fit = fit_two_harmonics(&beam, F1, amplitude(&s, 2, 0.0), amplitude(&s, 17, 0.0)).unwrap();
    assert!(fit.alternatives.is_empty(), "{:?}", fit.alternatives);
}

#[test]
fn full_inversion_recovers_the_force_coefficients_and_the_pulse() {
    let beam = beam();
    let si = silicon();
    let (force, tau, phase) = (si.max_force, si.contact_time_ratio, si.pulse_phase);
    let s = photodiode(&beam, force, tau, phase);
    for pair in [Some((2, 17)), Some((6, 17)), Some((4, 18)), None] {
        let options = InversionOptions {
            pair,
            ..InversionOptions::default()
        };
        let r = reconstruct_force(&beam, F1, &samples(&s, 0.0), &options).unwrap();
        let kmax = r.coefficients.len() - 1;
        let truth = cut_cosine_train(force, tau, phase, kmax);
        let mut worst: f64 = 0.0;
        for c in &r.coefficients {
            let expected = match c.harmonic {
                0 => CoefficientSource::NotMeasured,
                1 => CoefficientSource::Fundamental,
                k if k <= KMAX => CoefficientSource::Measured,
                _ => CoefficientSource::NotMeasured,
            };
            assert_eq!(c.source, expected, "k {}", c.harmonic);
            if expected == CoefficientSource::Measured {
                let err = (c.value - truth[c.harmonic]).norm() / truth[c.harmonic].norm();
                worst = worst.max(err);
            }
            // The prior is the exact cut cosine here, so the filled ones are right too.
            assert!(
                (c.prior - truth[c.harmonic]).norm() < 1e-9 * truth[0].norm(),
                "prior k {}",
                c.harmonic
            );
        }
        println!(
            "pair {:?} → {:?}: K = {kmax}, worst |Δc_k|/|c_k| {worst:.1e}; peak {:+.4} %, τ {:+.4} %, \
             phase {:+.1e} rad",
            pair,
            r.prior.fit.harmonics,
            100.0 * (r.peak_force / force - 1.0),
            100.0 * (r.contact_time_ratio / tau - 1.0),
            r.pulse_phase - phase,
        );
        assert_eq!(kmax, (20.0 / tau).ceil() as usize);
        assert!(worst < 1e-9);
        assert!(rel(r.peak_force, force) < 0.01 && rel(r.contact_time_ratio, tau) < 0.01);
        assert!((r.pulse_phase - phase).abs() < 1e-6);
        assert!((r.prior.pulse_phase - phase).abs() < 1e-9);
        // The grid is the series.
        let c: Vec<Complex64> = r.coefficients.iter().map(|c| c.value).collect();
        let n = r.force.len();
        let theta = 2.0 * PI * 7.0 / n as f64;
        assert!((force_series(&c, theta) - r.force[7]).abs() < 1e-12 * force);
        // No noise: σ of the force is zero.
        assert_eq!(r.force_sigma, 0.0);
    }

    // The measured harmonics alone (series cut at k = 32, just past the cut cosine's first
    // spectral zero at 1.5/τ = 28.9) misplace the pulse by a few percent.
    let options = InversionOptions {
        pair: Some((2, 17)),
        max_harmonic: Some(KMAX),
        ..InversionOptions::default()
    };
    let r = reconstruct_force(&beam, F1, &samples(&s, 0.0), &options).unwrap();
    let (dp, dt) = (r.peak_force / force - 1.0, r.contact_time_ratio / tau - 1.0);
    println!(
        "series cut at 32: peak {:+.3} %, τ {:+.3} %",
        100.0 * dp,
        100.0 * dt
    );
    assert!((0.03..0.04).contains(&dp) && (-0.08..-0.06).contains(&dt));
}

#[test]
fn full_inversion_of_the_simulated_hertz_pulse() {
    // Harmonics from the FFT of the 1-DOF force itself (not a cut cosine): the measured
    // harmonics carry the true shape, the prior only fills k = 0, 1 and the tail.
    let beam = beam();
    for (modulus, peak_tol, tau_tol) in [(129e9, 0.01, 0.02), (5e9, 0.01, 0.01)] {
        let sol = solve(modulus);
        let s: Vec<Complex64> = sol
            .force_coefficients(KMAX)
            .iter()
            .enumerate()
            .map(|(k, c)| photodiode_transfer(&beam, 2.0 * PI * F1 * k as f64) * c)
            .collect();
        let r =
            reconstruct_force(&beam, F1, &samples(&s, 0.0), &InversionOptions::default()).unwrap();
        let (dp, dt) = (
            r.peak_force / sol.max_force - 1.0,
            r.contact_time_ratio / sol.contact_time_ratio - 1.0,
        );
        println!(
            "E {:.0} GPa (τ {:.4}): pair {:?}, peak {:+.3} %, τ {:+.3} %, phase {:+.1e} rad, \
             mean {:.4e} vs {:.4e} N",
            modulus / 1e9,
            sol.contact_time_ratio,
            r.prior.fit.harmonics,
            100.0 * dp,
            100.0 * dt,
            r.pulse_phase - sol.pulse_phase,
            r.mean_force,
            sol.mean_force
        );
        assert!(dp.abs() < peak_tol && dt.abs() < tau_tol);
        assert!((r.pulse_phase - sol.pulse_phase).abs() < 1e-5);
        // The automatic pair stays before the pulse's first spectral zero.
        let (a, b) = r.prior.fit.harmonics;
        assert!((a.max(b) as f64) < 1.5 / sol.contact_time_ratio);
    }
}

#[test]
fn full_inversion_with_noise_drops_harmonics_below_the_floor() {
    let beam = beam();
    let si = silicon();
    let s = photodiode(&beam, si.max_force, si.contact_time_ratio, si.pulse_phase);
    // Lock-in noise of 1 % of H17 per quadrature; σ per quadrature of S_k is half of that.
    let sigma = 0.01 * 2.0 * s[17].norm();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let options = InversionOptions {
        pair: Some((2, 17)),
        ..InversionOptions::default()
    };
    let (mut peaks, mut taus, mut predicted) = (Vec::new(), Vec::new(), Vec::new());
    let mut dropped = Vec::new();
    for _ in 0..200 {
        let n = noisy(&s, sigma, &mut rng);
        let r = reconstruct_force(&beam, F1, &samples(&n, 0.5 * sigma), &options).unwrap();
        peaks.push(r.peak_force);
        taus.push(r.contact_time_ratio);
        predicted.push(r.force_sigma);
        dropped = r
            .coefficients
            .iter()
            .filter(|c| c.source == CoefficientSource::BelowNoiseFloor)
            .map(|c| c.harmonic)
            .collect();
    }
    let (mp, sp) = mean_std(&peaks);
    let (mt, st) = mean_std(&taus);
    let (force_sigma, _) = mean_std(&predicted);
    println!(
        "noise 1 % of H17: dropped {dropped:?}; peak {mp:.4e} ± {sp:.2e} N (σ_F(θ) predicted \
         {force_sigma:.2e}), τ {mt:.5} ± {st:.5}"
    );
    // Harmonic 12 sits next to the light-lever zero at 11.61·f1; from 23 on the force
    // itself fades towards the cut cosine's first spectral zero (k = 28.9). Harmonic 3, by
    // the zero at 2.85·f1, still has an expected SNR of ≈ 14 at this noise.
    assert!(dropped.contains(&12) && !dropped.contains(&3));
    assert!(dropped.iter().all(|&k| k == 12 || (23..=32).contains(&k)));
    assert!(rel(mp, si.max_force) < 0.01 && rel(mt, si.contact_time_ratio) < 0.01);
    // The pointwise σ of the measured part describes the peak's spread.
    assert!(rel(sp, force_sigma) < 0.2, "{sp} vs {force_sigma}");
}

#[test]
fn modulus_from_the_one_dof_force_and_contact_time() {
    let t = table();
    let moduli = t.moduli();
    assert_eq!(moduli.len(), DEFAULT_TABLE_POINTS);
    assert!(rel(moduli[0], 1e9) < 1e-12 && rel(moduli[moduli.len() - 1], 1e12) < 1e-12);
    // Harder samples: larger force, shorter contact.
    assert!(t.forces().windows(2).all(|w| w[1] > w[0]));
    assert!(t.taus().windows(2).all(|w| w[1] < w[0]));
    let mut worst: f64 = 0.0;
    for modulus in [50e9, 80e9, 116.1e9, 129e9, 160e9, 200e9] {
        let s = solve(modulus);
        let (f, tau) = (s.max_force, s.contact_time_ratio);
        // Exact inputs (weights by relative misfit) and with realistic σ.
        for (sf, st) in [(0.0, 0.0), (1e-2 * f, 1e-2 * tau)] {
            let e = t.estimate(f, tau, sf, st).unwrap();
            assert_eq!(e.range, TableRange::Inside);
            assert!(e.force_in_range && e.tau_in_range);
            worst = worst.max(rel(e.youngs_modulus, modulus));
            assert!(rel(e.youngs_modulus, modulus) < 0.02, "{modulus}: {e:?}");
        }
    }
    println!("modulus from the 1-DOF's own (F, τ): worst relative error {worst:.2e}");
    assert!(worst < 1e-3);
}

#[test]
fn modulus_reports_measurements_outside_the_table() {
    let t = table();
    let n = t.forces().len();
    let (fmin, fmax) = (t.forces()[0], t.forces()[n - 1]);
    let (tmax, tmin) = (t.taus()[0], t.taus()[n - 1]);
    let soft = t.estimate(0.8 * fmin, 1.2 * tmax, 0.0, 0.0).unwrap();
    assert_eq!(soft.range, TableRange::BelowTable);
    assert!(!soft.force_in_range && !soft.tau_in_range);
    assert!(rel(soft.youngs_modulus, 1e9) < 1e-6);
    let hard = t.estimate(1.1 * fmax, 0.9 * tmin, 1e-9, 1e-3).unwrap();
    assert_eq!(hard.range, TableRange::AboveTable);
    assert!(rel(hard.youngs_modulus, 1e12) < 1e-6);
    assert!(t.estimate(-1.0, 0.05, 0.0, 0.0).is_err());
    assert!(t.estimate(60e-9, 0.05, -1.0, 0.0).is_err());
}

#[test]
fn propagated_uncertainties_match_the_spread_of_noisy_trials() {
    let beam = beam();
    let t = table();
    let si = silicon();
    let s = photodiode(&beam, si.max_force, si.contact_time_ratio, si.pulse_phase);
    // Lock-in noise: 1 % of H17 per quadrature, so σ of each amplitude ≈ 1 % of H17.
    let sigma = 0.01 * 2.0 * s[17].norm();
    for (a, b) in [(2, 17), (6, 17), (4, 18)] {
        let fit0 =
            fit_two_harmonics(&beam, F1, amplitude(&s, a, sigma), amplitude(&s, b, sigma)).unwrap();
        let cov0 = fit0.force_tau_covariance();
        let e0 = t
            .estimate_with_covariance(fit0.max_force, fit0.tau, cov0)
            .unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let (mut taus, mut forces, mut moduli) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..200 {
            let n = noisy(&s, sigma, &mut rng);
            let fit =
                fit_two_harmonics(&beam, F1, amplitude(&n, a, sigma), amplitude(&n, b, sigma))
                    .unwrap();
            let cov = fit.force_tau_covariance();
            let e = t
                .estimate_with_covariance(fit.max_force, fit.tau, cov)
                .unwrap();
            taus.push(fit.tau);
            forces.push(fit.max_force);
            moduli.push(e.youngs_modulus);
        }
        let (mt, st) = mean_std(&taus);
        let (mf, sf) = mean_std(&forces);
        let (me, se) = mean_std(&moduli);
        println!(
            "({a}, {b}) at σ = 1 % of H17: σ_τ {:.3e} vs {st:.3e} (τ̄ {mt:.5}), σ_F {:.3e} vs \
             {sf:.3e} N (F̄ {mf:.4e}), σ_E {:.2} vs {:.2} GPa (Ē {:.2} GPa), corr(τ, F) {:+.2}",
            fit0.sigma_tau,
            fit0.sigma_force,
            e0.uncertainty / 1e9,
            se / 1e9,
            me / 1e9,
            fit0.correlation
        );
        assert!(rel(st, fit0.sigma_tau) < 0.2);
        assert!(rel(sf, fit0.sigma_force) < 0.2);
        assert!(rel(se, e0.uncertainty) < 0.2);
        // No bias beyond the statistical error of the mean.
        assert!((mt - si.contact_time_ratio).abs() < 4.0 * st / 200f64.sqrt());
        assert!((me - 129e9).abs() < 4.0 * se / 200f64.sqrt());
    }
}

#[test]
fn silicon_and_the_softer_inhomogeneity_are_told_apart() {
    let beam = beam();
    let t = table();
    let spectrum = |modulus: f64| {
        let s = solve(modulus);
        photodiode(&beam, s.max_force, s.contact_time_ratio, s.pulse_phase)
    };
    let (si, inh) = (spectrum(129e9), spectrum(116.1e9));
    let h17 = 2.0 * si[17].norm();
    let estimate = |s: &[Complex64], sigma: f64| {
        let fit =
            fit_two_harmonics(&beam, F1, amplitude(s, 2, sigma), amplitude(s, 17, sigma)).unwrap();
        t.estimate_with_covariance(fit.max_force, fit.tau, fit.force_tau_covariance())
            .unwrap()
    };
    // σ_E is linear in the noise: the largest noise with |ΔE| > 3σ_E.
    let unit = 0.01 * h17;
    let (e_si, e_inh) = (estimate(&si, unit), estimate(&inh, unit));
    let delta = e_si.youngs_modulus - e_inh.youngs_modulus;
    let single = 0.01 * delta / (3.0 * e_si.uncertainty.max(e_inh.uncertainty));
    let combined = 0.01 * delta / (3.0 * e_si.uncertainty.hypot(e_inh.uncertainty));
    println!(
        "(2, 17): ΔE = {:.2} GPa; σ_E = {:.2} GPa per 1 % of H17; |ΔE| > 3σ_E up to σ = {:.2} % \
         of H17 (3σ of the difference: {:.2} %)",
        delta / 1e9,
        e_si.uncertainty / 1e9,
        100.0 * single,
        100.0 * combined
    );
    assert!(rel(delta, 12.9e9) < 1e-3);
    assert!(single > 0.005);
    // Check it by trials at half of H17's 1 %: every estimate is nearer its own material.
    let sigma = 0.005 * h17;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let midpoint = 0.5 * (129e9 + 116.1e9);
    let (mut right, mut gaps) = (0, Vec::new());
    for _ in 0..100 {
        let a = estimate(&noisy(&si, sigma, &mut rng), sigma);
        let b = estimate(&noisy(&inh, sigma, &mut rng), sigma);
        right +=
            usize::from(a.youngs_modulus > midpoint) + usize::from(b.youngs_modulus < midpoint);
        gaps.push((a.youngs_modulus - b.youngs_modulus) / a.uncertainty.hypot(b.uncertainty));
    }
    let (mean_gap, _) = mean_std(&gaps);
    println!("σ = 0.5 % of H17: {right}/200 classified right, mean ΔE/σ_ΔE = {mean_gap:.2}");
    assert!(right >= 190 && mean_gap > 3.0);
}

#[test]
fn a_two_harmonic_table_removes_the_cut_cosine_bias_of_a_hertz_pulse() {
    // Real 1-DOF force harmonics (not a cut cosine) through the two-harmonic method: its
    // (F, τ) differ from the pulse's own peak and 1.5·FWHM, so a table of the latter biases
    // E; a table of what the method reports on the 1-DOF pulse does not.
    let beam = beam();
    let pair = PulseMeasure::TwoHarmonic { low: 2, high: 17 };
    let matched = ModulusTable::with_measure(
        &oscillator(129e9),
        SI,
        0.28,
        DEFAULT_TABLE_RANGE,
        DEFAULT_TABLE_POINTS,
        pair,
    )
    .unwrap();
    assert_eq!(matched.measure(), pair);
    for modulus in [80e9, 129e9, 200e9] {
        let sol = solve(modulus);
        let s: Vec<Complex64> = sol
            .force_coefficients(KMAX)
            .iter()
            .enumerate()
            .map(|(k, c)| photodiode_transfer(&beam, 2.0 * PI * F1 * k as f64) * c)
            .collect();
        let fit =
            fit_two_harmonics(&beam, F1, amplitude(&s, 2, 0.0), amplitude(&s, 17, 0.0)).unwrap();
        let good = matched.estimate(fit.max_force, fit.tau, 0.0, 0.0).unwrap();
        let biased = table().estimate(fit.max_force, fit.tau, 0.0, 0.0).unwrap();
        println!(
            "E {:.0} GPa: two-harmonic F {:+.2} %, τ {:+.2} % vs the pulse; E from the \
             matched table {:+.3} %, from the shape table {:+.1} %",
            modulus / 1e9,
            100.0 * (fit.max_force / sol.max_force - 1.0),
            100.0 * (fit.tau / sol.contact_time_ratio - 1.0),
            100.0 * (good.youngs_modulus / modulus - 1.0),
            100.0 * (biased.youngs_modulus / modulus - 1.0),
        );
        assert!(rel(good.youngs_modulus, modulus) < 0.02);
    }
}

#[test]
fn full_inversion_uses_a_measured_mean_and_rejects_bad_input() {
    let beam = beam();
    let si = silicon();
    let s = photodiode(&beam, si.max_force, si.contact_time_ratio, si.pulse_phase);
    let truth = cut_cosine_train(si.max_force, si.contact_time_ratio, si.pulse_phase, KMAX);
    let mut with_mean = samples(&s, 0.0);
    with_mean.push(HarmonicSample {
        harmonic: 0,
        value: s[0],
        sigma: 0.0,
    });
    let options = InversionOptions::default();
    let r = reconstruct_force(&beam, F1, &with_mean, &options).unwrap();
    assert_eq!(r.coefficients[0].source, CoefficientSource::Measured);
    assert!(rel(r.coefficients[0].value.re, truth[0].re) < 1e-12);

    let run = |samples: &[HarmonicSample], options: &InversionOptions| {
        reconstruct_force(&beam, F1, samples, options)
    };
    let mut twice = samples(&s, 0.0);
    twice.push(twice[4]);
    assert_eq!(
        run(&twice, &options),
        Err(InversionError::DuplicateHarmonic(5))
    );
    let pair = InversionOptions {
        pair: Some((2, 40)),
        ..options
    };
    assert_eq!(
        run(&samples(&s, 0.0), &pair),
        Err(InversionError::PairNotMeasured(40))
    );
    let coarse = InversionOptions {
        grid_points: 4,
        ..options
    };
    assert!(matches!(
        run(&samples(&s, 0.0), &coarse),
        Err(InversionError::GridTooSmall { .. })
    ));
    // Only the fundamental and one higher harmonic: no pair.
    let few = &samples(&s, 0.0)[..2];
    assert_eq!(run(few, &options), Err(InversionError::NoUsablePair));
    // A harmonic drowned in noise cannot be a candidate for the pair either.
    let mut noisy_pair = samples(&s, 0.0)[..3].to_vec();
    noisy_pair[2].sigma = noisy_pair[2].value.norm();
    assert_eq!(
        run(&noisy_pair, &options),
        Err(InversionError::NoUsablePair)
    );
}
