//! Multi-harmonic lock-in: a bank of demodulators at harmonics of a drive's oscillators.
//!
//! Signal path of demodulator i at harmonic k (all demodulators share steps 1–2):
//!
//! 1. Mixing with `2·e^{−ikθ[m]}` (θ the drive phase of sample m from the integer
//!    [`PhaseAccumulator`]) and the CIC [`Predecimator`] (D = 16, N = 4), fused: the CIC
//!    output at a window centre m_c is
//!    `2·e^{−ikθ[m_c]} Σ_u h_u [cos(kωu)·(s[m_c−u] + s[m_c+u]) + i·sin(kωu)·(s[m_c−u] − s[m_c+u])]`,
//!    ω the phase step per sample. Mixing thus costs nothing at the input rate; the
//!    symmetric taps halve the multiply–adds (one real coefficient per tap, re or im), and
//!    the sums and differences are shared by every demodulator. Tables of `h_u cos(kωu)`
//!    and `h_u sin(kωu)` come from the exact integer phase `u·k·word`.
//! 2. `e^{−ikθ[m_c]}` per demodulator: a phasor rotated by `e^{−ikωD}` per decimated
//!    sample, recomputed exactly from the integer phase every 256 decimated samples, so its
//!    rounding error stays below 10⁻¹³ and cannot accumulate.
//! 3. Droop compensator `[−a, 1+2a, −a]` at f_s/D (see [`Predecimator`]).
//! 4. The demodulator's [`LowPass`] at f_s/D, then decimation to its output rate.
//!
//! Each demodulator reads harmonic k of one of two oscillators ([`Oscillator`]): the drive
//! (θ, which a PLL moves with [`LockInBank::align_drive`]) or the second excitation
//! (θ₂, [`LockInBank::align_drive2`]). The oscillator only decides which integer phase and
//! frequency word a lane's tables and phasors are computed from (steps 1–2); the kernel
//! runs every lane alike, so it costs the same whichever oscillators the lanes read.
//!
//! Layout is structure-of-arrays over demodulators ("lanes", in blocks of 16) so the loops
//! over lanes vectorise; on x86-64 with AVX2 and FMA a kernel compiled for them is chosen at
//! construction.

use super::lowpass::MAX_ORDER;
use super::predecimator::Predecimator;
use super::simd::F64s;
use super::{DspError, LowPass};
/// The reference a demodulator reads: harmonic k of the drive's phase (the excitation a
/// PLL moves) or of the second excitation's. The settings' `/demods/N/oscillator` maps onto
/// it (`pipeline::dsp_plan`), as the DSP stage takes nothing from the settings.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Oscillator {
    /// The drive: [`LockInBank::align_drive`] moves it.
    #[default]
    Drive,
    /// The second excitation: [`LockInBank::align_drive2`] moves it.
    Drive2,
}
use crate::timebase::{PREDECIMATION, PhaseAccumulator, harmonic_phase, phase_to_radians};
use rustfft::num_complex::Complex64;

/// Number of demodulators a bank holds at most.
pub const MAX_DEMODULATORS: usize = 32;
/// Granularity of [`LockInBank::split`]: shards hold whole groups of this many lanes, the
/// width of one AVX2 register of f64 (the portable SSE2 kernel's registers hold 2, which
/// divides it).
pub const SPLIT_LANES: usize = 4;
/// Order N of the CIC pre-decimator (cascaded boxcars).
pub const PREDECIMATION_ORDER: usize = 4;

const PREDECIMATOR: Predecimator = Predecimator {
    factor: PREDECIMATION,
    order: PREDECIMATION_ORDER,
};
/// Half-length c of the pre-decimator FIR (its group delay in input samples).
const HALF: usize = PREDECIMATOR.half_len();

/// How far (rad per input sample, at the highest harmonic) the pre-decimator's mixing taps
/// may be from the drive's frequency before they are recomputed: the kernel h (unit sum,
/// second moment σ² = order·(factor² − 1)/12 = 85 samples²) shifted by δ passes
/// 1 − δ²σ²/2 of the signal, within 1e-6 at δ = 1.5e-4 (e.g. 2.4 Hz at harmonic 32 of a
/// 10 MS/s stream).
pub const TAPS_TOLERANCE: f64 = 1.5e-4;
/// Lanes per block: demodulators are processed 16 at a time, each block's state one struct.
const BLOCK: usize = 16;
/// Input samples copied into the history buffer per pass.
const CHUNK: usize = 4096;
/// Decimated samples between exact recomputations of the rotating reference phasors.
const REANCHOR_INTERVAL: u32 = 256;
/// Decimated samples the kernel computes in one pass over a block's lanes, where the
/// registers hold them: each row of the mixing table is loaded once for all of them, and
/// each lane's state (phasor, compensator, low-pass, boxcar) is loaded and stored once a
/// pass, not once a sample. A pass ends early at a re-anchoring or an output (fewer are
/// computed one at a time); every lane's arithmetic is the same as one sample at a time,
/// in the same order, so the bits are too.
const STEPS: usize = 4;

/// Settings of one demodulator of a [`LockInBank`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Demodulator {
    /// Whether the demodulator runs and produces output.
    pub enable: bool,
    /// Harmonic k of its oscillator (1); 0 demodulates the mean. Above the Nyquist
    /// frequency (k·f > f_s/2, f the oscillator's frequency) it demodulates the alias, as
    /// sampling dictates.
    pub harmonic: u32,
    /// Low-pass order: identical first-order sections in cascade (1–8).
    pub order: u32,
    /// Time constant τ of each low-pass section (s).
    pub time_constant: f64,
    /// Requested output rate (Hz). The bank realises f_s/(D·M) for the integer M closest
    /// to f_s/(D·rate), at most f_s/D; [`LockInBank::output_rate`] reports it.
    pub output_rate: f64,
    /// The oscillator whose harmonic k it reads: the drive (the default) or the second
    /// excitation.
    pub oscillator: Oscillator,
}

impl Demodulator {
    /// An enabled demodulator at `harmonic` with `order` sections of `time_constant` (s),
    /// producing `output_rate` (Hz).
    pub const fn new(harmonic: u32, order: u32, time_constant: f64, output_rate: f64) -> Self {
        Self {
            enable: true,
            harmonic,
            order,
            time_constant,
            output_rate,
            oscillator: Oscillator::Drive,
        }
    }

    /// The same demodulator reading harmonic k of `oscillator`.
    pub const fn on(self, oscillator: Oscillator) -> Self {
        Self { oscillator, ..self }
    }
}

/// One output of one demodulator.
///
/// A signal `A·cos(k·θ + φ)`, θ the drive phase of the bank's [`PhaseAccumulator`], reads
/// `x + i·y = A·e^{iφ}`: `x` and `y` are in the unit of the input (m for the photodiode),
/// [`r`](Self::r) is the peak amplitude A and [`phase`](Self::phase) is φ in radians. For
/// k = 0 the mean μ reads `x = μ`, `y = 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LockInSample {
    /// Index of the demodulator in the bank.
    pub demod: usize,
    /// Its harmonic k.
    pub harmonic: u32,
    /// The oscillator whose harmonic k it reads.
    pub oscillator: Oscillator,
    /// Index of the newest input sample that went into this output (counted from the
    /// bank's first sample). The low-pass adds its own delay (n·τ at DC); the
    /// pre-decimator and compensator a fixed [`LockInBank::group_delay`].
    pub sample_index: u64,
    /// In-phase part X = A cos φ (input unit).
    pub x: f64,
    /// Quadrature part Y = A sin φ (input unit).
    pub y: f64,
}

impl LockInSample {
    /// Peak amplitude R = |X + iY| (input unit).
    pub fn r(&self) -> f64 {
        self.x.hypot(self.y)
    }

    /// Phase φ = arg(X + iY) against k times its oscillator's phase (rad, in (−π, π]).
    pub fn phase(&self) -> f64 {
        self.y.atan2(self.x)
    }
}

/// Sixteen lanes of one quantity.
type Lanes = [f64; BLOCK];

/// One row of the pre-decimator's table over a block of lanes: `[re, im]` (see
/// [`Plan::coef`]). Aligned to a cache line, as [`BlockConstants`]: it is the stream of
/// loads the kernel's multiply–adds read.
#[derive(Clone, Copy, Debug)]
#[repr(align(64))]
struct Row([Lanes; 2]);

/// Constants of one block of lanes. Aligned to a cache line, so that no vector load of
/// its lanes splits across two (the heap gives 16 bytes otherwise: the bank's speed then
/// depended on where its blocks happened to land).
#[derive(Clone, Debug)]
#[repr(align(64))]
struct BlockConstants {
    /// `e^{−ikωD}`: the reference phasor's rotation per decimated sample.
    step_re: Lanes,
    step_im: Lanes,
    /// α per low-pass section; 1 (pass-through) above a lane's order.
    alpha: [Lanes; MAX_ORDER as usize],
}

