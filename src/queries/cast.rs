//! Sphere and capsule casts: the first time a rounded shape moving along a straight line touches a mesh.
//!
//! Both shapes are a core (a point, a segment) grown by a radius, so a cast is the first time the core's
//! distance to a triangle falls to the radius. That time is the least over the feature pairs that can touch
//! first: the core's ends against the face (offset plane), the edges (cylinders) and the corners (spheres);
//! for a segment also its interior against the triangle's corners (the corner moving backwards into the
//! segment's cylinder) and against the edges (the distance of two lines, linear in time). A segment's
//! interior meets the face's interior first only when it is parallel to the face, and then its ends touch at
//! the same time.

use super::closest::{Feature, closest_on_triangle, present};
use super::frame::Frame;
use super::shapes::{DBox, Shape, segment_segment, segment_triangle_closest};
use crate::MeshBvh;
use crate::bvh::traverse_by;
use crate::geometry::{Aabb, Ray};
use glam::{DVec3, Quat, Vec3};

/// Where a cast shape first touches a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CastHit {
    /// Time of impact, in units of the cast's direction (the shape's centre is at `origin + t·dir`). Zero
    /// when the shape starts touching the mesh.
    pub t: f32,
    /// The point of contact on the mesh.
    pub point: Vec3,
    /// Unit normal at the contact, pointing from the mesh towards the shape's centre (away from the surface
    /// the shape touched). For a shape that starts with its centre exactly on the surface, the face normal
    /// facing against the direction of motion.
    pub normal: Vec3,
    /// Index of the triangle touched.
    pub primitive: u32,
    /// Barycentric weight of the triangle's second corner at the contact.
    pub u: f32,
    /// Barycentric weight of the third corner.
    pub v: f32,
    /// Face, edge or corner of the triangle at the contact.
    pub feature: Feature,
}

/// The smallest root `t ≥ 0` of `a t² + 2 b t + c = 0` with `a > 0`, if the roots are real and the smaller
/// one is not negative (the stable form avoids cancelling `-b` against the square root).
fn first_root(a: f64, b: f64, c: f64) -> Option<f64> {
    let disc = b * b - a * c;
    if a <= 0.0 || disc < 0.0 || b >= 0.0 {
        return None; // no real root, or moving away: the smaller root is behind
    }
    let t = c / (-b + disc.sqrt());
    (t >= 0.0).then_some(t)
}

/// The time at which a sphere of radius `r` whose centre moves along `c + t·d` first touches triangle `t`,
/// given that it does not touch it at `t = 0`: the least of the face's offset plane (contact inside the
/// face), the edges' cylinders (contact inside the edge) and the corners' spheres.
fn sphere_triangle_toi(c: DVec3, d: DVec3, r: f64, [a, b, cc]: [DVec3; 3]) -> Option<f64> {
    let mut best: Option<f64> = None;
    let mut take = |t: f64| {
        if best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    };
    let n = (b - a).cross(cc - a);
    let len = n.length();
    if len > 0.0 {
        let face = n / len;
        // The side of the plane the centre starts on.
        let (n, s) = match face.dot(c - a) {
            s if s < 0.0 => (-face, -s),
            s => (face, s),
        };
        let vn = n.dot(d);
        if vn < 0.0 && s >= r {
            let t = (s - r) / -vn;
            let q = c + d * t - n * r;
            // Inside the closed face, by the signs of the sub-triangle normals against the winding's normal.
            let inside = [(a, b), (b, cc), (cc, a)]
                .iter()
                .all(|&(p0, p1)| (p1 - p0).cross(q - p0).dot(face) >= 0.0);
            if inside {
                take(t);
            }
        }
    }
    for (p0, p1) in [(a, b), (b, cc), (cc, a)] {
        let e = p1 - p0;
        let ee = e.dot(e);
        if ee == 0.0 {
            continue;
        }
        let m = c - p0;
        let (mp, dp) = (m - e * (m.dot(e) / ee), d - e * (d.dot(e) / ee));
        if let Some(t) = first_root(dp.dot(dp), mp.dot(dp), mp.dot(mp) - r * r) {
            let s = (c + d * t - p0).dot(e) / ee;
            if (0.0..=1.0).contains(&s) {
                take(t);
            }
        }
    }
    for v in [a, b, cc] {
        let m = c - v;
        if let Some(t) = first_root(d.dot(d), m.dot(d), m.dot(m) - r * r) {
            take(t);
        }
    }
    best
}

