//! Step responses of a closed loop, two ways:
//!
//! - [`model_step`]: the continuous linear model of [`LoopModel`] (the output sampling a
//!   pure delay of half a period, the PID continuous), integrated at a fine step. This is
//!   the advisor's prediction.
//! - [`discrete_step`]: what the instrument will run: the discrete [`Pid`] at the
//!   demodulator's output rate, holding its output between updates, the demodulator's
//!   filter as `dsp::lowpass` runs it at its own rate, the dead time as a sample buffer,
//!   the plant exact for a held input.
//!
//! The step, for both: the PLL tracks a 1 Hz step of the input's frequency (the output is
//! the PID's frequency command, which T = L/(1 + L) takes to 1 Hz); the PLL on a driven
//! lever ([`Plant::Resonator`]) a 1 Hz step of the lever's resonance (the output is the
//! drive frequency, likewise); the amplitude loop's
//! set-point steps by 1 (the output is the demodulated amplitude). The derivative acts on
//! the measurement in both, as in [`Pid`], so for the amplitude loop with D ≠ 0 the
//! set-point response is not T alone.

use super::loop_model::{Gains, LoopModel, ModelError, Plant, positive};
use super::pid::{Pid, PidError, PidSettings};
use std::f64::consts::TAU;

/// Why a discrete loop cannot be simulated.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    /// The filter rate or the duration, named.
    #[error(transparent)]
    Input(#[from] ModelError),
    /// The gains make no valid [`Pid`].
    #[error(transparent)]
    Pid(#[from] PidError),
}

/// Overshoot and settling of a unit step response.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepMetrics {
    /// Peak above the final value, as a fraction of the step (1; 0 if it never overshoots).
    pub overshoot: f64,
    /// Time after which the output stays within 2 % of the step of its final value (s).
    pub settling_time: f64,
}

/// A unit step response sampled every `dt` from t = `dt`.
#[derive(Clone, Debug, PartialEq)]
pub struct StepTrace {
    /// Sample interval (s).
    pub dt: f64,
    /// The output at t = dt, 2·dt, ...
    pub values: Vec<f64>,
}

impl StepTrace {
    /// Overshoot and 2 % settling time against the final value 1 (the loops integrate, so
    /// the step is tracked exactly). Settling is the time of the first sample after the
    /// last one outside the band.
    pub fn metrics(&self) -> StepMetrics {
        let peak = self.values.iter().copied().fold(f64::MIN, f64::max);
        let last_out = self.values.iter().rposition(|y| (y - 1.0).abs() > 0.02);
        StepMetrics {
            overshoot: (peak - 1.0).max(0.0),
            settling_time: last_out.map_or(0.0, |n| (n + 2) as f64 * self.dt),
        }
    }
}

/// A first-order section 1/(1 + sτ), discretised ramp-invariantly (exact for an input
/// linear between samples): second-order accurate, unlike the step-invariant form's half
/// sample of bias, and well-behaved even where the step exceeds τ.
#[derive(Clone, Copy, Debug)]
struct RampSection {
    a: f64,
    b0: f64,
    b1: f64,
    x: f64,
    y: f64,
}

impl RampSection {
    fn new(tau: f64, h: f64) -> Self {
        let a = (-h / tau).exp();
        let c = tau * -(-h / tau).exp_m1() / h; // τ(1 − a)/h
        Self {
            a,
            b0: 1.0 - c,
            b1: c - a,
            x: 0.0,
            y: 0.0,
        }
    }

    fn step(&mut self, x: f64) -> f64 {
        self.y = self.a * self.y + self.b0 * x + self.b1 * self.x;
        self.x = x;
        self.y
    }
}

/// A delay line at step h: reads x(t_n − delay) by linear interpolation.
struct Delay {
    history: Vec<f64>,
    whole: usize,
    frac: f64,
}

impl Delay {
    fn new(delay: f64, h: f64) -> Self {
        let samples = delay / h;
        let whole = samples.floor() as usize;
        Self {
            history: vec![0.0; whole + 2],
            whole,
            frac: samples - whole as f64,
        }
    }

    /// Pushes x(t_n) (the newest) and returns x(t_n − delay); history before the start is 0.
    fn push_and_read(&mut self, x: f64) -> f64 {
        self.history.rotate_right(1);
        self.history[0] = x;
        (1.0 - self.frac) * self.history[self.whole] + self.frac * self.history[self.whole + 1]
    }

