//! The analysis of a recording: its reference, the lock-in bank and spectrum of
//! [`DspPlan`] and the force inversion of [`ForceEstimator`], as the daemon runs them, over
//! the file in pieces, with the outputs streamed to `.npy` files.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::npy::NpyWriter;
use super::reader::{Format, Source};
use super::reference::{self, Fit};
use crate::config::Settings;
use crate::inversion::{ForceEstimate, ForceEstimator};
use crate::pipeline::{DemodFrame, DemodValue, DspPlan, DspSink, DspTeam, dsp_threads};
use crate::timebase::{frequency_word, phase_to_radians};

/// Sample times read and processed per piece: 2^16 (a few MB for any channel count).
pub const PIECE: usize = 1 << 16;

/// What to analyse and how (`ftafm analyse`'s flags).
#[derive(Clone, Debug)]
pub struct Options {
    /// The recording; `-` is standard input (raw formats).
    pub file: PathBuf,
    pub format: Format,
    /// Channels of raw input (the other formats have them in the header).
    pub channels: usize,
    /// The channel holding the photodiode signal (0 = first).
    pub signal_channel: usize,
    /// Sample rate (Hz) where the file has none, or to override it.
    pub sample_rate: Option<f64>,
    /// The channel holding the excitation, whose phase is the reference.
    pub reference_channel: Option<usize>,
    /// The drive frequency (Hz), refined from the signal.
    pub drive_frequency: Option<f64>,
    /// The channel holding the second excitation, whose phase is the reference of the
    /// demodulators on `drive2` (it may be the first excitation's channel, both summed).
    pub reference2_channel: Option<usize>,
    /// The second excitation's frequency (Hz), refined from the signal (or, with
    /// `reference2_channel`, where to look for it).
    pub drive2_frequency: Option<f64>,
    /// InvOLS (m/V): metres per unit of the file's values.
    pub invols: Option<f64>,
    /// The file's values are metres already.
    pub metres: bool,
    /// Directory for demods.npy, force.npy, spectrum.npy, summary.json.
    pub out: Option<PathBuf>,
    /// Show a progress bar on standard error.
    pub progress: bool,
}

/// The reference written next to a recording by `ftafm record-signal` (`F.json` next to
/// `F.npy`): the synthesiser's own drive phase words, so the analysis locks exactly as the
/// daemon's lock-in did.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Sidecar {
    /// Always "ftafm-signal".
    pub format: String,
    /// Sample rate (Hz).
    pub sample_rate: f64,
    /// Drive frequency (Hz).
    pub drive_frequency: f64,
    /// The drive's phase increment per sample (2^64 = one cycle).
    pub frequency_word: u64,
    /// The drive phase word of the first sample.
    pub phase_word: u64,
    /// "m": the samples are metres.
    pub units: String,
}

/// The sidecar path of a recording: the same name with `.json`.
pub fn sidecar_path(file: &Path) -> PathBuf {
    file.with_extension("json")
}

/// How the reference was obtained, and what it is.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceReport {
    /// "sidecar" (the synthesiser's drive words), "channel N" (an excitation channel) or
    /// "signal" (the signal's own fundamental, as a PLL locks).
    pub source: String,
    /// Frequency (Hz).
    pub frequency: f64,
    /// Phase of the first sample (rad, cosine convention).
    pub phase: f64,
    /// The fit, where one was made.
    pub fit: Option<Fit>,
}

impl ReferenceReport {
    /// The reference a fit measured, from `source`.
    fn fitted(source: String, fit: Fit) -> Self {
        Self {
            source,
            frequency: fit.frequency,
            phase: fit.phase,
            fit: Some(fit),
        }
    }
}

/// Mean and spread of one force quantity over the estimates.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Spread {
    /// Mean of the estimates.
    pub mean: f64,
    /// Standard deviation of the estimates about their mean.
    pub std: f64,
    /// Mean of the estimates' own stated standard deviations.
    pub sigma: f64,
    #[serde(skip)]
    n: f64,
    #[serde(skip)]
    m2: f64,
}

