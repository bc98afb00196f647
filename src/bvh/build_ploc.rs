//! PLOC builder: Meister and Bittner, "Parallel Locally-Ordered Clustering for Bounding Volume Hierarchy
//! Construction" (IEEE TVCG 2018). Bottom-up agglomerative clustering on a Morton curve.
//!
//! The primitives are sorted along a 30-bit Morton curve and each starts as a cluster. Unlike LBVH's, the
//! curve's cells are cubes ([`morton30_cube`](crate::geometry::morton30_cube): every axis scaled by the
//! centroids' largest extent), so a thin axis is not stretched to 1024 cells: on a folded sheet
//! (`scenes::folded_sheet(20, 0.7)`, 0.16 thick, 0.5 × 1 wide) per-axis cells ordered the clusters mostly by
//! the fold's height and PLOC's tree cost 1.158× CPU binned SAH's; see docs/BENCHMARKS.md for the figures.
//! Every round, each cluster finds its nearest neighbour among the `radius` clusters before and after it
//! in the current order, the distance being the surface area of the box of the two merged; mutual nearest
//! neighbours merge into a new cluster at the lower position, and the surviving clusters are compacted in
//! order (a prefix sum on the GPU). Rounds repeat until one cluster is left: the root.
//!
//! Use it where a rebuild must be near LBVH speed but the tree should be close to binned SAH (the paper
//! reports ~90–100% of full-sweep SAH quality at r = 16). Cost: a Morton sort, then about
//! `log n` rounds of `O(c · 2r)` box unions over the `c` clusters left (`c` falls geometrically), parallel
//! within a round, and one O(n) pass laying the merge tree out in the crate's node order.
//!
//! Determinism, and the rules the GPU builder (`src/gpu/ploc.rs`, `shaders/ploc.wgsl`) follows exactly so
//! that both give the same tree node for node:
//! - the distance is [`merge_area`]: the union's extents `d = max - min` (exact min/max), then
//!   `(d.x·d.y + d.y·d.z) + d.z·d.x` in f32, in that order (the GPU keeps each product out of an FMA);
//! - equal distances are told apart by [`pair_key`] of the two positions, `(lower position odd, gap, lower
//!   position)` compared lexicographically: symmetric and distinct for distinct pairs, and among equally
//!   near neighbours it pairs positions (0, 1), (2, 3), … — with a plain "lower position wins" rule, a run of
//!   equal boxes (repeated or collinear zero-area triangles) would merge one pair per round, n rounds;
//! - the merged cluster's left child is the one at the lower position.
//!
//! A mutual pair always exists while two clusters are left: the pair that is smallest in (distance, key)
//! over the whole round is each member's choice. So every round merges at least one pair and the loop
//! ends after at most `n - 1` rounds (about `log n` in practice).

#[cfg(feature = "gpu")]
use super::Node;
use super::build_lbvh::sorted_codes;
use super::layout::Slot;
use super::topdown::{self, BALANCED_DEPTH, ObjectMedian, PARALLEL_SUBTREE};
use super::{BuildInput, MortonBits};
use crate::geometry::Aabb;
use crate::parallel;

/// The paper's default search radius.
pub const DEFAULT_PLOC_RADIUS: u32 = 16;

/// Largest search radius [`Builder::Ploc`](super::Builder::Ploc) accepts.
pub const MAX_PLOC_RADIUS: u32 = 256;

/// The merge tree PLOC makes. Ids `0..n` are the leaves, in Morton order; ids `n..2n-1` are the merged
/// clusters, `children[id - n] = [left, right]`, a child always having a lower id than its parent (ids
/// are handed out round by round). Only the shape matters for the laid-out tree, not the ids.
pub(crate) struct MergeTree {
    pub children: Vec<[u32; 2]>,
    pub root: u32,
}

/// PLOC's distance: the surface area (halved) of the box around both, in the fixed f32 order above.
#[inline]
pub(crate) fn merge_area(a: &Aabb, b: &Aabb) -> f32 {
    let d = a.max.max(b.max) - a.min.min(b.min);
    (d.x * d.y + d.y * d.z) + d.z * d.x
}

/// Builds into `slot` (the root slot, `slot.prims` = `0..n`): sort, cluster, lay out.
pub(crate) fn build(input: &BuildInput, slot: Slot<'_>, radius: u32) -> usize {
    sorted_codes(input, slot.prims, MortonBits::Bits30, true);
    let leaves = slot.prims.to_vec();
    let mut boxes = vec![Aabb::EMPTY; leaves.len()];
    parallel::fill(input.parallel, &mut boxes, 1 << 14, |i| {
        input.bounds[leaves[i] as usize]
    });
    let tree = cluster(boxes, radius as usize, input.parallel);
    write_tree(input, slot, &leaves, &tree)
}

