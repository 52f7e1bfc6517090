//! The node table: every node of the settings tree declared once, with its path, unit,
//! values ([`Kind`]), whether `set` may change it at runtime, its description, and the
//! setting it reads and writes. The registry, `list`, the checks of one value, the config
//! loader and the docs' node table all come from it; adding a node is one row here plus the
//! code that uses the setting. Limits between nodes are in `relations`.

use super::kind::{Kind, NodeValue, TextEntry, Typed};
use super::limits::*;
use super::settings::{
    DEMODULATOR_COUNT, Engine, INCLUSION_COUNT, InclusionShape, InversionMethod, Oscillator,
    PID_COUNT, PidInput, PidTarget, Settings, SourceKind, SpectrumWindow, SweepDirection,
    SweepParameter, SweepScale,
};

/// Declares [`Field`] and its table from rows of
/// `[#[fixed]] Variant "path", "unit", kind, setting, "description";`
/// for the scalar nodes, and, for each index-keyed table (`/demods/N/…`), rows of
/// `Variant "key", "unit", kind, field of the entry, "description with {i}";`.
/// `#[fixed]` marks a node that only a config file sets (read-only at runtime).
macro_rules! node_table {
    (
        scalars {
            $( $(#[$fixed:ident])? $var:ident $path:literal, $unit:literal, $kind:expr,
               $($place:ident).+, $desc:literal; )*
        }
        $( table $table:ident($i:ident) in $entries:ident[$count:expr] at $prefix:literal {
            $( $tvar:ident $key:literal, $tunit:literal, $tkind:expr, $tplace:ident,
               $tdesc:literal; )*
        } )*
    ) => {
        /// One node of the tree. Nodes of an index-keyed table carry their index N of
        /// `/inclusions/N/…` and `/demods/N/…`.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum Field {
            $( #[doc = concat!("`", $path, "`: ", $desc)] $var, )*
            $($( #[doc = concat!("`", $prefix, "/N/", $key, "`: ", $tdesc)] $tvar(usize), )*)*
        }

        impl Field {
            /// Every node in tree order: the scalar nodes, then each table's entries in
            /// index order (`/inclusions/0/…` … `/inclusions/7/…`, `/demods/0/…` …).
            pub(crate) fn every() -> Vec<Field> {
                #[allow(unused_mut)]
                let mut all = vec![$(Field::$var),*];
                $( for $i in 0..$count {
                    all.extend([$(Field::$tvar($i)),*]);
                } )*
                all
            }

            $(
                #[doc = concat!("The nodes of entry `index` of `", $prefix, "`, in tree order.")]
                #[allow(dead_code)]
                pub(crate) fn $table(index: usize) -> Vec<Field> {
                    vec![$(Field::$tvar(index)),*]
                }
            )*

            /// The node path, e.g. `/sample/youngs_modulus`, `/demods/3/harmonic`.
            pub fn path(self) -> String {
                match self {
                    $( Field::$var => $path.to_owned(), )*
                    $($( Field::$tvar($i) => format!("{}/{}/{}", $prefix, $i, $key), )*)*
                }
            }

            /// SI unit: `Hz`, `N/m`, `m`, `Pa`, `s`, `1/s`, `K`, `m/√Hz`, `J` (the Hamaker
            /// constant), `1` (dimensionless numbers and counts), `bit` (ADC resolution),
            /// `samples` (FFT and trace lengths, decimation, points of the force waveform),
            /// `frames` (demodulator frames averaged), `points`, `pixels` (per scan line),
            /// `clients`, `messages`, `bytes`, `threads`, `sub-steps` (the coupled engine's
            /// per sample in contact), or empty for text, lists of text, booleans and the
            /// inversion's harmonic numbers.
            pub fn unit(self) -> &'static str {
                match self {
                    $( Field::$var => $unit, )*
                    $($( Field::$tvar(_) => $tunit, )*)*
                }
            }

            /// Whether the protocol's `set` may change the node while the instrument runs.
            /// Only the sample rate is fixed (every buffer, filter and FFT plan is sized from
            /// it), and the DSP stage's thread count (its threads start with the pipeline).
            pub fn writable(self) -> bool {
                match self {
                    $( Field::$var => node_table!(@writable $($fixed)?), )*
                    $($( Field::$tvar(_) => true, )*)*
                }
            }

            /// The values the node takes, without the limits that depend on other nodes.
            pub fn kind(self) -> Kind {
                match self {
                    $( Field::$var => $kind, )*
                    $($( Field::$tvar(_) => $tkind, )*)*
                }
            }

            /// One sentence saying what the node is, with its unit.
            pub fn description(self) -> String {
                match self {
                    $( Field::$var => $desc.to_owned(), )*
                    $($( Field::$tvar($i) => format!($tdesc), )*)*
                }
            }

            /// The node's current value; `None` only for an index the settings lack.
            pub(crate) fn read(self, s: &Settings) -> Option<Typed> {
                Some(match self {
                    $( Field::$var => s.$($place).+.typed(), )*
                    $($( Field::$tvar($i) => s.$entries.get($i)?.$tplace.typed(), )*)*
                })
            }

            /// Stores a value already checked against [`Field::kind`]. `None` if the value
            /// does not fit the setting (cannot happen after the node's own type check) or
            /// the settings lack the index.
            pub(crate) fn write(self, s: &mut Settings, value: Typed) -> Option<()> {
                match self {
                    $( Field::$var => s.$($place).+ = NodeValue::from_typed(value)?, )*
                    $($( Field::$tvar($i) => {
                        s.$entries.get_mut($i)?.$tplace = NodeValue::from_typed(value)?;
                    } )*)*
                }
                Some(())
            }
        }
    };
    (@writable) => { true };
    (@writable fixed) => { false };
}

/// The settings' named choices are text nodes: a choice is its name.
macro_rules! named_value {
    ($($t:ty),*) => {$(
        impl NodeValue for $t {
            fn typed(&self) -> Typed {
                Typed::Text(self.name())
            }
            fn from_typed(value: Typed) -> Option<Self> {
                match value {
                    Typed::Text(name) => <$t>::from_name(name),
                    _ => None,
                }
            }
        }
    )*};
}
named_value!(
    Engine,
    SourceKind,
    SpectrumWindow,
    InversionMethod,
    SweepParameter,
    SweepScale,
    SweepDirection,
    InclusionShape,
    PidInput,
    PidTarget,
    Oscillator
);

node_table! {
    scalars {
        CantileverF1 "/cantilever/f1", "Hz", Kind::Float(FREQUENCY), cantilever.f1,
            "First flexural resonance frequency f1 of the cantilever, in Hz.";
        CantileverK "/cantilever/k", "N/m", Kind::Float(STIFFNESS), cantilever.k,
            "Static spring constant of the cantilever at the tip (3EI/L³), in N/m.";
        CantileverQ "/cantilever/q", "1", Kind::FloatList { entry: QUALITY, max_len: MAX_MODES }, cantilever.q,
            "Quality factor of each cantilever mode from the first on (dimensionless); the list's length is the number of modes with a given Q.";
        CantileverExtraModes "/cantilever/extra_modes", "1", Kind::Integer { min: 0, max: MAX_MODES as u64 - 1 }, cantilever.extra_modes,
            "Number of modes simulated beyond the q list, damped by Rayleigh damping (Eq. B.7) fitted to the last two q values.";
        CantileverTipRadius "/cantilever/tip_radius", "m", Kind::Float(TIP_RADIUS), cantilever.tip_radius,
            "Radius R of the tip apex, in m.";
        TipYoungsModulus "/tip/youngs_modulus", "Pa", Kind::Float(MODULUS), tip.youngs_modulus,
            "Young's modulus of the tip material, in Pa.";
        TipPoisson "/tip/poisson", "1", Kind::Float(POISSON), tip.poisson,
            "Poisson ratio of the tip material (dimensionless).";
        SampleYoungsModulus "/sample/youngs_modulus", "Pa", Kind::Float(MODULUS), sample.youngs_modulus,
            "Young's modulus of the sample under the tip, in Pa.";
        SamplePoisson "/sample/poisson", "1", Kind::Float(POISSON), sample.poisson,
            "Poisson ratio of the sample under the tip (dimensionless).";
        DriveFrequency "/drive/frequency", "Hz", Kind::Float(FREQUENCY), drive.frequency,
            "Drive frequency Ω/2π of the base excitation, in Hz; below half the sample rate. Setting it to another value than /cantilever/f1 turns /drive/follow_f1 off.";
        DriveFollowF1 "/drive/follow_f1", "", Kind::Bool, drive.follow_f1,
            "The drive frequency follows /cantilever/f1, like an instrument's auto-tune (true), or stays where /drive/frequency puts it (false); setting /drive/frequency to another value than f1 turns it off.";
        DriveFreeAmplitude "/drive/free_amplitude", "m", Kind::Float(LENGTH), drive.free_amplitude,
            "Free (non-contact) peak tip amplitude at the drive frequency, in m.";
        Drive2Enable "/drive2/enable", "", Kind::Bool, drive2.enable,
            "A second base excitation at /drive2/frequency drives the lever beside /drive's (bimodal AFM: every mode and the contact take the sum), or is off (false). The coupled engine only, and not while scanning. Demodulators on oscillator \"drive2\" read its frequency either way.";
        Drive2Frequency "/drive2/frequency", "Hz", Kind::Float(FREQUENCY), drive2.frequency,
            "Frequency Ω₂/2π of the second excitation, in Hz; below half the sample rate. Its default is the default lever's second flexural resonance, and a lever preset sets its own (`ftafm info` lists a lever's modes).";
        Drive2FreeAmplitude "/drive2/free_amplitude", "m", Kind::Float(LENGTH), drive2.free_amplitude,
            "Free (non-contact) peak tip amplitude the second excitation gives at /drive2/frequency, in m.";
        SurfaceDistance "/surface/distance", "m", Kind::Float(LENGTH), surface.distance,
            "Distance A_set from the tip's rest position to the sample surface, in m; the tip taps when it is below the amplitude.";
        AdhesionEnable "/adhesion/enable", "", Kind::Bool, adhesion.enable,
            "DMT adhesion (physics.md §6): the van der Waals pull −HR/(6(a0 + gap)²) above the surface and the constant −HR/(6a0²) in contact, added to the Hertz force. The coupled engine only: the paper engine's 1-DOF orbit has none (a warning says so).";
        AdhesionHamaker "/adhesion/hamaker", "J", Kind::Float(HAMAKER), adhesion.hamaker,
            "Hamaker constant H of the tip, sample and medium between them, in J (silicon on silicon in air ≈ 6.4e-20 J).";
        AdhesionDistance "/adhesion/distance", "m", Kind::Float(INTERMOLECULAR_DISTANCE), adhesion.distance,
            "Intermolecular distance a0, in m: the gap at which the attraction saturates (0.165 nm in the literature's tapping simulations).";
        #[fixed] SynthSampleRate "/synth/sample_rate", "Hz", Kind::Float(SAMPLE_RATE), synth.sample_rate,
            "Photodiode sample rate of the synthesiser, in Hz; fixed at start (config file only).";
        SynthEngine "/synth/engine", "", Kind::Text(Engine::NAMES), synth.engine,
            "Tip-force engine: \"paper\" (cut-cosine pulses from the 1-DOF model, the paper's method); \"coupled\" (all modes integrated sample by sample with the Hertz force from the instantaneous tip position).";
        SynthSeed "/synth/seed", "1", Kind::Integer { min: 0, max: u64::MAX }, synth.seed,
            "Seed of every random source (integer); the same seed and settings give the same stream.";
        SynthRealtime "/synth/realtime", "", Kind::Bool, synth.realtime,
            "Pace synthesis to the wall clock (true) or run as fast as possible (false).";
        SynthAntiAlias "/synth/anti_alias", "", Kind::Bool, synth.anti_alias,
            "The ADC's anti-alias filter (true): the signal is integrated over a triangle window (sinc^2, zero at every multiple of 2 x sample_rate), taken at twice the sample rate, decimated by a halfband FIR and the window's droop compensated: flat to 0.4 x sample_rate, >= 88 dB down from 0.6 x sample_rate, delay 21.5 samples (compensated in the drive phase); false samples the signal directly, with every alias.";
        SynthContactSubsteps "/synth/contact_substeps", "sub-steps", Kind::Even { min: MIN_CONTACT_SUBSTEPS.into(), max: MAX_CONTACT_SUBSTEPS.into() }, synth.contact_substeps,
            "Fewest sub-steps of a sample where the coupled engine resolves the contact (near and in contact; clear of the surface a sample is one step), an even number: a tap whose contact is stiffer than they resolve within /synth/substep_budget is integrated at 2, 4 or 8 times as many. Fewer is faster and less accurate (errors against the offline orbit per count in docs/ft-afm.md); the paper engine ignores it.";
        SynthSubstepBudget "/synth/substep_budget", "rad", Kind::Float(SUBSTEP_BUDGET), synth.substep_budget,
            "Error budget of the coupled engine's sub-steps in contact: the most a sub-step may span of the tip's frequency on the contact's stiffness, ω_c·dt in rad (the harmonics' error grows as about 28 %·(ω_c·dt)²: 0.05 keeps it below 0.07 %). A tap over it at /synth/contact_substeps is integrated at 2, 4 or 8 times as many (counted in status as refined_samples). 0 turns it off: every contact sample at /synth/contact_substeps.";
        NoiseEnable "/noise/enable", "", Kind::Bool, noise.enable,
            "Switches all noise sources on (true) or off (false).";
        NoiseTemperature "/noise/temperature", "K", Kind::Float(TEMPERATURE), noise.temperature,
            "Temperature of the cantilever's thermal (Brownian) noise, in K, applied to every mode by fluctuation–dissipation; 0 turns thermal noise off.";
        NoiseDetectorDensity "/noise/detector_density", "m/√Hz", Kind::Float(DETECTOR_DENSITY), noise.detector_density,
            "One-sided density of the white detector noise added to the deflection signal, in m/√Hz; 0 turns it off.";
        NoiseAdcBits "/noise/adc_bits", "bit", Kind::Integer { min: 0, max: MAX_ADC_BITS.into() }, noise.adc_bits,
            "Resolution of the ADC that digitises the deflection signal, in bits; 0 means no quantisation.";
        NoiseAdcRange "/noise/adc_range", "m", Kind::Float(ADC_RANGE), noise.adc_range,
            "Full scale of the ADC input, ±adc_range, in (nominal) m; samples beyond it clip and are counted.";
        SpectrumEnable "/spectrum/enable", "", Kind::Bool, spectrum.enable,
            "Computes and sends the spectrum of the deflection signal (true) or not (false).";
        SpectrumSize "/spectrum/size", "samples", Kind::PowerOfTwo { min: MIN_SPECTRUM_SIZE.into(), max: MAX_SPECTRUM_SIZE.into() }, spectrum.size,
            "FFT length of the spectrum, in samples: a power of two from 256 to 1048576.";
        SpectrumWindow "/spectrum/window", "", Kind::Text(SpectrumWindow::NAMES), spectrum.window,
            "Window applied to each spectrum frame: \"rectangular\", \"hann\", \"blackman_harris\" or \"flat_top\".";
        SpectrumRate "/spectrum/rate", "Hz", Kind::Float(SPECTRUM_RATE), spectrum.rate,
            "Spectra computed per second, in Hz; frames may overlap, at most the sample rate.";
        ScopeEnable "/scope/enable", "", Kind::Bool, scope.enable,
            "Takes and sends time-domain traces of the raw photodiode signal, the scope stream (true), or not (false).";
        ScopeLength "/scope/length", "samples", Kind::Integer { min: MIN_SCOPE_LENGTH.into(), max: MAX_SCOPE_LENGTH.into() }, scope.length,
            "Samples per scope trace, counted after decimation, in samples: 16 to 65536.";
        ScopeDecimation "/scope/decimation", "samples", Kind::Integer { min: 1, max: MAX_SCOPE_DECIMATION.into() }, scope.decimation,
            "Scope decimation, in samples: each trace keeps every Nth photodiode sample (1 keeps all).";
        ScopeRate "/scope/rate", "Hz", Kind::Float(SCOPE_RATE), scope.rate,
            "Scope traces per second, in Hz; traces must not overlap, so length × decimation / sample rate ≤ 1 / rate.";
        SourceKind "/source/kind", "", Kind::Text(SourceKind::NAMES), source.kind,
            "Where the chain's samples come from: \"synth\" (the synthesiser, the modelled cantilever and sample) or \"stream\" (samples a client pushes over the WebSocket in binary frames at /synth/sample_rate, scaled to m by the frame; docs/protocol.md, \"Streaming samples in\"). With a stream the lock-in's reference is /drive/frequency from sample 0 of the stream, and the synthesiser's nodes shape nothing.";
        #[fixed] DspThreads "/dsp/threads", "threads", Kind::Integer { min: 0, max: MAX_DSP_THREADS.into() }, dsp.threads,
            "Threads of the DSP stage, in threads: the lock-in bank is split between them (each runs a share of the demodulators on every block; the outputs are bit for bit those of one thread); 0 (auto) adds threads only on a machine with more than 2 cores, one per core beyond two, at most 4 in all; fixed at start (config file only).";
        ServerAllowedOrigins "/server/allowed_origins", "", Kind::TextList { max_len: MAX_ALLOWED_ORIGINS, max_bytes: MAX_ORIGIN_BYTES, entry: TextEntry::Origin }, server.allowed_origins,
            "Web origins (scheme://host[:port], e.g. \"http://localhost:3000\") besides the server's own whose pages may open the WebSocket; any other origin is refused with 403; no \"*\" wildcard. A change applies to connections opened from then on.";
        ServerAllowedHosts "/server/allowed_hosts", "", Kind::TextList { max_len: MAX_ALLOWED_ORIGINS, max_bytes: MAX_HOST_BYTES, entry: TextEntry::Host }, server.allowed_hosts,
            "Host names besides loopback names and IP addresses by which the server may be reached (e.g. \"lab-pc.example.org\"); a request whose Host header names anything else is refused with 403, which stops DNS rebinding. A change applies to requests from then on.";
        ServerMaxClients "/server/max_clients", "clients", Kind::Integer { min: 1, max: MAX_CLIENTS.into() }, server.max_clients,
            "Most WebSocket clients connected at once, in clients; beyond it the handshake is refused with 503. A change applies to connections opened from then on.";
        ServerClientQueue "/server/client_queue", "messages", Kind::Integer { min: MIN_CLIENT_QUEUE.into(), max: MAX_CLIENT_QUEUE.into() }, server.client_queue,
            "Length of each client's outgoing queue, in messages; a client further behind loses its own messages (counted, seen as gaps in seq). A change applies to connections opened from then on.";
        ServerClientQueueBytes "/server/client_queue_bytes", "bytes", Kind::Integer { min: MIN_CLIENT_QUEUE_BYTES, max: MAX_CLIENT_QUEUE_BYTES }, server.client_queue_bytes,
            "Most bytes queued for each client, in bytes (one message larger than this still goes when its queue is empty); a client further behind loses its own messages (counted, seen as gaps in seq). A change applies to sends from then on.";
        ServerStallTimeout "/server/stall_timeout", "s", Kind::Float(STALL_TIMEOUT), server.stall_timeout,
            "A client whose socket accepts nothing for this long, in s, is disconnected (close 1008 \"stalled\"). A change applies from then on.";
        InversionEnable "/inversion/enable", "", Kind::Bool, inversion.enable,
            "Reconstructs the tip–sample force live from the demodulator outputs and sends it, the force stream (true), or not (false).";
        InversionMethod "/inversion/method", "", Kind::Text(InversionMethod::NAMES), inversion.method,
            "Force reconstruction: \"full\" divides every usable harmonic by the cantilever's transfer function (Stark et al. 2002); \"two_harmonic\" takes the width τ and peak F of the cut cosine from two harmonics (the paper's Sec. 3).";
        InversionHarmonicA "/inversion/harmonic_a", "", Kind::Integer { min: MIN_INVERSION_HARMONIC.into(), max: MAX_HARMONIC.into() }, inversion.harmonic_a,
            "First of the two harmonics of the two-harmonic method, and an anchor of the full method's fit of missing harmonics (a harmonic number, 2 to 10000); while the inversion is enabled an enabled demodulator must measure it.";
        InversionHarmonicB "/inversion/harmonic_b", "", Kind::Integer { min: MIN_INVERSION_HARMONIC.into(), max: MAX_HARMONIC.into() }, inversion.harmonic_b,
            "Second of the two harmonics of the two-harmonic method, and an anchor of the full method's fit of missing harmonics (a harmonic number, 2 to 10000, not harmonic_a); while the inversion is enabled an enabled demodulator must measure it.";
        InversionAveraging "/inversion/averaging", "frames", Kind::Integer { min: 1, max: MAX_INVERSION_AVERAGING.into() }, inversion.averaging,
            "Demodulator frames averaged per force estimate, in frames; 1 gives one estimate per demodulator frame.";
        InversionPoints "/inversion/points", "samples", Kind::Integer { min: MIN_INVERSION_POINTS.into(), max: MAX_INVERSION_POINTS.into() }, inversion.points,
            "Points of the reconstructed force waveform over one drive period, in samples: 16 to 4096.";
        ScanEnable "/scan/enable", "", Kind::Bool, scan.enable,
            "Raster-scans the tip over the sample map and sends the image stream (true), or rests it over the base material at /surface/distance (false).";
        ScanSize "/scan/size", "m", Kind::Float(SCAN_SIZE), scan.size,
            "Side of the square scan area, in m, centred on /scan/x, /scan/y.";
        ScanPixels "/scan/pixels", "pixels", Kind::Integer { min: MIN_SCAN_PIXELS.into(), max: MAX_SCAN_PIXELS.into() }, scan.pixels,
            "Pixels per scan line, and lines per frame (the image is square), in pixels: 8 to 1024.";
        ScanLineRate "/scan/line_rate", "Hz", Kind::Float(LINE_RATE), scan.line_rate,
            "Scan lines per second, trace and retrace together, in Hz; each pixel must last at least 10 drive periods, and 2 × pixels × line_rate ≤ 20000 pixels per second.";
        ScanX "/scan/x", "m", Kind::Float(POSITION), scan.x,
            "Centre of the scan area in sample coordinates, x, in m (x grows to the right along a trace).";
        ScanY "/scan/y", "m", Kind::Float(POSITION), scan.y,
            "Centre of the scan area in sample coordinates, y, in m (line 0 is at the top, the largest y).";
        FeedbackEnable "/feedback/enable", "", Kind::Bool, feedback.enable,
            "The amplitude feedback moves the surface distance to hold the fundamental amplitude at the setpoint while scanning (true), or the distance stays at /surface/distance (false).";
        FeedbackSetpoint "/feedback/setpoint", "m", Kind::Float(SETPOINT), feedback.setpoint,
            "Photodiode amplitude at the drive frequency the feedback holds, in m (peak, as demodulator harmonic 1 reads it); 0 holds the steady amplitude at /surface/distance over the base material.";
        FeedbackProportional "/feedback/proportional", "1", Kind::Float(PROPORTIONAL_GAIN), feedback.proportional,
            "Proportional gain of the amplitude feedback (dimensionless): m of distance per m of amplitude error.";
        FeedbackIntegral "/feedback/integral", "1/s", Kind::Float(INTEGRAL_GAIN), feedback.integral,
            "Integral gain of the amplitude feedback, in 1/s: m of distance per second per m of amplitude error.";
        SweeperParameter "/sweeper/parameter", "", Kind::Text(SweepParameter::NAMES), sweeper.parameter,
            "The node a sweep steps: \"/drive/frequency\" (a tune: the base, i.e. piezo, amplitude is held at what gives /drive/free_amplitude at the drive frequency when the sweep starts, so the resonance shows), \"/surface/distance\" (an approach curve), \"/drive/free_amplitude\" or \"/sample/youngs_modulus\".";
        SweeperStart "/sweeper/start", "", Kind::Float(SWEEP_VALUE), sweeper.start,
            "First value of a sweep, in the unit of /sweeper/parameter; within that node's range when the sweep starts.";
        SweeperStop "/sweeper/stop", "", Kind::Float(SWEEP_VALUE), sweeper.stop,
            "Last value of a sweep, in the unit of /sweeper/parameter; within that node's range when the sweep starts.";
        SweeperPoints "/sweeper/points", "points", Kind::Integer { min: 2, max: MAX_SWEEP_POINTS.into() }, sweeper.points,
            "Points of each leg of a sweep, both ends included, in points: 2 to 10000.";
        SweeperScale "/sweeper/scale", "", Kind::Text(SweepScale::NAMES), sweeper.scale,
            "Spacing of a sweep's points: \"linear\" or \"log\" (start and stop > 0).";
        SweeperDirection "/sweeper/direction", "", Kind::Text(SweepDirection::NAMES), sweeper.direction,
            "Legs of a sweep: \"up\" (start to stop), \"down\" (stop to start) or \"both\" (up, then down: an approach and a retract).";
        SweeperSettling "/sweeper/settling", "s", Kind::Float(SWEEP_SETTLING), sweeper.settling,
            "Simulated time waited at each point before averaging, in s; 0 waits automatically for mode 1 to ring down and the demodulators' filters to settle, to 1e-3.";
        SweeperAveraging "/sweeper/averaging", "frames", Kind::Integer { min: 1, max: MAX_SWEEP_AVERAGING.into() }, sweeper.averaging,
            "Demodulator frames averaged at each point of a sweep, in frames: 1 to 100000.";
        SweeperEnable "/sweeper/enable", "", Kind::Bool, sweeper.enable,
            "A sweep runs (true): set true to start one, false to abort it; it turns false by itself when the sweep is done, and the swept node is restored.";
    }
    table inclusion(i) in inclusions[INCLUSION_COUNT] at "/inclusions" {
        InclusionEnable "enable", "", Kind::Bool, enable,
            "Inclusion {i} is part of the sample map (true) or absent (false); where inclusions overlap, the higher index is on top.";
        InclusionShape "shape", "", Kind::Text(InclusionShape::NAMES), shape,
            "Shape of inclusion {i}: \"disc\" (diameter width) or \"rectangle\" (width along x by length along y).";
        InclusionX "x", "m", Kind::Float(POSITION), x,
            "Centre of inclusion {i} in sample coordinates, x, in m.";
        InclusionY "y", "m", Kind::Float(POSITION), y,
            "Centre of inclusion {i} in sample coordinates, y, in m.";
        InclusionWidth "width", "m", Kind::Float(EXTENT), width,
            "Diameter of inclusion {i} if a disc, its extent along x if a rectangle, in m.";
        InclusionLength "length", "m", Kind::Float(EXTENT), length,
            "Extent of inclusion {i} along y if a rectangle, in m; a disc does not use it.";
        InclusionHeight "height", "m", Kind::Float(HEIGHT), height,
            "Height of inclusion {i}'s surface above the base material's, in m; negative is a pit.";
        InclusionYoungsModulus "youngs_modulus", "Pa", Kind::Float(MODULUS), youngs_modulus,
            "Young's modulus of inclusion {i}'s material, in Pa; = /inclusions/{i}/relative_modulus × /sample/youngs_modulus while that is above 0, and setting it makes the inclusion absolute.";
        InclusionRelativeModulus "relative_modulus", "1", Kind::Float(RELATIVE_MODULUS), relative_modulus,
            "Young's modulus of inclusion {i} relative to the base material's (/sample/youngs_modulus), so a change of sample keeps the contrast; 0: absolute (/inclusions/{i}/youngs_modulus).";
        InclusionPoisson "poisson", "1", Kind::Float(POISSON), poisson,
            "Poisson ratio of inclusion {i}'s material (dimensionless).";
    }
    table demod(i) in demods[DEMODULATOR_COUNT] at "/demods" {
        DemodEnable "enable", "", Kind::Bool, enable,
            "Demodulator {i} produces output (true) or is idle (false).";
        DemodHarmonic "harmonic", "1", Kind::Integer { min: 0, max: MAX_HARMONIC.into() }, harmonic,
            "Harmonic k of the drive frequency that demodulator {i} measures (dimensionless, 0 is the mean); k × drive frequency must stay below half the sample rate while enabled.";
        DemodOrder "order", "1", Kind::Integer { min: 1, max: MAX_FILTER_ORDER.into() }, order,
            "Order of demodulator {i}'s low-pass filter, the number of cascaded first-order sections (dimensionless).";
        DemodTimeconstant "timeconstant", "s", Kind::Float(TIME_CONSTANT), timeconstant,
            "Time constant of each first-order low-pass section of demodulator {i}, in s; at least one sample period.";
        DemodRate "rate", "Hz", Kind::Float(OUTPUT_RATE), rate,
            "Output rate of demodulator {i}, in Hz; at most the sample rate.";
        DemodOscillator "oscillator", "", Kind::Text(Oscillator::NAMES), oscillator,
            "The oscillator demodulator {i} reads its harmonic of: \"drive\" (/drive/frequency, and a PLL's moves of it) or \"drive2\" (/drive2/frequency, the second excitation's, whether or not it is enabled).";
    }
    table pid(i) in pids[PID_COUNT] at "/pids" {
        PidEnable "enable", "", Kind::Bool, enable,
            "PID {i} regulates, once per drive period in the synthesiser (true), or is idle (false); enabling it starts from the output's present value (bumpless), disabling it leaves the output where it is.";
        PidInput "input", "", Kind::Text(PidInput::NAMES), input,
            "What PID {i} regulates: \"r\" (amplitude, m peak), \"phase\" (rad), \"x\" or \"y\" (m) of its own demodulator at /pids/{i}/harmonic, a one-period boxcar of the photodiode samples (ADC and noise included) read as the demods stream reads it; \"mean_deflection\" (m) that boxcar's mean of the samples (contact mode's deflection; the harmonic is not read; oscillator \"drive\"); \"frequency_shift\" (Hz) the frequency shift of the PLL on its oscillator.";
        PidHarmonic "harmonic", "1", Kind::Integer { min: 1, max: MAX_HARMONIC.into() }, harmonic,
            "Harmonic k of the drive that PID {i}'s demodulator reads (dimensionless); k × drive frequency must stay below half the sample rate while enabled.";
        PidSetpoint "setpoint", "", Kind::Float(PID_SETPOINT), setpoint,
            "Set-point of PID {i}, in its input's unit (m for r, x, y; rad for the phase).";
        PidP "p", "", Kind::Float(PID_P), p,
            "Proportional gain P of PID {i}, in output unit per input unit (m/m for an amplitude loop on the surface distance); negative for a reverse-acting loop, all non-zero gains sharing one sign while enabled.";
        PidI "i", "1/s", Kind::Float(PID_I), i,
            "Integral gain I of PID {i}, in output unit per input unit per s; the sign of P (or any sign if P is 0) while enabled.";
        PidD "d", "s", Kind::Float(PID_D), d,
            "Derivative gain D of PID {i}, in output unit·s per input unit, on the measurement (a set-point step does not kick); the sign of P and I while enabled.";
        PidDBandwidth "d_bandwidth", "Hz", Kind::Float(PID_D_BANDWIDTH), d_bandwidth,
            "Bandwidth of PID {i}'s derivative low-pass (first order), in Hz; below half the drive frequency (the PID's Nyquist frequency) while enabled.";
        PidOutputMin "output_min", "", Kind::Float(PID_OUTPUT), output_min,
            "Lowest output of PID {i}, in its output's unit (m: at least -1e-6 for surface_distance, a surface above the rest position pressing the lever up as in contact mode, at least 0 for drive_amplitude; Hz for drive_frequency, above 0); at most output_max.";
        PidOutputMax "output_max", "", Kind::Float(PID_OUTPUT), output_max,
            "Highest output of PID {i}, in its output's unit (m for surface_distance and drive_amplitude, at most 1e-6; Hz for drive_frequency, below /synth/sample_rate / 2 over the highest harmonic an enabled demodulator or PID reads).";
        PidRate "rate", "", Kind::Float(PID_RATE), rate,
            "Largest change of PID {i}'s output per second, in its output's unit per s; 0: no rate limit.";
        PidOutput "output", "", Kind::Text(PidTarget::NAMES), output,
            "What PID {i} drives (the coupled engine only): \"surface_distance\" (the z piezo: the distance from the tip's rest position to the surface, as the scan's feedback moves it), \"drive_frequency\" (Hz: the excitation's frequency, which the lock-in's reference follows; on the phase of harmonic 1 a PLL), \"drive_amplitude\" (m: the excitation, as the free tip amplitude it gives at /drive/frequency), or \"drive2_frequency\" and \"drive2_amplitude\" (the same of the second excitation, /drive2/enable true: on the phase of harmonic 1 of drive2, mode 2's PLL). At most one enabled PID drives an output, and none while a scan runs or a sweep steps the same node.";
        PidOscillator "oscillator", "", Kind::Text(Oscillator::NAMES), oscillator,
            "The oscillator whose harmonic /pids/{i}/harmonic PID {i}'s demodulator reads: \"drive\" (a boxcar of one drive period) or \"drive2\" (the second excitation, /drive2/enable true: a low-pass of /pids/{i}/input_bandwidth, since a boxcar of the drive's period does not reject the tapping's harmonics beside f2).";
        PidInputBandwidth "input_bandwidth", "Hz", Kind::Float(PID_INPUT_BANDWIDTH), input_bandwidth,
            "-3 dB bandwidth of PID {i}'s demodulator low-pass (four first-order sections) on \"drive2\", in Hz; at most a quarter of the drive frequency (the PID's update rate) while it reads drive2.";
    }
}
