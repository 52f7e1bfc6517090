//! What the thermal motion does to the mean of the harmonics, and so to the modulus the
//! force inversion reads: the noise-free stream against the same stream with the thermal
//! force on and the detector's noise and the ADC's rounding off, each demodulated over
//! whole drive periods (as the lock-in's reference does, with its time constant → ∞).
//!
//! `cargo run --release --example thermal_jitter -- [SECONDS] [coupled|paper] [KELVIN]`
//! (default 1 s, the coupled engine, the default 300 K; default settings otherwise). Prints, for two seeds,
//! the relative change of H1, H6, H17, H18 and the equivalent rms jitter of the tap against
//! the drive (1 − |⟨e^{ikφ}⟩| ≈ k²σ²/2 for a small jitter φ of any distribution), and the
//! modulus the estimator reads off the averaged harmonics.

use std::f64::consts::PI;

use ftafm::config::{Engine, Settings, default_settings};
use ftafm::inversion::ForceEstimator;
use ftafm::pipeline::{DemodFrame, DemodValue};
use ftafm::synth::{SynthPlan, SynthState};
use rustfft::num_complex::Complex64;

/// X + iY of H1–H32 over `seconds` of whole drive periods of `settings`' stream (seed
/// `seed`), at the drive phase at which the ADC took each sample.
fn readings(settings: &Settings, seconds: f64, seed: u64) -> Vec<Complex64> {
    let plan = SynthPlan::new(settings).expect("a valid plan");
    let mut state = SynthState::steady(&plan, seed);
    let per_period = plan.sample_rate / plan.drive_frequency;
    let n = (per_period * (seconds * plan.drive_frequency).round()).round() as usize;
    let turn = 2f64.powi(64);
    let angle = |word: u64| -(word as f64) / turn * 2.0 * PI;
    let step: Vec<Complex64> = (0..=32u64)
        .map(|k| Complex64::from_polar(1.0, angle(plan.frequency_word.wrapping_mul(k))))
        .collect();
    let start = plan.output_phase(state.phase());
    let mut sums = vec![Complex64::new(0.0, 0.0); 33];
    let mut block = vec![0.0; 1 << 16];
    let mut done = 0usize;
    while done < n {
        let len = block.len().min(n - done);
        plan.process(&mut state, &mut block[..len]);
        let first = start.wrapping_add(plan.frequency_word.wrapping_mul(done as u64));
        for k in 1..=32u64 {
            // Re-anchored every block, so the rotation's rounding does not build up.
            let mut r = Complex64::from_polar(1.0, angle(first.wrapping_mul(k)));
            let mut acc = Complex64::new(0.0, 0.0);
            for &x in &block[..len] {
                acc += x * r;
                r *= step[k as usize];
            }
            sums[k as usize] += acc;
        }
        done += len;
    }
    sums[1..].iter().map(|s| s * (2.0 / n as f64)).collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let seconds: f64 = args.first().and_then(|a| a.parse().ok()).unwrap_or(1.0);
    let mut settings = default_settings();
    settings.synth.engine = match args.get(1).map(String::as_str) {
        None | Some("coupled") => Engine::Coupled,
        Some("paper") => Engine::Paper,
        Some(other) => {
            eprintln!("the engine is coupled or paper, not {other}");
            std::process::exit(2);
        }
    };
    if let Some(kelvin) = args.get(2) {
        settings.noise.temperature = kelvin.parse().unwrap_or_else(|_| {
            eprintln!("KELVIN must be a number, not {kelvin}");
            std::process::exit(2);
        });
    }
    let estimator = ForceEstimator::new(&settings)
        .expect("a valid estimator")
        .expect("the inversion is on by default");
    let modulus = |z: &[Complex64]| {
        let mut frame = DemodFrame {
            sample_index: 0,
            t: 0.0,
            t_synth_ns: 0,
            t_dsp_ns: 0,
            len: z.len(),
            values: [DemodValue::default(); 32],
            pids: Default::default(),
        };
        for (i, z) in z.iter().enumerate() {
            frame.values[i] = DemodValue {
                index: i as u8,
                harmonic: i as u32 + 1,
                oscillator: Default::default(),
                x: z.re,
                y: z.im,
            };
        }
        // A vanishing bandwidth: these are means, with no fit bias to take out.
        estimator
            .estimate_frame(&frame, 1e-9)
            .map(|e| e.youngs_modulus)
            .unwrap_or(f64::NAN)
    };
    let mut quiet = settings.clone();
    quiet.noise.enable = false;
    let exact = readings(&quiet, 200.0 / settings.drive.frequency, 1);
    let mut thermal = settings.clone();
    thermal.noise.detector_density = 0.0;
    thermal.noise.adc_bits = 32;
    println!(
        "{:?} engine, E set {:.1} GPa, {} K, {seconds} s per seed; noise-free stream reads E = {:.3} GPa",
        settings.synth.engine,
        settings.sample.youngs_modulus / 1e9,
        settings.noise.temperature,
        modulus(&exact) / 1e9
    );
    for seed in [1u64, 2] {
        let z = readings(&thermal, seconds, seed);
        for k in [1usize, 6, 17, 18] {
            let change = z[k - 1].norm() / exact[k - 1].norm() - 1.0;
            let jitter = (-2.0 * change).max(0.0).sqrt() / k as f64;
            println!(
                "seed {seed} H{k:>2}: {:+.4} % (as a jitter: {:.2} mrad rms)",
                100.0 * change,
                1e3 * jitter
            );
        }
        println!(
            "seed {seed}: thermal force on, E read {:.3} GPa",
            modulus(&z) / 1e9
        );
    }
}
