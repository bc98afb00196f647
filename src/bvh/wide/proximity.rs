//! Proximity walks of a [`WideBvh`]: nearest-first by box distance (closest points) and by box overlap
//! (shape overlaps), four child boxes per SIMD test.
//!
//! When to use: queries in the mesh's own frame on a mesh that has a wide tree ([`MeshBvh::closest_point`],
//! [`MeshBvh::overlapping`] do so themselves). The box tests run in `f32` on the lanes as stored; the
//! distance walk only ever prunes a box whose `f32` distance, shrunk by more than its rounding, exceeds the
//! caller's `f64` bound, so it visits every leaf the exact binary walk would need. Given the lanes' discs
//! (`discs.rs`), it also prunes a leaf whose disc bound does (most leaves a box lets through:
//! a box is as thick as its triangle is wide, a disc as thin as the triangle). Sphere overlaps do not use
//! the discs: their small balls reach few leaves the discs would rule out, and the fit cost more than it
//! saved (152 → 186 M instructions on the `bench queries` row).
//!
//! Cost: one four-lane test per wide node (about a third of the binary tree's node visits), no allocation.
//!
//! [`MeshBvh::closest_point`]: crate::MeshBvh::closest_point
//! [`MeshBvh::overlapping`]: crate::MeshBvh::overlapping

use super::discs::{LaneDiscs, disc4};
use super::{
    EMPTY_LANE, NearStack, WIDE_STACK, WIDTH, WideBvh, WideNode, is_leaf, leaf_slots,
    nearest_first, pop_within, prefetch_lanes,
};
use crate::bvh::stack::Stack;
use crate::geometry::Aabb;
use glam::{Vec3, Vec4};
use std::ops::Range;

/// The `f32` squared box distance is within `(1 + 5u)` of the exact one (`u = 2⁻²⁴`: one rounding per
/// subtraction, square and sum); scaled by this it is a lower bound with room to spare.
const LOWER_BOUND_SCALE: f32 = 1.0 - 1.0 / (1 << 20) as f32;

/// An `f32` bound at least `bound` (an `f64` squared distance) for comparing box distances against: the
/// bound grown by far more than the conversion's rounding, and never below the smallest normal `f32`
/// (the box distance's absolute rounding in the subnormal range).
#[inline]
fn bound_f32(bound: f64) -> f32 {
    ((bound * (1.0 + 1e-6)) as f32).max(f32::MIN_POSITIVE)
}

/// Lanes that hold a child (bit `i` for lane `i`).
#[inline(always)]
fn used_lanes(node: &WideNode) -> u32 {
    (0..WIDTH).fold(0, |m, i| m | (u32::from(node.child[i] != EMPTY_LANE) << i))
}

/// `mask` without the node's unused lanes. Only a test against an unbounded limit can keep an unused lane
/// (its empty box is infinitely far, and overlaps no finite box), so the payloads are read only then.
#[inline(always)]
fn keep_used(mask: u32, node: &WideNode, unbounded: bool) -> u32 {
    if unbounded {
        mask & used_lanes(node)
    } else {
        mask
    }
}

impl WideBvh {
    /// Walks the leaves whose boxes lie within squared distance `bound` of `p`, nearest box first:
    /// `leaf(slots, bound)` may lower `*bound` (the best squared distance found so far) and later boxes
    /// beyond it are skipped. `p` must be finite. `slot_data` is the per-slot array `leaf` reads: when a
    /// node is opened, the entries of its kept leaves and the nodes of its kept inner lanes are prefetched,
    /// so their cache misses overlap the sorting and the nearer subtrees' work.
    pub(crate) fn walk_nearest<T>(
        &self,
        p: Vec3,
        mut bound: f64,
        slot_data: &[T],
        discs: &[LaneDiscs],
        mut leaf: impl FnMut(Range<usize>, &mut f64),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let mut limit = bound_f32(bound);
        let mut stack = NearStack::new();
        let mut cur = 0u32;
        loop {
            if is_leaf(cur) {
                leaf(leaf_slots(cur), &mut bound);
                limit = bound_f32(bound);
            } else {
                let node = &self.nodes[cur as usize];
                let (d2, mask) = bound4(node, discs.get(cur as usize), p, limit);
                let mask = keep_used(mask, node, limit == f32::INFINITY);
                if mask != 0 {
                    prefetch_lanes(&self.nodes, cur, &node.child, mask, slot_data, discs);
                    cur = nearest_first(&node.child, mask, &d2, &mut stack);
                    continue;
                }
            }
            // Pop the next subtree that may still hold something within the bound.
            match pop_within(&mut stack, limit) {
                Some(node) => cur = node,
                None => return,
            }
        }
    }

