//! A 4-wide BVH derived from the binary tree, for faster ray queries on the CPU.
//!
//! When to use: any mesh that answers more than a handful of rays between rebuilds. [`MeshBvh`] derives
//! one by default ([`BuildOptions::wide`](super::BuildOptions::wide)) and its closest-hit, any-hit and
//! all-hits queries walk it instead of the binary tree; the answers are the same (same triangle, or a
//! triangle hit at exactly the same `t`), because the child boxes are the binary tree's boxes and the SIMD
//! box test rounds exactly like the scalar one (see [`simd`]).
//!
//! The binary tree stays the maintenance structure (GPU layout, degradation metric, other queries). The
//! wide tree is collapsed from it once per build and refitted in place by copying the refitted binary boxes
//! into its lanes: a refit frame never re-collapses.
//!
//! Cost: the collapse is one bottom-up and one top-down pass over the binary nodes, O(n), somewhat less
//! than an LBVH build of the same mesh (`bench cpu`, rows `collapse 1 thread`); the refit copy is
//! O(wide nodes) and adds a third to two thirds to a refit (`bench cpu`, rows `refit + wide4`).
//! Memory: 128 bytes per wide node (112 of node, 16 of refit sources); with the small
//! leaves the measured cost ratio picks, about 0.4 wide nodes per triangle, 48–59 bytes per triangle on
//! the `bench cpu` scenes, on top of the binary tree's ~64.
//!
//! Collapse: a binary subtree becomes one wide leaf when it holds at most [`MAX_WIDE_LEAF`] triangles and
//! its SAH leaf cost `A · n · C_tri` is no more than the cost of keeping it inner, `A · C_wide / 3 +
//! cost(children)` (a wide node replaces about three binary inner nodes); [`WIDE_NODE_COST`] is the
//! measured cost of one four-box test in triangle tests. Each wide node then takes its binary node's two
//! children and opens the largest-area inner child until it has four.
//!
//! For large static meshes, [`compact`] quantises the child boxes to 8 bits per plane: about half the
//! bytes, the same answers, slower node visits.
//!
//! [`MeshBvh`]: super::MeshBvh

pub mod compact;
mod discs;
mod packet;
mod proximity;
pub mod simd;

use super::node::{COUNT_SHIFT, FIRST_MASK};
use super::prefetch;
use super::stack::Stack;
use super::traverse::Counter;
use super::{LEAF_BIT, MAX_DEPTH, Node};
use crate::geometry::{Aabb, Ray, hit_limit};
pub(crate) use discs::{DiscCache, LaneDiscs};
use simd::{RayLanes, hit4};
use std::ops::Range;
use std::sync::Arc;

/// Children per wide node.
pub const WIDTH: usize = 4;

/// Most triangles one wide leaf holds.
pub const MAX_WIDE_LEAF: usize = 8;

/// Cost of one wide node visit in units of one watertight triangle test. `bench cpu` measures the bare
/// kernels (rows `kinetrace kernels`): a four-box SSE test 1.7 ns, a triangle test 7.3 ns, ratio 0.23
/// (2-core dev VM, release); a visit also sorts the hit lanes and pushes them, which we count as as much
/// again, hence 0.5. With so cheap a node against the watertight triangle test, the SAH rule keeps leaves
/// small: most wide leaves hold the binary tree's single triangles.
pub const WIDE_NODE_COST: f32 = 0.5;

/// Payload of an unused lane (its box is empty, so no ray ever reaches it).
const EMPTY_LANE: u32 = u32::MAX;

/// One node of a [`WideBvh`]: four child boxes as structure of arrays, 112 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WideNode {
    /// Child boxes by row: `[min x, min y, min z, max x, max y, max z][lane]`. Unused lanes hold the empty
    /// box (`+∞` minima, `−∞` maxima).
    pub bounds: [[f32; WIDTH]; 6],
    /// Per lane: an inner child's index in [`WideBvh::nodes`]; a leaf as in [`Node::index`] (bit 31 set,
    /// bits 27..=30 the count, bits 0..=26 the first slot); `u32::MAX` for an unused lane.
    pub child: [u32; WIDTH],
}

