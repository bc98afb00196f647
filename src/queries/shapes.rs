//! The query shapes (sphere, capsule, oriented box) and their exact-in-`f64` distance and overlap tests
//! against one triangle.

use super::closest::closest_on_triangle;
use crate::geometry::Aabb;
use glam::{DMat3, DVec3, Quat, Vec3};

/// A shape for overlap queries and casts, in the mesh's (or the world's) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// A ball: all points within `radius` of `center`.
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius (0 is a point).
        radius: f32,
    },
    /// All points within `radius` of the segment from `a` to `b`.
    Capsule {
        /// One end of the core segment.
        a: Vec3,
        /// The other end.
        b: Vec3,
        /// Radius.
        radius: f32,
    },
    /// A box of half-extents `half` around `center`, turned by `rotation`.
    Box {
        /// Centre.
        center: Vec3,
        /// Half-extents along the box's own axes (each ≥ 0).
        half: Vec3,
        /// Orientation of the box's axes.
        rotation: Quat,
    },
}

impl Shape {
    /// A sphere.
    pub fn sphere(center: Vec3, radius: f32) -> Shape {
        Shape::Sphere { center, radius }
    }

    /// A capsule around the segment `a`–`b`.
    pub fn capsule(a: Vec3, b: Vec3, radius: f32) -> Shape {
        Shape::Capsule { a, b, radius }
    }

    /// An oriented box.
    pub fn cuboid(center: Vec3, half: Vec3, rotation: Quat) -> Shape {
        Shape::Box {
            center,
            half,
            rotation,
        }
    }

    /// False for shapes no query can answer: non-finite values, negative radii or extents, a rotation that
    /// is not (close to) a unit quaternion.
    pub fn is_valid(&self) -> bool {
        match *self {
            Shape::Sphere { center, radius } => {
                center.is_finite() && radius >= 0.0 && radius.is_finite()
            }
            Shape::Capsule { a, b, radius } => {
                a.is_finite() && b.is_finite() && radius >= 0.0 && radius.is_finite()
            }
            Shape::Box {
                center,
                half,
                rotation,
            } => {
                center.is_finite()
                    && half.is_finite()
                    && half.min_element() >= 0.0
                    && rotation.is_finite()
                    && rotation.is_normalized()
            }
        }
    }

    /// An axis-aligned box holding the shape, widened by a few ulp so that it is conservative.
    pub fn bounds(&self) -> Aabb {
        let b = match *self {
            Shape::Sphere { center, radius } => Aabb::new(center - radius, center + radius),
            Shape::Capsule { a, b, radius } => Aabb::new(a.min(b) - radius, a.max(b) + radius),
            Shape::Box {
                center,
                half,
                rotation,
            } => {
                let m = glam::Mat3::from_quat(rotation);
                let ext =
                    m.x_axis.abs() * half.x + m.y_axis.abs() * half.y + m.z_axis.abs() * half.z;
                Aabb::new(center - ext, center + ext)
            }
        };
        widen(b)
    }
}

/// Relative margin, against the box's centre and half-extents, by which a point must lie inside an oriented
/// box for [`OverlapTest`] to accept without the separating-axis test: far above that test's `f64` rounding
/// (a few `2⁻⁵³` of the same magnitudes), so a point inside by it passes every axis of the test.
const BOX_INSIDE_MARGIN: f64 = 1e-9;

/// A shape made ready for the overlap tests of one query: its `f64` form (for a box, the rotation's matrix)
/// computed once instead of per triangle.
#[derive(Clone, Copy, Debug)]
pub(crate) enum OverlapTest {
    /// Centre and squared radius.
    Ball { center: DVec3, r2: f64 },
    /// Core segment and squared radius.
    Capsule { a: DVec3, b: DVec3, r2: f64 },
    /// The box and the absolute margin of [`BOX_INSIDE_MARGIN`].
    Box { dbox: DBox, margin: f64 },
}

impl OverlapTest {
    /// The test of `shape` (valid, [`Shape::is_valid`]).
    pub(crate) fn new(shape: &Shape) -> OverlapTest {
        match *shape {
            Shape::Sphere { center, radius } => OverlapTest::Ball {
                center: center.as_dvec3(),
                r2: f64::from(radius) * f64::from(radius),
            },
            Shape::Capsule { a, b, radius } => OverlapTest::Capsule {
                a: a.as_dvec3(),
                b: b.as_dvec3(),
                r2: f64::from(radius) * f64::from(radius),
            },
            Shape::Box {
                center,
                half,
                rotation,
            } => OverlapTest::Box {
                dbox: DBox::new(center, half, rotation),
                margin: BOX_INSIDE_MARGIN
                    * f64::from(center.abs().max_element() + half.max_element()),
            },
        }
    }

