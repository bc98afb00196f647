//! The crate's watertight ray–triangle test against the exact oracle (`tests/common/oracle.rs`), on rays
//! aimed at edges and vertices where `f32` rounding matters most: wherever the oracle says the arithmetic
//! decides, the answers must be equal, and distances and barycentrics within the derived bounds.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::Ray;
use kinetrace::geometry::TriangleRay;
use rand::Rng;

/// A point on an edge or at a corner of `tri`, moved off it by `jitter` (relative to the triangle's size).
fn near_boundary(r: &mut impl Rng, tri: [Vec3; 3], jitter: f32) -> Vec3 {
    let k = r.random_range(0..3);
    let (a, b) = (tri[k], tri[(k + 1) % 3]);
    let s = match r.random_range(0..4) {
        0 => 0.0,
        1 => 0.5,
        _ => r.random::<f32>(),
    };
    let size = (b - a).length().max((tri[(k + 2) % 3] - a).length());
    a + (b - a) * s + rand_vec_in(r, jitter * size)
}

fn rand_vec_in(r: &mut impl Rng, h: f32) -> Vec3 {
    if h == 0.0 {
        return Vec3::ZERO;
    }
    Vec3::new(
        r.random_range(-h..h),
        r.random_range(-h..h),
        r.random_range(-h..h),
    )
}

#[test]
fn watertight_test_agrees_with_exact_arithmetic_wherever_it_decides() {
    let mut r = rng(1);
    let (mut certain, mut disputed, mut hits) = (0, 0, 0);
    for i in 0..200_000 {
        let tri = [0, 1, 2].map(|_| rand_vec(&mut r, -1.0, 1.0));
        let jitter = [0.0, 1e-6, 1e-5, 1e-4][i % 4];
        let target = near_boundary(&mut r, tri, jitter);
        let o = rand_vec(&mut r, -3.0, 3.0);
        let ray = Ray::new(o, target - o);
        let got = TriangleRay::new(&ray).intersect(tri[0], tri[1], tri[2], ray.tmin, ray.tmax);
        let v = ray_triangle(&ray, tri);
        if !v.certain {
            disputed += 1;
            continue;
        }
        certain += 1;
        assert_eq!(
            got.is_some(),
            v.hit,
            "ray {i}: {got:?} vs {v:?} {ray:?} {tri:?}"
        );
        if let Some(h) = got {
            hits += 1;
            assert!(
                (h.t as f64 - v.t).abs() <= v.t_err,
                "ray {i}: t {h:?} vs {v:?}"
            );
            for (k, got) in [h.u, h.v].into_iter().enumerate() {
                let e = (got as f64 - v.bary[k + 1]).abs();
                assert!(e <= v.bary_err[k + 1], "ray {i}: bary {h:?} vs {v:?}");
            }
        }
    }
    // Most rays are decidable, and both answers and the disputed band are exercised.
    assert!(
        certain > 70_000 && hits > 25_000 && disputed > 100_000,
        "{certain} {hits} {disputed}"
    );
}

#[test]
fn rays_exactly_through_shared_edges_and_corners_tie_exactly() {
    // Two triangles sharing the diagonal of the unit square, rays straight down: every value is exact,
    // so the oracle says "hit" for both at the same t, and the lower index wins.
    let (p0, p1, p2, p3) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
    let tris = [[p0, p1, p2], [p0, p2, p3]];
    for s in [0.0f32, 0.25, 0.5, 1.0] {
        let ray = Ray::new(Vec3::new(s, s, 2.0), -Vec3::Z);
        let [a, b] = tris.map(|t| ray_triangle(&ray, t));
        assert!(
            a.hit && b.hit && !a.certain && !b.certain,
            "{s}: {a:?} {b:?}"
        );
        assert_eq!((a.t, b.t), (2.0, 2.0));
        assert_eq!(RayOracle::new(&ray, tris).closest(), Some((0, 2.0)));
    }
    // Zero-area triangles and rays in the triangle's plane never hit, exactly.
    let ray = Ray::new(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z);
    for tri in [[p0, p1, p1], [p0, p1, Vec3::new(2.0, 0.0, 0.0)]] {
        let v = ray_triangle(&ray, tri);
        assert!(!v.hit, "{tri:?}: {v:?}");
    }
    let in_plane = Ray::new(Vec3::new(-1.0, 0.25, 0.0), Vec3::X);
    assert!(!ray_triangle(&in_plane, tris[0]).hit);
}

#[test]
fn exact_fallback_decides_what_f64_cannot() {
    // Rays exactly through a corner: o and the corner a are within a factor 2 per component, so d = a − o
    // is exact in f32 (Sterbenz) and two edge volumes d·(Δa×Δb) = d·(d×Δb) are exactly zero. In f64 the
    // three-factor products round, so the naive value is often not zero; the oracle's exact fallback must
    // still say "on the corner: a hit, disputed".
    let mut r = rng(2);
    let mut naive_nonzero = 0;
    for i in 0..1000 {
        let a = rand_vec(&mut r, 0.5, 0.9);
        let o = rand_vec(&mut r, 0.5, 0.9);
        let d = a - o;
        if d.length() < 0.05 {
            continue;
        }
        let (b, c) = (rand_vec(&mut r, -1.0, 1.0), rand_vec(&mut r, -1.0, 1.0));
        let ray = Ray::new(o, d);
        let v = ray_triangle(&ray, [a, b, c]);
        assert!(v.hit && !v.certain, "corner ray {i}: {v:?}");
        assert!((v.t - 1.0).abs() < 1e-12, "corner ray {i}: t {}", v.t);
        let (dd, db) = (d.as_dvec3(), (b - o).as_dvec3());
        naive_nonzero += (dd.dot(dd.cross(db)) != 0.0) as usize;
    }
    assert!(
        naive_nonzero > 100,
        "f64 alone decided {naive_nonzero} of them"
    );
}
