//! The rebuild policies in the ECS: the adaptive cost model rebuilds when its measurements say so and
//! explains itself in `TraceStats`, a GPU is chosen only where one exists, and whatever a policy does,
//! answers equal brute force.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute};
use common::*;
use glam::Vec3;
use kinetrace::Ray;
use kinetrace::bvh::Builder;
use kinetrace::ecs::*;
use rand::rngs::SmallRng;

fn app(policy: RebuildPolicy, mode: TraceMode) -> (World, Schedule) {
    app_with(TraceConfig {
        policy,
        mode,
        ..Default::default()
    })
}

/// A soup whose vertices random-walk, each on its own: the motion that degrades refitted trees most.
struct Walk {
    entity: Entity,
    rng: SmallRng,
    step: f32,
}

impl Walk {
    fn spawn(world: &mut World, triangles: usize, seed: u64, step: f32) -> Walk {
        let mesh = soup(seed, triangles);
        let entity = world
            .spawn((
                TraceMesh(mesh.clone()),
                VertexPositions(mesh.positions().to_vec()),
            ))
            .id();
        Walk {
            entity,
            rng: rng(seed),
            step,
        }
    }

    fn advance(&mut self, world: &mut World) {
        let mut vp = world.get_mut::<VertexPositions>(self.entity).unwrap();
        for p in vp.0.iter_mut() {
            *p += rand_vec(&mut self.rng, -self.step, self.step);
        }
    }
}

/// Rays through the unit box, where the soup lives.
fn rays(r: &mut SmallRng, n: usize) -> Vec<Ray> {
    (0..n)
        .map(|_| {
            let from = Vec3::splat(0.5) + rand_dir(r) * 2.0;
            let to = rand_vec(r, 0.0, 1.0);
            Ray::new(from, to - from)
        })
        .collect()
}

/// Runs one frame with `n` batched closest-hit requests and checks the first `checked` answers, batched
/// and immediate, against brute force. Returns the mesh's stats of the frame.
fn frame(
    world: &mut World,
    schedule: &mut Schedule,
    walk: &Walk,
    r: &mut SmallRng,
    n: usize,
    checked: usize,
) -> MeshStats {
    let rays = rays(r, n);
    {
        let mut queue = world.resource_mut::<RayQueue>();
        for (i, ray) in rays.iter().enumerate() {
            queue.cast(i as u64, *ray, QueryFilter::default());
        }
    }
    schedule.run(world);
    world.clear_trackers();
    let results = world.resource::<RayResults>().clone();
    let f = world.resource::<TraceStats>().frame;
    for (i, ray) in rays.iter().take(checked).enumerate() {
        let expect = brute(world, ray, &QueryFilter::default());
        agree(
            results.hits[i].1.as_ref(),
            expect,
            &format!("frame {f} batched ray {i}"),
        );
        let immediate =
            world
                .resource::<TraceWorld>()
                .cast_ray(ray, f32::INFINITY, &QueryFilter::default());
        agree(
            immediate.as_ref(),
            expect,
            &format!("frame {f} immediate ray {i}"),
        );
    }
    let stats = world.resource::<TraceStats>();
    *stats
        .meshes
        .iter()
        .find(|m| m.entity == walk.entity)
        .expect("the mesh moved, so it did work")
}

