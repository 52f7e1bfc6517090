//! The few f64 vector operations the lock-in kernel needs, over explicit SIMD registers.
//!
//! Why not leave it to the auto-vectoriser: it vectorises the pre-decimator's
//! multiply–add rows but leaves the low-pass cascade (values carried from section to
//! section) scalar, which made that cheap stage cost as much as the expensive one. With
//! explicit registers both are vector code on every target.
//!
//! Every operation is `unsafe`: the caller guarantees that the CPU has the type's target
//! features (always true for [`Sse2`] on x86-64 and for `f64`; [`Avx2Fma`] needs a runtime
//! check) and, for loads and stores, that `LANES` values are readable or writable at the
//! pointer.

/// A vector of `LANES` f64.
pub(super) trait F64s: Copy {
    /// Number of f64 in the vector.
    const LANES: usize;

    /// Every lane `x`.
    unsafe fn splat(x: f64) -> Self;
    /// Unaligned load of `LANES` values.
    unsafe fn load(src: *const f64) -> Self;
    /// Unaligned store of `LANES` values.
    unsafe fn store(self, dst: *mut f64);
    /// Lane-wise `self + b`.
    unsafe fn add(self, b: Self) -> Self;
    /// Lane-wise `self − b`.
    unsafe fn sub(self, b: Self) -> Self;
    /// Lane-wise `self · b`.
    unsafe fn mul(self, b: Self) -> Self;
    /// Lane-wise `self · b + c` (fused where the target has FMA).
    unsafe fn mul_add(self, b: Self, c: Self) -> Self;
}

/// One lane: the portable fallback.
impl F64s for f64 {
    const LANES: usize = 1;

    #[inline(always)]
    unsafe fn splat(x: f64) -> Self {
        x
    }
    #[inline(always)]
    unsafe fn load(src: *const f64) -> Self {
        // SAFETY: the caller guarantees one readable value.
        unsafe { *src }
    }
    #[inline(always)]
    unsafe fn store(self, dst: *mut f64) {
        // SAFETY: the caller guarantees one writable value.
        unsafe { *dst = self }
    }
    #[inline(always)]
    unsafe fn add(self, b: Self) -> Self {
        self + b
    }
    #[inline(always)]
    unsafe fn sub(self, b: Self) -> Self {
        self - b
    }
    #[inline(always)]
    unsafe fn mul(self, b: Self) -> Self {
        self * b
    }
    #[inline(always)]
    unsafe fn mul_add(self, b: Self, c: Self) -> Self {
        // Not `f64::mul_add`: without hardware FMA that is a slow library call.
        self * b + c
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) use x86::{Avx2Fma, Avx512, Sse2};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::F64s;

    /// Two lanes in an SSE2 register: part of every x86-64 CPU.
    #[derive(Clone, Copy)]
    pub(in crate::dsp) struct Sse2(__m128d);

    impl F64s for Sse2 {
        const LANES: usize = 2;

        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            // SAFETY: SSE2 is baseline on x86-64.
            Self(unsafe { _mm_set1_pd(x) })
        }
        #[inline(always)]
        unsafe fn load(src: *const f64) -> Self {
            // SAFETY: the caller guarantees two readable values.
            Self(unsafe { _mm_loadu_pd(src) })
        }
        #[inline(always)]
        unsafe fn store(self, dst: *mut f64) {
            // SAFETY: the caller guarantees two writable values.
            unsafe { _mm_storeu_pd(dst, self.0) }
        }
        #[inline(always)]
        unsafe fn add(self, b: Self) -> Self {
            // SAFETY: SSE2 is baseline on x86-64.
            Self(unsafe { _mm_add_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn sub(self, b: Self) -> Self {
            // SAFETY: SSE2 is baseline on x86-64.
            Self(unsafe { _mm_sub_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul(self, b: Self) -> Self {
            // SAFETY: SSE2 is baseline on x86-64.
            Self(unsafe { _mm_mul_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul_add(self, b: Self, c: Self) -> Self {
            // SAFETY: SSE2 is baseline on x86-64.
            unsafe { self.mul(b).add(c) }
        }
    }

    /// Four lanes in an AVX register, multiply–adds fused. Only for CPUs that report AVX2
    /// and FMA; the operations inline into functions compiled with those features.
    #[derive(Clone, Copy)]
    pub(in crate::dsp) struct Avx2Fma(__m256d);

    impl F64s for Avx2Fma {
        const LANES: usize = 4;

        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            // SAFETY: the caller guarantees AVX.
            Self(unsafe { _mm256_set1_pd(x) })
        }
        #[inline(always)]
        unsafe fn load(src: *const f64) -> Self {
            // SAFETY: the caller guarantees AVX and four readable values.
            Self(unsafe { _mm256_loadu_pd(src) })
        }
        #[inline(always)]
        unsafe fn store(self, dst: *mut f64) {
            // SAFETY: the caller guarantees AVX and four writable values.
            unsafe { _mm256_storeu_pd(dst, self.0) }
        }
        #[inline(always)]
        unsafe fn add(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX.
            Self(unsafe { _mm256_add_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn sub(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX.
            Self(unsafe { _mm256_sub_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX.
            Self(unsafe { _mm256_mul_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul_add(self, b: Self, c: Self) -> Self {
            // SAFETY: the caller guarantees FMA.
            Self(unsafe { _mm256_fmadd_pd(self.0, b.0, c.0) })
        }
    }

    /// Eight lanes in an AVX-512 register, multiply–adds fused: the same operations lane by
    /// lane as [`Avx2Fma`], so the same bits. Only for CPUs that report AVX-512F (and AVX2
    /// and FMA); the operations inline into functions compiled with that feature.
    #[derive(Clone, Copy)]
    pub(in crate::dsp) struct Avx512(__m512d);

    impl F64s for Avx512 {
        const LANES: usize = 8;

        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            // SAFETY: the caller guarantees AVX-512F.
            Self(unsafe { _mm512_set1_pd(x) })
        }
        #[inline(always)]
        unsafe fn load(src: *const f64) -> Self {
            // SAFETY: the caller guarantees AVX-512F and eight readable values.
            Self(unsafe { _mm512_loadu_pd(src) })
        }
        #[inline(always)]
        unsafe fn store(self, dst: *mut f64) {
            // SAFETY: the caller guarantees AVX-512F and eight writable values.
            unsafe { _mm512_storeu_pd(dst, self.0) }
        }
        #[inline(always)]
        unsafe fn add(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX-512F.
            Self(unsafe { _mm512_add_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn sub(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX-512F.
            Self(unsafe { _mm512_sub_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul(self, b: Self) -> Self {
            // SAFETY: the caller guarantees AVX-512F.
            Self(unsafe { _mm512_mul_pd(self.0, b.0) })
        }
        #[inline(always)]
        unsafe fn mul_add(self, b: Self, c: Self) -> Self {
            // SAFETY: the caller guarantees AVX-512F.
            Self(unsafe { _mm512_fmadd_pd(self.0, b.0, c.0) })
        }
    }
}
