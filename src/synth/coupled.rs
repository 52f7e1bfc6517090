//! The coupled engine on the real-time thread (physics.md §6): every mode integrated
//! together, sample by sample, with the Hertz force taken from the instantaneous tip
//! position `z = u + w(L)`.
//!
//! The modal states are the same as the paper engine's: the deviation `h_n = Y_n − Y⁰_n`
//! from the free (no contact) steady response, which is known in closed form and added
//! analytically. `h` obeys the damped modes driven by the tip force `g` (and the thermal
//! force), so a step is a Strang splitting:
//! - kick: `ḣ_n += (dt/2)·(φ_n(L)/M_n)·g(z)` (in `q = Ẏ − λ̄Y` a velocity kick adds to Re q);
//! - drift: the exact modal propagator `e^{λ dt}` plus the held thermal input;
//! - kick again with the force at the new position (and that force is the next step's
//!   first kick, so a step costs one force evaluation).
//!
//! A sample is one step while the tip is well clear of the surface at both of its ends
//! (where `g = 0` and the step is exact, or with adhesion where the van der Waals pull is
//! weak and smooth); otherwise it is redone in `/synth/contact_substeps` sub-steps
//! ([`DEFAULT_SUBSTEPS`] by default), so that the contact,
//! which lasts a few samples, is resolved. The thermal input is held
//! over the whole sample, and the sub-steps' propagation of it sums to exactly the
//! one-step value, so the noise does not depend on where the engine sub-steps.
//!
//! The sub-step follows an error budget: the splitting's error grows as (ω_c·dt)², where
//! ω_c = √(k_c·Σ φ_n(L)²/M_n) is the frequency of the tip on the contact's stiffness
//! k_c = (3/2)·κ·√δ at the deepest indentation δ. Each tap is integrated at one sub-step
//! count, the base count (`/synth/contact_substeps`) doubled up to [`REFINEMENTS`] times:
//! the count the last tap's stiffest contact needed with [`HEADROOM`] to spare. A sample
//! whose contact is stiffer than its count resolves within `/synth/substep_budget`
//! ([`DEFAULT_SUBSTEP_BUDGET`] by default) is redone at
//! twice the count, which the rest of the tap keeps. So a stiff contact or a lever with
//! many modes (its tip lighter) is resolved where it needs it, without a constant for the
//! user to tune; and a tap is not cut into samples of different counts, whose different
//! errors would add harmonics of their own (measured: mixing 12 and 24 per sample raised
//! H30's error on a 10-mode lever from 0.07 % to 0.21 %).

// The lanes are read and written in lock-step by index: the form the compiler vectorises.
#![allow(clippy::needless_range_loop)]

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::drive::Drive;
use super::lanes::{Lanes, Portable};
use super::modal::ModalKernel;
use super::phasor::Phasors;
use super::window::Moments;
use crate::physics::beam::{MAX_MODES, Mode};
use crate::physics::contact::{Adhesion, HertzContact};

/// With adhesion, a sample is one step only where the gap is at least this many
/// intermolecular distances a0 at both ends, where the pull is below 1/121 of its most and
/// its gradient below 1/1331 of its most. Measured against the offline reference with
/// adhesion (`tests/synth_coupled.rs`).
pub const ADHESION_REACH: f64 = 10.0;

/// Sub-steps per sample near and in contact by default (`/synth/contact_substeps`).
/// Measured against the offline reference (`tests/synth_coupled.rs`): see docs/ft-afm.md.
pub const DEFAULT_SUBSTEPS: usize = 12;

/// The default of `/synth/substep_budget`: the most ω_c·dt a sub-step may span in contact
/// (rad), ω_c being the tip's frequency on the contact stiffness at the deepest
/// indentation (module docs). Measured against
/// the offline orbit (`tests/synth_coupled.rs`, noise off): the worst error of H2–H18 is
/// about 28 %·(ω_c·dt)² over the default lever in hard tapping, 10- and 16-mode levers and
/// the 300 kHz lever, so this budget keeps it below 0.07 %, inside the 0.1 % goal.
/// The defaults (Table 1, 12 sub-steps) peak at 0.042: they are not refined.
pub const DEFAULT_SUBSTEP_BUDGET: f64 = 0.05;

/// The contact stiffness a tap's sub-step count is chosen for, over the stiffest the last
/// tap met: a tap up to this much stiffer (its indentation 44 % deeper) needs no redo.
pub const HEADROOM: f64 = 1.2;

/// The sub-step count the coupled engine's taps use, carried from sample to sample
/// ([`CoupledKernel::step_lanes`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Refinement {
    /// 0: the base count; r: 2^r times it.
    level: usize,
    /// The stiffest contact k_c (N/m) met since the last sub-stepped sample without one.
    peak: f64,
}

/// How many times a sample may be redone at twice the sub-steps to meet
/// the budget: up to 8× `/synth/contact_substeps`.
pub const REFINEMENTS: usize = 3;

/// Propagation of the mode lanes over one step: `q ← e^{λ dt}·q + noise·ξ`.
#[derive(Clone, Debug, Default)]
pub(crate) struct Drift {
    pub a_re: [f64; MAX_MODES],
    pub a_im: [f64; MAX_MODES],
    /// Held thermal input per standard normal deviate over this step, real and imaginary.
    pub noise_re: [f64; MAX_MODES],
    pub noise_im: [f64; MAX_MODES],
}

impl Drift {
    /// The drift over `dt` (s) of `modes` whose thermal input over the whole sample of
    /// `h` (s) has standard deviation `sigma` (m/s²) per mode; a sub-step carries the part
    /// of it that, propagated over the remaining sub-steps, sums to the whole.
    fn new(modes: &[Mode], dt: f64, thermal_sigma: &[f64]) -> Self {
        let mut d = Self::default();
        for (m, (mode, sigma)) in modes.iter().zip(thermal_sigma).enumerate() {
            let k = ModalKernel::new(mode, dt);
            d.a_re[m] = k.propagator.re;
            d.a_im[m] = k.propagator.im;
            d.noise_re[m] = k.hold_gain.re * sigma;
            d.noise_im[m] = k.hold_gain.im * sigma;
        }
        d
    }
}

/// A kernel's constants for [`CoupledKernel::step_lanes`], as lanes: the whole sample's
/// drift, the sub-steps' and the read-outs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CoupledLanes<V> {
    tip: V,
    kick: V,
    a_re: V,
    a_im: V,
    noise_re: V,
    noise_im: V,
    /// The base level's sub-step constants.
    sub: SubLanes<V>,
}

/// A [`SubstepLevel`]'s constants as lanes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SubLanes<V> {
    sub_a_re: V,
    sub_a_im: V,
    sub_noise_re: V,
    sub_noise_im: V,
    sub_gap_im: V,
    sub_gap_re: V,
    sub_gap_noise: V,
    two_gap_re: V,
    two_gap_im: V,
    two_gap_noise: V,
}

