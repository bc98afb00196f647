//! Test support: scene generators and brute-force oracles that share no traversal code with the crate.
#![allow(dead_code, unused_imports)] // each test binary uses a different part

pub mod ecs;

use glam::{DVec3, Vec3};
use kinetrace::geometry::TriangleRay;
use kinetrace::{Mesh, Ray};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

pub fn rng(seed: u64) -> SmallRng {
    SmallRng::seed_from_u64(seed)
}

pub fn rand_vec(r: &mut SmallRng, lo: f32, hi: f32) -> Vec3 {
    Vec3::new(
        r.random_range(lo..hi),
        r.random_range(lo..hi),
        r.random_range(lo..hi),
    )
}

/// A uniformly random unit direction.
pub fn rand_dir(r: &mut SmallRng) -> Vec3 {
    loop {
        let v = rand_vec(r, -1.0, 1.0);
        let l = v.length_squared();
        if l > 1e-4 && l <= 1.0 {
            return v / l.sqrt();
        }
    }
}

pub use kinetrace::scenes::{cube_sphere, icosphere, soup};

/// The mesh with every vertex mapped by `f`.
pub fn map_mesh(m: &Mesh, f: impl Fn(Vec3) -> Vec3) -> Mesh {
    Mesh::new(
        m.positions().iter().map(|&p| f(p)).collect::<Vec<_>>(),
        m.indices().to_vec(),
    )
    .unwrap()
}

/// Brute force closest hit: every triangle, the crate's documented rule (smallest t, then lowest index;
/// zero-area triangles never hit). Returns (triangle, t).
pub fn brute_closest(m: &Mesh, ray: &Ray) -> Option<(u32, f32)> {
    if !ray.is_valid() {
        return None;
    }
    let tr = TriangleRay::new(ray);
    let mut best: Option<(u32, f32)> = None;
    for i in 0..m.triangle_count() {
        let [a, b, c] = m.triangle(i);
        if (b - a).cross(c - a) == Vec3::ZERO {
            continue;
        }
        if let Some(h) = tr.intersect(a, b, c, ray.tmin, ray.tmax)
            && best.is_none_or(|(_, t)| h.t < t)
        {
            best = Some((i as u32, h.t));
        }
    }
    best
}

/// Brute force any hit.
pub fn brute_any(m: &Mesh, ray: &Ray) -> bool {
    brute_closest(m, ray).is_some()
}

/// Independent f64 Möller–Trumbore (no culling): (t, u, v) with the barycentrics of v1 and v2.
pub fn moller_trumbore(o: Vec3, d: Vec3, tri: [Vec3; 3]) -> Option<(f64, f64, f64)> {
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let [a, b, c] = tri.map(|v| v.as_dvec3());
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return None;
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some((e2.dot(q) / det, u, v))
}

pub fn dvec(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

/// Asserts that a BVH's closest hit agrees with brute force: the same triangle and `t`, or — on an exact tie
/// at a shared edge or vertex — another triangle that the ray really hits at the same `t` (within 1e-6
/// relative, the rounding of the box test against the triangle test).
/// [`assert_same_hit`] against [`brute_closest`] over the mesh.
pub fn assert_brute_hit(m: &Mesh, ray: &Ray, got: Option<(u32, f32)>, what: &str) {
    assert_same_hit(m, ray, got, brute_closest(m, ray), what);
}

pub fn assert_same_hit(
    m: &Mesh,
    ray: &Ray,
    got: Option<(u32, f32)>,
    expect: Option<(u32, f32)>,
    what: &str,
) {
    match (got, expect) {
        (Some((gp, gt)), Some((ep, et))) if gp != ep => {
            assert!(
                (gt - et).abs() <= 1e-6 * et.abs().max(1e-30),
                "{what}: {got:?} vs {expect:?} {ray:?}"
            );
            let [a, b, c] = m.triangle(gp as usize);
            let h = TriangleRay::new(ray).intersect(a, b, c, ray.tmin, ray.tmax);
            assert_eq!(
                h.map(|h| h.t),
                Some(gt),
                "{what}: reported triangle {gp} is not hit at {gt}"
            );
        }
        _ => assert_eq!(got, expect, "{what}: {ray:?}"),
    }
}

/// Closest point of triangle `t` to `p` (Ericson, Real-Time Collision Detection, §5.1.5), in f64.
pub fn closest_on_triangle(p: DVec3, [a, b, c]: [DVec3; 3]) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}
