//! Stack-based traversal of a [`Bvh`](super::Bvh) for one ray, shared by closest-hit and any-hit queries.
//!
//! Both children of an inner node are tested with the conservative slab test; when both are hit the nearer
//! is visited first and the farther is pushed with its entry distance, which is re-checked against the
//! closest hit found so far when it is popped. The stack is a fixed array of [`MAX_DEPTH`] entries — builders
//! never make deeper trees — so a query allocates nothing.

use super::stack::Stack;
use super::{MAX_DEPTH, Node};
use crate::geometry::{Ray, hit_limit};
use std::ops::Range;

/// Work done by queries: the "measured traversal steps" used to compare tree quality.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TraversalStats {
    /// Nodes whose children were box-tested (inner nodes visited).
    pub inner_visits: u64,
    /// Leaves visited.
    pub leaf_visits: u64,
    /// Primitive intersection tests.
    pub prim_tests: u64,
}

impl TraversalStats {
    /// Adds another count.
    pub fn add(&mut self, o: &TraversalStats) {
        self.inner_visits += o.inner_visits;
        self.leaf_visits += o.leaf_visits;
        self.prim_tests += o.prim_tests;
    }
}

/// Counts work, or not: `()` counts nothing and compiles away.
pub(crate) trait Counter {
    fn inner(&mut self);
    fn leaf(&mut self, prims: usize);
}

impl Counter for () {
    #[inline(always)]
    fn inner(&mut self) {}
    #[inline(always)]
    fn leaf(&mut self, _: usize) {}
}

impl Counter for TraversalStats {
    #[inline(always)]
    fn inner(&mut self) {
        self.inner_visits += 1;
    }
    #[inline(always)]
    fn leaf(&mut self, prims: usize) {
        self.leaf_visits += 1;
        self.prim_tests += prims as u64;
    }
}

/// Walks the leaves whose boxes the ray reaches within the current `tmax`, nearest box first.
///
/// `leaf(slots, tmax)` tests a leaf's primitives, may lower `*tmax` (closest hit), and returns true to stop
/// the whole traversal (any hit). The ray must be valid.
///
/// Boxes are tested, and pushed ones kept, against `tmax` moved outward by
/// [`robust_far`](crate::geometry::robust_far)'s slack (2 to 4 ulps) and by the ray's
/// [`hit_slack`](Ray::hit_slack) for the root's box ([`hit_limit`]), not `tmax` itself: a triangle's `t`
/// can round below its box's entry distance — by an ulp or two for a triangle lying in the box's face
/// plane (an axis-aligned face), by ulps of its vertices' depths rather than of `t` for a short hit on a
/// large triangle — so a box culled at `tmax` exactly could hold a closer hit than the one found, and which hit was kept then depended on the order of the visits (one tree's against
/// another's, the CPU's against the GPU's: 19 of 14,400 rays on the colliding crowd of
/// `tests/gpu_frame.rs` before the relative slack; two characters' coplanar faces 0.0077 from a ray's
/// origin, hits 6 ulps apart, at 12 times real time before the absolute one; `tests/ray_order.rs` builds
/// such faces by the thousand). Not a bound for a triangle met at a grazing angle. Every ray traversal of a
/// BVH keeps this rule: single rays, packets, binary and wide trees, the top level's, the GPU kernels. One
/// multiplication and one addition per leaf.
#[inline]
pub(crate) fn traverse<C: Counter>(
    nodes: &[Node],
    ray: &Ray,
    counter: &mut C,
    mut leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
) {
    let mut tmax = ray.tmax;
    let slack = nodes
        .first()
        .map_or(0.0, |root| ray.hit_slack(&root.aabb()));
    traverse_by(
        nodes,
        hit_limit(tmax, slack),
        counter,
        |n, limit| ray.intersect_aabb(&n.aabb(), limit),
        |slots, limit| {
            let stop = leaf(slots, &mut tmax);
            *limit = hit_limit(tmax, slack);
            stop
        },
    );
}

/// Nearest-first traversal under any box test: the one loop behind ray, closest-point and sweep queries.
///
/// `enter(node, bound)` returns the node's key (an entry distance) when its box can still hold something
/// within `bound`, else `None`. Children are visited in key order; a pushed sibling is skipped when it is
/// popped if its key exceeds the bound by then. `leaf(slots, bound)` tests a leaf, may tighten `*bound`, and
/// returns true to stop. The stack is [`MAX_DEPTH`] entries: builders never make deeper trees.
#[inline]
pub(crate) fn traverse_by<C: Counter, K: PartialOrd + Copy>(
    nodes: &[Node],
    mut bound: K,
    counter: &mut C,
    enter: impl Fn(&Node, K) -> Option<K>,
    mut leaf: impl FnMut(Range<usize>, &mut K) -> bool,
) {
    let Some(root) = nodes.first() else { return };
    if enter(root, bound).is_none() {
        return;
    }
    let mut stack = Stack::<(u32, K), MAX_DEPTH>::new();
    let mut cur = 0usize;
    loop {
        let n = &nodes[cur];
        if n.is_leaf() {
            counter.leaf(n.count());
            if leaf(n.slots(), &mut bound) {
                return;
            }
        } else {
            counter.inner();
            let c = n.left();
            let a = enter(&nodes[c], bound);
            let b = enter(&nodes[c + 1], bound);
            match (a, b) {
                (Some(ka), Some(kb)) => {
                    let (near, far, kfar) = if ka <= kb {
                        (c, c + 1, kb)
                    } else {
                        (c + 1, c, ka)
                    };
                    stack.push((far as u32, kfar));
                    cur = near;
                    continue;
                }
                (Some(_), None) => {
                    cur = c;
                    continue;
                }
                (None, Some(_)) => {
                    cur = c + 1;
                    continue;
                }
                (None, None) => {}
            }
        }
        // Pop the next subtree that can still hold something within the bound.
        loop {
            let Some((node, entry)) = stack.pop() else {
                return;
            };
            if entry <= bound {
                cur = node as usize;
                break;
            }
        }
    }
}