/// The time at which a capsule (segment `p0 p1`, radius `r`) moving along `d` first touches the triangle,
/// given that it does not touch it at `t = 0` (see the [module documentation](self)).
fn capsule_triangle_toi(p0: DVec3, p1: DVec3, d: DVec3, r: f64, tri: [DVec3; 3]) -> Option<f64> {
    let mut best = [p0, p1]
        .into_iter()
        .filter_map(|p| sphere_triangle_toi(p, d, r, tri))
        .min_by(f64::total_cmp);
    let mut take = |t: f64| {
        if best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    };
    let e = p1 - p0;
    let ee = e.dot(e);
    if ee == 0.0 {
        return best;
    }
    // The segment's interior against a corner: the corner moves by -d into the segment's cylinder.
    for v in tri {
        let m = v - p0;
        let (mp, dp) = (m - e * (m.dot(e) / ee), d - e * (d.dot(e) / ee));
        if let Some(t) = first_root(dp.dot(dp), -mp.dot(dp), mp.dot(mp) - r * r) {
            let s = (v - d * t - p0).dot(e) / ee;
            if (0.0..=1.0).contains(&s) {
                take(t);
            }
        }
    }
    // The segment's interior against an edge's interior: the lines' distance along their common normal.
    for k in 0..3 {
        let (q0, q1) = (tri[k], tri[(k + 1) % 3]);
        let n = e.cross(q1 - q0);
        let len = n.length();
        if len == 0.0 {
            continue; // parallel: the ends or the corners touch first
        }
        let n = n / len;
        let (w, v) = ((p0 - q0).dot(n), d.dot(n));
        if w.abs() < r || w * v >= 0.0 {
            continue; // already within r of the line (contact comes through ends or corners), or receding
        }
        let t = (w.signum() * r - w) / v;
        let (s, u) = segment_segment(p0 + d * t, p1 + d * t, q0, q1);
        if s > 0.0 && s < 1.0 && u > 0.0 && u < 1.0 {
            take(t);
        }
    }
    best
}

/// What a cast sweeps: the core of a rounded shape (a point for a sphere, a segment for a capsule; the
/// radius is applied on top) or an oriented box (radius 0).
#[derive(Clone, Copy)]
enum Core {
    Point(DVec3),
    Segment(DVec3, DVec3),
    Box(DBox),
}

impl Core {
    /// Whether the shape (core grown by `r`) touches the triangle.
    fn touches(self, r: f64, tri: [DVec3; 3]) -> bool {
        match self {
            Core::Point(p) => closest_on_triangle(p, tri).dist2 <= r * r,
            Core::Segment(a, b) => segment_triangle_closest(a, b, tri).1 <= r * r,
            Core::Box(b) => b.sweep(DVec3::ZERO, tri).is_some(),
        }
    }

    /// The first time the shape moving by `d` touches the triangle, given that it does not at `t = 0`.
    fn toi(self, d: DVec3, r: f64, tri: [DVec3; 3]) -> Option<f64> {
        match self {
            Core::Point(p) => sphere_triangle_toi(p, d, r, tri),
            Core::Segment(a, b) => capsule_triangle_toi(a, b, d, r, tri),
            Core::Box(b) => b.sweep(d, tri).map(|(t, _)| t),
        }
    }

    /// The contact with the triangle at time `t`: the point on the triangle and the unit normal from the
    /// triangle towards the shape.
    fn contact(self, d: DVec3, t: f64, tri: [DVec3; 3]) -> (DVec3, DVec3) {
        let face = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
        let facing = if face.dot(d) > 0.0 { -face } else { face };
        let off = d * t;
        match self {
            Core::Point(_) | Core::Segment(..) => {
                let core = match self {
                    Core::Point(p) => p + off,
                    Core::Segment(a, b) => segment_triangle_closest(a + off, b + off, tri).0,
                    Core::Box(_) => unreachable!(),
                };
                let q = closest_on_triangle(core, tri).point;
                let away = core - q;
                let n = if away.length_squared() > 0.0 {
                    away.normalize()
                } else {
                    facing
                };
                (q, n)
            }
            Core::Box(b) => {
                let moved = DBox {
                    center: b.center + off,
                    ..b
                };
                let n = match b.sweep(d, tri) {
                    Some((_, Some(axis))) => (b.axes * axis).normalize(),
                    _ => facing,
                };
                (box_contact_point(&moved, tri), n)
            }
        }
    }
}

