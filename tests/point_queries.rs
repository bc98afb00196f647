//! Closest points, containment and shape overlaps against oracles that share no code with the crate:
//!
//! - closest points: a brute force over all triangles that projects onto the plane, solves for barycentrics
//!   and otherwise takes the nearest of the three edges (not the crate's Voronoi-region walk), and parry3d's
//!   `TriMesh::project_point`;
//! - containment: the analytic answer for an axis-aligned box mesh on a grid of points lying exactly on its
//!   faces, edges and corners, and a majority of three random-direction ray-parity counts (f64
//!   Möller–Trumbore) for a closed, deformed mesh;
//! - overlaps: the brute-force distance for spheres, parry3d's `intersection_test` for capsules and boxes,
//!   away from the touching boundary where a tolerance-based test may decide either way.

mod common;

use common::{icosphere, map_mesh, parity_inside, rand_vec, rng, soup};
use glam::{DVec3, Quat, Vec3};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::queries::{Feature, Shape};
use kinetrace::{Mesh, MeshBvh};
use rand::Rng;

// ---------------------------------------------------------------------------------------------------
// Oracles
// ---------------------------------------------------------------------------------------------------

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

/// Whether the crate's rule makes this triangle absent (exactly zero `f32` cross product).
fn absent(t: [Vec3; 3]) -> bool {
    (t[1] - t[0]).cross(t[2] - t[0]) == Vec3::ZERO
}

/// Distance from `p` to segment `a b`, f64.
fn point_segment(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let l = ab.length_squared();
    let k = if l > 0.0 {
        ((p - a).dot(ab) / l).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * k)).length()
}

/// Distance from `p` to the closed triangle: the plane distance when the projection falls inside (solved by
/// Cramer's rule on the Gram matrix), else the nearest edge.
fn point_triangle(p: DVec3, t: [DVec3; 3]) -> f64 {
    point_triangle_bounded(p, t).0
}

/// [`point_triangle`] with a bound on its rounding error: the Gram solve loses `κ = g11·g22 / det` ulp of
/// the coordinates' magnitude (large for needles), the edge distances a few. The solve also decides face
/// or edges, so a point whose projection lies within its error of an edge may be answered from the edges
/// when it is on the face: the edge answer carries the same `κ` bound whenever the solve ran.
fn point_triangle_bounded(p: DVec3, [a, b, c]: [DVec3; 3]) -> (f64, f64) {
    let mag = [a, b, c, p]
        .iter()
        .map(|v| v.abs().max_element())
        .fold(0.0, f64::max);
    let (e1, e2, w) = (b - a, c - a, p - a);
    let (g11, g12, g22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = g11 * g22 - g12 * g12;
    let mut err = mag * f64::EPSILON * 8.0;
    if det > 0.0 {
        let (r1, r2) = (w.dot(e1), w.dot(e2));
        let u = (r1 * g22 - r2 * g12) / det;
        let v = (g11 * r2 - g12 * r1) / det;
        err *= g11 * g22 / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
            return ((w - e1 * u - e2 * v).length(), err);
        }
    }
    let edges = point_segment(p, a, b)
        .min(point_segment(p, b, c))
        .min(point_segment(p, c, a));
    (edges, err)
}

/// The distance from `p` to the mesh's present triangles.
fn brute_distance(m: &Mesh, p: Vec3) -> Option<f64> {
    brute_distance_bounded(m, p).map(|(dist, _)| dist)
}

/// The distance from `p` to the mesh's present triangles, with a bound on its error: the largest bound of
/// the triangles that could be the nearest given their own bounds.
fn brute_distance_bounded(m: &Mesh, p: Vec3) -> Option<(f64, f64)> {
    let all: Vec<(f64, f64)> = (0..m.triangle_count())
        .map(|i| m.triangle(i))
        .filter(|t| !absent(*t))
        .map(|t| point_triangle_bounded(d(p), t.map(d)))
        .collect();
    let best = all.iter().map(|&(x, e)| x + e).min_by(f64::total_cmp)?;
    let dist = all.iter().map(|&(x, _)| x).min_by(f64::total_cmp)?;
    let err = all
        .iter()
        .filter(|&&(x, e)| x - e <= best)
        .map(|&(_, e)| e)
        .fold(0.0, f64::max);
    Some((dist, err))
}

fn parry_mesh(m: &Mesh) -> parry3d::shape::TriMesh {
    use parry3d::math::Vector;
    let v = m
        .positions()
        .iter()
        .map(|p| Vector::new(p.x, p.y, p.z))
        .collect();
    let idx = (0..m.triangle_count())
        .filter(|&i| !absent(m.triangle(i)))
        .map(|i| {
            [
                m.indices()[3 * i],
                m.indices()[3 * i + 1],
                m.indices()[3 * i + 2],
            ]
        })
        .collect();
    parry3d::shape::TriMesh::new(v, idx).expect("a valid parry mesh")
}

// ---------------------------------------------------------------------------------------------------
// Scenes
// ---------------------------------------------------------------------------------------------------

/// Random triangles with needles (one corner pulled within 1e-4 of another edge) and exactly degenerate
/// ones (repeated and collinear corners) mixed in.
fn needles_and_degenerates(seed: u64, n: usize) -> Mesh {
    let mut r = rng(seed);
    let mut pos = Vec::new();
    for i in 0..n {
        let a = rand_vec(&mut r, -1.0, 1.0);
        let b = a + rand_vec(&mut r, -0.3, 0.3);
        let c = match i % 4 {
            0 => a.lerp(b, r.random_range(0.0..1.0)) + rand_vec(&mut r, -1e-4, 1e-4),
            1 => a,
            2 => a + (b - a) * 2.0,
            _ => a + rand_vec(&mut r, -0.3, 0.3),
        };
        pos.extend([a, b, c]);
    }
    Mesh::new(pos, (0..3 * n as u32).collect::<Vec<_>>()).unwrap()
}

fn scenes() -> Vec<(&'static str, Mesh)> {
    vec![
        ("soup", soup(3, 400)),
        ("icosphere", icosphere(3)),
        ("torus", kinetrace::scenes::bumpy_torus(3000)),
        ("needles", needles_and_degenerates(5, 300)),
        (
            "offset 1e5",
            map_mesh(&icosphere(2), |p| p + Vec3::splat(1e5)),
        ),
        ("tiny 1e-4", map_mesh(&soup(7, 200), |p| p * 1e-4)),
        ("huge 1e4", map_mesh(&icosphere(2), |p| p * 1e4)),
    ]
}

