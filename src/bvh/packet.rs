//! Coherent ray packets through a [`MeshBvh`]: up to [`MAX_PACKET`] rays (a 4×4 or 8×8 tile of camera rays,
//! or shadow rays toward one light) walk the tree together. A mesh with its 4-wide query tree (the default)
//! walks that one, four child boxes per visit ([`wide`](super::wide), same scheme and answers); without
//! it (`BuildOptions::wide(false)`, or a compact tree) the binary tree, as below.
//!
//! **Scheme (ours, after Wald et al. 2007 "Ray Tracing Deformable Scenes using Dynamic BVHs" and Overbeck
//! et al. 2008 "Large Ray Packets"):** a node is first tested against the whole packet with *interval
//! arithmetic*: on each axis where every ray's direction has the same sign, the intervals of the origins and
//! of the reciprocal directions bound every ray's slab distances, and a box that the bounds place beyond
//! every ray's range is culled for all rays at once (one test instead of up to 64). A box that survives is
//! entered with the *active range*: the first and the last ray of the packet whose own slab test (the exact
//! test single rays use, against that ray's current closest hit) accepts the box — rays outside the range
//! skip the whole subtree. Leaves test the rays in the range against the leaf box four at a time (SSE on
//! x86-64, the bits of the single-ray test), then its triangles, four rays against each triangle at a time
//! (SSE on x86-64, the scalar watertight test's operations lane by lane: see `geometry/triangle4.rs`). Children
//! are visited nearer-first by their interval lower bound; a pushed sibling is re-scanned when popped, so
//! hits found meanwhile shrink its range.
//!
//! **Answers equal single rays.** Every box a ray's single-ray traversal would enter with a given `tmax` is
//! entered by the packet for that ray with the same or a larger bound: the interval bounds are computed with
//! the same rounded operations applied to the extreme origins and reciprocals (rounding is monotone) and
//! widened by the same Ize factor, and the range scans use [`Ray::intersect_aabb`] itself. So each ray finds
//! the same closest `t`; among triangles hit at exactly that `t` it keeps the lowest index it tested, which
//! can differ from the single ray's pick at a vertex fan (the tie rule of [`MeshBvh`]).
//!
//! **When it pays.** Packets amortise a node visit over the rays that share it: camera tiles and shadow
//! rays toward one point light. A packet with no axis on which all directions share a sign cannot be culled
//! as a whole and is traced ray by ray ([`MeshBvh::closest_hit`]) — the fallback rule; a merely wide packet
//! still gives exact answers, but its active ranges stay wide and it approaches the single-ray cost plus the
//! range scans. Costs: no allocation; the stack is [`MAX_DEPTH`] entries of 8 bytes, and the packet's per-ray
//! state (about 16 KB for 64 rays) is kept per thread from packet to packet, a packet setting only its own
//! rays' lanes ([`PacketLanes`]).

use super::stack::Stack;
use super::traverse::TraversalStats;
use super::wide::simd::RayLanes;
use super::{MAX_DEPTH, MeshBvh, Node};
use crate::bvh::Hit;
#[cfg(target_arch = "x86_64")]
use crate::geometry::TriangleRays;
use crate::geometry::{Aabb, Ray, TriangleHit, TriangleRay, hit_limit, robust_far};
use crate::parallel;
use glam::{BVec3, Vec3};
use std::cell::RefCell;
use std::ops::Range;

/// Most rays in one packet (a 64-bit active mask); longer slices given to the packet queries are cut into
/// packets of this size.
pub const MAX_PACKET: usize = 64;

/// Runs `trace(rays, out)` over consecutive packets of `packet` rays (clamped to `1..=MAX_PACKET`), on all
/// threads with the `parallel` feature: the batched form of every packet query. `out` must be as long as
/// `rays`.
pub(crate) fn for_each_packet<T: Send>(
    rays: &[Ray],
    packet: usize,
    out: &mut [T],
    trace: impl Fn(&[Ray], &mut [T]) + Sync + Send,
) {
    assert_eq!(rays.len(), out.len(), "one output per ray");
    let packet = packet.clamp(1, MAX_PACKET);
    parallel::fill_chunks(true, out, packet, |i, out| {
        trace(&rays[i * packet..i * packet + out.len()], out)
    });
}

