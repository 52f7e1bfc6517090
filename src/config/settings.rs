//! Typed, validated instrument settings. Every field is SI; each one is a node of the
//! tree (`/cantilever/f1` is `Settings::cantilever.f1`). See `docs/configuration.md`.

use serde::{Deserialize, Serialize};

use super::indexed_table::Indexed;

/// Number of lock-in demodulators in the bank (`/demods/0` … `/demods/31`).
pub const DEMODULATOR_COUNT: usize = 32;
/// Number of inclusion slots in the sample map (`/inclusions/0` … `/inclusions/7`).
pub const INCLUSION_COUNT: usize = 8;
/// Number of PID units (`/pids/0` … `/pids/3`), as an MFLI with its PID option has.
pub const PID_COUNT: usize = 4;

/// The whole instrument configuration.
///
/// Some nodes follow others: the drive frequency follows `/cantilever/f1` while
/// `/drive/follow_f1`, and an inclusion's modulus follows the base material's while its
/// `relative_modulus` is above 0. [`Settings::set`], [`Settings::apply`] and the config
/// loader keep those links; fields written directly are taken as they stand.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub cantilever: CantileverSettings,
    pub tip: Material,
    pub sample: Material,
    pub drive: DriveSettings,
    /// `[drive2]`: the second excitation (absent from older files: off).
    #[serde(default)]
    pub drive2: SecondDriveSettings,
    pub surface: SurfaceSettings,
    pub adhesion: AdhesionSettings,
    pub synth: SynthSettings,
    pub noise: NoiseSettings,
    pub spectrum: SpectrumSettings,
    pub scope: ScopeSettings,
    /// `[dsp]`: threads of the DSP stage (absent from older files: the default, auto).
    #[serde(default)]
    pub dsp: DspSettings,
    /// `[source]`: where the chain's samples come from (absent from older files: the
    /// synthesiser).
    #[serde(default)]
    pub source: SourceSettings,
    pub server: ServerSettings,
    pub inversion: InversionSettings,
    pub scan: ScanSettings,
    pub feedback: FeedbackSettings,
    pub sweeper: SweeperSettings,
    /// Inclusions in the sample; always [`INCLUSION_COUNT`] entries, index = N of
    /// `/inclusions/N` (a table keyed by index, like `[demods]`).
    #[serde(with = "super::indexed_table")]
    pub inclusions: Vec<InclusionSettings>,
    /// Demodulator bank; always [`DEMODULATOR_COUNT`] entries, index = N of `/demods/N`.
    /// (De)serialised as a table keyed by index (`[demods]` with keys `"0"` … `"31"`), so
    /// TOML and JSON paths mirror the node tree.
    #[serde(with = "super::indexed_table")]
    pub demods: Vec<DemodSettings>,
    /// PID units; always [`PID_COUNT`] entries, index = N of `/pids/N`, keyed by index like
    /// `[demods]` (absent from older files: every unit disabled, at its defaults).
    #[serde(default = "default_pids", with = "super::indexed_table")]
    pub pids: Vec<PidUnitSettings>,
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
    /// Whether `frequency` follows `/cantilever/f1` (an instrument's auto-tune): while true
    /// the two are equal, and a change of f1 moves the drive with it.
    pub follow_f1: bool,
    /// Free tip amplitude at the drive frequency, peak (m).
    pub free_amplitude: f64,
}

/// `[drive2]`: a second base excitation, u₂ = U₂·sin θ₂, beside `/drive`'s, for bimodal
/// AFM (docs/loops.md): both move the base, and every mode and the tip's contact take the
/// sum. Its phase θ₂ starts at 0 with sample 0 and runs on at its own frequency.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SecondDriveSettings {
    /// The second excitation drives the base (true) or is off (false). Demodulators on
    /// `"drive2"` read its frequency either way.
    pub enable: bool,
    /// Its frequency Ω₂/2π (Hz).
    pub frequency: f64,
    /// Free tip amplitude it gives at its frequency, peak (m).
    pub free_amplitude: f64,
}

