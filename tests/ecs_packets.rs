//! Packets in the batched queries: camera tiles and shadow rays toward one light, queued as packets among
//! single requests, are answered exactly as the single-ray path answers each of them (and as world-space
//! brute force does), while the entities move and deform.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute};
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use kinetrace::scenes::bumpy_torus;

#[test]
fn queued_packets_answer_like_single_rays() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    // The ground, on a layer of its own.
    world.spawn((
        TraceMesh(cube_sphere(4)),
        MotionHint::Static,
        TraceTransform(Affine3A::from_scale_rotation_translation(
            Vec3::new(8.0, 0.2, 8.0),
            Quat::IDENTITY,
            Vec3::new(0.0, -1.2, 0.0),
        )),
        QueryLayers(0b10),
    ));
    let movers: Vec<Entity> = (0..4)
        .map(|_| {
            world
                .spawn((
                    TraceMesh(icosphere(2)),
                    MotionHint::Rigid,
                    QueryLayers(0b01),
                ))
                .id()
        })
        .collect();
    let rest = bumpy_torus(1500);
    let blob = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
            TraceTransform(Affine3A::from_translation(Vec3::new(0.0, 0.5, 2.0))),
        ))
        .id();
    let light = Vec3::new(3.0, 12.0, -2.0);
    let eye = Vec3::new(0.5, 4.0, -9.0);
    let mut r = rng(4);
    for f in 0..6u32 {
        let time = f as f32 * 0.4;
        for (k, &e) in movers.iter().enumerate() {
            let a = time + k as f32 * 1.6;
            world.get_mut::<TraceTransform>(e).unwrap().0 =
                Affine3A::from_scale_rotation_translation(
                    Vec3::splat(0.8 + 0.2 * k as f32),
                    Quat::from_rotation_y(a),
                    Vec3::new(3.0 * a.cos(), 0.2 * k as f32, 3.0 * a.sin()),
                );
        }
        let mut vp = world.get_mut::<VertexPositions>(blob).unwrap();
        for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
            *p = *q * (1.0 + 0.2 * (time + q.x * 4.0).sin());
        }
        // Singles, a 32×32 camera in tiles, more singles, and shadow packets from random points, two of
        // them with filters (layers, an excluded entity).
        let camera = camera(eye, Vec3::ZERO, 32, 8, 0.9);
        let singles: Vec<Ray> = (0..40)
            .map(|_| Ray::new(rand_vec(&mut r, -5.0, 5.0), rand_dir(&mut r)))
            .collect();
        let points: Vec<Vec3> = (0..150).map(|_| rand_vec(&mut r, -4.0, 4.0)).collect();
        let filters = [
            QueryFilter::default(),
            QueryFilter::default().layers(0b01),
            QueryFilter::default().exclude(blob),
        ];
        {
            let mut q = world.resource_mut::<RayQueue>();
            for (i, ray) in singles[..20].iter().enumerate() {
                q.cast(i as u64, *ray, QueryFilter::default());
            }
            q.cast_packet(100, &camera, QueryFilter::default());
            q.cast_packet(5000, &camera[..100], filters[1].clone());
            for (i, ray) in singles[20..].iter().enumerate() {
                q.cast(20 + i as u64, *ray, QueryFilter::default());
            }
            q.shadow(9999, points[0], light, QueryFilter::default());
            for (k, filter) in filters.iter().enumerate() {
                q.shadow_packet(10_000 * (k as u64 + 1), &points, light, filter.clone());
            }
        }
        schedule.run(&mut world);
        world.clear_trackers();
        let results = world.resource::<RayResults>().clone();
        // The same queries, ray by ray, in the same order.
        let mut expect = Vec::new();
        for (i, ray) in singles[..20].iter().enumerate() {
            expect.push((i as u64, *ray, QueryFilter::default()));
        }
        for (i, ray) in camera.iter().enumerate() {
            expect.push((100 + i as u64, *ray, QueryFilter::default()));
        }
        for (i, ray) in camera[..100].iter().enumerate() {
            expect.push((5000 + i as u64, *ray, filters[1].clone()));
        }
        for (i, ray) in singles[20..].iter().enumerate() {
            expect.push((20 + i as u64, *ray, QueryFilter::default()));
        }
        assert_eq!(results.hits.len(), expect.len());
        let mut hits = 0;
        for (k, ((tag, got), (etag, ray, filter))) in results.hits.iter().zip(&expect).enumerate() {
            assert_eq!(tag, etag, "frame {f} request {k}");
            let single = world
                .resource::<TraceWorld>()
                .cast_ray(ray, f32::INFINITY, filter);
            assert_eq!(
                got.as_ref().map(|h| h.distance.to_bits()),
                single.as_ref().map(|h| h.distance.to_bits()),
                "frame {f} request {k}: {got:?} vs {single:?}"
            );
            if got.as_ref().map(|h| (h.entity, h.triangle))
                != single.as_ref().map(|h| (h.entity, h.triangle))
            {
                // Only an exact tie may name another triangle: brute force decides.
                let b = brute(&mut world, ray, filter);
                agree(got.as_ref(), b, &format!("frame {f} request {k}"));
            }
            hits += got.is_some() as usize;
        }
        assert!(hits > 300, "frame {f}: {hits} hits");
        assert_eq!(results.shadows.len(), 1 + 3 * points.len());
        assert_eq!(results.shadows[0].0, 9999);
        let mut occluded = 0;
        for (k, filter) in filters.iter().enumerate() {
            for (i, &p) in points.iter().enumerate() {
                let (tag, got) = results.shadows[1 + k * points.len() + i];
                assert_eq!(tag, 10_000 * (k as u64 + 1) + i as u64);
                let single = world.resource::<TraceWorld>().occluded(p, light, filter);
                assert_eq!(got, single, "frame {f} filter {k} point {i}");
                occluded += got as usize;
            }
        }
        assert!(occluded > 20, "frame {f}: {occluded} occluded");
    }
}

