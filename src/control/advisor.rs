//! A PID advisor, as LabOne's: gains for a target closed-loop bandwidth, from the loop's own
//! transfer function ([`LoopModel`]).
//!
//! Method. The gains are parametrised by the crossover ω_c they are to give: the PI zero
//! sits at a quarter of it (I = P·ω_c/4, 14° of lag at ω_c: enough integral action to track
//! within a few time constants, little phase) — on the driven lever's PLL
//! ([`Plant::Resonator`]) at the lever's pole 1/τ_c where that is higher, cancelling it (the
//! loop then an integrator, as a PLL on an external signal is) — with `Kind::Pid` a
//! derivative too
//! (D = P/(4ω_c), its low-pass at 4ω_c below the PID's Nyquist frequency), and P makes
//! |L(iω_c)| = 1. The phase margin then falls monotonically with ω_c (every part's lag
//! grows with frequency); the highest ω_c with 45° of margin bounds what is reachable. Below
//! it, the closed loop's −3 dB bandwidth grows monotonically with ω_c, and bisection on
//! ω_c finds the target. The advice carries the predicted bandwidth, margin, overshoot and
//! 2 % settling time ([`model_step`]).

use super::loop_model::{Gains, LoopModel, ModelError, Plant};
use super::step::{StepMetrics, model_step};
use std::f64::consts::{PI, TAU};

/// The least phase margin the advice keeps (degrees).
pub const MIN_PHASE_MARGIN: f64 = 45.0;

/// How close to the target the advice's bandwidth is (relative).
pub const BANDWIDTH_TOLERANCE: f64 = 0.01;

/// The PI zero's place: I/P = ω_c / this.
const INTEGRAL_RATIO: f64 = 4.0;

/// The derivative: D/P = this / ω_c.
const DERIVATIVE_RATIO: f64 = 0.25;

/// Which terms the advice sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// P and I; D = 0.
    Pi,
    /// P, I and D (with its low-pass).
    Pid,
}

/// Gains for a target bandwidth and what the linear model predicts of them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Advice {
    /// The gains, for negative feedback in the model's sign convention: the PLL's
    /// measurement is the reference's phase minus the input's, the amplitude loop's plant
    /// gain positive, the driven lever's phase taken to rise with the drive frequency. A
    /// loop whose actuator acts the other way takes them all negated: the live PLL
    /// (`/pids/N` on `drive_frequency`), whose lever's phase falls as the frequency rises.
    pub gains: Gains,
    /// The closed loop's −3 dB bandwidth (Hz).
    pub bandwidth: f64,
    /// The crossover frequency, where |L| = 1 (Hz).
    pub crossover: f64,
    /// The phase margin (degrees).
    pub phase_margin: f64,
    /// The step response's overshoot and 2 % settling time ([`super::step`]).
    pub step: StepMetrics,
}

/// Why there is no advice.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AdvisorError {
    /// An input out of range, named.
    #[error(transparent)]
    Input(#[from] ModelError),
    /// The kind of controller asked for does not fit the plant.
    #[error("{0}")]
    Form(&'static str),
    /// The target needs less phase margin than [`MIN_PHASE_MARGIN`].
    #[error(
        "target bandwidth {target} Hz is out of reach: {limit} limits the bandwidth to {best:.4} Hz at {MIN_PHASE_MARGIN}° phase margin ({lags})"
    )]
    Unreachable {
        /// The bandwidth asked for (Hz).
        target: f64,
        /// The highest bandwidth with [`MIN_PHASE_MARGIN`] (Hz).
        best: f64,
        /// The part of the loop whose lag at that crossover is the largest, in words.
        limit: String,
        /// Every part's phase lag at that crossover, in words.
        lags: String,
    },
    /// The closed loop's −3 dB bandwidth jumps across the target as the gains grow (|T|
    /// runs close to −3 dB over a range of frequencies): no gains of the advisor's shape
    /// give it.
    #[error(
        "target bandwidth {target} Hz is not reached within 1 %: the bandwidth jumps past it, to {reached:.4} Hz; try another target or kind"
    )]
    Missed {
        /// The bandwidth asked for (Hz).
        target: f64,
        /// The bandwidth of the closest gains (Hz).
        reached: f64,
    },
}

