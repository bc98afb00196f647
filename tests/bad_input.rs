//! What a careless or hostile caller meets at every public entry point: NaN and ±∞ in rays, vertices,
//! distances and radii, zero-length and denormal directions, empty meshes, out-of-range and degenerate
//! indices, zero-scale and non-invertible transforms, 1e30 coordinates. Each call returns its documented
//! answer or a clear error — never a panic, a hang, or a hit that is not there. Where an answer is expected
//! it is checked against brute force ([`RayOracle`], the tests' own exact arithmetic) or an analytic value.
#![cfg(feature = "parallel")]

mod common;
use bevy_ecs::prelude::*;
use common::ecs::app_with;
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::collide::{PairQuery, Placed};
use kinetrace::ecs::*;
use kinetrace::grid::{GridOptions, UniformGrid};
use kinetrace::queries::Shape;
use kinetrace::{Error, Mesh, MeshBvh, Ray};

const NAN: f32 = f32::NAN;
const INF: f32 = f32::INFINITY;
/// Smaller than `f32::MIN_POSITIVE`: a denormal.
const DENORMAL: f32 = 1e-40;

/// Values that no coordinate should carry.
const NON_FINITE: [f32; 3] = [NAN, INF, -INF];

/// A unit quad in z = 0 (two triangles) and a triangle at z = 1 above it.
fn quad_and_roof() -> Mesh {
    Mesh::new(
        vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.5, 0.0, 1.0),
            Vec3::new(0.0, 0.5, 1.0),
        ],
        vec![0, 1, 2, 0, 2, 3, 4, 5, 6],
    )
    .unwrap()
}

/// Every builder, with and without the wide query tree.
fn trees(m: &Mesh) -> Vec<(String, MeshBvh)> {
    Builder::ALL
        .into_iter()
        .flat_map(|b| [BuildOptions::new(b), BuildOptions::new(b).wide(false)])
        .map(|o| (format!("{o:?}"), MeshBvh::build(m, &o).unwrap()))
        .collect()
}

/// Rays that no query can answer: non-finite origin or direction, a zero or all-denormal direction, a NaN
/// range.
fn invalid_rays() -> Vec<Ray> {
    let mut rays = vec![
        Ray::new(Vec3::new(0.3, 0.3, 2.0), Vec3::ZERO),
        Ray::new(Vec3::new(0.3, 0.3, 2.0), Vec3::splat(DENORMAL)),
        Ray::new(Vec3::new(0.3, 0.3, 2.0), Vec3::new(-0.0, 0.0, -DENORMAL)),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, NAN, 10.0),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, 0.0, NAN),
        Ray::segment(Vec3::new(0.3, 0.3, 2.0), Vec3::new(0.3, 0.3, 2.0)),
    ];
    for bad in NON_FINITE {
        rays.push(Ray::new(Vec3::new(0.3, bad, 2.0), -Vec3::Z));
        rays.push(Ray::new(
            Vec3::new(0.3, 0.3, 2.0),
            Vec3::new(0.0, bad, -1.0),
        ));
        rays.push(Ray::new(Vec3::splat(bad), Vec3::splat(bad)));
    }
    rays
}

/// Valid rays with awkward values, each aimed at `quad_and_roof`: denormal direction components, a huge
/// direction, ranges that are empty, negative or infinite, origins far away.
fn awkward_rays() -> Vec<Ray> {
    let down = |x: f32, y: f32| Ray::new(Vec3::new(x, y, 2.0), -Vec3::Z);
    vec![
        down(0.3, 0.3),
        down(0.1, 0.1),
        Ray::new(
            Vec3::new(0.3, 0.3, 2.0),
            Vec3::new(DENORMAL, -DENORMAL, -1.0),
        ),
        Ray::new(Vec3::new(0.3, 0.3, 2.0), Vec3::new(0.0, 0.0, -1e30)),
        Ray::new(Vec3::new(0.3, 0.3, 2.0), Vec3::new(0.0, 0.0, -1e-30)),
        Ray::new(Vec3::new(0.3, 0.3, 1e30), -Vec3::Z),
        Ray::new(Vec3::new(-1e30, 0.3, 0.5), Vec3::X),
        Ray::new(Vec3::new(0.3, 0.3, -1e30), Vec3::new(0.0, 0.0, 1.0)),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, 0.0, -1.0),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, 5.0, 1.0),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, -INF, INF),
        Ray::with_range(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z, 1.5, INF),
        Ray::with_range(Vec3::new(0.1, 0.1, 2.0), -Vec3::Z, -5.0, 1.0),
        Ray::with_range(Vec3::new(0.1, 0.1, 2.0), -Vec3::Z, INF, INF),
        Ray::with_range(Vec3::new(0.1, 0.1, 2.0), -Vec3::Z, -INF, -INF),
    ]
}

#[test]
fn mesh_construction_rejects_bad_data_with_errors_naming_it() {
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
    // An empty mesh is a mesh, with nothing in it.
    let empty = Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap();
    assert_eq!(empty.triangle_count(), 0);
    // Indices without vertices, and u32::MAX.
    assert!(matches!(
        Mesh::new(Vec::<Vec3>::new(), vec![0, 0, 0]),
        Err(Error::IndexOutOfRange {
            position: 0,
            index: 0,
            vertex_count: 0
        })
    ));
    assert!(matches!(
        Mesh::new(p.clone(), vec![0, 1, u32::MAX]),
        Err(Error::IndexOutOfRange {
            position: 2,
            index: u32::MAX,
            ..
        })
    ));
    assert_eq!(
        Mesh::new(p.clone(), vec![0, 1]).unwrap_err(),
        Error::IndexCountNotMultipleOfThree { count: 2 }
    );
    // A NaN or infinite vertex that no triangle uses is still refused: positions may be re-indexed later.
    for bad in NON_FINITE {
        let mut q = p.clone();
        q.push(Vec3::new(0.0, 0.0, bad));
        assert!(matches!(
            Mesh::new(q, vec![0, 1, 2]),
            Err(Error::NonFiniteVertex { vertex: 3, .. })
        ));
    }
    // 1e30 and denormal coordinates are finite, hence legal.
    Mesh::new(
        vec![Vec3::splat(1e30), Vec3::X * -1e30, Vec3::splat(DENORMAL)],
        vec![0, 1, 2],
    )
    .unwrap();
    // with_positions on an empty mesh: only an empty list matches.
    assert!(empty.with_positions(Vec::<Vec3>::new()).is_ok());
    assert!(matches!(
        empty.with_positions(vec![Vec3::ZERO]),
        Err(Error::VertexCountMismatch {
            expected: 0,
            got: 1
        })
    ));
}