/// Interval bounds over a packet's rays, per axis: origins, reciprocal directions, and which axes every
/// ray crosses in the same direction (the only axes that can cull).
pub(super) struct Bounds {
    pub(super) olo: Vec3,
    pub(super) ohi: Vec3,
    pub(super) rlo: Vec3,
    pub(super) rhi: Vec3,
    pub(super) neg: BVec3,
    pub(super) usable: BVec3,
    pub(super) tmin: f32,
}

impl Bounds {
    /// The bounds of the rays in `mask`; `None` when no axis can cull.
    pub(super) fn new(rays: &[Ray], mask: u64) -> Option<Bounds> {
        let (mut olo, mut ohi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let (mut rlo, mut rhi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let (mut any_neg, mut any_pos, mut zero) = (BVec3::FALSE, BVec3::FALSE, BVec3::FALSE);
        let mut tmin = f32::INFINITY;
        for i in lanes(mask) {
            let r = &rays[i];
            olo = olo.min(r.origin);
            ohi = ohi.max(r.origin);
            rlo = rlo.min(r.inv_dir());
            rhi = rhi.max(r.inv_dir());
            any_neg |= r.dir_neg();
            any_pos |= !r.dir_neg();
            zero |= r.dir().cmpeq(Vec3::ZERO);
            tmin = tmin.min(r.tmin);
        }
        let usable = !((any_neg & any_pos) | zero);
        usable.any().then_some(Bounds {
            olo,
            ohi,
            rlo,
            rhi,
            neg: any_neg,
            usable,
            tmin,
        })
    }

    /// A lower bound of every ray's entry distance into `b` when some ray may reach it within `tmax` (the
    /// packet's largest), else `None`.
    #[inline]
    pub(super) fn enter(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        // Near plane: the largest (b − o)·r any ray can have is bounded below by the extreme origin
        // against both ends of the reciprocal interval; far plane likewise from above.
        let n = Vec3::select(self.neg, b.max - self.olo, b.min - self.ohi);
        let f = Vec3::select(self.neg, b.min - self.ohi, b.max - self.olo);
        let near = (n * self.rlo).min(n * self.rhi);
        let far = (f * self.rlo).max(f * self.rhi);
        let near = Vec3::select(self.usable, near, Vec3::NEG_INFINITY);
        let far = Vec3::select(self.usable, far, Vec3::INFINITY);
        let tnear = near.max_element().max(self.tmin);
        (tnear <= robust_far(far.min_element()).min(tmax)).then_some(tnear)
    }
}

/// The lanes set in `mask`, lowest first.
#[inline]
pub(super) fn lanes(mut mask: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            i
        })
    })
}

/// Lanes `first..=last` of a 64-bit mask.
#[inline]
pub(super) fn range_mask(first: usize, last: usize) -> u64 {
    (u64::MAX >> (63 - last)) & (u64::MAX << first)
}

/// The state of one packet: its rays, their best hits and which are still looking. The per-ray arrays live
/// in the thread's [`PacketLanes`], of which a packet sets only its own rays' lanes.
pub(super) struct Packet<'a> {
    pub(super) rays: &'a [Ray],
    /// Rays still traversing (any-hit queries drop a ray at its first hit).
    pub(super) active: u64,
    pub(super) lanes: &'a mut PacketLanes,
    /// The largest [`Ray::hit_slack`] of the rays for the tree's box: every box test's limit adds it, as
    /// single rays add their own (see `traverse`).
    pub(super) slack: f32,
}

