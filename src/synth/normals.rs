//! Standard normal deviates for the noise sources, many at a time: eight xoshiro256++
//! streams side by side and the Box–Muller transform in single precision, written as
//! fixed-width lane arithmetic so that the compiler keeps all eight lanes in vector
//! registers (two AVX2 registers of `u64`, one of `f32`). Where the CPU has AVX-512 the
//! transform runs on two successive batches at once, one to each half of a register: the
//! same operations lane by lane, so the same bits, and more deviates a second on a core
//! whose long chains (the logarithm's polynomial, the square root) then carry twice the
//! lanes through its window of instructions in flight (figures: docs/benchmarks.md).
//!
//! Why not `rand_distr`'s ziggurat: it draws one deviate at a time through data-dependent
//! branches and table look-ups, where a sample of the synthesiser needs one deviate per
//! mode and one for the detector; this draws them at a fraction of its cost
//! (docs/benchmarks.md). No maintained crate offers vectorised normal deviates on stable
//! Rust (`rand`'s SIMD support needs the nightly `portable_simd`).
//!
//! The transform, per 64-bit word of a stream:
//! - the radius from the high 32 bits: u = (⌊hi/2⌋ + ½)·2⁻³¹ ∈ (0, 1], r = √(−2 ln u); its
//!   largest value, 6.66, bounds the deviates: a normal exceeds it with probability 3e-11;
//! - the angle from the low 32 bits: two bits choose the quadrant (the signs of cosine and
//!   sine, which keeps the angle uniform over the circle), thirty its place within it;
//! - the pair r·cos θ, r·sin θ: two independent standard normals.
//!
//! The logarithm, sine and cosine are Cephes' single-precision polynomials (S. L. Moshier):
//! within a few units in the last place of `f32` (this module's tests), far below the
//! deviates' own statistical scatter. Each multiply–add of the polynomials is fused (one
//! rounding): FMA instructions in the vector build, `f32::mul_add` in the portable one, so
//! every build of the crate, whatever its vector width, gives the same bits. Fused, the
//! transform's chains are shorter and its instructions fewer, so it is faster too
//! (docs/benchmarks.md).

// The lanes are read and written in lock-step by index: the form the compiler vectorises.
#![allow(clippy::needless_range_loop)]

use std::f32::consts::{FRAC_1_SQRT_2, FRAC_PI_2};

/// Streams side by side.
const LANES: usize = 8;
/// Deviates per batch: two per stream.
pub const BATCH: usize = 2 * LANES;

/// Eight xoshiro256++ streams, 2^128 steps apart, drawn into normal deviates a batch of
/// [`BATCH`] at a time. The deviates handed out do not depend on how the requests for
/// them are cut: a batch that a request leaves unfinished is kept for the next.
#[derive(Clone, Debug)]
pub struct NormalSource {
    /// Stream states, word by word: `s[w][lane]`.
    s: [[u64; LANES]; 4],
    /// The batch being handed out and how far.
    batch: [f32; BATCH],
    used: usize,
    /// Whether the CPU has AVX2 and FMA.
    avx2: bool,
    /// Whether the CPU has AVX-512F (whose FMA is part of it).
    avx512: bool,
}

impl NormalSource {
    /// Streams seeded from `seed`: the first by SplitMix64 (as `rand_xoshiro`'s
    /// `seed_from_u64`), each next one the previous jumped by 2^128 steps.
    pub fn new(seed: u64) -> Self {
        Self::set(seed, 0)
    }

    /// The `set`-th source of `seed`: its streams follow those of set − 1 on the chain of
    /// jumps, so the sources of one seed never overlap.
    pub fn set(seed: u64, set: usize) -> Self {
        let mut split = seed;
        let mut state: [u64; 4] = std::array::from_fn(|_| splitmix64(&mut split));
        for _ in 0..set * LANES {
            jump(&mut state);
        }
        let mut s = [[0; LANES]; 4];
        for lane in 0..LANES {
            for (w, word) in state.iter().enumerate() {
                s[w][lane] = *word;
            }
            jump(&mut state);
        }
        Self {
            s,
            batch: [0.0; BATCH],
            used: BATCH,
            avx2: crate::cpu::fma_available(),
            avx512: crate::cpu::avx512_available(),
        }
    }

    /// A source whose 32 state words (four per stream) are SplitMix64 outputs `first`,
    /// `first` + 1, … of `seed`: cheap to make (no jumps), so that every page of deviates
    /// can have sources of its own ([`super::noise_pages`]). SplitMix64 is a bijection of
    /// its counter, so sources made from disjoint ranges of outputs never share a state.
    /// Allocation-free.
    pub fn splitmix_range(seed: u64, first: u64) -> Self {
        let mut split = seed.wrapping_add(first.wrapping_mul(SPLITMIX_GAMMA));
        let mut s = [[0; LANES]; 4];
        for lane in 0..LANES {
            for word in s.iter_mut() {
                word[lane] = splitmix64(&mut split);
            }
        }
        Self {
            s,
            batch: [0.0; BATCH],
            used: BATCH,
            avx2: crate::cpu::fma_available(),
            avx512: crate::cpu::avx512_available(),
        }
    }