impl Default for SecondDriveSettings {
    /// Off, at the default lever's second flexural resonance, 1 nm: the small second
    /// amplitude of bimodal AFM.
    fn default() -> Self {
        Self {
            enable: false,
            frequency: 626.689e3,
            free_amplitude: 1e-9,
        }
    }
}

/// `[surface]`: where the sample is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceSettings {
    /// A_set: distance from the tip's rest position to the sample surface (m).
    pub distance: f64,
}

/// `[adhesion]`: DMT adhesion on top of the Hertz contact (physics.md §6), off by default as
/// in the paper.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AdhesionSettings {
    /// Whether the coupled engine adds the adhesion force.
    pub enable: bool,
    /// Hamaker constant H (J).
    pub hamaker: f64,
    /// Intermolecular distance a0 (m).
    pub distance: f64,
}

/// How the tip force is computed in the synthesiser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// Cut-cosine pulse train with F, τ and phase from the 1-DOF model (the paper's method).
    Paper,
    /// Contact force from the instantaneous tip position of all modes, integrated sample
    /// by sample with the modes (docs/physics.md, "The coupled orbit").
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
    #[serde(with = "wide_u64")]
    pub seed: u64,
    /// Pace synthesis to the wall clock (true) or run as fast as possible (false).
    pub realtime: bool,
    /// The ADC's anti-alias filter: integrate over a triangle window, sample at 2·f_s,
    /// decimate by a halfband FIR and compensate the window's droop (true, the default),
    /// or sample the signal directly (false).
    #[serde(default = "yes")]
    pub anti_alias: bool,
    /// Sub-steps of a sample where the coupled engine resolves the contact (even; absent
    /// from older files: the default, 12).
    #[serde(default = "default_contact_substeps")]
    pub contact_substeps: u32,
    /// Error budget of the sub-steps in contact, ω_c·dt (rad; 0: off, every contact sample
    /// at `contact_substeps`). Absent from older files: the default, 0.05
    /// (`synth::coupled::DEFAULT_SUBSTEP_BUDGET`, which says how it was measured).
    #[serde(default = "default_substep_budget")]
    pub substep_budget: f64,
}

/// A `u64` in a file: TOML's integers end at 2⁶³ − 1, so a larger value (a seed may be any
/// `u64`) is written as a string of its decimal digits, `"18446744073709551615"`, and read
/// back from one, so that every value the settings hold can be saved and loaded again.
pub(crate) mod wide_u64 {
    use serde::de::{self, Visitor};
    use serde::{Deserializer, Serializer};

    /// Whether `text` is how [`serialize`] writes a value beyond TOML's integers: decimal
    /// digits of a `u64` above `i64::MAX` (smaller values are plain integers).
    pub(crate) fn parse(text: &str) -> Option<u64> {
        let n: u64 = text.parse().ok()?;
        (text.bytes().all(|b| b.is_ascii_digit()) && i64::try_from(n).is_err()).then_some(n)
    }

    pub fn serialize<S: Serializer>(value: &u64, s: S) -> Result<S::Ok, S::Error> {
        match i64::try_from(*value) {
            Ok(n) => s.serialize_i64(n),
            Err(_) => s.serialize_str(&value.to_string()),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        d.deserialize_any(WideU64)
    }

    struct WideU64;

    impl Visitor<'_> for WideU64 {
        type Value = u64;

        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("an integer 0 … 2⁶⁴ − 1 (above 2⁶³ − 1 as a string of its digits)")
        }

        fn visit_u64<E: de::Error>(self, n: u64) -> Result<u64, E> {
            Ok(n)
        }

        fn visit_i64<E: de::Error>(self, n: i64) -> Result<u64, E> {
            u64::try_from(n).map_err(|_| E::invalid_value(de::Unexpected::Signed(n), &self))
        }

