//! Which periodic orbit a user gets, and finding it every time: the orbit an approach from
//! far reaches, by continuation along the surface distance, and the orbit the tip settles
//! on when the surface appears under the free orbit (the "contact start").
//!
//! Continuation. Out of reach (beyond the free orbit's lowest point, plus a margin with
//! adhesion, whose pull has no edge) the free orbit is the orbit. From there the surface
//! moves towards the tip in steps; each step's orbit is found by Newton's method from the
//! previous one (extrapolated along the path), with the previous step's Jacobian as the
//! chord matrix. A step that fails, or lands on an unstable orbit, is halved; where the
//! branch ends (a fold: the attractive regime giving way to the repulsive one) no step is
//! small enough, and the tip does what it does on a real approach: it jumps. The jump is
//! followed in time from the last orbit, one mode-1 decay time at a time, with a Newton
//! attempt after each, until a stable orbit takes it; it is reported with the distance
//! where it happened and the branches on either side.
//!
//! The work is counted in periods of the one-period map against the search's budget, and
//! every period checks for cancellation.

use std::cell::Cell;
use std::f64::consts::PI;

use super::fixed_point::{FixedPoint, Matrix, NewtonLimits, floquet, newton};
use super::period_map::PeriodMap;
use super::{Branch, CoupledError, CoupledProblem, Jump, SearchLimits};

/// Where an approach with adhesion starts, beyond the free orbit's lowest point, as a
/// fraction of the free amplitude: the DMT pull there is ~1e-4 of the tapping force scale.
const ADHESION_START_MARGIN: f64 = 0.2;
/// The first step of the continuation and the largest, as fractions of the free amplitude:
/// the path of an approach depends on the distances it passes, not on where it ends, so an
/// approach to a nearer surface passes through the orbits of one to a farther one.
const FIRST_STEP: f64 = 0.1;
const LARGEST_STEP: f64 = 0.2;
/// The smallest step before the branch counts as ended (fraction of the free amplitude).
const SMALLEST_STEP: f64 = 1e-3;
/// How far past the end of a branch the surface moves before the jump is followed
/// (fraction of the free amplitude): right at a fold the motion lingers for a long time
/// near the vanished orbit, as it would on an approach that stopped there.
const PAST_THE_END: f64 = 0.02;
/// Mode-1 decay times a jump is followed for before it counts as never settling.
const SETTLE_DECAY_TIMES: usize = 24;

/// The Newton solves on the way, the last one's included: loose, the next step corrects
/// what is left, and the search tightens its end to [`FINAL`] (a Newton to 1e-11 at a step's
/// end can stall on the integrator's own noise where one to 1e-7 passes: counted as the end
/// of the branch, that jumped to the other one).
const STEP: NewtonLimits = NewtonLimits {
    tolerance: 1e-7,
    iterations: 30,
    refreshes: 3,
};
/// The Newton solves that end a search.
pub(super) const FINAL: NewtonLimits = NewtonLimits {
    tolerance: 1e-11,
    iterations: 30,
    refreshes: 4,
};

/// The same problem with the surface at `distance` (m).
fn at(problem: &CoupledProblem, distance: f64) -> CoupledProblem {
    CoupledProblem {
        surface_distance: distance,
        ..problem.clone()
    }
}

/// The surface distance (m) at which the free orbit's lowest point just touches: −min z.
fn grazing_distance(map: &PeriodMap<'_>) -> f64 {
    const POINTS: usize = 4096;
    let zero = vec![0.0; 2 * map.p.modes.len()];
    (0..POINTS)
        .map(|i| -map.tip(i as f64 * map.t_period / POINTS as f64, &zero))
        .fold(f64::MIN, f64::max)
}