/// Per-ray state of a packet of up to [`MAX_PACKET`] rays (about 16 KB), kept per thread from packet to packet:
/// a packet of `n` rays writes lanes `0..n` only. Made afresh for each packet, the arrays' 64 lanes cost
/// more to clear than a short packet's rays cost to set up (sorted runs of reflection rays at 512² hold
/// about 16 rays). Lanes past the packet's rays hold an earlier packet's values: they are only ever read
/// by the four-ray tests, whose results for them are masked off.
pub(super) struct PacketLanes {
    /// Each ray's watertight-test constants (lanes of invalid rays are not set: they are never active),
    /// and the same by component for the four-ray test (x86-64).
    tris: [TriangleRay; MAX_PACKET],
    #[cfg(target_arch = "x86_64")]
    shear: TriangleRays<MAX_PACKET>,
    /// Current `tmax` of each ray (its closest hit so far); −∞ for an invalid ray.
    pub(super) tmax: [f32; MAX_PACKET],
    /// `(primitive, slot, u, v)` of each ray's best hit.
    best: [Option<(u32, usize, f32, f32)>; MAX_PACKET],
    /// The rays' slab-test constants by component, for the leaf box test four rays at a time.
    columns: RayColumns,
    /// Each ray's four-box constants for the wide tree, set by its walk.
    pub(super) wide: [RayLanes; MAX_PACKET],
}

impl PacketLanes {
    const EMPTY: PacketLanes = PacketLanes {
        tris: [TriangleRay::EMPTY; MAX_PACKET],
        #[cfg(target_arch = "x86_64")]
        shear: TriangleRays::EMPTY,
        tmax: [f32::NEG_INFINITY; MAX_PACKET],
        best: [None; MAX_PACKET],
        columns: RayColumns {
            origin: [[0.0; MAX_PACKET]; 3],
            inv_dir: [[0.0; MAX_PACKET]; 3],
            neg: [[0; MAX_PACKET]; 3],
            tmin: [0.0; MAX_PACKET],
        },
        wide: [RayLanes::EMPTY; MAX_PACKET],
    };
}

thread_local! {
    /// The thread's packet lanes (see [`PacketLanes`]); static storage, no allocation.
    static LANES: RefCell<PacketLanes> = const { RefCell::new(PacketLanes::EMPTY) };
}

/// Runs `f` with the thread's [`PacketLanes`] (a fresh set on the call stack if a packet on this thread
/// is already using them).
fn with_lanes<R>(f: impl FnOnce(&mut PacketLanes) -> R) -> R {
    LANES.with(|cell| match cell.try_borrow_mut() {
        Ok(mut lanes) => f(&mut lanes),
        Err(_) => {
            let mut fresh = PacketLanes::EMPTY;
            f(&mut fresh)
        }
    })
}

/// A packet's rays by component (structure of arrays): origins, reciprocal directions, each axis's sign
/// as an all-ones or all-zeros word, `tmin`.
struct RayColumns {
    origin: [[f32; MAX_PACKET]; 3],
    inv_dir: [[f32; MAX_PACKET]; 3],
    neg: [[u32; MAX_PACKET]; 3],
    tmin: [f32; MAX_PACKET],
}

impl RayColumns {
    /// Sets lane `i` to ray `r`.
    #[inline]
    fn set(&mut self, i: usize, r: &Ray) {
        let neg = r.dir_neg();
        for (a, neg) in [neg.x, neg.y, neg.z].into_iter().enumerate() {
            self.origin[a][i] = r.origin[a];
            self.inv_dir[a][i] = r.inv_dir()[a];
            self.neg[a][i] = if neg { u32::MAX } else { 0 };
        }
        self.tmin[i] = r.tmin;
    }
}

