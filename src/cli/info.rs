//! `ftafm info`: the configured instrument.

use std::process::ExitCode;

use super::{ConfigArg, load};

pub fn command(config: &ConfigArg) -> Result<ExitCode, ExitCode> {
    let settings = load(config)?;
    let report = super::paper::compute(&settings, 1.0).map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    let m = &report.materials[0];
    println!(
        "ftafm {}: {} modes, f1 = {} kHz, k = {} N/m, sample E = {} GPa",
        env!("CARGO_PKG_VERSION"),
        report.modes.len(),
        settings.cantilever.f1 / 1e3,
        settings.cantilever.k,
        settings.sample.youngs_modulus / 1e9
    );
    println!(
        "{:>4}  {:>12}  {:>8}  {:>12}  {:>9}",
        "mode", "f (kHz)", "Q", "K_n (N/m)", "L·φ'(L)"
    );
    for mode in &report.modes {
        println!(
            "{:>4}  {:>12.3}  {:>8.1}  {:>12.4e}  {:>9.4}",
            mode.n,
            mode.frequency / 1e3,
            mode.q,
            mode.stiffness,
            mode.tip_slope
        );
    }
    println!(
        "drive {} kHz{}, sample rate {} MS/s",
        settings.drive.frequency / 1e3,
        if settings.drive.follow_f1 {
            " (follows f1)"
        } else {
            ""
        },
        settings.synth.sample_rate / 1e6
    );
    for warning in settings
        .warnings()
        .into_iter()
        .chain(crate::model::range_warnings(&settings))
    {
        println!("warning: {warning}");
    }
    println!(
        "tapping at A_free = {:.1} nm, A_set = {:.1} nm: F = {:.2} nN, tau = {:.4}, theta = {:.2} deg",
        settings.drive.free_amplitude * 1e9,
        settings.surface.distance * 1e9,
        m.max_force * 1e9,
        m.contact_time_ratio,
        m.phase_shift_deg
    );
    println!("`ftafm serve` runs this instrument live; `ftafm paper` prints the full report");
    Ok(ExitCode::SUCCESS)
}
