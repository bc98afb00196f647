//! Gameplay queries beyond rays, against the same refitted trees: closest points, containment, shape
//! overlaps and shape casts.
//!
//! - [`MeshBvh::closest_point`]: the nearest point of a mesh (with the triangle, barycentrics and whether
//!   it lies on a face, an edge or a corner), optionally within a maximum distance.
//! - [`MeshBvh::contains_point`]: inside or outside a closed mesh, exact (winding number along an
//!   axis-parallel ray with exact predicates and simulation of simplicity; points on the surface are
//!   inside).
//! - [`MeshBvh::overlapping`]: the triangles a [`Shape`] (sphere, capsule, oriented box) touches.
//! - [`MeshBvh::cast_sphere`], [`MeshBvh::cast_capsule`], [`MeshBvh::cast_box`]: the first contact of a
//!   shape swept along a line (time of impact, point, normal, triangle, barycentrics), including a start in
//!   contact (`t = 0` with the way out); [`MeshBvh::cast_shape`] takes any [`Shape`].
//!
//! For a batch of points asked in no particular order, [`MortonOrder`] gives the order that keeps
//! neighbouring queries together (and the tree's nodes in cache).
//!
//! Across the entities of a `bevy_ecs` scene, with world transforms and filters, the same queries are on
//! [`SpatialRays`](crate::ecs::SpatialRays) and, batched, [`ShapeQueue`](crate::ecs::ShapeQueue).
//!
//! All of them read the tree's current corners, so after [`MeshBvh::refit`] they answer for the deformed
//! mesh; zero-area triangles are absent, as they are for rays and collisions. Distances and overlap tests
//! run in `f64` on the `f32` corners.
//!
//! ```
//! use kinetrace::{MeshBvh, bvh::BuildOptions, queries::Shape, scenes};
//! use glam::Vec3;
//! let mut ball = MeshBvh::build(&scenes::icosphere(2), &BuildOptions::default())?;
//! let near = ball.closest_point(Vec3::new(3.0, 0.0, 0.0), f32::INFINITY).unwrap();
//! assert!((near.distance - 2.0).abs() < 0.05);
//! assert!(ball.contains_point(Vec3::new(0.5, 0.0, 0.0)));
//! let mut touched = Vec::new();
//! ball.overlapping(&Shape::sphere(Vec3::new(1.0, 0.0, 0.0), 0.1), &mut touched);
//! assert!(!touched.is_empty());
//! # Ok::<(), kinetrace::Error>(())
//! ```

#[cfg(doc)]
use crate::MeshBvh;

mod ascending;
mod cast;
mod closest;
mod contains;
mod frame;
mod morton_order;
mod overlap;
mod point_bound;
mod shapes;

pub(crate) use ascending::sort_ascending;
pub(crate) use cast::Sweep;
pub(crate) use closest::box_dist2;
#[cfg(test)]
pub(crate) use closest::closest_on_triangle;
pub(crate) use frame::Frame;

pub use cast::CastHit;
pub use closest::{Feature, PointHit};
pub use morton_order::MortonOrder;
pub use shapes::Shape;
