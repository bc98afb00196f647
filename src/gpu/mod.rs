//! The GPU back end on wgpu: LBVH rebuild, binned SAH and hybrid rebuilds ([`GpuSahBuilder`]), refit with the degradation metric, closest-hit and any-hit ray
//! queries, linear-blend skinning, and the broad phase of collision queries (the overlapping leaf pairs
//! of two trees, [`GpuPairs`]), as WGSL compute kernels in `shaders/` driven by thin Rust here.
//!
//! Results equal the CPU path's on the same input: the tree has the CPU [`Bvh`](crate::bvh::Bvh) layout,
//! and rays carry the CPU's precomputed watertight-test constants. Nothing here relies on WGSL guarantees it
//! does not give: no subgroup operations, no float atomics, no spinning between workgroups, and every read
//! of another invocation's results is separated from its write by a dispatch boundary (bottom-up passes
//! run one dispatch per tree level).
//!
//! ```no_run
//! use kinetrace::gpu::{GpuContext, GpuMeshBvh, GpuRays, Query};
//! use kinetrace::{Mesh, Ray, scenes};
//! use glam::Vec3;
//! # fn main() -> kinetrace::Result<()> {
//! let gpu = GpuContext::new()?; // Error::NoGpu when there is none: use the CPU path instead
//! let mesh = scenes::icosphere(4);
//! let mut bvh = GpuMeshBvh::new(&gpu, &mesh)?;
//! let mut rays = GpuRays::new(&gpu);
//! let mut frame = gpu.encoder();
//! bvh.record_build(&gpu, &mut frame);
//! let hits = rays.record(&gpu, &mut frame, &bvh, &[Ray::new(Vec3::new(0.0, 0.0, -3.0), Vec3::Z)], Query::Closest);
//! gpu.submit(frame);
//! let hits = hits.wait(&gpu)?; // or try_take() next frame, without stalling
//! assert!(hits[0].primitive().is_some());
//! # Ok(()) }
//! ```

pub(crate) mod buffers;
mod build_sah;
mod bvh;
mod collide;
mod context;
mod frame;
mod kernels;
mod ploc;
mod precise;
mod scan;
pub(crate) mod scene;
mod shadow_map;
mod skin;
pub(crate) mod sort;
pub mod taskpool;
pub(crate) mod trace;
mod tree;

pub use buffers::Readback;
pub use build_sah::{
    CLUSTERED_HYBRID_LEVELS, GPU_BINS, GpuBuildCounts, GpuSahBuilder, GpuSahOptions, HYBRID_LEVELS,
    SMALL_SPLIT_MAX, SWEEP_MAX, hybrid_levels,
};
pub use bvh::{BuildPhase, DegradationReadback, GpuMeshBvh, MAX_HISTOGRAM_BINS};
pub use collide::{GpuPairs, PairsReadback, PairsResult};
#[cfg(feature = "testing")]
pub use context::shared_for_tests;
pub use context::{
    ALLOW_SOFTWARE_ENV, GpuContext, GpuCounters, GpuOptions, adapter_accepted, software_allowed,
};
pub use frame::{
    Calibrated, CostReading, FrameBuilder, GpuPhases, Maintained, MeshUpdate, RefitState,
    ResidentMesh, SahReading,
};
pub(crate) use frame::{
    FrameCollider, FrameContacts, FrameInstance, FrameReadback, FrameTimer, PhasesReadback,
    ReadTrees, ResidentPairs, ResidentScene, world_bound,
};
pub use ploc::{GpuPloc, PlocBuildCounts};
#[cfg(feature = "testing")]
pub use precise::{divide, square_root};
pub use shadow_map::GpuShadowMap;
pub use skin::GpuSkin;
#[cfg(feature = "testing")]
pub use sort::sort_pairs;
pub use trace::{GpuHit, GpuRays, Query};
pub use tree::GpuTree;