#[test]
fn empty_meshes_answer_nothing_everywhere() {
    let empty = Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap();
    // A hit from another mesh, to see that the batched query overwrites its output.
    let stale = MeshBvh::build(&quad_and_roof(), &BuildOptions::default())
        .unwrap()
        .closest_hit(&Ray::new(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z));
    assert!(stale.is_some());
    for (what, mut bvh) in trees(&empty) {
        let ray = Ray::new(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z);
        assert!(bvh.closest_hit(&ray).is_none(), "{what}");
        assert!(!bvh.any_hit(&ray), "{what}");
        let mut all = vec![];
        bvh.all_hits(&ray, &mut all);
        assert!(all.is_empty(), "{what}");
        let mut out = [stale];
        bvh.closest_hits(&[ray], &mut out);
        assert_eq!(out, [None], "{what}");
        let mut stats = TraversalStats::default();
        bvh.closest_hits_packet(&[ray; 4], &mut [None; 4], &mut stats);
        assert!(bvh.closest_point(Vec3::ZERO, INF).is_none(), "{what}");
        assert!(!bvh.contains_point(Vec3::ZERO), "{what}");
        assert!(
            bvh.cast_sphere(Vec3::ZERO, Vec3::X, 1.0, INF).is_none(),
            "{what}"
        );
        let mut tris = vec![7];
        bvh.overlapping(&Shape::sphere(Vec3::ZERO, 1e30), &mut tris);
        assert!(tris.is_empty(), "{what}");
        assert_eq!(bvh.refit(&[]).unwrap(), 0.0, "{what}");
        assert!(matches!(
            bvh.refit(&[Vec3::ZERO]),
            Err(Error::VertexCountMismatch { .. })
        ));
        let mut contacts = vec![];
        let stats = PairQuery::new()
            .meshes(
                Placed::new(&bvh, Affine3A::IDENTITY),
                Placed::new(&bvh, Affine3A::IDENTITY),
                &mut contacts,
            )
            .unwrap();
        assert!(contacts.is_empty(), "{what}: {stats:?}");
    }
    let grid = UniformGrid::build(&empty, &GridOptions::default()).unwrap();
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    assert!(grid.closest_hit(&ray).is_none());
    assert!(!grid.any_hit(&ray));
}

#[test]
fn invalid_rays_hit_nothing_on_every_structure() {
    let m = quad_and_roof();
    let rays = invalid_rays();
    let grid = UniformGrid::build(&m, &GridOptions::default()).unwrap();
    for (what, bvh) in trees(&m) {
        for (i, ray) in rays.iter().enumerate() {
            assert!(!ray.is_valid(), "ray {i} {ray:?}");
            let what = format!("{what} ray {i} {ray:?}");
            assert_eq!(bvh.closest_hit(ray), None, "{what}");
            assert!(!bvh.any_hit(ray), "{what}");
            let mut all = vec![];
            bvh.all_hits(ray, &mut all);
            assert!(all.is_empty(), "{what}");
            assert_eq!(grid.closest_hit(ray), None, "grid {what}");
            assert!(!grid.any_hit(ray), "grid {what}");
        }
        // As packets, mixed with valid rays: the invalid lanes stay empty, the valid ones are answered.
        let good = Ray::new(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z);
        let mixed: Vec<Ray> = rays.iter().flat_map(|r| [*r, good]).collect();
        let mut stats = TraversalStats::default();
        for chunk in mixed.chunks(16) {
            let mut hits = vec![None; chunk.len()];
            let mut any = vec![false; chunk.len()];
            bvh.closest_hits_packet(chunk, &mut hits, &mut stats);
            bvh.any_hits_packet(chunk, &mut any, &mut stats);
            let mut ghits = vec![None; chunk.len()];
            let mut gany = vec![false; chunk.len()];
            grid.closest_hits_packet(chunk, &mut ghits, &mut stats);
            grid.any_hits_packet(chunk, &mut gany, &mut stats);
            for (k, r) in chunk.iter().enumerate() {
                let expect = r.is_valid().then_some((0, 2.0));
                for (by, h, a) in [("bvh", hits[k], any[k]), ("grid", ghits[k], gany[k])] {
                    assert_eq!(h.map(|h| (h.primitive, h.t)), expect, "{by} {what} {r:?}");
                    assert_eq!(a, expect.is_some(), "{by} {what} {r:?}");
                }
            }
        }
    }
}

