//! The coupled tapping orbit (physics.md §6): every mode integrated together, the Hertz
//! force taken from the instantaneous tip position, and the periodic steady state found by
//! shooting. Offline and accurate, not real-time: it is the independent reference that the
//! paper's 1-DOF method (and a real-time coupled engine) are measured against.
//!
//! Method. In the relative frame each mode obeys
//! `Ÿn + 2γnωn Ẏn + ωn² Yn = −Pn ü + (φn(L)/Mn) g`, `Mn = Kn/ωn²`, with the base
//! `u = U sin Ωt`. Write `Yn = Y⁰n + hn`, where `Y⁰n` is the free (no contact) steady
//! response, known in closed form. The deviation `h` obeys the homogeneous damped modes
//! driven by `g` alone, so:
//! - out of contact `h` is propagated exactly (each mode's 2×2 matrix exponential), and the
//!   next contact is found by scanning the exact trajectory and bisecting on it;
//! - in contact it is integrated by an adaptive Dormand–Prince 5(4) Runge–Kutta with a tight
//!   tolerance and a step cap, and the exit is located by bisection on the step;
//! - with DMT adhesion the force never vanishes, so the Runge–Kutta integrates the whole
//!   period (a longer cap outside contact) and bisects for the entry as for the exit;
//! - the periodic orbit is the fixed point of the one-period map `h(0) ↦ h(T)`, found by
//!   Newton's method (Jacobian by central differences) after a transient has decayed;
//!   the Jacobian at the solution is the monodromy matrix, whose eigenvalues are the Floquet
//!   multipliers (their product is `exp(−Σ 2γnωn T)` by Liouville, a check).
//!
//! At the periodic orbit `h` is exactly the periodic response to `g`, so the harmonics of the
//! tip motion and of the photodiode follow from the Fourier coefficients of `g`, which are
//! integrated over the contact (where `g` lives; the whole period with adhesion) on the
//! integrator's own steps.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::beam::{Cantilever, MAX_MODES, Mode};
use super::contact::{Adhesion, HertzContact};

/// The tapping problem of §6: modes, drive, surface and contact.
#[derive(Clone, Debug)]
pub struct CoupledProblem {
    /// The cantilever's modes (all of them take part).
    pub modes: Vec<Mode>,
    /// Drive angular frequency Ω (rad/s).
    pub drive_omega: f64,
    /// Free tip deflection amplitude |w(L)| at Ω (m), `/drive/free_amplitude`.
    pub free_amplitude: f64,
    /// A_set: tip rest position to the surface (m); the surface is at z = −A_set.
    pub surface_distance: f64,
    /// The Hertz contact.
    pub contact: HertzContact,
    /// DMT adhesion on top of it, if any ([`CoupledProblem::with_adhesion`]).
    pub adhesion: Option<Adhesion>,
}

/// Why no periodic orbit came out.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CoupledError {
    /// Newton's method did not converge.
    #[error(
        "the coupled periodic orbit did not converge (residual {residual:e} after {iterations} Newton iterations)"
    )]
    NoConvergence { residual: f64, iterations: usize },
    /// The contact integration could not keep its tolerance.
    #[error("the contact integration failed: {0}")]
    Integration(String),
}

/// The periodic steady state and what physics.md §6 reports of it.
#[derive(Clone, Debug)]
pub struct CoupledOrbit {
    /// Base amplitude U (m) that gives the free amplitude.
    pub base_amplitude: f64,
    /// Peak tip–sample force F (N): the largest push, 0 if the tip never pushes.
    pub max_force: f64,
    /// Maximum indentation δ_max (m).
    pub max_indentation: f64,
    /// τ = 1.5·FWHM/T of the force pulse (1).
    pub contact_time_ratio: f64,
    /// Fraction of the period in contact (1).
    pub contact_fraction: f64,
    /// Drive phase Ωt (rad, in [0, 2π)) at the force peak.
    pub pulse_phase: f64,
    /// θ: phase of the fundamental of z when tapping minus that of the free z (rad).
    pub phase_shift: f64,
    /// Peak amplitude of the fundamental of z (m).
    pub tapping_amplitude: f64,
    /// Two-sided Fourier coefficients c_k = (1/T)∫g e^{−ikΩt}dt of the force (N),
    /// k = 0..=harmonics.
    pub force_coefficients: Vec<Complex64>,
    /// Peak amplitudes 2|S_k| (m) of the photodiode's response to g at harmonic k, k ≥ 1
    /// (index 0: the mean |S_0|), as §2 defines them.
    pub spectrum: Vec<f64>,
    /// Modal deviations from the free orbit at t = 0: (hn, ḣn) per mode (m, m/s).
    pub initial_state: Vec<f64>,
    /// Scaled residual |h(T) − h(0)| of the fixed point (1).
    pub residual: f64,
    /// Newton iterations taken.
    pub newton_iterations: usize,
    /// Product of the Floquet multipliers (det of the monodromy matrix) (1).
    pub floquet_product: f64,
    /// Largest Floquet multiplier modulus estimate (spectral radius bound by power
    /// iteration) (1): below 1 means a stable period-1 orbit.
    pub floquet_max: f64,
    /// Whether the orbit is period 1: the fixed point converged and is stable.
    pub period_one: bool,
    /// Contact work ∮ g ż dt over one period (J): 0 for a conservative (Hertz) contact.
    pub contact_work: f64,
    /// Work done by the base drive on the modes over one period (J).
    pub drive_work: f64,
    /// Energy dissipated by the modal damping over one period (J).
    pub damping_work: f64,
    /// ∮ g u̇ dt (J): what the contact force does against the moving base.
    pub base_contact_work: f64,
}

