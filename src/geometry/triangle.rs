//! The watertight ray–triangle test of Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection"
//! (JCGT 2013).
//!
//! The ray is turned into a frame where it runs along +z through the origin (a permutation of the axes and
//! a shear, computed once per ray by [`TriangleRay::new`]); each triangle vertex is transformed the same way
//! and the three 2D edge functions decide the hit. Two triangles sharing an edge compute that edge's function
//! from the same transformed vertices, with exactly opposite signs, so a ray can never slip between them —
//! through an edge or a vertex it hits both, and the closest-hit rule (smallest `t`, then smallest primitive
//! index) keeps exactly one. An edge function that is exactly zero is recomputed in `f64`, where the products
//! of two `f32` are exact, so its sign is always right.
//!
//! Zero-area triangles (repeated vertices, collinear vertices) have a zero determinant and never hit.

use super::Ray;
use glam::Vec3;

/// Per-ray constants of the watertight test: the axis permutation and the shear, as three row vectors.
///
/// The paper's transformed coordinates are `x = A[kx] − Sx·A[kz]`, `y = A[ky] − Sy·A[kz]`, `z = Sz·A[kz]`
/// for a vertex `A` relative to the origin. Here they are `row_x · A`, `row_y · A`, `row_z · A` with
/// `row_x = e_kx − Sx·e_kz` and so on: each row has one coefficient exactly 1 and one exactly 0, so the dot
/// product rounds exactly like the paper's expression (adding ±0 changes nothing), with no data-dependent
/// indexing in the inner loop.
#[derive(Clone, Copy, Debug)]
pub struct TriangleRay {
    origin: Vec3,
    row_x: Vec3,
    row_y: Vec3,
    row_z: Vec3,
}

/// Where a ray meets a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Distance along the ray, in units of its direction.
    pub t: f32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the third vertex (the first has `1 - u - v`).
    pub v: f32,
}

impl TriangleRay {
    /// Constants of no ray, for storage that a ray's own constants overwrite before use.
    pub(crate) const EMPTY: TriangleRay = TriangleRay {
        origin: Vec3::ZERO,
        row_x: Vec3::ZERO,
        row_y: Vec3::ZERO,
        row_z: Vec3::ZERO,
    };

    /// Precomputes the transform for `ray` (which must be valid, see [`Ray::is_valid`]).
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        let a = ray.dir().abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding of the projected triangle independent of the ray's direction sign.
        if ray.dir()[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let dz = ray.dir()[kz];
        let (sx, sy, sz) = (ray.dir()[kx] / dz, ray.dir()[ky] / dz, 1.0 / dz);
        let mut row_x = Vec3::ZERO;
        row_x[kx] = 1.0;
        row_x[kz] = -sx;
        let mut row_y = Vec3::ZERO;
        row_y[ky] = 1.0;
        row_y[kz] = -sy;
        let mut row_z = Vec3::ZERO;
        row_z[kz] = sz;
        Self {
            origin: ray.origin,
            row_x,
            row_y,
            row_z,
        }
    }

    /// Constants from their parts, any bits at all, for testing the four-ray test where no ray leads.
    #[cfg(all(test, target_arch = "x86_64"))]
    pub(crate) fn from_parts([origin, row_x, row_y, row_z]: [Vec3; 4]) -> Self {
        Self {
            origin,
            row_x,
            row_y,
            row_z,
        }
    }

    /// The origin and the shear's three rows, for the four-ray test's columns.
    #[cfg(target_arch = "x86_64")]
    pub(crate) fn parts(&self) -> [Vec3; 4] {
        [self.origin, self.row_x, self.row_y, self.row_z]
    }

    /// The shear as three rows (x, y, z of the ray's frame), for the GPU kernels.
    #[cfg(feature = "gpu")]
    pub(crate) fn rows(&self) -> [Vec3; 3] {
        [self.row_x, self.row_y, self.row_z]
    }

