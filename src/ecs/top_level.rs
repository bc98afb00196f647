//! The top-level tree (TLAS) over the entities' world boxes: refitted while the set of entities stays the
//! same, its degradation measured at every refit, and rebuilt by the same kind of rule as the meshes.
//!
//! Without the rule a crowd that wanders across a level would keep the tree it had when it was spawned:
//! siblings drift apart, every inner box grows to span the level, and every ray visits most entities. With
//! it, the TLAS is rebuilt (binned SAH over the entity boxes, one thread) when
//!
//! - the set of entities changed (always);
//! - under [`RebuildPolicy::Lauterbach`], the degradation metric of the refit exceeds its threshold (0.40
//!   by default, thesis §4.1.5), as for meshes;
//! - under [`RebuildPolicy::Custom`], the same at the thesis's 0.40 (a custom policy decides per mesh; the
//!   top level is not a mesh it was written for);
//! - under [`RebuildPolicy::Adaptive`], the top level's own [`AdaptivePolicy`] (one build, CPU binned
//!   SAH) says so: when the extra query time the refitted tree costs, every batched ray being charged for
//!   its top-level work, exceeds a rebuild's measured time by its noise margin, or when its SAH cost,
//!   extrapolated one frame, would pass [`AdaptivePolicy::sah_bound`] (1.5) × a fresh tree's. With one
//!   build offered it has no build to try or calibrate: its only choice is when to rebuild.
//!
//! Cost per frame in which any entity moved: a pass over the entities for their boxes, a refit (O(n), no
//! allocation), under the adaptive policy an SAH-cost pass over the nodes; a rebuild is O(n log n) and
//! allocates. What happened is in [`TraceStats::top_level`](super::TraceStats).

use super::config::{THESIS_THRESHOLD, lauterbach};
use super::{Decision, RebuildPolicy, TopLevelAction, TopLevelReason, TopLevelStats, TraceWorld};
use crate::adaptive::AdaptivePolicy;
use crate::bvh::{BuildOptions, Builder, Bvh};
use crate::geometry::Aabb;
use glam::Vec3;
use std::time::Instant;

/// The top level's builder: binned SAH, whose trees are the best and whose cost over entity boxes (a few
/// thousand at most) is small.
const BUILDER: Builder = Builder::SAH;

/// What the top level keeps from frame to frame besides its tree.
#[derive(Default)]
pub(crate) struct TopLevelState {
    /// Under [`RebuildPolicy::Adaptive`]: the top level's learned cost model.
    adaptive: Option<AdaptivePolicy>,
    /// The tree's SAH cost, kept current only under the adaptive policy (0 otherwise).
    pub(crate) sah: f64,
    /// The last frame's report, with its running totals.
    pub(crate) stats: TopLevelStats,
}

impl TraceWorld {
    /// Brings the TLAS up to date under `policy`, with `rays` batched requests expected this frame: a
    /// rebuild when entities came or went or the rule asks for one after a refit, a refit when only boxes
    /// moved, nothing when nothing changed. Returns what was done.
    pub(crate) fn update_tlas(&mut self, policy: &RebuildPolicy, rays: usize) -> TopLevelStats {
        let stats = &mut self.top.stats;
        stats.action = TopLevelAction::Unchanged;
        stats.degradation = 0.0;
        stats.prediction = None;
        if !self.tlas_dirty {
            return *stats;
        }
        let membership =
            self.membership_changed || self.tlas_entities.len() != self.instances.len();
        if membership {
            self.tlas_entities.clear();
            self.tlas_entities.extend(self.instances.keys().copied());
            // HashMap order is arbitrary: sort so the tree does not depend on it.
            self.tlas_entities.sort_unstable();
        }
        self.tlas_bounds.clear();
        let inst = &self.instances;
        // An entity whose mesh is empty still takes a slot, with a point box that no ray reaches twice.
        self.tlas_bounds.extend(self.tlas_entities.iter().map(|e| {
            let b = inst[e].world_bounds;
            if b.is_empty() {
                Aabb::from_point(Vec3::ZERO)
            } else {
                b
            }
        }));
        // Entity boxes are finite (the top-level system refuses transforms that carry a mesh past f32's
        // range), so a refit fails only when the count changed, which membership covers.
        let refit = if membership {
            None
        } else {
            self.tlas.refit(&self.tlas_bounds).ok()
        };
        let rebuild = match refit {
            None => Some(TopLevelReason::Membership),
            Some(d) => {
                self.top.stats.degradation = d;
                self.top.stats.frames_since_rebuild += 1;
                self.decide(policy, d, rays)
                    .then_some(TopLevelReason::Policy)
            }
        };
        match rebuild {
            None => {
                self.top.stats.action = TopLevelAction::Refit;
                self.top.stats.refits += 1;
            }
            Some(reason) => self.rebuild_tlas(policy, reason),
        }
        self.tlas_dirty = false;
        self.membership_changed = false;
        self.version += 1;
        self.top.stats
    }

    /// The rule's answer for the refitted tree of degradation `d`: true to rebuild.
    fn decide(&mut self, policy: &RebuildPolicy, d: f32, rays: usize) -> bool {
        let threshold = match policy {
            RebuildPolicy::Lauterbach { threshold } => *threshold,
            RebuildPolicy::Custom(_) => THESIS_THRESHOLD,
            RebuildPolicy::Adaptive { .. } => {
                let Some(adaptive) = self.top.adaptive.as_mut() else {
                    // The policy became adaptive at run time: rebuild once to start measuring.
                    return true;
                };
                self.top.sah = self.tlas.sah_cost();
                let rebuild = adaptive.after_refit(self.top.sah, rays as f64);
                self.top.stats.prediction = Some(adaptive.prediction());
                return rebuild;
            }
        };
        lauterbach(d, threshold) != Decision::Keep
    }

    /// A fresh TLAS over the current boxes; the adaptive policy, if any, is told what it cost.
    fn rebuild_tlas(&mut self, policy: &RebuildPolicy, reason: TopLevelReason) {
        let t = Instant::now();
        self.tlas = Bvh::build(
            &self.tlas_bounds,
            &BuildOptions::new(BUILDER).parallel(false),
        )
        .expect("entity boxes are finite and few");
        let seconds = t.elapsed().as_secs_f64();
        let top = &mut self.top;
        if matches!(policy, RebuildPolicy::Adaptive { .. }) {
            top.sah = self.tlas.sah_cost();
            top.adaptive
                .get_or_insert_with(|| AdaptivePolicy::new(&[BUILDER]))
                .built(BUILDER, self.tlas_bounds.len(), seconds, top.sah);
        } else {
            top.adaptive = None;
            top.sah = 0.0;
        }
        top.stats.action = TopLevelAction::Rebuild { reason };
        top.stats.rebuilds += 1;
        top.stats.frames_since_rebuild = 0;
    }

    /// The top level's share of a frame's batched queries under the adaptive policy: every ray pays its
    /// top-level traversal, expected work `C_tlas` (the TLAS's SAH cost) against `total_work`, the
    /// expected work of a ray through both levels. O(1).
    pub(crate) fn attribute_top_level(&mut self, rays: usize, seconds: f64, total_work: f64) {
        if let Some(adaptive) = self.top.adaptive.as_mut()
            && total_work > 0.0
        {
            adaptive.queried(
                rays as f64,
                self.top.sah,
                seconds * self.top.sah / total_work,
            );
        }
    }
}
