//! Structural checks of a tree, for tests and debugging.

use super::{Bvh, MAX_DEPTH, MAX_LEAF_SIZE};
use crate::geometry::Aabb;
use crate::{Error, Result};

impl Bvh {
    /// Checks every invariant the queries rely on, in O(n):
    /// - the node count is `2·leaves − 1` and every node is reached exactly once from the root;
    /// - children sit after their parent, siblings side by side, no branch deeper than [`MAX_DEPTH`];
    /// - every leaf holds 1..=[`MAX_LEAF_SIZE`] slots, and the slots of all leaves cover every slot once;
    /// - [`prim_indices`](Self::prim_indices) is a permutation of the primitive ids;
    /// - every parent's box contains its children's, and, when `prim_bounds` is given (indexed by primitive
    ///   id), every leaf's box contains its primitives'.
    ///
    /// Returns [`Error::InvalidTree`] naming the first broken rule.
    pub fn validate(&self, prim_bounds: Option<&[Aabb]>) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidTree(m));
        let n = self.prims.len();
        if self.nodes.is_empty() {
            return if n == 0 {
                Ok(())
            } else {
                bad(format!("no nodes for {n} primitives"))
            };
        }
        if let Some(b) = prim_bounds
            && b.len() != n
        {
            return bad(format!("{} primitive boxes for {n} primitives", b.len()));
        }
        let mut seen_prim = vec![false; n];
        for (slot, &p) in self.prims.iter().enumerate() {
            match seen_prim.get_mut(p as usize) {
                Some(s) if !*s => *s = true,
                _ => {
                    return bad(format!(
                        "slot {slot} holds primitive {p}, out of range or repeated"
                    ));
                }
            }
        }
        let mut seen_node = vec![false; self.nodes.len()];
        let mut seen_slot = vec![false; n];
        let (mut leaves, mut reached) = (0usize, 0usize);
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, depth)) = stack.pop() {
            if std::mem::replace(&mut seen_node[i], true) {
                return bad(format!("node {i} is reached twice"));
            }
            reached += 1;
            if depth >= MAX_DEPTH {
                return bad(format!("node {i} is at depth {depth}, past MAX_DEPTH"));
            }
            let node = &self.nodes[i];
            let b = node.aabb();
            if node.is_leaf() {
                leaves += 1;
                let (count, slots) = (node.count(), node.slots());
                if count == 0 || count > MAX_LEAF_SIZE as usize || slots.end > n {
                    return bad(format!("leaf {i} has slots {slots:?} of {n}"));
                }
                for s in slots {
                    if std::mem::replace(&mut seen_slot[s], true) {
                        return bad(format!("slot {s} is in two leaves"));
                    }
                    if let Some(pb) = prim_bounds
                        && !b.contains_box(&pb[self.prims[s] as usize])
                    {
                        return bad(format!(
                            "leaf {i} does not contain primitive {}",
                            self.prims[s]
                        ));
                    }
                }
            } else {
                let c = node.left();
                if c <= i || c + 1 >= self.nodes.len() {
                    return bad(format!("inner node {i} has children {c}, {}", c + 1));
                }
                for k in [c, c + 1] {
                    if !b.contains_box(&self.nodes[k].aabb()) {
                        return bad(format!("node {i} does not contain its child {k}"));
                    }
                    stack.push((k, depth + 1));
                }
            }
        }
        if reached != self.nodes.len() {
            return bad(format!(
                "{} of {} nodes are unreachable",
                self.nodes.len() - reached,
                self.nodes.len()
            ));
        }
        if self.nodes.len() != 2 * leaves - 1 {
            return bad(format!("{} nodes for {leaves} leaves", self.nodes.len()));
        }
        if let Some(s) = seen_slot.iter().position(|s| !s) {
            return bad(format!("slot {s} is in no leaf"));
        }
        Ok(())
    }
}
