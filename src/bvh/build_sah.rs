//! Binned SAH builder (Wald 2007; the CPU reference of Lauterbach's GPU builder, thesis §5.2).
//!
//! Each node's centroids are sorted into `bins` equal slots per axis; the cut between two slots with the
//! lowest surface-area-heuristic cost wins, and a node becomes a leaf when no cut is cheaper than
//! intersecting all its primitives (and it holds at most `max_leaf_size`). Cost model, as in
//! [`quality`](super::quality): `C_TRAV + C_ISECT · (A_L·N_L + A_R·N_R) / A` for a cut, `C_ISECT · N` for a
//! leaf, with [`C_TRAV`] = [`C_ISECT`] = 1.
//!
//! When to use: the best trees of the crate's builders, for meshes that are queried a lot and rebuilt
//! rarely. Cost: O(n log n) with a pass over 3 axes per level; nodes above 64k primitives bin in parallel.

use super::BuildInput;
use super::quality::{C_ISECT, C_TRAV};
use super::topdown::{Box3A, Cut, Prim, Sides, SplitRule, centroid_bounds, partition};
use crate::geometry::Aabb;
use crate::parallel;
use glam::{UVec3, Vec3A};

/// Largest number of bins per axis.
pub const MAX_BINS: u32 = 64;
const MAX: usize = MAX_BINS as usize;

/// Per-axis bins of one node: primitive count and bounds of the primitives whose centroid falls in each.
/// Only the first `n` bins of each axis are in use.
#[derive(Clone)]
struct Bins {
    n: usize,
    count: [[u32; MAX]; 3],
    bounds: [[Box3A; MAX]; 3],
}

impl Bins {
    fn new(n: usize) -> Self {
        Self {
            n,
            count: [[0; MAX]; 3],
            bounds: [[Box3A::EMPTY; MAX]; 3],
        }
    }

    /// Empties the first `n` bins of each axis for reuse.
    fn reset(&mut self, n: usize) {
        self.n = n;
        for a in 0..3 {
            self.count[a][..n].fill(0);
            self.bounds[a][..n].fill(Box3A::EMPTY);
        }
    }

    /// Adds the primitives, one sequential pass: one centroid and three bin indices per primitive.
    fn add(&mut self, binner: &Binner, prims: &[Prim]) {
        for p in prims {
            let i = binner.bins(p.centroid());
            for axis in 0..3 {
                let b = i[axis] as usize;
                self.count[axis][b] += 1;
                self.bounds[axis][b].grow_prim(p);
            }
        }
    }

    fn merge(mut self, o: Bins) -> Bins {
        for a in 0..3 {
            for b in 0..self.n {
                self.count[a][b] += o.count[a][b];
                self.bounds[a][b] = self.bounds[a][b].union(&o.bounds[a][b]);
            }
        }
        self
    }

    /// The cheapest cut: `(A_L·N_L + A_R·N_R, axis, first right bin)`, ties to the more balanced cut, then
    /// the lower axis and bin; and the node's box. `None` when no cut leaves both sides non-empty.
    fn best_cut(&self, m: usize) -> (Option<(f64, usize, usize)>, Aabb) {
        let mut best: Option<(f64, u64, usize, usize)> = None;
        let mut node = Box3A::EMPTY;
        for axis in 0..3 {
            let (count, bounds) = (&self.count[axis][..self.n], &self.bounds[axis][..self.n]);
            let mut right_cost = [0f64; MAX];
            let (mut rb, mut rn) = (Box3A::EMPTY, 0u64);
            for i in (1..self.n).rev() {
                rb = rb.union(&bounds[i]);
                rn += count[i] as u64;
                right_cost[i] = rb.aabb().half_area_f64() * rn as f64;
            }
            node = node.union(&rb).union(&bounds[0]);
            let (mut lb, mut ln) = (Box3A::EMPTY, 0u64);
            for i in 1..self.n {
                lb = lb.union(&bounds[i - 1]);
                ln += count[i - 1] as u64;
                let rn = m as u64 - ln;
                if ln == 0 || rn == 0 {
                    continue;
                }
                let cost = lb.aabb().half_area_f64() * ln as f64 + right_cost[i];
                let imbalance = ln.abs_diff(rn);
                if best.is_none_or(|(c, im, _, _)| cost < c || (cost == c && imbalance < im)) {
                    best = Some((cost, imbalance, axis, i));
                }
            }
        }
        (best.map(|(c, _, a, i)| (c, a, i)), node.aabb())
    }
}

