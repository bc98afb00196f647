//! The uniform grid (single-ray 3D-DDA and frustum packets) against brute force over every triangle.

mod common;
#[path = "../examples/report/scenes.rs"]
#[allow(dead_code)]
mod scenes;

use common::*;
use glam::{DVec3, UVec3, Vec3};
use kinetrace::bvh::TraversalStats;
use kinetrace::grid::{GridOptions, MAX_PACKET, UniformGrid};
use kinetrace::scenes::{bumpy_torus, cube_sphere, icosphere, soup};
use kinetrace::{Error, Mesh, Ray};
use rand::Rng;
use std::path::Path;

fn grid(m: &Mesh) -> UniformGrid {
    UniformGrid::build(m, &GridOptions::default()).unwrap()
}

/// The grid without and with the triangle–cell overlap test.
fn grids(m: &Mesh) -> [UniformGrid; 2] {
    [false, true].map(|overlap_test| {
        let options = GridOptions {
            overlap_test,
            ..Default::default()
        };
        UniformGrid::build(m, &options).unwrap()
    })
}

/// Closest and any hit of every ray, single ray and in packets of 16 and 64, against brute force.
fn check(m: &Mesh, g: &UniformGrid, rays: &[Ray], what: &str) -> usize {
    let mut hits = 0;
    for (i, ray) in rays.iter().enumerate() {
        let expect = brute_closest(m, ray);
        let got = g.closest_hit(ray).map(|h| (h.primitive, h.t));
        assert_same_hit(m, ray, got, expect, &format!("{what} ray {i}"));
        assert_eq!(g.any_hit(ray), expect.is_some(), "{what} any-hit ray {i}");
        hits += expect.is_some() as usize;
    }
    for size in [16, MAX_PACKET] {
        check_packets(m, g, rays, size, what);
    }
    hits
}

/// Packets of `size` consecutive rays give what brute force gives (the same triangle, or an exact tie).
fn check_packets(m: &Mesh, g: &UniformGrid, rays: &[Ray], size: usize, what: &str) {
    let mut out = vec![None; rays.len()];
    let mut any = vec![false; rays.len()];
    let mut stats = TraversalStats::default();
    for (r, (o, a)) in rays
        .chunks(size)
        .zip(out.chunks_mut(size).zip(any.chunks_mut(size)))
    {
        g.closest_hits_packet(r, o, &mut stats);
        g.any_hits_packet(r, a, &mut stats);
    }
    for (i, ray) in rays.iter().enumerate() {
        let expect = brute_closest(m, ray);
        let got = out[i].map(|h| (h.primitive, h.t));
        assert_same_hit(
            m,
            ray,
            got,
            expect,
            &format!("{what} packet {size} ray {i}"),
        );
        assert_eq!(
            any[i],
            expect.is_some(),
            "{what} packet {size} any-hit ray {i}"
        );
    }
}

/// Random rays: from inside the mesh's box, and from outside aimed into it.
fn random_rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let b = m
        .triangle_bounds()
        .iter()
        .fold(kinetrace::Aabb::EMPTY, |a, b| a.union(b));
    let (c, e) = (b.center(), b.extent().max(Vec3::splat(1e-3)));
    let mut r = rng(seed);
    (0..n)
        .map(|i| {
            let inside = c + (rand_vec(&mut r, -0.5, 0.5) * e);
            if i % 2 == 0 {
                Ray::new(inside, rand_dir(&mut r))
            } else {
                let o = c + rand_dir(&mut r) * e.length() * 2.0;
                Ray::new(o, inside - o)
            }
        })
        .collect()
}

#[test]
fn every_report_scene_matches_brute_force() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets");
    let (all, skipped) = scenes::Scene::all(6000, &assets);
    for s in skipped {
        eprintln!("note: {s}");
    }
    let mut pos = Vec::new();
    for s in &all {
        for frame in [0, 45] {
            s.positions(frame, &mut pos);
            let m = s.mesh(&pos);
            for g in grids(&m) {
                let b = g.bounds();
                let eye = b.center() + Vec3::new(0.3, 0.4, 1.0) * b.extent().length();
                let mut rays = camera(eye, b.center(), 32, 8, 0.9);
                rays.extend(random_rays(&m, frame as u64 + 7, 400));
                let what = format!("{} frame {frame} {:?}", s.name, g.options());
                assert!(check(&m, &g, &rays, &what) > 0, "{what}: no ray hits");
            }
        }
    }
}

