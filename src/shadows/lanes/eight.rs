//! Eight lanes: AVX2 on x86-64. [`F8`] is private to [`lanes`](super): the only way to it is
//! [`widest`](super::widest), which checks that the CPU has the AVX2 generation first, so every
//! instruction below runs on a CPU that has it (and the lanes' tests, behind the same check). Every `F8`
//! starts as a [`splat`](Lanes::splat) or a [`load`](Lanes::load), which check it again in debug builds.

use super::{Bits, Lanes, four::transpose_sse};
use glam::Vec3;
use std::arch::x86_64::*;
use std::ops::{Add, Div, Mul, Sub};

/// Eight `f32` lanes in one AVX register.
#[derive(Clone, Copy)]
pub(super) struct F8(__m256);

// SAFETY (every `unsafe` block in this module): the intrinsics need AVX or AVX2, which the CPU has
// wherever an `F8` exists (see the module's docs); loads and gathers state their own bounds.

/// Eight points transposed: each half by [`transpose_sse`], the halves joined.
#[inline(always)]
fn transpose(eight: &[Vec3; 8]) -> [F8; 3] {
    let (low, high) = eight.split_at(4);
    let (low, high) = (
        transpose_sse(low.try_into().expect("four points")),
        transpose_sse(high.try_into().expect("four points")),
    );
    unsafe {
        [
            F8(_mm256_set_m128(high[0], low[0])),
            F8(_mm256_set_m128(high[1], low[1])),
            F8(_mm256_set_m128(high[2], low[2])),
        ]
    }
}

macro_rules! arithmetic {
    ($($op:ident $fn:ident $intrinsic:ident),*) => {$(
        impl $op for F8 {
            type Output = F8;
            #[inline(always)]
            fn $fn(self, other: F8) -> F8 {
                F8(unsafe { $intrinsic(self.0, other.0) })
            }
        }
    )*};
}

arithmetic!(Add add _mm256_add_ps, Sub sub _mm256_sub_ps, Mul mul _mm256_mul_ps, Div div _mm256_div_ps);

impl F8 {
    /// The lanes where `self ∘ other` holds (an ordered compare: false where either is NaN), as bits.
    #[inline(always)]
    fn compare<const OP: i32>(self, other: F8) -> Bits {
        unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<OP>(self.0, other.0)) as Bits }
    }
}

impl Lanes for F8 {
    const N: usize = 8;

    #[inline(always)]
    fn splat(v: f32) -> Self {
        debug_assert!(crate::dispatch::has_wide(), "eight lanes need AVX2");
        F8(unsafe { _mm256_set1_ps(v) })
    }

    #[inline(always)]
    fn load(v: &[Vec3]) -> [Self; 3] {
        debug_assert!(crate::dispatch::has_wide(), "eight lanes need AVX2");
        match v.first_chunk::<8>() {
            Some(eight) => transpose(eight),
            None => {
                let mut padded = [Vec3::ZERO; 8];
                padded[..v.len()].copy_from_slice(v);
                transpose(&padded)
            }
        }
    }

    #[inline(always)]
    fn compiled<R>(f: impl FnOnce() -> R) -> R {
        crate::dispatch::wide_only(f)
    }

    #[inline(always)]
    fn max(self, other: Self) -> Self {
        F8(unsafe { _mm256_max_ps(self.0, other.0) })
    }

    #[inline(always)]
    fn sqrt(self) -> Self {
        F8(unsafe { _mm256_sqrt_ps(self.0) })
    }

    #[inline(always)]
    fn trunc(self) -> Self {
        F8(unsafe { _mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(self.0) })
    }

    #[inline(always)]
    fn le(self, other: Self) -> Bits {
        self.compare::<_CMP_LE_OQ>(other)
    }

    #[inline(always)]
    fn lt(self, other: Self) -> Bits {
        self.compare::<_CMP_LT_OQ>(other)
    }

    #[inline(always)]
    fn ge(self, other: Self) -> Bits {
        self.compare::<_CMP_GE_OQ>(other)
    }

    #[inline(always)]
    fn gt(self, other: Self) -> Bits {
        self.compare::<_CMP_GT_OQ>(other)
    }

    #[inline(always)]
    fn equal(self, other: Self) -> Bits {
        self.compare::<_CMP_EQ_OQ>(other)
    }

    #[inline(always)]
    fn finite(self) -> Bits {
        let abs = F8(unsafe { _mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0) });
        abs.lt(Self::splat(f32::INFINITY))
    }

    /// One masked gather: the lanes not read keep NaN.
    #[inline(always)]
    unsafe fn gather_within(table: &[f32], res: usize, x: Self, y: Self, read: Bits) -> Self {
        // SAFETY: the lanes in `read` have `x` and `y` in `[0, res)`, `res² ≤ table.len()` (the caller's
        // promise), so they truncate to texel indices whose `j · res + i` is below `res²` (and below
        // 2²⁸: an `i32`); the mask keeps every other lane from being read.
        unsafe {
            let (i, j) = (_mm256_cvttps_epi32(x.0), _mm256_cvttps_epi32(y.0));
            let at = _mm256_add_epi32(_mm256_mullo_epi32(j, _mm256_set1_epi32(res as i32)), i);
            let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let wanted = _mm256_and_si256(_mm256_set1_epi32(read as i32), bit);
            let mask = _mm256_castsi256_ps(_mm256_cmpeq_epi32(wanted, bit));
            F8(_mm256_mask_i32gather_ps::<4>(
                _mm256_set1_ps(f32::NAN),
                table.as_ptr(),
                at,
                mask,
            ))
        }
    }
}