impl MeshBvh {
    /// [`closest_hit`](Self::closest_hit) for every ray of `rays`, traced as packets of up to
    /// [`MAX_PACKET`] consecutive rays (each node culled for the whole packet by interval arithmetic; a
    /// packet whose rays share no direction sign on any axis is traced ray by ray). `out` must be as long
    /// as `rays`; single-threaded (see [`closest_hits_packets`](Self::closest_hits_packets)).
    pub fn closest_hits_packet(
        &self,
        rays: &[Ray],
        out: &mut [Option<Hit>],
        stats: &mut TraversalStats,
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        with_lanes(|lanes| {
            for (rays, out) in rays.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
                let mut p = Packet::new(rays, lanes, &self.bvh().bounds());
                if self.trace_packet(&mut p, false, stats) {
                    let l = &p.lanes;
                    for (i, o) in out.iter_mut().enumerate() {
                        *o = l.best[i]
                            .map(|(prim, slot, u, v)| self.packet_hit(l.tmax[i], prim, slot, u, v));
                    }
                } else {
                    for (o, r) in out.iter_mut().zip(rays) {
                        *o = self.closest_hit_counted(r, stats);
                    }
                }
            }
        });
    }

    /// [`any_hit`](Self::any_hit) for every ray, as packets; like
    /// [`closest_hits_packet`](Self::closest_hits_packet).
    pub fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool], stats: &mut TraversalStats) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        with_lanes(|lanes| {
            for (rays, out) in rays.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
                let mut p = Packet::new(rays, lanes, &self.bvh().bounds());
                if self.trace_packet(&mut p, true, stats) {
                    for (i, o) in out.iter_mut().enumerate() {
                        *o = p.lanes.best[i].is_some();
                    }
                } else {
                    for (o, r) in out.iter_mut().zip(rays) {
                        *o = self.any_hit_counted(r, stats);
                    }
                }
            }
        });
    }

    /// Batched closest-hit queries: `rays` holds consecutive packets of `packet` rays each (camera tiles in
    /// tile order, or shadow rays grouped by light), traced on all threads with the `parallel` feature.
    pub fn closest_hits_packets(&self, rays: &[Ray], packet: usize, out: &mut [Option<Hit>]) {
        for_each_packet(rays, packet, out, |rays, out| {
            self.closest_hits_packet(rays, out, &mut TraversalStats::default())
        });
    }

    /// Batched any-hit queries (shadow rays), as [`closest_hits_packets`](Self::closest_hits_packets).
    pub fn any_hits_packets(&self, rays: &[Ray], packet: usize, out: &mut [bool]) {
        for_each_packet(rays, packet, out, |rays, out| {
            self.any_hits_packet(rays, out, &mut TraversalStats::default())
        });
    }

    fn packet_hit(&self, t: f32, primitive: u32, slot: usize, u: f32, v: f32) -> Hit {
        let [a, b, c] = self.slot_triangles()[slot];
        Hit {
            t,
            primitive,
            u,
            v,
            normal: (b - a).cross(c - a).normalize_or_zero(),
        }
    }

    /// Traces the packet `p` (up to [`MAX_PACKET`] rays, made by [`Packet::new`]); false when it must be
    /// traced ray by ray.
    fn trace_packet(&self, p: &mut Packet, any: bool, stats: &mut TraversalStats) -> bool {
        let rays = p.rays;
        let nodes = self.bvh().nodes();
        if p.active == 0 || nodes.is_empty() {
            return true;
        }
        let Some(bounds) = Bounds::new(rays, p.active) else {
            return false;
        };
        if let Some(wide) = self.wide() {
            wide.trace_packet(self, p, &bounds, any, stats);
            return true;
        }
        let mut limit_all = p.limit_all();
        let mut stack = Stack::<(u32, u8, u8), MAX_DEPTH>::new();
        let (mut cur, mut first, mut last) = (0usize, 0usize, MAX_PACKET - 1);
        if bounds.enter(&nodes[0].aabb(), limit_all).is_none() {
            return true;
        }
        loop {
            // Narrow the range to the first and last ray whose own slab test accepts this node.
            if let Some((f, l)) = p.scan(&nodes[cur], first, last) {
                (first, last) = (f, l);
                let n = &nodes[cur];
                if n.is_leaf() {
                    stats.leaf_visits += 1;
                    if p.leaf(self, &n.aabb(), n.slots(), (first, last, true), any, stats) {
                        if p.active == 0 {
                            return true;
                        }
                        limit_all = p.limit_all();
                    }
                } else {
                    stats.inner_visits += 1;
                    let c = n.left();
                    let a = bounds.enter(&nodes[c].aabb(), limit_all);
                    let b = bounds.enter(&nodes[c + 1].aabb(), limit_all);
                    let next = match (a, b) {
                        (Some(ka), Some(kb)) => {
                            let (near, far) = if ka <= kb { (c, c + 1) } else { (c + 1, c) };
                            stack.push((far as u32, first as u8, last as u8));
                            Some(near)
                        }
                        (Some(_), None) => Some(c),
                        (None, Some(_)) => Some(c + 1),
                        (None, None) => None,
                    };
                    if let Some(next) = next {
                        cur = next;
                        continue;
                    }
                }
            }
            let Some((n, f, l)) = stack.pop() else {
                return true;
            };
            (cur, first, last) = (n as usize, f as usize, l as usize);
        }
    }
}

