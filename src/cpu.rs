//! What the CPU can do, for the real-time kernels that carry a build for wider vectors
//! (the lock-in bank, the synthesis loop, the ADC's filter) beside the portable one. The
//! standard library caches the answers, so asking is cheap; the kernels ask once, when
//! they are built.

/// Makes the calling function's stack frame aligned to 64 bytes (a cache line): inlined
/// at the top of a vector kernel, it holds a 64-byte-aligned value whose address is
/// taken, so the compiler realigns the frame, and the vector registers the kernel spills
/// and reloads in its loop sit in whole cache lines. Without it the frame's alignment
/// follows the stack's, which address-space randomisation shifts by 16 bytes from run to
/// run: in about half the runs each 512-bit spill split across two cache lines and the
/// synthesis loop ran 30 % slower (docs/benchmarks.md).
#[inline(always)]
pub(crate) fn align_frame() {
    #[repr(align(64))]
    struct Line(#[allow(dead_code)] [u8; 64]);
    let mut line = Line([0; 64]);
    std::hint::black_box(&mut line);
}

/// Whether the CPU has AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
pub fn fma_available() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Whether the CPU has AVX2 and FMA (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn fma_available() -> bool {
    false
}

/// Whether the CPU has AVX2.
#[cfg(target_arch = "x86_64")]
pub fn avx2_available() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Whether the CPU has AVX2 (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx2_available() -> bool {
    false
}

/// Whether the CPU has AVX-512 (the foundation instructions) and AVX2.
#[cfg(target_arch = "x86_64")]
pub fn avx512_available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx2")
}

/// Whether the CPU has AVX-512 (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx512_available() -> bool {
    false
}
