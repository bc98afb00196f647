//! The four-box slab test of a [`WideNode`]: SSE on x86-64, NEON on aarch64, a portable loop elsewhere.
//!
//! Every path computes, lane by lane, exactly the operations of [`Ray::intersect_aabb`] in the same order
//! (subtract, multiply, `max_keep`/`min_keep` chains, the far distance moved out by `2 ulp` of its size,
//! `<=`), with no fused multiply-add, so all three give the same bits as the binary tree's scalar test and
//! as each other: a ray that touches a box is never culled, NaN axes (a ray in a slab plane) fall out the
//! same way.
//!
//! SSE2 is part of the x86-64 baseline and NEON of the aarch64 one, so no runtime detection is needed for
//! four lanes. Each SIMD function is one `unsafe` block: the intrinsics need it although the baseline
//! guarantees them, and the loads and stores take pointers to the node's `[f32; 4]` rows.

use super::WideNode;
#[cfg(any(target_arch = "x86_64", target_arch = "aarch64"))]
use crate::geometry::ROBUST_FAR_SLACK;
use crate::geometry::{Ray, max_keep, min_keep, robust_far};

/// Per-ray constants of the four-box test, computed once per query.
#[derive(Clone, Copy, Debug)]
pub struct RayLanes {
    /// Row of [`WideNode::bounds`] holding the near plane of each axis (min rows 0..3, max rows 3..6),
    /// chosen by the direction's sign as `Ray::intersect_aabb` does.
    near: [usize; 3],
    /// Row holding the far plane of each axis.
    far: [usize; 3],
    origin: [f32; 3],
    inv_dir: [f32; 3],
    tmin: f32,
}

impl RayLanes {
    /// Constants of no ray, for storage that a ray's own constants overwrite before use.
    pub(crate) const EMPTY: RayLanes = RayLanes {
        near: [0, 1, 2],
        far: [3, 4, 5],
        origin: [0.0; 3],
        inv_dir: [0.0; 3],
        tmin: 0.0,
    };

    /// The constants for `ray` (any ray; invalid ones simply produce meaningless masks).
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        let neg = ray.dir_neg();
        let neg = [neg.x, neg.y, neg.z];
        Self {
            near: std::array::from_fn(|a| if neg[a] { 3 + a } else { a }),
            far: std::array::from_fn(|a| if neg[a] { a } else { 3 + a }),
            origin: ray.origin.to_array(),
            inv_dir: ray.inv_dir().to_array(),
            tmin: ray.tmin,
        }
    }
}

/// Which lanes' boxes the ray reaches within `tmax` (bit `i` for lane `i`) and each lane's entry distance
/// (meaningful for the set bits only). Which implementation runs is fixed at compile time by the target.
#[inline(always)]
pub fn hit4(node: &WideNode, r: &RayLanes, tmax: f32) -> (u32, [f32; 4]) {
    #[cfg(target_arch = "x86_64")]
    {
        hit4_sse(node, r, tmax)
    }
    #[cfg(target_arch = "aarch64")]
    {
        hit4_neon(node, r, tmax)
    }
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    {
        hit4_portable(node, r, tmax)
    }
}

/// The reference path: one lane at a time, plain `f32`.
#[inline]
pub fn hit4_portable(node: &WideNode, r: &RayLanes, tmax: f32) -> (u32, [f32; 4]) {
    let b = &node.bounds;
    let mut mask = 0;
    let mut near = [0.0; 4];
    for i in 0..4 {
        let t = |row: usize, a: usize| (b[row][i] - r.origin[a]) * r.inv_dir[a];
        let tnear = max_keep(
            t(r.near[0], 0),
            max_keep(t(r.near[1], 1), max_keep(t(r.near[2], 2), r.tmin)),
        );
        let tfar = min_keep(
            t(r.far[0], 0),
            min_keep(t(r.far[1], 1), min_keep(t(r.far[2], 2), f32::INFINITY)),
        );
        if tnear <= min_keep(robust_far(tfar), tmax) {
            mask |= 1 << i;
        }
        near[i] = tnear;
    }
    (mask, near)
}

/// [`robust_far`] on four lanes, with the scalar form's operations (the slack takes each lane's sign bit).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn robust_far_sse(far: std::arch::x86_64::__m128) -> std::arch::x86_64::__m128 {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of the x86-64 baseline; register operations only.
    unsafe {
        let sign = _mm_and_ps(far, _mm_set1_ps(-0.0));
        let slack = _mm_or_ps(_mm_set1_ps(ROBUST_FAR_SLACK), sign);
        _mm_mul_ps(far, _mm_add_ps(_mm_set1_ps(1.0), slack))
    }
}

