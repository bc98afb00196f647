//! Partial rebuilds: after a refit, rebuild only the subtrees that degraded, each in place with binned SAH
//! over its own primitives (the thesis's lazy top-down rebuild, §6.1.5, with the refit metric per subtree).
//!
//! When to use: a mesh whose motion tears one part of it apart while the rest moves coherently (a limb
//! that swings through the body, a debris field next to an intact wall): a full rebuild would redo the
//! whole tree, a refit alone would leave the torn part's boxes overlapping. Where the whole mesh degrades
//! evenly the root's subtree crosses the threshold and this is a full binned-SAH rebuild.
//!
//! Selection: the degradation of a subtree is the refit metric restricted to it, `Σ (ratio − ratio₀) /
//! inner nodes` over its inner nodes (so the root's is [`Bvh::degradation`]). Walking down from the root,
//! the highest subtrees whose degradation exceeds [`PartialOptions::threshold`] and that hold at least
//! [`PartialOptions::min_primitives`] primitives are rebuilt; nothing below a rebuilt node is looked at.
//! One exception keeps the work where the damage is: a degraded subtree whose root's own split is still
//! good (its ratio rose by no more than the threshold) and whose degraded children are big enough to be
//! rebuilt on their own is passed over for its children, since rebuilding it would redo healthy work around the damage (the few node ratios
//! above the rebuilt subtrees stay as refitted — a full rebuild repairs those). So a torn part's
//! subtrees are rebuilt, not the root above them whose mean they drag over the threshold.
//!
//! In place: a subtree's descendants occupy one contiguous block of the node array and its primitives one
//! contiguous run of slots, so the rebuilt subtree is written back into the same node block and the same
//! slots. Everything outside the selected subtrees keeps its bytes, ancestors included (the rebuilt
//! subtree's root box is the union of the same primitive boxes, so it is bit for bit the old one). The
//! rebuilt subtree must use as many nodes as the old one: always true for trees of one primitive per leaf
//! (the default [`BuildOptions::max_leaf_size`](super::BuildOptions::max_leaf_size)); a subtree whose
//! rebuild would come out with another leaf count, or that lies in a tree without that layout (read back
//! from a GPU builder), is left refitted and counted in [`PartialRebuild::skipped`].
//!
//! Cost: one bottom-up pass over all nodes (as a refit, plus 32 bytes of scratch per node), then a binned
//! SAH build over the selected primitives only: O(k log k) for `k` primitives rebuilt.

use super::build_sah::BinnedSah;
use super::layout::{self, Slot};
use super::{BuildInput, Bvh, MAX_BINS, Node, topdown};
use crate::geometry::{Aabb, sa_ratio};
use crate::{Error, Result};
use std::ops::Range;
use std::sync::Arc;

/// When [`Bvh::rebuild_degraded`] rebuilds a subtree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartialOptions {
    /// Subtree degradation above which a subtree is rebuilt; 0.40 by default, the thesis's full-rebuild
    /// threshold applied per subtree.
    pub threshold: f32,
    /// Subtrees over fewer primitives are not rebuilt on their own (their ancestors may be); 64 by default,
    /// so that a few torn leaves do not cost a build call each.
    pub min_primitives: usize,
    /// Largest primitive count per leaf of the rebuilt subtrees; 1 by default (see the
    /// [module docs](self) on node counts).
    pub max_leaf_size: u32,
    /// SAH bins per axis, 2..=[`MAX_BINS`]; 16 by default.
    pub bins: u32,
    /// Build large subtrees on all threads (with the `parallel` feature); the result is the same.
    pub parallel: bool,
}

impl Default for PartialOptions {
    fn default() -> Self {
        Self {
            threshold: 0.40,
            min_primitives: 64,
            max_leaf_size: 1,
            bins: 16,
            parallel: true,
        }
    }
}

impl PartialOptions {
    pub(super) fn check(&self) -> Result<()> {
        if !(2..=MAX_BINS).contains(&self.bins) {
            return Err(Error::InvalidOption(format!(
                "{} SAH bins is outside 2..={MAX_BINS}",
                self.bins
            )));
        }
        if !(1..=super::MAX_LEAF_SIZE).contains(&self.max_leaf_size) {
            return Err(Error::InvalidOption(format!(
                "max_leaf_size {} is outside 1..={}",
                self.max_leaf_size,
                super::MAX_LEAF_SIZE
            )));
        }
        if !self.threshold.is_finite() {
            return Err(Error::InvalidOption(format!(
                "partial rebuild threshold {} is not finite",
                self.threshold
            )));
        }
        Ok(())
    }
}

