//! The periodic orbit as a fixed point of the one-period map `h(0) ↦ h(T)`: Newton's method
//! (with a chord matrix where a nearby one serves), and the orbit's Floquet multipliers, the
//! eigenvalues of the monodromy matrix.

use nalgebra::DMatrix;

use super::CoupledError;
use super::period_map::PeriodMap;

/// The one-period map's Jacobian ∂Φ/∂h (n × n, n = 2 × modes): at a fixed point, the
/// monodromy matrix.
pub(super) type Matrix = DMatrix<f64>;

/// How hard one Newton solve tries.
#[derive(Clone, Copy, Debug)]
pub(super) struct NewtonLimits {
    /// Scaled residual |Φ(h) − h| at which it stops (1).
    pub tolerance: f64,
    /// Newton steps at most.
    pub iterations: usize,
    /// Fresh Jacobians at most (each costs 2n periods).
    pub refreshes: usize,
}

/// A converged fixed point.
pub(super) struct FixedPoint {
    /// The modal deviations at t = 0 (m, m/s per mode).
    pub h: Vec<f64>,
    /// Its scaled residual (1).
    pub residual: f64,
    /// Newton steps taken.
    pub iterations: usize,
    /// The mean force (N) over the period from `h`.
    pub mean_force: f64,
    /// The last Jacobian used: the monodromy matrix if `fresh`, else a nearby problem's;
    /// none if `h` was a fixed point already.
    pub jacobian: Option<Matrix>,
    /// Whether `jacobian` was computed by this solve.
    pub fresh: bool,
}

/// Newton's method on Φ(h) − h = 0 from `h`, with `jacobian` as the chord matrix while it
/// halves the residual at every step (a nearby fixed point's: the previous node of a table,
/// the previous set-point of an approach), and the Jacobian at the current iterate whenever a
/// step fails to; a step that still fails is damped (halved down to 1/64) if that lowers the
/// residual at all.
///
/// # Errors
/// [`CoupledError::NoConvergence`] when the residual stops falling above the tolerance, and
/// the integration's own errors.
pub(super) fn newton(
    map: &PeriodMap<'_>,
    mut h: Vec<f64>,
    jacobian: Option<Matrix>,
    limits: NewtonLimits,
) -> Result<FixedPoint, CoupledError> {
    let n = h.len();
    let mut next = map.period(&h)?;
    let mut mean_force = map.mean_force();
    let mut residual = map.residual(&h, &next);
    let mut jacobian = jacobian.filter(|j| j.nrows() == n);
    let (mut fresh, mut current, mut refreshes) = (false, false, 0);
    let mut iterations = 0;
    while residual >= limits.tolerance && iterations < limits.iterations {
        let j = match &jacobian {
            Some(j) => j,
            None => {
                refreshes += 1;
                (fresh, current) = (true, true);
                jacobian.insert(map.jacobian(&h)?)
            }
        };
        iterations += 1;
        let delta = (j - Matrix::identity(n, n))
            .lu()
            .solve(&nalgebra::DVector::from_iterator(
                n,
                h.iter().zip(&next).map(|(x, y)| x - y),
            ));
        let accepted = match delta {
            Some(delta) => {
                let step = |s: f64| -> Vec<f64> {
                    h.iter().zip(delta.iter()).map(|(x, d)| x + s * d).collect()
                };
                let trial = step(1.0);
                let trial_next = map.period(&trial)?;
                let trial_mean = map.mean_force();
                let r = map.residual(&trial, &trial_next);
                if r < 0.5 * residual {
                    Some((trial, trial_next, trial_mean, r))
                } else if !current && refreshes < limits.refreshes {
                    None
                } else {
                    // Damped: the first fraction of the step that lowers the residual.
                    let mut best = (r < residual).then_some((trial, trial_next, trial_mean, r));
                    let mut s = 0.5;
                    while best.is_none() && s >= 1.0 / 64.0 {
                        let trial = step(s);
                        let trial_next = map.period(&trial)?;
                        let r = map.residual(&trial, &trial_next);
                        if r < residual {
                            best = Some((trial, trial_next, map.mean_force(), r));
                        }
                        s *= 0.5;
                    }
                    match best {
                        Some(b) => Some(b),
                        None => break,
                    }
                }
            }
            None if !current && refreshes < limits.refreshes => None,
            None => break,
        };
        match accepted {
            Some((trial, trial_next, trial_mean, r)) => {
                if let Some(j) = jacobian.as_mut() {
                    broyden(j, &trial, &h, &trial_next, &next, &map.scale);
                }
                (h, next, mean_force, residual) = (trial, trial_next, trial_mean, r);
                current = false;
            }
            // The matrix (borrowed, or an earlier iterate's) no longer helps: Newton's own,
            // here, at the next turn.
            None => jacobian = None,
        }
    }
    if residual >= limits.tolerance {
        return Err(CoupledError::NoConvergence {
            residual,
            iterations,
        });
    }
    Ok(FixedPoint {
        h,
        residual,
        iterations,
        mean_force,
        jacobian,
        fresh,
    })
}

/// Broyden's rank-one update of the chord matrix `j` after the step `h0 → h1` that took
/// Φ from `f0` to `f1`: the secant condition J·Δh = ΔΦ, with the smallest change in the
/// scaled norm (positions and velocities weighed by `scale`). It keeps a nearby problem's
/// matrix close to this one's without the 2n periods of a fresh one.
fn broyden(j: &mut Matrix, h1: &[f64], h0: &[f64], f1: &[f64], f0: &[f64], scale: &[f64]) {
    let n = h1.len();
    let dh: Vec<f64> = h1.iter().zip(h0).map(|(a, b)| a - b).collect();
    let weight: Vec<f64> = dh.iter().zip(scale).map(|(d, s)| d / (s * s)).collect();
    let norm: f64 = dh.iter().zip(&weight).map(|(d, w)| d * w).sum();
    if !(norm > 0.0 && norm.is_finite()) {
        return;
    }
    for row in 0..n {
        let predicted: f64 = (0..n).map(|c| j[(row, c)] * dh[c]).sum();
        let miss = (f1[row] - f0[row]) - predicted;
        for (c, w) in weight.iter().enumerate() {
            j[(row, c)] += miss * w / norm;
        }
    }
}

/// The Floquet multipliers of a monodromy matrix: (their product, the largest modulus).
pub(super) fn floquet(monodromy: &Matrix) -> (f64, f64) {
    let largest = monodromy
        .complex_eigenvalues()
        .iter()
        .map(|m| m.norm())
        .fold(0.0, f64::max);
    (monodromy.determinant(), largest)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A damped rotation's multipliers: the eigenvalues r·e^{±iφ} and r₂ of a block matrix.
    #[test]
    fn floquet_reads_the_eigenvalues_of_a_rotation() {
        let (r, phi, r2) = (0.992, 0.3f64, 0.5);
        let m = Matrix::from_row_slice(
            3,
            3,
            &[
                r * phi.cos(),
                -r * phi.sin(),
                0.0,
                r * phi.sin(),
                r * phi.cos(),
                0.0,
                0.0,
                0.0,
                r2,
            ],
        );
        let (product, largest) = floquet(&m);
        assert!((largest - r).abs() < 1e-12, "{largest}");
        assert!((product - r * r * r2).abs() < 1e-12, "{product}");
    }
}