    /// Whether the closed shape and the closed triangle share a point, decided in `f64`.
    #[inline]
    pub(crate) fn triangle(&self, t: [DVec3; 3]) -> bool {
        match *self {
            // A corner in the ball settles it (common when the ball is large against the triangles); the
            // three corners are compared without a branch each (which corner is in is a coin toss).
            OverlapTest::Ball { center, r2 } => {
                let d = t.map(|p| p.distance_squared(center));
                ((d[0] <= r2) | (d[1] <= r2) | (d[2] <= r2))
                    || closest_on_triangle(center, t).dist2 <= r2
            }
            OverlapTest::Capsule { a, b, r2 } => segment_triangle_closest(a, b, t).1 <= r2,
            // A corner inside by the margin settles it: the separating-axis test would pass too.
            OverlapTest::Box { dbox, margin } => {
                let v = t.map(|p| dbox.local(p));
                v.iter().any(|&x| dbox.holds(x, DVec3::ZERO, margin)) || dbox.overlaps_local(&v)
            }
        }
    }

    /// True when [`triangle`](Self::triangle) accepts every triangle whose corners lie in `b` (and whose box
    /// meets the shape's): for a box when `b` lies inside it by twice the margin (then so do the triangles'
    /// corners by the margin). Lets a whole subtree be reported without a test per triangle. Never for a
    /// capsule, nor a ball (its walk has a four-lane test of its own, `WideBvh::walk_within`).
    #[inline(always)]
    pub(crate) fn holds(&self, b: &Aabb) -> bool {
        match *self {
            OverlapTest::Ball { .. } | OverlapTest::Capsule { .. } => false,
            OverlapTest::Box { dbox, margin } => {
                let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
                let extent = (dbox.axes.transpose().abs()) * ((hi - lo) * 0.5);
                dbox.holds(dbox.local((lo + hi) * 0.5), extent, 2.0 * margin)
            }
        }
    }
}

/// Widens a box by 4 ulp of its largest magnitude on each side, covering the `f32` rounding of its corners.
fn widen(b: Aabb) -> Aabb {
    let m = b.min.abs().max(b.max.abs()).max_element();
    let pad = m * 4.0 * f32::EPSILON;
    Aabb::new(b.min - pad, b.max + pad)
}

