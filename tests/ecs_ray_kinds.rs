//! Ray kinds in the batched queries (issue 13): shadow rays toward two lights (one inside a mesh) and
//! reflection rays from primary hits, queued among primary requests, are answered as world-space brute
//! force (the independent exact oracle) answers them, whichever secondary strategy traces them — plain BVH,
//! sorted BVH or CRSH, fixed or picked by the planner — in a closed room with moving and deforming meshes,
//! with rays starting on surfaces and rays with zero direction components. Every answer keeps its
//! request's tag and place.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{app_with, world_triangles};
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use kinetrace::scenes::{folded_sheet, icosphere, shoebox};

/// One request as queued: closest hit (`Ray`) or occlusion (`from`, `to`), its kind and filter.
#[derive(Clone)]
enum Request {
    Cast(Ray, RequestKind, QueryFilter),
    Shadow(Vec3, Vec3, RequestKind, QueryFilter),
}

/// Queues `requests` with tags `1000 + i`, runs a frame, and returns the results.
fn run(world: &mut World, schedule: &mut Schedule, requests: &[Request]) -> RayResults {
    {
        let mut q = world.resource_mut::<RayQueue>();
        for (i, r) in requests.iter().enumerate() {
            let tag = 1000 + i as u64;
            match r.clone() {
                Request::Cast(ray, kind, f) => q.cast_kind(tag, ray, kind, f),
                Request::Shadow(from, to, kind, f) => q.shadow_kind(tag, from, to, kind, f),
            }
        }
    }
    schedule.run(world);
    world.clear_trackers();
    world.resource::<RayResults>().clone()
}

/// The oracle's verdict on a closest-hit answer over the world triangles keyed by `keys`
/// (`(entity, triangle)`): the answer is one an `f32` watertight test may give — no certain hit missed,
/// the triangle reported hit or disputed, at its exact distance and no farther than any certain hit, to
/// the oracle's bound plus the world's object-space rounding (1e-4 relative, as
/// [`common::ecs::agree`]).
fn check_closest(oracle: &RayOracle, keys: &[(Entity, u32)], got: Option<&RayHit>, what: &str) {
    let slack = |t: f64| 1e-4 * t.abs().max(1.0);
    let certain: Vec<_> = (0..keys.len() as u32)
        .filter_map(|i| oracle.verdict(i))
        .filter(|v| v.hit && v.certain)
        .collect();
    let Some(h) = got else {
        assert!(certain.is_empty(), "{what}: missed {:?}", certain[0]);
        return;
    };
    let k = (keys.iter().position(|&key| key == (h.entity, h.triangle))).expect("a known triangle");
    let v = (oracle.verdict(k as u32)).unwrap_or_else(|| panic!("{what}: {h:?} is a certain miss"));
    assert!(v.hit || !v.certain, "{what}: {h:?} not hit {v:?}");
    let t = h.distance as f64;
    assert!(
        (t - v.t).abs() <= v.t_err + slack(v.t),
        "{what}: {h:?} vs exactly {}",
        v.t
    );
    for w in certain {
        assert!(
            t <= w.t + w.t_err + slack(w.t),
            "{what}: {h:?}, but {w:?} is nearer"
        );
    }
}

/// The scene: a closed room (identity), three spheres moving rigidly (one scaled unevenly), a deforming
/// cloth, and a sphere around the second light.
struct Scene {
    movers: Vec<Entity>,
    cloth: Entity,
    /// The sphere around the second light.
    lamp: Entity,
    rest: kinetrace::Mesh,
    lights: [Vec3; 2],
}