/// State of one block of lanes. One struct per block, so that the compiler sees one
/// object and no aliasing between its arrays; aligned to a cache line, as
/// [`BlockConstants`].
#[derive(Clone, Debug)]
#[repr(align(64))]
struct BlockState {
    /// `e^{−ikθ[m_c]}` for the next decimated sample.
    rot_re: Lanes,
    rot_im: Lanes,
    /// The two previous pre-decimator outputs, for the droop compensator.
    prev1_re: Lanes,
    prev1_im: Lanes,
    prev2_re: Lanes,
    prev2_im: Lanes,
    /// Low-pass section outputs.
    lowpass_re: [Lanes; MAX_ORDER as usize],
    lowpass_im: [Lanes; MAX_ORDER as usize],
    /// Sums of the pre-decimator's baseband outputs since the last
    /// [`LockInBank::take_integrals`]: the boxcar (pixel) demodulation.
    acc_re: Lanes,
    acc_im: Lanes,
}

impl Default for BlockState {
    fn default() -> Self {
        Self {
            rot_re: [1.0; BLOCK],
            rot_im: [0.0; BLOCK],
            prev1_re: [0.0; BLOCK],
            prev1_im: [0.0; BLOCK],
            prev2_re: [0.0; BLOCK],
            prev2_im: [0.0; BLOCK],
            lowpass_re: [[0.0; BLOCK]; MAX_ORDER as usize],
            lowpass_im: [[0.0; BLOCK]; MAX_ORDER as usize],
            acc_re: [0.0; BLOCK],
            acc_im: [0.0; BLOCK],
        }
    }
}

/// What the settings and the oscillators' frequencies determine, per lane (lane = position
/// among the enabled demodulators; lanes past `count` are spare and compute zeros).
#[derive(Debug)]
struct Plan {
    /// Enabled demodulators (lanes in use).
    count: usize,
    /// Demodulator index of each lane in use.
    demod: Vec<usize>,
    /// Harmonic of each lane (0 for spare lanes).
    harmonic: Vec<u32>,
    /// The oscillator of each lane (the drive for spare lanes).
    oscillator: Vec<Oscillator>,
    /// Mixer gain: 2 for k ≥ 1 (one-sided peak amplitude), 1 for the mean; 0 when spare.
    gain: Vec<f64>,
    /// Decimated samples per output, per lane in use.
    period: Vec<u32>,
    /// Low-pass sections run (the highest order in the bank).
    sections: usize,
    /// Pre-decimator taps h_{c+u}, u = 0…c.
    taps: Vec<f64>,
    /// `[block][u]` → `[g·h_u·cos(kωu), g·h_u·sin(kωu)]` over the block's lanes.
    coef: Vec<Row>,
    blocks: Vec<BlockConstants>,
    /// The frequency word the drive lanes' `coef` was computed for.
    taps_word: u64,
    /// The same for the lanes on the second excitation.
    taps_word2: u64,
    /// The highest harmonic of a lane in use on the drive.
    max_harmonic: u32,
    /// The highest harmonic of a lane in use on the second excitation.
    max_harmonic2: u32,
    /// Lanes in use on the second excitation.
    count2: usize,
    /// Times `coef` was recomputed.
    retunes: u64,
}

/// Everything that changes while processing.
#[derive(Debug)]
struct State {
    /// Drive phase of sample `samples`, the next one to arrive.
    drive: PhaseAccumulator,
    /// The second excitation's phase of that sample.
    drive2: PhaseAccumulator,
    /// Input samples consumed.
    samples: u64,
    /// The last 2c input samples, then room for a chunk.
    history: Vec<f64>,
    /// Input samples until the next decimated output (1…D).
    until_output: usize,
    /// Decimated samples until the phasors are recomputed exactly.
    reanchor_in: u32,
    /// Whether the next re-anchoring follows a move of an oscillator's word (a PLL's step,
    /// up to one a drive period): it then takes each lane's phasor as a power of its
    /// oscillator's, one `sin_cos` an oscillator, not one a lane. The periodic
    /// re-anchoring, and every one of a bank whose oscillators never move, stays exact.
    reanchor_moved: bool,
    /// Shared sums (u = 0…c) and differences of samples symmetric about the centre, for
    /// each of up to [`STEPS`] decimated samples (`[step·(c + 1) + u]`).
    sums: Vec<f64>,
    diffs: Vec<f64>,
    blocks: Vec<BlockState>,
    /// Low-pass output of each lane at the last decimated sample.
    out_re: Vec<f64>,
    out_im: Vec<f64>,
    /// Decimated samples until each lane's next output, as of the last output.
    countdown: Vec<u32>,
    /// Decimated samples since the last output of any lane.
    since_output: u32,
    /// Decimated samples summed in the boxcar integrators.
    integrated: u32,
    /// The smallest countdown: when the next output of any lane is due.
    next_output: u32,
}

/// A bank of up to [`MAX_DEMODULATORS`] lock-in demodulators at harmonics of one drive.
///
/// Built off the real-time thread ([`new`](Self::new) allocates every table and buffer);
/// [`process`](Self::process) neither allocates, locks nor blocks.
///
/// Phase reference: the bank's drive phase θ is a [`PhaseAccumulator`] that starts at phase
/// word 0 on the first sample given to [`process`](Self::process) (index 0) unless set with
/// [`set_drive_phase`](Self::set_drive_phase), and advances by the frequency word each
/// sample. Demodulator k reads `A·e^{iφ}` for a signal `A·cos(k·θ + φ)`: phase 0 is a
/// cosine whose peak coincides with phase word 0 of k·θ.
///
/// ```
/// use ftafm::dsp::{Demodulator, LockInBank};
///
/// let (fs, drive) = (10e6, 100.0123e3);
/// // Harmonics 1 and 3: 4th-order low-pass of 100 µs, outputs at 1 kHz.
/// let demods = [Demodulator::new(1, 4, 100e-6, 1e3), Demodulator::new(3, 4, 100e-6, 1e3)];
/// let mut bank = LockInBank::new(fs, drive, &demods)?;
///
/// let signal: Vec<f64> = (0..50_000)
///     .map(|m| {
///         let theta = std::f64::consts::TAU * drive * m as f64 / fs;
///         20e-9 * (theta + 0.5).cos() + 0.1e-9 * (3.0 * theta - 1.0).cos()
///     })
///     .collect();
/// let mut third = None;
/// bank.process(&signal, |s| if s.harmonic == 3 { third = Some(s) });
/// let third = third.unwrap();
/// assert!((third.r() - 0.1e-9).abs() < 1e-15);
/// assert!((third.phase() + 1.0).abs() < 1e-6);
/// # Ok::<(), ftafm::dsp::DspError>(())
/// ```
#[derive(Debug)]
pub struct LockInBank {
    sample_rate: f64,
    demods: Vec<Demodulator>,
    compensation: f64,
    plan: Plan,
    state: State,
    fma: bool,
    /// The AVX-512 build of the AVX2+FMA kernel (the same bits) where the CPU has it.
    avx512: bool,
}

impl LockInBank {
    /// A bank for input at `sample_rate` (Hz) and a drive at `drive_frequency` (Hz), with
    /// `demodulators[i]` becoming demodulator i (at most [`MAX_DEMODULATORS`]; disabled
    /// ones are neither validated nor run). Drive phase 0 at sample 0. Demodulators on
    /// [`Oscillator::Drive2`] read a second excitation at 0 Hz until
    /// [`align_drive2`](Self::align_drive2) sets it ([`with_drive2`](Self::with_drive2)
    /// gives its frequency from the start).
    pub fn new(
        sample_rate: f64,
        drive_frequency: f64,
        demodulators: &[Demodulator],
    ) -> Result<Self, DspError> {
        let drive = PhaseAccumulator::new(drive_frequency, sample_rate)?;
        Self::with_drives(
            sample_rate,
            drive,
            PhaseAccumulator::from_words(0, 0),
            demodulators,
        )
    }

    /// [`new`](Self::new) with the second excitation at `drive2_frequency` (Hz), its
    /// phase 0 at sample 0.
    pub fn with_drive2(
        sample_rate: f64,
        drive_frequency: f64,
        drive2_frequency: f64,
        demodulators: &[Demodulator],
    ) -> Result<Self, DspError> {
        let drive = PhaseAccumulator::new(drive_frequency, sample_rate)?;
        let drive2 = PhaseAccumulator::new(drive2_frequency, sample_rate)?;
        Self::with_drives(sample_rate, drive, drive2, demodulators)
    }

