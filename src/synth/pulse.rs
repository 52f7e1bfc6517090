//! The paper engine's tip force: a cut-cosine pulse train locked to the drive phase,
//! integrated exactly over each sample interval (the pulse is only ~5 samples wide at the
//! default rate, so sampling it would distort the high harmonics).

use std::f64::consts::PI;

use rustfft::num_complex::Complex64;

use super::modal::ModalKernel;
use super::window::Moments;
use crate::physics::beam::MAX_MODES;
use crate::timebase::TWO_POW_64;

/// A cut-cosine pulse train, F·cos(π(t − t_c)/(τT)) for |t − t_c| < τT/2, once per period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PulseTrain {
    /// Peak force F (N).
    pub max_force: f64,
    /// Width as a fraction of the period, τ (1).
    pub tau: f64,
    /// Drive phase of the pulse centre (rad).
    pub centre_phase: f64,
}

/// The pulse train prepared for one sample rate and drive frequency.
#[derive(Clone, Debug)]
pub struct PulseKernel {
    max_force: f64,
    /// Phase word of the window start, t_c − τT/2.
    window_start: u64,
    /// Window length in phase words (τ·2^64).
    window_words: u64,
    /// Seconds per phase word at this drive frequency.
    seconds_per_word: f64,
    /// ν = π/(τT) (rad/s).
    nu: f64,
    h: f64,
    /// Per mode: 1/(−λ + iν) and 1/(−λ − iν).
    inverse_rates: Vec<(Complex64, Complex64)>,
    /// Per mode: e^{λh/2}, the propagator to the sample's midpoint.
    half_propagators: Vec<Complex64>,
    /// e^{iνh} and e^{iνh/2}: the pulse's phasor across a whole and a half sample, so a
    /// sample inside the pulse needs one sine and cosine, not two.
    rotation: Complex64,
    half_rotation: Complex64,
}

/// Where the pulse lies within one sample interval [t_n, t_n + h], in seconds from t_n.
#[derive(Clone, Copy, Debug)]
pub struct Overlap {
    /// Start of the overlap (s), ≥ 0.
    pub a: f64,
    /// End of the overlap (s), ≤ h.
    pub b: f64,
    /// Pulse centre relative to t_n (s).
    pub centre: f64,
}

/// The pulse's phasor e^{iν(s − centre)} at the overlap's start `a`, at its end `b` and,
/// where the overlap spans the sample's midpoint, at the midpoint: the sines and cosines
/// every integral over the sample shares, each computed once (inside a pulse, rotated from
/// the start's rather than computed).
#[derive(Clone, Copy, Debug)]
pub struct Phasors {
    pub a: Complex64,
    pub b: Complex64,
    pub half: Complex64,
}

impl PulseKernel {
    /// Prepares `train` for sample period `h` (s), a drive advancing `frequency_word` phase
    /// words per sample, and the given modes.
    pub fn new(train: &PulseTrain, h: f64, frequency_word: u64, modes: &[ModalKernel]) -> Self {
        let mut kernel = Self::idle(h);
        kernel.retune(train, h, frequency_word, modes);
        kernel
    }

    /// A kernel that applies no force, with room for [`MAX_MODES`] modes so that
    /// [`retune`](Self::retune) never allocates.
    pub fn idle(h: f64) -> Self {
        Self {
            max_force: 0.0,
            window_start: 0,
            window_words: 0,
            seconds_per_word: 0.0,
            nu: 0.0,
            h,
            inverse_rates: Vec::with_capacity(MAX_MODES),
            half_propagators: Vec::with_capacity(MAX_MODES),
            rotation: Complex64::new(1.0, 0.0),
            half_rotation: Complex64::new(1.0, 0.0),
        }
    }