/// The gains whose crossover is `omega` (rad/s).
fn gains_at(model: &LoopModel, kind: Kind, omega: f64) -> Gains {
    let f_out = model.demodulator.output_rate();
    let (d_ratio, d_bandwidth) = match kind {
        Kind::Pi => (0.0, 0.25 * f_out),
        // Four times the crossover, but under the discrete PID's Nyquist frequency.
        Kind::Pid => (DERIVATIVE_RATIO, (4.0 * omega / TAU).min(0.4 * f_out)),
    };
    // The PI zero (rad/s): a quarter of the crossover, or the driven lever's pole where
    // that is higher (cancelled: the loop an integrator around the crossover).
    let zero = match model.plant {
        Plant::Resonator { time_constant, .. } => (omega / INTEGRAL_RATIO).max(1.0 / time_constant),
        _ => omega / INTEGRAL_RATIO,
    };
    let shape = if model.plant.time_constant() == Some(0.0) {
        // A plant without a pole has no roll-off of its own: the integrator alone crosses
        // over, as a proportional part would hold |L| near 1 up to the delay's lag.
        Gains {
            p: 0.0,
            i: 1.0,
            d: 0.0,
            d_bandwidth,
        }
    } else {
        Gains {
            p: 1.0,
            i: zero,
            d: d_ratio / omega,
            d_bandwidth,
        }
    };
    let scale = 1.0 / model.open_loop(&shape, omega).norm();
    Gains {
        p: scale * shape.p,
        i: scale * shape.i,
        d: scale * shape.d,
        d_bandwidth,
    }
}

/// 180° + arg L at ω (degrees) for the gains crossing over there.
fn margin_at(model: &LoopModel, kind: Kind, omega: f64) -> f64 {
    180.0
        + model
            .open_loop_phase(&gains_at(model, kind, omega), omega)
            .to_degrees()
}

fn bandwidth_at(model: &LoopModel, kind: Kind, omega: f64) -> f64 {
    model
        .bandwidth(&gains_at(model, kind, omega))
        .unwrap_or(f64::INFINITY)
}

