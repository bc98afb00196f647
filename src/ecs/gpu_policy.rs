//! [`RebuildPolicy::Adaptive`](super::RebuildPolicy) on the GPU-resident frame
//! ([`gpu_frame`](super::gpu_frame)): the planner of [`AdaptivePolicy`] per resident mesh, fed what comes
//! back without blocking, one frame late.
//!
//! What it is told, in **counted work** instead of seconds (one unit: one node visit or triangle test of
//! one ray), in a cost table of its own (the CPU mirror's policies learn seconds; the two never mix):
//! - the tree's SAH cost and root area, reduced on the GPU after each refit and rebuild and read back
//!   beside the degradation metric (`ResidentMesh::measure_costs`): the cost of frame n's tree reaches
//!   the policy when its read-back is found done, normally in frame n + 1, and a rebuild it asks for is
//!   recorded then (one frame late, or more when the GPU is behind; a refit recorded while a reading is
//!   on its way is not measured, so a lagging GPU shows the policy fewer frames and the rent rises slower);
//! - the rays a mesh receives: the last frame's batched rays times the mesh's share of the scene, its
//!   world box's area over the scene box's (boxes from the CPU's conservative bounds of the last frame,
//!   `gpu::frame::bound`), as the CPU mode apportions its measured query time;
//! - a frame's query work: those rays times the SAH cost, the expected visits per ray that the SAH cost
//!   models (exact for rays spread evenly over the mesh's box, as the CPU mode's apportioning assumes);
//! - a rebuild's work: `prior_time(build) · n·log2 n` units ([`Build::prior_time`]: 1 for LBVH, 5 for
//!   binned SAH): a GPU build passes over its triangles about `log2 n` times, each pass about one node
//!   visit's work per triangle. Our model, not a measurement: GPU timestamps per mesh and GPU visit
//!   counters would replace it (not done).
//!
//! The rent rule, the guard and the margin are the planner's ([`crate::adaptive`]); the only build
//! offered is the mesh's resident builder ([`TraceConfig::builder`](super::TraceConfig) where the GPU
//! has it in one submission, else GPU LBVH), so the planner decides when to rebuild, not with what, and
//! its guard rests on its priors (no binned-SAH tree is measured unless that is the builder). Cost: a
//! few dozen arithmetic operations per changed mesh per frame, two dispatches over the nodes and 40 bytes
//! read back per measured update.

use crate::adaptive::{AdaptivePolicy, Asset, Build, CostTable, TreeCost, costs::size_unit};
use crate::gpu::RefitState;
use bevy_ecs::entity::Entity;
use std::collections::HashMap;

/// The resident meshes' planners and the rays each receives.
#[derive(Default)]
pub(crate) struct ResidentPolicies {
    table: CostTable,
    meshes: HashMap<Entity, Plan>,
}

struct Plan {
    policy: AdaptivePolicy,
    /// A rebuild the policy asked for, not yet recorded.
    due: bool,
    /// Share of the scene's rays, from last frame's boxes (1 until known).
    share: f64,
}

/// The work of a rebuild of `triangles` with `build` (see the module docs).
pub(crate) fn rebuild_work(build: Build, triangles: usize) -> f64 {
    build.prior_time() * size_unit(triangles)
}

impl ResidentPolicies {
    /// Feeds mesh `e`'s planner the reading in `state` (if a new one came back) and says whether to
    /// rebuild now; `rays` is the last frame's batched ray count.
    pub fn rebuild(
        &mut self,
        e: Entity,
        asset: Asset,
        build: Build,
        state: &RefitState,
        rays: usize,
    ) -> bool {
        let table = &self.table;
        let plan = self.meshes.entry(e).or_insert_with(|| Plan {
            policy: AdaptivePolicy::shared(&[build], table, asset),
            due: false,
            share: 1.0,
        });
        if let Some(c) = state.cost {
            let cost = TreeCost {
                sah: c.reading.sah,
                root_area: Some(c.reading.root_half_area),
            };
            let rays = rays as f64 * plan.share;
            if c.rebuilt {
                (plan.policy).built(
                    build,
                    asset.triangles,
                    rebuild_work(build, asset.triangles),
                    cost,
                );
                plan.due = false;
            } else {
                plan.policy.queried(rays, cost.sah, rays * cost.sah);
                plan.due |= plan.policy.after_refit(cost, rays);
            }
        }
        std::mem::take(&mut plan.due)
    }

    /// Sets every planned mesh's share of the rays from this frame's world boxes (`None` where a mesh's
    /// box is unknown: it is assumed to meet every ray) and forgets meshes not listed.
    pub fn set_shares(&mut self, boxes: &[(Entity, Option<crate::Aabb>)]) {
        let mut scene = crate::Aabb::EMPTY;
        for b in boxes.iter().filter_map(|b| b.1) {
            scene = scene.union(&b);
        }
        let area = scene.half_area_f64();
        let mut kept = HashMap::with_capacity(self.meshes.len());
        for (e, b) in boxes {
            if let Some(mut plan) = self.meshes.remove(e) {
                plan.share = match b {
                    Some(b) if area > 0.0 => (b.half_area_f64() / area).min(1.0),
                    _ => 1.0,
                };
                kept.insert(*e, plan);
            }
        }
        self.meshes = kept;
    }
}
