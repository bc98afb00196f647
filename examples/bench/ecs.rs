//! Suite `ecs`: frame cost of the plugin for 1, 10 and 100 deforming meshes of 10k triangles with 10k
//! batched rays, under Lauterbach's policy and the adaptive one, split by phase; the ECS layer's own
//! overhead (frame time minus the work of the phases: scheduling, change detection, bookkeeping); the
//! frame time of an idle world of 1,000 static meshes; and 10k queued shadow requests between random
//! points among 10 (100) meshes, whose runs of single requests the queue walks four at a time,
//! interleaved, against the same segments through `TraceWorld::occluded` one by one on all threads.

use crate::record::Records;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::ecs::*;
use kinetrace::scenes::{SceneRng, bumpy_torus};
use std::time::{Duration, Instant};

const SUITE: &str = "ecs";

pub fn run(rec: &mut Records) {
    println!("suite ecs on {}", crate::record::machine());
    let counts: &[usize] = if rec.quick { &[1, 10] } else { &[1, 10, 100] };
    let frames = if rec.quick { 10 } else { 30 };
    for &n in counts {
        for policy in [RebuildPolicy::LAUTERBACH, RebuildPolicy::ADAPTIVE] {
            deforming(rec, n, frames, policy);
        }
    }
    idle(rec, if rec.quick { 200 } else { 1000 });
    shadow_requests(rec, if rec.quick { 10 } else { 100 }, frames);
}

/// `n` static bumpy tori of 10k triangles in rows 3 units apart, and 10k shadow segments between random
/// points among them (scattered, as gameplay's line-of-sight checks are): the batched queries phase per
/// frame against `occluded` one by one on all threads, same segments, same answers (asserted); medians
/// over `frames` frames, which a shared machine disturbs less than means.
fn shadow_requests(rec: &mut Records, n: usize, frames: usize) {
    use rayon::prelude::*;
    let scene = format!("{n} static x 10k tris + 10k queued shadow segments");
    println!("\n{scene}");
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE);
    let rest = bumpy_torus(10_000);
    let side = (n as f32).sqrt().ceil() as usize;
    for i in 0..n {
        let at = Vec3::new((i % side) as f32 * 3.0, 0.0, (i / side) as f32 * 3.0);
        world.spawn((
            TraceMesh(rest.clone()),
            TraceTransform(Affine3A::from_translation(at)),
        ));
    }
    let mut r = SceneRng::new(2);
    let extent = side as f32 * 3.0;
    let mut point = || {
        Vec3::new(
            r.range(-1.5, extent),
            r.range(-1.0, 1.0),
            r.range(-1.5, extent),
        )
    };
    let segments: Vec<(Vec3, Vec3)> = (0..10_000).map(|_| (point(), point())).collect();
    let (mut queued, mut answers) = (Vec::new(), Vec::new());
    for f in 0..frames + 2 {
        let mut queue = world.resource_mut::<RayQueue>();
        for (i, &(from, to)) in segments.iter().enumerate() {
            queue.shadow(i as u64, from, to, QueryFilter::default());
        }
        schedule.run(&mut world);
        world.clear_trackers();
        if f >= 2 {
            queued.push(world.resource::<TraceStats>().query_time);
        }
        answers = world.resource::<RayResults>().shadows.clone();
    }
    let tw = world.resource::<TraceWorld>();
    let all = QueryFilter::default();
    let (mut one_by_one, mut blocked) = (Vec::new(), Vec::new());
    for _ in 0..frames {
        let t = Instant::now();
        blocked = (segments.par_iter())
            .map(|&(from, to)| tw.occluded(from, to, &all))
            .collect();
        one_by_one.push(t.elapsed());
    }
    assert!(
        answers.iter().map(|a| a.1).eq(blocked.iter().copied()),
        "the queue and `occluded` disagree"
    );
    let median = |mut t: Vec<Duration>| {
        t.sort();
        t[t.len() / 2].as_secs_f64() * 1e3
    };
    let (queued, one_by_one) = (median(queued), median(one_by_one));
    rec.add(SUITE, &scene, "queued, interleaved", "phase", queued, "ms");
    rec.add(
        SUITE,
        &scene,
        "occluded one by one",
        "time",
        one_by_one,
        "ms",
    );
    rec.add(
        SUITE,
        &scene,
        "queued vs one by one",
        "speedup",
        one_by_one / queued,
        "x",
    );
    println!(
        "  {} of {} blocked",
        blocked.iter().filter(|&&b| b).count(),
        blocked.len()
    );
}

/// The plugin's systems run in a chain, so a single-threaded executor suits them: the multi-threaded one
/// costs tens of microseconds per frame in thread wake-ups alone. (Queries still use all threads.)
fn app(policy: RebuildPolicy) -> (World, Schedule) {
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    let config = TraceConfig {
        policy,
        ..Default::default()
    };
    KinetracePlugin {
        config,
        ..Default::default()
    }
    .build(&mut world, &mut schedule);
    (world, schedule)
}

