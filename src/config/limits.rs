//! The limits of the settings: the most modes, harmonics, clients …, and the static range of
//! each kind of quantity. Limits that depend on another node (the Nyquist frequency, one
//! sample period) are in `relations`.

use super::range::Range;

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
/// Error budget of the coupled engine's sub-steps, ω_c·dt in rad (`/synth/substep_budget`):
/// 0 (off) to 1, where the harmonics' error would be tens of per cent.
pub(crate) const SUBSTEP_BUDGET: Range = Range::closed(0.0, 1.0);
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
pub(crate) const FREQUENCY: Range = Range::above_up_to(0.0, 1e8);
/// Spring constant in N/m.
pub(crate) const STIFFNESS: Range = Range::above_up_to(0.0, 1e5);
/// Quality factors: above 0.5 so every mode is underdamped (γ = 1/(2Q) < 1).
pub(crate) const QUALITY: Range = Range::above_up_to(0.5, 1e7);
/// Tip radius in m: up to 10 µm (colloidal probes).
pub(crate) const TIP_RADIUS: Range = Range::above_up_to(0.0, 1e-5);
/// Young's modulus in Pa: up to 10 TPa (above diamond's 1.2 TPa).
pub(crate) const MODULUS: Range = Range::above_up_to(0.0, MAX_YOUNGS_MODULUS);
/// Poisson ratio: the thermodynamic limits of an isotropic solid, both excluded (ν = 0.5
/// is incompressible, ν = −1 makes the shear modulus infinite).
pub(crate) const POISSON: Range = Range::between(-1.0, 0.5);
/// An inclusion's modulus relative to the base material's: 0 (absolute), up to 10⁴.
pub(crate) const RELATIVE_MODULUS: Range = Range::closed(0.0, 1e4);
/// Amplitudes and distances in m: up to 1 µm.
pub(crate) const LENGTH: Range = Range::above_up_to(0.0, 1e-6);
/// Hamaker constant in J: up to 1e-17 J, beyond any pair of solids (metals reach ~4e-19 J).
pub(crate) const HAMAKER: Range = Range::above_up_to(0.0, 1e-17);
/// Intermolecular distance a0 of the adhesion in m: 0.01 nm to 1 nm.
pub(crate) const INTERMOLECULAR_DISTANCE: Range = Range::closed(1e-11, 1e-9);
/// Photodiode sample rate in Hz.
pub(crate) const SAMPLE_RATE: Range = Range::closed(1e3, 1e9);
/// Filter time constant in s.
pub(crate) const TIME_CONSTANT: Range = Range::above_up_to(0.0, 100.0);
/// Demodulator output rate in Hz: never above the highest sample rate (and, in
/// `relations`, never above the configured one); at least one output per 1000 s.
pub(crate) const OUTPUT_RATE: Range = Range::closed(MIN_RATE, SAMPLE_RATE.max.value);
/// Temperature of the thermal noise in K; 0 turns it off.
pub(crate) const TEMPERATURE: Range = Range::closed(0.0, 1e4);
/// Detector noise density in m/√Hz: up to 1 nm/√Hz; 0 turns it off.
pub(crate) const DETECTOR_DENSITY: Range = Range::closed(0.0, 1e-9);
/// ADC full scale in m: ±1 pm to ±10 µm. Below 1 pm the step of a 32-bit ADC would
/// underflow (its reciprocal overflow), and no deflection sensor reads less.
pub(crate) const ADC_RANGE: Range = Range::closed(1e-12, 1e-5);
/// Spectra per second in Hz (and, in `relations`, never above the sample rate).
pub(crate) const SPECTRUM_RATE: Range = Range::closed(MIN_RATE, 1e3);
/// Scope traces per second in Hz (and, in `relations`, traces must not overlap).
pub(crate) const SCOPE_RATE: Range = Range::closed(MIN_RATE, 100.0);
/// Seconds a client's socket may accept nothing before it is disconnected.
pub(crate) const STALL_TIMEOUT: Range = Range::closed(1.0, 600.0);
/// Side of the square scan area in m: up to 100 µm (a typical piezo scanner's range).
pub(crate) const SCAN_SIZE: Range = Range::above_up_to(0.0, 100e-6);
/// Scan lines per second in Hz (and, in `relations`, at least ten drive periods per pixel
/// and at most 20000 pixels per second).
pub(crate) const LINE_RATE: Range = Range::closed(MIN_RATE, 100.0);
/// Positions in sample coordinates in m (scan centre, inclusion centre): within ±1 mm.
pub(crate) const POSITION: Range = Range::closed(-1e-3, 1e-3);
/// Amplitude setpoint of the feedback in m: up to 1 µm; 0 means the amplitude at the
/// surface distance over the base material.
pub(crate) const SETPOINT: Range = Range::closed(0.0, 1e-6);
/// Proportional gain of the feedback (1).
pub(crate) const PROPORTIONAL_GAIN: Range = Range::closed(0.0, 10.0);
/// Integral gain of the feedback in 1/s.
pub(crate) const INTEGRAL_GAIN: Range = Range::closed(0.0, 1e6);
/// Width and length of an inclusion in m: up to 1 mm.
pub(crate) const EXTENT: Range = Range::above_up_to(0.0, 1e-3);
/// Height of an inclusion above the base material in m: ±1 µm (negative is a pit).
pub(crate) const HEIGHT: Range = Range::closed(-1e-6, 1e-6);
/// Start and stop of a sweep: any finite value here; the swept node's own range applies
/// when the sweep starts.
pub(crate) const SWEEP_VALUE: Range = Range::closed(-1e13, 1e13);
/// Settling time of a sweep point (s).
pub(crate) const SWEEP_SETTLING: Range = Range::closed(0.0, 100.0);
/// Most points per leg of a sweep.
pub const MAX_SWEEP_POINTS: u32 = 10_000;
/// Most demodulator frames averaged per sweep point.
pub const MAX_SWEEP_AVERAGING: u32 = 100_000;
/// A PID's set-point, in its input's unit (m for r, x, y; rad for the phase): ±10, which
/// holds every phase and any photodiode reading.
pub(crate) const PID_SETPOINT: Range = Range::closed(-10.0, 10.0);
/// A PID's proportional gain (output unit per input unit); negative for a reverse-acting
/// loop. The bound only keeps the arithmetic finite: the loop's stability is the user's.
pub(crate) const PID_P: Range = Range::closed(-1e9, 1e9);
/// A PID's integral gain (output unit per input unit per s).
pub(crate) const PID_I: Range = Range::closed(-1e12, 1e12);
/// A PID's derivative gain (output unit·s per input unit).
pub(crate) const PID_D: Range = Range::closed(-1e6, 1e6);
/// A PID derivative low-pass's bandwidth in Hz; below half the drive frequency (the PID's
/// Nyquist frequency) while the unit is enabled.
pub(crate) const PID_D_BANDWIDTH: Range = Range::above_up_to(0.0, 1e8);
/// A PID demodulator's low-pass bandwidth in Hz (`/pids/N/input_bandwidth`); the drive
/// frequency narrows it while the unit reads drive2.
pub(crate) const PID_INPUT_BANDWIDTH: Range = Range::above_up_to(0.0, 1e8);
/// A PID's output limits, in its output's unit; the output's own range narrows them
/// (`/pids/N/output`: the surface distance's −1 µm … 1 µm).
pub(crate) const PID_OUTPUT: Range = Range::closed(-1e9, 1e9);
/// A PID's output rate limit, in its output's unit per s; 0: none.
pub(crate) const PID_RATE: Range = Range::closed(0.0, 1e12);
/// Highest surface distance a PID may drive to (m): `/surface/distance`'s own maximum.
pub const MAX_PID_DISTANCE: f64 = 1e-6;
/// Lowest surface distance a PID may drive to (m): the surface up to 1 µm above the tip's
/// rest position, pressing the lever up, as contact mode's deflection loop holds it.
pub const MIN_PID_DISTANCE: f64 = -1e-6;
