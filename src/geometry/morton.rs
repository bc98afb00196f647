//! Morton (Z-order) codes of points inside a box.
//!
//! A point is quantised to a grid over the box (10 bits per axis for the 30-bit code, 21 for the 63-bit code)
//! and the bits of the three coordinates are interleaved, x in the lowest position of each triple. Points
//! outside the box are clamped to it; a flat box axis quantises to 0.

use super::Aabb;
use glam::Vec3;

/// Spreads the low 10 bits of `v` so that bit `i` lands at bit `3i`.
#[inline]
pub(crate) fn spread10(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    x = (x | (x << 2)) & 0x0924_9249;
    x
}

/// Spreads the low 21 bits of `v` so that bit `i` lands at bit `3i`.
#[inline]
fn spread21(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Maps `p` into `[0, 1]^3` relative to `bounds` (clamped; 0 on flat axes).
#[inline]
fn normalise(p: Vec3, bounds: &Aabb) -> Vec3 {
    let e = bounds.extent();
    let inv = Vec3::select(e.cmpgt(Vec3::ZERO), e.recip(), Vec3::ZERO);
    ((p - bounds.min) * inv).clamp(Vec3::ZERO, Vec3::ONE)
}

/// Quantises a value in `[0, 1]` to `0..2^bits` (the top value is folded into the last cell).
#[inline]
fn quantise(x: f32, cells: f32) -> u32 {
    (x * cells).min(cells - 1.0) as u32
}

/// 30-bit Morton code of `p` in `bounds` (1024 cells per axis).
#[inline]
pub fn morton30(p: Vec3, bounds: &Aabb) -> u32 {
    code30(normalise(p, bounds))
}

/// 30-bit Morton code of `p` on a grid of cubic cells: every axis is scaled by the box's largest extent, so
/// a thin axis gets fewer cells instead of being stretched to 1024 of them. Use it where the curve's
/// order should follow distances (PLOC's initial order); it costs the same as [`morton30`].
#[inline]
pub fn morton30_cube(p: Vec3, bounds: &Aabb) -> u32 {
    let m = bounds.extent().max_element();
    let inv = if m > 0.0 { m.recip() } else { 0.0 };
    code30(((p - bounds.min) * inv).clamp(Vec3::ZERO, Vec3::ONE))
}

/// The interleaved 30-bit code of a point in `[0, 1]^3`.
#[inline]
fn code30(n: Vec3) -> u32 {
    let q = |x| spread10(quantise(x, 1024.0));
    q(n.x) | (q(n.y) << 1) | (q(n.z) << 2)
}

/// 63-bit Morton code of `p` in `bounds` (2,097,152 cells per axis).
#[inline]
pub fn morton63(p: Vec3, bounds: &Aabb) -> u64 {
    let n = normalise(p, bounds);
    let q = |x| spread21(quantise(x, 2_097_152.0) as u64);
    q(n.x) | (q(n.y) << 1) | (q(n.z) << 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference interleave, one bit at a time.
    fn naive(x: u64, y: u64, z: u64, bits: u32) -> u64 {
        (0..bits).fold(0, |acc, i| {
            acc | ((x >> i) & 1) << (3 * i)
                | ((y >> i) & 1) << (3 * i + 1)
                | ((z >> i) & 1) << (3 * i + 2)
        })
    }

    #[test]
    fn spreads_match_bitwise_reference() {
        for v in [0u32, 1, 2, 3, 0x155, 0x2aa, 0x3ff, 513] {
            assert_eq!(spread10(v) as u64, naive(v as u64, 0, 0, 10));
        }
        for v in [0u64, 1, 0x15_5555, 0x0a_aaaa, 0x1f_ffff, 1_234_567] {
            assert_eq!(spread21(v), naive(v, 0, 0, 21));
        }
    }

    #[test]
    fn corners_and_clamping() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        assert_eq!(morton30(Vec3::ZERO, &b), 0);
        assert_eq!(morton30(Vec3::ONE, &b), (1 << 30) - 1);
        assert_eq!(morton63(Vec3::ONE, &b), (1 << 63) - 1);
        assert_eq!(morton30(Vec3::splat(5.0), &b), (1 << 30) - 1);
        assert_eq!(morton30(Vec3::splat(-5.0), &b), 0);
        // x is the lowest bit of each triple.
        assert_eq!(
            morton30(Vec3::new(1.0, 0.0, 0.0), &b),
            naive(1023, 0, 0, 10) as u32
        );
        // Flat box: everything quantises to zero on that axis.
        let flat = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0));
        assert_eq!(morton30(Vec3::new(0.0, 0.0, 0.0), &flat), 0);
    }

    #[test]
    fn cube_codes_scale_every_axis_by_the_largest_extent() {
        // A 4 × 1 × 0.25 box: 1024 cells along x, 256 along y, 64 along z.
        let b = Aabb::new(Vec3::ZERO, Vec3::new(4.0, 1.0, 0.25));
        assert_eq!(
            morton30_cube(Vec3::new(4.0, 1.0, 0.25), &b),
            naive(1023, 256, 64, 10) as u32
        );
        assert_eq!(
            morton30_cube(Vec3::new(2.0, 0.5, 0.125), &b),
            naive(512, 128, 32, 10) as u32
        );
        // Per-axis codes stretch the thin axes to the whole grid.
        assert_eq!(
            morton30(Vec3::new(2.0, 0.5, 0.125), &b),
            naive(512, 512, 512, 10) as u32
        );
        let point = Aabb::new(Vec3::ONE, Vec3::ONE);
        assert_eq!(morton30_cube(Vec3::ONE, &point), 0);
    }
}