    /// Fills `out` with the next standard normal deviates, as `f64` or as `f32` (they are
    /// drawn in single precision, so both hold the same values). Allocation-free. Where the
    /// CPU has AVX2 and FMA (detected once, at construction) the batches are drawn with
    /// their instructions; the deviates are the same bits either way.
    #[inline]
    pub fn fill<T: Deviate>(&mut self, out: &mut [T]) {
        let mut out = out;
        if self.used < BATCH {
            let n = out.len().min(BATCH - self.used);
            let (head, rest) = out.split_at_mut(n);
            for (o, b) in head.iter_mut().zip(&self.batch[self.used..]) {
                *o = T::from_f32(*b);
            }
            self.used += n;
            out = rest;
        }
        let whole = out.len() / BATCH * BATCH;
        let (body, tail) = out.split_at_mut(whole);
        #[cfg(target_arch = "x86_64")]
        if self.avx512 {
            // SAFETY: `avx512` is true only where the CPU has AVX-512F.
            unsafe { avx512::fill_batches(&mut self.s, body) };
        } else if self.avx2 {
            // SAFETY: `avx2` is true only where the CPU has AVX2 and FMA.
            unsafe { avx2::fill_batches(&mut self.s, body) };
        } else {
            self.fill_batches(body);
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.fill_batches(body);
        if !tail.is_empty() {
            let mut batch = [0.0f32; BATCH];
            self.fill_batches(&mut batch);
            self.batch = batch;
            for (o, b) in tail.iter_mut().zip(&batch) {
                *o = T::from_f32(*b);
            }
            self.used = tail.len();
        }
    }

    /// Fills `out`, a whole number of batches, by the portable lane arithmetic.
    fn fill_batches<T: Deviate>(&mut self, out: &mut [T]) {
        for o in out.chunks_exact_mut(BATCH) {
            let b = next_batch(&mut self.s);
            for (o, b) in o.iter_mut().zip(b) {
                *o = T::from_f32(b);
            }
        }
    }
}

/// The types a [`NormalSource`] fills: `f64` and `f32`.
pub trait Deviate: Copy + sealed::Sealed {
    /// Whether the type is `f32` (the vector code stores it without widening).
    const SINGLE: bool;
    /// The deviate, exactly.
    fn from_f32(x: f32) -> Self;
}

impl Deviate for f64 {
    const SINGLE: bool = false;
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        f64::from(x)
    }
}

impl Deviate for f32 {
    const SINGLE: bool = true;
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        x
    }
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f64 {}
    impl Sealed for f32 {}
}

/// Stream j of the interleaved order in which the vector code pairs the words of the two
/// halves of the streams: 0, 4, 1, 5, 2, 6, 3, 7.
const fn interleaved(j: usize) -> usize {
    if j.is_multiple_of(2) {
        j / 2
    } else {
        LANES / 2 + j / 2
    }
}

/// The next batch of the streams `s`: each stream's next word turned into two deviates,
/// the cosines first, then the sines, lane j from stream [`interleaved`]`(j)`.
fn next_batch(s: &mut [[u64; LANES]; 4]) -> [f32; BATCH] {
    let words = next_words(s);
    let mut radius_u = [0.0f32; LANES];
    let mut angle = [0.0f32; LANES];
    let mut lo = [0u32; LANES];
    for j in 0..LANES {
        let x = words[interleaved(j)];
        lo[j] = x as u32;
        // 31 bits by a signed conversion, which every vector unit has.
        radius_u[j] = (((x >> 33) as i32) as f32 + 0.5) * (1.0 / 2_147_483_648.0);
        angle[j] = ((lo[j] & 0x3fff_ffff) as i32) as f32 * (1.0 / 1_073_741_824.0);
    }
    let ln = ln(radius_u);
    let mut out = [0.0f32; BATCH];
    for j in 0..LANES {
        let r = (-2.0 * ln[j]).sqrt();
        // θ = φ + π/4 with φ ∈ [−π/4, π/4), where the polynomials hold.
        let phi = (angle[j] - 0.5) * FRAC_PI_2;
        let (s, c) = sin_cos_quarter(phi);
        let cos = (c - s) * FRAC_1_SQRT_2 * r;
        let sin = (c + s) * FRAC_1_SQRT_2 * r;
        // Bits 31 and 30 of the low half: the quadrant, as the signs.
        out[j] = f32::from_bits(cos.to_bits() ^ (lo[j] & 0x8000_0000));
        out[LANES + j] = f32::from_bits(sin.to_bits() ^ ((lo[j] << 1) & 0x8000_0000));
    }
    out
}

/// One xoshiro256++ step of every stream.
fn next_words(s: &mut [[u64; LANES]; 4]) -> [u64; LANES] {
    let [s0, s1, s2, s3] = s;
    let mut out = [0u64; LANES];
    for i in 0..LANES {
        out[i] = s0[i]
            .wrapping_add(s3[i])
            .rotate_left(23)
            .wrapping_add(s0[i]);
        let t = s1[i] << 17;
        s2[i] ^= s0[i];
        s3[i] ^= s1[i];
        s1[i] ^= s2[i];
        s0[i] ^= s3[i];
        s2[i] ^= t;
        s3[i] = s3[i].rotate_left(45);
    }
    out
}

/// The constants of the vector builds' transforms ([`avx2`], [`avx512`]), in a table.
#[cfg(target_arch = "x86_64")]
mod table {
    /// One constant in all eight 32-bit lanes, as its bits, in a whole 32-byte line.
    #[repr(C, align(32))]
    pub(super) struct Row(pub(super) [u32; 8]);

    const fn f(x: f32) -> Row {
        Row([x.to_bits(); 8])
    }

