//! Linear models of the two loops the instrument closes, in continuous time: the open-loop
//! transfer function L(s) = C(s)·G(s)·H(s)·e^{−sT} as a product of parts, its frequency
//! response, crossover, phase margin and the closed loop's −3 dB bandwidth.
//!
//! - C(s) = P + I/s + D·s/(1 + s/ω_d): the PID in the parallel form of [`super::Pid`].
//! - G(s): the plant. PLL on an external signal: the reference phase integrates the
//!   frequency command, 2π/s (rad per Hz·s). PLL on the driven lever: its phase answers the
//!   drive frequency as slope/(1 + s·τ_c) (rad/Hz). Amplitude loop: the lever's envelope,
//!   G0/(1 + s·τ_c).
//! - H(s) = (1 + s·τ)^{−n}: the demodulator's output filter, n identical first-order
//!   sections of time constant τ each (restated from `dsp::lowpass`, which `control` may
//!   not import); n = 0 for the live PID units' demodulators, which have none.
//! - e^{−sT}: every delay in the loop as one dead time: the demodulator's output sampling
//!   (a zero-order hold at f_out, ≈ 1/(2·f_out)) plus the fixed delays of the chain.

use rustfft::num_complex::Complex64;
use std::f64::consts::{PI, TAU};

/// Highest demodulator filter order (`/demods/N/order`).
pub const MAX_ORDER: u32 = 8;

/// The ADC's decimation chain delays the signal by this many samples at f_s
/// (docs/signal-chain.md): a dead time inside any loop through a demodulator.
pub const ADC_DELAY_SAMPLES: f64 = 21.5;

/// The lock-in's pre-decimator and droop compensator delay the signal by this many input
/// samples before the low-pass (`LockInBank::group_delay`, c + D = 30 + 16).
pub const LOCKIN_DELAY_SAMPLES: f64 = 46.0;

/// The lock-in's low-pass runs at f_s / this (`dsp::lockin`'s pre-decimation).
pub const PREDECIMATION: f64 = 16.0;

/// An input the model cannot take: which, its value and what is allowed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{parameter} = {value} is out of range: allowed {allowed}")]
pub struct ModelError {
    /// The input's name (`order`, `time_constant`, ...).
    pub parameter: &'static str,
    /// The value given.
    pub value: f64,
    /// What is allowed, in words.
    pub allowed: &'static str,
}

pub(crate) fn positive(parameter: &'static str, value: f64) -> Result<(), ModelError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ModelError {
            parameter,
            value,
            allowed: "a finite number > 0",
        })
    }
}

/// `value` finite and ≥ 0, or the error naming `parameter` and what is `allowed`.
fn non_negative(
    parameter: &'static str,
    value: f64,
    allowed: &'static str,
) -> Result<(), ModelError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ModelError {
            parameter,
            value,
            allowed,
        })
    }
}

/// The demodulator in the loop: its output filter and the delays between the actuator and
/// the demodulator's output. Its filter has 1–8 sections ([`Self::new`]), or none (order 0:
/// [`Self::unfiltered`], [`Self::pid_unit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Demodulator {
    order: u32,
    time_constant: f64,
    output_rate: f64,
    dead_time: f64,
    filter_rate: Option<f64>,
}

impl Demodulator {
    /// A filter of `order` (1–8; see [`Self::unfiltered`] for none) sections of `time_constant` τ (s) each, read out at
    /// `output_rate` f_out (Hz), behind a fixed `dead_time` (s, ≥ 0).
    pub fn new(
        order: u32,
        time_constant: f64,
        output_rate: f64,
        dead_time: f64,
    ) -> Result<Self, ModelError> {
        if !(1..=MAX_ORDER).contains(&order) {
            return Err(ModelError {
                parameter: "order",
                value: order as f64,
                allowed: "an integer in 1..=8 (first-order sections)",
            });
        }
        positive("time_constant", time_constant)?;
        positive("output_rate", output_rate)?;
        non_negative("dead_time", dead_time, "a finite time ≥ 0 s")?;
        Ok(Self {
            order,
            time_constant,
            output_rate,
            dead_time,
            filter_rate: None,
        })
    }

