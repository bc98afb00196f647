//! What the crate did this frame, and why.

use crate::adaptive::{Build, Prediction};
use crate::grid::{ChoiceReason, StructureKind};
use bevy_ecs::prelude::*;
use std::time::Duration;

/// What happened to one mesh this frame. Meshes that did nothing are not listed (they cost nothing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MeshAction {
    /// Refitted, keeping the tree (its degradation is in [`MeshStats::degradation`]).
    Refit,
    /// Built from scratch.
    Rebuild {
        /// With which builder, on which device (where it really ran: a GPU build asked for without a GPU
        /// context runs on the CPU).
        build: Build,
        /// Why.
        reason: RebuildReason,
    },
    /// Refitted, then its degraded subtrees rebuilt ([`Decision::PartialRebuild`](super::Decision) or
    /// the adaptive policy's [`Verdict::Partial`](crate::adaptive::Verdict::Partial)).
    PartialRebuild {
        /// Triangles in the rebuilt subtrees (0 when none had degraded enough).
        triangles: usize,
    },
    /// Only moved: the top level followed, the tree was untouched.
    Moved,
    /// Left out after an error (see [`TraceError`](super::TraceError)).
    Failed,
}

/// Why a tree was rebuilt.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RebuildReason {
    /// The entity is new (or recovered from an error).
    New,
    /// Its index buffer changed.
    Topology,
    /// The policy asked for it after a refit.
    Policy,
}

/// One mesh's work this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshStats {
    /// The entity.
    pub entity: Entity,
    /// What was done.
    pub action: MeshAction,
    /// Degradation metric after the refit (0 for fresh builds).
    pub degradation: f32,
    /// Time spent on it.
    pub time: Duration,
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy): why a refitted mesh was kept or rebuilt
    /// (the predicted rebuild time against the extra query time paid so far, or the cost guard, or a
    /// build being tried). `None` for other policies and for meshes that were not refitted.
    pub prediction: Option<Prediction>,
}

/// Which structure answers one mesh's rays, and why (see [`Structure`](super::Structure)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StructureStats {
    /// The entity.
    pub entity: Entity,
    /// The structure that answers its closest-hit and any-hit rays.
    pub structure: StructureKind,
    /// Why that one.
    pub why: StructureWhy,
}

/// A per-mesh option the planner ([`Choice`](crate::adaptive::Choice)) picked this frame, under
/// [`RebuildPolicy::Adaptive`](super::RebuildPolicy).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OptionStats {
    /// The entity.
    pub entity: Entity,
    /// The option in use from this frame on.
    pub option: PlannedOption,
    /// Whether it is being tried (not measured often enough yet) rather than chosen on measurements.
    pub tried: bool,
}

/// The per-mesh options the planner picks (more join as they become planner options).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlannedOption {
    /// The wide (4-lane) query tree on (`true`) or the binary tree only: the wide tree costs a collapse
    /// per build and its refit every frame, and repays it only with enough rays.
    Wide(bool),
    /// Queued packet requests meet the mesh as packets (`true`) or ray by ray: a packet shares its node
    /// visits among coherent rays and repays its lane bookkeeping only when they stay together.
    Packets(bool),
    /// How this frame's batch of secondary rays was traced ([`SecondaryRays`](super::SecondaryRays)). A
    /// choice per batch, not per mesh: its [`OptionStats::entity`] is `Entity::PLACEHOLDER`.
    Secondary(super::RayBatch, super::SecondaryStrategy),
    /// The order this frame's batch of closest-point requests was answered in
    /// ([`PointBatches`](super::PointBatches)). A choice per batch: its [`OptionStats::entity`] is
    /// `Entity::PLACEHOLDER`.
    PointOrder(super::PointOrder),
    /// The structure that answers the mesh's rays, for a mesh under [`Structure::Auto`](super::Structure):
    /// the grid costs a rebuild every frame and repays it only where it answers rays faster than the
    /// BVH (why it was picked: [`TraceStats::structures`]).
    Structure(StructureKind),
    /// The grid's [triangle–cell overlap test](crate::grid::GridOptions::overlap_test) on (`true`) or
    /// triangles binned by their boxes, for a mesh the planner keeps as a grid: the test slows every
    /// rebuild 2.2–2.6× and repays it only where its fewer references speed up enough rays.
    Overlap(bool),
}

/// Why a mesh is kept in its structure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StructureWhy {
    /// [`Structure::Bvh`](super::Structure) or [`Structure::Grid`](super::Structure), by the config or the
    /// entity's [`TraceStructure`](super::TraceStructure).
    Fixed,
    /// [`Structure::Auto`](super::Structure): the rule's reason.
    Rule(ChoiceReason),
}

/// What happened to the top-level tree this frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TopLevelAction {
    /// Nothing moved, came or went: the tree was untouched.
    #[default]
    Unchanged,
    /// Refitted to the entities' new boxes, keeping the tree (its degradation is in
    /// [`TopLevelStats::degradation`]).
    Refit,
    /// Built from scratch (binned SAH over the entity boxes).
    Rebuild {
        /// Why.
        reason: TopLevelReason,
    },
}

/// Why the top-level tree was rebuilt.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TopLevelReason {
    /// Entities came or went (the first build included).
    Membership,
    /// The rebuild policy asked for it after a refit (see [`RebuildPolicy`](super::RebuildPolicy)).
    Policy,
}