    /// [`new`](Self::new) with both oscillators given as phase accumulators.
    fn with_drives(
        sample_rate: f64,
        drive: PhaseAccumulator,
        drive2: PhaseAccumulator,
        demodulators: &[Demodulator],
    ) -> Result<Self, DspError> {
        if demodulators.len() > MAX_DEMODULATORS {
            return Err(DspError::TooManyDemodulators(demodulators.len()));
        }
        let decimated_rate = sample_rate / PREDECIMATION as f64;
        let mut filters = Vec::new();
        for (index, d) in demodulators.iter().enumerate() {
            if !d.enable {
                continue;
            }
            let wrap = |source| DspError::Demodulator {
                index,
                source: Box::new(source),
            };
            let filter = LowPass::new(d.order, d.time_constant, decimated_rate).map_err(wrap)?;
            if !(d.output_rate.is_finite() && d.output_rate > 0.0) {
                return Err(wrap(DspError::OutputRate(d.output_rate)));
            }
            filters.push((index, *d, filter));
        }

        let count = filters.len();
        let nblocks = count.div_ceil(BLOCK);
        let width = nblocks * BLOCK;
        let sections = filters
            .iter()
            .map(|f| f.2.order() as usize)
            .max()
            .unwrap_or(0);
        let idle = BlockConstants {
            step_re: [1.0; BLOCK],
            step_im: [0.0; BLOCK],
            alpha: [[1.0; BLOCK]; MAX_ORDER as usize],
        };
        let max_harmonic_on = |oscillator| {
            filters
                .iter()
                .filter(|f| f.1.oscillator == oscillator)
                .map(|f| f.1.harmonic)
                .max()
                .unwrap_or(0)
        };
        let mut plan = Plan {
            count,
            demod: filters.iter().map(|f| f.0).collect(),
            harmonic: vec![0; width],
            oscillator: vec![Oscillator::Drive; width],
            gain: vec![0.0; width],
            period: vec![0; count],
            sections,
            taps: PREDECIMATOR.taps()[HALF..].to_vec(),
            coef: vec![Row([[0.0; BLOCK]; 2]); nblocks * (HALF + 1)],
            blocks: vec![idle; nblocks],
            taps_word: 0,
            taps_word2: 0,
            max_harmonic: max_harmonic_on(Oscillator::Drive),
            max_harmonic2: max_harmonic_on(Oscillator::Drive2),
            count2: filters
                .iter()
                .filter(|f| f.1.oscillator == Oscillator::Drive2)
                .count(),
            retunes: 0,
        };
        for (lane, (_, d, filter)) in filters.iter().enumerate() {
            plan.harmonic[lane] = d.harmonic;
            plan.oscillator[lane] = d.oscillator;
            plan.gain[lane] = if d.harmonic == 0 { 1.0 } else { 2.0 };
            let period = (decimated_rate / d.output_rate).round();
            plan.period[lane] = period.clamp(1.0, u32::MAX as f64) as u32;
            for alpha in &mut plan.blocks[lane / BLOCK].alpha[..filter.order() as usize] {
                alpha[lane % BLOCK] = filter.alpha();
            }
        }
        plan.tune(Oscillator::Drive, drive.frequency_word());
        if plan.count2 > 0 {
            plan.tune(Oscillator::Drive2, drive2.frequency_word());
        }

        let state = State {
            drive,
            drive2,
            samples: 0,
            history: vec![0.0; 2 * HALF + CHUNK],
            until_output: PREDECIMATION,
            reanchor_in: 0,
            reanchor_moved: false,
            sums: vec![0.0; STEPS * (HALF + 1)],
            diffs: vec![0.0; STEPS * (HALF + 1)],
            blocks: vec![BlockState::default(); nblocks],
            out_re: vec![0.0; width],
            out_im: vec![0.0; width],
            countdown: plan.period.clone(),
            since_output: 0,
            integrated: 0,
            next_output: plan.period.iter().copied().min().unwrap_or(u32::MAX),
        };
        Ok(Self {
            sample_rate,
            demods: demodulators.to_vec(),
            compensation: PREDECIMATOR.droop_compensation(),
            plan,
            state,
            fma: crate::cpu::fma_available(),
            avx512: crate::cpu::fma_available() && crate::cpu::avx512_available(),
        })
    }

    /// Splits the bank into at most `parts` banks ("shards") that together compute, bit for
    /// bit, what this one would: each takes a run of consecutive enabled demodulators (its
    /// lanes), cut only at multiples of [`SPLIT_LANES`], and keeps this bank's drive, kernel
    /// and number of low-pass sections (a lane whose order is below the bank's highest still
    /// runs the pass-through sections above it, whose rounding is part of its output).
    /// Every step of the kernel is lane-wise, so a lane's arithmetic does not depend on
    /// which bank holds it nor where in its vector registers it sits. Shards hold their
    /// demodulators under their own indices (those of other shards disabled), and report
    /// them in index order, so running the shards on the same input and taking their outputs
    /// shard by shard for each output time gives this bank's outputs in its order.
    ///
    /// Gives fewer parts when there are fewer groups of [`SPLIT_LANES`] lanes (one when no
    /// demodulator is enabled). The shards start as a new bank starts (filters at zero); the
    /// drive phase and frequency are this bank's. Allocates (call it off the real-time
    /// thread).
    pub fn split(self, parts: usize) -> Result<Vec<LockInBank>, DspError> {
        let groups = self.plan.count.div_ceil(SPLIT_LANES);
        let parts = parts.clamp(1, groups.max(1));
        if parts == 1 {
            return Ok(vec![self]);
        }
        let mut shards = Vec::with_capacity(parts);
        for part in 0..parts {
            let lo = (groups * part / parts * SPLIT_LANES).min(self.plan.count);
            let hi = (groups * (part + 1) / parts * SPLIT_LANES).min(self.plan.count);
            let mine = &self.plan.demod[lo..hi];
            let demods: Vec<Demodulator> = self
                .demods
                .iter()
                .enumerate()
                .map(|(index, d)| Demodulator {
                    enable: d.enable && mine.contains(&index),
                    ..*d
                })
                .collect();
            let mut shard = Self::with_drives(
                self.sample_rate,
                self.state.drive,
                self.state.drive2,
                &demods,
            )?;
            shard.plan.sections = self.plan.sections;
            shard.fma = self.fma;
            shard.avx512 = self.avx512;
            shards.push(shard);
        }
        Ok(shards)
    }

    /// Enabled demodulators (lanes in use).
    pub fn lanes(&self) -> usize {
        self.plan.count
    }

    /// Use the portable kernel even where the AVX2/FMA one could run (for comparisons;
    /// results agree to rounding).
    pub fn with_portable_kernel(mut self) -> Self {
        self.fma = false;
        self.avx512 = false;
        self
    }

    /// Use the AVX2+FMA kernel even where the AVX-512 one could run (for comparisons: the
    /// two give the same bits).
    pub fn with_avx2_kernel(mut self) -> Self {
        self.avx512 = false;
        self
    }