    /// A demodulator without an output filter (order 0: H(s) = 1), read out at
    /// `output_rate` f_out (Hz) behind a fixed `dead_time` (s, ≥ 0). Its time constant is
    /// reported as 0 s.
    pub fn unfiltered(output_rate: f64, dead_time: f64) -> Result<Self, ModelError> {
        let mut d = Self::new(1, 1.0, output_rate, dead_time)?;
        d.order = 0;
        d.time_constant = 0.0;
        Ok(d)
    }

    /// The demodulator of a live PID unit (`/pids/N`, `synth::pids`): the least-squares
    /// sinusoid over the drive period just ended, read once a period, no low-pass. At drive
    /// frequency f (Hz, T = 1/f) and input rate `sample_rate` f_s (Hz): output rate f
    /// (the unit's update rate); dead time T/2 (the one-period boxcar's mean delay) plus
    /// `adc_delay_samples`/f_s (the ADC filter's delay, [`ADC_DELAY_SAMPLES`] with
    /// `/synth/anti_alias`, else 0); with the output's zero-order hold (half a period, in
    /// [`Self::total_delay`]) the loop's delay is T + `adc_delay_samples`/f_s. The boxcar's
    /// amplitude droop, sinc(ωT/2), is under 1 % below f/8 and is not modelled.
    pub fn pid_unit(
        drive_frequency: f64,
        sample_rate: f64,
        adc_delay_samples: f64,
    ) -> Result<Self, ModelError> {
        positive("drive_frequency", drive_frequency)?;
        positive("sample_rate", sample_rate)?;
        non_negative(
            "adc_delay_samples",
            adc_delay_samples,
            "a finite number of samples ≥ 0",
        )?;
        Self::unfiltered(
            drive_frequency,
            0.5 / drive_frequency + adc_delay_samples / sample_rate,
        )
    }

    /// The same, its filter running discretely at `filter_rate` (Hz) as `dsp::lowpass`
    /// runs it: each section `y[m] = y[m−1] + α(x[m] − y[m−1])` takes the newest sample
    /// in, which puts it half a sample ahead of the continuous section of the same τ
    /// (H(e^{iωh}) ≈ e^{iωh/2}/(1 + iωτ) for ωh ≪ 1): n sections lead by n/(2·filter_rate).
    pub fn with_filter_rate(self, filter_rate: f64) -> Result<Self, ModelError> {
        positive("filter_rate", filter_rate)?;
        Ok(Self {
            filter_rate: Some(filter_rate),
            ..self
        })
    }

    /// The instrument's demodulator at input rate `sample_rate` f_s (Hz): the dead time is
    /// the ADC's and the lock-in pre-decimator's fixed delays, (21.5 + 46)/f_s; the filter
    /// runs at f_s/16 ([`Self::with_filter_rate`]).
    pub fn instrument(
        order: u32,
        time_constant: f64,
        output_rate: f64,
        sample_rate: f64,
    ) -> Result<Self, ModelError> {
        positive("sample_rate", sample_rate)?;
        Self::new(
            order,
            time_constant,
            output_rate,
            (ADC_DELAY_SAMPLES + LOCKIN_DELAY_SAMPLES) / sample_rate,
        )?
        .with_filter_rate(sample_rate / PREDECIMATION)
    }

    /// Number of first-order sections n (0: no filter).
    pub fn order(&self) -> u32 {
        self.order
    }

    /// Time constant τ of each section (s; 0 without a filter).
    pub fn time_constant(&self) -> f64 {
        self.time_constant
    }

    /// Output rate f_out (Hz): the rate the PID runs at.
    pub fn output_rate(&self) -> f64 {
        self.output_rate
    }

    /// The fixed dead time (s), without the output sampling's.
    pub fn dead_time(&self) -> f64 {
        self.dead_time
    }

    /// The rate the filter runs at (Hz), if it is modelled as discrete.
    pub fn filter_rate(&self) -> Option<f64> {
        self.filter_rate
    }