#[test]
fn rays_along_cell_planes_and_axes_with_signed_zeros() {
    // A regular sheet of quads and a sphere: rays exactly on the grid's cell planes, parallel to the axes,
    // with +0 and −0 in their zero components, from inside and outside the grid.
    for m in [
        cube_sphere(6),
        map_mesh(&cube_sphere(4), |p| p * Vec3::new(3.0, 1.0, 0.5)),
    ] {
        let g = grid(&m);
        let (b, res) = (g.bounds(), g.resolution());
        let cell = b.extent() / res.as_vec3();
        let mut rays = Vec::new();
        for a in 0..3 {
            let (u, v) = ((a + 1) % 3, (a + 2) % 3);
            for i in 0..=res[u] {
                for j in [0, res[v] / 2, res[v]] {
                    let mut o = b.center();
                    o[u] = b.min[u] + i as f32 * cell[u];
                    o[v] = b.min[v] + j as f32 * cell[v];
                    for (start, sign) in [
                        (b.min[a] - 1.0, 1.0f32),
                        (b.max[a] + 1.0, -1.0),
                        (b.center()[a], 1.0),
                    ] {
                        o[a] = start;
                        for zero in [0.0f32, -0.0] {
                            let mut d = Vec3::splat(zero);
                            d[a] = sign;
                            rays.push(Ray::new(o, d));
                        }
                    }
                }
            }
        }
        // Diagonal rays through cell corners.
        for i in 0..=res.x {
            let o = b.min + cell * i as f32 - Vec3::splat(1.0);
            rays.push(Ray::new(o, Vec3::ONE));
            rays.push(Ray::new(o + Vec3::splat(2.0), -Vec3::ONE));
        }
        check(&m, &g, &rays, "planes");
    }
}

#[test]
fn offsets_of_1e5_and_origins_far_outside() {
    let base = icosphere(3);
    for off in [Vec3::splat(1e5), Vec3::new(-1e5, 3.0, 1e5)] {
        let m = map_mesh(&base, |p| p + off);
        let rays = random_rays(&m, 3, 600);
        for g in grids(&m) {
            check(&m, &g, &rays, "offset");
        }
    }
    // Origins 1e5 away from a unit mesh near the origin: far rays take the brute-force path.
    let g = grid(&base);
    let mut r = rng(5);
    let rays: Vec<Ray> = (0..300)
        .map(|_| {
            let o = rand_dir(&mut r) * 1e5;
            Ray::new(o, rand_vec(&mut r, -0.5, 0.5) - o)
        })
        .collect();
    assert!(g.is_far(rays[0].origin));
    assert!(check(&base, &g, &rays, "far origin") > 100);
}

#[test]
fn teapot_in_stadium_one_cell_one_triangle_and_empty() {
    // A dense sphere of 0.01 in a box of 1000: the grid's size stays bounded and answers stay exact.
    let teapot = map_mesh(&icosphere(4), |p| p * 0.01);
    let mut pos = teapot.positions().to_vec();
    let mut idx = teapot.indices().to_vec();
    let k = pos.len() as u32;
    pos.extend([
        Vec3::splat(-500.0),
        Vec3::new(500.0, -500.0, -500.0),
        Vec3::new(0.0, 500.0, 500.0),
    ]);
    idx.extend([k, k + 1, k + 2]);
    let m = Mesh::new(pos, idx).unwrap();
    let mut rays = random_rays(&teapot, 9, 500);
    rays.extend(camera(Vec3::new(0.0, 0.0, 0.05), Vec3::ZERO, 16, 4, 0.8));
    rays.extend(random_rays(&m, 10, 300));
    for g in grids(&m) {
        assert!(g.reference_count() as u64 <= 32 * m.triangle_count() as u64);
        check(&m, &g, &rays, "stadium");
    }

    // Every triangle overlapping every other: identical large triangles, all in every cell.
    let tri = [
        Vec3::ZERO,
        Vec3::new(1.0, 0.0, 0.2),
        Vec3::new(0.0, 1.0, 0.7),
    ];
    let pos: Vec<Vec3> = (0..300).flat_map(|_| tri).collect();
    let m = Mesh::new(pos, (0..900).collect::<Vec<u32>>()).unwrap();
    let g = grid(&m);
    assert!(
        g.reference_count() as u64 <= 32 * 300,
        "{} refs",
        g.reference_count()
    );
    check(&m, &g, &random_rays(&m, 11, 300), "one cell");

    // One triangle.
    let m = Mesh::new(tri.to_vec(), vec![0, 1, 2]).unwrap();
    let g = grid(&m);
    assert!(check(&m, &g, &random_rays(&m, 12, 300), "one triangle") > 0);

    // No triangles, and only zero-area triangles: nothing is ever hit.
    for m in [
        Mesh::new(Vec::<Vec3>::new(), Vec::<u32>::new()).unwrap(),
        Mesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            vec![0, 1, 2, 1, 1, 1],
        )
        .unwrap(),
    ] {
        let g = grid(&m);
        for ray in random_rays(&cube_sphere(2), 13, 100) {
            assert!(g.closest_hit(&ray).is_none() && !g.any_hit(&ray));
        }
        check(&m, &g, &random_rays(&cube_sphere(2), 14, 64), "empty");
    }
}

