//! The real-time photodiode synthesiser: state plus the per-sample loop.
//!
//! Sample n is the light-lever signal at t_n = n·h: the drive's steady response
//! Re[Ŝ·e^{iθ_n}] plus Σ (2/3)·Lφn′(L)·Y_n of the modal states, which carry the response to
//! the tap force, every transient and the thermal noise; then the ADC: its anti-alias
//! filter (the signal taken at t_n and t_n + h/2, decimated by a halfband FIR, [`super::adc`];
//! sample n is then the filtered signal at t_n − D), detector noise, clipping and
//! quantisation.

use rustfft::num_complex::Complex64;

use super::adc::{AdcFilter, COMPENSATOR_HISTORY, GRID_HISTORY, WindowSample};
use super::coupled::{CoupledKernel, CoupledTrace, Refinement};
use super::digitiser::{DigitiserInput, detect_and_quantise};
use super::drive::Drive;
#[cfg(target_arch = "x86_64")]
use super::lanes::{Avx8, Avx512x8};
use super::lanes::{Lanes, Portable};
use super::noise_pages::{NoisePages, PAGE, PageCounts, PageKey, PageSupply};
use super::normals::NormalSource;
use super::phasor::{Phasors, Two};

use super::modal::ModalKernel;
use super::plan::SynthPlan;
use super::pulse::PulseKernel;
use super::window::Moments;
use crate::physics::beam::MAX_MODES;
use crate::timebase::{TWO_POW_64, phase_to_radians};

/// The drive phasor e^{iθ} is advanced by multiplication and re-anchored from the exact
/// integer phase at every multiple of this many samples (of the absolute sample index, so
/// the stream does not depend on how it is cut into blocks).
const REANCHOR: u64 = 256;

/// The builds of the synthesis loop: the same stream from each, bit for bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Build {
    Portable,
    Avx2,
    Avx512,
}

impl Build {
    /// The widest build this CPU runs.
    fn detect() -> Self {
        if crate::cpu::avx512_available() {
            Self::Avx512
        } else if crate::cpu::fma_available() {
            Self::Avx2
        } else {
            Self::Portable
        }
    }
}

/// Counters the synthesiser keeps; read them between blocks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SynthCounters {
    /// Samples produced.
    pub samples: u64,
    /// Samples clipped by the ADC's full scale, of those finished here
    /// ([`SynthPlan::process`]; [`SynthPlan::process_window`] leaves them to its
    /// [`Digitiser`](super::digitiser::Digitiser)).
    pub clipped: u64,
    /// Samples in contact the coupled engine redid at more than `/synth/contact_substeps`
    /// sub-steps, their contact being stiffer than that count resolves within the error
    /// budget ([`SUBSTEP_BUDGET`](super::coupled::SUBSTEP_BUDGET)).
    pub refined: u64,
    /// Samples over that budget even at the finest sub-steps (8× the count).
    pub over_budget: u64,
}

/// What the ADC's window carries from one sample to the next ([`super::window`]): the
/// last sample's thermal deviates, and if it had a tap force, its knot at its midpoint
/// (κ, one lane per mode) and what its force adds to the window on the next grid sample.
#[derive(Clone, Debug, Default)]
struct WindowCarry {
    z: [f64; MAX_MODES],
    mid: [f64; MAX_MODES],
    input: f64,
    /// Whether the last sample had a tap force.
    forced: bool,
    /// Whether the carry continues the stream: not at a start without the filter's
    /// history, after a change of plan ([`SynthState::retarget`]) or with the filter off.
    valid: bool,
}

/// Samples per chunk: the loop writes a chunk's grid and midpoint samples, then the ADC
/// filter decimates them. A chunk never straddles two pages of deviates.
const CHUNK: usize = 256;

/// Where the loop's samples go: finished here (the ADC's FIRs, detector noise and
/// quantisation on this thread), or as the signal through the ADC's window, for another
/// thread to finish ([`super::digitiser`]).
pub(crate) enum Output<'a> {
    Samples(&'a mut [f64]),
    Window(&'a mut [WindowSample]),
}

impl Output<'_> {
    fn len(&self) -> usize {
        match self {
            Self::Samples(s) => s.len(),
            Self::Window(w) => w.len(),
        }
    }
}

/// Mutable state of the synthesiser. Build it off the real-time thread.
#[derive(Clone, Debug)]
pub struct SynthState {
    /// Real and imaginary parts of each mode's q (structure of arrays, so they vectorise).
    re: [f64; MAX_MODES],
    im: [f64; MAX_MODES],
    phase: u64,
    rho: Complex64,
    /// `/drive2`'s phase word of the next sample and its phasor (kept where it drives):
    /// the reference of the demodulators on it, which runs on whether or not it drives.
    phase2: u64,
    rho2: Complex64,
    /// Seed of the noise sources.
    seed: u64,
    /// The thermal and detector deviates, a page of samples at a time, keyed by the
    /// absolute sample index ([`super::noise_pages`]): drawn here or, with a page queue
    /// attached, ahead by another thread. A sample's `L` lanes are read from its first
    /// mode's deviate on, so lanes past the plan's modes read the next samples' deviates
    /// (or the page's zero padding), which their zero coefficients ignore.
    noise: NoisePages,
    /// The ADC filter's histories and the chunk's grid and midpoint samples.
    adc: AdcFilter,
    /// The ADC window's carry from the last sample.
    window: WindowCarry,
    /// The widest vector instructions the CPU has (the loop is compiled for them).
    build: Build,
    /// The coupled engine's sub-step count for the next tap.
    refinement: Refinement,
    /// Counters.
    pub counters: SynthCounters,
}

