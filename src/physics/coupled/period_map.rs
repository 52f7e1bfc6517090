//! The one-period map of the coupled problem: each mode's deviation from the free orbit
//! propagated exactly out of contact and integrated by Dormand–Prince 5(4) in contact.

use std::cell::Cell;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};

use rustfft::num_complex::Complex64;

use super::fixed_point::Matrix;
use super::record::Record;
use super::{CoupledError, CoupledProblem, SearchLimits};
use crate::physics::beam::MAX_MODES;

/// The step the out-of-contact scan takes, as a fraction of the fastest mode's period and of
/// the drive period: fine enough that no contact hides between two scan points.
pub(super) const SCAN_PER_FASTEST: f64 = 1.0 / 24.0;
pub(super) const SCAN_PER_PERIOD: f64 = 1.0 / 4000.0;
/// The largest step inside contact (fraction of the drive period) when the orbit is
/// measured, and while shooting.
pub(super) const CONTACT_STEP_MEASURE: f64 = 1.0 / 200_000.0;
pub(super) const CONTACT_STEP_SHOOT: f64 = 1.0 / 20_000.0;
/// Relative tolerance of the contact integration.
pub(super) const RTOL: f64 = 1e-11;

/// The one-period map and the pieces it is made of, precomputed for a problem.
pub(super) struct PeriodMap<'a> {
    pub(super) p: &'a CoupledProblem,
    pub(super) t_period: f64,
    pub(super) u: f64,
    /// U·Ŷn: free modal responses.
    pub(super) free: Vec<Complex64>,
    /// φn(L)/Mn: modal force per newton of tip force (1/kg).
    pub(super) force_gain: Vec<f64>,
    pub(super) scan_step: f64,
    /// Each mode's exact propagator over `scan_step`, the step the force-free stretch takes
    /// again and again.
    pub(super) scan_propagator: Vec<[[f64; 2]; 2]>,
    /// [`PeriodMap::scales`], once.
    pub(super) scale: Vec<f64>,
    /// Shooting periods integrated so far, against `max_periods`.
    periods: &'a Cell<usize>,
    max_periods: usize,
    cancel: Option<&'a AtomicBool>,
    /// The mean force (N) over the last period [`PeriodMap::period`] integrated: which side
    /// of zero tells the attractive regime from the repulsive one.
    mean_force: Cell<f64>,
}

impl<'a> PeriodMap<'a> {
    /// The map of `p`, counting its periods in `periods` against `limits`.
    pub(super) fn new(
        p: &'a CoupledProblem,
        periods: &'a Cell<usize>,
        limits: SearchLimits<'a>,
    ) -> Self {
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
            periods,
            max_periods: limits.max_periods,
            cancel: limits.cancel,
            mean_force: Cell::new(0.0),
        };
        map.scale = map.scales();
        map
    }

    /// Scales of the state components for residuals and difference steps: the free
    /// amplitude of each mode (at least 1e-3 of the free amplitude) and ωn times it.
    pub(super) fn scales(&self) -> Vec<f64> {
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
    pub(super) fn residual(&self, h: &[f64], next: &[f64]) -> f64 {
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
    pub(super) fn phasor(&self, t: f64) -> Complex64 {
        let (s, c) = (self.p.drive_omega * t).sin_cos();
        Complex64::new(c, s)
    }

    /// Base position and velocity at the drive phasor `e`.
    pub(super) fn base(&self, e: Complex64) -> (f64, f64) {
        (self.u * e.im, self.u * self.p.drive_omega * e.re)
    }

    /// Free modal displacement and velocity of mode n at the drive phasor `e`.
    pub(super) fn free_mode(&self, n: usize, e: Complex64) -> (f64, f64) {
        let y = self.free[n] * e;
        (y.im, (Complex64::i() * self.p.drive_omega * y).im)
    }

    /// Tip position z (m) at t for deviations h.
    pub(super) fn tip(&self, t: f64, h: &[f64]) -> f64 {
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
    pub(super) fn indentation(&self, t: f64, h: &[f64]) -> f64 {
        -self.p.surface_distance - self.tip(t, h)
    }

    /// Exact homogeneous propagation of h over dt.
    pub(super) fn propagate(&self, h: &[f64], dt: f64) -> Vec<f64> {
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
    pub(super) fn derivative(&self, t: f64, h: &[f64], out: &mut [f64]) {
        let g = self.p.force(self.indentation(t, h));
        for (n, m) in self.p.modes.iter().enumerate() {
            let (y, v) = (h[2 * n], h[2 * n + 1]);
            out[2 * n] = v;
            out[2 * n + 1] =
                -2.0 * m.gamma * m.omega * v - m.omega * m.omega * y + self.force_gain[n] * g;
        }
    }

    /// One Dormand–Prince 5(4) step: the 5th-order result and the error estimate.
    pub(super) fn dp_step(&self, t: f64, h: &[f64], dt: f64) -> (Vec<f64>, f64) {
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

    /// Φ(h): one shooting period from deviations `h` at t = 0, counted against the search's
    /// budget.
    ///
    /// # Errors
    /// [`CoupledError::Cancelled`], [`CoupledError::OverBudget`] and the integration's.
    pub(super) fn period(&self, h: &[f64]) -> Result<Vec<f64>, CoupledError> {
        if self.cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            return Err(CoupledError::Cancelled);
        }
        let done = self.periods.get();
        if done >= self.max_periods {
            return Err(CoupledError::OverBudget { periods: done });
        }
        self.periods.set(done + 1);
        self.integrate(h, CONTACT_STEP_SHOOT, None)
    }

    /// The mean force (N) over the last period integrated.
    pub(super) fn mean_force(&self) -> f64 {
        self.mean_force.get()
    }

    /// Integrates one period from deviations `h` at t = 0; records when asked.
    pub(super) fn integrate(
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
        // ∫g dt by the trapezoid on the Runge–Kutta's points (g vanishes on the exact
        // stretches): the mean force's sign is all it is used for.
        let mut impulse = 0.0;
        let mut g_last = self.p.force(self.indentation(0.0, &h));
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
                g_last = 0.0;
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
            let t_before = t;
            // The step's start, for the record's quadrature over it.
            let h_before = record.is_some().then(|| h.clone());
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
            let g = self.p.force(self.indentation(t, &h));
            impulse += 0.5 * (g_last + g) * (t - t_before);
            g_last = g;
            if let (Some(r), Some(h0)) = (record.as_deref_mut(), h_before) {
                self.add_step_coefficients(r, t_before, &h0, t);
                self.accumulate(r, t, &h);
            }
        }
        self.mean_force.set(impulse / t_end);
        Ok(h)
    }
}

/// exp(A·dt) of one damped mode, A = [[0, 1], [−ω², −2γω]], for any γ ≥ 0.
pub(super) fn modal_exponential(omega: f64, gamma: f64, dt: f64) -> [[f64; 2]; 2] {
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
    /// ∂Φ/∂h by central differences, scaled steps (2n periods).
    pub(super) fn jacobian(&self, h: &[f64]) -> Result<Matrix, CoupledError> {
        let n = h.len();
        let mut j = Matrix::zeros(n, n);
        for col in 0..n {
            let eps = 1e-6 * self.scale[col];
            let mut plus = h.to_vec();
            let mut minus = h.to_vec();
            plus[col] += eps;
            minus[col] -= eps;
            let fp = self.period(&plus)?;
            let fm = self.period(&minus)?;
            for row in 0..n {
                j[(row, col)] = (fp[row] - fm[row]) / (2.0 * eps);
            }
        }
        Ok(j)
    }
}