/// The frames (after the first) at which the adaptive policy rebuilt the walking soup, under `n` rays
/// per frame; checks every decision against the grounds it gives.
fn policy_rebuilds(n: usize, frames: u32) -> Vec<u32> {
    let lbvh_only = RebuildPolicy::Adaptive {
        builders: &[Builder::LBVH],
    };
    let (mut world, mut schedule) = app(lbvh_only, TraceMode::Cpu);
    let mut walk = Walk::spawn(&mut world, 2000, 7, 0.01);
    let mut r = rng(11);
    let mut rebuilt = vec![];
    for f in 0..frames {
        walk.advance(&mut world);
        let m = frame(&mut world, &mut schedule, &walk, &mut r, n, 4);
        if f == 0 {
            assert!(matches!(
                m.action,
                MeshAction::Rebuild {
                    reason: RebuildReason::New,
                    ..
                }
            ));
            continue;
        }
        let p = m
            .prediction
            .expect("the adaptive policy explains every refit");
        assert_eq!(p.build, Build::cpu(Builder::LBVH), "the one build offered");
        match (m.action, p.verdict) {
            (MeshAction::Refit, Verdict::Keep) => assert!(p.rent_s <= p.rebuild_s, "{p:?}"),
            (MeshAction::Rebuild { build, reason }, v) => {
                assert_eq!((build, reason), (p.build, RebuildReason::Policy));
                match v {
                    Verdict::Guard => assert!(p.sah > 1.4 * p.fresh_sah, "{p:?}"),
                    Verdict::Rent => assert!(p.rent_s > p.rebuild_s, "{p:?}"),
                    _ => panic!("frame {f}: rebuilt on {v:?}"),
                }
                rebuilt.push(f);
            }
            other => panic!("frame {f}: {other:?}"),
        }
        if n == 0 {
            assert_eq!(p.rent_s, 0.0, "no rays, no rent");
        }
    }
    rebuilt
}

#[test]
fn adaptive_rebuilds_sooner_the_more_rays_a_degraded_tree_costs() {
    let many = policy_rebuilds(4000, 40);
    let none = policy_rebuilds(0, 40);
    assert!(
        !many.is_empty(),
        "a degrading tree under many rays is rebuilt"
    );
    assert!(
        many.len() > none.len(),
        "many rays: {many:?}; none: {none:?}"
    );
    assert!(
        none.first().is_none_or(|&f| f > many[0]),
        "without rays the tree is refitted longer: many {many:?}, none {none:?}"
    );
}

/// Runs `frames` frames of a walking soup under `policy` and `mode` with 200 rays a frame (20 checked
/// against brute force); returns the mesh's stats of every frame.
fn run(policy: RebuildPolicy, mode: TraceMode, frames: u32) -> Vec<MeshStats> {
    let (mut world, mut schedule) = app(policy, mode);
    let mut walk = Walk::spawn(&mut world, 1000, 3, 0.01);
    let mut r = rng(5);
    (0..frames)
        .map(|_| {
            walk.advance(&mut world);
            frame(&mut world, &mut schedule, &walk, &mut r, 200, 20)
        })
        .collect()
}

fn rebuilds(stats: &[MeshStats]) -> impl Iterator<Item = (usize, Build, RebuildReason)> + '_ {
    stats
        .iter()
        .enumerate()
        .filter_map(|(f, m)| match m.action {
            MeshAction::Rebuild { build, reason } => Some((f, build, reason)),
            _ => None,
        })
}

#[test]
fn lauterbach_rebuilds_exactly_past_its_threshold_and_explains_nothing_more() {
    for (policy, threshold) in [
        (RebuildPolicy::Lauterbach { threshold: 0.1 }, 0.1),
        (RebuildPolicy::LAUTERBACH, 0.4),
        (RebuildPolicy::Custom(lauterbach_policy), 0.4),
    ] {
        let stats = run(policy, TraceMode::Cpu, 30);
        for (f, m) in stats.iter().enumerate().skip(1) {
            let expect = if m.degradation > threshold {
                MeshAction::Rebuild {
                    build: Build::cpu(Builder::LBVH),
                    reason: RebuildReason::Policy,
                }
            } else {
                MeshAction::Refit
            };
            assert_eq!(m.action, expect, "{policy:?} frame {f}: {}", m.degradation);
            assert_eq!(m.prediction, None);
        }
    }
}

fn always_gpu_lbvh(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build::GPU_LBVH)
}

fn always_gpu_sah(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build {
        builder: Builder::SAH,
        device: Device::Gpu,
    })
}