        fn visit_str<E: de::Error>(self, text: &str) -> Result<u64, E> {
            parse(text).ok_or_else(|| E::invalid_value(de::Unexpected::Str(text), &self))
        }
    }
}

fn default_contact_substeps() -> u32 {
    12
}

fn default_substep_budget() -> f64 {
    0.05
}

fn yes() -> bool {
    true
}

/// `[noise]`: noise sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSettings {
    /// All noise sources on or off.
    pub enable: bool,
    /// Temperature of the cantilever's thermal (Brownian) noise, every mode by
    /// fluctuation–dissipation (K); 0 turns thermal noise off.
    pub temperature: f64,
    /// One-sided density of the white detector noise (m/√Hz); 0 turns it off.
    pub detector_density: f64,
    /// Resolution of the ADC (bit); 0 means no quantisation.
    pub adc_bits: u32,
    /// Full scale of the ADC input, ±`adc_range` (nominal m); samples beyond it clip.
    pub adc_range: f64,
}

/// Window applied to each frame of the spectrum (`/spectrum/window`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SpectrumWindow {
    /// No window (all ones).
    Rectangular,
    /// Hann (raised cosine).
    Hann,
    /// Four-term Blackman–Harris: −92 dB side lobes.
    BlackmanHarris,
    /// Flat top: amplitudes read correctly between bins.
    FlatTop,
}

impl SpectrumWindow {
    /// Every window, in the order of [`SpectrumWindow::NAMES`].
    pub const ALL: [SpectrumWindow; 4] = [
        SpectrumWindow::Rectangular,
        SpectrumWindow::Hann,
        SpectrumWindow::BlackmanHarris,
        SpectrumWindow::FlatTop,
    ];
    /// The names used in config files and the protocol (`/spectrum/window`).
    pub const NAMES: &'static [&'static str] =
        &["rectangular", "hann", "blackman_harris", "flat_top"];

    /// The config/protocol name of this window (`"hann"`, `"blackman_harris"`, …).
    pub fn name(self) -> &'static str {
        match self {
            SpectrumWindow::Rectangular => "rectangular",
            SpectrumWindow::Hann => "hann",
            SpectrumWindow::BlackmanHarris => "blackman_harris",
            SpectrumWindow::FlatTop => "flat_top",
        }
    }

    /// The window called `name`, if there is one.
    pub fn from_name(name: &str) -> Option<SpectrumWindow> {
        SpectrumWindow::ALL
            .into_iter()
            .find(|window| window.name() == name)
    }
}

/// `[spectrum]`: the sliding FFT of the photodiode signal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpectrumSettings {
    /// Spectra are computed and sent.
    pub enable: bool,
    /// FFT length (samples): a power of two from 256 to 1048576.
    pub size: u32,
    /// Window applied to each frame.
    pub window: SpectrumWindow,
    /// Spectra per second (Hz); frames may overlap, so only `rate ≤ sample_rate` is required.
    pub rate: f64,
}

/// `[dsp]`: how the DSP stage uses the machine's cores.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DspSettings {
    /// Threads the DSP stage runs on, the DSP thread included (1 … 8); 0 (auto): 1 on a
    /// machine with 2 cores or fewer, else one more per core beyond two, at most 4. Fixed
    /// while the pipeline runs.
    pub threads: u32,
}

/// Where the DSP chain's samples come from (`/source/kind`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// The synthesiser: the modelled cantilever, tapping the modelled sample.
    #[default]
    Synth,
    /// Samples a client pushes over the WebSocket in binary frames (docs/protocol.md,
    /// "Streaming samples in"): a digitiser's, or a recording replayed.
    Stream,
}