/// How [`CoupledKernel::step_lanes`] took a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Stepping {
    /// Sub-steps taken: 0 where the sample was one step.
    pub substeps: u32,
    /// Whether the sample took more sub-steps than the base count.
    pub refined: bool,
    /// Whether even the finest level left the sample over the budget.
    pub over_budget: bool,
}

impl Stepping {
    /// Whether the sample was sub-stepped.
    pub fn substepped(self) -> bool {
        self.substeps > 0
    }
}

/// The constants of one sub-step count: its drift, the gap's parts and the stiffest
/// contact it resolves within the budget.
#[derive(Clone, Debug)]
pub(crate) struct SubstepLevel {
    /// The sub-step's drift.
    sub: Drift,
    /// Sub-steps per sample (even).
    substeps: usize,
    /// Half a sub-step (s).
    half_dt: f64,
    /// Drive phasor per sub-step, e^{iΩh/S}; and the second excitation's, e^{iΩ₂h/S}
    /// (1 without one).
    sub_rotation: Complex64,
    sub_rotation2: Complex64,
    /// The tip's displacement after a sub-step's drift per unit of Im q, of Re q and of
    /// the thermal deviate before it (m), and per newton of the force whose kick opened
    /// the sub-step (Σ tip·a_im·kick times the kick's duration, m/N): half a sub-step
    /// for the first, a whole one for the others.
    sub_gap_im: [f64; MAX_MODES],
    sub_gap_re: [f64; MAX_MODES],
    sub_gap_noise: [f64; MAX_MODES],
    first_gap_per_force: f64,
    gap_per_force: f64,
    /// The same two sub-steps on: the tip's displacement after a sub-step's kick and two
    /// drifts per unit of the Re q and Im q before them and of the held deviate (m), and
    /// per newton-second of that kick (m/(N·s)).
    two_gap_re: [f64; MAX_MODES],
    two_gap_im: [f64; MAX_MODES],
    two_gap_noise: [f64; MAX_MODES],
    two_gap_per_impulse: f64,
    /// The stiffest contact k_c (N/m) this level resolves within the budget.
    stiffness_limit: f64,
}

impl SubstepLevel {
    /// `substeps` sub-steps of a sample of `h` (s) for `modes` with the kernel's `tip` and
    /// `kick` gains, driven at `omega` (rad/s), the thermal input as in [`Drift::new`];
    /// `inverse_mass` Σ φ_n(L)²/M_n (1/kg) and `budget` (ω_c·dt, rad; 0: none) set the
    /// stiffness limit.
    #[allow(clippy::too_many_arguments)]
    fn new(
        modes: &[Mode],
        tip: &[f64; MAX_MODES],
        kick: &[f64; MAX_MODES],
        h: f64,
        omega: f64,
        thermal_sigma: &[f64],
        substeps: usize,
        inverse_mass: f64,
        budget: f64,
    ) -> Self {
        let dt = h / substeps as f64;
        let sub = Drift::new(modes, dt, thermal_sigma);
        let (mut sub_gap_im, mut sub_gap_re) = ([0.0; MAX_MODES], [0.0; MAX_MODES]);
        let mut sub_gap_noise = [0.0; MAX_MODES];
        let mut sub_gap_kick = 0.0;
        for m in 0..modes.len() {
            sub_gap_im[m] = tip[m] * sub.a_re[m];
            sub_gap_re[m] = tip[m] * sub.a_im[m];
            sub_gap_noise[m] = tip[m] * sub.noise_im[m];
            sub_gap_kick += tip[m] * sub.a_im[m] * kick[m];
        }
        // Two drifts compose: the gap two sub-steps on is the one-sub-step gap of the
        // drifted lanes, Σ g_re·(a_re·re − a_im·im + n_re·ξ) + g_im·(a_im·re + a_re·im +
        // n_im·ξ) + g_ξ·ξ.
        let (mut two_gap_re, mut two_gap_im) = ([0.0; MAX_MODES], [0.0; MAX_MODES]);
        let mut two_gap_noise = [0.0; MAX_MODES];
        let mut two_gap_per_impulse = 0.0;
        for m in 0..modes.len() {
            two_gap_re[m] = sub_gap_re[m] * sub.a_re[m] + sub_gap_im[m] * sub.a_im[m];
            two_gap_im[m] = sub_gap_im[m] * sub.a_re[m] - sub_gap_re[m] * sub.a_im[m];
            two_gap_noise[m] = sub_gap_re[m] * sub.noise_re[m]
                + sub_gap_im[m] * sub.noise_im[m]
                + sub_gap_noise[m];
            two_gap_per_impulse += two_gap_re[m] * kick[m];
        }
        // ω_c·dt ≤ budget: k_c·Σφ²/M ≤ (budget/dt)².
        let omega_limit = budget / dt;
        let stiffness_limit = if budget > 0.0 {
            omega_limit * omega_limit / inverse_mass
        } else {
            f64::INFINITY
        };
        Self {
            sub_gap_im,
            sub_gap_re,
            sub_gap_noise,
            first_gap_per_force: sub_gap_kick * 0.5 * dt,
            gap_per_force: sub_gap_kick * dt,
            two_gap_re,
            two_gap_im,
            two_gap_noise,
            two_gap_per_impulse,
            sub,
            substeps,
            half_dt: 0.5 * dt,
            sub_rotation: Complex64::from_polar(1.0, omega * dt),
            sub_rotation2: Complex64::new(1.0, 0.0),
            stiffness_limit,
        }
    }

    /// This level's constants as lanes of `V`.
    #[inline(always)]
    fn lanes<V: Lanes>(&self) -> SubLanes<V> {
        SubLanes {
            sub_a_re: V::load(&self.sub.a_re),
            sub_a_im: V::load(&self.sub.a_im),
            sub_noise_re: V::load(&self.sub.noise_re),
            sub_noise_im: V::load(&self.sub.noise_im),
            sub_gap_im: V::load(&self.sub_gap_im),
            sub_gap_re: V::load(&self.sub_gap_re),
            sub_gap_noise: V::load(&self.sub_gap_noise),
            two_gap_re: V::load(&self.two_gap_re),
            two_gap_im: V::load(&self.two_gap_im),
            two_gap_noise: V::load(&self.two_gap_noise),
        }
    }
}

/// The coupled engine's contact as it integrated it ([`SynthPlan::coupled_trace`]).
///
/// [`SynthPlan::coupled_trace`]: super::SynthPlan::coupled_trace
#[derive(Clone, Debug)]
pub struct CoupledTrace {
    /// Tip force at the end of every sub-step, [`substeps`](Self::substeps) per sample (N).
    pub force: Vec<f64>,
    /// Sub-step length (s).
    pub dt: f64,
    /// Sub-steps per sample.
    pub substeps: usize,
    /// Tip position z at the start of every sample (m; the surface is at −A_set).
    pub tip: Vec<f64>,
    /// Drive phase word of the first sample (2^64 = one period; 0 = cosine peak).
    pub start_phase: u64,
    /// The free tip motion: z⁰ = Re[free_tip·e^{iθ}] (m).
    pub free_tip: Complex64,
    /// `/drive2`'s phase word at the first sample, and its part of the free tip motion,
    /// Re[free_tip2·e^{iθ₂}] (m; 0 where it does not drive).
    pub start_phase2: u64,
    pub free_tip2: Complex64,
}

