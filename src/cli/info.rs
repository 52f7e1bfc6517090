//! `ftafm info`: the configured instrument, its numbers from the engine the daemon runs.

use std::process::ExitCode;

use super::{ConfigArg, load};
use crate::config::quantity::quantity_rounded as si;

pub fn command(config: &ConfigArg) -> Result<ExitCode, ExitCode> {
    let settings = load(config)?;
    let cantilever = crate::model::cantilever(&settings).map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    println!(
        "ftafm {}: {} modes, f1 = {}, k = {}, sample E = {}",
        env!("CARGO_PKG_VERSION"),
        cantilever.modes.len(),
        si(settings.cantilever.f1, "Hz", 6),
        si(settings.cantilever.k, "N/m", 4),
        si(settings.sample.youngs_modulus, "Pa", 4)
    );
    // k_tip = K_n/φ_n(L)²: the spring a point force at the tip sees (the k of FM-AFM's
    // and the bimodal expressions).
    println!(
        "{:>4}  {:>12}  {:>8}  {:>12}  {:>12}  {:>9}",
        "mode", "f", "Q", "K_n", "k_tip", "L·φ'(L)"
    );
    for mode in &cantilever.modes {
        println!(
            "{:>4}  {:>12}  {:>8.1}  {:>12}  {:>12}  {:>9.4}",
            mode.n,
            si(mode.frequency, "Hz", 6),
            mode.q,
            si(mode.stiffness, "N/m", 5),
            si(mode.tip_stiffness(), "N/m", 5),
            mode.tip_slope
        );
    }
    println!(
        "drive {}{}, sample rate {}",
        si(settings.drive.frequency, "Hz", 6),
        if settings.drive.follow_f1 {
            " (follows f1)"
        } else {
            ""
        },
        si(settings.synth.sample_rate, "S/s", 4)
    );
    for warning in settings
        .warnings()
        .into_iter()
        .chain(crate::model::range_warnings(&settings))
    {
        println!("warning: {warning}");
    }
    // The engine the daemon runs (/synth/engine); the other one's figures differ (`ftafm
    // paper` shows both).
    let engine = settings.synth.engine;
    let tapping = format!(
        "tapping at A_free = {}, A_set = {}",
        si(settings.drive.free_amplitude, "m", 4),
        si(settings.surface.distance, "m", 4)
    );
    match super::paper::sample_row(&settings, engine) {
        Ok(m) => println!(
            "{tapping}, by the {} engine (/synth/engine): F = {}, tau = {:.4}, theta = {:.2} deg",
            engine.name(),
            si(m.max_force, "N", 4),
            m.contact_time_ratio,
            m.phase_shift_deg
        ),
        Err(e) => println!(
            "{tapping}: the {} engine (/synth/engine) has no result: {e}",
            engine.name()
        ),
    }
    println!("`ftafm serve` runs this instrument live; `ftafm paper` prints the full report");
    Ok(ExitCode::SUCCESS)
}
