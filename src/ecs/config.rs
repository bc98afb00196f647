//! Settings of the plugin, and the rebuild policy: Lauterbach's threshold, the adaptive cost model, or yours.

use super::MotionHint;
use crate::adaptive::Build;
use crate::bvh::Builder;
use crate::characterize::SceneProfile;
use crate::grid::GridOptions;
use bevy_ecs::prelude::*;

/// Where batched queries run. Immediate queries ([`SpatialRays`](super::SpatialRays)) and tree maintenance
/// run on the CPU in every mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum TraceMode {
    /// CPU only; no GPU device is ever created.
    #[default]
    Cpu,
    /// Batched queries on the GPU when a hardware adapter exists (feature `gpu`), else on the CPU, said once
    /// in the log. Software adapters (llvmpipe, lavapipe, WARP) are skipped — on the same cores the CPU path
    /// is faster — unless [`TraceConfig::allow_software_gpu`] or the environment variable
    /// `KINETRACE_ALLOW_SOFTWARE_GPU=1` allows them.
    GpuWhenAvailable,
    /// Batched queries on the GPU, software adapters included (CI machines without a GPU run lavapipe);
    /// [`KinetracePlugin::try_build`](super::KinetracePlugin::try_build) fails with
    /// [`Error::NoGpu`](crate::Error::NoGpu) without one.
    GpuRequired,
}

/// When batched query results become readable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Latency {
    /// In the frame the requests were pushed, after [`TraceSystems::Queries`](super::TraceSystems::Queries).
    #[default]
    SameFrame,
    /// One frame later: frame N's answers are published in frame N+1 (the mode that lets a GPU back end
    /// answer without stalling the frame).
    NextFrame,
}

/// What a [`Custom`](RebuildPolicy::Custom) policy sees about one mesh that was just refitted.
#[derive(Clone, Copy, Debug)]
pub struct PolicyInput<'a> {
    /// The entity's hint.
    pub hint: MotionHint,
    /// Triangles of the mesh.
    pub triangles: usize,
    /// The degradation metric after this frame's refit (thesis §4.1.5).
    pub degradation: f32,
    /// Frames since the tree was last built.
    pub frames_since_rebuild: u32,
    /// Batched requests answered last frame (see [`TraceStats::rays_last_frame`](super::TraceStats)).
    pub rays_last_frame: usize,
    /// The characteriser's profile of the mesh, when it has one.
    pub profile: Option<&'a SceneProfile>,
    /// Mean rise of the degradation per refit over the last refits.
    pub motion_incoherence: f32,
    /// Whether a GPU context exists to build on ([`Device::Gpu`](crate::adaptive::Device::Gpu) is honoured only then).
    pub gpu: bool,
}

/// What to do with a refitted mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    /// Keep the refitted tree.
    Keep,
    /// Rebuild it now, with this builder on this device. The GPU runs [`Build::GPU_LBVH`],
    /// [`Build::GPU_SAH`], [`Build::gpu_hybrid`] (16 bins, 30-bit codes) and PLOC of any radius
    /// ([`Build::GPU_PLOC`]); any other GPU build, or one with no GPU context, runs on the CPU instead (said
    /// once in the log).
    Rebuild(Build),
    /// Rebuild only the subtrees that degraded past the default [`PartialOptions`] (binned SAH on the CPU,
    /// see [`MeshBvh::rebuild_degraded`]); the wide tree is collapsed again when anything was rebuilt.
    /// Use it when a deformation is local (an explosion of a corner, a limb): it costs a pass over the
    /// nodes plus a build over the rebuilt triangles only, where a full rebuild costs one over all of
    /// them. The nodes above the rebuilt subtrees stay as refitted.
    ///
    /// [`PartialOptions`]: crate::bvh::PartialOptions
    /// [`MeshBvh::rebuild_degraded`]: crate::bvh::MeshBvh::rebuild_degraded
    PartialRebuild,
}

/// A custom policy: called once per refitted mesh per frame. Untouched meshes never reach it (they cost
/// nothing), new meshes and topology changes always rebuild.
pub type Policy = for<'a> fn(&PolicyInput<'a>) -> Decision;

/// Lauterbach's criterion at the thesis's threshold (§4.1.5): rebuild with CPU LBVH when the degradation
/// metric exceeds 0.40. The same as [`RebuildPolicy::LAUTERBACH`], as a [`Policy`] to call from your own.
pub fn lauterbach_policy(input: &PolicyInput<'_>) -> Decision {
    lauterbach(input.degradation, THESIS_THRESHOLD)
}

/// Lauterbach's threshold (thesis §4.1.5).
pub(super) const THESIS_THRESHOLD: f32 = 0.40;

pub(super) fn lauterbach(degradation: f32, threshold: f32) -> Decision {
    if degradation > threshold {
        Decision::Rebuild(Build::cpu(Builder::LBVH))
    } else {
        Decision::Keep
    }
}