    /// Name of the kernel in use: `"avx512"` (the AVX2+FMA kernel's operations on eight
    /// lanes a register), `"avx2+fma"`, or the portable one, `"sse2"` on x86-64 and
    /// `"scalar"` elsewhere.
    pub fn kernel(&self) -> &'static str {
        if self.avx512 {
            "avx512"
        } else if self.fma {
            "avx2+fma"
        } else if cfg!(target_arch = "x86_64") {
            "sse2"
        } else {
            "scalar"
        }
    }

    /// Input sample rate f_s (Hz).
    pub const fn sample_rate(&self) -> f64 {
        self.sample_rate
    }

    /// Rate the low-pass filters run at, f_s/D (Hz): the highest possible output rate.
    pub fn decimated_rate(&self) -> f64 {
        self.sample_rate / PREDECIMATION as f64
    }

    /// Fixed delay of the pre-decimator and its droop compensator, c + D = 46 (input
    /// samples): an input sample reaches the low-pass this much later.
    pub const fn group_delay(&self) -> usize {
        HALF + PREDECIMATION
    }

    /// The demodulator settings, as given.
    pub fn demodulators(&self) -> &[Demodulator] {
        &self.demods
    }

    /// Realised output rate of demodulator `index` (Hz), `None` if absent or disabled.
    pub fn output_rate(&self, index: usize) -> Option<f64> {
        let lane = self.plan.demod.iter().position(|&d| d == index)?;
        Some(self.decimated_rate() / self.plan.period[lane] as f64)
    }

    /// The low-pass filter of demodulator `index` (at the decimated rate), `None` if absent
    /// or disabled.
    pub fn low_pass(&self, index: usize) -> Option<LowPass> {
        let d = self.demods.get(index).filter(|d| d.enable)?;
        LowPass::new(d.order, d.time_constant, self.decimated_rate()).ok()
    }

    /// The drive phase accumulator; its phase is that of the next input sample.
    pub const fn drive(&self) -> &PhaseAccumulator {
        &self.state.drive
    }

    /// Realised drive frequency (Hz).
    pub fn drive_frequency(&self) -> f64 {
        self.state.drive.frequency(self.sample_rate)
    }

    /// The second excitation's phase accumulator (the reference of the demodulators on
    /// [`Oscillator::Drive2`]); its phase is that of the next input sample.
    pub const fn drive2(&self) -> &PhaseAccumulator {
        &self.state.drive2
    }

    /// Input samples consumed so far; also the index of the next one.
    pub const fn samples_processed(&self) -> u64 {
        self.state.samples
    }

    /// Change the drive frequency (Hz) without a phase jump: the drive phase of the next
    /// sample is kept and only the frequency word changes. Real-time safe (no allocation),
    /// but recomputes the mixing tables, about 10³ `sin_cos`. For the next c = 30 samples
    /// the pre-decimator window straddles the change and mixes its older samples at the new
    /// frequency: a transient far shorter than any low-pass time constant.
    pub fn set_drive_frequency(&mut self, frequency: f64) -> Result<(), DspError> {
        self.state
            .drive
            .set_frequency(frequency, self.sample_rate)?;
        self.plan
            .tune(Oscillator::Drive, self.state.drive.frequency_word());
        self.state.reanchor_in = 0;
        Ok(())
    }

    /// Lock the bank to an external drive phase accumulator: `phase` is the phase word of
    /// the next input sample and `frequency_word` its step per sample. Retunes (as
    /// [`set_drive_frequency`](Self::set_drive_frequency) does) only when the word changes,
    /// so calling it for every block costs nothing while the drive is steady. Real-time safe.
    ///
    /// A PLL moves the word by a little at every drive period: then only the phase steps
    /// follow it (one `sin_cos` per lane) while the pre-decimator's mixing taps stay on the
    /// word they were computed for, as long as that shifts the taps' symmetric kernel by at
    /// most [`TAPS_TOLERANCE`] rad per sample at its lanes' highest harmonic: its passband
    /// gain is then within 1e-6 of what exact taps give, and its phase exact (the kernel
    /// stays symmetric about the window's centre, where the reference is taken).
    ///
    /// Only the demodulators on [`Oscillator::Drive`] follow; those on the second
    /// excitation keep their reference ([`align_drive2`](Self::align_drive2)).
    pub fn align_drive(&mut self, phase: u64, frequency_word: u64) {
        if frequency_word != self.state.drive.frequency_word() {
            self.state.drive = PhaseAccumulator::from_words(phase, frequency_word);
            self.plan.follow(Oscillator::Drive, frequency_word);
            self.state.reanchor_moved = true;
        } else {
            self.state.drive.set_phase(phase);
        }
        self.state.reanchor_in = 0;
    }

    /// [`align_drive`](Self::align_drive) for the second excitation: `phase` its phase
    /// word of the next input sample and `frequency_word` its step per sample (2^64 = one
    /// period). Moves the demodulators on [`Oscillator::Drive2`] only; with none, it keeps
    /// the accumulator and touches nothing the other lanes compute. Real-time safe.
    pub fn align_drive2(&mut self, phase: u64, frequency_word: u64) {
        if frequency_word != self.state.drive2.frequency_word() {
            self.state.drive2 = PhaseAccumulator::from_words(phase, frequency_word);
            if self.plan.count2 > 0 {
                self.plan.follow(Oscillator::Drive2, frequency_word);
                self.state.reanchor_moved = true;
            }
        } else {
            self.state.drive2.set_phase(phase);
        }
        // The phasors' re-anchoring is exact, but re-anchoring at another sample than the
        // drive's alignment alone asks for would round the drive lanes differently.
        if self.plan.count2 > 0 {
            self.state.reanchor_in = 0;
        }
    }

    /// Times the pre-decimator's mixing taps were recomputed since the bank was built.
    pub fn retunes(&self) -> u64 {
        self.plan.retunes
    }

    /// Set the drive phase word (2^-64 cycle) of the next input sample, to align the bank
    /// with the drive's own phase accumulator.
    pub fn set_drive_phase(&mut self, phase: u64) {
        self.state.drive.set_phase(phase);
        self.state.reanchor_in = 0;
    }

    /// The boxcar demodulation since the last call: for each enabled demodulator, in index
    /// order, `sink(demod, harmonic, oscillator, x, y)` with X + iY the mean of its
    /// pre-decimated baseband samples (the same calibration as its low-pass output: peak
    /// amplitude, phase against k times its oscillator's phase). A decimated sample belongs
    /// to the call after the input sample that completes it,
    /// [`group_delay`](Self::group_delay) samples after its centre. Resets the integrators; returns the decimated samples averaged (0: nothing
    /// is reported). Real-time safe.
    pub fn take_integrals(
        &mut self,
        mut sink: impl FnMut(usize, u32, Oscillator, f64, f64),
    ) -> u32 {
        let n = self.state.integrated;
        if n > 0 {
            let scale = 1.0 / f64::from(n);
            for l in 0..self.plan.count {
                let block = &self.state.blocks[l / BLOCK];
                sink(
                    self.plan.demod[l],
                    self.plan.harmonic[l],
                    self.plan.oscillator[l],
                    block.acc_re[l % BLOCK] * scale,
                    block.acc_im[l % BLOCK] * scale,
                );
            }
        }
        for block in &mut self.state.blocks {
            block.acc_re = [0.0; BLOCK];
            block.acc_im = [0.0; BLOCK];
        }
        self.state.integrated = 0;
        n
    }

    /// Demodulate a block of input samples (any length) and hand each output to `sink` in
    /// time order (demodulators in index order within one time). Real-time safe.
    pub fn process<F>(&mut self, input: &[f64], mut sink: F)
    where
        F: FnMut(LockInSample),
    {
        #[cfg(target_arch = "x86_64")]
        if self.avx512 {
            // SAFETY: `avx512` is only true when the CPU reported AVX-512F, AVX2 and FMA at
            // construction.
            unsafe { self.process_avx512(input, &mut sink) };
        } else if self.fma {
            // SAFETY: `fma` is only true when the CPU reported AVX2 and FMA at construction.
            unsafe { self.process_avx2_fma(input, &mut sink) };
        } else {
            // SAFETY: SSE2 is part of every x86-64 CPU.
            unsafe { self.process_kernel::<super::simd::Sse2, 4, 1, F>(input, &mut sink) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        // SAFETY: plain f64 needs no CPU feature.
        unsafe {
            self.process_kernel::<f64, 4, 1, F>(input, &mut sink)
        };
    }

    /// The kernel compiled for AVX2 and FMA.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn process_avx2_fma<F>(&mut self, input: &[f64], sink: &mut F)
    where
        F: FnMut(LockInSample),
    {
        // One register of four lanes for re and one for im, for four decimated samples:
        // eight independent FMA chains, enough to cover the FMA latency, with the table's
        // two rows and the samples' sums in AVX2's sixteen registers (four lanes by four
        // samples took 9.7 % less time than sixteen lanes by one sample, Zen 4,
        // `lockin_bank/32_demods_order4_avx2`).
        // SAFETY: the caller guarantees AVX2 and FMA.
        unsafe { self.process_kernel::<super::simd::Avx2Fma, 1, 4, F>(input, sink) };
    }

    /// The kernel compiled for AVX-512F: the AVX2+FMA kernel's operations, eight lanes a
    /// register.
    ///
    /// # Safety
    /// The CPU must support AVX-512F, AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn process_avx512<F>(&mut self, input: &[f64], sink: &mut F)
    where
        F: FnMut(LockInSample),
    {
        // Two registers of eight lanes for re and two for im (a block of sixteen), for
        // [`STEPS`] decimated samples: sixteen FMA chains, which keep a core that does one
        // 512-bit FMA a cycle busy, in 28 of the 32 registers with the table's four rows
        // and the samples' sums.
        // SAFETY: the caller guarantees AVX-512F, AVX2 and FMA.
        unsafe { self.process_kernel::<super::simd::Avx512, 2, STEPS, F>(input, sink) };
    }

    /// [`process`](Self::process) through the AVX-512 kernel one decimated sample a pass:
    /// what its passes of [`STEPS`] samples must equal bit for bit. The CPU must have
    /// AVX-512F, AVX2 and FMA.
    #[cfg(all(test, target_arch = "x86_64"))]
    fn process_one_step_at_a_time(&mut self, input: &[f64], mut sink: impl FnMut(LockInSample)) {
        assert!(self.avx512);
        #[target_feature(enable = "avx512f,avx2,fma")]
        unsafe fn run<F: FnMut(LockInSample)>(bank: &mut LockInBank, input: &[f64], sink: &mut F) {
            // SAFETY: the caller guarantees AVX-512F, AVX2 and FMA.
            unsafe { bank.process_kernel::<super::simd::Avx512, 2, 1, F>(input, sink) };
        }
        // SAFETY: `avx512` is only true when the CPU reported AVX-512F, AVX2 and FMA.
        unsafe { run(self, input, &mut sink) };
    }

    /// The whole block loop, monomorphised per vector type `V` (`NV` registers per
    /// quantity, `T` decimated samples a pass, at most [`STEPS`]) so that everything
    /// inlines into the function carrying the target features.
    ///
    /// # Safety
    /// The CPU must support `V`'s target features.
    #[inline(always)]
    unsafe fn process_kernel<V: F64s, const NV: usize, const T: usize, F>(
        &mut self,
        input: &[f64],
        sink: &mut F,
    ) where
        F: FnMut(LockInSample),
    {
        let span = 2 * HALF;
        for chunk in input.chunks(CHUNK) {
            let n = chunk.len();
            self.state.history[span..span + n].copy_from_slice(chunk);
            let mut fire = self.state.until_output - 1;
            while fire < n {
                let due = (n - 1 - fire) / PREDECIMATION + 1;
                // SAFETY: passed on from the caller.
                let done = unsafe { self.decimated_steps::<V, NV, T, F>(fire, due, sink) };
                fire += done * PREDECIMATION;
            }
            self.state.until_output = fire - n + 1;
            self.state.history.copy_within(n..n + span, 0);
            self.state.samples += n as u64;
            self.state.drive.advance(n as u64);
            self.state.drive2.advance(n as u64);
        }
    }

    /// Up to `due` (≥ 1) consecutive decimated samples, the first completed by chunk
    /// sample `fire` (history index `fire + 2c`), the next ones D samples apart; returns
    /// how many it computed: at most `T`, and the pass ends before a re-anchoring and at
    /// an output.
    ///
    /// # Safety
    /// The CPU must support `V`'s target features.
    #[inline(always)]
    unsafe fn decimated_steps<V: F64s, const NV: usize, const T: usize, F>(
        &mut self,
        fire: usize,
        due: usize,
        sink: &mut F,
    ) -> usize
    where
        F: FnMut(LockInSample),
    {
        let plan = &self.plan;
        let st = &mut self.state;
        if plan.count == 0 {
            return due;
        }

        if st.reanchor_in == 0 {
            // The window centre is `HALF` samples before `fire`; `fire` is relative to the
            // sample whose phase the accumulator holds.
            let centre = fire as i64 - HALF as i64;
            let (centre_phase, centre_phase2) =
                (st.drive.phase_at(centre), st.drive2.phase_at(centre));
            if st.reanchor_moved {
                let bases = [centre_phase, centre_phase2].map(|p| {
                    let (s, c) = phase_to_radians(p).sin_cos();
                    Complex64::new(c, -s)
                });
                let mut powers = HarmonicPowers::default();
                for l in 0..plan.count {
                    let o = plan.oscillator[l] as usize;
                    let rot = powers.of(o, bases[o], plan.harmonic[l]);
                    let block = &mut st.blocks[l / BLOCK];
                    block.rot_re[l % BLOCK] = rot.re;
                    block.rot_im[l % BLOCK] = rot.im;
                }
                st.reanchor_moved = false;
            } else {
                for l in 0..plan.count {
                    let phase = match plan.oscillator[l] {
                        Oscillator::Drive => centre_phase,
                        Oscillator::Drive2 => centre_phase2,
                    };
                    let theta = phase_to_radians(harmonic_phase(phase, plan.harmonic[l]));
                    let (s, c) = theta.sin_cos();
                    let block = &mut st.blocks[l / BLOCK];
                    block.rot_re[l % BLOCK] = c;
                    block.rot_im[l % BLOCK] = -s;
                }
            }
            st.reanchor_in = REANCHOR_INTERVAL;
        }
        // The pass: no re-anchoring inside it, and an output only at its last sample.
        let steps = due
            .min(T)
            .min(st.reanchor_in as usize)
            .min((st.next_output - st.since_output) as usize);

        let width = HALF + 1;
        for step in 0..steps {
            let start = fire + step * PREDECIMATION;
            let window = &st.history[start..start + 2 * HALF + 1];
            let (older, newer) = window.split_at(HALF);
            let (centre, newer) = newer.split_first().expect("window has a centre");
            let sums = &mut st.sums[step * width..(step + 1) * width];
            let diffs = &mut st.diffs[step * width..(step + 1) * width];
            sums[0] = *centre;
            diffs[0] = 0.0;
            for (((s, d), a), b) in sums[1..]
                .iter_mut()
                .zip(&mut diffs[1..])
                .zip(older.iter().rev())
                .zip(newer)
            {
                *s = a + b;
                *d = a - b;
            }
        }
        st.reanchor_in -= steps as u32;
        st.integrated += steps as u32;

        // The section count is a constant inside the kernel, so its loop unrolls.
        let c = self.compensation;
        if steps == T {
            // SAFETY: passed on from the caller; the sums and differences of `T` samples
            // were written above.
            unsafe { all_blocks_sections::<V, NV, T>(plan, st, c, 0) };
        } else {
            for step in 0..steps {
                // SAFETY: as above, for the one sample `step`.
                unsafe { all_blocks_sections::<V, NV, 1>(plan, st, c, step) };
            }
        }

        // Outputs are rare (kHz against the MHz decimated rate): look at the lanes only
        // when the earliest of them is due.
        st.since_output += steps as u32;
        if st.since_output == st.next_output {
            let sample_index = st.samples + (fire + (steps - 1) * PREDECIMATION) as u64;
            let elapsed = st.since_output;
            let mut next = u32::MAX;
            for l in 0..plan.count {
                st.countdown[l] -= elapsed;
                if st.countdown[l] == 0 {
                    st.countdown[l] = plan.period[l];
                    sink(LockInSample {
                        demod: plan.demod[l],
                        harmonic: plan.harmonic[l],
                        oscillator: plan.oscillator[l],
                        sample_index,
                        x: st.out_re[l],
                        y: st.out_im[l],
                    });
                }
                next = next.min(st.countdown[l]);
            }
            st.since_output = 0;
            st.next_output = next;
        }
        steps
    }
}

/// [`all_blocks`] for the plan's number of low-pass sections (a constant in each build, so
/// that the sections' loop unrolls), for `T` decimated samples from sample `first` of the
/// shared sums.
///
/// # Safety
/// The CPU must support `V`'s target features; `first + T <= STEPS`.
#[inline(always)]
unsafe fn all_blocks_sections<V: F64s, const NV: usize, const T: usize>(
    plan: &Plan,
    st: &mut State,
    c: f64,
    first: usize,
) {
    // SAFETY (all arms): passed on from the caller.
    unsafe {
        match plan.sections {
            1 => all_blocks::<V, NV, 1, T>(plan, st, c, first),
            2 => all_blocks::<V, NV, 2, T>(plan, st, c, first),
            3 => all_blocks::<V, NV, 3, T>(plan, st, c, first),
            4 => all_blocks::<V, NV, 4, T>(plan, st, c, first),
            5 => all_blocks::<V, NV, 5, T>(plan, st, c, first),
            6 => all_blocks::<V, NV, 6, T>(plan, st, c, first),
            7 => all_blocks::<V, NV, 7, T>(plan, st, c, first),
            _ => all_blocks::<V, NV, 8, T>(plan, st, c, first),
        }
    }
}

/// [`lane_block`] over every block of lanes, for low-pass filters of `S` sections and `T`
/// decimated samples from sample `first` of the shared sums.
///
/// # Safety
/// The CPU must support `V`'s target features; `first + T <= STEPS`.
#[inline(always)]
unsafe fn all_blocks<V: F64s, const NV: usize, const S: usize, const T: usize>(
    plan: &Plan,
    st: &mut State,
    compensation: f64,
    first: usize,
) {
    debug_assert!(first + T <= STEPS);
    let lanes = NV * V::LANES;
    let width = HALF + 1;
    let shared = (
        &st.sums[first * width..(first + T) * width],
        &st.diffs[first * width..(first + T) * width],
    );
    let blocks = plan
        .coef
        .chunks_exact(HALF + 1)
        .zip(&plan.blocks)
        .zip(&mut st.blocks)
        .zip(
            st.out_re
                .chunks_exact_mut(BLOCK)
                .zip(st.out_im.chunks_exact_mut(BLOCK)),
        );
    for (((coef, constants), state), (out_re, out_im)) in blocks {
        for sub in (0..BLOCK).step_by(lanes) {
            // SAFETY: `sub + lanes <= BLOCK` (BLOCK is a multiple of `lanes`); `shared`
            // holds `T` samples' sums and differences; the CPU features are passed on
            // from the caller.
            unsafe {
                lane_block::<V, NV, S, T>(
                    sub,
                    coef,
                    shared,
                    constants,
                    state,
                    compensation,
                    (&mut out_re[sub..sub + lanes], &mut out_im[sub..sub + lanes]),
                )
            };
        }
    }
}

/// Everything after the shared sums and differences, for lanes `sub .. sub + NV·LANES`
/// of one block and `T` consecutive decimated samples, kept in registers from one stage
/// and one sample to the next: mixer and pre-decimator, shift to baseband, droop
/// compensation, low-pass. Writes the last sample's low-pass output to `out` and rotates
/// the reference phasors on by `T` decimated samples.
///
/// # Safety
/// The CPU must support `V`'s target features, `sub + NV·LANES <= BLOCK`, `sums` and
/// `diffs` must hold `T·(c + 1)` values, and both `out` slices `NV·LANES`.
#[inline(always)]
unsafe fn lane_block<V: F64s, const NV: usize, const S: usize, const T: usize>(
    sub: usize,
    coef: &[Row],
    (sums, diffs): (&[f64], &[f64]),
    k: &BlockConstants,
    st: &mut BlockState,
    compensation: f64,
    (out_re, out_im): (&mut [f64], &mut [f64]),
) {
    let w = V::LANES;
    let width = HALF + 1;
    debug_assert!(sub + NV * w <= BLOCK);
    debug_assert!(out_re.len() >= NV * w && out_im.len() >= NV * w);
    assert!(coef.len() == width && sums.len() == T * width && diffs.len() == T * width);
    // SAFETY: every pointer below is `sub + j·w` (j < NV) into a BLOCK-long array, or
    // `j·w` into an `out` slice, and `w` values from there are in bounds by the
    // preconditions; the shared sums are read at `t·(c + 1) + u` (t < T, u ≤ c), inside
    // the lengths asserted above; the CPU features are the caller's guarantee.
    unsafe {
        let at = |lanes: &Lanes, j: usize| lanes.as_ptr().add(sub + j * w);
        let at_mut = |lanes: &mut Lanes, j: usize| lanes.as_mut_ptr().add(sub + j * w);
        let (sums, diffs) = (sums.as_ptr(), diffs.as_ptr());

        // Each row of the table is loaded once for the `T` samples.
        let mut fr = [[V::splat(0.0); NV]; T];
        let mut fi = [[V::splat(0.0); NV]; T];
        for (u, Row([row_re, row_im])) in coef.iter().enumerate() {
            let re: [V; NV] = std::array::from_fn(|j| V::load(at(row_re, j)));
            let im: [V; NV] = std::array::from_fn(|j| V::load(at(row_im, j)));
            for t in 0..T {
                let p = V::splat(*sums.add(t * width + u));
                let q = V::splat(*diffs.add(t * width + u));
                for j in 0..NV {
                    fr[t][j] = re[j].mul_add(p, fr[t][j]);
                    fi[t][j] = im[j].mul_add(q, fi[t][j]);
                }
            }
        }

        let a = V::splat(compensation);
        let centre_gain = V::splat(1.0 + 2.0 * compensation);
        for j in 0..NV {
            let (mut rr, mut ri) = (V::load(at(&st.rot_re, j)), V::load(at(&st.rot_im, j)));
            let (mut ar, mut ai) = (V::load(at(&st.acc_re, j)), V::load(at(&st.acc_im, j)));
            let (sr, si) = (V::load(at(&k.step_re, j)), V::load(at(&k.step_im, j)));
            let (mut p1r, mut p1i) = (V::load(at(&st.prev1_re, j)), V::load(at(&st.prev1_im, j)));
            let (mut p2r, mut p2i) = (V::load(at(&st.prev2_re, j)), V::load(at(&st.prev2_im, j)));
            let alpha: [V; S] = std::array::from_fn(|s| V::load(at(&k.alpha[s], j)));
            let mut yr: [V; S] = std::array::from_fn(|s| V::load(at(&st.lowpass_re[s], j)));
            let mut yi: [V; S] = std::array::from_fn(|s| V::load(at(&st.lowpass_im[s], j)));
            let (mut xr, mut xi) = (V::splat(0.0), V::splat(0.0));
            for t in 0..T {
                // Shift to baseband.
                let zr = rr.mul(fr[t][j]).sub(ri.mul(fi[t][j]));
                let zi = rr.mul(fi[t][j]).add(ri.mul(fr[t][j]));
                // The boxcar integrator of the pixel demodulation.
                ar = ar.add(zr);
                ai = ai.add(zi);
                // Rotate the reference on to the next decimated sample.
                (rr, ri) = (rr.mul(sr).sub(ri.mul(si)), rr.mul(si).add(ri.mul(sr)));

                // Droop compensator, centred on the previous sample.
                xr = centre_gain.mul(p1r).sub(a.mul(zr.add(p2r)));
                xi = centre_gain.mul(p1i).sub(a.mul(zi.add(p2i)));
                (p2r, p2i) = (p1r, p1i);
                (p1r, p1i) = (zr, zi);

                // Low-pass cascade.
                for s in 0..S {
                    xr = alpha[s].mul_add(xr.sub(yr[s]), yr[s]);
                    xi = alpha[s].mul_add(xi.sub(yi[s]), yi[s]);
                    (yr[s], yi[s]) = (xr, xi);
                }
            }
            rr.store(at_mut(&mut st.rot_re, j));
            ri.store(at_mut(&mut st.rot_im, j));
            ar.store(at_mut(&mut st.acc_re, j));
            ai.store(at_mut(&mut st.acc_im, j));
            p1r.store(at_mut(&mut st.prev1_re, j));
            p1i.store(at_mut(&mut st.prev1_im, j));
            p2r.store(at_mut(&mut st.prev2_re, j));
            p2i.store(at_mut(&mut st.prev2_im, j));
            for s in 0..S {
                yr[s].store(at_mut(&mut st.lowpass_re[s], j));
                yi[s].store(at_mut(&mut st.lowpass_im[s], j));
            }
            xr.store(out_re.as_mut_ptr().add(j * w));
            xi.store(out_im.as_mut_ptr().add(j * w));
        }
    }
}

impl Plan {
    /// The word `oscillator`'s lanes' taps were computed for, and their highest harmonic.
    fn taps_of(&self, oscillator: Oscillator) -> (u64, u32) {
        match oscillator {
            Oscillator::Drive => (self.taps_word, self.max_harmonic),
            Oscillator::Drive2 => (self.taps_word2, self.max_harmonic2),
        }
    }

    /// Whether the taps computed for `oscillator`'s lanes serve `word`: the kernel shift
    /// 2π·k·Δword/2^64 at their highest harmonic k within [`TAPS_TOLERANCE`].
    fn taps_hold(&self, oscillator: Oscillator, word: u64) -> bool {
        let (taps_word, max_harmonic) = self.taps_of(oscillator);
        let shift = word.wrapping_sub(taps_word) as i64 as f64 / crate::timebase::TWO_POW_64
            * std::f64::consts::TAU
            * f64::from(max_harmonic);
        shift.abs() <= TAPS_TOLERANCE
    }

    /// `oscillator` moved to `word` while running: its lanes' phase steps follow, and their
    /// taps too when they no longer hold ([`taps_hold`](Self::taps_hold)). No allocation.
    fn follow(&mut self, oscillator: Oscillator, word: u64) {
        if self.taps_hold(oscillator, word) {
            self.follow_steps(oscillator, word);
        } else {
            self.retune(oscillator, word);
        }
    }

    /// Records that `oscillator`'s lanes' taps are now computed for `word`.
    fn set_taps_word(&mut self, oscillator: Oscillator, word: u64) {
        match oscillator {
            Oscillator::Drive => self.taps_word = word,
            Oscillator::Drive2 => self.taps_word2 = word,
        }
        self.retunes += 1;
    }

    /// The phase steps per decimated sample of `oscillator`'s lanes for `word` (the taps
    /// stay). No allocation.
    fn tune_steps(&mut self, oscillator: Oscillator, word: u64) {
        let step = word.wrapping_mul(PREDECIMATION as u64);
        for (l, (&k, &o)) in self.harmonic.iter().zip(&self.oscillator).enumerate() {
            if o != oscillator {
                continue;
            }
            let (block, i) = (l / BLOCK, l % BLOCK);
            let (s, c) = phase_to_radians(harmonic_phase(step, k)).sin_cos();
            self.blocks[block].step_re[i] = c;
            self.blocks[block].step_im[i] = -s;
        }
    }

    /// [`tune_steps`](Self::tune_steps) for an oscillator that moved while running: each
    /// lane's step as a power of the oscillator's own (one `sin_cos`, not one a lane;
    /// within a few 1e-15 of `tune_steps`'). No allocation.
    fn follow_steps(&mut self, oscillator: Oscillator, word: u64) {
        let step = word.wrapping_mul(PREDECIMATION as u64);
        let (s, c) = phase_to_radians(step).sin_cos();
        let base = Complex64::new(c, -s);
        let mut powers = HarmonicPowers::default();
        for (l, (&k, &o)) in self.harmonic.iter().zip(&self.oscillator).enumerate() {
            if o != oscillator {
                continue;
            }
            let p = powers.of(o as usize, base, k);
            let (block, i) = (l / BLOCK, l % BLOCK);
            self.blocks[block].step_re[i] = p.re;
            self.blocks[block].step_im[i] = p.im;
        }
    }

    /// [`tune`](Self::tune) for an oscillator that moved while running: each of its lanes'
    /// mixing phasors e^{ikωu} by recurrence from one `sin_cos` (31 complex products, within
    /// a few 1e-15 of `tune`'s), so a PLL whose drive wanders costs the DSP thread about 32
    /// `sin_cos` a retune, not 10³. No allocation.
    fn retune(&mut self, oscillator: Oscillator, word: u64) {
        self.set_taps_word(oscillator, word);
        for l in 0..self.harmonic.len() {
            if self.oscillator[l] != oscillator {
                continue;
            }
            let (k, g) = (self.harmonic[l], self.gain[l]);
            let (block, i) = (l / BLOCK, l % BLOCK);
            let rows = &mut self.coef[block * (HALF + 1)..][..HALF + 1];
            let (s, c) = phase_to_radians(harmonic_phase(word, k)).sin_cos();
            let turn = Complex64::new(c, s);
            let mut phasor = Complex64::new(1.0, 0.0);
            for (h, row) in self.taps.iter().zip(rows) {
                row.0[0][i] = g * h * phasor.re;
                row.0[1][i] = g * h * phasor.im;
                phasor *= turn;
            }
        }
        self.follow_steps(oscillator, word);
    }

    /// Recompute everything of `oscillator`'s lanes that depends on its frequency word (no
    /// allocation).
    fn tune(&mut self, oscillator: Oscillator, word: u64) {
        self.set_taps_word(oscillator, word);
        for l in 0..self.harmonic.len() {
            if self.oscillator[l] != oscillator {
                continue;
            }
            let (k, g) = (self.harmonic[l], self.gain[l]);
            let (block, i) = (l / BLOCK, l % BLOCK);
            let rows = &mut self.coef[block * (HALF + 1)..][..HALF + 1];
            for (u, (h, row)) in self.taps.iter().zip(rows).enumerate() {
                let theta = phase_to_radians(harmonic_phase(word.wrapping_mul(u as u64), k));
                let (s, c) = theta.sin_cos();
                row.0[0][i] = g * h * c;
                row.0[1][i] = g * h * s;
            }
        }
        self.tune_steps(oscillator, word);
    }
}

/// Powers z^k of one phasor per oscillator for lanes in turn: the next harmonic up is one
/// product from the last lane's power (the banks' harmonics mostly run 1, 2, 3, …), any
/// other is taken by squaring. Each within a few 1e-15 of e^{ikφ} by `sin_cos`.
#[derive(Default)]
struct HarmonicPowers {
    /// The last harmonic and its power, per oscillator (0: none yet).
    last: [(u32, Complex64); 2],
}

impl HarmonicPowers {
    fn of(&mut self, oscillator: usize, base: Complex64, k: u32) -> Complex64 {
        let (last_k, last) = self.last[oscillator];
        let power = if last_k > 0 && k == last_k + 1 {
            last * base
        } else if last_k > 0 && k == last_k {
            last
        } else {
            base.powu(k)
        };
        self.last[oscillator] = (k, power);
        power
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Powers by products against `sin_cos` of the harmonic's phase: harmonics in a run, a
    /// jump, a repeat and one high harmonic.
    #[test]
    fn harmonic_powers_match_sin_cos() {
        let phase: u64 = 0x1357_9bdf_2468_ace0;
        let (s, c) = phase_to_radians(phase).sin_cos();
        let base = Complex64::new(c, -s);
        let mut powers = HarmonicPowers::default();
        for k in [0u32, 1, 2, 3, 7, 8, 8, 31, 32, 1000, 10_000] {
            let (s, c) = phase_to_radians(harmonic_phase(phase, k)).sin_cos();
            let exact = Complex64::new(c, -s);
            let p = powers.of(0, base, k);
            assert!((p - exact).norm() < 1e-12, "k = {k}: {p} against {exact}");
        }
    }

    fn tone(n: usize, fs: f64, f: f64, amp: f64, phase: f64) -> Vec<f64> {
        let r = f / fs;
        (0..n)
            .map(|m| amp * (std::f64::consts::TAU * (m as f64 * r).fract() + phase).cos())
            .collect()
    }

    fn last_outputs(bank: &mut LockInBank, input: &[f64]) -> Vec<LockInSample> {
        let mut last = vec![None; MAX_DEMODULATORS];
        bank.process(input, |s| last[s.demod] = Some(s));
        last.into_iter().flatten().collect()
    }

    #[test]
    fn reads_a_tone_with_both_kernels() {
        let fs = 10e6;
        let fd = 100.0123e3;
        let demods = [
            Demodulator::new(1, 4, 100e-6, 10e3),
            Demodulator::new(3, 4, 100e-6, 10e3),
        ];
        let mut x = tone(200_000, fs, fd, 2.0, 0.3);
        for (m, v) in tone(200_000, fs, 3.0 * fd, 0.5, -1.2).iter().enumerate() {
            x[m] += v;
        }
        for portable in [false, true] {
            let mut bank = LockInBank::new(fs, fd, &demods).unwrap();
            if portable {
                bank = bank.with_portable_kernel();
            }
            let out = last_outputs(&mut bank, &x);
            assert_eq!(out.len(), 2);
            assert!((out[0].r() - 2.0).abs() < 1e-6, "{:?}", out[0]);
            assert!((out[0].phase() - 0.3).abs() < 1e-6);
            assert!((out[1].r() - 0.5).abs() < 1e-6, "{:?}", out[1]);
            assert!((out[1].phase() + 1.2).abs() < 1e-6);
        }
    }

    #[test]
    fn a_drive_moved_by_a_little_keeps_its_taps_and_reads_as_exact_taps_do() {
        // A tone at fd + 2 Hz read at harmonics 1 and 32 by a bank tuned to fd and then
        // aligned to the tone's word (a PLL's small step: the taps stay, the steps follow),
        // against a bank built at the tone's frequency (exact taps).
        let fs = 10e6;
        let fd = 100.0123e3;
        let f = fd + 2.0;
        let demods = [
            Demodulator::new(1, 4, 100e-6, 10e3),
            Demodulator::new(32, 4, 100e-6, 10e3),
        ];
        let mut x = tone(200_000, fs, f, 2.0, 0.3);
        for (m, v) in tone(200_000, fs, 32.0 * f, 0.5, -1.2).iter().enumerate() {
            x[m] += v;
        }
        let exact = last_outputs(&mut LockInBank::new(fs, f, &demods).unwrap(), &x);
        let mut moved = LockInBank::new(fs, fd, &demods).unwrap();
        let word = PhaseAccumulator::new(f, fs).unwrap().frequency_word();
        moved.align_drive(0, word);
        assert_eq!(moved.retunes(), 1, "the taps stay on the first tuning");
        let kept = last_outputs(&mut moved, &x);
        for (a, b) in kept.iter().zip(&exact) {
            let gain = a.r() / b.r() - 1.0;
            let phase = a.phase() - b.phase();
            assert!(gain.abs() < 1e-6, "harmonic {}: gain {gain:e}", a.harmonic);
            assert!(
                phase.abs() < 1e-9,
                "harmonic {}: phase {phase:e}",
                a.harmonic
            );
        }
        // Far enough, the taps are recomputed (by recurrence): as a bank built there.
        let g = fd + 100.0;
        let far = PhaseAccumulator::new(g, fs).unwrap().frequency_word();
        let mut x = tone(200_000, fs, g, 2.0, 0.3);
        for (m, v) in tone(200_000, fs, 32.0 * g, 0.5, -1.2).iter().enumerate() {
            x[m] += v;
        }
        let mut retuned = LockInBank::new(fs, fd, &demods).unwrap();
        retuned.align_drive(0, far);
        assert_eq!(retuned.retunes(), 2);
        let exact = last_outputs(&mut LockInBank::new(fs, g, &demods).unwrap(), &x);
        for (a, b) in last_outputs(&mut retuned, &x).iter().zip(&exact) {
            assert!((a.r() / b.r() - 1.0).abs() < 1e-12, "{a:?} {b:?}");
            assert!((a.phase() - b.phase()).abs() < 1e-12, "{a:?} {b:?}");
        }
    }

    /// Runs `bank` over `x` in blocks of 4096 samples, aligned at each block to the drive
    /// (`word`, or `stepped` from sample `step` on, phase-continuous as a PLL moves it) and to
    /// the second excitation (`word2`), as the DSP thread does from the block headers; the
    /// drive's step lands inside a block, as a reference change does. Returns every output.
    fn run_blocks(
        bank: &mut LockInBank,
        x: &[f64],
        (word, stepped, step): (u64, u64, usize),
        word2: u64,
    ) -> Vec<LockInSample> {
        let drive_phase = |m: usize| {
            if m <= step {
                word.wrapping_mul(m as u64)
            } else {
                let at_step = word.wrapping_mul(step as u64);
                at_step.wrapping_add(stepped.wrapping_mul((m - step) as u64))
            }
        };
        let drive_word = |m: usize| if m < step { word } else { stepped };
        let mut out = Vec::new();
        let mut start = 0;
        while start < x.len() {
            let end = (start + 4096).min(x.len());
            bank.align_drive(drive_phase(start), drive_word(start));
            bank.align_drive2(word2.wrapping_mul(start as u64), word2);
            if (start + 1..end).contains(&step) {
                bank.process(&x[start..step], |s| out.push(s));
                bank.align_drive(drive_phase(step), stepped);
                bank.process(&x[step..end], |s| out.push(s));
            } else {
                bank.process(&x[start..end], |s| out.push(s));
            }
            start = end;
        }
        out
    }

    #[test]
    fn a_demodulator_on_drive2_reads_its_tone_and_ignores_the_drives_pll() {
        // A·cos θ₁ + B·cos(θ₂ + φ), f₂ incommensurate with f₁; the drive steps by 40 Hz at
        // sample `step` (a PLL's reference change) and the signal's first tone with it.
        let (fs, f1, f2) = (10e6, 100e3, 626.689e3);
        let (a, b, phi) = (2.0, 0.5, 0.7);
        let word = PhaseAccumulator::new(f1, fs).unwrap().frequency_word();
        let stepped = PhaseAccumulator::new(f1 + 40.0, fs)
            .unwrap()
            .frequency_word();
        let word2 = PhaseAccumulator::new(f2, fs).unwrap().frequency_word();
        let (n, step) = (300_000, 100_003);
        let signal = |pll: bool| -> Vec<f64> {
            let theta = |w: u64, m: u64| phase_to_radians(w.wrapping_mul(m));
            (0..n)
                .map(|m| {
                    let theta1 = if pll && m > step {
                        let at_step = word.wrapping_mul(step as u64);
                        phase_to_radians(
                            at_step.wrapping_add(stepped.wrapping_mul((m - step) as u64)),
                        )
                    } else {
                        theta(word, m as u64)
                    };
                    a * theta1.cos() + b * (theta(word2, m as u64) + phi).cos()
                })
                .collect()
        };
        let demods = [
            Demodulator::new(1, 4, 100e-6, 10e3),
            Demodulator::new(1, 4, 100e-6, 10e3).on(Oscillator::Drive2),
        ];
        let last = |out: &[LockInSample], demod: usize| {
            *out.iter().rev().find(|s| s.demod == demod).unwrap()
        };
        let mut results = Vec::new();
        // Without and with the step.
        for pll in [false, true] {
            let stepped = if pll { stepped } else { word };
            let mut bank = LockInBank::with_drive2(fs, f1, f2, &demods).unwrap();
            let out = run_blocks(&mut bank, &signal(pll), (word, stepped, step), word2);
            let (d1, d2) = (last(&out, 0), last(&out, 1));
            assert_eq!(d2.oscillator, Oscillator::Drive2);
            assert_eq!(d1.oscillator, Oscillator::Drive);
            assert!(
                (d1.x - a).abs() < 1e-6 * a && d1.y.abs() < 1e-6 * a,
                "{d1:?}"
            );
            let (x, y) = (b * phi.cos(), b * phi.sin());
            assert!(
                (d2.x - x).abs() < 1e-6 * b && (d2.y - y).abs() < 1e-6 * b,
                "{d2:?}"
            );
            results.push(out);
        }
        // The same stepped signal through a bank whose drive reference stays put: its
        // drive2 demodulator's outputs are those of the bank that followed the step, bit
        // for bit, all along; its drive demodulator's are not (the reference runs 40 Hz
        // from the first tone, whose phasor turns by 2π·40 Hz·t).
        let mut frozen = LockInBank::with_drive2(fs, f1, f2, &demods).unwrap();
        let out = run_blocks(&mut frozen, &signal(true), (word, word, step), word2);
        let on = |out: &[LockInSample], demod: usize| -> Vec<(u64, u64, u64)> {
            out.iter()
                .filter(|s| s.demod == demod)
                .map(|s| (s.sample_index, s.x.to_bits(), s.y.to_bits()))
                .collect()
        };
        assert!(on(&out, 1).len() > 200);
        assert_eq!(on(&out, 1), on(&results[1], 1));
        let d1 = last(&out, 0);
        assert!(
            (d1.x - a).abs() > 1e-3 * a || d1.y.abs() > 1e-3 * a,
            "{d1:?}"
        );
    }

    #[test]
    fn lanes_on_drive2_leave_the_drive_lanes_bit_for_bit() {
        // The drive's lanes of a bank with lanes on /drive2 beside them compute what a bank
        // of the drive's lanes alone does, bit for bit, through a PLL's step.
        let (fs, f1, f2) = (10e6, 100.0123e3, 626.689e3);
        let word = PhaseAccumulator::new(f1, fs).unwrap().frequency_word();
        let stepped = PhaseAccumulator::new(f1 + 300.0, fs)
            .unwrap()
            .frequency_word();
        let word2 = PhaseAccumulator::new(f2, fs).unwrap().frequency_word();
        let mut x = tone(120_000, fs, f1, 2.0, 0.3);
        for (m, v) in tone(120_000, fs, f2, 0.5, -1.2).iter().enumerate() {
            x[m] += v;
        }
        let drive: Vec<Demodulator> = (0..20)
            .map(|i| Demodulator::new(i, 1 + i % 8, 50e-6, 20e3))
            .collect();
        // Interleaved: lanes on /drive2 between the drive's, in the same blocks of lanes.
        let mut mixed = drive.clone();
        for k in 1..=5 {
            mixed.insert(
                3 * k as usize,
                Demodulator::new(k, 3, 50e-6, 20e3).on(Oscillator::Drive2),
            );
        }
        let both: Vec<Demodulator> = mixed
            .iter()
            .map(|d| Demodulator {
                enable: d.oscillator == Oscillator::Drive,
                ..*d
            })
            .collect();
        let keep = |out: Vec<LockInSample>| -> Vec<_> {
            out.into_iter()
                .filter(|s| s.oscillator == Oscillator::Drive)
                .map(|s| (s.demod, s.sample_index, s.x.to_bits(), s.y.to_bits()))
                .collect()
        };
        let alone = keep(run_blocks(
            &mut LockInBank::with_drive2(fs, f1, f2, &both).unwrap(),
            &x,
            (word, stepped, 70_001),
            word2,
        ));
        let beside = keep(run_blocks(
            &mut LockInBank::with_drive2(fs, f1, f2, &mixed).unwrap(),
            &x,
            (word, stepped, 70_001),
            word2,
        ));
        assert!(alone.len() > 1000, "{} outputs", alone.len());
        assert_eq!(alone, beside);
    }

    #[test]
    fn the_avx512_kernel_is_the_avx2_kernel_bit_for_bit() {
        let fs = 10e6;
        let fd = 100.0123e3;
        // 32 demodulators (two blocks), every filter order, outputs at several rates.
        let demods: Vec<Demodulator> = (0..32)
            .map(|i| {
                Demodulator::new(
                    i + 1,
                    1 + i % 8,
                    20e-6 * f64::from(1 + i % 5),
                    1e3 * f64::from(1 + i % 7),
                )
            })
            .collect();
        let mut x = tone(150_000, fs, fd, 2e-8, 0.3);
        for (m, v) in tone(150_000, fs, 17.0 * fd, 3e-11, -1.2).iter().enumerate() {
            x[m] += v + 1e-12 * ((m * 7919 % 1000) as f64 - 500.0);
        }
        let wide = LockInBank::new(fs, fd, &demods).unwrap();
        if wide.kernel() != "avx512" {
            eprintln!("no AVX-512 here ({}): nothing to compare", wide.kernel());
            return;
        }
        let narrow = LockInBank::new(fs, fd, &demods).unwrap().with_avx2_kernel();
        assert_eq!(narrow.kernel(), "avx2+fma");
        let run = |mut bank: LockInBank| {
            let mut out = Vec::new();
            // Blocks of uneven lengths, as the ring hands them over.
            for chunk in x.chunks(4093) {
                bank.process(chunk, |s| {
                    out.push((s.demod, s.sample_index, s.x.to_bits(), s.y.to_bits()))
                });
            }
            out
        };
        let (a, b) = (run(wide), run(narrow));
        assert!(a.len() > 1000, "{} outputs", a.len());
        assert_eq!(a, b);
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn passes_of_several_samples_are_one_sample_at_a_time_bit_for_bit() {
        let (fs, fd) = (10e6, 100.0123e3);
        // Two blocks, every filter order, outputs at several rates (passes cut short by
        // outputs), a drive moved as a PLL moves it at every block and once inside one
        // (re-anchorings off the periodic ones), and the boxcar read at every block.
        let demods: Vec<Demodulator> = (0..32)
            .map(|i| {
                Demodulator::new(
                    i + 1,
                    1 + i % 8,
                    20e-6 * f64::from(1 + i % 5),
                    1e3 * f64::from(1 + i % 7) + 37.0 * f64::from(i % 3),
                )
            })
            .collect();
        let mut x = tone(120_000, fs, fd, 2e-8, 0.3);
        for (m, v) in tone(120_000, fs, 17.0 * fd, 3e-11, -1.2).iter().enumerate() {
            x[m] += v + 1e-12 * ((m * 7919 % 1000) as f64 - 500.0);
        }
        let probe = LockInBank::new(fs, fd, &demods).unwrap();
        if probe.kernel() != "avx512" {
            eprintln!("no AVX-512 here ({}): nothing to compare", probe.kernel());
            return;
        }
        let word = probe.drive().frequency_word();
        let run = |one_at_a_time: bool| {
            let mut bank = LockInBank::new(fs, fd, &demods).unwrap();
            let mut out = Vec::new();
            let mut start = 0;
            // Blocks of uneven lengths, some shorter than a decimated sample.
            for (b, len) in [4093, 3, 17, 5000, 1, 4096, 777].iter().cycle().enumerate() {
                if start >= x.len() {
                    break;
                }
                let end = (start + len).min(x.len());
                let w = word.wrapping_add((b % 5) as u64 * 1_000_003);
                bank.align_drive(w.wrapping_mul(start as u64), w);
                let mut push = |s: LockInSample| {
                    out.push((s.demod, s.sample_index, s.x.to_bits(), s.y.to_bits()))
                };
                if one_at_a_time {
                    bank.process_one_step_at_a_time(&x[start..end], &mut push);
                } else {
                    bank.process(&x[start..end], &mut push);
                }
                bank.take_integrals(|d, _, _, x, y| out.push((d, 0, x.to_bits(), y.to_bits())));
                start = end;
            }
            out
        };
        let (a, b) = (run(false), run(true));
        assert!(a.len() > 1000, "{} outputs", a.len());
        assert_eq!(a, b);
    }

    #[test]
    fn the_kernel_reads_its_lanes_from_whole_cache_lines() {
        // A vector load that splits across two lines costs the bank up to a quarter of its
        // speed (docs/benchmarks.md), so the heap's 16-byte alignment is not enough.
        let bank = LockInBank::new(10e6, 1e5, &[Demodulator::new(1, 4, 1e-4, 1e3); 32]).unwrap();
        let line = |p: *const u8| p as usize % 64;
        assert_eq!(line(bank.plan.coef.as_ptr().cast()), 0);
        assert_eq!(line(bank.plan.blocks.as_ptr().cast()), 0);
        assert_eq!(line(bank.state.blocks.as_ptr().cast()), 0);
        assert!(align_of::<Row>() >= 64 && align_of::<BlockState>() >= 64);
        assert!(align_of::<BlockConstants>() >= 64);
    }

    #[test]
    fn blocks_can_move_to_the_real_time_thread() {
        fn send<T: Send + 'static>() {}
        send::<LockInBank>();
        send::<crate::dsp::SlidingSpectrum>();
    }

    #[test]
    fn output_rate_is_quantised_to_the_decimated_rate() {
        let bank = LockInBank::new(10e6, 100e3, &[Demodulator::new(1, 1, 1e-3, 3e3)]).unwrap();
        let period = (625e3f64 / 3e3).round();
        assert_eq!(bank.output_rate(0), Some(625e3 / period));
        assert_eq!(bank.output_rate(1), None);
    }

    #[test]
    fn rejects_bad_settings_naming_the_demodulator() {
        let mut d = [Demodulator::new(1, 4, 1e-4, 1e3); 3];
        d[2].order = 9;
        assert!(matches!(
            LockInBank::new(10e6, 1e5, &d),
            Err(DspError::Demodulator { index: 2, .. })
        ));
        d[2].enable = false;
        assert!(LockInBank::new(10e6, 1e5, &d).is_ok());
        assert!(LockInBank::new(10e6, 1e5, &[d[0]; 33]).is_err());
    }
}