/// Everything the coupled engine adds to a plan. Built off the real-time thread.
#[derive(Clone, Debug)]
pub struct CoupledKernel {
    /// Hertz prefactor κ_eff·√R (N/m^{3/2}).
    pub(crate) stiffness: f64,
    /// Adhesion HR/6 (N·m; 0 without adhesion), its intermolecular distance a0 (m) and the
    /// pull in contact HR/(6a0²) (N).
    strength: f64,
    a0: f64,
    pull_off: f64,
    adhesion: Option<Adhesion>,
    /// A_set: the surface is at z = −A_set (m).
    pub(crate) distance: f64,
    /// The free tip position (base plus free deflection): z⁰ = Re[free_tip·e^{iθ}] (m).
    pub(crate) free_tip: Complex64,
    /// The second excitation's part of it, Re[free_tip2·e^{iθ₂}] (m; 0 without one).
    pub(crate) free_tip2: Complex64,
    /// The free tip's curvature bound from the first excitation, Ω²·|z⁰| (m/s²).
    curvature: f64,
    /// The free tip's curvature bound from the second excitation, Ω₂²·|z⁰₂| (m/s²; 0
    /// without one), which the margin adds to the first's.
    curvature2: f64,
    /// Tip metres per unit of Im q: φ_n(L)/ω_d (s).
    pub(crate) tip: [f64; MAX_MODES],
    /// Change of Re q per newton-second of tip force: φ_n(L)/M_n (1/kg).
    pub(crate) kick: [f64; MAX_MODES],
    /// The whole sample's drift.
    pub(crate) full: Drift,
    /// The sub-steps of a sample near and in contact: `/synth/contact_substeps`, and twice,
    /// four and eight times as many for samples whose contact is stiffer than the base
    /// resolves within the budget.
    base: SubstepLevel,
    finer: [SubstepLevel; REFINEMENTS],
    /// The budget the levels were built for (ω_c·dt, rad; 0: none).
    budget: f64,
    /// Half the sample period (s).
    pub(crate) half_h: f64,
    /// A sample whose ends both leave at least this gap to the surface is one step (m):
    /// a bound on how far the tip can dip below the chord of its path within a sample.
    pub(crate) margin: f64,
    /// Base amplitude U (m).
    pub base_amplitude: f64,
    /// Drive angular frequency Ω (rad/s) and the contact, for the steady state.
    omega: f64,
    contact: HertzContact,
}

