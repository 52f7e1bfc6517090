//! Whole-settings validation: every node inside its own range, the limits that tie nodes
//! together (the Nyquist frequency, one sample period, the number of modes, the inversion's
//! harmonics and the demodulators that measure them, the scan's pixel dwell time and pixel
//! rate). These run after a
//! whole config file or a whole `set`, never per key, so the order of keys never matters.
//! Every message about a relation names every node it involves.

use super::error::NodeError;
use super::kind::Kind;
use super::limits::{
    MAX_HARMONIC, MAX_MODES, MAX_PID_DISTANCE, MAX_PIXEL_RATE, MAX_SCAN_PIXELS,
    MAX_SCOPE_DECIMATION, MAX_SCOPE_LENGTH, MIN_INVERSION_HARMONIC, MIN_PID_DISTANCE,
    MIN_PIXEL_PERIODS,
};
use super::quantity::{number, quantity};
use super::range::{Bound, Range};
use super::registry::registry;
use super::settings::{
    DEMODULATOR_COUNT, DemodSettings, Engine, INCLUSION_COUNT, Oscillator, PID_COUNT, PidInput,
    PidTarget, PidUnitSettings, Settings, SourceKind, SweepParameter,
};

impl Settings {
    /// Checks everything `set` and the config loader guarantee: exactly
    /// [`INCLUSION_COUNT`] inclusions and [`DEMODULATOR_COUNT`] demodulators, every node
    /// inside its range, and the relations between nodes. Returns the first problem found.
    pub fn validate(&self) -> Result<(), NodeError> {
        if self.inclusions.len() != INCLUSION_COUNT {
            return Err(NodeError::InvalidValue {
                path: "/inclusions".to_owned(),
                message: format!(
                    "/inclusions has {} inclusions: exactly {INCLUSION_COUNT} (0 … {}) are required",
                    self.inclusions.len(),
                    INCLUSION_COUNT - 1
                ),
            });
        }
        if self.pids.len() != PID_COUNT {
            return Err(NodeError::InvalidValue {
                path: "/pids".to_owned(),
                message: format!(
                    "/pids has {} PIDs: exactly {PID_COUNT} (0 … {}) are required",
                    self.pids.len(),
                    PID_COUNT - 1
                ),
            });
        }
        if self.demods.len() != DEMODULATOR_COUNT {
            return Err(NodeError::InvalidValue {
                path: "/demods".to_owned(),
                message: format!(
                    "/demods has {} demodulators: exactly {DEMODULATOR_COUNT} (0 … {}) are required",
                    self.demods.len(),
                    DEMODULATOR_COUNT - 1
                ),
            });
        }
        for spec in registry() {
            let value = spec
                .field
                .read(self)
                .ok_or_else(|| NodeError::UnknownPath {
                    path: spec.path.clone(),
                })?;
            spec.check(&value)?;
        }
        check_modes(self)?;
        check_drive(self)?;
        check_drive2(self)?;
        check_spectrum(self)?;
        check_scope(self)?;
        check_demods(self)?;
        check_inversion(self)?;
        check_scan(self)?;
        check_sweeper(self)?;
        check_pids(self)
    }
}

fn invalid(path: impl Into<String>, message: String) -> NodeError {
    NodeError::InvalidValue {
        path: path.into(),
        message,
    }
}

/// Nyquist frequency in Hz.
fn nyquist(s: &Settings) -> f64 {
    s.synth.sample_rate / 2.0
}

/// The largest k (at most [`MAX_HARMONIC`]) with k × `drive` < `limit` (Hz).
fn harmonics_below(drive: f64, limit: f64) -> u64 {
    let max = u64::from(MAX_HARMONIC);
    if !drive.is_finite() || drive <= 0.0 {
        return max;
    }
    // Start from the closed form, then step so the answer agrees exactly with
    // [`harmonic_in_band`].
    let mut k = ((limit / drive).ceil() - 1.0).clamp(0.0, max as f64) as u64;
    while k > 0 && k as f64 * drive >= limit {
        k -= 1;
    }
    while k < max && (k + 1) as f64 * drive < limit {
        k += 1;
    }
    k
}

/// Whether harmonic `k` of the drive lies below the Nyquist frequency, where the lock-in can
/// measure it. An enabled demodulator above it is *out of band*: it is kept (so a drive
/// raised for a stiffer lever does not refuse the whole configuration) but produces no
/// frames, and `status` and `list` say so.
pub fn harmonic_in_band(s: &Settings, k: u32) -> bool {
    f64::from(k) * s.drive.frequency < nyquist(s)
}

impl Settings {
    /// The frequency of `oscillator` (Hz): `/drive/frequency` or `/drive2/frequency`.
    pub fn oscillator_frequency(&self, oscillator: Oscillator) -> f64 {
        match oscillator {
            Oscillator::Drive => self.drive.frequency,
            Oscillator::Drive2 => self.drive2.frequency,
        }
    }

    /// Whether demodulator `d`'s harmonic of its oscillator lies below the Nyquist
    /// frequency.
    pub fn demod_in_band(&self, d: &DemodSettings) -> bool {
        f64::from(d.harmonic) * self.oscillator_frequency(d.oscillator) < nyquist(self)
    }

    /// Whether demodulator `index` is enabled and its harmonic in band: it produces frames.
    pub fn demod_active(&self, index: usize) -> bool {
        self.demods
            .get(index)
            .is_some_and(|d| d.enable && self.demod_in_band(d))
    }

    /// The enabled demodulators whose harmonic is at or above the Nyquist frequency, by
    /// index: they produce no frames until the drive or the sample rate brings them in band.
    pub fn demods_out_of_band(&self) -> Vec<usize> {
        (0..self.demods.len())
            .filter(|&i| self.demods[i].enable && !self.demod_active(i))
            .collect()
    }

    /// The two harmonics the inversion uses, (lower, higher): `/inversion/harmonic_a` and
    /// `_b` where an active (enabled, in band) demodulator measures them; a configured one
    /// that is out of band is replaced by the nearest active harmonic ≥ 2 below it (above
    /// it if there is none below), different from the other. `None` when the inversion is
    /// disabled or fewer than two active harmonics ≥ 2 exist.
    pub fn inversion_harmonics(&self) -> Option<(u32, u32)> {
        if !self.inversion.enable {
            return None;
        }
        let active: Vec<u32> = enabled_harmonics(self)
            .into_iter()
            .filter(|&k| k >= MIN_INVERSION_HARMONIC && harmonic_in_band(self, k))
            .collect();
        let pick = |want: u32, taken: Option<u32>| -> Option<u32> {
            let free = |k: &&u32| Some(**k) != taken;
            if active.contains(&want) && Some(want) != taken {
                return Some(want);
            }
            active
                .iter()
                .filter(free)
                .filter(|&&k| k < want)
                .max()
                .or_else(|| active.iter().filter(free).filter(|&&k| k > want).min())
                .copied()
        };
        let (a, b) = (self.inversion.harmonic_a, self.inversion.harmonic_b);
        // The lower one first, so a lost upper harmonic moves down past it rather than
        // taking its place.
        let (low, high) = (a.min(b), a.max(b));
        let low = pick(low, None)?;
        let high = pick(high, Some(low))?;
        Some((low.min(high), low.max(high)))
    }
}

