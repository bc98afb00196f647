//! The ray-space hierarchy, built bottom-up over rays in the order given: level 1 joins `s` consecutive
//! rays, each level above joins `s` consecutive nodes of the level below, up to depth `D`.
//!
//! Sorted rays give tight nodes (CRSH); request order gives the RAH baseline. Cost: O(n) node unions,
//! `n / (s - 1)` nodes of 40 bytes; the levels are built in parallel chunks with the `parallel` feature.

use super::RayNode;
use crate::{Error, Ray, Result, parallel};
use glam::Vec3;
use std::ops::Range;

/// The levels of sphere–cone nodes over a ray sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct RayHierarchy {
    branching: usize,
    /// `levels[k]` is level `k + 1`; node `j` of level `k + 1` holds nodes `j·s .. j·s + s` of level `k`
    /// (rays at level 0).
    levels: Vec<Vec<RayNode>>,
}

impl RayHierarchy {
    /// Builds `depth` levels of branching `branching` over `rays`, which must all be valid
    /// ([`Ray::is_valid`]). The seed tests `s ∈ {8, 16}` and `D ∈ {2, 3, 4}`. `Error::InvalidOption` for
    /// `s < 2`, `D < 1`, `s^D > 2^24` or an invalid ray.
    pub fn build(rays: &[Ray], branching: usize, depth: usize, parallel: bool) -> Result<Self> {
        check_shape(branching, depth)?;
        if let Some(i) = rays.iter().position(|r| !r.is_valid()) {
            return Err(Error::InvalidOption(format!(
                "ray {i} is not valid: the hierarchy takes trimmed rays"
            )));
        }
        let s = branching;
        let mut first = vec![RayNode::default(); rays.len().div_ceil(s)];
        parallel::fill(parallel, &mut first, 256, |j| {
            let leaves: Vec<RayNode> = rays[j * s..((j + 1) * s).min(rays.len())]
                .iter()
                .map(RayNode::of_ray)
                .collect();
            RayNode::enclosing(&leaves)
        });
        let mut levels = vec![first];
        for _ in 1..depth {
            let below = levels.last().expect("level 1 is there");
            let mut next = vec![RayNode::default(); below.len().div_ceil(s)];
            parallel::fill(parallel, &mut next, 256, |j| {
                RayNode::enclosing(&below[j * s..((j + 1) * s).min(below.len())])
            });
            levels.push(next);
        }
        Ok(Self { branching, levels })
    }

    /// `s`, the children per node.
    pub fn branching(&self) -> usize {
        self.branching
    }

    /// `D`, the number of node levels above the rays.
    pub fn depth(&self) -> usize {
        self.levels.len()
    }

    /// The nodes of level `k` (1 = just above the rays, [`depth`](Self::depth) = the top).
    ///
    /// # Panics
    /// When `k` is outside `1..=depth()`, like slice indexing.
    pub fn level(&self, k: usize) -> &[RayNode] {
        &self.levels[k - 1]
    }

    /// What lies under node `j` of level `k`: nodes of level `k - 1`, or at level 1 the positions of
    /// the hierarchy's `rays` rays.
    pub(crate) fn children(&self, k: usize, j: usize, rays: usize) -> Range<usize> {
        let below = if k == 1 {
            rays
        } else {
            self.level(k - 1).len()
        };
        let s = self.branching;
        j * s..((j + 1) * s).min(below)
    }

    /// The triangles among `candidates` whose sphere (`sphere(t)`: centre, radius) node `j` of level `k`
    /// may reach, in candidate order.
    pub(crate) fn survivors(
        &self,
        k: usize,
        j: usize,
        candidates: &[u32],
        sphere: impl Fn(u32) -> (Vec3, f32),
    ) -> Vec<u32> {
        let node = &self.level(k)[j];
        (candidates.iter().copied())
            .filter(|&t| {
                let (c, r) = sphere(t);
                node.hits_sphere(c, r)
            })
            .collect()
    }
}

/// `Error::InvalidOption` unless `s >= 2`, `D >= 1` and `s^D <= 2^24`.
pub(crate) fn check_shape(branching: usize, depth: usize) -> Result<()> {
    let rays_per_top = u32::try_from(depth)
        .ok()
        .and_then(|d| (branching as u64).checked_pow(d));
    if branching < 2 || depth < 1 || rays_per_top.is_none_or(|n| n > 1 << 24) {
        return Err(Error::InvalidOption(format!(
            "ray hierarchy branching {branching}, depth {depth}: need s >= 2, D >= 1, s^D <= 2^24"
        )));
    }
    Ok(())
}
