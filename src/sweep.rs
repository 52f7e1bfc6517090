//! The sweeper's arithmetic, free of sockets and threads: the points of a sweep, how long
//! to let the cantilever and the lock-in settle at each, the fit of a tune and what an
//! approach curve shows (where contact starts, jumps between branches, hysteresis).
//! `server::sweeper` runs sweeps with it.

use std::f64::consts::PI;

/// The nodes a sweep may step.
pub const PARAMETERS: [&str; 4] = [
    "/drive/frequency",
    "/surface/distance",
    "/drive/free_amplitude",
    "/sample/youngs_modulus",
];

/// Which way a point was reached: from `start` towards `stop` (`Up`; for a distance
/// sweep from far to near, the approach) or back (`Down`, the retract).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Leg {
    /// From `start` towards `stop`.
    Up,
    /// From `stop` back towards `start`.
    Down,
}

impl Leg {
    /// `"up"` or `"down"`, as the sweep stream names it.
    pub fn name(self) -> &'static str {
        match self {
            Leg::Up => "up",
            Leg::Down => "down",
        }
    }
}

/// One point of a sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    /// The parameter's value (its node's unit).
    pub value: f64,
    /// The leg it belongs to.
    pub leg: Leg,
}

/// The values of a sweep from `start` to `stop` in `n` points (both ends included),
/// evenly spaced (`log = false`) or evenly spaced in log (both ends > 0), over the legs
/// `up` and/or `down` (both: up, then down from `stop` back to `start`, the turning point
/// measured on both legs).
pub fn points(start: f64, stop: f64, n: usize, log: bool, up: bool, down: bool) -> Vec<Point> {
    let at = |i: usize| -> f64 {
        if n < 2 {
            return start;
        }
        let x = i as f64 / (n - 1) as f64;
        if i == 0 {
            start
        } else if i == n - 1 {
            stop
        } else if log {
            (start.ln() + x * (stop.ln() - start.ln())).exp()
        } else {
            start + x * (stop - start)
        }
    };
    let mut out = Vec::with_capacity(2 * n);
    if up {
        out.extend((0..n).map(|i| Point {
            value: at(i),
            leg: Leg::Up,
        }));
    }
    if down {
        out.extend((0..n).rev().map(|i| Point {
            value: at(i),
            leg: Leg::Down,
        }));
    }
    out
}