impl SynthState {
    /// State at sample 0, drive phase 0, with every mode already in its periodic steady
    /// state under the tap force and its thermal motion drawn from the stationary
    /// distribution, so the stream starts settled. `seed` seeds every random source.
    pub fn steady(plan: &SynthPlan, seed: u64) -> Self {
        let mut start = NormalSource::set(seed, 2);
        let mut thermal = [Complex64::new(0.0, 0.0); MAX_MODES];
        for (m, kernel) in plan.modes.iter().enumerate() {
            let sigma = plan.thermal_sigma[m];
            if sigma == 0.0 {
                continue;
            }
            // Stationary covariance of q under q ← a·q + g·σ·ξ: E|q|² = σ²|g|²/(1 − |a|²),
            // E q² = σ²g²/(1 − a²); draw (Re q, Im q) from it by Cholesky.
            let (a, g) = (kernel.propagator, kernel.hold_gain);
            let abs2 = sigma * sigma * g.norm_sqr() / (1.0 - a.norm_sqr());
            let sq = g * g * (sigma * sigma) / (1.0 - a * a);
            let (vr, vi, c) = (0.5 * (abs2 + sq.re), 0.5 * (abs2 - sq.re), 0.5 * sq.im);
            let l11 = vr.max(0.0).sqrt();
            let l21 = if l11 > 0.0 { c / l11 } else { 0.0 };
            let l22 = (vi - l21 * l21).max(0.0).sqrt();
            let mut z = [0.0; 2];
            start.fill(&mut z);
            let [z1, z2] = z;
            thermal[m] = Complex64::new(l11 * z1, l21 * z1 + l22 * z2);
        }
        let (q, adc, window, refinement) = if plan.anti_alias.is_some() {
            plan.settled_start(&thermal)
        } else {
            let mut q = thermal;
            let (tap, refinement) = plan.tap_steady_state(0.0);
            for (q, tap) in q.iter_mut().zip(tap) {
                *q += tap;
            }
            (
                q,
                AdcFilter::new(CHUNK, |_| 0.0),
                WindowCarry::default(),
                refinement,
            )
        };
        Self {
            re: q.map(|q| q.re),
            im: q.map(|q| q.im),
            phase: 0,
            rho: Complex64::new(1.0, 0.0),
            phase2: 0,
            rho2: Complex64::new(1.0, 0.0),
            seed,
            noise: NoisePages::new(),
            adc,
            window,
            build: Build::detect(),
            refinement,
            counters: SynthCounters::default(),
        }
    }

    fn q(&self, m: usize) -> Complex64 {
        Complex64::new(self.re[m], self.im[m])
    }

    fn set_q(&mut self, m: usize, q: Complex64) {
        self.re[m] = q.re;
        self.im[m] = q.im;
    }

    /// Takes the pages of deviates from `supply` from now on, where another thread draws
    /// them ahead ([`super::noise_pages::PageFactory`]); the stream is the same bits.
    pub fn attach_noise_supply(&mut self, supply: PageSupply) {
        self.noise.attach(supply);
    }

    /// Where the pages of deviates came from so far.
    pub fn noise_pages(&self) -> PageCounts {
        self.noise.counts
    }

    /// Index of the next sample.
    pub fn sample_index(&self) -> u64 {
        self.counters.samples
    }

    /// Drive phase word of the next sample (2^64 = one period; 0 = cosine peak).
    pub fn phase(&self) -> u64 {
        self.phase
    }

    /// `/drive2`'s phase word of the next sample (2^64 = one period; 0 = cosine peak).
    pub fn phase2(&self) -> u64 {
        self.phase2
    }

    /// Moves the stream on by `samples` without synthesising them: the sample index and the
    /// drive phase advance as if they had been (the modes keep their state, and the ADC
    /// window's next sample starts afresh), so a streamed source's blocks take the place of
    /// synthesised ones in the same count and on the same reference. Allocation-free.
    pub fn skip(&mut self, plan: &SynthPlan, samples: u64) {
        self.counters.samples += samples;
        self.phase = self
            .phase
            .wrapping_add(plan.frequency_word.wrapping_mul(samples));
        self.rho = Complex64::from_polar(1.0, phase_to_radians(self.phase));
        self.set_phase2(
            plan,
            self.phase2
                .wrapping_add(plan.frequency_word2.wrapping_mul(samples)),
        );
        self.window.valid = false;
    }

    /// Starts a streamed source whose next sample has index `writer_index` in the writer's
    /// own count: the chain's index moves on by one (so the DSP restarts its filters with
    /// the stream, a discontinuity), and the drive phase becomes the drive's at that index
    /// from the writer's sample 0 (phase 0, the cosine's peak), so a stream's reference
    /// does not depend on when it started. Allocation-free.
    pub fn start_stream(&mut self, plan: &SynthPlan, writer_index: u64) {
        self.counters.samples += 1;
        self.phase = plan.frequency_word.wrapping_mul(writer_index);
        self.rho = Complex64::from_polar(1.0, phase_to_radians(self.phase));
        self.set_phase2(plan, plan.frequency_word2.wrapping_mul(writer_index));
        self.window.valid = false;
    }

    /// Puts `/drive2`'s phase at `phase2`, its phasor with it where it drives.
    fn set_phase2(&mut self, plan: &SynthPlan, phase2: u64) {
        self.phase2 = phase2;
        if plan.drive2.is_some() {
            self.rho2 = Complex64::from_polar(1.0, phase_to_radians(phase2));
        }
    }

