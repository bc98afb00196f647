//! The planner of one mesh's tree: per frame keep the refitted tree, rebuild it, or try a build not
//! measured yet (see the [module docs](super) for the rules).

use super::costs::{Asset, CostTable, Tables};
use super::query_model::{QueryModel, proportional};
use super::rank::{Candidate, choose, pays};
use super::{Build, Estimate};
use crate::bvh::{Builder, Bvh};
use crate::characterize::SceneProfile;

/// The SAH bound by default: no tree answers queries with an SAH cost above 1.5 × a fresh binned-SAH
/// tree's.
pub const DEFAULT_SAH_BOUND: f64 = 1.5;

/// Standard deviations of margin by default (about 98% one-sided confidence for normal errors).
pub const DEFAULT_Z: f64 = 2.0;

/// What the planner is told about a tree: its SAH cost and, where known, its root box's half area (the
/// scene's extent, which tells the guard how fast the scene spreads out). An `f64` converts to a cost with
/// the area unknown.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TreeCost {
    /// [`Bvh::sah_cost`].
    pub sah: f64,
    /// Half the surface area of the root box, if known.
    pub root_area: Option<f64>,
}

impl TreeCost {
    /// The cost of `bvh`: one pass over its nodes.
    pub fn of(bvh: &Bvh) -> TreeCost {
        TreeCost::measured(bvh, bvh.sah_cost())
    }

    /// The cost of `bvh` whose SAH cost `sah` was measured already (by
    /// [`MeshBvh::refit_with_sah`](crate::MeshBvh::refit_with_sah), in the refit's own pass). O(1).
    pub fn measured(bvh: &Bvh, sah: f64) -> TreeCost {
        TreeCost {
            sah,
            root_area: Some(bvh.bounds().half_area_f64()),
        }
    }
}

impl From<f64> for TreeCost {
    fn from(sah: f64) -> TreeCost {
        TreeCost {
            sah,
            root_area: None,
        }
    }
}

/// What [`AdaptivePolicy::after_refit`] decided, and on which ground.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Verdict {
    /// Keep the refitted tree: the rent paid so far does not exceed the rebuild's predicted cost by the
    /// margin (or nothing was built yet to compare with).
    #[default]
    Keep,
    /// Rebuild to measure a build not tried yet: its expected gain over the horizon exceeds its cost.
    Explore,
    /// Rebuild: the SAH ratio against a fresh binned-SAH tree, extrapolated one frame, would pass
    /// [`AdaptivePolicy::sah_bound`].
    Guard,
    /// Rebuild: the extra query time paid since the last rebuild exceeds the rebuild's predicted time by
    /// the margin.
    Rent,
    /// Rebuild only the degraded subtrees ([`Bvh::rebuild_degraded`]): a rebuild was due by the rent, and
    /// [`AdaptivePolicy::prefer_partial`] found the partial rebuild cheaper than the full one by the
    /// margin. Report it with [`AdaptivePolicy::partially_rebuilt`].
    Partial,
    /// Rebuild without refitting first ([`AdaptivePolicy::outpaced`]): the guard rebuilt the trees of
    /// the last frames one frame after their build, and the one-frame ratio, as measured and as it
    /// trends, stays above the bound, so a refit would only be thrown away. The prediction's `sah` is
    /// then NaN (no refitted tree was measured).
    Outpaced,
}

/// The update a due rebuild takes: the whole tree or its degraded subtrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Update {
    Full,
    Partial,
}

/// The numbers behind the last decision of [`AdaptivePolicy::after_refit`]: what users see in
/// [`TraceStats`](crate::ecs::TraceStats) to learn why a mesh was or was not rebuilt.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    /// The decision.
    pub verdict: Verdict,
    /// The build a rebuild uses now.
    pub build: Build,
    /// Its predicted seconds (0 before any build was measured).
    pub rebuild_s: f64,
    /// Extra query seconds the refitted tree has cost since the last rebuild, this frame included: the
    /// rays times the SAH cost above a fresh tree's, summed over those frames, at the marginal rate as
    /// estimated now.
    pub rent_s: f64,
    /// The margin the rent must exceed the rebuild by: `z` standard deviations of their difference.
    pub margin_s: f64,
    /// The refitted tree's SAH cost.
    pub sah: f64,
    /// The predicted SAH cost of a fresh binned-SAH tree of this frame, the quantity the bound is stated
    /// in (0 while unknown).
    pub fresh_sah: f64,
}

impl Default for Prediction {
    fn default() -> Self {
        Self {
            verdict: Verdict::Keep,
            build: Build::cpu(Builder::LBVH),
            rebuild_s: 0.0,
            rent_s: 0.0,
            margin_s: 0.0,
            sah: 0.0,
            fresh_sah: 0.0,
        }
    }
}

/// The planner of one mesh (see the module docs). Keep one per mesh, made with [`shared`](Self::shared)
/// so that meshes learn from each other; it allocates only when made and for builds or assets the shared
/// table has not seen.
#[derive(Clone, Debug)]
pub struct AdaptivePolicy {
    builds: Vec<Build>,
    costs: CostTable,
    asset: Asset,
    clustered: bool,
    /// Rays per frame at this mesh.
    rays: Estimate,
    /// This mesh's query seconds per ray against its tree's SAH cost: the rent's marginal rate.
    query_model: QueryModel,
    /// Frames between rebuilds.
    interval: Estimate,
    /// Frames from a binned-SAH rebuild to the next rebuild, and from any other: how long an exact
    /// and an inexact anchor last on this mesh (see [`View::exact_anchor_pays`]).
    after_exact: Estimate,
    after_inexact: Estimate,
    /// The fresh cost, in SAH units, of a tree of relative quality 1 at the last rebuild.
    reference: f64,
    /// Whether [`reference`](Self::reference) was assumed (carried forward by the guard's factor when a
    /// build nobody had measured was anchored) rather than measured: the next anchor then learns neither
    /// a drift nor an anchor error from it, as both would hold the assumption's conservatism, not the
    /// scene's motion.
    assumed: bool,
    triangles: usize,
    /// The root's half area at the last rebuild, if told, and the tree's SAH cost then.
    area_built: Option<f64>,
    sah_built: f64,
    /// The factor the guard last carried the fresh cost forward by (learned drift or spread).
    guard_factor: f64,
    /// The factor by which the last refit's scene had drawn in since the rebuild (see
    /// [`drawn_in`]): the fresh cost is expected that much higher, and drift is learned around it.
    drawn_in: f64,
    /// How far this mesh's rebuilt trees landed from their predicted cost: see [`AnchorError`].
    anchor_error: AnchorError,
    /// The last binned-SAH tree built on this mesh: see [`Exact`].
    exact: Option<Exact>,
    /// The index in `builds` past the last build [`calibrated`](Self::calibrated).
    calibrating: usize,
    /// Whether a build was calibrated since the last rebuild: the next choice of build is made afresh,
    /// without the hysteresis that keeps the build in use (see [`View::plan`]).
    rechoose: bool,
    current: Option<Build>,
    /// The rent's work since the last rebuild: see [`RentWork`].
    work: RentWork,
    frames: u32,
    age: u32,
    /// The tree's SAH cost at the last refit or rebuild, which the guard reads this frame's rise from
    /// (NaN where no rise is read: a sibling's first frame).
    last_sah: f64,
    last: Prediction,
    /// The guard's one-frame ratios, for [`outpaced`](Self::outpaced): see [`Pace`].
    pace: Pace,
    /// Seconds per [`size_unit`](super::costs::size_unit) of the triangles a partial rebuild redid.
    partial_rate: Estimate,
    /// Whether this mesh tries builds its asset has not measured: the asset's first mesh does, a
    /// [`sibling`](Self::sibling) never (what the first measures reaches it through the table).
    explores: bool,
    /// Whether unmeasured builds are measured by [`calibration`](Self::calibration) (the caller asks for
    /// it after each rebuild) rather than tried on frames of their own: rebuilds then use measured
    /// builds only, binned SAH until the calibration (false by default).
    pub calibrates: bool,
    /// The bound on the SAH ratio against a fresh binned-SAH tree ([`DEFAULT_SAH_BOUND`]).
    pub sah_bound: f64,
    /// Standard deviations of margin for every "act now?" decision and every change of build
    /// ([`DEFAULT_Z`]).
    pub z: f64,
}

impl AdaptivePolicy {
    /// A policy choosing among `builders` on the CPU (an empty slice means LBVH), with a table of its own.
    pub fn new(builders: &[Builder]) -> Self {
        let builds: Vec<Build> = builders.iter().map(|&b| Build::cpu(b)).collect();
        Self::with_builds(&builds)
    }

    /// A policy choosing among `builds` (an empty slice means CPU LBVH), with a table of its own, e.g.
    /// the CPU builders plus [`Build::GPU_LBVH`] where a GPU exists.
    pub fn with_builds(builds: &[Build]) -> Self {
        Self::shared(builds, &CostTable::new(), Asset::default())
    }

    /// A policy choosing among `builds` (an empty slice means CPU LBVH) for a mesh of `asset`, learning
    /// into and from `costs`: what any mesh of the table measured predicts this one's build times, and
    /// what a mesh of the same asset measured predicts its trees, so it explores only what nobody tried.
    pub fn shared(builds: &[Build], costs: &CostTable, asset: Asset) -> Self {
        let mut builds = builds.to_vec();
        if builds.is_empty() {
            builds.push(Build::cpu(Builder::LBVH));
        }
        Self {
            builds,
            costs: costs.clone(),
            asset,
            clustered: false,
            rays: Estimate::default(),
            query_model: QueryModel::default(),
            interval: Estimate::default(),
            after_exact: Estimate::default(),
            after_inexact: Estimate::default(),
            reference: 0.0,
            assumed: false,
            triangles: asset.triangles,
            area_built: None,
            sah_built: 0.0,
            guard_factor: 1.0,
            drawn_in: 1.0,
            anchor_error: AnchorError::default(),
            exact: None,
            calibrating: 0,
            rechoose: false,
            current: None,
            work: RentWork::default(),
            frames: 0,
            age: 0,
            last_sah: f64::NAN,
            last: Prediction::default(),
            pace: Pace::default(),
            partial_rate: Estimate::default(),
            explores: true,
            calibrates: false,
            sah_bound: DEFAULT_SAH_BOUND,
            z: DEFAULT_Z,
        }
    }

    /// The policy of another mesh of the same asset whose tree starts as a copy of this mesh's, refitted
    /// to its own pose, instead of a build of its own (a crowd's instances: a refit is O(n), a build
    /// O(n log n)). It shares the table and takes over what this mesh knows of the copied tree — the
    /// build that made it, the fresh cost then, the frames since — so the first
    /// [`after_refit`](Self::after_refit) judges the copy like any refitted tree: the guard rebuilds it
    /// at once if its cost would pass the bound, the rent when the copy costs more queries than a build.
    /// It explores nothing: trying builds is left to the asset's first mesh, whose measurements it reads
    /// from the shared table (without that mesh, the asset keeps what was measured). Cost: one clone of
    /// the small policy (its list of builds).
    pub fn sibling(&self) -> AdaptivePolicy {
        AdaptivePolicy {
            work: RentWork::default(),
            explores: false,
            // No rise is read from a cost measured on another mesh.
            last_sah: f64::NAN,
            last: Prediction::default(),
            pace: Pace::default(),
            ..self.clone()
        }
    }

