//! Structure choice in the ECS (issue 12): meshes kept as grids answer like brute force, frame after frame
//! of deformation and motion, for batched and immediate closest hits and for occlusion; `Structure::Auto`
//! follows the documented rule of `grid::choice` on each mesh's profile; `TraceStats` says which structure
//! answered and why.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute};
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::characterize::SceneProfile;
use kinetrace::ecs::*;
use kinetrace::grid::choice::{MAX_EMPTY_BIN_FRACTION, MIN_GRID_TRIANGLES, MIN_SIZE_SPREAD};
use kinetrace::scenes::bumpy_torus;
use kinetrace::{Mesh, Ray};

fn frame(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

/// What the entity's row in this frame's `TraceStats::structures` says, if it has one.
fn reported(world: &World, e: Entity) -> Option<(StructureKind, StructureWhy)> {
    let stats = world.resource::<TraceStats>();
    let mut rows = stats.structures.iter().filter(|s| s.entity == e);
    let row = rows.next().map(|s| (s.structure, s.why));
    assert!(rows.next().is_none(), "{e} reported twice");
    row
}

/// Positions of `rest` deformed at `time`: a wave along y, different for every vertex.
fn wave(rest: &Mesh, time: f32, out: &mut [Vec3]) {
    for (p, q) in out.iter_mut().zip(rest.positions()) {
        *p = *q * (1.0 + 0.25 * (time + 3.0 * q.y + q.x).sin());
    }
}

#[test]
fn grid_meshes_answer_like_brute_force_over_deforming_frames() {
    let (mut world, mut schedule) = app_with(TraceConfig {
        structure: Structure::Grid,
        ..Default::default()
    });
    let rest = icosphere(3);
    let deform = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
            TraceTransform(Affine3A::from_translation(Vec3::new(2.5, 0.0, 0.0))),
        ))
        .id();
    let soup_rest = soup(7, 600);
    let scattered = world
        .spawn((
            TraceMesh(soup_rest.clone()),
            VertexPositions(soup_rest.positions().to_vec()),
            TraceTransform(Affine3A::from_scale(Vec3::splat(3.0))),
        ))
        .id();
    // A rigid torus moving through the others, and one mesh that keeps its BVH by its own component.
    let rigid = world
        .spawn((TraceMesh(bumpy_torus(800)), MotionHint::Rigid))
        .id();
    let kept_bvh = world
        .spawn((
            TraceMesh(cube_sphere(3)),
            VertexPositions(cube_sphere(3).positions().to_vec()),
            TraceStructure(Structure::Bvh),
            TraceTransform(Affine3A::from_translation(Vec3::new(-2.5, 0.0, 0.0))),
        ))
        .id();
    let cube_rest = cube_sphere(3);
    let mut r = rng(12);
    let all = QueryFilter::default();
    for f in 0..8u32 {
        let time = f as f32 * 0.4;
        world.get_mut::<TraceTransform>(rigid).unwrap().0 = Affine3A::from_rotation_translation(
            Quat::from_rotation_x(time),
            Vec3::new(0.0, time.sin(), 0.5 * time.cos()),
        );
        wave(
            &rest,
            time,
            &mut world.get_mut::<VertexPositions>(deform).unwrap().0,
        );
        wave(
            &soup_rest,
            time,
            &mut world.get_mut::<VertexPositions>(scattered).unwrap().0,
        );
        wave(
            &cube_rest,
            time,
            &mut world.get_mut::<VertexPositions>(kept_bvh).unwrap().0,
        );
        // From anywhere around, towards the meshes (most rays hit something).
        let rays: Vec<Ray> = (0..60)
            .map(|_| {
                let from = rand_vec(&mut r, -5.0, 5.0);
                Ray::new(from, rand_vec(&mut r, -2.0, 2.0) - from)
            })
            .collect();
        {
            let mut queue = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.iter().enumerate() {
                queue.cast(i as u64, *ray, all.clone());
                queue.shadow(i as u64, ray.origin, ray.at(6.0), all.clone());
            }
        }
        frame(&mut world, &mut schedule);

        // Which structure answers, and why: the config's grid, the component's BVH.
        for e in [deform, scattered] {
            assert_eq!(
                reported(&world, e),
                Some((StructureKind::Grid, StructureWhy::Fixed)),
                "frame {f}"
            );
            assert!(world.resource::<TraceWorld>().grid(e).is_some());
        }
        assert_eq!(
            reported(&world, kept_bvh),
            Some((StructureKind::Bvh, StructureWhy::Fixed)),
            "frame {f}"
        );
        assert!(world.resource::<TraceWorld>().grid(kept_bvh).is_none());
        // The rigid torus is maintained once (it never deforms) and keeps its grid.
        if f == 0 {
            assert_eq!(
                reported(&world, rigid),
                Some((StructureKind::Grid, StructureWhy::Fixed))
            );
        } else {
            assert_eq!(reported(&world, rigid), None, "frame {f}: only moved");
        }

        let results = world.resource::<RayResults>().clone();
        assert_eq!(results.hits.len(), rays.len());
        assert_eq!(results.shadows.len(), rays.len());
        let mut hits = 0;
        for (i, ray) in rays.iter().enumerate() {
            let expect = brute(&mut world, ray, &all);
            hits += expect.is_some() as usize;
            agree(
                results.hits[i].1.as_ref(),
                expect,
                &format!("frame {f} batched ray {i}"),
            );
            let immediate = world
                .resource::<TraceWorld>()
                .cast_ray(ray, f32::INFINITY, &all);
            agree(
                immediate.as_ref(),
                expect,
                &format!("frame {f} immediate ray {i}"),
            );
            let seg = Ray::segment(ray.origin, ray.at(6.0));
            let blocked = brute(&mut world, &seg, &all).is_some();
            assert_eq!(
                results.shadows[i].1, blocked,
                "frame {f} batched shadow {i}"
            );
            assert_eq!(
                world
                    .resource::<TraceWorld>()
                    .occluded(ray.origin, ray.at(6.0), &all),
                blocked,
                "frame {f} immediate shadow {i}"
            );
        }
        assert!(
            hits > 20,
            "frame {f}: only {hits} rays hit, the test means little"
        );
    }
}

