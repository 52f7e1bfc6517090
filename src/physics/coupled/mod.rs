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
//!   Newton's method (Jacobian by central differences, [`fixed_point`]) along an approach
//!   from far ([`approach`]): continuation in the surface distance from the free orbit,
//!   following the jump where a branch ends as a real approach does;
//!   the Jacobian at the solution is the monodromy matrix, whose eigenvalues are the Floquet
//!   multipliers (their product is `exp(−Σ 2γnωn T)` by Liouville, a check).
//!
//! At the periodic orbit `h` is exactly the periodic response to `g`, so the harmonics of the
//! tip motion and of the photodiode follow from the Fourier coefficients of `g`, which are
//! integrated over the contact (where `g` lives; the whole period with adhesion) by
//! Gauss–Legendre quadrature on each of the integrator's own steps.

mod approach;
mod fixed_point;
mod period_map;
mod record;

use std::cell::Cell;
use std::f64::consts::PI;
use std::sync::atomic::AtomicBool;

use rustfft::num_complex::Complex64;

use super::beam::{Cantilever, Mode};
use super::contact::{Adhesion, HertzContact};
use fixed_point::{Matrix, NewtonLimits, floquet, newton};
use period_map::PeriodMap;
use record::{Record, from_minimum, full_width_at_half_maximum};

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
    /// The motion repeats every other period: there is no stable period-1 orbit.
    #[error(
        "the tapping motion is period 2 (it repeats every other drive period, residual {residual:e}): \
         no period-1 orbit to report; raise the set-point or lower the free amplitude"
    )]
    PeriodTwo { residual: f64 },
    /// The motion did not settle on any orbit (chaos, or a slower transient than allowed).
    #[error(
        "the tapping motion did not settle on a period-1 orbit within {decay_times} mode-1 decay \
         times (residual {residual:e}): it may be chaotic"
    )]
    NoSettling { decay_times: usize, residual: f64 },
    /// The search used its budget of periods ([`SearchLimits::max_periods`]).
    #[error("the orbit search used its budget of {periods} drive periods without converging")]
    OverBudget { periods: usize },
    /// The search was cancelled ([`SearchLimits::cancel`]).
    #[error("the orbit search was cancelled")]
    Cancelled,
}

/// What bounds one orbit search: the work, counted in drive periods integrated, and a flag
/// that cancels it from another thread (checked every period).
#[derive(Clone, Copy, Debug)]
pub struct SearchLimits<'a> {
    /// Periods of the one-period map at most (1).
    pub max_periods: usize,
    /// Set to stop the search with [`CoupledError::Cancelled`].
    pub cancel: Option<&'a AtomicBool>,
}

/// The default budget of a search: 20 000 periods, about 7× the costliest point of the
/// preset grid in `tests/orbit_search.rs` (2825 periods; its `--nocapture` output lists each
/// point's periods and time).
pub const MAX_PERIODS: usize = 20_000;

impl Default for SearchLimits<'_> {
    fn default() -> Self {
        Self {
            max_periods: MAX_PERIODS,
            cancel: None,
        }
    }
}

/// The regime an orbit is in, by the sign of the mean tip–sample force over a period (García
/// & San Paulo, Phys. Rev. B 60, 4961, 1999): attractive where the net force pulls the tip,
/// repulsive where it pushes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Branch {
    /// No force at all: the tip never reaches the surface and nothing pulls it.
    Free,
    /// The mean force pulls the tip towards the sample.
    Attractive,
    /// The mean force pushes the tip away.
    Repulsive,
}

impl Branch {
    /// The branch of an orbit whose mean force over a period is `mean_force` (N).
    pub fn of(mean_force: f64) -> Self {
        if mean_force > 0.0 {
            Self::Repulsive
        } else if mean_force < 0.0 {
            Self::Attractive
        } else {
            Self::Free
        }
    }

    /// Its name: "free", "attractive", "repulsive".
    pub fn name(self) -> &'static str {
        match self {
            Self::Free => "free",
            Self::Attractive => "attractive",
            Self::Repulsive => "repulsive",
        }
    }
}

