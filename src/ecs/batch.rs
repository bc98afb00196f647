//! Batched queries: gameplay systems push requests, [`TraceSystems::Queries`](super::TraceSystems::Queries) runs
//! them all at once, on all threads, and publishes the answers.

use super::{QueryFilter, RayHit};
use crate::geometry::Ray;
use bevy_ecs::prelude::*;
use glam::Vec3;

/// A closest-hit request; `tag` is yours (an entity's bits, an index...), returned with the answer.
#[derive(Clone, Debug)]
pub struct RayRequest {
    /// Your identifier.
    pub tag: u64,
    /// The world-space ray.
    pub ray: Ray,
    /// Which entities it may hit.
    pub filter: QueryFilter,
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
}

/// Requests queued this frame. Push from any system that runs before
/// [`TraceSystems::Queries`](super::TraceSystems::Queries); the queue is drained there (its memory is kept for the
/// next frame).
#[derive(Resource, Default, Debug)]
pub struct RayQueue {
    pub(crate) rays: Vec<RayRequest>,
    pub(crate) shadows: Vec<ShadowRequest>,
}

impl RayQueue {
    /// Queues a closest-hit query.
    pub fn cast(&mut self, tag: u64, ray: Ray, filter: QueryFilter) {
        self.rays.push(RayRequest { tag, ray, filter });
    }

    /// Queues an occlusion query from `from` to `to`.
    pub fn shadow(&mut self, tag: u64, from: Vec3, to: Vec3, filter: QueryFilter) {
        self.shadows.push(ShadowRequest {
            tag,
            from,
            to,
            filter,
        });
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
