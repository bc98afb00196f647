//! The closest point of a mesh to a point: Ericson's region test per triangle, best-first over the tree.

use super::frame::Frame;
use super::point_bound;
use crate::MeshBvh;
use crate::bvh::{is_collapsed, traverse_by};
use crate::geometry::Aabb;
use glam::{DVec3, Vec3};
use std::ops::Range;

/// The part of a triangle a closest point lies on. Corners are numbered as in the index buffer; edge `i`
/// runs from corner `i` to corner `(i + 1) % 3`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Feature {
    /// The interior of the face.
    Face,
    /// The interior of edge `i` (corner `i` to corner `(i + 1) % 3`).
    Edge(u8),
    /// Corner `i`.
    Vertex(u8),
}

/// The point of a mesh nearest to a query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointHit {
    /// The nearest point on the mesh.
    pub point: Vec3,
    /// Its distance to the query point.
    pub distance: f32,
    /// Index of the triangle it lies on (`indices[3·primitive ..]`).
    pub primitive: u32,
    /// Barycentric weight of the triangle's second corner.
    pub u: f32,
    /// Barycentric weight of the third corner (the first has `1 - u - v`).
    pub v: f32,
    /// Face, edge or corner.
    pub feature: Feature,
}

/// The closest point of one triangle, in `f64`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TrianglePoint {
    pub point: DVec3,
    pub dist2: f64,
    pub u: f64,
    pub v: f64,
    pub feature: Feature,
}