    /// x(t_n − delay) when delay ≥ h, before x(t_n) is known: reads one sample back.
    fn read_ahead(&self) -> f64 {
        // With x(t_n) not yet pushed, index k of the history is x(t_{n−1−k}).
        let k = self.whole - 1;
        (1.0 - self.frac) * self.history[k] + self.frac * self.history[k + 1]
    }

    fn push(&mut self, x: f64) {
        self.history.rotate_right(1);
        self.history[0] = x;
    }
}

/// Most fine steps a model simulation takes: the step grows to stay within it.
const MAX_STEPS: f64 = 4e6;

/// The continuous model's unit step response over `duration` (s), integrated at a step
/// fine against the crossover `omega_c` (rad/s), the filter and the delay.
pub fn model_step(model: &LoopModel, gains: &Gains, omega_c: f64, duration: f64) -> StepTrace {
    let d = &model.demodulator;
    let delay = d.total_delay();
    let mut h = (TAU / (400.0 * omega_c)).min(delay);
    h = h.max(duration / MAX_STEPS);
    // The delay must read only the past (no algebraic loop): at least one step. Where the
    // step is longer than the delay, the delay's lag at ω_c is below 2π/400 rad anyway.
    let mut delay_line = Delay::new(delay.max(h), h);
    let mut filter = vec![RampSection::new(d.time_constant(), h); d.order() as usize];
    let (setpoint, mut integral, mut e_prev) = match model.plant {
        Plant::Pll | Plant::Resonator { .. } => (0.0, 0.0, 0.0),
        Plant::Amplitude { .. } => (1.0, 0.0, 1.0),
    };
    let derivative_a = (-TAU * gains.d_bandwidth * h).exp();
    let (mut derivative, mut m_prev) = (0.0, 0.0);
    let mut plant_section = match model.plant {
        Plant::Amplitude { time_constant, .. } | Plant::Resonator { time_constant, .. } => {
            Some(RampSection::new(time_constant, h))
        }
        Plant::Pll => None,
    };
    let (mut phase_ref, mut u_prev) = (0.0, 0.0);
    let steps = (duration / h).ceil() as usize;
    let mut values = Vec::with_capacity(steps);
    for n in 1..=steps {
        let t = n as f64 * h;
        let mut m = delay_line.read_ahead();
        for section in &mut filter {
            m = section.step(m);
        }
        let e = setpoint - m;
        integral += gains.i * h * 0.5 * (e + e_prev);
        // dv/dt = ω_d(ṁ − v), exact for m linear over the step.
        derivative = derivative_a * derivative + (1.0 - derivative_a) * (m - m_prev) / h;
        let u = gains.p * e + integral - gains.d * derivative;
        let (x, output) = match (model.plant, plant_section.as_mut()) {
            (Plant::Amplitude { gain, .. }, Some(section)) => (section.step(gain * u), m),
            // The lever's phase, of the drive's offset from the resonance stepped to 1 Hz.
            (Plant::Resonator { slope, .. }, Some(section)) => (section.step(slope * (u - 1.0)), u),
            _ => {
                phase_ref += TAU * h * 0.5 * (u + u_prev);
                // The input's phase ramps at the stepped frequency, 1 Hz.
                (phase_ref - TAU * t, u)
            }
        };
        delay_line.push(x);
        values.push(output);
        e_prev = e;
        m_prev = m;
        u_prev = u;
    }
    StepTrace { dt: h, values }
}

