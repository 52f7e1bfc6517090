//! The 1-DOF impact oscillator of the paper (Eq. 10–12) and its periodic steady state.
//!
//! `z'' + 2γ1ω1 z' + ω1²(z − A_d sin Ωt) = F_ts(z)/m`, m = k/ω1², tip position z positive
//! away from the sample, surface at z = −A_set, Hertz repulsion for indentation
//! δ = −A_set − z > 0.
//!
//! The periodic orbit is found by shooting: Newton's method on the one-period map, with its
//! Jacobian (the monodromy matrix) from the variational equations integrated alongside the
//! orbit by fixed-step RK4. The contact force is C¹ in z (∝ δ^{3/2}), so the monodromy
//! needs no saltation correction at the contact boundary. Accuracy is controlled by step
//! doubling until the pulse parameters change by less than the requested tolerance.
//! This takes a few milliseconds instead of integrating hundreds of transient periods.

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::contact::HertzContact;

/// Parameters of the 1-DOF tapping problem, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImpactOscillator {
    /// Spring constant k (N/m).
    pub k: f64,
    /// Resonance frequency f1 (Hz).
    pub f1: f64,
    /// Quality factor Q1 (1).
    pub q: f64,
    /// Drive frequency Ω/2π (Hz).
    pub drive_frequency: f64,
    /// Free tip amplitude at the drive frequency (m); fixes the base amplitude A_d.
    pub free_amplitude: f64,
    /// A_set: tip rest position to sample surface (m).
    pub surface_distance: f64,
    /// Tip–sample contact.
    pub contact: HertzContact,
}

/// The default [`SolveOptions::max_transient_periods`]: 10 000 periods of 1024 steps,
/// about 0.5 s of one core (Xeon, 2.5 GHz class), the full decay up to Q ≈ 1700. Above
/// that the solver still tries Newton from where the budget's transient leads, which
/// converges for the vacuum levers tried (Q up to 1e7); where it does not, the solve fails
/// with [`ImpactError::NoSteadyOrbit`] instead of integrating 6·Q periods (minutes).
pub const MAX_TRANSIENT_PERIODS: usize = 10_000;

/// Accuracy and effort of [`ImpactOscillator::solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveOptions {
    /// Steps per drive period to start from (a power of two is convenient).
    pub initial_steps: usize,
    /// Upper bound on steps per period.
    pub max_steps: usize,
    /// Step doubling stops when F, τ and the tapping amplitude change by less than this,
    /// relative (1).
    pub tolerance: f64,
    /// Most drive periods of transient the solver integrates, in all, to reach Newton's
    /// basin when Newton fails from its first guess (periods). The transient decays over
    /// about Q/π periods, so at a high Q the full decay (6·Q periods) may exceed it; the
    /// solve then fails with [`ImpactError::NoSteadyOrbit`] rather than running for
    /// minutes: this bounds a solve's time whatever the parameters.
    pub max_transient_periods: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            initial_steps: 1024,
            max_steps: 1 << 16,
            tolerance: 1e-6,
            max_transient_periods: MAX_TRANSIENT_PERIODS,
        }
    }
}

/// Why no periodic orbit was found.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ImpactError {
    /// Newton's method on the period map did not converge, even after a long transient.
    #[error(
        "the periodic orbit did not converge (residual {residual:.3e} after {iterations} iterations)"
    )]
    NoConvergence { residual: f64, iterations: usize },
    /// Newton did not converge, and the transient that would lead into its basin is longer
    /// than the solver's budget ([`SolveOptions::max_transient_periods`]).
    #[error(
        "no steady tapping orbit within {periods} drive periods of transient at Q = {q} \
         (a transient decays over about Q/π periods; Newton's residual {residual:.3e})"
    )]
    NoSteadyOrbit {
        periods: usize,
        q: f64,
        residual: f64,
    },
    /// The parameters are not physical (non-positive or non-finite).
    #[error("invalid 1-DOF parameters: {0}")]
    InvalidParameters(&'static str),
}