impl Settings {
    /// Why the node at `path` does not do what its value alone suggests, for `list`, `get`
    /// and `status`: an enabled demodulator out of band, an inversion harmonic replaced by
    /// an in-band one (or no two in band), adhesion that the paper engine does not model.
    /// `None` when there is nothing to say.
    pub fn node_warning(&self, path: &str) -> Option<String> {
        if self.source.kind == SourceKind::Stream && shapes_only_the_synthesis(path) {
            return Some(STREAM_SOURCE_WARNING.to_owned());
        }
        if path.starts_with("/adhesion/") || path == "/synth/engine" {
            return self.adhesion_ignored().then(|| {
                "adhesion is on but /synth/engine is \"paper\", whose 1-DOF orbit has no \
                 adhesion: it acts only with /synth/engine = \"coupled\""
                    .to_owned()
            });
        }
        let rest = path.strip_prefix("/demods/");
        if let Some((index, key)) = rest.and_then(|r| r.split_once('/')) {
            let i: usize = index.parse().ok()?;
            let d = self.demods.get(i)?;
            let (node, f) = match d.oscillator {
                Oscillator::Drive => ("/drive/frequency", self.drive.frequency),
                Oscillator::Drive2 => ("/drive2/frequency", self.drive2.frequency),
            };
            return (matches!(key, "harmonic" | "enable" | "oscillator")
                && d.enable
                && !self.demod_in_band(d))
            .then(|| {
                format!(
                    "out of band: /demods/{i}/harmonic × {node} = {} × {} = {} is at \
                     or above the Nyquist frequency /synth/sample_rate / 2 = {}; demodulator {i} \
                     produces no frames (harmonics up to {} are in band: lower its harmonic or \
                     {node}, or raise the sample rate in the config)",
                    d.harmonic,
                    quantity(f, "Hz"),
                    quantity(f64::from(d.harmonic) * f, "Hz"),
                    quantity(nyquist(self), "Hz"),
                    harmonics_below(f, nyquist(self))
                )
            });
        }
        let configured = match path {
            "/inversion/harmonic_a" => self.inversion.harmonic_a,
            "/inversion/harmonic_b" => self.inversion.harmonic_b,
            _ => return None,
        };
        if !self.inversion.enable {
            return None;
        }
        let Some((low, high)) = self.inversion_harmonics() else {
            return Some(format!(
                "no force estimates: the inversion needs two enabled demodulators in band at \
                 harmonics ≥ 2, and {} with harmonics below {}",
                describe_enabled_harmonics(self),
                quantity(nyquist(self), "Hz")
            ));
        };
        let (a, b) = (self.inversion.harmonic_a, self.inversion.harmonic_b);
        let used = if configured == a.min(b) { low } else { high };
        (used != configured).then(|| {
            format!(
                "harmonic {configured} is out of band ({} ≥ the Nyquist frequency {}): the \
                 inversion uses harmonic {used} instead",
                quantity(f64::from(configured) * self.drive.frequency, "Hz"),
                quantity(nyquist(self), "Hz")
            )
        })
    }

    /// Why the force estimates would be biased or short of what the inversion relies on,
    /// each with what to change: demodulated harmonics ≥ 2 at or above
    /// [`PASSBAND_FRACTION`] × `/synth/sample_rate` (outside the anti-alias filter's flat
    /// passband, or near Nyquist without it: measured attenuated, or not at all), and
    /// harmonics from 2 to the higher of `/inversion/harmonic_a` and `_b` that no enabled
    /// demodulator measures. Empty when the inversion is off. For `status`, `info` and every
    /// `force` message.
    pub fn force_warnings(&self) -> Vec<String> {
        if !self.inversion.enable {
            return Vec::new();
        }
        let mut out = Vec::new();
        let edge = PASSBAND_FRACTION * self.synth.sample_rate;
        let drive = self.drive.frequency;
        let enabled = enabled_harmonics(self);
        let outside: Vec<u32> = enabled
            .iter()
            .copied()
            .filter(|&k| k >= MIN_INVERSION_HARMONIC && f64::from(k) * drive >= edge)
            .collect();
        if let Some(&top) = outside.iter().max() {
            let needed = round_up_nicely(f64::from(top) * drive / PASSBAND_FRACTION);
            out.push(format!(
                "force estimate biased: harmonics {} that the inversion relies on are above \
                 {PASSBAND_FRACTION} × the sample rate ({} at {}), outside the anti-alias \
                 filter's flat passband: raise /synth/sample_rate to {} (config file), or lower \
                 /drive/frequency, or disable those demodulators",
                ranges(&outside),
                quantity(edge, "Hz"),
                quantity(self.synth.sample_rate, "S/s"),
                if needed >= 1e6 {
                    format!("{}e6", needed / 1e6)
                } else {
                    number(needed)
                }
            ));
        }
        let top = self.inversion.harmonic_a.max(self.inversion.harmonic_b);
        let missing: Vec<u32> = (MIN_INVERSION_HARMONIC..=top)
            .filter(|k| !enabled.contains(k))
            .collect();
        if !missing.is_empty() && self.inversion.method == super::settings::InversionMethod::Full {
            out.push(format!(
                "force estimate from fewer harmonics: harmonics {} up to the inversion's \
                 harmonic {top} are not demodulated, so the full fit reads less of the pulse: \
                 enable demodulators at them (/demods/N/harmonic, /demods/N/enable)",
                ranges(&missing)
            ));
        }
        out
    }

    /// Whether `[adhesion]` is on where the engine ignores it.
    fn adhesion_ignored(&self) -> bool {
        self.adhesion.enable && self.synth.engine == Engine::Paper
    }

    /// Every node warning ([`Settings::node_warning`]), each once: demodulators out of band
    /// in one line, then the inversion's, then adhesion the engine ignores. For `status`
    /// and the dashboard.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        let outside = self.demods_out_of_band();
        if !outside.is_empty() {
            let list: Vec<String> = outside
                .iter()
                .map(|&i| {
                    let d = &self.demods[i];
                    match d.oscillator {
                        Oscillator::Drive => format!("{i} (H{})", d.harmonic),
                        Oscillator::Drive2 => format!("{i} (H{} of drive2)", d.harmonic),
                    }
                })
                .collect();
            out.push(format!(
                "demodulators out of band, producing no frames: {} (harmonic × its oscillator's \
                 frequency, /drive/frequency = {} or /drive2/frequency = {}, must be below the \
                 Nyquist frequency {})",
                list.join(", "),
                quantity(self.drive.frequency, "Hz"),
                quantity(self.drive2.frequency, "Hz"),
                quantity(nyquist(self), "Hz")
            ));
        }
        let mut seen = Vec::new();
        for path in ["/inversion/harmonic_a", "/inversion/harmonic_b"] {
            if let Some(w) = self.node_warning(path)
                && !seen.contains(&w)
            {
                out.push(format!("{path}: {w}"));
                seen.push(w);
            }
        }
        out.extend(self.force_warnings());
        if self.source.kind == SourceKind::Stream {
            out.push(format!("/source/kind: {STREAM_SOURCE_WARNING}"));
        } else if let Some(w) = self.node_warning("/adhesion/enable") {
            out.push(format!("/adhesion/enable: {w}"));
        }
        out
    }
}

/// What a node that only shapes the synthesis says while the samples come from a stream.
const STREAM_SOURCE_WARNING: &str = "the source is a stream (/source/kind): the synthesiser's \
     nodes (/sample, /surface, /adhesion, /noise, /scan, /feedback, \
     /inclusions, /synth/engine and its sub-steps) shape nothing; /drive/frequency is the \
     lock-in's reference, and the force inversion takes /cantilever and /tip as its model \
     of the lever that recorded the stream";