impl SourceKind {
    /// Every source, in the order of [`SourceKind::NAMES`].
    pub const ALL: [SourceKind; 2] = [SourceKind::Synth, SourceKind::Stream];
    /// The names used in config files and the protocol (`/source/kind`).
    pub const NAMES: &'static [&'static str] = &["synth", "stream"];

    /// The config/protocol name of this source (`"synth"`, `"stream"`).
    pub fn name(self) -> &'static str {
        match self {
            SourceKind::Synth => "synth",
            SourceKind::Stream => "stream",
        }
    }

    /// The source called `name`, if there is one.
    pub fn from_name(name: &str) -> Option<SourceKind> {
        SourceKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// `[source]`: where the chain's samples come from.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceSettings {
    /// The synthesiser, or samples streamed in by a client.
    pub kind: SourceKind,
}

/// `[scope]`: time-domain traces of the raw photodiode signal (the `scope` stream).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScopeSettings {
    /// Traces are taken and sent.
    pub enable: bool,
    /// Samples per trace, after decimation (samples): 16 to 65536.
    pub length: u32,
    /// Keep every Nth photodiode sample (samples): 1 (every sample) to 10000.
    pub decimation: u32,
    /// Traces per second (Hz), 0 < rate ≤ 100. Traces do not overlap:
    /// `length × decimation / sample_rate ≤ 1 / rate`.
    pub rate: f64,
}

/// `[server]`: the WebSocket server's limits. All of them may change at runtime and apply to
/// connections and sends from then on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServerSettings {
    /// Web origins (`scheme://host[:port]`, e.g. `http://localhost:3000`) besides the
    /// server's own whose pages may open the WebSocket; a page from any other origin is
    /// refused with 403. Each starts with `http://` or `https://` and has no path; at most
    /// 64 entries of at most 256 bytes. No wildcard: `"*"` would let any web page drive the
    /// instrument.
    pub allowed_origins: Vec<String>,
    /// Host names (no port) besides loopback names and IP addresses that the `Host` header of
    /// a request may name; anything else is refused with 403 (DNS rebinding). At most 64.
    pub allowed_hosts: Vec<String>,
    /// Most clients connected at once (clients); beyond it the handshake is refused with 503.
    pub max_clients: u32,
    /// Length of each client's outgoing queue (messages); a client further behind loses its
    /// own messages (counted, and visible as gaps in `seq`).
    pub client_queue: u32,
    /// Most bytes queued for each client (bytes); one larger message still goes when the
    /// queue is empty.
    pub client_queue_bytes: u64,
    /// A client whose socket accepts nothing for this long is disconnected (s); close code
    /// 1008, reason `"stalled"`.
    pub stall_timeout: f64,
}

/// How the live inversion turns demodulator outputs into a force (`/inversion/method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InversionMethod {
    /// Divide every usable harmonic by the cantilever's transfer function and sum the Fourier
    /// series of the force (Stark et al. 2002); missing harmonics are fitted, anchored at the
    /// two harmonics of [`InversionSettings`].
    Full,
    /// Width τ and peak F of the cut-cosine pulse from the amplitudes of two harmonics (the
    /// paper's Sec. 3).
    TwoHarmonic,
}

impl InversionMethod {
    /// Every method, in the order of [`InversionMethod::NAMES`].
    pub const ALL: [InversionMethod; 2] = [InversionMethod::Full, InversionMethod::TwoHarmonic];
    /// The names used in config files and the protocol (`/inversion/method`).
    pub const NAMES: &'static [&'static str] = &["full", "two_harmonic"];

    /// The config/protocol name of this method (`"full"`, `"two_harmonic"`).
    pub fn name(self) -> &'static str {
        match self {
            InversionMethod::Full => "full",
            InversionMethod::TwoHarmonic => "two_harmonic",
        }
    }

    /// The method called `name`, if there is one.
    pub fn from_name(name: &str) -> Option<InversionMethod> {
        InversionMethod::ALL
            .into_iter()
            .find(|method| method.name() == name)
    }
}

