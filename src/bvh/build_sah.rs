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
#[derive(Clone)]
struct Bins {
    count: [[u32; MAX_BINS as usize]; 3],
    bounds: [[Aabb; MAX_BINS as usize]; 3],
}

impl Bins {
    fn new() -> Self {
        Self {
            count: [[0; MAX_BINS as usize]; 3],
            bounds: [[Aabb::EMPTY; MAX_BINS as usize]; 3],
        }
    }

    fn merge(mut self, o: Bins) -> Bins {
        for a in 0..3 {
            for b in 0..MAX_BINS as usize {
                self.count[a][b] += o.count[a][b];
                self.bounds[a][b] = self.bounds[a][b].union(&o.bounds[a][b]);
            }
        }
        self
    }
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

impl SplitRule for BinnedSah {
    fn split(&self, input: &BuildInput, prims: &mut [u32]) -> Option<usize> {
        let m = prims.len();
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
        let fill = |ps: &[u32]| {
            let mut bins = Bins::new();
            for &p in ps {
                let c = input.centroids[p as usize];
                let b = &input.bounds[p as usize];
                for axis in 0..3 {
                    let i = binner.bin(c, axis);
                    bins.count[axis][i] += 1;
                    bins.bounds[axis][i] = bins.bounds[axis][i].union(b);
                }
            }
            bins
        };
        let bins = if input.parallel && m >= 1 << 16 {
            parallel::map_reduce(true, prims, 1 << 14, Bins::new(), fill, Bins::merge)
        } else {
            fill(prims)
        };

        // Sweep every axis; cost in units of the node's area: A_L·N_L + A_R·N_R.
        let mut best: Option<(f64, usize, usize, usize)> = None; // (cost, imbalance, axis, first right bin)
        let mut node = Aabb::EMPTY;
        for axis in 0..3 {
            if extent[axis] <= 0.0 {
                continue;
            }
            let (count, bounds) = (&bins.count[axis], &bins.bounds[axis]);
            let mut right_cost = [0f64; MAX_BINS as usize];
            let (mut rb, mut rn) = (Aabb::EMPTY, 0u64);
            for i in (1..nbins).rev() {
                rb = rb.union(&bounds[i]);
                rn += count[i] as u64;
                right_cost[i] = rb.half_area_f64() * rn as f64;
            }
            node = node.union(&rb).union(&bounds[0]);
            let (mut lb, mut ln) = (Aabb::EMPTY, 0u64);
            for i in 1..nbins {
                lb = lb.union(&bounds[i - 1]);
                ln += count[i - 1] as u64;
                let rn = m as u64 - ln;
                if ln == 0 || rn == 0 {
                    continue;
                }
                let cost = lb.half_area_f64() * ln as f64 + right_cost[i];
                let imbalance = ln.abs_diff(rn) as usize;
                if best.is_none_or(|(c, im, _, _)| cost < c || (cost == c && imbalance < im)) {
                    best = Some((cost, imbalance, axis, i));
                }
            }
        }
        let (cost, _, axis, cut) = best?;
        let area = node.half_area_f64();
        let split_cost = C_TRAV * area + C_ISECT * cost;
        let leaf_cost = C_ISECT * m as f64 * area;
        if m <= input.max_leaf && leaf_cost <= split_cost {
            return None;
        }
        let k = partition(prims, |p| {
            binner.bin(input.centroids[p as usize], axis) < cut
        });
        debug_assert!(0 < k && k < m);
        Some(k)
    }
}
