//! A discrete PID controller in the parallel form of Zurich Instruments' LabOne PIDs:
//!
//! ```text
//! e[n]   = r − m[n]                                  (error, input units)
//! out[n] = P·e[n] + I·Σ e[k]·dt + D·(de/dt)_filtered  (output units)
//! ```
//!
//! with P in output units per input unit, I in output units per input unit per second and
//! D in output units·s per input unit. (The ideal or series form P·(e + ∫e/Tᵢ + T_d·ė)
//! maps onto it by I = P/Tᵢ, D = P·T_d.)
//!
//! - The derivative acts on the measurement, not the error (de/dt = −dm/dt while the
//!   set-point holds), so a set-point step does not kick the output; it passes a first-order
//!   low-pass of the configured bandwidth, discretised exactly (step-invariant).
//! - The integrator is a forward-Euler sum; it starts at `center`, so after a reset with no
//!   error the output is `center`.
//! - Anti-windup by conditional integration (clamping): a step whose output is limited
//!   (by the output limits or the rate limit) does not integrate an error that would drive
//!   the output further into the limit. Chosen over back-calculation because it needs no
//!   tracking time constant to tune (LabOne exposes none), and it leaves the integrator
//!   exactly where the limited output left it, so recovery starts at once.
//! - Enable is bumpless: [`Pid::enable`] takes the output to start from; the next update
//!   presets the integrator so that its output equals it.
//!
//! [`Pid::update`] neither allocates, locks, logs nor blocks: it is meant for the real-time
//! chain at the demodulator rate.

use std::f64::consts::PI;

/// The configuration of one PID (every value in SI or the loop's own units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PidSettings {
    /// Set-point r (input units).
    pub setpoint: f64,
    /// Proportional gain P (output units per input unit); negative for a reverse-acting
    /// loop (all non-zero gains then share its sign).
    pub p: f64,
    /// Integral gain I (output units per input unit per second).
    pub i: f64,
    /// Derivative gain D (output units·s per input unit).
    pub d: f64,
    /// −3 dB bandwidth of the derivative's first-order low-pass (Hz), below the Nyquist
    /// frequency 1/(2·dt).
    pub d_bandwidth: f64,
    /// Lowest output (output units).
    pub output_min: f64,
    /// Highest output (output units).
    pub output_max: f64,
    /// Largest change of the output per second (output units/s); `None`: unlimited.
    pub rate_limit: Option<f64>,
    /// The output after a reset with no error, where the integrator starts (output units);
    /// within the output limits.
    pub center: f64,
    /// Sample period dt (s): the interval between two calls of [`Pid::update`].
    pub dt: f64,
}

impl Default for PidSettings {
    /// A PI loop at 1 kHz with unit gains, output in [−1, 1]; no rate limit.
    fn default() -> Self {
        Self {
            setpoint: 0.0,
            p: 1.0,
            i: 1.0,
            d: 0.0,
            d_bandwidth: 100.0,
            output_min: -1.0,
            output_max: 1.0,
            rate_limit: None,
            center: 0.0,
            dt: 1e-3,
        }
    }
}

/// A setting that a PID cannot run with: which one, its value and what is allowed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("PID {parameter} = {value} is out of range: allowed {allowed}")]
pub struct PidError {
    /// The parameter's name (`p`, `i`, `d`, `d_bandwidth`, `output_min`, ...).
    pub parameter: &'static str,
    /// The value given.
    pub value: f64,
    /// What is allowed, in words.
    pub allowed: String,
}

fn refuse(parameter: &'static str, value: f64, allowed: impl Into<String>) -> PidError {
    PidError {
        parameter,
        value,
        allowed: allowed.into(),
    }
}

/// A value as a message shows it: plain where that is short, in exponent form where it is
/// not (an output limit of 4e-8 m, not 0.00000004).
fn show(x: f64) -> String {
    if x == 0.0 || (1e-3..1e6).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

fn finite(parameter: &'static str, value: f64) -> Result<(), PidError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(refuse(parameter, value, "a finite number"))
    }
}