const _: () = assert!(std::mem::size_of::<WideNode>() == 112);

impl WideNode {
    const EMPTY: WideNode = WideNode {
        bounds: [
            [f32::INFINITY; WIDTH],
            [f32::INFINITY; WIDTH],
            [f32::INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
            [f32::NEG_INFINITY; WIDTH],
        ],
        child: [EMPTY_LANE; WIDTH],
    };

    /// The box of lane `i`.
    pub fn lane_box(&self, i: usize) -> Aabb {
        let b = &self.bounds;
        Aabb::new(
            [b[0][i], b[1][i], b[2][i]].into(),
            [b[3][i], b[4][i], b[5][i]].into(),
        )
    }

    fn set_lane_box(&mut self, i: usize, n: &Node) {
        for a in 0..3 {
            self.bounds[a][i] = n.min[a];
            self.bounds[3 + a][i] = n.max[a];
        }
    }
}

/// Entries a walk of the wide tree may hold: each level pushes at most three siblings, and wide trees are
/// no deeper than their binary tree.
const WIDE_STACK: usize = (WIDTH - 1) * MAX_DEPTH + 1;

/// The stack of a nearest-first walk: a child and its entry key, with room for [`nearest_first`]'s three
/// writes above the deepest push.
type NearStack = Stack<(u32, f32), { WIDE_STACK + WIDTH }>;

/// True for a lane payload that is a leaf (unused lanes included).
#[inline]
fn is_leaf(payload: u32) -> bool {
    payload & LEAF_BIT != 0
}

/// Slots of a leaf payload.
#[inline]
fn leaf_slots(payload: u32) -> Range<usize> {
    let first = (payload & FIRST_MASK) as usize;
    first..first + ((payload >> COUNT_SHIFT) & 0xf) as usize
}

/// Sorts the lanes of `mask` (not empty) by `key` (lane order among equals), pushes all but the nearest
/// onto `stack` farthest first, and returns the nearest lane's child, to visit next. Shared by the ray walk
/// (keys: entry distances) and the closest-point walk (squared box and disc distances).
///
/// Without a branch on the keys: the lanes are sorted by a five-exchange network on codes (a kept lane's
/// key bits, which order as the non-negative keys do, above its lane number; a dropped lane below every
/// kept one), and three entries are written with the kept ones counted. An insertion sort and its loop
/// over the kept lanes mispredicted about twice a node (`callgrind --branch-sim`). A negative key (a ray
/// whose `tmin` is below 0, inside the box) is ordered as 0, nearest; the key pushed is always exact.
#[inline(always)]
fn nearest_first(
    child: &[u32; WIDTH],
    mask: u32,
    key: &[f32; WIDTH],
    stack: &mut NearStack,
) -> u32 {
    // The key's bits (0 for a set sign bit) less their two lowest (keys that close tie: only the order is
    // approximate, the key pushed is exact), one step up so that a kept key of 0 stays above the dropped
    // lanes; `wrapping_` for the NaN bit patterns only a dropped lane has.
    let code = |i: usize| {
        let kept = (mask >> i) & 1;
        let bits = key[i].to_bits();
        let bits = bits & !((bits as i32 >> 31) as u32);
        ((bits >> 2).wrapping_add(1) << 2).wrapping_mul(kept) | i as u32
    };
    let mut c = [code(0), code(1), code(2), code(3)];
    // Descending: the farthest first, the nearest at `kept − 1`.
    for (i, j) in [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)] {
        let (a, b) = (c[i], c[j]);
        c[i] = a.max(b);
        c[j] = a.min(b);
    }
    let lane = |j: usize| (c[j] & 3) as usize;
    let entry = |j: usize| (child[lane(j)], key[lane(j)]);
    let kept = mask.count_ones() as usize;
    stack.push_first([entry(0), entry(1), entry(2)], kept - 1);
    child[lane(kept - 1)]
}

/// A 4-wide BVH over the same slots as the binary [`Bvh`](super::Bvh) it was collapsed from. See the
/// [module docs](self).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WideBvh {
    nodes: Vec<WideNode>,
    /// For each node and lane, the binary node whose box the lane copies on a refit (`u32::MAX`: unused).
    /// Topology: clones share it.
    src: Arc<[[u32; WIDTH]]>,
}