impl Spread {
    fn add(&mut self, v: f64, sigma: f64) {
        self.n += 1.0;
        let d = v - self.mean;
        self.mean += d / self.n;
        self.m2 += d * (v - self.mean);
        self.std = if self.n > 1.0 {
            (self.m2 / (self.n - 1.0)).sqrt()
        } else {
            0.0
        };
        self.sigma += (sigma - self.sigma) / self.n;
    }
}

/// The force estimates in brief.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ForceSummary {
    /// Estimates made.
    pub estimates: u64,
    /// Averaging windows whose fit failed (counted; the last reason in `last_error`).
    pub failed: u64,
    /// Demodulator frames left out while the filters settled.
    pub unsettled_frames: u64,
    /// Time from which frames were used (s).
    pub settle_from: f64,
    pub max_force: Spread,
    pub youngs_modulus: Spread,
    pub contact_time_ratio: Spread,
    pub last_error: Option<String>,
    /// Why the estimates may be biased (the estimator's warnings).
    pub warnings: Vec<String>,
}

/// What `ftafm analyse` reports.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub file: String,
    /// Sample rate (Hz) and where it came from.
    pub sample_rate: f64,
    pub sample_rate_from: &'static str,
    pub channels: usize,
    pub signal_channel: usize,
    /// Sample times analysed, and their duration (s).
    pub samples: u64,
    pub seconds: f64,
    /// Metres per unit of the values read, and how that was set.
    pub metres_per_unit: f64,
    pub scale: String,
    pub reference: ReferenceReport,
    /// The reference of the demodulators on `drive2`, where one was measured
    /// (`--reference2-channel`, `--drive2-frequency`); without it they read
    /// `/drive2/frequency` from phase 0 at the first sample.
    pub reference2: Option<ReferenceReport>,
    /// Demodulator frames and spectra written.
    pub demod_frames: u64,
    pub spectra: u64,
    /// Width of a spectrum bin (Hz), 0 without a spectrum.
    pub bin_width: f64,
    /// None when the inversion is off or the configuration gives none (`why_no_force`).
    pub force: Option<ForceSummary>,
    pub why_no_force: Option<String>,
    /// Lock-in threads.
    pub threads: usize,
    /// Wall time of the analysis (s), the speed against real time, and in MS/s.
    pub elapsed: f64,
    pub realtime_factor: f64,
    pub msps: f64,
    /// The output directory, if any.
    pub out: Option<String>,
}

/// Outputs as the analysis makes them: the frames the DSP plan's sink collects.
struct Collector<'a> {
    frame: DemodFrame,
    fs: f64,
    demods: usize,
    demod_out: Option<NpyWriter>,
    spectrum_out: Option<NpyWriter>,
    /// The inversion's thread: frames to it, estimates back (for the observer only).
    inversion: Option<Inversion>,
    /// Demodulator frames left out of the inversion while the filters settled.
    unsettled: u64,
    settle_from: f64,
    frames: u64,
    spectra: u64,
    bin_width: f64,
    row: Vec<u8>,
    error: Option<std::io::Error>,
    /// Every demodulator frame and estimate, for tests ([`analyse_with`]).
    observer: Option<&'a mut dyn FnMut(Output<'_>)>,
}

/// An output as it is made, for a caller that wants them in memory.
pub enum Output<'a> {
    Demods(&'a DemodFrame),
    Force(&'a ForceEstimate),
}

impl Collector<'_> {
    fn write(&mut self, which: u8) {
        let w = if which == 0 {
            &mut self.demod_out
        } else {
            &mut self.spectrum_out
        };
        if let Some(w) = w
            && let Err(e) = w.row(&self.row)
            && self.error.is_none()
        {
            self.error = Some(e);
        }
    }

    fn flush(&mut self) {
        if self.frame.len == 0 {
            return;
        }
        self.frame.t = self.frame.sample_index as f64 / self.fs;
        self.frames += 1;
        let d = self.demods;
        let mut vals = vec![(f64::NAN, f64::NAN, 0u32); d];
        for v in self.frame.values() {
            if let Some(slot) = vals.get_mut(v.index as usize) {
                *slot = (v.x, v.y, v.harmonic);
            }
        }
        self.row.clear();
        self.row.extend(self.frame.sample_index.to_le_bytes());
        self.row.extend(self.frame.t.to_le_bytes());
        for f in [
            |v: &(f64, f64, u32)| v.0,
            |v: &(f64, f64, u32)| v.1,
            |v: &(f64, f64, u32)| v.0.hypot(v.1),
            |v: &(f64, f64, u32)| v.1.atan2(v.0),
        ] {
            for v in &vals {
                self.row.extend(f(v).to_le_bytes());
            }
        }
        for v in &vals {
            self.row.extend(v.2.to_le_bytes());
        }
        self.write(0);
        if let Some(obs) = &mut self.observer {
            obs(Output::Demods(&self.frame));
        }
        if let Some(inv) = &self.inversion {
            if self.frame.t < self.settle_from {
                self.unsettled += 1;
            } else {
                // Blocks while the inversion's queue is full: memory stays bounded and no
                // frame is dropped.
                let _ = inv.frames.send(self.frame);
            }
        }
        self.observe_estimates();
        self.frame.len = 0;
    }
}