impl<'a> Packet<'a> {
    /// The packet of `rays` (at most [`MAX_PACKET`]), its valid rays active, in `lanes` (see
    /// [`PacketLanes`]), for a tree whose root box is `root`.
    fn new(rays: &'a [Ray], lanes: &'a mut PacketLanes, root: &Aabb) -> Self {
        debug_assert!(rays.len() <= MAX_PACKET);
        let (mut active, mut slack) = (0, 0.0f32);
        for (i, r) in rays.iter().enumerate() {
            lanes.columns.set(i, r);
            lanes.best[i] = None;
            lanes.tmax[i] = f32::NEG_INFINITY;
            if r.is_valid() {
                lanes.tris[i] = TriangleRay::new(r);
                #[cfg(target_arch = "x86_64")]
                lanes.shear.set(i, &lanes.tris[i]);
                lanes.tmax[i] = r.tmax;
                active |= 1 << i;
                slack = slack.max(r.hit_slack(root));
            }
        }
        Packet {
            rays,
            active,
            lanes,
            slack,
        }
    }

    /// The rays of `mask` whose slab test ([`Ray::intersect_aabb`], the same bits) accepts `b` within their
    /// current `tmax`: four rays per SSE test on x86-64.
    #[inline]
    fn reach(&self, b: &Aabb, mask: u64) -> u64 {
        #[cfg(target_arch = "x86_64")]
        {
            self.reach_sse(b, mask)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            lanes(mask)
                .filter(|&i| self.reaches(i, b))
                .fold(0, |m, i| m | 1 << i)
        }
    }

    /// [`reach`](Self::reach) on SSE: lane by lane the operations of [`Ray::intersect_aabb`] in its order
    /// (the near and far planes picked by the sign, subtract, multiply, `maxps`/`minps` keeping the running
    /// value on NaN, the far scale, `<=`), as the wide tree's `hit4_sse` does for four boxes.
    #[cfg(target_arch = "x86_64")]
    #[inline]
    fn reach_sse(&self, b: &Aabb, mask: u64) -> u64 {
        use std::arch::x86_64::*;
        let c = &self.lanes.columns;
        let mut out = 0;
        let mut left = mask;
        while left != 0 {
            let g = (left.trailing_zeros() / 4 * 4) as usize;
            // SAFETY: SSE and SSE2 are part of the x86-64 baseline; `g + 4 <= MAX_PACKET` (g is a multiple
            // of 4 below 64), so every unaligned load reads four floats or words inside a column.
            let hit = unsafe {
                let (mut near, mut far) = (
                    _mm_loadu_ps(c.tmin[g..].as_ptr()),
                    _mm_set1_ps(f32::INFINITY),
                );
                for a in [2, 1, 0] {
                    let neg = _mm_castsi128_ps(_mm_loadu_si128(c.neg[a][g..].as_ptr().cast()));
                    let (lo, hi) = (_mm_set1_ps(b.min[a]), _mm_set1_ps(b.max[a]));
                    let np = _mm_or_ps(_mm_and_ps(neg, hi), _mm_andnot_ps(neg, lo));
                    let fp = _mm_or_ps(_mm_and_ps(neg, lo), _mm_andnot_ps(neg, hi));
                    let o = _mm_loadu_ps(c.origin[a][g..].as_ptr());
                    let inv = _mm_loadu_ps(c.inv_dir[a][g..].as_ptr());
                    near = _mm_max_ps(_mm_mul_ps(_mm_sub_ps(np, o), inv), near);
                    far = _mm_min_ps(_mm_mul_ps(_mm_sub_ps(fp, o), inv), far);
                }
                // Each ray's far distance moved outward by the slack, or its `tmax` so moved plus the
                // packet's slack, whichever is nearer.
                let tmax = _mm_loadu_ps(self.lanes.tmax[g..].as_ptr());
                let limit = _mm_min_ps(
                    super::wide::simd::robust_far_sse(far),
                    _mm_add_ps(
                        super::wide::simd::robust_far_sse(tmax),
                        _mm_set1_ps(self.slack),
                    ),
                );
                _mm_movemask_ps(_mm_cmple_ps(near, limit)) as u64
            };
            out |= hit << g;
            left &= !(0xf << g);
        }
        out & mask
    }