#[test]
fn million_rays_from_inside_a_closed_mesh_never_miss() {
    // Every ray from inside a closed mesh must hit it; counted without an oracle, and a sample checked
    // against brute force.
    let m = cube_sphere(16);
    let g = grid(&m);
    let mut r = rng(17);
    let mut misses = 0;
    let mut sample = Vec::new();
    for i in 0..1_000_000 {
        let ray = Ray::new(rand_vec(&mut r, -0.5, 0.5), rand_dir(&mut r));
        misses += g.closest_hit(&ray).is_none() as usize;
        if i % 5000 == 0 {
            sample.push(ray);
        }
    }
    assert_eq!(misses, 0);
    check(&m, &g, &sample, "inside");
}

#[test]
fn incoherent_packets_equal_single_rays() {
    // Packets of random directions (falling back to single rays) and packets of shadow rays toward a
    // point light (coherent, different origins).
    let m = bumpy_torus(4000);
    let [g, overlap] = grids(&m);
    check(
        &m,
        &overlap,
        &random_rays(&m, 21, 640),
        "incoherent, overlap test",
    );
    check(&m, &g, &random_rays(&m, 21, 640), "incoherent");
    let mut r = rng(22);
    let light = Vec3::new(0.3, 3.0, 0.2);
    let shadow: Vec<Ray> = (0..640)
        .map(|_| {
            Ray::segment(
                rand_vec(&mut r, -1.5, 1.5) * Vec3::new(1.0, 0.2, 1.0),
                light,
            )
        })
        .collect();
    check(&m, &g, &shadow, "shadow");
}