/// A point of the triangle where it touches the box: the centroid of the triangle clipped to the box grown by
/// a few ulp of the magnitudes (Sutherland–Hodgman against the six faces in the box's frame), or the
/// triangle's point nearest the box's centre if rounding left nothing.
fn box_contact_point(b: &DBox, tri: [DVec3; 3]) -> DVec3 {
    let mag = tri
        .iter()
        .map(|p| p.abs().max_element())
        .fold(b.center.abs().max_element(), f64::max);
    let grow = b.half + DVec3::splat((mag + b.half.max_element()) * 1e-9);
    let mut poly = [DVec3::ZERO; 9];
    let mut next = [DVec3::ZERO; 9];
    let mut n = 3;
    for (k, p) in tri.iter().enumerate() {
        poly[k] = b.local(*p);
    }
    for axis in 0..3 {
        for sign in [1.0, -1.0] {
            // Keep the part where sign · x[axis] <= grow[axis].
            let inside = |p: DVec3| sign * p[axis] <= grow[axis];
            let mut m = 0;
            for i in 0..n {
                let (p, q) = (poly[i], poly[(i + 1) % n]);
                if inside(p) {
                    next[m] = p;
                    m += 1;
                }
                if inside(p) != inside(q) && m < next.len() {
                    let k = (sign * grow[axis] - p[axis]) / (q[axis] - p[axis]);
                    next[m] = p.lerp(q, k);
                    m += 1;
                }
            }
            std::mem::swap(&mut poly, &mut next);
            n = m;
            if n == 0 {
                return closest_on_triangle(b.center, tri).point;
            }
        }
    }
    let centroid = poly[..n].iter().copied().sum::<DVec3>() / n as f64;
    b.axes * centroid + b.center
}

impl MeshBvh {
    /// Sweeps a sphere of `radius` from `origin` along `dir` up to `max_t` (in units of `dir`) and returns
    /// where it first touches the mesh.
    ///
    /// A sphere that already touches the mesh at `origin` returns `t = 0`, the nearest point of the mesh and
    /// the direction from it to the centre (the way out of the penetration). Grazing contacts count: a
    /// sphere sliding along a face at exactly `radius` touches it at `t = 0`. The time of impact is computed
    /// in `f64` from the tree's current corners (offset plane, edge cylinders and corner spheres, the
    /// earliest wins; among triangles touched at the same time the lowest index). Zero-area triangles are
    /// absent. Returns `None` for a non-finite or negative radius, a non-finite origin or direction, a zero
    /// direction with no contact at the start, or a miss.
    ///
    /// Cost: a ray traversal against boxes grown by the radius, one time-of-impact solve per triangle in the
    /// boxes reached, nearest box first. No allocation.
    ///
    /// ```
    /// use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions};
    /// use glam::Vec3;
    /// let floor = Mesh::new(vec![Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(0.0, 0.0, 5.0)], vec![0, 1, 2])?;
    /// let bvh = MeshBvh::build(&floor, &BuildOptions::default())?;
    /// // A ball of radius 0.5 dropped from y = 3 lands when its centre is at y = 0.5.
    /// let hit = bvh.cast_sphere(Vec3::new(0.0, 3.0, 0.0), -Vec3::Y, 0.5, 10.0).unwrap();
    /// assert_eq!((hit.t, hit.point, hit.normal), (2.5, Vec3::ZERO, Vec3::Y));
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn cast_sphere(&self, origin: Vec3, dir: Vec3, radius: f32, max_t: f32) -> Option<CastHit> {
        if !(origin.is_finite() && dir.is_finite() && radius.is_finite() && radius >= 0.0)
            || max_t.is_nan()
        {
            return None;
        }
        let core = Core::Point(origin.as_dvec3());
        self.cast_core(core, origin, dir, radius, max_t, Frame::Mesh)
    }

    /// Sweeps a capsule (the points within `radius` of the segment `a`–`b`) along `dir` up to `max_t` and
    /// returns where it first touches the mesh, with the same conventions as [`MeshBvh::cast_sphere`]: `t` in
    /// units of `dir`, `t = 0` and the way out for a start in contact, the normal from the contact towards
    /// the capsule's core.
    ///
    /// Cost: as a sphere cast with boxes grown by the capsule's extent, and about three times the work per
    /// triangle. No allocation.
    ///
    /// ```
    /// use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions};
    /// use glam::Vec3;
    /// let floor = Mesh::new(vec![Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(0.0, 0.0, 5.0)], vec![0, 1, 2])?;
    /// let bvh = MeshBvh::build(&floor, &BuildOptions::default())?;
    /// // A character's capsule (feet at y = 1.5, head at 3.5, radius 0.5) falls 1 unit before it stands.
    /// let hit = bvh.cast_capsule(Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.0, 4.0, 0.0), -Vec3::Y, 0.5, 10.0).unwrap();
    /// assert_eq!((hit.t, hit.normal), (1.5, Vec3::Y));
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn cast_capsule(
        &self,
        a: Vec3,
        b: Vec3,
        dir: Vec3,
        radius: f32,
        max_t: f32,
    ) -> Option<CastHit> {
        if !(a.is_finite() && b.is_finite()) {
            return None;
        }
        let core = Core::Segment(a.as_dvec3(), b.as_dvec3());
        self.cast_core(core, a, dir, radius, max_t, Frame::Mesh)
    }