/// Entity `k` of a row: `mesh` turned `k` radians about x, `k · step − 3` along x and `k · rise` up.
fn in_a_row(mesh: kinetrace::Mesh, k: usize, step: f32, rise: f32) -> (TraceMesh, TraceTransform) {
    let k = k as f32;
    (
        TraceMesh(mesh),
        TraceTransform(Affine3A::from_rotation_translation(
            Quat::from_rotation_x(k),
            Vec3::new(k * step - 3.0, k * rise, 0.0),
        )),
    )
}

#[test]
fn world_packets_match_brute_force() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    for k in 0..5 {
        let mesh = if k % 2 == 0 {
            icosphere(2)
        } else {
            cube_sphere(3)
        };
        world.spawn(in_a_row(mesh, k, 1.5, 0.0));
    }
    schedule.run(&mut world);
    let mut rays = camera(Vec3::new(0.0, 2.0, -8.0), Vec3::ZERO, 16, 8, 0.9);
    // An invalid ray and a ray with a short range inside a packet.
    rays[3] = Ray::new(Vec3::NAN, Vec3::Z);
    rays[9] = Ray::with_range(rays[9].origin, rays[9].dir(), 0.0, 0.5);
    let mut out = vec![None; rays.len()];
    world
        .resource::<TraceWorld>()
        .cast_packet(&rays, 50.0, &QueryFilter::default(), &mut out);
    for (i, ray) in rays.iter().enumerate() {
        let clipped = Ray::with_range(ray.origin, ray.dir(), ray.tmin, ray.tmax.min(50.0));
        let b = brute(&mut world, &clipped, &QueryFilter::default());
        agree(out[i].as_ref(), b, &format!("ray {i}"));
    }
    assert!(out.iter().filter(|h| h.is_some()).count() > 50);
    assert!(out[3].is_none() && out[9].is_none());
}

/// Scattered shadow segments through the two-level world, their walks interleaved
/// (`TraceWorld::occluded_interleaved`), answer exactly as `occluded` segment by segment and as the exact
/// brute-force oracle allows: overlapping entities (several walks per segment, one blocked walk ending
/// the others), one entity kept as a grid (walked on its own), one on a layer the filter rejects,
/// invalid and empty segments among them, in batches of every size around the four walks.
#[test]
fn interleaved_segments_answer_as_occluded_and_brute_force() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let (mut grid, mut spawned) = (None, Vec::new());
    for k in 0..6 {
        let mesh = if k % 2 == 0 {
            icosphere(2)
        } else {
            bumpy_torus(800)
        };
        let mut e = world.spawn(in_a_row(mesh, k, 0.8, 0.2));
        e.insert(QueryLayers(if k == 4 { 0b10 } else { 0b01 }));
        spawned.push(e.id());
        if k == 3 {
            grid = Some(e.insert(TraceStructure(Structure::Grid)).id());
        }
    }
    schedule.run(&mut world);
    schedule.run(&mut world);
    // One entity walked on its own (its grid), the others interleaved (their wide trees).
    let grid = grid.unwrap();
    let tw = world.resource::<TraceWorld>();
    assert_eq!(
        tw.structure(grid).unwrap().0,
        kinetrace::grid::StructureKind::Grid
    );
    let wide = (spawned.iter())
        .filter(|&&e| e != grid && tw.blas(e).is_some_and(|b| b.wide().is_some()))
        .count();
    assert_eq!(wide, 5, "the BVH entities walk their wide trees");
    let filter = QueryFilter {
        layers: 0b01,
        ..Default::default()
    };
    let mut r = rng(41);
    let mut segments: Vec<(Vec3, Vec3)> = (0..300)
        .map(|_| (rand_vec(&mut r, -3.5, 3.5), rand_vec(&mut r, -3.5, 3.5)))
        .collect();
    segments[5].1 = Vec3::NAN;
    segments[11].1 = segments[11].0;
    let one_by_one: Vec<bool> = {
        let tw = world.resource::<TraceWorld>();
        segments
            .iter()
            .map(|&(a, b)| tw.occluded(a, b, &filter))
            .collect()
    };
    let (_, tris) = common::ecs::world_triangles(&mut world, &filter);
    for (i, (&(a, b), &got)) in segments.iter().zip(&one_by_one).enumerate() {
        RayOracle::new(&Ray::segment(a, b), tris.iter().copied())
            .check_any(got, &format!("segment {i}"));
    }
    let blocked = one_by_one.iter().filter(|&&b| b).count();
    assert!(blocked > 60 && blocked < 240, "{blocked} of 300 blocked");
    let tw = world.resource::<TraceWorld>();
    let mut from = 0;
    for len in [0, 1, 3, 4, 5, 9, 64, usize::MAX] {
        let to = from + len.min(segments.len() - from);
        let mut out = vec![true; to - from];
        tw.occluded_interleaved(&segments[from..to], &filter, &mut out);
        assert_eq!(out, one_by_one[from..to], "segments {from}..{to}");
        from = to;
    }
}