impl Scene {
    fn spawn(world: &mut World) -> Scene {
        world.spawn((
            TraceMesh(shoebox(Vec3::splat(-6.0), Vec3::splat(6.0))),
            MotionHint::Static,
        ));
        let movers = (0..3)
            .map(|_| {
                world
                    .spawn((TraceMesh(icosphere(2)), MotionHint::Rigid))
                    .id()
            })
            .collect();
        let rest = folded_sheet(12, 0.0);
        let cloth = world
            .spawn((
                TraceMesh(rest.clone()),
                VertexPositions(rest.positions().to_vec()),
                TraceTransform(Affine3A::from_scale_rotation_translation(
                    Vec3::splat(3.0),
                    Quat::IDENTITY,
                    Vec3::new(0.0, -3.0, 0.0),
                )),
            ))
            .id();
        let lights = [Vec3::new(2.0, 5.0, -1.0), Vec3::new(-3.0, 2.0, 3.0)];
        // The second light sits inside a sphere: every segment toward it is occluded by that sphere.
        let lamp = world
            .spawn((
                TraceMesh(icosphere(1)),
                MotionHint::Static,
                TraceTransform(Affine3A::from_scale_rotation_translation(
                    Vec3::splat(0.5),
                    Quat::IDENTITY,
                    lights[1],
                )),
            ))
            .id();
        Scene {
            movers,
            cloth,
            lamp,
            rest,
            lights,
        }
    }

    fn animate(&self, world: &mut World, time: f32) {
        for (k, &e) in self.movers.iter().enumerate() {
            let a = time + k as f32 * 2.1;
            let scale = if k == 0 {
                Vec3::new(1.5, 0.7, 1.0)
            } else {
                Vec3::splat(0.8 + 0.3 * k as f32)
            };
            world.get_mut::<TraceTransform>(e).unwrap().0 =
                Affine3A::from_scale_rotation_translation(
                    scale,
                    Quat::from_rotation_y(a),
                    Vec3::new(3.0 * a.cos(), 0.5 * k as f32 - 0.5, 3.0 * a.sin()),
                );
        }
        let mut vp = world.get_mut::<VertexPositions>(self.cloth).unwrap();
        for (p, q) in vp.0.iter_mut().zip(self.rest.positions()) {
            *p = *q + Vec3::Y * 0.3 * (time + q.x * 3.0).sin();
        }
    }

    /// Primary camera rays, and from their hits (found through the world, which the oracle then
    /// judges) shadow segments from each light to the hit point (and one more queued as a primary
    /// request) and reflection rays starting on the surface, each request through one of three filters
    /// in turn — every entity, all but the second light's sphere, all but the cloth — so that
    /// neighbouring requests, which the queue walks together, see different entities; interleaved,
    /// with rays along the axes (zero direction components) and an invalid one.
    fn requests(&self, world: &World, r: &mut rand::rngs::SmallRng) -> Vec<Request> {
        let tw = world.resource::<TraceWorld>();
        let all = QueryFilter::default();
        let eye = Vec3::new(0.5, 1.0, -5.5);
        let mut out = Vec::new();
        let (lamp, cloth) = (self.lamp, self.cloth);
        let filters = [
            all.clone(),
            QueryFilter::default().exclude(lamp),
            QueryFilter::default().predicate(move |e| e != cloth),
        ];
        // Neighbouring requests see different entities.
        let next = |out: &Vec<Request>| filters[out.len() % 3].clone();
        for ray in camera(eye, Vec3::ZERO, 16, 4, 1.2) {
            out.push(Request::Cast(ray, RequestKind::Primary, next(&out)));
            let Some(h) = tw.cast_ray(&ray, f32::INFINITY, &all) else {
                continue;
            };
            // On the untransformed room, rays start exactly at the hit point (on the surface, to f32
            // rounding). On transformed entities the world traces in object space, whose rounding at
            // t ≈ 0 the world-space oracle cannot judge: there they start 1e-3 off the surface.
            let placed = world.get::<TraceTransform>(h.entity).unwrap().0;
            let facing = -h.normal * ray.dir().dot(h.normal).signum();
            let point = if placed == Affine3A::IDENTITY {
                h.point
            } else {
                h.point + 1e-3 * facing
            };
            let kinds = (0..2).map(|k| RequestKind::Shadow { light: k });
            for (k, kind) in kinds.chain([RequestKind::Primary]).enumerate() {
                let light = self.lights[k % 2 + k / 2];
                out.push(Request::Shadow(light, point, kind, next(&out)));
            }
            let d = ray.dir() - 2.0 * ray.dir().dot(h.normal) * h.normal;
            let reflected = Ray::new(point, d);
            out.push(Request::Cast(
                reflected,
                RequestKind::Reflection,
                next(&out),
            ));
        }
        // Axis rays from random points, a filtered reflection ray and an invalid one.
        for k in 0..24 {
            let mut d = Vec3::ZERO;
            d[k % 3] = if k % 2 == 0 { 1.0 } else { -1.0 };
            let o = rand_vec(r, -4.0, 4.0);
            out.push(Request::Cast(
                Ray::new(o, d),
                RequestKind::Reflection,
                all.clone(),
            ));
        }
        let skip_cloth = QueryFilter::default().exclude(self.cloth);
        let o = Vec3::new(0.0, 4.0, 0.0);
        out.push(Request::Cast(
            Ray::new(o, -Vec3::Y),
            RequestKind::Reflection,
            skip_cloth,
        ));
        out.push(Request::Cast(
            Ray::new(Vec3::NAN, Vec3::Y),
            RequestKind::Reflection,
            all.clone(),
        ));
        out.push(Request::Shadow(
            self.lights[0],
            self.lights[0],
            RequestKind::Shadow { light: 0 },
            all,
        ));
        out
    }
}