    /// Sweeps an oriented box (half-extents `half` around `center`, turned by `rotation`) along `dir` up to
    /// `max_t` and returns where it first touches the mesh, with the conventions of
    /// [`MeshBvh::cast_sphere`]: `t = 0` for a start in contact, the normal pointing from the mesh towards the
    /// box. The time of impact is exact in `f64` (the separating-axis intervals of the 13 candidate axes);
    /// the normal is the axis that separated last (for a start in contact, the face normal against the
    /// motion); the point is the centre of the region where the triangle meets the box at that time.
    /// Returns `None` for non-finite input, negative extents or a rotation that is not a unit quaternion.
    ///
    /// Cost: as a sphere cast, with 13 axis projections per triangle in the boxes reached. No allocation.
    ///
    /// ```
    /// use kinetrace::{Mesh, MeshBvh, bvh::BuildOptions};
    /// use glam::{Quat, Vec3};
    /// let floor = Mesh::new(vec![Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(0.0, 0.0, 5.0)], vec![0, 1, 2])?;
    /// let bvh = MeshBvh::build(&floor, &BuildOptions::default())?;
    /// // A crate 1 unit tall dropped from a height of 3 lands after 2.5 units.
    /// let hit = bvh.cast_box(Vec3::new(0.0, 3.0, 0.0), Vec3::splat(0.5), Quat::IDENTITY, -Vec3::Y, 10.0).unwrap();
    /// assert_eq!((hit.t, hit.normal), (2.5, Vec3::Y));
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn cast_box(
        &self,
        center: Vec3,
        half: Vec3,
        rotation: Quat,
        dir: Vec3,
        max_t: f32,
    ) -> Option<CastHit> {
        if !Shape::cuboid(center, half, rotation).is_valid() {
            return None;
        }
        let core = Core::Box(DBox::new(center, half, rotation));
        self.cast_core(core, center, dir, 0.0, max_t, Frame::Mesh)
    }

    /// Sweeps any [`Shape`] along `dir` up to `max_t`: [`cast_sphere`](Self::cast_sphere),
    /// [`cast_capsule`](Self::cast_capsule) or [`cast_box`](Self::cast_box) by its kind, with their
    /// conventions and costs.
    pub fn cast_shape(&self, shape: &Shape, dir: Vec3, max_t: f32) -> Option<CastHit> {
        self.cast_shape_in(shape, dir, max_t, Frame::Mesh)
    }

    /// [`cast_shape`](Self::cast_shape) with the shape, the direction and the answer in `frame`.
    pub(crate) fn cast_shape_in(
        &self,
        shape: &Shape,
        dir: Vec3,
        max_t: f32,
        frame: Frame,
    ) -> Option<CastHit> {
        if !shape.is_valid() {
            return None;
        }
        let (core, anchor, radius) = match *shape {
            Shape::Sphere { center, radius } => (Core::Point(center.as_dvec3()), center, radius),
            Shape::Capsule { a, b, radius } => {
                (Core::Segment(a.as_dvec3(), b.as_dvec3()), a, radius)
            }
            Shape::Box {
                center,
                half,
                rotation,
            } => (Core::Box(DBox::new(center, half, rotation)), center, 0.0),
        };
        self.cast_core(core, anchor, dir, radius, max_t, frame)
    }