/// Time (s) for a cascade of `order` first-order low-pass filters of time constant
/// `timeconstant` (s) to settle within `inaccuracy` (relative) of a step:
/// x·τ where 1 − e^{−x}·Σ_{k<order} x^k/k! = 1 − inaccuracy.
pub fn filter_settling(order: u32, timeconstant: f64, inaccuracy: f64) -> f64 {
    let order = order.max(1);
    let remaining = |x: f64| -> f64 {
        let (mut term, mut sum) = (1.0, 1.0);
        for k in 1..order {
            term *= x / f64::from(k);
            sum += term;
        }
        (-x).exp() * sum
    };
    // remaining(x) falls monotonically from 1: bisect.
    let (mut lo, mut hi) = (0.0, 1.0);
    while remaining(hi) > inaccuracy {
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if remaining(mid) > inaccuracy {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi * timeconstant
}

/// Time (s) for a mode of frequency `f` (Hz) and quality factor `q` to ring down to
/// `inaccuracy` of a step in its drive: the amplitude envelope decays as e^{−πft/Q}.
pub fn ring_down(f: f64, q: f64, inaccuracy: f64) -> f64 {
    q / (PI * f) * (1.0 / inaccuracy).ln()
}

/// A tune's resonance from the amplitude response of a base-excited oscillator,
/// A(f) = a·f² / √((f0² − f²)² + (f0·f/Q)²) (the deflection of a lever whose base moves with
/// a fixed amplitude).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TuneFit {
    /// Resonance frequency (Hz).
    pub f0: f64,
    /// Quality factor (1).
    pub q: f64,
    /// The response's high-frequency limit `a` (m): the base amplitude seen by the
    /// detector.
    pub amplitude: f64,
}

/// Fits [`TuneFit`] to amplitudes `r` (m) at frequencies `f` (Hz): the model makes
/// f⁴/r² = (f0⁴ − (2 − 1/Q²)·f0²·f² + f⁴)/a², a quadratic in f², so a weighted linear
/// least-squares fit (weights r⁴/f⁸, i.e. relative errors of r) gives it in closed form.
/// `None` if there are fewer than three usable points or the data is not a resonance.
pub fn fit_tune(f: &[f64], r: &[f64]) -> Option<TuneFit> {
    let rows: Vec<(f64, f64, f64)> = f
        .iter()
        .zip(r)
        .filter(|(f, r)| f.is_finite() && r.is_finite() && **f > 0.0 && **r > 0.0)
        .map(|(&f, &r)| {
            let u = f * f;
            let y = u * u / (r * r);
            // Relative error of r → error of y ∝ 2y: weight 1/y².
            (u, y, 1.0 / (y * y))
        })
        .collect();
    if rows.len() < 3 {
        return None;
    }
    // Scale f² to O(1) so the normal equations stay well conditioned.
    let scale = rows.iter().map(|(u, _, _)| *u).fold(0.0, f64::max);
    let mut m = [[0.0f64; 3]; 3];
    let mut v = [0.0f64; 3];
    for &(u, y, w) in &rows {
        let x = u / scale;
        let basis = [1.0, x, x * x];
        for ((row, vi), bi) in m.iter_mut().zip(v.iter_mut()).zip(basis) {
            *vi += w * bi * y;
            for (mij, bj) in row.iter_mut().zip(basis) {
                *mij += w * bi * bj;
            }
        }
    }
    let [c0, c1, c2] = solve3(m, v)?;
    // y = c0 + c1·x + c2·x², x = f²/scale: c2 = scale²/a², c1 = −(2 − 1/Q²)·f0²·scale/a²,
    // c0 = f0⁴/a².
    if c0 <= 0.0 || c2 <= 0.0 {
        return None;
    }
    let f0_sq = (c0 / c2).sqrt() * scale;
    let a = scale / c2.sqrt();
    let inv_q_sq = 2.0 + c1 * a * a / (f0_sq * scale);
    if inv_q_sq <= 0.0 {
        return None;
    }
    Some(TuneFit {
        f0: f0_sq.sqrt(),
        q: 1.0 / inv_q_sq.sqrt(),
        amplitude: a,
    })
}

/// Solves the 3×3 system `m·x = v` by Gaussian elimination with partial pivoting.
fn solve3(mut m: [[f64; 3]; 3], mut v: [f64; 3]) -> Option<[f64; 3]> {
    for col in 0..3 {
        let pivot = (col..3).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        if m[pivot][col].abs() < 1e-300 {
            return None;
        }
        m.swap(col, pivot);
        v.swap(col, pivot);
        let pivot_row = m[col];
        for row in col + 1..3 {
            let k = m[row][col] / pivot_row[col];
            for (x, p) in m[row].iter_mut().zip(pivot_row).skip(col) {
                *x -= k * p;
            }
            v[row] -= k * v[col];
        }
    }
    let mut x = [0.0; 3];
    for row in (0..3).rev() {
        let tail: f64 = (row + 1..3).map(|j| m[row][j] * x[j]).sum();
        x[row] = (v[row] - tail) / m[row][row];
    }
    x.iter().all(|x| x.is_finite()).then_some(x)
}

/// Where an approach curve shows contact: the first value (in the order measured) at
/// which the amplitude `r` falls below `1 − drop` of the free amplitude, the mean of the
/// first `free_points` points (taken far from the surface).
pub fn contact_onset(values: &[f64], r: &[f64], free_points: usize, drop: f64) -> Option<f64> {
    let n = free_points.clamp(1, r.len().max(1));
    if r.len() < 2 {
        return None;
    }
    let free = r[..n].iter().sum::<f64>() / n as f64;
    values
        .iter()
        .zip(r)
        .find(|(_, r)| **r < (1.0 - drop) * free)
        .map(|(v, _)| *v)
}

/// A jump between branches: consecutive points whose amplitudes differ by more than
/// `threshold` (relative to the larger) and by more than three times the relative step of
/// the parameter (an amplitude that follows the parameter smoothly is no jump), at the
/// value before and after it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Jump {
    /// The parameter's value before the jump.
    pub from: f64,
    /// …and after it.
    pub to: f64,
    /// The amplitude before and after (m).
    pub r_before: f64,
    /// The amplitude after (m).
    pub r_after: f64,
}

