//! Run-time dispatch to the instruction sets the running CPU has beyond the target's baseline.
//!
//! The crate is built for the target's baseline (SSE2 on x86-64) unless the application asks for more
//! (`-C target-cpu`). A few hot loops are compiled a second time for the AVX2 generation of x86-64 (AVX2,
//! FMA, BMI1, BMI2, LZCNT, POPCNT: three-operand SIMD, one-instruction bit counts) and run that way where
//! the CPU has it ([`wide_available`]): the selective shadow pass's classification, shadow map and `Δ`
//! table ([`shadows`](crate::shadows); about 5% of a selective pass on the crowd), and the classification
//! takes eight pixels at a time in AVX registers there instead of four (`wide_only`; about a seventh of
//! a selective pass on the quick crowd). Same operations in the same order — Rust never fuses a product
//! and a sum into one rounding unless asked (`mul_add`) — so the results are bit for bit the baseline
//! build's.

/// Calls `f`, compiled for AVX2, FMA, BMI1, BMI2, LZCNT and POPCNT where the running CPU has them (x86-64
/// only; elsewhere, or on an older CPU, as built). Costs one cached feature check per call: wrap a loop,
/// not one item. Only code inlined into `f` is compiled twice — mark `f` `#[inline(always)]` where it is
/// a closure that calls out, and keep the functions it calls `#[inline]` — and work it hands to other
/// threads runs as built.
#[inline(always)]
pub(crate) fn widest<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if wide_available() {
        // SAFETY: the CPU has every feature `avx2` is compiled for (checked just above).
        return unsafe { avx2(f) };
    }
    f()
}

/// Calls `f` compiled for the AVX2 generation: for code that exists only where the CPU has it (eight
/// SIMD lanes chosen after [`wide_available`]). Panics where the CPU lacks it (even under the testing
/// hook's baseline build, which only steers [`widest`]).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn wide_only<R>(f: impl FnOnce() -> R) -> R {
    if has_wide() {
        // SAFETY: the CPU has every feature `avx2` is compiled for (checked just above).
        return unsafe { avx2(f) };
    }
    panic!("code built for the AVX2 generation reached on a CPU without it")
}

/// Whether the loops built twice run their AVX2-generation build on this CPU (x86-64 with AVX2, FMA, BMI1,
/// BMI2, LZCNT and POPCNT; never elsewhere). The check is cached by the standard library.
pub fn wide_available() -> bool {
    #[cfg(feature = "testing")]
    if BASELINE_ONLY.load(std::sync::atomic::Ordering::Relaxed) {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    if has_wide() {
        return true;
    }
    false
}

/// Whether the CPU has every feature `avx2` is compiled for (cached by the standard library), whatever
/// the testing hook says.
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_wide() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
        && std::arch::is_x86_feature_detected!("bmi1")
        && std::arch::is_x86_feature_detected!("bmi2")
        && std::arch::is_x86_feature_detected!("lzcnt")
        && std::arch::is_x86_feature_detected!("popcnt")
}

#[cfg(feature = "testing")]
static BASELINE_ONLY: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Test hook (feature `testing`): with `true`, the loops built twice run their baseline build, on every thread, until
/// called with `false` — for tests that compare the two builds of a loop. Both give the same results, so a
/// test running meanwhile is not disturbed.
#[cfg(feature = "testing")]
pub fn baseline_only_for_tests(baseline: bool) {
    BASELINE_ONLY.store(baseline, std::sync::atomic::Ordering::Relaxed);
}

/// `f()`, with `f` inlined and compiled for the AVX2 generation of x86-64.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}