impl CoupledKernel {
    /// The kernel for `modes` sampled every `h` (s), driven at `omega` (rad/s) with free
    /// modal responses `drive_response` (Y⁰_n = Re[Ŷ_n e^{iθ}], m) from a base amplitude
    /// `base_amplitude` (m), the surface at `distance` (m), the `contact` and its
    /// `adhesion`, with the thermal input of each mode held over a sample of standard
    /// deviation `thermal_sigma`, a sample near and in contact cut into `substeps` (even,
    /// at least 2) or up to 8 times as many for a tap whose contact is stiffer than
    /// `substeps` resolve within `budget` (ω_c·dt, rad; 0: never).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        modes: &[Mode],
        h: f64,
        omega: f64,
        drive_response: &[Complex64],
        base_amplitude: f64,
        distance: f64,
        contact: &HertzContact,
        adhesion: Option<Adhesion>,
        thermal_sigma: &[f64],
        substeps: usize,
        budget: f64,
    ) -> Self {
        assert!(
            substeps >= 2 && substeps.is_multiple_of(2),
            "sub-steps must be even and at least 2, not {substeps}"
        );
        let mut tip = [0.0; MAX_MODES];
        let mut kick = [0.0; MAX_MODES];
        // u = U sin θ = Re[−iU e^{iθ}].
        let mut free_tip = Complex64::new(0.0, -base_amplitude);
        for (m, (mode, y)) in modes.iter().zip(drive_response).enumerate() {
            let kernel = ModalKernel::new(mode, h);
            tip[m] = kernel.tip_gain;
            kick[m] = kernel.force_gain;
            free_tip += y * mode.tip_value;
        }
        let curvature = free_curvature(modes, omega, drive_response, base_amplitude);
        let margin = free_margin(h, curvature, adhesion);
        let (mut strength, mut a0, mut pull_off) = (0.0, 1.0, 0.0);
        if let Some(a) = adhesion {
            strength = a.strength(contact.radius);
            a0 = a.distance;
            pull_off = a.pull_off(contact.radius);
        }
        // Σ φ_n(L)²/M_n: the tip's inverse mass on a point force, which sets the frequency
        // of the tip on the contact's stiffness.
        let inverse_mass: f64 = modes
            .iter()
            .zip(&kick)
            .map(|(mode, k)| mode.tip_value * k)
            .sum();
        let level = |substeps| {
            SubstepLevel::new(
                modes,
                &tip,
                &kick,
                h,
                omega,
                thermal_sigma,
                substeps,
                inverse_mass,
                budget,
            )
        };
        let base = level(substeps);
        let finer = std::array::from_fn(|r| level(substeps << (r + 1)));
        Self {
            stiffness: contact.stiffness_coefficient(),
            strength,
            a0,
            pull_off,
            adhesion,
            distance,
            free_tip,
            free_tip2: Complex64::new(0.0, 0.0),
            curvature,
            curvature2: 0.0,
            tip,
            kick,
            full: Drift::new(modes, h, thermal_sigma),
            base,
            finer,
            budget,
            half_h: 0.5 * h,
            margin,
            base_amplitude,
            omega,
            contact: *contact,
        }
    }

    /// Takes up a new drive (a PLL's frequency, an amplitude loop's excitation) for the
    /// lever's `modes` sampled every `h` (s): the free tip motion, the sub-steps' drive
    /// phasors and the margin follow it; the stepping constants do not depend on it.
    /// Allocation-free, so the real-time thread may call it.
    pub(crate) fn set_drive(&mut self, modes: &[Mode], h: f64, drive: &Drive) {
        let omega = drive.omega();
        let response = &drive.response[..modes.len()];
        self.free_tip = drive.free_tip(modes);
        self.curvature = free_curvature(modes, omega, response, drive.base_amplitude);
        self.margin = free_margin(h, self.curvature + self.curvature2, self.adhesion);
        self.base_amplitude = drive.base_amplitude;
        self.omega = omega;
        for level in std::iter::once(&mut self.base).chain(&mut self.finer) {
            level.sub_rotation = Complex64::from_polar(1.0, omega * 2.0 * level.half_dt);
        }
    }

    /// Takes up the second excitation `drive2` (or none) beside the first: the free tip
    /// motion's second part, the sub-steps' second phasors and the margin. Built off the
    /// real-time thread with the plan.
    pub(crate) fn set_second_drive(&mut self, modes: &[Mode], h: f64, drive2: Option<&Drive>) {
        let (free_tip2, curvature2, omega2) = match drive2 {
            Some(d) => (
                d.free_tip(modes),
                free_curvature(
                    modes,
                    d.omega(),
                    &d.response[..modes.len()],
                    d.base_amplitude,
                ),
                d.omega(),
            ),
            None => (Complex64::new(0.0, 0.0), 0.0, 0.0),
        };
        self.free_tip2 = free_tip2;
        self.curvature2 = curvature2;
        self.margin = free_margin(h, self.curvature + curvature2, self.adhesion);
        for level in std::iter::once(&mut self.base).chain(&mut self.finer) {
            level.sub_rotation2 = Complex64::from_polar(1.0, omega2 * 2.0 * level.half_dt);
        }
    }

    /// Tip–sample force (N) at a gap `gap` = z + A_set (m) between tip and surface.
    #[inline(always)]
    pub(crate) fn force(&self, gap: f64) -> f64 {
        if gap < 0.0 {
            let delta = -gap;
            let hertz = self.stiffness * delta * delta.sqrt();
            // x − 0 is x, bit for bit: without adhesion the subtraction would only lengthen
            // the sub-steps' chain from one force to the next.
            if self.pull_off != 0.0 {
                hertz - self.pull_off
            } else {
                hertz
            }
        } else if self.strength != 0.0 {
            let d = self.a0 + gap;
            -self.strength / (d * d)
        } else {
            0.0
        }
    }

    /// [`force`](Self::force) at `gap` (N), and the gap after it, `base + per_force·force`
    /// (m), with the Hertz branch's product fused: `(per_force·κδ)·√δ + base`, so the
    /// sub-steps' chain from one gap to the next is a square root and one multiply-add.
    #[inline(always)]
    fn force_and_gap(&self, gap: f64, base: f64, per_force: f64) -> (f64, f64) {
        if gap < 0.0 {
            let delta = -gap;
            let root = delta.sqrt();
            let k_delta = self.stiffness * delta;
            let hertz = k_delta * root;
            if self.pull_off != 0.0 {
                let next = (per_force * k_delta).mul_add(root, base - per_force * self.pull_off);
                (hertz - self.pull_off, next)
            } else {
                (hertz, (per_force * k_delta).mul_add(root, base))
            }
        } else if self.strength != 0.0 {
            let d = self.a0 + gap;
            let g = -self.strength / (d * d);
            (g, per_force.mul_add(g, base))
        } else {
            (0.0, base)
        }
    }

    /// The constants of [`step_lanes`](Self::step_lanes) as lanes of `V`.
    #[inline(always)]
    pub(crate) fn lanes<V: Lanes>(&self) -> CoupledLanes<V> {
        CoupledLanes {
            tip: V::load(&self.tip),
            kick: V::load(&self.kick),
            a_re: V::load(&self.full.a_re),
            a_im: V::load(&self.full.a_im),
            noise_re: V::load(&self.full.noise_re),
            noise_im: V::load(&self.full.noise_im),
            sub: self.base.lanes(),
        }
    }

    /// Sub-steps of a sample near and in contact before any refinement
    /// (`/synth/contact_substeps`).
    pub(crate) fn substeps(&self) -> usize {
        self.base.substeps
    }

    /// Tip position z (m) at drive phasor `rho` with mode lanes `im` (Im q).
    #[inline(always)]
    pub(crate) fn tip_position<V: Lanes, P: Phasors>(
        &self,
        c: &CoupledLanes<V>,
        rho: P,
        im: V,
    ) -> f64 {
        rho.real(self.free_tips()) + c.tip.mul(im).sum()
    }

    /// The free tip's complex amplitudes on each excitation, as the loop's phasors carry
    /// them.
    #[inline(always)]
    fn free_tips<P: Phasors>(&self) -> P {
        P::new(self.free_tip, self.free_tip2)
    }

    /// The step of a sample clear of the surface at both ends without adhesion, where the
    /// tip force is zero throughout: the lanes `re`, `im` advanced from the tip position
    /// `tip` (m) at the sample's start to the phasor `next` with the thermal deviates `z`,
    /// and the tip position at its end; `None` if adhesion is on, if `tip` is unknown
    /// (NaN) or near the surface, or if the end is. Where it gives a step,
    /// [`step_lanes`](Self::step_lanes) gives the same bits with zero moments; this one
    /// leaves out that step's force law and bookkeeping, which nine samples in ten of
    /// tapping skip.
    #[inline(always)]
    pub(crate) fn clear_step<V: Lanes, P: Phasors>(
        &self,
        c: &CoupledLanes<V>,
        re: V,
        im: V,
        next: P,
        z: V,
        tip: f64,
    ) -> Option<(V, V, f64)> {
        // NaN compares false: an unknown start goes to `step_lanes`.
        if self.strength == 0.0 && tip + self.distance >= self.margin {
            let r1 = c
                .a_im
                .neg_mul_add(im, c.a_re.mul_add(re, c.noise_re.mul(z)));
            let i1 = c.a_im.mul_add(re, c.a_re.mul_add(im, c.noise_im.mul(z)));
            let z1 = self.tip_position(c, next, i1);
            (z1 + self.distance >= self.margin).then_some((r1, i1, z1))
        } else {
            None
        }
    }

    /// Advances the lanes `re`, `im` (Re q, Im q) by one sample from drive phasor `rho` to
    /// `next` with the thermal deviates `z` (one per mode lane), with the constants `c` of
    /// this kernel. Returns the lanes and the tip position at `next`, and how it stepped; if
    /// it sub-stepped, `mid` holds the lanes' Re q and Im q at the sample's midpoint, before
    /// the kick there (for the ADC's window). `moments` gets the kicks' impulses (N·s) and
    /// their first moments over the sample's halves, the kicks at the sample's ends
    /// included. `tip` is the position at `rho` if known (NaN if not: it is computed), so a
    /// loop of steps computes each position once. `record` is handed the index j and the
    /// force at the end of every base sub-step j ([`substeps`](Self::substeps) values per
    /// sample, the end-of-sample force repeated where the sample is one step; a refined
    /// sample hands those of its sub-steps that end on the base grid, and a sample redone
    /// hands them again from j = 0); the real-time loop passes a no-op, which compiles away.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(crate) fn step_lanes<V: Lanes, P: Phasors>(
        &self,
        c: &CoupledLanes<V>,
        re: V,
        im: V,
        rho: P,
        next: P,
        z: V,
        tip: f64,
        mid: &mut (V, V),
        moments: &mut Moments,
        refinement: &mut Refinement,
        record: &mut impl FnMut(usize, f64),
    ) -> (V, V, f64, Stepping) {
        let z0 = if tip.is_nan() {
            self.tip_position(c, rho, im)
        } else {
            tip
        };
        let gap0 = z0 + self.distance;
        let g0 = self.force(gap0);
        let mut r = re;
        if g0 != 0.0 {
            r = c.kick.mul_add(V::splat(self.half_h * g0), r);
        }
        let h = 2.0 * self.half_h;
        let r1 = c.a_im.neg_mul_add(im, c.a_re.mul_add(r, c.noise_re.mul(z)));
        let i1 = c.a_im.mul_add(r, c.a_re.mul_add(im, c.noise_im.mul(z)));
        let z1 = self.tip_position(c, next, i1);
        let gap1 = z1 + self.distance;
        if gap0.min(gap1) >= self.margin {
            // Clear of the surface at both ends: no force at the end, or adhesion's weak one.
            let mut r1 = r1;
            let mut g1 = 0.0;
            moments.s1 += self.half_h * g0;
            if self.strength != 0.0 {
                g1 = self.force(gap1);
                r1 = c.kick.mul_add(V::splat(self.half_h * g1), r1);
                moments.kick(self.half_h * g1, h, true);
            }
            for j in 0..self.base.substeps {
                record(j, g1);
            }
            return (r1, i1, z1, Stepping::default());
        }
        let before = *moments;
        let mut r = refinement.level.min(REFINEMENTS);
        let (mut re1, mut im1, mut z1, deepest) =
            self.at_level(c, r, re, im, rho, z, g0, gap0, mid, moments, record);
        // The contact's stiffness at the deepest indentation met, against the budget.
        let stiffness = 1.5 * self.stiffness * (-deepest).max(0.0).sqrt();
        while r < REFINEMENTS && stiffness > self.level(r).stiffness_limit {
            // Redone from the same start (a sample's inputs are its arguments) at twice
            // the count, which the rest of the tap keeps.
            r += 1;
            *moments = before;
            let refined = self.at_level(c, r, re, im, rho, z, g0, gap0, mid, moments, record);
            (re1, im1, z1) = (refined.0, refined.1, refined.2);
        }
        let stepping = Stepping {
            substeps: self.level(r).substeps as u32,
            refined: r > 0,
            over_budget: stiffness > self.level(r).stiffness_limit,
        };
        refinement.level = r;
        if deepest >= 0.0 {
            // Near the surface, not in it: between taps. The next tap's count is the one
            // the last tap's stiffest contact needs with headroom (finer or coarser).
            if refinement.peak > 0.0 {
                let want = refinement.peak * HEADROOM;
                refinement.level = (0..REFINEMENTS)
                    .find(|&r| want <= self.level(r).stiffness_limit)
                    .unwrap_or(REFINEMENTS);
                refinement.peak = 0.0;
            }
        } else {
            refinement.peak = refinement.peak.max(stiffness);
        }
        (re1, im1, z1, stepping)
    }

    /// The sub-step level `r`: 0 the base count, r the base count times 2^r.
    #[inline(always)]
    fn level(&self, r: usize) -> &SubstepLevel {
        if r == 0 {
            &self.base
        } else {
            &self.finer[r - 1]
        }
    }

    /// [`sub_step`](Self::sub_step) at level `r`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn at_level<V: Lanes, P: Phasors>(
        &self,
        c: &CoupledLanes<V>,
        r: usize,
        re: V,
        im: V,
        rho: P,
        z: V,
        g0: f64,
        gap0: f64,
        mid: &mut (V, V),
        moments: &mut Moments,
        record: &mut impl FnMut(usize, f64),
    ) -> (V, V, f64, f64) {
        if r > 0 {
            self.finer_steps(c, r, re, im, rho, z, g0, gap0, mid, moments, record)
        } else if self.base.substeps == DEFAULT_SUBSTEPS {
            // The default count compiled as a constant: its loop's bounds and midpoint known.
            self.sub_step::<V, P, DEFAULT_SUBSTEPS>(
                c, &self.base, &c.sub, 1, re, im, rho, z, g0, gap0, mid, moments, record,
            )
        } else {
            self.sub_step::<V, P, 0>(
                c, &self.base, &c.sub, 1, re, im, rho, z, g0, gap0, mid, moments, record,
            )
        }
    }

    /// [`sub_step`](Self::sub_step) at a finer level `r` ≥ 1, its lanes loaded here. Inline
    /// like the rest: the loop is compiled once per instruction set under its target
    /// features, which a function out of line would not inherit (out of line, every lane
    /// operation became a call: the synthesis ran 9× slower).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn finer_steps<V: Lanes, P: Phasors>(
        &self,
        c: &CoupledLanes<V>,
        r: usize,
        re: V,
        im: V,
        rho: P,
        z: V,
        g0: f64,
        gap0: f64,
        mid: &mut (V, V),
        moments: &mut Moments,
        record: &mut impl FnMut(usize, f64),
    ) -> (V, V, f64, f64) {
        let level = self.level(r);
        let lanes = level.lanes::<V>();
        self.sub_step::<V, P, 0>(
            c,
            level,
            &lanes,
            1 << r,
            re,
            im,
            rho,
            z,
            g0,
            gap0,
            mid,
            moments,
            record,
        )
    }

    /// The sub-steps of [`step_lanes`](Self::step_lanes) at `level` (its lanes `s`) from
    /// the force `g0` at the sample's start, the two half kicks between them merged into
    /// one. The sub-steps are a chain from one force to the next, so the gap at the end of
    /// sub-step j is taken apart by what it waits for: the lanes two sub-steps back (before
    /// sub-step j − 1's kick, a sum across lanes that runs beside the chain), that kick's
    /// part (Φ·impulse) and sub-step j's own kick's part (C·g, fused into the force law).
    /// The chain from one gap to the next is then the force law's square root and one
    /// multiply-add; the lanes' arithmetic and the kick's part, a sub-step ahead of it, run
    /// beside it. `FIXED`: the level's count of sub-steps as a constant, or 0 to read it.
    /// `stride`: sub-steps per base sub-step, for `record`. Returns the lanes, the tip
    /// position at the end and the smallest gap met (m; from `gap0`, the start's).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn sub_step<V: Lanes, P: Phasors, const FIXED: usize>(
        &self,
        c: &CoupledLanes<V>,
        level: &SubstepLevel,
        s: &SubLanes<V>,
        stride: usize,
        mut re: V,
        mut im: V,
        rho: P,
        z: V,
        g0: f64,
        gap0: f64,
        mid: &mut (V, V),
        moments: &mut Moments,
        record: &mut impl FnMut(usize, f64),
    ) -> (V, V, f64, f64) {
        let dt = 2.0 * level.half_dt;
        let h = 2.0 * self.half_h;
        let rotation = P::new(level.sub_rotation, level.sub_rotation2);
        let free_tips = self.free_tips::<P>();
        let mut r = rho.times(rotation);
        // Sub-step 0: its gap from the lanes it starts from.
        let p = s
            .sub_gap_im
            .mul_add(im, s.sub_gap_re.mul_add(re, s.sub_gap_noise.mul(z)));
        let mut gap = r.real(free_tips) + p.sum() + self.distance + level.first_gap_per_force * g0;
        let mut deepest = gap0;
        let mut g = g0;
        let mut impulse = level.half_dt * g0;
        let substeps = if FIXED > 0 { FIXED } else { level.substeps };
        for j in 1..=substeps {
            // The lanes before the kick of sub-step j − 1 give the gap at the end of
            // sub-step j, with that kick's part (Φ·impulse) and sub-step j's (C·g) added.
            let two = s
                .two_gap_re
                .mul_add(re, s.two_gap_im.mul_add(im, s.two_gap_noise.mul(z)));
            // Beside the chain: the deepest point for the budget.
            deepest = deepest.min(gap);
            let next_g;
            if j < substeps {
                r = r.times(rotation);
                let base = r.real(free_tips)
                    + two.sum()
                    + self.distance
                    + level.two_gap_per_impulse * impulse;
                (next_g, gap) = self.force_and_gap(gap, base, level.gap_per_force);
            } else {
                next_g = self.force(gap);
            }
            // The base grid's sub-steps only (a stride of 1 is every one: no division).
            if stride == 1 {
                record(j - 1, next_g);
            } else if j.is_multiple_of(stride) {
                record(j / stride - 1, next_g);
            }
            if g != 0.0 {
                re = c.kick.mul_add(V::splat(impulse), re);
            }
            // The kick at (j − 1)·dt: the midpoint's (j = S/2 + 1) is in the second half.
            // Through u32 (the count is a u32 in the settings): one conversion instruction,
            // where a u64's takes five without AVX-512. The same value.
            moments.kick(impulse, f64::from((j - 1) as u32) * dt, j > substeps / 2);
            let r1 = s
                .sub_a_im
                .neg_mul_add(im, s.sub_a_re.mul_add(re, s.sub_noise_re.mul(z)));
            im = s
                .sub_a_im
                .mul_add(re, s.sub_a_re.mul_add(im, s.sub_noise_im.mul(z)));
            re = r1;
            if j == substeps / 2 {
                // The midpoint, before its kick.
                *mid = (re, im);
            }
            g = next_g;
            impulse = dt * g;
        }
        if g != 0.0 {
            re = c.kick.mul_add(V::splat(level.half_dt * g), re);
        }
        moments.kick(level.half_dt * g, h, true);
        (re, im, gap - self.distance, deepest)
    }

    /// The modal states at drive phase `theta` (rad) on the engine's own periodic orbit: the
    /// engine run from the free orbit (h = 0, as an approach from far reaches it) without
    /// noise, with a step of a whole fraction of the period near `h` so that whole periods
    /// end at `theta` again, for enough periods that mode 1's transient has decayed by
    /// e^{−15}. Off the real-time thread (milliseconds).
    pub(crate) fn steady_state(
        &self,
        modes: &[Mode],
        drive_response: &[Complex64],
        h: f64,
        theta: f64,
    ) -> ([Complex64; MAX_MODES], Refinement) {
        let (re, im, refinement) =
            self.orbit(modes, drive_response, h, theta, 0, &mut |_, _, _| {});
        (
            std::array::from_fn(|m| Complex64::new(re[m], im[m])),
            refinement,
        )
    }

    /// One period of the engine's own periodic orbit ([`steady_state`](Self::steady_state)
    /// from θ = 0), noise-free: the photodiode's amplitude at the drive frequency (m, peak;
    /// the demodulation of `drive_signal` plus Σ `lever`·Im q over the period's samples, as
    /// the scan's feedback reads it) and the drive phase of the largest tip force (rad;
    /// `None` out of contact). Off the real-time thread.
    pub(crate) fn orbit_reading(
        &self,
        modes: &[Mode],
        drive_response: &[Complex64],
        h: f64,
        lever: &[f64; MAX_MODES],
        drive_signal: Complex64,
    ) -> (f64, Option<f64>) {
        let mut sum = Complex64::new(0.0, 0.0);
        let mut samples = 0usize;
        let (mut peak, mut peak_theta) = (0.0, None);
        self.orbit(modes, drive_response, h, 0.0, 1, &mut |theta, im, force| {
            let rho = Complex64::from_polar(1.0, theta);
            let signal =
                (drive_signal * rho).re + lever.iter().zip(im).map(|(l, q)| l * q).sum::<f64>();
            sum += signal * rho.conj();
            samples += 1;
            if force > peak {
                peak = force;
                peak_theta = Some(theta);
            }
        });
        (2.0 * sum.norm() / samples.max(1) as f64, peak_theta)
    }

    /// Runs the noise-free engine from the free orbit to its periodic orbit (see
    /// [`steady_state`](Self::steady_state)), then `extra` more periods, handing `sample`
    /// the drive phase, the lanes' Im q and the largest sub-step force of every step of
    /// those. Returns the lanes at the end and the sub-step count its taps settled on.
    fn orbit(
        &self,
        modes: &[Mode],
        drive_response: &[Complex64],
        h: f64,
        theta: f64,
        extra: usize,
        sample: &mut impl FnMut(f64, &[f64; MAX_MODES], f64),
    ) -> ([f64; MAX_MODES], [f64; MAX_MODES], Refinement) {
        let omega = self.omega;
        let period = 2.0 * PI / omega;
        let steps = (period / h).round().max(8.0) as usize;
        let step = period / steps as f64;
        let silent = vec![0.0; modes.len()];
        let mut kernel = Self::new(
            modes,
            step,
            omega,
            drive_response,
            self.base_amplitude,
            self.distance,
            &self.contact,
            self.adhesion,
            &silent,
            self.base.substeps,
            self.budget,
        );
        // A scan may have set another surface under the tip.
        kernel.stiffness = self.stiffness;
        let q1 = modes.first().map_or(1.0, |m| m.q);
        let periods = ((15.0 * q1 / PI).ceil() as usize).clamp(50, 50_000);
        type All = Portable<MAX_MODES>;
        let c = kernel.lanes::<All>();
        let (mut re, mut im) = (All::splat(0.0), All::splat(0.0));
        let mut mid = (re, im);
        let mut moments = Moments::default();
        let mut refinement = Refinement::default();
        let z = All::splat(0.0);
        for period in 0..periods + extra {
            let mut rho = Complex64::from_polar(1.0, theta);
            for j in 0..steps {
                // Re-anchored every step: the orbit must close on `theta` exactly.
                let phase = theta + omega * step * j as f64;
                let next = Complex64::from_polar(1.0, phase + omega * step);
                // The last `extra` periods are handed to `sample`.
                let recorded = period >= periods;
                let mut before = [0.0; MAX_MODES];
                if recorded {
                    im.store(&mut before);
                }
                let mut largest = 0.0f64;
                (re, im, _, _) = kernel.step_lanes(
                    &c,
                    re,
                    im,
                    rho,
                    next,
                    z,
                    f64::NAN,
                    &mut mid,
                    &mut moments,
                    &mut refinement,
                    &mut |j, g| {
                        // A sample redone finer hands its forces again from j = 0.
                        if j == 0 {
                            largest = 0.0;
                        }
                        largest = largest.max(g);
                    },
                );
                if recorded {
                    sample(phase, &before, largest);
                }
                rho = next;
            }
        }
        let (mut re_out, mut im_out) = ([0.0; MAX_MODES], [0.0; MAX_MODES]);
        re.store(&mut re_out);
        im.store(&mut im_out);
        (re_out, im_out, refinement)
    }
}