    /// Re-prepares the kernel for another pulse train, in place: allocation-free when
    /// `modes` are no more than the kernel was built with room for (always, for
    /// [`idle`](Self::idle) kernels). Call it between pulses, not inside one.
    pub fn retune(
        &mut self,
        train: &PulseTrain,
        h: f64,
        frequency_word: u64,
        modes: &[ModalKernel],
    ) {
        let tau = train.tau.clamp(0.0, 1.0);
        let window_words = (tau * TWO_POW_64).min(TWO_POW_64 - 1.0) as u64;
        let centre = (train.centre_phase / (2.0 * PI)).rem_euclid(1.0) * TWO_POW_64;
        self.window_start = (centre as u64).wrapping_sub(window_words / 2);
        self.window_words = window_words;
        self.seconds_per_word = h / frequency_word.max(1) as f64;
        let period = TWO_POW_64 * self.seconds_per_word;
        self.nu = if tau > 0.0 { PI / (tau * period) } else { 0.0 };
        self.h = h;
        self.max_force = if tau > 0.0 { train.max_force } else { 0.0 };
        self.rotation = Complex64::from_polar(1.0, self.nu * h);
        self.half_rotation = Complex64::from_polar(1.0, 0.5 * self.nu * h);
        self.inverse_rates.clear();
        self.half_propagators.clear();
        let i_nu = Complex64::new(0.0, self.nu);
        for m in modes {
            self.inverse_rates
                .push(((-m.lambda + i_nu).inv(), (-m.lambda - i_nu).inv()));
            self.half_propagators.push((m.lambda * (0.5 * h)).exp());
        }
    }

    /// The part of the pulse in the sample interval starting at drive phase word `phase`
    /// and advancing `step` words, if any.
    #[inline]
    pub fn overlap(&self, phase: u64, step: u64) -> Option<Overlap> {
        if self.max_force == 0.0 {
            return None;
        }
        let rel = phase.wrapping_sub(self.window_start);
        // Window start relative to t_n, in words: −rel if the interval starts inside the
        // window, or the distance ahead if the window starts within this interval.
        let start_words = if rel < self.window_words {
            -(rel as f64)
        } else {
            let ahead = rel.wrapping_neg();
            if ahead >= step {
                return None;
            }
            ahead as f64
        };
        let ws = start_words * self.seconds_per_word;
        let we = ws + self.window_words as f64 * self.seconds_per_word;
        let a = ws.max(0.0);
        let b = we.min(self.h);
        if b <= a {
            return None;
        }
        Some(Overlap {
            a,
            b,
            centre: 0.5 * (ws + we),
        })
    }

    /// The phasors of `overlap` ([`Phasors`]).
    #[inline]
    pub fn phasors(&self, overlap: &Overlap) -> Phasors {
        let Overlap { a, b, centre } = *overlap;
        let half = 0.5 * self.h;
        let ca = Complex64::from_polar(1.0, self.nu * (a - centre));
        let cb = if a <= 0.0 && b >= self.h {
            ca * self.rotation
        } else {
            Complex64::from_polar(1.0, self.nu * (b - centre))
        };
        let ch = if a >= half || b <= half {
            // Not spanned: the midpoint's phasor is never read.
            Complex64::new(1.0, 0.0)
        } else if a <= 0.0 {
            ca * self.half_rotation
        } else {
            Complex64::from_polar(1.0, self.nu * (half - centre))
        };
        Phasors {
            a: ca,
            b: cb,
            half: ch,
        }
    }

