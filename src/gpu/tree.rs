//! A tree whose nodes live in a GPU buffer: what the GPU builder makes and the pair traversal reads.

use crate::bvh::{MAX_DEPTH, Node};

/// A tree whose nodes are on the GPU, in the crate's [`Node`] layout, as
/// [`GpuPairs::record`](super::GpuPairs::record) reads it: a valid tree (see
/// [`Bvh::validate`](crate::bvh::Bvh::validate)), such as [`GpuMeshBvh::tree`](super::GpuMeshBvh::tree).
#[derive(Clone, Copy, Debug)]
pub struct GpuTree<'a> {
    /// The node buffer (root at index 0).
    pub nodes: &'a wgpu::Buffer,
    /// Number of nodes; 0 for an empty tree.
    pub count: u32,
    /// Depth of the deepest leaf (the root is at depth 0), or any larger bound: the traversal records
    /// `height_a + height_b + 2` rounds, so a tight height saves empty dispatches.
    pub height: u32,
}

impl<'a> GpuTree<'a> {
    /// A tree of `count` nodes of unknown height (bounded by [`MAX_DEPTH`]).
    pub fn new(nodes: &'a wgpu::Buffer, count: u32) -> Self {
        Self {
            nodes,
            count,
            height: MAX_DEPTH as u32,
        }
    }
}

/// The depth of every node of a tree in the crate's layout (the root at 0), into `out`.
pub(crate) fn node_depths(nodes: &[Node], out: &mut Vec<u32>) {
    out.clear();
    out.resize(nodes.len(), 0);
    for (i, n) in nodes.iter().enumerate() {
        if !n.is_leaf() && n.left() + 1 < nodes.len() {
            out[n.left()] = out[i] + 1;
            out[n.left() + 1] = out[i] + 1;
        }
    }
}
