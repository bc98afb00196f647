//! The ECS layer: decisions per mesh kind, queries against world-space brute force, filters, despawns,
//! a soak run with bounded memory, and bad input.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute};
use common::*;
use glam::{Affine3A, Mat4, Quat, Vec3};
use kinetrace::Ray;
use kinetrace::anim::SkinWeights;
use kinetrace::ecs::*;
use rand::Rng;
use std::sync::Arc;

fn app() -> (World, Schedule) {
    app_with(TraceConfig::default())
}

fn frame(world: &mut World, schedule: &mut Schedule) {
    schedule.run(world);
    world.clear_trackers();
}

#[test]
fn static_rigid_and_deforming_meshes_for_300_frames() {
    let (mut world, mut schedule) = app();
    let stat = world
        .spawn((
            TraceMesh(cube_sphere(3)),
            MotionHint::Static,
            TraceTransform(Affine3A::from_translation(Vec3::new(-3.0, 0.0, 0.0))),
        ))
        .id();
    let rigid = world
        .spawn((TraceMesh(icosphere(2)), MotionHint::Rigid))
        .id();
    let rest = icosphere(2);
    let deform = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
            TraceTransform(Affine3A::from_translation(Vec3::new(3.0, 0.0, 0.0))),
        ))
        .id();
    let mut r = rng(1);
    for f in 0..300u32 {
        let time = f as f32 * 0.05;
        world.get_mut::<TraceTransform>(rigid).unwrap().0 = Affine3A::from_rotation_translation(
            Quat::from_rotation_y(time),
            Vec3::new(0.0, time.sin(), 0.0),
        );
        let mut vp = world.get_mut::<VertexPositions>(deform).unwrap();
        for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
            *p = *q * (1.0 + 0.3 * (time + q.y * 3.0).sin());
        }
        // Batched requests for this frame.
        let rays: Vec<Ray> = (0..20)
            .map(|_| Ray::new(rand_vec(&mut r, -6.0, 6.0), rand_dir(&mut r)))
            .collect();
        {
            let mut queue = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.iter().enumerate() {
                queue.cast(i as u64, *ray, QueryFilter::default());
            }
        }
        frame(&mut world, &mut schedule);
        let stats = world.resource::<TraceStats>().clone();
        let action = |e: Entity| {
            stats
                .meshes
                .iter()
                .find(|m| m.entity == e)
                .map(|m| m.action)
        };
        if f == 0 {
            assert!(matches!(
                action(stat),
                Some(MeshAction::Rebuild {
                    reason: RebuildReason::New,
                    ..
                })
            ));
        } else {
            assert_eq!(action(stat), None, "frame {f}: the static mesh did work");
            assert_eq!(
                action(rigid),
                Some(MeshAction::Moved),
                "frame {f}: the rigid mesh did BLAS work"
            );
            assert!(
                matches!(
                    action(deform),
                    Some(
                        MeshAction::Refit
                            | MeshAction::Rebuild {
                                reason: RebuildReason::Policy,
                                ..
                            }
                    )
                ),
                "frame {f}: {:?}",
                action(deform)
            );
        }
        // Batched answers equal brute force, as do immediate ones.
        let results = world.resource::<RayResults>().clone();
        assert_eq!(results.hits.len(), rays.len());
        for (i, ray) in rays.iter().enumerate() {
            let expect = brute(&mut world, ray, &QueryFilter::default());
            agree(
                results.hits[i].1.as_ref(),
                expect,
                &format!("frame {f} batched ray {i}"),
            );
            let immediate = world.resource::<TraceWorld>().cast_ray(
                ray,
                f32::INFINITY,
                &QueryFilter::default(),
            );
            agree(
                immediate.as_ref(),
                expect,
                &format!("frame {f} immediate ray {i}"),
            );
            let occluded = world.resource::<TraceWorld>().occluded(
                ray.origin,
                ray.at(4.0),
                &QueryFilter::default(),
            );
            let seg = Ray::segment(ray.origin, ray.at(4.0));
            assert_eq!(
                occluded,
                brute(&mut world, &seg, &QueryFilter::default()).is_some(),
                "frame {f} shadow {i}"
            );
        }
    }
    let stats = world.resource::<TraceStats>();
    assert!(stats.refits + stats.rebuilds == 1);
}