/// Coincident entities (the same triangles at the same transform) are hit at the same distance; the answer
/// is the entity with the lowest `Entity::to_bits`, on every path — immediate rays, batched single rays,
/// batched packets, and the GPU's batches where an adapter exists — whatever order their top levels visit
/// them in. The higher entity's mesh carries two far triangles more, so that its box holds every ray's
/// origin and is visited first.
#[test]
fn coincident_entities_tie_to_the_lowest_entity_on_every_path() {
    let mut configs = vec![TraceConfig::default()];
    if gpu_or_skip().is_some() {
        configs.push(TraceConfig {
            mode: TraceMode::GpuRequired,
            ..TraceConfig::default()
        });
    }
    let sphere = icosphere(2);
    let mut pos = sphere.positions().to_vec();
    let mut idx = sphere.indices().to_vec();
    for corner in [Vec3::splat(-10.0), Vec3::splat(10.0)] {
        idx.extend((0..3).map(|k| (pos.len() + k) as u32));
        pos.extend([corner, corner + Vec3::X * 0.1, corner + Vec3::Y * 0.1]);
    }
    let padded = kinetrace::Mesh::new(pos, idx).unwrap();
    for config in configs {
        let mode = config.mode;
        let (mut world, mut schedule) = app_with(config);
        let place = TraceTransform(Affine3A::from_translation(Vec3::new(0.3, -0.2, 0.5)));
        let a = world.spawn(place).id();
        let b = world.spawn(place).id();
        let (low, high) = if a.to_bits() < b.to_bits() {
            (a, b)
        } else {
            (b, a)
        };
        world.entity_mut(low).insert(TraceMesh(sphere.clone()));
        world.entity_mut(high).insert(TraceMesh(padded.clone()));
        let mut r = rng(31);
        let rays: Vec<Ray> = (0..64)
            .map(|_| {
                let o = Vec3::new(0.3, -0.2, 0.5) + rand_dir(&mut r) * 4.0;
                Ray::new(o, Vec3::new(0.3, -0.2, 0.5) - o + rand_dir(&mut r) * 0.3)
            })
            .collect();
        let mut queue = world.resource_mut::<RayQueue>();
        for (i, ray) in rays.iter().enumerate() {
            queue.cast(i as u64, *ray, QueryFilter::default());
        }
        queue.cast_packet(1_000, &rays[..16], QueryFilter::default());
        schedule.run(&mut world);
        let trace = world.resource::<TraceWorld>();
        let results = world.resource::<RayResults>();
        assert_eq!(results.hits.len(), rays.len() + 16, "{mode:?}");
        for (tag, hit) in &results.hits {
            let i = (*tag % 1_000) as usize;
            let alone = trace.cast_ray(&rays[i], f32::INFINITY, &QueryFilter::default());
            let alone = alone.expect("every ray is aimed at the sphere");
            assert_eq!(alone.entity, low, "{mode:?} ray {i}: immediate");
            let hit = hit.expect("every ray is aimed at the sphere");
            assert_eq!(hit.entity, low, "{mode:?} ray {tag}: batched");
            assert_eq!(hit.distance, alone.distance, "{mode:?} ray {tag}");
        }
    }
}
