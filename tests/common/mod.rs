//! Test support: scene generators and brute-force oracles that share no code with the crate (the ray oracle
//! is exact arithmetic of its own, [`oracle`]), and [`skip`] for tests that cannot run here.
#![allow(dead_code, unused_imports)] // each test binary uses a different part

pub mod ecs;
mod exact;
mod oracle;
mod skip;

pub use oracle::{RayOracle, TriangleVerdict, ray_triangle};
pub use skip::*;

use glam::{DVec3, Vec3};
use kinetrace::bvh::{BuildOptions, Builder, MortonBits};
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

/// `n` rays at a scene: every other one aimed at a random triangle's centroid, the rest in random
/// directions, all from random points of the scene's box grown by its extent on every side.
pub fn scene_rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let mut r = rng(seed);
    let b = m
        .triangle_bounds()
        .iter()
        .fold(kinetrace::Aabb::EMPTY, |a, t| a.union(t));
    let (lo, hi) = (b.min - b.extent(), b.max + b.extent());
    (0..n)
        .map(|i| {
            let o = lo + (hi - lo) * Vec3::new(r.random(), r.random(), r.random());
            if i % 2 == 0 {
                let [a, bb, c] = m.triangle(r.random_range(0..m.triangle_count()));
                Ray::new(o, (a + bb + c) / 3.0 - o)
            } else {
                Ray::new(o, rand_dir(&mut r))
            }
        })
        .collect()
}

pub use kinetrace::scenes::{cube_sphere, icosphere, soup};

/// Every builder (the presets and a non-default setting of each family), with one and four triangles per
/// leaf, and with one per leaf without the wide query tree (so ray queries walk the binary tree): the build
/// configurations a whole-crate property is checked under.
pub fn all_build_options() -> Vec<BuildOptions> {
    let mut v = Vec::new();
    for b in Builder::ALL.into_iter().chain([
        Builder::Lbvh {
            morton: MortonBits::Bits63,
        },
        Builder::Sah { bins: 4 },
        Builder::Hybrid {
            lbvh_levels: 2,
            bins: 8,
            morton: MortonBits::Bits63,
        },
        Builder::PLOC,
        Builder::Ploc { radius: 1 },
    ]) {
        for leaf in [1, 4] {
            v.push(BuildOptions::new(b).max_leaf_size(leaf));
        }
        v.push(BuildOptions::new(b).wide(false));
    }
    v
}

/// The mesh with every vertex mapped by `f`.
pub fn map_mesh(m: &Mesh, f: impl Fn(Vec3) -> Vec3) -> Mesh {
    Mesh::new(
        m.positions().iter().map(|&p| f(p)).collect::<Vec<_>>(),
        m.indices().to_vec(),
    )
    .unwrap()
}

/// An `n`×`n` tile-ordered pinhole camera at `eye` looking at `target`: coherent packets of `tile`².
pub fn camera(eye: Vec3, target: Vec3, n: u32, tile: u32, fov: f32) -> Vec<Ray> {
    let f = (target - eye).normalize();
    let r = f.cross(Vec3::Y).normalize_or(Vec3::X);
    let up = r.cross(f);
    let s = (fov * 0.5).tan();
    let mut rays = Vec::new();
    for ty in (0..n).step_by(tile as usize) {
        for tx in (0..n).step_by(tile as usize) {
            for y in ty..(ty + tile).min(n) {
                for x in tx..(tx + tile).min(n) {
                    let px = ((x as f32 + 0.5) / n as f32 * 2.0 - 1.0) * s;
                    let py = ((y as f32 + 0.5) / n as f32 * 2.0 - 1.0) * s;
                    rays.push(Ray::new(eye, f + r * px + up * py));
                }
            }
        }
    }
    rays
}

/// Brute force closest hit by the independent oracle ([`RayOracle`]): the exact answer for the `f32` ray and
/// triangles — smallest exact `t`, then lowest index; a ray through an edge or vertex hits; zero-area
/// triangles and rays in a triangle's plane never hit. Returns (triangle, `t` rounded to `f32`). The crate's
/// `f32` answer may differ from it within rounding (near an edge, at an exact tie): compare with
/// [`assert_brute_hit`] / [`assert_same_hit`], which know those bounds, not with `assert_eq!`.
pub fn brute_closest(m: &Mesh, ray: &Ray) -> Option<(u32, f32)> {
    RayOracle::of_mesh(m, ray)
        .closest()
        .map(|(i, t)| (i, t as f32))
}

/// Brute force any hit: whether the ray exactly hits some triangle (see [`brute_closest`]). Compare a crate
/// answer with [`assert_any_hit`], which allows disputed rays.
pub fn brute_any(m: &Mesh, ray: &Ray) -> bool {
    RayOracle::of_mesh(m, ray).any()
}

