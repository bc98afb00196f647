//! Single-ray traversal: the 3D-DDA of Amanatides & Woo with mailboxing, the baseline the packets are
//! measured against and the path for scattered rays.
//!
//! The walk steps from the cell where the ray enters the grid to the face-neighbour across the nearest cell
//! plane. Plane distances are recomputed from the plane's index at every step (never accumulated), so the
//! walk's rounding stays within the grid's margin however many cells it crosses. A closest-hit walk stops
//! after the first cell whose exit distance is at least the best hit: any nearer (or tied) hit lies in a
//! cell already visited, because triangles are binned with that margin.

use super::{Mailbox, UniformGrid};
use crate::bvh::{Hit, TraversalStats};
use crate::geometry::{Ray, TriangleRay, hit_limit};
use glam::Vec3;

/// Entries of a single ray's mailbox.
const RAY_MAILBOX: usize = 32;

impl UniformGrid {
    /// The nearest hit within the ray's `[tmin, tmax]`, or `None` (also for an invalid ray).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        self.closest_hit_counted(ray, &mut TraversalStats::default())
    }

    /// [`closest_hit`](Self::closest_hit), adding the work done to `stats`: cells visited as
    /// `inner_visits`, non-empty cells as `leaf_visits`, triangle tests as `prim_tests`.
    pub fn closest_hit_counted(&self, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let tr = TriangleRay::new(ray);
        let slack = ray.hit_slack(&self.bounds);
        let mut best: Option<(f32, u32, f32, f32)> = None;
        let mut tmax = ray.tmax;
        let mut mail = Mailbox::<RAY_MAILBOX>::new();
        self.walk(ray, stats, |refs, t_exit, stats| {
            for &p in refs {
                if mail.seen(p) {
                    continue;
                }
                stats.prim_tests += 1;
                let [a, b, c] = self.tris[p as usize];
                if let Some(h) = tr.intersect(a, b, c, ray.tmin, tmax)
                    && best.is_none_or(|(bt, bp, ..)| h.t < bt || p < bp)
                {
                    best = Some((h.t, p, h.u, h.v));
                    tmax = h.t;
                }
            }
            // Done when the next cell lies beyond the best hit's limit, as a BVH culls boxes (see
            // `traverse`: a triangle further on can compute its `t` a little before the cell's entry).
            best.is_some_and(|(t, ..)| hit_limit(t, slack) < t_exit)
        });
        best.map(|(t, p, u, v)| self.hit(t, p, u, v))
    }

    /// True when anything lies within the ray's `[tmin, tmax]` (shadow rays). Stops at the first hit.
    pub fn any_hit(&self, ray: &Ray) -> bool {
        self.any_hit_counted(ray, &mut TraversalStats::default())
    }

    /// [`any_hit`](Self::any_hit), adding the work done to `stats` (as in
    /// [`closest_hit_counted`](Self::closest_hit_counted)).
    pub fn any_hit_counted(&self, ray: &Ray, stats: &mut TraversalStats) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let tr = TriangleRay::new(ray);
        let mut mail = Mailbox::<RAY_MAILBOX>::new();
        let mut hit = false;
        self.walk(ray, stats, |refs, _, stats| {
            hit = refs.iter().any(|&p| {
                if mail.seen(p) {
                    return false;
                }
                stats.prim_tests += 1;
                let [a, b, c] = self.tris[p as usize];
                tr.intersect(a, b, c, ray.tmin, ray.tmax).is_some()
            });
            hit
        });
        hit
    }

    /// The part of the ray's `[tmin, tmax]` inside the grid box, or `None`. Like [`Ray::intersect_aabb`], an
    /// axis on which the direction is zero and the origin lies on a plane puts no limit (NaN falls out).
    #[inline]
    pub(super) fn clip(&self, ray: &Ray) -> Option<(f32, f32)> {
        if self.refs.is_empty() {
            return None;
        }
        let t0 = (self.bounds.min - ray.origin) * ray.inv_dir();
        let t1 = (self.bounds.max - ray.origin) * ray.inv_dir();
        let near = Vec3::select(ray.dir_neg(), t1, t0);
        let far = Vec3::select(ray.dir_neg(), t0, t1);
        let mut lo = ray.tmin;
        let mut hi = ray.tmax;
        for a in 0..3 {
            if near[a] > lo {
                lo = near[a];
            }
            if far[a] < hi {
                hi = far[a];
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// Calls `visit(refs, t_exit, stats)` for every cell the ray crosses within its range, nearest first,
    /// until `visit` returns true. Far rays (see [`UniformGrid::is_far`]) get one call with every triangle.
    fn walk(
        &self,
        ray: &Ray,
        stats: &mut TraversalStats,
        mut visit: impl FnMut(&[u32], f32, &mut TraversalStats) -> bool,
    ) {
        let Some((t_in, t_out)) = self.clip(ray) else {
            return;
        };
        if self.is_far(ray.origin) {
            stats.inner_visits += 1;
            let all: &[u32] = &self.refs;
            // Every binned triangle is in `refs`; the mailbox drops the repeats.
            visit(all, f32::INFINITY, stats);
            return;
        }
        let (o, d, inv) = (ray.origin, ray.dir(), ray.inv_dir());
        let mut cell = self.cell_of(ray.at(t_in)).as_ivec3();
        let res = self.res.as_ivec3();
        let step = glam::IVec3::new(
            (d.x > 0.0) as i32 - (d.x < 0.0) as i32,
            (d.y > 0.0) as i32 - (d.y < 0.0) as i32,
            (d.z > 0.0) as i32 - (d.z < 0.0) as i32,
        );
        // Distance to the plane ahead of `cell` on axis `a` (∞ when the ray is parallel to the axis' planes).
        let plane_t = |cell: glam::IVec3, a: usize| -> f32 {
            if step[a] == 0 {
                return f32::INFINITY;
            }
            let i = cell[a] + (step[a] > 0) as i32;
            (self.bounds.min[a] + i as f32 * self.cell[a] - o[a]) * inv[a]
        };
        let mut next = Vec3::new(plane_t(cell, 0), plane_t(cell, 1), plane_t(cell, 2));
        loop {
            let a = if next.x <= next.y && next.x <= next.z {
                0
            } else if next.y <= next.z {
                1
            } else {
                2
            };
            let t_exit = next[a].min(t_out);
            let i = self.cell_index(cell.as_uvec3());
            let refs = self.cell_refs(i);
            stats.inner_visits += 1;
            if !refs.is_empty() {
                stats.leaf_visits += 1;
                if visit(refs, t_exit, stats) {
                    return;
                }
            }
            if next[a] >= t_out {
                return;
            }
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= res[a] {
                return;
            }
            next[a] = plane_t(cell, a);
        }
    }
}
