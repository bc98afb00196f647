//! The report's secondary-ray section (issue 13): per scene, its middle frame seen by a camera of `side`²
//! pixels (128², 32² in `--quick`); per primary hit one shadow ray from the frame's light to the point (the
//! seed's direction) and one reflection ray leaving the surface. Each batch, in pixel order, goes through
//! the [`kinetrace::raysort`] strategies the ECS plans among — the BVH, the sorted BVH, sorted packets of
//! [`SORTED_PACKET`], sorted runs of as many cut above [`RUN_LOW_BITS`], CRSH with s = 8, D = 2 — and through the ECS's secondary planner
//! ([`Choice::secondary`]) over [`ROUNDS`] batches, each round's measured seconds taught as the ECS does
//! once per frame, and batches under [`MIN_TRIED_RAYS`] trying nothing, as in the ECS. All on one thread.
//!
//! Per row: Mrays/s (best of three for the fixed strategies, the rounds' median for the planner), tests per
//! ray (coarse + exact), and mismatches: answers unlike the BVH's (every ray; hits by distance and
//! triangle) plus, for the BVH row, sampled rays whose answer differs from brute force.

use super::camera::Orbit;
use super::harness::{Settings, frame_light, median, mismatches, planned_label};
use super::scenes::Scene;
use glam::Vec3;
use kinetrace::adaptive::Choice;
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::ecs::{MIN_TRIED_RAYS, SORTED_PACKET, SecondaryStrategy};
use kinetrace::raysort::{
    Answer, KeyLayout, RUN_LOW_BITS, RayKind, RayScene, SecondaryRay, Strategy, Traced,
};
use kinetrace::{Mesh, Ray};
use std::fmt::Write as _;
use std::time::Instant;

/// Batches the planner row answers: enough for its tries (each option's first batches) and some settled
/// ones.
pub const ROUNDS: usize = 12;

/// The fixed strategies, in their rows' order, then the planner's row.
pub const FIXED: [SecondaryStrategy; 5] = [
    SecondaryStrategy::Bvh,
    SecondaryStrategy::SortedBvh,
    SecondaryStrategy::SortedPackets,
    SecondaryStrategy::SortedRuns,
    SecondaryStrategy::Crsh,
];

/// One strategy on one batch of one scene.
pub struct SecondaryRow {
    pub scene: &'static str,
    /// `shadow` or `reflection`.
    pub batch: &'static str,
    pub strategy: String,
    pub rays: usize,
    pub mrays: f64,
    pub tests_per_ray: f64,
    pub mismatches: u32,
}

fn name(s: SecondaryStrategy) -> &'static str {
    match s {
        SecondaryStrategy::Bvh => "bvh",
        SecondaryStrategy::SortedBvh => "sorted-bvh",
        SecondaryStrategy::SortedPackets => "sorted-packets",
        SecondaryStrategy::SortedRuns => "sorted-runs",
        SecondaryStrategy::Crsh => "crsh-s8-d2",
    }
}

fn strategy(s: SecondaryStrategy) -> Strategy {
    match s {
        SecondaryStrategy::Bvh => Strategy::Bvh,
        SecondaryStrategy::SortedBvh => Strategy::SortedBvh,
        SecondaryStrategy::SortedPackets => Strategy::SortedPackets {
            size: SORTED_PACKET,
        },
        SecondaryStrategy::SortedRuns => Strategy::SortedRuns {
            size: SORTED_PACKET,
            drop_bits: RUN_LOW_BITS,
        },
        SecondaryStrategy::Crsh => Strategy::Crsh {
            branching: 8,
            depth: 2,
        },
    }
}

/// The scene's rows: both batches, the fixed strategies, then `planned` with its picks in the name.
pub fn run(scene: &Scene, settings: &Settings) -> Vec<SecondaryRow> {
    let mut pos = Vec::new();
    scene.positions(settings.frames / 2, &mut pos);
    let mesh = scene.mesh(&pos);
    let rs =
        RayScene::build(&mesh, &BuildOptions::new(Builder::SAH)).expect("scene meshes are valid");
    let side = if settings.frames <= Settings::QUICK.frames {
        32
    } else {
        128
    };
    let layout = KeyLayout::default();
    let trace = |rays: &[SecondaryRay], s| {
        rs.trace(rays, strategy(s), &layout, false)
            .expect("valid options")
    };
    let mut rows = Vec::new();
    for (batch, rays) in secondary_rays(&rs, side) {
        let n = rays.len().max(1) as f64;
        let bvh = trace(&rays, SecondaryStrategy::Bvh);
        for s in FIXED {
            let (mut best, mut traced) = (f64::INFINITY, None);
            for _ in 0..3 {
                let start = Instant::now();
                let t = trace(&rays, s);
                best = best.min(start.elapsed().as_secs_f64());
                traced = Some(t);
            }
            let traced = traced.expect("three runs");
            let mut bad = unlike(&traced, &bvh);
            if s == SecondaryStrategy::Bvh {
                bad += against_brute_force(&rs, &mesh, &rays, settings.checked_rays);
            }
            rows.push(SecondaryRow {
                scene: scene.name,
                batch,
                strategy: name(s).into(),
                rays: rays.len(),
                mrays: n / best / 1e6,
                tests_per_ray: traced.stats.total() as f64 / n,
                mismatches: bad,
            });
        }
        let mut planner = Choice::secondary();
        let (mut rates, mut tests, mut bad) = (Vec::with_capacity(ROUNDS), 0, 0);
        let mut picks = [0usize; FIXED.len()];
        for _ in 0..ROUNDS {
            let s = planner.decide_batch(rays.len(), MIN_TRIED_RAYS);
            let start = Instant::now();
            let traced = trace(&rays, s);
            let t = start.elapsed().as_secs_f64();
            planner.served(s, rays.len() as f64, t);
            rates.push(n / t / 1e6);
            tests += traced.stats.total();
            bad += unlike(&traced, &bvh);
            picks[FIXED.iter().position(|&f| f == s).expect("a fixed option")] += 1;
        }
        rows.push(SecondaryRow {
            scene: scene.name,
            batch,
            strategy: planned_label(
                name(planner.current()),
                FIXED.iter().map(|&s| name(s)).zip(picks),
            ),
            rays: rays.len(),
            mrays: median(&mut rates),
            tests_per_ray: tests as f64 / n / ROUNDS as f64,
            mismatches: bad,
        });
    }
    rows
}

