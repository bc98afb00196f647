//! LBVH builder: sort primitives along a Morton curve, then build the binary radix tree of Karras,
//! "Maximizing Parallelism in the Construction of BVHs, Octrees, and k-d Trees" (HPG 2012).
//!
//! The tree is the one Karras defines; on the CPU it is found by one O(n) stack pass (see [`radix_tree`])
//! rather than Karras's per-node binary searches, which exist to expose parallelism to a GPU. Equal Morton
//! codes are told apart by the primitives' positions in the sorted order (Karras §4), so meshes whose
//! centroids all coincide still get a balanced tree. This is the builder of choice when a tree must be
//! rebuilt every frame, and the GPU builder's reference. Quality is below SAH, and poor when a small
//! detailed object sits in a large box (teapot in a stadium: all its primitives share a few Morton cells);
//! the hybrid builder fixes that below the top levels.
//!
//! Cost: O(n) code computation, a radix sort of `⌈bits/11⌉` passes, an O(n) stack pass for the tree, and one
//! pass that lays the tree out in the crate's node order and computes the bounds bottom-up.

use super::layout::Slot;
use super::topdown::{self, BALANCED_DEPTH, ObjectMedian, PARALLEL_SUBTREE, bounds_of};
use super::{BuildInput, MortonBits, radix_sort};
use crate::geometry::{Aabb, morton30, morton30_cube, morton63};
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
    let codes = sorted_codes(input, slot.prims, bits, false);
    let mut children = vec![[LEAF; 2]; n.saturating_sub(1)];
    let root = if n > 1 {
        radix_tree(&codes, &mut children)
    } else {
        LEAF
    };
    // Leaves read their boxes in slot order: gather them once, in a loop whose loads can overlap, instead
    // of one dependent cache miss per leaf during the recursion.
    let mut sorted = vec![Aabb::EMPTY; n];
    parallel::fill(input.parallel, &mut sorted, 1 << 14, |i| {
        input.bounds[slot.prims[i] as usize]
    });
    let w = Writer {
        input,
        children: &children,
        sorted: &sorted,
        below,
    };
    w.write(slot, root, 0)
}

/// Morton codes of the primitives' centroids in the centroids' box, sorted; `prims` is reordered with them.
/// 30-bit codes travel packed with their primitive in one `u64` (code in the high half), so the sort moves
/// 8 bytes per primitive instead of 12. With `cube`, 30-bit codes are on cubic cells ([`morton30_cube`],
/// PLOC's order) instead of per-axis ones.
pub(crate) fn sorted_codes(
    input: &BuildInput,
    prims: &mut [u32],
    bits: MortonBits,
    cube: bool,
) -> Vec<u64> {
    let code30 = if cube { morton30_cube } else { morton30 };
    let cb = bounds_of(input.parallel, prims, |&p| {
        input.centroids[p as usize].into()
    });
    let mut codes = vec![0u64; prims.len()];
    match bits {
        MortonBits::Bits30 => {
            parallel::fill(input.parallel, &mut codes, 1 << 14, |i| {
                let p = prims[i];
                ((code30(input.centroids[p as usize], &cb) as u64) << 32) | p as u64
            });
            radix_sort::sort_by_bits(&mut codes, 30, input.parallel, |&x| x >> 32);
            for (p, c) in prims.iter_mut().zip(codes.iter_mut()) {
                (*p, *c) = (*c as u32, *c >> 32);
            }
        }
        MortonBits::Bits63 => {
            parallel::fill(input.parallel, &mut codes, 1 << 14, |i| {
                morton63(input.centroids[prims[i] as usize], &cb)
            });
            let mut vals = prims.to_vec();
            radix_sort::sort_pairs(&mut codes, &mut vals, bits.bits());
            prims.copy_from_slice(&vals);
        }
    }
    codes
}

/// Length of the common prefix of the sorted keys at `i` and `i + 1` (Karras's δ), with equal codes told
/// apart by the common prefix of their positions, as if each key were `code ‖ position`.
#[inline]
fn adjacent_prefix(codes: &[u64], i: usize) -> u32 {
    let (a, b) = (codes[i], codes[i + 1]);
    if a == b {
        64 + (i as u32 ^ (i as u32 + 1)).leading_zeros()
    } else {
        (a ^ b).leading_zeros()
    }
}

/// The binary radix tree over sorted keys, as children of split positions: `children[g] = [left, right]`
/// for the inner node that splits between keys `g` and `g + 1`, each child the split position of the inner
/// node below or [`LEAF`] where that side is a single key. Returns the root's split position.
///
/// An inner node splits its range where the highest differing bit of its keys flips — at the unique
/// smallest adjacent prefix length in the range (keys are sorted, so that bit flips once). The radix tree
/// is therefore the Cartesian tree of the adjacent prefix lengths, which one stack pass builds in O(n);
/// Karras's Algorithm 1 finds the same nodes independently of each other, the form a GPU needs.
fn radix_tree(codes: &[u64], children: &mut [[u32; 2]]) -> u32 {
    debug_assert_eq!(children.len() + 1, codes.len());
    let mut stack: Vec<(u32, u32)> = Vec::with_capacity(64);
    for g in 0..children.len() {
        let d = adjacent_prefix(codes, g);
        let mut last = LEAF;
        while let Some(&(top, td)) = stack.last() {
            if td <= d {
                break;
            }
            last = top;
            stack.pop();
        }
        children[g] = [last, LEAF];
        if let Some(&(top, _)) = stack.last() {
            children[top as usize][1] = g as u32;
        }
        stack.push((g as u32, d));
    }
    stack[0].0
}