/// The jumps of one leg (values and amplitudes in the order measured).
pub fn jumps(values: &[f64], r: &[f64], threshold: f64) -> Vec<Jump> {
    values
        .windows(2)
        .zip(r.windows(2))
        .filter(|(v, r)| {
            let dr = (r[1] - r[0]).abs() / r[0].abs().max(r[1].abs());
            let dv = (v[1] - v[0]).abs() / v[0].abs().max(v[1].abs());
            dr > threshold && dr > 3.0 * dv
        })
        .map(|(v, r)| Jump {
            from: v[0],
            to: v[1],
            r_before: r[0],
            r_after: r[1],
        })
        .collect()
}

/// Harmonic 1 within this share of its free amplitude and this phase (rad) of its free
/// phase, a point of an approach is free; a mean deflection within this (m) of the free
/// one leaves the regime to the phase (the default noise puts an averaged point's mean
/// within ~2 pm of it).
pub const FREE_DROP: f64 = 0.02;
pub const FREE_TWIST: f64 = 0.02;
pub const MEAN_FLOOR: f64 = 5e-12;

/// The tapping regime of one point of an approach curve, as the coupled engine names its
/// orbits (physics.md §6, `Branch`): by the sign of the mean tip–sample force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regime {
    /// The amplitude and phase of harmonic 1 are the free ones (within `drop` and `twist`).
    Free,
    /// The mean force pulls the tip towards the sample.
    Attractive,
    /// The mean force pushes the tip away.
    Repulsive,
}

impl Regime {
    /// The regime as a number, as a scan's `regime` channel holds it per pixel: −1
    /// attractive, 0 free, +1 repulsive (the sign of the mean force against the free lever's).
    pub fn code(self) -> f64 {
        match self {
            Regime::Attractive => -1.0,
            Regime::Free => 0.0,
            Regime::Repulsive => 1.0,
        }
    }

    /// The regime a `regime` channel's value names (the inverse of [`code`](Self::code)),
    /// `None` for NaN or anything else.
    pub fn from_code(code: f64) -> Option<Regime> {
        [Regime::Attractive, Regime::Free, Regime::Repulsive]
            .into_iter()
            .find(|r| r.code() == code)
    }

    /// `"free"`, `"attractive"` or `"repulsive"`, as the approach summary names it.
    pub fn name(self) -> &'static str {
        match self {
            Regime::Free => "free",
            Regime::Attractive => "attractive",
            Regime::Repulsive => "repulsive",
        }
    }
}

/// One point of an approach curve as the regime reads it: harmonic 1's amplitude `r` and
/// phase against the drive (rad), and the mean deflection (m) where a demodulator measures
/// harmonic 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ApproachPoint {
    /// Harmonic 1's amplitude.
    pub r: f64,
    /// Harmonic 1's phase against the drive (rad).
    pub phase: f64,
    /// The mean deflection (m), if measured.
    pub mean: Option<f64>,
}

