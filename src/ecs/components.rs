//! The components users put on entities.

use crate::anim::{MorphTargets, SkinWeights};
use crate::{Error, Mesh};
use bevy_ecs::prelude::*;
use glam::{Affine3A, Mat4, Vec3};
use std::sync::Arc;

/// Makes an entity traceable: its mesh in object space (the rest pose, for a skinned mesh). Cloning is
/// cheap (positions and indices are shared), so many entities can use one mesh.
///
/// Replacing it with a mesh of the same index buffer ([`Mesh::with_positions`]) counts as a deformation
/// (refit); a different index buffer is a topology change (rebuild).
#[derive(Component, Clone, Debug)]
#[require(TraceTransform, QueryLayers)]
pub struct TraceMesh(pub Mesh);

/// Object-to-world transform of a traceable entity; moving an entity only touches the top level. Write it
/// before [`TraceSystems::TopLevel`](super::TraceSystems::TopLevel), or let the plugin follow your own
/// transform component into it ([`KinetracePlugin::sync_transforms`](super::KinetracePlugin::sync_transforms)).
#[derive(Component, Clone, Copy, Debug, PartialEq, Default)]
pub struct TraceTransform(pub Affine3A);

/// Current object-space vertex positions of a deforming mesh, overriding [`TraceMesh`]'s. Write them (or
/// let [`TraceSkin`] write them) each frame the mesh deforms: a change means a refit, with no allocation.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct VertexPositions(pub Vec<Vec3>);

/// Linear-blend skinning of a [`TraceMesh`]: its weights and this frame's joint matrices (joint world
/// transform × inverse bind matrix, in the mesh's object space), and optionally morph targets with this
/// frame's weights, applied to the rest positions first. Changing it re-skins the mesh into
/// [`VertexPositions`] during [`TraceSystems::Skin`](super::TraceSystems::Skin).
#[derive(Component, Clone, Debug)]
#[require(VertexPositions)]
pub struct TraceSkin {
    /// Joints and weights per vertex, shared between entities with the same mesh.
    pub weights: Arc<SkinWeights>,
    /// The joint palette.
    pub joint_matrices: Vec<Mat4>,
    /// Blend shapes of the mesh, if any.
    pub morphs: Option<Arc<MorphTargets>>,
    /// Their weights this frame (one per target).
    pub morph_weights: Vec<f32>,
}

impl TraceSkin {
    /// A skin with these weights and matrices, no morph targets.
    pub fn new(weights: Arc<SkinWeights>, joint_matrices: Vec<Mat4>) -> Self {
        Self {
            weights,
            joint_matrices,
            morphs: None,
            morph_weights: Vec::new(),
        }
    }
}

/// Which query layers an entity is on (a bit mask; all by default). A query sees an entity when the masks
/// share a bit.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct QueryLayers(pub u32);

impl QueryLayers {
    /// Every layer.
    pub const ALL: QueryLayers = QueryLayers(u32::MAX);
}

impl Default for QueryLayers {
    fn default() -> Self {
        Self::ALL
    }
}

/// How an entity's geometry is expected to change; the policy uses it to pick the first builder and to
/// skip work. Without a hint an entity is treated as [`MotionHint::Deforming`].
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum MotionHint {
    /// Never moves: built once with the best builder.
    Static,
    /// Moves as a whole: only its transform changes, the top level follows.
    Rigid,
    /// Deforms: refitted, rebuilt when the tree degrades.
    #[default]
    Deforming,
}

/// Put on an entity whose geometry could not be used (non-finite skinned positions, joints out of range,
/// a transform that is not finite...). The entity is left out of every query until the cause is fixed and
/// this component removed; the rest of the world keeps working.
#[derive(Component, Clone, Debug)]
pub struct TraceError(pub Error);

/// Sent once each time an entity gets a [`TraceError`].
#[derive(Message, Clone, Debug)]
pub struct TraceErrorMessage {
    /// The entity.
    pub entity: Entity,
    /// What was wrong.
    pub error: Error,
}