/// Query points around a mesh: uniform in its box grown by half its size, plus points on its vertices and
/// edge midpoints.
fn points(m: &Mesh, seed: u64, n: usize) -> Vec<Vec3> {
    let b = m
        .positions()
        .iter()
        .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    let (c, h) = ((b.0 + b.1) * 0.5, (b.1 - b.0) * 0.75 + Vec3::splat(1e-6));
    let mut r = rng(seed);
    let mut out: Vec<Vec3> = (0..n)
        .map(|_| {
            c + h * Vec3::new(
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
            )
        })
        .collect();
    out.extend(m.positions().iter().take(50));
    out.extend((0..m.triangle_count().min(50)).map(|i| {
        let t = m.triangle(i);
        (t[0] + t[1]) * 0.5
    }));
    out
}

fn scale(m: &Mesh) -> f64 {
    m.positions()
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0.0f32, f32::max) as f64
}

// ---------------------------------------------------------------------------------------------------
// Closest points
// ---------------------------------------------------------------------------------------------------

/// Checks one answer against the brute force: same distance up to the f32 rounding of the reported value
/// (half an ulp of the distance), the crate's f64 rounding (a few hundred ulp of the coordinates' magnitude
/// at most) and the oracle's own bound (see [`point_triangle_bounded`]); the point lies on the named triangle at the reported barycentrics, at the
/// reported distance; the feature agrees with the barycentrics.
fn check_closest(m: &Mesh, bvh: &MeshBvh, p: Vec3, what: &str) {
    let got = bvh.closest_point(p, f32::INFINITY);
    let want = brute_distance_bounded(m, p);
    let (Some(h), Some((w, oracle_err))) = (got, want) else {
        assert_eq!(got.is_some(), want.is_some(), "{what}: {p:?}");
        return;
    };
    let coord = scale(m).max(d(p).abs().max_element());
    let tol = w * f32::EPSILON as f64 + coord * 1e-13 + oracle_err;
    assert!(
        (h.distance as f64 - w).abs() <= tol,
        "{what}: {p:?} got {} want {w}",
        h.distance
    );
    let t = m.triangle(h.primitive as usize).map(d);
    assert!(
        !absent(m.triangle(h.primitive as usize)),
        "{what}: absent triangle reported"
    );
    let on = t[0] + (t[1] - t[0]) * h.u as f64 + (t[2] - t[0]) * h.v as f64;
    // The point is rounded to f32 (half an ulp per coordinate) and the barycentrics too.
    let pt_tol = coord * 4.0 * f32::EPSILON as f64;
    assert!(
        (on - d(h.point)).length() <= pt_tol * 4.0,
        "{what}: barycentrics {on:?} vs {:?}",
        h.point
    );
    let (off, off_err) = point_triangle_bounded(d(h.point), t);
    assert!(off <= pt_tol + off_err, "{what}: point not on its triangle");
    assert!(
        ((d(h.point) - d(p)).length() - h.distance as f64).abs() <= pt_tol + tol,
        "{what}"
    );
    let (u, v) = (h.u, h.v);
    match h.feature {
        // Barycentrics are rounded to f32: a face point next to an edge may round onto it.
        Feature::Face => assert!(
            u >= 0.0 && v >= 0.0 && u + v <= 1.0 + 1e-6,
            "{what}: face at ({u}, {v})"
        ),
        Feature::Edge(0) => assert!(
            v == 0.0 && u > 0.0 && u < 1.0,
            "{what}: edge 0 at ({u}, {v})"
        ),
        Feature::Edge(1) => assert!(
            (u + v - 1.0).abs() < 1e-6 && u > 0.0 && v > 0.0,
            "{what}: edge 1"
        ),
        Feature::Edge(2) => assert!(
            u == 0.0 && v > 0.0 && v < 1.0,
            "{what}: edge 2 at ({u}, {v})"
        ),
        Feature::Vertex(k) => assert_eq!(
            [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)][k as usize],
            (u, v),
            "{what}"
        ),
        Feature::Edge(_) => panic!("{what}: no such edge"),
    }
}

/// Both walks: the wide tree's (four `f32` box distances at a time, the default) and the binary tree's.
#[test]
fn closest_points_equal_brute_force() {
    for (name, m) in scenes() {
        for builder in [Builder::SAH, Builder::LBVH] {
            for wide in [true, false] {
                let bvh = MeshBvh::build(&m, &BuildOptions::new(builder).wide(wide)).unwrap();
                assert_eq!(bvh.wide().is_some(), wide);
                for p in points(&m, 11, 300) {
                    let what = format!("{name} {} wide {wide}", builder.name());
                    check_closest(&m, &bvh, p, &what);
                }
            }
        }
    }
}

#[test]
fn closest_points_follow_refits() {
    let rest = kinetrace::scenes::bumpy_torus(4000);
    let mut bvh = MeshBvh::build(&rest, &BuildOptions::new(Builder::LBVH)).unwrap();
    for frame in 1..=4 {
        let s = frame as f32 * 0.4;
        let bent = map_mesh(&rest, |p| {
            p + Vec3::new(0.0, (p.x * 3.0 + s).sin() * 0.3 * s, p.y * p.x * s)
        });
        bvh.refit(bent.positions()).unwrap();
        for p in points(&bent, frame, 300) {
            check_closest(&bent, &bvh, p, &format!("frame {frame}"));
        }
    }
}

/// Points on and near a torus's axis are almost equidistant from its whole inner ring, so the walk opens
/// hundreds of leaves and filters their triangles four at a time with an `f32` bound before the exact test.
/// The answer must still be the nearest triangle: its distance as in [`check_closest`], and where the
/// oracle's nearest triangle beats every other by more than the oracles' error bounds, that very triangle
/// (elsewhere the nearest point is on an edge or corner that triangles share, or symmetric bumps tie).
#[test]
fn closest_points_near_a_torus_axis_pick_the_nearest_triangle() {
    let rest = kinetrace::scenes::bumpy_torus(3000);
    let twisted = map_mesh(&rest, |p| {
        let (s, c) = (0.4 * p.y).sin_cos();
        Vec3::new(p.x * c - p.z * s, p.y, p.x * s + p.z * c)
    });
    let mut r = rng(23);
    let mut decided = 0;
    for m in [rest, twisted] {
        let points: Vec<Vec3> = (0..200)
            .map(|i| {
                let off = rand_vec(&mut r, -1.0, 1.0) * [1e-3, 0.05, 0.15][i % 3];
                Vec3::new(0.0, r.random_range(-0.6..0.6), 0.0) + off
            })
            .collect();
        for wide in [true, false] {
            let bvh = MeshBvh::build(&m, &BuildOptions::default().wide(wide)).unwrap();
            for &p in &points {
                check_closest(&m, &bvh, p, &format!("axis wide {wide}"));
                let got = bvh.closest_point(p, f32::INFINITY).unwrap().primitive as usize;
                let mut by_distance: Vec<(f64, f64, usize)> = (0..m.triangle_count())
                    .filter(|&i| !absent(m.triangle(i)))
                    .map(|i| {
                        let (x, e) = point_triangle_bounded(d(p), m.triangle(i).map(d));
                        (x, e, i)
                    })
                    .collect();
                by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
                let [(x0, e0, i0), (x1, e1, _)] = [by_distance[0], by_distance[1]];
                if x1 - e1 > x0 + e0 {
                    assert_eq!(got, i0, "axis wide {wide}: {p:?}");
                    decided += 1;
                }
            }
        }
    }
    assert!(
        decided >= 100,
        "only {decided} of 800 answers have a clear nearest triangle"
    );
}

