//! `ftafm presets`: the presets, with their sources.

use std::process::ExitCode;

use crate::config;

pub fn command(json: bool) -> Result<ExitCode, ExitCode> {
    if json {
        println!(
            "{}",
            serde_json::to_string(&config::PRESETS).expect("plain strings")
        );
        return Ok(ExitCode::SUCCESS);
    }
    for kind in [config::PresetKind::Cantilever, config::PresetKind::Sample] {
        println!(
            "{}:",
            match kind {
                config::PresetKind::Cantilever => "cantilevers ([cantilever])",
                config::PresetKind::Sample => "samples ([sample]; inclusions follow)",
            }
        );
        for p in config::PRESETS.iter().filter(|p| p.kind == kind) {
            println!("  {:<14} {}", p.name, p.summary());
        }
    }
    println!("use: ftafm --preset tap300 --preset polystyrene; sources: config/presets/NAME.toml");
    Ok(ExitCode::SUCCESS)
}