    /// Calls `leaf` with the slots of every leaf whose box overlaps `b` (touching counts), in tree order.
    /// The same comparisons as [`Aabb::overlaps`], four lanes at a time. `leaf`'s flag says that the leaf
    /// lies in a lane (its own or an ancestor's) whose box `whole` accepted: under an accepted inner lane
    /// every leaf is handed over without further tests.
    pub(crate) fn walk_overlapping(
        &self,
        b: &Aabb,
        whole: impl Fn(&Aabb) -> bool,
        leaf: impl FnMut(Range<usize>, bool),
    ) {
        // An unused lane's empty box overlaps no box with finite corners.
        let unbounded = !(b.min.is_finite() && b.max.is_finite());
        self.walk_lanes(
            |node| {
                let keep = keep_used(overlap4(node, b), node, unbounded);
                let accepted = (0..WIDTH).fold(0, |m, i| {
                    m | (u32::from(keep >> i & 1 != 0 && whole(&node.lane_box(i))) << i)
                });
                (keep, accepted)
            },
            leaf,
        );
    }

    /// Calls `leaf` with the slots of every leaf whose box may lie within squared distance `bound` of `p`
    /// (a ball's leaves: tighter than its bounding box, which holds twice its volume), in tree order. `p`
    /// must be finite. `leaf`'s flag says that every point of the leaf's box lies within squared distance
    /// `bound · (1 − 9·10⁻⁷)` of `p` (exactly: the four-lane farthest-corner test keeps a margin above its
    /// `f32` rounding); a lane that close is not opened but handed over leaf by leaf without further tests.
    pub(crate) fn walk_within(&self, p: Vec3, bound: f64, leaf: impl FnMut(Range<usize>, bool)) {
        let limit = bound_f32(bound);
        let unbounded = limit == f32::INFINITY;
        let inside = Vec4::splat((bound * (1.0 - 1e-6)) as f32);
        self.walk_lanes(
            |node| {
                let keep = keep_used(dist4(node, p, limit).1, node, unbounded);
                let far = far4(node, p) * INSIDE_SCALE + Vec4::splat(f32::MIN_POSITIVE);
                (keep, keep & far.cmple(inside).bitmask())
            },
            leaf,
        );
    }

    /// Depth-first walk into the lanes `test` keeps (its first mask, bit `i` for lane `i`; `test` must drop
    /// unused lanes), handing `leaf` each kept leaf's slots and whether it lies under a lane of `test`'s
    /// second mask (a subset of the first), whose subtrees are not tested further.
    #[inline(always)]
    fn walk_lanes(
        &self,
        test: impl Fn(&WideNode) -> (u32, u32),
        mut leaf: impl FnMut(Range<usize>, bool),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        // Each entry: a node, and whether it lies under an accepted lane (all its leaves go, untested).
        let mut stack = Stack::<(u32, bool), WIDE_STACK>::new();
        stack.push((0, false));
        while let Some((top, under)) = stack.pop() {
            let node = &self.nodes[top as usize];
            let (mut mask, whole) = if under {
                let used = used_lanes(node);
                (used, used)
            } else {
                test(node)
            };
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let (c, all) = (node.child[i], whole >> i & 1 != 0);
                if is_leaf(c) {
                    leaf(leaf_slots(c), all);
                } else {
                    stack.push((c, all));
                }
            }
        }
    }
}

/// Scales the `f32` squared distance of a box's farthest corner up to an upper bound of the exact one (within
/// `(1 + 5u)` of it, `u = 2⁻²⁴`, as [`LOWER_BOUND_SCALE`]'s; the walk adds the smallest normal `f32` for the
/// subnormal range).
const INSIDE_SCALE: f32 = 1.0 + 1.0 / (1 << 20) as f32;

/// Each lane's squared distance from `p` to its box's farthest corner, in `f32` (unused lanes: infinite).
#[inline(always)]
fn far4(node: &WideNode, p: Vec3) -> Vec4 {
    let b = &node.bounds;
    let p = p.to_array();
    (0..3).fold(Vec4::ZERO, |sum, a| {
        let pa = Vec4::splat(p[a]);
        let lo = (Vec4::from_array(b[a]) - pa).abs();
        let d = lo.max((Vec4::from_array(b[3 + a]) - pa).abs());
        sum + d * d
    })
}

/// Whether any lane of `node` is a leaf (only leaf lanes have discs).
#[inline(always)]
fn has_leaf_lane(node: &WideNode) -> bool {
    node.child.iter().any(|&c| c != EMPTY_LANE && is_leaf(c))
}

/// [`dist4`] raised to the lanes' disc bounds where the node has discs ([`disc4`]): per lane a lower bound
/// of the squared distance from `p` to anything in it, and the lanes whose bound is at most `limit`. A node
/// of inner lanes only (the upper levels: their discs are all empty) skips the discs and their 128 bytes.
#[inline(always)]
fn bound4(node: &WideNode, discs: Option<&LaneDiscs>, p: Vec3, limit: f32) -> ([f32; WIDTH], u32) {
    let (d2, mask) = dist4(node, p, limit);
    let Some(d) = discs.filter(|_| has_leaf_lane(node)) else {
        return (d2, mask);
    };
    // Both are lower bounds, so is the larger; `disc4` is never NaN.
    let v = disc4(d, p).max(Vec4::from_array(d2));
    (v.to_array(), v.cmple(Vec4::splat(limit)).bitmask())
}

