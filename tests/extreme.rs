//! Numerically extreme scenes: every builder, with and without the wide query tree, checked against brute
//! force and analytic answers.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, MortonBits};
use kinetrace::{Mesh, MeshBvh, Ray};
use rand::Rng;

fn builders() -> Vec<BuildOptions> {
    Builder::ALL
        .into_iter()
        .chain([Builder::Lbvh {
            morton: MortonBits::Bits63,
        }])
        .flat_map(|b| {
            [
                BuildOptions::new(b),
                BuildOptions::new(b).max_leaf_size(4),
                BuildOptions::new(b).wide(false),
            ]
        })
        .collect()
}

/// Checks every builder's answers against the oracle; returns how many rays exactly hit.
fn check_rays(m: &Mesh, rays: &[Ray], what: &str) -> usize {
    let oracles: Vec<RayOracle> = rays.iter().map(|r| RayOracle::of_mesh(m, r)).collect();
    for opt in builders() {
        let bvh = MeshBvh::build(m, &opt).unwrap();
        bvh.bvh().validate(Some(&m.triangle_bounds())).unwrap();
        for (i, (ray, oracle)) in rays.iter().zip(&oracles).enumerate() {
            let got = bvh.closest_hit(ray).map(|h| (h.primitive, h.t));
            oracle.check_closest(got, &format!("{what} {opt:?} ray {i}"));
            oracle.check_any(bvh.any_hit(ray), &format!("{what} {opt:?} any-hit ray {i}"));
        }
    }
    oracles.iter().filter(|o| o.any()).count()
}

/// Rays from random points inside a sphere of `radius` around `centre`, and from outside aimed at it.
fn sphere_rays(centre: Vec3, radius: f32, seed: u64, n: usize) -> Vec<Ray> {
    let mut r = rng(seed);
    (0..n)
        .map(|i| {
            if i % 2 == 0 {
                Ray::new(
                    centre + rand_dir(&mut r) * radius * r.random_range(0.0f32..0.8),
                    rand_dir(&mut r),
                )
            } else {
                let o = centre + rand_dir(&mut r) * radius * 3.0;
                let target = centre + rand_dir(&mut r) * radius * r.random_range(0.0f32..1.2);
                Ray::new(o, target - o)
            }
        })
        .collect()
}

#[test]
fn huge_offsets_and_scales() {
    // (offset, scale): the sphere stays representable (at 1e7 the f32 spacing is 1, so radius 1e3).
    for (offset, scale) in [
        (1e5f32, 1.0f32),
        (1e7, 1e3),
        (0.0, 1e-4),
        (0.0, 1e4),
        (-1e5, 10.0),
    ] {
        let c = Vec3::new(offset, -0.5 * offset, 0.25 * offset);
        let m = map_mesh(&icosphere(2), |p| c + p * scale);
        let rays = sphere_rays(c, scale, 1, 300);
        let hits = check_rays(&m, &rays, &format!("offset {offset} scale {scale}"));
        // Every ray from inside the closed sphere hits it.
        assert!(hits >= 150, "offset {offset} scale {scale}: {hits} hits");
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        for ray in rays.iter().step_by(2) {
            assert!(
                bvh.any_hit(ray),
                "offset {offset} scale {scale}: inside ray slipped out {ray:?}"
            );
        }
        // Analytic distance from outside to the sphere along a radius: 2·scale (polyhedron within 3%).
        let h = bvh
            .closest_hit(&Ray::new(c + Vec3::X * 3.0 * scale, -Vec3::X))
            .unwrap();
        assert!(
            (h.t / scale - 2.0).abs() < 0.03,
            "offset {offset} scale {scale}: t = {}",
            h.t
        );
    }
}

