//! The mode lanes as one value, for the synthesiser's loop: with up to eight modes, one
//! AVX-512 register where the CPU has it ([`Avx512x8`]), two AVX2 registers where it has
//! those ([`Avx8`]), an array otherwise; with more modes, an array of all lanes
//! ([`Portable`]). Written out, the loop's lanes stay in registers; as arrays indexed in a
//! large loop body the compiler had assembled them lane by lane (about half as many
//! instructions per sample again).
//!
//! All do the same IEEE operations in the same order, lane by lane, and reduce in the
//! same tree as [`lane_sum`](super::modal::lane_sum) (for eight lanes: lane m with m + 4,
//! then with m + 2, then the two), so every build gives the same bits.

/// A fixed number of `f64` lanes.
pub(crate) trait Lanes: Copy {
    /// The first lanes' worth of `a` (at least that long).
    fn load(a: &[f64]) -> Self;
    /// The first lanes' worth of `a`, widened to `f64` (exact).
    fn load_f32(a: &[f32]) -> Self;
    /// Writes the lanes to the first lanes' worth of `a`.
    fn store(self, a: &mut [f64]);
    /// Every lane `x`.
    fn splat(x: f64) -> Self;
    fn add(self, other: Self) -> Self;
    fn sub(self, other: Self) -> Self;
    fn mul(self, other: Self) -> Self;
    /// `self·a + b`, rounded once.
    fn mul_add(self, a: Self, b: Self) -> Self;
    /// `b − self·a`, rounded once.
    fn neg_mul_add(self, a: Self, b: Self) -> Self;
    /// The sum, in [`lane_sum`](super::modal::lane_sum)'s tree.
    fn sum(self) -> f64;
    /// The sums of `self` and `other`, each as [`sum`](Self::sum) (the same bits): for
    /// two read-outs of one sample, which the vector kinds reduce side by side.
    #[inline(always)]
    fn sum2(self, other: Self) -> (f64, f64) {
        (self.sum(), other.sum())
    }
}

/// `L` lanes in an array (`L` a power of two): for CPUs without AVX2, and for more than
/// eight modes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Portable<const L: usize>([f64; L]);

