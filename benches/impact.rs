//! The 1-DOF periodic solve: re-run whenever a user changes the sample or the setpoint, so
//! it must be fast (goal: under 5 ms for the default case).

use criterion::{Criterion, criterion_group, criterion_main};
use ftafm::physics::{Elastic, HertzContact, ImpactOscillator};

fn paper_case(modulus: f64) -> ImpactOscillator {
    let si = Elastic {
        youngs_modulus: 129e9,
        poisson: 0.28,
    };
    let sample = Elastic {
        youngs_modulus: modulus,
        poisson: 0.28,
    };
    ImpactOscillator {
        k: 20.0,
        f1: 100e3,
        q: 100.0,
        drive_frequency: 100e3,
        free_amplitude: 30e-9,
        surface_distance: 20e-9,
        contact: HertzContact::new(si, sample, 10e-9),
    }
}

fn solve(c: &mut Criterion) {
    let mut group = c.benchmark_group("impact_solve");
    for (name, modulus) in [
        ("silicon_129GPa", 129e9),
        ("inhomogeneity_116GPa", 116.1e9),
        ("polymer_2GPa", 2e9),
    ] {
        let osc = paper_case(modulus);
        group.bench_function(name, |b| b.iter(|| osc.solve().expect("converges")));
    }
    group.finish();
}

criterion_group!(benches, solve);
criterion_main!(benches);