impl WideBvh {
    /// Collapses a binary tree (see the [module docs](self)). O(n) time, 20 bytes of scratch per binary node.
    pub fn collapse(bin: &[Node]) -> WideBvh {
        if bin.is_empty() {
            return WideBvh::default();
        }
        let plan = LeafPlan::new(bin);
        // About 0.4 wide nodes per triangle with the usual small leaves: reserve that (a binary tree has
        // about two nodes per triangle) so the arrays do not move while they grow.
        let mut nodes = Vec::with_capacity(bin.len() / 4 + 1);
        let mut src = Vec::with_capacity(bin.len() / 4 + 1);
        nodes.push(WideNode::EMPTY);
        src.push([EMPTY_LANE; WIDTH]);
        let mut work = vec![(0usize, 0usize)];
        while let Some((wi, b)) = work.pop() {
            // Only the root can be a planned leaf here: inner wide children are never planned leaves.
            let (kids, len) = if plan.is_leaf(b) {
                ([b; WIDTH], 1)
            } else {
                open(bin, &plan, b)
            };
            for (lane, &c) in kids[..len].iter().enumerate() {
                nodes[wi].set_lane_box(lane, &bin[c]);
                src[wi][lane] = c as u32;
                nodes[wi].child[lane] = if plan.is_leaf(c) {
                    let Planned { count, first, .. } = plan.0[c];
                    LEAF_BIT | (count << COUNT_SHIFT) | first
                } else {
                    nodes.push(WideNode::EMPTY);
                    src.push([EMPTY_LANE; WIDTH]);
                    work.push((nodes.len() - 1, c));
                    (nodes.len() - 1) as u32
                };
            }
        }
        WideBvh {
            nodes,
            src: src.into(),
        }
    }

    /// The nodes, root first.
    pub fn nodes(&self) -> &[WideNode] {
        &self.nodes
    }

    /// Bytes held: nodes plus refit sources (the sources shared with clones counted in full).
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * std::mem::size_of::<WideNode>() + self.src.len() * 4 * WIDTH
    }

    /// Copies the (refitted) boxes of `bin`, the binary tree this was collapsed from, into the lanes.
    /// O(wide nodes), no allocation.
    pub(crate) fn refit(&mut self, bin: &[Node]) {
        for (node, src) in self.nodes.iter_mut().zip(self.src.iter()) {
            for (lane, &s) in src.iter().enumerate() {
                if s != EMPTY_LANE {
                    node.set_lane_box(lane, &bin[s as usize]);
                }
            }
        }
    }

    /// Walks the leaves whose boxes the ray reaches within the current `tmax`, nearest box first, with the
    /// contract of the binary `traverse`: `leaf(slots, tmax)` may lower `*tmax` and returns true to stop.
    /// `slack` is the ray's [`hit_slack`](Ray::hit_slack) for the tree's box, added to every limit as the
    /// binary `traverse` adds it. `slot_data` is what a leaf's slots index (the triangles), asked of the
    /// cache as soon as a leaf's box is hit ([`prefetch_lanes`]). The ray must be valid.
    #[inline]
    pub(crate) fn traverse<C: Counter, T>(
        &self,
        slot_data: &[T],
        ray: &Ray,
        slack: f32,
        counter: &mut C,
        leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
    ) {
        walk(&self.nodes, slot_data, ray, slack, counter, leaf);
    }
}