/// The regime at `p` against the free point `free` (the same leg's far end): free while
/// the amplitude is within `drop` of the free one and the phase within `twist` rad of it;
/// otherwise the sign of the mean deflection (k times it is the mean force) if it is
/// measured and farther from the free one than `mean_floor` (m), else the sign of the phase
/// shift: a net attractive force makes the tip lag the drive more than free, a net repulsive
/// one less (García & San Paulo, Phys. Rev. B 60, 4961, 1999: the phase lag above or below
/// 90° at resonance), so the phase against the drive falls or rises.
pub fn regime(
    p: ApproachPoint,
    free: ApproachPoint,
    drop: f64,
    twist: f64,
    mean_floor: f64,
) -> Regime {
    let shift = wrap_phase(p.phase - free.phase);
    if p.r >= (1.0 - drop) * free.r && shift.abs() <= twist {
        return Regime::Free;
    }
    if let (Some(m), Some(m0)) = (p.mean, free.mean)
        && (m - m0).abs() > mean_floor
    {
        return if m > m0 {
            Regime::Repulsive
        } else {
            Regime::Attractive
        };
    }
    if shift < 0.0 {
        Regime::Attractive
    } else {
        Regime::Repulsive
    }
}

/// `x` wrapped into (−π, π].
pub fn wrap_phase(x: f64) -> f64 {
    let p = (x + PI).rem_euclid(2.0 * PI) - PI;
    if p == -PI { PI } else { p }
}

/// The phase (rad, in (−π, π]) of harmonic 1 against the excitation, as an instrument's
/// tune shows it: the demodulators measure against cos θ while the base moves as sin θ, so
/// it is the demodulator's phase + π/2 (−π/2 at resonance, 0 well below it).
pub fn phase_to_drive(phase: f64) -> f64 {
    let p = (phase + std::f64::consts::FRAC_PI_2).rem_euclid(std::f64::consts::TAU);
    if p > std::f64::consts::PI {
        p - std::f64::consts::TAU
    } else {
        p
    }
}

/// The free lever's point at `settings`' drive (`crate::synth::plan::free_reading`), the
/// reference of every regime: the phase is so sensitive to a force gradient (Q·k_ts/k) that
/// the far end of a few-nanometre approach with adhesion is already attractive.
pub fn free_point(settings: &crate::config::Settings) -> Option<ApproachPoint> {
    let free = crate::synth::plan::free_reading(settings)?;
    Some(ApproachPoint {
        r: free.norm(),
        phase: phase_to_drive(free.arg()),
        mean: Some(0.0),
    })
}