    /// Whether ray `i`'s own slab test ([`Ray::intersect_aabb`]) accepts `b` within its current `tmax`
    /// moved outward as single rays move it ([`hit_limit`], with the packet's slack; see `traverse`).
    #[inline]
    fn reaches(&self, i: usize, b: &Aabb) -> bool {
        self.rays[i]
            .intersect_aabb(b, hit_limit(self.lanes.tmax[i], self.slack))
            .is_some()
    }

    /// The largest current `tmax` of the active rays moved outward as each ray's is ([`hit_limit`]): no
    /// box whose entry lies beyond it can matter to the packet.
    #[inline]
    pub(super) fn limit_all(&self) -> f32 {
        hit_limit(
            lanes(self.active)
                .map(|i| self.lanes.tmax[i])
                .fold(f32::NEG_INFINITY, f32::max),
            self.slack,
        )
    }

    /// The first and last active ray in `first..=last` whose slab test accepts `n`'s box, or `None`.
    #[inline]
    fn scan(&self, n: &Node, first: usize, last: usize) -> Option<(usize, usize)> {
        let b = n.aabb();
        let hits = |&i: &usize| self.reaches(i, &b);
        let mask = self.active & range_mask(first, last.min(self.rays.len() - 1));
        let f = lanes(mask).find(hits)?;
        let mut upper = mask & !range_mask(0, f);
        while upper != 0 {
            let l = 63 - upper.leading_zeros() as usize;
            if hits(&l) {
                return Some((f, l));
            }
            upper &= !(1 << l);
        }
        Some((f, f))
    }