/// `[inversion]`: live FT-AFM force reconstruction from the demodulator outputs (the `force`
/// stream). Every key may change at runtime. While enabled, both harmonics must be measured
/// by an enabled demodulator; they must always differ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InversionSettings {
    /// Force estimates are computed and sent.
    pub enable: bool,
    /// How the force is reconstructed.
    pub method: InversionMethod,
    /// First harmonic of the two-harmonic method, and anchor of the full method's fit of
    /// missing harmonics (a harmonic number k of the drive): 2 to 10000.
    pub harmonic_a: u32,
    /// Second harmonic, as `harmonic_a`: 2 to 10000, never equal to `harmonic_a`.
    pub harmonic_b: u32,
    /// Demodulator frames averaged per force estimate (frames): 1 to 10000.
    pub averaging: u32,
    /// Points of the reconstructed force waveform over one drive period (samples): 16 to
    /// 4096.
    pub points: u32,
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
    /// The oscillator it demodulates against (absent from older files: `/drive`'s).
    #[serde(default)]
    pub oscillator: Oscillator,
}

/// `[scan]`: the raster scan of the tip over the sample map. Trace (left to right) and
/// retrace (right to left) at constant speed; the slow axis steps one pixel per line, line 0
/// at the top (largest y).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanSettings {
    /// The tip scans (true) or rests over the base material at `/surface/distance` (false).
    pub enable: bool,
    /// Side of the square scan area (m).
    pub size: f64,
    /// Pixels per line, and lines per frame (pixels).
    pub pixels: u32,
    /// Lines per second, trace and retrace together (Hz).
    pub line_rate: f64,
    /// Centre of the scan area in sample coordinates, x (m).
    pub x: f64,
    /// Centre of the scan area in sample coordinates, y (m).
    pub y: f64,
}

/// `[feedback]`: the amplitude feedback of tapping mode, a PI controller that moves the
/// sample so the photodiode amplitude at the drive frequency stays at the setpoint. Runs while
/// the scan runs; its output (the surface distance) is the height channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeedbackSettings {
    /// The controller acts (true) or holds the distance at `/surface/distance` (false).
    pub enable: bool,
    /// Photodiode amplitude at the drive frequency to hold (m, peak, as demodulator
    /// harmonic 1 reads it); 0 means the steady amplitude at `/surface/distance` over the
    /// base material.
    pub setpoint: f64,
    /// Proportional gain (m of distance per m of amplitude error, 1).
    pub proportional: f64,
    /// Integral gain (m of distance per s per m of amplitude error, 1/s).
    pub integral: f64,
}