    /// Adds to `re`, `im` the exact response at the sample's midpoint h/2 to the part of
    /// the pulse in `overlap` ∩ [0, h/2]: F·gain·∫ e^{λ(h/2−s)}·cos(ν(s − centre)) ds. The
    /// synthesiser reads the midpoint for the ADC's filter with it. `p`: the overlap's
    /// [`phasors`](Self::phasors).
    #[inline]
    pub fn apply_to_midpoint(
        &self,
        overlap: &Overlap,
        p: &Phasors,
        modes: &[ModalKernel],
        re: &mut [f64],
        im: &mut [f64],
    ) {
        let end = 0.5 * self.h;
        let a = overlap.a;
        let b = overlap.b.min(end);
        if b <= a {
            return;
        }
        let ca = p.a;
        let cb = if overlap.b > end { p.half } else { p.b };
        for ((((m, re), im), (inv_plus, inv_minus)), half) in modes
            .iter()
            .zip(re.iter_mut())
            .zip(im.iter_mut())
            .zip(&self.inverse_rates)
            .zip(&self.half_propagators)
        {
            // The constants 1 and e^{λh/2} at the half's ends (inside a pulse), else computed.
            let e_b = if b >= end {
                Complex64::new(1.0, 0.0)
            } else {
                (m.lambda * (end - b)).exp()
            };
            let e_a = if a <= 0.0 {
                *half
            } else {
                (m.lambda * (end - a)).exp()
            };
            let plus = (e_b * cb - e_a * ca) * inv_plus;
            let minus = (e_b * cb.conj() - e_a * ca.conj()) * inv_minus;
            let dq = (plus + minus) * (0.5 * self.max_force * m.force_gain);
            *re += dq.re;
            *im += dq.im;
        }
    }

    /// The force's moments over the sample's halves ([`Moments`], N·s and N·s²): the
    /// integrals of F·cos(ν(s − centre)) and of s times it over `overlap` ∩ [0, h/2) and
    /// ∩ [h/2, h], in closed form, for the ADC's window.
    #[inline]
    pub fn moments(&self, overlap: &Overlap, p: &Phasors) -> Moments {
        let half = 0.5 * self.h;
        let (nu, f) = (self.nu, self.max_force);
        // ∫ cos(ν(s − c)) = sin(ν(s − c))/ν; ∫ s·cos(ν(s − c)) = s·sin(…)/ν + cos(…)/ν².
        let over = |x0: f64, p0: Complex64, x1: f64, p1: Complex64| -> (f64, f64) {
            if x1 <= x0 {
                return (0.0, 0.0);
            }
            let first = (p1.im - p0.im) / nu;
            let second = (x1 * p1.im - x0 * p0.im) / nu + (p1.re - p0.re) / (nu * nu);
            (f * first, f * second)
        };
        let Overlap { a, b, .. } = *overlap;
        let (s1, t1, s2, t2) = if b <= half {
            let (s1, t1) = over(a, p.a, b, p.b);
            (s1, t1, 0.0, 0.0)
        } else if a >= half {
            let (s2, t2) = over(a, p.a, b, p.b);
            (0.0, 0.0, s2, t2)
        } else {
            let (s1, t1) = over(a, p.a, half, p.half);
            let (s2, t2) = over(half, p.half, b, p.b);
            (s1, t1, s2, t2)
        };
        Moments { s1, t1, s2, t2 }
    }

    /// Adds to the modal states (`re`, `im`: real and imaginary parts of q, one per mode)
    /// the exact response to the pulse over `overlap`:
    /// F·gain·∫_a^b e^{λ(h−s)}·cos(ν(s − centre)) ds for each mode.
    #[inline]
    pub fn apply(
        &self,
        overlap: &Overlap,
        p: &Phasors,
        modes: &[ModalKernel],
        re: &mut [f64],
        im: &mut [f64],
    ) {
        let Overlap { a, b, .. } = *overlap;
        let (ca, cb) = (p.a, p.b);
        for (((m, re), im), (inv_plus, inv_minus)) in modes
            .iter()
            .zip(re.iter_mut())
            .zip(im.iter_mut())
            .zip(&self.inverse_rates)
        {
            // e^{λ(h−x)}: the constants 1 and e^{λh} at the interval ends, else computed.
            let e_b = if b >= self.h {
                Complex64::new(1.0, 0.0)
            } else {
                (m.lambda * (self.h - b)).exp()
            };
            let e_a = if a <= 0.0 {
                m.propagator
            } else {
                (m.lambda * (self.h - a)).exp()
            };
            let plus = (e_b * cb - e_a * ca) * inv_plus;
            let minus = (e_b * cb.conj() - e_a * ca.conj()) * inv_minus;
            let dq = (plus + minus) * (0.5 * self.max_force * m.force_gain);
            *re += dq.re;
            *im += dq.im;
        }
    }
}
