//! Bimodal AM-FM maps: a scan of the default sample (silicon with a softer disc) with the
//! second excitation on and mode 2's PLL and amplitude loop running beside the scan's
//! amplitude feedback. Each pixel carries mode 2's frequency over it; the image's
//! `frequency_shift2`, `indentation` and `bimodal_modulus` channels come from it and from
//! mode 1's pixel phasor by the bimodal expressions, and the disc shows in them with the
//! contrast the configured moduli give, measured as `ftafm scan` measures every channel.

mod common;

use common::bimodal::{f2_of, mode_two_amplitude, mode_two_pll, second_reading};
use ftafm::cli::scan::{ChannelReport, ScanReport};
use ftafm::config::Settings;

/// The example `config/examples/bimodal_map.toml` on tap300 (the lever matched to a stiff
/// sample) over the default sample, noise off: 16 × 16 pixels of 1 ms; mode 2 driven at
/// 0.05 nm at its free resonance under a 1 kHz PLL (its input filter 8 kHz wide) and a
/// 500 Hz amplitude loop. Its gains and set-points are the derivation's
/// ([`mode_two_pll`], [`mode_two_amplitude`]) to the digits the file gives.
fn bimodal_scan() -> Settings {
    let example = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/examples/bimodal_map.toml"
    );
    let mut s =
        ftafm::config::load_with_presets(&["tap300".to_owned()], Some(example.as_ref())).unwrap();
    s.noise.enable = false;
    let f2 = f2_of(&s);
    assert!((s.drive2.frequency / f2 - 1.0).abs() < 1e-6);
    let a2 = s.drive2.free_amplitude;
    let free2 = second_reading(&s, f2, a2);
    let mut derived = s.clone();
    mode_two_pll(&mut derived, 0, free2.arg(), 1000.0);
    mode_two_amplitude(&mut derived, 1, free2.norm(), free2.norm() / a2, 500.0);
    for (file, want) in s.pids[..2].iter().zip(&derived.pids[..2]) {
        let close = |a: f64, b: f64, tolerance: f64| (a - b).abs() <= tolerance * b.abs();
        assert!(
            close(file.p, want.p, 1e-4) && close(file.i, want.i, 1e-4),
            "{file:?}"
        );
        assert!(close(file.output_min, want.output_min, 1e-6), "{file:?}");
        assert!(close(file.output_max, want.output_max, 1e-6), "{file:?}");
        assert!((file.setpoint - want.setpoint).abs() <= 1e-3 * want.setpoint.abs().max(1e-3));
    }
    s
}

fn channel<'a>(report: &'a ScanReport, name: &str) -> &'a ChannelReport {
    report
        .channels
        .iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no channel {name} in the image"))
}

/// The configured reduced modulus of the tip on a sample of `youngs_modulus` (Pa).
fn reduced(s: &Settings, youngs_modulus: f64) -> f64 {
    let (t, nu) = (&s.tip, s.sample.poisson);
    1.0 / ((1.0 - t.poisson * t.poisson) / t.youngs_modulus + (1.0 - nu * nu) / youngs_modulus)
}

/// Two frames (the second's channels measured: the loops locked in the first line of the
/// first), every pixel's Δf₂ and bimodal estimate; the modulus per material within 15 % of
/// the configured E* (the expressions' own accuracy on a stiff sample, docs/loops.md),
/// the disc's contrast within a quarter of the configured one, far above the pixels'
/// scatter.
#[test]
fn a_bimodal_map_shows_the_softer_disc() {
    let s = bimodal_scan();
    let report = ftafm::cli::scan::run(&s, 2, None, |_| {}).expect("the scan records");
    let counters = &report.counters;
    assert_eq!(counters.overrun_samples, 0);
    assert_eq!(counters.discontinuities, 0);
    for name in ["frequency_shift2", "indentation", "bimodal_modulus"] {
        let c = channel(&report, name);
        let r = &c.regions[0];
        eprintln!(
            "{name} ({}): silicon {:.5e} ± {:.2e} over {} pixels, disc {:.5e} ± {:.2e} over {} \
             pixels, contrast {:+.2} %, CNR {:.1}",
            c.unit,
            c.base_mean,
            c.base_std,
            c.base_pixels,
            r.mean,
            r.std,
            r.pixels,
            100.0 * r.contrast,
            r.cnr
        );
    }
    let shift = channel(&report, "frequency_shift2");
    let modulus = channel(&report, "bimodal_modulus");
    let indentation = channel(&report, "indentation");
    let disc = s
        .inclusions
        .iter()
        .find(|i| i.enable)
        .unwrap()
        .youngs_modulus;
    // The contact stiffens mode 2 on either material, less on the softer disc.
    assert!(shift.base_mean > 0.0 && shift.regions[0].mean > 0.0);
    assert!(shift.regions[0].mean < shift.base_mean);
    assert!(indentation.regions[0].mean > indentation.base_mean);
    // The sample's modulus per material within the expressions' accuracy on this lever,
    // and the disc's contrast the configured moduli's.
    for (read, truth) in [
        (modulus.base_mean, s.sample.youngs_modulus),
        (modulus.regions[0].mean, disc),
    ] {
        let error = reduced(&s, read) / reduced(&s, truth) - 1.0;
        assert!(
            error.abs() < 0.15,
            "E* {read:.4e} for {truth:.4e}: {:+.1} %",
            100.0 * error
        );
    }
    let want = 1.0 - s.sample.youngs_modulus / disc;
    let got = modulus.regions[0].contrast;
    assert!(
        (got - want).abs() < 0.25 * want.abs(),
        "contrast {:+.2} % against the configured {:+.2} %",
        100.0 * got,
        100.0 * want
    );
    assert!(modulus.regions[0].cnr > 5.0);
}