#[test]
fn parallel_build_equals_sequential_and_rebuild_reuses() {
    let m = soup(3, 20_000);
    let par = grid(&m);
    let seq = UniformGrid::build(
        &m,
        &GridOptions {
            parallel: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(par.resolution(), seq.resolution());
    assert_eq!(par.reference_count(), seq.reference_count());
    let res = par.resolution();
    let mut brute_refs = 0;
    for z in 0..res.z {
        for y in 0..res.y {
            for x in 0..res.x {
                let c = UVec3::new(x, y, z);
                assert_eq!(par.cell_triangles(c), seq.cell_triangles(c));
                assert!(par.cell_triangles(c).is_sorted());
                brute_refs += par.cell_triangles(c).len();
            }
        }
    }
    assert_eq!(brute_refs, par.reference_count());
    // Rebuilding over another mesh gives what a fresh build gives.
    let mut g = grid(&icosphere(2));
    g.rebuild(&m).unwrap();
    assert_eq!(g.reference_count(), par.reference_count());
}

#[test]
fn bad_options_are_errors() {
    for o in [
        GridOptions {
            lambda: 0.0,
            ..Default::default()
        },
        GridOptions {
            lambda: f32::NAN,
            ..Default::default()
        },
        GridOptions {
            macrocell: 0,
            ..Default::default()
        },
    ] {
        assert!(matches!(
            UniformGrid::build(&icosphere(1), &o),
            Err(Error::InvalidOption(_))
        ));
    }
    let _ = rng(0).random_range(0..1);
}

/// A flat mesh gets about λ·N cells, one layer thick: the thin axis's single cell does not count as a
/// thousandth of one (which once made a one-triangle grid 10 × 10 × 1 at any budget, and the bounded-size
/// retry loop never ended).
#[test]
fn flat_meshes_get_their_cell_budget() {
    let one = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap();
    let g = grid(&one);
    let r = g.resolution();
    assert_eq!(r.z, 1, "{r:?}");
    let cells = (r.x * r.y * r.z) as f32;
    assert!(cells <= 2.0 * GridOptions::default().lambda, "{r:?}");
    let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z);
    assert_eq!(
        g.closest_hit(&ray).map(|h| h.primitive),
        brute_closest(&one, &ray).map(|(i, _)| i)
    );
    // A flat sheet of many triangles: still one layer, about λ·N cells.
    let sheet = Mesh::new(
        (0..=40)
            .flat_map(|y| (0..=40).map(move |x| Vec3::new(x as f32, y as f32, 0.0)))
            .collect::<Vec<_>>(),
        (0..40u32)
            .flat_map(|y| {
                (0..40u32).flat_map(move |x| {
                    let i = y * 41 + x;
                    [i, i + 1, i + 42, i, i + 42, i + 41]
                })
            })
            .collect::<Vec<_>>(),
    )
    .unwrap();
    let g = grid(&sheet);
    let r = g.resolution();
    let budget = GridOptions::default().lambda * sheet.triangle_count() as f32;
    assert_eq!(r.z, 1, "{r:?}");
    assert!(
        ((r.x * r.y) as f32 - budget).abs() <= 0.1 * budget,
        "{r:?} for about {budget} cells"
    );
}

/// The reference bound holds on a rebuild whose box and triangle count equal the last frame's but whose
/// triangles grew to span the box (an explosion's debris reassembling): the budget is cut as on a fresh build.
#[test]
fn rebuilds_keep_the_reference_bound_when_triangles_grow() {
    let n = 400;
    let corner = |i: usize, k: usize| {
        Vec3::new(
            ((i * 7 + k * 3) % 20) as f32,
            ((i * 11 + k) % 20) as f32,
            ((i * 13 + k * 5) % 20) as f32,
        )
    };
    // Small triangles spread over [0, 20]³, plus two fixed corners so every frame has the same box.
    let small: Vec<Vec3> = (0..n)
        .flat_map(|i| {
            let c = corner(i, 0);
            [
                c,
                c + Vec3::new(0.5, 0.0, 0.0),
                c + Vec3::new(0.0, 0.5, 0.0),
            ]
        })
        .chain([Vec3::ZERO, Vec3::splat(20.5), Vec3::new(0.0, 20.5, 0.0)])
        .collect();
    // The same count and box, every triangle spanning it.
    let big: Vec<Vec3> = (0..n)
        .flat_map(|i| {
            [
                Vec3::ZERO,
                Vec3::new(20.5, 20.5, (i % 20) as f32),
                Vec3::new(0.0, 20.5, 20.5),
            ]
        })
        .chain([Vec3::ZERO, Vec3::splat(20.5), Vec3::new(0.0, 20.5, 0.0)])
        .collect();
    let idx: Vec<u32> = (0..3 * (n as u32 + 1)).collect();
    let (a, b) = (
        Mesh::new(small, idx.clone()).unwrap(),
        Mesh::new(big, idx).unwrap(),
    );
    let mut g = grid(&a);
    g.rebuild(&b).unwrap();
    let fresh = grid(&b);
    assert!(
        g.reference_count() <= 32 * b.triangle_count(),
        "{} refs",
        g.reference_count()
    );
    assert_eq!(g.resolution(), fresh.resolution());
    assert_eq!(g.reference_count(), fresh.reference_count());
}

/// Whether the closed triangle `t` and the closed box `lo..hi` share a point: the triangle clipped by the
/// box's six planes (Sutherland–Hodgman in `f64`) is not empty. Independent of the grid's separating-axis
/// test.
fn clip_overlaps(t: [DVec3; 3], lo: DVec3, hi: DVec3) -> bool {
    let mut poly = t.to_vec();
    for axis in 0..3 {
        for (bound, keep_below) in [(hi[axis], true), (lo[axis], false)] {
            let inside = |p: &DVec3| {
                if keep_below {
                    p[axis] <= bound
                } else {
                    p[axis] >= bound
                }
            };
            let mut out = Vec::with_capacity(poly.len() + 1);
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                if inside(&a) {
                    out.push(a);
                }
                if inside(&a) != inside(&b) {
                    let s = (bound - a[axis]) / (b[axis] - a[axis]);
                    let mut x = a + (b - a) * s;
                    x[axis] = bound;
                    out.push(x);
                }
            }
            poly = out;
            if poly.is_empty() {
                return false;
            }
        }
    }
    true
}