/// Each lane's squared distance from `p` to its box, scaled down to a lower bound of the exact one, and
/// the lanes whose bound is at most `limit` (bit `i` for lane `i`). Unused lanes come out infinite.
#[inline(always)]
fn dist4(node: &WideNode, p: Vec3, limit: f32) -> ([f32; WIDTH], u32) {
    #[cfg(target_arch = "x86_64")]
    {
        dist4_sse(node, p, limit)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        dist4_portable(node, p, limit)
    }
}

/// The reference path of [`dist4`], one lane at a time.
#[cfg(any(test, not(target_arch = "x86_64")))]
#[inline]
fn dist4_portable(node: &WideNode, p: Vec3, limit: f32) -> ([f32; WIDTH], u32) {
    let b = &node.bounds;
    let p = p.to_array();
    let mut d2 = [0f32; WIDTH];
    let mut mask = 0;
    for i in 0..WIDTH {
        let mut sum = 0.0;
        for a in 0..3 {
            let d = (b[a][i] - p[a]).max(p[a] - b[3 + a][i]).max(0.0);
            sum += d * d;
        }
        d2[i] = sum * LOWER_BOUND_SCALE;
        mask |= u32::from(d2[i] <= limit) << i;
    }
    (d2, mask)
}

/// SSE2 (x86-64 baseline) path of [`dist4`].
#[cfg(target_arch = "x86_64")]
#[inline]
fn dist4_sse(node: &WideNode, p: Vec3, limit: f32) -> ([f32; WIDTH], u32) {
    use std::arch::x86_64::*;
    // SAFETY: SSE and SSE2 are part of the x86-64 baseline; the loads read the node's `[f32; 4]` rows and
    // the store writes `d2` (16 bytes each), all unaligned forms.
    unsafe {
        let row = |i: usize| _mm_loadu_ps(node.bounds[i].as_ptr());
        let axis = |a: usize, pa: f32| {
            let pv = _mm_set1_ps(pa);
            let d = _mm_max_ps(
                _mm_max_ps(_mm_sub_ps(row(a), pv), _mm_sub_ps(pv, row(3 + a))),
                _mm_setzero_ps(),
            );
            _mm_mul_ps(d, d)
        };
        let sum = _mm_add_ps(_mm_add_ps(axis(0, p.x), axis(1, p.y)), axis(2, p.z));
        let d2v = _mm_mul_ps(sum, _mm_set1_ps(LOWER_BOUND_SCALE));
        let mask = _mm_movemask_ps(_mm_cmple_ps(d2v, _mm_set1_ps(limit))) as u32;
        let mut d2 = [0f32; WIDTH];
        _mm_storeu_ps(d2.as_mut_ptr(), d2v);
        (d2, mask)
    }
}

/// Lanes whose box overlaps `b` (bit `i` for lane `i`): `min ≤ b.max` and `b.min ≤ max` on every axis.
#[inline(always)]
fn overlap4(node: &WideNode, b: &Aabb) -> u32 {
    let r = &node.bounds;
    let (lo, hi) = (b.min.to_array(), b.max.to_array());
    (0..WIDTH).fold(0, |mask, i| {
        // `&`, not `&&`: no branches, so the four lanes compile to vector compares.
        let hit = (r[0][i] <= hi[0])
            & (r[1][i] <= hi[1])
            & (r[2][i] <= hi[2])
            & (lo[0] <= r[3][i])
            & (lo[1] <= r[4][i])
            & (lo[2] <= r[5][i]);
        mask | (u32::from(hit) << i)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SIMD distance lanes equal the reference loop bit for bit, unused lanes and points inside included.
    #[test]
    fn dist4_paths_agree() {
        let mut node = WideNode::EMPTY;
        let boxes = [
            ([0.0, 0.0, 0.0], [1.0, 2.0, 3.0]),
            ([-5.0, 1e-3, 7.0], [-4.0, 2e-3, 7.5]),
            ([1e5, -1e5, 3.0], [1e5 + 1.0, -1e5 + 0.5, 3.0]),
        ];
        for (i, (lo, hi)) in boxes.iter().enumerate() {
            for a in 0..3 {
                node.bounds[a][i] = lo[a];
                node.bounds[3 + a][i] = hi[a];
            }
            node.child[i] = i as u32;
        }
        for p in [
            Vec3::new(0.5, 1.0, 1.0),
            Vec3::new(-3.0, 0.1, 9.0),
            Vec3::splat(1e4),
        ] {
            let fast = dist4(&node, p, 50.0);
            let slow = dist4_portable(&node, p, 50.0);
            assert_eq!(fast.0.map(f32::to_bits), slow.0.map(f32::to_bits));
            assert_eq!(fast.1, slow.1);
        }
        let inside = dist4(&node, Vec3::new(0.5, 1.0, 1.0), 0.0);
        assert_eq!((inside.0[0], inside.1 & used_lanes(&node)), (0.0, 1));
    }
}