/// The periodic steady state of the 1-DOF tapping cantilever and its force pulse.
///
/// Phases are in radians of the drive, whose base motion is A_d·sin(Ωt).
#[derive(Clone, Debug, PartialEq)]
pub struct ImpactSolution {
    /// Steps per period of the orbit below.
    pub steps: usize,
    /// Tip position z (m) at phases 2πj/steps, j = 0..steps.
    pub position: Vec<f64>,
    /// Tip velocity dz/dt (m/s) at the same phases.
    pub velocity: Vec<f64>,
    /// Tip–sample force (N) at the same phases.
    pub force: Vec<f64>,
    /// Base (drive) amplitude A_d (m).
    pub base_amplitude: f64,
    /// Peak force F (N).
    pub max_force: f64,
    /// Maximum indentation δ_max (m).
    pub max_indentation: f64,
    /// τ of the cut cosine with the pulse's full width at half maximum: 1.5·FWHM/T (1).
    pub contact_time_ratio: f64,
    /// Fraction of the period with δ > 0 (1).
    pub contact_fraction: f64,
    /// Drive phase (rad, in [0, 2π)) of the lower turning point, where the force peaks.
    pub pulse_phase: f64,
    /// Peak amplitude of the fundamental of z (m).
    pub tapping_amplitude: f64,
    /// Phase lag of the fundamental of z behind the drive (rad).
    pub tapping_phase_lag: f64,
    /// Phase lag of the free oscillation behind the drive (rad).
    pub free_phase_lag: f64,
    /// Mean tip–sample force over a period (N).
    pub mean_force: f64,
    /// Mean tip position over a period (m).
    pub mean_position: f64,
    /// Relative change of F, τ and amplitude in the last step doubling (1): the error
    /// estimate of the coarser of the two solutions; this one is more accurate.
    pub error_estimate: f64,
    /// Newton iterations over all refinements.
    pub newton_iterations: usize,
}

impl ImpactSolution {
    /// θ: phase of the tapping fundamental relative to the free oscillation, in degrees, as
    /// the paper prints it (negative: tapping lags the drive less than the free tip does).
    pub fn phase_shift_deg(&self) -> f64 {
        (self.tapping_phase_lag - self.free_phase_lag).to_degrees()
    }

    /// Whether the tip touches the sample at all.
    pub fn in_contact(&self) -> bool {
        self.max_force > 0.0
    }

    /// Fourier coefficients c_k = (1/T)∫F(t)e^{−ikΩt}dt (N) of the simulated force,
    /// k = 0..=kmax, from an FFT of the orbit (Eq. 18 with the Dirac comb folded in).
    pub fn force_coefficients(&self, kmax: usize) -> Vec<Complex64> {
        two_sided_coefficients(&self.force, kmax)
    }

    /// Complex Fourier coefficients Z_k (m) of z, with z = Re Σ Z_k e^{ikΩt} (peak
    /// amplitudes |Z_k| for k ≥ 1; Z_0 is the mean).
    pub fn position_harmonics(&self, kmax: usize) -> Vec<Complex64> {
        let mut z = two_sided_coefficients(&self.position, kmax);
        for c in z.iter_mut().skip(1) {
            *c *= 2.0;
        }
        z
    }
}

/// (1/N)·DFT of one period of samples: the two-sided coefficients c_0..=c_kmax.
fn two_sided_coefficients(samples: &[f64], kmax: usize) -> Vec<Complex64> {
    let n = samples.len();
    let fft = realfft::RealFftPlanner::<f64>::new().plan_fft_forward(n);
    let mut input = samples.to_vec();
    let mut spectrum = fft.make_output_vec();
    fft.process(&mut input, &mut spectrum)
        .expect("buffer sizes come from the plan");
    spectrum
        .iter()
        .take(kmax.min(n / 2) + 1)
        .map(|c| c / n as f64)
        .collect()
}

/// Dimensionless form used by the integrator: phase s = Ωt, x = z/A_free.
#[derive(Clone, Copy)]
struct Scaled {
    /// ω1/Ω.
    r: f64,
    gamma: f64,
    /// A_d/A_free.
    base: f64,
    /// −A_set/A_free: the surface.
    surface: f64,
    /// κ√R·A_free^{1/2}/k: contact force per k·A_free per (indentation/A_free)^{3/2}.
    contact: f64,
}