    /// Takes the characteriser's profile as the prior of builds not measured yet: on a non-uniform
    /// (clustered) mesh LBVH's trees are expected worse, which makes trying a better builder pay sooner.
    pub fn set_profile(&mut self, profile: &SceneProfile) {
        if self.clustered == profile.uniform {
            self.clustered = !profile.uniform;
        }
    }

    /// The table this policy learns into.
    pub fn costs(&self) -> &CostTable {
        &self.costs
    }

    /// The asset whose measurements this policy shares through its table.
    pub fn asset(&self) -> Asset {
        self.asset
    }

    /// The build to use for the next rebuild: before anything is known the build of least prior time
    /// (the first offered among equals); then the cheapest predicted over a rebuild interval, kept
    /// unless another is cheaper beyond the noise; or a build not measured yet when trying it pays.
    pub fn next_build(&self) -> Build {
        let t = self.costs.lock();
        // A mesh's first build is no rebuild that trying a build could ride on.
        self.view(&t).plan(self.current.is_some()).0
    }

    /// Records a rebuild: its build, triangle count, measured seconds and the new tree's SAH cost.
    /// A non-finite or negative cost or time is not learned from (the rebuild still resets the rent).
    pub fn built(
        &mut self,
        build: impl Into<Build>,
        triangles: usize,
        seconds: f64,
        cost: impl Into<TreeCost>,
    ) {
        let build = build.into();
        let TreeCost {
            sah: sah_cost,
            root_area,
        } = cost.into();
        self.area_built = root_area.filter(|a| a.is_finite() && *a > 0.0);
        self.triangles = triangles;
        if seconds.is_finite() && seconds >= 0.0 {
            self.costs.learn_time(build, triangles, seconds);
        }
        if sah_cost.is_finite() && sah_cost > 0.0 {
            let predicted = {
                let t = self.costs.lock();
                let v = self.view(&t);
                // Before a drift was learned the error is the drift itself (learned as such).
                let drift_known = t.drift.get(&self.asset).is_some_and(|d| d.samples() > 0);
                v.relative(build)
                    .filter(|r| {
                        r.2 && drift_known
                            && self.reference > 0.0
                            && self.frames > 0
                            && !self.assumed
                    })
                    .map(|r| {
                        let walk = self.frames as f64 * v.walk_var();
                        let expected = v.mean_drift(self.frames) * self.drawn_in;
                        (self.reference * r.0 * expected, walk)
                    })
            };
            // The error holds the deviation of each inexact anchor (the previous one and this one); an
            // interval between two binned-SAH trees holds the walk alone, which `anchor` learns.
            let inexact = inexact(self.current, build);
            if let Some((predicted, walk)) = predicted
                && inexact > 0
            {
                self.anchor_error
                    .learn(sah_cost, predicted, walk, inexact as f64);
            }
            self.anchor(build, sah_cost);
            self.sah_built = sah_cost;
            if is_sah(&build) {
                self.exact = Some(Exact {
                    build,
                    sah: sah_cost,
                    area: self.area_built,
                    frames: 0,
                    carried: 1.0,
                });
            }
        }
        // A build tried on a frame that would have refitted says nothing of when rebuilds are due.
        if self.frames > 0 && self.last.verdict != Verdict::Explore {
            self.interval.add(self.frames as f64);
            match self.current {
                Some(b) if is_sah(&b) => self.after_exact.add(self.frames as f64),
                Some(_) => self.after_inexact.add(self.frames as f64),
                None => {}
            }
        }
        self.last_sah = sah_cost;
        self.current = Some(build);
        self.rechoose = false;
        self.guard_factor = 1.0;
        self.drawn_in = 1.0;
        self.work = RentWork::default();
        self.frames = 0;
    }

    /// A build to measure now, on the pose of the binned-SAH tree just built, where
    /// [`calibrates`](Self::calibrates) is set: at the mesh's first rebuild that came due (not its first
    /// build), the first build offered that no mesh of this asset has measured. Build it from the same
    /// positions, report it with [`calibrated`](Self::calibrated) (the tree in use stays the binned-SAH
    /// one) and ask again until `None`.
    ///
    /// A build's quality is its tree's cost over the fresh binned-SAH tree's on the same pose: measured
    /// here it is exact, where a build tried on a frame of its own is measured against the last
    /// binned-SAH tree carried forward as the guard carries it, which in a fast scene is far off (over
    /// the report's explosion LBVH's trees were learned as 1.69 × binned SAH against 1.16, which left
    /// binned SAH rebuilding every frame at three times LBVH's time). No worse tree is put in use to
    /// learn it, and a scene that never rebuilds never pays for it. A build is measured only where it
    /// may pay for its time within the horizon, by the rule that prices an exploration (against the
    /// build the planner would choose now, all of its time counted):
    /// the quick report's explosion calibrated hybrid on its first frame at binned SAH's time, where LBVH,
    /// calibrated just before, left hybrid nothing to save. One passed over is asked again after a later
    /// binned-SAH rebuild. Cost: one build of each build worth it, once per asset, in the frame of a
    /// rebuild that came due (a sibling, and any mesh of an asset measured already, calibrates nothing).
    pub fn calibration(&self) -> Option<Build> {
        let fresh = self.calibrates && self.explores && self.age > 0 && self.frames == 0;
        let e = self.exact.filter(|e| fresh && e.frames == 0)?;
        self.worth_calibrating(e.build, 1).pop()
    }

    /// The builds to measure on the pose of a rebuild with `due` about to be made, for a caller that
    /// records builds before it learns what they cost (the GPU-resident frame, whose readings come back
    /// a frame or more later): where `due` is binned SAH and [`calibration`](Self::calibration) would
    /// ask after it, every build it may ask for, in order, each judged against what is known now (not
    /// against the builds measured before it in the list, as `calibration` asks them one by one). Make
    /// them on that pose before the rebuild, then, once their costs are known, report the rebuild with
    /// [`built`](Self::built) and each of these with [`calibrated`](Self::calibrated). Empty (no
    /// allocation) where nothing is to be measured, which is every rebuild but an asset's first ones.
    pub fn calibrations_before(&self, due: Build) -> Vec<Build> {
        if !(self.calibrates && self.explores && self.age > 0 && is_sah(&due)) {
            return Vec::new();
        }
        self.worth_calibrating(due, usize::MAX)
    }

    /// Up to `most` builds after those calibrated, other than `anchor`, that no mesh of the asset has
    /// measured and that may pay for their time within the horizon against the build the planner would
    /// choose now (see [`calibration`](Self::calibration)).
    fn worth_calibrating(&self, anchor: Build, most: usize) -> Vec<Build> {
        let t = self.costs.lock();
        let v = self.view(&t);
        let chosen = v.plan(false).0;
        (self.builds.iter().skip(self.calibrating))
            .filter(|&&b| {
                b != anchor && t.quality(&self.asset, b).is_none() && v.pays_to_try(chosen, b, 0.0)
            })
            .take(most)
            .copied()
            .collect()
    }

    /// Records a build asked for by [`calibration`](Self::calibration): its triangle count, measured
    /// seconds and its tree's SAH cost. Learns its time and its quality against the binned-SAH tree of the
    /// same pose; the planner's state is otherwise unchanged (the tree in use is still that one) but for
    /// its next choice of build, made afresh: the build in use was not chosen against the one measured
    /// now, so hysteresis does not keep it. A non-finite time or cost is not learned (report a build
    /// that could not run so), and the next `calibration` moves past `build` either way.
    pub fn calibrated(
        &mut self,
        build: impl Into<Build>,
        triangles: usize,
        seconds: f64,
        cost: f64,
    ) {
        let build = build.into();
        if let Some(i) = self.builds.iter().position(|&b| b == build) {
            self.calibrating = self.calibrating.max(i + 1);
        }
        if seconds.is_finite() && seconds >= 0.0 {
            self.costs.learn_time(build, triangles, seconds);
        }
        let Some(e) = self.exact.filter(|e| e.frames == 0 && e.sah > 0.0) else {
            return;
        };
        let unit = (self.costs.lock().quality(&self.asset, e.build)).and_then(Estimate::mean);
        if let Some(unit) = unit
            && cost.is_finite()
            && cost > 0.0
        {
            self.costs
                .learn_quality(self.asset, build, unit * cost / e.sah);
            self.rechoose = true;
        }
    }

    /// Re-anchors the reference to a fresh tree of `build` at `sah_cost` and learns the build's quality
    /// where this asset had not measured it.
    fn anchor(&mut self, build: Build, sah_cost: f64) {
        let known = (self.costs.lock())
            .quality(&self.asset, build)
            .and_then(Estimate::mean);
        let old = self.reference;
        match known {
            Some(rel) if rel > 0.0 => {
                self.reference = sah_cost / rel;
                let assumed = std::mem::replace(&mut self.assumed, false);
                if old > 0.0 && self.frames > 0 && !assumed {
                    let k = self.frames as f64;
                    let x = (self.reference / (old * self.drawn_in)).ln();
                    let trend = (self.costs.lock().drift.get(&self.asset)).and_then(Estimate::mean);
                    self.costs.learn_drift(self.asset, x / k);
                    // The deviation from the trend known before (without one, the sample would be the
                    // whole drift): between two binned-SAH trees the walk's alone; across an inexact
                    // anchor, the walk's and that anchor's error, a bound of the walk.
                    if let Some(trend) = trend {
                        let sample = (x - trend * k).powi(2) / k;
                        if self.current.is_some_and(|b| is_sah(&b)) && is_sah(&build) {
                            self.costs.learn_walk(self.asset, sample);
                        }
                        self.costs.learn_walk_bound(self.asset, sample);
                    }
                }
            }
            _ => {
                // Unmeasured: compare with the last binned-SAH tree carried forward as the guard did
                // (an exact anchor, off only by the walk, trend and spread since, which err towards an
                // earlier guard: an explosion's fresh cost falls fast); without one, with where the guard
                // assumed the reference had fallen to (an error then makes this build look worse and the
                // guard earlier, never later), or start the unit here. No drift is learned from an
                // assumption.
                let exact = self.exact.filter(|_| old > 0.0).and_then(|e| {
                    let t = self.costs.lock();
                    let unit = t.quality(&self.asset, e.build)?.mean()?;
                    Some(e.sah * e.carried / unit)
                });
                let now = match exact {
                    Some(unit) => unit,
                    None if old > 0.0 => old * self.guard_factor,
                    None => sah_cost,
                };
                self.costs.learn_quality(self.asset, build, sah_cost / now);
                self.assumed = old > 0.0 && exact.is_none();
                self.reference = now;
            }
        }
    }

