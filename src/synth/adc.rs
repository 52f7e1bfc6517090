//! The ADC's anti-alias filter, modelled on an oversampling (sigma-delta) converter's
//! decimation chain, so that what lies above the Nyquist frequency does not fold onto the
//! harmonics.
//!
//! The model, at output rate f_s (docs/signal-chain.md states it for users):
//! - the signal is integrated over a triangle window of half-width h/2 and taken at twice
//!   the sample rate, at t_n and at the midpoints t_n + h/2 (the modulator's second-order
//!   sinc decimator: gain sinc²(f/2f_s), zero at every multiple of 2·f_s; exact, from the
//!   modal states at the knots and the input's moments, [`super::window`]);
//! - a halfband FIR of [`TAPS`] taps at 2·f_s (Kaiser window, β = [`KAISER_BETA`]) keeps
//!   0 … 0.4·f_s within ±4e-5 in amplitude and stops 0.6·f_s … 1.4·f_s by ≥ 88 dB
//!   (measured in this module's tests: 3.4e-5 both); 0.5·f_s is attenuated by 6 dB;
//! - a droop compensator of [`COMPENSATOR_TAPS`] taps at f_s undoes the window's sinc² in
//!   the passband: the whole chain is flat to ±4e-5 from DC (exact) to 0.4·f_s and ≥ 88 dB
//!   down from 0.6·f_s on;
//! - it is linear-phase with a delay of [`DELAY_HALF_SAMPLES`]/2 output samples: output
//!   sample n is the filtered signal at t_n − D, D = 21.5/f_s (2.15 µs at 10 MS/s). The
//!   synthesiser stamps each block with the drive phase at t_n − D, so the lock-in, the
//!   scope's drive phase and everything downstream see no phase shift from it;
//! - detector noise and quantisation act after it, at f_s.
//!
//! What still aliases: content near 2·f_s, 4·f_s, … (within 0.4·f_s of them), which folds
//! into the passband when the 2·f_s samples are taken, attenuated by the window (27× and
//! more for what lands below 0.3·f_s); the lock-in test in tests/physics_inversion.rs
//! measures what is left.

/// Half-length K of the halfband: [`TAPS`] = 4K + 3.
const K: usize = 14;
/// Taps of the halfband FIR at twice the sample rate (odd taps but the centre are zero).
pub const TAPS: usize = 4 * K + 3;
/// Non-zero taps on the grid samples t_n (the centre tap, 1/2, is on a midpoint).
pub const GRID_TAPS: usize = 2 * K + 2;
/// Grid samples of history the filter keeps.
pub const GRID_HISTORY: usize = GRID_TAPS - 1;
/// Midpoint samples of history: the centre tap reads the midpoint K + 1 samples back.
pub const MID_HISTORY: usize = K + 1;
/// Half-length of the droop compensator: [`COMPENSATOR_TAPS`] = 2M + 1.
const M: usize = 7;
/// Taps of the droop compensator at f_s.
pub const COMPENSATOR_TAPS: usize = 2 * M + 1;
/// Outputs of history the compensator keeps.
pub const COMPENSATOR_HISTORY: usize = 2 * M;
/// The compensator's taps c_1 … c_M (symmetric: c_{−k} = c_k; c_0 = 1 − 2Σc_k, so its
/// DC gain is 1). A minimax fit (iteratively reweighted least squares on 0 … 0.4·f_s, DC
/// held) of sinc²(f/2)·halfband(f)·C(f) to 1: ±3.9e-5.
const COMPENSATOR: [f64; M] = [
    -4.393_311_765_927_654e-2,
    1.083_741_392_488_644_4e-2,
    -3.996_672_214_529_688e-3,
    1.665_992_840_745_283_8e-3,
    -6.886_891_514_883_628e-4,
    2.650_139_533_494_703_6e-4,
    -8.092_994_835_745_474e-5,
];
/// The whole chain's delay in half output samples: the halfband's 2K + 1 and the
/// compensator's 2M, D = 21.5 samples.
pub const DELAY_HALF_SAMPLES: u64 = 2 * K as u64 + 1 + 2 * M as u64;
/// Kaiser window parameter: β = 0.1102·(A − 8.7) for a design attenuation A = 90 dB.
pub const KAISER_BETA: f64 = 0.1102 * (90.0 - 8.7);

/// Drive phase word `D` before `phase`, for a drive of `frequency_word` words per sample:
/// the phase at which an output sample was taken (exact modulo 2^64).
pub fn delayed_phase(phase: u64, frequency_word: u64) -> u64 {
    let delay = (u128::from(frequency_word) * u128::from(DELAY_HALF_SAMPLES)) >> 1;
    phase.wrapping_sub(delay as u64)
}