    const fn i(x: u32) -> Row {
        Row([x; 8])
    }

    // Where each constant of the transforms sits in `CONSTANTS`.
    pub(super) const HALF: usize = 0;
    pub(super) const INV_2_31: usize = 1;
    pub(super) const LOW_30: usize = 2;
    pub(super) const INV_2_30: usize = 3;
    pub(super) const EXPONENT: usize = 4;
    pub(super) const BIAS: usize = 5;
    pub(super) const MANTISSA: usize = 6;
    pub(super) const HALF_BITS: usize = 7;
    pub(super) const ROOT_HALF: usize = 8;
    pub(super) const ONE: usize = 9;
    pub(super) const LN_LEAD: usize = 10;
    pub(super) const LN_POLY_AT: usize = 11;
    pub(super) const LN2_LOW: usize = 19;
    pub(super) const MINUS_HALF: usize = 20;
    pub(super) const LN2_HIGH: usize = 21;
    pub(super) const MINUS_TWO: usize = 22;
    pub(super) const QUARTER_TURN: usize = 23;
    pub(super) const SIN: usize = 24;
    pub(super) const COS: usize = 27;
    pub(super) const SIGN: usize = 30;
    pub(super) const ONE_BITS: usize = 31;

    /// The vector transforms' constants. The transforms read them through a reference
    /// the compiler cannot see into ([`constants`]), so that it takes each as a memory
    /// operand of the instruction that uses it. Seen as constants, each was broadcast into
    /// a register of its own before every use, since the loop has more of them than the
    /// sixteen AVX2 registers: a sixth of the AVX2 loop's instructions were such broadcasts
    /// (the counts, and what they cost: docs/benchmarks.md). The same values, so the same
    /// bits.
    static CONSTANTS: [Row; 32] = [
        f(0.5),
        f(1.0 / 2_147_483_648.0),
        i(0x3fff_ffff),
        f(1.0 / 1_073_741_824.0),
        i(0xff),
        i(126),
        i(0x807f_ffff),
        i(0x3f00_0000),
        f(std::f32::consts::FRAC_1_SQRT_2),
        f(1.0),
        f(super::LN_LEADING),
        f(super::LN_POLY[0]),
        f(super::LN_POLY[1]),
        f(super::LN_POLY[2]),
        f(super::LN_POLY[3]),
        f(super::LN_POLY[4]),
        f(super::LN_POLY[5]),
        f(super::LN_POLY[6]),
        f(super::LN_POLY[7]),
        f(super::LN2_LOW_PART),
        f(-0.5),
        f(super::LN2_HIGH_PART),
        f(-2.0),
        f(std::f32::consts::FRAC_PI_2),
        f(super::SIN_POLY[0]),
        f(super::SIN_POLY[1]),
        f(super::SIN_POLY[2]),
        f(super::COS_POLY[0]),
        f(super::COS_POLY[1]),
        f(super::COS_POLY[2]),
        i(0x8000_0000),
        i(1),
    ];

    /// The table of the transforms' constants, opaque to the optimiser. Taken once per
    /// transform: taken once for the two batches of a pass, each load had two uses and
    /// went to a register again (docs/benchmarks.md).
    #[inline(always)]
    pub(super) fn constants() -> &'static [Row; 32] {
        std::hint::black_box(&CONSTANTS)
    }
}