/// The orbit an approach from far reaches at the problem's surface distance, and the jumps
/// on the way.
pub(super) fn approach(
    problem: &CoupledProblem,
    periods: &Cell<usize>,
    limits: SearchLimits<'_>,
) -> Result<(FixedPoint, Vec<Jump>), CoupledError> {
    let target = problem.surface_distance;
    let n = 2 * problem.modes.len();
    let graze = grazing_distance(&PeriodMap::new(problem, periods, limits));
    let margin = if problem.adhesion.is_some() {
        ADHESION_START_MARGIN * problem.free_amplitude
    } else {
        0.0
    };
    let start = target.max(graze + margin);
    let far = at(problem, start);
    let mut fixed = newton(
        &PeriodMap::new(&far, periods, limits),
        vec![0.0; n],
        None,
        STEP,
    )?;
    let amplitude = problem.free_amplitude;
    let smallest = SMALLEST_STEP * amplitude;
    let mut jumps = Vec::new();
    let mut distance = start;
    let mut step = FIRST_STEP * amplitude;
    // The orbit before the current one, for the predictor.
    let mut before: Option<(f64, Vec<f64>)> = None;
    while distance > target {
        let next = (distance - step).max(target);
        let predicted = match &before {
            Some((d, h)) => {
                let s = (distance - next) / (d - distance);
                fixed
                    .h
                    .iter()
                    .zip(h)
                    .map(|(x, y)| x + s * (x - y))
                    .collect()
            }
            None => fixed.h.clone(),
        };
        let there = at(problem, next);
        let map = PeriodMap::new(&there, periods, limits);
        let found = match newton(&map, predicted, fixed.jacobian.clone(), STEP) {
            Ok(f) => Some(f),
            Err(CoupledError::NoConvergence { .. } | CoupledError::Integration(_)) => None,
            Err(e) => return Err(e),
        };
        // An unstable orbit is where the motion leaves the branch, as a fold is: a branch
        // can lose its stability and regain it further on (tap300 with adhesion, 4 nm free:
        // the attractive orbit's largest multiplier is 1.05 from a set-point ratio of 0.79
        // to 0.78, 0.994 on either side, and a nudge of 1e-5 off it grows to the other
        // branch), and an approach that stepped across such a window would report an orbit
        // no real approach reaches.
        let found = match found {
            Some(f) if !stable(&map, &f)? => None,
            other => other,
        };
        // An orbit on another branch than the step started from is a step too long (Newton
        // drawn into a coexisting orbit's basin) until the step is the smallest: then the
        // branch changed within it.
        let found = found.filter(|f| {
            let (was, is) = (Branch::of(fixed.mean_force), Branch::of(f.mean_force));
            was == is || was == Branch::Free || step <= smallest
        });
        match found {
            Some(f) => {
                let (was, is) = (Branch::of(fixed.mean_force), Branch::of(f.mean_force));
                if was != is && was != Branch::Free {
                    // The branch the approach was on gave way within the step.
                    jumps.push(Jump {
                        distance: next,
                        from: was,
                        to: is,
                    });
                }
                before = Some((distance, std::mem::replace(&mut fixed, f).h));
                distance = next;
                step = (1.5 * step).min(LARGEST_STEP * amplitude);
            }
            None if step > smallest => step *= 0.5,
            None => {
                // The branch ends here: follow the jump in time, from a little past the end.
                let next = (distance - PAST_THE_END * problem.free_amplitude).max(target);
                let there = at(problem, next);
                let map = PeriodMap::new(&there, periods, limits);
                let from = Branch::of(fixed.mean_force);
                let (landed, _) = settle(&map, fixed.h.clone(), STEP)?;
                jumps.push(Jump {
                    distance: next,
                    from,
                    to: Branch::of(landed.mean_force),
                });
                fixed = landed;
                before = None;
                distance = next;
                step = FIRST_STEP * amplitude;
            }
        }
    }
    Ok((fixed, jumps))
}

/// Whether the fixed point `f` of `map` is stable: its largest Floquet multiplier below 1,
/// from the monodromy matrix its Newton solve computed at its last refresh, else a fresh one
/// (4 periods per mode).
fn stable(map: &PeriodMap<'_>, f: &FixedPoint) -> Result<bool, CoupledError> {
    let largest = match (&f.jacobian, f.fresh) {
        (Some(j), true) => floquet(j).1,
        _ => floquet(&map.jacobian(&f.h)?).1,
    };
    Ok(largest < 1.0)
}

/// The stable orbit the motion from `h` settles on, and its monodromy matrix: periods of the
/// map in chunks of one mode-1 decay time (Q1/π periods), a Newton attempt after each, kept
/// if the exact multipliers say the orbit is stable.
///
/// # Errors
/// [`CoupledError::PeriodTwo`] when the motion repeats every other period instead,
/// [`CoupledError::NoSettling`] when it does not settle within
/// [`SETTLE_DECAY_TIMES`] decay times, and the budget's and integration's errors.
pub(super) fn settle(
    map: &PeriodMap<'_>,
    mut h: Vec<f64>,
    limits: NewtonLimits,
) -> Result<(FixedPoint, Matrix), CoupledError> {
    let chunk = ((map.p.modes[0].q / PI).ceil() as usize).clamp(8, 2000);
    for _ in 0..SETTLE_DECAY_TIMES {
        for _ in 0..chunk {
            h = map.period(&h)?;
        }
        match newton(map, h.clone(), None, limits) {
            Ok(f) => {
                let monodromy = map.jacobian(&f.h)?;
                if floquet(&monodromy).1 < 1.0 {
                    return Ok((f, monodromy));
                }
            }
            Err(CoupledError::NoConvergence { .. } | CoupledError::Integration(_)) => {}
            Err(e) => return Err(e),
        }
    }
    let once = map.period(&h)?;
    let twice = map.period(&once)?;
    let (r1, r2) = (map.residual(&h, &once), map.residual(&h, &twice));
    if r2 < 1e-3 * r1 {
        Err(CoupledError::PeriodTwo { residual: r2 })
    } else {
        Err(CoupledError::NoSettling {
            decay_times: SETTLE_DECAY_TIMES,
            residual: r1,
        })
    }
}
