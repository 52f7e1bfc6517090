//! `ftafm record-signal`: the synthesiser's finished samples (through the ADC, as the
//! pipeline's DSP thread receives them) written to a `.npy` file in metres, with a sidecar
//! holding the drive's phase words, so that `ftafm analyse` can lock exactly as the live
//! lock-in does.

use std::path::Path;

use super::npy::NpyWriter;
use super::run::{Sidecar, sidecar_path};
use crate::config::Settings;
use crate::pipeline::BLOCK_SAMPLES;
use crate::synth::{SynthPlan, SynthState};
use crate::timebase::phase_to_radians;

/// What was written.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Recorded {
    /// Samples per channel.
    pub samples: u64,
    /// Channels: the signal, and the drive's cosine with `drive_channel`.
    pub channels: usize,
    pub sample_rate: f64,
    pub drive_frequency: f64,
    /// The file and its sidecar.
    pub file: String,
    pub sidecar: String,
}

/// Synthesises `samples` samples of `settings` into `path` (float64 metres; a second column
/// cos(drive phase) with `drive_channel`) and its sidecar.
pub fn record_signal(
    settings: &Settings,
    samples: u64,
    path: &Path,
    drive_channel: bool,
) -> Result<Recorded, String> {
    let plan = SynthPlan::new(settings).map_err(|e| e.to_string())?;
    let mut state = SynthState::steady(&plan, settings.synth.seed);
    let word = plan.frequency_word;
    let phase0 = plan.output_phase(state.phase());
    let io = |e: std::io::Error| format!("{}: {e}", path.display());
    let channels = 1 + usize::from(drive_channel);
    let tail = if drive_channel { "2" } else { "" };
    let mut out = NpyWriter::create(path, "'<f8'", tail).map_err(io)?;
    let mut block = vec![0.0; BLOCK_SAMPLES];
    let mut row = Vec::with_capacity(16);
    let mut index = 0u64;
    while index < samples {
        let len = (samples - index).min(BLOCK_SAMPLES as u64) as usize;
        let phase = plan.output_phase(state.phase());
        // The analysis assumes the free-running phase of one word per sample.
        let expect = phase0.wrapping_add(word.wrapping_mul(index));
        if phase != expect {
            return Err(format!(
                "the drive's phase at sample {index} is not the free-running one (a drive \
                 that changes is not recordable with a fixed reference)"
            ));
        }
        plan.process(&mut state, &mut block[..len]);
        for (j, v) in block[..len].iter().enumerate() {
            row.clear();
            row.extend(v.to_le_bytes());
            if drive_channel {
                let p = phase.wrapping_add(word.wrapping_mul(j as u64));
                row.extend(phase_to_radians(p).cos().to_le_bytes());
            }
            out.row(&row).map_err(io)?;
        }
        index += len as u64;
    }
    out.finish().map_err(io)?;
    let sidecar = Sidecar {
        format: "ftafm-signal".to_owned(),
        sample_rate: settings.synth.sample_rate,
        drive_frequency: settings.drive.frequency,
        frequency_word: word,
        phase_word: phase0,
        units: "m".to_owned(),
    };
    let side = sidecar_path(path);
    std::fs::write(
        &side,
        serde_json::to_string_pretty(&sidecar).expect("plain data"),
    )
    .map_err(|e| format!("{}: {e}", side.display()))?;
    Ok(Recorded {
        samples,
        channels,
        sample_rate: settings.synth.sample_rate,
        drive_frequency: settings.drive.frequency,
        file: path.display().to_string(),
        sidecar: side.display().to_string(),
    })
}