fn deforming(rec: &mut Records, n: usize, frames: usize, policy: RebuildPolicy) {
    let name = match policy {
        RebuildPolicy::Adaptive { .. } => "adaptive",
        _ => "lauterbach 0.4",
    };
    let scene = format!("{n} deforming x 10k tris + 10k rays, {name}");
    println!("\n{scene}");
    let (mut world, mut schedule) = app(policy);
    let rest = bumpy_torus(10_000);
    let ents: Vec<Entity> = (0..n)
        .map(|i| {
            let at = Vec3::new((i % 10) as f32 * 3.0, 0.0, (i / 10) as f32 * 3.0);
            world
                .spawn((
                    TraceMesh(rest.clone()),
                    VertexPositions(rest.positions().to_vec()),
                    TraceTransform(Affine3A::from_translation(at)),
                ))
                .id()
        })
        .collect();
    let mut r = SceneRng::new(1);
    // Rays down onto the meshes, most of which hit.
    let rays: Vec<Ray> = (0..10_000)
        .map(|i| {
            let m = i % n;
            let at = Vec3::new(
                (m % 10) as f32 * 3.0 + r.range(-1.4, 1.4),
                3.0,
                (m / 10) as f32 * 3.0 + r.range(-1.4, 1.4),
            );
            Ray::new(at, Vec3::new(r.range(-0.2, 0.2), -1.0, r.range(-0.2, 0.2)))
        })
        .collect();
    let (mut total, mut phases, mut maintain, mut top, mut queries) = (
        Duration::ZERO,
        Duration::ZERO,
        Duration::ZERO,
        Duration::ZERO,
        Duration::ZERO,
    );
    let mut rebuilds = 0;
    // Untimed: the first frame builds everything; under the adaptive policy the next three try each of its
    // builders once (a one-time cost per mesh).
    let warm = 4;
    for f in 0..frames + warm {
        let t = f as f32 * 0.05;
        for &e in &ents {
            let mut vp = world.get_mut::<VertexPositions>(e).expect("spawned");
            for (p, q) in vp.0.iter_mut().zip(rest.positions()) {
                *p = *q * (1.0 + 0.05 * (t + q.x * 3.0).sin());
            }
        }
        {
            let mut queue = world.resource_mut::<RayQueue>();
            for (i, ray) in rays.iter().enumerate() {
                queue.cast(i as u64, *ray, QueryFilter::default());
            }
        }
        let start = Instant::now();
        schedule.run(&mut world);
        world.clear_trackers();
        let elapsed = start.elapsed();
        if f < warm {
            continue;
        }
        let s = world.resource::<TraceStats>();
        total += elapsed;
        maintain += s.maintain_time;
        top += s.top_level_time;
        queries += s.query_time;
        rebuilds += s.rebuilds;
        phases += s.skin_time + s.maintain_time + s.top_level_time + s.query_time;
    }
    let per = |d: Duration| d.as_secs_f64() * 1e3 / frames as f64;
    rec.add(SUITE, &scene, "frame", "total", per(total), "ms");
    rec.add(
        SUITE,
        &scene,
        "maintain (refit/rebuild)",
        "phase",
        per(maintain),
        "ms",
    );
    rec.add(
        SUITE,
        &scene,
        "rebuilds",
        "count",
        rebuilds as f64,
        "in the timed frames",
    );
    rec.add(SUITE, &scene, "top level", "phase", per(top), "ms");
    rec.add(
        SUITE,
        &scene,
        "batched queries",
        "phase",
        per(queries),
        "ms",
    );
    let overhead = per(total) - per(phases);
    rec.add(SUITE, &scene, "ECS layer overhead", "time", overhead, "ms");
    rec.add(
        SUITE,
        &scene,
        "ECS layer overhead",
        "share",
        100.0 * overhead / per(total),
        "% (target < 5)",
    );
}

fn idle(rec: &mut Records, n: usize) {
    let scene = format!("idle world, {n} static meshes");
    println!("\n{scene}");
    let (mut world, mut schedule) = app(RebuildPolicy::LAUTERBACH);
    let mesh = bumpy_torus(500);
    for i in 0..n {
        let at = Vec3::new((i % 32) as f32 * 3.0, 0.0, (i / 32) as f32 * 3.0);
        world.spawn((
            TraceMesh(mesh.clone()),
            MotionHint::Static,
            TraceTransform(Affine3A::from_translation(at)),
        ));
    }
    // Untimed: the first frame builds every tree, the second characterises every mesh (once).
    for _ in 0..2 {
        schedule.run(&mut world);
        world.clear_trackers();
    }
    let frames = 200;
    let start = Instant::now();
    for _ in 0..frames {
        schedule.run(&mut world);
        world.clear_trackers();
    }
    let per = start.elapsed().as_secs_f64() * 1e6 / frames as f64;
    rec.add(SUITE, &scene, "frame", "total", per, "us (target < 50)");
}