/// The point of triangle `[a, b, c]` nearest to `p` (Ericson, *Real-Time Collision Detection*, §5.1.5):
/// the Voronoi region of `p` is found from six dot products, then `p` is projected onto that corner, edge
/// or the face. A triangle too thin for the face case (its projected area rounds to zero or below) is
/// answered from its three edges.
pub(crate) fn closest_on_triangle(p: DVec3, [a, b, c]: [DVec3; 3]) -> TrianglePoint {
    let at = |point: DVec3, u: f64, v: f64, feature: Feature| TrianglePoint {
        point,
        dist2: (p - point).length_squared(),
        u,
        v,
        feature,
    };
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return at(a, 0.0, 0.0, Feature::Vertex(0));
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return at(b, 1.0, 0.0, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let s = d1 / (d1 - d3);
        return at(a + ab * s, s, 0.0, Feature::Edge(0));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return at(c, 0.0, 1.0, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let s = d2 / (d2 - d6);
        return at(a + ac * s, 0.0, s, Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let s = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return at(b + (c - b) * s, 1.0 - s, s, Feature::Edge(1));
    }
    let sum = va + vb + vc;
    if sum > 0.0 {
        let (v, w) = (vb / sum, vc / sum);
        return at(a + ab * v + ac * w, v, w, Feature::Face);
    }
    // A sliver whose area rounded away: its nearest point is on an edge.
    [0u8, 1, 2]
        .map(|e| {
            let (s, t) = ([a, b, c][e as usize], [a, b, c][(e as usize + 1) % 3]);
            let d = t - s;
            let len2 = d.length_squared();
            let k = if len2 > 0.0 {
                ((p - s).dot(d) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (u, v) = match e {
                0 => (k, 0.0),
                1 => (1.0 - k, k),
                _ => (0.0, 1.0 - k),
            };
            at(s + d * k, u, v, Feature::Edge(e))
        })
        .into_iter()
        .min_by(|x, y| x.dist2.total_cmp(&y.dist2))
        .expect("three edges")
}

/// Squared distance from `p` to a box, in `f64` (0 inside).
#[inline]
pub(crate) fn box_dist2(b: &Aabb, p: DVec3) -> f64 {
    let d = (b.min.as_dvec3() - p)
        .max(p - b.max.as_dvec3())
        .max(DVec3::ZERO);
    d.length_squared()
}

/// The present (not zero-area) triangles of a leaf's `slots`, with their slot, corners in `f64` in `frame`.
pub(crate) fn present(
    tris: &[[Vec3; 3]],
    slots: Range<usize>,
    frame: Frame,
) -> impl Iterator<Item = (usize, [DVec3; 3])> + '_ {
    slots
        .filter(|&s| !is_collapsed(&tris[s]))
        .map(move |s| (s, frame.triangle(&tris[s])))
}

/// A box farther than the best distance by more than this relative margin is skipped. The margin covers the
/// `f64` rounding of the box and triangle distances (a few ulp), so a triangle at exactly the best distance is
/// still visited and the lowest primitive index wins ties whatever the tree.
const PRUNE_SLACK: f64 = 1.0 + 1e-12;

/// Leaves a search opens before it filters triangles four at a time with [`point_bound`]: a point near the
/// surface is answered within a few leaves, where the filter's batching would only delay the bound; a point
/// almost equidistant from a whole band of the surface opens hundreds.
const LEAVES_BEFORE_FILTER: u32 = 8;

/// One closest-point search: the best triangle so far and the triangles queued for the four-lane filter.
struct Search<'a> {
    p: Vec3,
    q: DVec3,
    /// Squared `max_distance`.
    limit: f64,
    frame: Frame,
    tris: &'a [[Vec3; 3]],
    prims: &'a [u32],
    best: Option<(TrianglePoint, u32)>,
    /// Leaves opened so far.
    leaves: u32,
    /// Slots waiting for [`point_bound::farther_than`] (the first `queued`).
    queue: [usize; 4],
    queued: usize,
}

impl Search<'_> {
    /// Tests the present triangles of a leaf's `slots`, lowering `*bound` to the best squared distance
    /// (with [`PRUNE_SLACK`]). Past [`LEAVES_BEFORE_FILTER`] leaves, in the mesh's frame, triangles are
    /// queued and tested four at a time.
    fn leaf(&mut self, slots: Range<usize>, bound: &mut f64) {
        self.leaves += 1;
        let filter = matches!(self.frame, Frame::Mesh) && self.leaves > LEAVES_BEFORE_FILTER;
        for slot in slots.filter(|&s| !is_collapsed(&self.tris[s])) {
            if filter {
                self.queue[self.queued] = slot;
                self.queued += 1;
                if self.queued == 4 {
                    self.flush(bound);
                }
            } else {
                self.exact(slot, bound);
            }
        }
    }

    /// Tests the queued triangles: exactly those the four-lane bound cannot rule out.
    fn flush(&mut self, bound: &mut f64) {
        if self.queued == 0 {
            return;
        }
        let lanes = std::array::from_fn(|i| &self.tris[self.queue[i.min(self.queued - 1)]]);
        let far = point_bound::farther_than(self.p, lanes, *bound);
        for i in 0..std::mem::take(&mut self.queued) {
            if far & (1 << i) == 0 {
                self.exact(self.queue[i], bound);
            }
        }
    }

    /// The exact `f64` test of the (present) triangle in `slot`.
    fn exact(&mut self, slot: usize, bound: &mut f64) {
        let t = self.frame.triangle(&self.tris[slot]);
        let q = self.q;
        // The triangle's own box first: most triangles of a leaf are farther than the best.
        let (lo, hi) = (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
        if (lo - q).max(q - hi).max(DVec3::ZERO).length_squared() > *bound {
            return;
        }
        let tp = closest_on_triangle(q, t);
        let prim = self.prims[slot];
        let better = match self.best {
            None => tp.dist2 <= self.limit,
            Some((b, bp)) => tp.dist2 < b.dist2 || (tp.dist2 == b.dist2 && prim < bp),
        };
        if better {
            self.best = Some((tp, prim));
            *bound = tp.dist2 * PRUNE_SLACK;
        }
    }
}

impl MeshBvh {
    /// The point of the mesh nearest to `p`, if one lies within `max_distance` (`f32::INFINITY` for no limit).
    ///
    /// Distances are computed in `f64` from the tree's current (refitted) corners, so the answer is the exact
    /// nearest point up to a few `f64` ulp. Among triangles at the same distance the lowest primitive index
    /// wins. Zero-area triangles are absent, as they are for rays and collisions. A non-finite `p` or a
    /// negative or NaN `max_distance` gives `None`.
    ///
    /// Cost: nearest-first descent of the wide tree when the mesh has one (else the binary tree): per node,
    /// four box distances and four disc bounds in one SIMD test each (a flat disc around each leaf's
    /// triangles, far tighter than their box; fitted on the first closest-point query after a build or
    /// refit, about three fifths of a refit's time, 128 bytes per wide node); about `log
    /// n` nodes and a handful of triangles for a point near the surface, more for a point almost
    /// equidistant from a band of the surface (near a torus's axis: hundreds of leaves). Past eight leaves,
    /// triangles are first ruled out four at a time by a conservative `f32` bound. On the 20k-triangle
    /// `bench queries` torus the discs take a query from 19.7 k instructions to about 12 k (refit and fit
    /// excluded; the fit adds about 2 k a query at 2,000 queries a frame); the answer is the same. No
    /// allocation once warm.
    ///
    /// ```
    /// use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions, queries::Feature};
    /// use glam::Vec3;
    /// let mesh = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2])?;
    /// let bvh = MeshBvh::build(&mesh, &BuildOptions::default())?;
    /// let hit = bvh.closest_point(Vec3::new(0.25, 0.25, 2.0), f32::INFINITY).unwrap();
    /// assert_eq!((hit.point, hit.distance, hit.feature), (Vec3::new(0.25, 0.25, 0.0), 2.0, Feature::Face));
    /// let corner = bvh.closest_point(Vec3::new(-1.0, -1.0, 0.0), 10.0).unwrap();
    /// assert_eq!(corner.feature, Feature::Vertex(0));
    /// assert!(bvh.closest_point(Vec3::new(0.0, 0.0, 5.0), 1.0).is_none());
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn closest_point(&self, p: Vec3, max_distance: f32) -> Option<PointHit> {
        self.closest_point_in(p, max_distance, Frame::Mesh)
    }

    /// [`closest_point`](Self::closest_point) with `p`, the limit and the answer in `frame`.
    pub(crate) fn closest_point_in(
        &self,
        p: Vec3,
        max_distance: f32,
        frame: Frame,
    ) -> Option<PointHit> {
        if !p.is_finite() || max_distance.is_nan() || max_distance < 0.0 {
            return None;
        }
        let mut search = Search {
            p,
            q: p.as_dvec3(),
            limit: f64::from(max_distance).powi(2),
            frame,
            tris: self.slot_triangles(),
            prims: self.bvh().prim_indices(),
            best: None,
            leaves: 0,
            queue: [0; 4],
            queued: 0,
        };
        let (limit, q) = (search.limit, search.q);
        match (frame, self.wide()) {
            // In the mesh's frame the wide tree's lanes are the boxes as stored: four at a time.
            (Frame::Mesh, Some(wide)) => {
                wide.walk_nearest(p, limit, search.tris, self.lane_discs(), |slots, bound| {
                    search.leaf(slots, bound)
                })
            }
            _ => traverse_by(
                self.bvh().nodes(),
                limit,
                &mut (),
                |n, bound| Some(box_dist2(&frame.node_box(n), q)).filter(|&d| d <= bound),
                |slots, bound| {
                    search.leaf(slots, bound);
                    false
                },
            ),
        }
        let mut bound = search.best.map_or(limit, |(b, _)| b.dist2 * PRUNE_SLACK);
        search.flush(&mut bound);
        let best = search.best;
        best.map(|(tp, prim)| PointHit {
            point: tp.point.as_vec3(),
            distance: tp.dist2.sqrt() as f32,
            primitive: prim,
            u: tp.u as f32,
            v: tp.v as f32,
            feature: tp.feature,
        })
    }
}