/// Answers of `got` unlike `want`'s: occlusion alike, hits at the same distance on the same triangle.
fn unlike(got: &Traced, want: &Traced) -> u32 {
    let same = |a: &Answer, b: &Answer| match (a, b) {
        (Answer::Hit(a), Answer::Hit(b)) => a.t == b.t && a.primitive == b.primitive,
        _ => a == b,
    };
    (got.answers.iter().zip(&want.answers))
        .filter(|(a, b)| !same(a, b))
        .count() as u32
}

/// The first `k` rays, evenly spread over the batch, whose BVH closest distance within their range differs
/// from brute force's (shadow rays: any hit is some hit, so the closest one decides both).
fn against_brute_force(rs: &RayScene, mesh: &Mesh, rays: &[SecondaryRay], k: usize) -> u32 {
    let step = (rays.len() / k.max(1)).max(1);
    let sample: Vec<Ray> = rays.iter().step_by(step).take(k).map(|r| r.ray).collect();
    mismatches(|r| rs.bvh().closest_hit(r).map(|h| h.t), mesh, &sample)
}

/// The shadow and reflection rays of the camera's primary hits, in pixel order. The camera looks at the
/// mesh's centre from above and aside, 0.9 of the bounds' diagonal away (outside them), a 53° view. Reflection rays start a
/// hair (1e-4 of the mesh's size) off the surface on their side, with their range from 0, so that brute
/// force (which has no lower bound) sees the same rays.
fn secondary_rays(rs: &RayScene, side: usize) -> [(&'static str, Vec<SecondaryRay>); 2] {
    let orbit = Orbit::around(rs.bvh().bvh().bounds(), Vec3::new(0.3, 0.5, 0.8), 0.9);
    let (light, size) = (frame_light(&orbit.bounds), orbit.size);
    let (mut shadow, mut reflect) = (Vec::new(), Vec::new());
    orbit.hits(rs, side, |tag, primary, h| {
        let p = primary.at(h.t);
        shadow.push(SecondaryRay {
            ray: Ray::with_range(light, p - light, 0.0, 1.0 - 1e-4),
            kind: RayKind::Shadow { light: 0 },
            tag,
        });
        let d = primary.dir();
        let r = d - 2.0 * d.dot(h.normal) * h.normal;
        let n = if r.dot(h.normal) >= 0.0 {
            h.normal
        } else {
            -h.normal
        };
        reflect.push(SecondaryRay {
            ray: Ray::with_range(p + n * 1e-4 * size, r, 0.0, f32::INFINITY),
            kind: RayKind::Reflection,
            tag,
        });
    });
    [("shadow", shadow), ("reflection", reflect)]
}

/// The summary's section: per scene and batch, a row per strategy.
pub fn table(rows: &[SecondaryRow]) -> String {
    if rows.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Secondary rays (issue 13)\n\nPer scene, its middle frame through a camera; per primary hit one \
         shadow ray from the light and one reflection ray, each batch in pixel order, on one thread. \
         `planned` is the ECS's secondary planner over 12 batches of the same rays, its Mrays/s their \
         median (its picks, batches per strategy, in brackets; the arrow names where it settled). Mismatches: answers unlike the BVH's, \
         and the BVH's sampled answers unlike brute force.\n\n\
         | scene | batch | strategy | rays | Mrays/s | × BVH | tests/ray | mismatches |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let bvh = rows
            .iter()
            .find(|b| b.scene == r.scene && b.batch == r.batch && b.strategy == "bvh")
            .map_or(f64::NAN, |b| b.mrays);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.3} | {:.2} | {:.1} | {} |",
            r.scene,
            r.batch,
            r.strategy,
            r.rays,
            r.mrays,
            r.mrays / bvh,
            r.tests_per_ray,
            r.mismatches
        );
    }
    s
}