/// Whether a request is a closest-hit one.
fn is_cast(r: &Request) -> bool {
    matches!(r, Request::Cast(..))
}

/// Checks `results` against `requests`: tags in queue order, answers the oracle allows.
fn check(world: &mut World, requests: &[Request], results: &RayResults, what: &str) -> usize {
    let casts = requests.iter().filter(|r| is_cast(r)).count();
    assert_eq!(results.hits.len(), casts, "{what}");
    assert_eq!(results.shadows.len(), requests.len() - casts, "{what}");
    let (mut hits, mut shadows) = (results.hits.iter(), results.shadows.iter());
    let mut found = 0;
    for (i, r) in requests.iter().enumerate() {
        let what = format!("{what} request {i}");
        let tag = 1000 + i as u64;
        match r {
            Request::Cast(ray, _, filter) => {
                let (t, got) = hits.next().unwrap();
                assert_eq!(*t, tag, "{what}");
                let (keys, tris) = world_triangles(world, filter);
                check_closest(&RayOracle::new(ray, tris), &keys, got.as_ref(), &what);
                found += got.is_some() as usize;
            }
            Request::Shadow(from, to, _, filter) => {
                let (t, got) = shadows.next().unwrap();
                assert_eq!(*t, tag, "{what}");
                let (_, tris) = world_triangles(world, filter);
                RayOracle::new(&Ray::segment(*from, *to), tris).check_any(*got, &what);
                found += *got as usize;
            }
        }
    }
    found
}

#[test]
fn every_secondary_strategy_answers_as_brute_force() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let scene = Scene::spawn(&mut world);
    let mut r = rng(13);
    for f in 0..2 {
        scene.animate(&mut world, f as f32 * 0.7);
        schedule.run(&mut world);
        world.clear_trackers();
        let requests = scene.requests(&world, &mut r);
        assert!(requests.len() > 500, "{} requests", requests.len());
        for strategy in [
            SecondaryStrategy::Bvh,
            SecondaryStrategy::SortedBvh,
            SecondaryStrategy::SortedPackets,
            SecondaryStrategy::SortedRuns,
            SecondaryStrategy::Crsh,
        ] {
            world.insert_resource(SecondaryRays::fixed(strategy));
            let results = run(&mut world, &mut schedule, &requests);
            let found = check(
                &mut world,
                &requests,
                &results,
                &format!("{f} {strategy:?}"),
            );
            assert!(found > 400, "frame {f} {strategy:?}: {found} answers found");
        }
    }
}

#[test]
fn crsh_shapes_answer_as_brute_force() {
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    let scene = Scene::spawn(&mut world);
    scene.animate(&mut world, 0.3);
    schedule.run(&mut world);
    world.clear_trackers();
    let requests = scene.requests(&world, &mut rng(5));
    for (branching, depth) in [(16, 3), (3, 1)] {
        let config = SecondaryRays::new(
            Some(SecondaryStrategy::Crsh),
            kinetrace::raysort::KeyLayout::default(),
            branching,
            depth,
        )
        .unwrap();
        world.insert_resource(config);
        let results = run(&mut world, &mut schedule, &requests);
        check(
            &mut world,
            &requests,
            &results,
            &format!("s{branching} D{depth}"),
        );
    }
    let bad = SecondaryRays::new(None, kinetrace::raysort::KeyLayout::default(), 1, 2);
    assert!(matches!(bad, Err(kinetrace::Error::InvalidOption(_))));
}

