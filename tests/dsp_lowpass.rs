//! The lock-in low-pass filter against its analytic step response and noise bandwidth.

use ftafm::dsp::{LowPass, LowPassState, MAX_ORDER};

/// Deterministic white Gaussian noise (xorshift64* and Box–Muller), unit variance.
struct Noise {
    state: u64,
    spare: Option<f64>,
}

impl Noise {
    fn new(seed: u64) -> Self {
        Self {
            state: seed | 1,
            spare: None,
        }
    }

    fn uniform(&mut self) -> f64 {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        let x = self.state.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn gaussian(&mut self) -> f64 {
        if let Some(x) = self.spare.take() {
            return x;
        }
        let r = (-2.0 * self.uniform().ln()).sqrt();
        let (s, c) = (std::f64::consts::TAU * self.uniform()).sin_cos();
        self.spare = Some(r * s);
        r * c
    }
}

#[test]
fn step_response_of_every_order_matches_n_cascaded_rc_sections() {
    // T/τ = 10⁻³: the discretisation error is O((T/τ)²) once the half-sample lead of each
    // section after the first is accounted for (see `LowPass`).
    let fs = 1e6;
    let tau = 1e-3;
    for n in 1..=MAX_ORDER {
        let lp = LowPass::new(n, tau, fs).unwrap();
        let mut state = LowPassState::default();
        let mut worst: f64 = 0.0;
        let samples = (40.0 * n as f64 * tau * fs) as usize;
        for m in 0..samples {
            let y = lp.step(&mut state, 1.0);
            let t = (m as f64 + 1.0 + (n as f64 - 1.0) / 2.0) / fs;
            worst = worst.max((y - lp.step_response(t)).abs());
        }
        println!("order {n}: worst |y − S(t)| = {worst:.2e}");
        assert!(worst < 2e-6, "order {n}: {worst:e}");
        // And it settles to 1.
        assert!((lp.step(&mut state, 1.0) - 1.0).abs() < 1e-12);
    }
}

#[test]
fn analytic_step_response_formula() {
    // n = 1 and n = 2 by hand.
    let lp1 = LowPass::new(1, 2.0, 1.0).unwrap();
    assert!((lp1.step_response(2.0) - (1.0 - (-1.0f64).exp())).abs() < 1e-15);
    let lp2 = LowPass::new(2, 2.0, 1.0).unwrap();
    assert!((lp2.step_response(2.0) - (1.0 - 2.0 * (-1.0f64).exp())).abs() < 1e-15);
    assert_eq!(lp2.step_response(-1.0), 0.0);
}

#[test]
fn enbw_formula_matches_numerical_integration() {
    // ∫₀^∞ (1 + (2πfτ)²)^{−n} df by the substitution 2πfτ = tan θ, which makes the
    // integrand cos^{2n−2} θ / (2πτ) on [0, π/2): smooth, so Simpson converges fast.
    let tau = 3e-4;
    for n in 1..=MAX_ORDER {
        let steps = 2000;
        let h = std::f64::consts::FRAC_PI_2 / steps as f64;
        let f = |theta: f64| theta.cos().powi(2 * n as i32 - 2) / (std::f64::consts::TAU * tau);
        let mut sum = f(0.0) + f(std::f64::consts::FRAC_PI_2);
        for i in 1..steps {
            sum += f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        let numeric = sum * h / 3.0;
        let lp = LowPass::new(n, tau, 1e6).unwrap();
        assert!(
            (lp.enbw() / numeric - 1.0).abs() < 1e-10,
            "order {n}: {} vs {numeric}",
            lp.enbw()
        );
    }
    // n = 1 is the textbook 1/(4τ).
    assert!((LowPass::new(1, tau, 1e6).unwrap().enbw() - 1.0 / (4.0 * tau)).abs() < 1e-9);
}

#[test]
fn impulse_response_energy_gives_the_analytic_enbw() {
    // Deterministic version of the noise test: Σ h² · f_s/2 is the discrete filter's
    // one-sided ENBW.
    let fs = 1e6;
    let tau = 1e-4; // T/τ = 10⁻²
    for n in 1..=MAX_ORDER {
        let lp = LowPass::new(n, tau, fs).unwrap();
        let mut state = LowPassState::default();
        let mut energy = lp.step(&mut state, 1.0).powi(2);
        for _ in 0..(200.0 * n as f64 * tau * fs) as usize {
            energy += lp.step(&mut state, 0.0).powi(2);
        }
        let enbw = energy * fs / 2.0;
        let rel = enbw / lp.enbw() - 1.0;
        println!("order {n}: discrete ENBW / analytic − 1 = {rel:.2e}");
        assert!(rel.abs() < 1e-4, "order {n}: {rel:e}");
    }
}

#[test]
fn white_noise_output_variance_gives_the_analytic_enbw() {
    // Real white noise of variance σ² at f_s has one-sided density 2σ²/f_s, so the output
    // variance is 2σ²·ENBW/f_s.
    let fs = 1e6;
    let tau = 1e-4;
    let samples = 10_000_000;
    let mut noise = Noise::new(0x5EED_0001);
    let mut input = vec![0.0; samples];
    let mut output = vec![0.0; samples];
    for n in 1..=MAX_ORDER {
        input.iter_mut().for_each(|x| *x = noise.gaussian());
        let lp = LowPass::new(n, tau, fs).unwrap();
        let mut state = LowPassState::default();
        lp.process(&mut state, &input, &mut output);
        let settle = (20.0 * n as f64 * tau * fs) as usize;
        let tail = &output[settle..];
        let mean = tail.iter().sum::<f64>() / tail.len() as f64;
        let var = tail.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / tail.len() as f64;
        let measured = var * fs / 2.0;
        let rel = measured / lp.enbw() - 1.0;
        println!(
            "order {n}: measured ENBW {measured:.2} Hz, analytic {:.2} Hz ({rel:+.2e})",
            lp.enbw()
        );
        // A few 10⁴ independent output samples: about 1 % standard error.
        assert!(rel.abs() < 0.05, "order {n}: {rel:e}");
    }
}