/// Asks the cache for what the kept lanes of `mask` lead to, so that it arrives while the walk goes on
/// with the nearest lane: a leaf lane's first slot's entries in `slot_data` (two lines), an inner lane's
/// node in `nodes` and its per-node data in `node_data` (two lines each; the node's twice when
/// `node_data` is empty). A dropped lane asks for node `here`, the one just visited, already in cache.
/// Four lanes and no branch per lane: a loop over the kept lanes mispredicted its exit about once a
/// node. A hint only: no load, no fault, whatever the address. For ray walks it made incoherent
/// closest-hit rays 1.12–1.21× as fast (`bench cpu --quick`, random rays, one thread, medians of six
/// alternated runs, 2-core Intel VM) and left coherent camera rays, whose lines are in cache anyway,
/// unchanged within noise.
#[inline(always)]
fn prefetch_lanes<N, T, D>(
    nodes: &[N],
    here: u32,
    child: &[u32; WIDTH],
    mask: u32,
    slot_data: &[T],
    node_data: &[D],
) {
    let here: *const i8 = nodes.as_ptr().wrapping_add(here as usize).cast();
    for (i, &c) in child.iter().enumerate() {
        let first = (c & FIRST_MASK) as usize;
        let slot: *const i8 = slot_data.as_ptr().wrapping_add(first).cast();
        let inner: *const i8 = nodes.as_ptr().wrapping_add(c as usize).cast();
        let data: *const i8 = if node_data.is_empty() {
            inner
        } else {
            node_data.as_ptr().wrapping_add(c as usize).cast()
        };
        let (a, b) = match (mask >> i & 1 != 0, is_leaf(c)) {
            (false, _) => (here, here),
            (true, true) => (slot, slot),
            (true, false) => (inner, data),
        };
        for at in [a, a.wrapping_add(64), b, b.wrapping_add(64)] {
            prefetch(at);
        }
    }
}

/// A wide node a ray walk can test.
pub(crate) trait Visit {
    /// The node's four lanes against a ray within `tmax`: the hit mask, the entry distances and the lane
    /// payloads.
    fn visit(&self, lanes: &RayLanes, tmax: f32) -> (u32, [f32; WIDTH], [u32; WIDTH]);
}

impl Visit for WideNode {
    #[inline(always)]
    fn visit(&self, lanes: &RayLanes, tmax: f32) -> (u32, [f32; WIDTH], [u32; WIDTH]) {
        let (mask, near) = hit4(self, lanes, tmax);
        (mask, near, self.child)
    }
}

/// The ordered traversal of a wide tree whose root is `nodes[0]` (none for an empty tree), with the
/// contract of [`WideBvh::traverse`] (the float tree tests its nodes, the [`compact`] one dequantises
/// them first: [`Visit`]).
#[inline(always)]
fn walk<N: Visit, C: Counter, T>(
    nodes: &[N],
    slot_data: &[T],
    ray: &Ray,
    slack: f32,
    counter: &mut C,
    mut leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
) {
    if nodes.is_empty() {
        return;
    }
    let lanes = RayLanes::new(ray);
    // Boxes against `tmax` moved outward by the far slack and the ray's `slack` for the tree, as in the
    // binary `traverse` (which says why).
    let mut tmax = ray.tmax;
    let mut limit = hit_limit(tmax, slack);
    let mut stack = NearStack::new();
    let mut cur = 0u32;
    loop {
        if is_leaf(cur) {
            let slots = leaf_slots(cur);
            counter.leaf(slots.len());
            if leaf(slots, &mut tmax) {
                return;
            }
            limit = hit_limit(tmax, slack);
        } else {
            counter.inner();
            let (mask, near, child) = nodes[cur as usize].visit(&lanes, limit);
            if mask != 0 {
                prefetch_lanes::<_, _, ()>(nodes, cur, &child, mask, slot_data, &[]);
                cur = nearest_first(&child, mask, &near, &mut stack);
                continue;
            }
        }
        // Pop the next subtree that can still hold something within tmax.
        match pop_within(&mut stack, limit) {
            Some(node) => cur = node,
            None => return,
        }
    }
}

/// Walks [`interleaved`] keeps going at once: with four, one walk's node is on its way from memory
/// while the other three test theirs (two gained less, eight no more; `bench cpu --quick`).
const INTERLEAVED: usize = 4;

/// A walk for [`interleaved`] to run: a ray down one wide tree.
pub(crate) struct Job<'a, N, T, X> {
    /// The tree's nodes (root first), and what its leaves' slots index (asked of the cache ahead).
    pub nodes: &'a [N],
    pub slot_data: &'a [T],
    /// The ray's box-test constants, and its box limit ([`hit_limit`]; a closest-hit walk's shrinks).
    pub lanes: RayLanes,
    pub limit: f32,
    /// What the caller's leaf test needs (the ray, its triangles).
    pub data: X,
}