/// Where an approach from far jumped from one orbit to another: the branch it was on ended.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Jump {
    /// The surface distance (m) of the first orbit after the jump.
    pub distance: f64,
    /// The branch before the jump.
    pub from: Branch,
    /// The branch after it.
    pub to: Branch,
}

/// The periodic steady state and what physics.md §6 reports of it.
#[derive(Clone, Debug)]
pub struct CoupledOrbit {
    /// Base amplitude U (m) that gives the free amplitude.
    pub base_amplitude: f64,
    /// Peak tip–sample force F (N): the largest push; where the tip never pushes (adhesion,
    /// out of contact) the strongest pull, negative; 0 where no force acts.
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
    /// Newton iterations taken (by the last Newton solve of the search).
    pub newton_iterations: usize,
    /// Drive periods the search integrated to find the orbit, its measure aside (1): what
    /// it cost, against [`SearchLimits::max_periods`].
    pub periods: usize,
    /// Product of the Floquet multipliers (det of the monodromy matrix) (1).
    pub floquet_product: f64,
    /// Largest Floquet multiplier modulus estimate (spectral radius bound by power
    /// iteration) (1): below 1 means a stable period-1 orbit.
    pub floquet_max: f64,
    /// Whether the orbit is period 1: the fixed point converged and is stable.
    pub period_one: bool,
    /// The regime: by the sign of the mean force (`force_coefficients[0]`).
    pub branch: Branch,
    /// Where the approach from far that reached this orbit jumped between orbits (empty for
    /// an orbit continued from a nearby problem's or found from a contact start).
    pub jumps: Vec<Jump>,
    /// Contact work ∮ g ż dt over one period (J): 0 for a conservative (Hertz) contact.
    pub contact_work: f64,
    /// Work done by the base drive on the modes over one period (J).
    pub drive_work: f64,
    /// Energy dissipated by the modal damping over one period (J).
    pub damping_work: f64,
    /// ∮ g u̇ dt (J): what the contact force does against the moving base.
    pub base_contact_work: f64,
}

/// Scaled residual at which [`CoupledProblem::solve_continued`] stops: below what the
/// measurement resolves (a table node's F and τ move by ~1e-10 of themselves).
const CONTINUED: NewtonLimits = NewtonLimits {
    tolerance: 1e-10,
    iterations: 60,
    refreshes: 8,
};

