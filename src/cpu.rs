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
/// synthesis loop ran markedly slower (docs/benchmarks.md has the figures).
#[inline(always)]
pub(crate) fn align_frame() {
    #[repr(align(64))]
    struct Line(#[allow(dead_code)] [u8; 64]);
    let mut line = Line([0; 64]);
    std::hint::black_box(&mut line);
}

/// The widest instruction set the vector kernels may use, capped by the environment
/// variable `FTAFM_ISA` (`avx512`, `avx2` or `portable`; unset: whatever the CPU has). With
/// it an AVX-512 machine runs, and measures, the builds an AVX2-only one runs (the same
/// bits: every build gives the portable build's). Read once.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// No vector kernels: the portable code.
    Portable,
    /// AVX2 and FMA.
    Avx2,
    /// AVX-512F (with AVX2 and FMA).
    Avx512,
}

impl Isa {
    /// The name `FTAFM_ISA` takes: `avx512`, `avx2` or `portable`.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

/// The build the vector kernels run here: the widest the CPU has, capped by `FTAFM_ISA`.
pub fn vector_build() -> Isa {
    if avx512_available() {
        Isa::Avx512
    } else if fma_available() {
        Isa::Avx2
    } else {
        Isa::Portable
    }
}

/// The machine a figure was measured on, for benchmark reports: the CPU's model name with
/// its family and model numbers where `/proc/cpuinfo` gives them (virtual machines often
/// name only the vendor's line, "AMD EPYC", and the numbers tell the generation), the CPUs
/// this process may use, and the vector build.
pub fn machine() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |name: &str| {
        info.lines()
            .find(|l| l.split(':').next().is_some_and(|k| k.trim() == name))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_owned())
    };
    let mut cpu = field("model name").unwrap_or_else(|| std::env::consts::ARCH.to_owned());
    if let (Some(family), Some(model)) = (field("cpu family"), field("model")) {
        cpu = format!("{cpu} (family {family} model {model})");
    }
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    format!("{cpu}, {cpus} CPUs, vector build {}", vector_build().name())
}

/// The cap `FTAFM_ISA` asks for, or an error naming the variable and its allowed values
/// (the command line checks it before it starts anything).
pub fn isa_from_env() -> Result<Isa, String> {
    match std::env::var("FTAFM_ISA").as_deref() {
        Err(_) | Ok("") | Ok("avx512") => Ok(Isa::Avx512),
        Ok("avx2") => Ok(Isa::Avx2),
        Ok("portable") => Ok(Isa::Portable),
        Ok(other) => Err(format!(
            "FTAFM_ISA must be one of avx512, avx2, portable (or unset), not {other:?}"
        )),
    }
}

/// The cap set by `FTAFM_ISA`. Panics with [`isa_from_env`]'s error on any other value: a
/// benchmark run on the wrong instruction set would report the wrong thing.
pub fn isa_cap() -> Isa {
    static CAP: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
    *CAP.get_or_init(|| isa_from_env().unwrap_or_else(|e| panic!("{e}")))
}

/// Whether the CPU has AVX2 and FMA (and `FTAFM_ISA` allows them).
#[cfg(target_arch = "x86_64")]
pub fn fma_available() -> bool {
    isa_cap() >= Isa::Avx2
        && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
}

/// Whether the CPU has AVX2 and FMA (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn fma_available() -> bool {
    false
}

/// Whether the CPU has AVX2 (and `FTAFM_ISA` allows it).
#[cfg(target_arch = "x86_64")]
pub fn avx2_available() -> bool {
    isa_cap() >= Isa::Avx2 && std::arch::is_x86_feature_detected!("avx2")
}

/// Whether the CPU has AVX2 (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx2_available() -> bool {
    false
}

/// Whether the CPU has AVX-512 (the foundation instructions) and AVX2 (and `FTAFM_ISA`
/// allows them).
#[cfg(target_arch = "x86_64")]
pub fn avx512_available() -> bool {
    isa_cap() >= Isa::Avx512
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx2")
}

/// Whether the CPU has AVX-512 (never, off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn avx512_available() -> bool {
    false
}

/// The core's clock while it runs this thread (GHz), estimated: a chain of dependent
/// integer additions, one a cycle on every x86-64 core, timed by the wall clock, the best
/// of five runs of 40 million additions (≈ 10 ms each at 4 GHz) so that a run the thread
/// lost the core in counts least. Under a hypervisor `/proc/cpuinfo` often gives only the
/// nominal clock, and without hardware counters there is no other: with it a benchmark's
/// throughput can be read as cycles a sample, which compares machines (docs/benchmarks.md).
/// `None` off x86-64.
#[cfg(target_arch = "x86_64")]
pub fn clock_ghz() -> Option<f64> {
    const ITERATIONS: u64 = 10_000_000;
    let mut best = f64::INFINITY;
    for _ in 0..5 {
        let start = std::time::Instant::now();
        let (mut x, mut n) = (0u64, ITERATIONS);
        // SAFETY: register arithmetic and a loop on registers only: no memory, no stack.
        // The addend is a register, not an immediate: recent Intel cores (Golden Cove and
        // later) fold chains of immediate additions at rename, several a cycle, which read
        // as a 10 GHz clock.
        unsafe {
            std::arch::asm!(
                "2:",
                "add {x}, {one}",
                "add {x}, {one}",
                "add {x}, {one}",
                "add {x}, {one}",
                "sub {n}, 1",
                "jnz 2b",
                x = inout(reg) x,
                n = inout(reg) n,
                one = in(reg) 1u64,
                options(nomem, nostack),
            );
        }
        std::hint::black_box((x, n));
        best = best.min(start.elapsed().as_secs_f64());
    }
    (best > 0.0).then(|| 4.0 * ITERATIONS as f64 / best / 1e9)
}

/// The core's clock (never estimated off x86-64).
#[cfg(not(target_arch = "x86_64"))]
pub fn clock_ghz() -> Option<f64> {
    None
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_clock_estimate_is_a_clock() {
        // One dependent addition a cycle at most, so never above the clock (no x86-64 core
        // runs at 8 GHz); a loaded machine lowers it, so the floor is only that it is a
        // clock at all, not a fixed share of the nominal one.
        let ghz = super::clock_ghz().expect("x86-64 has an estimate");
        assert!((0.1..8.0).contains(&ghz), "{ghz} GHz");
    }
}