impl Collector<'_> {
    /// Hands the estimates made so far to the observer, if there is one.
    fn observe_estimates(&mut self) {
        if let (Some(obs), Some(inv)) = (&mut self.observer, &self.inversion) {
            while let Ok(est) = inv.estimates.try_recv() {
                obs(Output::Force(&est));
            }
        }
    }
}

/// Frames in flight to the inversion's thread.
const INVERSION_QUEUE: usize = 256;

/// The force inversion on a thread of its own, so that its fits run beside the lock-in.
struct Inversion {
    frames: std::sync::mpsc::SyncSender<DemodFrame>,
    estimates: std::sync::mpsc::Receiver<ForceEstimate>,
    thread: std::thread::JoinHandle<Result<ForceSummary, String>>,
}

impl Inversion {
    fn start(
        mut estimator: ForceEstimator,
        mut out: Option<NpyWriter>,
        mut summary: ForceSummary,
        observe: bool,
    ) -> Result<Self, String> {
        let (frames, rx) = std::sync::mpsc::sync_channel::<DemodFrame>(INVERSION_QUEUE);
        let (tx, estimates) = std::sync::mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("ftafm-inversion".into())
            .spawn(move || {
                let mut row = Vec::new();
                for frame in rx {
                    match estimator.push(&frame) {
                        Some(Ok(est)) => {
                            summary.estimates += 1;
                            summary.max_force.add(est.max_force, est.max_force_sigma);
                            summary
                                .youngs_modulus
                                .add(est.youngs_modulus, est.youngs_modulus_sigma);
                            summary
                                .contact_time_ratio
                                .add(est.contact_time_ratio, est.contact_time_ratio_sigma);
                            if let Some(w) = &mut out {
                                row.clear();
                                row.extend(est.sample_index.to_le_bytes());
                                row.extend(est.t.to_le_bytes());
                                for v in [
                                    est.contact_time_ratio,
                                    est.contact_time_ratio_sigma,
                                    est.max_force,
                                    est.max_force_sigma,
                                    est.youngs_modulus,
                                    est.youngs_modulus_sigma,
                                    est.pulse_phase,
                                ] {
                                    row.extend(v.to_le_bytes());
                                }
                                for v in &est.waveform {
                                    row.extend(v.to_le_bytes());
                                }
                                w.row(&row).map_err(|e| format!("writing force.npy: {e}"))?;
                            }
                            if observe {
                                let _ = tx.send(est);
                            }
                        }
                        Some(Err(err)) => {
                            summary.failed += 1;
                            summary.last_error = Some(err.to_string());
                        }
                        None => {}
                    }
                }
                if let Some(w) = out {
                    w.finish().map_err(|e| format!("writing force.npy: {e}"))?;
                }
                Ok(summary)
            })
            .map_err(|e| format!("the inversion's thread: {e}"))?;
        Ok(Self {
            frames,
            estimates,
            thread,
        })
    }
}

