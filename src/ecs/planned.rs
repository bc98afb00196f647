//! The structure of a mesh under [`Structure::Auto`] with [`RebuildPolicy::Adaptive`]: a BVH or a grid
//! rebuilt every frame, planned per mesh from measured costs through a [`Choice`], with the rule of
//! [`crate::grid::choice`] (the characteriser's profile) as the prior; and the test hook that scripts the
//! costs every per-mesh option planner learns from.
//!
//! **The rule is ours** (the seeds give none). Every mesh starts on the BVH ([`Choice::structure`]: with
//! 15% of hysteresis the structure in use stays against one a little cheaper, and on time the rule's grid
//! picks were all dearer at 20k triangles on an idle machine — the soup, started on its grid, kept it 162
//! of 900 frames at 1.05 × the BVH's time; issue 12). The profile's rule sets the grid's prior seconds
//! per ray: 1 × the BVH's where it picked the grid, 1.2 × otherwise, 2 × for empty space. The grid's
//! overhead per frame is expected at the grid frames' seconds per triangle learned on any mesh (its
//! rebuild and the BVH's refit under it) times the mesh's triangles, before any mesh measured one at 2 ×
//! the BVH's. [`Choice`] tries the grid — at most three frames — only when the saving predicted, optimistic
//! by its 25% spread, times the frames seen so far pays the tries' predicted price by one spread of the
//! BVH's frames: a grid whose `0.75 · (q_g + o_g)` is above the BVH's `q + o` is never built (a scene
//! that gains nothing pays nothing). From then on measured costs (the mesh's maintenance time, grid
//! rebuild included, as overhead; its share of the frame's batched query time per ray) decide, with the
//! planner's one margin and hysteresis ([`crate::adaptive::rank::choose`]).
//!
//! Rigid motion: a mesh moved by its transform only is not in the maintain pass after its first build
//! (its geometry did not change), so it is never planned and keeps its BVH, which a rigid mesh never
//! updates — there is no per-frame rebuild for a grid to save, only its own to pay. Where the BVH's
//! update is nothing, the grid's overhead predicted through the priors' ratio (2 × nothing) was nothing
//! too; the learned seconds per triangle predict its rebuild (`tests/options.rs`).
//!
//! Two more rules (issue 12). Where the rule picked the BVH for empty space
//! ([`ChoiceReason::Clustered`]) the grid's prior is 2 × the BVH's seconds per ray, so it is never
//! tried: on the report's one clustered scene (rigid at `--quick` size) the grid took 2 × the BVH's
//! steps per ray (at 20k triangles, where the rule says alike sizes, 4.3 × the steps and 18 × the
//! time: one tried frame cost 5% of the run; there the horizon rule keeps it from being tried, the
//! first BVH frame's cold queries no longer reason enough). And an estimate goes stale as the scene changes:
//! the other structure is re-tried once the one in use has drifted by more than 15% since the other
//! was measured, at gaps doubling from 10 frames ([`Choice::retry_stale`]) — the report's explosion
//! had kept a grid drifting from 5.8 to 8.9 ms per frame against a BVH measured only in frames 1–4.
//!
//! **The data** (`cargo run --release --example report -- --quick`: ~3k triangles, 24 frames, 512
//! incoherent rays per frame plus shadow rays; 2-core dev VM shared with other builds, so times are
//! loaded). Traversal steps per ray over a fresh binned-SAH BVH's (work counts, free of the load):
//!
//! | scene | rule's pick | grid-single steps | lauterbach-0.4 steps | planned-options: frames on the grid |
//! |---|---|---|---|---|
//! | crowd | BVH | 3.71 | 1.21 | 3/24 (the try) |
//! | cloth | BVH | 3.29 | 1.30 | 3/24 |
//! | rigid | BVH | 3.68 | 1.13 | 3/24 |
//! | rigged_figure | BVH | 2.18 | 1.27 | 3/24 |
//! | explosion | grid | 2.46 | 1.08 (rebuilt every frame) | 21/24 |
//! | teapot_in_stadium | grid | 1.34 | 1.03 | 21/24 |
//! | soup | grid | 1.02 | 1.10 | 21/24 |
//!
//! Where the rule says BVH, the grid takes 1.7–3.3× the steps: the rule is right and the prior keeps
//! the grid to its three tried frames. Where it says grid, the grid's steps range from 0.93× to 2.3×
//! the BVH's: the profile cannot call these, so the grid's prior (1×) stays within one prior spread of
//! the BVH and is tried where it can pay, and only measured time decides. (This table is from before
//! the BVH was put first for every mesh: the rule's grid picks then started on the grid.)
//!
//! **Why the planner kept a slower grid** (issue 12: 891 of 900 frames on the grid in explosion, teapot
//! in stadium and soup, 1.17–1.73× lauterbach-0.4's time). Logged per frame in the report's
//! `planned-options`: the BVH's three tries measured it cheaper (teapot: 0.37 ms a frame against the
//! grid's 0.51 ms), but [`Choice`]'s margin was z spreads of one *frame*, and the grid's frames were
//! spiky — the report charged them the BVH's lauterbach rebuilds (12 ms every third frame on soup), and
//! the loaded machine stalled one frame in four by 10–20 ms — so the margin outgrew any difference of
//! means and the grid was never left. Fixed in [`Choice`] (margin on the difference of the means, at
//! least 15%; a sample over 4× its mean is a stall, clipped), in the report (the BVH only refitted under
//! the grid, as here) and here: the frame of a switch, which catches a BVH refitted under the grid up
//! (a rebuild), does not teach the structure's overhead. `tests/options.rs` scripts the spiky case.
//!
//! That was not all: the BVH's tried frames were also the first frames of its wide-tree and packet
//! choices, which tried the binary tree and ray-by-ray packets there and charged those tries to the BVH
//! (logged in the report, explosion: the first try measured with packets on, 49 ms of queries against
//! the grid's 6 ms; the next two with the binary tree). Now a structure being tried meets the options
//! under it as settled ([`Choice::hold`]), and a frame in which one of those is tried teaches the
//! structure nothing; the report, whose rays are incoherent, plans its packets with
//! [`Choice::incoherent_packets`] (single rays first), where the ECS's packet requests are coherent
//! tiles ([`Choice::packets`]). `tests/options.rs` checks that no option is tried beside a structure's
//! try.
//!
//! **The overlap test** ([`GridOptions::overlap_test`]) is planned per mesh kept as a grid
//! ([`plan_overlap`], [`Choice::overlap`]): its slower rebuild (the grid's rebuild seconds, as overhead)
//! against its seconds per ray (the grid's share of the query time), reported as
//! [`PlannedOption::Overlap`].
//!
//! Cost: a few arithmetic operations per mesh and frame; the grid is built only in frames it is in use.