    /// Tests the triangle `(v0, v1, v2)`; a hit counts when `tmin <= t <= tmax`. Both faces are hit.
    #[inline]
    pub fn intersect(
        &self,
        v0: Vec3,
        v1: Vec3,
        v2: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<TriangleHit> {
        let a = v0 - self.origin;
        let b = v1 - self.origin;
        let c = v2 - self.origin;
        let (ax, ay) = (self.row_x.dot(a), self.row_y.dot(a));
        let (bx, by) = (self.row_x.dot(b), self.row_y.dot(b));
        let (cx, cy) = (self.row_x.dot(c), self.row_y.dot(c));
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            let edge = |px: f32, py: f32, qx: f32, qy: f32| {
                (px as f64 * qy as f64 - py as f64 * qx as f64) as f32
            };
            u = edge(cx, cy, bx, by);
            v = edge(ax, ay, cx, cy);
            w = edge(bx, by, ax, ay);
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let (az, bz, cz) = (self.row_z.dot(a), self.row_z.dot(b), self.row_z.dot(c));
        let big_t = u * az + v * bz + w * cz;
        let rcp = 1.0 / det;
        let t = big_t * rcp;
        if !(t >= tmin && t <= tmax) {
            return None;
        }
        Some(TriangleHit {
            t,
            u: v * rcp,
            v: w * rcp,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3, tri: [Vec3; 3]) -> Option<TriangleHit> {
        let r = Ray::new(o, d);
        TriangleRay::new(&r).intersect(tri[0], tri[1], tri[2], r.tmin, r.tmax)
    }

    #[test]
    fn analytic_hit_and_barycentrics() {
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let h = hit(Vec3::new(0.25, 0.5, 2.0), -Vec3::Z * 2.0, tri).unwrap();
        assert!((h.t - 1.0).abs() < 1e-7);
        assert!((h.u - 0.25).abs() < 1e-7 && (h.v - 0.5).abs() < 1e-7);
        // Back face is hit too.
        let h = hit(Vec3::new(0.25, 0.5, -2.0), Vec3::Z, tri).unwrap();
        assert!((h.t - 2.0).abs() < 1e-7);
        // Outside.
        assert!(hit(Vec3::new(0.6, 0.6, 2.0), -Vec3::Z, tri).is_none());
        // Behind the origin.
        assert!(hit(Vec3::new(0.25, 0.25, 2.0), Vec3::Z, tri).is_none());
    }

    #[test]
    fn zero_area_triangles_never_hit() {
        let o = Vec3::new(1.0, 1.0, 5.0);
        for tri in [
            [Vec3::ONE, Vec3::ONE, Vec3::ONE],
            [Vec3::ZERO, Vec3::ONE, Vec3::ONE],
            [Vec3::ZERO, Vec3::ONE, Vec3::splat(2.0)],
            [
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(2.0, 1.0, 0.0),
            ],
        ] {
            for d in [-Vec3::Z, Vec3::new(-0.2, -0.2, -1.0), -Vec3::ONE] {
                assert!(hit(o, d, tri).is_none(), "{tri:?} {d:?}");
            }
        }
    }

    #[test]
    fn shared_edge_and_vertex_hit_both_sides() {
        // Two triangles sharing the diagonal of the unit square; rays exactly through the diagonal and corners.
        let (p0, p1, p2, p3) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let t1 = [p0, p1, p2];
        let t2 = [p0, p2, p3];
        // Straight down (exact origin) through every point of the diagonal, corners included; slanted rays
        // through interior points (rounding moves the origin slightly, still inside the quad).
        for (s, d) in [0.0f32, 0.1, 0.37, 0.5, 0.9, 1.0]
            .map(|s| (s, -Vec3::Z))
            .into_iter()
            .chain([0.1f32, 0.37, 0.5, 0.9].map(|s| (s, Vec3::new(0.1, -0.3, -1.0))))
        {
            {
                let o = Vec3::new(s, s, 0.0) - d * 3.0;
                let a = hit(o, d, t1).is_some();
                let b = hit(o, d, t2).is_some();
                assert!(a || b, "slipped through at s={s} d={d:?}");
            }
        }
    }

    /// The permutation and shear follow the paper's rule, read off the rows: `z` is the axis of the
    /// largest `|d|` (the first of equals), `x` and `y` the next two in cyclic order, swapped when `d` is
    /// negative along `z`; the rows hold 1 there and `−d_x/d_z`, `−d_y/d_z`, `1/d_z` in the `z` column,
    /// for every axis and sign, ties included.
    #[test]
    fn axes_and_shear_follow_the_papers_rule() {
        let values = [-2.0f32, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0];
        let mut cases = 0;
        for &x in &values {
            for &y in &values {
                for &z in &values {
                    let d = [x, y, z];
                    if d == [0.0; 3] {
                        continue;
                    }
                    let big = d.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                    let kz = d.iter().position(|v| v.abs() == big).unwrap();
                    let (mut kx, mut ky) = ((kz + 1) % 3, (kz + 2) % 3);
                    if d[kz] < 0.0 {
                        std::mem::swap(&mut kx, &mut ky);
                    }
                    let r = TriangleRay::new(&Ray::new(Vec3::ZERO, Vec3::from_array(d)));
                    let expect = |one: Option<usize>, at_kz: f32| {
                        let mut e = [0.0f32; 3];
                        if let Some(i) = one {
                            e[i] = 1.0;
                        }
                        e[kz] = at_kz;
                        e.map(f32::to_bits)
                    };
                    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
                    let what = format!("d = {d:?}");
                    assert_eq!(bits(r.row_x), expect(Some(kx), -(d[kx] / d[kz])), "{what}");
                    assert_eq!(bits(r.row_y), expect(Some(ky), -(d[ky] / d[kz])), "{what}");
                    assert_eq!(bits(r.row_z), expect(None, 1.0 / d[kz]), "{what}");
                    cases += 1;
                }
            }
        }
        assert_eq!(cases, 7 * 7 * 7 - 1);
    }
}
