//! Typed, validated instrument settings. Every field is SI; each one is a node of the
//! tree (`/cantilever/f1` is `Settings::cantilever.f1`). See `docs/configuration.md`.

use serde::{Deserialize, Serialize};

/// Number of lock-in demodulators in the bank (`/demods/0` … `/demods/31`).
pub const DEMODULATOR_COUNT: usize = 32;

/// The whole instrument configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub cantilever: CantileverSettings,
    pub tip: Material,
    pub sample: Material,
    pub drive: DriveSettings,
    pub surface: SurfaceSettings,
    pub synth: SynthSettings,
    pub noise: NoiseSettings,
    /// Demodulator bank; always [`DEMODULATOR_COUNT`] entries, index = N of `/demods/N`.
    /// (De)serialised as a table keyed by index (`[demods]` with keys `"0"` … `"31"`), so
    /// TOML and JSON paths mirror the node tree.
    #[serde(with = "super::demod_table")]
    pub demods: Vec<DemodSettings>,
}

/// `[cantilever]`: the rectangular beam.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CantileverSettings {
    /// First flexural resonance f1 (Hz).
    pub f1: f64,
    /// Static spring constant at the tip, 3EI/L³ (N/m).
    pub k: f64,
    /// Quality factor of each mode with a measured Q (1).
    pub q: Vec<f64>,
    /// Modes simulated beyond the `q` list, damped by the Rayleigh form (B.7) fitted to the
    /// last two given Q values (count).
    pub extra_modes: usize,
    /// Tip radius R (m).
    pub tip_radius: f64,
}

/// An isotropic elastic material (`[tip]`, `[sample]`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson ratio ν (1).
    pub poisson: f64,
}

/// `[drive]`: base excitation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveSettings {
    /// Drive frequency Ω/2π (Hz).
    pub frequency: f64,
    /// Free tip amplitude at the drive frequency, peak (m).
    pub free_amplitude: f64,
}

/// `[surface]`: where the sample is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceSettings {
    /// A_set: distance from the tip's rest position to the sample surface (m).
    pub distance: f64,
}

/// How the tip force is computed in the synthesiser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// Cut-cosine pulse train with F, τ and phase from the 1-DOF model (the paper's method).
    Paper,
    /// Contact force from the instantaneous tip position of all modes.
    Coupled,
}

impl Engine {
    /// Every engine, in the order of [`Engine::NAMES`].
    pub const ALL: [Engine; 2] = [Engine::Paper, Engine::Coupled];
    /// The names used in config files and the protocol (`/synth/engine`).
    pub const NAMES: &'static [&'static str] = &["paper", "coupled"];

    /// The config/protocol name of this engine (`"paper"`, `"coupled"`).
    pub fn name(self) -> &'static str {
        match self {
            Engine::Paper => "paper",
            Engine::Coupled => "coupled",
        }
    }

    /// The engine called `name`, if there is one.
    pub fn from_name(name: &str) -> Option<Engine> {
        Engine::ALL.into_iter().find(|engine| engine.name() == name)
    }
}

/// `[synth]`: the photodiode synthesiser.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSettings {
    /// Photodiode sample rate (Hz).
    pub sample_rate: f64,
    /// Tip-force engine.
    pub engine: Engine,
    /// Seed of every random source.
    pub seed: u64,
    /// Pace synthesis to the wall clock (true) or run as fast as possible (false).
    pub realtime: bool,
}

/// `[noise]`: noise sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSettings {
    /// All noise sources on or off.
    pub enable: bool,
}

/// `[demods.N]`: one lock-in demodulator.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DemodSettings {
    /// Demodulator produces output.
    pub enable: bool,
    /// Harmonic k of the drive it demodulates at (k = 0 is the mean).
    pub harmonic: u32,
    /// Low-pass filter order (cascaded first-order sections, 1–8).
    pub order: u32,
    /// Time constant of each first-order section (s).
    pub timeconstant: f64,
    /// Output rate (Hz).
    pub rate: f64,
}