    /// How far the discrete filter runs ahead of the continuous one (s): n/(2·filter_rate),
    /// 0 for a continuous filter.
    pub fn filter_lead(&self) -> f64 {
        self.filter_rate
            .map_or(0.0, |rate| 0.5 * self.order as f64 / rate)
    }

    /// All the delay in the loop (s): the output sampling's zero-order hold, taken as half
    /// an output period, plus the dead time, less the discrete filter's lead (never below 0).
    pub fn total_delay(&self) -> f64 {
        (0.5 / self.output_rate + self.dead_time - self.filter_lead()).max(0.0)
    }

    /// The filter's response (1 + iωτ)^{−n} at ω (rad/s).
    pub fn filter(&self, omega: f64) -> Complex64 {
        Complex64::new(1.0, omega * self.time_constant).powi(-(self.order as i32))
    }

    /// The filter and the delays: (1 + iωτ)^{−n}·e^{−iωT} at ω (rad/s).
    pub fn response(&self, omega: f64) -> Complex64 {
        self.filter(omega) * Complex64::from_polar(1.0, -omega * self.total_delay())
    }
}

/// What the loop's PID drives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Plant {
    /// PLL on an external signal: the PID's output is the reference's frequency offset
    /// (Hz), its input the demodulated phase (rad); the phase integrates the frequency:
    /// 2π/s.
    Pll,
    /// PLL on the driven lever: the PID's output is the drive's frequency (Hz), its input
    /// the demodulated phase of the lever's response at harmonic 1 (rad). Near resonance
    /// the phase answers a change of drive frequency as −slope/(1 + s·τ_c): it falls by
    /// slope = 2Q/f0 rad per Hz, through the envelope's time constant τ_c = Q/(π·f0). The
    /// model takes it positive, slope/(1 + s·τ_c), as the advisor's other plants; the PLL,
    /// whose phase falls as its output rises, takes the advice's gains negated.
    Resonator {
        /// |∂φ/∂f| at resonance, 2Q/f0 (rad/Hz).
        slope: f64,
        /// τ_c = Q/(π·f0) (s): the envelope's time constant.
        time_constant: f64,
    },
    /// Amplitude loop: the PID's output is the drive amplitude, its input the demodulated
    /// oscillation amplitude; the envelope answers as G0/(1 + s·τ_c). With τ_c = 0 any plant
    /// that answers at once ([`Plant::quasi_static`]).
    Amplitude {
        /// G0 = ∂A/∂U at the operating point (amplitude unit per drive unit).
        gain: f64,
        /// τ_c = Q/(π·f0) (s): the envelope's time constant.
        time_constant: f64,
    },
}

impl Plant {
    /// The amplitude loop of a lever of quality factor `q` and resonance `f0` (Hz), whose
    /// amplitude changes by `gain` per unit of drive.
    pub fn amplitude(gain: f64, q: f64, f0: f64) -> Result<Self, ModelError> {
        positive("gain", gain)?;
        positive("q", q)?;
        positive("f0", f0)?;
        Ok(Self::Amplitude {
            gain,
            time_constant: q / (PI * f0),
        })
    }

    /// A plant that answers at once on the loop's time scale, `gain` input units per output
    /// unit: [`Self::Amplitude`] without a pole (τ_c = 0), as the lever pressed on a sample
    /// answers a move of the surface (contact mode's deflection).
    pub fn quasi_static(gain: f64) -> Result<Self, ModelError> {
        positive("gain", gain)?;
        Ok(Self::Amplitude {
            gain,
            time_constant: 0.0,
        })
    }

    /// The plant's DC gain, for the plants that have one (input units per output unit).
    pub fn gain(&self) -> Option<f64> {
        match *self {
            Self::Amplitude { gain, .. } => Some(gain),
            Self::Pll | Self::Resonator { .. } => None,
        }
    }

    /// The PLL on a lever of quality factor `q` and resonance `f0` (Hz), driven near its
    /// resonance: [`Self::Resonator`] with slope 2Q/f0 and τ_c = Q/(π·f0).
    pub fn resonator(q: f64, f0: f64) -> Result<Self, ModelError> {
        positive("q", q)?;
        positive("f0", f0)?;
        Ok(Self::Resonator {
            slope: 2.0 * q / f0,
            time_constant: q / (PI * f0),
        })
    }