/// The same arithmetic in AVX2 and FMA instructions, operation for operation.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::table::*;
    use super::{BATCH, LANES};
    use std::arch::x86_64::*;

    /// Rotates the 64-bit lanes of `x` left by `K` (`R` = 64 − `K`).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn rotl<const K: i32, const R: i32>(x: __m256i) -> __m256i {
        _mm256_or_si256(_mm256_slli_epi64::<K>(x), _mm256_srli_epi64::<R>(x))
    }

    /// One xoshiro256++ step of four streams.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn step(s: &mut [__m256i; 4]) -> __m256i {
        let out = _mm256_add_epi64(rotl::<23, 41>(_mm256_add_epi64(s[0], s[3])), s[0]);
        let t = _mm256_slli_epi64::<17>(s[1]);
        s[2] = _mm256_xor_si256(s[2], s[0]);
        s[3] = _mm256_xor_si256(s[3], s[1]);
        s[1] = _mm256_xor_si256(s[1], s[2]);
        s[0] = _mm256_xor_si256(s[0], s[3]);
        s[2] = _mm256_xor_si256(s[2], t);
        s[3] = rotl::<45, 19>(s[3]);
        out
    }

    /// Two words of each stream (`x` from streams 0–3, `y` from 4–7) turned into the batch's
    /// cosines and sines (lane j from stream [`super::interleaved`]`(j)`), with the
    /// constants `k` ([`constants`]).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn transform(k: &[Row; 32], x: __m256i, y: __m256i) -> (__m256, __m256) {
        // SAFETY: a `Row` is 32 aligned bytes.
        let f = |n: usize| unsafe { _mm256_load_ps(k[n].0.as_ptr().cast()) };
        let i = |n: usize| unsafe { _mm256_load_si256(k[n].0.as_ptr().cast()) };
        // 32-bit lane j: the high (radius) or low (angle) half of stream interleaved(j).
        let hi = _mm256_blend_epi32::<0b1010_1010>(_mm256_srli_epi64::<32>(x), y);
        let lo = _mm256_blend_epi32::<0b1010_1010>(x, _mm256_slli_epi64::<32>(y));
        let radius_u = _mm256_mul_ps(
            _mm256_add_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32::<1>(hi)), f(HALF)),
            f(INV_2_31),
        );
        let angle = _mm256_mul_ps(
            _mm256_cvtepi32_ps(_mm256_and_si256(lo, i(LOW_30))),
            f(INV_2_30),
        );
        // ln, as `super::ln`.
        let bits = _mm256_castps_si256(radius_u);
        let e = _mm256_sub_epi32(
            _mm256_and_si256(_mm256_srli_epi32::<23>(bits), i(EXPONENT)),
            i(BIAS),
        );
        let m = _mm256_castsi256_ps(_mm256_or_si256(
            _mm256_and_si256(bits, i(MANTISSA)),
            i(HALF_BITS),
        ));
        let below = _mm256_cmp_ps::<_CMP_LT_OQ>(m, f(ROOT_HALF));
        let e = _mm256_add_epi32(e, _mm256_castps_si256(below));
        let t = _mm256_blendv_ps(
            _mm256_sub_ps(m, f(ONE)),
            _mm256_sub_ps(_mm256_add_ps(m, m), f(ONE)),
            below,
        );
        let z = _mm256_mul_ps(t, t);
        let mut p = f(LN_LEAD);
        for c in 0..8 {
            p = _mm256_fmadd_ps(p, t, f(LN_POLY_AT + c));
        }
        let ef = _mm256_cvtepi32_ps(e);
        let a = _mm256_fmadd_ps(ef, f(LN2_LOW), _mm256_mul_ps(f(MINUS_HALF), z));
        let y = _mm256_fmadd_ps(_mm256_mul_ps(p, t), z, a);
        let ln = _mm256_fmadd_ps(ef, f(LN2_HIGH), _mm256_add_ps(t, y));
        let r = _mm256_sqrt_ps(_mm256_mul_ps(f(MINUS_TWO), ln));
        // sin and cos, as `super::sin_cos_quarter`.
        let phi = _mm256_mul_ps(_mm256_sub_ps(angle, f(HALF)), f(QUARTER_TURN));
        let z = _mm256_mul_ps(phi, phi);
        let sp = _mm256_fmadd_ps(_mm256_fmadd_ps(f(SIN), z, f(SIN + 1)), z, f(SIN + 2));
        let s = _mm256_fmadd_ps(_mm256_mul_ps(sp, z), phi, phi);
        let cp = _mm256_fmadd_ps(_mm256_fmadd_ps(f(COS), z, f(COS + 1)), z, f(COS + 2));
        let c = _mm256_fmadd_ps(
            _mm256_mul_ps(cp, z),
            z,
            _mm256_fmadd_ps(f(MINUS_HALF), z, f(ONE)),
        );
        let root_half = f(ROOT_HALF);
        let cos = _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(c, s), root_half), r);
        let sin = _mm256_mul_ps(_mm256_mul_ps(_mm256_add_ps(c, s), root_half), r);
        let sign = i(SIGN);
        let cos = _mm256_xor_ps(cos, _mm256_castsi256_ps(_mm256_and_si256(lo, sign)));
        let sin_sign = _mm256_and_si256(_mm256_slli_epi32::<1>(lo), sign);
        let sin = _mm256_xor_ps(sin, _mm256_castsi256_ps(sin_sign));
        (cos, sin)
    }

    /// Stores a batch's cosines and sines to `o` (BATCH deviates of type T).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn store_batch<T: super::Deviate>(o: &mut [T], cos: __m256, sin: __m256) {
        debug_assert_eq!(o.len(), BATCH);
        // SAFETY: `o` holds BATCH = 16 deviates of type T, which is f32 if `SINGLE`
        // and f64 if not (the trait is sealed); unaligned stores.
        unsafe {
            if T::SINGLE {
                let p = o.as_mut_ptr().cast::<f32>();
                _mm256_storeu_ps(p, cos);
                _mm256_storeu_ps(p.add(8), sin);
            } else {
                let p = o.as_mut_ptr().cast::<f64>();
                _mm256_storeu_pd(p, _mm256_cvtps_pd(_mm256_castps256_ps128(cos)));
                _mm256_storeu_pd(p.add(4), _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(cos)));
                _mm256_storeu_pd(p.add(8), _mm256_cvtps_pd(_mm256_castps256_ps128(sin)));
                _mm256_storeu_pd(p.add(12), _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(sin)));
            }
        }
    }

    /// [`super::NormalSource::fill_batches`] with AVX2 and FMA.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn fill_batches<T: super::Deviate>(s: &mut [[u64; LANES]; 4], out: &mut [T]) {
        crate::cpu::align_frame();
        let load = |w: &[u64; LANES], half: usize| {
            // SAFETY: four u64 in bounds; unaligned load.
            unsafe { _mm256_loadu_si256(w[4 * half..].as_ptr().cast()) }
        };
        let mut a = [
            load(&s[0], 0),
            load(&s[1], 0),
            load(&s[2], 0),
            load(&s[3], 0),
        ];
        let mut b = [
            load(&s[0], 1),
            load(&s[1], 1),
            load(&s[2], 1),
            load(&s[3], 1),
        ];
        // Two batches a pass: their transforms are independent, so the core works on one
        // while the other waits on its long chains (logarithm, square root); the bits
        // are those of one batch at a time.
        let mut pairs = out.chunks_exact_mut(2 * BATCH);
        for o in &mut pairs {
            let (x0, y0) = (step(&mut a), step(&mut b));
            let (x1, y1) = (step(&mut a), step(&mut b));
            let (c0, s0) = transform(constants(), x0, y0);
            let (c1, s1) = transform(constants(), x1, y1);
            let (o0, o1) = o.split_at_mut(BATCH);
            store_batch(o0, c0, s0);
            store_batch(o1, c1, s1);
        }
        let rest = pairs.into_remainder();
        if !rest.is_empty() {
            let (x, y) = (step(&mut a), step(&mut b));
            let (c, s) = transform(constants(), x, y);
            store_batch(rest, c, s);
        }
        let store = |w: &mut [u64; LANES], half: usize, v: __m256i| {
            // SAFETY: four u64 in bounds; unaligned store.
            unsafe { _mm256_storeu_si256(w[4 * half..].as_mut_ptr().cast(), v) }
        };
        for w in 0..4 {
            store(&mut s[w], 0, a[w]);
            store(&mut s[w], 1, b[w]);
        }
    }
}

