//! Cut-cosine coefficients, the photodiode spectrum and Fig. 3 of the paper.

use std::f64::consts::PI;

use ftafm::physics::spectrum::{
    cut_cosine_coefficient, cut_cosine_train, photodiode_spectrum, photodiode_transfer,
    relative_contrast,
};
use ftafm::physics::{Cantilever, Elastic, Harmonic, HertzContact, ImpactOscillator};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;

/// Two-sided coefficients of a sampled cut cosine (N = 2^16 samples) by FFT.
fn fft_of_cut_cosine(force: f64, tau: f64, centre: f64) -> Vec<Complex64> {
    let n = 1 << 16;
    let mut buf: Vec<Complex64> = (0..n)
        .map(|j| {
            let s = 2.0 * PI * j as f64 / n as f64;
            // Distance in phase from the pulse centre, wrapped to (−π, π].
            let d = (s - centre + PI).rem_euclid(2.0 * PI) - PI;
            let half_width = PI * tau;
            let v = if d.abs() < half_width {
                force * (d / (2.0 * tau)).cos()
            } else {
                0.0
            };
            Complex64::new(v, 0.0)
        })
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    buf.iter().map(|c| c / n as f64).collect()
}

#[test]
fn cut_cosine_coefficients_match_an_fft_of_the_cut_cosine() {
    for (tau, centre) in [(0.0518, 0.0), (0.0526, 2.1), (0.125, 5.0), (0.3, 1.0)] {
        let fft = fft_of_cut_cosine(66e-9, tau, centre);
        let analytic = cut_cosine_train(66e-9, tau, centre, 40);
        for k in 0..=40 {
            // The sampled pulse's edges cost O(1/N²) of c_0.
            let err = (fft[k] - analytic[k]).norm() / analytic[0].norm();
            assert!(err < 1e-7, "tau {tau} k {k}: {} vs {}", fft[k], analytic[k]);
        }
    }
}

#[test]
fn cut_cosine_has_a_finite_limit_where_2_tau_k_is_one() {
    // τ = 0.125, k = 4: the formula is 0/0; the limit is Fτ/2.
    let at = cut_cosine_coefficient(1.0, 0.125, 4);
    assert!((at - 0.0625).abs() < 1e-15, "{at}");
    // Continuous through the limit from both sides.
    for d in [1e-3, 1e-5, 1e-7, 1e-9] {
        for tau in [0.125 - d, 0.125 + d] {
            let v = cut_cosine_coefficient(1.0, tau, 4);
            assert!((v - tau / 2.0).abs() < 3.0 * d, "tau {tau}: {v}");
            assert!(v.is_finite());
        }
    }
}

fn paper_spectra() -> (Vec<Harmonic>, Vec<Harmonic>) {
    let beam = Cantilever::new(100e3, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap();
    let si = Elastic {
        youngs_modulus: 129e9,
        poisson: 0.28,
    };
    let spectrum = |modulus: f64| {
        let sample = Elastic {
            youngs_modulus: modulus,
            poisson: 0.28,
        };
        let osc = ImpactOscillator {
            k: 20.0,
            f1: 100e3,
            q: 100.0,
            drive_frequency: 100e3,
            free_amplitude: 30e-9,
            surface_distance: 20e-9,
            contact: HertzContact::new(si, sample, 10e-9),
        };
        let s = osc.solve().unwrap();
        let force = cut_cosine_train(s.max_force, s.contact_time_ratio, s.pulse_phase, 32);
        photodiode_spectrum(&beam, 100e3, &force)
    };
    (spectrum(129e9), spectrum(116.1e9))
}

#[test]
fn figure_3_amplitudes_and_contrast() {
    let (si, inh) = paper_spectra();
    let c = relative_contrast(&si, &inh);
    let nm = |h: &Harmonic| h.amplitude * 1e9;
    // "the theoretical signal amplitude is equivalent to a static deflection of 0.19 nm"
    assert!(
        (0.185..0.195).contains(&nm(&si[6])),
        "H6 = {} nm",
        nm(&si[6])
    );
    // "c_rel ... is 0.3 %": silicon gives the larger signal, so c_rel is negative.
    assert!((0.0025..0.0035).contains(&-c[6]), "c6 = {}", c[6]);
    // "harmonics 17 and 18 ... about 0.025 nm ... c_rel = 3 %"
    for k in [17, 18] {
        assert!(
            (0.022..0.028).contains(&nm(&si[k])),
            "H{k} = {} nm",
            nm(&si[k])
        );
        assert!((0.025..0.035).contains(&-c[k]), "c{k} = {}", c[k]);
    }
    // "the relative contrast increases with increasing frequency"
    for k in 1..20 {
        assert!(
            c[k + 1].abs() > c[k].abs(),
            "|c| not growing at {k}: {} {}",
            c[k],
            c[k + 1]
        );
    }
    // Mode 2 enhances H6 and the light-lever zero near 2.81 f1 suppresses H3.
    assert!(si[6].amplitude > 4.0 * si[5].amplitude && si[6].amplitude > 3.0 * si[7].amplitude);
    assert!(si[3].amplitude < si[2].amplitude / 5.0 && si[3].amplitude < si[4].amplitude / 5.0);
}

#[test]
fn spectrum_mean_and_fundamental_follow_from_the_transfer_function() {
    let (si, _) = paper_spectra();
    // Harmonic 0: the mean force over the static light-lever response, just under c0/k.
    assert!(
        (1.0e-10..1.2e-10).contains(&si[0].amplitude),
        "H0 {}",
        si[0].amplitude
    );
    // Harmonic 1: mode 1 at resonance amplifies by Q = 100; ≈ 19 nm (the dashboard's H1 readout).
    assert!(
        (18.5e-9..20e-9).contains(&si[1].amplitude),
        "H1 {}",
        si[1].amplitude
    );
}

#[test]
fn photodiode_transfer_single_mode_by_hand() {
    // One mode: (2/3)·Lφ′(L)·φ(L)/K1 / (1 − β² + 2iγβ), evaluated independently.
    let beam = Cantilever::new(100e3, 20.0, &[100.0], 0).unwrap();
    let m = &beam.modes[0];
    for beta in [0.0, 0.5, 1.0, 2.0, 6.0] {
        let t = photodiode_transfer(&beam, beta * m.omega);
        let expected = (2.0 / 3.0) * (-2.7530) * (-2.0)
            / (20.0 * 1.875_104_069_f64.powi(4) / 3.0)
            / Complex64::new(1.0 - beta * beta, 2.0 * 0.005 * beta);
        // physics.md gives L·φ1′(L) to 4 decimals: 2e-5 relative.
        assert!(
            (t - expected).norm() / expected.norm() < 3e-5,
            "beta {beta}: {t} vs {expected}"
        );
    }
}