/// The grid taps c_{2i}, i = 0 … 2K + 1, of the halfband; the centre tap is 1/2.
pub fn grid_taps() -> [f64; GRID_TAPS] {
    let centre = (2 * K + 1) as f64;
    let half = centre;
    let mut taps = [0.0; GRID_TAPS];
    for (i, tap) in taps.iter_mut().enumerate() {
        let x = 2.0 * i as f64 - centre; // odd, so the sinc is not at its centre
        let sinc = (std::f64::consts::FRAC_PI_2 * x).sin() / (std::f64::consts::PI * x);
        let r = x / half;
        *tap =
            sinc * bessel_i0(KAISER_BETA * (1.0 - r * r).max(0.0).sqrt()) / bessel_i0(KAISER_BETA);
    }
    // DC gain exactly 1: the grid taps carry one half, the centre tap the other.
    let sum: f64 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t *= 0.5 / sum);
    taps
}

/// The modified Bessel function I₀ by its power series (converges for every argument
/// used here, β ≤ 10, to machine precision in < 40 terms).
fn bessel_i0(x: f64) -> f64 {
    let mut term = 1.0;
    let mut sum = 1.0;
    let q = 0.25 * x * x;
    for k in 1..60 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

/// The compensator's taps c_0 … c_M.
fn compensator_taps() -> [f64; M + 1] {
    let mut c = [0.0; M + 1];
    c[1..].copy_from_slice(&COMPENSATOR);
    c[0] = 1.0 - 2.0 * COMPENSATOR.iter().sum::<f64>();
    c
}

/// Gain of the whole front end at `frequency` f/f_s of a component before sampling (any
/// frequency, aliases included), its delay removed: the window's sinc², the halfband's
/// and the compensator's gains. Real; 1 at DC.
pub fn gain(taps: &[f64; GRID_TAPS], frequency: f64) -> f64 {
    super::window::gain(frequency) * halfband_gain(taps, frequency) * compensator_gain(frequency)
}

/// Gain of the droop compensator at `frequency` f/f_s: c_0 + 2Σ c_k·cos(2πkf).
pub fn compensator_gain(frequency: f64) -> f64 {
    let c = compensator_taps();
    let mut g = c[0];
    for (k, ck) in c.iter().enumerate().skip(1) {
        g += 2.0 * ck * (std::f64::consts::TAU * frequency * k as f64).cos();
    }
    g
}

/// Gain of the halfband at `frequency` f/f_s (cycles per output sample), its delay
/// removed: real, 1 at DC, 1/2 at f_s/2.
pub fn halfband_gain(taps: &[f64; GRID_TAPS], frequency: f64) -> f64 {
    // Grid tap i sits at 2i − (2K + 1) half samples from the centre.
    let mut g = 0.5;
    for (i, c) in taps.iter().enumerate() {
        let offset = (2 * i) as f64 - (2 * K + 1) as f64;
        g += c * (std::f64::consts::PI * frequency * offset).cos();
    }
    g
}

/// ADC model: quantisation step and clipping level, applied after the filter with the
/// detector noise ([`super::digitiser`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adc {
    /// Least significant bit (m).
    pub lsb: f64,
    /// Full scale: samples are clipped to ±range (m).
    pub range: f64,
    /// 1/lsb (1/m).
    pub codes_per_metre: f64,
}

/// The signal through the ADC's window at grid sample n and at midpoint n + ½ ([`super::window`]),
/// before the FIRs; with the filter off, `grid` is the sample itself. What the synthesiser
/// hands to the thread that finishes the ADC ([`super::digitiser`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WindowSample {
    /// At the grid sample t_n (m).
    pub grid: f64,
    /// At the midpoint t_n + h/2 (m).
    pub mid: f64,
}

/// What the filter's next output needs of the past ([`AdcFilter::history`]): the last
/// grid samples and midpoints, and the halfband's last outputs (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdcHistory {
    /// The last [`GRID_HISTORY`] grid samples, oldest first.
    pub grid: [f64; GRID_HISTORY],
    /// The last [`MID_HISTORY`] midpoints, oldest first.
    pub mid: [f64; MID_HISTORY],
    /// The halfband's last [`COMPENSATOR_HISTORY`] outputs, oldest first.
    pub compensator: [f64; COMPENSATOR_HISTORY],
}

