//! Settings of the plugin, and the pluggable rebuild policy.

use super::MotionHint;
use crate::bvh::Builder;
use crate::characterize::SceneProfile;
use bevy_ecs::prelude::*;

/// Where batched queries run. Immediate queries ([`SpatialRays`](super::SpatialRays)) and tree maintenance
/// run on the CPU in every mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum TraceMode {
    /// CPU only; no GPU device is ever created.
    #[default]
    Cpu,
    /// Batched queries on the GPU when an adapter exists (feature `gpu`), else on the CPU, said once in the
    /// log.
    GpuWhenAvailable,
    /// Batched queries on the GPU; [`KinetracePlugin::try_build`](super::KinetracePlugin::try_build) fails
    /// with [`Error::NoGpu`](crate::Error::NoGpu) without one.
    GpuRequired,
}

/// When batched query results become readable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Latency {
    /// In the frame the requests were pushed, after [`TraceSet::Queries`](super::TraceSet::Queries).
    #[default]
    SameFrame,
    /// One frame later: frame N's answers are published in frame N+1 (the mode that lets a GPU back end
    /// answer without stalling the frame).
    NextFrame,
}

/// What the policy sees about one mesh that was just refitted.
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
    /// The configured threshold ([`TraceConfig::rebuild_threshold`]).
    pub threshold: f32,
    /// Rays queried against the world last frame (immediate and batched).
    pub rays_last_frame: usize,
    /// The characteriser's profile of the mesh, when it has one.
    pub profile: Option<&'a SceneProfile>,
    /// Mean rise of the degradation per refit over the last refits.
    pub motion_incoherence: f32,
}

/// What to do with a refitted mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    /// Keep the refitted tree.
    Keep,
    /// Rebuild it now with this builder.
    Rebuild(Builder),
}

/// The policy: called once per refitted mesh per frame. Untouched meshes never reach it (they cost
/// nothing), new meshes and topology changes always rebuild.
pub type Policy = for<'a> fn(&PolicyInput<'a>) -> Decision;

/// Lauterbach's criterion (thesis §4.1.5): rebuild with LBVH when the degradation metric exceeds the
/// threshold (0.40 by default).
pub fn lauterbach_policy(input: &PolicyInput<'_>) -> Decision {
    if input.degradation > input.threshold {
        Decision::Rebuild(Builder::LBVH)
    } else {
        Decision::Keep
    }
}

/// The plugin's settings, a resource that may be changed at run time.
#[derive(Resource, Clone, Debug)]
pub struct TraceConfig {
    /// CPU or GPU for batched queries.
    pub mode: TraceMode,
    /// When batched results are published.
    pub latency: Latency,
    /// Degradation above which the default policy rebuilds (0.40).
    pub rebuild_threshold: f32,
    /// Builder for new deforming and rigid meshes and topology changes.
    pub builder: Builder,
    /// Builder for [`MotionHint::Static`] meshes (built once, so the best trees).
    pub static_builder: Builder,
    /// Refit-or-rebuild decision.
    pub policy: Policy,
    /// A mesh is characterised again when its degradation has moved by more than this since its last
    /// profile (hysteresis: profiles, and choices made from them, do not flip every frame). 0.2 by default.
    pub profile_refresh: f32,
}

impl Default for TraceConfig {
    fn default() -> Self {
        Self {
            mode: TraceMode::Cpu,
            latency: Latency::SameFrame,
            rebuild_threshold: 0.40,
            builder: Builder::LBVH,
            static_builder: Builder::SAH,
            policy: lauterbach_policy,
            profile_refresh: 0.2,
        }
    }
}