/// The closest points of segments `p0 p1` and `q0 q1` (Ericson §5.1.9), as parameters `(s, t)` in `[0, 1]`.
pub(crate) fn segment_segment(p0: DVec3, p1: DVec3, q0: DVec3, q1: DVec3) -> (f64, f64) {
    let (d1, d2, r) = (p1 - p0, q1 - q0, p0 - q0);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    if a == 0.0 && e == 0.0 {
        return (0.0, 0.0);
    }
    if a == 0.0 {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = d1.dot(r);
    if e == 0.0 {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = d1.dot(d2);
    let denom = a * e - b * b;
    let mut s = if denom > 0.0 {
        ((b * f - c * e) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut t = (b * s + f) / e;
    if t < 0.0 {
        t = 0.0;
        s = (-c / a).clamp(0.0, 1.0);
    } else if t > 1.0 {
        t = 1.0;
        s = ((b - c) / a).clamp(0.0, 1.0);
    }
    (s, t)
}

/// The point of segment `p0 p1` nearest to triangle `t`, and its squared distance. The minimum is attained at
/// an end of the segment, at the segment's point nearest an edge, or where the segment pierces the plane;
/// each candidate's distance to the triangle is a true distance, so the least candidate is the answer.
pub(crate) fn segment_triangle_closest(p0: DVec3, p1: DVec3, t: [DVec3; 3]) -> (DVec3, f64) {
    let mut candidates = [p0; 5];
    candidates[1] = p1;
    for e in 0..3 {
        let (s, _) = segment_segment(p0, p1, t[e], t[(e + 1) % 3]);
        candidates[2 + e] = p0.lerp(p1, s);
    }
    let mut best = candidates
        .map(|x| (x, closest_on_triangle(x, t).dist2))
        .into_iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("five candidates");
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let (s0, s1) = (n.dot(p0 - t[0]), n.dot(p1 - t[0]));
    if (s0 <= 0.0 && s1 >= 0.0) || (s0 >= 0.0 && s1 <= 0.0) {
        let k = if s0 == s1 { 0.0 } else { s0 / (s0 - s1) };
        let x = p0.lerp(p1, k);
        let d2 = closest_on_triangle(x, t).dist2;
        if d2 < best.1 {
            best = (x, d2);
        }
    }
    best
}

/// An oriented box in `f64`: centre, half-extents and the rotation's matrix (columns are the box's axes).
#[derive(Clone, Copy, Debug)]
pub(crate) struct DBox {
    pub center: DVec3,
    pub half: DVec3,
    pub axes: DMat3,
}

impl DBox {
    pub(crate) fn new(center: Vec3, half: Vec3, rotation: Quat) -> DBox {
        DBox {
            center: center.as_dvec3(),
            half: half.as_dvec3(),
            axes: DMat3::from_quat(rotation.as_dquat()),
        }
    }

    /// A world point in the box's frame.
    #[inline]
    pub(crate) fn local(&self, p: DVec3) -> DVec3 {
        self.axes.transpose() * (p - self.center)
    }

    /// Whether the box-frame box of centre `at` and half-extents `extent` lies inside this box shrunk by
    /// `margin` on every side.
    #[inline]
    fn holds(&self, at: DVec3, extent: DVec3, margin: f64) -> bool {
        (at.abs() + extent).cmple(self.half - margin).all()
    }

    /// Separating-axis sweep (Eberly's method of separating axes for moving convex polyhedra) of the closed
    /// box moving by `d` per unit of time against the closed triangle `t`: on each of the 13 candidate axes
    /// (the box's three, the triangle's normal, the nine cross products of the two sets of directions; those
    /// that vanish separate nothing) the projections overlap during one interval of time; the shapes overlap
    /// during the intersection of those intervals. Returns the first time `≥ 0` of overlap and, when it is
    /// later than 0, the box-frame axis whose interval opened last, turned to point from the triangle towards
    /// the box. `d = 0` is the static overlap test (Akenine-Möller 2001).
    pub(crate) fn sweep(&self, d: DVec3, t: [DVec3; 3]) -> Option<(f64, Option<DVec3>)> {
        let v = t.map(|p| self.local(p));
        let dl = self.axes.transpose() * d;
        let (mut first, mut last) = (0.0f64, f64::INFINITY);
        let mut normal = None;
        let mut axis_test = |axis: DVec3| -> bool {
            if axis == DVec3::ZERO {
                return true;
            }
            let p = v.map(|x| x.dot(axis));
            let r = self.half.dot(axis.abs());
            let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
            // The triangle's interval moves by -w·t relative to the box's [-r, r].
            let w = dl.dot(axis);
            let (enter, exit) = if w > 0.0 {
                ((lo - r) / w, (hi + r) / w)
            } else if w < 0.0 {
                ((hi + r) / w, (lo - r) / w)
            } else if lo <= r && hi >= -r {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                return false;
            };
            if enter > first {
                first = enter;
                normal = Some(if w > 0.0 { -axis } else { axis });
            }
            last = last.min(exit);
            first <= last
        };
        for axis in candidate_axes(&v) {
            if !axis_test(axis) {
                return None;
            }
        }
        Some((first, normal.filter(|_| first > 0.0)))
    }

    /// Whether the closed box and the closed triangle with corners `v` (in the box's frame, [`local`]) share a
    /// point: [`sweep`](Self::sweep) with `d = 0`, the same arithmetic on the same axes, without the
    /// intervals of time (an axis separates when the triangle's projection misses `[-r, r]`).
    ///
    /// [`local`]: Self::local
    pub(crate) fn overlaps_local(&self, v: &[DVec3; 3]) -> bool {
        candidate_axes(v).all(|axis| {
            if axis == DVec3::ZERO {
                return true;
            }
            let p = v.map(|x| x.dot(axis));
            let r = self.half.dot(axis.abs());
            p[0].min(p[1]).min(p[2]) <= r && p[0].max(p[1]).max(p[2]) >= -r
        })
    }
}

/// The candidate separating axes of a box and a triangle with corners `v` in the box's frame, in the order
/// they are tried: the box's three, the triangle's normal, the nine cross products of the box's axes with the
/// triangle's edges (zero ones separate nothing).
#[inline]
fn candidate_axes(v: &[DVec3; 3]) -> impl Iterator<Item = DVec3> {
    let edges = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    let n = edges[0].cross(edges[1]);
    [DVec3::X, DVec3::Y, DVec3::Z, n].into_iter().chain(
        [DVec3::X, DVec3::Y, DVec3::Z]
            .into_iter()
            .flat_map(move |a| edges.map(|e| a.cross(e))),
    )
}