    /// The time constant of the plant's pole (s), for the plants that have one.
    pub fn time_constant(&self) -> Option<f64> {
        match *self {
            Self::Pll => None,
            Self::Resonator { time_constant, .. } | Self::Amplitude { time_constant, .. } => {
                Some(time_constant)
            }
        }
    }

    /// G(iω) at ω (rad/s).
    pub fn response(&self, omega: f64) -> Complex64 {
        match *self {
            Self::Pll => Complex64::new(0.0, -TAU / omega),
            Self::Resonator {
                slope,
                time_constant,
            } => slope / Complex64::new(1.0, omega * time_constant),
            Self::Amplitude {
                gain,
                time_constant,
            } => gain / Complex64::new(1.0, omega * time_constant),
        }
    }
}

/// PID gains in the parallel form of [`super::PidSettings`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gains {
    /// P (output units per input unit).
    pub p: f64,
    /// I (output units per input unit per second).
    pub i: f64,
    /// D (output units·s per input unit).
    pub d: f64,
    /// The derivative low-pass's bandwidth f_d (Hz).
    pub d_bandwidth: f64,
}

impl Gains {
    /// C(iω) = P + I/(iω) + D·iω/(1 + iω/ω_d) at ω (rad/s).
    pub fn response(&self, omega: f64) -> Complex64 {
        let s = Complex64::new(0.0, omega);
        let derivative = self.d * s / (1.0 + s / (TAU * self.d_bandwidth));
        self.p + self.i / s + derivative
    }
}

/// A loop: a plant seen through a demodulator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopModel {
    /// What the PID drives.
    pub plant: Plant,
    /// What measures it.
    pub demodulator: Demodulator,
}

/// Points per decade of the searches' log grids: fine enough that no crossing of a smooth
/// response is stepped over; bisection then refines it.
const GRID_PER_DECADE: f64 = 40.0;

impl LoopModel {
    /// The plant and sensor without the controller: G(iω)·H(iω)·e^{−iωT} at ω (rad/s).
    pub fn process(&self, omega: f64) -> Complex64 {
        self.plant.response(omega) * self.demodulator.response(omega)
    }

    /// The open loop L(iω) = C·G·H·e^{−iωT} at ω (rad/s).
    pub fn open_loop(&self, gains: &Gains, omega: f64) -> Complex64 {
        gains.response(omega) * self.process(omega)
    }

    /// The closed loop T(iω) = L/(1 + L) at ω (rad/s).
    pub fn closed_loop(&self, gains: &Gains, omega: f64) -> Complex64 {
        let l = self.open_loop(gains, omega);
        l / (1.0 + l)
    }

    /// |T| at DC: 1 when the loop has an integrator (the PLL, or I ≠ 0).
    fn dc_closed_loop(&self, gains: &Gains) -> f64 {
        match self.plant {
            Plant::Amplitude { gain, .. } if gains.i == 0.0 => {
                let l = gain * gains.p;
                (l / (1.0 + l)).abs()
            }
            _ => 1.0,
        }
    }

    /// Finds the first ω on a log grid from `from` (rad/s) up to `to` where `below(ω)`
    /// holds, and refines it by bisection to a relative 1e-10.
    fn first_crossing(from: f64, to: f64, below: impl Fn(f64) -> bool) -> Option<f64> {
        let ratio = 10f64.powf(1.0 / GRID_PER_DECADE);
        let mut lo = from;
        if below(lo) {
            return None;
        }
        while lo < to {
            let hi = lo * ratio;
            if below(hi) {
                let (mut a, mut b) = (lo, hi);
                while (b - a) > 1e-10 * b {
                    let m = (a * b).sqrt();
                    if below(m) {
                        b = m;
                    } else {
                        a = m;
                    }
                }
                return Some(0.5 * (a + b));
            }
            lo = hi;
        }
        None
    }

    /// The searches' span (rad/s): wide enough for any loop the instrument can close, from
    /// a crossover of well below a µHz to far above any output rate.
    fn span(&self) -> (f64, f64) {
        (1e-6, 1e13)
    }

