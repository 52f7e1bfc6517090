//! How the daemon hands memory back to the system after large settings (a 2^20-point
//! spectrum's plan and its 7 MB messages) are undone. glibc keeps freed memory otherwise:
//! a thread arena's free top is never returned by `malloc_trim`, and after a large mapped
//! block is freed glibc raises its mapping threshold to that size, so the next ones land
//! in such arenas.

/// Blocks at or above this size (bytes) are mapped on their own and unmapped when freed.
const MAP_AT: i32 = 1 << 20;

/// Fixes glibc's mapping threshold at [`MAP_AT`] for the whole process (which also stops
/// its dynamic growth): every large message or buffer goes back to the system the moment
/// it is freed. Call once at start-up; the real-time threads never allocate, so the cost
/// of a map per large block falls on the server's threads only.
pub fn map_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's tuning parameters.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAP_AT);
    }
}

/// Hands memory the allocator holds free back to the system.
pub(crate) fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory of the allocator's arenas to the system.
    unsafe {
        libc::malloc_trim(0);
    }
}