/// Where a nearby problem's orbit search starts ([`CoupledProblem::solve_continued`]): the
/// fixed point's modal deviations and the Jacobian of the one-period map there.
#[derive(Clone, Debug)]
pub struct Continuation {
    h: Vec<f64>,
    jacobian: Option<Matrix>,
}

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
    /// no approach, and Newton's matrix is `from`'s until the residual stops falling by
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
        if from.h.len() != 2 * self.modes.len() {
            return Err(CoupledError::Integration(
                "the continuation is for another number of modes".into(),
            ));
        }
        let periods = Cell::new(0);
        let map = PeriodMap::new(self, &periods, SearchLimits::default());
        let fixed = newton(&map, from.h.clone(), from.jacobian.clone(), CONTINUED)?;
        let periods = periods.get();
        let (floquet_product, floquet_max) = match (&fixed.jacobian, fixed.fresh) {
            (Some(j), true) => floquet(j),
            _ => (f64::NAN, f64::NAN),
        };
        let record = map.measure_period(&fixed.h, harmonics)?;
        let mut orbit = self.measure(
            fixed.h.clone(),
            record,
            fixed.residual,
            fixed.iterations,
            floquet_product,
            floquet_max,
        );
        orbit.periods = periods;
        if !fixed.fresh {
            orbit.period_one = true;
        }
        Ok((
            orbit,
            Continuation {
                h: fixed.h,
                jacobian: fixed.jacobian,
            },
        ))
    }

    /// [`Self::solve`], with what a nearby problem can continue from
    /// ([`Self::solve_continued`]).
    pub fn solve_for_continuation(
        &self,
        harmonics: usize,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        self.solve_with(harmonics, SearchLimits::default())
    }

    /// The orbit an approach from far reaches (the branch a user's approach lands on; see
    /// [`approach`]), measured with harmonics up to `harmonics`, within the default
    /// [`SearchLimits`].
    ///
    /// # Errors
    /// A documented reason for every orbit it does not find: [`CoupledError`].
    pub fn solve(&self, harmonics: usize) -> Result<CoupledOrbit, CoupledError> {
        self.solve_with(harmonics, SearchLimits::default())
            .map(|(orbit, _)| orbit)
    }

    /// [`Self::solve`] within `limits`, with what a nearby problem can continue from.
    ///
    /// # Errors
    /// As [`Self::solve`], and [`CoupledError::OverBudget`] / [`CoupledError::Cancelled`].
    pub fn solve_with(
        &self,
        harmonics: usize,
        limits: SearchLimits<'_>,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        let periods = Cell::new(0);
        let (fixed, mut jumps) = approach::approach(self, &periods, limits)?;
        let map = PeriodMap::new(self, &periods, limits);
        let fixed = tighten(&map, fixed)?;
        let monodromy = map.jacobian(&fixed.h)?;
        let (fixed, monodromy) = if floquet(&monodromy).1 < 1.0 {
            (fixed, monodromy)
        } else {
            // The approach ended on an unstable orbit, which the motion leaves: follow it
            // from a nudge off it.
            let nudged = fixed.h.iter().zip(&map.scale).map(|(x, s)| x + 1e-4 * s);
            let (landed, monodromy) = approach::settle(&map, nudged.collect(), approach::FINAL)?;
            jumps.push(Jump {
                distance: self.surface_distance,
                from: Branch::of(fixed.mean_force),
                to: Branch::of(landed.mean_force),
            });
            (landed, monodromy)
        };
        let (orbit, continuation) = self.finish(&map, fixed, monodromy, harmonics)?;
        let periods = periods.get();
        Ok((
            CoupledOrbit {
                jumps,
                periods,
                ..orbit
            },
            continuation,
        ))
    }

    /// The orbit the tip settles on when the surface appears under the free orbit at the
    /// problem's distance (the first tap is the hardest): the other branch, where an
    /// attractive and a repulsive orbit coexist and the approach reaches the attractive one.
    ///
    /// # Errors
    /// As [`Self::solve_with`].
    pub fn solve_from_contact(
        &self,
        harmonics: usize,
        limits: SearchLimits<'_>,
    ) -> Result<CoupledOrbit, CoupledError> {
        self.solve_from_contact_for_continuation(harmonics, limits)
            .map(|(orbit, _)| orbit)
    }

    /// [`Self::solve_from_contact`], with what a nearby problem can continue from
    /// ([`Self::solve_continued`]): the contact branch traced to other distances.
    ///
    /// # Errors
    /// As [`Self::solve_with`].
    pub fn solve_from_contact_for_continuation(
        &self,
        harmonics: usize,
        limits: SearchLimits<'_>,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        let periods = Cell::new(0);
        let map = PeriodMap::new(self, &periods, limits);
        let (fixed, monodromy) =
            approach::settle(&map, vec![0.0; 2 * self.modes.len()], approach::FINAL)?;
        let (orbit, continuation) = self.finish(&map, fixed, monodromy, harmonics)?;
        Ok((
            CoupledOrbit {
                periods: periods.get(),
                ..orbit
            },
            continuation,
        ))
    }

    /// The orbit of a converged fixed point with its monodromy matrix: measured.
    fn finish(
        &self,
        map: &PeriodMap<'_>,
        fixed: fixed_point::FixedPoint,
        monodromy: Matrix,
        harmonics: usize,
    ) -> Result<(CoupledOrbit, Continuation), CoupledError> {
        let (floquet_product, floquet_max) = floquet(&monodromy);
        let record = map.measure_period(&fixed.h, harmonics)?;
        let orbit = self.measure(
            fixed.h.clone(),
            record,
            fixed.residual,
            fixed.iterations,
            floquet_product,
            floquet_max,
        );
        Ok((
            orbit,
            Continuation {
                h: fixed.h,
                jacobian: Some(monodromy),
            },
        ))
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
        let (push, pull, max_indentation) = record.force.iter().fold(
            (0.0f64, 0.0f64, 0.0f64),
            |(push, pull, d), &(_, g, delta)| (push.max(g), pull.min(g), d.max(delta)),
        );
        // Out of contact with adhesion the force's peak is its strongest pull.
        let max_force = if push > 0.0 { push } else { pull };
        let contact_time = record.contact_time;
        let fwhm = full_width_at_half_maximum(&from_minimum(&record.force, t_period), max_force);
        let t_peak = record
            .force
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0.0, |p| p.0);
        let pulse_phase = (self.drive_omega * t_peak).rem_euclid(2.0 * PI);
        let c = record.coefficients;
        let branch = Branch::of(c.first().map_or(0.0, |c0| c0.re));
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
            branch,
            jumps: Vec::new(),
            periods: 0,
            contact_work: record.contact_work,
            drive_work: record.drive_work,
            damping_work: record.damping_work,
            base_contact_work: record.base_contact_work,
        }
    }
}