impl PidSettings {
    /// Checks every setting; the error names the first bad one and its allowed range.
    pub fn validate(&self) -> Result<(), PidError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(refuse("dt", self.dt, "a finite period > 0 s"));
        }
        finite("setpoint", self.setpoint)?;
        finite("p", self.p)?;
        finite("i", self.i)?;
        finite("d", self.d)?;
        // A loop whose terms push opposite ways is no loop: the non-zero gains share one
        // sign (the first non-zero one's, P before I).
        let sign = if self.p != 0.0 { self.p } else { self.i };
        for (name, gain) in [("i", self.i), ("d", self.d)] {
            if gain != 0.0 && sign != 0.0 && gain.signum() != sign.signum() {
                let allowed = if sign > 0.0 {
                    "≥ 0 (the sign of the other gains; all negative for a reverse-acting loop)"
                } else {
                    "≤ 0 (the sign of the other gains, which are negative: a reverse-acting loop)"
                };
                return Err(refuse(name, gain, allowed));
            }
        }
        let nyquist = 0.5 / self.dt;
        if !(self.d_bandwidth.is_finite() && self.d_bandwidth > 0.0 && self.d_bandwidth < nyquist) {
            // To 12 significant digits: 0.5/1e-5 is 49999.99999999999, which no one should
            // have to read.
            let nyquist = format!("{nyquist:.11e}").parse::<f64>().unwrap_or(nyquist);
            return Err(refuse(
                "d_bandwidth",
                self.d_bandwidth,
                format!("(0, {nyquist}) Hz: above 0 and below the Nyquist frequency 1/(2·dt)"),
            ));
        }
        finite("output_min", self.output_min)?;
        finite("output_max", self.output_max)?;
        if self.output_min > self.output_max {
            return Err(refuse(
                "output_min",
                self.output_min,
                format!("≤ output_max = {}", show(self.output_max)),
            ));
        }
        if let Some(rate) = self.rate_limit
            && !(rate.is_finite() && rate > 0.0)
        {
            return Err(refuse(
                "rate_limit",
                rate,
                "a finite rate > 0 (output units/s), or none",
            ));
        }
        if !(self.center >= self.output_min && self.center <= self.output_max) {
            return Err(refuse(
                "center",
                self.center,
                format!(
                    "[{}, {}] (the output limits)",
                    show(self.output_min),
                    show(self.output_max)
                ),
            ));
        }
        Ok(())
    }
}

/// A running PID: its settings and its state.
#[derive(Clone, Debug)]
pub struct Pid {
    settings: PidSettings,
    /// The derivative low-pass's coefficient 1 − exp(−2π·f_c·dt).
    alpha: f64,
    enabled: bool,
    /// Integrator state I·Σe·dt plus `center` (output units).
    integral: f64,
    /// Low-passed dm/dt (input units/s).
    derivative: f64,
    last_measurement: f64,
    /// Whether `last_measurement` holds a sample: the derivative needs two.
    primed: bool,
    /// The output the next update starts from (bumpless enable).
    preset: Option<f64>,
    error: f64,
    output: f64,
    /// Whether the last update's output was limited (output limits or rate limit).
    limited: bool,
}

impl Pid {
    /// A PID with these settings, enabled, its output at `center`; refuses settings that
    /// [`PidSettings::validate`] refuses.
    pub fn new(settings: PidSettings) -> Result<Self, PidError> {
        settings.validate()?;
        Ok(Self {
            settings,
            alpha: 1.0 - (-2.0 * PI * settings.d_bandwidth * settings.dt).exp(),
            enabled: true,
            integral: settings.center,
            derivative: 0.0,
            last_measurement: 0.0,
            primed: false,
            preset: None,
            error: 0.0,
            output: settings.center,
            limited: false,
        })
    }

    /// Takes the settings of `tuned` (validated when it was built) and keeps this one's
    /// state: integrator, output, the derivative's history, enabled or not. A change of
    /// gains while running thus moves the output only by what the new gains make of the
    /// next error (the integrator's sum stays), as LabOne's PIDs do. Allocation-free.
    pub fn retune(&mut self, tuned: &Pid) {
        self.settings = tuned.settings;
        self.alpha = tuned.alpha;
    }

    /// The settings it runs with.
    pub fn settings(&self) -> &PidSettings {
        &self.settings
    }

    /// Changes the set-point (input units); the derivative acts on the measurement, so the
    /// output does not kick.
    pub fn set_setpoint(&mut self, setpoint: f64) -> Result<(), PidError> {
        finite("setpoint", setpoint)?;
        self.settings.setpoint = setpoint;
        Ok(())
    }

    /// Back to the state `new` made: integrator and output at `center`, the derivative's
    /// history cleared. Enabled or not stays as it was.
    pub fn reset(&mut self) {
        self.integral = self.settings.center;
        self.output = self.settings.center;
        self.derivative = 0.0;
        self.primed = false;
        self.preset = None;
        self.error = 0.0;
        self.limited = false;
    }