/// The bound on the free tip path's curvature (m/s²) of a drive at `omega` (rad/s) with
/// modal responses `drive_response` from base amplitude `base_amplitude` (m): Ω² times
/// the base's and each mode's tip amplitude.
fn free_curvature(
    modes: &[Mode],
    omega: f64,
    drive_response: &[Complex64],
    base_amplitude: f64,
) -> f64 {
    let mut curvature = omega * omega * base_amplitude;
    for (mode, y) in modes.iter().zip(drive_response) {
        curvature += omega * omega * (y * mode.tip_value).norm();
    }
    curvature
}

/// How far from the surface (m) a sample's ends must keep the tip for the whole sample to
/// be clear of it: twice the chord bound a·h²/8 of the tip's free path (its curvature
/// bounded by Ω²|z⁰| for the drive and ω_n² per mode at its drive amplitude; the tap
/// response is caught by the ends of the sample, where contact starts), never below 1 pm,
/// and adhesion's reach.
fn free_margin(h: f64, curvature: f64, adhesion: Option<Adhesion>) -> f64 {
    debug_assert!(curvature >= 0.0);
    let margin = (curvature * h * h / 4.0).max(1e-12);
    match adhesion {
        Some(a) => margin.max(ADHESION_REACH * a.distance),
        None => margin,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::Cantilever;
    use crate::physics::contact::Elastic;

    /// A kernel for the default lever far from the surface, with thermal input.
    fn far_kernel(h: f64) -> (CoupledKernel, Vec<Mode>) {
        kernel_at(h, 1.0, None)
    }

    /// A kernel for the default lever with the surface at `distance` (m) and `adhesion`,
    /// with thermal input.
    fn kernel_at(h: f64, distance: f64, adhesion: Option<Adhesion>) -> (CoupledKernel, Vec<Mode>) {
        kernel_with(h, distance, adhesion, DEFAULT_SUBSTEPS)
    }

    /// [`kernel_at`] with `substeps` sub-steps in contact.
    fn kernel_with(
        h: f64,
        distance: f64,
        adhesion: Option<Adhesion>,
        substeps: usize,
    ) -> (CoupledKernel, Vec<Mode>) {
        let c = Cantilever::new(100e3, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap();
        let si = Elastic {
            youngs_modulus: 129e9,
            poisson: 0.28,
        };
        let contact = HertzContact::new(si, si, 10e-9);
        let response: Vec<Complex64> = c.modes.iter().map(|_| Complex64::new(1e-9, 0.0)).collect();
        let sigma = vec![1e3; c.modes.len()];
        let k = CoupledKernel::new(
            &c.modes,
            h,
            2.0 * PI * 100e3,
            &response,
            1e-10,
            distance,
            &contact,
            adhesion,
            &sigma,
            substeps,
            DEFAULT_SUBSTEP_BUDGET,
        );
        (k, c.modes)
    }

    /// Sample `n`'s stand-ins for the thermal deviates: a fixed pattern, the same every run.
    fn deviates(n: usize) -> Portable<8> {
        Portable::load(&std::array::from_fn::<f64, 8, _>(|m| {
            ((n * 7 + m * 13) % 11) as f64 - 5.0
        }))
    }

    #[test]
    fn sub_steps_carry_the_same_held_thermal_input_as_one_step() {
        let (one, _) = far_kernel(1e-7);
        let mut sub = one.clone();
        // Force sub-stepping everywhere: without contact it must change nothing but rounding.
        sub.margin = f64::INFINITY;
        type P = Portable<8>;
        let (lanes_one, lanes_sub) = (one.lanes::<P>(), sub.lanes::<P>());
        let (mut a_re, mut a_im) = (P::splat(0.0), P::splat(0.0));
        let (mut b_re, mut b_im) = (P::splat(0.0), P::splat(0.0));
        let rotation = Complex64::from_polar(1.0, 2.0 * PI * 100e3 * 1e-7);
        let mut rho = Complex64::new(1.0, 0.0);
        let mut mid = (a_re, a_im);
        let mut moments = Moments::default();
        let (mut refinement_one, mut refinement_sub) =
            (Refinement::default(), Refinement::default());
        for n in 0..5000 {
            let z = deviates(n);
            let next = rho * rotation;
            let substepped;
            (a_re, a_im, _, substepped) = one.step_lanes(
                &lanes_one,
                a_re,
                a_im,
                rho,
                next,
                z,
                f64::NAN,
                &mut mid,
                &mut moments,
                &mut refinement_one,
                &mut |_, _| {},
            );
            assert!(!substepped.substepped());
            let substepped;
            (b_re, b_im, _, substepped) = sub.step_lanes(
                &lanes_sub,
                b_re,
                b_im,
                rho,
                next,
                z,
                f64::NAN,
                &mut mid,
                &mut moments,
                &mut refinement_sub,
                &mut |_, _| {},
            );
            assert!(substepped.substepped());
            rho = next;
        }
        let array = |x: P| {
            let mut a = [0.0; 8];
            x.store(&mut a);
            a
        };
        let (a_re, a_im, b_re, b_im) = (array(a_re), array(a_im), array(b_re), array(b_im));
        for m in 0..5 {
            let scale = a_re[m].abs().max(a_im[m].abs());
            assert!(scale > 0.0);
            assert!((a_re[m] - b_re[m]).abs() < 1e-9 * scale, "mode {m} re");
            assert!((a_im[m] - b_im[m]).abs() < 1e-9 * scale, "mode {m} im");
        }
    }

    /// Where `clear_step` gives a step, it is `step_lanes`'s bit for bit, with no force and
    /// no sub-steps; it gives none where the tip nears the surface, nor with adhesion.
    #[test]
    fn a_clear_step_is_the_general_step_bit_for_bit() {
        type P = Portable<8>;
        let bits = |x: P| {
            let mut a = [0.0; 8];
            x.store(&mut a);
            a.map(f64::to_bits)
        };
        let h = 1e-7;
        let rotation = Complex64::from_polar(1.0, 2.0 * PI * 100e3 * h);
        let (far, _) = far_kernel(h);
        // The surface a third of the way into the free swing: the tip taps.
        let amplitude = far.free_tip.norm();
        let adhesion = Adhesion {
            hamaker: 6.4e-20,
            distance: 0.165e-9,
        };
        for adhesion in [None, Some(adhesion)] {
            let (k, _) = kernel_at(h, amplitude / 3.0, adhesion);
            let c = k.lanes::<P>();
            let (mut re, mut im) = (P::splat(0.0), P::splat(0.0));
            let mut rho = Complex64::new(1.0, 0.0);
            let mut tip = f64::NAN;
            let mut refinement = Refinement::default();
            let (mut clear, mut near) = (0, 0);
            for n in 0..20_000 {
                let z = deviates(n);
                let next = rho * rotation;
                let quick = k.clear_step(&c, re, im, next, z, tip);
                let mut mid = (re, im);
                let mut moments = Moments::default();
                let substepped;
                (re, im, tip, substepped) = k.step_lanes(
                    &c,
                    re,
                    im,
                    rho,
                    next,
                    z,
                    tip,
                    &mut mid,
                    &mut moments,
                    &mut refinement,
                    &mut |_, _| {},
                );
                let substepped = substepped.substepped();
                match quick {
                    Some((q_re, q_im, q_tip)) => {
                        clear += 1;
                        assert!(adhesion.is_none(), "a clear step with adhesion");
                        assert_eq!(bits(q_re), bits(re), "sample {n}: Re q");
                        assert_eq!(bits(q_im), bits(im), "sample {n}: Im q");
                        assert_eq!(q_tip.to_bits(), tip.to_bits(), "sample {n}: tip");
                        assert!(!substepped, "sample {n}");
                        assert_eq!(moments, Moments::default(), "sample {n}");
                    }
                    None => near += 1,
                }
                rho = next;
            }
            if adhesion.is_none() {
                // Both kinds of sample were met, the tapping ones sub-stepped.
                assert!(clear > 10_000 && near > 1_000, "{clear} clear, {near} not");
            }
        }
    }

    /// What a run of samples of `k` gave: per sample its stepping and whether it was
    /// redone (its forces handed from j = 0 more than once), and the lanes' bits at the end.
    struct Run {
        steps: Vec<Stepping>,
        redone: Vec<bool>,
        bits: [u64; 16],
    }

    /// `samples` samples of `k` tapping from the free orbit without thermal input (so the
    /// taps settle on one periodic orbit), from `refinement`; `soften` at sample `soften.0` multiplies the contact's stiffness by
    /// `soften.1` (as a scan does, moving onto another material).
    fn tap_run(
        k: &mut CoupledKernel,
        samples: usize,
        mut refinement: Refinement,
        soften: (usize, f64),
    ) -> Run {
        type P = Portable<8>;
        let rotation = Complex64::from_polar(1.0, 2.0 * PI * 100e3 * 1e-7);
        let c = k.lanes::<P>();
        let (mut re, mut im) = (P::splat(0.0), P::splat(0.0));
        let mut rho = Complex64::new(1.0, 0.0);
        let mut tip = f64::NAN;
        let mut run = Run {
            steps: Vec::new(),
            redone: Vec::new(),
            bits: [0; 16],
        };
        for n in 0..samples {
            if n == soften.0 {
                k.stiffness *= soften.1;
            }
            let z = P::splat(0.0);
            let next = rho * rotation;
            let mut mid = (re, im);
            let mut moments = Moments::default();
            let mut starts = 0;
            let stepping;
            (re, im, tip, stepping) = k.step_lanes(
                &c,
                re,
                im,
                rho,
                next,
                z,
                tip,
                &mut mid,
                &mut moments,
                &mut refinement,
                &mut |j, _| starts += usize::from(j == 0),
            );
            run.steps.push(stepping);
            run.redone.push(starts > 1);
            rho = next;
        }
        let (mut a, mut b) = ([0.0; 8], [0.0; 8]);
        re.store(&mut a);
        im.store(&mut b);
        for m in 0..8 {
            run.bits[m] = a[m].to_bits();
            run.bits[8 + m] = b[m].to_bits();
        }
        run
    }

    /// The surface of [`a_clear_step_is_the_general_step_bit_for_bit`]'s tapping, its
    /// contact `stiffer` times the silicon's: taps stiffer than 12 sub-steps resolve.
    fn stiff_kernel(substeps: usize, stiffer: f64) -> CoupledKernel {
        let (far, _) = far_kernel(1e-7);
        let (mut k, _) = kernel_with(1e-7, far.free_tip.norm() / 3.0, None, substeps);
        k.stiffness *= stiffer;
        k
    }

    /// The settings' default budget is this module's, whose docs say how it was measured.
    #[test]
    fn the_default_budget_is_the_settings_default() {
        let s = crate::config::default_settings();
        assert_eq!(s.synth.substep_budget, DEFAULT_SUBSTEP_BUDGET);
        assert_eq!(s.synth.contact_substeps as usize, DEFAULT_SUBSTEPS);
    }

    /// A tap refined to twice the base count is, bit for bit, the tap of a kernel whose
    /// base count is twice as many: a refinement is the finer count, not an approximation.
    /// (Over the first 4000 samples from the free orbit, where every tap of this contact
    /// needs 24 or 48 sub-steps.)
    #[test]
    fn a_refined_tap_is_the_finer_counts_tap_bit_for_bit() {
        let mut k12 = stiff_kernel(12, 8.0);
        let mut k24 = stiff_kernel(24, 8.0);
        let from_1 = Refinement {
            level: 1,
            peak: 0.0,
        };
        let a = tap_run(&mut k12, 4000, from_1, (usize::MAX, 1.0));
        let b = tap_run(&mut k24, 4000, Refinement::default(), (usize::MAX, 1.0));
        let contact: Vec<_> = a.steps.iter().filter(|s| s.substepped()).collect();
        assert!(contact.len() > 200, "{} samples in contact", contact.len());
        // Every tap needed more than the 12 sub-steps, and 24 or 48 were within budget.
        assert!(contact.iter().all(|s| s.refined && !s.over_budget));
        assert!(contact.iter().any(|s| s.substeps == 24));
        assert!(contact.iter().any(|s| s.substeps == 48));
        assert_eq!(a.bits, b.bits);
        for (sa, sb) in a.steps.iter().zip(&b.steps) {
            assert_eq!(sa.substeps, sb.substeps);
        }
    }

    /// From the base count, the first stiff tap is redone finer where it crosses the
    /// budget. Once the taps have settled, every tap starts at the finer count it needs (no
    /// redo). When the contact turns soft, the taps after the next return to the base count.
    #[test]
    fn the_count_follows_the_contacts_stiffness_from_tap_to_tap() {
        let mut k = stiff_kernel(12, 8.0);
        let period = 100;
        let soft_from = 20_000;
        let run = tap_run(
            &mut k,
            26_000,
            Refinement::default(),
            (soft_from, 1.0 / 40.0),
        );
        let first_redo = run.redone.iter().position(|&r| r).expect("a redo");
        assert!(first_redo < period, "first redo at sample {first_redo}");
        // Settled (from the free orbit the taps take ~120 periods to settle).
        let settled = 14_000..soft_from;
        assert!(!run.redone[settled.clone()].contains(&true));
        let stiff: Vec<_> = run.steps[settled]
            .iter()
            .filter(|s| s.substepped())
            .collect();
        assert!(stiff.len() > 100, "{}", stiff.len());
        assert!(stiff.iter().all(|s| s.refined && s.substeps == 24));
        let soft: Vec<_> = run.steps[soft_from + 2 * period..]
            .iter()
            .filter(|s| s.substepped())
            .collect();
        assert!(soft.len() > 100, "{}", soft.len());
        assert!(soft.iter().all(|s| s.substeps == 12 && !s.refined));
    }
}