#[test]
fn ray_hits_lists_every_crossing_in_order() {
    let (mut world, mut schedule) = app();
    for x in [0.0f32, 3.0, 6.0] {
        world.spawn((
            TraceMesh(icosphere(2)),
            TraceTransform(Affine3A::from_translation(Vec3::new(x, 0.0, 0.0))),
        ));
    }
    frame(&mut world, &mut schedule);
    let mut hits = Vec::new();
    world.resource::<TraceWorld>().ray_hits(
        &Ray::new(Vec3::new(-5.0, 0.01, 0.02), Vec3::X),
        &QueryFilter::default(),
        &mut hits,
    );
    assert_eq!(hits.len(), 6, "{hits:?}");
    assert!(hits.windows(2).all(|w| w[0].distance <= w[1].distance));
    for (h, expect) in hits.iter().zip([4.0f32, 6.0, 7.0, 9.0, 10.0, 12.0]) {
        assert!(
            (h.distance - expect).abs() < 0.05,
            "{} vs {expect}",
            h.distance
        );
        assert!((h.point - Vec3::new(-5.0, 0.01, 0.02) - Vec3::X * h.distance).length() < 1e-4);
        assert!((h.normal.length() - 1.0).abs() < 1e-5);
    }
}

#[test]
fn filters_respect_layers_exclusions_and_predicates() {
    let (mut world, mut schedule) = app();
    let near = world
        .spawn((TraceMesh(icosphere(2)), QueryLayers(0b01)))
        .id();
    let far = world
        .spawn((
            TraceMesh(icosphere(2)),
            QueryLayers(0b10),
            TraceTransform(Affine3A::from_translation(Vec3::Z * 5.0)),
        ))
        .id();
    frame(&mut world, &mut schedule);
    let ray = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
    let tw = world.resource::<TraceWorld>();
    let hit = |f: QueryFilter| tw.cast_ray(&ray, f32::INFINITY, &f).map(|h| h.entity);
    assert_eq!(hit(QueryFilter::default()), Some(near));
    assert_eq!(hit(QueryFilter::default().layers(0b10)), Some(far));
    assert_eq!(hit(QueryFilter::default().exclude(near)), Some(far));
    assert_eq!(hit(QueryFilter::default().exclude(near).exclude(far)), None);
    assert_eq!(
        hit(QueryFilter::default().predicate(move |e| e == far)),
        Some(far)
    );
    assert_eq!(hit(QueryFilter::default().layers(0b100)), None);
    assert!(!tw.occluded(
        Vec3::new(0.0, 0.0, -5.0),
        Vec3::new(0.0, 0.0, 10.0),
        &QueryFilter::default().layers(0b100)
    ));
    // Changing layers at run time is seen next frame.
    world.get_mut::<QueryLayers>(near).unwrap().0 = 0b10;
    frame(&mut world, &mut schedule);
    let tw = world.resource::<TraceWorld>();
    assert_eq!(
        tw.cast_ray(&ray, f32::INFINITY, &QueryFilter::default().layers(0b10))
            .map(|h| h.entity),
        Some(near)
    );
}

#[test]
fn despawns_leave_no_stale_hits_and_no_leaks() {
    let (mut world, mut schedule) = app();
    let base = world.spawn(TraceMesh(cube_sphere(2))).id();
    frame(&mut world, &mut schedule);
    let baseline_entities = world.entities().count_spawned();
    let ray = Ray::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
    for round in 0..20 {
        let extra: Vec<Entity> = (0..5)
            .map(|i| {
                world
                    .spawn((
                        TraceMesh(icosphere(1)),
                        TraceTransform(Affine3A::from_translation(Vec3::new(
                            0.0,
                            0.0,
                            -8.0 + i as f32 * 0.5,
                        ))),
                    ))
                    .id()
            })
            .collect();
        frame(&mut world, &mut schedule);
        assert_eq!(world.resource::<TraceWorld>().len(), 6);
        let hit = world
            .resource::<TraceWorld>()
            .cast_ray(&ray, f32::INFINITY, &QueryFilter::default())
            .unwrap();
        assert_eq!(hit.entity, extra[0], "round {round}");
        // Despawn mid-loop, some by removing the component instead.
        for (i, e) in extra.iter().enumerate() {
            if i % 2 == 0 {
                world.despawn(*e);
            } else {
                world.entity_mut(*e).remove::<TraceMesh>();
                world.despawn(*e);
            }
        }
        frame(&mut world, &mut schedule);
        let tw = world.resource::<TraceWorld>();
        assert_eq!(tw.len(), 1);
        assert_eq!(tw.tlas().primitive_count(), 1);
        assert_eq!(
            tw.cast_ray(&ray, f32::INFINITY, &QueryFilter::default())
                .unwrap()
                .entity,
            base
        );
    }
    assert_eq!(world.entities().count_spawned(), baseline_entities);
}