/// Marks a child that is a single key.
const LEAF: u32 = u32::MAX;

/// Lays the radix tree out in the crate's node order, top-down, computing bounds on the way back up.
struct Writer<'a> {
    input: &'a BuildInput<'a>,
    children: &'a [[u32; 2]],
    /// Primitive boxes in slot (Morton) order.
    sorted: &'a [Aabb],
    below: Below<'a>,
}

impl Writer<'_> {
    /// Writes the radix-tree node that covers `slot`'s sorted range and splits it after position `split`
    /// (unused for a single key).
    fn write(&self, slot: Slot<'_>, split: u32, depth: usize) -> usize {
        let m = slot.prims.len();
        if m == 1
            || (m <= self.input.max_leaf && self.below.is_none_or(|(levels, _)| depth < levels))
        {
            let first = slot.prim_at as usize;
            let b = self.sorted[first..first + m]
                .iter()
                .fold(Aabb::EMPTY, |b, x| b.union(x));
            return slot.leaf(&b);
        }
        if let Some((levels, finish)) = self.below
            && depth >= levels
        {
            return finish(slot, depth);
        }
        if depth >= BALANCED_DEPTH {
            return topdown::build(self.input, &ObjectMedian, slot, depth);
        }
        let first = slot.prim_at as usize;
        let [l, r] = self.children[split as usize];
        let par = self.input.parallel && m >= PARALLEL_SUBTREE;
        slot.split(split as usize + 1 - first, par, [l, r], |child, s| {
            self.write(child, s, depth + 1)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Karras 2012, Algorithm 1, as published: the split position of inner node `i` found by binary search.
    fn karras_split(codes: &[u64], i: usize) -> (usize, usize, usize) {
        let delta = |i: usize, j: isize| -> i64 {
            if j < 0 || j as usize >= codes.len() {
                return -1;
            }
            let (a, b) = (codes[i], codes[j as usize]);
            if a == b {
                64 + (i as u32 ^ j as u32).leading_zeros() as i64
            } else {
                (a ^ b).leading_zeros() as i64
            }
        };
        let ii = i as isize;
        let d: isize = if delta(i, ii + 1) > delta(i, ii - 1) {
            1
        } else {
            -1
        };
        let dmin = delta(i, ii - d);
        let mut lmax = 2;
        while delta(i, ii + lmax * d) > dmin {
            lmax *= 2;
        }
        let (mut l, mut t) = (0, lmax / 2);
        while t >= 1 {
            if delta(i, ii + (l + t) * d) > dmin {
                l += t;
            }
            t /= 2;
        }
        let j = ii + l * d;
        let dnode = delta(i, j);
        let (mut s, mut div) = (0, 2);
        loop {
            let t = (l + div - 1) / div;
            if delta(i, ii + (s + t) * d) > dnode {
                s += t;
            }
            if t <= 1 {
                break;
            }
            div *= 2;
        }
        let gamma = (ii + s * d + d.min(0)) as usize;
        (i.min(j as usize), i.max(j as usize), gamma)
    }

    #[test]
    fn stack_pass_builds_karras_radix_tree() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        for (n, spread) in [
            (2usize, 1u64 << 30),
            (3, 4),
            (17, 1 << 30),
            (1000, 1 << 30),
            (1000, 7),
            (513, 1),
        ] {
            let mut codes: Vec<u64> = (0..n)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    s % spread
                })
                .collect();
            codes.sort_unstable();
            let mut children = vec![[LEAF; 2]; n - 1];
            let root = radix_tree(&codes, &mut children);
            // Walk our tree by ranges and compare every split with Karras's node for that range.
            let karras: std::collections::HashMap<(usize, usize), usize> = (0..n - 1)
                .map(|i| {
                    let (a, b, g) = karras_split(&codes, i);
                    ((a, b), g)
                })
                .collect();
            let mut stack = vec![(0usize, n - 1, root)];
            let mut inner = 0;
            while let Some((a, b, g)) = stack.pop() {
                inner += 1;
                assert_eq!(
                    karras.get(&(a, b)),
                    Some(&(g as usize)),
                    "n={n} range {a}..={b}"
                );
                let [l, r] = children[g as usize];
                if a < g as usize {
                    stack.push((a, g as usize, l));
                }
                if (g as usize) + 1 < b {
                    stack.push((g as usize + 1, b, r));
                }
            }
            assert_eq!(inner, n - 1);
        }
    }
}
