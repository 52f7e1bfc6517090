//! What the CPU can do, for the real-time kernels that carry a build for wider vectors
//! (the lock-in bank, the synthesis loop, the ADC's filter) beside the portable one. The
//! standard library caches the answers, so asking is cheap; the kernels ask once, when
//! they are built.

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
