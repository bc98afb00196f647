//! The report's closest-point batch section (issue 18): per scene, its middle frame under a binned-SAH tree;
//! a batch of as many points as the report has rays, uniform in the mesh's box grown by a fifth on each
//! side, answered on one thread in the orders the ECS plans between ([`PointBatches`]): as queued, in
//! Morton order ([`MortonOrder`], the sort timed with the queries), and by the ECS's planner of that order
//! ([`Choice::point_order`]) over [`ROUNDS`] batches, each batch's seconds taught as the ECS does once per
//! frame.
//!
//! Per row: µs per query (best of three for the fixed orders, the rounds' median for the planner) and
//! mismatches: answers unlike the as-queued ones (the order must change only the time; the answers
//! themselves are checked against brute force in `tests/shape_queries_ecs.rs` and `tests/queries.rs`).
//!
//! [`PointBatches`]: kinetrace::ecs::PointBatches

use super::harness::{Settings, median, planned_label};
use super::scenes::Scene;
use glam::Vec3;
use kinetrace::MeshBvh;
use kinetrace::adaptive::Choice;
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::ecs::PointOrder;
use kinetrace::queries::{MortonOrder, PointHit};
use kinetrace::scenes::SceneRng;
use std::fmt::Write as _;
use std::time::Instant;

/// Batches the planner row answers: enough for a try of the other order and some settled ones.
pub const ROUNDS: usize = 12;

/// The fixed orders, in their rows' order, then the planner's row.
pub const FIXED: [PointOrder; 2] = [PointOrder::Queued, PointOrder::Spatial];

/// One order on one scene's batch.
pub struct PointRow {
    pub scene: &'static str,
    pub order: String,
    pub points: usize,
    pub us_per_query: f64,
    pub mismatches: u32,
}

fn name(o: PointOrder) -> &'static str {
    match o {
        PointOrder::Queued => "as queued",
        PointOrder::Spatial => "morton",
    }
}

/// The scene's rows: the fixed orders, then `planned` with its picks in the name.
pub fn run(scene: &Scene, settings: &Settings) -> Vec<PointRow> {
    let mut pos = Vec::new();
    scene.positions(settings.frames / 2, &mut pos);
    let bvh = MeshBvh::build(&scene.mesh(&pos), &BuildOptions::new(Builder::SAH))
        .expect("scene meshes are valid");
    let b = bvh.bvh().bounds();
    let (lo, hi) = (b.min - b.extent() * 0.2, b.max + b.extent() * 0.2);
    let mut rng = SceneRng::new(23);
    let points: Vec<Vec3> = (0..settings.rays)
        .map(|_| lo + (hi - lo) * Vec3::new(rng.unit(), rng.unit(), rng.unit()))
        .collect();
    let n = points.len().max(1) as f64;
    let mut batch = Batch {
        bvh: &bvh,
        points: &points,
        order: MortonOrder::default(),
        answers: vec![None; points.len()],
    };
    batch.answer(PointOrder::Queued);
    let queued = batch.answers.clone();
    let mut rows = Vec::new();
    for o in FIXED {
        let best = (0..3)
            .map(|_| batch.answer(o))
            .fold(f64::INFINITY, f64::min);
        rows.push(PointRow {
            scene: scene.name,
            order: name(o).into(),
            points: points.len(),
            us_per_query: 1e6 * best / n,
            mismatches: batch.unlike(&queued),
        });
    }
    let mut planner = Choice::point_order();
    let (mut seconds, mut bad) = (Vec::with_capacity(ROUNDS), 0);
    let mut picks = [0usize; FIXED.len()];
    for _ in 0..ROUNDS {
        let o = planner.decide(n);
        let t = batch.answer(o);
        planner.served(o, n, t);
        seconds.push(t);
        bad += batch.unlike(&queued);
        picks[FIXED.iter().position(|&f| f == o).expect("a fixed order")] += 1;
    }
    rows.push(PointRow {
        scene: scene.name,
        order: planned_label(
            name(planner.current()),
            FIXED.iter().map(|&o| name(o)).zip(picks),
        ),
        points: points.len(),
        us_per_query: 1e6 * median(&mut seconds) / n,
        mismatches: bad,
    });
    rows
}

/// A batch of closest-point queries on one tree, answered into `answers` (in request order).
struct Batch<'a> {
    bvh: &'a MeshBvh,
    points: &'a [Vec3],
    order: MortonOrder,
    answers: Vec<Option<PointHit>>,
}

impl Batch<'_> {
    /// Answers every point in `order`; the seconds it took, the sort included.
    fn answer(&mut self, order: PointOrder) -> f64 {
        let start = Instant::now();
        let ask = |i: usize| self.bvh.closest_point(self.points[i], f32::INFINITY);
        match order {
            PointOrder::Queued => {
                for (i, a) in self.answers.iter_mut().enumerate() {
                    *a = ask(i);
                }
            }
            PointOrder::Spatial => {
                self.order.sort(self.points.len(), |i| self.points[i]);
                for i in self.order.indices() {
                    self.answers[i] = ask(i);
                }
            }
        }
        start.elapsed().as_secs_f64()
    }

    /// Answers unlike `want`'s.
    fn unlike(&self, want: &[Option<PointHit>]) -> u32 {
        (self.answers.iter().zip(want))
            .filter(|(a, b)| a != b)
            .count() as u32
    }
}

/// The summary's section: per scene, a row per order.
pub fn table(rows: &[PointRow]) -> String {
    if rows.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Closest-point batches (issue 18)\n\nPer scene, its middle frame under a binned-SAH tree; as \
         many points as rays, uniform in the mesh's box grown by a fifth, answered on one thread as \
         queued, in Morton order (the sort timed too), and by the ECS's planner of that order over 12 \
         batches (its µs/query their median; its picks, batches per order, in brackets; the arrow names \
         where it settled). Mismatches: answers unlike the as-queued ones.\n\n\
         | scene | order | points | µs/query | speed × as queued | mismatches |\n\
         |---|---|---|---|---|---|\n",
    );
    for r in rows {
        let queued = (rows.iter())
            .find(|q| q.scene == r.scene && q.order == name(PointOrder::Queued))
            .map_or(f64::NAN, |q| q.us_per_query);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {:.2} | {} |",
            r.scene,
            r.order,
            r.points,
            r.us_per_query,
            queued / r.us_per_query,
            r.mismatches
        );
    }
    s
}