    /// Stops regulating: updates hold the last output (the error is still computed).
    pub fn disable(&mut self) {
        self.enabled = false;
        self.preset = None;
    }

    /// Starts regulating from `from` (output units; clamped to the limits), typically the
    /// value the actuator holds now: the next update outputs exactly it (bumpless), the
    /// integrator preset to make it so.
    pub fn enable(&mut self, from: f64) {
        let from = if from.is_finite() {
            from.clamp(self.settings.output_min, self.settings.output_max)
        } else {
            self.output
        };
        self.enabled = true;
        self.output = from;
        self.preset = Some(from);
    }

    /// Whether it regulates.
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }

    /// The last error r − m (input units).
    pub fn error(&self) -> f64 {
        self.error
    }

    /// The last output (output units).
    pub fn output(&self) -> f64 {
        self.output
    }

    /// Whether the last update's output was held by a limit: the output limits or the rate
    /// limit (the integrator then holds too, see the module docs).
    pub fn is_limited(&self) -> bool {
        self.limited
    }

    /// The integrator's state (output units), `center` included.
    pub fn integral(&self) -> f64 {
        self.integral
    }

    /// One sample: takes the measurement (input units), returns the output (output units).
    #[inline]
    pub fn update(&mut self, measurement: f64) -> f64 {
        let s = &self.settings;
        let error = s.setpoint - measurement;
        if self.primed {
            let raw = (measurement - self.last_measurement) / s.dt;
            self.derivative += self.alpha * (raw - self.derivative);
        } else {
            self.primed = true;
        }
        self.last_measurement = measurement;
        self.error = error;
        if !self.enabled {
            self.limited = false;
            return self.output;
        }
        let p_term = s.p * error;
        // On the measurement: de/dt = −dm/dt with the set-point held.
        let d_term = -s.d * self.derivative;
        if let Some(start) = self.preset.take() {
            self.integral = start - p_term - d_term;
            self.output = start;
            self.limited = false;
            return start;
        }
        let candidate = self.integral + s.i * error * s.dt;
        let wanted = p_term + candidate + d_term;
        let mut out = wanted.clamp(s.output_min, s.output_max);
        if let Some(rate) = s.rate_limit {
            let step = rate * s.dt;
            out = out.clamp(self.output - step, self.output + step);
        }
        // Conditional integration: integrate unless the output is limited and this step's
        // integration would push it further into the limit.
        if (wanted - out) * (s.i * error) <= 0.0 {
            self.integral = candidate;
        }
        self.output = out;
        self.limited = out != wanted;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-order plant y' = (K·u − y)/τ, discretised exactly for a zero-order-held u.
    struct Plant {
        a: f64,
        gain: f64,
        y: f64,
    }

    impl Plant {
        fn new(gain: f64, tau: f64, dt: f64) -> Self {
            Self {
                a: (-dt / tau).exp(),
                gain,
                y: 0.0,
            }
        }

        fn step(&mut self, u: f64) -> f64 {
            self.y = self.a * self.y + self.gain * (1.0 - self.a) * u;
            self.y
        }
    }

    fn settings(p: f64, i: f64) -> PidSettings {
        PidSettings {
            setpoint: 0.5,
            p,
            i,
            d: 0.0,
            d_bandwidth: 100.0,
            output_min: -10.0,
            output_max: 10.0,
            rate_limit: None,
            center: 0.0,
            dt: 1e-3,
        }
    }

    /// Runs `steps` samples of a loop closed over `plant`; returns the plant outputs.
    fn run(pid: &mut Pid, plant: &mut Plant, steps: usize) -> Vec<f64> {
        (0..steps)
            .map(|_| {
                let u = pid.update(plant.y);
                plant.step(u)
            })
            .collect()
    }

    #[test]
    fn the_integrator_removes_the_steady_state_error_proportional_alone_leaves_it() {
        let (gain, p, step) = (2.0, 3.0, 0.5);
        let mut pi = Pid::new(settings(p, 5.0)).unwrap();
        let mut plant = Plant::new(gain, 0.1, 1e-3);
        run(&mut pi, &mut plant, 20_000);
        assert!((plant.y - step).abs() < 1e-9, "PI settles at {}", plant.y);

        let mut p_only = Pid::new(settings(p, 0.0)).unwrap();
        let mut plant = Plant::new(gain, 0.1, 1e-3);
        run(&mut p_only, &mut plant, 20_000);
        let expected_error = step / (1.0 + gain * p);
        assert!(
            (p_only.error() - expected_error).abs() < 1e-9,
            "P-only error {} against 1/(1+K·P)·step = {expected_error}",
            p_only.error()
        );
    }

    #[test]
    fn the_output_stays_within_its_limits() {
        let mut s = settings(50.0, 500.0);
        s.d = 0.5;
        s.output_min = -0.2;
        s.output_max = 0.3;
        let mut pid = Pid::new(s).unwrap();
        let mut x = 0.123_f64;
        for _ in 0..10_000 {
            // A chaotic measurement (logistic map) covering both directions of saturation.
            x = 3.99 * x * (1.0 - x);
            let out = pid.update(2.0 * x - 0.5);
            assert!((-0.2..=0.3).contains(&out), "{out}");
        }
    }

    /// Plant output after a long saturation (set-point 3, out of reach: the output is
    /// limited to 2) and a return to a reachable set-point 1; returns (the largest
    /// |y − 1| from 5 s after the change on, the time to settle within 2 %).
    fn recovery(mut step: impl FnMut(&mut Plant, f64) -> f64) -> (f64, f64) {
        let dt = 1e-3;
        let mut plant = Plant::new(1.0, 1.0, dt);
        let mut ys = Vec::new();
        for n in 0..60_000 {
            let r = if n < 20_000 { 3.0 } else { 1.0 };
            ys.push(step(&mut plant, r));
        }
        let after = &ys[25_000..];
        let worst = after.iter().map(|y| (y - 1.0).abs()).fold(0.0, f64::max);
        let settled = ys
            .iter()
            .rposition(|y| (y - 1.0).abs() > 0.02)
            .map_or(0.0, |n| (n as f64 - 20_000.0) * dt);
        (worst, settled)
    }

    #[test]
    fn anti_windup_bounds_the_recovery_after_a_long_saturation() {
        let mut s = settings(5.0, 10.0);
        s.output_min = -2.0;
        s.output_max = 2.0;
        let mut pid = Pid::new(s).unwrap();
        let clamped = recovery(|plant, r| {
            pid.set_setpoint(r).unwrap();
            let u = pid.update(plant.y);
            plant.step(u)
        });
        // The naive integrator: the same PI, its output clipped, its integrator never held.
        let mut integral = 0.0;
        let naive = recovery(|plant, r| {
            let e = r - plant.y;
            integral += 10.0 * e * 1e-3;
            plant.step((5.0 * e + integral).clamp(-2.0, 2.0))
        });
        eprintln!(
            "anti-windup: (worst |y − r| from 5 s on, settling time s): clamped {clamped:?}, naive {naive:?}"
        );
        assert!(clamped.0 < 0.02 && clamped.1 < 5.0, "clamped {clamped:?}");
        assert!(naive.0 > 0.5 && naive.1 > 10.0, "naive {naive:?}");
    }

    #[test]
    fn the_rate_limit_holds_and_is_reached() {
        let mut s = settings(100.0, 0.0);
        s.rate_limit = Some(50.0); // 0.05 per 1 ms step
        let mut pid = Pid::new(s).unwrap();
        let mut last = pid.output();
        let mut reached = false;
        for n in 0..1000 {
            let out = pid.update(if n < 500 { 0.0 } else { 1.0 });
            let jump = (out - last).abs();
            assert!(jump <= 0.05 + 1e-12, "step {n}: jump {jump}");
            reached |= (jump - 0.05).abs() < 1e-12;
            last = out;
        }
        assert!(reached);
    }

    #[test]
    fn enabling_and_disabling_are_bumpless() {
        let mut pid = Pid::new(settings(3.0, 5.0)).unwrap();
        let mut plant = Plant::new(2.0, 0.1, 1e-3);
        run(&mut pid, &mut plant, 500);
        pid.disable();
        let held = pid.output();
        // While disabled the output holds, whatever the measurement does.
        for m in [0.0, 1.0, -3.0] {
            assert_eq!(pid.update(m), held);
        }
        pid.enable(held);
        let first = pid.update(0.9);
        assert!((first - held).abs() < 1e-12, "{first} vs {held}");
        // From a value the actuator was moved to while disabled.
        pid.disable();
        pid.enable(0.3);
        assert!((pid.update(0.1) - 0.3).abs() < 1e-12);
        let next = pid.update(0.1);
        // Continues smoothly: only one sample's integration away.
        assert!((next - 0.3).abs() < 5.0 * 0.4 * 1e-3 + 1e-12, "{next}");
    }

    #[test]
    fn retuning_keeps_the_integrator_and_the_limit_is_reported() {
        let mut pid = Pid::new(settings(1.0, 50.0)).unwrap();
        let mut plant = Plant::new(2.0, 0.1, 1e-3);
        run(&mut pid, &mut plant, 3000);
        let (integral, output) = (pid.integral(), pid.output());
        assert!(!pid.is_limited());
        let tuned = Pid::new(settings(2.0, 80.0)).unwrap();
        pid.retune(&tuned);
        assert_eq!(pid.settings().p, 2.0);
        assert_eq!((pid.integral(), pid.output()), (integral, output));
        // Settled: the error is ~0, so the new gains move the output by next to nothing.
        let next = pid.update(plant.y);
        assert!((next - output).abs() < 1e-6, "{next} vs {output}");
        // A set-point out of reach drives the output into its limit, and says so.
        pid.set_setpoint(100.0).unwrap();
        let out = pid.update(plant.y);
        assert_eq!(out, 10.0);
        assert!(pid.is_limited());
    }

    #[test]
    fn a_setpoint_step_does_not_kick_the_derivative() {
        let mut s = settings(0.0, 0.0);
        s.d = 1.0;
        let mut pid = Pid::new(s).unwrap();
        for _ in 0..10 {
            pid.update(0.2);
        }
        pid.set_setpoint(5.0).unwrap();
        assert_eq!(pid.update(0.2), 0.0);
        // A measurement step does: D·f_c-filtered −dm/dt.
        assert!(pid.update(0.3) < 0.0);
    }

    #[test]
    fn the_same_inputs_give_the_same_bits() {
        let mut s = settings(2.0, 30.0);
        s.d = 0.01;
        s.rate_limit = Some(100.0);
        let trace = || {
            let mut pid = Pid::new(s).unwrap();
            let mut plant = Plant::new(1.5, 0.05, 1e-3);
            let mut x = 0.3_f64;
            (0..5000)
                .map(|_| {
                    x = 3.9 * x * (1.0 - x);
                    let u = pid.update(plant.y + 1e-3 * x);
                    plant.step(u).to_bits()
                })
                .collect::<Vec<u64>>()
        };
        assert_eq!(trace(), trace());
    }

    #[test]
    fn bad_settings_are_refused_naming_the_parameter_and_range() {
        let ok = settings(1.0, 1.0);
        let cases: Vec<(&str, PidSettings)> = vec![
            ("p", PidSettings { p: f64::NAN, ..ok }),
            (
                "i",
                PidSettings {
                    i: f64::INFINITY,
                    ..ok
                },
            ),
            ("i", PidSettings { i: -1.0, ..ok }),
            ("d", PidSettings { d: -0.1, ..ok }),
            (
                "d",
                PidSettings {
                    p: -1.0,
                    i: -1.0,
                    d: 0.1,
                    ..ok
                },
            ),
            ("dt", PidSettings { dt: 0.0, ..ok }),
            ("dt", PidSettings { dt: -1e-3, ..ok }),
            (
                "d_bandwidth",
                PidSettings {
                    d_bandwidth: 500.0,
                    ..ok
                },
            ),
            (
                "d_bandwidth",
                PidSettings {
                    d_bandwidth: 0.0,
                    ..ok
                },
            ),
            (
                "output_min",
                PidSettings {
                    output_min: 2.0,
                    output_max: 1.0,
                    center: 1.0,
                    ..ok
                },
            ),
            (
                "output_max",
                PidSettings {
                    output_max: f64::NAN,
                    ..ok
                },
            ),
            (
                "rate_limit",
                PidSettings {
                    rate_limit: Some(-1.0),
                    ..ok
                },
            ),
            ("center", PidSettings { center: 20.0, ..ok }),
            (
                "setpoint",
                PidSettings {
                    setpoint: f64::NEG_INFINITY,
                    ..ok
                },
            ),
        ];
        for (parameter, bad) in cases {
            let e = Pid::new(bad).unwrap_err();
            assert_eq!(e.parameter, parameter, "{e}");
            let text = e.to_string();
            assert!(
                text.contains(parameter) && text.contains("allowed"),
                "{text}"
            );
        }
        let e = Pid::new(PidSettings {
            d_bandwidth: 600.0,
            ..ok
        })
        .unwrap_err();
        assert!(
            e.to_string().contains("500"),
            "names the Nyquist frequency: {e}"
        );
        // A reverse-acting loop (all gains negative) is fine.
        assert!(
            Pid::new(PidSettings {
                p: -1.0,
                i: -2.0,
                d: -0.1,
                ..ok
            })
            .is_ok()
        );
    }
}
