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
//! The rent rule, the guard, the margin and the builder's choice are the planner's
//! ([`crate::adaptive`]). The builds offered ([`offered`]) are those the frame runs in its one submission
//! ([`FrameBuilder`]): GPU LBVH, and the GPU twins of the policy's builders that the GPU builds there
//! (16-bin SAH, 16-bin hybrids over 30-bit codes; not PLOC, which reads back per round, nor the task
//! pool's median). Each mesh's planner picks among them as on the CPU: the build of least predicted
//! work per frame (its rebuild's work over the interval between rebuilds plus a frame's query work on
//! its fresh tree, whose SAH cost every rebuild reads back), kept unless another beats it by the margin.
//! Builds no mesh of the asset measured are *calibrated*, as on the CPU ([`AdaptivePolicy::calibrates`]),
//! never put in use to be measured: the first build of an asset is binned SAH where offered (the guard's
//! bound is stated against it), and the asset's first rebuild that comes due is binned SAH too, before
//! which the frame builds, on the same pose and in the same submission, each unmeasured build that may
//! pay ([`AdaptivePolicy::calibrations_before`]) and reads back its tree's cost beside the rebuild's
//! ([`ResidentMesh::record`](crate::gpu::ResidentMesh::record)): its quality is then the exact ratio of
//! the two trees' costs. The GPU records them before any of their costs is known, so it measures every
//! build that may pay against what is known then, where the CPU, measuring one by one, may skip a build
//! the one before it made pointless. So a mesh that many rays meet gets the better tree (hybrid or SAH),
//! one that few meet the cheaper build (LBVH) (a scripted test below). On `tests/gpu_frame.rs`'s crowd
//! at nine times real time under 2,000 rays, LBVH and the hybrid are measured in the frame of the first
//! rebuild that came due and every rebuild stays binned SAH; at real time, and in `bench ecs-gpu
//! --quick` (1,000 rays over the crowd), the refitted trees stay about as good as fresh ones and no
//! rebuild pays (none happens, nothing is measured). Cost: a few dozen arithmetic operations per changed
//! mesh per frame, two dispatches over the nodes and 40 bytes read back per measured update, a SAH
//! builder's scratch (about 42 bytes per triangle) on each mesh that builds with one, and once per asset
//! one build and one cost reading of each build measured.

use crate::adaptive::{
    AdaptivePolicy, Asset, Build, CostTable, Prediction, TreeCost, costs::size_unit,
};
use crate::bvh::Builder;
use crate::gpu::{FrameBuilder, RefitState};
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
    /// The builds recorded to be measured before the last rebuild, their costs not yet read back.
    calibrating: Vec<Build>,
    /// A rebuild the policy asked for, not yet recorded, with its build.
    due: Option<Build>,
    /// The build of the last rebuild recorded: a rebuilt tree's cost read back is of that build's tree
    /// (a later rebuild replaces a reading still on its way).
    built_with: Build,
    /// Share of the scene's rays, from last frame's boxes (1 until known).
    share: f64,
}

/// The builds the resident frame offers the planner for the policy's `builders`: GPU LBVH first, then
/// the GPU twins of those the frame builds in one submission ([`FrameBuilder`]), each once.
pub(crate) fn offered(builders: &[Builder]) -> Vec<Build> {
    let mut builds = vec![Build::GPU_LBVH];
    for &builder in builders {
        let build = Build {
            builder,
            device: crate::adaptive::Device::Gpu,
        };
        if FrameBuilder::of(builder, false).is_some() && !builds.contains(&build) {
            builds.push(build);
        }
    }
    builds
}

/// How the frame runs `build` (one of [`offered`]'s; LBVH for any other).
pub(crate) fn frame_builder(build: Build) -> FrameBuilder {
    FrameBuilder::of(build.builder, false).unwrap_or(FrameBuilder::Lbvh)
}

/// The build `builder` is, as [`TraceStats`](super::TraceStats) names it.
pub(crate) fn build_of(builder: FrameBuilder) -> Build {
    match builder {
        FrameBuilder::Lbvh => Build::GPU_LBVH,
        FrameBuilder::Sah(o) if o.lbvh_levels == 0 => Build::GPU_SAH,
        FrameBuilder::Sah(o) => Build::gpu_hybrid(o.lbvh_levels),
    }
}