/// Whether the node at `path` only shapes the synthesised signal (no part of the DSP, the
/// reference or the inversion's model of the lever reads it).
fn shapes_only_the_synthesis(path: &str) -> bool {
    [
        "/source/kind",
        "/sample/",
        "/surface/",
        "/adhesion/",
        "/noise/",
        "/scan/",
        "/feedback/",
        "/pids/",
        "/inclusions/",
        "/synth/engine",
        "/synth/contact_substeps",
        "/synth/substep_budget",
        "/synth/anti_alias",
        "/synth/seed",
        "/drive/free_amplitude",
    ]
    .iter()
    .any(|p| path == *p || (p.ends_with('/') && path.starts_with(p)))
}

/// The fraction of the sample rate up to which the anti-alias filter is flat and the
/// lock-in measures a harmonic as it is (docs/signal-chain.md): the harmonics the inversion
/// relies on belong below it.
pub const PASSBAND_FRACTION: f64 = 0.4;

/// `x` rounded up to the next of 1, 1.25, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × a power of ten: a
/// sample rate to suggest (24 MS/s → 25 MS/s).
fn round_up_nicely(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let decade = 10f64.powf(x.log10().floor());
    [1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .find(|&v| v >= x * (1.0 - 1e-12))
        .unwrap_or(10.0 * decade)
}

/// Harmonics as runs: [2, 3, 4, 7] → "2-4, 7".
fn ranges(ks: &[u32]) -> String {
    let mut sorted = ks.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    let mut runs: Vec<String> = Vec::new();
    let mut i = 0;
    while i < sorted.len() {
        let mut j = i;
        while j + 1 < sorted.len() && sorted[j + 1] == sorted[j] + 1 {
            j += 1;
        }
        runs.push(if j > i {
            format!("{}-{}", sorted[i], sorted[j])
        } else {
            sorted[i].to_string()
        });
        i = j + 1;
    }
    runs.join(", ")
}

/// The drive frequency must stay below the Nyquist frequency, `/synth/sample_rate` / 2 (an
/// end that is itself excluded). Demodulators whose harmonic it pushes out of band stop
/// producing frames; they do not limit it.
pub(crate) fn highest_drive_frequency(s: &Settings) -> f64 {
    nyquist(s)
}

/// The lowest drive at which each pixel of the scan lasts at least [`MIN_PIXEL_PERIODS`]
/// drive periods at the current `/scan/line_rate` and `/scan/pixels` (checked whether or not
/// the scan runs), as `list` reports it.
pub(crate) fn lowest_drive_frequency(s: &Settings) -> f64 {
    2.0 * MIN_PIXEL_PERIODS * f64::from(s.scan.pixels) * s.scan.line_rate
}

/// The most `/cantilever/extra_modes` the current `/cantilever/q` allows: up to
/// [`MAX_MODES`] modes in all, and none without two Q values to fit the Rayleigh damping.
pub(crate) fn most_extra_modes(s: &Settings) -> u64 {
    let given = s.cantilever.q.len();
    if given < 2 {
        0
    } else {
        MAX_MODES.saturating_sub(given) as u64
    }
}

/// The mode count: `q` entries plus Rayleigh-damped extras, and enough `q` entries to fit
/// the Rayleigh form (B.7, two coefficients) when there are extras.
fn check_modes(s: &Settings) -> Result<(), NodeError> {
    let given = s.cantilever.q.len();
    let extra = s.cantilever.extra_modes;
    if given + extra > MAX_MODES {
        return Err(invalid(
            "/cantilever/extra_modes",
            format!(
                "/cantilever/extra_modes = {extra} with {given} entries in /cantilever/q makes \
                 {} modes: allowed at most {MAX_MODES} (entries of /cantilever/q + \
                 /cantilever/extra_modes ≤ {MAX_MODES})",
                given + extra
            ),
        ));
    }
    if extra > 0 && given < 2 {
        return Err(invalid(
            "/cantilever/extra_modes",
            format!(
                "/cantilever/extra_modes = {extra} needs at least 2 entries in /cantilever/q \
                 to fit the Rayleigh damping (B.7) of the extra modes, but /cantilever/q has \
                 {given}"
            ),
        ));
    }
    Ok(())
}

fn check_drive(s: &Settings) -> Result<(), NodeError> {
    let drive = s.drive.frequency;
    if drive >= nyquist(s) {
        return Err(invalid(
            "/drive/frequency",
            format!(
                "/drive/frequency = {} must be below the Nyquist frequency \
                 /synth/sample_rate / 2 = {}",
                quantity(drive, "Hz"),
                quantity(nyquist(s), "Hz")
            ),
        ));
    }
    Ok(())
}

/// The second excitation, while enabled: on the coupled engine (the paper engine's pulse
/// train is periodic in `/drive` alone), below the Nyquist frequency.
/// Disabled, it is only a reference: demodulators on it beyond Nyquist are out of band.
fn check_drive2(s: &Settings) -> Result<(), NodeError> {
    let d = &s.drive2;
    if !d.enable {
        return Ok(());
    }
    if d.frequency >= nyquist(s) {
        return Err(invalid(
            "/drive2/frequency",
            format!(
                "/drive2/frequency = {} must be below the Nyquist frequency \
                 /synth/sample_rate / 2 = {} while /drive2/enable = true",
                quantity(d.frequency, "Hz"),
                quantity(nyquist(s), "Hz")
            ),
        ));
    }
    if s.synth.engine != Engine::Coupled {
        return Err(invalid(
            "/drive2/enable",
            "/drive2/enable = true needs /synth/engine = \"coupled\": the paper engine's tap \
             force is a pulse train periodic in /drive alone"
                .to_owned(),
        ));
    }
    Ok(())
}

/// Spectrum frames may overlap, so the only limit on their rate is one per sample.
fn check_spectrum(s: &Settings) -> Result<(), NodeError> {
    let (rate, sample_rate) = (s.spectrum.rate, s.synth.sample_rate);
    if rate > sample_rate {
        return Err(invalid(
            "/spectrum/rate",
            format!(
                "/spectrum/rate = {} must not exceed /synth/sample_rate = {}",
                quantity(rate, "Hz"),
                quantity(sample_rate, "Hz")
            ),
        ));
    }
    Ok(())
}

/// Whether a trace of `span` photodiode samples (`/scope/length` × `/scope/decimation`)
/// lasts no longer than the time between traces, 1 / `/scope/rate`. Both sides are correctly
/// rounded quotients, so the test is monotone in `span`.
fn scope_span_fits(span: u64, s: &Settings) -> bool {
    span as f64 / s.synth.sample_rate <= 1.0 / s.scope.rate
}

/// The most photodiode samples one scope trace may span (`/scope/length` ×
/// `/scope/decimation`) so that traces do not overlap at the current `/scope/rate` and
/// `/synth/sample_rate`; at most 65536 × 10000, and 0 if not even one sample fits.
pub(crate) fn longest_scope_span(s: &Settings) -> u64 {
    let most = u64::from(MAX_SCOPE_LENGTH) * u64::from(MAX_SCOPE_DECIMATION);
    let (sample_rate, rate) = (s.synth.sample_rate, s.scope.rate);
    if !(sample_rate.is_finite() && rate.is_finite() && sample_rate > 0.0 && rate > 0.0) {
        return most;
    }
    // Start from the closed form, then step so the answer agrees exactly with
    // `scope_span_fits`, which `check_scope` applies.
    let mut span = (sample_rate / rate).floor().clamp(0.0, most as f64) as u64;
    while span > 0 && !scope_span_fits(span, s) {
        span -= 1;
    }
    while span < most && scope_span_fits(span + 1, s) {
        span += 1;
    }
    span
}

/// The highest `/scope/rate` at which traces of the current length and decimation do not
/// overlap: `/synth/sample_rate` / (`/scope/length` × `/scope/decimation`), as `list`
/// reports it.
pub(crate) fn highest_scope_rate(s: &Settings) -> f64 {
    let span = f64::from(s.scope.length) * f64::from(s.scope.decimation);
    s.synth.sample_rate / span
}

/// Scope traces must not overlap: each lasts `/scope/length` × `/scope/decimation` /
/// `/synth/sample_rate`, and one starts every 1 / `/scope/rate`. Checked whether or not the
/// scope is enabled, so enabling it never fails.
fn check_scope(s: &Settings) -> Result<(), NodeError> {
    let scope = &s.scope;
    let span = u64::from(scope.length) * u64::from(scope.decimation);
    if scope_span_fits(span, s) {
        return Ok(());
    }
    let duration = span as f64 / s.synth.sample_rate;
    Err(invalid(
        "/scope/rate",
        format!(
            "/scope/length × /scope/decimation / /synth/sample_rate = {} × {} / {} = {}, the \
             duration of one trace, must not exceed 1 / /scope/rate = 1 / {} = {}: traces must \
             not overlap (lower /scope/rate, /scope/length or /scope/decimation)",
            scope.length,
            scope.decimation,
            quantity(s.synth.sample_rate, "Hz"),
            quantity(duration, "s"),
            quantity(scope.rate, "Hz"),
            quantity(1.0 / scope.rate, "s")
        ),
    ))
}

fn check_demods(s: &Settings) -> Result<(), NodeError> {
    let sample_rate = s.synth.sample_rate;
    let period = 1.0 / sample_rate;
    for (index, demod) in s.demods.iter().enumerate() {
        if demod.timeconstant < period {
            return Err(invalid(
                format!("/demods/{index}/timeconstant"),
                format!(
                    "/demods/{index}/timeconstant = {} must be at least one sample period, \
                     1 / /synth/sample_rate = {}",
                    quantity(demod.timeconstant, "s"),
                    quantity(period, "s")
                ),
            ));
        }
        if demod.rate > sample_rate {
            return Err(invalid(
                format!("/demods/{index}/rate"),
                format!(
                    "/demods/{index}/rate = {} must not exceed /synth/sample_rate = {}",
                    quantity(demod.rate, "Hz"),
                    quantity(sample_rate, "Hz")
                ),
            ));
        }
    }
    Ok(())
}

/// The harmonics of `/drive` that the enabled demodulators measure, ascending, each once
/// (those on `/drive2` are no harmonics of the tapping).
fn enabled_harmonics(s: &Settings) -> Vec<u32> {
    let mut harmonics: Vec<u32> = s
        .demods
        .iter()
        .filter(|demod| demod.enable && demod.oscillator == Oscillator::Drive)
        .map(|demod| demod.harmonic)
        .collect();
    harmonics.sort_unstable();
    harmonics.dedup();
    harmonics
}

/// What the enabled demodulators measure, for messages: "enabled demodulators cover
/// harmonics 1–5, 7, 9–32", or "no demodulator is enabled".
fn describe_enabled_harmonics(s: &Settings) -> String {
    let harmonics = enabled_harmonics(s);
    let mut runs: Vec<(u32, u32)> = Vec::new();
    for &k in &harmonics {
        match runs.last_mut() {
            Some((_, last)) if *last + 1 == k => *last = k,
            _ => runs.push((k, k)),
        }
    }
    let shown: Vec<String> = runs
        .iter()
        .map(|&(first, last)| match last - first {
            0 => first.to_string(),
            1 => format!("{first}, {last}"),
            _ => format!("{first}–{last}"),
        })
        .collect();
    match harmonics.len() {
        0 => "no demodulator is enabled".to_owned(),
        1 => format!("enabled demodulators cover harmonic {}", shown[0]),
        _ => format!("enabled demodulators cover harmonics {}", shown.join(", ")),
    }
}

/// The lowest and highest value `/inversion/harmonic_a` (or `_b`, with `other` the value of
/// the other one) may take now, as `list` reports it: while the inversion is enabled, the
/// harmonics of enabled demodulators within 2 … [`MAX_HARMONIC`] other than `other`. `None`
/// when the inversion is disabled or no such demodulator exists (then the static range
/// stands).
pub(crate) fn inversion_harmonic_bounds(s: &Settings, other: u32) -> Option<(u64, u64)> {
    if !s.inversion.enable {
        return None;
    }
    let usable: Vec<u32> = enabled_harmonics(s)
        .into_iter()
        .filter(|&k| (MIN_INVERSION_HARMONIC..=MAX_HARMONIC).contains(&k) && k != other)
        .collect();
    Some((u64::from(*usable.first()?), u64::from(*usable.last()?)))
}

/// Whether demodulator `index` is, while the inversion is enabled, the only enabled one
/// measuring `/inversion/harmonic_a` or `_b`: then its harmonic cannot change.
pub(crate) fn sole_inversion_measure(s: &Settings, index: usize) -> bool {
    let Some(demod) = s.demods.get(index) else {
        return false;
    };
    let inversion = &s.inversion;
    let needed = [inversion.harmonic_a, inversion.harmonic_b];
    let on_drive = |d: &DemodSettings| d.enable && d.oscillator == Oscillator::Drive;
    inversion.enable
        && on_drive(demod)
        && needed.contains(&demod.harmonic)
        && !s
            .demods
            .iter()
            .enumerate()
            .any(|(i, d)| i != index && on_drive(d) && d.harmonic == demod.harmonic)
}

/// The inversion's two harmonics differ (always, so enabling the inversion never fails on
/// it), and while it is enabled each is measured by an enabled demodulator.
fn check_inversion(s: &Settings) -> Result<(), NodeError> {
    let inversion = &s.inversion;
    let (a, b) = (inversion.harmonic_a, inversion.harmonic_b);
    if a == b {
        return Err(invalid(
            "/inversion/harmonic_b",
            format!(
                "/inversion/harmonic_a = {a} and /inversion/harmonic_b = {b} must differ: the \
                 inversion needs two distinct harmonics"
            ),
        ));
    }
    if !inversion.enable {
        return Ok(());
    }
    let measured = |k: u32| {
        s.demods
            .iter()
            .any(|d| d.enable && d.oscillator == Oscillator::Drive && d.harmonic == k)
    };
    for (path, k) in [("/inversion/harmonic_a", a), ("/inversion/harmonic_b", b)] {
        if !measured(k) {
            return Err(invalid(
                path,
                format!(
                    "{path} = {k} is not measured by any enabled demodulator: while \
                     /inversion/enable = true, /inversion/harmonic_a and /inversion/harmonic_b \
                     must each be the harmonic of an enabled demodulator (/demods/N/harmonic \
                     with /demods/N/enable = true), and {}",
                    describe_enabled_harmonics(s)
                ),
            ));
        }
    }
    Ok(())
}

/// The highest `/scan/line_rate` at which each pixel lasts at least [`MIN_PIXEL_PERIODS`]
/// drive periods: a pixel lasts 1 / (2 × `/scan/pixels` × `/scan/line_rate`) (trace and
/// retrace share a line), so `/drive/frequency` / (2 × 10 × `/scan/pixels`).
fn dwell_line_rate(s: &Settings, pixels: u64) -> f64 {
    s.drive.frequency / (2.0 * MIN_PIXEL_PERIODS * pixels as f64)
}

/// The highest `/scan/line_rate` at which the image stream carries at most
/// [`MAX_PIXEL_RATE`] pixels per second: 20000 / (2 × `/scan/pixels`).
fn stream_line_rate(pixels: u64) -> f64 {
    MAX_PIXEL_RATE / (2.0 * pixels as f64)
}

/// Whether a scan of `pixels` per line at the current `/scan/line_rate` meets both limits;
/// monotone in `pixels`, so [`highest_scan_pixels`] can step to the exact edge.
fn scan_fits(pixels: u64, s: &Settings) -> bool {
    let rate = s.scan.line_rate;
    rate <= dwell_line_rate(s, pixels) && rate <= stream_line_rate(pixels)
}

/// The highest `/scan/line_rate` the relations allow with the current `/scan/pixels` and
/// `/drive/frequency`, as `list` reports it.
pub(crate) fn highest_line_rate(s: &Settings) -> f64 {
    let pixels = u64::from(s.scan.pixels);
    dwell_line_rate(s, pixels).min(stream_line_rate(pixels))
}

/// The most `/scan/pixels` the relations allow at the current `/scan/line_rate` and
/// `/drive/frequency`, at most [`MAX_SCAN_PIXELS`] (0 if not even one pixel fits), as `list`
/// reports it.
pub(crate) fn highest_scan_pixels(s: &Settings) -> u64 {
    let most = u64::from(MAX_SCAN_PIXELS);
    let (drive, rate) = (s.drive.frequency, s.scan.line_rate);
    if !(drive.is_finite() && rate.is_finite() && drive > 0.0 && rate > 0.0) {
        return most;
    }
    // Start from the closed form, then step so the answer agrees exactly with `scan_fits`,
    // which `check_scan` applies.
    let closed = (drive / (2.0 * MIN_PIXEL_PERIODS * rate)).min(MAX_PIXEL_RATE / (2.0 * rate));
    let mut pixels = closed.floor().clamp(0.0, most as f64) as u64;
    while pixels > 0 && !scan_fits(pixels, s) {
        pixels -= 1;
    }
    while pixels < most && scan_fits(pixels + 1, s) {
        pixels += 1;
    }
    pixels
}

/// The scan's line rate: each pixel lasts at least [`MIN_PIXEL_PERIODS`] drive periods (so
/// the lock-in sees each material), and the image stream carries at most
/// [`MAX_PIXEL_RATE`] pixels per second. Checked whether or not the scan is enabled, so
/// starting a scan never fails.
/// While a sweep runs: its ends within the swept node's range now, log spacing only above
/// 0, two different ends, and some demodulator to measure with. (Whether a tune's free
/// amplitude stays in range at every point is the model's question: `model::check`.)
fn check_sweeper(s: &Settings) -> Result<(), NodeError> {
    let w = &s.sweeper;
    if !w.enable {
        return Ok(());
    }
    let path = w.parameter.name();
    let spec = super::registry::node(path).ok_or_else(|| NodeError::UnknownPath {
        path: path.to_owned(),
    })?;
    let (low, high) = spec.bounds(s);
    let (low, high) = (
        low.as_f64().unwrap_or(f64::NEG_INFINITY),
        high.as_f64().unwrap_or(f64::INFINITY),
    );
    // The node's own interval narrowed by the bounds the settings put on it now, with each
    // end open or closed as it is enforced.
    let allowed = match spec.kind {
        Kind::Float(r) => {
            let min = if low > r.min.value {
                Bound {
                    value: low,
                    inclusive: true,
                }
            } else {
                r.min
            };
            let max = if high < r.max.value {
                Bound {
                    value: high,
                    inclusive: true,
                }
            } else {
                r.max
            };
            format!("{}{}", Range { min, max }, spec.unit_suffix())
        }
        _ => format!(
            "{} ≤ value ≤ {}{}",
            number(low),
            number(high),
            spec.unit_suffix()
        ),
    };
    for (key, value) in [("start", w.start), ("stop", w.stop)] {
        let bad = spec.check(&super::kind::Typed::Float(value)).err();
        if bad.is_some() || value < low || value > high {
            return Err(invalid(
                format!("/sweeper/{key}"),
                format!(
                    "/sweeper/{key} = {} is outside the range of /sweeper/parameter = {path} now: \
                     allowed {allowed}",
                    number(value),
                ),
            ));
        }
    }
    if w.start == w.stop {
        return Err(invalid(
            "/sweeper/stop",
            format!(
                "/sweeper/stop = /sweeper/start = {}: a sweep needs two different ends",
                number(w.stop)
            ),
        ));
    }
    if w.scale == super::settings::SweepScale::Log && (w.start <= 0.0 || w.stop <= 0.0) {
        return Err(invalid(
            "/sweeper/scale",
            format!(
                "/sweeper/scale = \"log\" needs /sweeper/start and /sweeper/stop above 0, got {} \
                 and {}",
                number(w.start),
                number(w.stop)
            ),
        ));
    }
    if !(0..DEMODULATOR_COUNT).any(|i| s.demod_active(i)) {
        return Err(invalid(
            "/sweeper/enable",
            "a sweep measures with the demodulators, and none is enabled and in band: enable \
             one (/demods/N/enable)"
                .to_owned(),
        ));
    }
    Ok(())
}

/// The enabled PID units' limits between nodes: their harmonic in band, an output the
/// engine can move exactly, output limits inside the output's range, at most one unit per
/// output, and no PID on the surface distance while the scan's feedback or a sweep of it
/// holds it. The gains' own consistency (signs, the derivative's bandwidth under the PID's
/// Nyquist frequency, min ≤ max) is the controller's: `model::check_pids`.
fn check_pids(s: &Settings) -> Result<(), NodeError> {
    let mut driven: [Option<usize>; PidTarget::ALL.len()] = [None; PidTarget::ALL.len()];
    for (index, pid) in s.pids.iter().enumerate().filter(|(_, p)| p.enable) {
        let target = pid.output.name();
        let second = pid.oscillator == Oscillator::Drive2;
        if (second || pid.output.on_drive2()) && !s.drive2.enable {
            let key = if second { "oscillator" } else { "output" };
            let value = if second {
                pid.oscillator.name()
            } else {
                target
            };
            return Err(invalid(
                format!("/pids/{index}/{key}"),
                format!(
                    "/pids/{index}/{key} = \"{value}\" while /pids/{index}/enable is true needs \
                     the second excitation: set /drive2/enable = true first (and disable the \
                     PID before /drive2/enable = false)"
                ),
            ));
        }
        if pid.input == PidInput::FrequencyShift
            && !s.pids.iter().any(|p| {
                p.enable
                    && p.input == PidInput::Phase
                    && p.output.frequency_of() == Some(pid.oscillator)
            })
        {
            let target = match pid.oscillator {
                Oscillator::Drive => PidTarget::DriveFrequency,
                Oscillator::Drive2 => PidTarget::Drive2Frequency,
            };
            return Err(invalid(
                format!("/pids/{index}/input"),
                format!(
                    "/pids/{index}/input = \"frequency_shift\" while /pids/{index}/enable is true \
                     reads the frequency shift of the PLL on its oscillator \
                     (/pids/{index}/oscillator = \"{}\"): enable a unit with input \"phase\" \
                     and output \"{}\" first",
                    pid.oscillator.name(),
                    target.name()
                ),
            ));
        }
        if pid.input == PidInput::MeanDeflection && second {
            return Err(invalid(
                format!("/pids/{index}/oscillator"),
                format!(
                    "/pids/{index}/input = \"mean_deflection\" while /pids/{index}/enable is \
                     true reads the mean of the samples over a drive period: set \
                     /pids/{index}/oscillator = \"drive\""
                ),
            ));
        }
        let frequency = s.oscillator_frequency(pid.oscillator);
        if pid.input != PidInput::MeanDeflection
            && f64::from(pid.harmonic) * frequency >= nyquist(s)
        {
            let node = if second {
                "/drive2/frequency"
            } else {
                "/drive/frequency"
            };
            return Err(invalid(
                format!("/pids/{index}/harmonic"),
                format!(
                    "/pids/{index}/harmonic = {} is out of band while /pids/{index}/enable is \
                     true: k × {node} = {} must stay below /synth/sample_rate / 2 = {} \
                     (at most {})",
                    pid.harmonic,
                    quantity(f64::from(pid.harmonic) * frequency, "Hz"),
                    quantity(nyquist(s), "Hz"),
                    harmonics_below(frequency, nyquist(s))
                ),
            ));
        }
        // The node's own range keeps the bandwidth a number above 0.
        if second && pid.input_bandwidth > s.drive.frequency / 4.0 {
            return Err(invalid(
                format!("/pids/{index}/input_bandwidth"),
                format!(
                    "/pids/{index}/input_bandwidth = {} is too wide for a unit on \"drive2\": \
                     allowed 0 < value ≤ /drive/frequency / 4 = {} (the unit reads its \
                     low-pass once per drive period)",
                    quantity(pid.input_bandwidth, "Hz"),
                    quantity(s.drive.frequency / 4.0, "Hz")
                ),
            ));
        }
        if s.source.kind == SourceKind::Stream {
            return Err(invalid(
                format!("/pids/{index}/enable"),
                format!(
                    "/pids/{index}/enable = true with /source/kind = \"stream\": the PIDs act on \
                     the synthesised cantilever, which a streamed source replaces"
                ),
            ));
        }
        if s.synth.engine != Engine::Coupled {
            return Err(invalid(
                format!("/pids/{index}/output"),
                format!(
                    "/pids/{index}/output = \"{target}\" needs /synth/engine = \"coupled\": \
                     the paper engine's tap force is the 1-DOF orbit at a fixed \
                     /surface/distance and drive, which it cannot move sample by sample"
                ),
            ));
        }
        match pid.output {
            PidTarget::SurfaceDistance => {
                // With the scan's own feedback off, a unit on the surface is its feedback.
                if s.scan.enable && s.feedback.enable {
                    return Err(invalid(
                        format!("/pids/{index}/output"),
                        format!(
                            "/pids/{index} drives the surface distance (/pids/{index}/output = \
                             \"{target}\") while /scan/enable = true, and the scan's amplitude \
                             feedback (/feedback/enable = true) drives it: disable one of them \
                             (with /feedback/enable = false the unit is the scan's feedback)"
                        ),
                    ));
                }
                check_pid_range(
                    index,
                    pid,
                    MIN_PID_DISTANCE,
                    MAX_PID_DISTANCE,
                    "m",
                    "the surface distance",
                )?;
            }
            PidTarget::DriveFrequency | PidTarget::DriveAmplitude => {
                if s.scan.enable && s.feedback.enable {
                    return Err(invalid(
                        format!("/pids/{index}/output"),
                        format!(
                            "/pids/{index} drives the drive (/pids/{index}/output = \
                             \"{target}\") while /scan/enable = true, whose amplitude \
                             feedback (/feedback/enable = true) reads the drive as /drive/* \
                             configure it: disable one of them (with /feedback/enable = false \
                             a unit on \"surface_distance\" is the scan's feedback; the second \
                             excitation's outputs run beside either)"
                        ),
                    ));
                }
            }
            // Bimodal AFM's mode-2 loops run beside a scan: its pixels carry the second
            // excitation's frequency.
            PidTarget::Drive2Frequency | PidTarget::Drive2Amplitude => {}
        }
        let swept = match pid.output {
            PidTarget::SurfaceDistance => Some(SweepParameter::SurfaceDistance),
            PidTarget::DriveFrequency => Some(SweepParameter::DriveFrequency),
            PidTarget::DriveAmplitude => Some(SweepParameter::DriveFreeAmplitude),
            PidTarget::Drive2Frequency | PidTarget::Drive2Amplitude => None,
        };
        if let Some(swept) = swept.filter(|&p| s.sweeper.enable && s.sweeper.parameter == p) {
            return Err(invalid(
                format!("/pids/{index}/output"),
                format!(
                    "/pids/{index} drives {} (/pids/{index}/output = \"{target}\") while a \
                     sweep steps it (/sweeper/parameter = \"{}\", /sweeper/enable = true): \
                     disable one of them",
                    swept.name(),
                    swept.name()
                ),
            ));
        }
        if let Some(moved) = pid.output.frequency_of() {
            // Every harmonic read of the oscillator must stay in band wherever the loop
            // takes it.
            let highest = (0..DEMODULATOR_COUNT)
                .filter(|&i| s.demod_active(i) && s.demods[i].oscillator == moved)
                .map(|i| s.demods[i].harmonic)
                .chain(
                    s.pids
                        .iter()
                        .filter(|p| p.enable && p.oscillator == moved)
                        .map(|p| p.harmonic),
                )
                .max()
                .unwrap_or(1);
            let limit = nyquist(s) / f64::from(highest);
            for (key, value) in [
                ("output_min", pid.output_min),
                ("output_max", pid.output_max),
            ] {
                if !(value > 0.0 && value < limit) {
                    return Err(invalid(
                        format!("/pids/{index}/{key}"),
                        format!(
                            "/pids/{index}/{key} = {} is outside the {} frequency's range for \
                             /pids/{index}/output = \"{target}\": allowed 0 < value < {} \
                             (/synth/sample_rate / 2 / {highest}, the highest harmonic of it \
                             an enabled demodulator or PID reads)",
                            quantity(value, "Hz"),
                            moved.name(),
                            quantity(limit, "Hz")
                        ),
                    ));
                }
            }
        }
        if matches!(
            pid.output,
            PidTarget::DriveAmplitude | PidTarget::Drive2Amplitude
        ) {
            check_pid_range(
                index,
                pid,
                0.0,
                MAX_PID_DISTANCE,
                "m",
                "the excitation's free amplitude",
            )?;
        }
        let slot = &mut driven[pid.output as usize];
        if let Some(first) = *slot {
            return Err(invalid(
                format!("/pids/{index}/output"),
                format!(
                    "/pids/{index}/output = \"{target}\", which /pids/{first} drives already \
                     (both enabled): an output takes at most one enabled PID"
                ),
            ));
        }
        *slot = Some(index);
    }
    Ok(())
}

/// PID unit `index`'s output limits within [`low`, `high`] (in `unit`), the range of `what`.
fn check_pid_range(
    index: usize,
    pid: &PidUnitSettings,
    low: f64,
    high: f64,
    unit: &str,
    what: &str,
) -> Result<(), NodeError> {
    let target = pid.output.name();
    for (key, value) in [
        ("output_min", pid.output_min),
        ("output_max", pid.output_max),
    ] {
        if !(low..=high).contains(&value) {
            return Err(invalid(
                format!("/pids/{index}/{key}"),
                format!(
                    "/pids/{index}/{key} = {} is outside {what}'s range for /pids/{index}/output \
                     = \"{target}\": allowed {} ≤ value ≤ {}",
                    quantity(value, unit),
                    quantity(low, unit),
                    quantity(high, unit)
                ),
            ));
        }
    }
    Ok(())
}

fn check_scan(s: &Settings) -> Result<(), NodeError> {
    let scan = &s.scan;
    let pixels = u64::from(scan.pixels);
    let rate = scan.line_rate;
    let dwell = dwell_line_rate(s, pixels);
    if rate > dwell {
        return Err(invalid(
            "/scan/line_rate",
            format!(
                "/scan/line_rate = {}: with {pixels} pixels per line (/scan/pixels) each pixel \
                 must last at least {} drive periods ({} / /drive/frequency = {}), so at most \
                 /drive/frequency / ({} × /scan/pixels) = {}",
                quantity(rate, "Hz"),
                number(MIN_PIXEL_PERIODS),
                number(MIN_PIXEL_PERIODS),
                quantity(MIN_PIXEL_PERIODS / s.drive.frequency, "s"),
                number(2.0 * MIN_PIXEL_PERIODS),
                quantity(dwell, "Hz")
            ),
        ));
    }
    let stream = stream_line_rate(pixels);
    if rate > stream {
        return Err(invalid(
            "/scan/line_rate",
            format!(
                "/scan/line_rate = {}: with {pixels} pixels per line (/scan/pixels) the image \
                 stream would carry 2 × /scan/pixels × /scan/line_rate = {} pixels per second, \
                 more than its {}, so at most {} / (2 × /scan/pixels) = {}",
                quantity(rate, "Hz"),
                number(2.0 * pixels as f64 * rate),
                number(MAX_PIXEL_RATE),
                number(MAX_PIXEL_RATE),
                quantity(stream, "Hz")
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Engine, default_settings};

    #[test]
    fn harmonics_above_the_passband_warn_with_the_sample_rate_that_fits_them() {
        let mut s = default_settings();
        assert!(s.force_warnings().is_empty(), "{:?}", s.force_warnings());
        // tap300 at 10 MS/s: H14 (4.2 MHz) and above are beyond 4 MHz.
        s.cantilever.f1 = 300e3;
        s.drive.frequency = 300e3;
        let w = s.force_warnings();
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("harmonics 14-32") && w[0].contains("4 MHz at 10 MS/s"),
            "{}",
            w[0]
        );
        assert!(
            w[0].contains("raise /synth/sample_rate to 25e6"),
            "{}",
            w[0]
        );
        assert!(s.warnings().contains(&w[0]));
        s.synth.sample_rate = 25e6;
        assert!(s.force_warnings().is_empty(), "{:?}", s.force_warnings());
        // A gap in the bank below the inversion's upper harmonic.
        s.demods[9].enable = false;
        s.demods[10].enable = false;
        let w = s.force_warnings();
        assert!(
            w.len() == 1 && w[0].contains("harmonics 10-11") && w[0].contains("not demodulated"),
            "{w:?}"
        );
        s.inversion.enable = false;
        assert!(s.force_warnings().is_empty());
    }

    #[test]
    fn suggested_sample_rates_round_up() {
        assert_eq!(round_up_nicely(24e6), 25e6);
        assert_eq!(round_up_nicely(12e6), 12.5e6);
        assert_eq!(round_up_nicely(10e6), 10e6);
        assert_eq!(round_up_nicely(8.1e6), 10e6);
        assert_eq!(ranges(&[2, 3, 4, 7, 9, 10]), "2-4, 7, 9-10");
    }

    #[test]
    fn highest_harmonic_agrees_with_the_check() {
        let highest_harmonic = |s: &Settings| harmonics_below(s.drive.frequency, nyquist(s));
        let mut s = default_settings();
        // 10 MHz sampling, 100 kHz drive: 50 × 100 kHz is exactly Nyquist, so 49.
        assert_eq!(highest_harmonic(&s), 49);
        s.drive.frequency = 3e6;
        assert_eq!(highest_harmonic(&s), 1);
        s.drive.frequency = 1.0;
        assert_eq!(highest_harmonic(&s), u64::from(MAX_HARMONIC));
    }

    #[test]
    fn a_scan_runs_on_either_engine() {
        let mut s = default_settings();
        s.scan.enable = true;
        for engine in Engine::ALL {
            s.synth.engine = engine;
            assert!(s.validate().is_ok(), "{engine:?}");
        }
    }

    #[test]
    fn spectrum_rate_is_at_most_the_sample_rate() {
        // The static ranges (rate ≤ 1 kHz, sample rate ≥ 1 kHz) keep this from failing in
        // `validate`; the relation itself still holds its ground.
        let mut s = default_settings();
        s.spectrum.rate = 1e3;
        s.synth.sample_rate = 1e3;
        assert!(check_spectrum(&s).is_ok());
        s.synth.sample_rate = 500.0;
        let message = check_spectrum(&s).unwrap_err().to_string();
        assert_eq!(
            message,
            "/spectrum/rate = 1 kHz must not exceed /synth/sample_rate = 500 Hz"
        );
    }

    #[test]
    fn longest_scope_span_agrees_with_the_check() {
        let mut s = default_settings();
        // 10 MHz / 20 Hz: 500000 samples between trace starts.
        assert_eq!(longest_scope_span(&s), 500_000);
        assert!(scope_span_fits(500_000, &s) && !scope_span_fits(500_001, &s));
        s.scope.rate = 100.0;
        s.synth.sample_rate = 6_553_600.0;
        assert_eq!(longest_scope_span(&s), 65_536);
        s.scope.rate = 3.0;
        s.synth.sample_rate = 1e3;
        assert_eq!(longest_scope_span(&s), 333);
        for rate in [0.7, 1.0 / 3.0, 7.0, 99.9, 100.0] {
            s.scope.rate = rate;
            let span = longest_scope_span(&s);
            assert!(scope_span_fits(span, &s) && !scope_span_fits(span + 1, &s));
        }
        // Never above the longest trace the static ranges allow.
        s.synth.sample_rate = 1e9;
        s.scope.rate = 1e-3;
        assert_eq!(longest_scope_span(&s), 65_536 * 10_000);
    }

    #[test]
    fn overlapping_scope_traces_name_all_four_nodes() {
        let mut s = default_settings();
        s.scope.length = 65_536;
        s.scope.decimation = 2;
        s.scope.rate = 100.0;
        let error = s.validate().unwrap_err();
        assert_eq!(error.path(), "/scope/rate");
        let message = error.to_string();
        for path in [
            "/scope/length",
            "/scope/decimation",
            "/scope/rate",
            "/synth/sample_rate",
        ] {
            assert!(message.contains(path), "{message}");
        }
        assert!(
            message.contains("13.1072 ms") && message.contains("10 ms"),
            "{message}"
        );
        s.scope.decimation = 1;
        assert!(s.validate().is_ok());
    }

    #[test]
    fn enabled_harmonics_read_as_runs() {
        let mut s = default_settings();
        assert_eq!(
            describe_enabled_harmonics(&s),
            "enabled demodulators cover harmonics 1–32"
        );
        s.demods[5].enable = false;
        s.demods[7].enable = false;
        s.demods[8].enable = false;
        s.demods[30].harmonic = 400;
        s.demods[31].harmonic = 3;
        assert_eq!(
            describe_enabled_harmonics(&s),
            "enabled demodulators cover harmonics 1–5, 7, 10–30, 400"
        );
        for demod in &mut s.demods {
            demod.enable = false;
        }
        assert_eq!(describe_enabled_harmonics(&s), "no demodulator is enabled");
        s.demods[2].enable = true;
        assert_eq!(
            describe_enabled_harmonics(&s),
            "enabled demodulators cover harmonic 3"
        );
        s.demods[3].enable = true;
        assert_eq!(
            describe_enabled_harmonics(&s),
            "enabled demodulators cover harmonics 3, 4"
        );
    }

    #[test]
    fn inversion_harmonics_are_measured_while_enabled() {
        let mut s = default_settings();
        assert_eq!(inversion_harmonic_bounds(&s, 17), Some((2, 32)));
        s.inversion.harmonic_b = 40;
        let error = s.validate().unwrap_err();
        assert_eq!(error.path(), "/inversion/harmonic_b");
        assert_eq!(
            error.to_string(),
            "/inversion/harmonic_b = 40 is not measured by any enabled demodulator: while \
             /inversion/enable = true, /inversion/harmonic_a and /inversion/harmonic_b must \
             each be the harmonic of an enabled demodulator (/demods/N/harmonic with \
             /demods/N/enable = true), and enabled demodulators cover harmonics 1–32"
        );
        s.inversion.enable = false;
        assert!(s.validate().is_ok());
        assert_eq!(inversion_harmonic_bounds(&s, 6), None);
        s.inversion.harmonic_a = 40;
        let error = s.validate().unwrap_err();
        assert_eq!(error.path(), "/inversion/harmonic_b");
        assert_eq!(
            error.to_string(),
            "/inversion/harmonic_a = 40 and /inversion/harmonic_b = 40 must differ: the \
             inversion needs two distinct harmonics"
        );
        // Only the fundamental and the mean measured: nothing the inversion may use.
        let mut s = default_settings();
        for demod in &mut s.demods[2..] {
            demod.enable = false;
        }
        s.demods[0].harmonic = 0;
        assert_eq!(inversion_harmonic_bounds(&s, 17), Some((2, 2)));
        s.demods[1].harmonic = 1;
        assert_eq!(inversion_harmonic_bounds(&s, 17), None);
    }

    #[test]
    fn scan_limits_agree_with_the_check() {
        let mut s = default_settings();
        // 100 kHz drive, 64 pixels: 100e3 / (20 × 64) = 78.125 Hz; 20000 / 128 = 156.25.
        assert_eq!(highest_line_rate(&s), 78.125);
        // At 2 Hz: 100e3 / 40 = 2500 pixels by dwell, 5000 by the stream: capped at 1024.
        assert_eq!(highest_scan_pixels(&s), 1024);
        for rate in [2.0, 3.0, 7.7, 39.0625, 50.0, 99.9, 100.0, 1e-3] {
            s.scan.line_rate = rate;
            let pixels = highest_scan_pixels(&s);
            assert!(pixels == 1024 || !scan_fits(pixels + 1, &s), "{rate}");
            assert!(pixels == 0 || scan_fits(pixels, &s), "{rate}");
        }
        s.scan.line_rate = 39.0625;
        assert_eq!(highest_scan_pixels(&s), 128);
        assert!(check_scan(&s).is_ok());
        s.scan.pixels = 129;
        assert_eq!(check_scan(&s).unwrap_err().path(), "/scan/line_rate");
        // A fast drive: the image stream's 20000 pixels per second bind first.
        s.drive.frequency = 1e6;
        s.scan.pixels = 128;
        assert_eq!(highest_line_rate(&s), 78.125);
        s.scan.line_rate = 78.125;
        assert_eq!(highest_scan_pixels(&s), 128);
        s.scan.line_rate = 100.0;
        assert_eq!(highest_scan_pixels(&s), 100);
        assert_eq!(
            check_scan(&s).unwrap_err().to_string(),
            "/scan/line_rate = 100 Hz: with 128 pixels per line (/scan/pixels) the image \
             stream would carry 2 × /scan/pixels × /scan/line_rate = 25600 pixels per second, \
             more than its 20000, so at most 20000 / (2 × /scan/pixels) = 78.125 Hz"
        );
    }

    #[test]
    fn a_demodulator_out_of_band_is_kept_and_named() {
        let mut s = default_settings();
        s.demods[3].harmonic = 60;
        s.validate().unwrap();
        assert!(!s.demod_active(3));
        assert_eq!(s.demods_out_of_band(), [3]);
        assert_eq!(
            s.node_warning("/demods/3/harmonic").unwrap(),
            "out of band: /demods/3/harmonic × /drive/frequency = 60 × 100 kHz = 6 MHz is at \
             or above the Nyquist frequency /synth/sample_rate / 2 = 5 MHz; demodulator 3 \
             produces no frames (harmonics up to 49 are in band: lower its harmonic or \
             /drive/frequency, or raise the sample rate in the config)"
        );
        assert!(s.node_warning("/demods/4/harmonic").is_none());
        s.demods[3].enable = false;
        assert!(s.node_warning("/demods/3/harmonic").is_none());
        // Harmonic 4 is now missing below the inversion's 17: the full fit says so.
        let w = s.warnings();
        assert!(
            w.len() == 1 && w[0].contains("harmonics 4 up to the inversion's harmonic 17"),
            "{w:?}"
        );
    }

    #[test]
    fn the_inversion_takes_in_band_harmonics_in_place_of_lost_ones() {
        // A 300 kHz lever at 10 MS/s: harmonics 1 … 16 in band, so 17 is replaced by 16.
        let mut s = default_settings();
        s.cantilever.f1 = 300e3;
        s.drive.frequency = 300e3;
        s.validate().unwrap();
        assert_eq!(s.inversion_harmonics(), Some((6, 16)));
        assert!(s.node_warning("/inversion/harmonic_a").is_none());
        assert_eq!(
            s.node_warning("/inversion/harmonic_b").unwrap(),
            "harmonic 17 is out of band (5.1 MHz ≥ the Nyquist frequency 5 MHz): the \
             inversion uses harmonic 16 instead"
        );
        // Out of band, replaced, and the force estimate's harmonics 14-32 above 0.4 f_s.
        assert_eq!(s.warnings().len(), 3, "{:?}", s.warnings());
        // Both out of band: the two highest in band, in order.
        s.inversion.harmonic_a = 20;
        s.inversion.harmonic_b = 18;
        assert_eq!(s.inversion_harmonics(), Some((15, 16)));
        // Fewer than two active harmonics ≥ 2: no estimates, said once.
        s.drive.frequency = 2.4e6;
        s.cantilever.f1 = 2.4e6;
        assert_eq!(s.inversion_harmonics(), None);
        let warnings = s.warnings();
        assert_eq!(
            warnings.iter().filter(|w| w.contains("no force")).count(),
            1,
            "{warnings:?}"
        );
    }

    #[test]
    fn adhesion_on_the_paper_engine_is_a_warning_on_its_nodes_and_in_status() {
        let mut s = default_settings();
        s.synth.engine = Engine::Paper;
        assert!(s.warnings().is_empty());
        s.adhesion.enable = true;
        s.validate().unwrap();
        let w = s.node_warning("/adhesion/hamaker").unwrap();
        assert!(w.contains("\"paper\"") && w.contains("\"coupled\""), "{w}");
        assert_eq!(s.node_warning("/synth/engine").as_deref(), Some(w.as_str()));
        assert_eq!(s.warnings(), vec![format!("/adhesion/enable: {w}")]);
        s.synth.engine = Engine::Coupled;
        assert!(s.node_warning("/adhesion/enable").is_none());
        assert!(s.warnings().is_empty());
    }
}
