//! Batched shape casts, closest points, overlaps and containment: gameplay systems push requests into
//! [`ShapeQueue`], [`TraceSystems::Queries`](super::TraceSystems::Queries) answers them all on all threads
//! into [`ShapeResults`], the same frame (these queries have no GPU path, so [`Latency`](super::Latency)
//! does not apply to them).
//!
//! Use the batch when many queries are asked at once (a crowd's capsules, a swarm's points): the answers
//! come on every core for the price of one system, and equal the immediate ones of
//! [`SpatialRays`](super::SpatialRays) bit for bit whatever the thread count. Once warm (the same number of
//! requests, answers no longer than before) a frame allocates nothing.

use super::{NearestPoint, PointBatches, QueryFilter, ShapeHit, TraceStats, TraceWorld};
use crate::parallel;
use crate::queries::Shape;
use bevy_ecs::prelude::*;
use glam::Vec3;

/// A shape-cast request: `shape` (world space) swept along `dir` up to `max_t`.
#[derive(Clone, Debug)]
pub struct ShapeCastRequest {
    /// Your identifier, returned with the answer.
    pub tag: u64,
    /// The shape at the start of the sweep.
    pub shape: Shape,
    /// Direction of motion (the time of impact is in its units).
    pub dir: Vec3,
    /// Longest sweep, in units of `dir`.
    pub max_t: f32,
    /// Which entities it may touch.
    pub filter: QueryFilter,
}

/// A closest-point request.
#[derive(Clone, Debug)]
pub struct ClosestPointRequest {
    /// Your identifier.
    pub tag: u64,
    /// The world point.
    pub point: Vec3,
    /// Largest distance of interest (`f32::INFINITY` for no limit).
    pub max_distance: f32,
    /// Which entities it may find.
    pub filter: QueryFilter,
}

/// An overlap request: which triangles of which entities `shape` touches.
#[derive(Clone, Debug)]
pub struct OverlapRequest {
    /// Your identifier.
    pub tag: u64,
    /// The world-space shape.
    pub shape: Shape,
    /// Which entities it may touch.
    pub filter: QueryFilter,
}

/// A containment request: which closed meshes hold `point`.
#[derive(Clone, Debug)]
pub struct ContainsRequest {
    /// Your identifier.
    pub tag: u64,
    /// The world point.
    pub point: Vec3,
    /// Which entities count.
    pub filter: QueryFilter,
}

/// Shape, point, overlap and containment requests queued this frame. Push from any system that runs before
/// [`TraceSystems::Queries`](super::TraceSystems::Queries); the queue is drained there (its memory is kept).
#[derive(Resource, Default, Debug)]
pub struct ShapeQueue {
    casts: Vec<ShapeCastRequest>,
    closest: Vec<ClosestPointRequest>,
    overlaps: Vec<OverlapRequest>,
    contains: Vec<ContainsRequest>,
}

impl ShapeQueue {
    /// Queues a shape cast (see [`TraceWorld::cast_shape`]).
    pub fn cast(&mut self, tag: u64, shape: Shape, dir: Vec3, max_t: f32, filter: QueryFilter) {
        self.casts.push(ShapeCastRequest {
            tag,
            shape,
            dir,
            max_t,
            filter,
        });
    }

    /// Queues a closest-point query (see [`TraceWorld::closest_point`]).
    pub fn closest_point(&mut self, tag: u64, point: Vec3, max_distance: f32, filter: QueryFilter) {
        self.closest.push(ClosestPointRequest {
            tag,
            point,
            max_distance,
            filter,
        });
    }

    /// Queues an overlap query (see [`TraceWorld::overlaps`]).
    pub fn overlap(&mut self, tag: u64, shape: Shape, filter: QueryFilter) {
        self.overlaps.push(OverlapRequest { tag, shape, filter });
    }

    /// Queues a containment query (see [`TraceWorld::containing`]).
    pub fn contains(&mut self, tag: u64, point: Vec3, filter: QueryFilter) {
        self.contains.push(ContainsRequest { tag, point, filter });
    }