/// The filter's state: the grid and midpoint samples of the current chunk behind their
/// histories. Allocated once, off the real-time thread.
#[derive(Clone, Debug)]
pub struct AdcFilter {
    /// [`GRID_HISTORY`] past grid samples, then the chunk's.
    pub(crate) grid: Vec<f64>,
    /// [`MID_HISTORY`] past midpoints, then the chunk's.
    pub(crate) mid: Vec<f64>,
    /// [`COMPENSATOR_HISTORY`] past halfband outputs, then the chunk's.
    compensator: Vec<f64>,
    /// The compensator's taps c_0 … c_M.
    compensator_taps: [f64; M + 1],
    /// The widest kernel the CPU runs.
    kernel: Kernel,
}

/// The builds of [`AdcFilter::decimate`]. The fused ones give the same bits as each
/// other (the same fused multiply-adds in the same order per output); the portable one's
/// last bits differ from theirs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kernel {
    Portable,
    /// AVX2 and FMA: thirty-two outputs in [`ACCUMULATORS`] registers, the taps streamed
    /// past them.
    Avx2Fma,
    /// AVX-512: sixty-four outputs in [`ACCUMULATORS`] registers.
    Avx512,
}

impl Kernel {
    fn detect() -> Self {
        if crate::cpu::avx512_available() && crate::cpu::fma_available() {
            Self::Avx512
        } else if crate::cpu::fma_available() {
            Self::Avx2Fma
        } else {
            Self::Portable
        }
    }
}

/// Registers of outputs the fused kernels accumulate at once. Each output is a chain of
/// dependent multiply-adds (31 for the halfband), so the kernels wait on the multiply-add's
/// latency (4 cycles on Zen 3 to Zen 5) unless enough chains run side by side to keep its
/// two pipes busy: 2 × 4 = 8. Fits AVX2's sixteen registers with the tap and the loaded
/// samples.
#[cfg(target_arch = "x86_64")]
const ACCUMULATORS: usize = 8;

/// A vector of f64 for the fused kernels. Its functions are for code compiled with the
/// vector's instructions, on a CPU that has them.
#[cfg(target_arch = "x86_64")]
trait FusedVector: Copy {
    /// Lanes.
    const WIDTH: usize;
    /// The `WIDTH` values from `p` on, which must all be readable: for loops whose
    /// bounds were checked once for all their loads.
    unsafe fn load_ptr(p: *const f64) -> Self;
    /// Writes the lanes to the first `WIDTH` of `x` (at least that long).
    unsafe fn store(self, x: &mut [f64]);
    unsafe fn splat(c: f64) -> Self;
    unsafe fn mul(self, o: Self) -> Self;
    unsafe fn add(self, o: Self) -> Self;
    /// `self·a + b`, rounded once.
    unsafe fn mul_add(self, a: Self, b: Self) -> Self;
}

#[cfg(target_arch = "x86_64")]
mod fused {
    use super::FusedVector;
    use std::arch::x86_64::*;

    // SAFETY (all): the slices are sliced to WIDTH first (bounds-checked); the CPU's
    // instructions are the caller's promise (the trait's documentation).
    impl FusedVector for __m256d {
        const WIDTH: usize = 4;
        #[inline(always)]
        unsafe fn load_ptr(p: *const f64) -> Self {
            unsafe { _mm256_loadu_pd(p) }
        }
        #[inline(always)]
        unsafe fn store(self, x: &mut [f64]) {
            unsafe { _mm256_storeu_pd(x[..4].as_mut_ptr(), self) }
        }
        #[inline(always)]
        unsafe fn splat(c: f64) -> Self {
            unsafe { _mm256_set1_pd(c) }
        }
        #[inline(always)]
        unsafe fn mul(self, o: Self) -> Self {
            unsafe { _mm256_mul_pd(self, o) }
        }
        #[inline(always)]
        unsafe fn add(self, o: Self) -> Self {
            unsafe { _mm256_add_pd(self, o) }
        }
        #[inline(always)]
        unsafe fn mul_add(self, a: Self, b: Self) -> Self {
            unsafe { _mm256_fmadd_pd(self, a, b) }
        }
    }

    impl FusedVector for __m512d {
        const WIDTH: usize = 8;
        #[inline(always)]
        unsafe fn load_ptr(p: *const f64) -> Self {
            unsafe { _mm512_loadu_pd(p) }
        }
        #[inline(always)]
        unsafe fn store(self, x: &mut [f64]) {
            unsafe { _mm512_storeu_pd(x[..8].as_mut_ptr(), self) }
        }
        #[inline(always)]
        unsafe fn splat(c: f64) -> Self {
            unsafe { _mm512_set1_pd(c) }
        }
        #[inline(always)]
        unsafe fn mul(self, o: Self) -> Self {
            unsafe { _mm512_mul_pd(self, o) }
        }
        #[inline(always)]
        unsafe fn add(self, o: Self) -> Self {
            unsafe { _mm512_add_pd(self, o) }
        }
        #[inline(always)]
        unsafe fn mul_add(self, a: Self, b: Self) -> Self {
            unsafe { _mm512_fmadd_pd(self, a, b) }
        }
    }
}

