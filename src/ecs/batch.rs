//! Batched queries: gameplay systems push requests, [`TraceSystems::Queries`](super::TraceSystems::Queries) runs
//! them all at once, on all threads, and publishes the answers.

use super::{QueryFilter, RayHit, RequestKind};
use crate::geometry::Ray;
use bevy_ecs::prelude::*;
use glam::Vec3;
use std::ops::Range;

/// A closest-hit request; `tag` is yours (an entity's bits, an index...), returned with the answer.
#[derive(Clone, Debug)]
pub struct RayRequest {
    /// Your identifier.
    pub tag: u64,
    /// The world-space ray.
    pub ray: Ray,
    /// Which entities it may hit.
    pub filter: QueryFilter,
    /// What kind of ray it is ([`RequestKind::Primary`] unless queued with
    /// [`cast_kind`](RayQueue::cast_kind)): secondary kinds may be traced in sorted order.
    pub kind: RequestKind,
}

/// An occlusion (shadow, line-of-sight) request between two world points.
#[derive(Clone, Debug)]
pub struct ShadowRequest {
    /// Your identifier.
    pub tag: u64,
    /// Start point.
    pub from: Vec3,
    /// End point.
    pub to: Vec3,
    /// Which entities may block it.
    pub filter: QueryFilter,
    /// What kind of ray it is ([`RequestKind::Primary`] unless queued with
    /// [`shadow_kind`](RayQueue::shadow_kind)): secondary kinds may be traced in sorted order.
    pub kind: RequestKind,
}

/// Requests queued this frame. Push from any system that runs before
/// [`TraceSystems::Queries`](super::TraceSystems::Queries); the queue is drained there (its memory is kept for the
/// next frame).
#[derive(Resource, Default, Debug)]
pub struct RayQueue {
    pub(crate) rays: Vec<RayRequest>,
    pub(crate) shadows: Vec<ShadowRequest>,
    /// Runs of `rays` queued by [`cast_packet`](Self::cast_packet), in order.
    pub(crate) ray_packets: Vec<Range<usize>>,
    /// Runs of `shadows` queued by [`shadow_packet`](Self::shadow_packet), in order.
    pub(crate) shadow_packets: Vec<Range<usize>>,
}

impl RayQueue {
    /// Queues a closest-hit query.
    pub fn cast(&mut self, tag: u64, ray: Ray, filter: QueryFilter) {
        self.cast_kind(tag, ray, RequestKind::Primary, filter);
    }

    /// Queues a closest-hit query of the given kind: a [`RequestKind::Reflection`] ray (or any secondary
    /// kind) joins the frame's batch of secondary closest-hit rays, which is traced in the order the
    /// [`SecondaryRays`](super::SecondaryRays) planner picks. Answers are the same either way.
    pub fn cast_kind(&mut self, tag: u64, ray: Ray, kind: RequestKind, filter: QueryFilter) {
        self.rays.push(RayRequest {
            tag,
            ray,
            filter,
            kind,
        });
    }

    /// Queues an occlusion query from `from` to `to`. The frame's single occlusion queries are answered
    /// in runs of up to 64 on all threads, each run's walks four at a time, interleaved
    /// ([`TraceWorld::occluded_interleaved`](super::TraceWorld::occluded_interleaved), each request
    /// through its own filter): the answers of [`TraceWorld::occluded`](super::TraceWorld::occluded).
    pub fn shadow(&mut self, tag: u64, from: Vec3, to: Vec3, filter: QueryFilter) {
        self.shadow_kind(tag, from, to, RequestKind::Primary, filter);
    }

    /// Queues an occlusion query of the given kind: a [`RequestKind::Shadow`] segment (or any secondary
    /// kind) joins the frame's batch of secondary occlusion rays (see [`cast_kind`](Self::cast_kind)).
    /// Put `from` at the light: segments of one light then share their origin, which keeps the ray
    /// hierarchy's spheres small.
    pub fn shadow_kind(
        &mut self,
        tag: u64,
        from: Vec3,
        to: Vec3,
        kind: RequestKind,
        filter: QueryFilter,
    ) {
        self.shadows.push(ShadowRequest {
            tag,
            from,
            to,
            filter,
            kind,
        });
    }

