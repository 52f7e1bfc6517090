//! The settings as nodes of a tree: which nodes exist ([`Field`]), their units, the values
//! each takes on its own ([`Kind`]), their descriptions, and typed reads and writes of
//! [`Settings`]. The limits between nodes are in `relations`; access by path is in `nodes`.

use serde_json::Value;

use super::nodes::show_json;
use super::quantity::number;
use super::range::Range;
use super::settings::{
    Engine, InclusionShape, InversionMethod, Settings, SpectrumWindow, SweepDirection,
    SweepParameter, SweepScale,
};

/// Most cantilever modes simulated: entries of `/cantilever/q` plus `/cantilever/extra_modes`.
pub const MAX_MODES: usize = 16;
/// Highest harmonic a demodulator may be set to (before the Nyquist limit applies).
pub const MAX_HARMONIC: u32 = 10_000;
/// Highest low-pass filter order of a demodulator.
pub const MAX_FILTER_ORDER: u32 = 8;
/// Highest Young's modulus of the tip or the sample (Pa): 10 TPa, well above diamond's
/// 1.2 TPa.
pub const MAX_YOUNGS_MODULUS: f64 = 1e13;
/// Highest ADC resolution, in bits (`/noise/adc_bits`; 0 means no quantisation).
pub const MAX_ADC_BITS: u32 = 32;
/// Shortest FFT of the spectrum, in samples (`/spectrum/size`, a power of two).
pub const MIN_SPECTRUM_SIZE: u32 = 256;
/// Longest FFT of the spectrum, in samples (`/spectrum/size`, a power of two): 2^20.
pub const MAX_SPECTRUM_SIZE: u32 = 1 << 20;
/// Shortest scope trace, in samples after decimation (`/scope/length`).
pub const MIN_SCOPE_LENGTH: u32 = 16;
/// Longest scope trace, in samples after decimation (`/scope/length`): 2^16.
pub const MAX_SCOPE_LENGTH: u32 = 1 << 16;
/// Highest scope decimation (`/scope/decimation`): every 10000th photodiode sample.
pub const MAX_SCOPE_DECIMATION: u32 = 10_000;
/// Most origins in `/server/allowed_origins`.
pub const MAX_ALLOWED_ORIGINS: usize = 64;
/// Longest entry of `/server/allowed_origins`, in bytes.
pub const MAX_ORIGIN_BYTES: usize = 256;
/// Longest entry of `/server/allowed_hosts`, in bytes (a DNS name's limit).
pub const MAX_HOST_BYTES: usize = 253;
/// Least and most bytes queued per client (`/server/client_queue_bytes`): 64 KiB to 1 GiB.
pub const MIN_CLIENT_QUEUE_BYTES: u64 = 1 << 16;
pub const MAX_CLIENT_QUEUE_BYTES: u64 = 1 << 30;
/// Most WebSocket clients connected at once (`/server/max_clients`).
pub const MAX_CLIENTS: u32 = 4096;
/// Most threads of the DSP stage (`/dsp/threads`): the lock-in bank splits into shards of at
/// least 4 of its 32 demodulators.
pub const MAX_DSP_THREADS: u32 = 8;
/// Fewest and most sub-steps of a sample in contact (`/synth/contact_substeps`, even): at 2
/// the contact is one kick each side of the midpoint; at 64 the worst error is a tenth of
/// the default's, at five times its cost in contact (docs/ft-afm.md).
pub const MIN_CONTACT_SUBSTEPS: u32 = 2;
pub const MAX_CONTACT_SUBSTEPS: u32 = 64;
/// Shortest per-client outgoing queue, in messages (`/server/client_queue`).
pub const MIN_CLIENT_QUEUE: u32 = 16;
/// Longest per-client outgoing queue, in messages (`/server/client_queue`): 2^16.
pub const MAX_CLIENT_QUEUE: u32 = 1 << 16;
/// Lowest harmonic the inversion may use (`/inversion/harmonic_a`, `/inversion/harmonic_b`):
/// the mean (0) and the drive itself (1) carry the cantilever's own motion, not the pulse's
/// shape. The highest is [`MAX_HARMONIC`].
pub const MIN_INVERSION_HARMONIC: u32 = 2;
/// Most demodulator frames averaged per force estimate (`/inversion/averaging`).
pub const MAX_INVERSION_AVERAGING: u32 = 10_000;
/// Fewest points of the reconstructed force waveform over one period (`/inversion/points`).
pub const MIN_INVERSION_POINTS: u32 = 16;
/// Most points of the reconstructed force waveform over one period (`/inversion/points`).
pub const MAX_INVERSION_POINTS: u32 = 4096;
/// Fewest pixels per scan line (and lines per frame), `/scan/pixels`.
pub const MIN_SCAN_PIXELS: u32 = 8;
/// Most pixels per scan line (and lines per frame), `/scan/pixels`.
pub const MAX_SCAN_PIXELS: u32 = 1024;
/// Drive periods each pixel of a scan line must last at least: the lock-in needs a few
/// periods to see the material change (`/scan/line_rate` ≤ `/drive/frequency` /
/// (2 × this × `/scan/pixels`)).
pub const MIN_PIXEL_PERIODS: f64 = 10.0;
/// Lowest rate of anything periodic the instrument produces (demodulator outputs,
/// spectra, scope traces, scan lines), in Hz: one per 1000 s. Slower is no instrument
/// setting, and a rate of 5e-324 Hz would make the samples between frames overflow any
/// integer (the DSP thread also clamps them, see `pipeline`).
pub const MIN_RATE: f64 = 1e-3;
/// Most pixels per second the image stream carries, trace and retrace together
/// (2 × `/scan/pixels` × `/scan/line_rate` ≤ this).
pub const MAX_PIXEL_RATE: f64 = 20_000.0;

// Static ranges. Limits that depend on another node (the Nyquist frequency, one sample
// period) are checked in `relations`, after a whole file or a `set` has been applied, so the
// order in which keys are applied never matters.
/// Frequencies in Hz: up to 100 MHz.
const FREQUENCY: Range = Range::above_up_to(0.0, 1e8);
/// Spring constant in N/m.
const STIFFNESS: Range = Range::above_up_to(0.0, 1e5);
/// Quality factors: above 0.5 so every mode is underdamped (γ = 1/(2Q) < 1).
const QUALITY: Range = Range::above_up_to(0.5, 1e7);
/// Tip radius in m: up to 10 µm (colloidal probes).
const TIP_RADIUS: Range = Range::above_up_to(0.0, 1e-5);
/// Young's modulus in Pa: up to 10 TPa (above diamond's 1.2 TPa).
const MODULUS: Range = Range::above_up_to(0.0, MAX_YOUNGS_MODULUS);
/// Poisson ratio: the thermodynamic limits of an isotropic solid, both excluded (ν = 0.5
/// is incompressible, ν = −1 makes the shear modulus infinite).
const POISSON: Range = Range::between(-1.0, 0.5);
/// An inclusion's modulus relative to the base material's: 0 (absolute), up to 10⁴.
const RELATIVE_MODULUS: Range = Range::closed(0.0, 1e4);
/// Amplitudes and distances in m: up to 1 µm.
const LENGTH: Range = Range::above_up_to(0.0, 1e-6);
/// Hamaker constant in J: up to 1e-17 J, beyond any pair of solids (metals reach ~4e-19 J).
const HAMAKER: Range = Range::above_up_to(0.0, 1e-17);
/// Intermolecular distance a0 of the adhesion in m: 0.01 nm to 1 nm.
const INTERMOLECULAR_DISTANCE: Range = Range::closed(1e-11, 1e-9);
/// Photodiode sample rate in Hz.
const SAMPLE_RATE: Range = Range::closed(1e3, 1e9);
/// Filter time constant in s.
const TIME_CONSTANT: Range = Range::above_up_to(0.0, 100.0);
/// Demodulator output rate in Hz: never above the highest sample rate (and, in
/// `relations`, never above the configured one); at least one output per 1000 s.
const OUTPUT_RATE: Range = Range::closed(MIN_RATE, SAMPLE_RATE.max.value);
/// Temperature of the thermal noise in K; 0 turns it off.
const TEMPERATURE: Range = Range::closed(0.0, 1e4);
/// Detector noise density in m/√Hz: up to 1 nm/√Hz; 0 turns it off.
const DETECTOR_DENSITY: Range = Range::closed(0.0, 1e-9);
/// ADC full scale in m: ±1 pm to ±10 µm. Below 1 pm the step of a 32-bit ADC would
/// underflow (its reciprocal overflow), and no deflection sensor reads less.
const ADC_RANGE: Range = Range::closed(1e-12, 1e-5);
/// Spectra per second in Hz (and, in `relations`, never above the sample rate).
const SPECTRUM_RATE: Range = Range::closed(MIN_RATE, 1e3);
/// Scope traces per second in Hz (and, in `relations`, traces must not overlap).
const SCOPE_RATE: Range = Range::closed(MIN_RATE, 100.0);
/// Seconds a client's socket may accept nothing before it is disconnected.
const STALL_TIMEOUT: Range = Range::closed(1.0, 600.0);
/// Side of the square scan area in m: up to 100 µm (a typical piezo scanner's range).
const SCAN_SIZE: Range = Range::above_up_to(0.0, 100e-6);
/// Scan lines per second in Hz (and, in `relations`, at least ten drive periods per pixel
/// and at most 20000 pixels per second).
const LINE_RATE: Range = Range::closed(MIN_RATE, 100.0);
/// Positions in sample coordinates in m (scan centre, inclusion centre): within ±1 mm.
const POSITION: Range = Range::closed(-1e-3, 1e-3);
/// Amplitude setpoint of the feedback in m: up to 1 µm; 0 means the amplitude at the
/// surface distance over the base material.
const SETPOINT: Range = Range::closed(0.0, 1e-6);
/// Proportional gain of the feedback (1).
const PROPORTIONAL_GAIN: Range = Range::closed(0.0, 10.0);
/// Integral gain of the feedback in 1/s.
const INTEGRAL_GAIN: Range = Range::closed(0.0, 1e6);
/// Width and length of an inclusion in m: up to 1 mm.
const EXTENT: Range = Range::above_up_to(0.0, 1e-3);
/// Height of an inclusion above the base material in m: ±1 µm (negative is a pit).
const HEIGHT: Range = Range::closed(-1e-6, 1e-6);
/// Start and stop of a sweep: any finite value here; the swept node's own range applies
/// when the sweep starts.
const SWEEP_VALUE: Range = Range::closed(-1e13, 1e13);
/// Settling time of a sweep point (s).
const SWEEP_SETTLING: Range = Range::closed(0.0, 100.0);
/// Most points per leg of a sweep.
pub const MAX_SWEEP_POINTS: u32 = 10_000;
/// Most demodulator frames averaged per sweep point.
pub const MAX_SWEEP_AVERAGING: u32 = 100_000;

