//! The commands (`serve`, `analyse`, `record-signal`, `replay`, `fm-invert`, `paper`, `info`, `presets`, `bench`, `scan`, `soak`, `stalls`), one
//! file each, and what they share; `main.rs` only parses the command line and dispatches.

pub mod analyse;
pub mod bench;
pub mod fm_invert;
pub mod info;
pub mod paper;
pub mod presets;
pub mod replay;
pub mod scan;
pub mod serve;
pub mod soak;
pub mod stalls;

use std::path::PathBuf;
use std::process::ExitCode;

use crate::config::{self, Settings};

/// The configuration flags of the commands that read a configuration; they go before the
/// command, after it, or both (those before first).
#[derive(clap::Args, Default)]
pub struct ConfigArg {
    /// A real cantilever or sample (`ftafm presets` lists them) overlaid on the embedded
    /// default, in the order given, before --config; e.g. --preset tap300 --preset mica.
    #[arg(long, value_name = "NAME")]
    pub preset: Vec<String>,
    /// TOML file overlaid on the embedded default configuration (after the presets).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

impl ConfigArg {
    /// Whether neither flag was given.
    pub fn is_empty(&self) -> bool {
        self.preset.is_empty() && self.config.is_none()
    }

    /// These flags followed by `later`'s: the presets of both in order; one --config at most.
    pub fn then(self, later: ConfigArg) -> Result<ConfigArg, String> {
        if self.config.is_some() && later.config.is_some() {
            return Err(
                "--config is given twice (before and after the command): give one file".to_owned(),
            );
        }
        let mut preset = self.preset;
        preset.extend(later.preset);
        Ok(ConfigArg {
            preset,
            config: self.config.or(later.config),
        })
    }
}

/// Restores SIGPIPE's default action, so a command whose reader has gone (`ftafm info |
/// head -1`) ends by the signal, quietly, as Unix tools do, instead of panicking in
/// `println!` on the error Rust's ignored SIGPIPE turns it into. Not for the daemon.
pub fn restore_sigpipe() {
    // SAFETY: called at start-up, before any thread is spawned; SIG_DFL is a valid
    // disposition for SIGPIPE and no handler of ours is replaced.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
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
