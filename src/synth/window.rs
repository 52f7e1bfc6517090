//! The ADC's integrating front end: each sample the converter takes at 2·f_s is the
//! photodiode signal averaged over a triangle window of half-width a = h/2 centred on it,
//! as a sigma-delta modulator's second-order sinc (CIC) decimator to 2·f_s gives. Its gain
//! sinc²(f·a) is zero at every multiple of 2·f_s, so what folds onto the passband when the
//! 2·f_s samples are taken (content near 2·f_s, 4·f_s, …) is attenuated by it:
//! content at 2·f_s ± 0.3·f_s by ≥ 27×.
//!
//! The window's integral is exact without integrating anything on the real-time thread.
//! A mode `Ÿ + 2γωẎ + ω²Y = u` multiplied by the window w(t) = (a − |t − c|)/a² and
//! integrated by parts twice gives (the ends of w are zero; its kinks are at the knots
//! c − a, c, c + a):
//!
//! ∫wY = ((4γ² − 1)/(a²ω²))·Δ²Y + (2γ/(a²ω³))·Δ²Ẏ + (1/ω²)·∫wu − (2γ/(a²ω³))·(U₊ − U₋)
//!
//! with Δ² the second difference over the three knots and U₋, U₊ the integrals of u over
//! the window's halves. So a windowed sample is a fixed functional of the modal states at
//! three consecutive half samples (the grid samples and midpoints the synthesiser already
//! computes) plus moments of the input over each half sample: the held thermal input in
//! closed form, the paper engine's pulse in closed form, the coupled engine's kicks summed
//! as it applies them. A kick exactly at a knot belongs to the side on which the knot's
//! state does not yet hold it (the state at a knot is taken between the kicks there).

use rustfft::num_complex::Complex64;

use super::modal::ModalKernel;

/// The window's gain at `frequency` f/f_s: sinc²(f/2), zero at every multiple of 2·f_s.
pub fn gain(frequency: f64) -> f64 {
    let x = std::f64::consts::FRAC_PI_2 * frequency;
    if x.abs() < 1e-8 {
        return 1.0;
    }
    let s = x.sin() / x;
    s * s
}

/// One mode's constants of the window, for a sample period `h`: the knot functional on
/// the mode's q and the weights of its input's moments, in photodiode metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModeWindow {
    /// Knot functional κ(q) = `knot_re`·Re q + `knot_im`·Im q (m per unit of q).
    pub knot_re: f64,
    pub knot_im: f64,
    /// Weight of ∫wu (m/s² for an acceleration input): L/ω² (s²; L the light-lever
    /// factor, photodiode metres per metre of Y).
    pub alpha: f64,
    /// Weight of U₊ − U₋ (m/s): −2γL/(a²ω³) (s).
    pub beta: f64,
}

impl ModeWindow {
    /// The window's constants for mode `k` sampled every `h` seconds.
    pub fn new(k: &ModalKernel, h: f64) -> Self {
        let a = 0.5 * h;
        let omega2 = k.lambda.norm_sqr();
        let omega = omega2.sqrt();
        let gamma = k.decay / omega;
        // Photodiode metres per metre of Y: lever_gain is per unit of Im q = ω_d·Y.
        let lever = k.lever_gain * k.omega_d;
        let p = (4.0 * gamma * gamma - 1.0) / (a * a * omega2);
        let r = 2.0 * gamma / (a * a * omega2 * omega);
        // κ = L·(p·Y + r·Ẏ) with Y = Im q/ω_d and Ẏ = Re q − γω·Y.
        Self {
            knot_re: lever * r,
            knot_im: lever * (p - r * k.decay) / k.omega_d,
            alpha: lever / omega2,
            beta: -lever * r,
        }
    }

    /// κ(q): this mode's part of a knot's value (m).
    pub fn knot(&self, q: Complex64) -> f64 {
        self.knot_re * q.re + self.knot_im * q.im
    }

    /// The functional q ↦ κ(c·q) as its weights on Re q and Im q.
    pub fn of(&self, c: Complex64) -> (f64, f64) {
        (
            self.knot_re * c.re + self.knot_im * c.im,
            self.knot_im * c.re - self.knot_re * c.im,
        )
    }
}

/// Moments of an input (a force, N, or a mode's acceleration, m/s²) over one sample
/// [0, h]: over the first half [0, a) its integral `s1` and first moment `t1` = ∫s·u ds,
/// over the second half [a, h] `s2` and `t2` (s from the sample's start).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Moments {
    pub s1: f64,
    pub t1: f64,
    pub s2: f64,
    pub t2: f64,
}

impl Moments {
    /// An input `u` held over the whole sample of length `h`.
    pub fn held(u: f64, h: f64) -> Self {
        let a = 0.5 * h;
        Self {
            s1: u * a,
            t1: u * 0.5 * a * a,
            s2: u * a,
            t2: u * 1.5 * a * a,
        }
    }

    /// An impulse `impulse` at `s` seconds into the sample, in its second half if
    /// `second` (a kick at the midpoint is: the midpoint's state is taken before it).
    #[inline(always)]
    pub fn kick(&mut self, impulse: f64, s: f64, second: bool) {
        if second {
            self.s2 += impulse;
            self.t2 += impulse * s;
        } else {
            self.s1 += impulse;
            self.t1 += impulse * s;
        }
    }