/// Clusters boxes given in Morton order.
pub(crate) fn cluster(mut boxes: Vec<Aabb>, radius: usize, parallel: bool) -> MergeTree {
    let n = boxes.len();
    let mut children = Vec::with_capacity(n.saturating_sub(1));
    let mut clusters: Vec<u32> = (0..n as u32).collect();
    let mut next = Vec::with_capacity(n);
    let mut nn = vec![0u32; n];
    while clusters.len() > 1 {
        let c = clusters.len();
        parallel::fill(parallel, &mut nn[..c], 1 << 12, |i| {
            nearest(&clusters, &boxes, i, radius)
        });
        next.clear();
        for i in 0..c {
            let j = nn[i] as usize;
            if nn[j] as usize != i {
                next.push(clusters[i]);
            } else if i < j {
                let (l, r) = (clusters[i], clusters[j]);
                let merged = boxes[l as usize].union(&boxes[r as usize]);
                next.push(boxes.len() as u32);
                boxes.push(merged);
                children.push([l, r]);
            }
        }
        std::mem::swap(&mut clusters, &mut next);
    }
    MergeTree {
        children,
        root: clusters.first().copied().unwrap_or(0),
    }
}

/// The tie key of positions `i` and `j` (see the module docs), as the GPU compares it.
#[inline]
fn pair_key(i: usize, j: usize) -> (usize, usize, usize) {
    let (lo, hi) = (i.min(j), i.max(j));
    (lo & 1, hi - lo, lo)
}

/// Position of the nearest neighbour of the cluster at position `i` within `radius` positions.
fn nearest(clusters: &[u32], boxes: &[Aabb], i: usize, radius: usize) -> u32 {
    let own = &boxes[clusters[i] as usize];
    let (lo, hi) = (
        i.saturating_sub(radius),
        (i + radius).min(clusters.len() - 1),
    );
    let mut best = (f32::INFINITY, i);
    for j in (lo..=hi).filter(|&j| j != i) {
        let d = merge_area(own, &boxes[clusters[j] as usize]);
        // The first candidate is always taken, so an infinite area still has a neighbour.
        if best.1 == i || d < best.0 || (d == best.0 && pair_key(i, j) < pair_key(i, best.1)) {
            best = (d, j);
        }
    }
    best.1 as u32
}

/// Lays a merge tree over `leaves` (primitive ids in Morton order) out into `slot` in the crate's node
/// order, left subtree first; subtrees of at most `max_leaf` primitives become leaves, and from
/// [`BALANCED_DEPTH`] on the rest is split by object median so that no leaf is deeper than the limit.
pub(crate) fn write_tree(
    input: &BuildInput,
    slot: Slot<'_>,
    leaves: &[u32],
    tree: &MergeTree,
) -> usize {
    let n = leaves.len();
    // Primitive counts per id: children have lower ids than their parent.
    let mut counts = vec![1u32; 2 * n - 1];
    for (k, [l, r]) in tree.children.iter().enumerate() {
        counts[n + k] = counts[*l as usize] + counts[*r as usize];
    }
    let w = Writer {
        input,
        leaves,
        tree,
        counts: &counts,
    };
    w.write(slot, tree.root, 0)
}

struct Writer<'a> {
    input: &'a BuildInput<'a>,
    leaves: &'a [u32],
    tree: &'a MergeTree,
    counts: &'a [u32],
}

impl Writer<'_> {
    fn children(&self, id: u32) -> [u32; 2] {
        self.tree.children[id as usize - self.leaves.len()]
    }

    /// Puts the primitives under `id` into `out`, left first.
    fn gather(&self, id: u32, out: &mut [u32]) {
        if (id as usize) < self.leaves.len() {
            out[0] = self.leaves[id as usize];
            return;
        }
        let [l, r] = self.children(id);
        let (lo, hi) = out.split_at_mut(self.counts[l as usize] as usize);
        self.gather(l, lo);
        self.gather(r, hi);
    }

    fn write(&self, slot: Slot<'_>, id: u32, depth: usize) -> usize {
        let m = slot.prims.len();
        if m <= self.input.max_leaf || depth >= BALANCED_DEPTH {
            self.gather(id, slot.prims);
            if m > self.input.max_leaf {
                return topdown::build(self.input, &ObjectMedian, slot, depth);
            }
            let b = slot
                .prims
                .iter()
                .fold(Aabb::EMPTY, |b, &p| b.union(&self.input.bounds[p as usize]));
            return slot.leaf(&b);
        }
        let [l, r] = self.children(id);
        let par = self.input.parallel && m >= PARALLEL_SUBTREE;
        slot.split(self.counts[l as usize] as usize, par, [l, r], |child, c| {
            self.write(child, c, depth + 1)
        })
    }
}

/// The nodes and slot order of the laid-out tree of a merge tree made elsewhere (the GPU builder), over
/// primitives with boxes `bounds` whose ids in Morton order are `leaves`.
#[cfg(feature = "gpu")]
pub(crate) fn lay_out(
    bounds: &[Aabb],
    leaves: Vec<u32>,
    tree: &MergeTree,
    max_leaf: u32,
    parallel: bool,
) -> (Vec<Node>, Vec<u32>) {
    let n = leaves.len();
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let centroids: Vec<glam::Vec3> = bounds.iter().map(Aabb::center).collect();
    let input = BuildInput {
        bounds,
        centroids: &centroids,
        max_leaf: max_leaf as usize,
        parallel: parallel && cfg!(feature = "parallel"),
    };
    let mut prims = leaves.clone();
    let mut nodes = vec![Node::default(); 2 * n - 1];
    let slot = super::layout::root_slot(&mut nodes, &mut prims);
    let used = write_tree(&input, slot, &leaves, tree);
    super::layout::compact(&mut nodes, used);
    (nodes, prims)
}