    /// Requests waiting.
    pub fn len(&self) -> usize {
        self.casts.len() + self.closest.len() + self.overlaps.len() + self.contains.len()
    }

    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn clear(&mut self) {
        self.casts.clear();
        self.closest.clear();
        self.overlaps.clear();
        self.contains.clear();
    }
}

/// Answers of this frame's [`ShapeQueue`], in request order with their tags.
#[derive(Resource, Default, Debug, Clone)]
pub struct ShapeResults {
    /// The frame whose requests these answer.
    pub frame: u64,
    /// Shape casts: the first contact, if any.
    pub casts: Vec<(u64, Option<ShapeHit>)>,
    /// Closest points.
    pub closest: Vec<(u64, Option<NearestPoint>)>,
    /// Overlaps: `(entity, triangle)` pairs sorted by entity then triangle.
    pub overlaps: Vec<(u64, Vec<(Entity, u32)>)>,
    /// Containment: the entities holding the point, sorted.
    pub contains: Vec<(u64, Vec<Entity>)>,
}

impl TraceWorld {
    /// Answers every request of `queue` into `out` (resized to the requests; the overlap and containment
    /// lists keep their memory), in parallel when the `parallel` feature is on. What
    /// [`TraceSystems::Queries`](super::TraceSystems::Queries) runs; call it yourself for a world you
    /// drive by hand. The answers equal the immediate queries' and do not depend on the thread count.
    ///
    /// Closest points are answered as queued here; the plugin's system orders them as its
    /// [`PointBatches`] resource says.
    pub fn answer_shapes(&self, queue: &ShapeQueue, out: &mut ShapeResults) {
        self.answer_shapes_with(queue, out, None);
    }

    /// [`answer_shapes`](Self::answer_shapes), closest points in the order `batches` picks (see
    /// [`answer_closest`](Self::answer_closest)).
    fn answer_shapes_with(
        &self,
        queue: &ShapeQueue,
        out: &mut ShapeResults,
        batches: Option<(&mut PointBatches, &mut TraceStats)>,
    ) {
        out.casts.resize(queue.casts.len(), (0, None));
        parallel::fill(true, &mut out.casts, 16, |i| {
            let r = &queue.casts[i];
            let hit = self.cast_shape(&r.shape, r.dir, r.max_t, &r.filter);
            (r.tag, hit)
        });
        self.answer_closest(&queue.closest, &mut out.closest, batches);
        out.overlaps
            .resize_with(queue.overlaps.len(), Default::default);
        parallel::for_each_mut(true, &mut out.overlaps, |i, (tag, found)| {
            let r = &queue.overlaps[i];
            *tag = r.tag;
            self.overlaps(&r.shape, &r.filter, found);
        });
        out.contains
            .resize_with(queue.contains.len(), Default::default);
        parallel::for_each_mut(true, &mut out.contains, |i, (tag, found)| {
            let r = &queue.contains[i];
            *tag = r.tag;
            self.containing(r.point, &r.filter, found);
        });
    }
}

/// Part of [`TraceSystems::Queries`](super::TraceSystems::Queries), before the ray queries: answers and
/// drains the [`ShapeQueue`] (closest points in the order [`PointBatches`] picks), and records how many requests took how long
/// ([`TraceStats::batched_shapes`], [`TraceStats::shape_query_time`]), which the ray queries' system
/// hands to the adaptive policy with its own.
pub(crate) fn shape_queries_system(
    world: Res<TraceWorld>,
    mut queue: ResMut<ShapeQueue>,
    mut results: ResMut<ShapeResults>,
    mut points: ResMut<PointBatches>,
    mut stats: ResMut<TraceStats>,
) {
    let start = std::time::Instant::now();
    results.frame = stats.frame;
    world.answer_shapes_with(&queue, &mut results, Some((&mut points, &mut stats)));
    stats.batched_shapes = queue.len();
    queue.clear();
    stats.shape_query_time = start.elapsed();
}
