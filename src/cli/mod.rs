//! The commands (`serve`, `paper`, `info`, `presets`, `bench`, `scan`, `soak`, `stalls`), one
//! file each, and what they share; `main.rs` only parses the command line and dispatches.

pub mod bench;
pub mod info;
pub mod paper;
pub mod presets;
pub mod scan;
pub mod serve;
pub mod soak;
pub mod stalls;

use std::path::PathBuf;
use std::process::ExitCode;

use crate::config::{self, Settings};

/// The configuration flags every command shares.
#[derive(clap::Args)]
pub struct ConfigArg {
    /// A real cantilever or sample (`ftafm presets` lists them) overlaid on the embedded
    /// default, in the order given, before --config; e.g. --preset tap300 --preset mica.
    #[arg(long, value_name = "NAME")]
    pub preset: Vec<String>,
    /// TOML file overlaid on the embedded default configuration (after the presets).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

/// Exit status for bad arguments or an invalid configuration (README.md, "Exit status").
pub const EXIT_USAGE: u8 = 2;

/// The settings the flags name: the embedded default, the presets, then the file; the
/// schema's checks, then whether the model can run them ([`crate::model::check`], bounded
/// in time, so a bad file is refused at once rather than worked on).
pub fn load(args: &ConfigArg) -> Result<Settings, ExitCode> {
    let usage = |e: &dyn std::fmt::Display| {
        eprintln!("ftafm: invalid configuration: {e}");
        ExitCode::from(EXIT_USAGE)
    };
    let settings =
        config::load_with_presets(&args.preset, args.config.as_deref()).map_err(|e| usage(&e))?;
    crate::model::check(&settings).map_err(|e| {
        let origin = args.config.as_deref().map_or_else(
            || "the configuration".to_owned(),
            |p| p.display().to_string(),
        );
        usage(&format!("{origin}: {e}"))
    })?;
    Ok(settings)
}

/// A command's report: one JSON object with `--json`, else its text form.
pub fn print_report<R: serde::Serialize>(json: bool, report: &R, text: impl FnOnce(&R) -> String) {
    if json {
        println!("{}", serde_json::to_string(report).expect("plain numbers"));
    } else {
        print!("{}", text(report));
    }
}