impl DspSink for Collector<'_> {
    fn demod(&mut self, index: u64, value: DemodValue) {
        if self.frame.len > 0 && self.frame.sample_index != index {
            self.flush();
        }
        if self.frame.len == 0 {
            self.frame.sample_index = index;
        }
        if self.frame.len < self.frame.values.len() {
            self.frame.values[self.frame.len] = value;
            self.frame.len += 1;
        }
    }

    fn spectrum<I: ExactSizeIterator<Item = f64>>(&mut self, index: u64, bin_width: f64, bins: I) {
        self.spectra += 1;
        self.bin_width = bin_width;
        self.row.clear();
        self.row.extend(index.to_le_bytes());
        self.row.extend((index as f64 / self.fs).to_le_bytes());
        for m in bins {
            self.row.extend((m as f32).to_le_bytes());
        }
        self.write(1);
    }
}

/// A recording opened for reading, with its sample rate and its scale to metres and where
/// each came from.
pub struct Opened {
    /// The samples, not yet read.
    pub src: Source,
    /// The file's name as given, for messages.
    pub name: String,
    /// Its `record-signal` sidecar, if it has one.
    pub sidecar: Option<Sidecar>,
    /// Sample rate (Hz) and what gave it (`--sample-rate`, the WAV header, the sidecar).
    pub sample_rate: f64,
    pub sample_rate_from: &'static str,
    /// Metres per unit of the file's values (m), and how it was set, in words.
    pub scale: f64,
    pub scale_text: String,
}

/// Opens `opts.file` and settles its sample rate, channels and scale from the file and the
/// options (`ftafm analyse` and `ftafm replay`); an error names the file and the flag to
/// give.
pub fn open(opts: &Options) -> Result<Opened, String> {
    let src = Source::open(&opts.file, opts.format, opts.channels)?;
    let name = src.name.clone();
    let sidecar: Option<Sidecar> = (opts.file.as_os_str() != "-")
        .then(|| std::fs::read(sidecar_path(&opts.file)).ok())
        .flatten()
        .and_then(|b| serde_json::from_slice::<Sidecar>(&b).ok())
        .filter(|s| s.format == "ftafm-signal");
    let (fs, fs_from) = match (opts.sample_rate, src.sample_rate, &sidecar) {
        (Some(f), _, _) => (f, "--sample-rate"),
        (None, Some(f), _) => (f, "the WAV header"),
        (None, None, Some(s)) => (s.sample_rate, "the sidecar (record-signal)"),
        (None, None, None) => {
            return Err(format!(
                "{name}: the file has no sample rate: give --sample-rate HZ"
            ));
        }
    };
    if !(fs.is_finite() && fs > 0.0) {
        return Err(format!("--sample-rate must be finite and > 0 Hz, got {fs}"));
    }
    for (what, ch) in [
        ("--signal-channel", Some(opts.signal_channel)),
        ("--reference-channel", opts.reference_channel),
        ("--reference2-channel", opts.reference2_channel),
    ] {
        if let Some(ch) = ch
            && ch >= src.channels
        {
            return Err(format!(
                "{what} {ch}: {name} has {} channel(s), numbered 0 to {}",
                src.channels,
                src.channels - 1
            ));
        }
    }
    if opts.reference_channel == Some(opts.signal_channel) {
        return Err("--reference-channel must differ from --signal-channel".to_owned());
    }
    if opts.reference2_channel == Some(opts.signal_channel) {
        return Err("--reference2-channel must differ from --signal-channel".to_owned());
    }
    if let Some(f) = opts.drive2_frequency
        && !(f.is_finite() && f > 0.0 && f < fs / 2.0)
    {
        return Err(format!(
            "--drive2-frequency must be finite, > 0 and below half the sample rate ({} Hz), \
             got {f}",
            fs / 2.0
        ));
    }
    let (scale, scale_text) = match (opts.metres, opts.invols, &sidecar) {
        (true, Some(_), _) => {
            return Err(
                "--units m and --invols exclude each other: the file is in metres, or \
                 in volts to be scaled"
                    .to_owned(),
            );
        }
        (true, None, _) => (1.0, "the file's values are metres (--units m)".to_owned()),
        (false, Some(k), _) if k.is_finite() && k > 0.0 => (
            k,
            format!("{} × InvOLS {k:e} m per unit (--invols)", src.units),
        ),
        (false, Some(k), _) => {
            return Err(format!("--invols must be finite and > 0 m/V, got {k}"));
        }
        (false, None, Some(s)) if s.units == "m" => (
            1.0,
            "the file's values are metres (its record-signal sidecar)".to_owned(),
        ),
        _ => {
            return Err(format!(
                "{name}: give --invols M_PER_V (the InvOLS: metres per volt of the file's \
                 values) or --units m (the values are metres already)"
            ));
        }
    };
    Ok(Opened {
        src,
        name,
        sidecar,
        sample_rate: fs,
        sample_rate_from: fs_from,
        scale,
        scale_text,
    })
}