#[test]
fn max_distance_limits_the_answer() {
    let m = soup(21, 300);
    let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let mut r = rng(4);
    for p in points(&m, 9, 400) {
        let want = brute_distance(&m, p).unwrap();
        let limit = (want * r.random_range(0.5..1.5)) as f32;
        if (limit as f64 - want).abs() <= want * 1e-6 {
            continue; // at the limit itself the f32 rounding of `limit` decides
        }
        assert_eq!(
            bvh.closest_point(p, limit).is_some(),
            want <= limit as f64,
            "{p:?} {limit} {want}"
        );
    }
    assert!(bvh.closest_point(Vec3::NAN, 1.0).is_none());
    assert!(bvh.closest_point(Vec3::ZERO, -1.0).is_none());
    assert!(bvh.closest_point(Vec3::ZERO, f32::NAN).is_none());
    let empty = MeshBvh::build(
        &Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap(),
        &BuildOptions::default(),
    )
    .unwrap();
    assert!(empty.closest_point(Vec3::ZERO, f32::INFINITY).is_none());
}

/// A fan of `n` triangles around the shared corner `c` (corner 0 of each), on a wavy cone of radius `r`:
/// every third a needle (its far corners 1e-6 of `r` apart), every fifth exactly degenerate.
fn fan(c: Vec3, r: f32, n: usize) -> Mesh {
    let mut pos = Vec::new();
    for i in 0..n {
        let rim = |k: f32| {
            let a = k * std::f32::consts::TAU / n as f32;
            c + Vec3::new(a.cos(), a.sin(), 0.3 * (3.0 * a).sin()) * r
        };
        let (b, far) = (rim(i as f32), rim(i as f32 + 1.0));
        let far = match i % 15 {
            0 | 5 | 10 => c,
            3 | 6 | 9 | 12 => b + (far - b) * 1e-6,
            _ => far,
        };
        pos.extend([c, b, far]);
    }
    Mesh::new(pos, (0..3 * n as u32).collect::<Vec<_>>()).unwrap()
}

/// The pruning of both walks (the wide tree's `f32` box bounds, the binary tree's `f64` ones) on inputs
/// made to tie: fans of needles and degenerate triangles sharing one corner, at tiny and huge scales and a
/// 1e5 offset. A point on the shared corner is at distance 0 from every present triangle, so the answer is
/// the analytic one: the lowest present index, at that corner. Points on edges and just off the fan are
/// checked against the brute force, and every tree (SAH, LBVH; wide or not) must give the same answer
/// bit for bit, as all of them compute the same exact distances and break ties by index.
#[test]
fn closest_point_pruning_keeps_ties_and_needles() {
    for (offset, r) in [
        (0.0, 1.0),
        (0.0, 1e-4),
        (0.0, 1e4),
        (1e5, 1.0),
        (1e5, 100.0),
    ] {
        let c = Vec3::new(offset, -offset, 0.5 * offset);
        let m = fan(c, r, 60);
        let trees: Vec<MeshBvh> = [Builder::SAH, Builder::LBVH]
            .into_iter()
            .flat_map(|b| [true, false].map(|w| BuildOptions::new(b).wide(w)))
            .map(|o| MeshBvh::build(&m, &o).unwrap())
            .collect();
        let first = (0..m.triangle_count())
            .find(|&i| !absent(m.triangle(i)))
            .unwrap() as u32;
        let mut r_ = rng(17);
        let mut queries = vec![c];
        for i in 0..m.triangle_count() {
            let t = m.triangle(i);
            queries.extend([t[1], (t[0] + t[1]) * 0.5, (t[1] + t[2]) * 0.5]);
            queries.push(t[1] + rand_vec(&mut r_, -1.0, 1.0) * r * 1e-3);
        }
        queries.extend((0..100).map(|_| c + rand_vec(&mut r_, -2.0, 2.0) * r));
        for (k, &p) in queries.iter().enumerate() {
            let what = format!("offset {offset} r {r} query {k}");
            let hits: Vec<_> = trees
                .iter()
                .map(|t| t.closest_point(p, f32::INFINITY))
                .collect();
            assert!(hits.iter().all(|h| *h == hits[0]), "{what}: {hits:?}");
            check_closest(&m, &trees[0], p, &what);
        }
        let at_corner = trees[0].closest_point(c, f32::INFINITY).unwrap();
        assert_eq!(
            (at_corner.distance, at_corner.primitive, at_corner.feature),
            (0.0, first, Feature::Vertex(0)),
            "offset {offset} r {r}"
        );
    }
}

