//! Four lanes: glam's [`Vec4`] (SSE2, NEON or wasm SIMD where the target has them, four plain floats
//! elsewhere), the lanes every target has.

use super::{Bits, Lanes};
use glam::{Vec3, Vec4};

impl Lanes for Vec4 {
    const N: usize = 4;

    #[inline(always)]
    fn splat(v: f32) -> Self {
        Vec4::splat(v)
    }

    #[inline(always)]
    fn load(v: &[Vec3]) -> [Self; 3] {
        let [a, b, c, d] = match v.first_chunk::<4>() {
            #[cfg(target_arch = "x86_64")]
            Some(four) => return transpose_sse(four).map(Vec4::from),
            #[cfg(not(target_arch = "x86_64"))]
            Some(&four) => four,
            None => std::array::from_fn(|k| v.get(k).copied().unwrap_or(Vec3::ZERO)),
        };
        [
            Vec4::new(a.x, b.x, c.x, d.x),
            Vec4::new(a.y, b.y, c.y, d.y),
            Vec4::new(a.z, b.z, c.z, d.z),
        ]
    }

    #[inline(always)]
    fn compiled<R>(f: impl FnOnce() -> R) -> R {
        crate::dispatch::widest(f)
    }

    #[inline(always)]
    fn max(self, other: Self) -> Self {
        Vec4::max(self, other)
    }

    #[inline(always)]
    fn sqrt(self) -> Self {
        Vec4::sqrt(self)
    }

    #[inline(always)]
    fn trunc(self) -> Self {
        Vec4::trunc(self)
    }

    #[inline(always)]
    fn le(self, other: Self) -> Bits {
        self.cmple(other).bitmask()
    }

    #[inline(always)]
    fn lt(self, other: Self) -> Bits {
        self.cmplt(other).bitmask()
    }

    #[inline(always)]
    fn ge(self, other: Self) -> Bits {
        self.cmpge(other).bitmask()
    }

    #[inline(always)]
    fn gt(self, other: Self) -> Bits {
        self.cmpgt(other).bitmask()
    }

    #[inline(always)]
    fn equal(self, other: Self) -> Bits {
        self.cmpeq(other).bitmask()
    }

    #[inline(always)]
    fn finite(self) -> Bits {
        self.is_finite_mask().bitmask()
    }

    #[inline(always)]
    unsafe fn gather_within(table: &[f32], res: usize, x: Self, y: Self, read: Bits) -> Self {
        let (x, y) = (x.to_array(), y.to_array());
        Vec4::from_array(std::array::from_fn(|k| {
            if read >> k & 1 == 0 {
                return f32::NAN;
            }
            // SAFETY: lane `k` of `read` has `x` and `y` in `[0, res)`, `res` at most 16384 (the caller's
            // promise), so they truncate to an `i32` (where `as usize`, saturating, costs about fifteen
            // instructions a coordinate on x86-64).
            let (i, j) = unsafe {
                (
                    x[k].to_int_unchecked::<i32>() as usize,
                    y[k].to_int_unchecked::<i32>() as usize,
                )
            };
            table[j * res + i]
        }))
    }
}

/// Four points on x86-64, transposed: the 48 bytes they are, as three loads of four floats
/// (`x0 y0 z0 x1 | y1 z1 x2 y2 | z2 x3 y3 z3`) transposed by six shuffles, the same lanes as gathering
/// them coordinate by coordinate (twelve scalar loads and nine shuffles, which the compiler does not
/// merge). About 2% of a quick selective pass.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn transpose_sse(four: &[Vec3; 4]) -> [std::arch::x86_64::__m128; 3] {
    use std::arch::x86_64::*;
    // `_MM_SHUFFLE(d, c, b, a)`: lanes a and b of the first operand, c and d of the second.
    const fn pick(a: i32, b: i32, c: i32, d: i32) -> i32 {
        d << 6 | c << 4 | b << 2 | a
    }
    let f = four.as_ptr().cast::<f32>();
    // SAFETY: SSE is part of the x86-64 baseline, and `Vec3` is three `f32`s (`repr(C)`, no padding), so
    // four of them are twelve floats: each unaligned load reads four of them, at 0, 4 and 8.
    unsafe {
        let (m0, m1, m2) = (
            _mm_loadu_ps(f),
            _mm_loadu_ps(f.add(4)),
            _mm_loadu_ps(f.add(8)),
        );
        let x2x3 = _mm_shuffle_ps::<{ pick(2, 3, 0, 1) }>(m1, m2); // x2 y2 z2 x3
        let yz01 = _mm_shuffle_ps::<{ pick(1, 2, 0, 1) }>(m0, m1); // y0 z0 y1 z1
        let y2y3 = _mm_shuffle_ps::<{ pick(3, 3, 2, 2) }>(m1, m2); // y2 y2 y3 y3
        [
            _mm_shuffle_ps::<{ pick(0, 3, 0, 3) }>(m0, x2x3),
            _mm_shuffle_ps::<{ pick(0, 2, 0, 2) }>(yz01, y2y3),
            _mm_shuffle_ps::<{ pick(1, 3, 0, 3) }>(yz01, m2),
        ]
    }
}