use super::stats::PlannedOption;
use super::world::Instance;
use super::{Structure, StructureWhy};
use crate::adaptive::Choice;
use crate::grid::{
    ChoiceInput, ChoiceReason, GridOptions, StructureChoice, StructureKind, choose_structure,
};
use bevy_ecs::entity::Entity;
use std::sync::Arc;

/// Test hook: seconds that replace what the option planners measure. Called per mesh with the option in
/// use; `None` keeps the measured seconds. Set with [`TraceWorld::script_costs`](super::TraceWorld).
#[doc(hidden)]
pub type CostScript = Arc<dyn Fn(Entity, PlannedOption) -> Option<ScriptedCost> + Send + Sync>;

/// Test hook: one option's scripted cost for a frame (see [`CostScript`]).
#[doc(hidden)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScriptedCost {
    /// Seconds the option adds to keeping the mesh current this frame.
    pub overhead_s: f64,
    /// Seconds per ray it answers.
    pub per_ray_s: f64,
}

/// The seconds an option planner learns: the script's, where a script is set and has some, else `measured`.
/// `pick` chooses the field of [`ScriptedCost`].
pub(crate) fn scripted(
    script: Option<&CostScript>,
    e: Entity,
    option: PlannedOption,
    measured: f64,
    pick: impl Fn(ScriptedCost) -> f64,
) -> f64 {
    script.and_then(|s| s(e, option)).map_or(measured, pick)
}

