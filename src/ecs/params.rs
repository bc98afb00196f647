//! The immediate query system parameter.

use super::{NearestPoint, QueryFilter, RayHit, ShapeHit, TraceWorld};
use crate::geometry::Ray;
use crate::queries::Shape;
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use glam::Vec3;

/// Immediate ray queries for gameplay systems, against the structures of this frame (use it in systems
/// ordered after [`TraceSystems::TopLevel`](super::TraceSystems::TopLevel)). CPU traversal; cost: one top-level
/// traversal plus one per entity whose box the ray reaches.
///
/// ```
/// # use kinetrace::ecs::*;
/// # use kinetrace::Ray;
/// # use bevy_ecs::prelude::*;
/// # use glam::Vec3;
/// fn aim(rays: SpatialRays, shooters: Query<(Entity, &TraceTransform)>) {
///     for (me, t) in &shooters {
///         let ray = Ray::new(t.0.translation.into(), Vec3::Z);
///         if let Some(hit) = rays.cast_ray(&ray, 100.0, &QueryFilter::default().exclude(me)) {
///             println!("{me} sees {} at {} m, triangle {}", hit.entity, hit.distance, hit.triangle);
///         }
///     }
/// }
/// # let mut s = Schedule::default(); s.add_systems(aim);
/// ```
#[derive(SystemParam)]
pub struct SpatialRays<'w> {
    world: Res<'w, TraceWorld>,
}

impl SpatialRays<'_> {
    /// The nearest hit within `max_t` (and the ray's own range).
    pub fn cast_ray(&self, ray: &Ray, max_t: f32, filter: &QueryFilter) -> Option<RayHit> {
        self.world.cast_ray(ray, max_t, filter)
    }

    /// Whether anything accepted lies between two points.
    pub fn occluded(&self, from: Vec3, to: Vec3, filter: &QueryFilter) -> bool {
        self.world.occluded(from, to, filter)
    }

    /// Every hit along the ray, nearest first.
    pub fn ray_hits(&self, ray: &Ray, filter: &QueryFilter) -> Vec<RayHit> {
        let mut out = Vec::new();
        self.world.ray_hits(ray, filter, &mut out);
        out
    }

    /// The first contact of `shape` (world space) swept along `dir` up to `max_t`, among accepted entities
    /// (see [`TraceWorld::cast_shape`]): a character's capsule before it moves, a thrown ball's path.
    pub fn cast_shape(
        &self,
        shape: &Shape,
        dir: Vec3,
        max_t: f32,
        filter: &QueryFilter,
    ) -> Option<ShapeHit> {
        self.world.cast_shape(shape, dir, max_t, filter)
    }

    /// The nearest surface point of an accepted entity within `max_distance` (see
    /// [`TraceWorld::closest_point`]).
    pub fn closest_point(
        &self,
        p: Vec3,
        max_distance: f32,
        filter: &QueryFilter,
    ) -> Option<NearestPoint> {
        self.world.closest_point(p, max_distance, filter)
    }

    /// Every `(entity, triangle)` the shape touches, into `out` (see [`TraceWorld::overlaps`]).
    pub fn overlaps(&self, shape: &Shape, filter: &QueryFilter, out: &mut Vec<(Entity, u32)>) {
        self.world.overlaps(shape, filter, out);
    }

    /// The accepted entities whose closed meshes hold `p` (see [`TraceWorld::containing`]).
    pub fn contains(&self, p: Vec3, filter: &QueryFilter) -> Vec<Entity> {
        let mut out = Vec::new();
        self.world.containing(p, filter, &mut out);
        out
    }

    /// The structures themselves.
    pub fn world(&self) -> &TraceWorld {
        &self.world
    }
}