    /// Tests the triangles in `slots` (a leaf with box `b`) against the active rays in `first..=last` that
    /// reach `b` (`ends_known`: the first and the last are known to, and are not tested again); true when
    /// any ray's best hit changed.
    pub(super) fn leaf(
        &mut self,
        bvh: &MeshBvh,
        b: &Aabb,
        slots: Range<usize>,
        (first, last, ends_known): (usize, usize, bool),
        any: bool,
        stats: &mut TraversalStats,
    ) -> bool {
        let (tris, prims) = (bvh.slot_triangles(), bvh.bvh().prim_indices());
        let mut changed = false;
        let range = self.active & range_mask(first, last);
        let known = if ends_known {
            range & (1 << first | 1 << last)
        } else {
            0
        };
        let reach = self.reach(b, range & !known) | known;
        #[cfg(target_arch = "x86_64")]
        {
            // Four rays against each triangle at a time; each ray still meets the leaf's triangles in
            // slot order, with its `tmax` as lowered by the ones before.
            let mut left = reach;
            while left != 0 {
                let g = (left.trailing_zeros() / 4 * 4) as usize;
                let mut group = (left >> g) & 0xf;
                left &= !(0xf << g);
                for s in slots.clone() {
                    if group == 0 {
                        break;
                    }
                    stats.prim_tests += u64::from(group.count_ones());
                    let l = &*self.lanes;
                    let four = l.shear.intersect4(g, tris[s], &l.columns.tmin, &l.tmax);
                    for k in lanes(u64::from(four.hit | four.exact) & group) {
                        let i = g + k;
                        let h = if four.exact >> k & 1 == 0 {
                            TriangleHit {
                                t: four.t[k],
                                u: four.u[k],
                                v: four.v[k],
                            }
                        } else {
                            let Some(h) = self.test(i, tris[s]) else {
                                continue;
                            };
                            h
                        };
                        changed |= self.take(i, prims[s], s, h, any);
                        if any && self.active >> i & 1 == 0 {
                            group &= !(1 << k);
                        }
                    }
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        for i in lanes(reach) {
            for s in slots.clone() {
                stats.prim_tests += 1;
                if let Some(h) = self.test(i, tris[s]) {
                    changed |= self.take(i, prims[s], s, h, any);
                    if any && self.active >> i & 1 == 0 {
                        break;
                    }
                }
            }
        }
        changed
    }

    /// Ray `i` alone against `triangle` within its current range.
    #[inline]
    fn test(&self, i: usize, [a, b, c]: [Vec3; 3]) -> Option<TriangleHit> {
        let r = &self.rays[i];
        self.lanes.tris[i].intersect(a, b, c, r.tmin, self.lanes.tmax[i])
    }

    /// Keeps `h`, ray `i`'s hit on primitive `prim` (in `slot`), when it is nearer than the ray's best, or
    /// as near and of a lower primitive; an any-hit packet's ray ends there (see the `any` of
    /// [`leaf`](Self::leaf)). True when kept.
    #[inline]
    fn take(&mut self, i: usize, prim: u32, slot: usize, h: TriangleHit, any: bool) -> bool {
        let l = &mut *self.lanes;
        let t = l.tmax[i];
        if !l.best[i].is_none_or(|(bp, ..)| h.t < t || prim < bp) {
            return false;
        }
        l.best[i] = Some((prim, slot, h.u, h.v));
        l.tmax[i] = h.t;
        if any {
            self.active &= !(1 << i);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::SceneRng;

    /// A component from a small set that hits the edge cases (zeros of both signs, values on the boxes'
    /// planes) or a random value.
    fn pick(rng: &mut SceneRng, edges: &[f32]) -> f32 {
        match rng.next_u64() % 4 {
            0 => edges[(rng.next_u64() % edges.len() as u64) as usize],
            _ => rng.range(-2.0, 2.0),
        }
    }

    #[test]
    fn four_rays_at_a_time_reach_what_each_ray_reaches_alone() {
        let mut rng = SceneRng::new(13);
        let edges = [0.0, -0.0, 1.0, -1.0, 0.5];
        for round in 0..2_000 {
            let v = |rng: &mut SceneRng| {
                Vec3::new(pick(rng, &edges), pick(rng, &edges), pick(rng, &edges))
            };
            let n = 1 + (rng.next_u64() % MAX_PACKET as u64) as usize;
            let rays: Vec<Ray> = (0..n)
                .map(|_| {
                    let (o, d) = (v(&mut rng), v(&mut rng));
                    Ray::with_range(o, d, rng.range(0.0, 0.5), rng.range(0.0, 4.0))
                })
                .collect();
            let mut state = PacketLanes::EMPTY;
            let root = Aabb::new(v(&mut rng), v(&mut rng) + Vec3::splat(3.0));
            let p = Packet::new(&rays, &mut state, &root);
            // Some rays as if they had found hits; some lanes unlimited.
            for i in 0..n {
                match rng.next_u64() % 4 {
                    0 => p.lanes.tmax[i] = f32::INFINITY,
                    1 => p.lanes.tmax[i] = rng.range(0.0, 1.0),
                    _ => {}
                }
            }
            let (a, b) = (v(&mut rng), v(&mut rng));
            // Flat boxes (a plane on both sides) as well as solid ones.
            let b = if round % 5 == 0 {
                Aabb::new(a.min(b).with_y(a.y), a.max(b).with_y(a.y))
            } else {
                Aabb::new(a.min(b), a.max(b))
            };
            let mask = p.active & rng.next_u64();
            let alone = lanes(mask)
                .filter(|&i| {
                    rays[i]
                        .intersect_aabb(&b, hit_limit(p.lanes.tmax[i], p.slack))
                        .is_some()
                })
                .fold(0, |m, i| m | 1 << i);
            assert_eq!(p.reach(&b, mask), alone, "round {round}");
        }
    }
}