    /// What this sample's input adds to the three windows it touches, for input weights
    /// `alpha` and `beta` (summed over the modes it drives): (the window centred on the
    /// sample's start, the one on its midpoint, the one on its end).
    #[inline(always)]
    pub fn weigh(&self, alpha: f64, beta: f64, h: f64) -> (f64, f64, f64) {
        let a = 0.5 * h;
        let inv_a2 = 1.0 / (a * a);
        let start = alpha * (a * self.s1 - self.t1) * inv_a2 + beta * self.s1;
        let mid = alpha * (self.t1 + h * self.s2 - self.t2) * inv_a2 + beta * (self.s2 - self.s1);
        let end = alpha * (self.t2 - a * self.s2) * inv_a2 - beta * self.s2;
        (start, mid, end)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::Cantilever;

    /// Y(t) of a mode from state `q0` at t = 0 under input `u` held from then on.
    fn free(k: &ModalKernel, q0: Complex64, u: f64, t: f64) -> Complex64 {
        let e = (k.lambda * t).exp();
        e * q0 + u * (e - 1.0) / k.lambda
    }

    /// ∫w·L·Y over the window [c − a, c + a] by composite Simpson on `n` intervals of a
    /// trajectory given as a function of time.
    fn simpson(k: &ModalKernel, a: f64, q: impl Fn(f64) -> Complex64, n: usize) -> f64 {
        let lever = k.lever_gain * k.omega_d;
        let dt = 2.0 * a / n as f64;
        let f = |j: usize| {
            let t = -a + j as f64 * dt;
            let w = (a - t.abs()) / (a * a);
            w * lever * q(t).im / k.omega_d
        };
        let mut s = f(0) + f(n);
        for j in 1..n {
            s += if j % 2 == 1 { 4.0 } else { 2.0 } * f(j);
        }
        s * dt / 3.0
    }

    #[test]
    fn the_knot_functional_and_the_input_moments_give_the_window_integral() {
        // Every mode of a 300 kHz lever at 25 MS/s and of the default at 10 MS/s, a state
        // and held inputs either side of the centre, plus a kick inside: the formula
        // against Simpson's rule on 20 000 intervals of the exact trajectory.
        for (f1, k_n, fs) in [(300e3, 40.0, 25e6), (100e3, 20.0, 10e6)] {
            let c = Cantilever::new(f1, k_n, &[400.0, 500.0, 600.0, 700.0, 800.0], 0).unwrap();
            let h = 1.0 / fs;
            let a = 0.5 * h;
            for mode in &c.modes {
                let k = ModalKernel::new(mode, h);
                let win = ModeWindow::new(&k, h);
                let q0 = Complex64::new(3e-3, 2e-4) * k.omega_d.max(1.0) * 1e-9;
                let (u_left, u_right) = (7e3 * mode.omega / c.modes[0].omega, -4e3);
                let (impulse, at) = (5e-3, 0.3 * a);
                // Exact trajectory: back from the centre under u_left, on under u_right
                // with a kick (a jump of Re q) at `at`.
                let back = |t: f64| {
                    // q(c) = e^{λ|t|}·q(t) + u(e^{λ|t|} − 1)/λ, solved for q(t).
                    let e = (k.lambda * -t).exp();
                    (q0 - u_left * (e - 1.0) / k.lambda) / e
                };
                let q = |t: f64| {
                    if t < 0.0 {
                        back(t)
                    } else if t < at {
                        free(&k, q0, u_right, t)
                    } else {
                        let before = free(&k, q0, u_right, at);
                        free(&k, before + impulse, u_right, t - at)
                    }
                };
                let reference = simpson(&k, a, q, 20_000);
                let knots = win.knot(q(-a)) - 2.0 * win.knot(q(0.0)) + win.knot(q(a));
                // The left half is the end half of a sample held at u_left; the right half
                // the start half of one held at u_right with the kick.
                let mut right = Moments::held(u_right, h);
                right.kick(impulse, at, false);
                let left = Moments::held(u_left, h);
                let (start, _, _) = right.weigh(win.alpha, win.beta, h);
                let (_, _, end) = left.weigh(win.alpha, win.beta, h);
                let formula = knots + start + end;
                let scale = reference.abs().max(win.knot(q0).abs() * 1e-3);
                assert!(
                    (formula - reference).abs() < 1e-9 * scale,
                    "mode {} at {fs}: {formula:e} vs {reference:e}",
                    mode.n
                );
            }
        }
    }

    #[test]
    fn the_midpoint_window_of_a_held_sample_is_exact() {
        let c = Cantilever::new(100e3, 20.0, &[400.0, 500.0, 600.0], 0).unwrap();
        let h = 1e-7;
        for mode in &c.modes {
            let k = ModalKernel::new(mode, h);
            let win = ModeWindow::new(&k, h);
            let q0 = Complex64::new(-1e-3, 5e-4) * k.omega_d * 1e-9;
            let u = 2e4;
            // The window centred on the midpoint spans the sample [0, h].
            let q = |t: f64| free(&k, q0, u, t + 0.5 * h);
            let reference = simpson(&k, 0.5 * h, q, 20_000);
            let knots = win.knot(q(-0.5 * h)) - 2.0 * win.knot(q(0.0)) + win.knot(q(0.5 * h));
            let (_, mid, _) = Moments::held(u, h).weigh(win.alpha, win.beta, h);
            let scale = reference.abs().max(1e-3 * win.knot(q0).abs());
            assert!(
                (knots + mid - reference).abs() < 1e-9 * scale,
                "mode {}",
                mode.n
            );
        }
    }

    #[test]
    fn the_gain_is_sinc_squared() {
        assert_eq!(gain(0.0), 1.0);
        assert!(gain(2.0).abs() < 1e-30);
        assert!((gain(1.0) - 4.0 / (std::f64::consts::PI * std::f64::consts::PI)).abs() < 1e-15);
    }
}