#[test]
fn closest_points_agree_with_parry() {
    use parry3d::math::{Pose, Vector};
    use parry3d::query::PointQuery;
    // parry projects in f32, which loses the needles (errors up to 2e-5) and the 1e5 offset; the brute force
    // above checks those.
    for (name, m) in scenes()
        .into_iter()
        .filter(|(n, _)| !n.starts_with("offset") && *n != "needles")
    {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let pm = parry_mesh(&m);
        for p in points(&m, 3, 200) {
            let ours = bvh.closest_point(p, f32::INFINITY).unwrap();
            let proj = pm.project_point(&Pose::IDENTITY, Vector::new(p.x, p.y, p.z), false);
            let theirs = (Vec3::from_array(proj.point.to_array()) - p).length();
            // parry works in f32 throughout: allow its rounding (a few ulp of the coordinates).
            let tol = scale(&m).max(p.abs().max_element() as f64) * 1e-5;
            assert!(
                (ours.distance as f64 - theirs as f64).abs() <= tol,
                "{name}: {p:?} ours {} parry {theirs}",
                ours.distance
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------------
// Containment
// ---------------------------------------------------------------------------------------------------

/// The surface of the box `[0, n]³` split into unit squares (two triangles each), outward-facing, integer
/// corners.
fn grid_box(n: i32) -> Mesh {
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    for axis in 0..3 {
        for (side, flip) in [(0, true), (n, false)] {
            for i in 0..n {
                for j in 0..n {
                    let corner = |a: i32, b: i32| {
                        let mut q = [0.0f32; 3];
                        q[axis] = side as f32;
                        q[(axis + 1) % 3] = a as f32;
                        q[(axis + 2) % 3] = b as f32;
                        Vec3::from_array(q)
                    };
                    let base = pos.len() as u32;
                    pos.extend([
                        corner(i, j),
                        corner(i + 1, j),
                        corner(i + 1, j + 1),
                        corner(i, j + 1),
                    ]);
                    let quad = if flip {
                        [0, 2, 1, 0, 3, 2]
                    } else {
                        [0, 1, 2, 0, 2, 3]
                    };
                    idx.extend(quad.map(|k| base + k));
                }
            }
        }
    }
    Mesh::new(pos, idx).unwrap()
}

#[test]
fn containment_is_exact_on_faces_edges_and_corners() {
    let n = 3;
    for (what, m) in [
        ("outward", grid_box(n)),
        ("inward", {
            let b = grid_box(n);
            let idx: Vec<u32> = b
                .indices()
                .chunks(3)
                .flat_map(|t| [t[0], t[2], t[1]])
                .collect();
            Mesh::new(b.positions().to_vec(), idx).unwrap()
        }),
    ] {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        // Every coordinate on a half-integer grid: rays along +x run exactly through shared edges and
        // corners of the surface's triangles, and many points lie on the surface itself.
        let steps: Vec<f32> = (-2..=2 * n + 2).map(|k| k as f32 * 0.5).collect();
        let mut checked = 0;
        for &x in &steps {
            for &y in &steps {
                for &z in &steps {
                    let p = Vec3::new(x, y, z);
                    let want = p.min_element() >= 0.0 && p.max_element() <= n as f32;
                    assert_eq!(bvh.contains_point(p), want, "{what}: {p:?}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000);
    }
}

#[test]
fn containment_equals_ray_parity_on_a_closed_deformed_mesh() {
    // A closed sphere, twisted and squashed like a bending limb, then refitted.
    let rest = icosphere(3);
    let mut bvh = MeshBvh::build(&rest, &BuildOptions::new(Builder::LBVH)).unwrap();
    let bent = map_mesh(&rest, |p| {
        let a = p.y * 1.5;
        Vec3::new(
            p.x * a.cos() - p.z * a.sin(),
            p.y * 1.8,
            (p.x * a.sin() + p.z * a.cos()) * 0.6,
        ) + Vec3::X * p.y * p.y
    });
    bvh.refit(bent.positions()).unwrap();
    let mut r = rng(77);
    let dirs = [0, 1, 2].map(|_| common::rand_dir(&mut r).as_dvec3());
    let tris: Vec<[Vec3; 3]> = (0..bent.triangle_count())
        .map(|i| bent.triangle(i))
        .collect();
    let mut inside = 0;
    let count = 20_000;
    // Random points only: a point on the surface is inside by the documented rule, where parity is moot.
    for p in points(&bent, 5, count).into_iter().take(count) {
        let want = parity_inside(&tris, p, &dirs);
        assert_eq!(bvh.contains_point(p), want, "{p:?}");
        inside += want as usize;
    }
    assert!(
        inside > count / 10,
        "the sample should have points on both sides ({inside})"
    );
    assert!(!bvh.contains_point(Vec3::NAN));
    // Every vertex lies on the surface, exactly.
    for &v in bent.positions() {
        assert!(bvh.contains_point(v), "vertex {v:?}");
    }
}

// ---------------------------------------------------------------------------------------------------
// Overlaps
// ---------------------------------------------------------------------------------------------------

/// Both walks: the wide tree's (four `f32` box–ball distances at a time, the default) and the binary tree's
/// (box against the ball's box).
#[test]
fn sphere_overlaps_equal_brute_force() {
    for (name, m, wide) in scenes()
        .into_iter()
        .flat_map(|(n, m)| [(n, m.clone(), true), (n, m, false)])
    {
        let bvh = MeshBvh::build(&m, &BuildOptions::default().wide(wide)).unwrap();
        assert_eq!(bvh.wide().is_some(), wide);
        let s = scale(&m);
        let mut r = rng(8);
        let mut out = Vec::new();
        for p in points(&m, 2, 150) {
            let radius = (s * r.random_range(0.01..0.5)) as f32;
            bvh.overlapping(&Shape::sphere(p, radius), &mut out);
            let want: Vec<u32> = (0..m.triangle_count() as u32)
                .filter(|&i| {
                    let t = m.triangle(i as usize);
                    !absent(t) && point_triangle(d(p), t.map(d)) <= radius as f64
                })
                .collect();
            // Triangles within rounding of the sphere's surface may go either way.
            let near = |i: &u32| {
                let dist = point_triangle(d(p), m.triangle(*i as usize).map(d));
                (dist - radius as f64).abs() <= s * 1e-12
            };
            let strip = |v: &[u32]| v.iter().copied().filter(|i| !near(i)).collect::<Vec<_>>();
            assert_eq!(
                strip(&out),
                strip(&want),
                "{name} wide {wide}: sphere {p:?} r {radius}"
            );
        }
    }
}

/// parry's answer for a shape against one triangle, from its `distance` (accurate to f32 rounding, unlike its
/// tolerance-based `intersection_test`), or `None` within a relative 1e-4 of the shape's surface, where f32
/// rounding may decide either way.
fn parry_overlap(shape: &Shape, t: [Vec3; 3]) -> Option<bool> {
    use parry3d::math::{Pose, Vector};
    use parry3d::query::distance;
    use parry3d::shape::{Cuboid, Segment, Triangle};
    let v = |p: Vec3| Vector::new(p.x, p.y, p.z);
    let tri = Triangle::new(v(t[0]), v(t[1]), v(t[2]));
    match *shape {
        Shape::Capsule { a, b, radius } => {
            let dist = distance(
                &Pose::IDENTITY,
                &Segment::new(v(a), v(b)),
                &Pose::IDENTITY,
                &tri,
            )
            .unwrap()
            .distance;
            ((dist - radius).abs() > radius * 1e-4).then_some(dist < radius)
        }
        Shape::Box {
            center,
            half,
            rotation,
        } => {
            let pose = Pose::from_parts(
                v(center),
                parry3d::glamx::Quat::from_array(rotation.to_array()),
            );
            let dist = |grow: f32| {
                distance(&pose, &Cuboid::new(v(half * grow)), &Pose::IDENTITY, &tri)
                    .unwrap()
                    .distance
            };
            let (shrunk, grown) = (dist(1.0 - 1e-4), dist(1.0 + 1e-4));
            (shrunk == 0.0 || grown > 0.0).then_some(shrunk == 0.0)
        }
        Shape::Sphere { .. } => unreachable!("spheres are checked by brute force"),
    }
}

#[test]
fn capsule_and_box_overlaps_agree_with_parry() {
    for (name, m, wide) in scenes()
        .into_iter()
        .filter(|(n, _)| !n.starts_with("offset") && !n.starts_with("tiny"))
        .flat_map(|(n, m)| [(n, m.clone(), true), (n, m, false)])
    {
        let bvh = MeshBvh::build(&m, &BuildOptions::default().wide(wide)).unwrap();
        let s = scale(&m) as f32;
        let mut r = rng(31);
        let mut out = Vec::new();
        let mut decided = 0;
        for (k, p) in points(&m, 4, 120).into_iter().enumerate() {
            let size = s * r.random_range(0.02..0.4);
            let shape = if k % 2 == 0 {
                Shape::capsule(p, p + common::rand_dir(&mut r) * size * 2.0, size * 0.3)
            } else {
                let q = Quat::from_axis_angle(common::rand_dir(&mut r), r.random_range(0.0..6.0));
                Shape::cuboid(p, Vec3::new(size, size * 0.5, size * 0.2), q)
            };
            bvh.overlapping(&shape, &mut out);
            for i in 0..m.triangle_count() as u32 {
                let t = m.triangle(i as usize);
                if absent(t) {
                    assert!(!out.contains(&i), "{name}: absent triangle {i} reported");
                    continue;
                }
                if let Some(want) = parry_overlap(&shape, t) {
                    assert_eq!(
                        out.binary_search(&i).is_ok(),
                        want,
                        "{name}: {shape:?} triangle {i}"
                    );
                    decided += 1;
                }
            }
        }
        assert!(decided > 1000, "{name}: {decided}");
    }
}

/// Shapes that hold whole subtrees of the wide tree (reported without a test per triangle): a ball or a
/// turned box around the whole mesh reports every present triangle and no absent one (the analytic answer),
/// and so does the binary walk, which tests every triangle.
#[test]
fn shapes_around_the_whole_mesh_report_every_present_triangle() {
    for (name, m) in scenes() {
        let (lo, hi) = m
            .positions()
            .iter()
            .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let (c, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        let want: Vec<u32> = (0..m.triangle_count() as u32)
            .filter(|&i| !absent(m.triangle(i as usize)))
            .collect();
        // Room for the f32 rounding of the centre at the scene's magnitude.
        let room = (half.length() + scale(&m) as f32 * 1e-5) * 1.01;
        let q = Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        for shape in [
            Shape::sphere(c, room),
            Shape::cuboid(c, Vec3::splat(room), q),
            Shape::cuboid(c, half * 1.01 + scale(&m) as f32 * 1e-5, Quat::IDENTITY),
        ] {
            for wide in [true, false] {
                let bvh = MeshBvh::build(&m, &BuildOptions::default().wide(wide)).unwrap();
                let mut out = Vec::new();
                bvh.overlapping(&shape, &mut out);
                assert_eq!(out, want, "{name} wide {wide}: {shape:?}");
            }
        }
    }
}

#[test]
fn invalid_shapes_overlap_nothing() {
    let bvh = MeshBvh::build(&icosphere(1), &BuildOptions::default()).unwrap();
    let mut out = vec![7];
    for shape in [
        Shape::sphere(Vec3::NAN, 1.0),
        Shape::sphere(Vec3::ZERO, -1.0),
        Shape::capsule(Vec3::ZERO, Vec3::INFINITY, 1.0),
        Shape::cuboid(Vec3::ZERO, Vec3::new(1.0, -1.0, 1.0), Quat::IDENTITY),
        Shape::cuboid(Vec3::ZERO, Vec3::ONE, Quat::from_xyzw(0.0, 0.0, 0.0, 2.0)),
    ] {
        bvh.overlapping(&shape, &mut out);
        assert!(out.is_empty(), "{shape:?}");
    }
}

// ---------------------------------------------------------------------------------------------------
// Sphere casts
// ---------------------------------------------------------------------------------------------------

/// A cast shape for the oracle: a sphere is a capsule whose segment is one point.
#[derive(Clone, Copy, Debug)]
struct Swept {
    a: Vec3,
    b: Vec3,
    dir: Vec3,
    r: f32,
}

impl Swept {
    fn sphere(c: Vec3, dir: Vec3, r: f32) -> Self {
        Swept { a: c, b: c, dir, r }
    }

    fn cast(&self, bvh: &MeshBvh, max_t: f32) -> Option<kinetrace::queries::CastHit> {
        if self.a == self.b {
            bvh.cast_sphere(self.a, self.dir, self.r, max_t)
        } else {
            bvh.cast_capsule(self.a, self.b, self.dir, self.r, max_t)
        }
    }

    /// Distance from the core at time `t` to one triangle. For a segment, a golden-section search along it:
    /// the distance from a point moving on a line to a convex set is convex, so the search converges to the
    /// minimum (to 4e-9 of the segment's length after 40 steps, far below the walk's δ).
    fn core_distance(&self, t: f64, tri: [DVec3; 3]) -> f64 {
        let off = d(self.dir) * t;
        let (a, b) = (d(self.a) + off, d(self.b) + off);
        let f = |k: f64| point_triangle(a.lerp(b, k), tri);
        if self.a == self.b {
            return f(0.0);
        }
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..40 {
            let (x1, x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
            if f(x1) <= f(x2) {
                hi = x2;
            } else {
                lo = x1;
            }
        }
        f(lo).min(f(hi)).min(f(0.0)).min(f(1.0))
    }

    /// The brute-force gap `distance(core at t) - r` over the mesh's present triangles.
    fn gap(&self, m: &Mesh, t: f64) -> f64 {
        (0..m.triangle_count())
            .map(|i| m.triangle(i))
            .filter(|t| !absent(*t))
            .map(|tri| self.core_distance(t, tri.map(d)))
            .fold(f64::INFINITY, f64::min)
            - self.r as f64
    }
}

/// Checks a cast against the brute-force gap: at the reported time the shape touches (the gap is zero up to
/// the f32 rounding of `t` and of the coordinates, or not positive at `t = 0` for a start in contact), and on
/// the way there — or all the way to `max_t` for a miss — it never sinks deeper than `δ` into the mesh. The
/// way is walked by conservative advancement: the gap shrinks by at most `|dir|` per unit of `t`, so steps
/// of `max(gap, δ) / |dir|` cannot step over a penetration deeper than `δ`.
fn check_sweep(m: &Mesh, bvh: &MeshBvh, sw: Swept, max_t: f32, what: &str) {
    let ours = sw.cast(bvh, max_t);
    let s = scale(m).max(d(sw.a).abs().max(d(sw.b).abs()).max_element()) + sw.r as f64;
    let delta = s * 1e-6;
    let speed = d(sw.dir).length();
    let end = ours.map_or(max_t as f64, |h| h.t as f64);
    if let Some(h) = ours {
        let g = sw.gap(m, h.t as f64);
        let tol = 8.0 * f32::EPSILON as f64 * (s + h.t as f64 * speed);
        if h.t == 0.0 {
            assert!(g <= tol, "{what}: start contact claimed with gap {g}");
        } else {
            assert!(
                g.abs() <= tol,
                "{what}: gap {g} at reported t {} (tol {tol})",
                h.t
            );
        }
        // The contact point is on the named triangle, at distance r from the core.
        let tri = m.triangle(h.primitive as usize).map(d);
        assert!(
            point_triangle(d(h.point), tri) <= tol,
            "{what}: contact off its triangle"
        );
        if h.t > 0.0 {
            let reach = sw.core_distance(h.t as f64, [d(h.point); 3]);
            assert!(
                (reach - sw.r as f64).abs() <= tol,
                "{what}: contact {reach} from the core, not at radius"
            );
        }
        assert!(
            (h.normal.length() - 1.0).abs() < 1e-5,
            "{what}: normal {:?}",
            h.normal
        );
    }
    let mut t = 0.0;
    let mut steps = 0;
    while t < end - delta / speed {
        let g = sw.gap(m, t);
        assert!(
            g > -delta,
            "{what}: penetrates by {} at t = {t} before the reported {end}",
            -g
        );
        t += g.max(delta) / speed;
        steps += 1;
        assert!(steps < 100_000, "{what}: the walk did not end");
    }
}

fn check_cast(m: &Mesh, bvh: &MeshBvh, c: Vec3, dir: Vec3, r: f32, max_t: f32, what: &str) {
    check_sweep(m, bvh, Swept::sphere(c, dir, r), max_t, what);
}

#[test]
fn sphere_casts_equal_brute_force() {
    for (name, m) in scenes() {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let s = scale(&m) as f32;
        let mut r = rng(12);
        for (k, p) in points(&m, 6, 60).into_iter().enumerate() {
            let radius = match k % 4 {
                0 => s * 1e-4,
                1 => s * 0.05,
                2 => s * 0.3,
                _ => 0.0,
            };
            let target = m.positions()[r.random_range(0..m.positions().len())];
            let dir = if k % 5 == 0 {
                common::rand_dir(&mut r) * s
            } else {
                target - p
            };
            if dir == Vec3::ZERO {
                continue;
            }
            check_cast(&m, &bvh, p, dir, radius, 2.0, &format!("{name} #{k}"));
        }
    }
}

/// The square `[-1, 1]²` in the plane y = 0, two upward-facing triangles sharing the diagonal through the
/// origin: the floor of the analytic cast cases.
fn floor() -> MeshBvh {
    let corners =
        [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, z)| Vec3::new(x, 0.0, z));
    let mesh = Mesh::new(corners.to_vec(), vec![0, 2, 1, 0, 3, 2]).unwrap();
    MeshBvh::build(&mesh, &BuildOptions::default()).unwrap()
}

#[test]
fn sphere_casts_on_analytic_cases() {
    let bvh = floor();
    // Dropped onto the shared edge: lands at the analytic time, on the face, normal up.
    let h = bvh
        .cast_sphere(Vec3::new(0.25, 2.0, 0.25), -Vec3::Y, 0.5, 10.0)
        .unwrap();
    assert_eq!(
        (h.t, h.point, h.normal),
        (1.5, Vec3::new(0.25, 0.0, 0.25), Vec3::Y)
    );
    // Starting in contact: t = 0, pushed out along +y.
    let h = bvh
        .cast_sphere(Vec3::new(0.5, 0.25, -0.5), Vec3::X, 0.5, 10.0)
        .unwrap();
    assert_eq!((h.t, h.normal), (0.0, Vec3::Y));
    // Grazing: sliding along the floor at exactly the radius touches from the start.
    let h = bvh.cast_sphere(Vec3::new(-3.0, 0.5, 0.0), Vec3::X, 0.5, 10.0);
    assert_eq!(
        h.map(|h| h.t),
        Some(2.0),
        "reaches the floor's edge, at x = -1, after 2 units"
    );
    // Parallel just above: a miss.
    assert!(
        bvh.cast_sphere(Vec3::new(-3.0, 0.5001, 0.0), Vec3::X, 0.5, 10.0)
            .is_none()
    );
    // Hitting the rim edge from the side: the edge x = 1 at height 0, sphere centre at height 0.3.
    let h = bvh
        .cast_sphere(Vec3::new(3.0, 0.3, 0.0), -Vec3::X, 0.5, 10.0)
        .unwrap();
    let expect = 2.0 - (0.5f64 * 0.5 - 0.3 * 0.3).sqrt();
    assert!(
        (h.t as f64 - expect).abs() <= 4.0 * f32::EPSILON as f64 * 3.0,
        "{} vs {expect}",
        h.t
    );
    assert!(matches!(h.feature, Feature::Edge(_)), "{:?}", h.feature);
    // Corner: straight down onto the corner (1, 0, 1) from the outside diagonal.
    let h = bvh
        .cast_sphere(Vec3::new(1.3, 1.0, 1.3), -Vec3::Y, 0.5, 10.0)
        .unwrap();
    let horiz = (0.3f64 * 0.3 * 2.0).sqrt();
    let expect = 1.0 - (0.25 - horiz * horiz).sqrt();
    assert!(
        (h.t as f64 - expect).abs() <= 4.0 * f32::EPSILON as f64 * 2.0,
        "{} vs {expect}",
        h.t
    );
    assert!(matches!(h.feature, Feature::Vertex(_)));
    // Bad input is no hit, not a panic.
    assert!(bvh.cast_sphere(Vec3::NAN, Vec3::X, 1.0, 1.0).is_none());
    assert!(bvh.cast_sphere(Vec3::ZERO, Vec3::X, -1.0, 1.0).is_none());
    assert!(
        bvh.cast_sphere(Vec3::new(0.0, 5.0, 0.0), Vec3::ZERO, 1.0, 1.0)
            .is_none()
    );
}

#[test]
fn sphere_and_capsule_casts_agree_with_parry() {
    use parry3d::math::{Pose, Vector};
    use parry3d::query::{ShapeCastOptions, cast_shapes};
    use parry3d::shape::{Ball, Capsule};
    for (name, m) in scenes()
        .into_iter()
        .filter(|(n, _)| ["icosphere", "torus", "soup"].contains(n))
    {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let pm = parry_mesh(&m);
        let mut r = rng(5);
        let (mut compared, mut disputed) = (0, 0);
        for (k, p) in points(&m, 8, 100).into_iter().take(100).enumerate() {
            let dir = common::rand_dir(&mut r) * 2.0;
            let radius = r.random_range(0.01..0.2);
            let axis = if k % 2 == 0 {
                Vec3::ZERO
            } else {
                common::rand_dir(&mut r) * 0.3
            };
            let sw = Swept {
                a: p,
                b: p + axis,
                dir,
                r: radius,
            };
            let v = |x: Vec3| Vector::new(x.x, x.y, x.z);
            let cast = |pose: Pose, shape: &dyn parry3d::shape::Shape| {
                cast_shapes(
                    &pose,
                    v(dir),
                    shape,
                    &Pose::IDENTITY,
                    Vector::ZERO,
                    &pm,
                    ShapeCastOptions::with_max_time_of_impact(1.0),
                )
                .unwrap()
            };
            let theirs = if axis == Vec3::ZERO {
                cast(Pose::from_translation(v(p)), &Ball::new(radius))
            } else {
                cast(Pose::IDENTITY, &Capsule::new(v(p), v(p + axis), radius))
            };
            let ours = sw.cast(&bvh, 1.0);
            if let Some(h) = ours.filter(|h| h.t == 0.0) {
                // A start in contact is t = 0 here; parry ignores a penetration the shape moves out of.
                assert!(sw.gap(&m, 0.0) <= 1e-6, "{name}: {h:?}");
                continue;
            }
            // parry stops its conservative advancement within about 1e-4 of the contact distance; where it
            // differs by more, or only one side hits, the brute force adjudicates ours.
            let agree = match (ours, theirs) {
                (Some(a), Some(b)) => ((a.t - b.time_of_impact) * dir.length()).abs() <= 2e-4,
                (None, None) => true,
                _ => false,
            };
            if agree {
                compared += 1;
            } else {
                check_sweep(&m, &bvh, sw, 1.0, &format!("{name} vs parry {theirs:?}"));
                disputed += 1;
            }
        }
        eprintln!(
            "{name}: {compared} casts agree with parry, {disputed} adjudicated by brute force"
        );
        assert!(
            compared > 50 && disputed * 10 < compared,
            "{name}: {compared} agree, {disputed} disputed"
        );
    }
}

#[test]
fn capsule_casts_equal_brute_force() {
    for (name, m) in scenes()
        .into_iter()
        .filter(|(n, _)| ["soup", "torus", "needles", "huge 1e4"].contains(n))
    {
        let m = if m.triangle_count() > 600 {
            map_mesh(&m, |p| p)
        } else {
            m
        };
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let s = scale(&m) as f32;
        let mut r = rng(13);
        for (k, p) in points(&m, 7, 25).into_iter().take(25).enumerate() {
            let axis = common::rand_dir(&mut r) * s * r.random_range(0.05..0.5);
            let radius = [s * 1e-4, s * 0.05, s * 0.2][k % 3];
            let target = m.positions()[r.random_range(0..m.positions().len())];
            let dir = target - p;
            check_sweep(
                &m,
                &bvh,
                Swept {
                    a: p,
                    b: p + axis,
                    dir,
                    r: radius,
                },
                2.0,
                &format!("{name} capsule #{k}"),
            );
        }
    }
}

#[test]
fn capsule_casts_on_analytic_cases() {
    let bvh = floor();
    // Lying flat, falling: the whole segment lands at once, at the radius.
    let h = bvh
        .cast_capsule(
            Vec3::new(-0.5, 2.0, 0.0),
            Vec3::new(0.5, 2.0, 0.0),
            -Vec3::Y,
            0.25,
            10.0,
        )
        .unwrap();
    assert_eq!((h.t, h.normal), (1.75, Vec3::Y));
    // Its interior against the floor's rim edge (x = 1): a horizontal capsule along z, swept in -x at height
    // 0.1, touches the edge when its axis is sqrt(r² - 0.1²) beyond x = 1.
    let h = bvh
        .cast_capsule(
            Vec3::new(3.0, 0.1, -0.5),
            Vec3::new(3.0, 0.1, 0.5),
            -Vec3::X,
            0.25,
            10.0,
        )
        .unwrap();
    let expect = 2.0 - (0.25f64 * 0.25 - 0.1 * 0.1).sqrt();
    assert!(
        (h.t as f64 - expect).abs() <= 8.0 * f32::EPSILON as f64,
        "{} vs {expect}",
        h.t
    );
    assert!(matches!(h.feature, Feature::Edge(_)));
    // Crossed edges: a capsule along x above the floor, swept sideways in -z across the rim edge z = -1 from
    // below the floor's plane — misses; from the side at the plane's height, hits the edge interior.
    assert!(
        bvh.cast_capsule(
            Vec3::new(-0.5, -0.3, 3.0),
            Vec3::new(0.5, -0.3, 3.0),
            -Vec3::Z,
            0.25,
            2.0
        )
        .is_none()
    );
    let h = bvh
        .cast_capsule(
            Vec3::new(-0.5, 0.0, -3.0),
            Vec3::new(0.5, 0.0, -3.0),
            Vec3::Z,
            0.25,
            10.0,
        )
        .unwrap();
    assert_eq!(h.t, 1.75);
    // A vertical capsule straight down onto the middle of the floor, starting in contact: t = 0.
    let h = bvh
        .cast_capsule(
            Vec3::new(0.3, 0.1, 0.3),
            Vec3::new(0.3, 2.0, 0.3),
            Vec3::X,
            0.25,
            1.0,
        )
        .unwrap();
    assert_eq!(h.t, 0.0);
    assert!(
        bvh.cast_capsule(Vec3::NAN, Vec3::ZERO, Vec3::X, 1.0, 1.0)
            .is_none()
    );
}

// ---------------------------------------------------------------------------------------------------
// Box casts
// ---------------------------------------------------------------------------------------------------

/// parry's signed gap between the box moved to time `t` and the mesh's present triangles: the distance, or
/// minus the penetration depth (its EPA stops within about 1e-5 of the extent).
fn box_gap(m: &Mesh, center: Vec3, half: Vec3, rot: Quat, dir: Vec3, t: f64) -> f64 {
    use parry3d::math::{Pose, Vector};
    use parry3d::query::{contact, distance};
    use parry3d::shape::{Cuboid, Triangle};
    let v = |p: Vec3| Vector::new(p.x, p.y, p.z);
    let c = (d(center) + d(dir) * t).as_vec3();
    let pose = Pose::from_parts(v(c), parry3d::glamx::Quat::from_array(rot.to_array()));
    let cube = Cuboid::new(v(half));
    (0..m.triangle_count())
        .map(|i| m.triangle(i))
        .filter(|t| !absent(*t))
        .map(|t| {
            let tri = Triangle::new(v(t[0]), v(t[1]), v(t[2]));
            match contact(&pose, &cube, &Pose::IDENTITY, &tri, 0.0).unwrap() {
                Some(c) => c.dist as f64,
                None => {
                    distance(&pose, &cube, &Pose::IDENTITY, &tri)
                        .unwrap()
                        .distance as f64
                }
            }
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn box_casts_equal_brute_force() {
    for (name, m) in scenes()
        .into_iter()
        .filter(|(n, _)| ["soup", "icosphere", "needles"].contains(n))
    {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let s = scale(&m) as f32;
        let mut r = rng(17);
        let mut hits = 0;
        for (k, p) in points(&m, 9, 30).into_iter().take(30).enumerate() {
            let half = Vec3::new(
                r.random_range(0.01..0.2),
                r.random_range(0.01..0.2),
                r.random_range(0.001..0.1),
            ) * s;
            let rot = Quat::from_axis_angle(common::rand_dir(&mut r), r.random_range(0.0..6.0));
            let target = m.positions()[r.random_range(0..m.positions().len())];
            let dir = target - p;
            let what = format!("{name} box #{k}");
            let ours = bvh.cast_box(p, half, rot, dir, 2.0);
            let gap = |t: f64| box_gap(&m, p, half, rot, dir, t);
            // parry's f32 GJK/EPA decide the gap to about 1e-5 of the extent: the walk and the contact are held
            // to that, not to our f64 arithmetic.
            let delta = 1e-5 * s as f64;
            let speed = d(dir).length();
            let end = ours.map_or(2.0, |h| h.t as f64);
            if let Some(h) = ours {
                hits += 1;
                let g = gap(h.t as f64);
                if h.t == 0.0 {
                    assert!(g <= delta, "{what}: start contact claimed with gap {g}");
                } else {
                    assert!(g.abs() <= delta, "{what}: gap {g} at reported t {}", h.t);
                }
                let tri = m.triangle(h.primitive as usize).map(d);
                assert!(
                    point_triangle(d(h.point), tri) <= delta,
                    "{what}: contact off its triangle"
                );
                // The contact point is on the box's surface (within the gap's tolerance).
                let c = d(p) + d(dir) * h.t as f64;
                let local = (rot.as_dquat().inverse() * (d(h.point) - c)).abs();
                let outside = (local - d(half)).max_element();
                assert!(
                    outside.abs() <= delta || h.t == 0.0,
                    "{what}: contact {outside} off the box surface"
                );
                assert!((h.normal.length() - 1.0).abs() < 1e-5, "{what}");
            }
            let mut t = 0.0;
            let mut steps = 0;
            while t < end - delta / speed {
                let g = gap(t);
                assert!(
                    g > -delta,
                    "{what}: penetrates by {} at t = {t} before the reported {end}",
                    -g
                );
                t += g.max(delta) / speed;
                steps += 1;
                assert!(steps < 100_000, "{what}: the walk did not end");
            }
        }
        assert!(hits > 10, "{name}: {hits}");
    }
}

#[test]
fn box_casts_on_analytic_cases() {
    let bvh = floor();
    // Flat: the bottom face lands at t = 3 - 0.5.
    let h = bvh
        .cast_box(
            Vec3::new(0.2, 3.0, 0.1),
            Vec3::splat(0.5),
            Quat::IDENTITY,
            -Vec3::Y,
            10.0,
        )
        .unwrap();
    assert_eq!((h.t, h.normal), (2.5, Vec3::Y));
    // Face on face: the point lies in the contact region, under the box's bottom face.
    let p = h.point;
    assert!(
        p.y.abs() < 1e-6 && (-0.3..=0.7).contains(&p.x) && (-0.4..=0.6).contains(&p.z),
        "{p:?}"
    );
    // Turned 45° about z: an edge lands first, 0.5·√2 below the centre.
    let q = Quat::from_rotation_z(std::f32::consts::FRAC_PI_4);
    let h = bvh
        .cast_box(
            Vec3::new(0.0, 3.0, 0.0),
            Vec3::splat(0.5),
            q,
            -Vec3::Y,
            10.0,
        )
        .unwrap();
    let expect = 3.0 - 0.5 * 2f64.sqrt();
    assert!((h.t as f64 - expect).abs() <= 1e-6, "{} vs {expect}", h.t);
    assert!((h.normal - Vec3::Y).length() < 1e-6, "{:?}", h.normal);
    // Sliding flat along the floor at exactly half its height: touching from the start.
    let h = bvh
        .cast_box(
            Vec3::new(0.0, 0.5, 0.0),
            Vec3::splat(0.5),
            Quat::IDENTITY,
            Vec3::X,
            10.0,
        )
        .unwrap();
    assert_eq!(h.t, 0.0);
    // Just above: it slides off the floor's far edge without touching.
    assert!(
        bvh.cast_box(
            Vec3::new(-3.0, 0.5001, 0.0),
            Vec3::splat(0.5),
            Quat::IDENTITY,
            Vec3::X,
            10.0
        )
        .is_none()
    );
    // From the side into the floor's rim: the box's face x = -0.5 reaches x = 1 at t = 1.5.
    let h = bvh
        .cast_box(
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::splat(0.5),
            Quat::IDENTITY,
            -Vec3::X,
            10.0,
        )
        .unwrap();
    assert_eq!((h.t, h.normal), (1.5, Vec3::X));
    // Bad input.
    assert!(
        bvh.cast_box(
            Vec3::ZERO,
            Vec3::new(-1.0, 1.0, 1.0),
            Quat::IDENTITY,
            Vec3::X,
            1.0
        )
        .is_none()
    );
    assert!(
        bvh.cast_box(
            Vec3::ZERO,
            Vec3::ONE,
            Quat::from_xyzw(0.0, 0.0, 0.0, 3.0),
            Vec3::X,
            1.0
        )
        .is_none()
    );
    assert!(
        bvh.cast_box(Vec3::NAN, Vec3::ONE, Quat::IDENTITY, Vec3::X, 1.0)
            .is_none()
    );
}