/// Hysteresis between the legs: the largest difference of the amplitudes measured at the
/// same value on the way up and on the way down, relative to the larger, and where.
pub fn hysteresis(up: &[(f64, f64)], down: &[(f64, f64)]) -> Option<(f64, f64)> {
    up.iter()
        .filter_map(|(v, ru)| {
            let (_, rd) = down.iter().find(|(w, _)| w == v)?;
            let scale = ru.abs().max(rd.abs());
            (scale > 0.0).then(|| ((ru - rd).abs() / scale, *v))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_regime_reads_the_mean_deflection_before_the_phase() {
        let free = ApproachPoint {
            r: 10e-9,
            phase: -1.5,
            mean: Some(0.0),
        };
        let at = |r: f64, phase: f64, mean: Option<f64>| {
            regime(ApproachPoint { r, phase, mean }, free, 0.02, 0.02, 1e-12)
        };
        assert_eq!(at(9.9e-9, -1.51, Some(0.0)), Regime::Free);
        // Lagging more: attractive; less: repulsive.
        assert_eq!(at(8e-9, -1.9, None), Regime::Attractive);
        assert_eq!(at(8e-9, -1.1, None), Regime::Repulsive);
        // The mean deflection decides where it is measured.
        assert_eq!(at(8e-9, -1.9, Some(5e-12)), Regime::Repulsive);
        assert_eq!(at(8e-9, -1.1, Some(-5e-12)), Regime::Attractive);
        // Below its floor the phase does.
        assert_eq!(at(8e-9, -1.9, Some(1e-13)), Regime::Attractive);
        // Across ±π.
        let wrapped = ApproachPoint {
            r: 8e-9,
            phase: 3.1,
            mean: None,
        };
        let free_wrapped = ApproachPoint {
            phase: -3.1,
            ..free
        };
        assert_eq!(
            regime(wrapped, free_wrapped, 0.02, 0.02, 1e-12),
            Regime::Attractive
        );
    }

    #[test]
    fn points_cover_both_ends_on_each_leg() {
        let p = points(1.0, 3.0, 3, false, true, true);
        let values: Vec<f64> = p.iter().map(|p| p.value).collect();
        assert_eq!(values, [1.0, 2.0, 3.0, 3.0, 2.0, 1.0]);
        assert_eq!(p[2].leg, Leg::Up);
        assert_eq!(p[3].leg, Leg::Down);
        let log = points(1e9, 1e11, 3, true, true, false);
        assert_eq!((log[0].value, log[2].value), (1e9, 1e11));
        let log = points(1.0, 100.0, 3, true, true, false);
        assert!((log[1].value - 10.0).abs() < 1e-12);
        assert_eq!(log[2].value, 100.0);
        let down = points(5.0, 1.0, 2, false, false, true);
        assert_eq!(down.iter().map(|p| p.value).collect::<Vec<_>>(), [1.0, 5.0]);
    }

    #[test]
    fn settling_times_match_their_closed_forms() {
        // First order: e^{−x} = ε.
        let t = filter_settling(1, 2e-3, 1e-3);
        assert!((t / 2e-3 - (1e3f64).ln()).abs() < 1e-9);
        // Second order: e^{−x}(1 + x) = ε at x = 9.233…
        let x = filter_settling(2, 1.0, 1e-3);
        assert!(((-x).exp() * (1.0 + x) - 1e-3).abs() < 1e-12);
        assert!(filter_settling(4, 1.0, 1e-3) > x);
        assert!((ring_down(1e5, 100.0, (-1.0f64).exp()) - 100.0 / (PI * 1e5)).abs() < 1e-15);
    }

    #[test]
    fn a_tune_fit_recovers_its_resonance() {
        let (f0, q, a) = (101_234.0, 87.0, 3e-10);
        let f: Vec<f64> = (0..121).map(|i| 99e3 + i as f64 * 40.0).collect();
        let r: Vec<f64> = f
            .iter()
            .map(|f| a * f * f / ((f0 * f0 - f * f).powi(2) + (f0 * f / q).powi(2)).sqrt())
            .collect();
        let fit = fit_tune(&f, &r).unwrap();
        assert!((fit.f0 / f0 - 1.0).abs() < 1e-9, "{fit:?}");
        assert!((fit.q / q - 1.0).abs() < 1e-7, "{fit:?}");
        assert!((fit.amplitude / a - 1.0).abs() < 1e-7, "{fit:?}");
        // Noise of 1 % on each point moves them little.
        let noisy: Vec<f64> = r
            .iter()
            .enumerate()
            .map(|(i, r)| r * (1.0 + 0.01 * ((i as f64 * 1.7).sin())))
            .collect();
        let fit = fit_tune(&f, &noisy).unwrap();
        assert!(
            (fit.f0 / f0 - 1.0).abs() < 2e-4 && (fit.q / q - 1.0).abs() < 0.03,
            "{fit:?}"
        );
        assert!(fit_tune(&f[..2], &r[..2]).is_none());
    }

    #[test]
    fn approach_curves_show_contact_jumps_and_hysteresis() {
        let values = [30.0, 28.0, 26.0, 24.0, 22.0, 20.0];
        let r = [10.0, 10.0, 10.0, 9.5, 6.0, 5.8];
        assert_eq!(contact_onset(&values, &r, 2, 0.02), Some(24.0));
        let j = jumps(&values, &r, 0.2);
        assert_eq!(j.len(), 1);
        assert_eq!((j[0].from, j[0].to), (24.0, 22.0));
        let up = [(1.0, 10.0), (2.0, 8.0)];
        let down = [(2.0, 8.0), (1.0, 5.0)];
        assert_eq!(hysteresis(&up, &down), Some((0.5, 1.0)));
    }
}