    /// Moves the modes from drive `from` to drive `to` at the next sample without a jump:
    /// each mode's displacement and velocity stay what they are, and its free motion takes
    /// up the difference of the two steady responses, as a physical transient. What a PLL
    /// or an amplitude loop does to the excitation. `modes` are the plan's kernels.
    /// Allocation-free.
    pub(crate) fn redrive(&mut self, modes: &[ModalKernel], from: &Drive, to: &Drive) {
        let rho = self.rho;
        for (m, kernel) in modes.iter().enumerate() {
            let (yh, vh) = kernel.displacement_velocity(self.q(m));
            let (y0, v0) = from.particular(m, rho);
            let (y1, v1) = to.particular(m, rho);
            self.set_q(m, kernel.state_of(yh + y0 - y1, vh + v0 - v1));
        }
        // A carried tap's midpoint knot holds the old basis' lanes (the loops move the
        // drive where the tip is highest, so this is rare): its window starts afresh.
        if self.window.forced {
            self.window.valid = false;
        }
    }

    /// [`redrive`](Self::redrive) for the second excitation: the modes move from its
    /// drive `from` to `to` (either `None`: not driving) at the next sample, against θ₂.
    /// What mode 2's PLL or amplitude loop does to it. Allocation-free.
    pub(crate) fn redrive2(
        &mut self,
        modes: &[ModalKernel],
        from: Option<&Drive>,
        to: Option<&Drive>,
    ) {
        let rho2 = Complex64::from_polar(1.0, phase_to_radians(self.phase2));
        let particular =
            |d: Option<&Drive>, m: usize| d.map_or((0.0, 0.0), |d| d.particular(m, rho2));
        for (m, kernel) in modes.iter().enumerate() {
            let (yh, vh) = kernel.displacement_velocity(self.q(m));
            let (y0, v0) = particular(from, m);
            let (y1, v1) = particular(to, m);
            self.set_q(m, kernel.state_of(yh + y0 - y1, vh + v0 - v1));
        }
        self.rho2 = rho2;
        if self.window.forced {
            self.window.valid = false;
        }
    }

    /// Moves from `old` to `new` without a jump: the modal displacements and velocities
    /// stay continuous, so a change of drive, sample or cantilever shows as a physical
    /// transient. Modes that `new` adds start at rest; modes it drops are gone. A new seed
    /// takes over the noise: from then on the deviates are that seed's at those samples.
    pub fn retarget(&mut self, old: &SynthPlan, new: &SynthPlan) {
        // The window's carry belongs to the old plan's modes and drive: the next grid
        // sample's window takes the sample before it as free of force and thermal input
        // (one approximate window in the transient).
        self.window.valid = false;
        if new.seed != old.seed {
            self.seed = new.seed;
        }
        let theta = phase_to_radians(self.phase);
        let rho = Complex64::from_polar(1.0, theta);
        let rho2 = Complex64::from_polar(1.0, phase_to_radians(self.phase2));
        // Both excitations' steady motions: the second's where it drives.
        let particular = |plan: &SynthPlan, m: usize| {
            let (y, v) = plan.drive.particular(m, rho);
            match &plan.drive2 {
                Some(d) => {
                    let (y2, v2) = d.particular(m, rho2);
                    (y + y2, v + v2)
                }
                None => (y, v),
            }
        };
        for m in 0..new.modes.len() {
            let (y, v) = if m < old.modes.len() {
                let (yh, vh) = old.modes[m].displacement_velocity(self.q(m));
                let (yp, vp) = particular(old, m);
                (yh + yp, vh + vp)
            } else {
                (0.0, 0.0)
            };
            let (yp, vp) = particular(new, m);
            self.set_q(m, new.modes[m].state_of(y - yp, v - vp));
        }
        for m in new.modes.len()..MAX_MODES {
            self.set_q(m, Complex64::new(0.0, 0.0));
        }
        self.rho2 = rho2;
    }
}

impl SynthPlan {
    /// Fills `out` with the next samples (nominal metres). Allocation-free, lock-free.
    /// The tip rests over the base material at `/surface/distance`; a scan runs through
    /// [`process_scan`](Self::process_scan).
    pub fn process(&self, state: &mut SynthState, out: &mut [f64]) {
        self.process_with(
            &self.drive,
            self.drive2.as_ref(),
            self.pulse.as_ref(),
            self.coupled.as_ref(),
            state,
            Output::Samples(out),
        );
    }

    /// The next samples through the ADC's window, unfinished: a
    /// [`Digitiser`](super::digitiser::Digitiser) given them and the returned input
    /// makes of them the samples [`process`](Self::process) would have given, bit for bit.
    /// For the pipeline, whose DSP thread finishes them. Allocation-free, lock-free.
    pub fn process_window(
        &self,
        state: &mut SynthState,
        out: &mut [WindowSample],
    ) -> DigitiserInput {
        let input = DigitiserInput {
            filter: self.anti_alias.is_some(),
            detector_sigma: self.detector_sigma,
            adc: self.adc,
            seed: state.seed,
            history: state.adc.history(),
        };
        self.process_with(
            &self.drive,
            self.drive2.as_ref(),
            self.pulse.as_ref(),
            self.coupled.as_ref(),
            state,
            Output::Window(out),
        );
        input
    }

    /// [`process`](Self::process) with the tap force of `pulse` on the paper engine, or of
    /// the contact of `coupled` (which takes precedence); neither: free oscillation.
    pub(crate) fn process_with(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        match state.build {
            // SAFETY: `build` names an instruction set only where the CPU has it.
            #[cfg(target_arch = "x86_64")]
            Build::Avx512 => unsafe {
                self.process_avx512(drive, drive2, pulse, coupled, state, out)
            },
            #[cfg(target_arch = "x86_64")]
            Build::Avx2 => unsafe { self.process_avx2(drive, drive2, pulse, coupled, state, out) },
            _ => self.process_modes::<Portable<8>>(drive, drive2, pulse, coupled, state, out),
        }
    }