/// A text choice of the config and the protocol: its names, in the order of `ALL`.
macro_rules! named_choice {
    ($(#[$doc:meta])* $name:ident { $($(#[$vdoc:meta])* $variant:ident = $text:literal),+ $(,)? }) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
        pub enum $name {
            $($(#[$vdoc])* #[serde(rename = $text)] $variant),+
        }

        impl $name {
            /// Every choice, in the order of `NAMES`.
            pub const ALL: &'static [$name] = &[$($name::$variant),+];
            /// The names used in config files and the protocol.
            pub const NAMES: &'static [&'static str] = &[$($text),+];

            /// This choice's name.
            pub fn name(self) -> &'static str {
                match self {
                    $($name::$variant => $text),+
                }
            }

            /// The choice called `name`, if there is one.
            pub fn from_name(name: &str) -> Option<$name> {
                Self::ALL.iter().copied().find(|c| c.name() == name)
            }
        }
    };
}

named_choice! {
    /// The reference a demodulator reads (`/demods/N/oscillator`): its harmonic k is of
    /// this oscillator's frequency and phase.
    #[derive(Default)]
    Oscillator {
        /// `/drive`: the excitation the tapping and the FT-AFM harmonics follow.
        #[default]
        Drive = "drive",
        /// `/drive2`: the second excitation (bimodal AFM), whether or not it is enabled.
        Drive2 = "drive2",
    }
}

named_choice! {
    /// The node a sweep steps (`/sweeper/parameter`).
    SweepParameter {
        /// `/drive/frequency`: a tune, at a constant base (piezo) amplitude.
        DriveFrequency = "/drive/frequency",
        /// `/surface/distance`: an approach (and retract) curve.
        SurfaceDistance = "/surface/distance",
        /// `/drive/free_amplitude`.
        DriveFreeAmplitude = "/drive/free_amplitude",
        /// `/sample/youngs_modulus`.
        SampleYoungsModulus = "/sample/youngs_modulus",
    }
}

named_choice! {
    /// Spacing of a sweep's points (`/sweeper/scale`).
    SweepScale {
        /// Evenly spaced values.
        Linear = "linear",
        /// Evenly spaced logarithms (start and stop > 0).
        Log = "log",
    }
}

named_choice! {
    /// Legs of a sweep (`/sweeper/direction`).
    SweepDirection {
        /// From start to stop.
        Up = "up",
        /// From stop to start.
        Down = "down",
        /// From start to stop and back (an approach, then a retract).
        Both = "both",
    }
}

named_choice! {
    /// What a PID unit reads (`/pids/N/input`): a part of the reading of its own modelled
    /// demodulator at `/pids/N/harmonic` (the `demods` stream's names and units), or a
    /// value derived from another unit.
    PidInput {
        /// The amplitude r = |x + iy| (m, peak).
        R = "r",
        /// The phase atan2(y, x) (rad, in [−π, π]).
        Phase = "phase",
        /// The in-phase part x (m).
        X = "x",
        /// The quadrature part y (m).
        Y = "y",
        /// The frequency shift Δf of the PLL on the unit's oscillator (Hz): that unit's
        /// output after its update less `/drive/frequency` (`/drive2/frequency` on
        /// `drive2`). A loop on it at constant Δf is FM-AFM's topography.
        FrequencyShift = "frequency_shift",
        /// The mean deflection (m): the mean of the photodiode samples over the unit's
        /// drive period, the DC its demodulator reads at harmonic 0 (`/pids/N/harmonic` is
        /// not read). A loop on it at constant deflection is contact mode's topography.
        MeanDeflection = "mean_deflection",
    }
}

named_choice! {
    /// What a PID unit drives (`/pids/N/output`).
    PidTarget {
        /// The z piezo: the distance from the tip's rest position to the sample surface (m),
        /// `/surface/distance`'s quantity, moved as the scan's amplitude feedback moves it.
        SurfaceDistance = "surface_distance",
        /// The drive's frequency (Hz), with the lock-in's reference: a unit on the phase
        /// of harmonic 1 is a PLL. `/drive/frequency` is the centre it starts from.
        DriveFrequency = "drive_frequency",
        /// The drive's amplitude, as the free tip amplitude it gives at `/drive/frequency`
        /// (m, `/drive/free_amplitude`'s quantity): the base amplitude in proportion.
        DriveAmplitude = "drive_amplitude",
        /// The second excitation's frequency (Hz), with the reference of the demodulators
        /// on `drive2`: a unit on the phase of harmonic 1 of `drive2` is mode 2's PLL
        /// (bimodal AM-FM). `/drive2/frequency` is the centre it starts from.
        Drive2Frequency = "drive2_frequency",
        /// The second excitation's amplitude, as the free tip amplitude it gives at
        /// `/drive2/frequency` (m, `/drive2/free_amplitude`'s quantity).
        Drive2Amplitude = "drive2_amplitude",
    }
}

impl PidTarget {
    /// Whether it moves the second excitation (`/drive2`).
    pub fn on_drive2(self) -> bool {
        matches!(self, Self::Drive2Frequency | Self::Drive2Amplitude)
    }

    /// Its bit in a mask of outputs (`pid_held`'s, [`written`](Self::written)'s).
    pub fn bit(self) -> u64 {
        1 << self as u64
    }

    /// The node that holds its value while no unit moves it: a write of that node takes
    /// the output back from a unit that stopped on it.
    pub fn node(self) -> &'static str {
        match self {
            Self::SurfaceDistance => "/surface/distance",
            Self::DriveFrequency => "/drive/frequency",
            Self::DriveAmplitude => "/drive/free_amplitude",
            Self::Drive2Frequency => "/drive2/frequency",
            Self::Drive2Amplitude => "/drive2/free_amplitude",
        }
    }

    /// The outputs whose nodes a change writes, [`bit`](Self::bit) each: those of
    /// `paths` ([`node`](Self::node)), or all of them for a load of settings or a preset
    /// (`None`: possibly any node). A write counts whether or not it changes the value.
    pub fn written(paths: Option<&[String]>) -> u64 {
        Self::ALL
            .iter()
            .filter(|t| paths.is_none_or(|p| p.iter().any(|p| p == t.node())))
            .fold(0, |mask, t| mask | t.bit())
    }

    /// The oscillator whose frequency it moves, if it moves one.
    pub fn frequency_of(self) -> Option<Oscillator> {
        match self {
            Self::DriveFrequency => Some(Oscillator::Drive),
            Self::Drive2Frequency => Some(Oscillator::Drive2),
            _ => None,
        }
    }
}

