//! Refit: recompute every box bottom-up after the primitives moved, keeping the topology, and measure how
//! much the tree degraded (Lauterbach thesis §4.1.3 and §4.1.5).
//!
//! When to use: every frame a mesh deforms without changing topology. Cost: one reverse pass over the nodes
//! (children always follow their parent), O(n), no allocation; the metric is fused into the same pass.
//!
//! The degradation metric is `Σ (ratio(v) − ratio₀(v)) / inner_count` over inner nodes, where
//! `ratio = SA(v) / (SA(left) + SA(right))` now and `ratio₀` is the same ratio stored in the node when it was
//! built. It is 0 for an unchanged tree, scale-free, and grows as siblings drift apart inside their parents;
//! the thesis rebuilds above 0.40. Differences are signed, as in the thesis (a node can also get tighter).

use super::quality::{C_ISECT, C_TRAV};
use super::{Bvh, Node};
use crate::geometry::{Aabb, sa_ratio, sa_ratio_of_extents};
use crate::{Error, Result};
use glam::Vec3A;

impl Bvh {
    /// Refits to new primitive boxes (indexed by primitive id, as given to [`Bvh::build`]) and returns the
    /// degradation metric.
    ///
    /// Errors: [`Error::VertexCountMismatch`] when `prim_bounds` has the wrong length,
    /// [`Error::NonFiniteBounds`] for an empty or non-finite box (the tree is then unchanged).
    pub fn refit(&mut self, prim_bounds: &[Aabb]) -> Result<f32> {
        self.check_bounds(prim_bounds)?;
        let prims = &self.prims;
        Ok(refit_nodes(&mut self.nodes, |slot| {
            prim_bounds[prims[slot] as usize].lanes()
        }))
    }

    /// [`Error::VertexCountMismatch`] unless there is one box per primitive, [`Error::NonFiniteBounds`]
    /// for the first empty or non-finite one.
    pub(crate) fn check_bounds(&self, prim_bounds: &[Aabb]) -> Result<()> {
        if prim_bounds.len() != self.prims.len() {
            return Err(Error::VertexCountMismatch {
                expected: self.prims.len(),
                got: prim_bounds.len(),
            });
        }
        if let Some(primitive) = prim_bounds
            .iter()
            .position(|b| b.is_empty() || !b.min.is_finite() || !b.max.is_finite())
        {
            return Err(Error::NonFiniteBounds { primitive });
        }
        Ok(())
    }

    /// The degradation metric of the current boxes against the build-time ratios, without changing anything
    /// (what the last refit returned).
    pub fn degradation(&self) -> f32 {
        let mut sum = 0f64;
        for n in self.nodes.iter().filter(|n| !n.is_leaf()) {
            let (l, r) = (&self.nodes[n.left()], &self.nodes[n.left() + 1]);
            sum += (sa_ratio(&n.aabb(), &l.aabb(), &r.aabb()) - n.sa_ratio) as f64;
        }
        normalise(sum, &self.nodes)
    }
}

/// Recomputes all boxes of `nodes` from `slot_bounds(slot)` (a box's minimum and maximum corners) at the
/// leaves; returns the degradation metric. Build-time ratios are kept. The boxes are combined in SIMD
/// lanes: `min`/`max` and [`sa_ratio`]'s arithmetic round per lane exactly as the scalar forms do, so
/// the boxes and the metric are those of the scalar pass, bit for bit.
pub(crate) fn refit_nodes(
    nodes: &mut [Node],
    slot_bounds: impl FnMut(usize) -> (Vec3A, Vec3A),
) -> f32 {
    refit_pass::<false>(nodes, slot_bounds).0
}

/// [`refit_nodes`]; with `SAH`, also the refitted tree's SAH cost ([`Bvh::sah_cost`], up to the order
/// its terms are summed in) from the same pass, a few operations a node instead of a second pass: from
/// `Σ A(n)·w(n)` and `Σ w(n)` (`w`: [`C_TRAV`] for an inner node, the count times [`C_ISECT`] for a
/// leaf), the SAH cost being their quotient by the root's area (the second sum where the root has none,
/// as [`Bvh::sah_cost`] counts every node with probability 1 then).
#[inline(always)]
pub(crate) fn refit_pass<const SAH: bool>(
    nodes: &mut [Node],
    mut slot_bounds: impl FnMut(usize) -> (Vec3A, Vec3A),
) -> (f32, f64) {
    let mut sum = 0f64;
    let (mut area_sum, mut weight_sum) = (0f64, 0f64);
    for i in (0..nodes.len()).rev() {
        let n = nodes[i];
        let (min, max) = if n.is_leaf() {
            let mut slots = n.slots();
            // A leaf holds at least one slot.
            let first = slot_bounds(slots.next().unwrap_or(0));
            slots.fold(first, |(lo, hi), s| {
                let (l, h) = slot_bounds(s);
                (lo.min(l), hi.max(h))
            })
        } else {
            let (l, r) = (&nodes[n.left()], &nodes[n.left() + 1]);
            let (lmin, lmax) = (Vec3A::from_array(l.min), Vec3A::from_array(l.max));
            let (rmin, rmax) = (Vec3A::from_array(r.min), Vec3A::from_array(r.max));
            let (min, max) = (lmin.min(rmin), lmax.max(rmax));
            sum += f64::from(sa_ratio_of_extents(max - min, lmax - lmin, rmax - rmin) - n.sa_ratio);
            (min, max)
        };
        if SAH {
            let w = if n.is_leaf() {
                n.count() as f64 * C_ISECT
            } else {
                C_TRAV
            };
            area_sum += Aabb::new(min.into(), max.into()).half_area_f64() * w;
            weight_sum += w;
        }
        nodes[i].min = min.to_array();
        nodes[i].max = max.to_array();
    }
    let sah = match nodes.first() {
        Some(root) if SAH => match root.aabb().half_area_f64() {
            ra if ra > 0.0 => area_sum / ra,
            _ => weight_sum,
        },
        _ => 0.0,
    };
    (normalise(sum, nodes), sah)
}

/// Divides the summed ratio differences by the number of inner nodes (0 for trees without any).
fn normalise(sum: f64, nodes: &[Node]) -> f32 {
    let inner = nodes.len() / 2;
    if inner == 0 {
        0.0
    } else {
        (sum / inner as f64) as f32
    }
}