    /// [`process_with`](Self::process_with) compiled for AVX-512: the same operations in
    /// the same order, eight lanes to a register, so the same stream bit for bit. The CPU
    /// must have AVX-512F and AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    unsafe fn process_avx512(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        crate::cpu::align_frame();
        self.process_modes::<Avx512x8>(drive, drive2, pulse, coupled, state, out);
    }

    /// [`process_with`](Self::process_with) compiled for AVX2 and FMA: the same operations
    /// in the same order (the multiply–adds fused where the lanes' `mul_add` asks for it,
    /// as the portable build's `f64::mul_add`), four lanes to a register, so the stream is
    /// bit-identical to the portable build's. The CPU must have AVX2 and FMA (without FMA
    /// the lanes' fused operations could not be inlined: each would be a call).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn process_avx2(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        crate::cpu::align_frame();
        self.process_modes::<Avx8>(drive, drive2, pulse, coupled, state, out);
    }

    /// Up to eight modes: the loop on eight lanes of `V`; more: on an array of all lanes.
    #[inline(always)]
    fn process_modes<V: Lanes>(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        if self.modes.len() <= 8 {
            self.process_engines::<V>(drive, drive2, pulse, coupled, state, out);
        } else {
            self.process_engines::<Portable<MAX_MODES>>(drive, drive2, pulse, coupled, state, out);
        }
    }

    /// The loop on lanes of `V` (lanes past the plan's modes hold zeros and contribute
    /// nothing), for the engine and the filter: each combination's loop is compiled as if
    /// written alone.
    #[inline(always)]
    fn process_engines<V: Lanes>(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        // A second excitation drives only the coupled engine (the settings refuse it on
        // the paper engine's).
        let two = drive2.filter(|_| coupled.is_some());
        match (coupled, self.anti_alias.is_some(), two) {
            (Some(c), true, None) => self.process_lanes::<V, Complex64, true, true>(
                drive,
                None,
                None,
                Some(c),
                state,
                out,
            ),
            (Some(c), false, None) => self.process_lanes::<V, Complex64, false, true>(
                drive,
                None,
                None,
                Some(c),
                state,
                out,
            ),
            (Some(c), true, d2) => {
                self.process_lanes::<V, Two, true, true>(drive, d2, None, Some(c), state, out)
            }
            (Some(c), false, d2) => {
                self.process_lanes::<V, Two, false, true>(drive, d2, None, Some(c), state, out)
            }
            (None, true, _) => self
                .process_lanes::<V, Complex64, true, false>(drive, None, pulse, None, state, out),
            (None, false, _) => self
                .process_lanes::<V, Complex64, false, false>(drive, None, pulse, None, state, out),
        }
    }

    /// The per-sample loop on mode lanes of `V` held in registers. `MID`: with the ADC's
    /// filter (the signal through its window at the grid samples and midpoints,
    /// [`super::window`]); `COUPLED`: the coupled engine's contact, else the paper engine's
    /// pulse. The samples where a pulse falls take arrays of the lanes for its exact
    /// integrals.
    ///
    /// Through the window, grid sample n spans the second half of sample n − 1 and the
    /// first of sample n, and midpoint n + ½ spans sample n. Where neither sample has a tap
    /// force, both are fixed functionals of the state at t_n and the two samples' thermal
    /// deviates; otherwise the window is taken from its three knots and the force's
    /// moments, carrying the last midpoint's knot and its sample's force from a forced
    /// sample to the next ([`WindowCarry`]).
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn process_lanes<V: Lanes, P: Phasors, const MID: bool, const COUPLED: bool>(
        &self,
        drive: &Drive,
        drive2: Option<&Drive>,
        pulse: Option<&PulseKernel>,
        coupled: Option<&CoupledKernel>,
        state: &mut SynthState,
        out: Output<'_>,
    ) {
        let k = &self.lanes;
        let rotation = |word: u64| {
            Complex64::from_polar(1.0, word as f64 / TWO_POW_64 * std::f64::consts::TAU)
        };
        // The second excitation's amplitudes (zero where it does not drive; a single
        // drive's phasors leave them out).
        let zero = Complex64::new(0.0, 0.0);
        // θ₂ runs at the second excitation's word where it drives (a loop may move it),
        // else at `/drive2/frequency`'s, as the reference of demodulators on it.
        let word2 = drive2.map_or(self.frequency_word2, |d| d.word);
        let step = P::new(
            rotation(drive.word),
            drive2.map_or(zero, |_| rotation(word2)),
        );
        let grid_c = P::new(drive.grid, drive2.map_or(zero, |d| d.grid));
        let mid_c = P::new(drive.mid, drive2.map_or(zero, |d| d.mid));
        let signal_c = P::new(drive.signal, drive2.map_or(zero, |d| d.signal));
        let (start_index, start_phase2) = (state.counters.samples, state.phase2);
        let (a_re, a_im) = (V::load(&k.a_re), V::load(&k.a_im));
        let (noise_re, noise_im) = (V::load(&k.noise_re), V::load(&k.noise_im));
        let lever = V::load(&k.lever);
        let coupled_lanes = coupled.map(|c| c.lanes::<V>());
        let n = self.modes.len();
        let mut re = V::load(&state.re);
        let mut im = V::load(&state.im);
        let carry = &state.window;
        let valid = MID && carry.valid;
        // Without a carry (the window just started) the last sample is taken as free, with
        // no thermal input: one grid sample's window is then approximate.
        let mut z_before = if valid {
            V::load(&carry.z)
        } else {
            V::splat(0.0)
        };
        let mut forced_before = valid && carry.forced;
        let mut knot_before = V::load(&carry.mid);
        let mut input_before = carry.input;
        // The coupled engine's tip position at the next sample, once a step has found it.
        let mut tip = f64::NAN;
        let mut phase = state.phase;
        let mut rho = P::new(state.rho, state.rho2);
        let mut index = state.counters.samples;
        let mut clipped = 0u64;
        let (mut refined, mut over_budget) = (0u64, 0u64);
        let mut refinement = state.refinement;
        let mut out = out;
        let total = out.len();
        // The detector's deviates are drawn where the samples are finished.
        let finish_here = matches!(out, Output::Samples(_));
        let mut done = 0;
        while done < total {
            let within = index as usize % PAGE;
            let len = (total - done).min(CHUNK).min(PAGE - within);
            self.prepare_noise(state, index, finish_here);
            let thermal = state.noise.page().thermal(within, n);
            let (grid, mids) = match &mut out {
                Output::Samples(samples) if !MID => (&mut samples[done..done + len], &mut [][..]),
                _ => {
                    let (grid, mids) = state.adc.chunk_mut(len);
                    (grid, if MID { mids } else { &mut [][..] })
                }
            };
            let mut i = 0;
            while i < len {
                let out = &mut grid[i];
                // Lanes past the plan's modes read the next samples' deviates (zero
                // coefficients).
                let z = V::load_f32(&thermal[i * n..]);
                if index.is_multiple_of(REANCHOR) {
                    let phase2 = start_phase2.wrapping_add(word2.wrapping_mul(index - start_index));
                    rho = P::at(phase, phase2);
                }
                let (re0, im0) = (re, im);
                let mut next = rho.times(step);
                'sample: {
                    // The coupled engine's common case in tapping: a sample clear of the
                    // surface after a sample without force. It has no force and no carry, so
                    // none of the bookkeeping below; the same bits as the general path.
                    if COUPLED
                        && MID
                        && !forced_before
                        && let (Some(coupled), Some(lanes)) = (coupled, &coupled_lanes)
                        && let Some(clear) = coupled.clear_step(lanes, re, im, next, z, tip)
                    {
                        (re, im, tip) = clear;
                        (*out, mids[i]) = self.free_windows(
                            (re0, im0),
                            z,
                            z_before,
                            rho.real(grid_c),
                            rho.real(mid_c),
                        );
                        z_before = z;
                        // The run of clear samples after it, in a loop of its own: its few
                        // live values stay in registers and the checks the run has passed
                        // are not repeated. It stops before the chunk's end, the drive
                        // phasor's next re-anchoring and the first sample not clear, which
                        // the loop above takes up. The same bits as one sample at a time.
                        // It repeats the first sample's body above on purpose: the two
                        // folded into one loop from sample i took 15 more instructions a
                        // clear sample (172 against 157 through the window, callgrind, AVX2).
                        let stop = len.min(i + (REANCHOR - index % REANCHOR) as usize);
                        let mut rho_run = next;
                        let mut j = i + 1;
                        while j < stop {
                            let z = V::load_f32(&thermal[j * n..]);
                            let next_run = rho_run.times(step);
                            let Some(clear) = coupled.clear_step(lanes, re, im, next_run, z, tip)
                            else {
                                break;
                            };
                            (grid[j], mids[j]) = self.free_windows(
                                (re, im),
                                z,
                                z_before,
                                rho_run.real(grid_c),
                                rho_run.real(mid_c),
                            );
                            (re, im, tip) = clear;
                            z_before = z;
                            rho_run = next_run;
                            j += 1;
                        }
                        // Samples i + 1 … j − 1; the common tail below adds sample i's step.
                        let more = (j - i - 1) as u64;
                        phase = phase.wrapping_add(drive.word.wrapping_mul(more));
                        next = rho_run;
                        index += more;
                        i += more as usize;
                        break 'sample;
                    }
                    // A forced sample's knot at its midpoint, and the force's moments.
                    let mut knot_mid = V::splat(0.0);
                    let mut moments = Moments::default();
                    let mut forced = false;
                    // Clear after a forced sample, or sampled directly: the short step too.
                    // Where the block above has just failed it, this tries it again, a
                    // repeat at each approach to the surface only; skipping the repeat
                    // measured 2–3 % slower in the AVX2 build (code layout), so it stays.
                    if COUPLED
                        && let (Some(coupled), Some(lanes)) = (coupled, &coupled_lanes)
                        && let Some(clear) = coupled.clear_step(lanes, re, im, next, z, tip)
                    {
                        (re, im, tip) = clear;
                    } else if COUPLED
                        && let (Some(coupled), Some(lanes)) = (coupled, &coupled_lanes)
                    {
                        let mut midq = (re, im);
                        let stepping;
                        (re, im, tip, stepping) = coupled.step_lanes(
                            lanes,
                            re,
                            im,
                            rho,
                            next,
                            z,
                            tip,
                            &mut midq,
                            &mut moments,
                            &mut refinement,
                            &mut |_, _| {},
                        );
                        refined += u64::from(stepping.refined);
                        over_budget += u64::from(stepping.over_budget);
                        if MID {
                            forced = moments != Moments::default();
                            if stepping.substepped() {
                                knot_mid = V::load(&k.knot_re)
                                    .mul_add(midq.0, V::load(&k.knot_im).mul(midq.1));
                            } else if forced {
                                // The kick at the sample's start, seen at the midpoint.
                                knot_mid = V::load(&k.mid_kick)
                                    .mul_add(V::splat(moments.s1), self.free_knot_mid(re0, im0, z));
                            }
                        }
                    } else if let Some(overlap) = pulse.and_then(|p| p.overlap(phase, drive.word)) {
                        // A pulse falls in this sample: its exact integrals, mode by mode.
                        let pulse = pulse.expect("an overlap has a pulse");
                        let phasors = pulse.phasors(&overlap);
                        if MID {
                            let mut dre = [0.0; MAX_MODES];
                            let mut dim = [0.0; MAX_MODES];
                            pulse.apply_to_midpoint(
                                &overlap,
                                &phasors,
                                &self.modes,
                                &mut dre[..n],
                                &mut dim[..n],
                            );
                            knot_mid = V::load(&k.knot_re).mul_add(
                                V::load(&dre),
                                V::load(&k.knot_im)
                                    .mul_add(V::load(&dim), self.free_knot_mid(re0, im0, z)),
                            );
                            moments = pulse.moments(&overlap, &phasors);
                            forced = true;
                        }
                        let r1 = a_im.neg_mul_add(im, a_re.mul_add(re, noise_re.mul(z)));
                        let i1 = a_im.mul_add(re, a_re.mul_add(im, noise_im.mul(z)));
                        let (mut r, mut i) = ([0.0; MAX_MODES], [0.0; MAX_MODES]);
                        r1.store(&mut r);
                        i1.store(&mut i);
                        pulse.apply(&overlap, &phasors, &self.modes, &mut r[..n], &mut i[..n]);
                        (re, im) = (V::load(&r), V::load(&i));
                    } else {
                        let r1 = a_im.neg_mul_add(im, a_re.mul_add(re, noise_re.mul(z)));
                        im = a_im.mul_add(re, a_re.mul_add(im, noise_im.mul(z)));
                        re = r1;
                    }
                    if MID {
                        let drive_grid = rho.real(grid_c);
                        let drive_mid = rho.real(mid_c);
                        if !forced && !forced_before {
                            (*out, mids[i]) =
                                self.free_windows((re0, im0), z, z_before, drive_grid, drive_mid);
                        } else {
                            (*out, mids[i]) = self.forced_windows(
                                (re0, im0),
                                (re, im),
                                z,
                                z_before,
                                if forced {
                                    knot_mid
                                } else {
                                    self.free_knot_mid(re0, im0, z)
                                },
                                forced_before.then_some((knot_before, input_before)),
                                &moments,
                                (drive_grid, drive_mid),
                            );
                            if forced {
                                knot_before = knot_mid;
                                input_before = moments
                                    .weigh(self.force_window.0, self.force_window.1, self.h)
                                    .2;
                            }
                        }
                        forced_before = forced;
                        z_before = z;
                    } else {
                        *out = rho.real(signal_c) + lever.mul(im0).sum();
                    }
                }
                phase = phase.wrapping_add(drive.word);
                rho = next;
                index += 1;
                i += 1;
            }
            let taps = if MID { self.anti_alias.as_ref() } else { None };
            match &mut out {
                Output::Samples(samples) => {
                    let chunk = &mut samples[done..done + len];
                    if let Some(taps) = taps {
                        state.adc.decimate(taps, chunk);
                    } else {
                        state.adc.remember(chunk);
                    }
                    clipped += detect_and_quantise(
                        chunk,
                        self.detector_sigma,
                        state.noise.page().detector(within),
                        self.adc,
                    );
                }
                Output::Window(window) => {
                    // The histories are read at the call's end: only the chunks whose
                    // halfband outputs can be among its last few need them.
                    let settle = total - (done + len) < COMPENSATOR_HISTORY;
                    state.adc.pass(taps, &mut window[done..done + len], settle);
                }
            }
            done += len;
        }
        re.store(&mut state.re);
        im.store(&mut state.im);
        let carry = &mut state.window;
        z_before.store(&mut carry.z);
        knot_before.store(&mut carry.mid);
        (carry.input, carry.forced, carry.valid) = (input_before, forced_before, MID);
        state.phase = phase;
        state.rho = rho.first();
        if let Some(rho2) = rho.second() {
            state.rho2 = rho2;
        }
        state.phase2 = start_phase2.wrapping_add(word2.wrapping_mul(index - start_index));
        state.counters.samples = index;
        state.counters.clipped += clipped;
        state.counters.refined += refined;
        state.refinement = refinement;
        state.counters.over_budget += over_budget;
    }

    /// The windows on grid sample n and on midpoint n + ½ where neither sample n nor n − 1
    /// has a tap force: fixed functionals of the state `re`, `im` at t_n and the thermal
    /// deviates `z` and `z_before` of samples n and n − 1, plus the drive's parts.
    #[inline(always)]
    fn free_windows<V: Lanes>(
        &self,
        (re, im): (V, V),
        z: V,
        z_before: V,
        drive_grid: f64,
        drive_mid: f64,
    ) -> (f64, f64) {
        let k = &self.lanes;
        let g = V::load(&k.free_grid_re).mul_add(
            re,
            V::load(&k.free_grid_im).mul_add(
                im,
                V::load(&k.free_grid_noise)
                    .mul_add(z, V::load(&k.free_grid_noise_before).mul(z_before)),
            ),
        );
        let m = V::load(&k.free_mid_re).mul_add(
            re,
            V::load(&k.free_mid_im).mul_add(im, V::load(&k.free_mid_noise).mul(z)),
        );
        let (g, m) = g.sum2(m);
        (drive_grid + g, drive_mid + m)
    }

    /// κ at the midpoint of a sample without force, from the state `re`, `im` at its start
    /// and its thermal deviates `z`.
    #[inline(always)]
    fn free_knot_mid<V: Lanes>(&self, re: V, im: V, z: V) -> V {
        let k = &self.lanes;
        V::load(&k.mid_re).mul_add(
            re,
            V::load(&k.mid_im).mul_add(im, V::load(&k.mid_noise).mul(z)),
        )
    }

    /// The windows on grid sample n and on midpoint n + ½ where sample n or n − 1 has a
    /// tap force, from the knots ([`super::window`]): the states at t_n and t_{n+1}, the
    /// knot at n + ½ `knot_mid`, the thermal deviates of samples n and n − 1, the force's
    /// `moments` over sample n, and for a forced sample n − 1 its knot at n − ½ and what
    /// its force gives the window on n (else that knot is found from the state at t_n).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn forced_windows<V: Lanes>(
        &self,
        (re0, im0): (V, V),
        (re1, im1): (V, V),
        z: V,
        z_before: V,
        knot_mid: V,
        before: Option<(V, f64)>,
        moments: &Moments,
        (drive_grid, drive_mid): (f64, f64),
    ) -> (f64, f64) {
        let k = &self.lanes;
        let (knot_re, knot_im) = (V::load(&k.knot_re), V::load(&k.knot_im));
        let knot_grid = knot_re.mul_add(re0, knot_im.mul(im0));
        let knot_next = knot_re.mul_add(re1, knot_im.mul(im1));
        // A `match`, not `unwrap_or_else`: a closure is not compiled with the caller's
        // target features, so its lane arithmetic had been calls to the intrinsics.
        let (knot_left, input_left) = match before {
            Some(before) => before,
            None => {
                let back = V::load(&k.back_re).mul_add(
                    re0,
                    V::load(&k.back_im).mul_add(im0, V::load(&k.back_noise).mul(z_before)),
                );
                (back, 0.0)
            }
        };
        let (w_start, w_mid, _) = moments.weigh(self.force_window.0, self.force_window.1, self.h);
        let g = V::load(&k.grid_noise).mul_add(
            z,
            V::load(&k.grid_noise_before).mul_add(
                z_before,
                knot_left.add(knot_mid).sub(knot_grid.add(knot_grid)),
            ),
        );
        let m = V::load(&k.mid_input_noise)
            .mul_add(z, knot_grid.add(knot_next).sub(knot_mid.add(knot_mid)));
        let (g, m) = g.sum2(m);
        (
            drive_grid + g + (input_left + w_start),
            drive_mid + m + w_mid,
        )
    }

    /// Advances `state` by `samples` samples of the coupled engine with the noise left
    /// out, recording the tip force at every sub-step and the tip position at every
    /// sample: the engine's own view of the contact, for checks against the offline orbit.
    /// Not for the real-time thread (it allocates). `None` with the paper engine.
    pub fn coupled_trace(&self, state: &mut SynthState, samples: usize) -> Option<CoupledTrace> {
        let coupled = self.coupled.as_ref()?;
        // Both excitations where the second drives: the tip where the stream puts it.
        Some(if self.drive2.is_some() {
            self.trace_with::<Two>(coupled, state, samples)
        } else {
            self.trace_with::<Complex64>(coupled, state, samples)
        })
    }

    /// [`coupled_trace`](Self::coupled_trace) with the drive phasors `P`.
    fn trace_with<P: Phasors>(
        &self,
        coupled: &CoupledKernel,
        state: &mut SynthState,
        samples: usize,
    ) -> CoupledTrace {
        let (step, step2) = (self.frequency_word, self.frequency_word2);
        let mut trace = CoupledTrace {
            force: Vec::with_capacity(samples * coupled.substeps()),
            tip: Vec::with_capacity(samples),
            dt: self.h / coupled.substeps() as f64,
            substeps: coupled.substeps(),
            start_phase: state.phase,
            free_tip: coupled.free_tip,
            start_phase2: state.phase2,
            free_tip2: coupled.free_tip2,
        };
        type All = Portable<MAX_MODES>;
        let lanes = coupled.lanes::<All>();
        let z = All::splat(0.0);
        let (mut re, mut im) = (All::load(&state.re), All::load(&state.im));
        let mut mid = (re, im);
        let mut moments = Moments::default();
        for _ in 0..samples {
            let rho = P::at(state.phase, state.phase2);
            let (next_phase, next_phase2) = (
                state.phase.wrapping_add(step),
                state.phase2.wrapping_add(step2),
            );
            let next = P::at(next_phase, next_phase2);
            let tip = coupled.tip_position(&lanes, rho, im);
            trace.tip.push(tip);
            let start = trace.force.len();
            (re, im, _, _) = coupled.step_lanes(
                &lanes,
                re,
                im,
                rho,
                next,
                z,
                tip,
                &mut mid,
                &mut moments,
                &mut state.refinement,
                // A sample redone finer hands its forces again from j = 0.
                &mut |j, g| {
                    trace.force.truncate(start + j);
                    trace.force.push(g);
                },
            );
            (state.phase, state.phase2) = (next_phase, next_phase2);
            state.counters.samples += 1;
        }
        re.store(&mut state.re);
        im.store(&mut state.im);
        state.rho = Complex64::from_polar(1.0, phase_to_radians(state.phase));
        state.rho2 = Complex64::from_polar(1.0, phase_to_radians(state.phase2));
        state.window.valid = false;
        trace
    }

    /// The modal states at phase 0, the ADC filter's history and the window's carry for a
    /// stream that starts on the periodic orbit under the tap force plus the free motion
    /// `thermal`: the samples before phase 0 that the filter remembers (its halfband's and
    /// compensator's histories, and one more for the window's carry) synthesised without
    /// noise from the orbit's state that many samples earlier (and `thermal` propagated
    /// back), so the filter's history and the states it ends in are one stream, settled
    /// from its first sample.
    fn settled_start(
        &self,
        thermal: &[Complex64; MAX_MODES],
    ) -> ([Complex64; MAX_MODES], AdcFilter, WindowCarry, Refinement) {
        let mut quiet = self.clone();
        quiet.thermal_sigma.iter_mut().for_each(|s| *s = 0.0);
        quiet.detector_sigma = 0.0;
        quiet.adc = None;
        const BEFORE: usize = GRID_HISTORY + 1 + COMPENSATOR_HISTORY;
        let before = BEFORE;
        let word = self.frequency_word;
        let start = 0u64.wrapping_sub((before as u64).wrapping_mul(word));
        let start2 = 0u64.wrapping_sub((before as u64).wrapping_mul(self.frequency_word2));
        let t = -(before as f64) * self.h;
        let (periodic, refinement) = self.tap_steady_state(phase_to_radians(start));
        let mut temp = SynthState {
            re: [0.0; MAX_MODES],
            im: [0.0; MAX_MODES],
            phase: start,
            rho: Complex64::from_polar(1.0, phase_to_radians(start)),
            phase2: start2,
            rho2: Complex64::from_polar(1.0, phase_to_radians(start2)),
            seed: 0,
            noise: NoisePages::new(),
            adc: AdcFilter::new(CHUNK, |_| 0.0),
            window: WindowCarry::default(),
            build: Build::detect(),
            refinement,
            counters: SynthCounters::default(),
        };
        // A mode so heavily damped (a high mode under Rayleigh damping) that its thermal
        // state, propagated back over the prehistory, would grow by more than MAX_BACK
        // takes its thermal state at the end instead: propagated back, it reached 1e100
        // and more on a 10-mode lever and the filter's history overflowed to NaN. Such a
        // mode forgets its state within the prehistory, so its part of the history is
        // below the thermal motion it starts with.
        const MAX_BACK: f64 = 1e3;
        let mut late = [Complex64::new(0.0, 0.0); MAX_MODES];
        for (m, kernel) in self.modes.iter().enumerate() {
            let back = (kernel.lambda * t).exp();
            if back.norm() <= MAX_BACK {
                temp.set_q(m, periodic[m] + thermal[m] * back);
            } else {
                temp.set_q(m, periodic[m]);
                late[m] = thermal[m];
            }
        }
        let mut scratch = [0.0; BEFORE];
        quiet.process_with(
            &quiet.drive,
            quiet.drive2.as_ref(),
            quiet.pulse.as_ref(),
            quiet.coupled.as_ref(),
            &mut temp,
            Output::Samples(&mut scratch),
        );
        (
            std::array::from_fn(|m| temp.q(m) + late[m]),
            temp.adc,
            temp.window,
            temp.refinement,
        )
    }

    /// Makes the page of deviates that holds sample `index` current, if the plan has noise.
    #[inline(always)]
    fn prepare_noise(&self, state: &mut SynthState, index: u64, detector: bool) {
        let key = PageKey {
            seed: state.seed,
            page: index / PAGE as u64,
            modes: if self.thermal_sigma.iter().any(|&s| s > 0.0) {
                self.modes.len() as u8
            } else {
                0
            },
            detector: detector && self.detector_sigma > 0.0,
        };
        if key.needs_deviates() {
            state.noise.prepare(key);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Engine, default_settings};

    /// The loop on sixteen lanes (which runs beyond eight modes) gives the eight lanes'
    /// stream for five modes, bit for bit: both engines, with noise, the ADC's filter,
    /// adhesion, and hard tapping. The lanes past the modes add exact zeros.
    #[test]
    fn sixteen_lanes_give_the_eight_lanes_stream() {
        for (engine, adhesion, distance) in [
            (Engine::Paper, false, 20e-9),
            (Engine::Coupled, false, 20e-9),
            (Engine::Coupled, true, 20e-9),
            (Engine::Coupled, false, 10e-9),
        ] {
            let mut settings = default_settings();
            settings.synth.engine = engine;
            settings.adhesion.enable = adhesion;
            settings.surface.distance = distance;
            let plan = SynthPlan::new(&settings).unwrap();
            let mut eight = SynthState::steady(&plan, 5);
            let mut sixteen = eight.clone();
            let (mut a, mut b) = (vec![0.0; 20_000], vec![0.0; 20_000]);
            plan.process(&mut eight, &mut a);
            plan.process_engines::<Portable<MAX_MODES>>(
                &plan.drive,
                plan.drive2.as_ref(),
                plan.pulse.as_ref(),
                plan.coupled.as_ref(),
                &mut sixteen,
                Output::Samples(&mut b),
            );
            assert!(
                a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{engine:?}, adhesion {adhesion}, A_set {distance:e}"
            );
            assert_eq!(eight.re, sixteen.re);
        }
    }

    /// The AVX-512 and AVX2 builds of the loop and the portable one give the same stream,
    /// bit for bit, for both engines with every noise source and the ADC's filter on (the
    /// builds this CPU has).
    #[test]
    fn the_vector_builds_of_the_loop_are_bit_identical_to_the_portable_one() {
        let builds: Vec<Build> = [Build::Avx512, Build::Avx2]
            .into_iter()
            .filter(|b| match b {
                Build::Avx512 => crate::cpu::avx512_available(),
                _ => crate::cpu::fma_available(),
            })
            .collect();
        eprintln!("builds compared with the portable one: {builds:?}");
        for engine in [Engine::Paper, Engine::Coupled] {
            let mut settings = default_settings();
            settings.synth.engine = engine;
            let plan = SynthPlan::new(&settings).unwrap();
            let mut portable = SynthState::steady(&plan, 7);
            portable.build = Build::Portable;
            let mut b = vec![0.0; 20_000];
            let mut fast: Vec<SynthState> = builds
                .iter()
                .map(|&build| SynthState {
                    build,
                    ..portable.clone()
                })
                .collect();
            plan.process(&mut portable, &mut b);
            for state in &mut fast {
                let mut a = vec![0.0; 20_000];
                plan.process(state, &mut a);
                assert_eq!(a, b, "{engine:?} {:?}", state.build);
            }
        }
    }
}