/// One node of the tree. Inclusion and demodulator nodes carry their index N of
/// `/inclusions/N/…` and `/demods/N/…`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Field {
    /// `/cantilever/f1` (Hz).
    CantileverF1,
    /// `/cantilever/k` (N/m).
    CantileverK,
    /// `/cantilever/q` (list of Q, 1).
    CantileverQ,
    /// `/cantilever/extra_modes` (count).
    CantileverExtraModes,
    /// `/cantilever/tip_radius` (m).
    CantileverTipRadius,
    /// `/tip/youngs_modulus` (Pa).
    TipYoungsModulus,
    /// `/tip/poisson` (1).
    TipPoisson,
    /// `/sample/youngs_modulus` (Pa).
    SampleYoungsModulus,
    /// `/sample/poisson` (1).
    SamplePoisson,
    /// `/drive/frequency` (Hz).
    DriveFrequency,
    /// `/drive/follow_f1` (bool).
    DriveFollowF1,
    /// `/drive/free_amplitude` (m).
    DriveFreeAmplitude,
    /// `/surface/distance` (m).
    SurfaceDistance,
    /// `/adhesion/enable` (bool).
    AdhesionEnable,
    /// `/adhesion/hamaker` (J).
    AdhesionHamaker,
    /// `/adhesion/distance` (m).
    AdhesionDistance,
    /// `/synth/sample_rate` (Hz), read-only at runtime.
    SynthSampleRate,
    /// `/synth/engine` (text).
    SynthEngine,
    /// `/synth/seed` (integer).
    SynthSeed,
    /// `/synth/realtime` (bool).
    SynthRealtime,
    /// `/synth/anti_alias` (bool).
    SynthAntiAlias,
    /// `/synth/contact_substeps` (sub-steps, even).
    SynthContactSubsteps,
    /// `/noise/enable` (bool).
    NoiseEnable,
    /// `/noise/temperature` (K).
    NoiseTemperature,
    /// `/noise/detector_density` (m/√Hz).
    NoiseDetectorDensity,
    /// `/noise/adc_bits` (bit).
    NoiseAdcBits,
    /// `/noise/adc_range` (m).
    NoiseAdcRange,
    /// `/spectrum/enable` (bool).
    SpectrumEnable,
    /// `/spectrum/size` (samples, a power of two).
    SpectrumSize,
    /// `/spectrum/window` (text).
    SpectrumWindow,
    /// `/spectrum/rate` (Hz).
    SpectrumRate,
    /// `/scope/enable` (bool).
    ScopeEnable,
    /// `/scope/length` (samples).
    ScopeLength,
    /// `/scope/decimation` (samples).
    ScopeDecimation,
    /// `/scope/rate` (Hz).
    ScopeRate,
    /// `/dsp/threads` (threads; 0 = auto), read-only at runtime.
    DspThreads,
    /// `/server/allowed_origins` (list of text).
    ServerAllowedOrigins,
    /// `/server/allowed_hosts` (list of text).
    ServerAllowedHosts,
    /// `/server/max_clients` (clients).
    ServerMaxClients,
    /// `/server/client_queue` (messages).
    ServerClientQueue,
    /// `/server/client_queue_bytes` (bytes).
    ServerClientQueueBytes,
    /// `/server/stall_timeout` (s).
    ServerStallTimeout,
    /// `/inversion/enable` (bool).
    InversionEnable,
    /// `/inversion/method` (text).
    InversionMethod,
    /// `/inversion/harmonic_a` (harmonic number).
    InversionHarmonicA,
    /// `/inversion/harmonic_b` (harmonic number).
    InversionHarmonicB,
    /// `/inversion/averaging` (frames).
    InversionAveraging,
    /// `/inversion/points` (samples).
    InversionPoints,
    /// `/scan/enable` (bool).
    ScanEnable,
    /// `/scan/size` (m).
    ScanSize,
    /// `/scan/pixels` (pixels).
    ScanPixels,
    /// `/scan/line_rate` (Hz).
    ScanLineRate,
    /// `/scan/x` (m).
    ScanX,
    /// `/scan/y` (m).
    ScanY,
    /// `/feedback/enable` (bool).
    FeedbackEnable,
    /// `/feedback/setpoint` (m).
    FeedbackSetpoint,
    /// `/feedback/proportional` (1).
    FeedbackProportional,
    /// `/feedback/integral` (1/s).
    FeedbackIntegral,
    /// `/sweeper/parameter` (text).
    SweeperParameter,
    /// `/sweeper/start` (the parameter's unit).
    SweeperStart,
    /// `/sweeper/stop` (the parameter's unit).
    SweeperStop,
    /// `/sweeper/points` (points).
    SweeperPoints,
    /// `/sweeper/scale` (text).
    SweeperScale,
    /// `/sweeper/direction` (text).
    SweeperDirection,
    /// `/sweeper/settling` (s).
    SweeperSettling,
    /// `/sweeper/averaging` (frames).
    SweeperAveraging,
    /// `/sweeper/enable` (bool).
    SweeperEnable,
    /// `/inclusions/N/enable` (bool).
    InclusionEnable(usize),
    /// `/inclusions/N/shape` (text).
    InclusionShape(usize),
    /// `/inclusions/N/x` (m).
    InclusionX(usize),
    /// `/inclusions/N/y` (m).
    InclusionY(usize),
    /// `/inclusions/N/width` (m).
    InclusionWidth(usize),
    /// `/inclusions/N/length` (m).
    InclusionLength(usize),
    /// `/inclusions/N/height` (m).
    InclusionHeight(usize),
    /// `/inclusions/N/youngs_modulus` (Pa).
    InclusionYoungsModulus(usize),
    /// `/inclusions/N/relative_modulus` (1).
    InclusionRelativeModulus(usize),
    /// `/inclusions/N/poisson` (1).
    InclusionPoisson(usize),
    /// `/demods/N/enable` (bool).
    DemodEnable(usize),
    /// `/demods/N/harmonic` (integer).
    DemodHarmonic(usize),
    /// `/demods/N/order` (integer).
    DemodOrder(usize),
    /// `/demods/N/timeconstant` (s).
    DemodTimeconstant(usize),
    /// `/demods/N/rate` (Hz).
    DemodRate(usize),
}

/// What values a node takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// A finite number inside the range.
    Float(Range),
    /// An integer with `min ≤ value ≤ max`.
    Integer {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// `true` or `false`.
    Bool,
    /// A power of two with `min ≤ value ≤ max` (both powers of two).
    PowerOfTwo {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// An even integer with `min ≤ value ≤ max` (both even).
    Even {
        /// Smallest allowed value.
        min: u64,
        /// Largest allowed value.
        max: u64,
    },
    /// One of these strings.
    Text(&'static [&'static str]),
    /// A list of 1 to `max_len` finite numbers, each inside `entry`.
    FloatList {
        /// Range of each entry.
        entry: Range,
        /// Longest list allowed.
        max_len: usize,
    },
    /// A list of 0 to `max_len` strings, each of 1 to `max_bytes` bytes and of the form
    /// `entry` (a JSON array of strings; a TOML array of strings in files).
    TextList {
        /// Longest list allowed.
        max_len: usize,
        /// Longest entry allowed, in bytes (UTF-8).
        max_bytes: usize,
        /// The form every entry takes.
        entry: TextEntry,
    },
}

impl Kind {
    /// The name of the value's type in the protocol's `list` (`type`).
    pub fn type_name(self) -> &'static str {
        match self {
            Kind::Float(_) => "float",
            Kind::Integer { .. } | Kind::PowerOfTwo { .. } | Kind::Even { .. } => "integer",
            Kind::Bool => "bool",
            Kind::Text(_) => "text",
            Kind::FloatList { .. } => "float_list",
            Kind::TextList { .. } => "text_list",
        }
    }
}

/// The form each entry of a [`Kind::TextList`] takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextEntry {
    /// A web origin as browsers send it in the `Origin` header: `http://` or `https://`, then
    /// a non-empty host with an optional `:port`, and nothing after it (no path, not even a
    /// trailing `/`, no query, fragment or user name). A wildcard (`"*"`) is no origin.
    Origin,
    /// A DNS host name as a `Host` header names it, without a port: labels of letters,
    /// digits and `-` separated by dots. No wildcard.
    Host,
}