/// The step the out-of-contact scan takes, as a fraction of the fastest mode's period and of
/// the drive period: fine enough that no contact hides between two scan points.
const SCAN_PER_FASTEST: f64 = 1.0 / 24.0;
const SCAN_PER_PERIOD: f64 = 1.0 / 4000.0;
/// The largest step inside contact (fraction of the drive period) when the orbit is
/// measured, and while shooting.
const CONTACT_STEP_MEASURE: f64 = 1.0 / 200_000.0;
const CONTACT_STEP_SHOOT: f64 = 1.0 / 20_000.0;
/// Relative tolerance of the contact integration.
const RTOL: f64 = 1e-11;

/// Harmonics of the force summed on the integrator's points; beyond, by FFT.
const DENSE_HARMONICS: usize = 64;
/// Points per period of the force's FFT for the harmonics beyond [`DENSE_HARMONICS`]: the
/// grid step is T/65536, and the interpolant's content that folds onto harmonic j ≤ 1024
/// comes from harmonics ≥ 64 512, ~10⁻⁴ of the 1024th's.
const FFT_POINTS: usize = 1 << 16;

/// Two-sided Fourier coefficients c_j = (1/T)∫g e^{−ijΩt}dt, j = 0..=harmonics, of the force
/// recorded at `samples` (t, g, δ) in one period [0, T), linear between them and zero before
/// the first and after the last (the record starts and ends where g vanishes, and between
/// contacts its points are where g = 0 and g ≈ 0⁺), by the FFT of that on a uniform grid.
fn fft_coefficients(
    samples: &[(f64, f64, f64)],
    t_period: f64,
    harmonics: usize,
) -> Vec<Complex64> {
    let n = FFT_POINTS;
    let mut grid = vec![0.0; n];
    if let (Some(first), Some(last)) = (samples.first(), samples.last()) {
        let mut i = 0;
        for (m, g) in grid.iter_mut().enumerate() {
            let t = m as f64 * t_period / n as f64;
            if t < first.0 || t > last.0 {
                continue;
            }
            while i + 1 < samples.len() && samples[i + 1].0 < t {
                i += 1;
            }
            let (a, b) = (samples[i], samples[(i + 1).min(samples.len() - 1)]);
            *g = if b.0 > a.0 {
                a.1 + (b.1 - a.1) * (t - a.0) / (b.0 - a.0)
            } else {
                a.1
            };
        }
    }
    let mut planner = realfft::RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let mut spectrum = fft.make_output_vec();
    // A length that is the plan's and a grid of it cannot fail.
    fft.process(&mut grid, &mut spectrum)
        .expect("the FFT's buffers have its length");
    spectrum
        .into_iter()
        .take(harmonics + 1)
        .map(|x| x / n as f64)
        .collect()
}

/// Scaled residual at which [`CoupledProblem::solve_continued`] stops: below what the
/// measurement resolves (a table node's F and τ move by ~1e-10 of themselves).
const CONTINUED_RESIDUAL: f64 = 1e-10;

/// Where a nearby problem's orbit search starts ([`CoupledProblem::solve_continued`]): the
/// fixed point's modal deviations and the Jacobian of the one-period map there.
#[derive(Clone, Debug)]
pub struct Continuation {
    h: Vec<f64>,
    jacobian: Vec<Vec<f64>>,
}

/// What a period's integration reports (when measuring).
#[derive(Default)]
struct Record {
    /// (t, g, δ) at every point in contact.
    force: Vec<(f64, f64, f64)>,
    /// Time (s) of the steps with the tip in contact at either end, the contact's share of
    /// the period wherever in it the contact falls (across t = 0 too).
    contact_time: f64,
    /// Trapezoid sums over the whole period.
    drive_work: f64,
    damping_work: f64,
    contact_work: f64,
    base_contact_work: f64,
    coefficients: Vec<Complex64>,
    /// The previous point and its power terms.
    last: Option<(f64, Powers)>,
}

/// (drive power, damping power, g·ż, g·u̇, g, δ) at one point.
type Powers = (f64, f64, f64, f64, f64, f64);

impl CoupledProblem {
    /// The problem for a cantilever, drive (Hz, m), surface distance (m) and contact.
    pub fn new(
        cantilever: &Cantilever,
        drive_frequency: f64,
        free_amplitude: f64,
        surface_distance: f64,
        contact: HertzContact,
    ) -> Self {
        Self {
            modes: cantilever.modes.clone(),
            drive_omega: 2.0 * PI * drive_frequency,
            free_amplitude,
            surface_distance,
            contact,
            adhesion: None,
        }
    }

    /// The same problem with DMT adhesion (physics.md §6). Its force acts at every distance,
    /// so the orbit is then integrated by the Runge–Kutta over the whole period.
    pub fn with_adhesion(mut self, adhesion: Option<Adhesion>) -> Self {
        self.adhesion = adhesion;
        self
    }

    /// Tip–sample force g (N, positive pushes the tip away) at indentation `delta` (m).
    pub fn force(&self, delta: f64) -> f64 {
        let repulsion = self.contact.force(delta.max(0.0));
        match self.adhesion {
            Some(a) => repulsion + a.force(self.contact.radius, delta),
            None => repulsion,
        }
    }

    fn period(&self) -> f64 {
        2.0 * PI / self.drive_omega
    }

    /// Ŷn per metre of base amplitude: the free modal response is `Y⁰n = U·Im(Ŷn e^{iΩt})`.
    fn free_modal_per_base(&self) -> Vec<Complex64> {
        let w = self.drive_omega;
        self.modes
            .iter()
            .map(|m| {
                let d = Complex64::new(m.omega * m.omega - w * w, 2.0 * m.gamma * m.omega * w);
                m.participation * w * w / d
            })
            .collect()
    }

