//! Watertightness: rays from inside a closed mesh always hit it, also through shared edges and vertices.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::{Mesh, MeshBvh, Ray};
use rand::Rng;

/// `n` rays from random points well inside the unit sphere in random directions; returns the misses.
fn misses_from_inside(bvh: &MeshBvh, seed: u64, n: usize) -> usize {
    let mut r = rng(seed);
    let rays: Vec<Ray> = (0..n)
        .map(|_| {
            let o = rand_dir(&mut r) * r.random_range(0.0f32..0.9);
            Ray::new(o, rand_dir(&mut r))
        })
        .collect();
    let mut hits = vec![None; n];
    bvh.closest_hits(&rays, &mut hits);
    hits.iter().filter(|h| h.is_none()).count()
}

fn closed_meshes() -> [(&'static str, Mesh); 2] {
    [
        ("icosphere", icosphere(4)),
        ("cube-sphere", cube_sphere(24)),
    ]
}

#[test]
fn a_million_rays_from_inside_never_miss() {
    for (name, m) in closed_meshes() {
        let bvh = MeshBvh::build(&m, &BuildOptions::new(Builder::SAH)).unwrap();
        assert_eq!(misses_from_inside(&bvh, 1, 1_000_000), 0, "{name}");
    }
    // The other builders on fewer rays: watertightness is the triangle test's, but traversal must not cull.
    for (name, m) in closed_meshes() {
        for b in [Builder::Median, Builder::LBVH, Builder::HYBRID] {
            let bvh = MeshBvh::build(&m, &BuildOptions::new(b).max_leaf_size(4)).unwrap();
            assert_eq!(misses_from_inside(&bvh, 2, 20_000), 0, "{name} {b:?}");
        }
    }
}

#[test]
fn rays_through_shared_vertices_and_edges_always_hit() {
    for (name, m) in closed_meshes() {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let mut targets: Vec<Vec3> = m.positions().to_vec();
        // Directions through edge midpoints (a + b points at the midpoint's direction from the centre).
        for t in m.indices().chunks(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                targets.push(m.positions()[a as usize] + m.positions()[b as usize]);
            }
        }
        let mut r = rng(3);
        for (i, &p) in targets.iter().enumerate() {
            // From the centre: the ray passes exactly through a vertex (t = 1).
            let from_centre = Ray::new(Vec3::ZERO, p);
            let h = bvh.closest_hit(&from_centre);
            assert!(
                h.is_some(),
                "{name}: centre ray {i} through {p} slipped through"
            );
            let got = h.map(|h| (h.primitive, h.t));
            assert_brute_hit(&m, &from_centre, got, &format!("{name} {i}"));
            // From outside, aimed back at the centre through the same point.
            let outside = Ray::new(p.normalize() * 3.0, -p);
            assert!(
                bvh.any_hit(&outside),
                "{name}: outside ray {i} slipped through"
            );
            // From a random inside point towards the vertex or edge point.
            let o = rand_dir(&mut r) * r.random_range(0.0f32..0.5);
            let q = if i < m.positions().len() {
                p
            } else {
                p.normalize() * 0.999
            };
            assert!(
                bvh.any_hit(&Ray::new(o, q - o)),
                "{name}: inside ray {i} slipped through"
            );
        }
    }
}

#[test]
fn exactly_one_hit_through_a_shared_edge_of_a_grid() {
    // A flat 8x8 grid of unit squares at integer coordinates: rays straight down through grid lines and
    // grid vertices (exactly representable) must hit, and the reported triangle is the lowest index among
    // those containing the point, as brute force says.
    let n = 8u32;
    let mut pos = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            pos.push(Vec3::new(x as f32, y as f32, 0.0));
        }
    }
    let mut idx = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x;
            idx.extend([a, a + 1, a + n + 2, a, a + n + 2, a + n + 1]);
        }
    }
    let m = Mesh::new(pos, idx).unwrap();
    for b in Builder::ALL {
        let bvh = MeshBvh::build(&m, &BuildOptions::new(b)).unwrap();
        for i in 1..(4 * n) {
            for j in 1..(4 * n) {
                let (x, y) = (i as f32 * 0.25, j as f32 * 0.25);
                for d in [
                    -Vec3::Z,
                    Vec3::new(0.0, 0.25, -1.0),
                    Vec3::new(-0.5, 0.0, -1.0),
                ] {
                    let ray = Ray::new(Vec3::new(x, y, 0.0) - d * 4.0, d);
                    let h = bvh.closest_hit(&ray);
                    assert!(h.is_some(), "{b:?}: ({x}, {y}) {d} slipped through");
                    // Every coordinate, shear factor and product here is a small dyadic number, so the
                    // crate's f32 arithmetic is exact and must give the exact answer, tie rule included.
                    let got = h.map(|h| (h.primitive, h.t));
                    assert_eq!(got, brute_closest(&m, &ray), "{b:?}: ({x}, {y}) {d}");
                }
            }
        }
    }
}
