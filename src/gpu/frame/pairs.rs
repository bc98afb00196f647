//! Collider pairs of the GPU-resident frame: the pair traversal ([`GpuPairs`]) of every candidate pair of
//! resident trees, recorded into the frame's encoder after the meshes' maintenance, and the read-back of
//! the colliders' trees (nodes, slot ids, positions) that the CPU's exact triangle tests need.

use super::ResidentMesh;
use crate::Result;
use crate::bvh::{Bvh, Node};
use crate::gpu::buffers::Readback;
use crate::gpu::{GpuContext, GpuPairs, PairsReadback, PairsResult};
use glam::{Affine3A, Vec3};
use std::collections::HashMap;

/// Starting capacities of a pair's traversal buffers (queued pairs, leaf pairs): a few hundred leaf pairs
/// cover characters that brush each other; a deeper contact overflows once, is answered by the CPU's
/// traversal of the read-back trees that frame, and finds grown buffers from the next frame on.
const PAIR_CAPACITY: u32 = 1 << 10;

/// A collider of this frame's scene.
pub(crate) struct FrameCollider<'a> {
    /// The caller's id, which [`PairTrees`] and [`FrameContacts`] report.
    pub id: u64,
    /// The mesh, as maintained earlier in the same encoder.
    pub mesh: &'a ResidentMesh,
    /// Object to world (invertible; the caller checks).
    pub transform: Affine3A,
}

/// The pair traversals kept from frame to frame, one per pair of collider ids (their buffers grow with
/// the pair's contact and are reused).
pub(crate) struct ResidentPairs {
    traversals: HashMap<(u64, u64), GpuPairs>,
    /// Capacity of a new pair's buffers (queued pairs, leaf pairs).
    capacity: u32,
}

impl Default for ResidentPairs {
    fn default() -> Self {
        Self {
            traversals: HashMap::new(),
            capacity: PAIR_CAPACITY,
        }
    }
}

/// A collider's tree on its way back, with what the CPU needs to pair it with its mesh.
struct TreeReadback {
    /// Index into the frame's colliders.
    index: usize,
    /// Nodes (8 words each), then the slots' triangle ids, then the positions (3 words each).
    words: Readback<u32>,
    nodes: usize,
    tris: usize,
}

/// A collider's tree as read back: the tree and the vertex positions it was refitted or built over.
pub(crate) struct PairTree {
    /// The tree (slot order and boxes of the GPU's tree).
    pub bvh: Bvh,
    /// Object-space vertex positions after this frame's skinning or upload.
    pub positions: Vec<Vec3>,
}

/// One pair's traversal on its way back: `(a, b)` by index into the frame's colliders, `a == b` for a
/// mesh against itself.
struct PairReadback {
    pair: (usize, usize),
    leaves: PairsReadback,
}

/// A frame's collider pairs on their way back.
pub(crate) struct FrameContacts {
    trees: Vec<TreeReadback>,
    pairs: Vec<PairReadback>,
    /// Pairs traversed for the first time (their traversals made this frame).
    pub created: usize,
}

/// What came back for one candidate pair: the leaf pairs the GPU found, or `None` when the traversal
/// overflowed its buffers (the caller then walks the read-back trees on the CPU).
pub(crate) struct PairLeaves {
    /// Indices into [`ReadTrees::trees`]; equal for a mesh against itself.
    pub pair: (usize, usize),
    /// Overlapping leaf pairs (node indices of the two trees).
    pub leaves: Option<Vec<[u32; 2]>>,
}

/// A frame's collider trees and pair traversals, read back.
pub(crate) struct ReadTrees {
    /// Per collider in a pair traversed, its index into the frame's colliders and its tree.
    pub trees: Vec<(usize, PairTree)>,
    /// Per candidate pair, what the traversal found.
    pub pairs: Vec<PairLeaves>,
}

impl ResidentPairs {
    /// Test hook (feature `testing`): new pairs' buffers start with room for `capacity` queued pairs and
    /// leaf pairs (rounded up to the buffers' 256-byte minimum), so that tests reach the overflow path.
    #[cfg(feature = "testing")]
    pub fn start_capacity(&mut self, capacity: u32) {
        self.capacity = capacity;
    }

