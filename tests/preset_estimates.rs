//! Every lever preset with every sample preset, at its defaults: whether the live force
//! estimator's modulus is within 3 of its own σ of the set modulus, or the estimate carries
//! a warning (or a table-range flag) that says why not:
//! `cargo test --release --test preset_estimates -- --nocapture` prints every point.
//!
//! What it does: per combination, loads the presets as `--preset LEVER --preset SAMPLE`
//! does, builds the daemon's [`ForceEstimator`] (coupled engine, its modulus table), solves
//! the coupled orbit at the set modulus as the live engine reaches it (an approach from
//! far), reads every active demodulator off it through the estimator's own lock-in model
//! (the anti-alias filter and aliases), adds Gaussian noise of the predicted σ of one live
//! estimate (seeded; the presets average one frame), and estimates from that reading. With
//! `FTAFM_PRESET_AVERAGED=1`, where that estimate fails and the estimator says one frame is
//! noise-limited, the point is tried again at `/inversion/averaging` = 100 (0.1 s), for the
//! figures docs/ft-afm.md quotes. The 24 points run on two threads.
//!
//! What it does not cover: the synthesiser and the DSP chain themselves (the readings are
//! the model's, not a demodulated photodiode stream: `tests/physics_inversion.rs` checks
//! that they agree, and `tests/pipeline.rs` runs the chain), H1's drive response (the
//! estimator leaves H1 out), the paper engine, adhesion and a scan. The Hertz contact is far outside its small-strain range on PDMS; the estimate is
//! of the model as simulated (`status` says so for the settings).

use std::sync::Mutex;

use ftafm::config::{PRESETS, PresetKind, load_with_presets};
use ftafm::inversion::ForceEstimator;
use ftafm::physics::inversion::{ALIAS_HARMONICS, TableRange};
use ftafm::pipeline::{DemodFrame, DemodValue};
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rand_xoshiro::rand_core::SeedableRng;
use rustfft::num_complex::Complex64;

/// `/inversion/averaging` of the second try where one frame is noise-limited: 0.1 s.
const AVERAGED: u32 = 100;

/// What one lever × sample gave.
struct Outcome {
    names: String,
    set: f64,
    estimate: Result<(f64, f64, TableRange), String>,
    warnings: Vec<String>,
}

fn point(lever: &str, sample: &str, seed: u64, averaging: Option<u32>) -> Outcome {
    let names = match averaging {
        Some(n) => format!("{lever} + {sample}, averaging {n}"),
        None => format!("{lever} + {sample}"),
    };
    let mut settings = load_with_presets(&[lever.to_owned(), sample.to_owned()], None).unwrap();
    if let Some(n) = averaging {
        settings.inversion.averaging = n;
    }
    let set = settings.sample.youngs_modulus;
    let failed = |why: String, warnings: Vec<String>| Outcome {
        names: names.clone(),
        set,
        estimate: Err(why),
        warnings,
    };
    let estimator = match ForceEstimator::new(&settings) {
        Ok(Some(e)) => e,
        Ok(None) => return failed("the inversion is off".into(), settings.force_warnings()),
        Err(why) => return failed(why, settings.force_warnings()),
    };
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let problem = ftafm::model::coupled_problem(
        &settings,
        &cantilever,
        settings.sample,
        settings.drive.frequency,
    );
    let orbit = match problem.solve(ALIAS_HARMONICS) {
        Ok(orbit) => orbit,
        Err(e) => return failed(format!("no orbit: {e}"), estimator.warnings().to_vec()),
    };
    let c = &orbit.force_coefficients;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut frame = DemodFrame::empty();
    let mut bandwidth = 0.0;
    for (i, d) in settings.demods.iter().enumerate() {
        if !settings.demod_active(i) {
            continue;
        }
        bandwidth = estimator.estimate_bandwidth(i).unwrap();
        let read = estimator
            .lockin_model()
            .read(d.harmonic as usize, |j| {
                c.get(j).copied().unwrap_or_default()
            })
            .unwrap();
        let z: Complex64 = 2.0 * read;
        let sigma = estimator.phasor_sigma(d.harmonic, bandwidth);
        let (x, y): (f64, f64) = (
            StandardNormal.sample(&mut rng),
            StandardNormal.sample(&mut rng),
        );
        frame.values[frame.len] = DemodValue {
            index: i as u8,
            harmonic: d.harmonic,
            oscillator: d.oscillator,
            x: z.re + sigma * x,
            y: z.im + sigma * y,
        };
        frame.len += 1;
    }
    match estimator.estimate_frame(&frame, bandwidth) {
        Ok(r) => Outcome {
            names,
            set,
            estimate: Ok((r.youngs_modulus, r.youngs_modulus_sigma, r.table_range)),
            warnings: r.warnings,
        },
        Err(e) => failed(e.to_string(), estimator.warnings().to_vec()),
    }
}

