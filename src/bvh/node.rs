//! The 32-byte node shared by the CPU and the GPU.

use crate::geometry::Aabb;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// One node of a binary [`Bvh`](super::Bvh): 32 bytes, `#[repr(C)]`, the same bytes on the CPU and in GPU
/// buffers (WGSL: `struct Node { min: vec3<f32>, index: u32, max: vec3<f32>, sa_ratio: f32 }`).
///
/// | bytes | field | meaning |
/// |---|---|---|
/// | 0..12 | `min` | smallest corner of the node's box |
/// | 12..16 | `index` | inner: index of the left child, the right child is `index + 1`. Leaf: bit 31 set, bits 27..=30 the primitive count (1..=15), bits 0..=26 the first slot in [`Bvh::prim_indices`](super::Bvh::prim_indices) |
/// | 16..28 | `max` | largest corner |
/// | 28..32 | `sa_ratio` | inner: `SA(node) / (SA(left) + SA(right))` when the tree was built (see [`sa_ratio`](crate::geometry::sa_ratio)), the reference the refit degradation metric compares against. Leaf: 0 |
///
/// Children always sit at higher indices than their parent, and every node's descendants occupy one
/// contiguous block of the node array, so bottom-up passes run as one reverse loop.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    /// Smallest corner of the box.
    pub min: [f32; 3],
    /// Child or leaf payload, see the table above.
    pub index: u32,
    /// Largest corner of the box.
    pub max: [f32; 3],
    /// Construction surface-area ratio (inner nodes).
    pub sa_ratio: f32,
}

const _: () = assert!(std::mem::size_of::<Node>() == 32);
const _: () = assert!(std::mem::align_of::<Node>() == 4);

/// Bit 31 of [`Node::index`] marks a leaf.
pub const LEAF_BIT: u32 = 1 << 31;
pub(crate) const COUNT_SHIFT: u32 = 27;
pub(crate) const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;

/// Largest number of primitives one leaf can hold.
pub const MAX_LEAF_SIZE: u32 = 15;

/// Largest number of primitives one tree can hold (2^27, the leaf's first-slot field).
pub const MAX_PRIMITIVES: usize = 1 << COUNT_SHIFT;

/// No builder makes a tree deeper than this (root at depth 0), so traversal stacks of this size never
/// overflow. Builders switch to balanced splits when a branch gets deep.
pub const MAX_DEPTH: usize = 64;

impl Node {
    /// A leaf over slots `first .. first + count` with the given box.
    #[inline]
    pub fn leaf(first: u32, count: u32, bounds: &Aabb) -> Self {
        debug_assert!((1..=MAX_LEAF_SIZE).contains(&count) && first <= FIRST_MASK);
        Self {
            min: bounds.min.to_array(),
            index: LEAF_BIT | (count << COUNT_SHIFT) | first,
            max: bounds.max.to_array(),
            sa_ratio: 0.0,
        }
    }

    /// An inner node whose children are at `left` and `left + 1`.
    #[inline]
    pub fn inner(left: u32, bounds: &Aabb, sa_ratio: f32) -> Self {
        Self {
            min: bounds.min.to_array(),
            index: left,
            max: bounds.max.to_array(),
            sa_ratio,
        }
    }

    /// True for leaves.
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.index & LEAF_BIT != 0
    }

    /// Index of the left child (inner nodes).
    #[inline]
    pub fn left(&self) -> usize {
        self.index as usize
    }

    /// First slot of a leaf.
    #[inline]
    pub fn first(&self) -> usize {
        (self.index & FIRST_MASK) as usize
    }

    /// Number of primitives of a leaf (0 for inner nodes).
    #[inline]
    pub fn count(&self) -> usize {
        if self.is_leaf() {
            ((self.index >> COUNT_SHIFT) & 0xf) as usize
        } else {
            0
        }
    }

    /// Slots of a leaf.
    #[inline]
    pub fn slots(&self) -> std::ops::Range<usize> {
        let f = self.first();
        f..f + self.count()
    }

    /// The node's box.
    #[inline]
    pub fn aabb(&self) -> Aabb {
        Aabb::new(Vec3::from_array(self.min), Vec3::from_array(self.max))
    }

    /// Replaces the node's box.
    #[inline]
    pub fn set_aabb(&mut self, b: &Aabb) {
        self.min = b.min.to_array();
        self.max = b.max.to_array();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_round_trips() {
        let b = Aabb::new(Vec3::ZERO, Vec3::ONE);
        let l = Node::leaf(FIRST_MASK, MAX_LEAF_SIZE, &b);
        assert!(l.is_leaf());
        assert_eq!(l.first(), FIRST_MASK as usize);
        assert_eq!(l.count(), MAX_LEAF_SIZE as usize);
        let i = Node::inner(12345, &b, 1.5);
        assert!(!i.is_leaf());
        assert_eq!(i.left(), 12345);
        assert_eq!(i.count(), 0);
        assert_eq!(bytemuck::bytes_of(&i).len(), 32);
        // Field offsets as documented.
        let bytes = bytemuck::bytes_of(&i);
        assert_eq!(u32::from_le_bytes(bytes[12..16].try_into().unwrap()), 12345);
        assert_eq!(f32::from_le_bytes(bytes[28..32].try_into().unwrap()), 1.5);
    }
}