/// Asserts that an any-hit answer is one the oracle allows: `true` only if some triangle is hit or within
/// rounding of it, `false` only if no triangle is certainly hit.
pub fn assert_any_hit(m: &Mesh, ray: &Ray, got: bool, what: &str) {
    RayOracle::of_mesh(m, ray).check_any(got, what);
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

/// Asserts that a closest hit (triangle, `t`) is one the independent oracle allows: the triangle is hit (or
/// the ray passes within `f32` rounding of its edge), `t` is within the derived `f32` bound of the exact
/// distance, and no triangle is certainly hit nearer — exactly "the same triangle" wherever the arithmetic
/// decides, any of the tied triangles at a shared edge or vertex. See [`RayOracle::check_closest`].
pub fn assert_brute_hit(m: &Mesh, ray: &Ray, got: Option<(u32, f32)>, what: &str) {
    RayOracle::of_mesh(m, ray).check_closest(got, what);
}

/// Asserts that two answers to the same closest-hit query (e.g. a tree's and brute force's, or the GPU's
/// and the CPU's) are equal or both allowed by the oracle (see [`assert_brute_hit`]).
pub fn assert_same_hit(
    m: &Mesh,
    ray: &Ray,
    got: Option<(u32, f32)>,
    expect: Option<(u32, f32)>,
    what: &str,
) {
    let oracle = RayOracle::of_mesh(m, ray);
    oracle.check_closest(got, what);
    if expect != got {
        oracle.check_closest(expect, &format!("{what} (expected answer)"));
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

/// f64 Möller–Trumbore, both faces: `Some(t)` when the ray from `o` along `dir` crosses the closed triangle
/// at `t > 0`.
pub fn crossing(o: DVec3, dir: DVec3, [a, b, c]: [DVec3; 3]) -> Option<f64> {
    let (e1, e2) = (b - a, c - a);
    let pv = dir.cross(e2);
    let det = e1.dot(pv);
    if det == 0.0 {
        return None;
    }
    let tv = o - a;
    let u = tv.dot(pv) / det;
    let qv = tv.cross(e1);
    let v = dir.dot(qv) / det;
    let t = e2.dot(qv) / det;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0).then_some(t)
}

/// Inside a closed triangle set by the parity of [`crossing`]s along each of `dirs` (an odd number of
/// random directions), majority vote: a direction that grazes an edge miscounts, the others outvote it.
pub fn parity_inside(tris: &[[Vec3; 3]], p: Vec3, dirs: &[DVec3]) -> bool {
    let odd = dirs
        .iter()
        .filter(|&&dir| {
            tris.iter()
                .filter(|t| crossing(p.as_dvec3(), dir, t.map(Vec3::as_dvec3)).is_some())
                .count()
                % 2
                == 1
        })
        .count();
    2 * odd > dirs.len()
}

/// `n` triangles in the unit cube, centres on a jittered lattice (evenly spread), edges `s` times `10^x`
/// with `x` uniform in `[0, decades]`: alike triangles for 0 decades, mixed sizes for more.
pub fn even_soup(n: usize, s: f32, decades: f32) -> Mesh {
    let mut r = rng(3);
    let k = (n as f32).cbrt().ceil() as usize;
    let mut pos = Vec::with_capacity(3 * n);
    for i in 0..n {
        let cell = Vec3::new((i % k) as f32, ((i / k) % k) as f32, (i / (k * k)) as f32);
        let c = (cell + Vec3::splat(0.5) + rand_vec(&mut r, -0.3, 0.3)) / k as f32;
        let e = s * 10f32.powf(decades * rand_vec(&mut r, 0.0, 1.0).x);
        pos.extend([
            c,
            c + Vec3::new(e, 0.0, 0.2 * e),
            c + Vec3::new(0.0, e, 0.5 * e),
        ]);
    }
    Mesh::new(pos, (0..3 * n as u32).collect::<Vec<_>>()).unwrap()
}

/// `n` zero-area triangles on one line (x from 0 to n / 2), each over three consecutive points.
pub fn collinear_zero_area(n: u32) -> Mesh {
    Mesh::new(
        (0..n)
            .map(|i| Vec3::new(i as f32 * 0.5, 0.0, 0.0))
            .collect::<Vec<Vec3>>(),
        (0..n)
            .map(|i| [i, (i + 1) % n, (i + 2) % n])
            .collect::<Vec<_>>()
            .concat(),
    )
    .unwrap()
}

/// A 1e-6 icosphere of subdivision `subdiv` (the teapot) at (0.25, 0.25, 0.25) inside a 1e4 box (the
/// stadium): the clustered scene of the thesis. The teapot's triangles come first.
pub fn teapot_in_stadium(subdiv: u32) -> Mesh {
    use kinetrace::scenes::{cube_sphere, icosphere};
    let tiny = map_mesh(&icosphere(subdiv), |p| p * 1e-6 + Vec3::splat(0.25));
    let stadium = map_mesh(&cube_sphere(2), |p| p.signum() * 5e3);
    let mut pos = tiny.positions().to_vec();
    let mut idx = tiny.indices().to_vec();
    idx.extend(stadium.indices().iter().map(|i| i + pos.len() as u32));
    pos.extend_from_slice(stadium.positions());
    Mesh::new(pos, idx).unwrap()
}
