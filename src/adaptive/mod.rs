//! The planner: per mesh and per frame, keep the refitted tree, rebuild it, or try a build not measured
//! yet — with which builder on which device — from costs learned online and shared between meshes. Our
//! design (the research gives a fixed threshold, thesis §4.1.5, and the observation that SAH pays off with
//! many rays per triangle, seed 004 §6.3); `examples/report` measures it against every fixed strategy.
//!
//! # The model
//!
//! A frame costs update time plus query time, and query time per ray grows along a line in the tree's
//! SAH cost. Learned, each as a running mean *and variance* ([`Estimate`]), in a [`CostTable`] that every
//! mesh of a world shares:
//! - per [`Build`] (a builder on a [`Device`]): seconds per unit of `n·log2 n` ([`costs::size_unit`]), so
//!   a time measured on one mesh predicts a mesh of another size;
//! - per [`Asset`] (same topology: the ECS's shared index buffer, or [`Asset::of_indices`]) and build: the
//!   SAH cost its trees reach, relative to the asset's unit — so the second instance of a character knows
//!   every build its first instance tried and explores nothing;
//! - seconds per ray per unit of SAH cost (the proportional rate); and per mesh, rays per frame, frames
//!   between rebuilds, the drift of a fresh tree's cost from frame to frame, and the line of query seconds
//!   per ray against SAH cost fitted over the mesh's frames, whose slope — the *marginal* rate, about half
//!   the proportional one on the report's scenes — the rent and the builder choice use, with the
//!   proportional rate as its prior until the mesh's own frames say otherwise (`query_model`).
//!
//! # The rules
//!
//! Every choice goes through one core ([`rank`]): options are [`Candidate`]s with a predicted cost and the
//! standard deviation of that prediction (from the estimates' variances; a prediction made from a prior
//! carries 25%).
//! - **Rebuild (rent)**: after each refit the work the refitted tree costs beyond a fresh tree,
//!   `rays · (C_now − C_fresh)`, is added up since the last rebuild, and the rent is that sum at the
//!   marginal rate as estimated *now* (so a rate revised down by the mesh's own frames revalues the
//!   whole rent, not only the frames to come: charged frame by frame at the prior's proportional rate,
//!   a scene whose query time ignores the SAH cost kept the rent of its first frames and rebuilt for
//!   nothing). Its spread is what was measured: the measured query rates' relative spread of their
//!   mean times the rent, and the anchor's error (the measured RMS error of a rebuilt tree's predicted
//!   cost, per inexact anchor of the last tree and the tree the rebuild would make) times the rate
//!   times the rays and fresh costs summed, as that error shifts every frame's fresh cost alike. Not
//!   the marginal fit's spread, whose prior counts as uncertain by its whole value (where the tree's
//!   cost varies too little for the slope to show through the timing noise, `z` such spreads grew as
//!   fast as the rent, and a churning corner's rent never came due: issue 19), nor the guard's random
//!   walk of the fresh cost, which bounds the guard's worst case. The mesh is rebuilt once the rent
//!   exceeds the predicted rebuild time by `z` standard deviations of their difference ([`rank::pays`],
//!   `z` = [`AdaptivePolicy::z`], 2 by default) — the ski-rental rule with a margin from the measured
//!   noise instead of a magic constant.
//! - **Builder (hysteresis)**: the build used is the one of least predicted cost per frame (rebuild time
//!   over the interval between rebuilds plus a frame's queries on its fresh tree), but the build in use is
//!   kept unless another beats it by `z` standard deviations of the difference ([`rank::choose`]): timings
//!   jittering around equal costs never flip the choice.
//! - **Explore**: a build nobody measured on this asset is tried when its expected saving per frame (from
//!   the priors: [`Build::prior_quality`], which the characteriser's profile sharpens through
//!   [`AdaptivePolicy::set_profile`], and [`Build::prior_time`]; optimistic by one standard deviation, as
//!   what is unknown may be better than assumed) times the horizon exceeds what trying it costs (its whole
//!   time on a frame that would have refitted, its extra time over the chosen build's when a rebuild is
//!   due). The horizon is the frames seen so far (a scene that ran `n` frames is expected to run about `n`
//!   more), so short scenes explore little and long ones what can repay itself. One exception: the first
//!   rebuild due on an asset with no binned-SAH tree measured builds one, because the bound is stated
//!   against it. A build tried is measured against the last binned-SAH tree of the mesh carried forward
//!   by the guard's factor for it (an exact anchor, carried conservatively); without one, against the reference carried forward by the
//!   guard's (conservative) factor, so an error in it errs towards an earlier guard. Before an interval
//!   between rebuilds was measured, a build tried is priced over the frames the current one has lasted,
//!   and a rebuild that tried a build teaches no interval. The first build of an asset
//!   nobody measured is the one of least predicted time.
//! - **Calibrate** (instead of exploring, where [`AdaptivePolicy::calibrates`] is set, as the ECS plugin
//!   and the report do): an asset's first rebuild that comes due builds binned SAH (the only build
//!   measured), and every build nobody measured is then built once on that same pose and dropped
//!   ([`AdaptivePolicy::calibration`]), its quality the exact ratio of the two trees' costs. A build tried
//!   on a frame of its own is measured against a carried anchor, and in a fast scene that is far off:
//!   over the report's explosion LBVH was learned at 1.69 × binned SAH against 1.16, stayed outside the
//!   bound for good, and binned SAH rebuilt every frame at three times LBVH's time. A scene that never
//!   rebuilds calibrates nothing, and no worse tree is put in use to be measured. The GPU-resident
//!   frame, whose tree costs come back a frame late, asks before the rebuild instead
//!   ([`AdaptivePolicy::calibrations_before`]) and builds them in the rebuild's submission.
//! - **Guard (the SAH bound)**: the bound ([`AdaptivePolicy::sah_bound`], 1.5) is on the quantity the
//!   report measures: the tree's SAH cost over a fresh *binned-SAH* tree's of the same frame. The fresh
//!   cost is predicted from the last rebuild (its build's measured relative cost and the asset's measured
//!   binned-SAH cost), carried forward at the lower of two factors: a fall as fast as the asset's learned
//!   drift *magnitude* times the frames `k`, plus `z` standard deviations of a random walk, `√(k·w)`,
//!   whose variance per frame `w` is learned between two binned-SAH trees (whose anchors have no
//!   error), once a trend is known (before, the sample is the whole drift), and capped by a bound
//!   learned from every interval (whose anchors' errors add to the walk): a walk of 0.073 a frame,
//!   learned while the report's explosion slowed from falling 48% a frame to 1%, kept the guard's
//!   one-frame factor at 0.58 with no later pair of binned-SAH trees to revise it, and the guard
//!   rebuilt all 300 frames (issue 19). At least 0.001² a frame
//!   (issue 19 too: a drift spread learned from 1–3-frame intervals between LBVH trees held their own
//!   deviations, 2–2.7% a frame, and carried linearly it rebuilt the report's soup every 1.3 frames;
//!   the walk is carried as `√k`) (the sign of the trend is not trusted: the report's orbiting rigid
//!   bodies' fresh cost rose 2% a frame for two intervals, then fell 1.7% a frame, and a guard that
//!   carried the rise forward passed the bound by 3%), and the root area then over the root area now ([`TreeCost`]: as a scene spreads out, every
//!   box but the root can shrink relative to it by that much, so an explosion's fresh cost is assumed to
//!   fall as fast as its extent grows) — the latter no lower than `1 / (1 + |C_now / C_built − 1|)`, since
//!   a motion that kept the refitted tree's cost (uniform scaling, rigid motion) kept the fresh tree's
//!   too. A fresh cost that falls makes the guard earlier, never later. The mesh's last binned-SAH tree
//!   is kept as a second, exact anchor through rebuilds with other builds, carried forward the same way
//!   (by the root area alone: its tree is not the one refitted now), and the guard takes the higher of
//!   the two fresh costs. A guard rebuild that would not be due were the last tree exactly of its
//!   build's mean quality (due to the anchor error alone) builds binned SAH, which ends that error, where
//!   that pays: each build priced over the frames its kind of anchor (exact after binned SAH, inexact
//!   after the others) has lasted on the mesh. The ratio is extrapolated one
//!   frame (the tree's cost at this frame's rise, the fresh cost carried a frame further), and the mesh is rebuilt *before* the next frame would pass the bound
//!   (while the fresh binned-SAH cost rests on the priors, before it would pass the bound over one prior
//!   spread, 1.2, and that rebuild measures a binned-SAH tree, where one is offered; where none is, the
//!   bound rests on the priors);
//!   should motion be more explosive than the trend, the check runs on the refitted tree before the
//!   frame's queries and rebuilds in the same frame. So no tree answers queries above the bound, under the
//!   one assumption that the fresh tree's cost falls no faster than the slower of those two factors allow
//!   (`tests/policy.rs` checks every frame of every report scene, at three sizes, against a real fresh
//!   build). A single tree is better or worse than its build's mean quality (one LBVH tree over orbiting
//!   rigid bodies sits anywhere from 1.0 to 1.38 × binned SAH), so a fresh cost anchored on a LBVH or
//!   hybrid rebuild can be too high. Every rebuild of a measured build tests the prediction of its cost,
//!   and after a rebuild that is not binned SAH the guard lowers the fresh cost by `z` RMS log errors of
//!   those predictions (after a binned-SAH rebuild the anchor is exact); the bound then also assumes that
//!   a tree deviates from its build's mean by less than `z` such errors. An error between two inexact
//!   anchors counts half to each. Only trees better than predicted count (twice, as the lower half of
//!   a symmetric error): they make the guard late, while a tree worse than predicted makes it early;
//!   a decelerating explosion's lagging trend put all its trees above their predictions, and counted
//!   as anchor error that lag left LBVH no room under the bound (issue 19).
//!   The anchor error starts from a prior (a log spread of 0.08, the widest a tree's quality showed
//!   around its build's mean over the report's scenes) worth two samples and moves to the measured
//!   RMS as rebuilds test it (the posterior mean of a variance under a scaled inverse-χ² prior), so
//!   the first rebuilds, where the RMS rested on one or two samples (and the report's rigid scene
//!   passed the bound at 1.53), are covered too. While the fresh cost rests on the priors the anchor
//!   error does not apply (the bound rests on the priors); to avoid that, the first build of an asset
//!   is binned SAH where one is offered and the bound is finite (one binned-SAH build per asset), and
//!   with no rays nothing is explored outside a guard rebuild.
//!   Builds whose fresh trees, as the guard sees them after a rebuild (anchor error included), sit
//!   more than 90% of the way to the bound are not chosen: a tree worse than its build's mean cannot
//!   answer the frame it is built on above the bound. Cost: guard rebuilds come earlier after LBVH
//!   and hybrid rebuilds (by `exp(2 · 0.08)` = 1.17 at most in the ratio), and a build whose mean
//!   tree sits above `1.45 / 1.17` × binned SAH is left out until its trees are seen to sit close to
//!   their mean.
//!   With no rays, the rent stays 0 and nothing is worth exploring: only the guard rebuilds.
//! - **Partial rebuild (a third update)**: after a rebuild due by the rent ([`Verdict::Rent`]) the caller
//!   may offer one ([`AdaptivePolicy::prefer_partial`], the triangles
//!   [`crate::bvh::Bvh::degraded_primitives`] counts, a pass over the nodes paid only in such frames);
//!   the rebuild due is ranked against it with [`rank::choose`] (the full rebuild as the option
//!   in use, so the partial one must be cheaper beyond the margin); its time is learned per mesh, its
//!   prior is the binned-SAH rate at the rebuilt size ([`Verdict::Partial`]). The guard always rebuilds
//!   the whole tree.
//! - **Outpaced (no refit)**: where the guard rebuilt the last trees one frame after their build, the
//!   caller asks [`AdaptivePolicy::outpaced`] before refitting; while the one-frame ratio, as measured
//!   and as its fall per frame extrapolates over twice the frames skipped, stays above the bound, the
//!   mesh is rebuilt without a refit ([`Verdict::Outpaced`]), measuring again one frame in
//!   [`PACE_MEASURE`] (the report's explosion: a refit is a third of an LBVH build, thrown away every
//!   frame). A skip the motion did not need costs a rebuild, never the bound.
//!
//! # Adding an option
//!
//! Structures (BVH or grid), updates (refit, partial or full rebuild), ray processing (packets, sorting)
//! are choices of the same shape, and all go through [`rank::choose`] (same margin, same hysteresis):
//! - A per-mesh choice among ways of doing the same work, each costing an overhead a frame plus seconds
//!   per unit of work (a ray): use a [`Choice`] — give each option its priors, tell it what the option
//!   in use cost ([`Choice::kept`] for the overhead, [`Choice::served`] for the work), ask
//!   [`Choice::decide`] each frame, and list the pick in `TraceStats::options` as a new
//!   `PlannedOption` variant. The wide query tree is the example (`src/ecs/maintain.rs`, `plan_wide`;
//!   its query seconds come from `TraceWorld::attribute_queries`).
//! - A choice with a cost model of its own: give each option a predicted cost from an [`Estimate`] of
//!   what it measured (in the shared table when it generalises across meshes), turn them into
//!   [`Candidate`]s and call [`rank::choose`] with the option in use; decide "act now?" with
//!   [`rank::pays`].
//! - A new build (a GPU builder, a partial rebuild): add its prior to [`Build::prior_quality`] and
//!   [`Build::prior_time`] and offer it in the builds list.
//!
//! # Cost
//!
//! A few dozen arithmetic operations per call under one uncontended lock; the caller supplies the tree's
//! SAH cost ([`crate::bvh::Bvh::sah_cost`], one pass over the nodes, about the cost of a refit).
//!
//! ```
//! use kinetrace::adaptive::{AdaptivePolicy, Asset, Build, CostTable, Verdict};
//! use kinetrace::bvh::Builder;
//! let table = CostTable::new();
//! let asset = Asset { triangles: 10_000, id: 1 };
//! let mut policy = AdaptivePolicy::shared(&[Build::cpu(Builder::LBVH)], &table, asset);
//! policy.sah_bound = f64::INFINITY; // this example is about the rent, not the guard
//! policy.built(Builder::LBVH, 10_000, 0.004, 55.0); // a 10k-triangle build took 4 ms; SAH cost 55
//! for _ in 0..3 {
//!     policy.queried(20_000.0, 55.0, 0.010); // 20k rays took 10 ms, three times
//! }
//! // Each frame at cost 60 costs about 0.91 ms more in queries than the fresh tree did; the rent must pass
//! // the 4 ms rebuild by two standard deviations of one build (25% of 4 ms while it was measured once):
//! // more than 6 ms, reached in the 7th frame.
//! let rebuilt = (1..20).find(|_| policy.after_refit(60.0, 20_000.0)).unwrap();
//! assert_eq!(rebuilt, 7);
//! let why = policy.prediction();
//! assert_eq!(why.verdict, Verdict::Rent);
//! assert!(why.rent_s > why.rebuild_s + why.margin_s);
//! // A second mesh of the same asset starts from what the first one learned.
//! let twin = AdaptivePolicy::shared(&[Build::cpu(Builder::LBVH)], &table, asset);
//! assert_eq!(twin.predicted_rebuild(Builder::LBVH), 0.004);
//! ```

mod build;
mod choice;
pub mod costs;
mod estimate;
mod policy;
mod query_model;
pub mod rank;

pub use build::{Build, Device};
pub use choice::Choice;
pub use costs::{Asset, CostTable};
pub use estimate::Estimate;
pub use policy::{
    AdaptivePolicy, DEFAULT_SAH_BOUND, DEFAULT_Z, PACE_MEASURE, Prediction, TreeCost, Verdict,
};
pub use rank::Candidate;
