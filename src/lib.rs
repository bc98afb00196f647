//! # kinetrace
//!
//! Fast, correct ray, shadow and collision queries against meshes that move and deform every frame —
//! skinned characters included — for `bevy_ecs` games and simulations.
//!
//! Each frame it keeps one BVH per mesh current — refitted in O(n) while the motion is coherent, rebuilt
//! when Lauterbach's degradation metric says the tree has decayed — and answers closest-hit, any-hit
//! (shadow) and collision queries against it:
//!
//! - [`geometry`]: boxes, rays, the watertight triangle test, Morton codes.
//! - [`bvh`]: one node layout built four ways (LBVH, hybrid, binned SAH, median), refit, closest-hit and
//!   any-hit traversal, quality metrics.
//! - [`collide`]: mesh–mesh and self-collision contacts with exact triangle–triangle tests, and first
//!   times of contact of meshes swept over a frame.
//! - `gpu` (feature `gpu`, on by default): the same on wgpu compute — LBVH build, refit, ray queries,
//!   skinning, the collision broad phase — with results equal to the CPU's.
//! - [`anim`]: glTF loading, skeletons, animation sampling, CPU skinning, the procedural humanoid.
//! - [`characterize`] and [`adaptive`]: the scene profile and the learned refit-or-rebuild policy.
//! - [`ecs`]: the `bevy_ecs` plugin that runs all of it per frame, and the query parameter for gameplay code.
//! - [`scenes`]: procedural meshes for examples, tests and benchmarks.
//!
//! The core API alone, without an ECS:
//!
//! ```
//! use kinetrace::prelude::*;
//! use glam::Vec3;
//!
//! // A unit quad in the z = 0 plane, two triangles sharing the diagonal.
//! let positions = vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
//! let mesh = Mesh::new(positions, vec![0, 1, 2, 0, 2, 3])?;
//! let mut bvh = MeshBvh::build(&mesh, &BuildOptions::new(Builder::SAH))?;
//!
//! // A ray straight down through the shared diagonal hits exactly one triangle.
//! let hit = bvh.closest_hit(&Ray::new(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z)).expect("a hit");
//! assert_eq!(hit.t, 2.0);
//! assert_eq!(hit.normal, Vec3::Z);
//!
//! // Shadow ray: is anything between these two points?
//! assert!(bvh.any_hit(&Ray::segment(Vec3::new(0.3, 0.6, 1.0), Vec3::new(0.3, 0.6, -1.0))));
//!
//! // The mesh moves: refit, and rebuild when the tree has degraded too much (thesis threshold 0.40).
//! let moved: Vec<Vec3> = mesh.positions().iter().map(|p| *p * Vec3::new(3.0, 1.0, 1.0)).collect();
//! let degradation = bvh.refit(&moved)?;
//! if degradation > 0.40 {
//!     bvh = MeshBvh::build(&mesh.with_positions(moved)?, &BuildOptions::new(Builder::LBVH))?;
//! }
//! assert!(bvh.closest_hit(&Ray::new(Vec3::new(2.5, 0.5, 1.0), -Vec3::Z)).is_some());
//!
//! // Bad input is an error, not a panic.
//! assert!(Mesh::new(vec![Vec3::NAN], vec![0, 0, 0]).is_err());
//! # Ok::<(), kinetrace::Error>(())
//! ```

#![warn(missing_docs)]

pub mod adaptive;
pub mod anim;
pub mod bvh;
pub mod characterize;
pub mod collide;
pub mod dispatch;
pub mod ecs;
mod error;
pub mod geometry;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod grid;
mod mesh;
mod parallel;
pub mod queries;
pub mod raysort;
pub mod scenes;
pub mod shadows;
pub mod sound;

pub use bvh::{Hit, MeshBvh};
pub use error::{Error, Result};
pub use geometry::{Aabb, Ray};
pub use mesh::Mesh;

/// The types most programs need.
pub mod prelude {
    pub use crate::bvh::{BuildOptions, Builder, Bvh, Hit, MeshBvh, MortonBits};
    pub use crate::geometry::{Aabb, Ray};
    pub use crate::{Error, Mesh, Result};
}

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