    /// Records a frame's queries: rays cast (fractional where a caller apportions a batch over meshes), the
    /// tree's SAH cost and the measured seconds.
    pub fn queried(&mut self, rays: f64, sah_cost: f64, seconds: f64) {
        if rays > 0.0 && sah_cost > 0.0 && seconds.is_finite() && seconds >= 0.0 {
            self.costs
                .lock()
                .query_rate
                .add(seconds / (rays * sah_cost));
            self.query_model.add(sah_cost, seconds / rays);
            self.rays.add(rays);
        }
    }

    /// After a refit to `cost` (an SAH cost, or a [`TreeCost`] with the root's area), with `rays` rays
    /// expected this frame: true to rebuild now
    /// (with [`next_build`](Self::next_build)), before this frame's queries; the grounds are in
    /// [`prediction`](Self::prediction).
    pub fn after_refit(&mut self, cost: impl Into<TreeCost>, rays: f64) -> bool {
        let TreeCost {
            sah: sah_cost,
            root_area,
        } = cost.into();
        // A scene that spread out since the rebuild may have a cheaper fresh tree: as the scene's
        // extent grows by a factor, every box but the root's can shrink relative to it by as much. But a
        // motion that kept the refitted tree's cost (a uniform scaling, a rigid motion) kept the
        // fresh tree's too: the fall is assumed no larger than the refitted cost's relative change.
        let spread_out = |area: Option<f64>, sah: f64| {
            let moved = 1.0 / (1.0 + (sah_cost / sah.max(f64::MIN_POSITIVE) - 1.0).abs());
            match (area, root_area) {
                (Some(then), Some(now)) if now > 0.0 => (then / now).min(1.0).max(moved),
                _ => 1.0,
            }
        };
        self.next_frame();
        let t = self.costs.lock();
        let v = self.view(&t);
        let (build, _) = v.plan(true);
        let (rebuild_s, rebuild_spread) = v.time(build).unwrap_or((0.0, 0.0));
        let mut p = Prediction {
            verdict: Verdict::Keep,
            build,
            rebuild_s,
            rent_s: 0.0,
            margin_s: 0.0,
            sah: sah_cost,
            fresh_sah: 0.0,
        };
        let mut work = self.work;
        let mut ratio = f64::NAN;
        let mut guard_factor = 1.0;
        let drawn = drawn_in(self.area_built, root_area, self.sah_built, sah_cost);
        // The fresh cost were the last rebuild's tree exactly of its build's mean quality.
        let mut unerring = 0.0;
        let mut exact_carried = 1.0;
        if self.reference > 0.0 {
            if let Some(sah) = v.fresh_sah_relative() {
                let carried = drawn
                    * v.guard_drift(self.frames)
                        .min(spread_out(self.area_built, self.sah_built));
                guard_factor = carried * v.anchor_factor(self.current);
                p.fresh_sah = self.reference * sah * guard_factor;
                unerring = self.reference * sah * carried;
                // The last binned-SAH tree, carried forward, bounds the fresh cost too: it has no
                // anchor error, only the walk and trend since.
                // (Its tree is not the one refitted now, so no fall is ruled out by how little the
                // refitted tree's cost moved: the root's area alone bounds it.)
                if let Some(e) = self.exact {
                    let spread = match (e.area, root_area) {
                        (Some(then), Some(now)) if now > 0.0 => (then / now).min(1.0),
                        _ => 1.0,
                    };
                    let carried = v.guard_drift(e.frames).min(spread);
                    p.fresh_sah = p.fresh_sah.max(e.sah * carried);
                    unerring = unerring.max(e.sah * carried);
                    exact_carried = carried;
                }
                ratio = sah_cost / p.fresh_sah;
            }
            let rate = v.rate();
            let rate_relative = v.rate_relative_spread();
            let fresh = v.relative(build).map_or(0.0, |r| {
                self.reference * r.0 * v.mean_drift(self.frames) * drawn
            });
            work.add(rays.max(0.0), sah_cost, fresh);
            p.rent_s = rate * work.excess;
            // The rent's spread: the rate's error as measured (relative, so that it scales the rent)
            // and the anchor's, which shifts the fresh cost of every frame since the rebuild alike.
            let anchor = v.rent_anchor_error(build);
            p.margin_s = self.z
                * rebuild_spread
                    .hypot(rate_relative * p.rent_s)
                    .hypot(rate * anchor * work.fresh);
            // The ratio extrapolated one frame: the tree's cost at this frame's rise, the fresh cost
            // carried one frame further. (Not the ratio at its own rise: after a rebuild that holds
            // the guard's whole one-frame margin, which grows by far less in the frames after, and
            // the soup of the report was rebuilt four frames running on it, issue 19.)
            let rise = (sah_cost - self.last_sah).max(0.0);
            let ahead = if rise.is_finite() && sah_cost > 0.0 {
                1.0 + rise / sah_cost
            } else {
                1.0
            } * v.guard_drift(self.frames)
                / v.guard_drift(self.frames + 1);
            p.verdict = if p.fresh_sah > 0.0 && ratio * ahead > v.guard_at() {
                // Due only for the anchor's error (not were the last tree of its build's mean
                // quality): a binned-SAH tree, exact, ends that error where one is offered and pays.
                if sah_cost / unerring * ahead <= v.guard_at()
                    && let Some(&b) = self.builds.iter().find(|b| is_sah(b))
                    && v.exact_anchor_pays(b, build)
                {
                    p.build = b;
                    p.rebuild_s = v.time(b).map_or(0.0, |t| t.0);
                }
                Verdict::Guard
            } else if p.rent_s > 0.0 && pays(p.rent_s, rebuild_s, p.margin_s / self.z, self.z) {
                Verdict::Rent
            } else {
                // With no rays a build is tried only where the guard rebuilds anyway.
                match (rays > 0.0).then(|| v.plan(false)) {
                    Some((b, true)) => {
                        p.build = b;
                        p.rebuild_s = v.time(b).map_or(0.0, |t| t.0);
                        Verdict::Explore
                    }
                    _ => Verdict::Keep,
                }
            };
        }
        drop(t);
        self.pace.refitted(
            (p.verdict == Verdict::Guard && self.frames == 1).then_some(ratio),
            self.sah_bound,
        );
        if let Some(e) = &mut self.exact {
            e.carried = exact_carried;
        }
        self.guard_factor = guard_factor;
        self.drawn_in = drawn;
        self.work = work;
        self.last_sah = sah_cost;
        self.last = p;
        p.verdict != Verdict::Keep
    }

    /// Counts a frame since the last rebuild and the last binned-SAH tree.
    fn next_frame(&mut self) {
        self.frames += 1;
        self.age = self.age.saturating_add(1);
        if let Some(e) = &mut self.exact {
            e.frames += 1;
        }
    }

    /// Ask before refitting: true to rebuild this frame without refitting (with
    /// [`prediction`](Self::prediction)'s build, reported with [`built`](Self::built) as any rebuild;
    /// the verdict is [`Verdict::Outpaced`]), false to refit and ask [`after_refit`](Self::after_refit).
    ///
    /// True while the guard's last refits each came one frame after a rebuild and passed the bound, and
    /// the trend of that one-frame ratio over those frames stays above the bound for twice the frames
    /// skipped: an explosion whose trees do not survive a frame pays for its refits only now and then
    /// (at most one frame in [`PACE_MEASURE`]), to see whether the motion has slowed. A wrong skip costs a
    /// rebuild where a refit would have been kept, never the bound (a fresh tree is its own best). O(1).
    pub fn outpaced(&mut self) -> bool {
        if !self.pace.skip() {
            return false;
        }
        self.next_frame();
        let t = self.costs.lock();
        let v = self.view(&t);
        let (build, _) = v.plan(true);
        self.last = Prediction {
            verdict: Verdict::Outpaced,
            build,
            rebuild_s: v.time(build).map_or(0.0, |t| t.0),
            sah: f64::NAN,
            ..Prediction::default()
        };
        true
    }

    /// What [`outpaced`](Self::outpaced) will answer when asked next, without asking (no frame is
    /// counted): for running refits ahead of the question. O(1).
    pub(crate) fn skips_next_refit(&self) -> bool {
        self.pace.left > 0
    }

    /// After an [`after_refit`](Self::after_refit) whose verdict is [`Verdict::Rent`], weighs rebuilding
    /// only the degraded subtrees instead: a partial rebuild of `triangles` triangles
    /// ([`Bvh::degraded_primitives`]) is ranked against the full rebuild with [`choose`], the full one as
    /// the option in use, so the partial one must be cheaper beyond the margin. If it is, the verdict
    /// becomes [`Verdict::Partial`] (its predicted seconds in the [`prediction`](Self::prediction)) and
    /// the answer is true; report it with [`partially_rebuilt`](Self::partially_rebuilt). After any other
    /// verdict the answer is false: the guard always rebuilds the whole tree (a partial rebuild leaves the
    /// nodes above the rebuilt subtrees as refitted), and a kept tree needs no count. So ask only after a
    /// `Rent` verdict: counting the triangles is a pass over the nodes, cheap beside the rebuild due in
    /// that frame and wasted in any other. Its time is predicted from partial rebuilds measured on this
    /// mesh, else from the binned-SAH build rate at `triangles` (what a partial rebuild mostly is), with
    /// the prior's spread. O(1).
    pub fn prefer_partial(&mut self, triangles: usize) -> bool {
        if self.last.verdict != Verdict::Rent || triangles == 0 || triangles >= self.triangles {
            return false;
        }
        let t = self.costs.lock();
        let v = self.view(&t);
        let (Some((partial_s, partial_spread)), Some((full_s, full_spread))) =
            (v.partial_time(triangles), v.time(self.last.build))
        else {
            return false;
        };
        let full = Candidate {
            option: Update::Full,
            cost_s: full_s,
            spread_s: full_spread,
        };
        let partial = Candidate {
            option: Update::Partial,
            cost_s: partial_s,
            spread_s: partial_spread,
        };
        if choose([full, partial].into_iter(), Some(Update::Full), self.z) != Some(Update::Partial)
        {
            return false;
        }
        self.last.rebuild_s = partial_s;
        self.last.verdict = Verdict::Partial;
        true
    }

    /// Records a partial rebuild of `triangles` triangles that took `seconds` (the whole call, refit
    /// excluded) and left a tree of SAH cost `sah_cost`: learns its rate and restarts the rent, as a
    /// rebuild does; the guard's reference (the last full rebuild's) is kept.
    pub fn partially_rebuilt(&mut self, triangles: usize, seconds: f64, sah_cost: f64) {
        if triangles > 0 && seconds.is_finite() && seconds >= 0.0 {
            self.partial_rate
                .add(seconds / super::costs::size_unit(triangles));
        }
        if sah_cost.is_finite() && sah_cost > 0.0 {
            self.sah_built = sah_cost;
            self.last_sah = sah_cost;
        }
        self.work = RentWork::default();
    }

    /// Why the last [`after_refit`](Self::after_refit) decided as it did (the default before any).
    pub fn prediction(&self) -> Prediction {
        self.last
    }

    /// Predicted seconds of a rebuild with `build` at this mesh's size (0 before any build time was
    /// measured in the table).
    pub fn predicted_rebuild(&self, build: impl Into<Build>) -> f64 {
        let t = self.costs.lock();
        self.view(&t).time(build.into()).map_or(0.0, |t| t.0)
    }