thread_local! {
    /// Each thread's bins, reused from node to node.
    static SCRATCH: std::cell::RefCell<Bins> = std::cell::RefCell::new(Bins::new(0));
}

/// Maps centroids to bins: `min(⌊(c - min)·scale⌋, last)` per axis.
#[derive(Clone, Copy)]
struct Binner {
    min: Vec3A,
    scale: Vec3A,
    last: u32,
}

impl Binner {
    /// The bin on all three axes at once.
    #[inline]
    fn bins(&self, c: Vec3A) -> UVec3 {
        let v = (c - self.min) * self.scale;
        UVec3::new(self.step(v.x), self.step(v.y), self.step(v.z))
    }

    /// The bin on one axis.
    #[inline]
    fn bin(&self, c: Vec3A, axis: usize) -> u32 {
        self.step((c[axis] - self.min[axis]) * self.scale[axis])
    }

    /// The bin of the scaled offset `v`: its floor, at most the last bin. NaN (0·∞ on a subnormal extent)
    /// and negative offsets give bin 0 (`f32::max` returns its other operand for NaN), `+∞` the last: the
    /// bins of saturating casts, without the fix-ups that cost x86-64 about six instructions per axis in
    /// the binning pass.
    #[inline]
    fn step(&self, v: f32) -> u32 {
        let v = v.max(0.0).min(self.last as f32);
        // SAFETY: `v` is finite and in `[0, last]` (`last` below `MAX_BINS`), so it truncates to a `u32`.
        unsafe { v.to_int_unchecked::<u32>() }
    }
}

/// The binned SAH rule with `bins` bins per axis (2..=[`MAX_BINS`]).
pub(crate) struct BinnedSah {
    pub bins: u32,
}

/// Whether a node of `m` primitives with the given box and cheapest cut (`A_L·N_L + A_R·N_R`) should stay a
/// leaf: when it may (`m <= max_leaf`) and intersecting everything costs no more than the cut.
fn keep_leaf(input: &BuildInput, m: usize, node: &Aabb, cut_cost: f64) -> bool {
    let area = node.half_area_f64();
    m <= input.max_leaf && C_ISECT * m as f64 * area <= C_TRAV * area + C_ISECT * cut_cost
}

impl SplitRule for BinnedSah {
    /// Cost: above the bin count, one binning pass and one partitioning pass over the node's primitives (the
    /// partition also finds the children's centroid bounds); binning is parallel from 64k primitives. At
    /// most the bin count, see [`exact_split`].
    fn split(
        &self,
        input: &BuildInput,
        prims: &mut [Prim],
        centroids: Option<Aabb>,
    ) -> Option<Cut> {
        let m = prims.len();
        if m <= self.bins as usize {
            return exact_split(input, prims);
        }
        let cb = centroids.unwrap_or_else(|| centroid_bounds(input, prims));
        let extent = Vec3A::from(cb.extent());
        if extent.max_element() <= 0.0 {
            // All centroids coincide: no spatial cut exists; the driver makes a leaf or an object median.
            return None;
        }
        let nbins = self.bins as usize;
        let binner = Binner {
            min: cb.min.into(),
            scale: Vec3A::select(
                extent.cmpgt(Vec3A::ZERO),
                Vec3A::splat(nbins as f32) / extent,
                Vec3A::ZERO,
            ),
            last: nbins as u32 - 1,
        };
        let (best, node) = if input.parallel && m >= 1 << 16 {
            let fill = |ps: &[Prim]| {
                let mut b = Bins::new(nbins);
                b.add(&binner, ps);
                b
            };
            parallel::map_reduce(true, prims, 1 << 14, Bins::new(nbins), fill, Bins::merge)
                .best_cut(m)
        } else {
            SCRATCH.with_borrow_mut(|b| {
                b.reset(nbins);
                b.add(&binner, prims);
                b.best_cut(m)
            })
        };
        let (cost, axis, cut) = best?;
        if keep_leaf(input, m, &node, cost) {
            return None;
        }
        let cut = cut as u32;
        let mut sides = Sides::new();
        let k = partition(prims, |p| {
            let c = p.centroid();
            let left = binner.bin(c, axis) < cut;
            sides.add(c, left);
            left
        });
        debug_assert!(0 < k && k < m);
        Some(sides.cut(k))
    }
}