/// Bisection in log ω on a predicate true at `lo`, false at `hi`: the boundary (rad/s).
fn bisect(mut lo: f64, mut hi: f64, holds: impl Fn(f64) -> bool) -> f64 {
    while hi - lo > 1e-12 * hi {
        let mid = (lo * hi).sqrt();
        if holds(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The highest crossover (rad/s) with [`MIN_PHASE_MARGIN`]; `None` if none has it.
fn highest_crossover(model: &LoopModel, kind: Kind) -> Option<f64> {
    let top = PI * model.demodulator.output_rate() * 10.0;
    let ratio = 10f64.powf(1.0 / 40.0);
    let ok = |w: f64| margin_at(model, kind, w) >= MIN_PHASE_MARGIN;
    let mut w = top * 1e-12;
    if !ok(w) {
        return None;
    }
    while w < top {
        let next = w * ratio;
        if !ok(next) {
            return Some(bisect(w, next, ok));
        }
        w = next;
    }
    Some(top)
}

/// Formats a time (s) with the SI prefix that fits it.
fn time(t: f64) -> String {
    let (scale, unit) = if t >= 1.0 {
        (1.0, "s")
    } else if t >= 1e-3 {
        (1e3, "ms")
    } else if t >= 1e-6 {
        (1e6, "µs")
    } else {
        (1e9, "ns")
    };
    format!("{} {unit}", significant(t * scale))
}

fn significant(x: f64) -> String {
    let text = format!("{x:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Names the part of the loop whose lag at ω (rad/s) is the largest, of those that lag
/// more the faster the loop (the filter, the hold, the dead time, the lever's envelope), and
/// lists every part's lag there.
fn limit_at(model: &LoopModel, kind: Kind, omega: f64) -> (String, String) {
    let d = &model.demodulator;
    let filter = d.order() as f64 * (omega * d.time_constant()).atan();
    let hold = omega * 0.5 / d.output_rate();
    let dead = omega * (d.dead_time() - d.filter_lead());
    let mut parts = Vec::with_capacity(4);
    if d.order() > 0 {
        parts.push((
            filter,
            "filter",
            format!(
                "the demodulator's filter (order {}, τ {})",
                d.order(),
                time(d.time_constant())
            ),
        ));
    }
    parts.extend([
        (
            hold,
            "hold",
            format!(
                "the demodulator's output rate ({} Hz: a hold of half a period, {})",
                significant(d.output_rate()),
                time(0.5 / d.output_rate())
            ),
        ),
        (
            dead,
            "dead time",
            format!("the dead time ({})", time(d.dead_time())),
        ),
    ]);
    let plant = match model.plant {
        Plant::Pll => PI / 2.0,
        Plant::Amplitude { time_constant, .. } => {
            let lag = (omega * time_constant).atan();
            parts.push((
                lag,
                "envelope",
                format!("the lever's envelope (τ_c {})", time(time_constant)),
            ));
            lag
        }
        // Listed, not named as the limit: its lag is bounded by 90°, which the PI's zero
        // takes back below 4/τ_c, as the PLL's integrator's is fixed.
        Plant::Resonator { time_constant, .. } => (omega * time_constant).atan(),
    };
    let controller = -gains_at(model, kind, omega).response(omega).arg();
    let mut lags: Vec<String> = parts
        .iter()
        .map(|(lag, short, _)| format!("{short} {:.1}°", lag.to_degrees()))
        .collect();
    match model.plant {
        Plant::Pll => lags.push(format!("integrator {:.0}°", plant.to_degrees())),
        Plant::Resonator { .. } => lags.push(format!("lever {:.1}°", plant.to_degrees())),
        Plant::Amplitude { .. } => {}
    }
    lags.push(format!("controller {:.1}°", controller.to_degrees()));
    let lags = format!(
        "lags at the {} Hz crossover: {}",
        significant(omega / TAU),
        lags.join(", ")
    );
    let (_, _, name) = parts
        .into_iter()
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .expect("parts");
    (name, lags)
}

/// Gains giving the closed loop `model` a −3 dB bandwidth of `target_bandwidth` (Hz) with
/// at least [`MIN_PHASE_MARGIN`], or why not.
pub fn advise(
    model: &LoopModel,
    target_bandwidth: f64,
    kind: Kind,
) -> Result<Advice, AdvisorError> {
    if !(target_bandwidth.is_finite() && target_bandwidth > 0.0) {
        return Err(ModelError {
            parameter: "target_bandwidth",
            value: target_bandwidth,
            allowed: "a finite bandwidth > 0 Hz",
        }
        .into());
    }
    if kind == Kind::Pid && model.plant.time_constant() == Some(0.0) {
        return Err(AdvisorError::Form(
            "kind \"pid\" does not fit a plant that answers at once (no pole for a \
             derivative to lead): its loop is an integrator alone, which kind \"pi\" gives",
        ));
    }
    let unreachable = |best: f64, omega: f64| {
        let (limit, lags) = limit_at(model, kind, omega);
        AdvisorError::Unreachable {
            target: target_bandwidth,
            best,
            limit,
            lags,
        }
    };
    let w_max = highest_crossover(model, kind).ok_or_else(|| unreachable(0.0, 0.0))?;
    let best = bandwidth_at(model, kind, w_max);
    if target_bandwidth > best {
        return Err(unreachable(best, w_max));
    }
    // A crossover low enough that the bandwidth is below the target (it is of the order of
    // the crossover for any usable margin).
    let mut w_lo = (TAU * target_bandwidth / 10.0).min(w_max);
    while bandwidth_at(model, kind, w_lo) > target_bandwidth {
        w_lo /= 10.0;
    }
    let omega = bisect(w_lo, w_max, |w| {
        bandwidth_at(model, kind, w) <= target_bandwidth
    });
    let gains = gains_at(model, kind, omega);
    let bandwidth = model.bandwidth(&gains).unwrap_or(f64::INFINITY);
    // The bandwidth jumps where |T| grazes −3 dB (a plateau near the crossover); the
    // bisection then stops at the jump, short of the target.
    if (bandwidth / target_bandwidth - 1.0).abs() > BANDWIDTH_TOLERANCE {
        return Err(AdvisorError::Missed {
            target: target_bandwidth,
            reached: bandwidth,
        });
    }
    let crossover = model.crossover(&gains).unwrap_or(omega);
    let step = model_step(model, &gains, crossover, step_duration(crossover)).metrics();
    Ok(Advice {
        gains,
        bandwidth,
        crossover: crossover / TAU,
        phase_margin: model.phase_margin(&gains).unwrap_or(f64::NAN),
        step,
    })
}

/// How long a step response is followed (s) for a crossover ω_c (rad/s): long against the
/// slowest closed-loop mode, the PI zero's at about ω_c/4.
pub fn step_duration(omega_c: f64) -> f64 {
    100.0 / omega_c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::loop_model::Demodulator;
    use crate::control::step::discrete_step;

    /// The instrument's input rate (Hz) and the rate its demodulator filters run at, f_s/16.
    const SAMPLE_RATE: f64 = 10e6;
    const FILTER_RATE: f64 = SAMPLE_RATE / 16.0;

    fn pll(order: u32, tau: f64, f_out: f64) -> LoopModel {
        LoopModel {
            plant: Plant::Pll,
            demodulator: Demodulator::instrument(order, tau, f_out, SAMPLE_RATE).unwrap(),
        }
    }

    /// PLL settings (order, τ, output rate) across the range, each with targets.
    fn pll_cases() -> Vec<(u32, f64, f64, Vec<f64>)> {
        vec![
            (1, 10e-6, 125e3, vec![100.0, 1e3, 5e3]),
            (4, 10e-6, 125e3, vec![50.0, 1e3, 3e3]),
            (8, 10e-6, 125e3, vec![300.0, 2e3]),
            (1, 100e-6, 25e3, vec![20.0, 300.0]),
            (4, 100e-6, 25e3, vec![10.0, 200.0]),
            (8, 100e-6, 25e3, vec![10.0, 100.0]),
            (1, 1e-3, 5e3, vec![1.0, 40.0]),
            (4, 1e-3, 5e3, vec![2.0, 20.0]),
            (8, 1e-3, 5e3, vec![1.0, 10.0]),
        ]
    }

    #[test]
    fn the_advice_hits_the_target_bandwidth_with_its_margin() {
        for (order, tau, f_out, targets) in pll_cases() {
            let model = pll(order, tau, f_out);
            for target in targets {
                for kind in [Kind::Pi, Kind::Pid] {
                    let a = advise(&model, target, kind)
                        .unwrap_or_else(|e| panic!("order {order} τ {tau} {target} Hz: {e}"));
                    eprintln!(
                        "PLL order {order} τ {tau:e} s f_out {f_out:e} Hz, {kind:?} target {target} Hz: \
                         bandwidth {:.4} Hz, crossover {:.4} Hz, margin {:.1}°, overshoot {:.1} %, \
                         settling {:.4e} s; P {:.4e} I {:.4e} D {:.3e}",
                        a.bandwidth,
                        a.crossover,
                        a.phase_margin,
                        100.0 * a.step.overshoot,
                        a.step.settling_time,
                        a.gains.p,
                        a.gains.i,
                        a.gains.d
                    );
                    assert!((a.bandwidth / target - 1.0).abs() < 0.01, "{target}: {a:?}");
                    assert!(a.phase_margin >= MIN_PHASE_MARGIN - 1e-6, "{a:?}");
                }
            }
        }
    }

    /// The default lever (f1 = 100 kHz, Q = 100) driven at f1 through a live PID unit's
    /// demodulator at 10 MS/s with the ADC filter.
    fn lever_pll() -> LoopModel {
        LoopModel {
            plant: Plant::resonator(100.0, 1e5).unwrap(),
            demodulator: Demodulator::pid_unit(1e5, SAMPLE_RATE, 21.5).unwrap(),
        }
    }

    #[test]
    fn the_levers_pll_at_500_hz_is_near_the_hand_formula() {
        // By hand: the PI's zero on the lever's pole, P = I·τ_c, and an integrator loop of
        // crossover B: I = 2π·B·f1/(2Q) = 1.571e6 Hz/(rad·s), P = 500 Hz/rad (the PLL takes
        // them negated).
        let model = lever_pll();
        let (hand_i, hand_p) = (TAU * 500.0 * 1e5 / 200.0, 500.0);
        for kind in [Kind::Pi, Kind::Pid] {
            let a = advise(&model, 500.0, kind).unwrap();
            eprintln!(
                "lever PLL 500 Hz {kind:?}: P {:.2} Hz/rad ({:+.1} %), I {:.4e} Hz/(rad·s)                  ({:+.1} %), D {:.3e}, bandwidth {:.2} Hz, crossover {:.2} Hz, margin {:.1}°,                  overshoot {:.2} %, settling {:.1} µs",
                a.gains.p,
                100.0 * (a.gains.p / hand_p - 1.0),
                a.gains.i,
                100.0 * (a.gains.i / hand_i - 1.0),
                a.gains.d,
                a.bandwidth,
                a.crossover,
                a.phase_margin,
                100.0 * a.step.overshoot,
                1e6 * a.step.settling_time
            );
            assert!((a.bandwidth / 500.0 - 1.0).abs() < 0.01, "{a:?}");
            assert!((a.gains.p / hand_p - 1.0).abs() < 0.2, "{a:?}");
            assert!((a.gains.i / hand_i - 1.0).abs() < 0.2, "{a:?}");
        }
        // The reach: the hold and the dead time (a period and 21.5 samples) limit it.
        let Err(e) = advise(&model, 1e6, Kind::Pi) else {
            panic!("reachable")
        };
        eprintln!("{e}");
        let AdvisorError::Unreachable { best, .. } = e else {
            panic!("{e}")
        };
        assert!(best > 5e3 && best < 25e3, "{e}");
        assert!(e.to_string().contains("dead time"), "{e}");
        assert!(!e.to_string().contains("filter"), "{e}");
    }

    #[test]
    fn the_levers_pll_advice_agrees_with_its_discrete_loop() {
        let model = lever_pll();
        let mut worst = (0.0f64, 0.0f64);
        for target in [50.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0, 10e3, 15e3] {
            for kind in [Kind::Pi, Kind::Pid] {
                let a = advise(&model, target, kind).unwrap();
                // The units' demodulator reads every sample: the dead time at f_s.
                let sim = discrete_step(
                    &model,
                    &a.gains,
                    SAMPLE_RATE,
                    step_duration(TAU * a.crossover),
                )
                .unwrap()
                .metrics();
                eprintln!(
                    "lever PLL {kind:?} {target} Hz: overshoot model {:.2} % discrete {:.2} %,                      settling model {:.1} µs discrete {:.1} µs, margin {:.1}°",
                    100.0 * a.step.overshoot,
                    100.0 * sim.overshoot,
                    1e6 * a.step.settling_time,
                    1e6 * sim.settling_time,
                    a.phase_margin
                );
                // Within 10 % of the predicted overshoot, or 1 % of the step below 10 %.
                let overshoot = (sim.overshoot - a.step.overshoot).abs();
                assert!(
                    overshoot <= 0.1 * a.step.overshoot.max(0.1),
                    "{target} {kind:?}"
                );
                // The discrete loop's settling is known to an update period (10 µs): within
                // 10 % or two of them.
                let settling = (sim.settling_time - a.step.settling_time).abs();
                assert!(
                    settling <= (0.1 * a.step.settling_time).max(2e-5),
                    "{target} {kind:?}"
                );
                worst = (
                    worst.0.max(overshoot),
                    worst.1.max(settling / a.step.settling_time),
                );
            }
        }
        eprintln!(
            "lever PLL, worst: overshoot {:.2} % of the step, settling {:.1} %",
            100.0 * worst.0,
            100.0 * worst.1
        );
    }

    #[test]
    fn an_unreachable_target_is_refused_naming_the_limit() {
        // A slow filter: order 4, τ = 0.5 ms.
        let model = pll(4, 0.5e-3, 25e3);
        let e = advise(&model, 1e3, Kind::Pi).unwrap_err();
        eprintln!("{e}");
        let AdvisorError::Unreachable {
            best, ref limit, ..
        } = e
        else {
            panic!("{e}")
        };
        assert!(limit.contains("filter (order 4, τ 500 µs)"), "{e}");
        assert!(best > 10.0 && best < 1e3, "{e}");
        // The best reachable is reachable, with its margin.
        let a = advise(&model, best * 0.999, Kind::Pi).unwrap();
        assert!((a.phase_margin - MIN_PHASE_MARGIN).abs() < 1.0, "{a:?}");
        // A slow output rate and a fast filter: the hold limits.
        let model = pll(1, 10e-6, 1e3);
        let e = advise(&model, 500.0, Kind::Pi).unwrap_err();
        assert!(e.to_string().contains("output rate (1000 Hz"), "{e}");
    }

    /// The highest bandwidth with 45° of margin for every demodulator setting of the
    /// tests, PI and PID: the derivative's lead reaches further.
    #[test]
    fn the_reach_grows_with_the_derivative_and_falls_with_the_filter() {
        for (order, tau, f_out, _) in pll_cases() {
            let model = pll(order, tau, f_out);
            let best = |kind| match advise(&model, 1e9, kind) {
                Err(AdvisorError::Unreachable { best, limit, .. }) => (best, limit),
                other => panic!("{other:?}"),
            };
            let (pi, limit) = best(Kind::Pi);
            let (pid, _) = best(Kind::Pid);
            eprintln!(
                "PLL order {order} τ {tau:e} s f_out {f_out:e} Hz: reach PI {pi:.1} Hz, PID {pid:.1} Hz; limit: {limit}"
            );
            assert!(pi > 0.0 && pid > pi, "{pi} {pid}");
            // The hold's half period alone costs 45° at f_out/4.
            assert!(pi < f_out / 10.0, "{pi}");
        }
    }

    #[test]
    fn bad_targets_are_refused_naming_them() {
        let model = pll(4, 1e-4, 25e3);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = advise(&model, bad, Kind::Pi).unwrap_err();
            let text = e.to_string();
            assert!(
                text.contains("target_bandwidth") && text.contains("> 0 Hz"),
                "{text}"
            );
        }
    }

    /// The advice's overshoot and settling (the continuous model) against the discrete PID
    /// driving the discretised plant through the demodulator's discrete filter and delay.
    #[test]
    fn the_predicted_step_agrees_with_the_discrete_loop() {
        let mut cases: Vec<(LoopModel, f64, Kind)> = Vec::new();
        for (order, tau, f_out, targets) in pll_cases() {
            for target in targets {
                for kind in [Kind::Pi, Kind::Pid] {
                    cases.push((pll(order, tau, f_out), target, kind));
                }
            }
        }
        // At the edge of the reach, where the margin is 45° and the delays matter most.
        for (order, tau, f_out) in [(1, 10e-6, 125e3), (8, 10e-6, 125e3), (4, 1e-3, 5e3)] {
            let model = pll(order, tau, f_out);
            for kind in [Kind::Pi, Kind::Pid] {
                let Err(AdvisorError::Unreachable { best, .. }) = advise(&model, 1e9, kind) else {
                    panic!("reachable")
                };
                cases.push((model, 0.98 * best, kind));
            }
        }
        // A lever whose envelope is faster than the loop (no overshoot), and one (Q = 10⁴,
        // τ_c = 10.6 ms) slower, which acts as an integrator at the crossover.
        for (q, order, tau, target) in [
            (400.0, 4, 1e-4, 100.0),
            (400.0, 2, 1e-5, 1e3),
            (1e4, 4, 1e-4, 100.0),
            (1e4, 2, 1e-5, 1e3),
            (1e4, 8, 1e-5, 1e3),
        ] {
            let model = LoopModel {
                plant: Plant::amplitude(1.0, q, 300e3).unwrap(),
                demodulator: Demodulator::instrument(order, tau, 25e3, SAMPLE_RATE).unwrap(),
            };
            cases.push((model, target, Kind::Pi));
            cases.push((model, target, Kind::Pid));
        }
        let mut worst = (0.0f64, 0.0f64);
        for (model, target, kind) in cases {
            let a = advise(&model, target, kind).unwrap();
            assert!((a.bandwidth / target - 1.0).abs() < 0.01, "{a:?}");
            let duration = step_duration(TAU * a.crossover);
            let sim = discrete_step(&model, &a.gains, FILTER_RATE, duration)
                .unwrap()
                .metrics();
            // Relative to the predicted overshoot; where it is below 1 % (none to speak of),
            // relative to 1 % of the step.
            let overshoot_error =
                (sim.overshoot - a.step.overshoot).abs() / a.step.overshoot.max(0.01);
            let settling_error = (sim.settling_time / a.step.settling_time - 1.0).abs();
            worst = (worst.0.max(overshoot_error), worst.1.max(settling_error));
            eprintln!(
                "{:?} {kind:?} order {} τ {:e} s f_out {:e} Hz target {target} Hz: overshoot model {:.2} % discrete {:.2} % ({:+.1} %), \
                 settling model {:.4e} s discrete {:.4e} s ({:+.1} %)",
                model.plant,
                model.demodulator.order(),
                model.demodulator.time_constant(),
                model.demodulator.output_rate(),
                100.0 * a.step.overshoot,
                100.0 * sim.overshoot,
                100.0 * (sim.overshoot - a.step.overshoot) / a.step.overshoot.max(0.01),
                a.step.settling_time,
                sim.settling_time,
                100.0 * (sim.settling_time / a.step.settling_time - 1.0),
            );
        }
        eprintln!(
            "worst: overshoot {:.1} %, settling {:.1} %",
            100.0 * worst.0,
            100.0 * worst.1
        );
        assert!(worst.0 < 0.1 && worst.1 < 0.1, "{worst:?}");
    }
}