#[test]
fn soak_10000_frames_with_spawns_and_despawns_stays_bounded() {
    let (mut world, mut schedule) = app();
    let rest = icosphere(1);
    let mut live: Vec<Entity> = Vec::new();
    let mut r = rng(3);
    let mut peak_nodes = 0;
    for f in 0..10_000u32 {
        if live.len() < 12 || r.random_bool(0.3) {
            let e = world
                .spawn((
                    TraceMesh(rest.clone()),
                    VertexPositions(rest.positions().to_vec()),
                    TraceTransform(Affine3A::from_translation(rand_vec(&mut r, -5.0, 5.0))),
                ))
                .id();
            live.push(e);
        }
        if live.len() > 20 || r.random_bool(0.3) {
            let e = live.swap_remove(r.random_range(0..live.len()));
            world.despawn(e);
        }
        let t = f as f32 * 0.01;
        for &e in &live {
            let mut vp = world.get_mut::<VertexPositions>(e).unwrap();
            for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                *p = *q * (1.0 + 0.2 * (t + q.x * 5.0).sin());
            }
        }
        world.resource_mut::<RayQueue>().cast(
            0,
            Ray::new(Vec3::ZERO, Vec3::X),
            QueryFilter::default(),
        );
        frame(&mut world, &mut schedule);
        let tw = world.resource::<TraceWorld>();
        assert_eq!(tw.len(), live.len());
        peak_nodes = peak_nodes.max(tw.tlas().nodes().len());
        assert!(tw.tlas().nodes().len() <= 2 * 21, "frame {f}");
        assert_eq!(world.resource::<RayResults>().hits.len(), 1);
        assert!(world.resource::<RayQueue>().is_empty());
    }
    assert!(peak_nodes > 0);
    assert!(world.resource::<TraceStats>().meshes.capacity() < 1000);
}

#[test]
fn bad_skins_and_transforms_are_errors_and_the_rest_keeps_working() {
    let (mut world, mut schedule) = app();
    let good = world.spawn(TraceMesh(icosphere(2))).id();
    let m = icosphere(1);
    let n = m.positions().len();
    let weights = Arc::new(SkinWeights {
        joints: vec![[0, 1, 0, 0]; n],
        weights: vec![[0.5, 0.5, 0.0, 0.0]; n],
    });
    let bad_joint = world
        .spawn((
            TraceMesh(m.clone()),
            TraceSkin::new(weights.clone(), vec![Mat4::IDENTITY]),
        ))
        .id();
    let nan = world
        .spawn((
            TraceMesh(m.clone()),
            TraceSkin::new(
                weights.clone(),
                vec![Mat4::IDENTITY, Mat4::from_translation(Vec3::NAN)],
            ),
        ))
        .id();
    let bad_transform = world
        .spawn((
            TraceMesh(m.clone()),
            TraceTransform(Affine3A::from_scale(Vec3::ZERO)),
        ))
        .id();
    // Finite transform and finite mesh, but together past f32's range: no world box.
    let overflow = world
        .spawn((
            TraceMesh(map_mesh(&m, |p| p * 1e38)),
            TraceTransform(Affine3A::from_translation(Vec3::X * 3e38)),
        ))
        .id();
    let ok_skin = world
        .spawn((
            TraceMesh(m.clone()),
            TraceSkin::new(
                weights,
                vec![Mat4::IDENTITY, Mat4::from_translation(Vec3::Y * 9.0)],
            ),
        ))
        .id();
    frame(&mut world, &mut schedule);
    for e in [bad_joint, nan, bad_transform, overflow] {
        assert!(world.get::<TraceError>(e).is_some(), "{e} has no error");
        assert!(!world.resource::<TraceWorld>().contains(e));
    }
    for e in [bad_transform, overflow] {
        let transform_error = &world.get::<TraceError>(e).unwrap().0;
        assert!(
            matches!(transform_error, kinetrace::Error::InvalidTransform(_)),
            "{transform_error:?}"
        );
    }
    let messages = world.resource::<Messages<TraceErrorMessage>>();
    assert_eq!(messages.len(), 4);
    let tw = world.resource::<TraceWorld>();
    assert!(tw.contains(good) && tw.contains(ok_skin));
    // The good skin moved the mesh halfway up: it is hit where the skinned positions are.
    let hit = tw
        .cast_ray(
            &Ray::new(Vec3::new(0.0, 4.5, -5.0), Vec3::Z),
            f32::INFINITY,
            &QueryFilter::default(),
        )
        .unwrap();
    assert_eq!(hit.entity, ok_skin);
    // Fixing the cause and removing the error brings the entity back.
    world.get_mut::<TraceTransform>(bad_transform).unwrap().0 = Affine3A::IDENTITY;
    world.entity_mut(bad_transform).remove::<TraceError>();
    frame(&mut world, &mut schedule);
    assert!(world.resource::<TraceWorld>().contains(bad_transform));
    // An invalid ray is no hit, not a panic.
    assert!(
        world
            .resource::<TraceWorld>()
            .cast_ray(&Ray::new(Vec3::NAN, Vec3::X), 1.0, &QueryFilter::default())
            .is_none()
    );
}

