//! Presets: real cantilevers and samples from data sheets and handbooks
//! (`config/presets/*.toml`, each citing its source), compiled into the binary. A preset is
//! an overlay like any config file: `--preset tap300 --preset polystyrene` lays them over the
//! embedded default, in order, before `--config`.

use std::path::Path;

use super::error::ConfigError;
use super::load::{default_settings, overlay_str};
use super::settings::Settings;

/// What a preset sets up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PresetKind {
    /// A cantilever (`[cantilever]`): f1, k, Q, tip radius; with the sample rate
    /// (`[synth]`), tune (`[sweeper]`) and second excitation's frequency (`[drive2]`, its
    /// mode 2) that fit it.
    Cantilever,
    /// A sample material (`[sample]`); inclusions given relative to it follow it.
    Sample,
}

/// One preset: its name, what it sets up and its TOML (whose first comment line summarises
/// it and whose comments cite the source).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Preset {
    /// The name `--preset` takes.
    pub name: &'static str,
    /// Cantilever or sample.
    pub kind: PresetKind,
    /// The overlay, with its sources in comments.
    pub toml: &'static str,
}

impl Preset {
    /// The file's first line without its `# name:` prefix: "the most common tapping-mode
    /// lever, 300 kHz and 40 N/m."
    pub fn summary(&self) -> &'static str {
        let first = self.toml.lines().next().unwrap_or_default();
        let text = first.trim_start_matches('#').trim();
        text.split_once(": ").map_or(text, |(_, rest)| rest)
    }
}

macro_rules! preset {
    ($name:literal, $kind:ident) => {
        Preset {
            name: $name,
            kind: PresetKind::$kind,
            toml: include_str!(concat!("../../config/presets/", $name, ".toml")),
        }
    };
}

/// Every preset, cantilevers first.
pub const PRESETS: [Preset; 11] = [
    preset!("tap300", Cantilever),
    preset!("tap150", Cantilever),
    preset!("multi75", Cantilever),
    preset!("ac240", Cantilever),
    preset!("tap525", Cantilever),
    preset!("silicon", Sample),
    preset!("fused_silica", Sample),
    preset!("polystyrene", Sample),
    preset!("pdms", Sample),
    preset!("mica", Sample),
    preset!("hopg", Sample),
];

/// The preset called `name`, or an error that lists them all.
pub fn preset(name: &str) -> Result<&'static Preset, ConfigError> {
    PRESETS
        .iter()
        .find(|p| p.name == name)
        .ok_or_else(|| ConfigError::UnknownPreset {
            name: super::show::cut(name).into_owned(),
            allowed: PRESETS
                .iter()
                .map(|p| p.name)
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// The embedded default, then each preset in order, then the file at `path`: what
/// `--preset … --config FILE` runs.
pub fn load_with_presets(names: &[String], path: Option<&Path>) -> Result<Settings, ConfigError> {
    let mut settings = default_settings();
    for name in names {
        let p = preset(name)?;
        settings = overlay_str(settings, p.toml, &format!("preset {}", p.name))?;
    }
    match path {
        None => Ok(settings),
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
                path: path.to_owned(),
                error,
            })?;
            overlay_str(settings, &text, &path.display().to_string())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_loads_and_changes_only_its_table() {
        let default = default_settings();
        for p in PRESETS {
            let s = load_with_presets(&[p.name.to_owned()], None)
                .unwrap_or_else(|e| panic!("{}: {e}", p.name));
            match p.kind {
                PresetKind::Cantilever => {
                    assert_ne!(s.cantilever, default.cantilever, "{}", p.name);
                    assert_eq!(s.sample, default.sample, "{}", p.name);
                    // The drive follows the lever; the second excitation stays off.
                    assert_eq!(s.drive.frequency, s.cantilever.f1, "{}", p.name);
                    assert_ne!(s.drive2.frequency, default.drive2.frequency, "{}", p.name);
                    assert!(!s.drive2.enable, "{}", p.name);
                }
                PresetKind::Sample => {
                    assert_eq!(s.cantilever, default.cantilever, "{}", p.name);
                    assert_eq!(s.drive2, default.drive2, "{}", p.name);
                    // The paper's 10 % softer disc stays 10 % softer.
                    assert_eq!(
                        s.inclusions[0].youngs_modulus,
                        0.9 * s.sample.youngs_modulus,
                        "{}",
                        p.name
                    );
                }
            }
            assert!(!p.summary().is_empty(), "{}", p.name);
            assert!(!p.summary().starts_with(p.name), "{}", p.summary());
        }
    }

    /// Every lever preset is a complete FT-AFM set-up, alone and under every sample preset:
    /// it loads and validates, every demodulated harmonic (the inversion's, the scan's
    /// images') lies inside the anti-alias filter's flat passband, 0.4 × the sample rate,
    /// so nothing warns about the force estimate, and the sweeper's default tune spans the
    /// resonance, f1 ± 2 f1/Q1.
    #[test]
    fn every_lever_with_every_sample_is_a_complete_set_up() {
        let levers = PRESETS.iter().filter(|p| p.kind == PresetKind::Cantilever);
        for lever in levers {
            let samples = PRESETS.iter().filter(|p| p.kind == PresetKind::Sample);
            for sample in std::iter::once(None).chain(samples.map(Some)) {
                let mut names = vec![lever.name.to_owned()];
                names.extend(sample.map(|s| s.name.to_owned()));
                let s =
                    load_with_presets(&names, None).unwrap_or_else(|e| panic!("{names:?}: {e}"));
                s.validate().unwrap_or_else(|e| panic!("{names:?}: {e}"));
                let edge = crate::config::PASSBAND_FRACTION * s.synth.sample_rate;
                assert_eq!(
                    s.demods.iter().filter(|d| d.enable).count(),
                    32,
                    "{names:?}"
                );
                for d in s.demods.iter().filter(|d| d.enable) {
                    assert!(
                        f64::from(d.harmonic) * s.drive.frequency < edge,
                        "{names:?}: H{} above {edge} Hz",
                        d.harmonic
                    );
                }
                assert!(
                    s.force_warnings().is_empty(),
                    "{names:?}: {:?}",
                    s.force_warnings()
                );
                assert!(s.warnings().is_empty(), "{names:?}: {:?}", s.warnings());
                let (f1, q1) = (s.cantilever.f1, s.cantilever.q[0]);
                let half = f1 / q1;
                assert!(
                    (s.sweeper.start - (f1 - 2.0 * half)).abs() < 0.02 * half
                        && (s.sweeper.stop - (f1 + 2.0 * half)).abs() < 0.02 * half,
                    "{names:?}: tune {} … {} Hz around {f1} Hz, Q1 = {q1}",
                    s.sweeper.start,
                    s.sweeper.stop
                );
                let mut sweeping = s.clone();
                sweeping.sweeper.enable = true;
                sweeping
                    .validate()
                    .unwrap_or_else(|e| panic!("{names:?}, a tune: {e}"));
            }
        }
    }

    #[test]
    fn an_unknown_preset_lists_the_known_ones() {
        let error = preset("tap3000").unwrap_err().to_string();
        assert!(
            error.contains("tap3000") && error.contains("tap300, tap150"),
            "{error}"
        );
    }
}