    /// The largest leaf-pair buffer among the traversals kept, in leaf pairs (0 with none).
    pub fn largest_capacity(&self) -> u32 {
        (self.traversals.values())
            .map(|t| t.capacity().1)
            .max()
            .unwrap_or(0)
    }

    /// Records the traversal of each of `pairs` (indices into `colliders`; `(i, i)` for self-collision)
    /// on the resident trees, `b` placed in `a`'s frame, and the read-back of the tree of every collider
    /// in one of `pairs`: 36 bytes per triangle and 12 per vertex down per frame, plus 8 per leaf pair
    /// found. Traversals of pairs
    /// not listed are kept while both colliders are (a pair culled this frame may be traversed the next,
    /// and a new traversal uploads its round parameters, 33 KiB); those of colliders gone are dropped.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        colliders: &[FrameCollider<'_>],
        pairs: &[(usize, usize)],
    ) -> Result<FrameContacts> {
        let mut out = FrameContacts {
            trees: Vec::with_capacity(colliders.len()),
            pairs: Vec::with_capacity(pairs.len()),
            created: 0,
        };
        let mut used = HashMap::with_capacity(pairs.len());
        for &(a, b) in pairs {
            let (ca, cb) = (&colliders[a], &colliders[b]);
            let key = (ca.id, cb.id);
            let mut traversal = self.traversals.remove(&key).unwrap_or_else(|| {
                out.created += 1;
                GpuPairs::with_capacity(ctx, self.capacity, self.capacity)
            });
            let other = (a != b).then(|| {
                let b_to_a = ca.transform.inverse() * cb.transform;
                (cb.mesh.bvh().tree(), b_to_a)
            });
            let leaves = traversal.record(ctx, encoder, ca.mesh.bvh().tree(), other)?;
            out.pairs.push(PairReadback {
                pair: (a, b),
                leaves,
            });
            used.insert(key, traversal);
        }
        let live: std::collections::HashSet<u64> = colliders.iter().map(|c| c.id).collect();
        (self.traversals).retain(|(a, b), _| live.contains(a) && live.contains(b));
        self.traversals.extend(used);
        let mut paired = vec![false; colliders.len()];
        for &(a, b) in pairs {
            (paired[a], paired[b]) = (true, true);
        }
        for (index, c) in colliders.iter().enumerate().filter(|(i, _)| paired[*i]) {
            let bvh = c.mesh.bvh();
            let (nodes, tris) = (bvh.node_count() as usize, bvh.triangle_count() as usize);
            let words = Readback::record_parts(
                ctx,
                encoder,
                &[
                    (bvh.nodes(), nodes * 8),
                    (bvh.slot_ids(), tris),
                    (bvh.positions(), bvh.vertex_count() as usize * 3),
                ],
            );
            out.trees.push(TreeReadback {
                index,
                words,
                nodes,
                tris,
            });
        }
        Ok(out)
    }
}

impl FrameContacts {
    /// Whether everything is back (a [`wait`](Self::wait) would not block).
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.trees.iter().all(|t| t.words.ready(ctx))
            && (self.pairs.iter()).all(|p| p.leaves.ready(ctx))
    }

    /// The trees and leaf pairs, waiting for them if they are not back.
    pub fn wait(self, ctx: &GpuContext) -> Result<ReadTrees> {
        let mut trees = Vec::with_capacity(self.trees.len());
        for t in self.trees {
            let words = t.words.wait(ctx)?;
            let (nodes, rest) = words.split_at(t.nodes * 8);
            let (ids, corners) = rest.split_at(t.tris);
            let nodes: Vec<Node> = bytemuck::cast_slice(nodes).to_vec();
            let positions = bytemuck::cast_slice::<u32, Vec3>(corners).to_vec();
            let tree = PairTree {
                bvh: Bvh::from_parts(nodes, ids.to_vec()),
                positions,
            };
            trees.push((t.index, tree));
        }
        let mut pairs = Vec::with_capacity(self.pairs.len());
        for p in self.pairs {
            let leaves = match p.leaves.wait(ctx)? {
                PairsResult::Done(l) => Some(l),
                PairsResult::Overflowed => None,
            };
            pairs.push(PairLeaves {
                pair: p.pair,
                leaves,
            });
        }
        Ok(ReadTrees { trees, pairs })
    }
}