/// The discrete loop's unit step response over `duration` (s): the [`Pid`] with these gains
/// at the demodulator's output rate, the filter at `filter_rate` (Hz, an integer multiple of
/// the output rate: the instrument's f_s/16), the dead time interpolated at that rate.
/// Sampled at each PID update.
pub fn discrete_step(
    model: &LoopModel,
    gains: &Gains,
    filter_rate: f64,
    duration: f64,
) -> Result<StepTrace, StepError> {
    let d = &model.demodulator;
    positive("filter_rate", filter_rate)?;
    positive("duration", duration)?;
    let ratio = filter_rate / d.output_rate();
    if !(ratio >= 1.0 && (ratio - ratio.round()).abs() < 1e-9 * ratio) {
        return Err(ModelError {
            parameter: "filter_rate",
            value: filter_rate,
            allowed: "an integer multiple of the demodulator's output rate (the filter is decimated to it)",
        }
        .into());
    }
    let decimation = ratio.round() as usize;
    let h = 1.0 / filter_rate;
    let dt = decimation as f64 * h;
    let setpoint = match model.plant {
        Plant::Pll | Plant::Resonator { .. } => 0.0,
        Plant::Amplitude { .. } => 1.0,
    };
    let mut pid = Pid::new(PidSettings {
        setpoint,
        p: gains.p,
        i: gains.i,
        d: gains.d,
        d_bandwidth: gains.d_bandwidth,
        output_min: -f64::MAX,
        output_max: f64::MAX,
        rate_limit: None,
        center: 0.0,
        dt,
    })?;
    // As dsp::lowpass: y += α(x − y), α = 1 − e^{−h/τ}, per section.
    let alpha = -(-h / d.time_constant()).exp_m1();
    let mut sections = vec![0.0; d.order() as usize];
    let mut delay_line = Delay::new(d.dead_time(), h);
    let mut x = 0.0;
    let mut u;
    let mut plant_a = 0.0;
    if let Plant::Amplitude { time_constant, .. } | Plant::Resonator { time_constant, .. } =
        model.plant
    {
        plant_a = (-h / time_constant).exp();
    }
    // The first update at t = 0, as the step happens: a set-point step is acted on at once,
    // as in the model (the loop's hold is in the model's delay).
    u = pid.update(0.0);
    let updates = (duration / dt).ceil() as usize;
    let mut values = Vec::with_capacity(updates);
    for n in 1..=updates * decimation {
        // The plant over (t_{n−1}, t_n] with the held command, exactly.
        x = match model.plant {
            Plant::Pll => x + TAU * h * (u - 1.0),
            Plant::Amplitude { gain, .. } => plant_a * x + (1.0 - plant_a) * gain * u,
            Plant::Resonator { slope, .. } => plant_a * x + (1.0 - plant_a) * slope * (u - 1.0),
        };
        let mut m = delay_line.push_and_read(x);
        for y in &mut sections {
            *y += alpha * (m - *y);
            m = *y;
        }
        if n % decimation == 0 {
            u = pid.update(m);
            values.push(match model.plant {
                Plant::Pll | Plant::Resonator { .. } => u,
                Plant::Amplitude { .. } => m,
            });
        }
    }
    Ok(StepTrace { dt, values })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::loop_model::Demodulator;

    #[test]
    fn a_first_order_loop_steps_as_its_closed_form() {
        // P alone on the PLL, negligible filter and delay: T = 1/(1 + s/ω_c), a pure
        // exponential: no overshoot, 2 % settling at ln(50)/ω_c.
        let model = LoopModel {
            plant: Plant::Pll,
            demodulator: Demodulator::new(1, 1e-9, 1e7, 0.0).unwrap(),
        };
        let gains = Gains {
            p: 50.0,
            i: 0.0,
            d: 0.0,
            d_bandwidth: 1e3,
        };
        let wc = TAU * 50.0;
        let m = model_step(&model, &gains, wc, 0.1).metrics();
        let expected = 50f64.ln() / wc;
        assert!(m.overshoot < 1e-6, "{m:?}");
        assert!(
            (m.settling_time - expected).abs() < 1e-3 * expected,
            "{m:?} against {expected}"
        );
    }

    #[test]
    fn a_filter_rate_that_is_no_multiple_of_the_output_rate_is_refused() {
        let model = LoopModel {
            plant: Plant::Pll,
            demodulator: Demodulator::new(1, 1e-4, 25e3, 0.0).unwrap(),
        };
        let gains = Gains {
            p: 10.0,
            i: 100.0,
            d: 0.0,
            d_bandwidth: 1e3,
        };
        for (rate, duration) in [(60e3, 0.1), (10e3, 0.1), (f64::NAN, 0.1), (625e3, 0.0)] {
            let e = discrete_step(&model, &gains, rate, duration).unwrap_err();
            let StepError::Input(e) = e else {
                panic!("{e}")
            };
            assert!(["filter_rate", "duration"].contains(&e.parameter), "{e}");
        }
        assert!(discrete_step(&model, &gains, 625e3, 1e-3).is_ok());
    }

    #[test]
    fn the_ramp_invariant_section_is_exact_for_a_ramp() {
        let (tau, h) = (1e-3, 3e-4);
        let mut s = RampSection::new(tau, h);
        for n in 1..50 {
            let t = n as f64 * h;
            let y = s.step(t);
            // Response to x = t from rest: t − τ(1 − e^{−t/τ}).
            let exact = t - tau * (1.0 - (-t / tau).exp());
            assert!((y - exact).abs() < 1e-15, "{n}: {y} vs {exact}");
        }
    }
}