/// The top level's report: this frame's action, the tree's state, and totals since the plugin started.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TopLevelStats {
    /// What was done this frame.
    pub action: TopLevelAction,
    /// The degradation metric of this frame's refit, as for meshes (on a policy rebuild, the value that
    /// triggered it); 0 in frames without a refit.
    pub degradation: f32,
    /// Refits since the tree was last built.
    pub frames_since_rebuild: u32,
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy): why the refitted tree was kept or rebuilt.
    /// `None` for other policies and in frames without a refit.
    pub prediction: Option<Prediction>,
    /// Refits since the plugin started.
    pub refits: u64,
    /// Rebuilds since the plugin started.
    pub rebuilds: u64,
}

/// Per-frame diagnostics, overwritten each frame.
#[derive(Resource, Clone, Debug, Default)]
pub struct TraceStats {
    /// Frames run so far.
    pub frame: u64,
    /// Meshes that did work.
    pub meshes: Vec<MeshStats>,
    /// Meshes characterised this frame, with their new profile (the current one of every mesh is in
    /// [`TraceWorld::profile`](super::TraceWorld::profile)).
    pub profiles: Vec<(Entity, std::sync::Arc<crate::characterize::SceneProfile>)>,
    /// Per mesh maintained this frame, which structure answers its rays and why (meshes not maintained keep
    /// last frame's).
    pub structures: Vec<StructureStats>,
    /// Per mesh maintained this frame under the adaptive policy, the options the planner picked; and per
    /// secondary batch answered this frame, how it was traced ([`PlannedOption::Secondary`]); and for the
    /// batch of closest points, its order ([`PlannedOption::PointOrder`]).
    pub options: Vec<OptionStats>,
    /// Time spent characterising.
    pub characterize_time: Duration,
    /// Refits, rebuilds, and meshes only moved.
    pub refits: usize,
    /// Rebuilds.
    pub rebuilds: usize,
    /// Builds run only to measure them ([`AdaptivePolicy::calibration`](crate::adaptive::AdaptivePolicy::calibration):
    /// at an asset's rebuilds under [`RebuildPolicy::Adaptive`](super::RebuildPolicy), each build
    /// offered that no mesh of it measured and that may pay for its time); their time is in their mesh's
    /// [`MeshStats::time`].
    pub calibrations: usize,
    /// Partial rebuilds this frame (counted in `refits` too: each starts with a refit); the triangles of
    /// each are in its [`MeshAction::PartialRebuild`].
    pub partial_rebuilds: usize,
    /// Triangles rebuilt by this frame's partial rebuilds, all meshes together.
    pub partial_triangles: usize,
    /// Meshes whose adaptive policy weighed a partial rebuild this frame: a pass over the mesh's nodes
    /// ([`Bvh::degraded_primitives`](crate::bvh::Bvh::degraded_primitives)), paid only where the rent
    /// made a rebuild due.
    pub partial_checks: usize,
    /// Refits run ahead of the meshes' turns, in parallel across meshes with the `parallel` feature
    /// (counted in `refits` too): every changed mesh that keeps its topology and is not rebuilt without a
    /// refit; new meshes and topology changes are refitted or built in turn.
    pub refits_ahead: usize,
    /// Meshes whose only change was their transform.
    pub moved: usize,
    /// New meshes that started from a copy of a sibling's tree (another entity of the same mesh),
    /// refitted, instead of a build of their own (counted in `refits` too; adaptive policy only).
    pub siblings: usize,
    /// What was done to the top level (the tree over the entities' world boxes), its degradation and its
    /// running totals.
    pub top_level: TopLevelStats,
    /// Batched closest-hit and occlusion requests answered.
    pub batched_rays: usize,
    /// The same count of the previous frame (what the policy sees).
    pub rays_last_frame: usize,
    /// Batched shape casts, closest points, overlaps and containment requests answered
    /// ([`ShapeQueue`](super::ShapeQueue)).
    pub batched_shapes: usize,
    /// The same count of the previous frame (what the adaptive policy sees beside the rays).
    pub shapes_last_frame: usize,
    /// Time per phase: clip sampling and joint matrices.
    pub animate_time: Duration,
    /// Skinning.
    pub skin_time: Duration,
    /// Refit and rebuild of meshes.
    pub maintain_time: Duration,
    /// Transforms and the top level.
    pub top_level_time: Duration,
    /// Batched ray queries.
    pub query_time: Duration,
    /// Batched shape queries ([`ShapeQueue`](super::ShapeQueue)).
    pub shape_query_time: Duration,
    /// This frame's GPU traffic: bytes uploaded and read back, submissions, blocking waits, and bytes of
    /// device buffers allocated (nonzero in a frame that made or grew a tree's or builder's buffers; all
    /// zero without a GPU context).
    #[cfg(feature = "gpu")]
    pub gpu: crate::gpu::GpuCounters,
    /// In the GPU-resident frame on a device with timestamp queries: the GPU's time per phase of the
    /// frame whose answers were published this frame ([`RayResults::frame`](super::RayResults)); `None`
    /// otherwise.
    #[cfg(feature = "gpu")]
    pub gpu_phases: Option<crate::gpu::GpuPhases>,
    /// What the GPU-resident frame did this frame (all zero outside it).
    #[cfg(feature = "gpu")]
    pub resident: super::ResidentStats,
    /// In the GPU-resident frame, the GPU's work per mesh this frame: refitted, or rebuilt with which GPU
    /// build and why; under the adaptive policy with the planner's grounds for a refitted tree judged
    /// this frame (its `time` is zero: the GPU's time per phase is in `gpu_phases`). Empty outside it.
    #[cfg(feature = "gpu")]
    pub resident_meshes: Vec<MeshStats>,
}