    /// Base amplitude U (m) whose free tip deflection amplitude |w(L)| at Ω is the free
    /// amplitude.
    pub fn base_amplitude(&self) -> f64 {
        let per_base: Complex64 = self
            .modes
            .iter()
            .zip(self.free_modal_per_base())
            .map(|(m, y)| m.tip_value * y)
            .sum();
        self.free_amplitude / per_base.norm()
    }

    /// The orbit of a problem that differs little from the one `from` was found for (e.g.
    /// the next node of a table in the sample's modulus), far cheaper than [`Self::solve`]:
    /// no transient, and Newton's matrix is `from`'s until the residual stops falling by
    /// half per iteration (a chord method; then it is recomputed at the current iterate,
    /// whenever a step fails to halve the residual, up to 8 times). Returns the orbit and
    /// what the next problem can continue from.
    ///
    /// The orbit's Floquet fields come from the last Jacobian computed, which may be
    /// `from`'s: `floquet_product` and `floquet_max` are NaN when it is, and `period_one`
    /// then says only that the fixed point converged.
    ///
    /// # Errors
    /// As [`Self::solve`]; also when the chord and Newton iterations do not converge from
    /// `from`'s state (the problems are too far apart, or the branch ends between them).
    pub fn solve_continued(
        &self,
        harmonics: usize,
        from: &Continuation,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        let map = PeriodMap::new(self);
        let scale = map.scales();
        let n2 = 2 * self.modes.len();
        if from.h.len() != n2 {
            return Err(CoupledError::Integration(
                "the continuation is for another number of modes".into(),
            ));
        }
        let mut h = from.h.clone();
        let mut jacobian = from.jacobian.clone();
        // Whether a Jacobian was computed here, whether it is that of the current iterate,
        // and how many were.
        let (mut fresh, mut current, mut refreshes) = (false, false, 0);
        let mut next = map.period(&h, CONTACT_STEP_SHOOT, None)?;
        let mut residual = map.residual(&h, &next);
        let mut iterations = 0;
        while residual >= CONTINUED_RESIDUAL && iterations < 60 {
            iterations += 1;
            let mut a = jacobian.clone();
            for (i, row) in a.iter_mut().enumerate() {
                row[i] -= 1.0;
            }
            let b: Vec<f64> = h.iter().zip(&next).map(|(x, y)| x - y).collect();
            let delta = solve_linear(a, b)
                .ok_or_else(|| CoupledError::Integration("singular Newton matrix".into()))?;
            let trial: Vec<f64> = h.iter().zip(&delta).map(|(x, d)| x + d).collect();
            let trial_next = map.period(&trial, CONTACT_STEP_SHOOT, None)?;
            let r = map.residual(&trial, &trial_next);
            if r < 0.5 * residual {
                (h, next, residual) = (trial, trial_next, r);
                current = false;
            } else if !current && refreshes < 8 {
                // The matrix (borrowed, or from an earlier iterate) no longer helps:
                // Newton's own, here.
                jacobian = map.jacobian(&h, &scale)?;
                (fresh, current) = (true, true);
                refreshes += 1;
            } else if r < residual {
                (h, next, residual) = (trial, trial_next, r);
                current = false;
            } else {
                break;
            }
        }
        if residual >= CONTINUED_RESIDUAL {
            return Err(CoupledError::NoConvergence {
                residual,
                iterations,
            });
        }
        let (floquet_product, floquet_max) = if fresh {
            (determinant(jacobian.clone()), spectral_radius(&jacobian))
        } else {
            (f64::NAN, f64::NAN)
        };
        let record = map.measure_period(&h, harmonics)?;
        let mut orbit = self.measure(
            h.clone(),
            record,
            residual,
            iterations,
            floquet_product,
            floquet_max,
        );
        if !fresh {
            orbit.period_one = true;
        }
        Ok((orbit, Continuation { h, jacobian }))
    }

    /// [`Self::solve`], with what a nearby problem can continue from
    /// ([`Self::solve_continued`]).
    pub fn solve_for_continuation(
        &self,
        harmonics: usize,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        let (orbit, jacobian) = self.solve_with_jacobian(harmonics)?;
        let h = orbit.initial_state.clone();
        Ok((orbit, Continuation { h, jacobian }))
    }

    /// Finds the periodic orbit and measures it, with harmonics up to `harmonics`.
    pub fn solve(&self, harmonics: usize) -> Result<CoupledOrbit, CoupledError> {
        self.solve_with_jacobian(harmonics).map(|(orbit, _)| orbit)
    }

    fn solve_with_jacobian(
        &self,
        harmonics: usize,
    ) -> Result<(CoupledOrbit, Vec<Vec<f64>>), CoupledError> {
        let map = PeriodMap::new(self);
        let n2 = 2 * self.modes.len();
        // Let the transient decay from the free orbit (h = 0): a few mode-1 decay times,
        // enough to land in Newton's basin of the branch an approach from far reaches.
        let q1 = self.modes[0].q;
        let transient = ((3.0 * q1 / PI).ceil() as usize).clamp(20, 3000);
        let mut h = vec![0.0; n2];
        for _ in 0..transient {
            h = map.period(&h, CONTACT_STEP_SHOOT, None)?;
        }
        // Newton on F(h) = Φ(h) − h, in scaled variables.
        let scale = map.scales();
        let mut iterations = 0;
        let mut next = map.period(&h, CONTACT_STEP_SHOOT, None)?;
        let mut residual = map.residual(&h, &next);
        let mut jacobian = vec![vec![0.0; n2]; n2];
        for _ in 0..30 {
            jacobian = map.jacobian(&h, &scale)?;
            if residual < 1e-12 {
                break;
            }
            iterations += 1;
            // (J − I)Δ = −(Φ(h) − h)
            let mut a: Vec<Vec<f64>> = jacobian.clone();
            for (i, row) in a.iter_mut().enumerate() {
                row[i] -= 1.0;
            }
            let b: Vec<f64> = h.iter().zip(&next).map(|(x, y)| x - y).collect();
            let delta = solve_linear(a, b)
                .ok_or_else(|| CoupledError::Integration("singular Newton matrix".into()))?;
            // Damped step: halve until the residual drops.
            let mut step = 1.0;
            loop {
                let trial: Vec<f64> = h.iter().zip(&delta).map(|(x, d)| x + step * d).collect();
                let trial_next = map.period(&trial, CONTACT_STEP_SHOOT, None)?;
                let r = map.residual(&trial, &trial_next);
                if r < residual || step < 1.0 / 64.0 {
                    h = trial;
                    next = trial_next;
                    residual = r;
                    break;
                }
                step *= 0.5;
            }
        }
        if residual > 1e-7 {
            return Err(CoupledError::NoConvergence {
                residual,
                iterations,
            });
        }
        // Floquet: the monodromy of the full state in the original variables is the
        // Jacobian of the map (h and Y differ by a periodic shift).
        let floquet_product = determinant(jacobian.clone());
        let floquet_max = spectral_radius(&jacobian);
        // Measure the orbit with the finer contact step.
        let record = map.measure_period(&h, harmonics)?;
        let orbit = self.measure(
            h,
            record,
            residual,
            iterations,
            floquet_product,
            floquet_max,
        );
        Ok((orbit, jacobian))
    }