/// The rule's documented profile tests, written out here from the module docs of `grid::choice`.
fn documented_rule(p: &SceneProfile) -> StructureKind {
    let empty = p.empty_bins as f64 / p.bins.max(1) as f64;
    if p.primitives >= MIN_GRID_TRIANGLES
        && empty <= MAX_EMPTY_BIN_FRACTION
        && p.size_spread > MIN_SIZE_SPREAD
    {
        StructureKind::Grid
    } else {
        StructureKind::Bvh
    }
}

/// A teapot in a stadium: two huge floor triangles and a tight cluster of tiny ones in a corner.
fn stadium(n: usize) -> Mesh {
    let mut pos = vec![
        Vec3::new(-100.0, 0.0, -100.0),
        Vec3::new(100.0, 0.0, -100.0),
        Vec3::new(100.0, 0.0, 100.0),
        Vec3::new(-100.0, 0.0, -100.0),
        Vec3::new(100.0, 0.0, 100.0),
        Vec3::new(-100.0, 0.0, 100.0),
    ];
    let teapot = even_soup(n, 0.02, 0.0);
    pos.extend(
        teapot
            .positions()
            .iter()
            .map(|p| *p + Vec3::new(90.0, 1.0, 90.0)),
    );
    let count = pos.len() as u32;
    Mesh::new(pos, (0..count).collect::<Vec<_>>()).unwrap()
}

#[test]
fn auto_follows_the_documented_rule_and_reports_it() {
    let (mut world, mut schedule) = app_with(TraceConfig {
        structure: Structure::Auto,
        ..Default::default()
    });
    let meshes = [
        even_soup(2000, 0.002, 2.5),
        even_soup(2000, 0.02, 0.0),
        stadium(2000),
        icosphere(1),
    ];
    let entities: Vec<Entity> = meshes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let at = Vec3::new(0.0, 0.0, 300.0 * i as f32);
            world
                .spawn((
                    TraceMesh(m.clone()),
                    VertexPositions(m.positions().to_vec()),
                    TraceTransform(Affine3A::from_translation(at)),
                ))
                .id()
        })
        .collect();
    let mut expected = Vec::new();
    for f in 0..4u32 {
        for (m, &e) in meshes.iter().zip(&entities) {
            let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
            for (p, q) in vp.0.iter_mut().zip(m.positions()) {
                *p = *q * (1.0 + 0.001 * f as f32);
            }
        }
        frame(&mut world, &mut schedule);
        for &e in &entities {
            let (kind, why) = reported(&world, e).expect("every mesh deformed");
            assert_eq!(
                world.resource::<TraceWorld>().structure(e),
                Some((kind, why))
            );
            let StructureWhy::Rule(reason) = why else {
                panic!("frame {f}: {why:?} under Auto");
            };
            if f == 0 {
                // Not characterised yet when first built.
                assert_eq!(
                    (kind, reason),
                    (StructureKind::Bvh, ChoiceReason::NoProfile)
                );
                continue;
            }
            // The profile the decision read: characterised before this frame's maintenance.
            let profile = world.resource::<TraceWorld>().profile(e).unwrap().clone();
            let want = documented_rule(&profile);
            assert_eq!(kind, want, "frame {f}: {reason:?} for {profile:?}");
            assert_eq!(
                world.resource::<TraceWorld>().grid(e).is_some(),
                want == StructureKind::Grid
            );
            if f == 3 {
                expected.push(want);
            }
        }
    }
    // The scenes exercise every test of the rule: the evenly spread soup of mixed sizes is a grid; the
    // soup of alike triangles, the stadium and the small sphere are not.
    assert_eq!(
        expected,
        [
            StructureKind::Grid,
            StructureKind::Bvh,
            StructureKind::Bvh,
            StructureKind::Bvh
        ]
    );
    // Rays through the world still equal brute force, grid and BVH meshes together.
    let mut r = rng(5);
    for i in 0..200 {
        let from = rand_vec(&mut r, -1.0, 2.0);
        let ray = Ray::new(
            from,
            rand_vec(&mut r, -0.5, 0.5) + Vec3::Z * 0.01 - from * 0.1,
        );
        let expect = brute(&mut world, &ray, &QueryFilter::default());
        let got =
            world
                .resource::<TraceWorld>()
                .cast_ray(&ray, f32::INFINITY, &QueryFilter::default());
        agree(got.as_ref(), expect, &format!("ray {i}"));
    }
}

#[test]
fn bad_grid_options_are_an_entity_error() {
    let (mut world, mut schedule) = app_with(TraceConfig {
        structure: Structure::Grid,
        grid: kinetrace::grid::GridOptions {
            lambda: f32::NAN,
            ..Default::default()
        },
        ..Default::default()
    });
    let e = world.spawn(TraceMesh(icosphere(1))).id();
    frame(&mut world, &mut schedule);
    assert!(matches!(
        world.get::<TraceError>(e),
        Some(TraceError(kinetrace::Error::InvalidOption(_)))
    ));
    assert!(!world.resource::<TraceWorld>().contains(e));
}