impl TextEntry {
    /// What an entry looks like, for "allowed …".
    pub fn describe(self) -> &'static str {
        match self {
            TextEntry::Origin => "an origin scheme://host[:port] with scheme http or https",
            TextEntry::Host => "a host name such as lab-pc.example.org, without a port",
        }
    }

    /// Why `entry` is not of this form (a phrase that follows "is"), or `None` if it is.
    /// The length in bytes is checked by the list, not here.
    pub fn problem(self, entry: &str) -> Option<&'static str> {
        match self {
            TextEntry::Origin => origin_problem(entry),
            TextEntry::Host => host_problem(entry),
        }
    }
}

fn host_problem(entry: &str) -> Option<&'static str> {
    if entry.contains('*') {
        return Some(
            "not allowed (wildcards are not supported: a pattern would let names you do not \
             control reach the instrument)",
        );
    }
    if entry.contains(':') {
        return Some("not a host name (no port or scheme: the port never matters here)");
    }
    let label_ok = |l: &str| {
        !l.is_empty()
            && l.len() <= 63
            && !l.starts_with('-')
            && !l.ends_with('-')
            && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
    };
    if !entry.split('.').all(label_ok) {
        return Some(
            "not a host name (labels of letters, digits and \"-\" separated by single dots)",
        );
    }
    None
}

fn origin_problem(entry: &str) -> Option<&'static str> {
    if entry == "*" {
        return Some(
            "not allowed (a wildcard would let any web page drive the instrument; list each \
             origin as scheme://host[:port])",
        );
    }
    let Some(authority) = entry
        .strip_prefix("http://")
        .or_else(|| entry.strip_prefix("https://"))
    else {
        return Some("not an origin (it must start with \"http://\" or \"https://\")");
    };
    if authority.is_empty() {
        return Some("not an origin (the host is missing)");
    }
    if authority.contains('/') {
        return Some(
            "not an origin (it has a path, a \"/\" after the host; an origin is \
             scheme://host[:port], without even a trailing \"/\")",
        );
    }
    if authority.contains(['?', '#']) {
        return Some("not an origin (it has a query or fragment after the host)");
    }
    if authority.contains('@') {
        return Some("not an origin (it has a user name before the host)");
    }
    if authority.contains('*') {
        return Some(
            "not allowed (wildcards are not supported: each entry is one exact origin, and a \
             pattern would let web pages you do not control drive the instrument)",
        );
    }
    if authority
        .chars()
        .any(|c| c.is_whitespace() || c.is_control())
    {
        return Some("not an origin (it contains white space or control characters)");
    }
    // An IPv6 host is bracketed (`[::1]`); otherwise a colon starts the port.
    let (host, port) = if let Some(rest) = authority.strip_prefix('[') {
        let Some((inside, after)) = rest.split_once(']') else {
            return Some("not an origin (the IPv6 host lacks its closing \"]\")");
        };
        if after.is_empty() {
            (inside, None)
        } else if let Some(port) = after.strip_prefix(':') {
            (inside, Some(port))
        } else {
            return Some("not an origin (only \":port\" may follow the IPv6 host)");
        }
    } else {
        match authority.split_once(':') {
            Some((host, port)) => (host, Some(port)),
            None => (authority, None),
        }
    };
    if host.is_empty() {
        return Some("not an origin (the host is missing)");
    }
    if let Some(port) = port {
        let digits = !port.is_empty() && port.bytes().all(|b| b.is_ascii_digit());
        if !digits || port.parse::<u16>().is_err() {
            return Some(
                "not an origin (the port after the host must be a number from 0 to 65535)",
            );
        }
    }
    None
}

/// A node's value once checked for type, in the representation of its [`Kind`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Typed {
    Float(f64),
    Integer(u64),
    Bool(bool),
    Text(&'static str),
    FloatList(Vec<f64>),
    TextList(Vec<String>),
}

impl Typed {
    pub(crate) fn to_json(&self) -> Value {
        match self {
            Typed::Float(x) => Value::from(*x),
            Typed::Integer(n) => Value::from(*n),
            Typed::Bool(b) => Value::from(*b),
            Typed::Text(t) => Value::from(*t),
            Typed::FloatList(list) => Value::from(list.clone()),
            Typed::TextList(list) => Value::from(list.clone()),
        }
    }

    /// The value as a message shows it.
    pub(crate) fn show(&self) -> String {
        match self {
            Typed::Float(x) => number(*x),
            Typed::Integer(n) => n.to_string(),
            Typed::Bool(b) => b.to_string(),
            Typed::Text(t) => format!("{t:?}"),
            Typed::FloatList(list) => {
                // A long list is cut, like any quoted value: its first entries and its length.
                const SHOWN: usize = 16;
                let entries: Vec<String> = list.iter().take(SHOWN).map(|x| number(*x)).collect();
                let more = if list.len() > SHOWN {
                    format!(", … ({} entries)", list.len())
                } else {
                    String::new()
                };
                format!("[{}{more}]", entries.join(", "))
            }
            // Entries may be long and many: shown cut short, like JSON in messages.
            Typed::TextList(_) => show_json(&self.to_json()),
        }
    }
}

impl Field {
    /// Nodes outside the index-keyed tables (inclusions, demodulators), in tree order.
    pub(crate) const SCALARS: [Field; 67] = [
        Field::CantileverF1,
        Field::CantileverK,
        Field::CantileverQ,
        Field::CantileverExtraModes,
        Field::CantileverTipRadius,
        Field::TipYoungsModulus,
        Field::TipPoisson,
        Field::SampleYoungsModulus,
        Field::SamplePoisson,
        Field::DriveFrequency,
        Field::DriveFollowF1,
        Field::DriveFreeAmplitude,
        Field::SurfaceDistance,
        Field::AdhesionEnable,
        Field::AdhesionHamaker,
        Field::AdhesionDistance,
        Field::SynthSampleRate,
        Field::SynthEngine,
        Field::SynthSeed,
        Field::SynthRealtime,
        Field::SynthAntiAlias,
        Field::SynthContactSubsteps,
        Field::NoiseEnable,
        Field::NoiseTemperature,
        Field::NoiseDetectorDensity,
        Field::NoiseAdcBits,
        Field::NoiseAdcRange,
        Field::SpectrumEnable,
        Field::SpectrumSize,
        Field::SpectrumWindow,
        Field::SpectrumRate,
        Field::ScopeEnable,
        Field::ScopeLength,
        Field::ScopeDecimation,
        Field::ScopeRate,
        Field::DspThreads,
        Field::ServerAllowedOrigins,
        Field::ServerAllowedHosts,
        Field::ServerMaxClients,
        Field::ServerClientQueue,
        Field::ServerClientQueueBytes,
        Field::ServerStallTimeout,
        Field::InversionEnable,
        Field::InversionMethod,
        Field::InversionHarmonicA,
        Field::InversionHarmonicB,
        Field::InversionAveraging,
        Field::InversionPoints,
        Field::ScanEnable,
        Field::ScanSize,
        Field::ScanPixels,
        Field::ScanLineRate,
        Field::ScanX,
        Field::ScanY,
        Field::FeedbackEnable,
        Field::FeedbackSetpoint,
        Field::FeedbackProportional,
        Field::FeedbackIntegral,
        Field::SweeperParameter,
        Field::SweeperStart,
        Field::SweeperStop,
        Field::SweeperPoints,
        Field::SweeperScale,
        Field::SweeperDirection,
        Field::SweeperSettling,
        Field::SweeperAveraging,
        Field::SweeperEnable,
    ];

    /// The nodes of inclusion `index`, in tree order.
    pub(crate) fn inclusion(index: usize) -> [Field; 10] {
        [
            Field::InclusionEnable(index),
            Field::InclusionShape(index),
            Field::InclusionX(index),
            Field::InclusionY(index),
            Field::InclusionWidth(index),
            Field::InclusionLength(index),
            Field::InclusionHeight(index),
            Field::InclusionYoungsModulus(index),
            Field::InclusionRelativeModulus(index),
            Field::InclusionPoisson(index),
        ]
    }

    /// The nodes of demodulator `index`, in tree order.
    pub(crate) fn demod(index: usize) -> [Field; 5] {
        [
            Field::DemodEnable(index),
            Field::DemodHarmonic(index),
            Field::DemodOrder(index),
            Field::DemodTimeconstant(index),
            Field::DemodRate(index),
        ]
    }