/// Runs walks `0..jobs` ([`Job`]s, from `start(job)`; `None`: nothing to walk), [`INTERLEAVED`] at a
/// time and a node of each in turn: the answers of as many [`walk`]s, but while one walk waits for its
/// next node (or leaf triangles) to come from memory, the others work — a single walk spends over half
/// of its time on those two loads when the tree is not in cache. At each leaf, `leaf(data, slot_data,
/// slots, limit)` tests the walk's ray against the slots, and may shrink the walk's box `limit` (a
/// closest hit found nearer); where it returns true (an any-hit walk's first hit) the walk calls
/// `hit(data)` and ends. A walk whose `settled(data)` turns true (its ray was found blocked by another
/// walk) ends at its next step. Without such walks it costs the same node visits as the walks one by
/// one.
pub(crate) fn interleaved<'a, N: Visit + 'a, T: 'a, X>(
    jobs: usize,
    mut start: impl FnMut(usize) -> Option<Job<'a, N, T, X>>,
    mut leaf: impl FnMut(&mut X, &[T], Range<usize>, &mut f32) -> bool,
    mut hit: impl FnMut(&X),
    settled: impl Fn(&X) -> bool,
) {
    let mut next = 0;
    // The next job with something to walk, at its root.
    let mut begin = || {
        while next < jobs {
            next += 1;
            match start(next - 1) {
                Some(job) if !job.nodes.is_empty() => return Some((job, 0u32)),
                _ => {}
            }
        }
        None
    };
    // Each walk's stack stays in place (not moved with the walk: 1.6 KB), emptied when a walk ends.
    let mut stacks: [NearStack; INTERLEAVED] = std::array::from_fn(|_| NearStack::new());
    let mut walks: [Option<_>; INTERLEAVED] = std::array::from_fn(|_| begin());
    while walks.iter().any(Option::is_some) {
        for (slot, stack) in walks.iter_mut().zip(&mut stacks) {
            let Some((w, cur)) = slot else { continue };
            let ended = if settled(&w.data) {
                true
            } else if is_leaf(*cur)
                && leaf(&mut w.data, w.slot_data, leaf_slots(*cur), &mut w.limit)
            {
                hit(&w.data);
                true
            } else {
                if !is_leaf(*cur) {
                    let (mask, near, child) = w.nodes[*cur as usize].visit(&w.lanes, w.limit);
                    if mask != 0 {
                        prefetch_lanes::<_, _, ()>(w.nodes, *cur, &child, mask, w.slot_data, &[]);
                        *cur = nearest_first(&child, mask, &near, stack);
                        continue;
                    }
                }
                match pop_within(stack, w.limit) {
                    Some(node) => {
                        *cur = node;
                        false
                    }
                    None => true,
                }
            };
            if ended {
                stack.clear();
                *slot = begin();
            }
        }
    }
}

/// Pops the next subtree whose entry lies within `limit` (those beyond it are dropped): `None` when the
/// stack runs out, the walk's end.
#[inline(always)]
pub(super) fn pop_within(stack: &mut NearStack, limit: f32) -> Option<u32> {
    std::iter::from_fn(|| stack.pop()).find_map(|(node, entry)| (entry <= limit).then_some(node))
}

/// What the collapse knows of one binary node.
#[derive(Clone, Copy, Default)]
struct Planned {
    /// Triangles in the subtree.
    count: u32,
    /// First slot of the subtree (subtrees own contiguous slot ranges).
    first: u32,
    /// Half surface area of the node's box.
    area: f32,
    /// True when the subtree becomes one wide leaf.
    leaf: bool,
}

/// Per binary node, in node order: counts, areas and the leaf decisions.
struct LeafPlan(Vec<Planned>);