    /// The crossover ω_c (rad/s): the lowest frequency where |L| falls to 1; `None` if
    /// |L| < 1 already at the bottom of the search or never falls to 1.
    pub fn crossover(&self, gains: &Gains) -> Option<f64> {
        let (lo, hi) = self.span();
        Self::first_crossing(lo, hi, |w| self.open_loop(gains, w).norm() < 1.0)
    }

    /// Phase margin (degrees): 180° + arg L(iω_c), the phase unwrapped by summing the
    /// parts' phases (each known in closed form) so that delays of many radians count.
    pub fn phase_margin(&self, gains: &Gains) -> Option<f64> {
        self.crossover(gains)
            .map(|w| 180.0 + self.open_loop_phase(gains, w).to_degrees())
    }

    /// arg L(iω) (rad), unwrapped: the sum of the parts' phases.
    pub fn open_loop_phase(&self, gains: &Gains, omega: f64) -> f64 {
        let d = &self.demodulator;
        let controller = gains.response(omega).arg();
        let plant = self.plant.response(omega).arg();
        let filter = -(d.order as f64) * (omega * d.time_constant).atan();
        controller + plant + filter - omega * d.total_delay()
    }

    /// The closed loop's −3 dB bandwidth (Hz): the lowest frequency where |T| falls below
    /// 1/√2 of its DC value (after any peaking); `None` if it never does in the span.
    pub fn bandwidth(&self, gains: &Gains) -> Option<f64> {
        let (lo, hi) = self.span();
        let level = self.dc_closed_loop(gains) * std::f64::consts::FRAC_1_SQRT_2;
        Self::first_crossing(lo, hi, |w| self.closed_loop(gains, w).norm() < level).map(|w| w / TAU)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    fn pll(order: u32, tau: f64, f_out: f64, dead: f64) -> LoopModel {
        LoopModel {
            plant: Plant::Pll,
            demodulator: Demodulator::new(order, tau, f_out, dead).unwrap(),
        }
    }

    #[test]
    fn the_parts_have_their_analytic_responses() {
        // An integrator: −90° at every frequency, |2π/s| = 2π/ω.
        for w in [1.0, 37.0, 1e4] {
            let g = Plant::Pll.response(w);
            assert!(close(g.arg().to_degrees(), -90.0, 1e-12));
            assert!(close(g.norm(), TAU / w, 1e-12 * TAU / w));
        }
        // A first-order section: −45° and 1/√2 at its corner; n sections: −n·45°, 2^{−n/2}.
        for order in [1, 4, 8] {
            let d = Demodulator::new(order, 1e-3, 1e9, 0.0).unwrap();
            let h = d.filter(1e3);
            let n = order as f64;
            assert!(close(h.norm(), 2f64.powf(-n / 2.0), 1e-12));
            let unwrapped = -n * 45.0;
            let wrapped = (unwrapped + 180.0).rem_euclid(360.0) - 180.0;
            assert!(close(h.arg().to_degrees(), wrapped, 1e-9), "{order}");
        }
        // The amplitude plant's corner at 1/τ_c = π·f0/Q.
        let plant = Plant::amplitude(2.0, 400.0, 3e5).unwrap();
        let Plant::Amplitude { time_constant, .. } = plant else {
            unreachable!()
        };
        assert!(close(time_constant, 400.0 / (PI * 3e5), 1e-18));
        let g = plant.response(1.0 / time_constant);
        assert!(close(g.arg().to_degrees(), -45.0, 1e-12));
        assert!(close(g.norm(), 2.0 / 2f64.sqrt(), 1e-12));
        // A delay: −ωT, with the output sampling's half period in it.
        let d = Demodulator::new(1, 1e-9, 1e4, 30e-6).unwrap();
        assert!(close(d.total_delay(), 80e-6, 1e-18));
        let w = 2000.0;
        let phase = d.response(w).arg() + (w * 1e-9).atan();
        assert!(close(phase, -w * 80e-6, 1e-12));
        // The PID: P + I/(iω) + D·iω/(1 + iω/ω_d).
        let c = Gains {
            p: 2.0,
            i: 300.0,
            d: 0.01,
            d_bandwidth: 1e3,
        }
        .response(100.0);
        let deriv = Complex64::new(0.0, 1.0) / Complex64::new(1.0, 100.0 / (TAU * 1e3));
        let expected = Complex64::new(2.0, -3.0) + deriv;
        assert!((c - expected).norm() < 1e-12);
    }

    #[test]
    fn the_discrete_filter_leads_the_continuous_one_by_half_a_sample_a_section() {
        // dsp::lowpass's section, y[m] = y[m−1] + α(x[m] − y[m−1]): H(z) = α/(1 − (1−α)/z).
        let (order, tau, rate) = (8, 1e-4, 625e3);
        let d = Demodulator::new(order, tau, rate, 0.0)
            .unwrap()
            .with_filter_rate(rate)
            .unwrap();
        assert!(close(d.filter_lead(), 4.0 / rate, 1e-18));
        let alpha = -(-1.0 / (tau * rate)).exp_m1();
        for f in [10.0, 300.0, 1e3] {
            let w = TAU * f;
            let z_inv = Complex64::from_polar(1.0, -w / rate);
            let discrete = (alpha / (1.0 - (1.0 - alpha) * z_inv)).powi(order as i32);
            let model = d.filter(w) * Complex64::from_polar(1.0, w * d.filter_lead());
            // The phase within 1e-3 of the filter's own lag; the gain within 1e-4.
            let lag = order as f64 * (w * tau).atan();
            assert!(
                (discrete.arg() - model.arg()).abs() < 1e-3 * lag,
                "{f} Hz: {} vs {}",
                discrete.arg(),
                model.arg()
            );
            assert!(
                (discrete.norm() / model.norm() - 1.0).abs() < 1e-4,
                "{f} Hz"
            );
            // Without the lead, the phase is off by ω·n/(2·rate).
            assert!((discrete.arg() - d.filter(w).arg() - w * 4.0 / rate).abs() < 1e-3 * lag);
        }
    }

    #[test]
    fn crossover_margin_and_bandwidth_of_a_pure_integrator_loop() {
        // P alone on 2π/s with a negligible filter and delay: L = 2πP/(iω), ω_c = 2πP,
        // margin 90°, T = 1/(1 + s/ω_c): −3 dB at ω_c.
        let m = pll(1, 1e-12, 1e12, 0.0);
        let g = Gains {
            p: 100.0,
            i: 0.0,
            d: 0.0,
            d_bandwidth: 1.0,
        };
        let wc = m.crossover(&g).unwrap();
        assert!(close(wc, TAU * 100.0, 1e-6), "{wc}");
        assert!(close(m.phase_margin(&g).unwrap(), 90.0, 1e-6));
        assert!(close(m.bandwidth(&g).unwrap(), 100.0, 1e-6));
    }

    #[test]
    fn the_phase_margin_counts_the_delay_unwrapped() {
        // ω_c = 2π·100 rad/s with T = 10 ms: the delay alone takes 360°.
        let m = pll(1, 1e-12, 1e12, 10e-3);
        let g = Gains {
            p: 100.0,
            i: 0.0,
            d: 0.0,
            d_bandwidth: 1.0,
        };
        assert!(close(m.phase_margin(&g).unwrap(), 90.0 - 360.0, 1e-5));
    }

    #[test]
    fn the_pid_units_demodulator_has_no_filter_and_a_period_of_delay() {
        // f = 100 kHz, f_s = 10 MS/s: the boxcar's T/2 and the ADC's 21.5 samples as dead
        // time, the hold's T/2 on top: T + 21.5/f_s = 12.15 µs in all.
        let d = Demodulator::pid_unit(1e5, 1e7, ADC_DELAY_SAMPLES).unwrap();
        assert_eq!(d.order(), 0);
        assert_eq!(d.time_constant(), 0.0);
        assert_eq!(d.output_rate(), 1e5);
        assert!(close(d.dead_time(), 5e-6 + 2.15e-6, 1e-18));
        assert!(close(d.total_delay(), 12.15e-6, 1e-18));
        assert_eq!(d.filter_lead(), 0.0);
        // No filter: a pure delay at every frequency.
        for w in [1.0, 1e3, 1e5] {
            assert_eq!(d.filter(w), Complex64::new(1.0, 0.0));
            let r = d.response(w);
            assert!(close(r.norm(), 1.0, 1e-12));
            assert!(close(r.arg(), -w * 12.15e-6, 1e-12));
        }
        // Without the ADC filter, T alone.
        let d = Demodulator::pid_unit(1e5, 1e7, 0.0).unwrap();
        assert!(close(d.total_delay(), 10e-6, 1e-18));
        // The loop's unwrapped phase has no filter term: a P-only PLL's margin is 90° less
        // the delay's lag at the crossover.
        let m = LoopModel {
            plant: Plant::Pll,
            demodulator: d,
        };
        let g = Gains {
            p: 100.0,
            i: 0.0,
            d: 0.0,
            d_bandwidth: 1.0,
        };
        let wc = m.crossover(&g).unwrap();
        assert!(close(wc, TAU * 100.0, 1e-6));
        let margin = 90.0 - (wc * 10e-6).to_degrees();
        assert!(close(m.phase_margin(&g).unwrap(), margin, 1e-6));
        for (name, result) in [
            ("drive_frequency", Demodulator::pid_unit(0.0, 1e7, 21.5)),
            ("sample_rate", Demodulator::pid_unit(1e5, f64::NAN, 21.5)),
            ("adc_delay_samples", Demodulator::pid_unit(1e5, 1e7, -1.0)),
            ("output_rate", Demodulator::unfiltered(-1.0, 0.0)),
            ("dead_time", Demodulator::unfiltered(1e5, f64::INFINITY)),
        ] {
            assert_eq!(result.unwrap_err().parameter, name);
        }
    }

    #[test]
    fn the_driven_levers_phase_is_a_pole_at_the_envelopes_rate() {
        // Q = 100, f0 = 100 kHz: 2Q/f0 = 2e-3 rad/Hz, τ_c = Q/(π·f0) = 318 µs.
        let plant = Plant::resonator(100.0, 1e5).unwrap();
        let Plant::Resonator {
            slope,
            time_constant,
        } = plant
        else {
            unreachable!()
        };
        assert!(close(slope, 2e-3, 1e-18));
        assert!(close(time_constant, 100.0 / (PI * 1e5), 1e-18));
        assert_eq!(plant.time_constant(), Some(time_constant));
        assert!(close(plant.response(1e-3).re, slope, 1e-12));
        let g = plant.response(1.0 / time_constant);
        assert!(close(g.arg().to_degrees(), -45.0, 1e-12));
        assert!(close(g.norm(), slope / 2f64.sqrt(), 1e-15));
        assert_eq!(Plant::resonator(100.0, 0.0).unwrap_err().parameter, "f0");
        assert_eq!(Plant::resonator(-1.0, 1e5).unwrap_err().parameter, "q");
    }

    #[test]
    fn bad_demodulator_settings_are_refused_naming_them() {
        for (name, result) in [
            ("order", Demodulator::new(0, 1e-3, 1e3, 0.0)),
            ("order", Demodulator::new(9, 1e-3, 1e3, 0.0)),
            ("time_constant", Demodulator::new(1, 0.0, 1e3, 0.0)),
            ("time_constant", Demodulator::new(1, -1e-3, 1e3, 0.0)),
            ("time_constant", Demodulator::new(1, f64::NAN, 1e3, 0.0)),
            ("output_rate", Demodulator::new(1, 1e-3, 0.0, 0.0)),
            ("dead_time", Demodulator::new(1, 1e-3, 1e3, -1e-6)),
            (
                "sample_rate",
                Demodulator::instrument(1, 1e-3, 1e3, f64::NAN),
            ),
        ] {
            let e = result.unwrap_err();
            assert_eq!(e.parameter, name);
            let text = e.to_string();
            assert!(text.contains(name) && text.contains("allowed"), "{text}");
        }
        assert!(
            Plant::amplitude(1.0, 0.0, 3e5)
                .unwrap_err()
                .to_string()
                .contains("q")
        );
    }
}