#[test]
fn next_frame_latency_publishes_one_frame_later() {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    KinetracePlugin {
        config: TraceConfig {
            latency: Latency::NextFrame,
            ..Default::default()
        },
        ..Default::default()
    }
    .build(&mut world, &mut schedule);
    world.spawn(TraceMesh(icosphere(2)));
    let ray = Ray::new(Vec3::new(0.0, 0.0, -5.0), Vec3::Z);
    world
        .resource_mut::<RayQueue>()
        .cast(41, ray, QueryFilter::default());
    frame(&mut world, &mut schedule);
    assert!(world.resource::<RayResults>().hits.is_empty());
    frame(&mut world, &mut schedule);
    let r = world.resource::<RayResults>();
    assert_eq!(r.hits.len(), 1);
    assert_eq!(r.hits[0].0, 41);
    assert!(r.hits[0].1.is_some());
    assert_eq!(r.frame, 1, "answers of frame 1's requests");
    frame(&mut world, &mut schedule);
    assert!(
        world.resource::<RayResults>().hits.is_empty(),
        "frame 2 queued nothing"
    );
}

/// Batched answers of the CPU and GPU modes on the same deforming, moving scene.
#[cfg(feature = "gpu")]
#[test]
fn cpu_and_gpu_modes_give_identical_batched_results() {
    if gpu_or_skip().is_none() {
        return;
    }
    for latency in [Latency::SameFrame, Latency::NextFrame] {
        let make = |mode| {
            app_with(TraceConfig {
                mode,
                latency,
                ..Default::default()
            })
        };
        let (mut cpu, mut cs) = make(TraceMode::Cpu);
        let (mut gpu, mut gs) = make(TraceMode::GpuRequired);
        assert!(gpu.get_resource::<GpuQueries>().is_some());
        let rest = icosphere(2);
        let mut ents = vec![];
        for w in [&mut cpu, &mut gpu] {
            ents.push(
                (0..6)
                    .map(|k| {
                        let at = Vec3::new((k % 3) as f32 * 2.5, (k / 3) as f32 * 2.5, 0.0);
                        w.spawn((
                            TraceMesh(rest.clone()),
                            VertexPositions(rest.positions().to_vec()),
                            TraceTransform(Affine3A::from_translation(at)),
                            QueryLayers(1 << (k % 2)),
                        ))
                        .id()
                    })
                    .collect::<Vec<_>>(),
            );
        }
        let mut r = rng(5);
        let mut compared = 0;
        for f in 0..20 {
            let t = f as f32 * 0.1;
            let rays: Vec<Ray> = (0..300)
                .map(|_| {
                    Ray::new(
                        Vec3::new(r.random_range(-2.0..7.0), r.random_range(-2.0..5.0), -6.0),
                        Vec3::new(r.random_range(-0.2..0.2), r.random_range(-0.2..0.2), 1.0),
                    )
                })
                .collect();
            for (w, es) in [(&mut cpu, &ents[0]), (&mut gpu, &ents[1])] {
                for (k, &e) in es.iter().enumerate() {
                    let mut vp = w.get_mut::<VertexPositions>(e).unwrap();
                    for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                        *p = *q * (1.0 + 0.2 * (t + q.y * 4.0 + k as f32).sin());
                    }
                    w.get_mut::<TraceTransform>(e).unwrap().0 = Affine3A::from_rotation_translation(
                        Quat::from_rotation_z(t * 0.3),
                        Vec3::new((k % 3) as f32 * 2.5, (k / 3) as f32 * 2.5, t.sin()),
                    );
                }
                let mut q = w.resource_mut::<RayQueue>();
                for (i, ray) in rays.iter().enumerate() {
                    let filter = match i % 4 {
                        0 => QueryFilter::default(),
                        1 => QueryFilter::default().layers(0b10),
                        2 => QueryFilter::default().exclude(es[0]),
                        _ => {
                            let keep = es[1];
                            QueryFilter::default().predicate(move |e| e != keep) // stays on the CPU
                        }
                    };
                    q.cast(i as u64, *ray, filter.clone());
                    q.shadow(i as u64, ray.origin, ray.at(8.0), filter);
                }
            }
            frame(&mut cpu, &mut cs);
            frame(&mut gpu, &mut gs);
            let (a, b) = (
                cpu.resource::<RayResults>().clone(),
                gpu.resource::<RayResults>().clone(),
            );
            assert_eq!(a.frame, b.frame);
            assert_eq!(a.hits.len(), b.hits.len(), "frame {f}");
            // The worlds' entity ids differ (resources are entities too): compare which spawned mesh was hit.
            let which = |es: &Vec<Entity>, e: Entity| es.iter().position(|&x| x == e);
            for ((ta, ha), (tb, hb)) in a.hits.iter().zip(&b.hits) {
                assert_eq!(ta, tb);
                match (ha, hb) {
                    (None, None) => {}
                    (Some(x), Some(y)) => {
                        assert_eq!(
                            which(&ents[0], x.entity),
                            which(&ents[1], y.entity),
                            "frame {f} ray {ta}: {x:?} vs {y:?}"
                        );
                        assert!(
                            (x.distance - y.distance).abs() <= 1e-5 * x.distance.abs().max(1.0),
                            "frame {f} ray {ta}"
                        );
                        if x.triangle != y.triangle {
                            assert!(
                                (x.distance - y.distance).abs() <= 1e-6 * x.distance.abs().max(1.0),
                                "frame {f} ray {ta}: tie expected"
                            );
                        } else {
                            assert!(
                                (x.normal - y.normal).length() < 1e-4,
                                "frame {f} ray {ta}: normals {x:?} {y:?}"
                            );
                        }
                        assert!(
                            (x.point - y.point).length() < 1e-4 * x.distance.max(1.0),
                            "frame {f} ray {ta}: points {x:?} {y:?}"
                        );
                    }
                    _ => panic!("frame {f} ray {ta}: {ha:?} vs {hb:?}"),
                }
            }
            assert_eq!(a.shadows, b.shadows, "frame {f}");
            compared += a.hits.iter().filter(|h| h.1.is_some()).count();
            if latency == Latency::NextFrame && f == 0 {
                assert!(
                    a.hits.is_empty() && b.hits.is_empty(),
                    "nothing is published before frame 1"
                );
            }
        }
        assert!(
            compared > 1000,
            "{latency:?}: only {compared} hits compared"
        );
    }
}