/// Eight frames of the scene's requests under `secondary` (answers checked every fourth frame): each
/// frame's secondary picks and whether each was a try, after asserting one pick per batch, both batches
/// present, no entity (a batch choice).
fn planned_frames(secondary: SecondaryRays) -> Vec<(SecondaryStrategy, bool)> {
    // The default policy: the batch planner needs no adaptive rebuild policy.
    let (mut world, mut schedule) = app_with(TraceConfig::default());
    world.insert_resource(secondary);
    let scene = Scene::spawn(&mut world);
    let mut r = rng(21);
    let mut picked = Vec::new();
    for f in 0..8 {
        scene.animate(&mut world, f as f32 * 0.2);
        schedule.run(&mut world);
        world.clear_trackers();
        let requests = scene.requests(&world, &mut r);
        assert!(requests.len() < MIN_TRIED_RAYS);
        let results = run(&mut world, &mut schedule, &requests);
        if f % 4 == 3 {
            check(&mut world, &requests, &results, &format!("frame {f}"));
        }
        let stats = world.resource::<TraceStats>();
        let batches: Vec<_> = (stats.options.iter())
            .filter_map(|o| match o.option {
                PlannedOption::Secondary(b, s) => Some((b, s, o.entity, o.tried)),
                _ => None,
            })
            .collect();
        assert_eq!(batches.len(), 2, "frame {f}: {batches:?}");
        assert!(batches.iter().any(|b| b.0 == RayBatch::Closest));
        assert!(batches.iter().any(|b| b.0 == RayBatch::Occlusion));
        assert!(batches.iter().all(|b| b.2 == Entity::PLACEHOLDER));
        picked.extend(batches.iter().map(|b| (b.1, b.3)));
    }
    picked
}

#[test]
fn planner_picks_per_batch_and_answers_stay_exact() {
    // The scene's batches are far below MIN_TRIED_RAYS: tries on every batch.
    let picked = planned_frames(SecondaryRays::default().tries_from(0));
    // The sorting strategies' priors predict them cheaper than the BVH, so one of them is tried once the
    // BVH has a measurement, whatever the times: which one, and whether the others follow, depends on what
    // the first measured (the sorted BVH comes first; measured cheap, it can keep sorted packets and runs
    // from looking cheaper than the option chosen).
    assert!(
        picked.iter().any(|&(s, tried)| tried
            && matches!(
                s,
                SecondaryStrategy::SortedBvh
                    | SecondaryStrategy::SortedPackets
                    | SecondaryStrategy::SortedRuns
            )),
        "{picked:?}"
    );
}

#[test]
fn small_batches_try_nothing() {
    // Both batches planned every frame, neither tried: the BVH, learned.
    let picked = planned_frames(SecondaryRays::default());
    assert!(
        (picked.iter()).all(|&p| p == (SecondaryStrategy::Bvh, false)),
        "{picked:?}"
    );
}

#[test]
fn primary_only_frames_plan_nothing() {
    let config = TraceConfig {
        policy: RebuildPolicy::ADAPTIVE,
        ..Default::default()
    };
    let (mut world, mut schedule) = app_with(config);
    let scene = Scene::spawn(&mut world);
    schedule.run(&mut world);
    let requests: Vec<Request> = scene
        .requests(&world, &mut rng(2))
        .into_iter()
        .filter(|r| matches!(r, Request::Cast(_, RequestKind::Primary, _)))
        .collect();
    let results = run(&mut world, &mut schedule, &requests);
    check(&mut world, &requests, &results, "primary");
    let stats = world.resource::<TraceStats>();
    assert!(
        !(stats.options.iter()).any(|o| matches!(o.option, PlannedOption::Secondary(..))),
        "{:?}",
        stats.options
    );
}