/// What a partial rebuild did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PartialRebuild {
    /// Subtrees rebuilt.
    pub subtrees: usize,
    /// Primitives in the rebuilt subtrees: the build work done.
    pub primitives: usize,
    /// Selected subtrees left refitted because their rebuild would not fit their node block.
    pub skipped: usize,
    /// Root node of each rebuilt subtree (its node index is unchanged; its descendants' block is rewritten).
    pub roots: Vec<usize>,
    /// Slot range of each rebuilt subtree (its slots now hold its primitives in another order).
    pub slots: Vec<Range<usize>>,
}

/// Per node, what the selection needs of its subtree, gathered in one bottom-up pass.
#[derive(Clone, Copy, Default)]
struct Subtree {
    /// Summed `ratio − ratio₀` of its inner nodes.
    degradation: f64,
    inner: u32,
    /// Its primitive slots span `slot_lo..slot_hi` and number `prims`.
    slot_lo: u32,
    slot_hi: u32,
    prims: u32,
    /// Its descendants span `node_lo..node_hi` (empty for a leaf).
    node_lo: u32,
    node_hi: u32,
}

impl Subtree {
    /// True when the descendants fill their index span and the primitives their slot span, so the
    /// subtree can be rewritten in place.
    fn is_contiguous(&self) -> bool {
        let nodes = 2 * (self.inner as usize + 1) - 2;
        (self.node_hi - self.node_lo) as usize == nodes && self.slot_hi - self.slot_lo == self.prims
    }
}

/// The [`Subtree`] record of every node.
fn subtrees(nodes: &[Node]) -> Vec<Subtree> {
    let mut out = vec![Subtree::default(); nodes.len()];
    for i in (0..nodes.len()).rev() {
        let n = &nodes[i];
        out[i] = if n.is_leaf() {
            let s = n.slots();
            Subtree {
                slot_lo: s.start as u32,
                slot_hi: s.end as u32,
                prims: s.len() as u32,
                node_lo: i as u32 + 1,
                node_hi: i as u32 + 1,
                ..Subtree::default()
            }
        } else {
            let c = n.left();
            let (l, r) = (&out[c], &out[c + 1]);
            let (lb, rb) = (nodes[c].aabb(), nodes[c + 1].aabb());
            Subtree {
                degradation: l.degradation
                    + r.degradation
                    + f64::from(sa_ratio(&n.aabb(), &lb, &rb) - n.sa_ratio),
                inner: 1 + l.inner + r.inner,
                slot_lo: l.slot_lo.min(r.slot_lo),
                slot_hi: l.slot_hi.max(r.slot_hi),
                prims: l.prims + r.prims,
                node_lo: (c as u32).min(l.node_lo).min(r.node_lo),
                node_hi: (c as u32 + 2).max(l.node_hi).max(r.node_hi),
            }
        };
    }
    out
}

impl Bvh {
    /// Rebuilds the degraded subtrees of a refitted tree (see the [module docs](self)); `prim_bounds` are
    /// the primitives' current boxes by primitive id, as given to the last [`Bvh::refit`].
    ///
    /// Errors: [`Error::InvalidOption`] for options out of range, [`Error::VertexCountMismatch`] for a wrong
    /// number of boxes, [`Error::NonFiniteBounds`] for an empty or non-finite box (the tree is unchanged).
    pub fn rebuild_degraded(
        &mut self,
        prim_bounds: &[Aabb],
        options: &PartialOptions,
    ) -> Result<PartialRebuild> {
        self.check_bounds(prim_bounds)?;
        self.rebuild_degraded_by(options, |p| prim_bounds[p as usize])
    }

    /// How many primitives [`rebuild_degraded`](Self::rebuild_degraded) would rebuild with `options` now,
    /// without changing anything: what a planner weighs a partial rebuild by. Cost: one pass over the
    /// nodes (32 bytes of scratch per node).
    ///
    /// Errors: [`Error::InvalidOption`] for options out of range.
    pub fn degraded_primitives(&self, options: &PartialOptions) -> Result<usize> {
        options.check()?;
        Ok(self
            .select(options)
            .iter()
            .map(|(_, _, s)| s.prims as usize)
            .sum())
    }