#[test]
fn teapot_in_a_stadium() {
    // A 1e-6 sphere at the centre of a 1e4 closed box, plus a few mid-sized objects in the stadium.
    let tiny = map_mesh(&icosphere(2), |p| p * 1e-6 + Vec3::splat(0.25));
    let stadium = map_mesh(&cube_sphere(2), |p| p.signum() * 5e3); // a closed 1e4 box
    let mut pos = tiny.positions().to_vec();
    let mut idx = tiny.indices().to_vec();
    let off = pos.len() as u32;
    pos.extend_from_slice(stadium.positions());
    idx.extend(stadium.indices().iter().map(|i| i + off));
    let m = Mesh::new(pos, idx).unwrap();
    let tiny_tris = tiny.triangle_count() as u32;
    let mut rays = sphere_rays(Vec3::splat(0.25), 1e-6, 2, 200);
    rays.extend(sphere_rays(Vec3::ZERO, 4e3, 3, 100));
    check_rays(&m, &rays, "teapot");
    for opt in builders() {
        let bvh = MeshBvh::build(&m, &opt).unwrap();
        // Aimed at the teapot along axes from across the stadium (the lateral coordinates stay exact in f32),
        // and from a slant close by (from afar, f32 cannot aim within 1e-6): hits the teapot, not the walls.
        for (d, dist) in [
            (Vec3::X, 4e3),
            (-Vec3::Y, 4e3),
            (-Vec3::Z, 4.5e3),
            (Vec3::new(0.3, -0.5, 1.0), 1e-5),
        ] {
            let d = d.normalize();
            let o = Vec3::splat(0.25) - d * dist;
            let h = bvh
                .closest_hit(&Ray::new(o, Vec3::splat(0.25) - o))
                .unwrap();
            assert!(
                h.primitive < tiny_tris,
                "{opt:?} {d}: hit the stadium instead of the teapot"
            );
            assert!(
                (h.t * dist - (dist - 1e-6)).abs() < 1e-3 * dist,
                "{opt:?} {d}: t = {}",
                h.t
            );
        }
    }
}

#[test]
fn identical_centroids() {
    // 500 triangles rotated about one common centroid: Morton codes all equal, no spatial split exists.
    let mut pos = Vec::new();
    for i in 0..500 {
        let a = i as f32 * 0.0125;
        let (s, c) = a.sin_cos();
        let r = 0.1 + (i % 7) as f32 * 0.05;
        let p = |k: f32| {
            let th = k * std::f32::consts::TAU / 3.0;
            Vec3::new(r * th.cos(), r * th.sin() * c, r * th.sin() * s)
        };
        pos.extend([p(0.0), p(1.0), p(2.0)]);
    }
    let m = Mesh::new(pos, (0..1500).collect::<Vec<u32>>()).unwrap();
    let c0 = m.triangle_bounds()[0].center();
    assert!(
        m.triangle_bounds()
            .iter()
            .all(|b| (b.center() - c0).length() < 0.5)
    );
    let rays = sphere_rays(Vec3::ZERO, 0.4, 4, 300);
    check_rays(&m, &rays, "identical centroids");
    // Exactly identical centroids and boxes: the same triangle repeated.
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(300)).unwrap();
    let rays = sphere_rays(Vec3::splat(0.3), 1.0, 5, 100);
    let hits = check_rays(&same, &rays, "repeated triangle");
    assert!(hits > 0);
}

#[test]
fn axis_parallel_rays_and_rays_inside_face_planes() {
    // An axis-aligned closed box of 12 triangles and a grid, hit by rays with exact zero components,
    // including rays that run exactly inside a face plane or along an edge.
    let cube = map_mesh(&cube_sphere(1), |p| p.signum());
    let grid = soup(6, 300);
    for m in [cube, grid] {
        let mut rays = Vec::new();
        for &x in &[-1.0f32, -0.5, 0.0, 0.3, 0.5, 1.0] {
            for &y in &[-1.0f32, 0.0, 0.25, 0.5, 1.0] {
                for d in [
                    Vec3::X,
                    -Vec3::X,
                    Vec3::Y,
                    -Vec3::Y,
                    Vec3::Z,
                    -Vec3::Z,
                    Vec3::new(1.0, 0.0, -1.0),
                ] {
                    let o = Vec3::new(x, y, x * 0.5) - d * 3.0;
                    rays.push(Ray::new(o, d));
                    rays.push(Ray::new(o, d * 1e-3)); // short direction: t scales, answers must not change
                    rays.push(Ray::new(o, Vec3::new(-0.0, -0.0, 0.0) + d)); // signed zeros
                }
            }
        }
        let hits = check_rays(&m, &rays, "axis-parallel");
        assert!(hits > 20, "{hits}");
    }
    // Along the cube's edges and faces from inside: the closed box is hit.
    let cube = map_mesh(&cube_sphere(1), |p| p.signum());
    let bvh = MeshBvh::build(&cube, &BuildOptions::default()).unwrap();
    for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
        for o in [
            Vec3::ZERO,
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, -1.0),
        ] {
            assert!(
                bvh.any_hit(&Ray::new(o, d)),
                "ray from {o} along {d} escaped the box"
            );
        }
    }
}