#[test]
fn without_a_gpu_every_build_runs_on_the_cpu() {
    let stats = run(RebuildPolicy::ADAPTIVE, TraceMode::Cpu, 30);
    for (f, build, _) in rebuilds(&stats) {
        assert_eq!(build.device, Device::Cpu, "adaptive, frame {f}");
    }
    assert!(
        stats
            .iter()
            .filter_map(|m| m.prediction)
            .all(|p| p.build.device == Device::Cpu)
    );
    // Every builder offered was tried: the policy explores, on the CPU only.
    let tried: Vec<Builder> = rebuilds(&stats).map(|(_, b, _)| b.builder).collect();
    for b in [Builder::LBVH, Builder::HYBRID, Builder::SAH] {
        assert!(tried.contains(&b), "{b:?} untried: {tried:?}");
    }
    // A custom policy asking for the GPU gets the same builder on the CPU.
    for (policy, expect) in [
        (always_gpu_lbvh as Policy, Builder::LBVH),
        (always_gpu_sah, Builder::SAH),
    ] {
        let stats = run(RebuildPolicy::Custom(policy), TraceMode::Cpu, 5);
        let asked: Vec<_> = rebuilds(&stats)
            .filter(|r| r.2 == RebuildReason::Policy)
            .map(|r| r.1)
            .collect();
        assert_eq!(asked, vec![Build::cpu(expect); 4]);
    }
}

/// With a GPU, the adaptive policy measures GPU LBVH too, and GPU-built trees answer like brute force.
#[cfg(feature = "gpu")]
#[test]
fn with_a_gpu_the_adaptive_policy_tries_it_and_answers_stay_exact() {
    if gpu_or_skip().is_none() {
        return;
    }
    let lbvh = RebuildPolicy::Adaptive {
        builders: &[Builder::LBVH],
    };
    let stats = run(lbvh, TraceMode::GpuRequired, 12);
    let built: Vec<_> = rebuilds(&stats).collect();
    assert_eq!(
        built[0],
        (0, Build::cpu(Builder::LBVH), RebuildReason::New),
        "the first offered build first"
    );
    assert_eq!(
        built[1],
        (1, Build::GPU_LBVH, RebuildReason::Policy),
        "then the untried GPU build"
    );
    assert_eq!(
        stats[1].prediction.map(|p| p.verdict),
        Some(Verdict::Explore)
    );
    // A policy may ask for the GPU every time; a GPU build of anything but LBVH runs on the CPU.
    for (policy, expect) in [
        (always_gpu_lbvh as Policy, Build::GPU_LBVH),
        (always_gpu_sah, Build::cpu(Builder::SAH)),
    ] {
        let stats = run(RebuildPolicy::Custom(policy), TraceMode::GpuRequired, 6);
        for (f, build, reason) in rebuilds(&stats).skip(1) {
            assert_eq!(
                (build, reason),
                (expect, RebuildReason::Policy),
                "frame {f}"
            );
        }
    }
}

#[test]
fn switching_to_the_adaptive_policy_at_run_time_rebuilds_once_to_measure() {
    let never = RebuildPolicy::Lauterbach {
        threshold: f32::INFINITY,
    };
    let (mut world, mut schedule) = app(never, TraceMode::Cpu);
    let mut walk = Walk::spawn(&mut world, 500, 9, 0.001);
    let mut r = rng(2);
    let mut step = |world: &mut World| {
        walk.advance(world);
        frame(world, &mut schedule, &walk, &mut r, 50, 10)
    };
    for _ in 0..3 {
        step(&mut world);
    }
    world.resource_mut::<TraceConfig>().policy = RebuildPolicy::Adaptive {
        builders: &[Builder::SAH],
    };
    let first = step(&mut world);
    assert_eq!(
        (first.action, first.prediction),
        (
            MeshAction::Rebuild {
                build: Build::cpu(Builder::SAH),
                reason: RebuildReason::Policy
            },
            None
        )
    );
    let next = step(&mut world);
    assert_eq!(
        next.action,
        MeshAction::Refit,
        "a fresh SAH tree, barely moved"
    );
    assert_eq!(
        next.prediction.map(|p| p.build),
        Some(Build::cpu(Builder::SAH))
    );
}
