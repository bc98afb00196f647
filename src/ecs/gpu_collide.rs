//! Collider pairs in the GPU-resident frame ([`gpu_frame`](super::gpu_frame)): the pair traversal runs on
//! the GPU in the frame's submission, over the trees the frame just maintained; the exact triangle tests
//! run on the CPU when the answers come back, so the contacts are those of the CPU's query on the same
//! geometry.
//!
//! Which pairs: every two colliders on interacting [`CollisionLayers`](super::CollisionLayers) whose
//! world boxes overlap, and each self-colliding one with itself. The boxes are this frame's, computed on
//! the CPU when the frame is recorded, without a read-back (`gpu::frame::bound`): from the joint
//! matrices for a GPU skin (each joint's bind-pose box of the vertices it moves, carried by the joint's
//! matrix), from the positions for a mesh deformed on the CPU, then through the transform; conservative by
//! construction and widened by a relative 2^-16 for the GPU's rounding, so a culled pair has no contact.
//! It is looser than the vertices' own box (a turned joint's box is carried whole), so some pairs apart
//! are still traversed. Culling on the GPU from the top level instead would still record every pair's
//! rounds (up to 130 dispatches each after a GPU build) and read back every pair's answers; culled on
//! the CPU, a pair apart costs one box test (O(n²) for n colliders, cheap beside a traversal) after
//! `O(joints)` per collider. A skin whose weights cannot be bounded (negative or non-finite) is never
//! culled. `GpuOnly` colliders take part: the trees and skinned positions of the colliders in a pair
//! traversed come back with the answers (36 bytes per triangle and 12 per vertex, plus 8 per leaf pair
//! found). Contacts arrive with the frame's ray answers ([`Latency`](super::Latency)), tagged
//! with their frame in [`Contacts::frame`](super::Contacts). Continuous colliders are tested at this frame's
//! positions (discrete); collision fronts are not used.

use super::{Collider, Contacts};
use crate::collide::{Contact, PairQuery, Placed};
use crate::gpu::{FrameCollider, FrameContacts, GpuContext, ReadTrees, ResidentPairs};
use crate::{Mesh, MeshBvh, Result};
use bevy_ecs::prelude::*;
use glam::Affine3A;

/// A collider of the frame being recorded.
pub(crate) struct Recorded {
    pub entity: Entity,
    pub collider: Collider,
    pub mesh: Mesh,
    pub transform: Affine3A,
    /// A conservative world box of this frame's vertices, if known.
    pub world: Option<crate::Aabb>,
}

/// A frame's contacts as the narrow phase found them.
#[derive(Default)]
pub(crate) struct Found {
    /// Per traversed pair, in entity order.
    pub pairs: Vec<FoundPair>,
    /// Traversals that overflowed their buffers (answered by the CPU's traversal).
    pub overflows: usize,
}

/// A frame's collider pairs on their way back, with what the narrow phase needs on the CPU.
pub(crate) struct PendingContacts {
    /// The colliders in entity order, as the read-backs index them.
    colliders: Vec<(Entity, Mesh, Affine3A)>,
    readback: FrameContacts,
}

/// One touching (or not) entity pair's contacts: `a <= b`.
pub(crate) type FoundPair = ((Entity, Entity), Vec<Contact>);

/// Sorts `colliders` by entity and records the traversal of every candidate pair whose world boxes
/// overlap (see the module docs) with `traversals`, each collider's resident tree found by `tree`; counts
/// the candidates and the pairs traversed in `counts`.
pub(crate) fn record<'a>(
    ctx: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    traversals: &mut ResidentPairs,
    mut colliders: Vec<Recorded>,
    tree: impl Fn(Entity) -> &'a crate::gpu::ResidentMesh,
    counts: &mut super::gpu_frame::ResidentStats,
) -> Result<PendingContacts> {
    colliders.sort_unstable_by_key(|c| c.entity);
    let mut pairs = Vec::new();
    for (i, a) in colliders.iter().enumerate() {
        if a.collider.self_collision {
            pairs.push((i, i));
            counts.pair_candidates += 1;
        }
        for (j, b) in colliders.iter().enumerate().skip(i + 1) {
            if a.collider.layers.interacts(&b.collider.layers) {
                counts.pair_candidates += 1;
                let apart = matches!((a.world, b.world), (Some(x), Some(y)) if !x.overlaps(&y));
                if !apart {
                    pairs.push((i, j));
                }
            }
        }
    }
    counts.pairs_traversed = pairs.len();
    let frame: Vec<FrameCollider> = (colliders.iter())
        .map(|c| FrameCollider {
            id: c.entity.to_bits(),
            mesh: tree(c.entity),
            transform: c.transform,
        })
        .collect();
    let readback = traversals.record(ctx, encoder, &frame, &pairs)?;
    counts.pairs_created = readback.created;
    Ok(PendingContacts {
        colliders: (colliders.into_iter())
            .map(|c| (c.entity, c.mesh, c.transform))
            .collect(),
        readback,
    })
}

impl PendingContacts {
    /// Whether the GPU's part is back.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.readback.ready(ctx)
    }

    /// Waits for the GPU's part if needed, then runs the exact tests of every candidate pair on the
    /// read-back trees: on the GPU's leaf pairs, or walking the trees on the CPU for a pair whose
    /// traversal overflowed. Pairs in entity order.
    pub fn finish(self, ctx: &GpuContext) -> Result<Found> {
        let ReadTrees { trees, pairs } = self.readback.wait(ctx)?;
        // Only the colliders of pairs traversed came back.
        let mut meshes: Vec<Option<MeshBvh>> = self.colliders.iter().map(|_| None).collect();
        for (i, tree) in trees {
            let mesh = self.colliders[i].1.with_positions(tree.positions)?;
            meshes[i] = Some(MeshBvh::from_tree(&mesh, tree.bvh));
        }
        let placed = |i: usize| {
            let missing = || crate::Error::Gpu(format!("collider {i}'s tree was not read back"));
            let mesh = meshes[i].as_ref().ok_or_else(missing)?;
            Ok::<_, crate::Error>(Placed::new(mesh, self.colliders[i].2))
        };
        let mut query = PairQuery::new();
        let mut out = Vec::with_capacity(pairs.len());
        let overflows = pairs.iter().filter(|p| p.leaves.is_none()).count();
        for p in pairs {
            let (a, b) = p.pair;
            let mut contacts = Vec::new();
            match (&p.leaves, a == b) {
                (Some(l), true) => query.itself_from_leaf_pairs(placed(a)?, l, &mut contacts)?,
                (Some(l), false) => {
                    query.meshes_from_leaf_pairs(placed(a)?, placed(b)?, l, &mut contacts)?
                }
                (None, true) => query.itself(placed(a)?, &mut contacts)?,
                (None, false) => query.meshes(placed(a)?, placed(b)?, &mut contacts)?,
            };
            out.push(((self.colliders[a].0, self.colliders[b].0), contacts));
        }
        out.sort_unstable_by_key(|p| p.0);
        Ok(Found {
            pairs: out,
            overflows,
        })
    }
}

/// Publishes a frame's collider pairs in `contacts` and sends the messages of pairs that began or ended
/// touching.
pub(crate) fn publish(
    frame: u64,
    found: &[FoundPair],
    contacts: &mut Contacts,
    state: &mut super::collide::CollisionState,
    started: &mut MessageWriter<super::CollisionStarted>,
    ended: &mut MessageWriter<super::CollisionEnded>,
) {
    contacts.clear(frame);
    for (pair, c) in found {
        contacts.push(*pair, c, &[]);
    }
    state.send_changes(contacts, started, ended);
}