    fn measure(
        &self,
        h: Vec<f64>,
        record: Record,
        residual: f64,
        iterations: usize,
        floquet_product: f64,
        floquet_max: f64,
    ) -> CoupledOrbit {
        let t_period = self.period();
        let (max_force, max_indentation) = record
            .force
            .iter()
            .fold((0.0f64, 0.0f64), |(f, d), &(_, g, delta)| {
                (f.max(g), d.max(delta))
            });
        let contact_time = record.contact_time;
        let fwhm = full_width_at_half_maximum(&from_minimum(&record.force, t_period), max_force);
        let t_peak = record
            .force
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0.0, |p| p.0);
        let pulse_phase = (self.drive_omega * t_peak).rem_euclid(2.0 * PI);
        let c = record.coefficients;
        // Tip fundamental: free part plus the response to g's fundamental.
        let u = self.base_amplitude();
        let per_base = self.free_modal_per_base();
        let w = self.drive_omega;
        let free_z1 = -Complex64::i()
            * (u + self
                .modes
                .iter()
                .zip(&per_base)
                .map(|(m, y)| m.tip_value * u * y)
                .sum::<Complex64>());
        let tip_response: Complex64 = self
            .modes
            .iter()
            .map(|m| m.tip_value * m.tip_value / m.stiffness * m.transfer(w))
            .sum();
        let tap_z1 = free_z1 + 2.0 * c.get(1).copied().unwrap_or_default() * tip_response;
        let lag = |z1: Complex64| -(Complex64::i() * z1).arg();
        let mut phase_shift = lag(tap_z1) - lag(free_z1);
        if phase_shift > PI {
            phase_shift -= 2.0 * PI;
        } else if phase_shift < -PI {
            phase_shift += 2.0 * PI;
        }
        let spectrum = c
            .iter()
            .enumerate()
            .map(|(k, ck)| {
                let s: Complex64 = self
                    .modes
                    .iter()
                    .map(|m| {
                        (2.0 / 3.0) * m.tip_slope * m.tip_value / m.stiffness
                            * m.transfer(k as f64 * w)
                    })
                    .sum::<Complex64>()
                    * ck;
                if k == 0 { s.norm() } else { 2.0 * s.norm() }
            })
            .collect();
        CoupledOrbit {
            base_amplitude: u,
            max_force,
            max_indentation,
            contact_time_ratio: 1.5 * fwhm / t_period,
            contact_fraction: contact_time / t_period,
            pulse_phase,
            phase_shift,
            tapping_amplitude: tap_z1.norm(),
            force_coefficients: c,
            spectrum,
            initial_state: h,
            residual,
            newton_iterations: iterations,
            floquet_product,
            floquet_max,
            period_one: residual <= 1e-7 && floquet_max < 1.0,
            contact_work: record.contact_work,
            drive_work: record.drive_work,
            damping_work: record.damping_work,
            base_contact_work: record.base_contact_work,
        }
    }
}

impl CoupledOrbit {
    /// θ in degrees, as the paper prints it.
    pub fn phase_shift_deg(&self) -> f64 {
        self.phase_shift.to_degrees()
    }
}

/// The force record as one period that starts at its smallest force: the samples before it
/// move to the end, a period later, so a pulse that straddles t = 0 (and T) is one stretch.
fn from_minimum(samples: &[(f64, f64, f64)], t_period: f64) -> Vec<(f64, f64, f64)> {
    let Some(k) = samples
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.1.total_cmp(&b.1.1))
        .map(|(i, _)| i)
    else {
        return Vec::new();
    };
    samples[k..]
        .iter()
        .copied()
        .chain(samples[..k].iter().map(|&(t, g, d)| (t + t_period, g, d)))
        .collect()
}

/// FWHM (s) of the force samples (t, g, δ), by linear interpolation at the half maximum.
fn full_width_at_half_maximum(samples: &[(f64, f64, f64)], peak: f64) -> f64 {
    if peak <= 0.0 || samples.len() < 2 {
        return 0.0;
    }
    let half = 0.5 * peak;
    let mut rise = None;
    let mut fall = None;
    for w in samples.windows(2) {
        let ((t0, g0, _), (t1, g1, _)) = (w[0], w[1]);
        if rise.is_none() && g0 < half && g1 >= half {
            rise = Some(t0 + (half - g0) / (g1 - g0) * (t1 - t0));
        }
        if rise.is_some() && g0 >= half && g1 < half {
            fall = Some(t0 + (g0 - half) / (g0 - g1) * (t1 - t0));
        }
    }
    match (rise, fall) {
        (Some(r), Some(f)) if f > r => f - r,
        _ => 0.0,
    }
}