impl AdcFilter {
    /// A filter for chunks of up to `chunk` samples, its history filled by `past(j)`,
    /// the signal j half samples before the first output (j = 1, 2, …).
    pub fn new(chunk: usize, past: impl Fn(usize) -> f64) -> Self {
        let mut grid = vec![0.0; GRID_HISTORY + chunk];
        let mut mid = vec![0.0; MID_HISTORY + chunk];
        for (i, g) in grid[..GRID_HISTORY].iter_mut().enumerate() {
            *g = past(2 * (GRID_HISTORY - i));
        }
        for (i, m) in mid[..MID_HISTORY].iter_mut().enumerate() {
            *m = past(2 * (MID_HISTORY - i) - 1);
        }
        // The halfband's past outputs: the signal its delay before each earlier output.
        let mut compensator = vec![0.0; COMPENSATOR_HISTORY + chunk];
        for (i, c) in compensator[..COMPENSATOR_HISTORY].iter_mut().enumerate() {
            *c = past(2 * (COMPENSATOR_HISTORY - i) + 2 * K + 1);
        }
        Self {
            grid,
            mid,
            compensator,
            compensator_taps: compensator_taps(),
            kernel: Kernel::detect(),
        }
    }

    /// What the next output needs of the past: the histories at the chunk's start.
    pub fn history(&self) -> AdcHistory {
        AdcHistory {
            grid: std::array::from_fn(|i| self.grid[i]),
            mid: std::array::from_fn(|i| self.mid[i]),
            compensator: std::array::from_fn(|i| self.compensator[i]),
        }
    }

    /// Continues from `history` (another filter's [`history`](Self::history)).
    pub fn set_history(&mut self, history: &AdcHistory) {
        self.grid[..GRID_HISTORY].copy_from_slice(&history.grid);
        self.mid[..MID_HISTORY].copy_from_slice(&history.mid);
        self.compensator[..COMPENSATOR_HISTORY].copy_from_slice(&history.compensator);
    }

    /// The longest chunk the filter takes at once.
    pub fn chunk(&self) -> usize {
        self.grid.len() - GRID_HISTORY
    }

    /// The next `n` grid samples and midpoints, to be written before a
    /// [`decimate`](Self::decimate) or [`pass`](Self::pass) of `n` outputs.
    pub(crate) fn chunk_mut(&mut self, n: usize) -> (&mut [f64], &mut [f64]) {
        (
            &mut self.grid[GRID_HISTORY..GRID_HISTORY + n],
            &mut self.mid[MID_HISTORY..MID_HISTORY + n],
        )
    }

    /// Hands the `out.len()` grid and midpoint samples written behind the histories to
    /// `out` unfiltered, for a filter on another thread to take them from this one's
    /// [`history`](Self::history), and keeps the histories as [`decimate`](Self::decimate)
    /// (`taps`) or [`remember`](Self::remember) (no taps) would have, bit for bit: the
    /// halfband's outputs for the compensator's history are its last [`COMPENSATOR_HISTORY`]
    /// outputs, each the same operations in the same order as in the kernels. Inlined, so
    /// that in the synthesiser's loop the fused multiply-adds are instructions, not calls.
    ///
    /// `settle`: whether the histories must hold after this chunk. The grid and midpoint
    /// histories always are; the compensator's (and, without taps, the midpoints derived
    /// from the grid) only where `settle` is set, which the caller must set for every chunk
    /// followed by fewer than [`COMPENSATOR_HISTORY`] samples before the histories are read,
    /// so that the newest halfband outputs are all computed from a settled start.
    #[inline(always)]
    pub(crate) fn pass(
        &mut self,
        taps: Option<&[f64; GRID_TAPS]>,
        out: &mut [WindowSample],
        settle: bool,
    ) {
        let n = out.len();
        for (i, o) in out.iter_mut().enumerate() {
            *o = WindowSample {
                grid: self.grid[GRID_HISTORY + i],
                mid: self.mid[MID_HISTORY + i],
            };
        }
        let Some(taps) = taps else {
            self.grid.copy_within(n..n + GRID_HISTORY, 0);
            if settle {
                self.remembered();
            }
            return;
        };
        if settle {
            let fused = self.kernel != Kernel::Portable;
            for i in n.saturating_sub(COMPENSATOR_HISTORY)..n {
                let mut acc = 0.5 * self.mid[i];
                for (t, &c) in taps.iter().rev().enumerate() {
                    acc = if fused {
                        c.mul_add(self.grid[t + i], acc)
                    } else {
                        acc + c * self.grid[t + i]
                    };
                }
                self.compensator[COMPENSATOR_HISTORY + i] = acc;
            }
            self.compensator.copy_within(n..n + COMPENSATOR_HISTORY, 0);
        }
        self.grid.copy_within(n..n + GRID_HISTORY, 0);
        self.mid.copy_within(n..n + MID_HISTORY, 0);
    }