/// A fixed point to the final tolerance, if a step of the search left it looser.
fn tighten(
    map: &PeriodMap<'_>,
    fixed: fixed_point::FixedPoint,
) -> Result<fixed_point::FixedPoint, CoupledError> {
    if fixed.residual < approach::FINAL.tolerance {
        Ok(fixed)
    } else {
        newton(map, fixed.h, fixed.jacobian, approach::FINAL)
    }
}

impl CoupledOrbit {
    /// θ in degrees, as the paper prints it.
    pub fn phase_shift_deg(&self) -> f64 {
        self.phase_shift.to_degrees()
    }
}

#[cfg(test)]
mod tests {
    use super::super::contact::Elastic;
    use super::record::{DENSE_HARMONICS, fft_coefficients};
    use super::*;

    /// The paper's silicon case: f1 = 100 kHz, k = 20 N/m, five Q, R = 10 nm, A = 30 nm,
    /// A_set = 20 nm.
    fn silicon_case() -> CoupledProblem {
        let beam = Cantilever::new(100e3, 20.0, &[100.0, 417.0, 340.0, 200.0, 26.0], 0).unwrap();
        let si = Elastic {
            youngs_modulus: 129e9,
            poisson: 0.28,
        };
        CoupledProblem::new(&beam, 100e3, 30e-9, 20e-9, HertzContact::new(si, si, 10e-9))
    }

    #[test]
    fn the_ffts_harmonics_are_the_sums_on_the_integrators_points() {
        let p = silicon_case();
        let orbit = p.solve(4).unwrap();
        let periods = Cell::new(0);
        let map = PeriodMap::new(&p, &periods, SearchLimits::default());
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

    /// With adhesion the force never vanishes and the integrator's steps out of contact are
    /// long (up to T/4000): the coefficients must not depend on that length. Measured on
    /// the same orbit with the steps out of contact 16 times shorter, harmonics 1–32 agree
    /// to ~1e-9 of each (a trapezoid on the steps' ends differs by 4.6e-6 already at H1).
    #[test]
    fn adhesions_coefficients_do_not_depend_on_the_step_out_of_contact() {
        let p = silicon_case().with_adhesion(Some(Adhesion {
            hamaker: 6.4e-20,
            distance: 0.165e-9,
        }));
        let orbit = p.solve(4).unwrap();
        let periods = Cell::new(0);
        let coarse = PeriodMap::new(&p, &periods, SearchLimits::default());
        let mut fine = PeriodMap::new(&p, &periods, SearchLimits::default());
        fine.scan_step /= 16.0;
        let (a, b) = (
            coarse.measure_period(&orbit.initial_state, 32).unwrap(),
            fine.measure_period(&orbit.initial_state, 32).unwrap(),
        );
        for k in 1..=32 {
            let (ca, cb) = (a.coefficients[k], b.coefficients[k]);
            let rel = (ca - cb).norm() / cb.norm();
            println!("H{k}: |c| {:.4e} N, coarse − fine {rel:.2e}", cb.norm());
            assert!(rel < 1e-7, "H{k}: {rel:e}");
        }
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
