//! The top-down driver shared by the spatial-median and binned-SAH builders (and by the hybrid builder
//! below its LBVH levels): ask a [`SplitRule`] where to cut, recurse into both halves in parallel when they
//! are big enough, and fall back to balanced object-median cuts where a rule cannot split or a branch gets
//! deep.

use super::layout::Slot;
use super::{BuildInput, MAX_DEPTH, MAX_PRIMITIVES};
use crate::geometry::Aabb;
use crate::parallel;

/// Below this many primitives a subtree is built on the current thread.
pub(crate) const PARALLEL_SUBTREE: usize = 2048;

/// From this depth on, only object-median cuts are made: they halve the count, so a subtree of at most
/// [`MAX_PRIMITIVES`] = 2^27 primitives adds at most 27 levels and no leaf is deeper than [`MAX_DEPTH`] - 1.
pub(crate) const BALANCED_DEPTH: usize = MAX_DEPTH - 1 - MAX_PRIMITIVES.trailing_zeros() as usize;

/// Where to cut a node.
pub(crate) trait SplitRule: Sync {
    /// Reorders `prims` so that the left child's come first and returns their number (`0 < k < len`), or
    /// `None` when the node should be a leaf. Only called with `prims.len() >= 2`.
    fn split(&self, input: &BuildInput, prims: &mut [u32]) -> Option<usize>;
}

/// Builds the subtree of `slot` at `depth` with `rule`. Returns the number of nodes used.
pub(crate) fn build<R: SplitRule>(
    input: &BuildInput,
    rule: &R,
    slot: Slot<'_>,
    depth: usize,
) -> usize {
    let m = slot.prims.len();
    if m == 1 {
        return slot.leaf(input.bounds);
    }
    let cut = if depth >= BALANCED_DEPTH {
        ObjectMedian.split(input, slot.prims)
    } else {
        rule.split(input, slot.prims)
    };
    let left = match cut {
        Some(k) => k,
        None if m <= input.max_leaf => return slot.leaf(input.bounds),
        None => ObjectMedian
            .split(input, slot.prims)
            .expect("object median always cuts"),
    };
    let par = input.parallel && m >= PARALLEL_SUBTREE;
    slot.split(left, par, |child, _| build(input, rule, child, depth + 1))
}

/// Bounds of the centroids of `prims`.
pub(crate) fn centroid_bounds(input: &BuildInput, prims: &[u32]) -> Aabb {
    let par = input.parallel && prims.len() >= 1 << 16;
    parallel::map_reduce(
        par,
        prims,
        1 << 14,
        Aabb::EMPTY,
        |ps| {
            ps.iter().fold(Aabb::EMPTY, |mut b, &p| {
                b.grow(input.centroids[p as usize]);
                b
            })
        },
        |a, b| a.union(&b),
    )
}

/// Cuts at the median primitive along the centroids' longest axis (ties broken by primitive id, so the result
/// is one well-defined order). Always cuts when `len >= 2`, and the halves differ by at most one.
pub(crate) struct ObjectMedian;

impl SplitRule for ObjectMedian {
    fn split(&self, input: &BuildInput, prims: &mut [u32]) -> Option<usize> {
        let axis = centroid_bounds(input, prims).largest_axis();
        let k = prims.len() / 2;
        prims.select_nth_unstable_by(k, |&a, &b| {
            let (ca, cb) = (
                input.centroids[a as usize][axis],
                input.centroids[b as usize][axis],
            );
            ca.total_cmp(&cb).then(a.cmp(&b))
        });
        Some(k)
    }
}

/// Moves the primitives for which `goes_left` holds to the front (order within each side is not kept) and
/// returns how many there are.
pub(crate) fn partition(prims: &mut [u32], goes_left: impl Fn(u32) -> bool) -> usize {
    let (mut i, mut j) = (0, prims.len());
    while i < j {
        if goes_left(prims[i]) {
            i += 1;
        } else {
            j -= 1;
            prims.swap(i, j);
        }
    }
    i
}