    /// Keeps the newest of `signal` (grid samples, taken without the filter) as history,
    /// with the midpoints between them interpolated, so that turning the filter on while
    /// running starts from the signal, not from a stale history.
    pub(crate) fn remember(&mut self, signal: &[f64]) {
        let n = signal.len().min(GRID_HISTORY);
        self.grid.copy_within(n..GRID_HISTORY, 0);
        self.grid[GRID_HISTORY - n..GRID_HISTORY].copy_from_slice(&signal[signal.len() - n..]);
        self.remembered();
    }

    /// [`remember`](Self::remember)'s midpoints and compensator history, from the grid
    /// history.
    fn remembered(&mut self) {
        for i in 0..MID_HISTORY {
            let g = GRID_HISTORY - MID_HISTORY + i;
            self.mid[i] = if g + 1 < GRID_HISTORY {
                0.5 * (self.grid[g] + self.grid[g + 1])
            } else {
                // The newest midpoint's right neighbour is not synthesised yet: extrapolate.
                1.5 * self.grid[g] - 0.5 * self.grid[g - 1]
            };
        }
        // The halfband's outputs would have been the signal 14.5 samples earlier.
        for i in 0..COMPENSATOR_HISTORY {
            let g = GRID_HISTORY - 1 - K - i;
            self.compensator[COMPENSATOR_HISTORY - 1 - i] = 0.5 * (self.grid[g] + self.grid[g - 1]);
        }
    }

