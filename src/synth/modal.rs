//! One flexural mode as an exactly discretised oscillator.
//!
//! Mode n obeys `Ÿ + 2γωẎ + ω²Y = u(t)` with `u = ω²·Fn/Kn`. With λ = −γω + iω_d and the
//! complex coordinate `q = Ẏ − λ̄Y` this is `q̇ = λq + u`, so over one sample
//! `q[n+1] = e^{λh}·q[n] + ∫₀ʰ e^{λ(h−s)} u(t_n + s) ds` — exact for any input whose
//! integral we can evaluate exactly (the cut-cosine pulse, sinusoids, piecewise-constant
//! noise). `Y = Im q / ω_d` and `Ẏ = Re q − γωY`.

use rustfft::num_complex::Complex64;

use crate::physics::Mode;

/// Per-mode constants of the discretisation at sample period `h`, all SI.
#[derive(Clone, Debug)]
pub struct ModalKernel {
    /// λ = −γω + iω_d (1/s).
    pub lambda: Complex64,
    /// e^{λh}: the one-sample propagator (1).
    pub propagator: Complex64,
    /// ω_d = ω√(1 − γ²) (rad/s).
    pub omega_d: f64,
    /// γω (1/s).
    pub decay: f64,
    /// u per newton of tip force: ω²·φn(L)/Kn (1/(kg)).
    pub force_gain: f64,
    /// Photodiode metres per unit of Im q: (2/3)·L·φn′(L)/ω_d (s).
    pub lever_gain: f64,
    /// Tip metres per unit of Im q: φn(L)/ω_d (s).
    pub tip_gain: f64,
    /// ∫₀ʰ e^{λ(h−s)} ds: response of q to a unit input held over one sample (s).
    pub hold_gain: Complex64,
}

impl ModalKernel {
    /// Kernel of `mode` sampled every `h` seconds.
    pub fn new(mode: &Mode, h: f64) -> Self {
        let omega_d = mode.omega * (1.0 - mode.gamma * mode.gamma).sqrt();
        let decay = mode.gamma * mode.omega;
        let lambda = Complex64::new(-decay, omega_d);
        let propagator = (lambda * h).exp();
        Self {
            lambda,
            propagator,
            omega_d,
            decay,
            force_gain: mode.omega * mode.omega * mode.tip_value / mode.stiffness,
            lever_gain: (2.0 / 3.0) * mode.tip_slope / omega_d,
            tip_gain: mode.tip_value / omega_d,
            hold_gain: (propagator - 1.0) / lambda,
        }
    }

    /// Modal displacement Y (m) and velocity Ẏ (m/s) of state `q`.
    #[inline]
    pub fn displacement_velocity(&self, q: Complex64) -> (f64, f64) {
        let y = q.im / self.omega_d;
        (y, q.re - self.decay * y)
    }

    /// State q of displacement `y` (m) and velocity `v` (m/s).
    #[inline]
    pub fn state_of(&self, y: f64, v: f64) -> Complex64 {
        // q = Ẏ − λ̄Y, λ̄ = −γω − iω_d.
        Complex64::new(v + self.decay * y, self.omega_d * y)
    }

    /// Stationary variance of Im q per unit variance of a held (piecewise-constant) input:
    /// Σ_j Im(e^{jλh}·g)² = ½(|g|²/(1 − |e^{λh}|²) − Re(g²/(1 − e^{2λh}))).
    pub fn held_noise_gain(&self) -> f64 {
        let a = self.propagator;
        let g = self.hold_gain;
        0.5 * (g.norm_sqr() / (1.0 - a.norm_sqr()) - (g * g / (1.0 - a * a)).re)
    }
}

/// Σ p[m] over `L` lanes (a power of two), added pairwise: independent additions the
/// compiler keeps in vector registers, where a running sum would be a serial chain of `L`
/// dependent additions in every sample of the hot loop.
#[inline(always)]
pub(crate) fn lane_sum<const L: usize>(mut p: [f64; L]) -> f64 {
    let mut width = L;
    while width > 1 {
        width /= 2;
        for m in 0..width {
            p[m] += p[m + width];
        }
    }
    p[0]
}