/// The work of a rebuild of `triangles` with `build` (see the module docs).
pub(crate) fn rebuild_work(build: Build, triangles: usize) -> f64 {
    build.prior_time() * size_unit(triangles)
}

impl ResidentPolicies {
    /// Feeds mesh `e`'s planner (choosing among `builds`, [`offered`]) the reading in `state` (if a new
    /// one came back) and says with which build to rebuild now, if at all: always for a first build
    /// (the planner's [`next_build`](AdaptivePolicy::next_build)); `rays` is the last frame's batched ray
    /// count. With it, the planner's grounds when a refitted tree's reading was judged this call.
    ///
    /// Builds no mesh of the asset has measured are calibrated, not tried on frames of their own (the
    /// planner's [`calibrates`](AdaptivePolicy::calibrates)): with an asset's first rebuild that comes
    /// due (binned SAH), the frame builds on that pose, before it, each unmeasured build that may pay
    /// ([`AdaptivePolicy::calibrations_before`]), pushed onto `calibrate`, and measures its tree;
    /// what they cost comes back with the rebuild's own reading and is learned after it. A build another
    /// mesh of the asset is calibrating already is not asked for twice.
    pub fn rebuild(
        &mut self,
        e: Entity,
        asset: Asset,
        builds: &[Build],
        state: &RefitState,
        rays: usize,
        calibrate: &mut Vec<FrameBuilder>,
    ) -> (Option<Build>, Option<Prediction>) {
        let table = &self.table;
        let plan = self.meshes.entry(e).or_insert_with(|| {
            let mut policy = AdaptivePolicy::shared(builds, table, asset);
            policy.calibrates = true;
            Plan {
                policy,
                calibrating: Vec::new(),
                due: None,
                built_with: Build::GPU_LBVH,
                share: 1.0,
            }
        });
        let mut judged = None;
        if let Some(c) = state.cost {
            let cost = TreeCost {
                sah: c.reading.sah,
                root_area: Some(c.reading.root_half_area),
            };
            let rays = rays as f64 * plan.share;
            if c.rebuilt {
                let build = plan.built_with;
                (plan.policy).built(
                    build,
                    asset.triangles,
                    rebuild_work(build, asset.triangles),
                    cost,
                );
                for m in state.calibrated {
                    let b = build_of(m.builder);
                    let work = rebuild_work(b, asset.triangles);
                    (plan.policy).calibrated(b, asset.triangles, work, m.reading.sah);
                }
                plan.calibrating.clear();
            } else {
                plan.policy.queried(rays, cost.sah, rays * cost.sah);
                if plan.policy.after_refit(cost, rays) {
                    plan.due = Some(plan.policy.prediction().build);
                }
                judged = Some(plan.policy.prediction());
            }
        }
        let due = if state.first_build {
            Some(plan.policy.next_build())
        } else {
            plan.due
        };
        plan.due = None;
        let Some(b) = due else {
            return (None, judged);
        };
        plan.built_with = b;
        // What this rebuild measures (readings of calibrations on an earlier pose still on their way
        // are dropped with it).
        let mut wanted = plan.policy.calibrations_before(b);
        wanted.retain(|w| {
            !(self.meshes.iter())
                .any(|(o, p)| *o != e && p.policy.asset() == asset && p.calibrating.contains(w))
        });
        calibrate.extend(wanted.iter().map(|&w| frame_builder(w)));
        self.meshes.get_mut(&e).expect("planned above").calibrating = wanted;
        (due, judged)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Aabb;
    use crate::gpu::{Calibrated, CostReading, SahReading};
    use glam::Vec3;

    /// The scripted SAH cost of a fresh tree of `b`: binned SAH 10, the hybrid 10.3, LBVH 11.5.
    fn fresh(b: Build) -> f64 {
        match b.builder {
            Builder::Sah { .. } => 10.0,
            Builder::Hybrid { .. } => 10.3,
            _ => 11.5,
        }
    }

    /// One mesh's tree as the script keeps it: its cost, whether last frame rebuilt it, and with what;
    /// the builds used and those only measured so far.
    struct Tree {
        e: Entity,
        cost: f64,
        rebuilt: bool,
        last: Option<Build>,
        since: u32,
        calibrated: Vec<Calibrated>,
        used: Vec<Build>,
        measured: Vec<Build>,
    }

    impl Tree {
        /// One frame: the planner is given last frame's reading, with the fresh costs of the builds it
        /// asked to measure; a rebuild resets the cost to the fresh tree's, a refit lets it rise by 3%.
        fn frame(&mut self, p: &mut ResidentPolicies, builds: &[Build], asset: Asset, rays: usize) {
            let reading = |sah| SahReading {
                sah,
                root_half_area: 1.0,
            };
            let cost = self.last.map(|_| CostReading {
                reading: reading(self.cost),
                rebuilt: self.rebuilt,
            });
            let state = RefitState {
                degradation: 0.0,
                frames_since_rebuild: self.since,
                cost,
                first_build: self.last.is_none(),
                calibrated: &self.calibrated,
            };
            let mut calibrate = vec![];
            let (build, _) = p.rebuild(self.e, asset, builds, &state, rays, &mut calibrate);
            self.rebuilt = build.is_some();
            self.calibrated = (calibrate.iter())
                .map(|&builder| Calibrated {
                    builder,
                    reading: reading(fresh(build_of(builder))),
                })
                .collect();
            self.measured.extend(calibrate.iter().map(|&b| build_of(b)));
            match build {
                Some(b) => {
                    (self.cost, self.last, self.since) = (fresh(b), Some(b), 0);
                    if !self.used.contains(&b) {
                        self.used.push(b);
                    }
                }
                None => (self.cost, self.since) = (self.cost * 1.03, self.since + 1),
            }
        }
    }

    /// Two meshes of one asset whose trees cost the same, scripted: one the whole batch of rays meets,
    /// the other a hundredth of it (its box's share of the scene's area). Both start with binned SAH (the
    /// guard's reference); the asset's first rebuild that comes due measures LBVH and the hybrid on its
    /// pose, each once for the asset, and no build is put in use before it was measured. Then the mesh
    /// with 10⁴ rays a frame rebuilds with a better tree than LBVH's, whose saved query work (rays × SAH
    /// cost) repays its 2.5–5 times LBVH's build work, and the mesh with 100 rays with LBVH, whose build
    /// work is least. Counted work only: no timing.
    #[test]
    fn each_mesh_gets_the_builder_its_counted_query_work_favours() {
        let builds = offered(&[Builder::LBVH, Builder::HYBRID, Builder::SAH, Builder::PLOC]);
        assert_eq!(
            builds,
            [Build::GPU_LBVH, Build::gpu_hybrid(6), Build::GPU_SAH],
            "PLOC is not built in the frame's submission"
        );
        let asset = Asset {
            triangles: 600,
            id: 1,
        };
        let mut p = ResidentPolicies::default();
        let tree = |i| Tree {
            e: Entity::from_raw_u32(i).unwrap(),
            cost: 0.0,
            rebuilt: false,
            last: None,
            since: 0,
            calibrated: vec![],
            used: vec![],
            measured: vec![],
        };
        let (mut busy, mut quiet) = (tree(1), tree(2));
        let boxes = [
            (busy.e, Some(Aabb::new(Vec3::ZERO, Vec3::splat(10.0)))),
            (quiet.e, Some(Aabb::new(Vec3::ZERO, Vec3::splat(1.0)))),
        ];
        for frame in 0..60 {
            for t in [&mut busy, &mut quiet] {
                t.frame(&mut p, &builds, asset, 10_000);
                if frame == 0 {
                    assert_eq!(t.last, Some(Build::GPU_SAH));
                }
            }
            let measured = [busy.measured.as_slice(), &quiet.measured].concat();
            for t in [&busy, &quiet] {
                for b in &t.used {
                    let ok = *b == Build::GPU_SAH || measured.contains(b);
                    assert!(ok, "frame {frame}: {b} used before it was measured");
                }
            }
            p.set_shares(&boxes);
        }
        let mut measured = [busy.measured.as_slice(), &quiet.measured].concat();
        measured.sort_by_key(|b| b.prior_time().to_bits());
        assert_eq!(measured, [Build::GPU_LBVH, Build::gpu_hybrid(6)]);
        let busy_build = busy.last.unwrap();
        assert!(fresh(busy_build) < fresh(Build::GPU_LBVH), "{busy_build}");
        assert_eq!(quiet.last, Some(Build::GPU_LBVH));
    }
}