/// The structure a mesh is to be kept in under `wanted`, and why; under [`Structure::Auto`] the rule of
/// [`crate::grid::choice`] on the instance's profile (none yet for a new mesh: the BVH).
pub(crate) fn structure_for(
    wanted: Structure,
    inst: Option<&Instance>,
) -> (StructureKind, StructureWhy) {
    match wanted {
        Structure::Bvh => (StructureKind::Bvh, StructureWhy::Fixed),
        Structure::Grid => (StructureKind::Grid, StructureWhy::Fixed),
        Structure::Auto => {
            let choice = rule(inst);
            (choice.structure, StructureWhy::Rule(choice.reason))
        }
    }
}

/// The rule of [`crate::grid::choice`] on the instance's profile (none yet for a new mesh: the BVH).
fn rule(inst: Option<&Instance>) -> StructureChoice {
    choose_structure(&ChoiceInput {
        profile: inst.and_then(|i| i.profile.as_deref()),
    })
}

/// The grid options of a mesh kept as a grid this frame: `options` with the
/// [overlap test](GridOptions::overlap_test) as the mesh's [`Choice::overlap`] picks it (made at its first
/// grid frame; with `hold`, the settled option, no try) where the planner chooses the mesh's structure —
/// the configured value is then only the planner's concern — else `options` as they are. Its rebuild
/// seconds and its share of the query time teach the choice. O(1).
pub(crate) fn plan_overlap(inst: &mut Instance, options: &GridOptions, hold: bool) -> GridOptions {
    if inst.kept.structure.is_none() {
        return *options;
    }
    let overlap = (inst.kept.overlap).get_or_insert_with(Choice::overlap);
    let overlap_test = if hold {
        overlap.hold()
    } else {
        overlap.decide(inst.load.rays())
    };
    GridOptions {
        overlap_test,
        ..*options
    }
}

/// [`structure_for`] under [`Structure::Auto`] with the planner (see the module docs): once the mesh has
/// a profile, its [`Choice`] (made then: [`Choice::structure`] with the rule's prior, the BVH first)
/// decides for the rays it expects, the grid's overhead expected at `grid_rate` (seconds per triangle of
/// a grid frame, learned on every mesh) times the mesh's triangles once any mesh measured one. The
/// reason is the rule's until both structures were measured, then both predictions
/// ([`ChoiceReason::Measured`], seconds per frame). O(1).
pub(crate) fn plan_structure(
    inst: &mut Instance,
    grid_rate: Option<f64>,
) -> (StructureKind, StructureWhy) {
    let prior = rule(Some(inst));
    let why = StructureWhy::Rule(prior.reason);
    if inst.profile.is_none() {
        return (prior.structure, why);
    }
    let triangles = inst.bvh.slot_indices().len() as f64;
    let choice = (inst.kept.structure).get_or_insert_with(|| Choice::structure(&prior));
    if let Some(rate) = grid_rate {
        choice.expect_overhead(StructureKind::Grid, rate * triangles);
    }
    let kind = choice.decide(inst.load.rays());
    let predicted = |k| match choice.predict(k, inst.load.rays()) {
        Some((c, true)) => Some(c.cost_s),
        _ => None,
    };
    match (
        predicted(StructureKind::Bvh),
        predicted(StructureKind::Grid),
    ) {
        (Some(bvh), Some(grid)) => (
            kind,
            StructureWhy::Rule(ChoiceReason::Measured { bvh, grid }),
        ),
        _ => (kind, why),
    }
}
