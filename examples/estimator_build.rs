//! How long the force estimator takes to build with each engine, adhesion off and on (its
//! modulus table): `cargo run --release --example estimator_build`.
use std::time::Instant;
fn main() {
    for engine in [ftafm::config::Engine::Paper, ftafm::config::Engine::Coupled] {
        for adhesion in [false, true] {
            let mut settings = ftafm::config::default_settings();
            settings.synth.engine = engine;
            settings.adhesion.enable = adhesion;
            let t = Instant::now();
            let e = ftafm::inversion::ForceEstimator::new(&settings);
            println!(
                "{engine:?} adhesion {adhesion}: {:.3} s ok {}",
                t.elapsed().as_secs_f64(),
                e.is_ok()
            );
        }
    }
}