#[test]
fn awkward_valid_rays_equal_brute_force() {
    let m = quad_and_roof();
    let grid = UniformGrid::build(&m, &GridOptions::default()).unwrap();
    for (i, ray) in awkward_rays().iter().enumerate() {
        assert!(ray.is_valid(), "ray {i}");
        let oracle = RayOracle::of_mesh(&m, ray);
        for (what, bvh) in trees(&m) {
            let what = format!("{what} ray {i}");
            oracle.check_closest(bvh.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
            oracle.check_any(bvh.any_hit(ray), &what);
            let mut all = vec![];
            bvh.all_hits(ray, &mut all);
            for h in &all {
                assert!(oracle.verdict(h.primitive).is_some(), "{what}: {h:?}");
            }
        }
        let what = format!("grid ray {i}");
        oracle.check_closest(grid.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
        oracle.check_any(grid.any_hit(ray), &what);
    }
    // The analytic answers of a few: the denormal components are flushed, the ray goes straight down.
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let rays = awkward_rays();
    assert_eq!(
        bvh.closest_hit(&rays[2]).map(|h| (h.primitive, h.t)),
        Some((0, 2.0))
    );
    assert_eq!(bvh.closest_hit(&rays[3]).map(|h| h.t), Some(2e-30));
    assert_eq!(bvh.closest_hit(&rays[4]).map(|h| h.t), Some(2e30));
    for empty_range in &rays[8..10] {
        assert!(bvh.closest_hit(empty_range).is_none());
    }
}

#[test]
fn degenerate_triangles_are_never_hit() {
    // Every triangle repeats an index or has collinear corners: nothing has an area.
    let p = vec![Vec3::ZERO, Vec3::X, Vec3::new(2.0, 0.0, 0.0), Vec3::Y];
    let m = Mesh::new(p, vec![0, 0, 0, 0, 1, 1, 0, 1, 2, 3, 3, 0]).unwrap();
    let grid = UniformGrid::build(&m, &GridOptions::default()).unwrap();
    let rays = [
        Ray::new(Vec3::new(0.5, 0.0, 1.0), -Vec3::Z),
        Ray::new(Vec3::new(0.0, 0.0, 1.0), -Vec3::Z),
        Ray::new(Vec3::new(-1.0, 0.0, 0.0), Vec3::X),
        Ray::new(Vec3::new(0.0, 0.5, 1.0), -Vec3::Z),
    ];
    for (what, bvh) in trees(&m) {
        for r in &rays {
            assert!(bvh.closest_hit(r).is_none(), "{what} {r:?}");
            assert!(!bvh.any_hit(r), "{what} {r:?}");
            assert!(grid.closest_hit(r).is_none(), "grid {r:?}");
        }
        // Zero-area triangles are absent from casts, and contain nothing.
        assert!(
            bvh.cast_sphere(Vec3::new(0.5, 0.0, 2.0), -Vec3::Z, 0.5, 10.0)
                .is_none(),
            "{what}"
        );
        assert!(!bvh.contains_point(Vec3::new(0.5, 0.0, 0.0)), "{what}");
    }
}

/// 64 random triangles spread over `±s`, 200 rays between them (more than ten of which hit) with their
/// oracles, and the grid over the triangles.
fn fan(s: f32) -> (Mesh, Vec<(Ray, RayOracle)>, UniformGrid) {
    let (mut pos, mut idx) = (vec![], vec![]);
    let mut r = rng(7);
    for i in 0..64u32 {
        let c = rand_vec(&mut r, -1.0, 1.0) * s;
        pos.extend([
            c,
            c + rand_vec(&mut r, -1.0, 1.0) * s * 0.3,
            c + rand_vec(&mut r, -1.0, 1.0) * s * 0.3,
        ]);
        idx.extend([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let m = Mesh::new(pos, idx).unwrap();
    let rays: Vec<(Ray, RayOracle)> = (0..200)
        .map(|_| {
            let o = rand_vec(&mut r, -1.5, 1.5) * s;
            let t = rand_vec(&mut r, -1.0, 1.0) * s;
            let ray = Ray::new(o, t - o);
            (ray, RayOracle::of_mesh(&m, &ray))
        })
        .collect();
    let meet = rays.iter().filter(|(_, o)| o.any()).count();
    assert!(meet > 10, "{meet} rays meet the fan");
    let grid = UniformGrid::build(&m, &GridOptions::default()).unwrap();
    (m, rays, grid)
}

/// A reported hit must be one the exact oracle finds (hit, or within rounding of an edge) at its distance.
fn assert_real(o: &RayOracle, got: Option<(u32, f32)>, what: &str) {
    if let Some((p, t)) = got {
        let v =
            (o.verdict(p)).unwrap_or_else(|| panic!("{what}: phantom hit on triangle {p} at {t}"));
        assert!(
            (t as f64 - v.t).abs() <= v.t_err,
            "{what}: triangle {p} at {t}, exactly {}",
            v.t
        );
    }
}

#[test]
fn coordinates_up_to_1e18_answer_like_brute_force() {
    let (m, rays, grid) = fan(1e18);
    for (what, bvh) in trees(&m) {
        for (i, (ray, o)) in rays.iter().enumerate() {
            let what = format!("{what} ray {i}");
            o.check_closest(bvh.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
            o.check_any(bvh.any_hit(ray), &what);
            o.check_closest(grid.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
        }
    }
}

#[test]
fn coordinates_of_1e30_build_and_never_report_a_hit_that_is_not_there() {
    // Past about 1e19 the triangle test's products overflow f32: a ray may miss a triangle it touches
    // (documented at `Mesh::new`), but what it reports is there.
    let (m, rays, grid) = fan(1e30);
    for (what, bvh) in trees(&m) {
        for (i, (ray, o)) in rays.iter().enumerate() {
            let what = format!("{what} ray {i}");
            assert_real(o, bvh.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
            assert_real(o, grid.closest_hit(ray).map(|h| (h.primitive, h.t)), &what);
            let mut all = vec![];
            bvh.all_hits(ray, &mut all);
            for h in all {
                assert_real(o, Some((h.primitive, h.t)), &what);
            }
            if bvh.any_hit(ray) {
                assert!(
                    (0..64).any(|t| o.verdict(t).is_some()),
                    "{what}: phantom any-hit"
                );
            }
        }
    }
    // Point queries at that scale (exact in f64): the nearest corner of a lone triangle.
    let s = 1e30f32;
    let far = Mesh::new(
        vec![
            Vec3::splat(s),
            Vec3::new(s, s, 0.5 * s),
            Vec3::new(0.5 * s, s, s),
        ],
        vec![0, 1, 2],
    )
    .unwrap();
    let bvh = MeshBvh::build(&far, &BuildOptions::default()).unwrap();
    let hit = bvh.closest_point(Vec3::splat(2.0 * s), INF).unwrap();
    assert_eq!(hit.point, Vec3::splat(s));
    assert!(bvh.closest_point(Vec3::splat(2.0 * s), 1.0).is_none());
    assert!(!bvh.contains_point(Vec3::splat(2.0 * s)));
    let hit = bvh.cast_sphere(Vec3::splat(2.0 * s), -Vec3::ONE, 0.0, INF);
    assert_eq!(hit.map(|h| h.point), Some(Vec3::splat(s)));
}

#[test]
fn refits_with_bad_positions_are_errors_and_keep_the_tree() {
    let m = quad_and_roof();
    for (what, mut bvh) in trees(&m) {
        for bad in NON_FINITE {
            let mut p = m.positions().to_vec();
            p[4].y = bad;
            assert!(
                matches!(bvh.refit(&p), Err(Error::NonFiniteVertex { vertex: 4, .. })),
                "{what}"
            );
        }
        assert!(matches!(
            bvh.refit(&[Vec3::ZERO; 3]),
            Err(Error::VertexCountMismatch {
                expected: 7,
                got: 3
            })
        ));
        // The tree still answers for the positions it had.
        let ray = Ray::new(Vec3::new(0.1, 0.1, 2.0), -Vec3::Z);
        assert_eq!(
            bvh.closest_hit(&ray).map(|h| (h.primitive, h.t)),
            Some((2, 1.0)),
            "{what}"
        );
        // Collapsing everything onto one point is legal and hits nothing.
        bvh.refit(&[Vec3::ONE; 7]).unwrap();
        assert!(
            bvh.closest_hit(&Ray::new(Vec3::new(1.0, 1.0, 2.0), -Vec3::Z))
                .is_none(),
            "{what}"
        );
    }
}

#[test]
fn shape_queries_refuse_bad_shapes_distances_and_directions() {
    let m = quad_and_roof();
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let above = Vec3::new(0.8, 0.8, 0.5);
    let mut bad_shapes = vec![
        Shape::sphere(above, -1.0),
        Shape::sphere(above, -0.0 - f32::MIN_POSITIVE),
        Shape::capsule(above, above + Vec3::Z, -0.1),
        Shape::cuboid(above, Vec3::new(0.1, -0.1, 0.1), Quat::IDENTITY),
        Shape::cuboid(above, Vec3::splat(0.1), Quat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
        Shape::cuboid(above, Vec3::splat(0.1), Quat::from_xyzw(1.0, 1.0, 1.0, 1.0)),
    ];
    for bad in NON_FINITE {
        bad_shapes.extend([
            Shape::sphere(above, bad),
            Shape::sphere(Vec3::new(bad, 0.0, 0.0), 0.1),
            Shape::capsule(above, Vec3::splat(bad), 0.1),
            Shape::capsule(above, above, bad),
            Shape::cuboid(above, Vec3::new(0.1, bad, 0.1), Quat::IDENTITY),
            Shape::cuboid(Vec3::splat(bad), Vec3::splat(0.1), Quat::IDENTITY),
            Shape::cuboid(above, Vec3::splat(0.1), Quat::from_xyzw(bad, 0.0, 0.0, 1.0)),
        ]);
    }
    let mut out = vec![];
    for s in &bad_shapes {
        assert!(!s.is_valid(), "{s:?}");
        assert!(bvh.cast_shape(s, -Vec3::Z, 10.0).is_none(), "{s:?}");
        out.push(99);
        bvh.overlapping(s, &mut out);
        assert!(out.is_empty(), "{s:?}");
    }
    // Valid shapes with bad directions or limits: nothing, unless already touching (t = 0, documented).
    let ball = Shape::sphere(above, 0.1);
    let touching = Shape::sphere(Vec3::new(0.8, 0.8, 0.05), 0.1);
    for dir in [
        Vec3::splat(NAN),
        Vec3::new(0.0, INF, -1.0),
        Vec3::new(0.0, 0.0, -INF),
    ] {
        assert!(bvh.cast_shape(&ball, dir, 10.0).is_none(), "{dir}");
        assert!(bvh.cast_shape(&touching, dir, 10.0).is_none(), "{dir}");
    }
    for max_t in [NAN, -1.0, -INF] {
        assert!(bvh.cast_shape(&ball, -Vec3::Z, max_t).is_none(), "{max_t}");
    }
    for dir in [Vec3::ZERO, Vec3::splat(DENORMAL)] {
        assert!(bvh.cast_shape(&ball, dir, 10.0).is_none(), "{dir}");
        // Already in contact: t = 0, whatever the direction.
        let hit = bvh
            .cast_shape(&touching, dir, 10.0)
            .expect("contact at the start");
        assert_eq!((hit.t, hit.primitive), (0.0, 0), "{dir}");
    }
    // A huge or tiny direction: t scales inversely (in units of dir); the ball lands at z = 0.1.
    let hit = bvh
        .cast_shape(&ball, Vec3::new(0.0, 0.0, -1e30), INF)
        .unwrap();
    assert_eq!(hit.t, 0.4e-30);
    let hit = bvh
        .cast_shape(&ball, Vec3::new(0.0, 0.0, -1e-30), INF)
        .unwrap();
    assert_eq!(hit.t, 0.4e30);
    // A radius of 1e30 touches everything at the start; a zero radius is a point, which sweeps as a ray.
    let huge = Shape::sphere(above, 1e30);
    assert_eq!(
        bvh.cast_shape(&huge, -Vec3::Z, 10.0).map(|h| h.t),
        Some(0.0)
    );
    bvh.overlapping(&huge, &mut out);
    assert_eq!(out, [0, 1, 2]);
    let point = Shape::sphere(Vec3::new(0.1, 0.1, 2.0), 0.0);
    assert_eq!(
        bvh.cast_shape(&point, -Vec3::Z, 10.0)
            .map(|h| (h.primitive, h.t)),
        Some((2, 1.0))
    );
    // Closest points: NaN or negative limits and non-finite points find nothing; +∞ has no limit.
    for max in [NAN, -1.0, -INF, -f32::MIN_POSITIVE] {
        assert!(bvh.closest_point(above, max).is_none(), "{max}");
    }
    for bad in NON_FINITE {
        assert!(bvh.closest_point(Vec3::new(0.5, bad, 0.5), INF).is_none());
        assert!(!bvh.contains_point(Vec3::new(0.5, bad, 0.5)));
    }
    let hit = bvh.closest_point(Vec3::new(0.8, 0.8, 1e30), INF).unwrap();
    assert_eq!((hit.primitive, hit.point), (0, Vec3::new(0.8, 0.8, 0.0)));
    // Zero limit: only a point on the surface.
    assert_eq!(
        bvh.closest_point(Vec3::new(0.8, 0.8, 0.0), 0.0)
            .map(|h| h.distance),
        Some(0.0)
    );
    assert!(bvh.closest_point(Vec3::new(0.8, 0.8, 1e-3), 0.0).is_none());
}

#[test]
fn collision_refuses_bad_transforms_and_finds_no_phantom_contacts() {
    let m = quad_and_roof();
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let mut q = PairQuery::new();
    let mut out = vec![];
    let zero = Affine3A::from_scale(Vec3::ZERO);
    let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    let nan = Affine3A::from_translation(Vec3::new(NAN, 0.0, 0.0));
    let inf = Affine3A::from_scale(Vec3::splat(INF));
    let id = Affine3A::IDENTITY;
    for bad in [zero, flat, nan, inf] {
        let a = Placed::new(&bvh, bad);
        let b = Placed::new(&bvh, id);
        assert!(
            matches!(q.meshes(a, b, &mut out), Err(Error::InvalidTransform(_))),
            "{bad:?}"
        );
        assert!(
            matches!(q.itself(a, &mut out), Err(Error::InvalidTransform(_))),
            "{bad:?}"
        );
    }
    for bad in [nan, inf] {
        let (a, b) = (Placed::new(&bvh, id), Placed::new(&bvh, bad));
        assert!(
            matches!(q.meshes(a, b, &mut out), Err(Error::InvalidTransform(_))),
            "{bad:?}"
        );
    }
    // `b` squashed to a point far away: finite, so a legal placement, and it touches nothing.
    let far_point =
        Affine3A::from_scale_rotation_translation(Vec3::ZERO, Quat::IDENTITY, Vec3::splat(10.0));
    q.meshes(
        Placed::new(&bvh, id),
        Placed::new(&bvh, far_point),
        &mut out,
    )
    .unwrap();
    assert!(out.is_empty(), "{out:?}");
    // 1e30 apart: no contacts.
    let far = Affine3A::from_translation(Vec3::splat(1e30));
    q.meshes(Placed::new(&bvh, id), Placed::new(&bvh, far), &mut out)
        .unwrap();
    assert!(out.is_empty(), "{out:?}");
}

#[test]
fn grid_options_and_rebuilds_reject_bad_values() {
    for lambda in [NAN, INF, 0.0, -1.0] {
        let o = GridOptions {
            lambda,
            ..Default::default()
        };
        assert!(
            matches!(UniformGrid::new(o), Err(Error::InvalidOption(_))),
            "{lambda}"
        );
    }
    let o = GridOptions {
        macrocell: 0,
        ..Default::default()
    };
    assert!(matches!(UniformGrid::new(o), Err(Error::InvalidOption(_))));
    // A tiny λ on a huge mesh still gives at least one cell; a huge λ is capped by memory, not a panic.
    let m = quad_and_roof();
    for lambda in [f32::MIN_POSITIVE, DENORMAL, 1e-30, 1e6] {
        let o = GridOptions {
            lambda,
            ..Default::default()
        };
        let g = UniformGrid::build(&m, &o).unwrap();
        let ray = Ray::new(Vec3::new(0.1, 0.1, 2.0), -Vec3::Z);
        assert_eq!(
            g.closest_hit(&ray).map(|h| (h.primitive, h.t)),
            Some((2, 1.0)),
            "{lambda}"
        );
    }
}

/// A GLB file from its JSON and binary chunks (each padded to 4 bytes).
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |b: &[u8], with: u8| {
        let mut v = b.to_vec();
        v.resize(b.len().div_ceil(4) * 4, with);
        v
    };
    let (json, bin) = (pad(json, b' '), pad(bin, 0));
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = b"glTF".to_vec();
    for word in [2, total as u32, json.len() as u32, 0x4E4F_534A] {
        out.extend(word.to_le_bytes());
    }
    out.extend(&json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(0x004E_4942u32.to_le_bytes());
    out.extend(&bin);
    out
}

/// A loaded file must be usable without panics: its clips sampled, its skin applied, its mesh built.
fn use_loaded(meshes: Vec<kinetrace::anim::GltfMesh>) {
    for g in meshes {
        MeshBvh::build(&g.mesh, &BuildOptions::default()).unwrap();
        let Some(c) = g.character else { continue };
        let mut pose = c.skeleton.rest_pose();
        let mut mats = vec![glam::Mat4::IDENTITY; pose.len()];
        let mut out = vec![Vec3::ZERO; g.mesh.positions().len()];
        for clip in &c.clips {
            for t in [0.0, 0.5 * clip.duration, clip.duration, -1.0, NAN, INF] {
                clip.sample(t, &mut pose);
                c.skeleton.skin_matrices(&pose, &mut mats);
                // An error (a joint index past the skeleton) is an answer too; a panic is not.
                let _ = kinetrace::anim::skin_positions(
                    g.mesh.positions(),
                    &c.weights,
                    &mats,
                    &mut out,
                );
            }
        }
    }
}

#[test]
fn gltf_garbage_and_corruptions_are_errors_or_usable_files() {
    use kinetrace::anim::{character_to_glb, humanoid, load_gltf, load_gltf_slice};
    assert!(matches!(
        load_gltf(std::path::Path::new("/nonexistent/dir/file.gltf")),
        Err(Error::Io { .. })
    ));
    for bytes in [
        &b""[..],
        b"{",
        b"glTF",
        b"glTF\x02\0\0\0\xff\xff\xff\xff",
        &[0; 12],
        b"{}",
    ] {
        let r = load_gltf_slice(bytes, None);
        assert!(
            matches!(r, Err(Error::Gltf(_))) || r.as_ref().is_ok_and(Vec::is_empty),
            "{bytes:?}: {r:?}"
        );
    }
    // Our own skinned, animated character as GLB, split into its chunks.
    let file = character_to_glb(&humanoid(300)).unwrap();
    let json_len = u32::from_le_bytes(file[12..16].try_into().unwrap()) as usize;
    let json = std::str::from_utf8(&file[20..20 + json_len])
        .unwrap()
        .to_string();
    let bin = &file[20 + json_len + 8..];
    assert_eq!(glb(json.as_bytes(), bin), file, "the chunks reassemble");
    use_loaded(load_gltf_slice(&file, None).unwrap());
    let mut errors = 0;
    let mut check = |bytes: &[u8]| match load_gltf_slice(bytes, None) {
        Ok(meshes) => use_loaded(meshes),
        Err(e) => {
            assert!(!e.to_string().is_empty());
            errors += 1;
        }
    };
    // Every number of the JSON replaced by values that break it.
    let b = json.as_bytes();
    let starts: Vec<usize> = (1..b.len())
        .filter(|&i| b[i].is_ascii_digit() && b":[,".contains(&b[i - 1]))
        .collect();
    assert!(starts.len() > 50, "{} numbers", starts.len());
    for &s in &starts {
        let end = s + b[s..]
            .iter()
            .take_while(|c| c.is_ascii_digit() || **c == b'.')
            .count();
        for with in ["4294967295", "1e30", "-1", "0", "3"] {
            check(&glb(
                format!("{}{with}{}", &json[..s], &json[end..]).as_bytes(),
                bin,
            ));
        }
    }
    // Binary data overwritten word by word: NaN, infinity, all ones (indices and joints out of range).
    for at in (0..bin.len() / 4).step_by(7) {
        for word in [0x7FC0_0000u32, 0x7F80_0000, u32::MAX] {
            let mut corrupt = bin.to_vec();
            corrupt[4 * at..4 * at + 4].copy_from_slice(&word.to_le_bytes());
            check(&glb(json.as_bytes(), &corrupt));
        }
    }
    // Truncated anywhere.
    for cut in (0..file.len()).step_by(61) {
        check(&file[..cut]);
    }
    assert!(errors > 100, "{errors} errors");
}

/// A plugin world with the quad-and-roof mesh at the origin and a second copy at `far`.
fn ecs_world(config: TraceConfig) -> (World, Schedule, Entity) {
    let (mut world, schedule) = app_with(config);
    let e = world.spawn(TraceMesh(quad_and_roof())).id();
    (world, schedule, e)
}

/// Queues ray `i` of `rays` as a closest-hit request and its segment `origin → origin + dir` as a
/// shadow request, both with tag `i`.
fn queue_rays(q: &mut RayQueue, rays: &[Ray]) {
    for (i, r) in rays.iter().enumerate() {
        q.cast(i as u64, *r, QueryFilter::default());
        let (from, to) = (r.origin, r.origin + r.dir());
        q.shadow(i as u64, from, to, QueryFilter::default());
    }
}

fn frame(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

#[test]
fn ecs_immediate_and_batched_queries_with_bad_values_find_nothing() {
    let (mut world, mut schedule, e) = ecs_world(TraceConfig::default());
    frame(&mut world, &mut schedule);
    let all = QueryFilter::default();
    let good = Ray::new(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z);
    let bad_rays = invalid_rays();
    {
        let tw = world.resource::<TraceWorld>();
        assert_eq!(
            tw.cast_ray(&good, 10.0, &all)
                .map(|h| (h.entity, h.distance)),
            Some((e, 2.0))
        );
        for r in &bad_rays {
            assert!(tw.cast_ray(r, 10.0, &all).is_none(), "{r:?}");
            let mut hits = vec![];
            tw.ray_hits(r, &all, &mut hits);
            assert!(hits.is_empty(), "{r:?}");
        }
        for max_t in [NAN, -1.0, -INF, 0.0] {
            assert!(tw.cast_ray(&good, max_t, &all).is_none(), "{max_t}");
        }
        let mut packet = vec![None; bad_rays.len()];
        tw.cast_packet(&bad_rays, 10.0, &all, &mut packet);
        assert!(packet.iter().all(Option::is_none));
        for bad in NON_FINITE {
            let from = Vec3::new(0.3, 0.3, 2.0);
            let to = Vec3::new(0.3, 0.3, -2.0);
            assert!(!tw.occluded(Vec3::new(0.3, bad, 2.0), to, &all), "{bad}");
            assert!(!tw.occluded(from, Vec3::splat(bad), &all), "{bad}");
            let mut out = [true; 2];
            tw.occluded_packet(&[(from, Vec3::splat(bad)), (from, to)], &all, &mut out);
            assert_eq!(out, [false, true], "{bad}");
            let mut out = [true; 2];
            tw.occluded_interleaved(&[(from, Vec3::splat(bad)), (from, to)], &all, &mut out);
            assert_eq!(out, [false, true], "{bad}");
            let shape = Shape::sphere(Vec3::new(0.5, 0.5, 0.5), bad);
            assert!(tw.cast_shape(&shape, -Vec3::Z, 10.0, &all).is_none());
            assert!(
                tw.cast_shape(
                    &Shape::sphere(Vec3::new(0.5, 0.5, 0.5), 0.1),
                    Vec3::splat(bad),
                    10.0,
                    &all
                )
                .is_none()
            );
            assert!(tw.closest_point(Vec3::splat(bad), INF, &all).is_none());
            let mut over = vec![];
            tw.overlaps(&shape, &all, &mut over);
            assert!(over.is_empty());
            let mut inside = vec![];
            tw.containing(Vec3::splat(bad), &all, &mut inside);
            assert!(inside.is_empty());
            assert_eq!(tw.contains_point(e, Vec3::splat(bad)), Some(false));
        }
        assert!(
            !tw.occluded(Vec3::ONE, Vec3::ONE, &all),
            "a zero-length segment"
        );
        for max in [NAN, -1.0] {
            assert!(tw.closest_point(Vec3::ONE, max, &all).is_none());
        }
        for max_t in [NAN, -1.0] {
            let s = Shape::sphere(Vec3::new(0.5, 0.5, 0.5), 0.1);
            assert!(tw.cast_shape(&s, -Vec3::Z, max_t, &all).is_none());
        }
    }
    // Batched: the same bad requests through the queues answer None / false / empty, and the good ones
    // beside them are answered.
    {
        let mut q = world.resource_mut::<RayQueue>();
        queue_rays(&mut q, &bad_rays);
        for (i, r) in bad_rays.iter().enumerate() {
            // Secondary kinds go through the secondary planner's sorting and packets.
            let (tag, all) = (3000 + i as u64, QueryFilter::default());
            q.cast_kind(tag, *r, RequestKind::Reflection, all.clone());
            let light = RequestKind::Shadow { light: 0 };
            q.shadow_kind(tag, r.origin, r.origin + r.dir(), light, all);
        }
        q.cast(1000, good, QueryFilter::default());
        q.shadow(
            1000,
            Vec3::new(0.3, 0.3, 2.0),
            Vec3::new(0.3, 0.3, -2.0),
            QueryFilter::default(),
        );
        q.cast_packet(2000, &bad_rays, QueryFilter::default());
        q.shadow_packet(
            2000,
            &[Vec3::splat(NAN), Vec3::new(0.3, 0.3, 2.0)],
            Vec3::new(0.3, 0.3, -2.0),
            QueryFilter::default(),
        );
    }
    {
        let mut q = world.resource_mut::<ShapeQueue>();
        for (i, bad) in NON_FINITE.into_iter().enumerate() {
            let i = i as u64;
            q.cast(
                i,
                Shape::sphere(Vec3::splat(0.5), bad),
                -Vec3::Z,
                10.0,
                QueryFilter::default(),
            );
            q.cast(
                10 + i,
                Shape::sphere(Vec3::splat(0.5), 0.1),
                -Vec3::Z,
                -bad.abs(),
                QueryFilter::default(),
            );
            q.closest_point(i, Vec3::splat(bad), INF, QueryFilter::default());
            q.closest_point(10 + i, Vec3::ONE, -bad.abs(), QueryFilter::default());
            q.overlap(
                i,
                Shape::capsule(Vec3::ZERO, Vec3::splat(bad), 1.0),
                QueryFilter::default(),
            );
            q.contains(i, Vec3::splat(bad), QueryFilter::default());
        }
        q.closest_point(1000, Vec3::new(0.8, 0.8, 0.5), INF, QueryFilter::default());
    }
    frame(&mut world, &mut schedule);
    let r = world.resource::<RayResults>();
    for (tag, hit) in &r.hits {
        assert_eq!(hit.is_some(), *tag == 1000, "{tag}: {hit:?}");
    }
    for (tag, hit) in &r.shadows {
        assert_eq!(*hit, *tag == 1000 || *tag == 2001, "{tag}");
    }
    assert_eq!(r.hits.len(), 3 * bad_rays.len() + 1);
    assert_eq!(r.shadows.len(), 2 * bad_rays.len() + 3);
    let s = world.resource::<ShapeResults>();
    assert_eq!(s.casts.len(), 6);
    assert!(s.casts.iter().all(|(_, h)| h.is_none()), "{:?}", s.casts);
    for (tag, p) in &s.closest {
        assert_eq!(
            p.map(|p| (p.entity, p.distance)),
            (*tag == 1000).then_some((e, 0.5)),
            "{tag}"
        );
    }
    assert!(s.overlaps.iter().all(|(_, o)| o.is_empty()));
    assert!(s.contains.iter().all(|(_, c)| c.is_empty()));
}

#[test]
fn ecs_entities_with_bad_data_get_trace_errors_and_are_never_hit() {
    let (mut world, mut schedule, good) = ecs_world(TraceConfig::default());
    let zero = world
        .spawn((
            TraceMesh(quad_and_roof()),
            TraceTransform(Affine3A::from_scale(Vec3::ZERO)),
        ))
        .id();
    let flat = world
        .spawn((
            TraceMesh(quad_and_roof()),
            TraceTransform(Affine3A::from_scale(Vec3::new(1.0, 1.0, 0.0))),
        ))
        .id();
    let nan = world
        .spawn((
            TraceMesh(quad_and_roof()),
            TraceTransform(Affine3A::from_translation(Vec3::splat(NAN))),
        ))
        .id();
    let past_range = world
        .spawn((
            TraceMesh(quad_and_roof()),
            TraceTransform(Affine3A::from_scale(Vec3::splat(1e38))),
        ))
        .id();
    let mut bad_positions = quad_and_roof().positions().to_vec();
    bad_positions[0].x = NAN;
    let nan_vertex = world
        .spawn((TraceMesh(quad_and_roof()), VertexPositions(bad_positions)))
        .id();
    let wrong_count = world
        .spawn((
            TraceMesh(quad_and_roof()),
            VertexPositions(vec![Vec3::ZERO; 2]),
        ))
        .id();
    let empty = world
        .spawn(TraceMesh(
            Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap(),
        ))
        .id();
    let huge = world
        .spawn((
            TraceMesh(quad_and_roof()),
            TraceTransform(Affine3A::from_translation(Vec3::new(0.0, 0.0, -1e30))),
        ))
        .id();
    for _ in 0..3 {
        frame(&mut world, &mut schedule);
    }
    for e in [zero, flat, nan, past_range, nan_vertex, wrong_count] {
        assert!(
            world.get::<TraceError>(e).is_some(),
            "{e} has no TraceError"
        );
    }
    for e in [good, empty, huge] {
        assert!(
            world.get::<TraceError>(e).is_none(),
            "{e}: {:?}",
            world.get::<TraceError>(e)
        );
    }
    let tw = world.resource::<TraceWorld>();
    let all = QueryFilter::default();
    // Straight down through everything: the good quad's roof at t = 1, the far copy 1e30 below.
    let ray = Ray::new(Vec3::new(0.1, 0.2, 2.0), -Vec3::Z);
    assert_eq!(
        tw.cast_ray(&ray, INF, &all).map(|h| (h.entity, h.distance)),
        Some((good, 1.0))
    );
    let mut hits = vec![];
    tw.ray_hits(&ray, &all, &mut hits);
    let hit_entities: Vec<Entity> = hits.iter().map(|h| h.entity).collect();
    assert_eq!(hit_entities, [good, good, huge, huge]);
    assert_eq!(hits[2].distance, 1e30);
    let p = tw
        .closest_point(Vec3::new(0.1, 0.1, 0.5), INF, &all)
        .unwrap();
    assert_eq!((p.entity, p.distance), (good, 0.5));
    // Fixing the data clears the error: the zero-scale entity gets a real scale.
    world.get_mut::<TraceTransform>(zero).unwrap().0 =
        Affine3A::from_translation(Vec3::new(5.0, 0.0, 0.0));
    world.entity_mut(zero).remove::<TraceError>();
    frame(&mut world, &mut schedule);
    let tw = world.resource::<TraceWorld>();
    let r = Ray::new(Vec3::new(5.3, 0.3, 2.0), -Vec3::Z);
    assert_eq!(tw.cast_ray(&r, INF, &all).map(|h| h.entity), Some(zero));
}

#[test]
fn trace_config_values_out_of_range_do_not_panic() {
    // Grid options out of their range: every mesh kept as a grid fails with an InvalidOption TraceError
    // (documented at `TraceConfig::grid`) and is not hit.
    for lambda in [NAN, -1.0, 0.0, INF] {
        let config = TraceConfig {
            structure: Structure::Grid,
            grid: GridOptions {
                lambda,
                ..Default::default()
            },
            profile_refresh: NAN,
            ..Default::default()
        };
        let (mut world, mut schedule, e) = ecs_world(config);
        for _ in 0..2 {
            frame(&mut world, &mut schedule);
        }
        assert!(
            matches!(
                world.get::<TraceError>(e),
                Some(TraceError(Error::InvalidOption(_)))
            ),
            "{lambda}: {:?}",
            world.get::<TraceError>(e)
        );
        let tw = world.resource::<TraceWorld>();
        let ray = Ray::new(Vec3::new(0.3, 0.3, 2.0), -Vec3::Z);
        assert!(
            tw.cast_ray(&ray, INF, &QueryFilter::default()).is_none(),
            "{lambda}"
        );
    }
    for threshold in [NAN, -1.0, INF] {
        let config = TraceConfig {
            policy: RebuildPolicy::Lauterbach { threshold },
            profile_refresh: -1.0,
            ..Default::default()
        };
        let (mut world, mut schedule, e) = ecs_world(config);
        let moved: Vec<Vec3> = quad_and_roof()
            .positions()
            .iter()
            .map(|p| *p * 2.0)
            .collect();
        world.entity_mut(e).insert(VertexPositions(moved));
        for _ in 0..2 {
            frame(&mut world, &mut schedule);
        }
        let tw = world.resource::<TraceWorld>();
        let ray = Ray::new(Vec3::new(1.5, 1.5, 2.0), -Vec3::Z);
        let hit = tw.cast_ray(&ray, INF, &QueryFilter::default());
        assert_eq!(
            hit.map(|h| (h.entity, h.distance)),
            Some((e, 2.0)),
            "{threshold}"
        );
    }
}

#[test]
fn animation_players_with_nan_or_infinite_times_and_speeds_keep_playing() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let asset = std::sync::Arc::new(kinetrace::anim::humanoid(300));
    let players: Vec<Entity> = [
        (0, NAN, 1.0),
        (0, 0.0, INF),
        (0, 0.0, NAN),
        (0, -INF, 1.0),
        (99, 0.0, 1.0),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, (clip, time, speed))| {
        let (mesh, skin, mut player) = AnimationPlayer::bundle(&asset, clip, time);
        player.speed = speed;
        let at = Affine3A::from_translation(Vec3::new(3.0 * i as f32, 0.0, 0.0));
        world.spawn((mesh, skin, player, TraceTransform(at))).id()
    })
    .collect();
    for _ in 0..3 {
        frame(&mut world, &mut schedule);
    }
    for &e in &players {
        assert!(
            world.get::<TraceError>(e).is_none(),
            "{e}: {:?}",
            world.get::<TraceError>(e)
        );
    }
    // Rays through a few triangles' centres of every character equal brute force over the skinned
    // triangles.
    let all = QueryFilter::default();
    let mut hits = 0;
    let indices = asset.mesh.indices();
    for (i, &e) in players.iter().enumerate() {
        let p = world.get::<VertexPositions>(e).unwrap().0.clone();
        for k in [0, indices.len() / 9, indices.len() / 3 * 2] {
            let tri = &indices[3 * (k / 3)..3 * (k / 3) + 3];
            let centre = tri.iter().map(|&v| p[v as usize]).sum::<Vec3>() / 3.0;
            let centre = centre + Vec3::X * (3.0 * i as f32);
            // Slanted, so that no triangle of the limbs' vertical sides lies edge-on along it.
            let dir = Vec3::new(0.31, -1.0, 0.17);
            let ray = Ray::new(centre - dir * 5.0, dir);
            let expect = common::ecs::brute(&mut world, &ray, &all);
            let got = world.resource::<TraceWorld>().cast_ray(&ray, INF, &all);
            // The entity and distance: a ray through a shared edge may name either triangle.
            assert_eq!(got.map(|h| h.entity), expect.map(|(e, ..)| e), "{i}");
            if let (Some(g), Some((.., t))) = (got, expect) {
                assert!(
                    (g.distance - t).abs() <= 1e-6 * t,
                    "{i}: {} vs {t}",
                    g.distance
                );
            }
            hits += got.is_some() as usize;
        }
    }
    assert!(hits >= players.len(), "{hits} hits");
}

#[cfg(feature = "gpu")]
#[test]
fn gpu_batches_answer_bad_and_awkward_rays_as_the_cpu_does() {
    if gpu_or_skip().is_none() {
        return;
    }
    let rays: Vec<Ray> = invalid_rays().into_iter().chain(awkward_rays()).collect();
    let run = |mode| {
        let (mut world, mut schedule, _) = ecs_world(TraceConfig {
            mode,
            ..Default::default()
        });
        frame(&mut world, &mut schedule);
        queue_rays(&mut world.resource_mut::<RayQueue>(), &rays);
        frame(&mut world, &mut schedule);
        world.resource::<RayResults>().clone()
    };
    let (cpu, gpu) = (run(TraceMode::Cpu), run(TraceMode::GpuRequired));
    assert_eq!(cpu.hits.len(), rays.len());
    let mut hits = 0;
    for ((tc, hc), (tg, hg)) in cpu.hits.iter().zip(&gpu.hits) {
        assert_eq!(tc, tg);
        let ray = rays[*tc as usize];
        match (hc, hg) {
            (Some(c), Some(g)) => {
                hits += 1;
                let tol = 1e-5 * c.distance.abs().max(f32::MIN_POSITIVE);
                assert!(
                    (c.distance - g.distance).abs() <= tol,
                    "{ray:?}: {c:?} vs {g:?}"
                );
            }
            (None, None) => {}
            _ => panic!("{ray:?}: CPU {hc:?}, GPU {hg:?}"),
        }
    }
    assert!(hits > 5, "{hits} hits");
    assert_eq!(cpu.shadows, gpu.shadows);
}