impl Scaled {
    /// x'' and ∂x''/∂x at phase `s`.
    #[inline]
    fn accel(&self, s: f64, x: f64, v: f64) -> (f64, f64) {
        let r2 = self.r * self.r;
        let depth = self.surface - x;
        let (f, df) = if depth > 0.0 {
            let root = depth.sqrt();
            (self.contact * depth * root, 1.5 * self.contact * root)
        } else {
            (0.0, 0.0)
        };
        let a = -2.0 * self.gamma * self.r * v - r2 * (x - self.base * s.sin()) + r2 * f;
        (a, -r2 - r2 * df)
    }

    /// One period of RK4 from `y0` with the monodromy matrix.
    fn period_map(&self, y0: [f64; 2], steps: usize) -> ([f64; 2], [[f64; 2]; 2]) {
        let h = 2.0 * PI / steps as f64;
        let damp = -2.0 * self.gamma * self.r;
        // State: x, v, and the 2×2 sensitivity ∂(x, v)/∂(x0, v0) stored column-wise.
        let f = |s: f64, y: &[f64; 6]| -> [f64; 6] {
            let (a, dadx) = self.accel(s, y[0], y[1]);
            [
                y[1],
                a,
                y[3],
                dadx * y[2] + damp * y[3],
                y[5],
                dadx * y[4] + damp * y[5],
            ]
        };
        let mut y = [y0[0], y0[1], 1.0, 0.0, 0.0, 1.0];
        for j in 0..steps {
            let s = j as f64 * h;
            y = rk4_step(&f, s, &y, h);
        }
        ([y[0], y[1]], [[y[2], y[4]], [y[3], y[5]]])
    }

    /// Orbit samples (x, v) at the grid phases, starting from `y0`.
    fn orbit(&self, y0: [f64; 2], steps: usize) -> (Vec<f64>, Vec<f64>) {
        let h = 2.0 * PI / steps as f64;
        let f = |s: f64, y: &[f64; 2]| -> [f64; 2] { [y[1], self.accel(s, y[0], y[1]).0] };
        let mut xs = Vec::with_capacity(steps);
        let mut vs = Vec::with_capacity(steps);
        let mut y = y0;
        for j in 0..steps {
            xs.push(y[0]);
            vs.push(y[1]);
            y = rk4_step(&f, j as f64 * h, &y, h);
        }
        (xs, vs)
    }

    /// Newton on P(y) − y = 0 from `y`. Returns the fixed point and the iterations used.
    fn newton(&self, mut y: [f64; 2], steps: usize) -> Result<([f64; 2], usize), f64> {
        let mut residual = f64::INFINITY;
        for it in 1..=40 {
            let (p, m) = self.period_map(y, steps);
            let g = [p[0] - y[0], p[1] - y[1]];
            let norm = g[0].hypot(g[1]);
            // The orbit is O(1) in these units; 1e-13 is a few ulps of a period's rounding.
            if norm < 1e-13 {
                return Ok((y, it));
            }
            if norm > residual * 4.0 && it > 8 {
                return Err(norm);
            }
            residual = norm;
            let j = [[m[0][0] - 1.0, m[0][1]], [m[1][0], m[1][1] - 1.0]];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det == 0.0 || !det.is_finite() {
                return Err(norm);
            }
            let dx = (j[1][1] * g[0] - j[0][1] * g[1]) / det;
            let dv = (-j[1][0] * g[0] + j[0][0] * g[1]) / det;
            // Limit the step: far from the orbit the linearisation across the contact
            // boundary can overshoot into the sample.
            let step = dx.hypot(dv);
            let scale = if step > 0.25 { 0.25 / step } else { 1.0 };
            y = [y[0] - scale * dx, y[1] - scale * dv];
        }
        Err(residual)
    }

    /// Integrates `periods` whole periods (a transient) from `y`.
    fn settle(&self, y: [f64; 2], steps: usize, periods: usize) -> [f64; 2] {
        let h = 2.0 * PI / steps as f64;
        let f = |s: f64, y: &[f64; 2]| -> [f64; 2] { [y[1], self.accel(s, y[0], y[1]).0] };
        let mut y = y;
        for _ in 0..periods {
            for j in 0..steps {
                y = rk4_step(&f, j as f64 * h, &y, h);
            }
        }
        y
    }
}