/// The same arithmetic in AVX-512 instructions, operation for operation, two batches to an
/// instruction: the eight streams' words are one register, and the transform runs on the
/// words of two successive steps side by side (the first batch in the low half of each
/// register, the next in the high half), each half laid out as [`avx2::transform`]'s.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::table::*;
    use super::{BATCH, LANES};
    use std::arch::x86_64::*;

    /// One xoshiro256++ step of the eight streams: lanes 0–3 streams 0–3, 4–7 streams 4–7.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn step(s: &mut [__m512i; 4]) -> __m512i {
        let out = _mm512_add_epi64(_mm512_rol_epi64::<23>(_mm512_add_epi64(s[0], s[3])), s[0]);
        let t = _mm512_slli_epi64::<17>(s[1]);
        s[2] = _mm512_xor_si512(s[2], s[0]);
        s[3] = _mm512_xor_si512(s[3], s[1]);
        s[1] = _mm512_xor_si512(s[1], s[2]);
        s[0] = _mm512_xor_si512(s[0], s[3]);
        s[2] = _mm512_xor_si512(s[2], t);
        s[3] = _mm512_rol_epi64::<45>(s[3]);
        out
    }

    /// Two batches from the words `w0` and `w1` of two successive steps: their cosines and
    /// sines, the first batch's in the low halves.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn transform(k: &[Row; 32], w0: __m512i, w1: __m512i) -> (__m512, __m512) {
        // Each constant broadcast from its row's first lane: a memory operand.
        let f = |n: usize| _mm512_set1_ps(f32::from_bits(k[n].0[0]));
        let i = |n: usize| _mm512_set1_epi32(k[n].0[0] as i32);
        // [streams 0–3 of w0, of w1] and [streams 4–7 of w0, of w1]: the AVX2 code's x, y.
        let x = _mm512_shuffle_i64x2::<0b01_00_01_00>(w0, w1);
        let y = _mm512_shuffle_i64x2::<0b11_10_11_10>(w0, w1);
        let hi = _mm512_mask_blend_epi32(0xaaaa, _mm512_srli_epi64::<32>(x), y);
        let lo = _mm512_mask_blend_epi32(0xaaaa, x, _mm512_slli_epi64::<32>(y));
        let radius_u = _mm512_mul_ps(
            _mm512_add_ps(_mm512_cvtepi32_ps(_mm512_srli_epi32::<1>(hi)), f(HALF)),
            f(INV_2_31),
        );
        let angle = _mm512_mul_ps(
            _mm512_cvtepi32_ps(_mm512_and_si512(lo, i(LOW_30))),
            f(INV_2_30),
        );
        // ln, as `super::ln`.
        let bits = _mm512_castps_si512(radius_u);
        let e = _mm512_sub_epi32(
            _mm512_and_si512(_mm512_srli_epi32::<23>(bits), i(EXPONENT)),
            i(BIAS),
        );
        let m = _mm512_castsi512_ps(_mm512_or_si512(
            _mm512_and_si512(bits, i(MANTISSA)),
            i(HALF_BITS),
        ));
        let below = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(m, f(ROOT_HALF));
        let e = _mm512_mask_sub_epi32(e, below, e, i(ONE_BITS));
        let t = _mm512_mask_blend_ps(
            below,
            _mm512_sub_ps(m, f(ONE)),
            _mm512_sub_ps(_mm512_add_ps(m, m), f(ONE)),
        );
        let z = _mm512_mul_ps(t, t);
        let mut p = f(LN_LEAD);
        for c in 0..8 {
            p = _mm512_fmadd_ps(p, t, f(LN_POLY_AT + c));
        }
        let ef = _mm512_cvtepi32_ps(e);
        let a = _mm512_fmadd_ps(ef, f(LN2_LOW), _mm512_mul_ps(f(MINUS_HALF), z));
        let y = _mm512_fmadd_ps(_mm512_mul_ps(p, t), z, a);
        let ln = _mm512_fmadd_ps(ef, f(LN2_HIGH), _mm512_add_ps(t, y));
        let r = _mm512_sqrt_ps(_mm512_mul_ps(f(MINUS_TWO), ln));
        // sin and cos, as `super::sin_cos_quarter`.
        let phi = _mm512_mul_ps(_mm512_sub_ps(angle, f(HALF)), f(QUARTER_TURN));
        let z = _mm512_mul_ps(phi, phi);
        let sp = _mm512_fmadd_ps(_mm512_fmadd_ps(f(SIN), z, f(SIN + 1)), z, f(SIN + 2));
        let s = _mm512_fmadd_ps(_mm512_mul_ps(sp, z), phi, phi);
        let cp = _mm512_fmadd_ps(_mm512_fmadd_ps(f(COS), z, f(COS + 1)), z, f(COS + 2));
        let c = _mm512_fmadd_ps(
            _mm512_mul_ps(cp, z),
            z,
            _mm512_fmadd_ps(f(MINUS_HALF), z, f(ONE)),
        );
        let root_half = f(ROOT_HALF);
        let cos = _mm512_mul_ps(_mm512_mul_ps(_mm512_sub_ps(c, s), root_half), r);
        let sin = _mm512_mul_ps(_mm512_mul_ps(_mm512_add_ps(c, s), root_half), r);
        let sign = i(SIGN);
        let cos = _mm512_castsi512_ps(_mm512_xor_si512(
            _mm512_castps_si512(cos),
            _mm512_and_si512(lo, sign),
        ));
        let sin_sign = _mm512_and_si512(_mm512_slli_epi32::<1>(lo), sign);
        let sin = _mm512_castsi512_ps(_mm512_xor_si512(_mm512_castps_si512(sin), sin_sign));
        (cos, sin)
    }

    /// Stores eight deviates `v` to `o` as type T.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn store8<T: super::Deviate>(o: &mut [T], v: __m256) {
        let o = &mut o[..LANES];
        // SAFETY: `o` holds eight deviates of type T, which is f32 if `SINGLE` and f64 if
        // not (the trait is sealed); unaligned stores.
        unsafe {
            if T::SINGLE {
                _mm256_storeu_ps(o.as_mut_ptr().cast::<f32>(), v);
            } else {
                _mm512_storeu_pd(o.as_mut_ptr().cast::<f64>(), _mm512_cvtps_pd(v));
            }
        }
    }

    /// Stores the two batches of `cos`, `sin` to `o` (2·BATCH deviates), or the first only
    /// (BATCH).
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn store_batches<T: super::Deviate>(o: &mut [T], cos: __m512, sin: __m512) {
        let low = |v: __m512| _mm512_castps512_ps256(v);
        let high = |v: __m512| _mm512_castps512_ps256(_mm512_shuffle_f32x4::<0b11_10_11_10>(v, v));
        store8(&mut o[..LANES], low(cos));
        store8(&mut o[LANES..BATCH], low(sin));
        if o.len() == 2 * BATCH {
            store8(&mut o[BATCH..BATCH + LANES], high(cos));
            store8(&mut o[BATCH + LANES..], high(sin));
        }
    }

    /// [`super::NormalSource::fill_batches`] with AVX-512.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn fill_batches<T: super::Deviate>(s: &mut [[u64; LANES]; 4], out: &mut [T]) {
        crate::cpu::align_frame();
        // SAFETY: eight u64 in bounds; unaligned loads.
        let mut w: [__m512i; 4] =
            std::array::from_fn(|k| unsafe { _mm512_loadu_si512(s[k].as_ptr().cast()) });
        // Four batches a pass: two transforms, independent of each other.
        let mut quads = out.chunks_exact_mut(4 * BATCH);
        for o in &mut quads {
            let (w0, w1) = (step(&mut w), step(&mut w));
            let (w2, w3) = (step(&mut w), step(&mut w));
            let (c0, s0) = transform(constants(), w0, w1);
            let (c1, s1) = transform(constants(), w2, w3);
            let (o0, o1) = o.split_at_mut(2 * BATCH);
            store_batches(o0, c0, s0);
            store_batches(o1, c1, s1);
        }
        for o in quads.into_remainder().chunks_mut(2 * BATCH) {
            let w0 = step(&mut w);
            // A lone last batch: its words twice, the high half not stored.
            let w1 = if o.len() == 2 * BATCH {
                step(&mut w)
            } else {
                w0
            };
            let (c, s) = transform(constants(), w0, w1);
            store_batches(o, c, s);
        }
        for (k, v) in w.iter().enumerate() {
            // SAFETY: eight u64 in bounds; unaligned store.
            unsafe { _mm512_storeu_si512(s[k].as_mut_ptr().cast(), *v) };
        }
    }
}

