//! # kinetrace
//!
//! Fast, correct ray, shadow and collision queries against meshes that move and deform every frame —
//! skinned characters included — for `bevy_ecs` games and simulations.
//!
//! This release is the CPU core: geometry ([`geometry`]), one BVH layout built four ways, refitted in O(n)
//! with Lauterbach's degradation metric, and queried with watertight closest-hit and any-hit traversal
//! ([`bvh`]).
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
pub mod ecs;
mod error;
pub mod geometry;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod grid;
mod mesh;
mod parallel;
pub mod scenes;

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
