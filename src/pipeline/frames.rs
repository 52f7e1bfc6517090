//! What the DSP thread hands out: demodulator frames (one output time point of the bank)
//! and spectrum frames (in buffers from a fixed pool, so nothing is allocated per frame).

use serde::Serialize;

use crate::dsp::MAX_DEMODULATORS;

/// One demodulator's output at one time point.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DemodValue {
    /// Demodulator index N of `/demods/N`.
    pub index: u8,
    /// Its harmonic k (of `oscillator`).
    pub harmonic: u32,
    /// The oscillator whose harmonic k it reads (`/demods/N/oscillator`). Internal: the
    /// stream formats leave it out, a client knows it from the node. Only values on
    /// [`Oscillator::Drive`](crate::config::Oscillator::Drive) are harmonics of the tapping.
    #[serde(skip)]
    pub oscillator: crate::config::Oscillator,
    /// In-phase part X (m, nominal photodiode deflection).
    pub x: f64,
    /// Quadrature part Y (m).
    pub y: f64,
}

impl DemodValue {
    /// Peak amplitude R = |X + iY| (m).
    pub fn r(&self) -> f64 {
        self.x.hypot(self.y)
    }

    /// Phase (rad) against k times its oscillator's phase (cosine reference).
    pub fn phase(&self) -> f64 {
        self.y.atan2(self.x)
    }

    /// Whether it reads a harmonic of the drive (the tapping), not of `/drive2`.
    pub fn on_drive(&self) -> bool {
        self.oscillator == crate::config::Oscillator::Drive
    }
}

/// All demodulator outputs at one output time point.
#[derive(Clone, Copy, Debug)]
pub struct DemodFrame {
    /// Index of the newest input sample reflected.
    pub sample_index: u64,
    /// Simulated time of that sample (s).
    pub t: f64,
    /// Unix time (ns) at which that sample was synthesised.
    pub t_synth_ns: u64,
    /// Unix time (ns) at which the DSP finished this frame.
    pub t_dsp_ns: u64,
    /// Number of valid entries in `values`.
    pub len: usize,
    /// The outputs, in demodulator order.
    pub values: [DemodValue; MAX_DEMODULATORS],
    /// The PID units' running sums after the block this frame was made in (a block's
    /// granularity: 4096 samples).
    pub pids: [crate::synth::PidSums; crate::config::PID_COUNT],
}

impl DemodFrame {
    /// The valid outputs.
    pub fn values(&self) -> &[DemodValue] {
        &self.values[..self.len]
    }

    /// A frame with no values yet, at sample 0: what a caller fills demodulator by
    /// demodulator.
    pub fn empty() -> Self {
        Self {
            sample_index: 0,
            t: 0.0,
            t_synth_ns: 0,
            t_dsp_ns: 0,
            len: 0,
            values: [DemodValue::default(); MAX_DEMODULATORS],
            pids: Default::default(),
        }
    }
}

/// One spectrum: peak amplitudes (m) of bins 0…N/2. The buffer comes from a fixed pool;
/// give it back with [`PipelineOutput::recycle`](super::PipelineOutput::recycle).
#[derive(Clone, Debug)]
pub struct SpectrumBuffer {
    /// Index of the newest input sample in the frame.
    pub sample_index: u64,
    /// Simulated time of that sample (s).
    pub t: f64,
    /// Unix time (ns) at which that sample was synthesised.
    pub t_synth_ns: u64,
    /// Unix time (ns) at which the DSP finished this frame.
    pub t_dsp_ns: u64,
    /// Bin spacing (Hz).
    pub bin_width: f64,
    /// |bin| for bins 0…N/2 (m, peak amplitude calibration).
    pub magnitudes: Vec<f32>,
}

/// A stretch of consecutive photodiode samples for a time-domain trace (the scope),
/// optionally decimated. The buffer comes from a fixed pool like [`SpectrumBuffer`].
#[derive(Clone, Debug)]
pub struct ScopeBuffer {
    /// Stream index of the newest sample in the trace.
    pub sample_index: u64,
    /// Simulated time of that sample (s).
    pub t: f64,
    /// Unix time (ns) at which that sample was synthesised.
    pub t_synth_ns: u64,
    /// Unix time (ns) at which the DSP finished this frame.
    pub t_dsp_ns: u64,
    /// Time between trace samples (s): decimation / sample rate.
    pub dt: f64,
    /// Drive phase θ (rad, cosine reference) at the first trace sample.
    pub start_phase: f64,
    /// Drive phase advance per trace sample (rad).
    pub phase_step: f64,
    /// The samples (m, nominal photodiode deflection), oldest first.
    pub samples: Vec<f32>,
}

impl ScopeBuffer {
    /// An empty buffer that holds `samples` samples without reallocating.
    pub fn with_capacity(samples: usize) -> Self {
        Self {
            sample_index: 0,
            t: 0.0,
            t_synth_ns: 0,
            t_dsp_ns: 0,
            dt: 0.0,
            start_phase: 0.0,
            phase_step: 0.0,
            samples: Vec::with_capacity(samples),
        }
    }
}

/// The harmonics of one pixel of a scan: every enabled demodulator's phasor averaged over
/// exactly the pixel's samples (a boxcar, so the image has no filter lag and sharp edges).
#[derive(Clone, Copy, Debug)]
pub struct PixelHarmonics {
    /// The raster the pixel belongs to (its generation and geometry: a consumer places the
    /// pixel by it, not by settings that may have moved on or not yet arrived).
    pub raster: crate::synth::Raster,
    /// The pixel.
    pub pixel: crate::synth::PixelId,
    /// Pre-decimated samples averaged.
    pub samples: u32,
    /// The mean phasors as demodulator values (`sample_index`, `t` and `t_synth_ns` of the
    /// pixel's last sample).
    pub frame: DemodFrame,
}
