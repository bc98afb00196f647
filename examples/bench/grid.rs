//! Suite `grid`: the per-frame uniform grid (seed 001) against our LBVH on the same triangles — build rate on
//! one and all threads, and single-ray vs packet queries (camera rays in 8×8 tiles, shadow rays toward a
//! point light) through the grid and through the BVH, on one thread.

use crate::cpu::one_thread;
use crate::record::{Records, best_of};
use crate::report_scenes::Scene;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::grid::{GridOptions, UniformGrid};
use kinetrace::scenes::bumpy_torus;
use kinetrace::{Aabb, Mesh, MeshBvh, Ray};
use std::ops::Range;
use std::path::Path;

const SUITE: &str = "grid";

pub fn run(rec: &mut Records) {
    println!("suite grid on {}", crate::record::machine());
    let (n, surface, side) = if rec.quick {
        (20_000, 200_000, 256)
    } else {
        (100_000, 1_000_000, 512)
    };
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets");
    let (scenes, _) = Scene::all(n, &assets);
    let mut pos = Vec::new();
    for s in scenes
        .iter()
        .filter(|s| s.name == "crowd" || s.name == "explosion")
    {
        s.positions(30, &mut pos);
        scene(rec, s.name, &s.mesh(&pos), side);
    }
    scene(rec, "surface", &bumpy_torus(surface), side);
}

/// Rays per camera tile (8×8).
const TILE_RAYS: usize = 64;

/// Packets of up to `size` consecutive rays, never crossing a tile boundary.
fn packets(tiles: &[Range<usize>], size: usize) -> Vec<Range<usize>> {
    tiles
        .iter()
        .flat_map(|t| {
            (t.start..t.end)
                .step_by(size)
                .map(move |s| s..(s + size).min(t.end))
        })
        .collect()
}

/// Camera rays over the mesh in `tile`×`tile` tiles, tile after tile.
fn tiled_camera(b: &Aabb, side: usize, tile: usize) -> Vec<Ray> {
    let crate::rays::Orbit {
        eye,
        fwd,
        right,
        up,
        ..
    } = crate::rays::Orbit::around(*b, Vec3::new(0.55, 0.45, 0.7), 1.1);
    let mut rays = Vec::with_capacity(side * side);
    for ty in (0..side).step_by(tile) {
        for tx in (0..side).step_by(tile) {
            for y in ty..ty + tile {
                for x in tx..tx + tile {
                    let (fx, fy) = (x as f32 / side as f32 - 0.5, y as f32 / side as f32 - 0.5);
                    rays.push(Ray::new(eye, fwd + right * fx * 0.9 + up * fy * 0.9));
                }
            }
        }
    }
    rays
}

