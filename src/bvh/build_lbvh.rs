//! LBVH builder: sort primitives along a Morton curve, then build the binary radix tree of Karras,
//! "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees" (HPG 2012).
//!
//! Every inner node of the radix tree is found independently (one binary search per node, in parallel), so
//! this is the builder of choice when a tree must be rebuilt every frame and is the GPU builder's reference.
//! Equal Morton codes are told apart by the primitives' positions in the sorted order (Karras §4), so meshes
//! whose centroids all coincide still get a balanced tree. Quality is below SAH, and poor when a small
//! detailed object sits in a large box (teapot in a stadium: all its primitives share a few Morton cells);
//! the hybrid builder fixes that below the top levels.
//!
//! Cost: O(n) code computation, a radix sort of `⌈bits/11⌉` passes, O(n log n) for the searches, and one
//! pass that lays the tree out in the crate's node order and computes the bounds bottom-up.

use super::layout::Slot;
use super::topdown::{self, BALANCED_DEPTH, ObjectMedian, PARALLEL_SUBTREE, centroid_bounds};
use super::{BuildInput, MortonBits, radix_sort};
use crate::geometry::{morton30, morton63};
use crate::parallel;

/// How the tree below the LBVH levels is finished (the hybrid builder).
pub(crate) type Below<'a> = Option<(usize, &'a (dyn Fn(Slot<'_>, usize) -> usize + Sync))>;

/// Builds into `slot` (the root slot of the whole tree, `slot.prims` = `0..n` on entry; they leave in Morton
/// order). With `below = Some((levels, finish))`, nodes at depth `levels` are handed to `finish` instead.
pub(crate) fn build(
    input: &BuildInput,
    slot: Slot<'_>,
    bits: MortonBits,
    below: Below<'_>,
) -> usize {
    let n = slot.prims.len();
    let codes = sorted_codes(input, slot.prims, bits);
    let mut split = vec![0u32; n.saturating_sub(1)];
    parallel::fill(input.parallel, &mut split, 4096, |i| {
        karras_split(&codes, i)
    });
    let w = Writer {
        input,
        split: &split,
        below,
    };
    w.write(slot, false, 0)
}

/// Morton codes of the primitives' centroids in the centroids' box, sorted; `prims` is reordered with them.
pub(crate) fn sorted_codes(input: &BuildInput, prims: &mut [u32], bits: MortonBits) -> Vec<u64> {
    let cb = centroid_bounds(input, prims);
    let mut codes = vec![0u64; prims.len()];
    parallel::fill(input.parallel, &mut codes, 1 << 14, |i| {
        let c = input.centroids[prims[i] as usize];
        match bits {
            MortonBits::Bits30 => morton30(c, &cb) as u64,
            MortonBits::Bits63 => morton63(c, &cb),
        }
    });
    let mut vals = prims.to_vec();
    radix_sort::sort_pairs(&mut codes, &mut vals, bits.bits());
    prims.copy_from_slice(&vals);
    codes
}

/// Length of the common prefix of keys `i` and `j` (Karras's δ), with equal codes extended by the indices'
/// common prefix; -1 outside the array.
#[inline]
fn delta(codes: &[u64], i: usize, j: isize) -> i32 {
    if j < 0 || j as usize >= codes.len() {
        return -1;
    }
    let (a, b) = (codes[i], codes[j as usize]);
    if a == b {
        64 + (i as u32 ^ j as u32).leading_zeros() as i32
    } else {
        (a ^ b).leading_zeros() as i32
    }
}

/// Karras's Algorithm 1 for inner node `i`: the position γ at which its range splits. Its range is
/// `[min(i, j), max(i, j)]`, the left child covers up to γ, the right child from γ + 1.
pub(crate) fn karras_split(codes: &[u64], i: usize) -> u32 {
    let ii = i as isize;
    let d: isize = if delta(codes, i, ii + 1) > delta(codes, i, ii - 1) {
        1
    } else {
        -1
    };
    let dmin = delta(codes, i, ii - d);
    let mut lmax: isize = 2;
    while delta(codes, i, ii + lmax * d) > dmin {
        lmax *= 2;
    }
    let mut l: isize = 0;
    let mut t = lmax / 2;
    while t >= 1 {
        if delta(codes, i, ii + (l + t) * d) > dmin {
            l += t;
        }
        t /= 2;
    }
    let j = ii + l * d;
    let dnode = delta(codes, i, j);
    let mut s: isize = 0;
    let mut div: isize = 2;
    loop {
        let t = (l + div - 1) / div;
        if delta(codes, i, ii + (s + t) * d) > dnode {
            s += t;
        }
        if t <= 1 {
            break;
        }
        div *= 2;
    }
    (ii + s * d + d.min(0)) as u32
}

/// Lays the radix tree out in the crate's node order, top-down, computing bounds on the way back up.
struct Writer<'a> {
    input: &'a BuildInput<'a>,
    split: &'a [u32],
    below: Below<'a>,
}

impl Writer<'_> {
    /// Writes the radix-tree node that covers `slot`'s sorted range. A left child's radix node is the last
    /// position of its range, a right child's (and the root's) the first.
    fn write(&self, slot: Slot<'_>, is_left: bool, depth: usize) -> usize {
        let m = slot.prims.len();
        if m == 1 {
            return slot.leaf(self.input.bounds);
        }
        if let Some((levels, finish)) = self.below
            && depth >= levels
        {
            return finish(slot, depth);
        }
        if m <= self.input.max_leaf {
            return slot.leaf(self.input.bounds);
        }
        if depth >= BALANCED_DEPTH {
            return topdown::build(self.input, &ObjectMedian, slot, depth);
        }
        let first = slot.prim_at as usize;
        let node = if is_left { first + m - 1 } else { first };
        let gamma = self.split[node] as usize;
        let par = self.input.parallel && m >= PARALLEL_SUBTREE;
        slot.split(gamma + 1 - first, par, |child, left| {
            self.write(child, left, depth + 1)
        })
    }
}