#[test]
fn the_overlap_test_bins_a_triangle_into_exactly_the_cells_it_reaches() {
    // Large diagonal triangles, a soup, needles and slivers, a sheet at a 1e5 offset, a teapot in a
    // stadium: with the overlap test a triangle is listed in a cell exactly when it reaches the cell grown
    // by the margin (up to the test's documented 1/1024 of the margin); without it, in every cell of its
    // grown box. Checked cell by cell against a polygon clipper.
    let mut r = rng(31);
    let big: Vec<Vec3> = (0..60).map(|_| rand_vec(&mut r, -1.0, 1.0)).collect();
    let needles: Vec<Vec3> = (0..40)
        .flat_map(|_| {
            let a = rand_vec(&mut r, -1.0, 1.0);
            let d = rand_vec(&mut r, -1.0, 1.0);
            [a, a + d, a + d * 1.0001 + Vec3::splat(1e-6)]
        })
        .collect();
    let stadium = {
        let mut p = map_mesh(&icosphere(2), |p| p * 0.01).positions().to_vec();
        p.extend([
            Vec3::splat(-50.0),
            Vec3::new(50.0, -50.0, -50.0),
            Vec3::new(0.0, 50.0, 50.0),
        ]);
        p
    };
    let soup_tris = |p: Vec<Vec3>| {
        let n = p.len() as u32 / 3 * 3;
        Mesh::new(p, (0..n).collect::<Vec<u32>>()).unwrap()
    };
    let teapot = icosphere(2);
    let mut stadium_idx = teapot.indices().to_vec();
    let k = teapot.positions().len() as u32;
    stadium_idx.extend([k, k + 1, k + 2]);
    let meshes = [
        soup_tris(big),
        soup_tris(needles),
        soup(5, 3000),
        map_mesh(&cube_sphere(6), |p| {
            p * Vec3::new(3.0, 1.0, 0.2) + Vec3::splat(1e5)
        }),
        Mesh::new(stadium, stadium_idx).unwrap(),
    ];
    for (mi, m) in meshes.iter().enumerate() {
        let [boxed, exact] = grids(m);
        assert_eq!(boxed.resolution(), exact.resolution(), "mesh {mi}");
        assert!(exact.reference_count() <= boxed.reference_count());
        let (b, res, margin) = (exact.bounds(), exact.resolution(), exact.margin() as f64);
        let cell = (b.extent() / res.as_vec3()).as_dvec3();
        let tris: Vec<[DVec3; 3]> = (0..m.triangle_count())
            .map(|i| m.triangle(i).map(|p| p.as_dvec3()))
            .collect();
        let mut dropped = 0;
        for z in 0..res.z {
            for y in 0..res.y {
                for x in 0..res.x {
                    let c = UVec3::new(x, y, z);
                    let lo = b.min.as_dvec3() + c.as_dvec3() * cell;
                    let (got, all) = (exact.cell_triangles(c), boxed.cell_triangles(c));
                    assert!(got.iter().all(|t| all.contains(t)), "mesh {mi} cell {c}");
                    for &t in all {
                        let reach = |grow: f64| {
                            clip_overlaps(tris[t as usize], lo - grow, lo + cell + grow)
                        };
                        let listed = got.contains(&t);
                        if reach(margin) {
                            assert!(
                                listed,
                                "mesh {mi}: triangle {t} reaches cell {c}, not listed"
                            );
                        }
                        if listed {
                            assert!(
                                reach(margin * (1.0 + 2.0 / 1024.0)),
                                "mesh {mi}: triangle {t} listed in cell {c} it does not reach"
                            );
                        }
                        dropped += !listed as usize;
                    }
                }
            }
        }
        eprintln!(
            "mesh {mi}: {} references with the overlap test, {} without ({dropped} dropped)",
            exact.reference_count(),
            boxed.reference_count()
        );
        // Same result on one thread.
        let seq = UniformGrid::build(
            m,
            &GridOptions {
                overlap_test: true,
                parallel: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(seq.reference_count(), exact.reference_count());
    }
}

/// Rays whose range reaches behind their origin (`tmin < 0`), from inside a closed sphere and a closed box
/// (flat walls): the DDA walks back to where the range starts, and every ray meets a wall.
#[test]
fn rays_reaching_behind_their_origin_match_brute_force() {
    let walls = kinetrace::scenes::shoebox(Vec3::splat(-0.5), Vec3::splat(0.5));
    for (m, what) in [(cube_sphere(8), "sphere"), (walls, "box")] {
        let mut r = rng(23);
        let rays: Vec<Ray> = (0..640)
            .map(|i| {
                let tmin = [f32::NEG_INFINITY, -3.0, -1e-3][i % 3];
                let (o, d) = (rand_vec(&mut r, -0.4, 0.4), rand_dir(&mut r));
                Ray::with_range(o, d, tmin, f32::INFINITY)
            })
            .collect();
        for g in grids(&m) {
            assert_eq!(check(&m, &g, &rays, what), rays.len(), "{what}");
        }
    }
}