/// SplitMix64's increment (the golden ratio in 64 bits).
const SPLITMIX_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// SplitMix64: the seeding generator xoshiro's authors recommend.
fn splitmix64(x: &mut u64) -> u64 {
    *x = x.wrapping_add(SPLITMIX_GAMMA);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// One step of scalar xoshiro256++ (the jump needs it).
fn step(s: &mut [u64; 4]) {
    let t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = s[3].rotate_left(45);
}

/// Advances `s` by 2^128 steps (the authors' jump polynomial).
fn jump(s: &mut [u64; 4]) {
    const JUMP: [u64; 4] = [
        0x180e_c6d3_3cfd_0aba,
        0xd5a6_1266_f0c9_392c,
        0xa958_2618_e03f_c9aa,
        0x39ab_dc45_29b1_661c,
    ];
    let mut acc = [0u64; 4];
    for word in JUMP {
        for b in 0..64 {
            if word & (1 << b) != 0 {
                for (a, x) in acc.iter_mut().zip(s.iter()) {
                    *a ^= x;
                }
            }
            step(s);
        }
    }
    *s = acc;
}

/// Cephes `logf`'s leading coefficient, before [`LN_POLY`].
const LN_LEADING: f32 = 7.037_683_6e-2;

/// ln 2 = 0.693359375 − 2.12194440e-4, the first part exact in few bits.
const LN2_HIGH_PART: f32 = 0.693_359_4;
const LN2_LOW_PART: f32 = -2.121_944_4e-4;

/// Cephes `sinf`'s and `cosf`'s polynomials in φ², highest power first (Horner).
const SIN_POLY: [f32; 3] = [-1.951_529_6e-4, 8.332_161e-3, -1.666_665_5e-1];
const COS_POLY: [f32; 3] = [2.443_315_7e-5, -1.388_731_6e-3, 4.166_664_6e-2];

/// Cephes `logf`'s polynomial in t = m − 1 after its leading coefficient [`LN_LEADING`],
/// highest power first (Horner).
const LN_POLY: [f32; 8] = [
    -1.151_461e-1,
    1.167_699_9e-1,
    -1.242_014_1e-1,
    1.424_932_3e-1,
    -1.666_805_8e-1,
    2.000_071_4e-1,
    -2.499_999_4e-1,
    3.333_333e-1,
];

/// ln x of every lane, x ∈ (0, 1] (normal numbers): Cephes `logf`.
#[inline(always)]
fn ln(x: [f32; LANES]) -> [f32; LANES] {
    let mut out = [0.0f32; LANES];
    for i in 0..LANES {
        let bits = x[i].to_bits();
        // x = 2^e·m with m ∈ [½, 1).
        let mut e = ((bits >> 23) & 0xff) as i32 - 126;
        let m = f32::from_bits((bits & 0x807f_ffff) | 0x3f00_0000);
        // m moved to [√½, √2) around 1, where the polynomial holds.
        let below = m < FRAC_1_SQRT_2;
        e -= i32::from(below);
        let t = if below { m + m - 1.0 } else { m - 1.0 };
        let z = t * t;
        let mut p = LN_LEADING;
        for c in LN_POLY {
            p = p.mul_add(t, c);
        }
        let ef = e as f32;
        let y = (p * t).mul_add(z, ef.mul_add(LN2_LOW_PART, -0.5 * z));
        out[i] = ef.mul_add(LN2_HIGH_PART, t + y);
    }
    out
}

/// sin φ and cos φ for φ ∈ [−π/4, π/4]: Cephes `sinf`/`cosf` polynomials.
#[inline(always)]
fn sin_cos_quarter(phi: f32) -> (f32, f32) {
    let z = phi * phi;
    let sp = SIN_POLY[0].mul_add(z, SIN_POLY[1]).mul_add(z, SIN_POLY[2]);
    let s = (sp * z).mul_add(phi, phi);
    let cp = COS_POLY[0].mul_add(z, COS_POLY[1]).mul_add(z, COS_POLY[2]);
    let c = (cp * z).mul_add(z, (-0.5f32).mul_add(z, 1.0));
    (s, c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_xoshiro::Xoshiro256PlusPlus;
    use rand_xoshiro::rand_core::{Rng, SeedableRng};

    fn words_to_bytes(s: [u64; 4]) -> [u8; 32] {
        let mut b = [0u8; 32];
        for (i, w) in s.iter().enumerate() {
            b[8 * i..8 * i + 8].copy_from_slice(&w.to_le_bytes());
        }
        b
    }

    /// Each lane is `rand_xoshiro`'s xoshiro256++, lane k the first jumped k times.
    #[test]
    fn the_streams_are_xoshiro256pp_2_to_the_128_apart() {
        let mut source = NormalSource::new(42);
        let mut first = [0u64; 4];
        for w in 0..4 {
            first[w] = source.s[w][0];
        }
        let mut reference = Xoshiro256PlusPlus::seed_from_u64(42);
        let mut check = Xoshiro256PlusPlus::from_seed(words_to_bytes(first));
        assert_eq!(reference.next_u64(), check.next_u64(), "SplitMix64 seeding");
        let mut lanes: Vec<Xoshiro256PlusPlus> = (0..LANES)
            .map(|k| {
                let mut r = Xoshiro256PlusPlus::from_seed(words_to_bytes(first));
                for _ in 0..k {
                    r.jump();
                }
                r
            })
            .collect();
        for _ in 0..100 {
            let words = next_words(&mut source.s);
            for (lane, r) in lanes.iter_mut().enumerate() {
                assert_eq!(words[lane], r.next_u64(), "lane {lane}");
            }
        }
    }

    #[test]
    fn the_logarithm_and_the_circle_are_within_a_few_f32_ulps() {
        let mut worst_ln: f64 = 0.0;
        for k in 0..100_000 {
            // Log-spaced over (2^-32, 1] and the dense end near 1.
            let x = if k % 2 == 0 {
                2f64.powf(-32.0 * k as f64 / 100_000.0)
            } else {
                1.0 - k as f64 * 1e-5 * 0.999
            } as f32;
            let got = ln([x; LANES])[0] as f64;
            let want = (x as f64).ln();
            let ulp = (want.abs() as f32).max(f32::MIN_POSITIVE);
            let ulp = f64::from(f32::from_bits(ulp.to_bits() + 1) - ulp);
            if want != 0.0 {
                worst_ln = worst_ln.max((got - want).abs() / ulp);
            } else {
                assert_eq!(got, 0.0);
            }
        }
        assert!(worst_ln < 3.0, "ln: {worst_ln} ulp");
        let mut worst: f64 = 0.0;
        for k in 0..=100_000 {
            let phi = (k as f64 / 100_000.0 - 0.5) * std::f64::consts::FRAC_PI_2;
            let (s, c) = sin_cos_quarter(phi as f32);
            let phi = f64::from(phi as f32);
            worst = worst
                .max((f64::from(s) - phi.sin()).abs())
                .max((f64::from(c) - phi.cos()).abs());
        }
        assert!(worst < 2.0 * f64::from(f32::EPSILON), "sin/cos: {worst:e}");
    }

    /// The AVX2 and AVX-512 batches are the portable ones, bit for bit, in double and
    /// single precision, for every count of batches a pass leaves over (the AVX-512 build
    /// draws four batches a pass, and a lone last one).
    #[test]
    fn every_build_gives_the_portable_batches() {
        let source = NormalSource::new(5);
        let mut portable = source.clone();
        (portable.avx2, portable.avx512) = (false, false);
        let mut builds = Vec::new();
        if source.avx2 {
            builds.push((
                "AVX2",
                NormalSource {
                    avx512: false,
                    ..source.clone()
                },
            ));
        }
        if source.avx512 {
            builds.push(("AVX-512", source.clone()));
        }
        if builds.is_empty() {
            eprintln!("no AVX2 here: nothing to compare");
            return;
        }
        for (name, mut fast) in builds {
            let mut reference = portable.clone();
            for batches in [4096, 1, 2, 3, 5, 6, 7] {
                let len = batches * BATCH;
                let (mut a, mut b) = (vec![0.0f64; len], vec![0.0f64; len]);
                let (mut single_fast, mut single_reference) = (fast.clone(), reference.clone());
                fast.fill(&mut a);
                reference.fill(&mut b);
                assert!(
                    a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "{name}, {batches} batches"
                );
                assert_eq!(fast.s, reference.s, "{name}, {batches} batches");
                // In single precision, both builds: the same deviates, not widened.
                let (mut c, mut d) = (vec![0.0f32; len], vec![0.0f32; len]);
                single_fast.fill(&mut c[..len.min(5)]);
                single_fast.fill(&mut c[len.min(5)..]);
                single_reference.fill(&mut d);
                for (single, double) in [(&c, &a), (&d, &a)] {
                    assert!(
                        single
                            .iter()
                            .zip(double)
                            .all(|(x, y)| f64::from(*x).to_bits() == y.to_bits()),
                        "{name}, {batches} batches, single precision"
                    );
                }
                assert_eq!(single_fast.s, fast.s);
            }
        }
    }

    #[test]
    fn the_stream_does_not_depend_on_how_it_is_cut() {
        let mut whole = NormalSource::new(3);
        let mut cut = whole.clone();
        let mut a = vec![0.0; 1000];
        whole.fill(&mut a);
        let mut b = vec![0.0; 1000];
        let mut at = 0;
        for (i, n) in [1, 7, 16, 33, 0, 5, 200, 17, 1].iter().cycle().enumerate() {
            let n = (*n).min(1000 - at);
            cut.fill(&mut b[at..at + n]);
            at += n;
            if at == 1000 || i > 10_000 {
                break;
            }
        }
        assert_eq!(a, b);
    }

    /// The moments up to the fourth, the tails and the correlations of 2^23 deviates, each
    /// within five standard errors of the normal distribution's.
    #[test]
    fn the_deviates_are_standard_normal_and_independent() {
        const N: usize = 1 << 23;
        let mut source = NormalSource::new(11);
        let mut x = vec![0.0; N];
        source.fill(&mut x);
        let n = N as f64;
        let mean = x.iter().sum::<f64>() / n;
        let m = |k: i32| x.iter().map(|v| v.powi(k)).sum::<f64>() / n;
        let (m2, m3, m4) = (m(2), m(3), m(4));
        let se = |variance: f64| 5.0 * (variance / n).sqrt();
        assert!(mean.abs() < se(1.0), "mean {mean}");
        assert!((m2 - 1.0).abs() < se(2.0), "variance {m2}");
        assert!(m3.abs() < se(15.0), "third moment {m3}");
        assert!((m4 - 3.0).abs() < se(96.0), "fourth moment {m4}");
        // Tails: P(|x| > 2), P(|x| > 3), P(|x| > 4) of the normal distribution.
        for (t, p) in [
            (2.0, 0.045_500_26),
            (3.0, 0.002_699_796),
            (4.0, 6.334_248e-5),
        ] {
            let seen = x.iter().filter(|v| v.abs() > t).count() as f64 / n;
            assert!(
                (seen - p).abs() < se(p * (1.0 - p)),
                "P(|x| > {t}) = {seen}, not {p}"
            );
        }
        // Neighbours, the pair of one word (cosine and sine, BATCH/2 apart), and the same
        // lane one batch later: uncorrelated.
        for lag in [1, LANES, BATCH, 2 * BATCH + 3] {
            let c = x.iter().zip(&x[lag..]).map(|(a, b)| a * b).sum::<f64>() / n;
            assert!(c.abs() < se(1.0), "lag {lag}: correlation {c}");
            let c2 = x
                .iter()
                .zip(&x[lag..])
                .map(|(a, b)| a * a * b * b)
                .sum::<f64>()
                / n;
            assert!((c2 - 1.0).abs() < se(8.0), "lag {lag}: x²y² {c2}");
        }
        let largest = x.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(largest > 4.5 && largest < 6.67, "largest {largest}");
    }
}
