//! How long the force estimator takes to build with each engine, adhesion off and on (its
//! modulus table), and on the coupled engine seeded from the previous build after a change
//! of the setpoint (a sweep's next point): `cargo run --release --example estimator_build`.
use std::time::Instant;

use ftafm::config::{Engine, default_settings};
use ftafm::inversion::ForceEstimator;

fn main() {
    for engine in [Engine::Paper, Engine::Coupled] {
        for adhesion in [false, true] {
            let mut settings = default_settings();
            settings.synth.engine = engine;
            settings.adhesion.enable = adhesion;
            let t = Instant::now();
            let built = ForceEstimator::new(&settings);
            println!(
                "{engine:?}, adhesion {adhesion}: {:.3} s ({})",
                t.elapsed().as_secs_f64(),
                if matches!(built, Ok(Some(_))) {
                    "built"
                } else {
                    "failed"
                }
            );
        }
    }
    let mut settings = default_settings();
    settings.synth.engine = Engine::Coupled;
    let mut previous = ForceEstimator::new(&settings).unwrap().unwrap();
    for distance in [19e-9, 18e-9, 14e-9, 22e-9] {
        settings.surface.distance = distance;
        let t = Instant::now();
        let next = ForceEstimator::seeded(&settings, previous.seed())
            .unwrap()
            .unwrap();
        println!(
            "coupled, A_set {:.0} nm seeded from the previous build: {:.3} s",
            distance * 1e9,
            t.elapsed().as_secs_f64()
        );
        previous = next;
    }
}
