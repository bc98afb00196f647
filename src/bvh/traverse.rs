//! Stack-based traversal of a [`Bvh`](super::Bvh) for one ray, shared by closest-hit and any-hit queries.
//!
//! Both children of an inner node are tested with the conservative slab test; when both are hit the nearer
//! is visited first and the farther is pushed with its entry distance, which is re-checked against the
//! closest hit found so far when it is popped. The stack is a fixed array of [`MAX_DEPTH`] entries — builders
//! never make deeper trees — so a query allocates nothing.

use super::{MAX_DEPTH, Node};
use crate::geometry::Ray;
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
#[inline]
pub(crate) fn traverse<C: Counter>(
    nodes: &[Node],
    ray: &Ray,
    counter: &mut C,
    mut leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
) {
    let mut tmax = ray.tmax;
    let Some(root) = nodes.first() else { return };
    if ray.intersect_aabb(&root.aabb(), tmax).is_none() {
        return;
    }
    let mut stack = [(0u32, 0f32); MAX_DEPTH];
    let mut sp = 0usize;
    let mut cur = 0usize;
    loop {
        let n = &nodes[cur];
        if n.is_leaf() {
            counter.leaf(n.count());
            if leaf(n.slots(), &mut tmax) {
                return;
            }
        } else {
            counter.inner();
            let c = n.left();
            let a = ray.intersect_aabb(&nodes[c].aabb(), tmax);
            let b = ray.intersect_aabb(&nodes[c + 1].aabb(), tmax);
            match (a, b) {
                (Some(ta), Some(tb)) => {
                    let (near, far, tfar) = if ta <= tb {
                        (c, c + 1, tb)
                    } else {
                        (c + 1, c, ta)
                    };
                    stack[sp] = (far as u32, tfar);
                    sp += 1;
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
        // Pop the next subtree that can still hold something nearer than the best hit.
        loop {
            if sp == 0 {
                return;
            }
            sp -= 1;
            let (node, entry) = stack[sp];
            if entry <= tmax {
                cur = node as usize;
                break;
            }
        }
    }
}
