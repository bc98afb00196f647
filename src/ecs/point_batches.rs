//! The order a frame's batched closest-point requests are answered in ([`PointBatches`]): as queued, or
//! along a Morton curve through their points, so that consecutive queries on a thread walk the same
//! nodes, discs and triangles while they are still in cache (each query is answered on its own, so the
//! answers are the same in either order; only the time differs). Over a large mesh a closest-point
//! query's few dozen wide nodes and their discs miss the cache when the points come in no particular
//! order (agents all over a level): on `bench queries` (points uniform around a deforming bumpy torus,
//! refit included, one thread) Morton order took about 23% less time at 200k triangles, whose trees far
//! exceed the cache, and no measurably different time at 20k (docs/BENCHMARKS.md, stop 39). A planned
//! choice like the secondary rays' ([`SecondaryRays`](super::SecondaryRays)).

use super::shape_batch::ClosestPointRequest;
use super::{NearestPoint, OptionStats, PlannedOption, TraceStats, TraceWorld};
use crate::adaptive::Choice;
use crate::parallel;
use crate::queries::MortonOrder;
use bevy_ecs::prelude::*;
use std::time::Instant;

/// The order a batch of closest-point requests is answered in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PointOrder {
    /// As queued.
    Queued,
    /// Along a Morton curve through the batch's points (cubic cells over their box).
    Spatial,
}

impl Choice<PointOrder> {
    /// The planner of [`PointBatches`]: as queued first (no sort, which costs a few percent where the
    /// trees stay in cache: the report's 3k-triangle scenes), Morton order tried at once at 0.8 × its
    /// seconds per query (`bench queries`: 0.76–0.77 at 200k triangles) and kept where it measures
    /// cheaper by the planner's margin; no overhead either way.
    pub fn point_order() -> Self {
        Choice::new(&[
            (PointOrder::Queued, 1.0, 1.0),
            (PointOrder::Spatial, 0.8, 1.0),
        ])
        .expect("two options")
    }
}

/// How batched closest-point requests are ordered: a fixed [`PointOrder`], or (the default) the order the
/// batch's planner ([`Choice::point_order`]) learns is cheaper from the measured seconds per query of
/// each, whatever the rebuild policy (the pick is in [`TraceStats::options`] as
/// [`PlannedOption::PointOrder`]). Morton order visits neighbouring points one after another, so their
/// walks share cached nodes: on `bench queries` about a quarter less time at 200k triangles, no
/// measurable change at 20k; it costs a pass over the points, a code each and a sort (well under a
/// microsecond per request, [`MortonOrder`]). The answers are the same in either order. The plugin
/// inserts the default; replace the resource to change it. No allocation once its buffers have grown to
/// the largest batch.
#[derive(Resource, Clone, Debug)]
pub struct PointBatches {
    fixed: Option<PointOrder>,
    planner: Choice<PointOrder>,
    /// The batch's Morton order.
    order: MortonOrder,
    /// Answers in the order they were computed.
    done: Vec<Option<NearestPoint>>,
}

impl Default for PointBatches {
    /// Planned.
    fn default() -> Self {
        Self {
            fixed: None,
            planner: Choice::point_order(),
            order: MortonOrder::default(),
            done: Vec::new(),
        }
    }
}

impl PointBatches {
    /// Always `order`, no planner.
    pub fn fixed(order: PointOrder) -> Self {
        Self {
            fixed: Some(order),
            ..Self::default()
        }
    }

    /// The order for a batch of `units` requests, and whether it is being tried.
    fn pick(&mut self, units: usize) -> (PointOrder, bool) {
        match self.fixed {
            Some(order) => (order, false),
            None => (self.planner.decide(units as f64), self.planner.explored()),
        }
    }
}

impl TraceWorld {
    /// The closest points of `requests` into `out` (resized to them), in request order with their tags,
    /// each as [`closest_point`](Self::closest_point) answers it; in parallel when the `parallel` feature
    /// is on. With `batches`, in the order it picks (teaching its planner the batch's time and recording
    /// the pick in `stats`), else as queued.
    pub(super) fn answer_closest(
        &self,
        requests: &[ClosestPointRequest],
        out: &mut Vec<(u64, Option<NearestPoint>)>,
        batches: Option<(&mut PointBatches, &mut TraceStats)>,
    ) {
        let answer =
            |r: &ClosestPointRequest| self.closest_point(r.point, r.max_distance, &r.filter);
        out.resize(requests.len(), (0, None));
        let mut batches = batches.filter(|_| !requests.is_empty());
        let (order, tried) =
            (batches.as_mut()).map_or((PointOrder::Queued, false), |(b, _)| b.pick(requests.len()));
        let start = Instant::now();
        match (order, batches.as_mut()) {
            (PointOrder::Spatial, Some((b, _))) => {
                let PointBatches { order, done, .. } = b;
                order.sort(requests.len(), |i| requests[i].point);
                done.resize(requests.len(), None);
                parallel::fill(true, done, 16, |k| answer(&requests[order.index(k)]));
                for (i, &hit) in order.indices().zip(done.iter()) {
                    out[i] = (requests[i].tag, hit);
                }
            }
            _ => parallel::fill(true, out, 16, |i| (requests[i].tag, answer(&requests[i]))),
        }
        // A fixed order teaches and reports nothing.
        let Some((batches, stats)) = batches.filter(|(b, _)| b.fixed.is_none()) else {
            return;
        };
        let seconds = start.elapsed().as_secs_f64();
        (batches.planner).served(order, requests.len() as f64, seconds);
        stats.options.push(OptionStats {
            entity: Entity::PLACEHOLDER,
            option: PlannedOption::PointOrder(order),
            tried,
        });
    }
}