/// The one-period map and the pieces it is made of, precomputed for a problem.
struct PeriodMap<'a> {
    p: &'a CoupledProblem,
    t_period: f64,
    u: f64,
    /// U·Ŷn: free modal responses.
    free: Vec<Complex64>,
    /// φn(L)/Mn: modal force per newton of tip force (1/kg).
    force_gain: Vec<f64>,
    scan_step: f64,
    /// Each mode's exact propagator over `scan_step`, the step the force-free stretch takes
    /// again and again.
    scan_propagator: Vec<[[f64; 2]; 2]>,
    /// [`PeriodMap::scales`], once.
    scale: Vec<f64>,
}

impl<'a> PeriodMap<'a> {
    fn new(p: &'a CoupledProblem) -> Self {
        let u = p.base_amplitude();
        let free = p.free_modal_per_base().into_iter().map(|y| u * y).collect();
        let t_period = p.period();
        let fastest = p.modes.iter().map(|m| m.omega).fold(0.0, f64::max);
        let scan_step = (SCAN_PER_FASTEST * 2.0 * PI / fastest).min(SCAN_PER_PERIOD * t_period);
        let mut map = Self {
            p,
            t_period,
            u,
            free,
            force_gain: p
                .modes
                .iter()
                .map(|m| m.tip_value * m.omega * m.omega / m.stiffness)
                .collect(),
            scan_step,
            scan_propagator: p
                .modes
                .iter()
                .map(|m| modal_exponential(m.omega, m.gamma, scan_step))
                .collect(),
            scale: Vec::new(),
        };
        map.scale = map.scales();
        map
    }

    /// Scales of the state components for residuals and difference steps: the free
    /// amplitude of each mode (at least 1e-3 of the free amplitude) and ωn times it.
    fn scales(&self) -> Vec<f64> {
        let floor = 1e-3 * self.p.free_amplitude;
        self.p
            .modes
            .iter()
            .zip(&self.free)
            .flat_map(|(m, y)| {
                let a = y.norm().max(floor / m.tip_value.abs());
                [a, a * m.omega]
            })
            .collect()
    }

