//! Secondary rays in coherent order (seed 002, Reis 2015): 32-bit ray keys, a stable key sort, and two ways
//! to trace the sorted rays — through the ordinary BVH, or through the coherent ray-space hierarchy (CRSH)
//! of sphere–cone nodes built over them. RAH (Roger, Assarsson & Holzschuch 2007, as the seed re-implemented
//! it: the same hierarchy over unsorted rays, no mesh-sphere cull) is the baseline.
//!
//! When to use it: batches of incoherent secondary rays (shadow rays toward lights, reflection rays) against
//! one mesh. [`Strategy::SortedBvh`] costs one O(n) key pass plus a radix sort over the chunks of equal key
//! and pays where request order is incoherent; [`Strategy::SortedPackets`] traces the sorted rays as
//! packets (faster than the BVH on shadow rays toward one light, slower on reflection rays); [`Strategy::SortedRuns`] cuts
//! those packets where the key changes and sorts on the bits above the cut only (1.2× the wide
//! single-ray BVH on the crowd's reflection rays at 1024² before the sort, 1.01–1.05× with it). CRSH cuts intersection tests against RAH, but its traversal
//! tests every triangle sphere against every top node, so on the CPU it is slower than the BVH for meshes of
//! more than a few hundred triangles: measure (`bench raysort`) before choosing it.
//!
//! - [`key`]: the key layouts per ray kind.
//! - [`sort`]: trim, compress, radix sort, decompress: the sorted order.
//! - [`cone`]: the sphere–cone node and its tests.
//! - [`hierarchy`]: the bottom-up build over sorted rays.
//! - [`trace`]: the strategies and their answers in request order.
//! - `gpu` (feature `gpu`): the same sorted order computed on the GPU.
//! - `gpu_crsh` (feature `gpu`): the CRSH traversal on the GPU, answers equal to the CPU's.
//!
//! In the ECS, requests queued with a secondary [`RequestKind`](crate::ecs::RequestKind) form per-frame
//! batches traced by these strategies through the two-level world, picked per batch by the planner
//! ([`SecondaryRays`](crate::ecs::SecondaryRays)), on the CPU.

pub mod cone;
#[cfg(feature = "gpu")]
pub mod gpu;
#[cfg(feature = "gpu")]
pub mod gpu_crsh;
pub mod hierarchy;
pub mod key;
pub mod sort;
pub mod trace;

pub use cone::RayNode;
#[cfg(feature = "gpu")]
pub use gpu::sort_rays_gpu;
#[cfg(feature = "gpu")]
pub use gpu_crsh::trace_crsh_gpu;
pub use hierarchy::RayHierarchy;
pub use key::KeyLayout;
pub use sort::{SortScratch, SortedRays, sort_rays};
pub use trace::{Answer, RUN_LOW_BITS, RayScene, RayTestStats, Strategy, Traced};

use crate::Ray;

/// What a secondary ray asks, which also picks its key layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RayKind {
    /// Any hit within the ray's range (occlusion). Cast shadow rays from the light toward the surface point
    /// (as the seed does, range `[0, 1 - ε]` of `point - light`): rays of one light then share their origin
    /// and the hierarchy's spheres stay small.
    Shadow {
        /// The light's index; only its low [`KeyLayout::light_bits`] bits enter the key.
        light: u32,
    },
    /// The closest hit within the ray's range.
    Reflection,
}

/// A ray of a secondary batch, with the caller's tag (a pixel index, say), which sorting carries along.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SecondaryRay {
    /// The ray.
    pub ray: Ray,
    /// What it asks.
    pub kind: RayKind,
    /// Caller's data, never read.
    pub tag: u32,
}