/// Analyses `opts.file` with the lock-in, spectrum and inversion of `settings` (its sample
/// rate and drive frequency replaced by the file's); writes the outputs to `opts.out`.
pub fn analyse(settings: &Settings, opts: &Options) -> Result<Summary, String> {
    analyse_with(settings, opts, None)
}

/// [`analyse`], handing every demodulator frame and force estimate to `observer` too.
pub fn analyse_with(
    settings: &Settings,
    opts: &Options,
    observer: Option<&mut dyn FnMut(Output<'_>)>,
) -> Result<Summary, String> {
    let Opened {
        mut src,
        name,
        sidecar,
        sample_rate: fs,
        sample_rate_from: fs_from,
        scale,
        scale_text,
    } = open(opts)?;
    let use_sidecar =
        sidecar.is_some() && opts.reference_channel.is_none() && opts.drive_frequency.is_none();
    if let Some(f) = opts.drive_frequency
        && !(f.is_finite() && f > 0.0 && f < fs / 2.0)
    {
        return Err(format!(
            "--drive-frequency must be > 0 and below half the sample rate ({} Hz), got {f}",
            fs / 2.0
        ));
    }
    // The first stretch is read before anything runs: the reference is measured from it.
    let chans = src.channels;
    let mut first = Vec::new();
    let mut piece = Vec::with_capacity(PIECE * chans);
    while first.len() < reference::MAX_FIT_SAMPLES * chans {
        let n = src.read(
            &mut piece,
            PIECE.min(reference::MAX_FIT_SAMPLES - first.len() / chans),
        )?;
        if n == 0 {
            break;
        }
        first.extend_from_slice(&piece);
    }
    let column = |data: &[f64], ch: usize| -> Vec<f64> {
        data.iter().skip(ch).step_by(chans).copied().collect()
    };
    // Checked before the reference is measured from them (a NaN would make it NaN).
    for ch in [
        Some(opts.signal_channel),
        opts.reference_channel,
        opts.reference2_channel,
    ]
    .into_iter()
    .flatten()
    {
        if let Some(bad) = first
            .iter()
            .skip(ch)
            .step_by(chans)
            .position(|v| !v.is_finite())
        {
            return Err(format!(
                "{name}: sample {bad} of channel {ch} is {}: the analysis takes finite values",
                first[bad * chans + ch]
            ));
        }
    }
    let reference = if use_sidecar {
        let s = sidecar.as_ref().expect("checked");
        ReferenceReport {
            source: "sidecar".to_owned(),
            frequency: s.drive_frequency,
            phase: phase_to_radians(s.phase_word),
            fit: None,
        }
    } else if let Some(ch) = opts.reference_channel {
        let fit = reference::fit(&column(&first, ch), fs, opts.drive_frequency)
            .map_err(|e| format!("{name}: reference channel {ch}: {e}"))?;
        ReferenceReport::fitted(format!("channel {ch}"), fit)
    } else if let Some(f) = opts.drive_frequency {
        let fit = reference::fit(&column(&first, opts.signal_channel), fs, Some(f))
            .map_err(|e| format!("{name}: the signal's fundamental near {f} Hz: {e}"))?;
        ReferenceReport::fitted("signal".to_owned(), fit)
    } else {
        return Err(format!(
            "{name}: give the reference: --reference-channel N (a channel holding the \
             excitation) or --drive-frequency HZ (refined from the signal)"
        ));
    };
    let (word, phase0) = match (&sidecar, use_sidecar) {
        (Some(s), true) => (s.frequency_word, s.phase_word),
        _ => (
            frequency_word(reference.frequency, fs).map_err(|e| e.to_string())?,
            reference::phase_word(reference.phase),
        ),
    };
    // The second excitation's, as the first's: from its channel (near --drive2-frequency,
    // else near /drive2/frequency), or the signal's tone near --drive2-frequency.
    let reference2 = if let Some(ch) = opts.reference2_channel {
        let near = opts.drive2_frequency.unwrap_or(settings.drive2.frequency);
        let fit = reference::fit(&column(&first, ch), fs, Some(near))
            .map_err(|e| format!("{name}: reference2 channel {ch}: {e}"))?;
        Some(ReferenceReport::fitted(format!("channel {ch}"), fit))
    } else if let Some(f) = opts.drive2_frequency {
        let fit = reference::fit(&column(&first, opts.signal_channel), fs, Some(f))
            .map_err(|e| format!("{name}: the signal's tone near {f} Hz: {e}"))?;
        Some(ReferenceReport::fitted("signal".to_owned(), fit))
    } else {
        None
    };
    let mut settings = settings.clone();
    settings.synth.sample_rate = fs;
    settings.drive.frequency = reference.frequency;
    settings.drive.follow_f1 = false;
    settings.scope.enable = false;
    // Without a measured reference, demodulators on /drive2 read /drive2/frequency from
    // phase 0 at the recording's first sample.
    let (word2, phase2) = match &reference2 {
        Some(r) => {
            settings.drive2.frequency = r.frequency;
            (
                frequency_word(r.frequency, fs).map_err(|e| e.to_string())?,
                reference::phase_word(r.phase),
            )
        }
        None => (
            frequency_word(settings.drive2.frequency, fs).map_err(|e| e.to_string())?,
            0,
        ),
    };
    let mut plan = DspPlan::new(&settings).map_err(|e| format!("the lock-in bank: {e}"))?;
    let threads = dsp_threads(&settings).min(plan.shards());
    let mut team =
        DspTeam::spawn(plan.shards() - 1, false).map_err(|e| format!("DSP threads: {e}"))?;
    let (estimator, why_no_force) = if settings.inversion.enable {
        match ForceEstimator::new(&settings) {
            Ok(Some(e)) => (Some(e), None),
            Ok(None) => (
                None,
                Some(
                    "the configuration gives no force estimates (too few demodulators in band)"
                        .to_owned(),
                ),
            ),
            Err(e) => (None, Some(e)),
        }
    } else {
        (None, Some("/inversion/enable is false".to_owned()))
    };
    let demods = settings.demods.len();
    let bins = plan.spectrum_bins();
    let points = settings.inversion.points as usize;
    let mut writers = (None, None, None);
    if let Some(dir) = &opts.out {
        std::fs::create_dir_all(dir).map_err(|e| format!("--out {}: {e}", dir.display()))?;
        let io = |e: std::io::Error| format!("--out {}: {e}", dir.display());
        let d = demods;
        writers.0 = Some(
            NpyWriter::create(
                &dir.join("demods.npy"),
                &format!(
                    "[('sample_index', '<u8'), ('t', '<f8'), ('x', '<f8', ({d},)), ('y', '<f8', \
                     ({d},)), ('r', '<f8', ({d},)), ('phase', '<f8', ({d},)), ('harmonic', \
                     '<u4', ({d},))]"
                ),
                "",
            )
            .map_err(io)?,
        );
        if bins > 0 {
            writers.1 = Some(
                NpyWriter::create(
                    &dir.join("spectrum.npy"),
                    &format!(
                        "[('sample_index', '<u8'), ('t', '<f8'), ('magnitudes', '<f4', \
                         ({bins},))]"
                    ),
                    "",
                )
                .map_err(io)?,
            );
        }
        if estimator.is_some() {
            writers.2 = Some(
                NpyWriter::create(
                    &dir.join("force.npy"),
                    &format!(
                        "[('sample_index', '<u8'), ('t', '<f8'), ('contact_time_ratio', '<f8'), \
                         ('contact_time_ratio_sigma', '<f8'), ('max_force', '<f8'), \
                         ('max_force_sigma', '<f8'), ('youngs_modulus', '<f8'), \
                         ('youngs_modulus_sigma', '<f8'), ('pulse_phase', '<f8'), \
                         ('waveform', '<f8', ({points},))]"
                    ),
                    "",
                )
                .map_err(io)?,
            );
        }
    }
    let settle_from = crate::instrument::sweeper::automatic_settling(&settings);
    let inversion = match estimator {
        Some(e) => {
            let summary = ForceSummary {
                settle_from,
                warnings: e.warnings().to_vec(),
                ..ForceSummary::default()
            };
            Some(Inversion::start(e, writers.2, summary, observer.is_some())?)
        }
        None => None,
    };
    let mut sink = Collector {
        frame: DemodFrame::empty(),
        fs,
        demods,
        demod_out: writers.0,
        spectrum_out: writers.1,
        inversion,
        unsettled: 0,
        settle_from,
        frames: 0,
        spectra: 0,
        bin_width: 0.0,
        row: Vec::new(),
        error: None,
        observer,
    };
    let bar = opts.progress.then(|| {
        let bar = indicatif::ProgressBar::new(src.frames.unwrap_or(0));
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {percent:>3}% {human_pos}/{human_len} samples, {per_sec}, ETA {eta}",
            )
            .expect("a valid template"),
        );
        bar
    });
    let start = Instant::now();
    let mut index: u64 = 0;
    let mut signal = Vec::with_capacity(PIECE);
    let mut run = |data: &[f64], index: &mut u64| -> Result<(), String> {
        for block in data.chunks(PIECE * chans) {
            signal.clear();
            signal.extend(
                block
                    .iter()
                    .skip(opts.signal_channel)
                    .step_by(chans)
                    .map(|v| v * scale),
            );
            if let Some(bad) = signal.iter().position(|v| !v.is_finite()) {
                return Err(format!(
                    "{name}: sample {} of channel {} is {}: the analysis takes finite values",
                    *index + bad as u64,
                    opts.signal_channel,
                    block[bad * chans + opts.signal_channel]
                ));
            }
            let phase = phase0.wrapping_add(word.wrapping_mul(*index));
            plan.align_drive2(phase2.wrapping_add(word2.wrapping_mul(*index)), word2);
            plan.process_block(&mut team, phase, word, &signal, &mut sink);
            *index += signal.len() as u64;
            if let Some(bar) = &bar {
                bar.set_position(*index);
            }
        }
        Ok(())
    };
    run(&first, &mut index)?;
    drop(first);
    loop {
        let n = src.read(&mut piece, PIECE)?;
        if n == 0 {
            break;
        }
        run(&piece, &mut index)?;
    }
    sink.flush();
    // The inversion's queue closed: its thread finishes the frames it holds.
    let force = match sink.inversion.take() {
        Some(inv) => {
            let Inversion {
                frames,
                estimates,
                thread,
            } = inv;
            drop(frames);
            let mut summary = thread
                .join()
                .map_err(|_| "the inversion's thread panicked".to_owned())??;
            summary.unsettled_frames = sink.unsettled;
            if let Some(obs) = &mut sink.observer {
                for est in estimates.try_iter() {
                    obs(Output::Force(&est));
                }
            }
            Some(summary)
        }
        None => None,
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    let elapsed = start.elapsed().as_secs_f64();
    if let Some(e) = sink.error.take() {
        return Err(format!("writing the outputs: {e}"));
    }
    for w in [sink.demod_out.take(), sink.spectrum_out.take()]
        .into_iter()
        .flatten()
    {
        w.finish()
            .map_err(|e| format!("writing the outputs: {e}"))?;
    }
    let seconds = index as f64 / fs;
    let summary = Summary {
        file: name,
        sample_rate: fs,
        sample_rate_from: fs_from,
        channels: chans,
        signal_channel: opts.signal_channel,
        samples: index,
        seconds,
        metres_per_unit: scale,
        scale: scale_text,
        reference,
        reference2,
        demod_frames: sink.frames,
        spectra: sink.spectra,
        bin_width: sink.bin_width,
        force,
        why_no_force,
        threads,
        elapsed,
        realtime_factor: seconds / elapsed,
        msps: index as f64 / elapsed / 1e6,
        out: opts.out.as_ref().map(|p| p.display().to_string()),
    };
    if let Some(dir) = &opts.out {
        let json = serde_json::to_string_pretty(&summary).expect("plain data");
        std::fs::write(dir.join("summary.json"), json)
            .map_err(|e| format!("--out {}: {e}", dir.display()))?;
    }
    Ok(summary)
}