    /// The subtrees to rebuild, as (root, depth, record), highest first (see the [module docs](self)).
    fn select(&self, options: &PartialOptions) -> Vec<(usize, usize, Subtree)> {
        let mut out = Vec::new();
        if self.nodes.is_empty() {
            return out;
        }
        let info = subtrees(&self.nodes);
        let threshold = f64::from(options.threshold);
        let crosses = |i: usize| {
            let s = &info[i];
            s.inner > 0 && s.degradation / f64::from(s.inner) > threshold
        };
        let min = options.min_primitives.max(2);
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, depth)) = stack.pop() {
            let s = info[i];
            // Nothing at or below a subtree too small to rebuild can be selected.
            if s.inner == 0 || (s.prims as usize) < min {
                continue;
            }
            let n = &self.nodes[i];
            let c = n.left();
            if crosses(i) {
                let (lb, rb) = (self.nodes[c].aabb(), self.nodes[c + 1].aabb());
                let own = f64::from(sa_ratio(&n.aabb(), &lb, &rb) - n.sa_ratio);
                let small = |k: usize| crosses(k) && (info[k].prims as usize) < min;
                let any = crosses(c) || crosses(c + 1);
                if own > threshold || !any || small(c) || small(c + 1) {
                    out.push((i, depth, s));
                    continue;
                }
            }
            stack.push((c + 1, depth + 1));
            stack.push((c, depth + 1));
        }
        out
    }

    /// [`rebuild_degraded`](Self::rebuild_degraded) with the boxes given by primitive id through `bounds`
    /// (valid, not checked), so that a mesh tree computes only the rebuilt triangles' boxes.
    pub(crate) fn rebuild_degraded_by(
        &mut self,
        options: &PartialOptions,
        bounds: impl Fn(u32) -> Aabb,
    ) -> Result<PartialRebuild> {
        options.check()?;
        let mut done = PartialRebuild::default();
        for (i, depth, s) in self.select(options) {
            if s.is_contiguous() && self.rebuild_subtree(i, &s, depth, options, &bounds) {
                done.subtrees += 1;
                done.primitives += s.prims as usize;
                done.roots.push(i);
                done.slots.push(s.slot_lo as usize..s.slot_hi as usize);
            } else {
                done.skipped += 1;
            }
        }
        Ok(done)
    }

    /// Rebuilds the subtree rooted at node `i` (at `depth`) with binned SAH into its own node block and
    /// slots. False, with nothing changed, when the new subtree would need another number of nodes.
    fn rebuild_subtree(
        &mut self,
        i: usize,
        s: &Subtree,
        depth: usize,
        options: &PartialOptions,
        bounds: &impl Fn(u32) -> Aabb,
    ) -> bool {
        let (lo, hi) = (s.slot_lo as usize, s.slot_hi as usize);
        let ids = &self.prims[lo..hi];
        let boxes: Vec<Aabb> = ids.iter().map(|&p| bounds(p)).collect();
        let centroids: Vec<_> = boxes.iter().map(Aabb::center).collect();
        let input = BuildInput {
            bounds: &boxes,
            centroids: &centroids,
            max_leaf: options.max_leaf_size as usize,
            parallel: options.parallel && cfg!(feature = "parallel"),
        };
        let m = ids.len();
        let mut local: Vec<u32> = (0..m as u32).collect();
        let mut tmp = vec![Node::default(); 2 * m - 1];
        let (root, desc) = tmp.split_first_mut().expect("m >= 2");
        let slot = Slot {
            node: root,
            desc,
            desc_at: 1,
            prim_at: lo as u32,
            prims: &mut local,
        };
        let used = topdown::build(&input, &BinnedSah { bins: options.bins }, slot, depth);
        if used != 2 * s.inner as usize + 1 {
            return false;
        }
        layout::compact(&mut tmp, used);
        // tmp[0] is node i; tmp[j ≥ 1] goes to the old block at node_lo + j − 1.
        let base = s.node_lo as usize;
        let at = |j: usize| if j == 0 { i } else { base + j - 1 };
        for (j, n) in tmp.iter().enumerate() {
            let mut n = *n;
            if !n.is_leaf() {
                n.index = at(n.left()) as u32;
            }
            self.nodes[at(j)] = n;
        }
        let new_ids: Vec<u32> = local.iter().map(|&l| ids[l as usize]).collect();
        // Shared with clones until now (`Bvh`'s docs): this tree gets its own.
        Arc::make_mut(&mut self.prims)[lo..hi].copy_from_slice(&new_ids);
        true
    }
}
