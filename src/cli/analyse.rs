//! `ftafm analyse FILE` (the chain on a recorded signal) and `ftafm record-signal` (the
//! synthesiser's signal to a file).

use std::path::PathBuf;
use std::process::ExitCode;

use super::{ConfigArg, EXIT_USAGE, load, print_report};
use crate::analyse::{self, Format, Options, Summary};

/// The flags that name a recording and how to read it, shared by `analyse` and `replay`.
#[derive(clap::Args)]
pub struct RecordingArgs {
    /// The recording: .npy (int16/int32/float32/float64, 1-D or samples × channels), .wav
    /// (PCM 16/24/32-bit, float 32-bit) or raw little-endian; `-` reads raw from stdin.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// The format; auto takes it from the extension.
    #[arg(long, value_enum, default_value_t = Format::Auto)]
    pub format: Format,
    /// Sample rate (Hz): needed for .npy and raw; overrides a WAV header's.
    #[arg(long, value_name = "HZ")]
    pub sample_rate: Option<f64>,
    /// Channels interleaved in raw input (1 ≤ N ≤ 64).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub channels: usize,
    /// The channel holding the photodiode signal (0 = first).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub signal_channel: usize,
    /// InvOLS (m/V): metres per unit of the file's values (a WAV's integers are ±1 at full
    /// scale).
    #[arg(long, value_name = "M_PER_V")]
    pub invols: Option<f64>,
    /// The units of the file's values: `m` (metres already; no --invols).
    #[arg(long, value_name = "UNITS")]
    pub units: Option<String>,
}

impl RecordingArgs {
    /// The analysis options these flags give (no reference, no outputs), or the flag that
    /// is wrong, in words.
    pub fn options(&self) -> Result<Options, String> {
        let metres = match self.units.as_deref() {
            None => false,
            Some("m") => true,
            Some(u) => return Err(format!("--units {u:?}: the allowed value is \"m\"")),
        };
        if !(1..=64).contains(&self.channels) {
            return Err(format!("--channels must be 1 to 64, got {}", self.channels));
        }
        Ok(Options {
            file: self.file.clone(),
            format: self.format,
            channels: self.channels,
            signal_channel: self.signal_channel,
            sample_rate: self.sample_rate,
            reference_channel: None,
            drive_frequency: None,
            reference2_channel: None,
            drive2_frequency: None,
            invols: self.invols,
            metres,
            out: None,
            progress: false,
        })
    }
}

/// `ftafm analyse`'s flags.
#[derive(clap::Args)]
pub struct AnalyseArgs {
    #[command(flatten)]
    pub config: ConfigArg,
    #[command(flatten)]
    pub recording: RecordingArgs,
    /// The channel holding the excitation: its phase is the lock-in's reference.
    #[arg(long, value_name = "N")]
    pub reference_channel: Option<usize>,
    /// The drive frequency (Hz), refined from the signal's fundamental (or, with
    /// --reference-channel, where to look for the excitation).
    #[arg(long, value_name = "HZ")]
    pub drive_frequency: Option<f64>,
    /// The channel holding the second excitation: its phase is the reference of the
    /// demodulators on drive2 (it may be --reference-channel's, both excitations summed).
    #[arg(long, value_name = "N")]
    pub reference2_channel: Option<usize>,
    /// The second excitation's frequency (Hz), refined from the signal's tone near it (or,
    /// with --reference2-channel, where to look for the excitation).
    #[arg(long, value_name = "HZ")]
    pub drive2_frequency: Option<f64>,
    /// Directory for demods.npy, spectrum.npy, force.npy and summary.json (created).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Print exactly one JSON object on stdout (progress still goes to stderr).
    #[arg(long)]
    pub json: bool,
}

/// Runs `ftafm analyse`.
pub fn command(args: AnalyseArgs) -> Result<ExitCode, ExitCode> {
    let usage = |e: String| {
        eprintln!("ftafm analyse: {e}");
        ExitCode::from(EXIT_USAGE)
    };
    let settings = load(&args.config)?;
    let opts = Options {
        reference_channel: args.reference_channel,
        drive_frequency: args.drive_frequency,
        reference2_channel: args.reference2_channel,
        drive2_frequency: args.drive2_frequency,
        out: args.out,
        progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
        ..args.recording.options().map_err(usage)?
    };
    let summary = analyse::analyse(&settings, &opts).map_err(|e| {
        eprintln!("ftafm analyse: {e}");
        ExitCode::FAILURE
    })?;
    print_report(args.json, &summary, text);
    Ok(ExitCode::SUCCESS)
}