/// `[pids.N]`: one PID unit in LabOne's shape, run once per drive period in the
/// synthesiser (docs/loops.md). Gains are in the output's unit per the input's unit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PidUnitSettings {
    /// The unit regulates (true) or is idle (false).
    pub enable: bool,
    /// The part of its demodulator's reading it regulates.
    pub input: PidInput,
    /// Harmonic k of the drive its demodulator reads (1 … 10000, in band while enabled).
    pub harmonic: u32,
    /// Set-point r (the input's unit: m, or rad for the phase).
    pub setpoint: f64,
    /// Proportional gain P (output unit per input unit).
    pub p: f64,
    /// Integral gain I (output unit per input unit per s).
    pub i: f64,
    /// Derivative gain D (output unit·s per input unit).
    pub d: f64,
    /// −3 dB bandwidth of the derivative's low-pass (Hz), below half the drive frequency.
    pub d_bandwidth: f64,
    /// Lowest output (the output's unit).
    pub output_min: f64,
    /// Highest output (the output's unit).
    pub output_max: f64,
    /// Largest change of the output per second (the output's unit per s); 0: none.
    pub rate: f64,
    /// What it drives.
    pub output: PidTarget,
    /// The oscillator whose harmonic k its demodulator reads (absent from older files:
    /// `/drive`'s).
    #[serde(default)]
    pub oscillator: Oscillator,
    /// −3 dB bandwidth (Hz) of its demodulator's low-pass (four first-order sections) on
    /// `drive2`, at most a quarter of the drive frequency (its update rate); a unit on
    /// `drive` reads a boxcar of one drive period instead.
    #[serde(default = "default_input_bandwidth")]
    pub input_bandwidth: f64,
}

/// `/pids/N/input_bandwidth`'s default (Hz): far below the default lever's spacing of f2
/// from the tapping's nearest harmonic (27 kHz), above a mode-2 PLL's usual bandwidth.
pub const DEFAULT_PID_INPUT_BANDWIDTH: f64 = 2e3;

fn default_input_bandwidth() -> f64 {
    DEFAULT_PID_INPUT_BANDWIDTH
}

impl Default for PidUnitSettings {
    /// A disabled amplitude loop on the surface distance with the scan feedback's gains.
    fn default() -> Self {
        Self {
            enable: false,
            input: PidInput::R,
            harmonic: 1,
            setpoint: 20e-9,
            p: 0.0,
            i: 1200.0,
            d: 0.0,
            d_bandwidth: 1000.0,
            output_min: 0.0,
            output_max: 100e-9,
            rate: 0.0,
            output: PidTarget::SurfaceDistance,
            oscillator: Oscillator::Drive,
            input_bandwidth: DEFAULT_PID_INPUT_BANDWIDTH,
        }
    }
}

