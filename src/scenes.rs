//! Procedural meshes for tests, benchmarks and demos: closed surfaces of any size and random triangle soups,
//! generated deterministically from a seed so every run sees the same triangles.

use crate::Mesh;
use glam::Vec3;
use std::collections::HashMap;

/// A small deterministic random generator (SplitMix64): enough for scene generation, no dependency.
#[derive(Clone, Debug)]
pub struct SceneRng(u64);

impl SceneRng {
    /// A generator for `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x9e37_79b9_7f4a_7c15)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in the box `[lo, hi)^3`.
    pub fn vec3(&mut self, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }

    /// A uniformly distributed unit vector.
    pub fn direction(&mut self) -> Vec3 {
        loop {
            let v = self.vec3(-1.0, 1.0);
            let l = v.length_squared();
            if l > 1e-4 && l <= 1.0 {
                return v / l.sqrt();
            }
        }
    }
}

/// `n` random triangles in the unit cube, sizes spread log-uniformly over two orders of magnitude (edges
/// about 0.002 to 0.2): an incoherent "scattered" scene with heavy overlap.
pub fn soup(seed: u64, n: usize) -> Mesh {
    let mut r = SceneRng::new(seed);
    let mut pos = Vec::with_capacity(3 * n);
    for _ in 0..n {
        let c = r.vec3(0.0, 1.0);
        let s = 0.002 * 10f32.powf(r.range(0.0, 2.0));
        for _ in 0..3 {
            pos.push(c + r.vec3(-s, s));
        }
    }
    Mesh::new(pos, (0..3 * n as u32).collect::<Vec<_>>()).expect("finite by construction")
}

/// A closed icosphere of radius 1 around the origin with `20 · 4^subdiv` triangles and shared vertices.
pub fn icosphere(subdiv: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    #[rustfmt::skip]
    let corners = [
        (-1.0, t, 0.0), (1.0, t, 0.0), (-1.0, -t, 0.0), (1.0, -t, 0.0),
        (0.0, -1.0, t), (0.0, 1.0, t), (0.0, -1.0, -t), (0.0, 1.0, -t),
        (t, 0.0, -1.0), (t, 0.0, 1.0), (-t, 0.0, -1.0), (-t, 0.0, 1.0),
    ];
    let mut pos: Vec<Vec3> = corners
        .iter()
        .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
        .collect();
    #[rustfmt::skip]
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
        [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
        [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    for _ in 0..subdiv {
        let mut mid = HashMap::new();
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
    Mesh::new(pos, tris.concat()).expect("finite by construction")
}

/// A closed cube-sphere: the six faces of a cube split into `n × n` quads (two triangles each, vertices shared
/// along the seams), projected onto the unit sphere. `12 n²` triangles.
pub fn cube_sphere(n: u32) -> Mesh {
    let mut pos = Vec::new();
    let mut ids = HashMap::new();
    let mut vertex = |p: [i32; 3], pos: &mut Vec<Vec3>| {
        *ids.entry(p).or_insert_with(|| {
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
                        .map(|q| vertex(q, &mut pos));
                    idx.extend([a, b, c, a, c, d]);
                }
            }
        }
    }
    Mesh::new(pos, idx).expect("finite by construction")
}

/// A closed, bumpy torus (major radius 1, minor 0.35, ±8% bumps) of about `triangles` triangles: a
/// coherent surface mesh of any size, with the uneven triangle density of a real model.
pub fn bumpy_torus(triangles: usize) -> Mesh {
    let nv = (((triangles / 2) as f64 / 3.0).sqrt().round() as usize).max(3);
    let nu = ((triangles / 2) / nv).max(3);
    let mut pos = Vec::with_capacity(nu * nv);
    for i in 0..nu {
        // Rings bunch up on one side of the torus: uneven triangle sizes.
        let s = i as f32 / nu as f32;
        let u = (s + 0.08 * (s * std::f32::consts::TAU).sin()) * std::f32::consts::TAU;
        for j in 0..nv {
            let v = j as f32 / nv as f32 * std::f32::consts::TAU;
            let r = 0.35 * (1.0 + 0.08 * (5.0 * u).sin() * (3.0 * v).cos());
            pos.push(Vec3::new(
                (1.0 + r * v.cos()) * u.cos(),
                r * v.sin(),
                (1.0 + r * v.cos()) * u.sin(),
            ));
        }
    }
    let mut idx = Vec::with_capacity(nu * nv * 6);
    for i in 0..nu {
        for j in 0..nv {
            let at = |a: usize, b: usize| ((a % nu) * nv + b % nv) as u32;
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            idx.extend([a, b, c, a, c, d]);
        }
    }
    Mesh::new(pos, idx).expect("finite by construction")
}

/// A sheet of `n × n` quads (`2n²` triangles) over the unit square, folded in two along `x = 0.5`: the
/// folded half waves through the flat one, so non-adjacent triangles cross along several lines — a
/// self-collision test case. `phase` moves the waves (animate it for a coherently deforming cloth).
pub fn folded_sheet(n: u32, phase: f32) -> Mesh {
    let n = n.max(1);
    let mut pos = Vec::with_capacity(((n + 1) * (n + 1)) as usize);
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
            pos.push(if u <= 0.5 {
                Vec3::new(u, v, 0.01 * (8.0 * v + phase).sin() * (5.0 * u + 0.3).cos())
            } else {
                let z = 0.08 * (10.0 * (u - 0.5) + phase).sin() * (6.0 * v - phase).cos();
                Vec3::new(1.0 - u, v, z)
            });
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    let mut idx = Vec::with_capacity((6 * n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            idx.extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            idx.extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Mesh::new(pos, idx).expect("finite by construction")
}

/// A closed axis-aligned box from `min` to `max`, two triangles per face, normals outward: the shoebox room
/// of acoustics tests and a simple occluder. 12 triangles.
///
/// # Panics
/// When a corner is not finite (the scenes here are fixed test and demo geometry).
pub fn shoebox(min: Vec3, max: Vec3) -> Mesh {
    assert!(
        min.is_finite() && max.is_finite(),
        "shoebox corners must be finite: {min} {max}"
    );
    let corner = |k: u32| {
        Vec3::select(
            glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0),
            max,
            min,
        )
    };
    let quads = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let idx: Vec<u32> = quads
        .iter()
        .flat_map(|[a, b, c, d]| [*a, *b, *c, *a, *c, *d])
        .collect();
    Mesh::new((0..8).map(corner).collect::<Vec<_>>(), idx).expect("finite corners")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed 2-manifold has every edge in exactly two triangles.
    fn is_closed(m: &Mesh) -> bool {
        let mut edges = HashMap::new();
        for t in m.indices().chunks(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        edges.values().all(|&c| c == 2)
    }

    #[test]
    fn closed_meshes_are_closed_and_sized() {
        assert_eq!(icosphere(2).triangle_count(), 320);
        assert_eq!(cube_sphere(3).triangle_count(), 108);
        let t = bumpy_torus(100_000);
        assert!(
            (t.triangle_count() as f64 / 1e5 - 1.0).abs() < 0.05,
            "{}",
            t.triangle_count()
        );
        for m in [icosphere(2), cube_sphere(3), bumpy_torus(5000)] {
            assert!(is_closed(&m));
        }
        assert_eq!(soup(1, 10).triangle_count(), 10);
    }
}