fn scene(rec: &mut Records, name: &str, mesh: &Mesh, side: usize) {
    let n = mesh.triangle_count() as f64;
    let reps = rec.reps();
    println!("\n{name}: {} triangles", mesh.triangle_count());
    let lbvh = BuildOptions::new(Builder::LBVH);
    let seq = GridOptions {
        parallel: false,
        ..Default::default()
    };
    let (g1, _) = one_thread(|| best_of(reps, || UniformGrid::build(mesh, &seq).unwrap()));
    let (gn, grid) = best_of(reps, || {
        UniformGrid::build(mesh, &GridOptions::default()).unwrap()
    });
    let (b1, _) = one_thread(|| {
        best_of(reps, || {
            MeshBvh::build(mesh, &lbvh.parallel(false)).unwrap()
        })
    });
    let (bn, bvh) = best_of(reps, || MeshBvh::build(mesh, &lbvh).unwrap());
    let mut binary = bvh.clone();
    binary.set_wide(false);
    for (who, t1, tn) in [("grid", g1, gn), ("LBVH", b1, bn)] {
        rec.add(SUITE, name, who, "build 1 thread", n / t1 / 1e6, "Mtris/s");
        rec.add(
            SUITE,
            name,
            who,
            "build all threads",
            n / tn / 1e6,
            "Mtris/s",
        );
    }
    rec.add(
        SUITE,
        name,
        "grid/LBVH",
        "build ratio 1 thread",
        b1 / g1,
        "x",
    );
    // The same grid binning each triangle only into the cells it overlaps.
    let overlap = GridOptions {
        overlap_test: true,
        ..seq
    };
    let (o1, exact) = one_thread(|| best_of(reps, || UniformGrid::build(mesh, &overlap).unwrap()));
    rec.add(
        SUITE,
        name,
        "grid overlap test",
        "build 1 thread",
        n / o1 / 1e6,
        "Mtris/s",
    );
    for (who, g) in [("grid", &grid), ("grid overlap test", &exact)] {
        let refs = g.reference_count() as f64 / n;
        rec.add(SUITE, name, who, "references per triangle", refs, "");
    }

    let camera = tiled_camera(&grid.bounds(), side, 8);
    let mut hits = vec![None; camera.len()];
    bvh.closest_hits(&camera, &mut hits);
    let light = grid.bounds().center() + Vec3::new(0.2, 1.0, 0.3) * grid.bounds().extent().length();
    // Shadow rays from the camera hits toward the light; the hits of one camera tile form one group, so
    // that a packet never mixes tiles.
    let (mut shadow, mut shadow_tiles) = (Vec::new(), Vec::new());
    for (rs, hs) in camera.chunks(TILE_RAYS).zip(hits.chunks(TILE_RAYS)) {
        let start = shadow.len();
        shadow.extend(rs.iter().zip(hs).filter_map(|(r, h)| {
            h.map(|h| Ray::with_range(r.at(h.t), light - r.at(h.t), 1e-4, 1.0))
        }));
        shadow_tiles.push(start..shadow.len());
    }
    let camera_tiles: Vec<_> = (0..camera.len())
        .step_by(TILE_RAYS)
        .map(|s| s..s + TILE_RAYS)
        .collect();
    let m = |rays: &[Ray], t: f64| rays.len() as f64 / t / 1e6;
    for (kind, rays, tiles) in [
        ("camera", &camera, &camera_tiles),
        ("shadow", &shadow, &shadow_tiles),
    ] {
        let any = kind == "shadow";
        let mut out = vec![None; rays.len()];
        let mut occ = vec![false; rays.len()];
        // Best time of single rays through a grid: any hits for shadow rays, closest hits otherwise.
        let single_grid = |g: &UniformGrid| {
            best_of(reps, || {
                if any {
                    rays.iter().filter(|r| g.any_hit(r)).count()
                } else {
                    rays.iter().filter(|r| g.closest_hit(r).is_some()).count()
                }
            })
            .0
        };
        let (t_grid, t_exact) = (single_grid(&grid), single_grid(&exact));
        let (t_bvh, _) = best_of(reps, || {
            if any {
                rays.iter().filter(|r| bvh.any_hit(r)).count()
            } else {
                rays.iter().filter(|r| bvh.closest_hit(r).is_some()).count()
            }
        });
        for (who, t) in [
            ("grid", t_grid),
            ("grid overlap test", t_exact),
            ("BVH", t_bvh),
        ] {
            let subject = format!("{who} single ray, {kind}");
            rec.add(
                SUITE,
                name,
                &subject,
                "Mrays/s 1 thread",
                m(rays, t),
                "Mrays/s",
            );
        }
        // Work per ray behind the times: cells (grid) or nodes (BVH) visited and triangle tests, one by
        // one and as 64-ray packets (a packet's cell visit counts once for all its rays).
        let mut single = [TraversalStats::default(); 2];
        for r in rays.iter() {
            if any {
                grid.any_hit_counted(r, &mut single[0]);
                bvh.any_hit_counted(r, &mut single[1]);
            } else {
                grid.closest_hit_counted(r, &mut single[0]);
                bvh.closest_hit_counted(r, &mut single[1]);
            }
        }
        let mut packed = [TraversalStats::default(); 2];
        for r in packets(tiles, TILE_RAYS) {
            let (rays, o, a) = (&rays[r.clone()], &mut out[r.clone()], &mut occ[r]);
            if any {
                grid.any_hits_packet(rays, a, &mut packed[0]);
                bvh.any_hits_packet(rays, a, &mut packed[1]);
            } else {
                grid.closest_hits_packet(rays, o, &mut packed[0]);
                bvh.closest_hits_packet(rays, o, &mut packed[1]);
            }
        }
        let per_ray = |x: u64| x as f64 / rays.len() as f64;
        for (who, st) in [
            ("grid single ray", single[0]),
            ("BVH single ray", single[1]),
            ("grid packet 64", packed[0]),
            ("BVH packet 64", packed[1]),
        ] {
            let subject = format!("{who}, {kind}");
            let steps = per_ray(st.inner_visits);
            rec.add(SUITE, name, &subject, "cells or nodes per ray", steps, "");
            rec.add(
                SUITE,
                name,
                &subject,
                "triangle tests per ray",
                per_ray(st.prim_tests),
                "",
            );
        }
        for size in [16, 64] {
            let ranges = packets(tiles, size);
            // "BVH" packets walk the 4-wide tree like the single rays; "BVH binary tree" packets walk the
            // binary tree (the packet path before wide packets), against the same wide single rays.
            let who_single = [
                ("grid", t_grid),
                ("grid overlap test", t_exact),
                ("BVH", t_bvh),
                ("BVH binary tree", t_bvh),
            ];
            for (who, single) in who_single {
                let (t, _) = best_of(reps, || {
                    let mut st = TraversalStats::default();
                    for range in &ranges {
                        let r = &rays[range.clone()];
                        let (o, a) = (&mut out[range.clone()], &mut occ[range.clone()]);
                        match (who, any) {
                            ("grid", true) => grid.any_hits_packet(r, a, &mut st),
                            ("grid", false) => grid.closest_hits_packet(r, o, &mut st),
                            ("grid overlap test", true) => exact.any_hits_packet(r, a, &mut st),
                            ("grid overlap test", false) => {
                                exact.closest_hits_packet(r, o, &mut st)
                            }
                            ("BVH", true) => bvh.any_hits_packet(r, a, &mut st),
                            ("BVH", false) => bvh.closest_hits_packet(r, o, &mut st),
                            (_, true) => binary.any_hits_packet(r, a, &mut st),
                            (_, false) => binary.closest_hits_packet(r, o, &mut st),
                        }
                    }
                });
                let subject = format!("{who} packet {size}, {kind}");
                rec.add(
                    SUITE,
                    name,
                    &subject,
                    "Mrays/s 1 thread",
                    m(rays, t),
                    "Mrays/s",
                );
                rec.add(SUITE, name, &subject, "speed-up vs single", single / t, "x");
            }
        }
    }
}