    /// Scaled distance |h(T) − h(0)| of `next` = Φ(`h`) from `h`: the fixed point's residual.
    fn residual(&self, h: &[f64], next: &[f64]) -> f64 {
        h.iter()
            .zip(next)
            .zip(&self.scale)
            .map(|((a, b), s)| ((b - a) / s).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// The drive's phasor e^{iΩt} at t: cos and sin from one `sin_cos` (the same bits as
    /// `Complex64::from_polar(1.0, Ωt)`, which takes them one at a time). The integrator
    /// asks for the tip at every stage: one phasor for the base and every mode there.
    fn phasor(&self, t: f64) -> Complex64 {
        let (s, c) = (self.p.drive_omega * t).sin_cos();
        Complex64::new(c, s)
    }

    /// Base position and velocity at the drive phasor `e`.
    fn base(&self, e: Complex64) -> (f64, f64) {
        (self.u * e.im, self.u * self.p.drive_omega * e.re)
    }

    /// Free modal displacement and velocity of mode n at the drive phasor `e`.
    fn free_mode(&self, n: usize, e: Complex64) -> (f64, f64) {
        let y = self.free[n] * e;
        (y.im, (Complex64::i() * self.p.drive_omega * y).im)
    }

    /// Tip position z (m) at t for deviations h.
    fn tip(&self, t: f64, h: &[f64]) -> f64 {
        let e = self.phasor(t);
        let (base, _) = self.base(e);
        base + self
            .p
            .modes
            .iter()
            .enumerate()
            .map(|(n, m)| m.tip_value * (self.free_mode(n, e).0 + h[2 * n]))
            .sum::<f64>()
    }

    /// Indentation δ = −A_set − z (m).
    fn indentation(&self, t: f64, h: &[f64]) -> f64 {
        -self.p.surface_distance - self.tip(t, h)
    }

    /// Exact homogeneous propagation of h over dt.
    fn propagate(&self, h: &[f64], dt: f64) -> Vec<f64> {
        let mut out = vec![0.0; h.len()];
        for (n, m) in self.p.modes.iter().enumerate() {
            let [[a, b], [c, d]] = if dt == self.scan_step {
                self.scan_propagator[n]
            } else {
                modal_exponential(m.omega, m.gamma, dt)
            };
            let (y, v) = (h[2 * n], h[2 * n + 1]);
            out[2 * n] = a * y + b * v;
            out[2 * n + 1] = c * y + d * v;
        }
        out
    }

    /// dh/dt in contact.
    fn derivative(&self, t: f64, h: &[f64], out: &mut [f64]) {
        let g = self.p.force(self.indentation(t, h));
        for (n, m) in self.p.modes.iter().enumerate() {
            let (y, v) = (h[2 * n], h[2 * n + 1]);
            out[2 * n] = v;
            out[2 * n + 1] =
                -2.0 * m.gamma * m.omega * v - m.omega * m.omega * y + self.force_gain[n] * g;
        }
    }

    /// One Dormand–Prince 5(4) step: the 5th-order result and the error estimate.
    fn dp_step(&self, t: f64, h: &[f64], dt: f64) -> (Vec<f64>, f64) {
        const C: [f64; 6] = [1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0, 1.0, 1.0];
        const A: [&[f64]; 6] = [
            &[1.0 / 5.0],
            &[3.0 / 40.0, 9.0 / 40.0],
            &[44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0],
            &[
                19372.0 / 6561.0,
                -25360.0 / 2187.0,
                64448.0 / 6561.0,
                -212.0 / 729.0,
            ],
            &[
                9017.0 / 3168.0,
                -355.0 / 33.0,
                46732.0 / 5247.0,
                49.0 / 176.0,
                -5103.0 / 18656.0,
            ],
            &[
                35.0 / 384.0,
                0.0,
                500.0 / 1113.0,
                125.0 / 192.0,
                -2187.0 / 6784.0,
                11.0 / 84.0,
            ],
        ];
        const E: [f64; 7] = [
            71.0 / 57600.0,
            0.0,
            -71.0 / 16695.0,
            71.0 / 1920.0,
            -17253.0 / 339200.0,
            22.0 / 525.0,
            -1.0 / 40.0,
        ];
        let n = h.len();
        // The stages on the stack: the integrator takes millions of steps in a table build.
        let mut k = [[0.0; 2 * MAX_MODES]; 7];
        self.derivative(t, h, &mut k[0][..n]);
        let mut tmp = vec![0.0; n];
        for s in 0..6 {
            for i in 0..n {
                tmp[i] = h[i]
                    + dt * A[s]
                        .iter()
                        .enumerate()
                        .map(|(j, a)| a * k[j][i])
                        .sum::<f64>();
            }
            self.derivative(t + C[s] * dt, &tmp, &mut k[s + 1][..n]);
        }
        // The 5th-order solution is the last stage's argument (FSAL).
        let scale = &self.scale;
        let err = (0..n)
            .map(|i| {
                let e = dt * E.iter().enumerate().map(|(j, c)| c * k[j][i]).sum::<f64>();
                let s = scale[i] * RTOL + RTOL * tmp[i].abs();
                (e / s).powi(2)
            })
            .sum::<f64>()
            / n as f64;
        (tmp, err.sqrt())
    }

    /// The measuring period from `h`: the record, with force coefficients up to `harmonics`
    /// — by the trapezoid on the integrator's own points up to [`DENSE_HARMONICS`], and
    /// beyond by the FFT of the force on a uniform grid of [`FFT_POINTS`] (interpolated
    /// linearly between those points): hundreds of harmonics (for the aliases) at the cost
    /// of one FFT rather than a multiplication per harmonic per point.
    fn measure_period(&self, h: &[f64], harmonics: usize) -> Result<Record, CoupledError> {
        let dense = harmonics.min(DENSE_HARMONICS);
        let mut record = Record {
            coefficients: vec![Complex64::new(0.0, 0.0); dense + 1],
            ..Record::default()
        };
        self.period(h, CONTACT_STEP_MEASURE, Some(&mut record))?;
        if harmonics > dense {
            let beyond = fft_coefficients(&record.force, self.t_period, harmonics);
            record
                .coefficients
                .extend_from_slice(&beyond[dense + 1..=harmonics]);
        }
        Ok(record)
    }

    /// Integrates one period from deviations `h` at t = 0; records when asked.
    fn period(
        &self,
        h: &[f64],
        contact_step: f64,
        mut record: Option<&mut Record>,
    ) -> Result<Vec<f64>, CoupledError> {
        let t_end = self.t_period;
        let max_contact_step = contact_step * t_end;
        // Adhesion pulls at every distance: no force-free stretch to propagate exactly.
        let force_free_outside = self.p.adhesion.is_none();
        let mut t = 0.0;
        let mut h = h.to_vec();
        let mut in_contact = self.indentation(0.0, &h) > 0.0;
        let mut dt = max_contact_step;
        if let Some(r) = record.as_deref_mut() {
            self.accumulate(r, t, &h);
        }
        while t < t_end {
            if !in_contact && force_free_outside {
                let step = self.scan_step.min(t_end - t);
                let next = self.propagate(&h, step);
                if self.indentation(t + step, &next) > 0.0 {
                    // Bisect for the entry on the exact trajectory.
                    let (mut lo, mut hi) = (0.0, step);
                    for _ in 0..80 {
                        let mid = 0.5 * (lo + hi);
                        if self.indentation(t + mid, &self.propagate(&h, mid)) > 0.0 {
                            hi = mid;
                        } else {
                            lo = mid;
                        }
                        if hi - lo <= 1e-16 * t_end {
                            break;
                        }
                    }
                    h = self.propagate(&h, hi);
                    t += hi;
                    in_contact = true;
                    dt = max_contact_step * 0.01;
                } else {
                    h = next;
                    t += step;
                }
                if let Some(r) = record.as_deref_mut() {
                    self.accumulate(r, t, &h);
                }
                continue;
            }
            // One adaptive step, no longer than the contact's cap inside and the scan step
            // outside.
            let cap = if in_contact {
                max_contact_step
            } else {
                self.scan_step
            };
            let step = dt.min(cap).min(t_end - t);
            let (trial, err) = self.dp_step(t, &h, step);
            if err > 1.0 && step > 1e-14 * t_end {
                dt = step * (0.9 * err.powf(-0.2)).max(0.2);
                continue;
            }
            if !trial.iter().all(|x| x.is_finite()) {
                return Err(CoupledError::Integration("non-finite state".into()));
            }
            let grow = if err > 0.0 {
                (0.9 * err.powf(-0.2)).clamp(0.2, 5.0)
            } else {
                5.0
            };
            if (self.indentation(t + step, &trial) > 0.0) != in_contact {
                // Crossed the surface within the step (the force's law changes there):
                // bisect on the step length.
                let (mut lo, mut hi) = (0.0, step);
                for _ in 0..80 {
                    let mid = 0.5 * (lo + hi);
                    if (self.indentation(t + mid, &self.dp_step(t, &h, mid).0) > 0.0) == in_contact
                    {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                    if hi - lo <= 1e-16 * t_end {
                        break;
                    }
                }
                h = self.dp_step(t, &h, hi).0;
                t += hi;
                in_contact = !in_contact;
                if in_contact {
                    dt = max_contact_step * 0.01;
                }
            } else {
                h = trial;
                t += step;
                dt = step * grow;
            }
            if let Some(r) = record.as_deref_mut() {
                self.accumulate(r, t, &h);
            }
        }
        Ok(h)
    }

    /// The power terms at (t, h).
    fn powers(&self, t: f64, h: &[f64]) -> Powers {
        let e = self.phasor(t);
        let (_, ubase_v) = self.base(e);
        let udd = -self.u * self.p.drive_omega.powi(2) * e.im;
        let delta = self.indentation(t, h);
        let g = self.p.force(delta);
        let mut drive = 0.0;
        let mut damping = 0.0;
        let mut tip_v = ubase_v;
        for (n, m) in self.p.modes.iter().enumerate() {
            let (_, v0) = self.free_mode(n, e);
            let v = v0 + h[2 * n + 1];
            let mass = m.stiffness / (m.omega * m.omega);
            drive += -mass * m.participation * udd * v;
            damping += mass * 2.0 * m.gamma * m.omega * v * v;
            tip_v += m.tip_value * v;
        }
        (drive, damping, g * tip_v, g * ubase_v, g, delta)
    }

    /// Adds the point (t, h) to the record: trapezoid sums from the previous point, and the
    /// force sample.
    fn accumulate(&self, r: &mut Record, t: f64, h: &[f64]) {
        let now = self.powers(t, h);
        if let Some((t0, before)) = r.last.take() {
            let dt = t - t0;
            r.drive_work += 0.5 * dt * (before.0 + now.0);
            r.damping_work += 0.5 * dt * (before.1 + now.1);
            r.contact_work += 0.5 * dt * (before.2 + now.2);
            r.base_contact_work += 0.5 * dt * (before.3 + now.3);
            if before.5 > 0.0 || now.5 > 0.0 {
                r.contact_time += dt;
            }
            if before.4 != 0.0 || now.4 != 0.0 {
                let w = self.p.drive_omega;
                // e^{−ikΩt} by powers of e^{−iΩt}, re-anchored every 64 harmonics: hundreds
                // of harmonics (for the aliases) cost multiplications, not sines.
                let (step0, step1) = (
                    Complex64::from_polar(1.0, -w * t0),
                    Complex64::from_polar(1.0, -w * t),
                );
                let (mut e0, mut e1) = (Complex64::new(1.0, 0.0), Complex64::new(1.0, 0.0));
                let weight = 0.5 * dt / self.t_period;
                for (k, c) in r.coefficients.iter_mut().enumerate() {
                    if k > 0 && k % 64 == 0 {
                        e0 = Complex64::from_polar(1.0, -(k as f64) * w * t0);
                        e1 = Complex64::from_polar(1.0, -(k as f64) * w * t);
                    }
                    *c += weight * (before.4 * e0 + now.4 * e1);
                    e0 *= step0;
                    e1 *= step1;
                }
            }
        }
        if now.4 != 0.0 || r.force.last().is_some_and(|l| l.1 != 0.0) {
            r.force.push((t, now.4, now.5.max(0.0)));
        }
        r.last = Some((t, now));
    }
}

/// exp(A·dt) of one damped mode, A = [[0, 1], [−ω², −2γω]], for any γ ≥ 0.
fn modal_exponential(omega: f64, gamma: f64, dt: f64) -> [[f64; 2]; 2] {
    // Eigenvalues r± = ω(−γ ± √(γ² − 1)); e^{At} = (r+ e^{r− t} − r− e^{r+ t})/(r+ − r−)·I
    //                                           + (e^{r+ t} − e^{r− t})/(r+ − r−)·A.
    let disc = Complex64::new(gamma * gamma - 1.0, 0.0).sqrt();
    if disc.norm() < 1e-6 {
        // Critically damped: e^{At} = e^{−ωt}[(1 + ωt)I + tA].
        let e = (-omega * dt).exp();
        return [
            [e * (1.0 + omega * dt), e * dt],
            [-e * omega * omega * dt, e * (1.0 - omega * dt)],
        ];
    }
    let rp = omega * (Complex64::new(-gamma, 0.0) + disc);
    let rm = omega * (Complex64::new(-gamma, 0.0) - disc);
    let (ep, em) = ((rp * dt).exp(), (rm * dt).exp());
    let diff = rp - rm;
    let alpha = ((rp * em - rm * ep) / diff).re;
    let beta = ((ep - em) / diff).re;
    [
        [alpha, beta],
        [-omega * omega * beta, alpha - 2.0 * gamma * omega * beta],
    ]
}

impl PeriodMap<'_> {
    /// ∂Φ/∂h by central differences, scaled steps.
    fn jacobian(&self, h: &[f64], scale: &[f64]) -> Result<Vec<Vec<f64>>, CoupledError> {
        let n = h.len();
        let mut j = vec![vec![0.0; n]; n];
        for col in 0..n {
            let eps = 1e-6 * scale[col];
            let mut plus = h.to_vec();
            let mut minus = h.to_vec();
            plus[col] += eps;
            minus[col] -= eps;
            let fp = self.period(&plus, CONTACT_STEP_SHOOT, None)?;
            let fm = self.period(&minus, CONTACT_STEP_SHOOT, None)?;
            for row in 0..n {
                j[row][col] = (fp[row] - fm[row]) / (2.0 * eps);
            }
        }
        Ok(j)
    }
}

/// Solves a·x = b by Gaussian elimination with partial pivoting; `None` if singular.
fn solve_linear(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col] == 0.0 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (top, rest) = a.split_at_mut(col + 1);
        let pivot_row = &top[col];
        for (i, row) in rest.iter_mut().enumerate() {
            let f = row[col] / pivot_row[col];
            eliminate(row, pivot_row, col, f);
            b[col + 1 + i] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row][k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row][row];
    }
    Some(x)
}

