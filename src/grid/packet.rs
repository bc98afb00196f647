//! Frustum packets through the grid, slice by slice along the packet's major axis (paper §3).
//!
//! A packet is up to [`MAX_PACKET`] rays (a 4×4 or 8×8 tile of camera rays, or shadow rays toward one light)
//! whose directions share the sign of one axis `k`. Their lines are bounded by four planes in the frame
//! `(w, u, v)`, `w` the distance along `k` from the packet's first plane: `u ≥ u_min + s_min·w` and so on —
//! from each ray's crossing of that first plane and its slopes `du/dk`, which covers any origins, not only a
//! common one. Each slice of cells along `k` then costs four multiply-adds for the rectangle of cells the
//! frustum overlaps; macrocells skip empty blocks of that rectangle; a per-packet mailbox tests a triangle
//! once however many cells list it; and a triangle whose three corners all lie outside one frustum plane
//! (four lanes at once, a `Vec4` compare) is never tested against any ray. Rays stop when their closest hit
//! lies before the slice's exit plane; the packet stops when all have.
//!
//! **Splitting rule (ours).** A packet is traced ray by ray ([`UniformGrid::closest_hit`]) when its rays do
//! not share a direction sign on the major axis of their mean direction, when one of its rays is
//! [far](UniformGrid::is_far), when the spread of its slopes exceeds [`PACKET_SPREAD_LIMIT`] (past that
//! width the frustum covers so many cells per slice that single rays are cheaper), or when its entry points
//! scatter over more than [`PACKET_START_CELLS`] cells per ray across the major axis.

use super::{Mailbox, UniformGrid};
use crate::bvh::{Hit, TraversalStats, for_each_packet};
use crate::geometry::{Ray, TriangleRay, hit_limit};
use glam::{UVec3, Vec3, Vec4};

pub use crate::bvh::MAX_PACKET;

/// Largest sum of the slope spreads `(max − min)` of `du/dk` and `dv/dk` over a packet that is still traced
/// as a packet. Ours: 0.5 is a frustum 27° wide, far beyond a camera tile (an 8×8 tile of a 60° 512-pixel
/// view spreads about 0.02) and about where it starts to overlap more cells per slice than the rays cross.
pub const PACKET_SPREAD_LIMIT: f32 = 0.5;

/// Largest area, in cells per ray, of the rectangle across the major axis that a packet's entry points
/// cover for it to be traced as a packet. Ours: a camera tile enters within a few cells; shadow rays from
/// one tile's hits scattered through an explosion spread over hundreds, and single rays win there.
pub const PACKET_START_CELLS: f32 = 4.0;

/// Entries of a packet's mailbox.
const PACKET_MAILBOX: usize = 256;

/// The best hit of one ray so far: `(t, triangle, u, v)`.
type Best = Option<(f32, u32, f32, f32)>;

