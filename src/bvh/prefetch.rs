//! A cache hint for walks that know which lines they will read next.

/// Asks the CPU to bring the cache line at `at` into every cache level (x86-64; nothing elsewhere). A hint
/// only: it reads nothing and cannot fault, whatever the address, so `at` may point past a slice or be
/// computed with `wrapping_add`.
#[inline(always)]
pub(crate) fn prefetch<T>(at: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of the x86-64 baseline; a prefetch reads nothing and never faults.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(at.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = at;
}