/// row[k] −= f·pivot[k] for k ≥ col.
fn eliminate(row: &mut [f64], pivot: &[f64], col: usize, f: f64) {
    for (x, p) in row[col..].iter_mut().zip(&pivot[col..]) {
        *x -= f * p;
    }
}

/// Determinant by elimination with partial pivoting.
fn determinant(mut a: Vec<Vec<f64>>) -> f64 {
    let n = a.len();
    let mut det = 1.0;
    for col in 0..n {
        let Some(pivot) = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
        else {
            return 0.0;
        };
        if a[pivot][col] == 0.0 {
            return 0.0;
        }
        if pivot != col {
            a.swap(col, pivot);
            det = -det;
        }
        det *= a[col][col];
        let (top, rest) = a.split_at_mut(col + 1);
        let pivot_row = &top[col];
        for row in rest.iter_mut() {
            let f = row[col] / pivot_row[col];
            eliminate(row, pivot_row, col, f);
        }
    }
    det
}

/// Spectral radius estimate: the growth of ‖Jᵐv‖ over m = 200 steps, (‖J²⁰⁰v‖/‖J¹⁰⁰v‖)^{1/100}.
fn spectral_radius(j: &[Vec<f64>]) -> f64 {
    let n = j.len();
    let mut v: Vec<f64> = (0..n).map(|i| 1.0 + 0.1 * i as f64).collect();
    let mut log_norm = 0.0;
    let mut at_half = 0.0;
    for step in 1..=200 {
        let w: Vec<f64> = (0..n)
            .map(|r| j[r].iter().zip(&v).map(|(a, x)| a * x).sum())
            .collect();
        let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            return 0.0;
        }
        log_norm += norm.ln();
        v = w.into_iter().map(|x| x / norm).collect();
        if step == 100 {
            at_half = log_norm;
        }
    }
    ((log_norm - at_half) / 100.0).exp()
}

