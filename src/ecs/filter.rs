//! Which entities a query sees, and what it returns.

use super::QueryLayers;
use bevy_ecs::entity::Entity;
use glam::{Vec2, Vec3};
use std::sync::Arc;

/// Filters entities out of a query: by layer mask, by a list of excluded entities (the caster itself,
/// typically), and by an optional predicate. The default sees everything.
///
/// ```
/// # use kinetrace::ecs::QueryFilter;
/// # use bevy_ecs::entity::Entity;
/// let me = Entity::PLACEHOLDER;
/// let f = QueryFilter::default().layers(0b10).exclude(me).predicate(|e| e.index_u32() % 2 == 0);
/// assert!(!f.accepts(me, 0b10));
/// ```
#[derive(Clone, Default)]
pub struct QueryFilter {
    /// Layer mask; an entity is seen when its [`QueryLayers`] share a bit with it. 0 means all.
    pub layers: u32,
    /// Entities never hit.
    pub excluded: Vec<Entity>,
    /// Entities for which this returns false are never hit.
    pub predicate: Option<Arc<dyn Fn(Entity) -> bool + Send + Sync>>,
}

impl std::fmt::Debug for QueryFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QueryFilter")
            .field("layers", &self.layers)
            .field("excluded", &self.excluded)
            .field("predicate", &self.predicate.is_some())
            .finish()
    }
}

impl QueryFilter {
    /// Whether `other` accepts exactly the entities this one does by construction: the same layers, the
    /// same excluded list and the same predicate object (compared by address, not by what it returns).
    pub(crate) fn same_as(&self, other: &QueryFilter) -> bool {
        self.layers == other.layers
            && self.excluded == other.excluded
            && match (&self.predicate, &other.predicate) {
                (None, None) => true,
                (Some(a), Some(b)) => Arc::ptr_eq(a, b),
                _ => false,
            }
    }

    /// Only entities on these layers.
    pub fn layers(mut self, mask: u32) -> Self {
        self.layers = mask;
        self
    }

    /// Never this entity.
    pub fn exclude(mut self, e: Entity) -> Self {
        self.excluded.push(e);
        self
    }

    /// Only entities for which `f` is true.
    pub fn predicate(mut self, f: impl Fn(Entity) -> bool + Send + Sync + 'static) -> Self {
        self.predicate = Some(Arc::new(f));
        self
    }

    /// Whether an entity on `layers` passes.
    pub fn accepts(&self, e: Entity, layers: u32) -> bool {
        let mask = if self.layers == 0 {
            QueryLayers::ALL.0
        } else {
            self.layers
        };
        mask & layers != 0
            && !self.excluded.contains(&e)
            && self.predicate.as_ref().is_none_or(|p| p(e))
    }
}

/// A ray's hit on an entity, in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// The entity hit.
    pub entity: Entity,
    /// Distance along the ray in units of its direction (world units for a unit direction).
    pub distance: f32,
    /// World-space point.
    pub point: Vec3,
    /// Unit world-space geometric normal (winding order, not facing the ray).
    pub normal: Vec3,
    /// Triangle index in the entity's mesh.
    pub triangle: u32,
    /// Barycentric weights of the triangle's second and third vertices.
    pub barycentrics: Vec2,
}
