//! Where builders put nodes: every subtree gets a fixed, precomputed place, so parallel builders write
//! disjoint slices and the output does not depend on thread timing.
//!
//! A subtree over `m` primitives has at most `2m - 1` nodes (one primitive per leaf), and its descendants
//! (everything but its root) take at most `2m - 2`. A [`Slot`] is a subtree's root node plus that block of
//! `2m - 2` nodes; splitting it puts the two children at the front of the block and gives each child the
//! block part of its own size. With one primitive per leaf every block is filled exactly; with larger leaves
//! some blocks end in unused nodes, which [`compact`] squeezes out.

use super::Node;
use crate::geometry::{Aabb, sa_ratio};

/// The place of one subtree in the node array.
pub(crate) struct Slot<'a> {
    /// The subtree's root.
    pub node: &'a mut Node,
    /// Room for its descendants (`2m - 2` nodes).
    pub desc: &'a mut [Node],
    /// Index of `desc[0]` in the whole array.
    pub desc_at: u32,
    /// First primitive slot of the subtree.
    pub prim_at: u32,
    /// The subtree's primitives (ids into the input), in slot order; builders reorder them in place.
    pub prims: &'a mut [u32],
}

impl<'a> Slot<'a> {
    /// Makes the root a leaf over all primitives of the subtree with the given box (the union of theirs).
    /// O(1): the caller has the box and has put the primitives' ids in [`prims`](Self::prims).
    pub fn leaf(self, bounds: &Aabb) -> usize {
        *self.node = Node::leaf(self.prim_at, self.prims.len() as u32, bounds);
        1
    }

    /// Splits into children over the first `left_count` primitives and the rest, builds them with
    /// `build(child, data)` where `data` is `[left, right]` (in parallel when asked), then sets the root's box
    /// and build-time SA ratio. Returns the number of nodes used.
    pub fn split<T: Send, F>(
        self,
        left_count: usize,
        parallel: bool,
        data: [T; 2],
        build: F,
    ) -> usize
    where
        F: Fn(Slot<'_>, T) -> usize + Sync + Send,
    {
        let count = self.prims.len();
        debug_assert!(0 < left_count && left_count < count);
        debug_assert_eq!(self.desc.len(), 2 * count - 2);
        let (pair, rest) = self.desc.split_at_mut(2);
        let (ldesc, rdesc) = rest.split_at_mut(2 * left_count - 2);
        let (l, r) = pair.split_at_mut(1);
        let (lp, rp) = self.prims.split_at_mut(left_count);
        let left = Slot {
            prims: lp,
            node: &mut l[0],
            desc: ldesc,
            desc_at: self.desc_at + 2,
            prim_at: self.prim_at,
        };
        let right = Slot {
            prims: rp,
            node: &mut r[0],
            desc: rdesc,
            desc_at: self.desc_at + 2 * left_count as u32,
            prim_at: self.prim_at + left_count as u32,
        };
        let [ld, rd] = data;
        let (nl, nr) = crate::parallel::join(parallel, || build(left, ld), || build(right, rd));
        let (lb, rb) = (l[0].aabb(), r[0].aabb());
        let bounds = lb.union(&rb);
        *self.node = Node::inner(self.desc_at, &bounds, sa_ratio(&bounds, &lb, &rb));
        1 + nl + nr
    }
}

/// The slot of a whole tree over `prims` (not empty), in `nodes` of length `2·prims.len() - 1`.
pub(crate) fn root_slot<'a>(nodes: &'a mut [Node], prims: &'a mut [u32]) -> Slot<'a> {
    debug_assert_eq!(nodes.len(), 2 * prims.len() - 1);
    let (root, desc) = nodes.split_first_mut().expect("a tree has a root");
    Slot {
        node: root,
        desc,
        desc_at: 1,
        prim_at: 0,
        prims,
    }
}

/// Drops unused nodes, keeping the order rules (children after parents, siblings adjacent, every subtree's
/// descendants contiguous). Does nothing when every node is used.
pub(crate) fn compact(nodes: &mut Vec<Node>, used: usize) {
    if used == nodes.len() {
        return;
    }
    let mut out = Vec::with_capacity(used);
    out.push(nodes[0]);
    // Depth-first: (old index, new index) of nodes whose children still have to be copied.
    let mut stack = vec![(0usize, 0usize)];
    while let Some((old, new)) = stack.pop() {
        let n = nodes[old];
        if n.is_leaf() {
            continue;
        }
        let c = n.left();
        let at = out.len();
        out.push(nodes[c]);
        out.push(nodes[c + 1]);
        out[new].index = at as u32;
        stack.push((c + 1, at + 1));
        stack.push((c, at));
    }
    debug_assert_eq!(out.len(), used);
    *nodes = out;
}