/// How the plugin decides, per refitted mesh per frame, between keeping the refitted tree and rebuilding.
/// The top level follows the same rule after each of its refits: the same threshold under
/// [`Lauterbach`](Self::Lauterbach), its own cost model (binned SAH only) under
/// [`Adaptive`](Self::Adaptive), the thesis's 0.40 under [`Custom`](Self::Custom) (see
/// [`TopLevelStats`](super::TopLevelStats)).
///
/// | policy | costs per refitted mesh | use when |
/// |---|---|---|
/// | [`Lauterbach`](Self::Lauterbach) | a comparison | a simple, predictable rule (the default, 0.40) |
/// | [`Adaptive`](Self::Adaptive) | an SAH-cost pass over the nodes (about a refit's cost), and a pass over all meshes after the batched queries | the ray load or the motion varies, or a GPU may build faster than the CPU |
/// | [`Custom`](Self::Custom) | your function | anything else |
#[derive(Clone, Copy, Debug)]
pub enum RebuildPolicy {
    /// Rebuild with CPU LBVH when the degradation metric exceeds `threshold` (thesis §4.1.5: 0.40).
    Lauterbach {
        /// Degradation above which the mesh is rebuilt.
        threshold: f32,
    },
    /// The planner of [`AdaptivePolicy`](crate::adaptive::AdaptivePolicy), one per mesh, all learning into
    /// one shared cost table (so the second entity spawned from the same [`Mesh`](crate::Mesh) explores
    /// nothing): it rebuilds once the extra query time a degraded tree has cost exceeds a rebuild's
    /// measured time by the noise margin, or before its SAH cost would pass 1.5 × a fresh binned-SAH
    /// tree's (best effort: the guard predicts that fresh cost; see [`adaptive`](crate::adaptive) for
    /// what it rests on and the known gap), and picks the build — one of `builders` on the CPU, plus GPU LBVH when the world has a GPU context
    /// ([`TraceMode::GpuWhenAvailable`] or [`TraceMode::GpuRequired`] found an adapter) — whose rebuild
    /// plus queries it predicts cheapest. Its predictions are in [`MeshStats::prediction`](super::MeshStats).
    ///
    /// Query time is measured for the batched requests as a whole and apportioned over meshes by their
    /// expected traversal work, `A(world box) / A(scene box) × SAH cost` — the surface-area model of the
    /// rays a mesh receives. That is exact for rays spread evenly over the scene and off by the ratio of
    /// a mesh's real ray density to the modelled one otherwise (a mesh that every ray aims at is
    /// under-charged, one that none aims at over-charged); counting real per-mesh traversal work would
    /// cost every query. Batched shape queries ([`ShapeQueue`](super::ShapeQueue): casts, closest points,
    /// overlaps, containment) are timed and apportioned the same way, and teach what answers them — the
    /// mesh's rebuilds, builder and wide tree, not its grid or packet choices. Immediate queries ([`SpatialRays`](super::SpatialRays)) are not timed, so a scene
    /// queried only through them is treated as ray-free: it rebuilds only on the cost guard
    /// ([`AdaptivePolicy::sah_bound`](crate::adaptive::AdaptivePolicy::sah_bound): 1.5 × a fresh binned-SAH
    /// tree's SAH cost).
    Adaptive {
        /// The CPU builders to choose among (e.g. LBVH, hybrids with several `k`, binned SAH); one not
        /// measured on the mesh's asset is tried when its expected gain repays it (see
        /// [`adaptive`](crate::adaptive)).
        builders: &'static [Builder],
    },
    /// Your function.
    Custom(Policy),
}

impl RebuildPolicy {
    /// Lauterbach at the thesis's threshold, 0.40 (the default).
    pub const LAUTERBACH: RebuildPolicy = RebuildPolicy::Lauterbach {
        threshold: THESIS_THRESHOLD,
    };
    /// The adaptive policy over CPU LBVH, hybrid (6 LBVH levels) and binned SAH.
    pub const ADAPTIVE: RebuildPolicy = RebuildPolicy::Adaptive {
        builders: &[Builder::LBVH, Builder::HYBRID, Builder::SAH],
    };
}

impl Default for RebuildPolicy {
    fn default() -> Self {
        Self::LAUTERBACH
    }
}