    /// The shared sweep: `core` grown by `radius`, moved along `dir`; `anchor` is the core's first point,
    /// from which the traversal's ray starts.
    fn cast_core(
        &self,
        core: Core,
        anchor: Vec3,
        dir: Vec3,
        radius: f32,
        max_t: f32,
        frame: Frame,
    ) -> Option<CastHit> {
        let sweep = Sweep::new(core, anchor, dir, radius, max_t)?;
        let (d, r) = (dir.as_dvec3(), f64::from(radius));
        let tris = self.slot_triangles();
        let prims = self.bvh().prim_indices();
        let mut best: Option<(f64, u32, [DVec3; 3])> = None;
        traverse_by(
            self.bvh().nodes(),
            sweep.ray.tmax,
            &mut (),
            |n, tmax| sweep.enter(&frame.node_box(n), tmax),
            |slots, tmax| {
                for (slot, tri) in present(tris, slots, frame) {
                    let toi = if core.touches(r, tri) {
                        Some(0.0)
                    } else if sweep.moving {
                        core.toi(d, r, tri)
                            .filter(|&t| t <= f64::from(sweep.ray.tmax))
                    } else {
                        None
                    };
                    let Some(toi) = toi else { continue };
                    let prim = prims[slot];
                    if best.is_none_or(|(bt, bp, _)| toi < bt || (toi == bt && prim < bp)) {
                        best = Some((toi, prim, tri));
                        // Boxes entered after the hit (by more than the box test's rounding) hold nothing earlier.
                        *tmax = (toi as f32) * (1.0 + 4.0 * f32::EPSILON) + f32::MIN_POSITIVE;
                    }
                }
                false
            },
        );
        best.map(|(t, prim, tri)| cast_hit(core, d, t, prim, tri))
    }
}

/// The contact of a cast that touches triangle `prim` (corners `tri`) at time `t`.
fn cast_hit(core: Core, d: DVec3, t: f64, prim: u32, tri: [DVec3; 3]) -> CastHit {
    let (point, normal) = core.contact(d, t, tri);
    let q = closest_on_triangle(point, tri);
    CastHit {
        t: t as f32,
        point: q.point.as_vec3(),
        normal: normal.as_vec3(),
        primitive: prim,
        u: q.u as f32,
        v: q.v as f32,
        feature: q.feature,
    }
}

/// A swept shape as the boxes of a tree see it: the ray its anchor follows and the shape's extent around
/// the anchor. Shared by the mesh's tree and the scene's top level.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sweep {
    /// The anchor's path, `[0, max_t]`.
    pub ray: Ray,
    /// False for a zero direction (or `max_t = 0`): only boxes holding the start are entered.
    pub moving: bool,
    anchor: Vec3,
    lo: Vec3,
    hi: Vec3,
}

impl Sweep {
    /// The sweep of `shape` along `dir` up to `max_t`; `None` for invalid input.
    pub(crate) fn of(shape: &Shape, dir: Vec3, max_t: f32) -> Option<Sweep> {
        if !shape.is_valid() {
            return None;
        }
        let b = shape.bounds();
        let anchor = b.center();
        let (lo, hi) = (b.min - anchor, b.max - anchor);
        Sweep::around(anchor, lo, hi, dir, max_t)
    }

    fn new(core: Core, anchor: Vec3, dir: Vec3, radius: f32, max_t: f32) -> Option<Sweep> {
        if !(anchor.is_finite() && radius.is_finite() && radius >= 0.0) {
            return None;
        }
        // The core's extent around the anchor, grown by the radius.
        let (lo, hi) = match core {
            Core::Point(_) => (Vec3::splat(-radius), Vec3::splat(radius)),
            Core::Segment(a, b) => {
                let rel = (b - a).as_vec3();
                (rel.min(Vec3::ZERO) - radius, rel.max(Vec3::ZERO) + radius)
            }
            Core::Box(b) => {
                let m = b.axes;
                let ext = (m.x_axis.abs() * b.half.x
                    + m.y_axis.abs() * b.half.y
                    + m.z_axis.abs() * b.half.z)
                    .as_vec3();
                (-ext, ext)
            }
        };
        Sweep::around(anchor, lo, hi, dir, max_t)
    }

    fn around(anchor: Vec3, lo: Vec3, hi: Vec3, dir: Vec3, max_t: f32) -> Option<Sweep> {
        if !(anchor.is_finite() && dir.is_finite()) || max_t.is_nan() {
            return None;
        }
        let ray = Ray::with_range(anchor, dir, 0.0, max_t.max(0.0));
        Some(Sweep {
            ray,
            moving: ray.is_valid(),
            anchor,
            lo,
            hi,
        })
    }

    /// Entry distance of the anchor into box `b` grown by the shape's extent (and 4 ulp of the magnitudes,
    /// so that it holds the box's Minkowski sum with the shape despite rounding), if before `tmax`; a box
    /// holding the start is entered at 0.
    pub(crate) fn enter(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        let m = b
            .min
            .abs()
            .max(b.max.abs())
            .max(self.anchor.abs())
            .max_element()
            + self.hi.max(-self.lo).max_element();
        let pad = Vec3::splat(m * 4.0 * f32::EPSILON);
        let b = Aabb::new(b.min - self.hi - pad, b.max - self.lo + pad);
        if b.contains_point(self.anchor) {
            Some(0.0)
        } else if self.moving {
            self.ray.intersect_aabb(&b, tmax)
        } else {
            None
        }
    }
}
