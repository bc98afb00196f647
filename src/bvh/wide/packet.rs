//! Coherent ray packets through the 4-wide tree: the packet scheme of the binary tree (`bvh/packet.rs`:
//! interval-arithmetic culling of the whole packet, then an active range of rays) applied to four child
//! boxes per visit.
//!
//! **Scheme (ours).** At a wide node the packet's interval bounds cull each of the four child boxes for all
//! rays at once. For the children that survive, the active rays of the node's range are scanned upward
//! with the single-ray four-box test ([`hit4`], the same bits as a ray alone) until every surviving child
//! has its first ray, then downward until each has its last: a coherent tile pays a few four-box tests per
//! node instead of one per ray. Children are visited nearer-first by their interval lower bound, the
//! others pushed with their ranges; a popped child whose bound lies beyond every active ray's closest hit
//! is dropped. A leaf tests each ray of its range against the leaf box (skipped for the two ends when it is
//! entered straight from its parent's scan) and then its triangles.
//!
//! **Answers equal single rays.** A ray whose own traversal reaches a leaf lies, at every ancestor, inside
//! the range the packet gives that child (the scans stop at the first and the last ray whose own test
//! accepts it, with a `tmax` no smaller than the ray alone has there), and the interval bound never culls
//! a box such a ray enters (see the binary scheme). So each ray finds the same closest `t`, and ties are
//! kept by the rule of the binary packets.
//!
//! **Cost.** No allocation: a stack of [`WIDE_STACK`] 16-byte entries and each ray's four-box constants
//! (5 KB for 64 rays) on the call stack.

use super::simd::{RayLanes, hit4};
use super::{EMPTY_LANE, WIDE_STACK, WIDTH, WideBvh, is_leaf, leaf_slots};
use crate::bvh::packet::{Bounds, Packet, lanes, range_mask};
use crate::bvh::stack::Stack;
use crate::bvh::{MeshBvh, TraversalStats};

/// A child waiting on the stack: its payload, where its box lives (`parent` node, `lane`), its range of
/// rays and its interval lower bound.
#[derive(Clone, Copy)]
struct Entry {
    child: u32,
    parent: u32,
    lane: u8,
    first: u8,
    last: u8,
    key: f32,
}

impl WideBvh {
    /// Walks the packet `p` (its valid rays active, `bounds` their interval bounds) through the tree,
    /// leaving every ray's closest hit (or first hit, with `any`) in `p`.
    pub(in crate::bvh) fn trace_packet(
        &self,
        mesh: &MeshBvh,
        p: &mut Packet,
        bounds: &Bounds,
        any: bool,
        stats: &mut TraversalStats,
    ) {
        let nodes = self.nodes();
        if nodes.is_empty() {
            return;
        }
        let n = p.rays.len();
        // Each ray's four-box constants, made once per packet: made inside the scans, where a node's test
        // waited on them, the sorted runs of reflection rays traced 15–20% slower (thread CPU time, crowd
        // at 1024², loaded 2-core VM), and camera tiles were not faster either.
        let mut pre = [RayLanes::new(&p.rays[0]); crate::bvh::MAX_PACKET];
        for (l, r) in pre.iter_mut().zip(p.rays) {
            *l = RayLanes::new(r);
        }
        let test = |p: &Packet, node, i: usize| hit4(node, &pre[i], p.tmax[i]).0;
        let mut tmax_all = p.tmax_all();
        let mut stack = Stack::<Entry, WIDE_STACK>::new();
        let mut cur = Entry {
            child: 0,
            parent: EMPTY_LANE,
            lane: 0,
            first: 0,
            last: (n - 1) as u8,
            key: f32::NEG_INFINITY,
        };
        // Whether `cur` was entered straight from its parent's scan (its end rays are known to hit it).
        let mut fresh = true;
        loop {
            let (first, last) = (cur.first as usize, cur.last as usize);
            if is_leaf(cur.child) {
                stats.leaf_visits += 1;
                let b = nodes[cur.parent as usize].lane_box(cur.lane as usize);
                let range = (first, last, fresh);
                if p.leaf(mesh, &b, leaf_slots(cur.child), range, any, stats) {
                    if p.active == 0 {
                        return;
                    }
                    tmax_all = p.tmax_all();
                }
            } else {
                stats.inner_visits += 1;
                let node = &nodes[cur.child as usize];
                let mut keys = [f32::INFINITY; WIDTH];
                let mut culled = 0u32;
                for (c, key) in keys.iter_mut().enumerate() {
                    if node.child[c] != EMPTY_LANE
                        && let Some(k) = bounds.enter(&node.lane_box(c), tmax_all)
                    {
                        (*key, culled) = (k, culled | 1 << c);
                    }
                }
                let mask = p.active & range_mask(first, last);
                let (mut lo, mut hi) = ([0u8; WIDTH], [0u8; WIDTH]);
                let mut found = 0u32;
                for i in lanes(mask) {
                    let new = test(p, node, i) & culled & !found;
                    for c in lanes(new as u64) {
                        lo[c] = i as u8;
                    }
                    found |= new;
                    if found == culled {
                        break;
                    }
                }
                let mut ended = 0u32;
                let mut down = mask;
                while ended != found {
                    let i = 63 - down.leading_zeros() as usize;
                    down &= !(1 << i);
                    let new = test(p, node, i) & found & !ended;
                    for c in lanes(new as u64) {
                        hi[c] = i as u8;
                    }
                    ended |= new;
                }
                if found != 0 {
                    // Nearest first: sort the entered children by key, push all but the nearest.
                    let mut order = [0usize; WIDTH];
                    let mut k = 0;
                    for c in lanes(found as u64) {
                        let mut j = k;
                        while j > 0 && keys[order[j - 1]] > keys[c] {
                            order[j] = order[j - 1];
                            j -= 1;
                        }
                        order[j] = c;
                        k += 1;
                    }
                    let entry = |c: usize| Entry {
                        child: node.child[c],
                        parent: cur.child,
                        lane: c as u8,
                        first: lo[c],
                        last: hi[c],
                        key: keys[c],
                    };
                    for &c in order[1..k].iter().rev() {
                        stack.push(entry(c));
                    }
                    (cur, fresh) = (entry(order[0]), true);
                    continue;
                }
            }
            // Pop the next child some active ray may still reach.
            loop {
                let Some(e) = stack.pop() else {
                    return;
                };
                if e.key <= tmax_all {
                    (cur, fresh) = (e, false);
                    break;
                }
            }
        }
    }
}
