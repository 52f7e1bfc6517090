//! The lock-in low-pass filter: `order` identical first-order sections in cascade.

use super::DspError;

/// Highest filter order (number of cascaded first-order sections).
pub const MAX_ORDER: u32 = 8;

/// A cascade of `order` identical first-order low-pass sections with time constant τ,
/// sampled at `sample_rate`.
///
/// Each section is `y[m] = y[m−1] + α·(x[m] − y[m−1])` with `α = 1 − e^{−T/τ}`, T the
/// sample period: the exact (step-invariant) discretisation of an RC section. For a unit
/// step entering at sample 0, one section gives exactly `1 − e^{−(m+1)T/τ}` at sample m.
/// Each further section runs half a sample ahead of its analytic counterpart, so the
/// cascade's output at sample m is the analytic step response at `(m + 1 + (n−1)/2)·T`
/// up to O((T/τ)²).
///
/// This is the configuration (immutable); the state is a separate [`LowPassState`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LowPass {
    order: u32,
    time_constant: f64,
    sample_rate: f64,
    alpha: f64,
}

/// State of a [`LowPass`]: the output of each section.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LowPassState {
    sections: [f64; MAX_ORDER as usize],
}

impl LowPass {
    /// A filter of `order` (1–8) sections with time constant `time_constant` (s) each, for
    /// samples at `sample_rate` (Hz).
    pub fn new(order: u32, time_constant: f64, sample_rate: f64) -> Result<Self, DspError> {
        if !(1..=MAX_ORDER).contains(&order) {
            return Err(DspError::Order(order));
        }
        if !(time_constant.is_finite() && time_constant > 0.0) {
            return Err(DspError::TimeConstant(time_constant));
        }
        if !(sample_rate.is_finite() && sample_rate > 0.0) {
            return Err(DspError::SampleRate(sample_rate));
        }
        // -expm1 keeps α accurate when T/τ is tiny (α ~ 1e-6 would lose digits as 1 − exp).
        let alpha = -(-1.0 / (time_constant * sample_rate)).exp_m1();
        Ok(Self {
            order,
            time_constant,
            sample_rate,
            alpha,
        })
    }

    /// Number of first-order sections.
    pub const fn order(&self) -> u32 {
        self.order
    }

    /// Time constant τ of each section (s).
    pub const fn time_constant(&self) -> f64 {
        self.time_constant
    }

    /// Sample rate the filter runs at (Hz).
    pub const fn sample_rate(&self) -> f64 {
        self.sample_rate
    }

    /// Smoothing factor α = 1 − e^{−T/τ} of each section (1).
    pub const fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Filter one sample.
    #[inline]
    pub fn step(&self, state: &mut LowPassState, x: f64) -> f64 {
        let mut v = x;
        for y in &mut state.sections[..self.order as usize] {
            *y += self.alpha * (v - *y);
            v = *y;
        }
        v
    }

    /// Filter a block; `output` must be as long as `input`.
    pub fn process(&self, state: &mut LowPassState, input: &[f64], output: &mut [f64]) {
        assert_eq!(
            input.len(),
            output.len(),
            "LowPass::process: lengths differ"
        );
        for (x, y) in input.iter().zip(output) {
            *y = self.step(state, *x);
        }
    }

    /// Analytic step response of n cascaded RC sections at time `t` (s) after the step:
    /// `1 − e^{−t/τ} Σ_{j<n} (t/τ)^j / j!` (1; 0 before the step).
    pub fn step_response(&self, t: f64) -> f64 {
        step_response(self.order, t / self.time_constant)
    }

    /// Analytic magnitude response `(1 + (2πfτ)²)^{−n/2}` at `frequency` (Hz).
    pub fn magnitude(&self, frequency: f64) -> f64 {
        let w = std::f64::consts::TAU * frequency * self.time_constant;
        (1.0 + w * w).powf(-0.5 * self.order as f64)
    }

    /// Analytic one-sided equivalent noise bandwidth (Hz):
    /// `∫₀^∞ |H(f)|² df = Γ(n − ½) / (4√π τ Γ(n)) = C(2n−2, n−1) / (4^{n−1} · 4τ)`.
    pub fn enbw(&self) -> f64 {
        enbw(self.order, self.time_constant)
    }
}

/// Analytic step response of `order` cascaded RC sections at `t_over_tau` = t/τ.
pub fn step_response(order: u32, t_over_tau: f64) -> f64 {
    if t_over_tau <= 0.0 {
        return 0.0;
    }
    let mut term = 1.0;
    let mut sum = 0.0;
    for j in 0..order {
        if j > 0 {
            term *= t_over_tau / j as f64;
        }
        sum += term;
    }
    1.0 - (-t_over_tau).exp() * sum
}

/// Analytic one-sided equivalent noise bandwidth (Hz) of `order` cascaded RC sections with
/// time constant `time_constant` (s). Γ(n − ½)/(√π Γ(n)) is the central binomial
/// coefficient C(2n−2, n−1) over 4^{n−1}, computed as a product to stay exact.
pub fn enbw(order: u32, time_constant: f64) -> f64 {
    let mut ratio = 1.0;
    for j in 1..order {
        // Γ(j + ½)/Γ(j + 1) = Γ(j − ½)/Γ(j) · (j − ½)/j
        ratio *= (j as f64 - 0.5) / j as f64;
    }
    ratio / (4.0 * time_constant)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enbw_closed_form() {
        assert!((enbw(1, 1.0) - 0.25).abs() < 1e-15);
        assert!((enbw(2, 1.0) - 0.125).abs() < 1e-15);
        assert!((enbw(3, 1.0) - 3.0 / 32.0).abs() < 1e-15);
        assert!((enbw(4, 2.0) - 5.0 / 64.0 / 2.0).abs() < 1e-15);
    }

    #[test]
    fn first_order_is_exact_at_samples() {
        let lp = LowPass::new(1, 1e-3, 1e5).unwrap();
        let mut s = LowPassState::default();
        for m in 0..1000 {
            let y = lp.step(&mut s, 1.0);
            let t = (m + 1) as f64 / 1e5;
            assert!((y - lp.step_response(t)).abs() < 1e-13);
        }
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(LowPass::new(0, 1.0, 1.0).is_err());
        assert!(LowPass::new(9, 1.0, 1.0).is_err());
        assert!(LowPass::new(1, 0.0, 1.0).is_err());
        assert!(LowPass::new(1, 1.0, f64::INFINITY).is_err());
    }
}
