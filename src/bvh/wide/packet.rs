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
//! is dropped. A leaf tests the rays of its range against the leaf box, four rays per SSE test (the two
//! ends are known to hit it when it is entered straight from its parent's scan), and then its triangles.
//! The interval culling takes the four child boxes of a node in one SSE pass ([`LaneBounds`]).
//!
//! What the four-ray leaf test buys: on the crowd's sorted reflection runs (1024², 36 rays a packet) a
//! packet visits about half the inner nodes its rays visit alone (4.9 four-box tests a ray against 10.2),
//! but its rays part near the leaves, and testing each ray of a leaf's range against the leaf box, one at a
//! time (4.4 box tests a ray), gave most of that back: the runs were no faster than single rays. Four rays a
//! test, the runs trace 14–16% faster (thread CPU time, loaded 2-core VM).
//!
//! **Answers equal single rays.** A ray whose own traversal reaches a leaf lies, at every ancestor, inside
//! the range the packet gives that child (the scans stop at the first and the last ray whose own test
//! accepts it, with a `tmax` no smaller than the ray alone has there), and the interval bound never culls
//! a box such a ray enters (see the binary scheme). So each ray finds the same closest `t`, and ties are
//! kept by the rule of the binary packets.
//!
//! **Cost.** No allocation: a stack of [`WIDE_STACK`] 16-byte entries on the call stack, and each ray's
//! four-box constants in the packet's per-thread lanes.

use super::simd::{RayLanes, hit4};
use super::{EMPTY_LANE, WIDE_STACK, WIDTH, WideBvh, WideNode, is_leaf, leaf_slots};
use crate::bvh::packet::{Bounds, Packet, lanes, range_mask};
use crate::bvh::stack::Stack;
use crate::bvh::{MeshBvh, TraversalStats};
use crate::geometry::hit_limit;

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
        for (l, r) in p.lanes.wide.iter_mut().zip(p.rays) {
            *l = RayLanes::new(r);
        }
        let test = |p: &Packet, node, i: usize| {
            hit4(node, &p.lanes.wide[i], hit_limit(p.lanes.tmax[i], p.slack)).0
        };
        let lanes4 = LaneBounds::new(bounds);
        let mut limit_all = p.limit_all();
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
                    limit_all = p.limit_all();
                }
            } else {
                stats.inner_visits += 1;
                let node = &nodes[cur.child as usize];
                let (culled, keys) = lanes4.enter4(node, limit_all);
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
                if e.key <= limit_all {
                    (cur, fresh) = (e, false);
                    break;
                }
            }
        }
    }
}

/// The packet's interval bounds ([`Bounds`]) set out for a wide node's four lanes: per axis on which the
/// packet can cull, the rows of the near and the far plane and the origin ends they are taken against,
/// chosen once per packet instead of per box.
#[derive(Clone, Copy)]
struct LaneBounds {
    /// Per usable axis: near-plane row, the origin end it is taken against, far-plane row, its origin end,
    /// and the reciprocal interval's ends.
    axes: [(usize, f32, usize, f32, f32, f32); 3],
    /// Usable axes (at least one: a packet without one is traced ray by ray).
    count: usize,
    tmin: f32,
}

impl LaneBounds {
    fn new(b: &Bounds) -> Self {
        let (neg, usable) = (b.neg.bitmask(), b.usable.bitmask());
        let mut axes = [(0, 0.0, 0, 0.0, 0.0, 0.0); 3];
        let mut count = 0;
        for a in (0..3).filter(|a| usable >> a & 1 == 1) {
            let (r0, r1) = (b.rlo[a], b.rhi[a]);
            axes[count] = if neg >> a & 1 == 1 {
                (3 + a, b.olo[a], a, b.ohi[a], r0, r1)
            } else {
                (a, b.ohi[a], 3 + a, b.olo[a], r0, r1)
            };
            count += 1;
        }
        Self {
            axes,
            count,
            tmin: b.tmin,
        }
    }