#[test]
fn profiles_are_refreshed_only_when_the_mesh_changed_enough() {
    let (mut world, mut schedule) = app();
    let stat = world
        .spawn((TraceMesh(icosphere(3)), MotionHint::Static))
        .id();
    let rigid = world
        .spawn((TraceMesh(icosphere(3)), MotionHint::Rigid))
        .id();
    let rest = soup(4, 2_000);
    let scatter = world
        .spawn((
            TraceMesh(rest.clone()),
            VertexPositions(rest.positions().to_vec()),
        ))
        .id();
    let mut r = rng(6);
    let dirs: Vec<Vec3> = (0..rest.triangle_count())
        .map(|_| rand_dir(&mut r))
        .collect();
    let mut refreshed = std::collections::HashMap::<Entity, usize>::new();
    for f in 0..60u32 {
        world.get_mut::<TraceTransform>(rigid).unwrap().0 =
            Affine3A::from_translation(Vec3::X * f as f32 * 0.1);
        let mut vp = world.get_mut::<VertexPositions>(scatter).unwrap();
        for (i, (p, q)) in vp.0.iter_mut().zip(rest.positions()).enumerate() {
            *p = *q + dirs[i / 3] * 0.004 * f as f32;
        }
        frame(&mut world, &mut schedule);
        for (e, p) in &world.resource::<TraceStats>().profiles {
            *refreshed.entry(*e).or_default() += 1;
            assert_eq!(p.primitives, if *e == scatter { 2_000 } else { 1_280 });
        }
    }
    let tw = world.resource::<TraceWorld>();
    // Static and rigid meshes: profiled once, when they arrived.
    assert_eq!(refreshed.get(&stat), Some(&1));
    assert_eq!(refreshed.get(&rigid), Some(&1));
    // The scattering soup: a few refreshes as it degraded (or was rebuilt), far fewer than frames.
    let n = refreshed[&scatter];
    assert!((2..30).contains(&n), "{n} refreshes");
    assert!(tw.profile(scatter).is_some());
    assert!(tw.motion_incoherence(scatter).unwrap() >= 0.0);
    assert_eq!(tw.motion_incoherence(rigid), Some(0.0));
}