impl<const L: usize> Lanes for Portable<L> {
    #[inline(always)]
    fn load(a: &[f64]) -> Self {
        Self(a[..L].try_into().expect("L lanes"))
    }
    #[inline(always)]
    fn load_f32(a: &[f32]) -> Self {
        let a = &a[..L];
        Self(std::array::from_fn(|m| f64::from(a[m])))
    }
    #[inline(always)]
    fn store(self, a: &mut [f64]) {
        a[..L].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn splat(x: f64) -> Self {
        Self([x; L])
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self(std::array::from_fn(|m| self.0[m] + o.0[m]))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Self(std::array::from_fn(|m| self.0[m] - o.0[m]))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self(std::array::from_fn(|m| self.0[m] * o.0[m]))
    }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|m| self.0[m].mul_add(a.0[m], b.0[m])))
    }
    #[inline(always)]
    fn neg_mul_add(self, a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|m| {
            (-self.0[m]).mul_add(a.0[m], b.0[m])
        }))
    }
    #[inline(always)]
    fn sum(self) -> f64 {
        super::modal::lane_sum(self.0)
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx::{Avx8, Avx512x8};

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::Lanes;
    use std::arch::x86_64::*;

    /// Eight lanes in two AVX registers: lanes 0–3 and 4–7. Only made inside code
    /// compiled for AVX2 on a CPU that has it (the synthesiser's `process_avx2`), where
    /// these functions are inlined.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx8(__m256d, __m256d);

    // SAFETY (every `unsafe` below): an `Avx8` exists only on a CPU with AVX2 (see the
    // type's documentation); loads and stores touch eight f64 (or f32) that their bounds
    // checks guarantee.
    impl Lanes for Avx8 {
        #[inline(always)]
        fn load(a: &[f64]) -> Self {
            let a = &a[..8];
            unsafe {
                Self(
                    _mm256_loadu_pd(a.as_ptr()),
                    _mm256_loadu_pd(a.as_ptr().add(4)),
                )
            }
        }
        #[inline(always)]
        fn load_f32(a: &[f32]) -> Self {
            let a = &a[..8];
            unsafe {
                let x = _mm256_loadu_ps(a.as_ptr());
                Self(
                    _mm256_cvtps_pd(_mm256_castps256_ps128(x)),
                    _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(x)),
                )
            }
        }
        #[inline(always)]
        fn store(self, a: &mut [f64]) {
            let a = &mut a[..8];
            unsafe {
                _mm256_storeu_pd(a.as_mut_ptr(), self.0);
                _mm256_storeu_pd(a.as_mut_ptr().add(4), self.1);
            }
        }
        #[inline(always)]
        fn splat(x: f64) -> Self {
            unsafe { Self(_mm256_set1_pd(x), _mm256_set1_pd(x)) }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Self(_mm256_add_pd(self.0, o.0), _mm256_add_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Self(_mm256_sub_pd(self.0, o.0), _mm256_sub_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Self(_mm256_mul_pd(self.0, o.0), _mm256_mul_pd(self.1, o.1)) }
        }
        #[inline(always)]
        fn mul_add(self, a: Self, b: Self) -> Self {
            unsafe {
                Self(
                    _mm256_fmadd_pd(self.0, a.0, b.0),
                    _mm256_fmadd_pd(self.1, a.1, b.1),
                )
            }
        }
        #[inline(always)]
        fn neg_mul_add(self, a: Self, b: Self) -> Self {
            unsafe {
                Self(
                    _mm256_fnmadd_pd(self.0, a.0, b.0),
                    _mm256_fnmadd_pd(self.1, a.1, b.1),
                )
            }
        }
        #[inline(always)]
        fn sum(self) -> f64 {
            unsafe {
                let s = _mm256_add_pd(self.0, self.1);
                let t = _mm_add_pd(_mm256_castpd256_pd128(s), _mm256_extractf128_pd::<1>(s));
                _mm_cvtsd_f64(t) + _mm_cvtsd_f64(_mm_unpackhi_pd(t, t))
            }
        }
        #[inline(always)]
        fn sum2(self, other: Self) -> (f64, f64) {
            unsafe {
                sum2_halves(
                    _mm256_add_pd(self.0, self.1),
                    _mm256_add_pd(other.0, other.1),
                )
            }
        }
    }

    /// The two sums of `s` and `t`, four lanes each, finished in `lane_sum`'s tree (lane m
    /// with m + 2, then the two) side by side: the halves of both in one register, added,
    /// then each pair with its neighbour.
    ///
    /// # Safety
    /// The CPU must have AVX.
    #[inline(always)]
    unsafe fn sum2_halves(s: __m256d, t: __m256d) -> (f64, f64) {
        unsafe {
            // [s0 + s2, s1 + s3, t0 + t2, t1 + t3].
            let u = _mm256_add_pd(
                _mm256_permute2f128_pd::<0x20>(s, t),
                _mm256_permute2f128_pd::<0x31>(s, t),
            );
            let v = _mm256_add_pd(u, _mm256_permute_pd::<0b0101>(u));
            (
                _mm256_cvtsd_f64(v),
                _mm_cvtsd_f64(_mm256_extractf128_pd::<1>(v)),
            )
        }
    }
    /// Eight lanes in one AVX-512 register. Only made inside code compiled for AVX-512
    /// on a CPU that has it (the synthesiser's `process_avx512`), where these functions
    /// are inlined.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx512x8(__m512d);

    // SAFETY (every `unsafe` below): an `Avx512x8` exists only on a CPU with AVX-512F and
    // AVX2; loads and stores touch eight f64 (or f32) that their bounds checks guarantee.
    impl Lanes for Avx512x8 {
        #[inline(always)]
        fn load(a: &[f64]) -> Self {
            let a = &a[..8];
            unsafe { Self(_mm512_loadu_pd(a.as_ptr())) }
        }
        #[inline(always)]
        fn load_f32(a: &[f32]) -> Self {
            let a = &a[..8];
            unsafe { Self(_mm512_cvtps_pd(_mm256_loadu_ps(a.as_ptr()))) }
        }
        #[inline(always)]
        fn store(self, a: &mut [f64]) {
            let a = &mut a[..8];
            unsafe { _mm512_storeu_pd(a.as_mut_ptr(), self.0) };
        }
        #[inline(always)]
        fn splat(x: f64) -> Self {
            unsafe { Self(_mm512_set1_pd(x)) }
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Self(_mm512_add_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Self(_mm512_sub_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Self(_mm512_mul_pd(self.0, o.0)) }
        }
        #[inline(always)]
        fn mul_add(self, a: Self, b: Self) -> Self {
            unsafe { Self(_mm512_fmadd_pd(self.0, a.0, b.0)) }
        }
        #[inline(always)]
        fn neg_mul_add(self, a: Self, b: Self) -> Self {
            unsafe { Self(_mm512_fnmadd_pd(self.0, a.0, b.0)) }
        }
        #[inline(always)]
        fn sum(self) -> f64 {
            unsafe {
                let s = _mm256_add_pd(
                    _mm512_castpd512_pd256(self.0),
                    _mm512_extractf64x4_pd::<1>(self.0),
                );
                let t = _mm_add_pd(_mm256_castpd256_pd128(s), _mm256_extractf128_pd::<1>(s));
                _mm_cvtsd_f64(t) + _mm_cvtsd_f64(_mm_unpackhi_pd(t, t))
            }
        }
        #[inline(always)]
        fn sum2(self, other: Self) -> (f64, f64) {
            let half = |x: __m512d| unsafe {
                _mm256_add_pd(_mm512_castpd512_pd256(x), _mm512_extractf64x4_pd::<1>(x))
            };
            unsafe { sum2_halves(half(self.0), half(other.0)) }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn array(x: impl Lanes) -> [f64; 8] {
        let mut a = [0.0; 8];
        x.store(&mut a);
        a
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx_ops(a: &[f64], b: &[f64]) -> ([[f64; 8]; 3], f64) {
        let (x, y) = (Avx8::load(a), Avx8::load(b));
        (
            [array(x.add(y)), array(x.sub(y)), array(x.mul(y))],
            x.mul(y).add(Avx8::splat(0.1)).sum(),
        )
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx_sum2(a: &[f64], b: &[f64]) -> (f64, f64) {
        Avx8::load(a).sum2(Avx8::load(b))
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    fn avx512_sum2(a: &[f64], b: &[f64]) -> (f64, f64) {
        Avx512x8::load(a).sum2(Avx512x8::load(b))
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    fn avx512_ops(a: &[f64], b: &[f64]) -> ([[f64; 8]; 3], f64) {
        let (x, y) = (Avx512x8::load(a), Avx512x8::load(b));
        (
            [array(x.add(y)), array(x.sub(y)), array(x.mul(y))],
            x.mul(y).add(Avx512x8::splat(0.1)).sum(),
        )
    }

    /// All kinds give the same bits, and the sum is `lane_sum`'s.
    #[test]
    fn the_avx_lanes_are_the_portable_lanes() {
        let a: Vec<f64> = (0..8)
            .map(|m| (m as f64 * 0.77 + 0.1).sin() * 1e-9)
            .collect();
        let b: Vec<f64> = (0..8).map(|m| (m as f64 * 1.31).cos() * 3e7).collect();
        let (x, y) = (Portable::<8>::load(&a), Portable::<8>::load(&b));
        let portable = (
            [array(x.add(y)), array(x.sub(y)), array(x.mul(y))],
            x.mul(y).add(Portable::<8>::splat(0.1)).sum(),
        );
        let p: [f64; 8] = std::array::from_fn(|m| a[m] * b[m] + 0.1);
        assert_eq!(
            portable.1.to_bits(),
            super::super::modal::lane_sum(p).to_bits()
        );
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::avx2_available() {
            // SAFETY: the CPU has AVX2.
            let fast = unsafe { avx_ops(&a, &b) };
            assert_eq!(fast.0, portable.0);
            assert_eq!(fast.1.to_bits(), portable.1.to_bits());
        }
        #[cfg(target_arch = "x86_64")]
        if crate::cpu::avx512_available() {
            // SAFETY: the CPU has AVX-512F and AVX2.
            let fast = unsafe { avx512_ops(&a, &b) };
            assert_eq!(fast.0, portable.0);
            assert_eq!(fast.1.to_bits(), portable.1.to_bits());
        }
    }

    /// Two sums side by side are each `lane_sum`'s, bit for bit, on lanes whose sum
    /// depends on the order of the additions (magnitudes 1e-3 to 1e13, both signs).
    #[test]
    fn two_sums_side_by_side_are_the_sums_one_by_one() {
        for seed in 0..200u64 {
            let lanes = |k: u64| -> [f64; 8] {
                std::array::from_fn(|m| {
                    let x = ((seed * 8 + m as u64) * 2 + k) as f64;
                    (x * 0.6173).sin() * 10f64.powi(((x * 1.37) as i32) % 17 - 3)
                })
            };
            let (a, b) = (lanes(0), lanes(1));
            let want = (
                super::super::modal::lane_sum(a),
                super::super::modal::lane_sum(b),
            );
            let bits = |p: (f64, f64)| (p.0.to_bits(), p.1.to_bits());
            let portable = Portable::<8>::load(&a).sum2(Portable::<8>::load(&b));
            assert_eq!(bits(portable), bits(want));
            #[cfg(target_arch = "x86_64")]
            if crate::cpu::avx2_available() {
                // SAFETY: the CPU has AVX2.
                assert_eq!(
                    bits(unsafe { avx_sum2(&a, &b) }),
                    bits(want),
                    "AVX2, {seed}"
                );
            }
            #[cfg(target_arch = "x86_64")]
            if crate::cpu::avx512_available() {
                // SAFETY: the CPU has AVX-512F and AVX2.
                assert_eq!(
                    bits(unsafe { avx512_sum2(&a, &b) }),
                    bits(want),
                    "AVX-512, {seed}"
                );
            }
        }
    }
}
