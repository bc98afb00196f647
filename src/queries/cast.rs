//! Sphere casts: the first time a sphere moving along a straight line touches a mesh.

use super::closest::{Feature, closest_on_triangle, present};
use crate::MeshBvh;
use crate::bvh::{Node, traverse_by};
use crate::geometry::{Aabb, Ray};
use glam::{DVec3, Vec3};

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
        let (c, d, r) = (origin.as_dvec3(), dir.as_dvec3(), f64::from(radius));
        let ray = Ray::with_range(origin, dir, 0.0, max_t.max(0.0));
        let moving = ray.is_valid();
        // Entry distance into a node's box grown by the radius (and 4 ulp of its magnitude, so that it holds
        // the box's Minkowski sum with the sphere despite rounding); a box holding the start is entered at 0.
        let enter = |n: &Node, tmax: f32| -> Option<f32> {
            let b = n.aabb();
            let pad = radius + b.min.abs().max(b.max.abs()).max_element() * 4.0 * f32::EPSILON;
            let b = Aabb::new(b.min - pad, b.max + pad);
            if b.contains_point(origin) {
                Some(0.0)
            } else if moving {
                ray.intersect_aabb(&b, tmax)
            } else {
                None
            }
        };
        let tris = self.slot_triangles();
        let prims = self.bvh().prim_indices();
        let mut best: Option<(f64, u32, usize)> = None;
        traverse_by(
            self.bvh().nodes(),
            ray.tmax,
            &mut (),
            enter,
            |slots, tmax| {
                for (slot, tri) in present(tris, slots) {
                    let toi = if closest_on_triangle(c, tri).dist2 <= r * r {
                        Some(0.0)
                    } else if moving {
                        sphere_triangle_toi(c, d, r, tri).filter(|&t| t <= f64::from(ray.tmax))
                    } else {
                        None
                    };
                    let Some(toi) = toi else { continue };
                    let prim = prims[slot];
                    if best.is_none_or(|(bt, bp, _)| toi < bt || (toi == bt && prim < bp)) {
                        best = Some((toi, prim, slot));
                        // Boxes entered after the hit (by more than the box test's rounding) hold nothing earlier.
                        *tmax = (toi as f32) * (1.0 + 4.0 * f32::EPSILON) + f32::MIN_POSITIVE;
                    }
                }
                false
            },
        );
        best.map(|(t, prim, slot)| self.cast_hit(c, d, t, prim, slot))
    }

    /// The contact of a sphere cast that touches triangle `prim` (in `slot`) at time `t`.
    fn cast_hit(&self, c: DVec3, d: DVec3, t: f64, prim: u32, slot: usize) -> CastHit {
        let tri = self.slot_triangles()[slot].map(Vec3::as_dvec3);
        let center = c + d * t;
        let q = closest_on_triangle(center, tri);
        let away = center - q.point;
        let normal = if away.length_squared() > 0.0 {
            away.normalize()
        } else {
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            if n.dot(d) > 0.0 { -n } else { n }
        };
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
}
