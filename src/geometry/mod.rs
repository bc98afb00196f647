//! Geometric primitives: boxes, rays, the watertight triangle test, exact orientation predicates and Morton
//! codes.

mod aabb;
mod morton;
mod predicates;
mod ray;
mod transform;
mod triangle;
#[cfg(target_arch = "x86_64")]
mod triangle4;

pub(crate) use aabb::sa_ratio_of_extents;
pub use aabb::{Aabb, MAX_SA_RATIO, sa_ratio};
pub(crate) use morton::spread10;
pub use morton::{morton30, morton30_cube, morton63};
pub use predicates::orient3d;
pub(crate) use predicates::{Plane, normal_est, orient2d_est};
pub use ray::{HIT_SLACK, ROBUST_FAR_SLACK, Ray, robust_far};
pub(crate) use ray::{hit_limit, max_keep, min_keep};
pub(crate) use transform::{check_finite, checked_inverse};
pub use triangle::{TriangleHit, TriangleRay};
#[cfg(target_arch = "x86_64")]
pub(crate) use triangle4::TriangleRays;