/// Which structure answers a mesh's closest-hit and any-hit rays (batched and [`SpatialRays`](super::SpatialRays)).
/// Set it for every mesh in [`TraceConfig::structure`], or per entity with a [`TraceStructure`] component.
///
/// | structure | costs per frame the mesh changes | use when |
/// |---|---|---|
/// | [`Bvh`](Self::Bvh) | a refit, a rebuild when the policy asks | almost always: BVH queries are the fastest on CPU (docs/BENCHMARKS.md) |
/// | [`Grid`](Self::Grid) | a refit of the BVH *and* a grid rebuild (O(n), no allocation once warm) | evenly spread triangles of mixed sizes (soups, debris), or geometry whose BVH would be rebuilt every frame (explosions) |
/// | [`Auto`](Self::Auto) | [`Grid`](Self::Grid)'s or [`Bvh`](Self::Bvh)'s, plus an O(1) decision | let the characteriser's profile choose ([`choose_structure`](crate::grid::choose_structure)) |
///
/// A mesh kept as a grid keeps its BVH too, refitted every frame but never rebuilt by the policy: the
/// queries the grid does not answer read it — [`ray_hits`](super::TraceWorld::ray_hits), collisions, the
/// shape queries (casts, closest points, overlaps, containment), `world_triangles` and batches answered on
/// the GPU — as does the entity's world box; on exploding geometry those queries slow down as the
/// never-rebuilt BVH degrades. Under [`Auto`](Self::Auto) the profile's rule decides; with
/// [`RebuildPolicy::Adaptive`] it is only the prior, and the mesh's measured costs (maintenance, grid
/// rebuild included, and its share of the batched query time) decide through the planner, which tries
/// the other structure for at most three frames (module `planned`); the decision and its reason are in
/// [`TraceStats::structures`](super::TraceStats), the planner's pick in `TraceStats::options`. A change of structure takes effect the next time the mesh
/// is maintained: at once for a changed [`TraceStructure`], at the mesh's next deformation for a changed
/// [`TraceConfig::structure`] — so a static mesh under [`Auto`](Self::Auto) keeps the BVH it was first built
/// with (its profile arrives a frame later).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Structure {
    /// A BVH, refitted and rebuilt by the [`RebuildPolicy`] (the default).
    #[default]
    Bvh,
    /// A uniform grid ([`UniformGrid`](crate::grid::UniformGrid)) rebuilt every frame the mesh changes.
    Grid,
    /// The rule of [`grid::choice`](crate::grid::choice) on the mesh's current profile; under
    /// [`RebuildPolicy::Adaptive`], the planner's pick from measured costs with that rule as the prior.
    Auto,
}

/// Per-entity override of [`TraceConfig::structure`].
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TraceStructure(pub Structure);

/// The plugin's settings, a resource that may be changed at run time.
#[derive(Resource, Clone, Debug)]
pub struct TraceConfig {
    /// CPU or GPU for batched queries.
    pub mode: TraceMode,
    /// When batched results are published.
    pub latency: Latency,
    /// Builder for new deforming and rigid meshes and topology changes (under
    /// [`RebuildPolicy::Adaptive`], the adaptive policy's choice instead).
    pub builder: Builder,
    /// Builder for [`MotionHint::Static`] meshes (built once, so the best trees).
    pub static_builder: Builder,
    /// Refit-or-rebuild decision; [`RebuildPolicy::LAUTERBACH`] by default.
    pub policy: RebuildPolicy,
    /// A mesh is characterised again when its degradation has moved by more than this since its last
    /// profile (hysteresis: profiles, and choices made from them, do not flip every frame). 0.2 by default.
    pub profile_refresh: f32,
    /// Which structure answers rays, for meshes without a [`TraceStructure`]; [`Structure::Bvh`] by
    /// default.
    pub structure: Structure,
    /// Options of the grids of meshes kept as grids. Out of range (a λ that is not finite and positive, a
    /// zero macrocell), every mesh kept as a grid fails with a [`TraceError`](super::TraceError) holding
    /// [`Error::InvalidOption`](crate::Error::InvalidOption) and is not queried until the options are
    /// fixed and the error component removed.
    pub grid: GridOptions,
    /// Let [`TraceMode::GpuWhenAvailable`] use a software adapter (false by default; read when the plugin
    /// is built).
    pub allow_software_gpu: bool,
    /// Keep the frame on the GPU (false by default; takes effect in a GPU mode that found an adapter): the
    /// GPU-resident frame of [`gpu_frame`](super::gpu_frame). Every mesh is uploaded once; per frame one
    /// submission skins, refits or rebuilds (with [`builder`](Self::builder) where the GPU has it, else
    /// GPU LBVH; the policy's rule on the degradation metric and SAH cost read back one frame late), builds the top
    /// level and answers the batched requests, and the CPU uploads only joint matrices, transforms and
    /// rays. Under [`Latency::NextFrame`] the CPU never waits for the GPU (answers arrive as soon as a
    /// later frame finds them done, normally the next one); under [`Latency::SameFrame`] it waits once per
    /// frame.
    pub resident: bool,
}

impl Default for TraceConfig {
    fn default() -> Self {
        Self {
            mode: TraceMode::Cpu,
            latency: Latency::SameFrame,
            builder: Builder::LBVH,
            static_builder: Builder::SAH,
            policy: RebuildPolicy::LAUTERBACH,
            profile_refresh: 0.2,
            structure: Structure::Bvh,
            grid: GridOptions::default(),
            allow_software_gpu: false,
            resident: false,
        }
    }
}