    /// Filters the `n` grid and midpoint samples written behind the histories into `out`
    /// (`out.len()` = n), then keeps the newest as history. Allocation-free. With AVX2 and
    /// FMA (detected once, at construction) the taps are fused multiply-adds; the last
    /// bits then differ from the portable path's.
    #[inline]
    pub(crate) fn decimate(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64]) {
        match self.kernel {
            // SAFETY: `kernel` names an instruction set only where the CPU has it.
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512 => unsafe { self.decimate_avx512(taps, out) },
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2Fma => unsafe { self.decimate_avx2_fma(taps, out) },
            _ => self.decimate_with::<false>(taps, out),
        }
    }

    /// The droop compensator over the halfband's outputs in `out`, in place, then its
    /// history kept: output i is c_0·x_i + Σ_k c_k·(x_{i−k} + x_{i+k}), the pairs added in
    /// order k = 1 … M, fused (`FUSED`) or not. Tap pair by tap pair over all outputs (the
    /// outputs are independent, so the loop vectorises). Inlined into each kernel, so
    /// that it is compiled for the kernel's instructions.
    #[inline(always)]
    fn compensate<const FUSED: bool>(&mut self, out: &mut [f64]) {
        let n = out.len();
        let x = &mut self.compensator;
        x[COMPENSATOR_HISTORY..COMPENSATOR_HISTORY + n].copy_from_slice(out);
        // Output i is centred on buffer sample i + M.
        let c = &self.compensator_taps;
        for (y, x0) in out.iter_mut().zip(&x[M..M + n]) {
            *y = c[0] * x0;
        }
        for k in 1..=M {
            for (y, (lo, hi)) in out
                .iter_mut()
                .zip(x[M - k..M - k + n].iter().zip(&x[M + k..M + k + n]))
            {
                *y = if FUSED {
                    c[k].mul_add(lo + hi, *y)
                } else {
                    *y + c[k] * (lo + hi)
                };
            }
        }
        x.copy_within(n..n + COMPENSATOR_HISTORY, 0);
    }

    /// [`compensate`](Self::compensate), fused, with [`ACCUMULATORS`] registers of `V`
    /// holding that many times `V::WIDTH` outputs while the tap pairs stream past them,
    /// then the rest one at a time (the same operations in the same order per output, so
    /// the same bits).
    ///
    /// # Safety
    /// The CPU must have `V`'s instructions.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn compensate_fused<V: FusedVector>(&mut self, out: &mut [f64]) {
        let n = out.len();
        let w = V::WIDTH;
        let blocks = n / (ACCUMULATORS * w) * (ACCUMULATORS * w);
        let x = &mut self.compensator;
        x[COMPENSATOR_HISTORY..COMPENSATOR_HISTORY + n].copy_from_slice(out);
        let c = &self.compensator_taps;
        // Output j reads buffer samples j … j + 2M: checked once here for the blocks.
        assert!(blocks + 2 * M <= x.len());
        let buffer = x.as_ptr();
        for i in (0..blocks).step_by(ACCUMULATORS * w) {
            // SAFETY: the CPU has V's instructions (the caller); every load is of `w` f64
            // that the assertion above found inside the buffer (output i + b·w + w − 1 <
            // blocks reads up to blocks − 1 + 2M); the stores are bounds-checked.
            unsafe {
                let at = |j: usize| buffer.add(j);
                let c0 = V::splat(c[0]);
                let mut y: [V; ACCUMULATORS] =
                    std::array::from_fn(|b| c0.mul(V::load_ptr(at(M + i + b * w))));
                for (k, &ck) in c.iter().enumerate().skip(1) {
                    let ck = V::splat(ck);
                    for (b, y) in y.iter_mut().enumerate() {
                        let o = i + b * w;
                        let pair = V::load_ptr(at(M - k + o)).add(V::load_ptr(at(M + k + o)));
                        *y = ck.mul_add(pair, *y);
                    }
                }
                for (b, y) in y.iter().enumerate() {
                    y.store(&mut out[i + b * w..]);
                }
            }
        }
        for (i, y) in out.iter_mut().enumerate().skip(blocks) {
            let mut acc = c[0] * x[M + i];
            for k in 1..=M {
                acc = c[k].mul_add(x[M - k + i] + x[M + k + i], acc);
            }
            *y = acc;
        }
        x.copy_within(n..n + COMPENSATOR_HISTORY, 0);
    }

    /// [`decimate`](Self::decimate) compiled for AVX2 and FMA. The CPU must have both.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn decimate_avx2_fma(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64]) {
        // SAFETY: the caller guarantees AVX2 and FMA, which `__m256d`'s kernel needs.
        unsafe { self.decimate_fused::<std::arch::x86_64::__m256d>(taps, out) };
    }

    /// [`decimate`](Self::decimate) compiled for AVX-512. The CPU must have AVX-512F,
    /// AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2,fma")]
    unsafe fn decimate_avx512(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64]) {
        // SAFETY: the caller guarantees AVX-512F and FMA, which `__m512d`'s kernel needs.
        unsafe { self.decimate_fused::<std::arch::x86_64::__m512d>(taps, out) };
    }

    /// The fused kernels: [`ACCUMULATORS`] registers of `V` hold that many times
    /// `V::WIDTH` outputs while the taps stream past them, then the rest one at a time.
    /// Inlined into the functions that carry the target features.
    ///
    /// # Safety
    /// The CPU must have `V`'s instructions.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn decimate_fused<V: FusedVector>(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64]) {
        crate::cpu::align_frame();
        let w = V::WIDTH;
        let blocks = out.len() / (ACCUMULATORS * w) * (ACCUMULATORS * w);
        let (grid, mid) = (&self.grid, &self.mid);
        // Output j reads grid samples j … j + GRID_TAPS − 1 and midpoint j: checked once
        // here for every output of the blocks, so that the loads below need no checks (one
        // per load had cost more than the multiply-adds).
        assert!(blocks + GRID_TAPS - 1 <= grid.len() && blocks <= mid.len());
        let (grid, mid) = (grid.as_ptr(), mid.as_ptr());
        for i in (0..blocks).step_by(ACCUMULATORS * w) {
            // SAFETY: the CPU has V's instructions (the caller); every load is of `w` f64
            // that the assertion above found inside its slice (output i + b·w + w − 1 <
            // blocks reads grid samples up to blocks − 1 + GRID_TAPS − 1 and midpoints up
            // to blocks − 1); the stores are bounds-checked.
            unsafe {
                let half = V::splat(0.5);
                let mut y: [V; ACCUMULATORS] =
                    std::array::from_fn(|b| half.mul(V::load_ptr(mid.add(i + b * w))));
                for (t, &c) in taps.iter().rev().enumerate() {
                    let c = V::splat(c);
                    for (b, y) in y.iter_mut().enumerate() {
                        *y = c.mul_add(V::load_ptr(grid.add(t + i + b * w)), *y);
                    }
                }
                for (b, y) in y.iter().enumerate() {
                    y.store(&mut out[i + b * w..]);
                }
            }
        }
        self.decimate_tail(taps, out, blocks);
        // SAFETY: the CPU has V's instructions (the caller).
        unsafe { self.compensate_fused::<V>(out) };
    }

    /// The fused kernels' outputs from `from` on, one at a time (the same fused
    /// multiply-adds in the same order), then the histories kept. Inlined into them.
    #[inline(always)]
    fn decimate_tail(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64], from: usize) {
        let n = out.len();
        for (i, y) in out.iter_mut().enumerate().skip(from) {
            let mut acc = 0.5 * self.mid[i];
            for (t, &c) in taps.iter().rev().enumerate() {
                acc = c.mul_add(self.grid[t + i], acc);
            }
            *y = acc;
        }
        self.grid.copy_within(n..n + GRID_HISTORY, 0);
        self.mid.copy_within(n..n + MID_HISTORY, 0);
    }

    #[inline(always)]
    fn decimate_with<const FUSED: bool>(&mut self, taps: &[f64; GRID_TAPS], out: &mut [f64]) {
        let n = out.len();
        // Output i reads grid samples i … i + 2K + 1 of the buffer (oldest first) and the
        // midpoint i of the buffer, K + 1 samples back. Tap by tap over all outputs: the
        // outputs are independent, so this loop vectorises (a dot product per output would
        // be a serial chain of additions).
        for (y, m) in out.iter_mut().zip(&self.mid[..n]) {
            *y = 0.5 * m;
        }
        for (t, &c) in taps.iter().rev().enumerate() {
            for (y, x) in out.iter_mut().zip(&self.grid[t..t + n]) {
                *y = if FUSED { c.mul_add(*x, *y) } else { *y + c * x };
            }
        }
        self.grid.copy_within(n..n + GRID_HISTORY, 0);
        self.mid.copy_within(n..n + MID_HISTORY, 0);
        self.compensate::<FUSED>(out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_halfbands_passband_is_flat_to_0_4_fs_and_its_stopband_is_88_db_down() {
        let taps = grid_taps();
        let mut worst_pass: f64 = 0.0;
        let mut worst_stop: f64 = 0.0;
        for j in 0..=4000 {
            let f = j as f64 / 4000.0; // 0 … f_s: the FIR at 2 f_s repeats beyond
            let g = halfband_gain(&taps, f);
            if f <= 0.4 {
                worst_pass = worst_pass.max((g - 1.0).abs());
            }
            if f >= 0.6 {
                worst_stop = worst_stop.max(g.abs());
            }
        }
        assert!(worst_pass < 4e-5, "passband ripple {worst_pass:e}");
        assert!(worst_stop < 4e-5, "stopband {worst_stop:e}");
        assert!((halfband_gain(&taps, 0.5) - 0.5).abs() < 1e-12);
        assert!((halfband_gain(&taps, 0.0) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn the_whole_chain_is_flat_to_0_4_fs_and_88_db_down_from_0_6_fs() {
        // Window, halfband and compensator: what a component before the sampler keeps.
        let taps = grid_taps();
        let (mut worst_pass, mut worst_stop) = (0.0f64, 0.0f64);
        for j in 0..=8000 {
            let f = j as f64 / 4000.0; // 0 … 2·f_s
            let g = gain(&taps, f);
            if f <= 0.4 {
                worst_pass = worst_pass.max((g - 1.0).abs());
            } else if (0.6..=1.4).contains(&f) {
                worst_stop = worst_stop.max(g.abs());
            }
        }
        println!("chain: passband {worst_pass:.2e}, stopband {worst_stop:.2e}");
        assert!(worst_pass < 4e-5, "passband ripple {worst_pass:e}");
        assert!(worst_stop < 4e-5, "stopband {worst_stop:e}");
        assert!((gain(&taps, 0.0) - 1.0).abs() < 1e-15);
        // What folds when the 2·f_s samples are taken: content at 2·f_s ± f lands on f,
        // weighed by the window; next to 2·f_s ± 0.3·f_s at most 1/27.
        for f in [1.7, 2.3, 3.7, 4.3] {
            let w = crate::synth::window::gain(f);
            assert!(w < 1.0 / 27.0, "{f}: {w}");
        }
    }

    #[test]
    fn a_sinusoid_comes_out_delayed_by_21_5_samples_with_the_windows_droop_undone() {
        // Point samples (no window) come out with the compensator's gain, 1/sinc² of the
        // window's droop; sampled through the window they would come out unchanged.
        let taps = grid_taps();
        let f = 0.3137; // cycles per output sample
        let boost = compensator_gain(f);
        assert!((boost * crate::synth::window::gain(f) - 1.0).abs() < 1e-4);
        let x = |half: f64| (std::f64::consts::PI * f * half + 0.4).cos();
        let mut adc = AdcFilter::new(64, |j| x(-(j as f64)));
        let mut out = vec![0.0; 64];
        for n in 0..64 {
            adc.grid[GRID_HISTORY + n] = x(2.0 * n as f64);
            adc.mid[MID_HISTORY + n] = x(2.0 * n as f64 + 1.0);
        }
        adc.decimate(&taps, &mut out);
        for (n, y) in out.iter().enumerate() {
            let want = boost * x(2.0 * n as f64 - DELAY_HALF_SAMPLES as f64);
            assert!((y - want).abs() < 4e-5, "sample {n}: {y} vs {want}");
        }
    }

    /// Feeds 64 samples of `x` (a function of time in half samples) on the grid and at the
    /// midpoints; each output must be `x` 21.5 samples earlier (the chain's delay) within `tolerance`.
    fn decimates_to_the_delayed_signal(
        adc: &mut AdcFilter,
        taps: &[f64; GRID_TAPS],
        x: impl Fn(f64) -> f64,
        tolerance: f64,
    ) {
        let mut out = vec![0.0; 64];
        for n in 0..64 {
            adc.grid[GRID_HISTORY + n] = x(2.0 * n as f64);
            adc.mid[MID_HISTORY + n] = x(2.0 * n as f64 + 1.0);
        }
        adc.decimate(taps, &mut out);
        for (n, y) in out.iter().enumerate() {
            let want = x(2.0 * n as f64 - DELAY_HALF_SAMPLES as f64);
            assert!((y - want).abs() < tolerance, "sample {n}: {y} vs {want}");
        }
    }

    #[test]
    fn a_filter_turned_on_starts_from_the_remembered_signal() {
        let taps = grid_taps();
        let f = 0.01; // a slow sinusoid, cycles per output sample
        let x = |half: f64| (std::f64::consts::PI * f * half).sin();
        let mut adc = AdcFilter::new(64, |_| 0.0);
        let before: Vec<f64> = (0..100).map(|n| x(2.0 * (n as f64 - 100.0))).collect();
        adc.remember(&before[..10]);
        adc.remember(&before[10..]);
        decimates_to_the_delayed_signal(&mut adc, &taps, x, 1e-3);
    }

    /// The register-blocked kernels give the bits of the tap-by-tap fused loop, for chunk
    /// lengths with and without a tail.
    #[test]
    fn the_fused_kernels_are_the_tap_by_tap_fused_loop_bit_for_bit() {
        let taps = grid_taps();
        let x = |j: usize| ((j as f64) * 0.377).sin() * 1e-8 + ((j as f64) * 0.0123).cos() * 3e-8;
        for kernel in [Kernel::Avx512, Kernel::Avx2Fma] {
            if !match kernel {
                Kernel::Avx512 => crate::cpu::avx512_available() && crate::cpu::fma_available(),
                _ => crate::cpu::fma_available(),
            } {
                continue;
            }
            for len in [256, 255, 47, 32, 16, 5, 1] {
                let mut fast = AdcFilter::new(256, |j| x(1000 + j));
                fast.kernel = kernel;
                let mut reference = fast.clone();
                let mut a = vec![0.0; len];
                let mut b = vec![0.0; len];
                for round in 0..3 {
                    for n in 0..len {
                        let g = 2 * (round * len + n);
                        fast.grid[GRID_HISTORY + n] = x(g);
                        fast.mid[MID_HISTORY + n] = x(g + 1);
                        reference.grid[GRID_HISTORY + n] = x(g);
                        reference.mid[MID_HISTORY + n] = x(g + 1);
                    }
                    fast.decimate(&taps, &mut a);
                    reference.decimate_with::<true>(&taps, &mut b);
                    assert!(
                        a.iter().zip(&b).all(|(p, q)| p.to_bits() == q.to_bits()),
                        "{kernel:?}, {len} samples, round {round}"
                    );
                    assert_eq!(fast.grid, reference.grid);
                    assert_eq!(fast.mid, reference.mid);
                }
            }
        }
    }

    #[test]
    fn the_delayed_phase_is_exact() {
        assert_eq!(delayed_phase(0, 2), 0u64.wrapping_sub(43));
        assert_eq!(
            delayed_phase(1 << 40, 1 << 60),
            (1u64 << 40).wrapping_sub(43 << 59)
        );
    }
}