#[test]
fn every_lever_preset_on_every_sample_preset_estimates_within_3_sigma_or_says_why_not() {
    let pick = |kind| {
        PRESETS
            .iter()
            .filter(move |p| p.kind == kind)
            .map(|p| p.name)
    };
    let mut todo: Vec<(&str, &str, u64)> = Vec::new();
    for lever in pick(PresetKind::Cantilever) {
        for sample in pick(PresetKind::Sample) {
            todo.push((lever, sample, todo.len() as u64 + 1));
        }
    }
    let averaged_too = std::env::var_os("FTAFM_PRESET_AVERAGED").is_some();
    let todo = Mutex::new(todo);
    let outcomes = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                while let Some((lever, sample, seed)) = todo.lock().unwrap().pop() {
                    let outcome = point(lever, sample, seed, None);
                    // Where one frame carries too little, what averaging brings: with
                    // FTAFM_PRESET_AVERAGED set (a figure for the docs, not the check: the
                    // point has already passed by its warning).
                    let retry = averaged_too
                        && outcome.estimate.is_err()
                        && outcome.warnings.iter().any(|w| w.contains("noise-limited"));
                    outcomes.lock().unwrap().push(outcome);
                    if retry {
                        let averaged = point(lever, sample, seed, Some(AVERAGED));
                        outcomes.lock().unwrap().push(averaged);
                    }
                }
            });
        }
    });
    let mut outcomes = outcomes.into_inner().unwrap();
    outcomes.sort_by(|a, b| a.names.cmp(&b.names));
    let mut bad = Vec::new();
    for o in &outcomes {
        let within = match &o.estimate {
            Ok((e, sigma, range)) => {
                eprintln!(
                    "{}: E {:.4e} ± {:.2e} Pa, set {:.4e} ({:+.2} σ, {range:?}); warnings {:?}",
                    o.names,
                    e,
                    sigma,
                    o.set,
                    (e - o.set) / sigma,
                    o.warnings
                );
                *range == TableRange::Inside
                    && sigma.is_finite()
                    && (e - o.set).abs() <= 3.0 * sigma
            }
            Err(why) => {
                eprintln!(
                    "{}: no estimate ({why}); warnings {:?}",
                    o.names, o.warnings
                );
                false
            }
        };
        let flagged = matches!(&o.estimate, Ok((_, _, range)) if *range != TableRange::Inside);
        if !within && o.warnings.is_empty() && !flagged {
            bad.push(o.names.clone());
        }
    }
    assert!(
        bad.is_empty(),
        "neither within 3 σ of the set modulus nor warned: {bad:?}"
    );
    // Not a vacuous pass: most points estimate within 3 σ.
    let within = outcomes
        .iter()
        .filter(|o| matches!(&o.estimate, Ok((e, s, TableRange::Inside)) if (e - o.set).abs() <= 3.0 * s))
        .count();
    assert!(
        within >= outcomes.len() / 2,
        "{within} of {} within 3 σ",
        outcomes.len()
    );
}
