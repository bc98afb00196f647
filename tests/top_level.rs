//! The top-level tree stays good while a crowd wanders: 500 rigid entities random-walk over a 1 km square
//! for 10,000 frames, and every frame the TLAS's SAH cost is within 1.5× of a fresh SAH build's over the
//! same boxes (both costs computed here from the node arrays), its reported degradation is the one
//! recomputed here from its nodes, and on sampled frames ray and shadow answers equal brute force. Under
//! the adaptive policy, the top level's own cost model decides, within its guard.

mod common;
use bevy_ecs::prelude::*;
use common::ecs::{agree, app_with, brute};
use common::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::adaptive::DEFAULT_SAH_BOUND;
use kinetrace::bvh::{BuildOptions, Builder, Bvh, Node};
use kinetrace::ecs::*;
use kinetrace::geometry::Aabb;
use rand::Rng;
use rand::rngs::SmallRng;

const ENTITIES: usize = 500;
const FRAMES: u64 = 10_000;
/// Half the side of the square the crowd walks on, in metres.
const HALF: f32 = 500.0;
/// Metres per frame.
const SPEED: f32 = 1.0;

/// Half the surface area of a node's box, in f64.
fn half_area(n: &Node) -> f64 {
    let e = Vec3::from(n.max).as_dvec3() - Vec3::from(n.min).as_dvec3();
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// The node's children, or `None` for a leaf (bit 31 of `index`, as the node layout documents).
fn children(n: &Node) -> Option<usize> {
    (n.index & (1 << 31) == 0).then_some(n.index as usize)
}

/// Primitives in a leaf (bits 27..=30 of `index`).
fn leaf_count(n: &Node) -> f64 {
    ((n.index >> 27) & 0xf) as f64
}

/// SAH cost from the node array: inner nodes cost 1, leaves 1 per primitive, each weighted by its area
/// over the root's.
fn sah(nodes: &[Node]) -> f64 {
    let root = half_area(&nodes[0]);
    nodes
        .iter()
        .map(|n| match children(n) {
            Some(_) => half_area(n) / root,
            None => half_area(n) / root * leaf_count(n),
        })
        .sum()
}

/// Lauterbach's degradation metric from the node array: the mean over inner nodes of
/// `A(n) / (A(left) + A(right))` now minus the ratio stored at build time.
fn degradation(nodes: &[Node]) -> f64 {
    let (mut sum, mut inner) = (0.0, 0);
    for n in nodes {
        if let Some(l) = children(n) {
            let now = half_area(n) / (half_area(&nodes[l]) + half_area(&nodes[l + 1]));
            sum += now - n.sa_ratio as f64;
            inner += 1;
        }
    }
    sum / inner as f64
}

/// One walker: where it is, where it heads, and how it is turned.
struct Walker {
    entity: Entity,
    pos: Vec3,
    heading: f32,
    yaw: f32,
}

impl Walker {
    /// A step of a correlated random walk (the heading wanders), reflected at the square's edges, and a
    /// small random turn of the body.
    fn step(&mut self, r: &mut SmallRng) {
        self.heading += r.random_range(-0.3..0.3);
        self.yaw += r.random_range(-0.1..0.1);
        self.pos += Vec3::new(self.heading.cos(), 0.0, self.heading.sin()) * SPEED;
        for (c, flip) in [(0, std::f32::consts::PI), (2, 0.0)] {
            if self.pos[c].abs() > HALF {
                self.pos[c] = self.pos[c].clamp(-HALF, HALF);
                self.heading = flip - self.heading;
            }
        }
    }

    fn transform(&self) -> Affine3A {
        Affine3A::from_rotation_translation(glam::Quat::from_rotation_y(self.yaw), self.pos)
    }
}

/// The world box of `local` (an object-space box) under `t`: its eight corners, transformed.
fn world_box(local: &Aabb, t: &Affine3A) -> Aabb {
    let mut b = Aabb::EMPTY;
    for i in 0..8 {
        let pick = |bit: usize, lo: f32, hi: f32| if i & bit == 0 { lo } else { hi };
        b.grow(t.transform_point3(Vec3::new(
            pick(1, local.min.x, local.max.x),
            pick(2, local.min.y, local.max.y),
            pick(4, local.min.z, local.max.z),
        )));
    }
    b
}

/// Rays for a sampled frame: down onto walkers from above (most hit), and level rays across the square at
/// body height from random points in random directions (some pass between walkers).
fn sample_rays(r: &mut SmallRng, walkers: &[Walker]) -> Vec<Ray> {
    let mut rays = Vec::new();
    for _ in 0..16 {
        let w = &walkers[r.random_range(0..walkers.len())];
        let jitter = Vec3::new(r.random_range(-1.2..1.2), 0.0, r.random_range(-1.2..1.2));
        rays.push(Ray::new(w.pos + jitter + Vec3::Y * 50.0, -Vec3::Y));
    }
    for _ in 0..16 {
        let from = Vec3::new(
            r.random_range(-HALF..HALF),
            r.random_range(-0.5..0.5),
            r.random_range(-HALF..HALF),
        );
        let a: f32 = r.random_range(0.0..std::f32::consts::TAU);
        rays.push(Ray::new(from, Vec3::new(a.cos(), 0.0, a.sin())));
    }
    rays
}

/// The walkers of one world, with the random source that moves them.
struct Crowd {
    walkers: Vec<Walker>,
    /// The mesh's object-space box.
    local: Aabb,
    r: SmallRng,
}

impl Crowd {
    /// `ENTITIES` rigid walkers of a tiny mesh (it keeps the frame cheap: the top level is what is
    /// measured), spread over the square.
    fn spawn(world: &mut World, seed: u64) -> Crowd {
        let mesh = icosphere(0);
        let local = mesh.positions().iter().fold(Aabb::EMPTY, |mut b, &p| {
            b.grow(p);
            b
        });
        let mut r = rng(seed);
        let walkers = (0..ENTITIES)
            .map(|_| {
                let mut w = Walker {
                    entity: Entity::PLACEHOLDER,
                    pos: Vec3::new(
                        r.random_range(-HALF..HALF),
                        0.0,
                        r.random_range(-HALF..HALF),
                    ),
                    heading: r.random_range(0.0..std::f32::consts::TAU),
                    yaw: r.random_range(0.0..std::f32::consts::TAU),
                };
                let placed = (TraceMesh(mesh.clone()), MotionHint::Rigid);
                w.entity = world.spawn((placed, TraceTransform(w.transform()))).id();
                w
            })
            .collect();
        Crowd { walkers, local, r }
    }

    /// Every walker takes a step; their transforms are written.
    fn step(&mut self, world: &mut World) {
        for w in &mut self.walkers {
            w.step(&mut self.r);
            world.get_mut::<TraceTransform>(w.entity).unwrap().0 = w.transform();
        }
    }

    /// The walkers' world boxes, computed here, into `out`.
    fn boxes(&self, out: &mut Vec<Aabb>) {
        out.clear();
        out.extend(
            self.walkers
                .iter()
                .map(|w| world_box(&self.local, &w.transform())),
        );
    }

    /// Closest hits and shadows of sampled rays equal brute force; returns how many rays hit.
    fn check_queries(&mut self, world: &mut World, frame: u64) -> usize {
        let filter = QueryFilter::default();
        let mut hits = 0;
        for (i, ray) in sample_rays(&mut self.r, &self.walkers).iter().enumerate() {
            let expect = brute(world, ray, &filter);
            let tw = world.resource::<TraceWorld>();
            let got = tw.cast_ray(ray, f32::INFINITY, &filter);
            agree(got.as_ref(), expect, &format!("frame {frame} ray {i}"));
            let to = ray.at(100.0);
            let blocked = brute(world, &Ray::segment(ray.origin, to), &filter);
            let tw = world.resource::<TraceWorld>();
            assert_eq!(
                tw.occluded(ray.origin, to, &filter),
                blocked.is_some(),
                "frame {frame} shadow {i}"
            );
            hits += expect.is_some() as usize;
        }
        hits
    }
}

/// A world with the plugin under `policy`, run on one thread.
fn app(policy: RebuildPolicy) -> (World, Schedule) {
    let (world, mut schedule) = app_with(TraceConfig {
        policy,
        ..Default::default()
    });
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    (world, schedule)
}

/// SAH cost of a fresh binned-SAH build over `boxes` (the top level's builder).
fn fresh_sah(boxes: &[Aabb]) -> (Bvh, f64) {
    let fresh = Bvh::build(boxes, &BuildOptions::new(Builder::SAH).parallel(false)).unwrap();
    let cost = sah(fresh.nodes());
    (fresh, cost)
}

#[test]
fn a_wandering_crowd_keeps_a_good_top_level() {
    let (mut world, mut schedule) = app(RebuildPolicy::default());
    let mut crowd = Crowd::spawn(&mut world, 11);
    let (mut worst, mut policy_rebuilds, mut sampled_hits) = (0f64, 0, 0);
    let mut boxes = Vec::with_capacity(ENTITIES);
    // The control: the first frame's tree, only ever refitted (what the top level did before it had a
    // rebuild rule). It must degrade past the bound, or the walk tests nothing.
    let mut refitted_only: Option<Bvh> = None;
    let mut control_worst = 0f64;
    // Top-level phase time of refit and of rebuild frames (printed, never asserted).
    let mut phase = [std::time::Duration::ZERO; 2];
    for frame in 0..FRAMES {
        if frame > 0 {
            crowd.step(&mut world);
        }
        schedule.run(&mut world);
        world.clear_trackers();

        let stats = world.resource::<TraceStats>();
        let top = stats.top_level;
        phase[(top.action != TopLevelAction::Refit) as usize] += stats.top_level_time;
        let expected = match frame {
            0 => TopLevelAction::Rebuild {
                reason: TopLevelReason::Membership,
            },
            _ if top.degradation > 0.40 => TopLevelAction::Rebuild {
                reason: TopLevelReason::Policy,
            },
            _ => TopLevelAction::Refit,
        };
        assert_eq!(top.action, expected, "frame {frame}: {top:?}");
        assert_eq!(stats.moved, if frame == 0 { 0 } else { ENTITIES });
        assert_eq!(top.refits + top.rebuilds, frame + 1);
        let tlas = world.resource::<TraceWorld>().tlas();
        if top.action == TopLevelAction::Refit {
            let d = degradation(tlas.nodes());
            assert!(
                (d - top.degradation as f64).abs() < 1e-5,
                "frame {frame}: {d} vs {top:?}"
            );
        } else if frame > 0 {
            policy_rebuilds += 1;
        }

        crowd.boxes(&mut boxes);
        let (fresh, fresh_cost) = fresh_sah(&boxes);
        let ratio = sah(tlas.nodes()) / fresh_cost;
        let control = refitted_only.get_or_insert_with(|| fresh.clone());
        control.refit(&boxes).unwrap();
        control_worst = control_worst.max(sah(control.nodes()) / fresh_cost);
        worst = worst.max(ratio);
        assert!(
            ratio <= 1.5,
            "frame {frame}: SAH {ratio:.3}× a fresh build's, {top:?}"
        );
        if frame % 500 == 250 {
            sampled_hits += crowd.check_queries(&mut world, frame);
        }
    }
    // The walk must have made the rule work, and the samples must have hit something.
    assert!(policy_rebuilds > 0, "the crowd never degraded the tree");
    assert!(sampled_hits > 0);
    assert!(
        control_worst > 1.5,
        "refitting alone stayed at {control_worst:.3}×"
    );
    let refits = FRAMES - 1 - policy_rebuilds;
    eprintln!(
        "worst SAH ratio {worst:.3} (refit only: {control_worst:.3}), {policy_rebuilds} policy rebuilds \
         in {FRAMES} frames; top-level phase {:?} per refit frame, {:?} per rebuild frame",
        phase[0] / refits as u32,
        phase[1] / (policy_rebuilds + 1) as u32
    );
}

/// Under the adaptive policy the top level has its own cost model, fed with batched rays: every refit is
/// judged (its SAH cost, recomputed here, is what the model saw), a kept tree is never past the guard
/// (1.5× the model's fresh cost), the tree is rebuilt exactly when the model says so, and answers stay
/// equal to brute force.
#[test]
fn the_adaptive_policy_owns_the_top_level() {
    let (mut world, mut schedule) = app(RebuildPolicy::ADAPTIVE);
    let mut crowd = Crowd::spawn(&mut world, 12);
    let (mut rebuilds, mut sampled_hits, mut worst) = (0, 0, 0f64);
    let mut boxes = Vec::with_capacity(ENTITIES);
    for frame in 0..FRAMES / 5 {
        if frame > 0 {
            crowd.step(&mut world);
        }
        {
            let mut queue = world.resource_mut::<RayQueue>();
            for i in 0..64 {
                let from = Vec3::new(-HALF + 15.0 * i as f32, 0.0, -HALF - 1.0);
                queue.cast(i, Ray::new(from, Vec3::Z), QueryFilter::default());
            }
        }
        schedule.run(&mut world);
        world.clear_trackers();

        let top = world.resource::<TraceStats>().top_level;
        let tlas = world.resource::<TraceWorld>().tlas();
        if frame == 0 {
            let membership = TopLevelReason::Membership;
            assert_eq!(top.action, TopLevelAction::Rebuild { reason: membership });
            continue;
        }
        let why = top.prediction.expect("every refit is judged");
        match top.action {
            TopLevelAction::Refit => {
                assert_eq!(why.verdict, Verdict::Keep, "frame {frame}");
                let cost = sah(tlas.nodes());
                assert!((cost - why.sah).abs() <= 1e-6 * cost, "{cost} vs {why:?}");
                assert!(
                    why.sah <= DEFAULT_SAH_BOUND * why.fresh_sah,
                    "frame {frame}: {why:?}"
                );
            }
            TopLevelAction::Rebuild { reason } => {
                assert_eq!(reason, TopLevelReason::Policy);
                assert!(
                    matches!(why.verdict, Verdict::Guard | Verdict::Rent),
                    "{why:?}"
                );
                rebuilds += 1;
            }
            TopLevelAction::Unchanged => panic!("frame {frame}: every walker moved"),
        }
        crowd.boxes(&mut boxes);
        worst = worst.max(sah(tlas.nodes()) / fresh_sah(&boxes).1);
        if frame % 500 == 250 {
            sampled_hits += crowd.check_queries(&mut world, frame);
        }
    }
    assert!(rebuilds > 0, "the model never rebuilt the top level");
    assert!(sampled_hits > 0);
    eprintln!(
        "adaptive: {rebuilds} rebuilds in {} frames, worst SAH {worst:.3}× a fresh build's",
        FRAMES / 5
    );
}