impl LeafPlan {
    /// One reverse pass (children follow their parent): SAH costs in half-area units, leaf cost
    /// `A · n`, inner cost `A · WIDE_NODE_COST / 3 + cost(children)`.
    fn new(bin: &[Node]) -> LeafPlan {
        let mut p = vec![Planned::default(); bin.len()];
        let mut cost = vec![0f32; bin.len()];
        for i in (0..bin.len()).rev() {
            let node = &bin[i];
            let area = node.aabb().half_area();
            if node.is_leaf() {
                let count = node.count() as u32;
                p[i] = Planned {
                    count,
                    first: node.first() as u32,
                    area,
                    leaf: true,
                };
                cost[i] = area * count as f32;
                continue;
            }
            let (l, r) = (node.left(), node.left() + 1);
            let count = p[l].count + p[r].count;
            let inner = area * WIDE_NODE_COST / (WIDTH - 1) as f32 + cost[l] + cost[r];
            let as_leaf = area * count as f32;
            let leaf = count as usize <= MAX_WIDE_LEAF && as_leaf <= inner;
            p[i] = Planned {
                count,
                first: p[l].first.min(p[r].first),
                area,
                leaf,
            };
            cost[i] = if leaf { as_leaf } else { inner };
        }
        LeafPlan(p)
    }

    fn is_leaf(&self, i: usize) -> bool {
        self.0[i].leaf
    }
}

/// The up to four binary nodes a wide node over inner binary node `b` gets (in `kids[..len]`): its two
/// children, then the largest-area child that is not a planned leaf opened into its two, until there are
/// four or none is left.
fn open(bin: &[Node], plan: &LeafPlan, b: usize) -> ([usize; WIDTH], usize) {
    let mut kids = [0usize; WIDTH];
    (kids[0], kids[1]) = (bin[b].left(), bin[b].left() + 1);
    let mut len = 2;
    while len < WIDTH {
        let mut best: Option<(usize, f32)> = None;
        for (j, &k) in kids[..len].iter().enumerate() {
            let area = plan.0[k].area;
            if !plan.is_leaf(k) && best.is_none_or(|(_, a)| area > a) {
                best = Some((j, area));
            }
        }
        let Some((j, _)) = best else { break };
        let c = bin[kids[j]].left();
        kids.copy_within(j + 1..len, j + 2);
        (kids[j], kids[j + 1]) = (c, c + 1);
        len += 1;
    }
    (kids, len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `nearest_first` returns the nearest kept lane's child and leaves the other kept lanes on the stack,
    /// nearest on top, each with its exact key, as a stable sort of the kept lanes does (`sort_by` on
    /// `total_cmp`, negative keys as 0: an oracle that shares nothing with the network), for every mask
    /// and keys with ties, zeros, negatives and infinities (keys that differ in more than their two lowest
    /// bits).
    #[test]
    fn nearest_first_matches_a_stable_sort() {
        let values = [-1.0, 0.0, 0.5, 1.0, 3.0, f32::INFINITY];
        let n = values.len();
        let mut cases = 0;
        for mask in 1u32..16 {
            for k in 0..n.pow(4) {
                let key: [f32; WIDTH] = std::array::from_fn(|i| values[k / n.pow(i as u32) % n]);
                let child = [10, 11, 12, 13];
                let mut stack = NearStack::new();
                stack.push((99, 9.0));
                let first = nearest_first(&child, mask, &key, &mut stack);
                let mut kept: Vec<usize> = (0..WIDTH).filter(|&i| mask >> i & 1 != 0).collect();
                kept.sort_by(|&a, &b| key[a].max(0.0).total_cmp(&key[b].max(0.0)));
                assert_eq!(first, child[kept[0]], "mask {mask:b} keys {key:?}");
                let popped: Vec<(u32, u32)> = std::iter::from_fn(|| stack.pop())
                    .map(|(c, k)| (c, k.to_bits()))
                    .collect();
                let expected: Vec<(u32, u32)> = kept[1..]
                    .iter()
                    .map(|&i| (child[i], key[i].to_bits()))
                    .chain([(99, 9f32.to_bits())])
                    .collect();
                assert_eq!(popped, expected, "mask {mask:b} keys {key:?}");
                cases += 1;
            }
        }
        assert_eq!(cases, 15 * 6usize.pow(4));
    }
}