/// SSE2 (x86-64 baseline): `maxps`/`minps` return their second operand on NaN, exactly `max_keep`/`min_keep`.
#[cfg(target_arch = "x86_64")]
#[inline]
pub fn hit4_sse(node: &WideNode, r: &RayLanes, tmax: f32) -> (u32, [f32; 4]) {
    use std::arch::x86_64::*;
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline, so every intrinsic here is available; the loads
    // read the node's `[f32; 4]` rows (16 bytes each) and the store writes `near` (16 bytes), all unaligned
    // forms.
    unsafe {
        let row = |i: usize| _mm_loadu_ps(node.bounds[i].as_ptr());
        let t = |rw: usize, a: usize| {
            _mm_mul_ps(
                _mm_sub_ps(row(rw), _mm_set1_ps(r.origin[a])),
                _mm_set1_ps(r.inv_dir[a]),
            )
        };
        let tnear = _mm_max_ps(
            t(r.near[0], 0),
            _mm_max_ps(
                t(r.near[1], 1),
                _mm_max_ps(t(r.near[2], 2), _mm_set1_ps(r.tmin)),
            ),
        );
        let tfar = _mm_min_ps(
            t(r.far[0], 0),
            _mm_min_ps(
                t(r.far[1], 1),
                _mm_min_ps(t(r.far[2], 2), _mm_set1_ps(f32::INFINITY)),
            ),
        );
        let limit = _mm_min_ps(robust_far_sse(tfar), _mm_set1_ps(tmax));
        let mask = _mm_movemask_ps(_mm_cmple_ps(tnear, limit)) as u32;
        let mut near = [0.0f32; 4];
        _mm_storeu_ps(near.as_mut_ptr(), tnear);
        (mask, near)
    }
}

/// NEON (aarch64 baseline): `vmaxq`/`vminq` propagate NaN, so `max_keep`/`min_keep` are a compare and a
/// select, keeping the running value when the lane is NaN.
#[cfg(target_arch = "aarch64")]
#[inline]
pub fn hit4_neon(node: &WideNode, r: &RayLanes, tmax: f32) -> (u32, [f32; 4]) {
    use std::arch::aarch64::*;
    // SAFETY: NEON is part of the aarch64 baseline; the loads read the node's `[f32; 4]` rows and a local
    // `[u32; 4]` (16 bytes each) and the store writes `near` (16 bytes), none with an alignment requirement.
    unsafe {
        let row = |i: usize| vld1q_f32(node.bounds[i].as_ptr());
        let max_k = |x, acc| vbslq_f32(vcgtq_f32(x, acc), x, acc);
        let min_k = |x, acc| vbslq_f32(vcltq_f32(x, acc), x, acc);
        let t = |rw: usize, a: usize| {
            vmulq_f32(
                vsubq_f32(row(rw), vdupq_n_f32(r.origin[a])),
                vdupq_n_f32(r.inv_dir[a]),
            )
        };
        let tnear = max_k(
            t(r.near[0], 0),
            max_k(t(r.near[1], 1), max_k(t(r.near[2], 2), vdupq_n_f32(r.tmin))),
        );
        let tfar = min_k(
            t(r.far[0], 0),
            min_k(
                t(r.far[1], 1),
                min_k(t(r.far[2], 2), vdupq_n_f32(f32::INFINITY)),
            ),
        );
        let sign = vandq_u32(vreinterpretq_u32_f32(tfar), vdupq_n_u32(1 << 31));
        let slack = vorrq_u32(vreinterpretq_u32_f32(vdupq_n_f32(ROBUST_FAR_SLACK)), sign);
        let far = vmulq_f32(
            tfar,
            vaddq_f32(vdupq_n_f32(1.0), vreinterpretq_f32_u32(slack)),
        );
        let limit = min_k(far, vdupq_n_f32(tmax));
        let hit = vcleq_f32(tnear, limit);
        let lane_bits = vld1q_u32([1u32, 2, 4, 8].as_ptr());
        let bits = vandq_u32(hit, lane_bits);
        let mask = vaddvq_u32(bits);
        let mut near = [0.0f32; 4];
        vst1q_f32(near.as_mut_ptr(), tnear);
        (mask, near)
    }
}
