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
use super::topdown::{SplitRule, centroid_bounds, partition};
use crate::geometry::Aabb;
use crate::parallel;
use glam::Vec3;

/// Largest number of bins per axis.
pub const MAX_BINS: u32 = 64;

/// Per-axis bins of one node: primitive count and bounds of the primitives whose centroid falls in each.
/// Only the first `n` bins of each axis are in use.
#[derive(Clone)]
struct Bins {
    n: usize,
    count: [[u32; MAX_BINS as usize]; 3],
    bounds: [[Aabb; MAX_BINS as usize]; 3],
}

impl Bins {
    fn new(n: usize) -> Self {
        Self {
            n,
            count: [[0; MAX_BINS as usize]; 3],
            bounds: [[Aabb::EMPTY; MAX_BINS as usize]; 3],
        }
    }

    /// Empties the first `n` bins of each axis for reuse.
    fn reset(&mut self, n: usize) {
        self.n = n;
        for a in 0..3 {
            self.count[a][..n].fill(0);
            self.bounds[a][..n].fill(Aabb::EMPTY);
        }
    }

    fn add(&mut self, input: &BuildInput, binner: &Binner, prims: &[u32]) {
        for &p in prims {
            let c = input.centroids[p as usize];
            let b = &input.bounds[p as usize];
            for axis in 0..3 {
                let i = binner.bin(c, axis);
                self.count[axis][i] += 1;
                self.bounds[axis][i] = self.bounds[axis][i].union(b);
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
        let mut node = Aabb::EMPTY;
        for axis in 0..3 {
            let (count, bounds) = (&self.count[axis][..self.n], &self.bounds[axis][..self.n]);
            let mut right_cost = [0f64; MAX_BINS as usize];
            let (mut rb, mut rn) = (Aabb::EMPTY, 0u64);
            for i in (1..self.n).rev() {
                rb = rb.union(&bounds[i]);
                rn += count[i] as u64;
                right_cost[i] = rb.half_area_f64() * rn as f64;
            }
            node = node.union(&rb).union(&bounds[0]);
            let (mut lb, mut ln) = (Aabb::EMPTY, 0u64);
            for i in 1..self.n {
                lb = lb.union(&bounds[i - 1]);
                ln += count[i - 1] as u64;
                let rn = m as u64 - ln;
                if ln == 0 || rn == 0 {
                    continue;
                }
                let cost = lb.half_area_f64() * ln as f64 + right_cost[i];
                let imbalance = ln.abs_diff(rn);
                if best.is_none_or(|(c, im, _, _)| cost < c || (cost == c && imbalance < im)) {
                    best = Some((cost, imbalance, axis, i));
                }
            }
        }
        (best.map(|(c, _, a, i)| (c, a, i)), node)
    }
}

thread_local! {
    /// Each thread's bins, reused from node to node.
    static SCRATCH: std::cell::RefCell<Bins> = std::cell::RefCell::new(Bins::new(0));
}

/// Maps a centroid coordinate to its bin on one axis.
#[derive(Clone, Copy)]
struct Binner {
    min: Vec3,
    scale: Vec3,
    last: usize,
}

impl Binner {
    #[inline]
    fn bin(&self, c: Vec3, axis: usize) -> usize {
        // Saturating float→int casts: NaN (0·∞ on a subnormal extent) gives 0, +∞ gives usize::MAX.
        (((c[axis] - self.min[axis]) * self.scale[axis]) as usize).min(self.last)
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
    fn split(&self, input: &BuildInput, prims: &mut [u32]) -> Option<usize> {
        let m = prims.len();
        if m <= self.bins as usize {
            return exact_split(input, prims);
        }
        let cb = centroid_bounds(input, prims);
        let extent = cb.extent();
        if extent.max_element() <= 0.0 {
            // All centroids coincide: no spatial cut exists; the driver makes a leaf or an object median.
            return None;
        }
        let nbins = self.bins as usize;
        let binner = Binner {
            min: cb.min,
            scale: Vec3::select(
                extent.cmpgt(Vec3::ZERO),
                Vec3::splat(nbins as f32) / extent,
                Vec3::ZERO,
            ),
            last: nbins - 1,
        };
        let (best, node) = if input.parallel && m >= 1 << 16 {
            let fill = |ps: &[u32]| {
                let mut b = Bins::new(nbins);
                b.add(input, &binner, ps);
                b
            };
            parallel::map_reduce(true, prims, 1 << 14, Bins::new(nbins), fill, Bins::merge)
                .best_cut(m)
        } else {
            SCRATCH.with_borrow_mut(|b| {
                b.reset(nbins);
                b.add(input, &binner, prims);
                b.best_cut(m)
            })
        };
        let (cost, axis, cut) = best?;
        if keep_leaf(input, m, &node, cost) {
            return None;
        }
        let k = partition(prims, |p| {
            binner.bin(input.centroids[p as usize], axis) < cut
        });
        debug_assert!(0 < k && k < m);
        Some(k)
    }
}

/// Full SAH for a node no bigger than the bin count (thesis §5.2.2: with as many candidates as primitives,
/// take the primitives' own positions): every cut between centroids sorted along each axis.
fn exact_split(input: &BuildInput, prims: &mut [u32]) -> Option<usize> {
    let m = prims.len();
    let mut best: Option<(f64, u64, usize, usize)> = None; // (cost, imbalance, axis, left count)
    let mut node = Aabb::EMPTY;
    let mut order = [0u32; MAX_BINS as usize];
    let order = &mut order[..m];
    let mut right_cost = [0f64; MAX_BINS as usize];
    for axis in 0..3 {
        order.copy_from_slice(prims);
        let key = |p: u32| input.centroids[p as usize][axis];
        order.sort_unstable_by(|&a, &b| key(a).total_cmp(&key(b)).then(a.cmp(&b)));
        let mut rb = Aabb::EMPTY;
        for i in (1..m).rev() {
            rb = rb.union(&input.bounds[order[i] as usize]);
            right_cost[i] = rb.half_area_f64() * (m - i) as f64;
        }
        node = rb.union(&input.bounds[order[0] as usize]);
        let mut lb = Aabb::EMPTY;
        for i in 1..m {
            lb = lb.union(&input.bounds[order[i - 1] as usize]);
            // Only cut between distinct centroids, so that equal centroids stay together as binning keeps them.
            if key(order[i - 1]) == key(order[i]) {
                continue;
            }
            let cost = lb.half_area_f64() * i as f64 + right_cost[i];
            let imbalance = (2 * i).abs_diff(m) as u64;
            if best.is_none_or(|(c, im, _, _)| cost < c || (cost == c && imbalance < im)) {
                best = Some((cost, imbalance, axis, i));
            }
        }
    }
    let (cost, _, axis, k) = best?;
    if keep_leaf(input, m, &node, cost) {
        return None;
    }
    let key = |p: u32| input.centroids[p as usize][axis];
    prims.sort_unstable_by(|&a, &b| key(a).total_cmp(&key(b)).then(a.cmp(&b)));
    Some(k)
}