/// Bad vertices given to meshes already traced — refitted ahead of their turns, in parallel — fail those
/// meshes with the refit's error (a NaN vertex, a wrong count), out of the world, while a healthy mesh
/// beside them is refitted and answers as brute force does.
#[test]
fn bad_vertices_of_meshes_refitted_ahead_are_errors() {
    let (mut world, mut schedule) = app();
    let m = icosphere(2);
    let at = |x: f32| TraceTransform(Affine3A::from_translation(Vec3::X * x));
    let spawn = |world: &mut World, x: f32| {
        let positions = VertexPositions(m.positions().to_vec());
        world.spawn((TraceMesh(m.clone()), positions, at(x))).id()
    };
    let [nan, short, ok] = [0.0, 4.0, 8.0].map(|x| spawn(&mut world, x));
    frame(&mut world, &mut schedule);
    let grown: Vec<Vec3> = m.positions().iter().map(|p| *p * 1.1).collect();
    for e in [nan, short, ok] {
        world.entity_mut(e).insert(VertexPositions(grown.clone()));
    }
    frame(&mut world, &mut schedule);
    assert_eq!(world.resource::<TraceStats>().refits_ahead, 3);
    let mut bad = grown.clone();
    bad[5].y = f32::NAN;
    world.entity_mut(nan).insert(VertexPositions(bad));
    world
        .entity_mut(short)
        .insert(VertexPositions(grown[1..].to_vec()));
    world.entity_mut(ok).insert(VertexPositions(grown.clone()));
    frame(&mut world, &mut schedule);
    assert_eq!(world.resource::<TraceStats>().refits_ahead, 3);
    let error = |e: Entity| world.get::<TraceError>(e).map(|t| t.0.clone());
    assert!(
        matches!(
            error(nan),
            Some(kinetrace::Error::NonFiniteVertex { vertex: 5, .. })
        ),
        "{:?}",
        error(nan)
    );
    assert!(
        matches!(
            error(short),
            Some(kinetrace::Error::VertexCountMismatch { .. })
        ),
        "{:?}",
        error(short)
    );
    assert!(error(ok).is_none());
    let traced = world.resource::<TraceWorld>();
    assert!(!traced.contains(nan) && !traced.contains(short) && traced.contains(ok));
    for y in [-0.5f32, 0.0, 0.5] {
        let ray = Ray::new(Vec3::new(8.0, y, -5.0), Vec3::Z);
        let got =
            world
                .resource::<TraceWorld>()
                .cast_ray(&ray, f32::INFINITY, &QueryFilter::default());
        let expect = brute(&mut world, &ray, &QueryFilter::default());
        agree(got.as_ref(), expect, &format!("ray at y {y}"));
    }
}