    /// The node path, e.g. `/sample/youngs_modulus`, `/demods/3/harmonic`.
    pub fn path(self) -> String {
        let fixed = match self {
            Field::CantileverF1 => "/cantilever/f1",
            Field::CantileverK => "/cantilever/k",
            Field::CantileverQ => "/cantilever/q",
            Field::CantileverExtraModes => "/cantilever/extra_modes",
            Field::CantileverTipRadius => "/cantilever/tip_radius",
            Field::TipYoungsModulus => "/tip/youngs_modulus",
            Field::TipPoisson => "/tip/poisson",
            Field::SampleYoungsModulus => "/sample/youngs_modulus",
            Field::SamplePoisson => "/sample/poisson",
            Field::DriveFrequency => "/drive/frequency",
            Field::DriveFollowF1 => "/drive/follow_f1",
            Field::DriveFreeAmplitude => "/drive/free_amplitude",
            Field::SurfaceDistance => "/surface/distance",
            Field::AdhesionEnable => "/adhesion/enable",
            Field::AdhesionHamaker => "/adhesion/hamaker",
            Field::AdhesionDistance => "/adhesion/distance",
            Field::SynthSampleRate => "/synth/sample_rate",
            Field::SynthEngine => "/synth/engine",
            Field::SynthSeed => "/synth/seed",
            Field::SynthRealtime => "/synth/realtime",
            Field::SynthAntiAlias => "/synth/anti_alias",
            Field::SynthContactSubsteps => "/synth/contact_substeps",
            Field::NoiseEnable => "/noise/enable",
            Field::NoiseTemperature => "/noise/temperature",
            Field::NoiseDetectorDensity => "/noise/detector_density",
            Field::NoiseAdcBits => "/noise/adc_bits",
            Field::NoiseAdcRange => "/noise/adc_range",
            Field::SpectrumEnable => "/spectrum/enable",
            Field::SpectrumSize => "/spectrum/size",
            Field::SpectrumWindow => "/spectrum/window",
            Field::SpectrumRate => "/spectrum/rate",
            Field::ScopeEnable => "/scope/enable",
            Field::ScopeLength => "/scope/length",
            Field::ScopeDecimation => "/scope/decimation",
            Field::ScopeRate => "/scope/rate",
            Field::DspThreads => "/dsp/threads",
            Field::ServerAllowedOrigins => "/server/allowed_origins",
            Field::ServerAllowedHosts => "/server/allowed_hosts",
            Field::ServerMaxClients => "/server/max_clients",
            Field::ServerClientQueue => "/server/client_queue",
            Field::ServerClientQueueBytes => "/server/client_queue_bytes",
            Field::ServerStallTimeout => "/server/stall_timeout",
            Field::InversionEnable => "/inversion/enable",
            Field::InversionMethod => "/inversion/method",
            Field::InversionHarmonicA => "/inversion/harmonic_a",
            Field::InversionHarmonicB => "/inversion/harmonic_b",
            Field::InversionAveraging => "/inversion/averaging",
            Field::InversionPoints => "/inversion/points",
            Field::ScanEnable => "/scan/enable",
            Field::ScanSize => "/scan/size",
            Field::ScanPixels => "/scan/pixels",
            Field::ScanLineRate => "/scan/line_rate",
            Field::ScanX => "/scan/x",
            Field::ScanY => "/scan/y",
            Field::FeedbackEnable => "/feedback/enable",
            Field::FeedbackSetpoint => "/feedback/setpoint",
            Field::FeedbackProportional => "/feedback/proportional",
            Field::FeedbackIntegral => "/feedback/integral",
            Field::SweeperParameter => "/sweeper/parameter",
            Field::SweeperStart => "/sweeper/start",
            Field::SweeperStop => "/sweeper/stop",
            Field::SweeperPoints => "/sweeper/points",
            Field::SweeperScale => "/sweeper/scale",
            Field::SweeperDirection => "/sweeper/direction",
            Field::SweeperSettling => "/sweeper/settling",
            Field::SweeperAveraging => "/sweeper/averaging",
            Field::SweeperEnable => "/sweeper/enable",
            Field::InclusionEnable(i) => return format!("/inclusions/{i}/enable"),
            Field::InclusionShape(i) => return format!("/inclusions/{i}/shape"),
            Field::InclusionX(i) => return format!("/inclusions/{i}/x"),
            Field::InclusionY(i) => return format!("/inclusions/{i}/y"),
            Field::InclusionWidth(i) => return format!("/inclusions/{i}/width"),
            Field::InclusionLength(i) => return format!("/inclusions/{i}/length"),
            Field::InclusionHeight(i) => return format!("/inclusions/{i}/height"),
            Field::InclusionYoungsModulus(i) => return format!("/inclusions/{i}/youngs_modulus"),
            Field::InclusionRelativeModulus(i) => {
                return format!("/inclusions/{i}/relative_modulus");
            }
            Field::InclusionPoisson(i) => return format!("/inclusions/{i}/poisson"),
            Field::DemodEnable(i) => return format!("/demods/{i}/enable"),
            Field::DemodHarmonic(i) => return format!("/demods/{i}/harmonic"),
            Field::DemodOrder(i) => return format!("/demods/{i}/order"),
            Field::DemodTimeconstant(i) => return format!("/demods/{i}/timeconstant"),
            Field::DemodRate(i) => return format!("/demods/{i}/rate"),
        };
        fixed.to_owned()
    }