#[inline]
fn rk4_step<const N: usize>(
    f: &impl Fn(f64, &[f64; N]) -> [f64; N],
    s: f64,
    y: &[f64; N],
    h: f64,
) -> [f64; N] {
    let add = |a: &[f64; N], b: &[f64; N], c: f64| -> [f64; N] {
        let mut o = *a;
        for i in 0..N {
            o[i] += c * b[i];
        }
        o
    };
    let k1 = f(s, y);
    let k2 = f(s + 0.5 * h, &add(y, &k1, 0.5 * h));
    let k3 = f(s + 0.5 * h, &add(y, &k2, 0.5 * h));
    let k4 = f(s + h, &add(y, &k3, h));
    let mut o = *y;
    for i in 0..N {
        o[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    o
}

impl ImpactOscillator {
    /// Base amplitude A_d (m) that gives the free tip amplitude at the drive frequency:
    /// A_free·√((1 − β²)² + (2γβ)²), β = Ω/ω1 (A_free/Q at resonance).
    pub fn base_amplitude(&self) -> f64 {
        let beta = self.drive_frequency / self.f1;
        let gamma = 0.5 / self.q;
        self.free_amplitude * ((1.0 - beta * beta).powi(2) + (2.0 * gamma * beta).powi(2)).sqrt()
    }

    /// Phase lag (rad) of the free oscillation behind the drive, atan2(2γβ, 1 − β²).
    pub fn free_phase_lag(&self) -> f64 {
        let beta = self.drive_frequency / self.f1;
        (2.0 * (0.5 / self.q) * beta).atan2(1.0 - beta * beta)
    }

    fn scaled(&self) -> Scaled {
        Scaled {
            r: self.f1 / self.drive_frequency,
            gamma: 0.5 / self.q,
            base: self.base_amplitude() / self.free_amplitude,
            surface: -self.surface_distance / self.free_amplitude,
            contact: self.contact.stiffness_coefficient() * self.free_amplitude.sqrt() / self.k,
        }
    }

    fn check(&self) -> Result<(), ImpactError> {
        let positive = [
            self.k,
            self.f1,
            self.q,
            self.drive_frequency,
            self.free_amplitude,
            self.surface_distance,
            self.contact.reduced_modulus,
            self.contact.radius,
        ];
        if positive.iter().all(|v| v.is_finite() && *v > 0.0) {
            Ok(())
        } else {
            Err(ImpactError::InvalidParameters(
                "k, f1, Q, drive frequency, amplitudes, distance, modulus and radius must be positive and finite",
            ))
        }
    }

    /// Solves for the periodic steady state with [`SolveOptions::default`].
    pub fn solve(&self) -> Result<ImpactSolution, ImpactError> {
        self.solve_with(&SolveOptions::default())
    }

    /// Solves for the periodic steady state, doubling the steps per period until the pulse
    /// parameters agree to `options.tolerance`.
    pub fn solve_with(&self, options: &SolveOptions) -> Result<ImpactSolution, ImpactError> {
        self.check()?;
        let sc = self.scaled();
        let free_lag = self.free_phase_lag();
        // The free orbit x = sin(s − φ) is the answer when it does not reach the surface.
        let free = [-free_lag.sin(), free_lag.cos()];
        let touches = -1.0 < sc.surface;
        let mut y = if touches {
            // Repulsive tapping: amplitude ≈ A_set, and (elastic contact) sin φ = A/A0 at
            // resonance, i.e. the tip lags the drive by less than the free tip does.
            let a = -sc.surface;
            let lag = free_lag - a.clamp(-1.0, 1.0).acos();
            [-a * lag.sin(), a * lag.cos()]
        } else {
            free
        };
        let mut steps = options.initial_steps.max(64);
        let mut iterations = 0;
        // Periods of transient still allowed, across every step count.
        let mut transient_left = options.max_transient_periods;
        let mut previous: Option<ImpactSolution> = None;
        loop {
            let y_fixed = match sc.newton(y, steps) {
                Ok((y_fixed, it)) => {
                    iterations += it;
                    y_fixed
                }
                Err(_) => {
                    // Far from the orbit: let the transient decay (time constant Q/π periods)
                    // and try again from where it leads.
                    let wanted = (6.0 * self.q).ceil() as usize;
                    let periods = wanted.min(transient_left);
                    transient_left -= periods;
                    let settled = sc.settle(y, steps.min(1024), periods);
                    match sc.newton(settled, steps) {
                        Ok((y_fixed, it)) => {
                            iterations += it;
                            y_fixed
                        }
                        Err(residual) if periods < wanted => {
                            return Err(ImpactError::NoSteadyOrbit {
                                periods: options.max_transient_periods,
                                q: self.q,
                                residual,
                            });
                        }
                        Err(residual) => {
                            return Err(ImpactError::NoConvergence {
                                residual,
                                iterations: iterations + 40,
                            });
                        }
                    }
                }
            };
            y = y_fixed;
            let mut solution = self.analyse(&sc, y_fixed, steps, free_lag);
            solution.newton_iterations = iterations;
            if let Some(prev) = previous.take() {
                let change = relative_change(&prev, &solution);
                solution.error_estimate = change;
                if change < options.tolerance || steps * 2 > options.max_steps {
                    return Ok(solution);
                }
            }
            previous = Some(solution);
            steps *= 2;
        }
    }

    fn analyse(&self, sc: &Scaled, y0: [f64; 2], steps: usize, free_lag: f64) -> ImpactSolution {
        let a0 = self.free_amplitude;
        let omega = 2.0 * PI * self.drive_frequency;
        let (xs, vs) = sc.orbit(y0, steps);
        let h = 2.0 * PI / steps as f64;
        let position: Vec<f64> = xs.iter().map(|x| x * a0).collect();
        let velocity: Vec<f64> = vs.iter().map(|v| v * a0 * omega).collect();
        let surface = -self.surface_distance;
        let force: Vec<f64> = position
            .iter()
            .map(|&z| self.contact.force(surface - z))
            .collect();
        let hermite = Hermite {
            xs: &xs,
            vs: &vs,
            h,
        };

        // Lower turning point: the sign change of v from − to + around the smallest x.
        let jmin = (0..steps)
            .min_by(|&a, &b| xs[a].total_cmp(&xs[b]))
            .unwrap_or(0);
        let (s_min, x_min) = hermite.minimum_near(jmin);
        let max_indentation = (surface / a0 - x_min).max(0.0) * a0;
        let max_force = self.contact.force(max_indentation);

        let (fwhm, contact_fraction) = if max_force > 0.0 {
            let half_depth = max_indentation * 0.5f64.powf(2.0 / 3.0);
            let x_half = (surface - half_depth) / a0;
            let width = |level: f64| hermite.width_below(jmin, level) / (2.0 * PI);
            (width(x_half), width(surface / a0))
        } else {
            (0.0, 0.0)
        };

        // Fundamental by the trapezoid rule, exact for trigonometric polynomials on the grid.
        let z1: Complex64 = xs
            .iter()
            .enumerate()
            .map(|(j, &x)| x * Complex64::from_polar(1.0, -(j as f64) * h))
            .sum::<Complex64>()
            * (2.0 / steps as f64);
        // x = A sin(s − φ) = Re[−iA e^{−iφ} e^{is}]  ⇒  φ = −arg(i·Z1).
        let tapping_phase_lag = -(Complex64::i() * z1).arg();
        let n = steps as f64;
        ImpactSolution {
            steps,
            base_amplitude: self.base_amplitude(),
            max_force,
            max_indentation,
            contact_time_ratio: 1.5 * fwhm,
            contact_fraction,
            pulse_phase: s_min.rem_euclid(2.0 * PI),
            tapping_amplitude: z1.norm() * a0,
            tapping_phase_lag,
            free_phase_lag: free_lag,
            mean_force: force.iter().sum::<f64>() / n,
            mean_position: position.iter().sum::<f64>() / n,
            position,
            velocity,
            force,
            error_estimate: f64::NAN,
            newton_iterations: 0,
        }
    }
}

fn relative_change(a: &ImpactSolution, b: &ImpactSolution) -> f64 {
    let rel = |p: f64, q: f64| {
        let scale = p.abs().max(q.abs());
        if scale == 0.0 {
            0.0
        } else {
            (p - q).abs() / scale
        }
    };
    rel(a.max_force, b.max_force)
        .max(rel(a.contact_time_ratio, b.contact_time_ratio))
        .max(rel(a.tapping_amplitude, b.tapping_amplitude))
}

/// Cubic Hermite interpolation of the periodic orbit between grid points (O(h⁴)).
struct Hermite<'a> {
    xs: &'a [f64],
    vs: &'a [f64],
    h: f64,
}

impl Hermite<'_> {
    fn n(&self) -> usize {
        self.xs.len()
    }

    /// x at fraction t ∈ [0, 1] of interval j (wrapping around the period).
    fn x(&self, j: usize, t: f64) -> f64 {
        let n = self.n();
        let (x0, x1) = (self.xs[j % n], self.xs[(j + 1) % n]);
        let (v0, v1) = (self.vs[j % n] * self.h, self.vs[(j + 1) % n] * self.h);
        let t2 = t * t;
        let t3 = t2 * t;
        (2.0 * t3 - 3.0 * t2 + 1.0) * x0
            + (t3 - 2.0 * t2 + t) * v0
            + (-2.0 * t3 + 3.0 * t2) * x1
            + (t3 - t2) * v1
    }

    /// dx/dt (per unit t) at fraction t of interval j.
    fn dx(&self, j: usize, t: f64) -> f64 {
        let n = self.n();
        let (x0, x1) = (self.xs[j % n], self.xs[(j + 1) % n]);
        let (v0, v1) = (self.vs[j % n] * self.h, self.vs[(j + 1) % n] * self.h);
        let t2 = t * t;
        (6.0 * t2 - 6.0 * t) * x0
            + (3.0 * t2 - 4.0 * t + 1.0) * v0
            + (-6.0 * t2 + 6.0 * t) * x1
            + (3.0 * t2 - 2.0 * t) * v1
    }

    /// Phase s (rad, unwrapped near grid point j) and value of the minimum near grid point j.
    fn minimum_near(&self, j: usize) -> (f64, f64) {
        let n = self.n();
        let prev = (j + n - 1) % n;
        // The minimum lies in [prev, j] if v(j) > 0, else in [j, j + 1].
        let (interval, base) = if self.vs[j] > 0.0 {
            (prev, j as f64 - 1.0)
        } else {
            (j, j as f64)
        };
        let t = bisect(|t| self.dx(interval, t), 0.0, 1.0);
        ((base + t) * self.h, self.x(interval, t))
    }

    /// Width in phase (rad) of the stretch around the minimum at s_min where x < level.
    fn width_below(&self, jmin: usize, level: f64) -> f64 {
        let n = self.n() as isize;
        let at = |i: isize| self.xs[i.rem_euclid(n) as usize];
        // Walk out from the minimum to the first grid points above the level.
        let mut right = jmin as isize;
        while at(right) < level && right - (jmin as isize) < n {
            right += 1;
        }
        let mut left = jmin as isize;
        while at(left) < level && (jmin as isize) - left < n {
            left -= 1;
        }
        let root = |i: isize| {
            let j = i.rem_euclid(n) as usize;
            let t = bisect(|t| self.x(j, t) - level, 0.0, 1.0);
            (i as f64 + t) * self.h
        };
        let s_right = root(right - 1);
        let s_left = root(left);
        // Both crossings are unwrapped relative to the same grid index, so this is a width.
        s_right - s_left
    }
}

/// Root of `f` in [a, b] by bisection, given a sign change (or the end nearer zero).
fn bisect(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    let fa = f(a);
    let fb = f(b);
    if fa == 0.0 {
        return a;
    }
    if fb == 0.0 || (fa > 0.0) == (fb > 0.0) {
        return if fa.abs() < fb.abs() { a } else { b };
    }
    for _ in 0..80 {
        let m = 0.5 * (a + b);
        let fm = f(m);
        if (fm > 0.0) == (fa > 0.0) {
            a = m;
        } else {
            b = m;
        }
    }
    0.5 * (a + b)
}