    fn view<'a>(&'a self, tables: &'a Tables) -> View<'a> {
        View { t: tables, p: self }
    }
}

/// Whether `b` builds binned-SAH trees: the trees the bound is stated against, so an anchor on one is
/// exact.
fn is_sah(b: &Build) -> bool {
    matches!(b.builder, Builder::Sah { .. })
}

/// How many of the last tree (built with `last`, if any) and a tree of `next` are inexact anchors of
/// the fresh binned-SAH cost: those not built by binned SAH.
fn inexact(last: Option<Build>, next: Build) -> usize {
    [last, Some(next)]
        .iter()
        .filter(|b| !b.is_some_and(|b| is_sah(&b)))
        .count()
}

/// The last binned-SAH tree built on a mesh: the fresh cost the bound is stated against, measured, not
/// inferred from a build's mean quality. A rebuild with another build moves the guard's reference to that
/// build's tree (with its anchor error); this one is kept beside it, carried forward by the trend and
/// walk alone, and the guard takes the higher of the two fresh costs, as both are lower bounds at `z`.
/// It also measures a build tried for the first time (its quality against this tree carried at the
/// mean drift) rather than against the guard's conservative reference.
#[derive(Clone, Copy, Debug)]
struct Exact {
    /// The binned-SAH build that made it.
    build: Build,
    /// Its SAH cost.
    sah: f64,
    /// Its root's half area, if told.
    area: Option<f64>,
    /// Frames since it was built.
    frames: u32,
    /// The factor the guard last carried its cost forward by (trend, walk and spread).
    carried: f64,
}

/// The factor by which a fresh tree's cost is expected to have risen because the scene drew in since
/// the rebuild: the root's half area then over now, no more than the refitted tree's cost rose
/// (`sah_now / sah_then`), and 1 where the scene did not draw in or that cost did not rise. As the
/// extent shrinks by a factor, a tree's boxes keep their areas while the root's shrinks: two bodies
/// closing in (the report's rigid scene) raise every tree's cost, the fresh one's too (by 1.35 where
/// the root's area fell by 1.39), and a guard that held the fresh cost where it was rebuilt at a
/// ratio of 1.48 against a true 1.08. A uniform scaling keeps every cost, and the refitted cost's
/// rise caps the factor at 1 there. What the fresh tree's own boxes did besides (the bodies' boxes
/// closing in shrink the top nodes) is drift, learned around this factor
/// ([`AdaptivePolicy::anchor`]) and allowed for by the guard as any drift. O(1).
fn drawn_in(area_then: Option<f64>, area_now: Option<f64>, sah_then: f64, sah_now: f64) -> f64 {
    match (area_then, area_now) {
        (Some(then), Some(now)) if now > 0.0 && sah_then > 0.0 => {
            (then / now).min(sah_now / sah_then).max(1.0)
        }
        _ => 1.0,
    }
}

/// At most one frame in this many refits while the motion outpaces refitting
/// ([`AdaptivePolicy::outpaced`]): a refit measured every 8 rebuilds adds an eighth of a refit to each
/// rebuild frame (a refit is about a third of an LBVH build: 4% of a frame's update), and a motion that
/// slows is seen within 8 frames.
pub const PACE_MEASURE: u32 = 8;

/// The one-frame ratios the guard rebuilt at ([`AdaptivePolicy::outpaced`]): the last two measured and
/// the frames between them, and the frames left to rebuild without refitting.
#[derive(Clone, Copy, Debug, Default)]
struct Pace {
    /// The last one-frame ratio, the one before it and the frames from that one to the last (0 while
    /// fewer than two were measured in a row).
    last: f64,
    before: f64,
    gap: u32,
    /// Frames since the last measurement.
    since: u32,
    /// Frames still to rebuild without refitting.
    left: u32,
}

impl Pace {
    /// A refit's verdict: `Some(ratio)` where the guard rebuilt a tree one frame old at that ratio, else
    /// `None` (the run of such frames is over). Plans the frames to skip: with two ratios measured, the
    /// frames until their trend (a geometric fall per frame; none if they rose) reaches `bound`, halved,
    /// at most [`PACE_MEASURE`] − 1.
    fn refitted(&mut self, guarded: Option<f64>, bound: f64) {
        let Some(r) = guarded.filter(|r| r.is_finite() && *r > bound) else {
            *self = Pace::default();
            return;
        };
        if self.last > 0.0 {
            (self.before, self.gap) = (self.last, self.since + 1);
        }
        (self.last, self.since, self.left) = (r, 0, 0);
        if self.gap == 0 {
            return;
        }
        let fall = (self.last / self.before).ln() / f64::from(self.gap);
        let frames = if fall < 0.0 {
            (self.last / bound).ln() / -fall / 2.0
        } else {
            f64::INFINITY
        };
        self.left = frames.min(f64::from(PACE_MEASURE - 1)) as u32;
    }

    /// Whether to skip this frame's refit (and count it): exactly while `left` is above 0, which
    /// [`AdaptivePolicy::skips_next_refit`] reads.
    fn skip(&mut self) -> bool {
        if self.left == 0 {
            return false;
        }
        self.left -= 1;
        self.since += 1;
        true
    }
}

/// What the rent has summed since the last rebuild (or partial rebuild), in ray × SAH units, priced in
/// seconds at the current marginal rate each frame, so that when the rate is revised (the mesh's frames
/// show query time following the SAH cost less than assumed) the whole rent is, not only the frames
/// still to come.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct RentWork {
    /// Rays times the SAH cost the refitted tree had above a fresh tree's: the rent.
    excess: f64,
    /// Rays times the fresh tree's cost: what an error of the anchor that fresh cost is predicted from
    /// (a relative error, the same in every frame since the rebuild) shifts the excess by, per unit.
    fresh: f64,
}

impl RentWork {
    /// Adds a frame of `rays` rays on a tree of SAH cost `sah` whose fresh tree is predicted at `fresh`.
    fn add(&mut self, rays: f64, sah: f64, fresh: f64) {
        self.excess += rays * (sah - fresh).max(0.0);
        self.fresh += rays * fresh;
    }
}

/// The error of the anchor the guard predicts the fresh binned-SAH cost from. After a rebuild with
/// LBVH or hybrid the fresh cost is inferred from that build's *mean* quality on the asset, but a single
/// tree is better or worse than the mean (one LBVH tree over orbiting rigid bodies sits anywhere from
/// 1.0 to 1.38 × binned SAH), so the inferred fresh cost can be too high and the ratio too low. Every
/// rebuild whose build's quality was measured tests the prediction: the tree's cost against the cost
/// predicted for a tree of that build (the reference carried forward at the mean drift, times the
/// build's mean quality). `e = ln(actual / predicted)` holds the new tree's deviation from its mean, the
/// previous anchor's deviation and the drift's error. The drift's random walk over the interval
/// (`frames · spread²`, which the guard's drift factor allows for apart) is subtracted from `e²`, and no
/// error is learned before the asset's drift is (the first interval's error *is* the drift). Under the
/// assumption that the trees' deviations are independent, zero-mean and alike from one rebuild to the
/// next, `E[e²] − walk ≥ 2σ² ≥ σ²` of a single tree. The guard multiplies the fresh cost by
/// `exp(−z · rms)` (RMS: a bias below the prediction counts as error too), so the bound holds while a tree deviates from its
/// build's mean by less than `z` RMS. Cost: a few operations per rebuild; no build is added.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct AnchorError {
    /// The running mean of `e²`.
    squares: Estimate,
}

impl AnchorError {
    /// Learns one rebuild: its tree's SAH cost, the cost predicted for it (both positive), the
    /// variance of `ln` of the fresh cost that the drift's walk explains over the interval (the guard
    /// allows for that apart) and the inexact anchors the error holds (1 or 2: the previous tree and
    /// this one, less any binned-SAH tree, which is exact): the sample is
    /// `max(0, 2 · min(e, 0)² − walk) / anchors`. Only a tree *better* than predicted (`e < 0`) counts,
    /// twice (the lower semivariance of a symmetric error is half its variance): it is the error that
    /// makes the guard late, while a tree worse than predicted makes it early. A decelerating scene's
    /// trend lags its motion, and its trees all land above the prediction: counted as anchor error,
    /// that lag (RMS 0.127 on the quick report's explosion) ruled LBVH out of the bound's room, and the
    /// planner rebuilt with binned SAH at 3× LBVH's time on every frame (issue 19).
    fn learn(&mut self, actual: f64, predicted: f64, walk: f64, anchors: f64) {
        if actual > 0.0 && predicted > 0.0 {
            let below = (actual / predicted).ln().min(0.0);
            self.squares
                .add((2.0 * below.powi(2) - walk).max(0.0) / anchors);
        }
    }

    /// The root mean square of `e`, with the prior: `√((ν₀·σ₀² + n·mean(e²)) / (ν₀ + n))`, `σ₀` =
    /// [`ANCHOR_PRIOR`] worth `ν₀` = [`ANCHOR_PRIOR_WEIGHT`] samples, `n` the samples the mean of `e²`
    /// is worth ([`Estimate::effective_samples`]). This is the posterior mean of the variance under a
    /// scaled inverse-χ² prior: with no sample it is the prior, and it moves to the measured RMS as
    /// samples come, so one or two lucky rebuilds cannot talk it down to zero.
    fn rms(&self) -> f64 {
        let n = self.squares.effective_samples();
        let sum = n * self.squares.mean().unwrap_or(0.0).max(0.0);
        ((ANCHOR_PRIOR_WEIGHT * ANCHOR_PRIOR.powi(2) + sum) / (ANCHOR_PRIOR_WEIGHT + n)).sqrt()
    }

    /// The root mean square of `e` as measured, without the prior: 0 before any rebuild tested a
    /// prediction. The rent's margin uses it (the prior is the guard's caution, the rent's is what was
    /// seen: a prior that held the rent back would keep the rebuilds that measure it from coming).
    fn measured(&self) -> f64 {
        self.squares.mean().unwrap_or(0.0).max(0.0).sqrt()
    }

    /// The factor a fresh cost anchored on an average-quality tree is multiplied by so that it is
    /// `z` RMS errors low: `exp(−z · rms)`.
    fn factor(&self, z: f64) -> f64 {
        (-z * self.rms()).exp()
    }
}

/// The policy's predictions, read from the table under one lock.
struct View<'a> {
    t: &'a Tables,
    p: &'a AdaptivePolicy,
}

/// The log spread of one tree's SAH cost around its build's mean that [`AnchorError`] assumes before it
/// has measured any: 0.08, the widest over the report's scenes at 1,000 and 4,000 triangles (LBVH and
/// hybrid over the orbiting rigid bodies, whose quality also trends from 1.14 to 1.37 × binned SAH in 20
/// frames; the other scenes 0.004–0.04).
const ANCHOR_PRIOR: f64 = 0.08;

/// The weight of [`ANCHOR_PRIOR`] in samples: two, so that the first two measured errors halve its
/// say and a scene whose trees sit close to their mean reaches its own spread within a few rebuilds.
const ANCHOR_PRIOR_WEIGHT: f64 = 2.0;