    /// SI unit: `Hz`, `N/m`, `m`, `Pa`, `s`, `1/s`, `K`, `m/√Hz`, `J` (the Hamaker
    /// constant), `1` (dimensionless numbers and counts), `bit` (ADC resolution), `samples`
    /// (FFT and trace lengths, decimation, points of the force waveform), `frames`
    /// (demodulator frames averaged), `pixels` (per scan line), `clients`, `messages`,
    /// `sub-steps` (the coupled engine's per sample in contact), or
    /// empty for text, lists of text, booleans and the inversion's harmonic numbers.
    pub fn unit(self) -> &'static str {
        match self {
            Field::CantileverF1
            | Field::DriveFrequency
            | Field::SynthSampleRate
            | Field::SpectrumRate
            | Field::ScopeRate
            | Field::ScanLineRate
            | Field::DemodRate(_) => "Hz",
            Field::CantileverK => "N/m",
            Field::CantileverTipRadius
            | Field::DriveFreeAmplitude
            | Field::SurfaceDistance
            | Field::AdhesionDistance
            | Field::NoiseAdcRange
            | Field::ScanSize
            | Field::ScanX
            | Field::ScanY
            | Field::FeedbackSetpoint
            | Field::InclusionX(_)
            | Field::InclusionY(_)
            | Field::InclusionWidth(_)
            | Field::InclusionLength(_)
            | Field::InclusionHeight(_) => "m",
            Field::NoiseTemperature => "K",
            Field::AdhesionHamaker => "J",
            Field::NoiseDetectorDensity => "m/√Hz",
            Field::NoiseAdcBits => "bit",
            Field::SpectrumSize
            | Field::ScopeLength
            | Field::ScopeDecimation
            | Field::InversionPoints => "samples",
            Field::InversionAveraging | Field::SweeperAveraging => "frames",
            Field::SweeperPoints => "points",
            Field::SweeperSettling => "s",
            Field::ScanPixels => "pixels",
            Field::ServerMaxClients => "clients",
            Field::DspThreads => "threads",
            Field::SynthContactSubsteps => "sub-steps",
            Field::ServerClientQueue => "messages",
            Field::ServerClientQueueBytes => "bytes",
            Field::TipYoungsModulus
            | Field::SampleYoungsModulus
            | Field::InclusionYoungsModulus(_) => "Pa",
            Field::DemodTimeconstant(_) | Field::ServerStallTimeout => "s",
            Field::FeedbackIntegral => "1/s",
            Field::CantileverQ
            | Field::CantileverExtraModes
            | Field::TipPoisson
            | Field::SamplePoisson
            | Field::InclusionPoisson(_)
            | Field::InclusionRelativeModulus(_)
            | Field::FeedbackProportional
            | Field::SynthSeed
            | Field::DemodHarmonic(_)
            | Field::DemodOrder(_) => "1",
            Field::SynthEngine
            | Field::SweeperParameter
            | Field::SweeperStart
            | Field::SweeperStop
            | Field::SweeperScale
            | Field::SweeperDirection
            | Field::SweeperEnable
            | Field::SynthRealtime
            | Field::SynthAntiAlias
            | Field::DriveFollowF1
            | Field::AdhesionEnable
            | Field::NoiseEnable
            | Field::SpectrumEnable
            | Field::SpectrumWindow
            | Field::ScopeEnable
            | Field::ServerAllowedOrigins
            | Field::ServerAllowedHosts
            | Field::InversionEnable
            | Field::InversionMethod
            | Field::InversionHarmonicA
            | Field::InversionHarmonicB
            | Field::ScanEnable
            | Field::FeedbackEnable
            | Field::InclusionEnable(_)
            | Field::InclusionShape(_)
            | Field::DemodEnable(_) => "",
        }
    }

    /// Whether the protocol's `set` may change the node while the instrument runs. Only the
    /// sample rate is fixed (every buffer, filter and FFT plan is sized from it), and the DSP
    /// stage's thread count (its threads start with the pipeline).
    pub fn writable(self) -> bool {
        !matches!(self, Field::SynthSampleRate | Field::DspThreads)
    }

    /// The values the node takes, without the limits that depend on other nodes.
    pub fn kind(self) -> Kind {
        match self {
            Field::CantileverF1 | Field::DriveFrequency => Kind::Float(FREQUENCY),
            Field::CantileverK => Kind::Float(STIFFNESS),
            Field::CantileverQ => Kind::FloatList {
                entry: QUALITY,
                max_len: MAX_MODES,
            },
            Field::CantileverExtraModes => Kind::Integer {
                min: 0,
                max: MAX_MODES as u64 - 1,
            },
            Field::CantileverTipRadius => Kind::Float(TIP_RADIUS),
            Field::TipYoungsModulus
            | Field::SampleYoungsModulus
            | Field::InclusionYoungsModulus(_) => Kind::Float(MODULUS),
            Field::TipPoisson | Field::SamplePoisson | Field::InclusionPoisson(_) => {
                Kind::Float(POISSON)
            }
            Field::InclusionRelativeModulus(_) => Kind::Float(RELATIVE_MODULUS),
            Field::DriveFreeAmplitude | Field::SurfaceDistance => Kind::Float(LENGTH),
            Field::AdhesionHamaker => Kind::Float(HAMAKER),
            Field::AdhesionDistance => Kind::Float(INTERMOLECULAR_DISTANCE),
            Field::SynthSampleRate => Kind::Float(SAMPLE_RATE),
            Field::SynthEngine => Kind::Text(Engine::NAMES),
            Field::SynthSeed => Kind::Integer {
                min: 0,
                max: u64::MAX,
            },
            Field::SynthContactSubsteps => Kind::Even {
                min: MIN_CONTACT_SUBSTEPS.into(),
                max: MAX_CONTACT_SUBSTEPS.into(),
            },
            Field::SynthRealtime
            | Field::SynthAntiAlias
            | Field::DriveFollowF1
            | Field::AdhesionEnable
            | Field::NoiseEnable
            | Field::SpectrumEnable
            | Field::ScopeEnable
            | Field::InversionEnable
            | Field::ScanEnable
            | Field::FeedbackEnable
            | Field::SweeperEnable
            | Field::InclusionEnable(_)
            | Field::DemodEnable(_) => Kind::Bool,
            Field::SweeperParameter => Kind::Text(SweepParameter::NAMES),
            Field::SweeperScale => Kind::Text(SweepScale::NAMES),
            Field::SweeperDirection => Kind::Text(SweepDirection::NAMES),
            Field::SweeperStart | Field::SweeperStop => Kind::Float(SWEEP_VALUE),
            Field::SweeperPoints => Kind::Integer {
                min: 2,
                max: MAX_SWEEP_POINTS.into(),
            },
            Field::SweeperSettling => Kind::Float(SWEEP_SETTLING),
            Field::SweeperAveraging => Kind::Integer {
                min: 1,
                max: MAX_SWEEP_AVERAGING.into(),
            },
            Field::NoiseTemperature => Kind::Float(TEMPERATURE),
            Field::NoiseDetectorDensity => Kind::Float(DETECTOR_DENSITY),
            Field::NoiseAdcBits => Kind::Integer {
                min: 0,
                max: MAX_ADC_BITS.into(),
            },
            Field::NoiseAdcRange => Kind::Float(ADC_RANGE),
            Field::SpectrumSize => Kind::PowerOfTwo {
                min: MIN_SPECTRUM_SIZE.into(),
                max: MAX_SPECTRUM_SIZE.into(),
            },
            Field::SpectrumWindow => Kind::Text(SpectrumWindow::NAMES),
            Field::SpectrumRate => Kind::Float(SPECTRUM_RATE),
            Field::ScopeLength => Kind::Integer {
                min: MIN_SCOPE_LENGTH.into(),
                max: MAX_SCOPE_LENGTH.into(),
            },
            Field::ScopeDecimation => Kind::Integer {
                min: 1,
                max: MAX_SCOPE_DECIMATION.into(),
            },
            Field::ScopeRate => Kind::Float(SCOPE_RATE),
            Field::ServerAllowedOrigins => Kind::TextList {
                max_len: MAX_ALLOWED_ORIGINS,
                max_bytes: MAX_ORIGIN_BYTES,
                entry: TextEntry::Origin,
            },
            Field::ServerAllowedHosts => Kind::TextList {
                max_len: MAX_ALLOWED_ORIGINS,
                max_bytes: MAX_HOST_BYTES,
                entry: TextEntry::Host,
            },
            Field::ServerMaxClients => Kind::Integer {
                min: 1,
                max: MAX_CLIENTS.into(),
            },
            Field::DspThreads => Kind::Integer {
                min: 0,
                max: MAX_DSP_THREADS.into(),
            },
            Field::ServerClientQueueBytes => Kind::Integer {
                min: MIN_CLIENT_QUEUE_BYTES,
                max: MAX_CLIENT_QUEUE_BYTES,
            },
            Field::ServerClientQueue => Kind::Integer {
                min: MIN_CLIENT_QUEUE.into(),
                max: MAX_CLIENT_QUEUE.into(),
            },
            Field::ServerStallTimeout => Kind::Float(STALL_TIMEOUT),
            Field::InversionMethod => Kind::Text(InversionMethod::NAMES),
            Field::InversionHarmonicA | Field::InversionHarmonicB => Kind::Integer {
                min: MIN_INVERSION_HARMONIC.into(),
                max: MAX_HARMONIC.into(),
            },
            Field::InversionAveraging => Kind::Integer {
                min: 1,
                max: MAX_INVERSION_AVERAGING.into(),
            },
            Field::InversionPoints => Kind::Integer {
                min: MIN_INVERSION_POINTS.into(),
                max: MAX_INVERSION_POINTS.into(),
            },
            Field::ScanSize => Kind::Float(SCAN_SIZE),
            Field::ScanPixels => Kind::Integer {
                min: MIN_SCAN_PIXELS.into(),
                max: MAX_SCAN_PIXELS.into(),
            },
            Field::ScanLineRate => Kind::Float(LINE_RATE),
            Field::ScanX | Field::ScanY | Field::InclusionX(_) | Field::InclusionY(_) => {
                Kind::Float(POSITION)
            }
            Field::FeedbackSetpoint => Kind::Float(SETPOINT),
            Field::FeedbackProportional => Kind::Float(PROPORTIONAL_GAIN),
            Field::FeedbackIntegral => Kind::Float(INTEGRAL_GAIN),
            Field::InclusionShape(_) => Kind::Text(InclusionShape::NAMES),
            Field::InclusionWidth(_) | Field::InclusionLength(_) => Kind::Float(EXTENT),
            Field::InclusionHeight(_) => Kind::Float(HEIGHT),
            Field::DemodHarmonic(_) => Kind::Integer {
                min: 0,
                max: MAX_HARMONIC.into(),
            },
            Field::DemodOrder(_) => Kind::Integer {
                min: 1,
                max: MAX_FILTER_ORDER.into(),
            },
            Field::DemodTimeconstant(_) => Kind::Float(TIME_CONSTANT),
            Field::DemodRate(_) => Kind::Float(OUTPUT_RATE),
        }
    }

    /// One sentence saying what the node is, with its unit.
    pub fn description(self) -> String {
        let fixed = match self {
            Field::CantileverF1 => {
                "First flexural resonance frequency f1 of the cantilever, in Hz."
            }
            Field::CantileverK => {
                "Static spring constant of the cantilever at the tip (3EI/L³), in N/m."
            }
            Field::CantileverQ => {
                "Quality factor of each cantilever mode from the first on (dimensionless); the list's length is the number of modes with a given Q."
            }
            Field::CantileverExtraModes => {
                "Number of modes simulated beyond the q list, damped by Rayleigh damping (Eq. B.7) fitted to the last two q values."
            }
            Field::CantileverTipRadius => "Radius R of the tip apex, in m.",
            Field::TipYoungsModulus => "Young's modulus of the tip material, in Pa.",
            Field::TipPoisson => "Poisson ratio of the tip material (dimensionless).",
            Field::SampleYoungsModulus => "Young's modulus of the sample under the tip, in Pa.",
            Field::SamplePoisson => "Poisson ratio of the sample under the tip (dimensionless).",
            Field::DriveFrequency => {
                "Drive frequency Ω/2π of the base excitation, in Hz; below half the sample rate. Setting it to another value than /cantilever/f1 turns /drive/follow_f1 off."
            }
            Field::DriveFollowF1 => {
                "The drive frequency follows /cantilever/f1, like an instrument's auto-tune (true), or stays where /drive/frequency puts it (false); setting /drive/frequency to another value than f1 turns it off."
            }
            Field::DriveFreeAmplitude => {
                "Free (non-contact) peak tip amplitude at the drive frequency, in m."
            }
            Field::AdhesionEnable => {
                "DMT adhesion (physics.md §6): the van der Waals pull −HR/(6(a0 + gap)²) above the surface and the constant −HR/(6a0²) in contact, added to the Hertz force. The coupled engine only: the paper engine's 1-DOF orbit has none (a warning says so)."
            }
            Field::AdhesionHamaker => {
                "Hamaker constant H of the tip, sample and medium between them, in J (silicon on silicon in air ≈ 6.4e-20 J)."
            }
            Field::AdhesionDistance => {
                "Intermolecular distance a0, in m: the gap at which the attraction saturates (0.165 nm in the literature's tapping simulations)."
            }
            Field::SurfaceDistance => {
                "Distance A_set from the tip's rest position to the sample surface, in m; the tip taps when it is below the amplitude."
            }
            Field::SynthSampleRate => {
                "Photodiode sample rate of the synthesiser, in Hz; fixed at start (config file only)."
            }
            Field::SynthEngine => {
                "Tip-force engine: \"paper\" (cut-cosine pulses from the 1-DOF model, the paper's method); \"coupled\" (all modes integrated sample by sample with the Hertz force from the instantaneous tip position)."
            }
            Field::SynthSeed => {
                "Seed of every random source (integer); the same seed and settings give the same stream."
            }
            Field::SynthRealtime => {
                "Pace synthesis to the wall clock (true) or run as fast as possible (false)."
            }
            Field::SynthContactSubsteps => {
                "Sub-steps of a sample where the coupled engine resolves the contact (near and in contact; clear of the surface a sample is one step), in sub-steps, an even number: fewer is faster and less accurate (errors against the offline orbit per count in docs/ft-afm.md); the paper engine ignores it."
            }
            Field::SynthAntiAlias => {
                "The ADC's anti-alias filter (true): the signal is integrated over a triangle window (sinc^2, zero at every multiple of 2 x sample_rate), taken at twice the sample rate, decimated by a halfband FIR and the window's droop compensated: flat to 0.4 x sample_rate, >= 88 dB down from 0.6 x sample_rate, delay 21.5 samples (compensated in the drive phase); false samples the signal directly, with every alias."
            }
            Field::NoiseEnable => "Switches all noise sources on (true) or off (false).",
            Field::NoiseTemperature => {
                "Temperature of the cantilever's thermal (Brownian) noise, in K, applied to every mode by fluctuation–dissipation; 0 turns thermal noise off."
            }
            Field::NoiseDetectorDensity => {
                "One-sided density of the white detector noise added to the deflection signal, in m/√Hz; 0 turns it off."
            }
            Field::NoiseAdcBits => {
                "Resolution of the ADC that digitises the deflection signal, in bits; 0 means no quantisation."
            }
            Field::NoiseAdcRange => {
                "Full scale of the ADC input, ±adc_range, in (nominal) m; samples beyond it clip and are counted."
            }
            Field::SpectrumEnable => {
                "Computes and sends the spectrum of the deflection signal (true) or not (false)."
            }
            Field::SpectrumSize => {
                "FFT length of the spectrum, in samples: a power of two from 256 to 1048576."
            }
            Field::SpectrumWindow => {
                "Window applied to each spectrum frame: \"rectangular\", \"hann\", \"blackman_harris\" or \"flat_top\"."
            }
            Field::SpectrumRate => {
                "Spectra computed per second, in Hz; frames may overlap, at most the sample rate."
            }
            Field::ScopeEnable => {
                "Takes and sends time-domain traces of the raw photodiode signal, the scope stream (true), or not (false)."
            }
            Field::ScopeLength => {
                "Samples per scope trace, counted after decimation, in samples: 16 to 65536."
            }
            Field::ScopeDecimation => {
                "Scope decimation, in samples: each trace keeps every Nth photodiode sample (1 keeps all)."
            }
            Field::ScopeRate => {
                "Scope traces per second, in Hz; traces must not overlap, so length × decimation / sample rate ≤ 1 / rate."
            }
            Field::ServerAllowedOrigins => {
                "Web origins (scheme://host[:port], e.g. \"http://localhost:3000\") besides the server's own whose pages may open the WebSocket; any other origin is refused with 403; no \"*\" wildcard. A change applies to connections opened from then on."
            }
            Field::DspThreads => {
                "Threads of the DSP stage, in threads: the lock-in bank is split between them (each runs a share of the demodulators on every block; the outputs are bit for bit those of one thread); 0 (auto) adds threads only on a machine with more than 2 cores, one per core beyond two, at most 4 in all; fixed at start (config file only)."
            }
            Field::ServerMaxClients => {
                "Most WebSocket clients connected at once, in clients; beyond it the handshake is refused with 503. A change applies to connections opened from then on."
            }
            Field::ServerClientQueue => {
                "Length of each client's outgoing queue, in messages; a client further behind loses its own messages (counted, seen as gaps in seq). A change applies to connections opened from then on."
            }
            Field::ServerClientQueueBytes => {
                "Most bytes queued for each client, in bytes (one message larger than this still goes when its queue is empty); a client further behind loses its own messages (counted, seen as gaps in seq). A change applies to sends from then on."
            }
            Field::ServerAllowedHosts => {
                "Host names besides loopback names and IP addresses by which the server may be reached (e.g. \"lab-pc.example.org\"); a request whose Host header names anything else is refused with 403, which stops DNS rebinding. A change applies to requests from then on."
            }
            Field::ServerStallTimeout => {
                "A client whose socket accepts nothing for this long, in s, is disconnected (close 1008 \"stalled\"). A change applies from then on."
            }
            Field::InversionEnable => {
                "Reconstructs the tip–sample force live from the demodulator outputs and sends it, the force stream (true), or not (false)."
            }
            Field::InversionMethod => {
                "Force reconstruction: \"full\" divides every usable harmonic by the cantilever's transfer function (Stark et al. 2002); \"two_harmonic\" takes the width τ and peak F of the cut cosine from two harmonics (the paper's Sec. 3)."
            }
            Field::InversionHarmonicA => {
                "First of the two harmonics of the two-harmonic method, and an anchor of the full method's fit of missing harmonics (a harmonic number, 2 to 10000); while the inversion is enabled an enabled demodulator must measure it."
            }
            Field::InversionHarmonicB => {
                "Second of the two harmonics of the two-harmonic method, and an anchor of the full method's fit of missing harmonics (a harmonic number, 2 to 10000, not harmonic_a); while the inversion is enabled an enabled demodulator must measure it."
            }
            Field::InversionAveraging => {
                "Demodulator frames averaged per force estimate, in frames; 1 gives one estimate per demodulator frame."
            }
            Field::InversionPoints => {
                "Points of the reconstructed force waveform over one drive period, in samples: 16 to 4096."
            }
            Field::ScanEnable => {
                "Raster-scans the tip over the sample map and sends the image stream (true), or rests it over the base material at /surface/distance (false)."
            }
            Field::ScanSize => "Side of the square scan area, in m, centred on /scan/x, /scan/y.",
            Field::ScanPixels => {
                "Pixels per scan line, and lines per frame (the image is square), in pixels: 8 to 1024."
            }
            Field::ScanLineRate => {
                "Scan lines per second, trace and retrace together, in Hz; each pixel must last at least 10 drive periods, and 2 × pixels × line_rate ≤ 20000 pixels per second."
            }
            Field::ScanX => {
                "Centre of the scan area in sample coordinates, x, in m (x grows to the right along a trace)."
            }
            Field::ScanY => {
                "Centre of the scan area in sample coordinates, y, in m (line 0 is at the top, the largest y)."
            }
            Field::FeedbackEnable => {
                "The amplitude feedback moves the surface distance to hold the fundamental amplitude at the setpoint while scanning (true), or the distance stays at /surface/distance (false)."
            }
            Field::FeedbackSetpoint => {
                "Photodiode amplitude at the drive frequency the feedback holds, in m (peak, as demodulator harmonic 1 reads it); 0 holds the steady amplitude at /surface/distance over the base material."
            }
            Field::FeedbackProportional => {
                "Proportional gain of the amplitude feedback (dimensionless): m of distance per m of amplitude error."
            }
            Field::FeedbackIntegral => {
                "Integral gain of the amplitude feedback, in 1/s: m of distance per second per m of amplitude error."
            }
            Field::SweeperParameter => {
                "The node a sweep steps: \"/drive/frequency\" (a tune: the base, i.e. piezo, amplitude is held at what gives /drive/free_amplitude at the drive frequency when the sweep starts, so the resonance shows), \"/surface/distance\" (an approach curve), \"/drive/free_amplitude\" or \"/sample/youngs_modulus\"."
            }
            Field::SweeperStart => {
                "First value of a sweep, in the unit of /sweeper/parameter; within that node's range when the sweep starts."
            }
            Field::SweeperStop => {
                "Last value of a sweep, in the unit of /sweeper/parameter; within that node's range when the sweep starts."
            }
            Field::SweeperPoints => {
                "Points of each leg of a sweep, both ends included, in points: 2 to 10000."
            }
            Field::SweeperScale => {
                "Spacing of a sweep's points: \"linear\" or \"log\" (start and stop > 0)."
            }
            Field::SweeperDirection => {
                "Legs of a sweep: \"up\" (start to stop), \"down\" (stop to start) or \"both\" (up, then down: an approach and a retract)."
            }
            Field::SweeperSettling => {
                "Simulated time waited at each point before averaging, in s; 0 waits automatically for mode 1 to ring down and the demodulators' filters to settle, to 1e-3."
            }
            Field::SweeperAveraging => {
                "Demodulator frames averaged at each point of a sweep, in frames: 1 to 100000."
            }
            Field::SweeperEnable => {
                "A sweep runs (true): set true to start one, false to abort it; it turns false by itself when the sweep is done, and the swept node is restored."
            }
            Field::InclusionEnable(i) => {
                return format!(
                    "Inclusion {i} is part of the sample map (true) or absent (false); where inclusions overlap, the higher index is on top."
                );
            }
            Field::InclusionShape(i) => {
                return format!(
                    "Shape of inclusion {i}: \"disc\" (diameter width) or \"rectangle\" (width along x by length along y)."
                );
            }
            Field::InclusionX(i) => {
                return format!("Centre of inclusion {i} in sample coordinates, x, in m.");
            }
            Field::InclusionY(i) => {
                return format!("Centre of inclusion {i} in sample coordinates, y, in m.");
            }
            Field::InclusionWidth(i) => {
                return format!(
                    "Diameter of inclusion {i} if a disc, its extent along x if a rectangle, in m."
                );
            }
            Field::InclusionLength(i) => {
                return format!(
                    "Extent of inclusion {i} along y if a rectangle, in m; a disc does not use it."
                );
            }
            Field::InclusionHeight(i) => {
                return format!(
                    "Height of inclusion {i}'s surface above the base material's, in m; negative is a pit."
                );
            }
            Field::InclusionYoungsModulus(i) => {
                return format!(
                    "Young's modulus of inclusion {i}'s material, in Pa; = /inclusions/{i}/relative_modulus × /sample/youngs_modulus while that is above 0, and setting it makes the inclusion absolute."
                );
            }
            Field::InclusionRelativeModulus(i) => {
                return format!(
                    "Young's modulus of inclusion {i} relative to the base material's (/sample/youngs_modulus), so a change of sample keeps the contrast; 0: absolute (/inclusions/{i}/youngs_modulus)."
                );
            }
            Field::InclusionPoisson(i) => {
                return format!("Poisson ratio of inclusion {i}'s material (dimensionless).");
            }
            Field::DemodEnable(i) => {
                return format!("Demodulator {i} produces output (true) or is idle (false).");
            }
            Field::DemodHarmonic(i) => {
                return format!(
                    "Harmonic k of the drive frequency that demodulator {i} measures (dimensionless, 0 is the mean); k × drive frequency must stay below half the sample rate while enabled."
                );
            }
            Field::DemodOrder(i) => {
                return format!(
                    "Order of demodulator {i}'s low-pass filter, the number of cascaded first-order sections (dimensionless)."
                );
            }
            Field::DemodTimeconstant(i) => {
                return format!(
                    "Time constant of each first-order low-pass section of demodulator {i}, in s; at least one sample period."
                );
            }
            Field::DemodRate(i) => {
                return format!("Output rate of demodulator {i}, in Hz; at most the sample rate.");
            }
        };
        fixed.to_owned()
    }

    /// The node's current value; `None` only for an inclusion or demodulator index the
    /// settings lack.
    pub(crate) fn read(self, s: &Settings) -> Option<Typed> {
        Some(match self {
            Field::CantileverF1 => Typed::Float(s.cantilever.f1),
            Field::CantileverK => Typed::Float(s.cantilever.k),
            Field::CantileverQ => Typed::FloatList(s.cantilever.q.clone()),
            Field::CantileverExtraModes => Typed::Integer(s.cantilever.extra_modes as u64),
            Field::CantileverTipRadius => Typed::Float(s.cantilever.tip_radius),
            Field::TipYoungsModulus => Typed::Float(s.tip.youngs_modulus),
            Field::TipPoisson => Typed::Float(s.tip.poisson),
            Field::SampleYoungsModulus => Typed::Float(s.sample.youngs_modulus),
            Field::SamplePoisson => Typed::Float(s.sample.poisson),
            Field::DriveFrequency => Typed::Float(s.drive.frequency),
            Field::DriveFollowF1 => Typed::Bool(s.drive.follow_f1),
            Field::DriveFreeAmplitude => Typed::Float(s.drive.free_amplitude),
            Field::SurfaceDistance => Typed::Float(s.surface.distance),
            Field::AdhesionEnable => Typed::Bool(s.adhesion.enable),
            Field::AdhesionHamaker => Typed::Float(s.adhesion.hamaker),
            Field::AdhesionDistance => Typed::Float(s.adhesion.distance),
            Field::SynthSampleRate => Typed::Float(s.synth.sample_rate),
            Field::SynthEngine => Typed::Text(s.synth.engine.name()),
            Field::SynthSeed => Typed::Integer(s.synth.seed),
            Field::SynthRealtime => Typed::Bool(s.synth.realtime),
            Field::SynthAntiAlias => Typed::Bool(s.synth.anti_alias),
            Field::SynthContactSubsteps => Typed::Integer(s.synth.contact_substeps.into()),
            Field::NoiseEnable => Typed::Bool(s.noise.enable),
            Field::NoiseTemperature => Typed::Float(s.noise.temperature),
            Field::NoiseDetectorDensity => Typed::Float(s.noise.detector_density),
            Field::NoiseAdcBits => Typed::Integer(s.noise.adc_bits.into()),
            Field::NoiseAdcRange => Typed::Float(s.noise.adc_range),
            Field::SpectrumEnable => Typed::Bool(s.spectrum.enable),
            Field::SpectrumSize => Typed::Integer(s.spectrum.size.into()),
            Field::SpectrumWindow => Typed::Text(s.spectrum.window.name()),
            Field::SpectrumRate => Typed::Float(s.spectrum.rate),
            Field::ScopeEnable => Typed::Bool(s.scope.enable),
            Field::ScopeLength => Typed::Integer(s.scope.length.into()),
            Field::ScopeDecimation => Typed::Integer(s.scope.decimation.into()),
            Field::ScopeRate => Typed::Float(s.scope.rate),
            Field::ServerAllowedOrigins => Typed::TextList(s.server.allowed_origins.clone()),
            Field::ServerAllowedHosts => Typed::TextList(s.server.allowed_hosts.clone()),
            Field::ServerClientQueueBytes => Typed::Integer(s.server.client_queue_bytes),
            Field::ServerMaxClients => Typed::Integer(s.server.max_clients.into()),
            Field::DspThreads => Typed::Integer(s.dsp.threads.into()),
            Field::ServerClientQueue => Typed::Integer(s.server.client_queue.into()),
            Field::ServerStallTimeout => Typed::Float(s.server.stall_timeout),
            Field::InversionEnable => Typed::Bool(s.inversion.enable),
            Field::InversionMethod => Typed::Text(s.inversion.method.name()),
            Field::InversionHarmonicA => Typed::Integer(s.inversion.harmonic_a.into()),
            Field::InversionHarmonicB => Typed::Integer(s.inversion.harmonic_b.into()),
            Field::InversionAveraging => Typed::Integer(s.inversion.averaging.into()),
            Field::InversionPoints => Typed::Integer(s.inversion.points.into()),
            Field::ScanEnable => Typed::Bool(s.scan.enable),
            Field::ScanSize => Typed::Float(s.scan.size),
            Field::ScanPixels => Typed::Integer(s.scan.pixels.into()),
            Field::ScanLineRate => Typed::Float(s.scan.line_rate),
            Field::ScanX => Typed::Float(s.scan.x),
            Field::ScanY => Typed::Float(s.scan.y),
            Field::FeedbackEnable => Typed::Bool(s.feedback.enable),
            Field::FeedbackSetpoint => Typed::Float(s.feedback.setpoint),
            Field::FeedbackProportional => Typed::Float(s.feedback.proportional),
            Field::FeedbackIntegral => Typed::Float(s.feedback.integral),
            Field::SweeperParameter => Typed::Text(s.sweeper.parameter.name()),
            Field::SweeperStart => Typed::Float(s.sweeper.start),
            Field::SweeperStop => Typed::Float(s.sweeper.stop),
            Field::SweeperPoints => Typed::Integer(s.sweeper.points.into()),
            Field::SweeperScale => Typed::Text(s.sweeper.scale.name()),
            Field::SweeperDirection => Typed::Text(s.sweeper.direction.name()),
            Field::SweeperSettling => Typed::Float(s.sweeper.settling),
            Field::SweeperAveraging => Typed::Integer(s.sweeper.averaging.into()),
            Field::SweeperEnable => Typed::Bool(s.sweeper.enable),
            Field::InclusionEnable(i) => Typed::Bool(s.inclusions.get(i)?.enable),
            Field::InclusionShape(i) => Typed::Text(s.inclusions.get(i)?.shape.name()),
            Field::InclusionX(i) => Typed::Float(s.inclusions.get(i)?.x),
            Field::InclusionY(i) => Typed::Float(s.inclusions.get(i)?.y),
            Field::InclusionWidth(i) => Typed::Float(s.inclusions.get(i)?.width),
            Field::InclusionLength(i) => Typed::Float(s.inclusions.get(i)?.length),
            Field::InclusionHeight(i) => Typed::Float(s.inclusions.get(i)?.height),
            Field::InclusionYoungsModulus(i) => Typed::Float(s.inclusions.get(i)?.youngs_modulus),
            Field::InclusionRelativeModulus(i) => {
                Typed::Float(s.inclusions.get(i)?.relative_modulus)
            }
            Field::InclusionPoisson(i) => Typed::Float(s.inclusions.get(i)?.poisson),
            Field::DemodEnable(i) => Typed::Bool(s.demods.get(i)?.enable),
            Field::DemodHarmonic(i) => Typed::Integer(s.demods.get(i)?.harmonic.into()),
            Field::DemodOrder(i) => Typed::Integer(s.demods.get(i)?.order.into()),
            Field::DemodTimeconstant(i) => Typed::Float(s.demods.get(i)?.timeconstant),
            Field::DemodRate(i) => Typed::Float(s.demods.get(i)?.rate),
        })
    }

    /// Stores a value already checked against [`Field::kind`]. `None` if the value does not
    /// fit the field (cannot happen after the node's own type check) or the settings lack
    /// the inclusion or demodulator index.
    pub(crate) fn write(self, s: &mut Settings, value: Typed) -> Option<()> {
        match (self, value) {
            (Field::CantileverF1, Typed::Float(x)) => s.cantilever.f1 = x,
            (Field::CantileverK, Typed::Float(x)) => s.cantilever.k = x,
            (Field::CantileverQ, Typed::FloatList(q)) => s.cantilever.q = q,
            (Field::CantileverExtraModes, Typed::Integer(n)) => {
                s.cantilever.extra_modes = usize::try_from(n).ok()?;
            }
            (Field::CantileverTipRadius, Typed::Float(x)) => s.cantilever.tip_radius = x,
            (Field::TipYoungsModulus, Typed::Float(x)) => s.tip.youngs_modulus = x,
            (Field::TipPoisson, Typed::Float(x)) => s.tip.poisson = x,
            (Field::SampleYoungsModulus, Typed::Float(x)) => s.sample.youngs_modulus = x,
            (Field::SamplePoisson, Typed::Float(x)) => s.sample.poisson = x,
            (Field::DriveFrequency, Typed::Float(x)) => s.drive.frequency = x,
            (Field::DriveFollowF1, Typed::Bool(b)) => s.drive.follow_f1 = b,
            (Field::DriveFreeAmplitude, Typed::Float(x)) => s.drive.free_amplitude = x,
            (Field::SurfaceDistance, Typed::Float(x)) => s.surface.distance = x,
            (Field::AdhesionEnable, Typed::Bool(b)) => s.adhesion.enable = b,
            (Field::AdhesionHamaker, Typed::Float(x)) => s.adhesion.hamaker = x,
            (Field::AdhesionDistance, Typed::Float(x)) => s.adhesion.distance = x,
            (Field::SynthSampleRate, Typed::Float(x)) => s.synth.sample_rate = x,
            (Field::SynthEngine, Typed::Text(name)) => s.synth.engine = Engine::from_name(name)?,
            (Field::SynthSeed, Typed::Integer(n)) => s.synth.seed = n,
            (Field::SynthRealtime, Typed::Bool(b)) => s.synth.realtime = b,
            (Field::SynthAntiAlias, Typed::Bool(b)) => s.synth.anti_alias = b,
            (Field::SynthContactSubsteps, Typed::Integer(n)) => {
                s.synth.contact_substeps = u32::try_from(n).ok()?;
            }
            (Field::NoiseEnable, Typed::Bool(b)) => s.noise.enable = b,
            (Field::NoiseTemperature, Typed::Float(x)) => s.noise.temperature = x,
            (Field::NoiseDetectorDensity, Typed::Float(x)) => s.noise.detector_density = x,
            (Field::NoiseAdcBits, Typed::Integer(n)) => {
                s.noise.adc_bits = u32::try_from(n).ok()?;
            }
            (Field::NoiseAdcRange, Typed::Float(x)) => s.noise.adc_range = x,
            (Field::SpectrumEnable, Typed::Bool(b)) => s.spectrum.enable = b,
            (Field::SpectrumSize, Typed::Integer(n)) => {
                s.spectrum.size = u32::try_from(n).ok()?;
            }
            (Field::SpectrumWindow, Typed::Text(name)) => {
                s.spectrum.window = SpectrumWindow::from_name(name)?;
            }
            (Field::SpectrumRate, Typed::Float(x)) => s.spectrum.rate = x,
            (Field::ScopeEnable, Typed::Bool(b)) => s.scope.enable = b,
            (Field::ScopeLength, Typed::Integer(n)) => s.scope.length = u32::try_from(n).ok()?,
            (Field::ScopeDecimation, Typed::Integer(n)) => {
                s.scope.decimation = u32::try_from(n).ok()?;
            }
            (Field::ScopeRate, Typed::Float(x)) => s.scope.rate = x,
            (Field::ServerAllowedOrigins, Typed::TextList(list)) => {
                s.server.allowed_origins = list;
            }
            (Field::ServerAllowedHosts, Typed::TextList(list)) => {
                s.server.allowed_hosts = list;
            }
            (Field::ServerClientQueueBytes, Typed::Integer(n)) => {
                s.server.client_queue_bytes = n;
            }
            (Field::DspThreads, Typed::Integer(n)) => s.dsp.threads = u32::try_from(n).ok()?,
            (Field::ServerMaxClients, Typed::Integer(n)) => {
                s.server.max_clients = u32::try_from(n).ok()?;
            }
            (Field::ServerClientQueue, Typed::Integer(n)) => {
                s.server.client_queue = u32::try_from(n).ok()?;
            }
            (Field::ServerStallTimeout, Typed::Float(x)) => s.server.stall_timeout = x,
            (Field::InversionEnable, Typed::Bool(b)) => s.inversion.enable = b,
            (Field::InversionMethod, Typed::Text(name)) => {
                s.inversion.method = InversionMethod::from_name(name)?;
            }
            (Field::InversionHarmonicA, Typed::Integer(n)) => {
                s.inversion.harmonic_a = u32::try_from(n).ok()?;
            }
            (Field::InversionHarmonicB, Typed::Integer(n)) => {
                s.inversion.harmonic_b = u32::try_from(n).ok()?;
            }
            (Field::InversionAveraging, Typed::Integer(n)) => {
                s.inversion.averaging = u32::try_from(n).ok()?;
            }
            (Field::InversionPoints, Typed::Integer(n)) => {
                s.inversion.points = u32::try_from(n).ok()?;
            }
            (Field::ScanEnable, Typed::Bool(b)) => s.scan.enable = b,
            (Field::ScanSize, Typed::Float(x)) => s.scan.size = x,
            (Field::ScanPixels, Typed::Integer(n)) => s.scan.pixels = u32::try_from(n).ok()?,
            (Field::ScanLineRate, Typed::Float(x)) => s.scan.line_rate = x,
            (Field::ScanX, Typed::Float(x)) => s.scan.x = x,
            (Field::ScanY, Typed::Float(x)) => s.scan.y = x,
            (Field::FeedbackEnable, Typed::Bool(b)) => s.feedback.enable = b,
            (Field::FeedbackSetpoint, Typed::Float(x)) => s.feedback.setpoint = x,
            (Field::FeedbackProportional, Typed::Float(x)) => s.feedback.proportional = x,
            (Field::FeedbackIntegral, Typed::Float(x)) => s.feedback.integral = x,
            (Field::SweeperParameter, Typed::Text(name)) => {
                s.sweeper.parameter = SweepParameter::from_name(name)?;
            }
            (Field::SweeperStart, Typed::Float(x)) => s.sweeper.start = x,
            (Field::SweeperStop, Typed::Float(x)) => s.sweeper.stop = x,
            (Field::SweeperPoints, Typed::Integer(n)) => {
                s.sweeper.points = u32::try_from(n).ok()?
            }
            (Field::SweeperScale, Typed::Text(name)) => {
                s.sweeper.scale = SweepScale::from_name(name)?;
            }
            (Field::SweeperDirection, Typed::Text(name)) => {
                s.sweeper.direction = SweepDirection::from_name(name)?;
            }
            (Field::SweeperSettling, Typed::Float(x)) => s.sweeper.settling = x,
            (Field::SweeperAveraging, Typed::Integer(n)) => {
                s.sweeper.averaging = u32::try_from(n).ok()?;
            }
            (Field::SweeperEnable, Typed::Bool(b)) => s.sweeper.enable = b,
            (Field::InclusionEnable(i), Typed::Bool(b)) => s.inclusions.get_mut(i)?.enable = b,
            (Field::InclusionShape(i), Typed::Text(name)) => {
                s.inclusions.get_mut(i)?.shape = InclusionShape::from_name(name)?;
            }
            (Field::InclusionX(i), Typed::Float(x)) => s.inclusions.get_mut(i)?.x = x,
            (Field::InclusionY(i), Typed::Float(x)) => s.inclusions.get_mut(i)?.y = x,
            (Field::InclusionWidth(i), Typed::Float(x)) => s.inclusions.get_mut(i)?.width = x,
            (Field::InclusionLength(i), Typed::Float(x)) => s.inclusions.get_mut(i)?.length = x,
            (Field::InclusionHeight(i), Typed::Float(x)) => s.inclusions.get_mut(i)?.height = x,
            (Field::InclusionYoungsModulus(i), Typed::Float(x)) => {
                s.inclusions.get_mut(i)?.youngs_modulus = x;
            }
            (Field::InclusionRelativeModulus(i), Typed::Float(x)) => {
                s.inclusions.get_mut(i)?.relative_modulus = x;
            }
            (Field::InclusionPoisson(i), Typed::Float(x)) => {
                s.inclusions.get_mut(i)?.poisson = x;
            }
            (Field::DemodEnable(i), Typed::Bool(b)) => s.demods.get_mut(i)?.enable = b,
            (Field::DemodHarmonic(i), Typed::Integer(n)) => {
                s.demods.get_mut(i)?.harmonic = u32::try_from(n).ok()?;
            }
            (Field::DemodOrder(i), Typed::Integer(n)) => {
                s.demods.get_mut(i)?.order = u32::try_from(n).ok()?;
            }
            (Field::DemodTimeconstant(i), Typed::Float(x)) => {
                s.demods.get_mut(i)?.timeconstant = x;
            }
            (Field::DemodRate(i), Typed::Float(x)) => s.demods.get_mut(i)?.rate = x,
            _ => return None,
        }
        Some(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_are_scheme_host_and_port_only() {
        for ok in [
            "http://localhost:3000",
            "https://lab.example.org",
            "http://127.0.0.1",
            "http://x:0",
            "http://x:65535",
            "http://[::1]:8080",
            "https://[2001:db8::1]",
        ] {
            assert_eq!(TextEntry::Origin.problem(ok), None, "{ok}");
        }
        for (bad, why) in [
            ("*", "wildcard"),
            ("http://*", "wildcards"),
            ("ftp://x", "must start with"),
            ("HTTP://x", "must start with"),
            ("localhost:3000", "must start with"),
            ("http://", "host is missing"),
            ("http://:80", "host is missing"),
            ("http://x/", "path"),
            ("http://x/path", "path"),
            ("http://x?q", "query"),
            ("http://x#f", "fragment"),
            ("http://u@x", "user name"),
            ("http://x\ty", "white space"),
            ("http://x:", "port"),
            ("http://x:65536", "port"),
            ("http://x:+80", "port"),
            ("http://x:1:2", "port"),
            ("http://[::1", "closing"),
            ("http://[::1]x", "only"),
            ("http://[]:80", "host is missing"),
        ] {
            let problem = TextEntry::Origin
                .problem(bad)
                .unwrap_or_else(|| panic!("{bad}"));
            assert!(problem.contains(why), "{bad}: {problem}");
        }
    }
}