    /// Queues coherent closest-hit queries answered as packets (see
    /// [`TraceWorld::cast_packet`](super::TraceWorld::cast_packet)): a tile of camera rays, tile after tile,
    /// cut into packets of up to [`MAX_PACKET`](crate::bvh::MAX_PACKET). Ray `i` gets tag `first_tag + i`;
    /// answers appear in [`RayResults::hits`] in queue order, exactly as if each ray had been
    /// [`cast`](Self::cast) (same distances; the same entity and triangle unless two tie exactly).
    ///
    /// ```
    /// use kinetrace::ecs::{QueryFilter, RayQueue};
    /// use kinetrace::Ray;
    /// use glam::Vec3;
    /// let mut queue = RayQueue::default(); // normally the plugin's resource, in a gameplay system
    /// let eye = Vec3::new(0.0, 2.0, 10.0);
    /// for tile in 0..4u64 {
    ///     let rays: Vec<Ray> = (0..64)
    ///         .map(|i| Ray::new(eye, Vec3::new((i % 8) as f32 * 0.01, (i / 8) as f32 * 0.01, -1.0)))
    ///         .collect();
    ///     queue.cast_packet(tile * 64, &rays, QueryFilter::default());
    /// }
    /// // Shadow rays from points toward one light, as packets too.
    /// let points = [Vec3::ZERO, Vec3::X, Vec3::Z];
    /// queue.shadow_packet(1000, &points, Vec3::new(3.0, 20.0, 1.0), QueryFilter::default());
    /// assert_eq!(queue.len(), 4 * 64 + 3);
    /// ```
    pub fn cast_packet(&mut self, first_tag: u64, rays: &[Ray], filter: QueryFilter) {
        let start = self.rays.len();
        for (i, &ray) in rays.iter().enumerate() {
            self.cast(first_tag.wrapping_add(i as u64), ray, filter.clone());
        }
        push_packets(&mut self.ray_packets, start, self.rays.len());
    }

    /// Queues occlusion queries from every point of `from` to the common point `to` (shadow rays toward a
    /// point light, line of sight toward one eye), answered as packets (see
    /// [`TraceWorld::occluded_packet`](super::TraceWorld::occluded_packet)). Segment `i` gets tag
    /// `first_tag + i`; answers appear in [`RayResults::shadows`] in queue order.
    pub fn shadow_packet(&mut self, first_tag: u64, from: &[Vec3], to: Vec3, filter: QueryFilter) {
        let start = self.shadows.len();
        for (i, &p) in from.iter().enumerate() {
            self.shadow(first_tag.wrapping_add(i as u64), p, to, filter.clone());
        }
        push_packets(&mut self.shadow_packets, start, self.shadows.len());
    }

    /// Requests waiting.
    pub fn len(&self) -> usize {
        self.rays.len() + self.shadows.len()
    }

    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Records `start..end` as packets of up to [`MAX_PACKET`](crate::bvh::MAX_PACKET) requests.
fn push_packets(packets: &mut Vec<Range<usize>>, start: usize, end: usize) {
    let n = crate::bvh::MAX_PACKET;
    packets.extend((start..end).step_by(n).map(|s| s..(s + n).min(end)));
}

/// Answers of the last batch, in request order: `(tag, hit)` and `(tag, occluded)`.
#[derive(Resource, Default, Debug, Clone)]
pub struct RayResults {
    /// The frame whose requests these answer (see [`Latency`](super::Latency)).
    pub frame: u64,
    /// Closest hits.
    pub hits: Vec<(u64, Option<RayHit>)>,
    /// Occlusion answers.
    pub shadows: Vec<(u64, bool)>,
}