/// Relative spread of a prediction made from a prior rather than a measurement.
const PRIOR_SPREAD: f64 = 0.25;

/// The least spread of the per-frame drift of `ln` of a fresh tree's cost the guard assumes: 0.1% a
/// frame, so a fresh cost predicted `k` frames ahead carries at least `z · 0.1% · k` of margin (the
/// report's rigid bodies drift about that much around a mean of 0).
const MIN_DRIFT_SPREAD: f64 = 0.001;

impl View<'_> {
    /// Predicted seconds of `b` at this mesh's size, and their standard deviation: measured, or scaled by
    /// the prior time ratio from another measured build.
    fn time(&self, b: Build) -> Option<(f64, f64)> {
        let unit = super::costs::size_unit(self.p.triangles);
        if let Some(e) = self.t.time(b)
            && let Some(m) = e.mean()
        {
            return Some((m * unit, e.spread() * unit));
        }
        let (m, k) = self
            .t
            .time
            .iter()
            .find_map(|(m, e)| Some((*m, e.mean()?)))?;
        let s = k * unit * b.prior_time() / m.prior_time();
        Some((s, PRIOR_SPREAD * s))
    }

    /// Predicted seconds of a partial rebuild of `k` triangles and their spread: this mesh's measured rate,
    /// else binned SAH's time scaled from this mesh's size to `k` (spread of a prior).
    fn partial_time(&self, k: usize) -> Option<(f64, f64)> {
        let unit = super::costs::size_unit(k);
        if let Some(m) = self.p.partial_rate.mean() {
            return Some((m * unit, self.p.partial_rate.spread() * unit));
        }
        let (s, _) = self.time(Build::cpu(Builder::SAH))?;
        let s = s * unit / super::costs::size_unit(self.p.triangles);
        Some((s, PRIOR_SPREAD * s))
    }

    /// The relative SAH cost of `b`'s trees on this asset, its spread, and whether it was measured.
    fn relative(&self, b: Build) -> Option<(f64, f64, bool)> {
        if let Some(e) = self.t.quality(&self.p.asset, b)
            && let Some(m) = e.mean()
        {
            return Some((m, e.spread(), true));
        }
        let c = self.p.clustered;
        let (m, rel) = self
            .t
            .quality
            .get(&self.p.asset)?
            .iter()
            .find_map(|(m, e)| Some((*m, e.mean()?)))?;
        let r = rel * b.prior_quality(c) / m.prior_quality(c);
        Some((r, PRIOR_SPREAD * r, false))
    }

    /// The relative SAH cost of a fresh binned-SAH tree on this asset: measured when any mesh of the
    /// asset built one, else the lowest that the measured builds' priors imply.
    fn fresh_sah_relative(&self) -> Option<f64> {
        self.fresh_sah().map(|f| f.0)
    }

    /// [`fresh_sah_relative`](Self::fresh_sah_relative), and whether it was measured (else it rests on
    /// the priors).
    fn fresh_sah(&self) -> Option<(f64, bool)> {
        let list = self.t.quality.get(&self.p.asset)?;
        let c = self.p.clustered;
        let sah = list
            .iter()
            .filter(|(b, _)| matches!(b.builder, Builder::Sah { .. }))
            .find_map(|(_, e)| Some((e.mean()?, true)));
        sah.or_else(|| {
            list.iter()
                .filter_map(|(b, e)| Some((e.mean()? / b.prior_quality(c), false)))
                .min_by(|a, b| a.0.total_cmp(&b.0))
        })
    }

    /// The ratio at which the guard rebuilds: the bound; or while the fresh binned-SAH cost rests on the
    /// priors and a binned-SAH build is offered, the bound over one prior spread (1.5 / 1.25 = 1.2), so
    /// that the prior's error cannot carry the tree past the bound before that rebuild measures a
    /// binned-SAH tree. Without a binned-SAH build to measure with, the bound rests on the priors.
    fn guard_at(&self) -> f64 {
        let sah_offered = (self.p.builds.iter()).any(|b| matches!(b.builder, Builder::Sah { .. }));
        match self.fresh_sah() {
            Some((_, false)) if sah_offered => self.p.sah_bound / (1.0 + PRIOR_SPREAD),
            _ => self.p.sah_bound,
        }
    }

    /// The factor by which a fresh tree's cost may have fallen `frames` frames after the last rebuild:
    /// at the asset's learned drift *magnitude* plus `z` spreads, the spread at least
    /// [`MIN_DRIFT_SPREAD`]. The sign of the trend is not trusted: a scene whose fresh cost rose for a
    /// few intervals can turn (the report's orbiting rigid bodies rise by 2% a frame, then fall by 1.7%),
    /// and a guard that carried the rise forward would pass the bound. A rise only makes the guard
    /// earlier, so assuming a fall as fast as any motion seen costs early rebuilds, never the bound.
    fn guard_drift(&self, frames: u32) -> f64 {
        let trend = (self.t.drift.get(&self.p.asset))
            .and_then(Estimate::mean)
            .unwrap_or(0.0);
        let k = frames as f64;
        (-(trend.abs() * k + self.p.z * (k * self.walk_var()).sqrt())).exp()
    }

    /// The variance per frame of the random walk of `ln` of the fresh cost around its trend: learned
    /// between binned-SAH trees, capped by its bound learned from every interval, at least
    /// [`MIN_DRIFT_SPREAD`]². Both forget old samples, but only the bound is fed by the rebuilds a fast
    /// scene keeps making with a cheaper builder: a walk of 0.073 a frame learned while the report's
    /// explosion slowed from falling 48% a frame to 1% kept the guard's one-frame factor at 0.58, and
    /// it rebuilt all 300 frames (issue 19). The bound is not a walk where none was learned: it holds
    /// the anchors' errors too, and LBVH trees 5% off their build's mean, taken for walk, made the
    /// guard rebuild 7 times in 300 frames where the tree stayed below the bound.
    fn walk_var(&self) -> f64 {
        let learned = |m: &std::collections::HashMap<Asset, Estimate>| {
            m.get(&self.p.asset).and_then(Estimate::mean)
        };
        let walk =
            learned(&self.t.walk).map(|w| learned(&self.t.walk_bound).map_or(w, |b| w.min(b)));
        walk.unwrap_or(0.0).max(MIN_DRIFT_SPREAD.powi(2))
    }

    /// The factor by which the fresh cost anchored at the last rebuild may be too high because that tree
    /// was better or worse than its build's mean: 1 after a binned-SAH rebuild (that tree *is* the fresh
    /// binned-SAH tree of its frame, so the anchor is exact), else [`AnchorError::factor`] at `z`;
    /// `built` is the build of that rebuild. 1 too while the fresh binned-SAH cost rests on the priors
    /// (no binned-SAH tree measured on the asset): the bound then rests on the priors, whose error
    /// (25%) is not a tree's deviation from a measured mean.
    fn anchor_factor(&self, built: Option<Build>) -> f64 {
        match (built, self.fresh_sah()) {
            (Some(b), _) if matches!(b.builder, Builder::Sah { .. }) => 1.0,
            (_, Some((_, true))) => self.p.anchor_error.factor(self.p.z),
            _ => 1.0,
        }
    }

    /// The factor by which a fresh tree's cost is expected to have changed `frames` frames after the last
    /// rebuild, at the asset's mean drift (1 before any was learned): what the rent is charged against.
    fn mean_drift(&self, frames: u32) -> f64 {
        let mean = self.t.drift.get(&self.p.asset).and_then(Estimate::mean);
        (mean.unwrap_or(0.0) * frames as f64).exp()
    }

    /// The query seconds per ray that one more unit of SAH cost adds (0 before any query was measured):
    /// this mesh's fitted slope ([`QueryModel::marginal`]) with the table's proportional rate as its
    /// prior. Its spread is [`rate_relative_spread`](Self::rate_relative_spread)'s.
    fn rate(&self) -> f64 {
        (self.p.query_model)
            .marginal(proportional(&self.t.query_rate))
            .0
    }

    /// The relative standard deviation of the rent's marginal rate, as measured: the spread of the mean
    /// of the table's measured query rates over that mean. Not the spread of the marginal
    /// fit ([`QueryModel::marginal`]), which takes its prior as uncertain by its whole value: where the
    /// tree's cost varies too little for the slope to show through the timing noise, that spread
    /// reaches the rate itself, and a margin of `z` times it grows as fast as the rent, so no rebuild
    /// ever comes due (issue 19: a churning corner's rent reached 6× the rebuild's cost while its
    /// margin grew to 3× the rent).
    fn rate_relative_spread(&self) -> f64 {
        let (mean, spread) = proportional(&self.t.query_rate);
        if mean > 0.0 { spread / mean } else { 0.0 }
    }

    /// The log error of the fresh cost the rent charges a rebuild with `b` against: the measured
    /// [`AnchorError`] of each inexact anchor of the two (the last tree and the tree `b` would build;
    /// a binned-SAH tree is exact). The guard's random walk of the fresh cost is not in it: the rent is
    /// measured against the anchor at the mean drift, and the walk bounds the guard's worst case, not
    /// the rent's error (its spread grows with the frames, and summed into the rent's margin it outgrew
    /// the rent).
    fn rent_anchor_error(&self, b: Build) -> f64 {
        self.p.anchor_error.measured() * (inexact(self.p.current, b) as f64).sqrt()
    }

    /// `b` as a candidate: its rebuild spread over the interval between rebuilds plus the queries of a
    /// frame on its fresh tree.
    fn candidate(&self, b: Build) -> Option<(Candidate<Build>, bool)> {
        self.candidate_over(b, self.p.interval.mean().unwrap_or(1.0))
    }

    /// [`candidate`](Self::candidate) with its rebuild spread over `interval` frames.
    fn candidate_over(&self, b: Build, interval: f64) -> Option<(Candidate<Build>, bool)> {
        let (time, time_spread) = self.time(b).unwrap_or((0.0, 0.0));
        let (rel, rel_spread, measured) = self.relative(b)?;
        let interval = interval.max(1.0);
        let per_rel = self.rate() * self.p.rays.mean().unwrap_or(0.0) * self.p.reference;
        Some((
            Candidate {
                option: b,
                cost_s: time / interval + per_rel * rel,
                spread_s: (time_spread / interval).hypot(per_rel * rel_spread),
            },
            measured,
        ))
    }

    /// Whether a rebuild due only for the anchor's error should end that error with the binned-SAH
    /// build `sah` rather than rebuild with `planned`: each priced as a [`candidate`](Self::candidate)
    /// over the frames that followed its kind of anchor on this mesh, an exact anchor lasting longer
    /// (the guard has no anchor error to allow for). Where an inexact anchor brings the guard back
    /// within a frame or two, binned SAH pays (the report's soup: its guard rebuilt every 1.3 frames
    /// with LBVH, binned-SAH trees lasted 12–57); where the motion brings it back as soon (the quick
    /// explosion: binned SAH lasted 3–6 frames at three times LBVH's time), the planned build does.
    /// Binned SAH until both kinds of interval were seen. O(1).
    fn exact_anchor_pays(&self, sah: Build, planned: Build) -> bool {
        let (Some(exact), Some(inexact)) = (self.p.after_exact.mean(), self.p.after_inexact.mean())
        else {
            return true;
        };
        match (
            self.candidate_over(sah, exact),
            self.candidate_over(planned, inexact),
        ) {
            (Some((s, _)), Some((p, _))) => s.cost_s <= p.cost_s,
            _ => true,
        }
    }

    /// Whether a fresh tree of `b` leaves room under the bound: its ratio to a fresh SAH tree, as the
    /// guard will see it after a rebuild with `b` (its anchor error included), at most 90% of the way
    /// from 1 to the bound (else the guard would rebuild it at once, every frame, and a tree worse than
    /// its build's mean would answer the frame it is built on above the bound).
    fn within_bound(&self, b: Build) -> bool {
        match (self.relative(b), self.fresh_sah_relative()) {
            (Some((rel, ..)), Some(sah)) => {
                rel / sah / self.anchor_factor(Some(b)) <= 1.0 + 0.9 * (self.p.sah_bound - 1.0)
            }
            _ => true,
        }
    }

    /// The build to use, and whether it is an exploration. `rebuilding`: a rebuild is due anyway, so
    /// trying a build costs only its extra time over the chosen one's; otherwise its whole time.
    fn plan(&self, rebuilding: bool) -> (Build, bool) {
        let builds = &self.p.builds;
        let measured = builds
            .iter()
            .filter_map(|&b| self.candidate(b))
            .filter(|(c, m)| *m && self.within_bound(c.option))
            .map(|(c, _)| c);
        // Hysteresis keeps a build chosen by cost against the noise of later measurements; the build in
        // use when a calibration measured others was no such choice (binned SAH, the only build measured
        // before), and keeping it by a margin set by the new builds' single timings cost the quick
        // report's explosion a second binned-SAH rebuild at twice LBVH's time in 8 of 11 runs.
        let current = self.p.current.filter(|_| !self.p.rechoose);
        let Some(chosen) = choose(measured, current, self.p.z) else {
            // Nothing measured on this asset within the bound: the best tree measured, else the
            // cheapest by the priors.
            let best_tree = builds
                .iter()
                .filter_map(|&b| Some((b, self.relative(b).filter(|r| r.2)?.0)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            return match best_tree {
                Some((b, _)) => (b, false),
                None => (self.first_build(), false),
            };
        };
        // A planner that calibrates tries nothing on frames of its own once a binned-SAH tree anchors
        // the calibration.
        if self.p.explores
            && !(self.p.calibrates && self.p.exact.is_some())
            && let Some(b) = self.worth_trying(chosen, rebuilding)
        {
            return (b, true);
        }
        (chosen, false)
    }

    /// The first build of an asset nobody measured: binned SAH where one is offered and the bound is
    /// finite (the bound is stated against its tree, so the guard is anchored exactly from the first
    /// frame rather than on priors: LBVH over the report's rigged figure is 1.57 × binned SAH against a
    /// prior of 1.15, and with no rays no rent rebuild would come to measure SAH); else the build of
    /// least predicted (or prior) time.
    fn first_build(&self) -> Build {
        if self.p.sah_bound.is_finite()
            && let Some(&b) =
                (self.p.builds.iter()).find(|b| matches!(b.builder, Builder::Sah { .. }))
        {
            return b;
        }
        let time = |b: &Build| self.time(*b).map_or(b.prior_time(), |t| t.0);
        *self
            .p
            .builds
            .iter()
            .min_by(|a, b| time(a).total_cmp(&time(b)))
            .expect("a policy has at least one build")
    }

    /// An unmeasured build worth trying instead of `chosen`: a binned-SAH build at the first rebuild due
    /// (it measures the bound's reference once per asset), or any build that
    /// [pays](Self::pays_to_try) for what trying it costs (`rebuilding`: its time over the chosen
    /// build's, else all of it).
    fn worth_trying(&self, chosen: Build, rebuilding: bool) -> Option<Build> {
        let sah_measured = self.t.quality.get(&self.p.asset).is_some_and(|l| {
            l.iter()
                .any(|(b, _)| matches!(b.builder, Builder::Sah { .. }))
        });
        let chosen_time = self.time(chosen).map_or(0.0, |t| t.0);
        let paid = if rebuilding { chosen_time } else { 0.0 };
        self.p.builds.iter().copied().find(|&b| {
            if rebuilding && !sah_measured && matches!(b.builder, Builder::Sah { .. }) {
                return self.relative(b).is_some_and(|r| !r.2);
            }
            self.pays_to_try(chosen, b, paid)
        })
    }

    /// Whether building `b`, whose trees were not measured on this asset, may pay for itself instead
    /// of `chosen`: its expected saving per frame (from the priors, optimistic by one spread: what is
    /// unknown may be better than assumed) times the horizon exceeds its time less `paid` (what a
    /// rebuild due anyway pays). The horizon is the frames seen so far: a scene that has run for `n`
    /// frames is expected to run about `n` more. Before an interval between rebuilds was measured, the
    /// current one has lasted `frames`: a build is priced over that, not over a single frame.
    fn pays_to_try(&self, chosen: Build, b: Build, paid: f64) -> bool {
        let interval = (self.p.interval.mean()).unwrap_or(self.p.frames as f64);
        let (Some((chosen_c, _)), Some((c, false))) = (
            self.candidate_over(chosen, interval),
            self.candidate_over(b, interval),
        ) else {
            return false;
        };
        let cost = self.time(b).map_or(0.0, |t| t.0) - paid;
        (chosen_c.cost_s - (c.cost_s - c.spread_s)) * self.p.age as f64 > cost.max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adaptive::Device;

    /// 1 ms per rebuild, 1 ns per ray per unit of cost, the cost rising by 1 per frame: the rent after
    /// k frames is 1e-6 · k(k+1)/2 s, and must pass 1 ms by 2 × 0.25 ms (one build measured): first at
    /// k(k+1) > 3000, k = 55.
    fn rent_frame(p: &mut AdaptivePolicy) -> u32 {
        p.sah_bound = f64::INFINITY;
        (1..1000)
            .find(|&k| p.after_refit(10.0 + k as f64, 1000.0))
            .unwrap()
    }

    fn measured() -> AdaptivePolicy {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.built(Builder::LBVH, 1000, 1e-3, 10.0);
        for _ in 0..3 {
            p.queried(1000.0, 10.0, 1e-5);
        }
        p
    }

    #[test]
    fn rebuilds_when_the_rent_passes_the_rebuild_by_the_margin() {
        let mut p = measured();
        assert_eq!(rent_frame(&mut p), 55);
        let why = p.prediction();
        assert_eq!(why.verdict, Verdict::Rent);
        assert!((why.margin_s - 0.5e-3).abs() < 1e-12, "{why:?}");
    }

    #[test]
    fn non_finite_measurements_are_not_learned() {
        let mut p = measured();
        p.built(Builder::LBVH, 1000, f64::NAN, f64::INFINITY);
        p.queried(1000.0, f64::NAN, f64::NAN);
        assert!((p.predicted_rebuild(Builder::LBVH) - 1e-3).abs() < 1e-12);
        assert_eq!(rent_frame(&mut p), 55);
    }

    /// Against a measured binned-SAH tree of cost 10, the guard rebuilds when the ratio extrapolated one
    /// frame at the tree's last rise passes 1.5: 1.2 (+0.2), 1.34 (+0.14), 1.4 (+0.06), then 1.46 (+0.06
    /// = 1.52: rebuilt, one frame before the tree itself would cross). A first interval with the fresh cost
    /// unchanged teaches the asset a drift of 0 (before it, the guard assumes a prior drift).
    #[test]
    fn the_guard_acts_before_the_bound() {
        let mut p = AdaptivePolicy::new(&[Builder::SAH]);
        p.built(Builder::SAH, 1000, 1.0, 10.0);
        assert!(!p.after_refit(10.0, 0.0));
        p.built(Builder::SAH, 1000, 1.0, 10.0);
        for sah in [12.0, 13.4, 14.0] {
            assert!(!p.after_refit(sah, 0.0), "{:?}", p.prediction());
        }
        assert!(p.after_refit(14.6, 0.0));
        let why = p.prediction();
        assert_eq!((why.verdict, why.rent_s), (Verdict::Guard, 0.0));
        // The fresh cost carried 4 frames as a random walk of the least spread: 10 · exp(−2 · 0.001 · √4).
        assert_eq!(why.sah, 14.6);
        assert!(
            (why.fresh_sah - 10.0 * (-0.004f64).exp()).abs() < 1e-9,
            "{why:?}"
        );
    }

    /// A scene that draws in raises the fresh cost the guard holds the tree against by the root's
    /// fall in area, no more than the tree's cost rose: the tree 5% above a fresh one while the root's
    /// area falls from 100 to 60 is kept (held against the cost it was built at, it would be at 1.75),
    /// a uniform shrinking (the tree's cost unchanged) raises nothing, and a tree whose cost rose by
    /// less than the area fell raises the fresh cost by as much as the tree's.
    #[test]
    fn a_scene_drawing_in_raises_the_fresh_cost_no_more_than_the_tree() {
        let cost = |sah, area| TreeCost {
            sah,
            root_area: Some(area),
        };
        let drift = |k: f64| (-2.0 * 0.001 * k.sqrt()).exp();
        let mut p = AdaptivePolicy::new(&[Builder::SAH]);
        p.built(Builder::SAH, 1000, 1.0, cost(10.0, 100.0));
        for (k, area) in [90.0, 80.0, 70.0, 60.0].into_iter().enumerate() {
            let fresh = 10.0 * 100.0 / area;
            assert!(
                !p.after_refit(cost(1.05 * fresh, area), 0.0),
                "{:?}",
                p.prediction()
            );
            let why = p.prediction().fresh_sah;
            assert!((why - fresh * drift(k as f64 + 1.0)).abs() < 1e-9, "{why}");
        }
        for (sah, fresh) in [(10.0, 10.0), (12.0, 12.0)] {
            let mut p = AdaptivePolicy::new(&[Builder::SAH]);
            p.built(Builder::SAH, 1000, 1.0, cost(10.0, 100.0));
            p.after_refit(cost(sah, 50.0), 0.0);
            let why = p.prediction().fresh_sah;
            assert!((why - fresh * drift(1.0)).abs() < 1e-9, "{why}");
        }
    }

    /// The anchor error is the posterior RMS of `ln(actual / predicted)` under the prior (0.08 worth
    /// two samples): with no sample the prior, `exp(−2 · 0.08)` at `z` = 2; two rebuilds 20% over and
    /// 20% under their prediction give `√((2 · 0.08² + 2 · ln² 1.2) / 4)` (the one over adds a zero,
    /// the one under counts twice); many samples of `−ln 1.2` count as the nine an exponentially
    /// weighted mean is worth: `√((2 · 0.08² + 9 · 2 · ln² 1.2) / 11)`.
    #[test]
    fn the_anchor_error_is_the_posterior_rms_log_error() {
        let prior = 2.0 * 0.08f64.powi(2);
        let l2 = 1.2f64.ln().powi(2);
        let mut e = AnchorError::default();
        assert!((e.rms() - 0.08).abs() < 1e-15);
        assert!((e.factor(2.0) - (-0.16f64).exp()).abs() < 1e-15);
        e.learn(12.0, 10.0, 0.0, 1.0);
        e.learn(10.0, 12.0, 0.0, 1.0);
        e.learn(f64::NAN, 1.0, 0.0, 1.0);
        assert!((e.rms() - ((prior + 2.0 * l2) / 4.0).sqrt()).abs() < 1e-12);
        // A sample the drift's walk explains in full adds a zero: three samples summing 2 · ln² 1.2.
        let mut w = e;
        w.learn(10.0, 12.0, 1.0, 1.0);
        assert!((w.rms() - ((prior + 2.0 * l2) / 5.0).sqrt()).abs() < 1e-12);
        // Two inexact anchors share an error: each holds half of it.
        let mut two = e;
        two.learn(10.0, 12.0, 0.0, 2.0);
        assert!((two.rms() - ((prior + 3.0 * l2) / 5.0).sqrt()).abs() < 1e-12);
        let mut many = AnchorError::default();
        for _ in 0..50 {
            many.learn(10.0, 12.0, 0.0, 1.0);
        }
        assert!((many.rms() - ((prior + 18.0 * l2) / 11.0).sqrt()).abs() < 1e-12);
        assert!((many.factor(2.0) - (-2.0 * many.rms()).exp()).abs() < 1e-15);
    }

    /// The rent's margin holds the anchor error as measured, over the rays and fresh costs summed: LBVH
    /// trees at 10, 10 and `10 / 1.1` one frame apart teach a drift of 0 and then `−ln 1.1` (mean
    /// `−ln 1.1 / 2`) and one anchor error, the third tree's `2 · ln² 1.1` (below its prediction: counted
    /// twice) less the least walk over a frame (0.001²), shared by two inexact anchors. Queries at
    /// exactly 1 ns per ray per unit (no spread) and three identical build times leave nothing else in
    /// the margin: after one frame of 1000 rays, whose fresh cost is `c = 10 / 1.1 · 1.1^(−1/2)`, it is
    /// `z · 1 ns · √(2 · ln² 1.1 − 10⁻⁶) · 1000 · c`.
    #[test]
    fn the_rent_margin_holds_the_measured_anchor_error() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH]);
        p.sah_bound = f64::INFINITY;
        for sah in [10.0, 10.0, 10.0 / 1.1] {
            if p.current.is_some() {
                p.after_refit(sah, 0.0);
            }
            p.built(Builder::LBVH, 1000, 1e-3, sah);
        }
        for _ in 0..3 {
            p.queried(1000.0, 10.0, 1e-5);
        }
        assert!(!p.after_refit(13.0, 1000.0));
        let why = p.prediction();
        let fresh = 10.0 / 1.1 / 1.1f64.sqrt();
        let error = (2.0 * 1.1f64.ln().powi(2) - 1e-6).sqrt();
        let expect = 2.0 * 1e-9 * error * 1000.0 * fresh;
        assert!(
            (why.margin_s - expect).abs() < 1e-9 * expect,
            "{why:?} vs {expect}"
        );
        assert!((why.rent_s - 1e-9 * 1000.0 * (13.0 - fresh)).abs() < 1e-15);
    }

    /// LBVH rebuilds one frame apart: the second lands at 10 as predicted (its error is not learned: no
    /// drift was known, so the error would be the drift itself; a drift of 0 is learned), the third at
    /// 12 against a predicted 10 (above its prediction: no error is learned). The drift is then 0 and `ln 1.2` (mean `ln 1.2 / 2`; no walk was learned, as no
    /// interval ran between two binned-SAH trees: the least, 0.001 a frame, so a fall of
    /// `1.2^(−0.5) · e^(−0.002)` a frame), and the fresh cost rests on LBVH's prior quality (no binned-SAH
    /// tree measured), where no anchor error applies. After a binned-SAH rebuild, whose tree is the fresh
    /// one, the anchor error is not applied either.
    #[test]
    fn the_anchor_error_is_not_applied_on_priors_nor_after_binned_sah() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.built(Builder::LBVH, 1000, 1e-3, 10.0);
        p.after_refit(10.0, 0.0);
        p.built(Builder::LBVH, 1000, 1e-3, 10.0);
        p.after_refit(10.0, 0.0);
        p.built(Builder::LBVH, 1000, 1e-3, 12.0);
        p.after_refit(12.0, 0.0);
        // No binned-SAH tree measured: the fresh cost rests on the priors, and no anchor error applies.
        let prior = Build::cpu(Builder::LBVH).prior_quality(false);
        let fall = 1.2f64.powf(-0.5) * (-0.002f64).exp();
        let expect = 12.0 / prior * fall;
        let fresh = p.prediction().fresh_sah;
        assert!(
            (fresh - expect).abs() < 1e-9 * expect,
            "{fresh} vs {expect}"
        );
        // A binned-SAH tree built at 10 after one more frame anchors the fresh cost exactly: only the
        // drift factor remains.
        p.built(Builder::SAH, 1000, 1e-2, 10.0);
        p.after_refit(10.0, 0.0);
        let why = p.prediction();
        assert!((why.fresh_sah - 10.0 * fall).abs() < 1e-9, "{why:?}");
    }

    /// The walk, scripted: binned-SAH trees at 10 and then 5 one frame apart teach a trend of `−ln 2`
    /// and no walk (before a trend is known the whole fall would pass for walk); a third at
    /// `5 · e^(−ln 2 + 0.1)` one frame later deviates from that trend by 0.1: a walk of 0.01 a frame,
    /// learned from the exact anchors alone (and a first sample of its bound). LBVH trees then follow
    /// the learned trend exactly, one frame apart (the first measured against the last binned-SAH tree
    /// and learning no drift): three intervals that bound the walk at 0, so the guard's walk falls to
    /// the bound's mean of 0.01 and three zeros, 0.0025, instead of keeping the early 0.01, which no
    /// later pair of binned-SAH trees revises.
    #[test]
    fn the_walk_waits_for_a_trend_and_later_intervals_bound_it() {
        let mut p = AdaptivePolicy::new(&[Builder::SAH, Builder::LBVH]);
        p.sah_bound = f64::INFINITY;
        let walk = |p: &AdaptivePolicy| p.view(&p.costs.lock()).walk_var();
        let trend = |p: &AdaptivePolicy| {
            let t = p.costs.lock();
            t.drift.get(&p.asset).and_then(Estimate::mean).unwrap()
        };
        p.built(Builder::SAH, 1000, 1e-2, 10.0);
        p.after_refit(10.0, 0.0);
        p.built(Builder::SAH, 1000, 1e-2, 5.0);
        assert!((trend(&p) + 2f64.ln()).abs() < 1e-12);
        {
            let t = p.costs.lock();
            assert!(t.walk.is_empty() && t.walk_bound.is_empty());
        }
        assert_eq!(walk(&p), MIN_DRIFT_SPREAD.powi(2));
        p.after_refit(5.0, 0.0);
        p.built(Builder::SAH, 1000, 1e-2, 5.0 * (0.1 - 2f64.ln()).exp());
        assert!((walk(&p) - 0.01).abs() < 1e-12, "{}", walk(&p));
        // LBVH, first measured against the last binned-SAH tree, then anchored on its own trees.
        let mut cost = 20.0;
        for _ in 0..4 {
            p.after_refit(cost, 0.0);
            cost *= trend(&p).exp();
            p.built(Builder::LBVH, 1000, 1e-3, cost);
        }
        let exact = p.costs.lock().walk.get(&p.asset).and_then(Estimate::mean);
        assert!((exact.unwrap() - 0.01).abs() < 1e-12);
        assert!((walk(&p) - 0.0025).abs() < 1e-12, "{}", walk(&p));
    }

    /// LBVH builds in 1 ms to twice the SAH tree's cost; SAH builds in 100 ms. With a rebuild every frame,
    /// SAH pays off once 1e-8 · rays > 0.099 s, i.e. above 9.9 million rays per frame.
    fn choice(rays: f64) -> Build {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.sah_bound = f64::INFINITY;
        p.built(Builder::LBVH, 1000, 1e-3, 20.0);
        p.built(Builder::SAH, 1000, 0.1, 10.0);
        p.queried(rays, 10.0, 1e-8 * rays);
        p.next_build()
    }

    /// Whether an anchor-error rebuild ends with binned SAH where binned-SAH trees lasted `exact`
    /// frames and LBVH trees `inexact`: LBVH builds in 1 ms to 1.1 × the SAH tree's cost, SAH in 3 ms,
    /// and the queries of a frame on a fresh SAH tree take 1 ms. Per frame, SAH costs 3/`exact` + 1 ms
    /// and LBVH 1/`inexact` + 1.1 ms.
    fn ends_with_sah(intervals: Option<(f64, f64)>) -> bool {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.built(Builder::LBVH, 1000, 1e-3, 11.0);
        p.built(Builder::SAH, 1000, 3e-3, 10.0);
        p.queried(1e6, 10.0, 1e-3);
        if let Some((exact, inexact)) = intervals {
            p.after_exact.add(exact);
            p.after_inexact.add(inexact);
        }
        let t = p.costs.lock();
        (p.view(&t)).exact_anchor_pays(Build::cpu(Builder::SAH), Build::cpu(Builder::LBVH))
    }

    #[test]
    fn an_exact_anchor_is_bought_where_it_lasts() {
        // Nothing seen yet: binned SAH, as before intervals were learned.
        assert!(ends_with_sah(None));
        // SAH trees last 20 frames, LBVH trees 1.3: 1.15 against 1.87 ms a frame.
        assert!(ends_with_sah(Some((20.0, 1.3))));
        // Both last a frame (an explosion): 4 against 2.1 ms.
        assert!(!ends_with_sah(Some((1.0, 1.0))));
        // SAH trees last 3 frames, LBVH 1: 2 against 2.1 ms; 2 frames: 2.5 against 2.1.
        assert!(ends_with_sah(Some((3.0, 1.0))));
        assert!(!ends_with_sah(Some((2.0, 1.0))));
    }

    #[test]
    fn the_builder_follows_the_ray_load() {
        assert_eq!(choice(1e6), Build::cpu(Builder::LBVH));
        assert_eq!(choice(1e8), Build::cpu(Builder::SAH));
    }

    /// The same builder on two devices: each device's time is learned apart, and the cheaper one wins
    /// whichever it is.
    #[test]
    fn the_device_is_the_cheaper_one() {
        for (cpu_s, gpu_s, expect) in [(1e-3, 4e-3, Device::Cpu), (4e-3, 1e-3, Device::Gpu)] {
            let mut p = AdaptivePolicy::with_builds(&[Build::cpu(Builder::LBVH), Build::GPU_LBVH]);
            assert_eq!(
                p.next_build(),
                Build::cpu(Builder::LBVH),
                "equal priors: the first offered"
            );
            p.built(Builder::LBVH, 1000, cpu_s, 20.0);
            p.built(Build::GPU_LBVH, 1000, gpu_s, 20.0);
            assert_eq!(p.next_build().device, expect);
            assert_eq!(p.predicted_rebuild(Build::GPU_LBVH), gpu_s);
        }
    }

    /// The relative quality the table holds for `b` on `p`'s asset.
    fn quality(p: &AdaptivePolicy, b: Builder) -> Option<f64> {
        p.costs.lock().quality(&p.asset, Build::cpu(b))?.mean()
    }

    /// A planner that calibrates builds binned SAH at load and calibrates nothing then (a scene that
    /// never rebuilds pays for nothing more); its first due rebuild is binned SAH (the only build
    /// measured), after which it asks for LBVH and hybrid on that pose: each learned as its tree's cost
    /// over that binned-SAH tree's exactly (15 / 12 and 13 / 12, the binned-SAH unit 1), its time as
    /// measured; a build reported as not run (NaN) is skipped, not asked again. It never tries a build on
    /// a frame of its own.
    #[test]
    fn calibration_measures_each_build_on_the_pose_of_the_first_rebuild() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::HYBRID, Builder::SAH]);
        p.calibrates = true;
        assert_eq!(p.next_build(), Build::cpu(Builder::SAH));
        assert_eq!(
            p.calibrations_before(Build::cpu(Builder::SAH)),
            [],
            "not at load"
        );
        p.built(Builder::SAH, 1000, 1e-2, 10.0);
        assert_eq!(p.calibration(), None, "nothing at load");
        let mut k = 0.0;
        while !p.after_refit(10.0 + k, 1000.0) {
            assert_ne!(p.prediction().verdict, Verdict::Explore);
            p.queried(1000.0, 10.0 + k, 1e-5 * (10.0 + k));
            k += 1.0;
        }
        assert_eq!(p.prediction().build, Build::cpu(Builder::SAH));
        let (lbvh, hybrid) = (Build::cpu(Builder::LBVH), Build::cpu(Builder::HYBRID));
        assert_eq!(p.calibrations_before(lbvh), [], "only on a binned-SAH pose");
        assert_eq!(p.calibrations_before(p.prediction().build), [lbvh, hybrid]);
        p.built(Builder::SAH, 1000, 1e-2, 12.0);
        assert_eq!(p.calibration(), Some(Build::cpu(Builder::LBVH)));
        p.calibrated(Builder::LBVH, 1000, 1e-3, 15.0);
        assert_eq!(p.calibration(), Some(Build::cpu(Builder::HYBRID)));
        p.calibrated(Builder::HYBRID, 1000, f64::NAN, f64::NAN);
        assert_eq!(p.calibration(), None);
        assert_eq!(quality(&p, Builder::SAH), Some(1.0));
        assert!((quality(&p, Builder::LBVH).unwrap() - 15.0 / 12.0).abs() < 1e-12);
        assert_eq!(quality(&p, Builder::HYBRID), None);
        assert!((p.predicted_rebuild(Builder::LBVH) - 1e-3).abs() < 1e-15);
        // Hybrid, reported as not run, stays unmeasured: the calibration is over.
        p.after_refit(12.0, 1000.0);
        assert_eq!(p.calibration(), None, "only right after a binned-SAH build");
    }

    /// A rebuild due on the first frame calibrates only what may pay within that horizon: LBVH (at a
    /// fifth of binned SAH's time by the prior, 8 ms saved a rebuild) is measured; hybrid, at 2.5 × the
    /// measured LBVH's time and with no queries to save on, is not. Asked before either is measured
    /// ([`AdaptivePolicy::calibrations_before`]), both are: hybrid's prior time (half binned SAH's)
    /// saves on binned SAH, the build chosen while LBVH is unknown.
    #[test]
    fn calibration_measures_only_what_may_pay_within_the_horizon() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::HYBRID, Builder::SAH]);
        p.calibrates = true;
        p.built(Builder::SAH, 1000, 1e-2, 10.0);
        assert!(p.after_refit(100.0, 0.0), "{:?}", p.prediction());
        assert_eq!(
            p.calibrations_before(Build::cpu(Builder::SAH)),
            [Build::cpu(Builder::LBVH), Build::cpu(Builder::HYBRID)]
        );
        p.built(Builder::SAH, 1000, 1e-2, 10.0);
        assert_eq!(p.calibration(), Some(Build::cpu(Builder::LBVH)));
        p.calibrated(Builder::LBVH, 1000, 2e-3, 11.0);
        assert_eq!(p.calibration(), None);
        assert_eq!(quality(&p, Builder::HYBRID), None);
    }

    /// The first choice of build after a calibration is made afresh: LBVH, measured once at 0.55 ms
    /// against binned SAH's 1 ms (no rays: a frame's cost is its rebuild), is chosen at the next rebuild,
    /// where hysteresis — 2 standard deviations of the difference of two prior 25% spreads, 0.57 ms —
    /// would have kept binned SAH, the build in use only because nothing else was measured. The choice
    /// after that keeps the build in use again.
    #[test]
    fn the_first_choice_after_a_calibration_is_made_afresh() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        p.calibrates = true;
        p.built(Builder::SAH, 1000, 1e-3, 10.0);
        assert!(p.after_refit(100.0, 0.0), "{:?}", p.prediction());
        p.built(Builder::SAH, 1000, 1e-3, 10.0);
        assert_eq!(p.calibration(), Some(Build::cpu(Builder::LBVH)));
        p.calibrated(Builder::LBVH, 1000, 0.55e-3, 11.0);
        assert_eq!(p.calibration(), None);
        assert!(p.after_refit(100.0, 0.0), "{:?}", p.prediction());
        assert_eq!(p.prediction().build, Build::cpu(Builder::LBVH));
        p.built(Builder::LBVH, 1000, 0.55e-3, 11.0);
        // Binned SAH timed faster since, now cheaper on average but within the noise of its timings:
        // LBVH, chosen by cost, is kept.
        for _ in 0..4 {
            p.costs.learn_time(Build::cpu(Builder::SAH), 1000, 0.3e-3);
        }
        assert!(p.predicted_rebuild(Builder::SAH) < p.predicted_rebuild(Builder::LBVH));
        assert!(p.after_refit(100.0, 0.0), "{:?}", p.prediction());
        assert_eq!(p.prediction().build, Build::cpu(Builder::LBVH));
    }

    /// A sibling, and a mesh of an asset whose builds were all measured, calibrate nothing; neither does
    /// a planner not asked to.
    #[test]
    fn calibration_is_asked_once_per_asset() {
        let rebuild = |p: &mut AdaptivePolicy| {
            p.built(Builder::SAH, 1000, 1e-2, 10.0);
            p.after_refit(100.0, 1000.0);
            p.built(Builder::SAH, 1000, 1e-2, 10.0);
        };
        let mut off = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        rebuild(&mut off);
        assert_eq!(off.calibration(), None);
        let mut first = AdaptivePolicy::new(&[Builder::LBVH, Builder::SAH]);
        first.calibrates = true;
        let mut sibling = first.sibling();
        rebuild(&mut sibling);
        assert_eq!(sibling.calibration(), None);
        assert_eq!(sibling.calibrations_before(Build::cpu(Builder::SAH)), []);
        rebuild(&mut first);
        assert_eq!(first.calibration(), Some(Build::cpu(Builder::LBVH)));
        first.calibrated(Builder::LBVH, 1000, 1e-3, 11.0);
        let mut later = AdaptivePolicy::shared(first.builds.as_slice(), first.costs(), first.asset);
        later.calibrates = true;
        rebuild(&mut later);
        assert_eq!(later.calibration(), None);
    }

    /// Binned-SAH trees at 10 whose refits a frame later cost `refit(frame)`: the frames rebuilt without
    /// a refit, each verdict checked (every refit's a guard rebuild).
    fn outpaced_frames(frames: u32, refit: impl Fn(u32) -> f64) -> Vec<u32> {
        let mut p = AdaptivePolicy::new(&[Builder::SAH]);
        p.built(Builder::SAH, 1000, 1e-3, 10.0);
        let mut skipped = vec![];
        for frame in 0..frames {
            if p.outpaced() {
                let why = p.prediction();
                assert_eq!(why.verdict, Verdict::Outpaced);
                assert_eq!(why.build, Build::cpu(Builder::SAH));
                assert!(why.sah.is_nan());
                skipped.push(frame);
            } else {
                assert!(p.after_refit(refit(frame), 1000.0));
                assert_eq!(p.prediction().verdict, Verdict::Guard);
            }
            p.built(Builder::SAH, 1000, 1e-3, 10.0);
        }
        skipped
    }

    /// Refits at 5 × the fresh cost, frame after frame: once two in a row measured no fall, 7 frames
    /// ([`PACE_MEASURE`] − 1) rebuild without refitting, then one refit measures again. Refits whose
    /// ratio halves every frame (8, 4, 2) would reach the bound within two frames: none is skipped.
    #[test]
    fn a_motion_that_outpaces_refitting_is_rebuilt_without_refits() {
        let steady = outpaced_frames(20, |_| 50.0);
        assert_eq!(
            steady,
            (2..9).chain(10..17).chain(18..20).collect::<Vec<_>>()
        );
        let slowing = outpaced_frames(3, |f| 80.0 / 2f64.powi(f as i32));
        assert_eq!(slowing, Vec::<u32>::new());
    }

    /// A refit the guard keeps ends the run: after the skipped frames, the refit that measures again
    /// keeps its tree (10.5 against 10), and the frame after it refits too.
    #[test]
    fn a_kept_refit_ends_the_outpaced_run() {
        let mut p = AdaptivePolicy::new(&[Builder::SAH]);
        p.built(Builder::SAH, 1000, 1e-3, 10.0);
        let mut skipped = 0;
        for refits in 0..3 {
            while p.outpaced() {
                skipped += 1;
                p.built(Builder::SAH, 1000, 1e-3, 10.0);
            }
            if refits < 2 {
                assert!(p.after_refit(50.0, 0.0));
                p.built(Builder::SAH, 1000, 1e-3, 10.0);
            }
        }
        assert_eq!(skipped, PACE_MEASURE - 1);
        assert!(!p.after_refit(10.5, 0.0));
        assert!(!p.outpaced());
        assert!(!p.after_refit(11.0, 0.0));
    }

    /// Given only CPU builds, no history of measurements makes the policy choose a GPU build.
    #[test]
    fn no_gpu_build_unless_given_one() {
        let mut p = AdaptivePolicy::new(&[Builder::LBVH, Builder::HYBRID, Builder::SAH]);
        let mut cost = 10.0;
        for frame in 0..200 {
            let next = p.next_build();
            assert_eq!(next.device, Device::Cpu);
            if frame == 0 || p.after_refit(cost, 1e4) {
                let b = p.prediction().build;
                // The GPU-like timing of a build that was never offered is learned but never chosen.
                p.built(Build::GPU_LBVH, 1000, 1e-9, 5.0);
                p.built(b, 1000, 1e-3 * (1 + frame % 3) as f64, 10.0);
                cost = 10.0;
            }
            p.queried(1e4, cost, 1e-3);
            cost += 1.0;
            assert_eq!(p.prediction().build.device, Device::Cpu);
        }
    }
}
