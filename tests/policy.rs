//! The rebuild policies in the ECS: the adaptive cost model rebuilds when its measurements say so and
//! explains itself in `TraceStats`, a GPU is chosen only where one exists, and whatever a policy does,
//! answers equal brute force.

mod common;
#[allow(dead_code)] // the report's grid rows: the harness names them, the adaptive strategy runs here
#[path = "../examples/report/grid_rows.rs"]
mod grid_rows;
#[allow(dead_code)] // the report's harness: only the adaptive strategy runs here
#[path = "../examples/report/harness.rs"]
mod harness;
#[allow(dead_code)] // the report's option rows: the harness names them
#[path = "../examples/report/option_rows.rs"]
mod option_rows;
#[allow(dead_code)]
#[path = "../examples/report/scenes.rs"]
mod scenes;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute, scripted_cost};
use common::*;
use glam::Vec3;
use kinetrace::Ray;
use kinetrace::adaptive::{
    AdaptivePolicy, Asset, Choice, CostTable, DEFAULT_SAH_BOUND, DEFAULT_Z, Verdict,
};
use kinetrace::bvh::{BuildOptions, Builder, MeshBvh};
use kinetrace::ecs::*;
use rand::Rng;
use rand::rngs::SmallRng;

/// Held by every test of this file, so that the test harness's parallel threads do not time each other:
/// verdicts follow measured seconds (the rent is charged from measured query and rebuild times), and on
/// two cores a test running beside the churning-corner test kept its rent from ever coming due (CI, and
/// here beside the SAH-bound test). The file's tests run one after another.
static MEASURED_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// [`MEASURED_TIME`], also after a test that held it failed.
fn measured_time() -> std::sync::MutexGuard<'static, ()> {
    MEASURED_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

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

    /// One corner of the soup churns: each triangle whose centroid lies below 0.4 on every axis moves
    /// by up to `step` per axis, its centroid kept within `[-0.2, 0.4)³`. The corner's triangles stir
    /// among themselves, so a refitted tree's corner subtrees degrade while a fresh tree's cost stays
    /// level, and the rest of the mesh is left alone.
    fn churn_corner(&mut self, world: &mut World, step: f32) {
        let mesh = world.get::<TraceMesh>(self.entity).unwrap().0.clone();
        let mut vp = world.get_mut::<VertexPositions>(self.entity).unwrap();
        for tri in mesh.indices().chunks(3) {
            let c = tri.iter().map(|&i| vp.0[i as usize]).sum::<Vec3>() / 3.0;
            if c.max_element() < 0.4 {
                let to = (c + rand_vec(&mut self.rng, -step, step))
                    .clamp(Vec3::splat(-0.2), Vec3::splat(0.399));
                for &i in tri {
                    vp.0[i as usize] += to - c;
                }
            }
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
            (MeshAction::Refit, Verdict::Keep) => {
                assert!(p.rent_s <= p.rebuild_s + p.margin_s, "{p:?}");
                assert!(p.sah <= DEFAULT_SAH_BOUND * p.fresh_sah, "{p:?}");
            }
            (MeshAction::Rebuild { build, reason }, v) => {
                assert_eq!((build, reason), (p.build, RebuildReason::Policy));
                match v {
                    // The ratio extrapolated one frame at its last rise (at most the ratio's own rise
                    // from 1) passed 1.5, so the ratio itself is past 1.25.
                    Verdict::Guard => assert!(p.sah > 1.25 * p.fresh_sah, "{p:?}"),
                    Verdict::Rent => {
                        assert!(n > 0, "frame {f}: no rays, yet rent: {p:?}");
                        assert!(p.rent_s > p.rebuild_s + p.margin_s, "{p:?}");
                    }
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
    let _serial = measured_time();
    let many = policy_rebuilds(16000, 40);
    let none = policy_rebuilds(0, 40);
    assert!(
        !many.is_empty(),
        "a degrading tree under many rays is rebuilt"
    );
    assert!(
        many.len() > none.len(),
        "many rays: {many:?}; none: {none:?}"
    );
    // Without rays only the guard rebuilds; with 16,000 rays a frame the rent comes due well before it
    // (4,000 left the rent at its margin: in 3 of 5 release runs on a 2-core EPYC only the guard rebuilt,
    // at the same frames as without rays), and the tree without rays is refitted longer after that too.
    assert!(
        none.get(1)
            .is_none_or(|&f| many.get(1).is_some_and(|&m| f > m)),
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
    let _serial = measured_time();
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

#[cfg(feature = "gpu")]
fn always_gpu_ploc(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build::GPU_PLOC)
}

#[cfg(feature = "gpu")]
fn always_gpu_median(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build::GPU_MEDIAN)
}

fn always_gpu_sah(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build {
        builder: Builder::SAH,
        device: Device::Gpu,
    })
}

#[cfg(feature = "gpu")]
fn always_gpu_hybrid(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build::gpu_hybrid(6))
}

#[cfg(feature = "gpu")]
fn always_gpu_sah8(_: &PolicyInput<'_>) -> Decision {
    Decision::Rebuild(Build {
        builder: Builder::Sah { bins: 8 },
        device: Device::Gpu,
    })
}

#[test]
fn without_a_gpu_every_build_runs_on_the_cpu() {
    let _serial = measured_time();
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
    let _serial = measured_time();
    if gpu_or_skip().is_none() {
        return;
    }
    let lbvh = RebuildPolicy::Adaptive {
        builders: &[Builder::LBVH],
    };
    let stats = run(lbvh, TraceMode::GpuRequired, 40);
    let built: Vec<_> = rebuilds(&stats).collect();
    assert_eq!(
        built[0],
        (0, Build::cpu(Builder::LBVH), RebuildReason::New),
        "equal prior times: the first offered build first"
    );
    // The GPU's prior time equals the CPU's, so trying it at a rebuild costs nothing extra and its
    // optimistic saving pays: the next rebuild tries it (on a frame that would have refitted, or due).
    let (f, build, reason) = built[1];
    assert_eq!((build, reason), (Build::GPU_LBVH, RebuildReason::Policy));
    assert_ne!(stats[f].prediction.map(|p| p.verdict), Some(Verdict::Keep));
    // A policy may ask for the GPU every time: LBVH, 16-bin SAH, the hybrid, PLOC and the median run there, other GPU
    // builds (here 8-bin SAH) on the CPU.
    for (policy, expect) in [
        (always_gpu_lbvh as Policy, Build::GPU_LBVH),
        (always_gpu_sah, Build::GPU_SAH),
        (always_gpu_hybrid, Build::gpu_hybrid(6)),
        (always_gpu_ploc, Build::GPU_PLOC),
        (always_gpu_median, Build::GPU_MEDIAN),
        (always_gpu_sah8, Build::cpu(Builder::Sah { bins: 8 })),
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
    let _serial = measured_time();
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

/// A scripted mesh for the planner alone, every cost known: each build has a time and a fresh tree's
/// SAH cost; a refitted tree's cost rises by `rise` per frame since its rebuild; queries take
/// `rate · rays · (sensitivity · cost + (1 − sensitivity) · 10)` (1: proportional to the cost; 0: the
/// same whatever the tree, 10 being the best tree's cost); build and query times are multiplied by uniform noise in `[1 − noise, 1 + noise]`
/// (seeded).
struct Script {
    builds: Vec<(Build, f64, f64)>,
    rise: f64,
    rays: f64,
    sensitivity: f64,
    noise: f64,
    rng: SmallRng,
}

/// What the planner did over a scripted run, counted.
#[derive(Debug, Default)]
struct Counted {
    /// Rebuilds with a build no mesh of the asset had measured before (the first build excepted).
    explorations: usize,
    /// Rebuilds per verdict: Explore, Guard, Rent.
    verdicts: [usize; 3],
    /// Rebuilds with a measured build different from the previous measured one.
    flips: usize,
}

const TRIANGLES: usize = 5000;

impl Script {
    fn jitter(&mut self) -> f64 {
        1.0 + self.rng.random_range(-self.noise..=self.noise)
    }

    fn of(&self, b: Build) -> (f64, f64) {
        let &(_, t, c) = self
            .builds
            .iter()
            .find(|s| s.0 == b)
            .expect("a scripted build");
        (t, c)
    }

    fn run(&mut self, p: &mut AdaptivePolicy, asset: Asset, frames: u32) -> Counted {
        let mut counted = Counted::default();
        let mut build = p.next_build();
        let mut last_measured = None;
        let (t, fresh) = self.of(build);
        let jitter = self.jitter();
        p.built(build, TRIANGLES, t * jitter, fresh);
        let mut since = 0;
        for _ in 0..frames {
            since += 1;
            let (_, fresh) = self.of(build);
            let mut cost = fresh * (1.0 + self.rise * since as f64);
            if p.after_refit(cost, self.rays) {
                let why = p.prediction();
                build = why.build;
                let slot = match why.verdict {
                    Verdict::Explore => 0,
                    Verdict::Guard => 1,
                    Verdict::Rent => 2,
                    Verdict::Keep => unreachable!("a rebuild is not kept"),
                    Verdict::Partial => unreachable!("no partial rebuild is offered"),
                    Verdict::Outpaced => unreachable!("asked only before a refit"),
                };
                counted.verdicts[slot] += 1;
                if p.costs().measured(&asset, build) {
                    counted.flips += (last_measured.is_some_and(|l| l != build)) as usize;
                    last_measured = Some(build);
                } else {
                    counted.explorations += 1;
                }
                let (t, fresh) = self.of(build);
                let jitter = self.jitter();
                p.built(build, TRIANGLES, t * jitter, fresh);
                cost = fresh;
                since = 0;
            }
            let per_ray = self.sensitivity * cost + (1.0 - self.sensitivity) * 10.0;
            let q = 1e-9 * self.rays * per_ray * self.jitter();
            p.queried(self.rays, cost, q);
        }
        counted
    }
}

fn script(rays: f64, noise: f64, seed: u64) -> Script {
    Script {
        builds: vec![
            (Build::cpu(Builder::LBVH), 1e-3, 12.0),
            (Build::cpu(Builder::HYBRID), 2.5e-3, 10.5),
            (Build::cpu(Builder::SAH), 5e-3, 10.0),
        ],
        rise: 0.01,
        rays,
        sensitivity: 1.0,
        noise,
        rng: rng(seed),
    }
}

/// The rent charges what a degraded tree costs in queries, as measured, not as its SAH cost says: the
/// scripted scene of [`script`] with no guard (an infinite bound), 10⁵ rays a frame and ±10% noise,
/// where rebuilding repays itself only if query time follows the cost. With query time proportional to
/// the cost, the rent rebuilds (a 1 ms LBVH rebuild against 1.2 µs more queries per frame per frame since
/// the rebuild: about every 16 frames); with query time the same whatever the tree, every rebuild is a
/// loss and the policy stays on refit: no rebuild at all in 300 frames, exploring included.
fn rent_rebuilds(sensitivity: f64, seed: u64) -> Counted {
    let mut s = Script {
        sensitivity,
        ..script(1e5, 0.1, seed)
    };
    let mut p = AdaptivePolicy::shared(&OFFERED, &CostTable::new(), Asset::default());
    p.sah_bound = f64::INFINITY;
    s.run(&mut p, Asset::default(), 300)
}

#[test]
fn the_policy_stays_on_refit_where_query_time_ignores_the_sah_cost() {
    let _serial = measured_time();
    for seed in 0..4 {
        let counted = rent_rebuilds(0.0, 40 + seed);
        assert_eq!(counted.verdicts, [0, 0, 0], "seed {seed}: {counted:?}");
    }
}

#[test]
fn the_policy_rebuilds_where_query_time_follows_the_sah_cost() {
    let _serial = measured_time();
    for seed in 0..4 {
        let counted = rent_rebuilds(1.0, 40 + seed);
        eprintln!("seed {seed}: {counted:?}");
        assert!(counted.verdicts[2] >= 6, "seed {seed}: {counted:?}");
    }
}

/// The rent comes due where timing noise hides how query time follows the SAH cost (issue 19: on the
/// churning corner the rent reached 6× the rebuild's cost while the margin it had to beat grew to 3.6×
/// the rebuild's; that test passed only when the rent came due in the first frames). The scripted scene
/// of [`script`] with no guard, 10⁵ rays a frame, query time proportional to the tree's cost with ±30%
/// noise on every timing, and a tree's cost rising only 0.2% a frame after each rebuild: too little for
/// the slope of query time against the cost to show through the noise. Each frame `k` after a rebuild
/// costs `2.4 µs · k` more than a fresh LBVH tree's would (`10⁵ · 1 ns · 12 · 0.002 · k`), so a 1 ms
/// LBVH rebuild (the one build offered) repays itself after about 30 frames: the rent rebuilds at least 6
/// times in 300 frames (at most 10 can pay).
#[test]
fn the_rent_comes_due_where_noise_hides_the_query_slope() {
    let _serial = measured_time();
    for seed in 0..4 {
        let mut s = Script {
            rise: 0.002,
            ..script(1e5, 0.3, 70 + seed)
        };
        let lbvh = [Build::cpu(Builder::LBVH)];
        let mut p = AdaptivePolicy::shared(&lbvh, &CostTable::new(), Asset::default());
        p.sah_bound = f64::INFINITY;
        let counted = s.run(&mut p, Asset::default(), 300);
        eprintln!("seed {seed}: {counted:?}");
        assert!(counted.verdicts[2] >= 6, "seed {seed}: {counted:?}");
    }
}

const OFFERED: [Build; 3] = [
    Build::cpu(Builder::LBVH),
    Build::cpu(Builder::HYBRID),
    Build::cpu(Builder::SAH),
];

/// The second mesh of an asset starts from the first one's measurements: it explores nothing, while the
/// first did explore (so the count could have been non-zero); a third mesh of another asset (same size,
/// other topology) explores again.
#[test]
fn the_second_instance_of_an_asset_explores_nothing() {
    let _serial = measured_time();
    let table = CostTable::new();
    let asset = Asset {
        triangles: TRIANGLES,
        id: 1,
    };
    let mut first = AdaptivePolicy::shared(&OFFERED, &table, asset);
    let a = script(1e6, 0.1, 1).run(&mut first, asset, 300);
    assert!(a.explorations >= 1, "the first instance explored: {a:?}");
    let mut second = AdaptivePolicy::shared(&OFFERED, &table, asset);
    let b = script(1e6, 0.1, 2).run(&mut second, asset, 300);
    assert_eq!((b.explorations, b.verdicts[0]), (0, 0), "{b:?}");
    let other = Asset { id: 2, ..asset };
    let mut third = AdaptivePolicy::shared(&OFFERED, &table, other);
    let c = script(1e6, 0.1, 3).run(&mut third, other, 300);
    assert!(
        c.explorations >= 1,
        "another asset measures its own trees: {c:?}"
    );
}

/// A stationary scene (the same motion after every rebuild) with ±10% noise on every build and query
/// time, seeded: once measured, the build chosen never changes. The builds are priced close enough that
/// the same script with no margin (`z` = 0) does flip.
#[test]
fn timing_noise_never_flips_the_build() {
    let _serial = measured_time();
    let mut flips_without_margin = 0;
    for seed in 0..8 {
        for z in [DEFAULT_Z, 0.0] {
            let mut s = script(2e5, 0.1, 10 + seed);
            let mut p = AdaptivePolicy::shared(&OFFERED, &CostTable::new(), Asset::default());
            p.z = z;
            let counted = s.run(&mut p, Asset::default(), 600);
            assert!(
                counted.verdicts[2] >= 10,
                "the scene rebuilds on rent: {counted:?}"
            );
            if z > 0.0 {
                assert_eq!(counted.flips, 0, "seed {seed}: {counted:?}");
            } else {
                flips_without_margin += counted.flips;
            }
        }
    }
    assert!(
        flips_without_margin > 0,
        "the script is one where noise can flip"
    );
}

/// With no rays the rent stays 0 and nothing is worth exploring: every rebuild is the guard's.
#[test]
fn without_rays_only_the_guard_rebuilds() {
    let _serial = measured_time();
    let mut p = AdaptivePolicy::shared(&OFFERED, &CostTable::new(), Asset::default());
    let counted = script(0.0, 0.1, 4).run(&mut p, Asset::default(), 300);
    assert!(counted.verdicts[1] > 0, "{counted:?}");
    assert_eq!(
        (counted.verdicts[0], counted.verdicts[2]),
        (0, 0),
        "{counted:?}"
    );
}

/// A scripted mesh whose every tree is known, for the guard: the fresh binned-SAH tree of frame `f`
/// costs `10 · exp(drift · f)`; a tree built by LBVH or hybrid costs that times its build's mean
/// quality (1.22, 1.21) times `exp(u)`, `u` uniform in `±0.05` (the anchor noise of one tree around its
/// build's mean, as the soup's trees showed), a binned-SAH tree exactly the fresh cost. A refitted
/// tree's ratio to the fresh binned-SAH tree of its frame moves from its tree's ratio at the rebuild
/// towards `ceiling` (`(1 − e^(−k/10))` of the way after `k` frames) plus `rise · k`: the true SAH ratio,
/// which the planner never sees. Queries cost 1 ns per ray per unit of SAH cost; builds 1, 2.5 and
/// 5 ms. Returns the guard's rebuilds and the largest true ratio a tree answered queries with.
fn guard_script(ceiling: f64, rise: f64, seed: u64) -> (usize, f64) {
    let mut r = rng(seed);
    let builds = [
        (Build::cpu(Builder::LBVH), 1e-3, 1.22),
        (Build::cpu(Builder::HYBRID), 2.5e-3, 1.21),
        (Build::cpu(Builder::SAH), 5e-3, 1.0),
    ];
    let fresh = |f: u32| 10.0 * (5e-4 * f as f64).exp();
    let rays = 2e4;
    let mut p = AdaptivePolicy::shared(&OFFERED, &CostTable::new(), Asset::default());
    let tree = |b: Build, r: &mut SmallRng| {
        let &(_, s, q) = builds.iter().find(|x| x.0 == b).unwrap();
        let noise = if q == 1.0 {
            0.0
        } else {
            r.random_range(-0.05..=0.05)
        };
        (s, q * f64::exp(noise))
    };
    let b = p.next_build();
    let (s, mut built_ratio) = tree(b, &mut r);
    p.built(b, TRIANGLES, s, built_ratio * fresh(0));
    let (mut guards, mut worst, mut since) = (0, 0.0f64, 0u32);
    for f in 1..300 {
        since += 1;
        let k = since as f64;
        let mut ratio =
            built_ratio + (ceiling - built_ratio) * (1.0 - (-k / 10.0).exp()) + rise * k;
        if p.after_refit(ratio * fresh(f), rays) {
            let why = p.prediction();
            guards += (why.verdict == Verdict::Guard) as usize;
            let (s, q) = tree(why.build, &mut r);
            p.built(why.build, TRIANGLES, s, q * fresh(f));
            (built_ratio, ratio, since) = (q, q, 0);
        }
        worst = worst.max(ratio);
        p.queried(rays, ratio * fresh(f), 1e-9 * rays * ratio * fresh(f));
    }
    (guards, worst)
}

/// The guard rebuilds for the bound, not for its own uncertainty (issue 19: on the report's soup 224 of
/// 226 rebuilds were the guard's while the refitted tree never passed 1.254 × a fresh binned-SAH tree):
/// a refitted tree whose true ratio levels off at 1.3, with the fresh cost drifting slowly and every
/// LBVH or hybrid tree up to 5% off its build's mean, is rebuilt by the guard at most 4 times in 300
/// frames. Where the ratio keeps rising (by 0.5% a frame on top), the guard does rebuild, and no tree
/// answers a frame above the bound.
#[test]
fn the_guard_rebuilds_rarely_below_the_bound_and_always_before_it() {
    let _serial = measured_time();
    for seed in 0..4 {
        let (guards, worst) = guard_script(1.3, 0.0, 60 + seed);
        eprintln!("seed {seed}: {guards} guard rebuilds, true ratio at most {worst:.3}");
        assert!(worst <= 1.3 + 1e-12, "seed {seed}: {worst}");
        assert!(guards <= 4, "seed {seed}: {guards} guard rebuilds");
        let (guards, worst) = guard_script(1.3, 0.005, 60 + seed);
        assert!(guards >= 1, "seed {seed}: the rise passes the bound");
        assert!(
            worst <= DEFAULT_SAH_BOUND,
            "seed {seed}: true ratio {worst}"
        );
    }
}

/// Through the ECS: two entities of one mesh share the plugin's cost table. The first is run alone until
/// its first rebuild came due: its first build is binned SAH, and at that rebuild it calibrates, on the
/// rebuild's pose, the other builds that may pay for their time (`TraceStats::calibrations`: one or both,
/// depending on what the builds measured); the second, spawned then, starts from a copy of its tree and
/// never explores nor calibrates while its planner decides frame after frame.
#[test]
fn a_second_entity_of_one_mesh_explores_nothing() {
    let _serial = measured_time();
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE, TraceMode::Cpu);
    let mut a = Walk::spawn(&mut world, 2000, 21, 0.01);
    let mut r = rng(22);
    let mut used: Vec<Build> = vec![];
    let mut calibrated = 0;
    for _ in 0..120 {
        a.advance(&mut world);
        let m = frame(&mut world, &mut schedule, &a, &mut r, 4000, 2);
        if let MeshAction::Rebuild { build, .. } = m.action
            && !used.contains(&build)
        {
            used.push(build);
        }
        calibrated += world.resource::<TraceStats>().calibrations;
        if calibrated > 0 {
            break;
        }
    }
    assert_eq!(
        used,
        [Build::cpu(Builder::SAH)],
        "the first entity's builds"
    );
    assert!(
        (1..OFFERED.len()).contains(&calibrated),
        "{calibrated} builds calibrated at its first rebuild"
    );
    // The second entity: the same mesh (the same index buffer), its own motion.
    let mesh = world.get::<TraceMesh>(a.entity).unwrap().0.clone();
    let entity = world
        .spawn((
            TraceMesh(mesh.clone()),
            VertexPositions(mesh.positions().to_vec()),
        ))
        .id();
    let mut b = Walk {
        entity,
        rng: rng(23),
        step: 0.01,
    };
    // The first entity stands still from now on (nothing of it to rebuild or calibrate), so that the
    // frames' calibrations are the second's.
    let mut decided = 0;
    for _ in 0..40 {
        b.advance(&mut world);
        let m = frame(&mut world, &mut schedule, &b, &mut r, 4000, 2);
        decided += m.prediction.is_some() as usize;
        assert_ne!(m.prediction.map(|p| p.verdict), Some(Verdict::Explore));
        assert_eq!(world.resource::<TraceStats>().calibrations, 0);
    }
    assert!(decided >= 30, "its planner decided {decided} of 40 frames");
}

/// Through the ECS: a soup whose triangles jump to new random places every frame (each keeps its shape,
/// moved by up to one soup's size per axis), so that a tree refitted one frame after its build is far
/// past the SAH bound (checked here against fresh binned-SAH trees of consecutive frames) while a fresh
/// tree's cost stays level. Once two refits measured the pace, the mesh is rebuilt without a refit
/// (`Verdict::Outpaced` in its `MeshStats`) on most frames; every refitted tree that answers a frame
/// is within the bound of a fresh binned-SAH tree of its frame, and answers equal brute force's.
#[test]
fn a_shuffled_mesh_is_rebuilt_without_refits() {
    let _serial = measured_time();
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE, TraceMode::Cpu);
    let mut walk = Walk::spawn(&mut world, 2000, 41, 0.0);
    let mesh = world.get::<TraceMesh>(walk.entity).unwrap().0.clone();
    let sah = BuildOptions::new(Builder::SAH);
    let mut r = rng(42);
    let (mut outpaced, mut refitted, mut last_fresh) = (0, 0, None::<MeshBvh>);
    for f in 0..40 {
        let pose: Vec<Vec3> = (mesh.positions().chunks(3))
            .flat_map(|t| {
                let to = rand_vec(&mut walk.rng, -0.5, 0.5);
                t.iter().map(move |&p| p + to)
            })
            .collect();
        let fresh = MeshBvh::build(&mesh.with_positions(pose.clone()).unwrap(), &sah).unwrap();
        let fresh_cost = fresh.bvh().sah_cost();
        let outpacing = last_fresh.replace(fresh).is_some_and(|mut t| {
            t.refit(&pose).unwrap();
            t.bvh().sah_cost() / fresh_cost > DEFAULT_SAH_BOUND
        });
        world.get_mut::<VertexPositions>(walk.entity).unwrap().0 = pose;
        let m = frame(&mut world, &mut schedule, &walk, &mut r, 500, 8);
        let Some(why) = m.prediction else { continue };
        if m.action == MeshAction::Refit {
            assert!(
                why.sah / fresh_cost <= DEFAULT_SAH_BOUND,
                "frame {f}: refitted at {} × a fresh tree",
                why.sah / fresh_cost
            );
        }
        assert!(
            outpacing,
            "frame {f}: a one-frame refit stays within the bound"
        );
        if why.verdict == Verdict::Outpaced {
            assert!(matches!(m.action, MeshAction::Rebuild { .. }), "{m:?}");
            outpaced += 1;
        } else {
            refitted += 1;
        }
    }
    assert!(
        outpaced >= 2 * refitted,
        "{outpaced} frames rebuilt without a refit, {refitted} refitted"
    );
}

/// The SAH bound holds on every frame of every report scene: the adaptive strategy of the report's
/// harness (CPU builders) at small sizes, its tree's SAH cost over a fresh binned-SAH build of the same
/// frame (the harness builds that reference every frame, apart from the strategy) at most 1.5 on every
/// frame, queries and rebuilds included. The planner never sees that reference: it predicts it, and the
/// guard assumes the fresh cost may fall as fast as any drift it has measured, either way.
///
/// After a rebuild with LBVH or hybrid the predicted fresh cost rests on that build's mean quality while
/// one tree can sit well off it (LBVH over the rigid bodies: 1.0–1.38 × binned SAH); the guard lowers it
/// by `z` RMS errors of its rebuild predictions (`AnchorError` in `src/adaptive/policy.rs`). The
/// planner's decisions follow measured timings, so runs differ: run it several times under load.
#[test]
fn the_sah_bound_holds_on_every_frame_of_every_report_scene() {
    let _serial = measured_time();
    for triangles in [1000, 2000, 4000] {
        let settings = harness::Settings {
            triangles,
            frames: 120,
            rays: 512,
            checked_rays: 4,
            runs: 1,
            software_gpu: false,
        };
        let (scenes, skipped) = scenes::Scene::all(settings.triangles, &shared_assets_dir());
        for s in &skipped {
            skip(s);
        }
        assert!(scenes.len() >= 6);
        let adaptive = [harness::Strategy::Adaptive {
            gpu: false,
            partial: false,
        }];
        for scene in &scenes {
            let records = harness::run_scene(scene, &settings, &adaptive, None);
            for r in &records[0] {
                assert!(
                    r.sah_ratio <= DEFAULT_SAH_BOUND,
                    "{} at {triangles} triangles, frame {}: SAH ratio {:.4}",
                    scene.name,
                    r.frame,
                    r.sah_ratio
                );
                assert_eq!(r.mismatches, 0, "{} frame {}", scene.name, r.frame);
            }
            let worst = records[0].iter().map(|r| r.sah_ratio).fold(0.0, f64::max);
            eprintln!("{} at {triangles}: worst SAH ratio {worst:.3}", scene.name);
        }
    }
}

/// A world under the adaptive policy, or a fixed one (Lauterbach 0.4) to compare with, holding one
/// walking soup of `triangles` (seeded `seed`), and the rays' generator (seeded `seed + 1`).
/// Scripts the costs the option planners learn for `cheaper`'s kind ([`scripted_cost`]: `cheaper` the
/// cheap one), so that whether its alternative is tried does not depend on the machine's load; the other
/// kinds are measured.
fn prefer(world: &mut World, cheaper: PlannedOption) {
    let kind = std::mem::discriminant(&cheaper);
    world
        .resource_mut::<TraceWorld>()
        .script_costs(Some(std::sync::Arc::new(move |_, option| {
            (std::mem::discriminant(&option) == kind)
                .then(|| scripted_cost(option, option == cheaper))
        })));
}

fn adaptive_or_fixed(
    adaptive: bool,
    triangles: usize,
    seed: u64,
) -> (World, Schedule, Walk, SmallRng) {
    let policy = if adaptive {
        RebuildPolicy::ADAPTIVE
    } else {
        RebuildPolicy::Lauterbach { threshold: 0.4 }
    };
    let (mut world, schedule) = app(policy, TraceMode::Cpu);
    let walk = Walk::spawn(&mut world, triangles, seed, 0.01);
    (world, schedule, walk, rng(seed + 1))
}

/// A new entity of a mesh another entity already traces starts from a copy of that sibling's tree,
/// refitted to its own pose (counted in `TraceStats::siblings`, a refit in its `MeshStats`), not from a
/// build; its answers equal brute force's from that first frame on, and it never explores. Under a
/// fixed policy (no planner to judge the copy) the same spawn builds from scratch.
#[test]
fn a_new_instance_starts_from_a_siblings_tree_and_explores_nothing() {
    let _serial = measured_time();
    for adaptive in [true, false] {
        let (mut world, mut schedule, mut a, mut r) = adaptive_or_fixed(adaptive, 2000, 31);
        for _ in 0..10 {
            a.advance(&mut world);
            frame(&mut world, &mut schedule, &a, &mut r, 256, 2);
        }
        // The second entity: the same mesh, in another pose (its own walk, moved off the first's).
        let mesh = world.get::<TraceMesh>(a.entity).unwrap().0.clone();
        let mut walk = rng(33);
        let pose: Vec<Vec3> = (mesh.positions().iter())
            .map(|p| *p + Vec3::X * 0.5 + rand_vec(&mut walk, -0.05, 0.05))
            .collect();
        let entity = world
            .spawn((TraceMesh(mesh.clone()), VertexPositions(pose)))
            .id();
        let mut b = Walk {
            entity,
            rng: walk,
            step: 0.01,
        };
        let first = frame(&mut world, &mut schedule, &b, &mut r, 256, 64);
        let siblings = world.resource::<TraceStats>().siblings;
        if !adaptive {
            assert_eq!(siblings, 0);
            assert!(matches!(
                first.action,
                MeshAction::Rebuild {
                    reason: RebuildReason::New,
                    ..
                }
            ));
            continue;
        }
        assert_eq!(siblings, 1);
        assert!(
            first.action == MeshAction::Refit
                || matches!(
                    first.action,
                    MeshAction::Rebuild {
                        reason: RebuildReason::Policy,
                        ..
                    }
                ),
            "a copy refitted (and judged): {first:?}"
        );
        for _ in 0..30 {
            a.advance(&mut world);
            b.advance(&mut world);
            let m = frame(&mut world, &mut schedule, &b, &mut r, 256, 8);
            assert_ne!(m.prediction.map(|p| p.verdict), Some(Verdict::Explore));
            assert_eq!(world.resource::<TraceStats>().siblings, 0);
        }
    }
}

/// Forgetting an asset (what the plugin does once its last mesh is gone) drops what was measured on it
/// and nothing else: a later mesh of it explores again, one of another asset still does not.
#[test]
fn a_forgotten_asset_is_measured_again() {
    let _serial = measured_time();
    let table = CostTable::new();
    let kept = Asset {
        triangles: TRIANGLES,
        id: 1,
    };
    let gone = Asset { id: 2, ..kept };
    for asset in [kept, gone] {
        let mut p = AdaptivePolicy::shared(&OFFERED, &table, asset);
        script(1e6, 0.1, 5).run(&mut p, asset, 300);
        assert!(OFFERED.iter().any(|&b| table.measured(&asset, b)));
    }
    table.retain_assets(|a| *a != gone);
    assert!(OFFERED.iter().all(|&b| !table.measured(&gone, b)));
    let mut again = AdaptivePolicy::shared(&OFFERED, &table, gone);
    assert!(script(1e6, 0.1, 6).run(&mut again, gone, 300).explorations >= 1);
    let mut twin = AdaptivePolicy::shared(&OFFERED, &table, kept);
    assert_eq!(
        script(1e6, 0.1, 7).run(&mut twin, kept, 300).explorations,
        0
    );
}

/// A scripted per-mesh choice between two options with known costs: option `a` (in use first) and `b`,
/// each `overhead + per_ray · rays` seconds a frame, times uniform noise of ±10% (seeded). Returns the
/// frames on which `b` was in use on measurements (not as a try) and the tries.
fn scripted_choice<T: Copy + PartialEq + std::fmt::Debug>(
    [a, b]: [T; 2],
    costs: [(f64, f64); 2],
    rays: f64,
    seed: u64,
) -> (usize, usize) {
    let mut choice = Choice::new(&[(a, 1.0, 1.0), (b, 1.0, 1.0)]).expect("two options");
    let mut r = rng(seed);
    let (mut on_b, mut tries) = (0, 0);
    for _ in 0..300 {
        let o = choice.decide(rays);
        let (overhead, per_ray) = if o == a { costs[0] } else { costs[1] };
        let mut jitter = || 1.0 + r.random_range(-0.1..=0.1);
        choice.kept(o, overhead * jitter());
        choice.served(o, rays, per_ray * rays * jitter());
        tries += choice.explored() as usize;
        on_b += (o == b && !choice.explored()) as usize;
    }
    (on_b, tries)
}

/// Every per-mesh option goes through the same rule: `b` is taken once its scripted cost is lower than
/// `a`'s by more than the margin (and kept from then on), and is only tried, never taken, when it is
/// lower by less than the noise allows or higher. Checked for the wide query tree (cheaper rays, an
/// overhead that few rays do not repay), packets against single rays, and a grid against the BVH.
/// Seeded; the margin is two standard deviations, not a proof: over 200 seeds of the 0.5% case one
/// run in 400 did switch.
#[test]
fn each_option_is_chosen_when_it_is_cheaper_beyond_the_margin_and_not_otherwise() {
    let _serial = measured_time();
    use kinetrace::grid::StructureKind;
    // Wide tree (b = on): 30% cheaper rays for 40 µs more maintenance a frame; with 1000 rays at 1 µs
    // it saves 300 µs, with 50 rays 15 µs (less than it costs).
    let wide = [(10e-6, 1e-6), (50e-6, 0.7e-6)];
    let (on, tries) = scripted_choice([false, true], wide, 1000.0, 41);
    assert!(
        tries <= 3 && on >= 290,
        "many rays repay the wide tree: {on} {tries}"
    );
    let (on, tries) = scripted_choice([false, true], wide, 50.0, 42);
    assert_eq!(on, 0, "few rays do not ({tries} tries)");
    for (per_ray_b, taken) in [(0.7e-6, true), (0.995e-6, false), (1.3e-6, false)] {
        let costs = [(0.0, 1e-6), (0.0, per_ray_b)];
        for seed in 0..8 {
            let (on, tries) = scripted_choice(["single", "packets"], costs, 500.0, 50 + seed);
            let grid = scripted_choice(
                [StructureKind::Bvh, StructureKind::Grid],
                costs,
                500.0,
                60 + seed,
            );
            if taken {
                assert!(
                    tries <= 3 && on >= 290 && grid.0 >= 290,
                    "{per_ray_b}: {on} {tries} {grid:?}"
                );
            } else {
                assert_eq!((on, grid.0), (0, 0), "{per_ray_b}: {tries} tries");
            }
        }
    }
}

/// Through the ECS: under the adaptive policy every maintained mesh reports the wide-tree option its
/// planner picked (`TraceStats::options`), and answers equal brute force whichever tree answers — the
/// binary one included, which the planner tries where the wide tree's upkeep may not pay (scripted
/// dearer: measured, the try depended on the machine's load); a fixed policy plans no options.
#[test]
fn the_wide_tree_is_a_planned_option_and_answers_stay_exact() {
    let _serial = measured_time();
    for adaptive in [true, false] {
        let (mut world, mut schedule, mut a, mut r) = adaptive_or_fixed(adaptive, 1000, 71);
        prefer(&mut world, PlannedOption::Wide(false));
        let mut seen = Vec::new();
        for _ in 0..40 {
            a.advance(&mut world);
            frame(&mut world, &mut schedule, &a, &mut r, 16, 16);
            let options = &world.resource::<TraceStats>().options;
            if !adaptive {
                assert!(options.is_empty());
                continue;
            }
            let wide: Vec<_> = (options.iter())
                .filter_map(|o| match o.option {
                    PlannedOption::Wide(on) => Some((o.entity, on)),
                    _ => None,
                })
                .collect();
            let [(entity, on)] = wide[..] else {
                panic!("one wide option per maintained mesh: {options:?}")
            };
            assert_eq!(entity, a.entity);
            seen.push(on);
        }
        if adaptive {
            assert_eq!(seen.len(), 40);
            assert!(seen[0], "the wide tree first, as without the planner");
            assert!(
                seen.contains(&false),
                "with 16 rays a frame the binary tree is tried: {seen:?}"
            );
        }
    }
}

/// Through the ECS: under the adaptive policy every maintained mesh reports whether its queued packets
/// meet it as packets or ray by ray (`PlannedOption::Packets`), and queued packet rays equal brute force
/// whichever way the planner picked that frame (single rays scripted cheaper, so that they are tried:
/// measured, the try failed 3 of 6 runs beside two busy loops); a fixed policy plans no options.
#[test]
fn packets_are_a_planned_option_and_answers_stay_exact() {
    let _serial = measured_time();
    for adaptive in [true, false] {
        let (mut world, mut schedule, mut a, mut r) = adaptive_or_fixed(adaptive, 1000, 73);
        prefer(&mut world, PlannedOption::Packets(false));
        let mut seen = Vec::new();
        for _ in 0..30 {
            a.advance(&mut world);
            let tile = rays(&mut r, 16);
            world
                .resource_mut::<RayQueue>()
                .cast_packet(0, &tile, QueryFilter::default());
            schedule.run(&mut world);
            world.clear_trackers();
            let results = world.resource::<RayResults>().clone();
            for (i, ray) in tile.iter().enumerate() {
                let expect = brute(&mut world, ray, &QueryFilter::default());
                let got = (results.hits.iter()).find(|h| h.0 == i as u64);
                agree(
                    got.and_then(|h| h.1.as_ref()),
                    expect,
                    &format!("packet ray {i}"),
                );
            }
            let options = &world.resource::<TraceStats>().options;
            let packets: Vec<_> = (options.iter())
                .filter_map(|o| match o.option {
                    PlannedOption::Packets(on) => Some((o.entity, on)),
                    _ => None,
                })
                .collect();
            if !adaptive {
                assert!(options.is_empty());
                continue;
            }
            let [(entity, on)] = packets[..] else {
                panic!("one packets option per maintained mesh: {options:?}")
            };
            assert_eq!(entity, a.entity);
            seen.push(on);
        }
        if adaptive {
            assert!(seen[0], "packets first, as without the planner");
            assert!(
                seen.contains(&false),
                "single rays are tried (prior within one spread): {seen:?}"
            );
        }
    }
}

fn always_partial(_: &PolicyInput<'_>) -> Decision {
    Decision::PartialRebuild
}

/// A custom policy may ask for partial rebuilds: while one corner of a soup churns and the rest barely
/// moves, the plugin rebuilds only degraded subtrees (counted in `TraceStats` and the mesh's action, fewer
/// triangles than the mesh), and every batched and immediate answer equals brute force each frame.
#[test]
fn a_custom_policy_gets_partial_rebuilds_and_exact_answers() {
    let _serial = measured_time();
    const N: usize = 4000;
    let (mut world, mut schedule) = app(RebuildPolicy::Custom(always_partial), TraceMode::Cpu);
    let mut walk = Walk::spawn(&mut world, N, 41, 0.0005);
    let mut r = rng(42);
    frame(&mut world, &mut schedule, &walk, &mut r, 64, 8);
    let (mut partial_frames, mut rebuilt) = (0, 0);
    for _ in 0..10 {
        walk.advance(&mut world);
        walk.churn_corner(&mut world, 0.5);
        let m = frame(&mut world, &mut schedule, &walk, &mut r, 256, 64);
        let stats = world.resource::<TraceStats>();
        match m.action {
            MeshAction::PartialRebuild { triangles } => {
                assert!(triangles > 0 && triangles < N, "{triangles} of {N}");
                assert_eq!(stats.partial_rebuilds, 1);
                assert_eq!(stats.partial_triangles, triangles);
                partial_frames += 1;
                rebuilt += triangles;
            }
            MeshAction::Refit => assert_eq!(stats.partial_rebuilds, 0),
            other => panic!("a partial-rebuild policy never rebuilds whole: {other:?}"),
        }
    }
    assert!(
        partial_frames > 0,
        "the churning corner degraded no subtree"
    );
    eprintln!("{partial_frames} partial rebuilds, {rebuilt} triangles rebuilt in all");
}

/// The adaptive policy's third update: while one corner of a soup churns and the rest barely moves, a
/// rebuild due by the rent becomes a partial rebuild of fewer triangles than the mesh (counted in
/// `TraceStats` and the mesh's action), every batched and immediate answer equals brute force each frame,
/// and the pass that counts the degraded triangles runs exactly in the frames whose rent made a rebuild
/// due (`Rent` or `Partial`): never in a frame that keeps the tree, explores or guards.
/// The corner churns slowly under many rays, so that the rent makes a rebuild due before the degradation
/// brings the guard (which always rebuilds whole) to act, but by 0.05 a frame, not 0.02: the rent rests
/// on the fitted slope of query time over SAH cost, and a tree whose cost rose 3% in 20 frames left that
/// slope in the timing noise in 2 runs of 6 here (the rent fell back to 0 and no rebuild came due in 60 frames).
/// The rays are 65,536 a frame for the same reason: at 32,768, once the world's entity lookups got
/// cheaper (an `EntityHashMap`), the slope stayed within the noise in 1 run of 3 on a 2-core Intel VM
/// (14 of 14 passed at 65,536).
#[test]
fn the_adaptive_policy_rebuilds_a_churning_corner_partially() {
    let _serial = measured_time();
    const N: usize = 4000;
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE, TraceMode::Cpu);
    let mut walk = Walk::spawn(&mut world, N, 43, 0.0005);
    let mut r = rng(44);
    frame(&mut world, &mut schedule, &walk, &mut r, 64, 8);
    let (mut partial_frames, mut checks, mut verdicts) = (0, 0, Vec::new());
    for _ in 0..60 {
        walk.advance(&mut world);
        walk.churn_corner(&mut world, 0.05);
        let m = frame(&mut world, &mut schedule, &walk, &mut r, 65536, 32);
        let stats = world.resource::<TraceStats>();
        let verdict = m.prediction.map(|p| p.verdict);
        verdicts.push(verdict);
        let due = matches!(verdict, Some(Verdict::Rent | Verdict::Partial));
        assert_eq!(stats.partial_checks, due as usize, "{verdict:?}");
        checks += stats.partial_checks;
        match m.action {
            MeshAction::PartialRebuild { triangles } => {
                assert_eq!(verdict, Some(Verdict::Partial));
                assert!(triangles > 0 && triangles < N, "{triangles} of {N}");
                assert_eq!(stats.partial_rebuilds, 1);
                assert_eq!(stats.partial_triangles, triangles);
                partial_frames += 1;
            }
            _ => {
                assert_ne!(verdict, Some(Verdict::Partial), "{:?}", m.action);
                assert_eq!(stats.partial_rebuilds, 0);
            }
        }
    }
    assert!(partial_frames > 0, "no partial rebuild: {verdicts:?}");
    eprintln!("{partial_frames} partial rebuilds, {checks} checks in 60 frames: {verdicts:?}");
}

/// A rigid scene pays no partial-rebuild check: meshes that only move never reach the planner's rebuild
/// decision, so no frame counts the degraded triangles (`TraceStats::partial_checks` stays 0 every
/// frame while rays keep the rent's measurements coming).
#[test]
fn a_rigid_scene_never_checks_for_a_partial_rebuild() {
    let _serial = measured_time();
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE, TraceMode::Cpu);
    let walk = Walk::spawn(&mut world, 2000, 45, 0.0);
    let mut r = rng(46);
    frame(&mut world, &mut schedule, &walk, &mut r, 64, 8);
    for k in 1..=40 {
        let angle = 0.05 * k as f32;
        world.get_mut::<TraceTransform>(walk.entity).unwrap().0 =
            glam::Affine3A::from_rotation_translation(
                glam::Quat::from_rotation_y(angle),
                Vec3::new(0.01 * k as f32, 0.0, 0.0),
            );
        let m = frame(&mut world, &mut schedule, &walk, &mut r, 256, 16);
        assert_eq!(m.action, MeshAction::Moved);
        assert_eq!(
            world.resource::<TraceStats>().partial_checks,
            0,
            "frame {k}"
        );
    }
}