/// [`PID_COUNT`] units at their defaults: what a file without `[pids]` has.
fn default_pids() -> Vec<PidUnitSettings> {
    vec![PidUnitSettings::default(); PID_COUNT]
}

/// `[sweeper]`: steps one node through a range in simulated time and measures every
/// demodulator at each point (the `sweep` stream); the node is restored afterwards.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweeperSettings {
    /// The node stepped.
    pub parameter: SweepParameter,
    /// First value (the parameter's unit).
    pub start: f64,
    /// Last value (the parameter's unit).
    pub stop: f64,
    /// Points per leg, both ends included.
    pub points: u32,
    /// Spacing of the points.
    pub scale: SweepScale,
    /// Legs: up, down, or both.
    pub direction: SweepDirection,
    /// Wait at each point before averaging (s of simulated time); 0: automatic, from the
    /// cantilever's ring-down and the demodulators' filters.
    pub settling: f64,
    /// Demodulator frames averaged per point.
    pub averaging: u32,
    /// A sweep runs (set true to start, false to abort; it turns false when done).
    pub enable: bool,
}

/// Shape of an inclusion (`/inclusions/N/shape`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InclusionShape {
    /// A disc of diameter `width`.
    Disc,
    /// A rectangle `width` (x) by `length` (y), sides along the axes.
    Rectangle,
}

impl InclusionShape {
    /// Every shape, in the order of [`InclusionShape::NAMES`].
    pub const ALL: [InclusionShape; 2] = [InclusionShape::Disc, InclusionShape::Rectangle];
    /// The names used in config files and the protocol.
    pub const NAMES: &'static [&'static str] = &["disc", "rectangle"];

    /// The config/protocol name of this shape.
    pub fn name(self) -> &'static str {
        match self {
            InclusionShape::Disc => "disc",
            InclusionShape::Rectangle => "rectangle",
        }
    }

    /// The shape called `name`, if there is one.
    pub fn from_name(name: &str) -> Option<InclusionShape> {
        InclusionShape::ALL
            .into_iter()
            .find(|shape| shape.name() == name)
    }
}

/// `[inclusions.N]`: a region of the sample of another material and height. Where
/// inclusions overlap, the one with the higher index is on top.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InclusionSettings {
    /// The inclusion is part of the sample.
    pub enable: bool,
    /// Disc or rectangle.
    pub shape: InclusionShape,
    /// Centre, x (m, sample coordinates).
    pub x: f64,
    /// Centre, y (m, sample coordinates).
    pub y: f64,
    /// Diameter of a disc, x extent of a rectangle (m).
    pub width: f64,
    /// y extent of a rectangle (m); not used by a disc.
    pub length: f64,
    /// Height of its surface above the base material's (m; negative: a pit).
    pub height: f64,
    /// Young's modulus E (Pa). While `relative_modulus` > 0 it is that times the base
    /// material's (`/sample/youngs_modulus`).
    pub youngs_modulus: f64,
    /// E relative to the base material's (1); 0: `youngs_modulus` stands on its own.
    pub relative_modulus: f64,
    /// Poisson ratio ν (1).
    pub poisson: f64,
}

impl Indexed for DemodSettings {
    const COUNT: usize = DEMODULATOR_COUNT;
    const TABLE: &'static str = "demods";
    const ITEM: &'static str = "demodulator";
}

impl Indexed for PidUnitSettings {
    const COUNT: usize = PID_COUNT;
    const TABLE: &'static str = "pids";
    const ITEM: &'static str = "PID";
}

impl Indexed for InclusionSettings {
    const COUNT: usize = INCLUSION_COUNT;
    const TABLE: &'static str = "inclusions";
    const ITEM: &'static str = "inclusion";
}