/// Full SAH for a node no bigger than the bin count (thesis §5.2.2: with as many candidates as primitives,
/// take the primitives' own positions): every cut between centroids sorted along each axis, ties in
/// position order. Cost: per axis, one sort of `m` integer keys and two sweeps over the node's primitives
/// (all in L1); then one in-place permutation along the chosen axis.
fn exact_split(input: &BuildInput, prims: &mut [Prim]) -> Option<Cut> {
    let m = prims.len();
    debug_assert!(m <= MAX);
    let mut best: Option<(f64, u64, usize)> = None; // (cost, imbalance, left count)
    let mut best_order = [0u8; MAX];
    let mut node = Box3A::EMPTY;
    let mut keys = [0u64; MAX];
    let keys = &mut keys[..m];
    let mut right_cost = [0f64; MAX];
    for axis in 0..3 {
        // Key: the centroid coordinate as an order-preserving integer (`f32::total_cmp`), then the position.
        for (i, (k, p)) in keys.iter_mut().zip(prims.iter()).enumerate() {
            let bits = p.centroid()[axis].to_bits();
            let ordered = if bits >> 31 == 1 {
                !bits
            } else {
                bits | 1 << 31
            };
            *k = u64::from(ordered) << 32 | i as u64;
        }
        keys.sort_unstable();
        let at = |i: usize| &prims[keys[i] as u32 as usize];
        let mut rb = Box3A::EMPTY;
        for i in (1..m).rev() {
            rb.grow_prim(at(i));
            right_cost[i] = rb.aabb().half_area_f64() * (m - i) as f64;
        }
        rb.grow_prim(at(0));
        node = rb;
        let mut lb = Box3A::EMPTY;
        let mut improved = false;
        for (i, &right) in right_cost[..m].iter().enumerate().skip(1) {
            lb.grow_prim(at(i - 1));
            // Only cut between distinct centroids, so that equal centroids stay together as binning keeps them.
            if at(i - 1).centroid()[axis] == at(i).centroid()[axis] {
                continue;
            }
            let cost = lb.aabb().half_area_f64() * i as f64 + right;
            let imbalance = (2 * i).abs_diff(m) as u64;
            if best.is_none_or(|(c, im, _)| cost < c || (cost == c && imbalance < im)) {
                best = Some((cost, imbalance, i));
                improved = true;
            }
        }
        if improved {
            for (o, &k) in best_order.iter_mut().zip(keys.iter()) {
                *o = k as u8;
            }
        }
    }
    let (cost, _, k) = best?;
    if keep_leaf(input, m, &node.aabb(), cost) {
        return None;
    }
    permute(prims, &best_order[..m]);
    Some(Cut {
        left: k,
        centroids: [None, None],
    })
}

/// Reorders `items` (at most 64) so that `items[i]` becomes the old `items[order[i]]`, in place by following
/// the permutation's cycles. O(len).
fn permute<T: Copy>(items: &mut [T], order: &[u8]) {
    debug_assert!(items.len() <= 64 && order.len() == items.len());
    let mut done = 0u64;
    for start in 0..items.len() {
        if done >> start & 1 == 1 {
            continue;
        }
        let first = items[start];
        let mut j = start;
        loop {
            done |= 1 << j;
            let src = order[j] as usize;
            if src == start {
                items[j] = first;
                break;
            }
            items[j] = items[src];
            j = src;
        }
    }
}
