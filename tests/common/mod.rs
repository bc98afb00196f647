//! Test support: scene generators and brute-force oracles that share no traversal code with the crate.
#![allow(dead_code)] // each test binary uses a different part

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

/// `n` random triangles in the unit cube with sizes spread over two orders of magnitude.
pub fn soup(seed: u64, n: usize) -> Mesh {
    let mut r = rng(seed);
    let mut pos = Vec::with_capacity(3 * n);
    for _ in 0..n {
        let c = rand_vec(&mut r, 0.0, 1.0);
        let s = 0.002 * 10f32.powf(r.random_range(0.0..2.0));
        for _ in 0..3 {
            pos.push(c + rand_vec(&mut r, -s, s));
        }
    }
    let idx = (0..3 * n as u32).collect::<Vec<_>>();
    Mesh::new(pos, idx).unwrap()
}

/// A closed icosphere of radius 1 around the origin, `subdiv` times subdivided (20·4^subdiv triangles),
/// vertices shared between triangles.
pub fn icosphere(subdiv: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut pos: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdiv {
        let mut mid = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, pos: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                pos.push(((pos[a as usize] + pos[b as usize]) * 0.5).normalize());
                pos.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut pos);
            let bc = midpoint(b, c, &mut pos);
            let ca = midpoint(c, a, &mut pos);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    Mesh::new(pos, tris.concat()).unwrap()
}

/// A closed cube-sphere: the six faces of a cube split into `n × n` quads (two triangles each, shared
/// vertices along face seams), projected onto the unit sphere.
pub fn cube_sphere(n: u32) -> Mesh {
    let mut pos = Vec::new();
    let mut map = std::collections::HashMap::new();
    let mut vid = |p: [i32; 3], pos: &mut Vec<Vec3>| {
        *map.entry(p).or_insert_with(|| {
            let v = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / n as f32 * 2.0 - Vec3::ONE;
            pos.push(v.normalize());
            pos.len() as u32 - 1
        })
    };
    let n = n as i32;
    let mut idx = Vec::new();
    for axis in 0..3 {
        for side in [0, n] {
            for i in 0..n {
                for j in 0..n {
                    let p = |a: i32, b: i32| {
                        let mut q = [0; 3];
                        q[axis] = side;
                        q[(axis + 1) % 3] = a;
                        q[(axis + 2) % 3] = b;
                        q
                    };
                    let [a, b, c, d] = [p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)]
                        .map(|q| vid(q, &mut pos));
                    idx.extend([a, b, c, a, c, d]);
                }
            }
        }
    }
    Mesh::new(pos, idx).unwrap()
}

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