#[test]
fn rays_starting_on_a_surface() {
    let m = icosphere(2);
    let mut r = rng(7);
    let mut rays = Vec::new();
    for _ in 0..300 {
        let i = r.random_range(0..m.triangle_count());
        let [a, b, c] = m.triangle(i);
        let p = a * 0.2 + b * 0.3 + c * 0.5;
        let n = (b - a).cross(c - a).normalize();
        rays.push(Ray::new(p, n)); // outward: may hit its own triangle at t ≈ 0 and nothing else
        rays.push(Ray::new(p, -n + rand_dir(&mut r) * 0.3)); // inward: crosses the sphere
        rays.push(Ray::with_range(p, -n, 1e-4, f32::INFINITY)); // offset start: skips its own triangle
    }
    check_rays(&m, &rays, "on surface");
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    for ray in rays.iter().skip(2).step_by(3) {
        let h = bvh
            .closest_hit(ray)
            .expect("inward ray from the surface hits the far side");
        assert!(h.t > 0.5, "t = {}", h.t);
    }
}

#[test]
fn needle_and_zero_area_triangles() {
    let mut pos = vec![];
    let mut idx = vec![];
    let mut add = |tri: [Vec3; 3]| {
        let b = pos.len() as u32;
        pos.extend(tri);
        idx.extend([b, b + 1, b + 2]);
    };
    // Needles: 1000 long, 1e-5 wide.
    for i in 0..50 {
        let y = i as f32 * 0.1;
        add([
            Vec3::new(-500.0, y, 0.0),
            Vec3::new(500.0, y, 0.0),
            Vec3::new(0.0, y + 1e-5, 0.0),
        ]);
    }
    // Zero area, away from the needles: repeated vertices, collinear points.
    let far = Vec3::new(2000.0, 0.0, 0.0);
    add([far + Vec3::ONE; 3]);
    add([far, far + Vec3::ONE, far + Vec3::ONE]);
    add([far, far + Vec3::ONE, far + Vec3::splat(2.0)]);
    add([
        far + Vec3::new(0.0, 7.0, 0.0),
        far + Vec3::new(1.0, 7.0, 0.0),
        far + Vec3::new(3.0, 7.0, 0.0),
    ]);
    let m = Mesh::new(pos, idx).unwrap();
    let mut rays = Vec::new();
    for i in 0..50 {
        for x in [-499.0f32, -10.0, 0.0, 3.0, 250.0] {
            let y = i as f32 * 0.1 + 2.5e-6;
            rays.push(Ray::new(Vec3::new(x * 1e-3, y, 1.0), -Vec3::Z)); // inside the needle near its middle
            rays.push(Ray::new(Vec3::new(x, y + 2e-5, 1.0), -Vec3::Z)); // just beside it
        }
    }
    // Straight at the degenerate triangles, through their vertices and along their lines.
    for (o, d) in [
        (Vec3::new(1.0, 1.0, 5.0), -Vec3::Z),
        (Vec3::new(0.5, 0.5, 5.0), Vec3::new(0.0, 0.0, -1.0)),
        (Vec3::new(-1.0, -1.0, -1.0), Vec3::ONE),
        (Vec3::new(-1.0, 7.0, 0.0), Vec3::X),
        (Vec3::new(2.0, 7.0, 3.0), -Vec3::Z),
    ] {
        rays.push(Ray::new(far + o, d));
    }
    let hits = check_rays(&m, &rays, "needles");
    assert!(hits >= 50, "{hits}");
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    for ray in &rays[rays.len() - 5..] {
        assert!(!bvh.any_hit(ray), "a zero-area triangle was hit by {ray:?}");
    }
}

#[test]
fn one_triangle_and_empty_meshes() {
    let one = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap();
    let empty = Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap();
    let rays = sphere_rays(Vec3::splat(0.3), 1.0, 8, 100);
    assert!(check_rays(&one, &rays, "one triangle") > 0);
    assert_eq!(check_rays(&empty, &rays, "empty"), 0);
    for opt in builders() {
        let e = MeshBvh::build(&empty, &opt).unwrap();
        assert!(e.bvh().is_empty() && e.bvh().nodes().is_empty());
        assert_eq!(e.bvh().sah_cost(), 0.0);
        let o = MeshBvh::build(&one, &opt).unwrap();
        assert_eq!(o.bvh().nodes().len(), 1);
        assert!(o.bvh().nodes()[0].is_leaf());
    }
    // Invalid rays are answered with no hit, never a panic.
    let bvh = MeshBvh::build(&one, &BuildOptions::default()).unwrap();
    for ray in [
        Ray::new(Vec3::splat(0.2), Vec3::ZERO),
        Ray::new(Vec3::NAN, -Vec3::Z),
        Ray::new(
            Vec3::new(0.2, 0.2, 1.0),
            Vec3::new(0.0, 0.0, f32::NEG_INFINITY),
        ),
        Ray::with_range(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z, f32::NAN, 2.0),
    ] {
        assert!(bvh.closest_hit(&ray).is_none() && !bvh.any_hit(&ray));
    }
}