#[cfg(test)]
mod tests {
    use super::super::contact::Elastic;
    use super::*;

    #[test]
    fn the_ffts_harmonics_are_the_sums_on_the_integrators_points() {
        // The paper's silicon case: f1 = 100 kHz, k = 20 N/m, five Q, R = 10 nm, A = 30 nm,
        // A_set = 20 nm.
        let beam = Cantilever::new(100e3, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap();
        let si = Elastic {
            youngs_modulus: 129e9,
            poisson: 0.28,
        };
        let p = CoupledProblem::new(&beam, 100e3, 30e-9, 20e-9, HertzContact::new(si, si, 10e-9));
        let orbit = p.solve(4).unwrap();
        let map = PeriodMap::new(&p);
        let record = map
            .measure_period(&orbit.initial_state, DENSE_HARMONICS)
            .unwrap();
        let fft = fft_coefficients(&record.force, map.t_period, DENSE_HARMONICS);
        let scale = record.coefficients[1].norm();
        let worst = (0..=DENSE_HARMONICS)
            .map(|j| (fft[j] - record.coefficients[j]).norm() / scale)
            .fold(0.0, f64::max);
        println!("worst FFT − sum over harmonics 0..=64: {worst:e} of |c1|");
        assert!(worst < 1e-6, "{worst:e}");
        // Beyond, the measured record carries them (the aliases need them).
        let record = map.measure_period(&orbit.initial_state, 1024).unwrap();
        assert_eq!(record.coefficients.len(), 1025);
        assert!(record.coefficients[1024].norm() > 0.0);
    }
}

#[cfg(test)]
mod light_tapping {
    use super::super::contact::Elastic;
    use super::*;

    /// Light tapping, where the tip motion at the lower turning point is a parabola:
    /// δ(t) = δm (1 − (t/tc)²) with tc = √(2δm/(A Ω²)), so the contact lasts a fraction
    /// (1/π)·√(2δm/A) of the period, and the Hertz force Fm (1 − (t/tc)²)^(3/2) is above half
    /// its peak for |t| < tc·√(1 − 2^(−2/3)): τ = 1.5·FWHM/T = 1.5·√(1 − 2^(−2/3))·fraction.
    /// At 29.9 nm the pulse straddles drive phase 0 (its peak at 6.245 rad), at 29.5 nm it
    /// does not: both must match.
    #[test]
    fn contact_time_and_width_match_the_parabolic_tip_motion_across_phase_zero() {
        let beam = Cantilever::new(100e3, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap();
        let si = Elastic {
            youngs_modulus: 129e9,
            poisson: 0.28,
        };
        for (distance, straddles) in [(29.9e-9, true), (29.5e-9, false)] {
            let p = CoupledProblem::new(
                &beam,
                100e3,
                30e-9,
                distance,
                HertzContact::new(si, si, 10e-9),
            );
            let o = p.solve(4).unwrap();
            let half_width = PI * o.contact_fraction;
            let to_zero = o.pulse_phase.min(2.0 * PI - o.pulse_phase);
            assert_eq!(to_zero < half_width, straddles, "{distance:e}: {o:?}");
            let fraction = (2.0 * o.max_indentation / o.tapping_amplitude).sqrt() / PI;
            let tau = 1.5 * (1.0 - 2f64.powf(-2.0 / 3.0)).sqrt() * fraction;
            println!(
                "{distance:e} m: contact fraction {:.5} (parabola {fraction:.5}), τ {:.5} (parabola {tau:.5})",
                o.contact_fraction, o.contact_time_ratio
            );
            assert!((o.contact_fraction / fraction - 1.0).abs() < 0.03, "{o:?}");
            assert!((o.contact_time_ratio / tau - 1.0).abs() < 0.03, "{o:?}");
        }
    }
}
