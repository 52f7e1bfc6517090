//! The drive phasors the per-sample loop carries: e^{iθ} of `/drive` alone, or beside it
//! e^{iθ₂} of `/drive2` (bimodal AFM). The loop and the contact kernel are generic over
//! [`Phasors`], so a lever driven at one frequency compiles to exactly the arithmetic it
//! had before the second excitation existed, and one driven at two adds one complex
//! product a step and one per signal.

use rustfft::num_complex::Complex64;

/// One phasor per excitation, and the complex amplitudes of a signal on each.
pub(crate) trait Phasors: Copy {
    /// From the phasors (or amplitudes) of `/drive` and `/drive2`; a single drive keeps the
    /// first alone.
    fn new(one: Complex64, two: Complex64) -> Self;
    /// At phase words `one` and `two` (2^64 = one period), computed afresh: the loop's
    /// re-anchoring. A single drive computes the first alone.
    fn at(one: u64, two: u64) -> Self;
    /// Each phasor advanced by its `step`.
    fn times(self, step: Self) -> Self;
    /// The real signal Re Σ c_k·ρ_k of the amplitudes `c` (m, N, …) on each excitation.
    fn real(self, c: Self) -> f64;
    /// `/drive`'s phasor.
    fn first(self) -> Complex64;
    /// `/drive2`'s phasor, if it is carried.
    fn second(self) -> Option<Complex64>;
}

impl Phasors for Complex64 {
    #[inline(always)]
    fn new(one: Complex64, _: Complex64) -> Self {
        one
    }

    #[inline(always)]
    fn at(one: u64, _: u64) -> Self {
        Complex64::from_polar(1.0, crate::timebase::phase_to_radians(one))
    }

    #[inline(always)]
    fn times(self, step: Self) -> Self {
        self * step
    }

    #[inline(always)]
    fn real(self, c: Self) -> f64 {
        (c * self).re
    }

    #[inline(always)]
    fn first(self) -> Complex64 {
        self
    }

    #[inline(always)]
    fn second(self) -> Option<Complex64> {
        None
    }
}

/// The phasors of both excitations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Two(pub Complex64, pub Complex64);

impl Phasors for Two {
    #[inline(always)]
    fn new(one: Complex64, two: Complex64) -> Self {
        Two(one, two)
    }

    #[inline(always)]
    fn at(one: u64, two: u64) -> Self {
        Two(Complex64::at(one, 0), Complex64::at(two, 0))
    }

    #[inline(always)]
    fn times(self, step: Self) -> Self {
        Two(self.0 * step.0, self.1 * step.1)
    }

    #[inline(always)]
    fn real(self, c: Self) -> f64 {
        // Re(a·b) = a.re·b.re − a.im·b.im, the second tone's fused onto the first's.
        let one = (c.0 * self.0).re;
        c.1.re.mul_add(self.1.re, (-c.1.im).mul_add(self.1.im, one))
    }

    #[inline(always)]
    fn first(self) -> Complex64 {
        self.0
    }

    #[inline(always)]
    fn second(self) -> Option<Complex64> {
        Some(self.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_tones_sum_what_each_gives_alone() {
        let (a, b) = (Complex64::new(0.3, -1.2), Complex64::new(-2.0, 0.7));
        let (ra, rb) = (Complex64::at(1 << 61, 0), Complex64::at(3 << 60, 0));
        let two = Two(ra, rb).real(Two(a, b));
        let alone = ra.real(a) + rb.real(b);
        assert!((two - alone).abs() < 1e-15, "{two} against {alone}");
        let stepped = Two(ra, rb).times(Two(rb, ra));
        assert_eq!(stepped, Two(ra * rb, rb * ra));
        assert_eq!(<Complex64 as Phasors>::new(ra, rb), ra);
    }
}