impl UniformGrid {
    /// [`closest_hit`](Self::closest_hit) for every ray of `rays`, traced as packets of up to [`MAX_PACKET`]
    /// consecutive rays (a packet whose directions do not share a sign on their major axis, that
    /// holds a far ray, or whose slopes spread too wide is traced ray by ray).
    /// `out` must be as long as `rays`; single-threaded (see [`closest_hits_packets`](Self::closest_hits_packets)).
    pub fn closest_hits_packet(
        &self,
        rays: &[Ray],
        out: &mut [Option<Hit>],
        stats: &mut TraversalStats,
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (rays, out) in rays.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
            let mut best = [None; MAX_PACKET];
            if self.trace_packet(rays, false, &mut best, stats) {
                for (o, b) in out.iter_mut().zip(best) {
                    *o = b.map(|(t, p, u, v)| self.hit(t, p, u, v));
                }
            } else {
                for (o, r) in out.iter_mut().zip(rays) {
                    *o = self.closest_hit_counted(r, stats);
                }
            }
        }
    }

    /// [`any_hit`](Self::any_hit) for every ray, as packets; like [`closest_hits_packet`](Self::closest_hits_packet).
    pub fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool], stats: &mut TraversalStats) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        for (rays, out) in rays.chunks(MAX_PACKET).zip(out.chunks_mut(MAX_PACKET)) {
            let mut best = [None; MAX_PACKET];
            if self.trace_packet(rays, true, &mut best, stats) {
                for (o, b) in out.iter_mut().zip(best) {
                    *o = b.is_some();
                }
            } else {
                for (o, r) in out.iter_mut().zip(rays) {
                    *o = self.any_hit_counted(r, stats);
                }
            }
        }
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

    /// Traces up to [`MAX_PACKET`] rays as one frustum; false (and nothing written) when the packet must
    /// be traced ray by ray instead.
    fn trace_packet(
        &self,
        rays: &[Ray],
        any: bool,
        best: &mut [Best; MAX_PACKET],
        stats: &mut TraversalStats,
    ) -> bool {
        let mut lanes = [None::<(TriangleRay, f32, f32)>; MAX_PACKET];
        // Each ray's slack for the grid's box: a slice beyond its best hit's limit ends it (see
        // `traverse`).
        let mut slack = [0.0f32; MAX_PACKET];
        let mut mean = Vec3::ZERO;
        for (i, r) in rays.iter().enumerate() {
            if !r.is_valid() {
                continue;
            }
            if let Some((t_in, t_out)) = self.clip(r) {
                if self.is_far(r.origin) {
                    return false;
                }
                lanes[i] = Some((TriangleRay::new(r), t_in, t_out));
                slack[i] = r.hit_slack(&self.bounds);
                mean += r.dir().normalize();
            }
        }
        let live = || {
            lanes
                .iter()
                .zip(rays)
                .filter_map(|(l, r)| l.map(|l| (l, r)))
        };
        if live().next().is_none() {
            return true;
        }
        let k = mean.abs().max_position();
        let sgn = mean[k].signum();
        if live().any(|(_, r)| r.dir()[k] * sgn <= 0.0) {
            return false;
        }
        let (u, v) = ((k + 1) % 3, (k + 2) % 3);
        // The packet's first and last planes along k, in the direction of travel (`sgn·x` grows).
        let (mut s0, mut s1) = (f32::INFINITY, f32::NEG_INFINITY);
        for ((_, t_in, t_out), r) in live() {
            s0 = s0.min(sgn * r.at(t_in)[k]);
            s1 = s1.max(sgn * r.at(t_out)[k]);
        }
        let x0 = sgn * s0;
        // Frustum: each ray's (u, v) on the first plane and its slopes per unit of w.
        let (mut amin, mut amax) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let (mut smin, mut smax) = (amin, amax);
        // Each lane's own line in the same frame, `(u, v) = a + s·w`, for the per-lane triangle cull.
        let mut lane_line = [(Vec3::ZERO, Vec3::ZERO); MAX_PACKET];
        for (i, r) in rays.iter().enumerate() {
            if lanes[i].is_none() {
                continue;
            }
            let d = r.dir();
            let s = Vec3::new(0.0, d[u] / d[k], d[v] / d[k]);
            let dx = x0 - r.origin[k];
            let a = Vec3::new(0.0, r.origin[u] + s.y * dx, r.origin[v] + s.z * dx);
            let s = s * sgn;
            lane_line[i] = (a, s);
            amin = amin.min(a);
            amax = amax.max(a);
            smin = smin.min(s);
            smax = smax.max(s);
        }
        if (smax - smin).y + (smax - smin).z > PACKET_SPREAD_LIMIT {
            return false;
        }
        // Where the rays enter, in cells across k: a packet whose starts scatter over more cells than it
        // has rays walks a rectangle wider than the rays' own cells (shadow rays from hits at different depths).
        let (mut elo, mut ehi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let mut count = 0.0;
        for ((_, t_in, _), r) in live() {
            let p = r.at(t_in) * self.inv_cell;
            (elo, ehi, count) = (elo.min(p), ehi.max(p), count + 1.0);
        }
        let e = ehi - elo + Vec3::ONE;
        if e[u] * e[v] > PACKET_START_CELLS * count {
            return false;
        }
        // Plane i of the four is `f_i(p) = P_i − (A_i + S_i·w) ≥ 0` inside, with P = (pu, −pu, pv, −pv).
        let fa = Vec4::new(amin.y, -amax.y, amin.z, -amax.z);
        let fs = Vec4::new(smin.y, -smax.y, smin.z, -smax.z);
        let m = self.margin;
        let outside = |p: Vec3| {
            let w = (p[k] - x0) * sgn;
            Vec4::new(p[u], -p[u], p[v], -p[v]) - (fa + fs * w)
        };
        let (g0, cs, res) = (self.bounds.min, self.cell, self.res);
        let slice_of = |x: f32| (((x - g0[k]) * self.inv_cell[k]).max(0.0) as u32).min(res[k] - 1);
        let (c_first, c_last) = (slice_of(x0), slice_of(sgn * s1));
        let mut tmax = [f32::INFINITY; MAX_PACKET];
        for (i, r) in rays.iter().enumerate() {
            tmax[i] = r.tmax;
        }
        // Per lane: where along w its segment starts, and the slice where its range ends.
        let mut w_start = [0.0f32; MAX_PACKET];
        let mut end_slice = [c_last; MAX_PACKET];
        let mut w_start_max = f32::NEG_INFINITY;
        for ((i, lane), r) in lanes.iter().enumerate().zip(rays) {
            if let Some((_, t_in, t_out)) = *lane {
                w_start[i] = sgn * r.at(t_in)[k] - s0;
                w_start_max = w_start_max.max(w_start[i]);
                end_slice[i] = slice_of(r.at(t_out)[k]);
            }
        }
        // The (a, s) bounds of the live lanes, and the first slice (in travel order) where one may end.
        let before = |a: u32, b: u32| if sgn > 0.0 { a < b } else { a > b };
        let live_bounds = |lanes: &[Option<(TriangleRay, f32, f32)>; MAX_PACKET], c: u32| {
            let (mut lo, mut hi) = ([Vec3::INFINITY; 2], [Vec3::NEG_INFINITY; 2]);
            let mut next = c_last;
            for (i, lane) in lanes.iter().enumerate() {
                if lane.is_some() {
                    let (a, s) = lane_line[i];
                    (lo[0], hi[0]) = (lo[0].min(a), hi[0].max(a));
                    (lo[1], hi[1]) = (lo[1].min(s), hi[1].max(s));
                    if before(c, end_slice[i]) && before(end_slice[i], next) {
                        next = end_slice[i];
                    }
                }
            }
            (lo, hi, next)
        };
        let (mut live_lo, mut live_hi, mut next_end) = live_bounds(&lanes, c_first);
        if !before(c_first, next_end) {
            next_end = c_first;
        }
        // The lanes' lines again, four lanes per entry for the per-lane triangle cull:
        // `([a_u, a_v], [s_u, s_v])`; a dead lane's `a` is +∞.
        let groups = rays.len().div_ceil(4);
        let mut soa = [([Vec4::INFINITY; 2], [Vec4::ZERO; 2]); MAX_PACKET / 4];
        for (i, lane) in lanes.iter().enumerate() {
            if lane.is_some() {
                let (a, s) = lane_line[i];
                let (la, ls) = &mut soa[i / 4];
                (la[0][i % 4], la[1][i % 4]) = (a.y, a.z);
                (ls[0][i % 4], ls[1][i % 4]) = (s.y, s.z);
            }
        }
        let kill = |soa: &mut [([Vec4; 2], [Vec4; 2]); MAX_PACKET / 4], i: usize| {
            soa[i / 4].0[0][i % 4] = f32::INFINITY;
            soa[i / 4].0[1][i % 4] = f32::INFINITY;
        };
        let mut mail = Mailbox::<PACKET_MAILBOX>::new();
        let mc = self.options.macrocell;
        let mut c = c_first;
        loop {
            let mut tested = false;
            let (plane_lo, plane_hi) = (g0[k] + c as f32 * cs[k], g0[k] + (c + 1) as f32 * cs[k]);
            let (x_in, x_out) = if sgn > 0.0 {
                (plane_lo, plane_hi)
            } else {
                (plane_hi, plane_lo)
            };
            let (w_in, w_out) = (((x_in - x0) * sgn).max(0.0), ((x_out - x0) * sgn).max(0.0));
            // The rectangle the live rays' own segments cover in this slice: tighter than the whole
            // frustum when origins are spread along k (shadow rays from a tile's hits).
            // Once every segment has started, the live lanes' bounds give it in four multiply-adds.
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            if w_in >= w_start_max {
                let [(la, ls), (ha, hs)] = [(live_lo[0], live_lo[1]), (live_hi[0], live_hi[1])];
                lo = (la + ls * w_in).min(la + ls * w_out);
                hi = (ha + hs * w_in).max(ha + hs * w_out);
            } else {
                for (i, lane) in lanes.iter().enumerate() {
                    if lane.is_none() || w_start[i] > w_out + m {
                        continue;
                    }
                    let (a, s) = lane_line[i];
                    let (p, q) = (a + s * w_in.max(w_start[i]), a + s * w_out);
                    lo = lo.min(p.min(q));
                    hi = hi.max(p.max(q));
                }
            }
            let (lo, hi) = (lo - m, hi + m);
            // Cell coordinates are compared and truncated without `floor` (a library call on baseline
            // x86-64): `h ≥ 0` and `l < res` hold for the unfloored values exactly when for the floored
            // ones, and truncation of a non-negative value is its floor.
            let cell_range = |a: usize, j: usize| {
                let to_cell = |x: f32| (x - g0[a]) * self.inv_cell[a];
                let (l, h) = (to_cell(lo[j]), to_cell(hi[j]));
                (h >= 0.0 && l < res[a] as f32)
                    .then(|| (l.max(0.0) as u32, (h as u32).min(res[a] - 1)))
            };
            if let (Some((u0, u1)), Some((v0, v1))) = (cell_range(u, 1), cell_range(v, 2)) {
                for mv in v0 / mc..=v1 / mc {
                    for mu in u0 / mc..=u1 / mc {
                        let mut mcell = UVec3::ZERO;
                        (mcell[k], mcell[u], mcell[v]) = (c / mc, mu, mv);
                        let mr = self.macro_res;
                        if !self.macro_full[(mcell.x + mr.x * (mcell.y + mr.y * mcell.z)) as usize]
                        {
                            continue;
                        }
                        for cv in v0.max(mv * mc)..=v1.min(mv * mc + mc - 1) {
                            for cu in u0.max(mu * mc)..=u1.min(mu * mc + mc - 1) {
                                let mut cell = UVec3::ZERO;
                                (cell[k], cell[u], cell[v]) = (c, cu, cv);
                                let refs = self.cell_refs(self.cell_index(cell));
                                stats.inner_visits += 1;
                                stats.leaf_visits += !refs.is_empty() as u64;
                                for &p in refs {
                                    if mail.seen(p) {
                                        continue;
                                    }
                                    let [a, b, cc] = self.tris[p as usize];
                                    let f = outside(a).max(outside(b)).max(outside(cc));
                                    if f.cmplt(Vec4::splat(-m)).any() {
                                        continue;
                                    }
                                    // The corners in the frustum frame: a lane whose line passes on
                                    // one side of all three in u or in v (beyond the margin) misses.
                                    // Four lanes at a time; dead lanes sit at +∞ and always miss.
                                    let w = (Vec3::new(a[k], b[k], cc[k]) - Vec3::splat(x0)) * sgn;
                                    let (pu, pv) = (
                                        [a[u], b[u], cc[u]].map(Vec4::splat),
                                        [a[v], b[v], cc[v]].map(Vec4::splat),
                                    );
                                    for g in 0..groups {
                                        let (la, ls) = soa[g];
                                        let d = |p: &[Vec4; 3], a: Vec4, s: Vec4| {
                                            let d = [0, 1, 2].map(|j| p[j] - (a + s * w[j]));
                                            (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
                                        };
                                        let (umin, umax) = d(&pu, la[0], ls[0]);
                                        let (vmin, vmax) = d(&pv, la[1], ls[1]);
                                        let (mp, mn) = (Vec4::splat(m), Vec4::splat(-m));
                                        let miss = umin.cmpgt(mp)
                                            | umax.cmplt(mn)
                                            | vmin.cmpgt(mp)
                                            | vmax.cmplt(mn);
                                        let mut near = !miss.bitmask() & 0xF;
                                        while near != 0 {
                                            let i = 4 * g + near.trailing_zeros() as usize;
                                            near &= near - 1;
                                            let Some((tr, ..)) = lanes[i] else { continue };
                                            tested = true;
                                            stats.prim_tests += 1;
                                            let r = &rays[i];
                                            if let Some(h) = tr.intersect(a, b, cc, r.tmin, tmax[i])
                                                && best[i]
                                                    .is_none_or(|(bt, bp, ..)| h.t < bt || p < bp)
                                            {
                                                best[i] = Some((h.t, p, h.u, h.v));
                                                tmax[i] = h.t;
                                                if any {
                                                    lanes[i] = None;
                                                    kill(&mut soa, i);
                                                }
                                            }
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
            }
            if c == c_last {
                return true;
            }
            // Rays whose best hit lies before this slice's exit, or whose range ends in it, are done:
            // only a slice that tested a triangle or where some range may end can finish one.
            if !tested && c != next_end {
                c = if sgn > 0.0 { c + 1 } else { c - 1 };
                continue;
            }
            let mut alive = false;
            for (i, lane) in lanes.iter_mut().enumerate() {
                if let Some((_, _, t_out)) = *lane {
                    let r = &rays[i];
                    let t_exit = (x_out - r.origin[k]) * r.inv_dir()[k];
                    let beyond = |t: f32| hit_limit(t, slack[i]) < t_exit;
                    if t_exit >= t_out || best[i].is_some_and(|(t, ..)| beyond(t)) {
                        *lane = None;
                        kill(&mut soa, i);
                    } else {
                        alive = true;
                    }
                }
            }
            if !alive {
                return true;
            }
            (live_lo, live_hi, next_end) = live_bounds(&lanes, c);
            c = if sgn > 0.0 { c + 1 } else { c - 1 };
        }
    }
}