fn text(s: &Summary) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{}: {} samples ({:.4} s) at {} Hz (from {}), channel {} of {}",
        s.file,
        s.samples,
        s.seconds,
        s.sample_rate,
        s.sample_rate_from,
        s.signal_channel,
        s.channels
    );
    let _ = writeln!(t, "scale: {}", s.scale);
    for (name, r) in [
        ("reference", Some(&s.reference)),
        ("reference2", s.reference2.as_ref()),
    ] {
        let Some(r) = r else { continue };
        let _ = write!(
            t,
            "{name}: {} at {:.6} Hz, phase {:.6} rad at sample 0",
            r.source, r.frequency, r.phase
        );
        if let Some(f) = &r.fit {
            let _ = write!(
                t,
                " (fit on {} samples, amplitude {:.4e}, phase residual {:.2e} rad)",
                f.samples, f.amplitude, f.phase_residual
            );
        }
        let _ = writeln!(t);
    }
    let _ = writeln!(
        t,
        "lock-in: {} demodulator frames, {} spectra on {} thread(s)",
        s.demod_frames, s.spectra, s.threads
    );
    match (&s.force, &s.why_no_force) {
        (Some(f), _) => {
            let _ = writeln!(
                t,
                "force: {} estimates ({} failed, {} frames before {:.4} s left out while \
                 the filters settled)",
                f.estimates, f.failed, f.unsettled_frames, f.settle_from
            );
            if f.estimates > 0 {
                let _ = writeln!(
                    t,
                    "  peak force {:.4e} N (±{:.2e} stated, {:.2e} spread), E {:.4e} Pa \
                     (±{:.2e}, {:.2e}), contact time ratio {:.4} (±{:.2e}, {:.2e})",
                    f.max_force.mean,
                    f.max_force.sigma,
                    f.max_force.std,
                    f.youngs_modulus.mean,
                    f.youngs_modulus.sigma,
                    f.youngs_modulus.std,
                    f.contact_time_ratio.mean,
                    f.contact_time_ratio.sigma,
                    f.contact_time_ratio.std
                );
            }
            if let Some(e) = &f.last_error {
                let _ = writeln!(t, "  last failure: {e}");
            }
            for w in &f.warnings {
                let _ = writeln!(t, "  warning: {w}");
            }
        }
        (None, Some(why)) => {
            let _ = writeln!(t, "force: none ({why})");
        }
        (None, None) => {}
    }
    let _ = writeln!(
        t,
        "speed: {:.3} s, {:.1}× real time, {:.2} MS/s",
        s.elapsed, s.realtime_factor, s.msps
    );
    if let Some(out) = &s.out {
        let _ = writeln!(
            t,
            "outputs: {out}/demods.npy, spectrum.npy, force.npy, summary.json"
        );
    }
    t
}

/// `ftafm record-signal`'s flags.
#[derive(clap::Args)]
pub struct RecordSignalArgs {
    #[command(flatten)]
    pub config: ConfigArg,
    /// Seconds of signal (0 < S ≤ 3600).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub seconds: f64,
    /// The .npy file to write (float64 metres); its sidecar F.json holds the drive's phase.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Add a second column: the drive's cosine, an excitation channel.
    #[arg(long)]
    pub drive_channel: bool,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Runs `ftafm record-signal`.
pub fn record_signal(args: RecordSignalArgs) -> Result<ExitCode, ExitCode> {
    if !(args.seconds > 0.0 && args.seconds <= 3600.0) {
        eprintln!(
            "ftafm record-signal: --seconds must be > 0 and ≤ 3600, got {}",
            args.seconds
        );
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let settings = load(&args.config)?;
    let samples = (args.seconds * settings.synth.sample_rate).round().max(1.0) as u64;
    let rec = analyse::record::record_signal(&settings, samples, &args.out, args.drive_channel)
        .map_err(|e| {
            eprintln!("ftafm record-signal: {e}");
            ExitCode::FAILURE
        })?;
    print_report(args.json, &rec, |r| {
        format!(
            "{}: {} samples × {} channel(s) at {} Hz, drive {} Hz; reference in {}\n",
            r.file, r.samples, r.channels, r.sample_rate, r.drive_frequency, r.sidecar
        )
    });
    Ok(ExitCode::SUCCESS)
}