    /// [`Bounds::enter`] for the four lanes of `node` at once: bit `c` set when some ray may reach lane
    /// `c`'s box within `tmax`, and each such lane's lower bound of the entry distances. The same rounded
    /// operations as `Bounds::enter` on every lane (no NaN arises: a usable axis has finite non-zero
    /// reciprocals, and empty lanes' infinite planes give infinite, culled bounds), so the same lanes and
    /// bounds.
    #[inline]
    fn enter4(&self, node: &WideNode, tmax: f32) -> (u32, [f32; WIDTH]) {
        let used = node.child.iter().enumerate();
        let used = used.fold(0, |m, (c, &ch)| m | u32::from(ch != EMPTY_LANE) << c);
        #[cfg(target_arch = "x86_64")]
        {
            let (mask, keys) = self.enter4_sse(node, tmax);
            (mask & used, keys)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let b = &node.bounds;
            let mut keys = [f32::INFINITY; WIDTH];
            let mut mask = 0;
            for (c, key) in keys.iter_mut().enumerate() {
                let (mut near, mut far) = (f32::NEG_INFINITY, f32::INFINITY);
                for &(nr, no, fr, fo, r0, r1) in &self.axes[..self.count] {
                    let (n, f) = (b[nr][c] - no, b[fr][c] - fo);
                    near = near.max((n * r0).min(n * r1));
                    far = far.min((f * r0).max(f * r1));
                }
                *key = near.max(self.tmin);
                if *key <= crate::geometry::robust_far(far).min(tmax) {
                    mask |= 1 << c;
                }
            }
            (mask & used, keys)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline]
    fn enter4_sse(&self, node: &WideNode, tmax: f32) -> (u32, [f32; WIDTH]) {
        use std::arch::x86_64::*;
        // SAFETY: SSE and SSE2 are part of the x86-64 baseline; the loads read the node's `[f32; 4]` rows
        // and the store writes `keys` (16 bytes each), all unaligned forms.
        unsafe {
            let row = |i: usize| _mm_loadu_ps(node.bounds[i].as_ptr());
            let mut near = _mm_set1_ps(f32::NEG_INFINITY);
            let mut far = _mm_set1_ps(f32::INFINITY);
            for &(nr, no, fr, fo, r0, r1) in &self.axes[..self.count] {
                let (r0, r1) = (_mm_set1_ps(r0), _mm_set1_ps(r1));
                let n = _mm_sub_ps(row(nr), _mm_set1_ps(no));
                let f = _mm_sub_ps(row(fr), _mm_set1_ps(fo));
                near = _mm_max_ps(near, _mm_min_ps(_mm_mul_ps(n, r0), _mm_mul_ps(n, r1)));
                far = _mm_min_ps(far, _mm_max_ps(_mm_mul_ps(f, r0), _mm_mul_ps(f, r1)));
            }
            let tnear = _mm_max_ps(near, _mm_set1_ps(self.tmin));
            // `minps` returns its second operand when one is NaN: `tmax` first, as `f32::min` ignores it.
            let limit = _mm_min_ps(_mm_set1_ps(tmax), super::simd::robust_far_sse(far));
            let mask = _mm_movemask_ps(_mm_cmple_ps(tnear, limit)) as u32;
            let mut keys = [0.0f32; WIDTH];
            _mm_storeu_ps(keys.as_mut_ptr(), tnear);
            (mask, keys)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Ray;
    use crate::scenes::SceneRng;
    use glam::Vec3;

    #[test]
    fn four_lanes_at_once_cull_as_the_packet_bounds_do_box_by_box() {
        let mut rng = SceneRng::new(29);
        let mut checked = 0;
        for round in 0..3_000 {
            // A packet whose directions share a sign on some axes (those can cull), origins nearby.
            let (base, spread) = (rng.range(-3.0, 3.0), rng.range(0.0, 1.0));
            let signs = [0, 1, 2].map(|_| rng.next_u64() % 3);
            let n = 1 + (rng.next_u64() % 64) as usize;
            let rays: Vec<Ray> = (0..n)
                .map(|_| {
                    let o = Vec3::new(base, base * 0.5, -base)
                        + spread * Vec3::splat(rng.range(-1.0, 1.0));
                    let d = Vec3::from(signs.map(|s| match s {
                        0 => rng.range(0.1, 1.0),
                        1 => -rng.range(0.1, 1.0),
                        _ => rng.range(-1.0, 1.0),
                    }));
                    Ray::with_range(o, d, rng.range(0.0, 0.1), f32::INFINITY)
                })
                .collect();
            let Some(bounds) = Bounds::new(&rays, u64::MAX >> (64 - n)) else {
                continue;
            };
            let mut node = WideNode::EMPTY;
            for c in 0..WIDTH {
                if rng.next_u64().is_multiple_of(5) {
                    continue; // an unused lane: the empty box
                }
                let (a, b) = (
                    [0; 3].map(|_| rng.range(-4.0, 4.0)),
                    [0; 3].map(|_| rng.range(-4.0, 4.0)),
                );
                for k in 0..3 {
                    node.bounds[k][c] = a[k].min(b[k]);
                    node.bounds[3 + k][c] = a[k].max(b[k]);
                }
                node.child[c] = c as u32;
            }
            let tmax = if round % 3 == 0 {
                f32::INFINITY
            } else {
                rng.range(0.0, 8.0)
            };
            let (mask, keys) = LaneBounds::new(&bounds).enter4(&node, tmax);
            for (c, key) in keys.iter().enumerate() {
                let one = (node.child[c] != EMPTY_LANE)
                    .then(|| bounds.enter(&node.lane_box(c), tmax))
                    .flatten();
                assert_eq!(mask >> c & 1 == 1, one.is_some(), "round {round} lane {c}");
                if let Some(k) = one {
                    assert_eq!(key.to_bits(), k.to_bits(), "round {round} lane {c}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 1_000, "only {checked} lanes entered");
    }
}
