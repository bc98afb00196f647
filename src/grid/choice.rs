//! Which structure answers a mesh's ray queries: a BVH (refitted, rebuilt when it degrades) or a uniform grid
//! rebuilt every frame. A pure function, [`choose_structure`], of the characteriser's profile and of
//! measured (or predicted) costs; the ECS calls it for meshes configured as `Structure::Auto`, and the
//! planner can call it with its own measurements.
//!
//! **The rule is ours.** The seeds give none: seed 001 (the grid) assumes the grid, seed 003 (the
//! characteriser) profiles a scene but decides nothing. The rule, in order:
//!
//! 1. **Measured costs decide when there are any.** With [`StructureCosts`] for both structures (seconds per
//!    frame: update plus the frame's queries), the cheaper one answers; the structure in use is kept unless
//!    the other is cheaper by more than [`SWITCH_MARGIN`] (10%), so that noise in the timings does not flip
//!    the choice every frame.
//! 2. **Otherwise the profile predicts.** A grid pays for empty space (cells that cost a step each) and for
//!    large triangles (referenced from many cells); a BVH adapts to both. So the grid is chosen only when
//!    all of these hold, else the BVH, with the first failed test as the reason:
//!    - at least [`MIN_GRID_TRIANGLES`] triangles (below, either structure is a handful of tests);
//!    - the Morton histogram is even: at most [`MAX_EMPTY_BIN_FRACTION`] of its bins are empty
//!      (a teapot in a stadium leaves most bins empty; a crowd of separate characters a good share);
//!    - triangle sizes are alike: [`SceneProfile::size_spread`] at most [`MAX_SIZE_SPREAD`].
//!
//!    The χ² test's verdict ([`SceneProfile::uniform`]) is reported but not required: at α = 0.005 it
//!    rejects uniformity for every real mesh of a few thousand triangles (every report scene fails it), so
//!    as a requirement it would never pick the grid.
//! 3. No profile (a mesh not characterised yet): the BVH.
//!
//! **Why these thresholds (the report's data, `cargo run --release --example report -- --quick`, 2-core dev
//! VM, ~3k triangles per scene, 512 rays per frame plus shadow rays, one query thread).** The grid is never
//! the faster structure to *query* on this machine (single rays 1.4–2.3× slower than the BVH on camera
//! rays, see docs/BENCHMARKS.md; packets do not yet pay); it can only win where the BVH must be rebuilt
//! often and the grid's linear rebuild is cheaper than the BVH's, which is the evenly spread, similarly
//! sized, incoherently moving geometry (the explosion, the triangle soup). See the issue-12 note in
//! docs/BENCHMARKS.md for the measured rows; the thresholds separate those scenes' profiles from the
//! crowd, the cloth, the teapot in a stadium and the rigid pieces. Measured costs (rule 1) override the
//! prediction wherever they exist, which is what keeps a wrong prediction from lasting.
//!
//! Cost: O(1) (the profile is computed by the characteriser).

use crate::characterize::SceneProfile;

/// Fewest triangles for which the profile may predict the grid.
pub const MIN_GRID_TRIANGLES: usize = 256;

/// Largest fraction of empty Morton-histogram bins for which the profile may predict the grid.
pub const MAX_EMPTY_BIN_FRACTION: f64 = 0.25;

/// Largest triangle-size spread (standard deviation over mean of the box diagonals) for which the profile
/// may predict the grid.
pub const MAX_SIZE_SPREAD: f64 = 1.0;

/// The structure in use is kept unless the other one's measured cost is lower by more than this fraction.
pub const SWITCH_MARGIN: f64 = 0.10;

/// The two structures a mesh can be kept in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum StructureKind {
    /// A BVH, refitted and rebuilt by the rebuild policy.
    #[default]
    Bvh,
    /// A uniform grid rebuilt every frame the mesh changes.
    Grid,
}

/// Seconds per frame each structure costs a mesh, measured or predicted: its update (BVH: refit and the
/// rebuilds amortised over the frames; grid: a rebuild) plus its share of the frame's queries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StructureCosts {
    /// BVH update seconds per frame.
    pub bvh_update: f64,
    /// BVH query seconds per frame.
    pub bvh_query: f64,
    /// Grid rebuild seconds per frame.
    pub grid_build: f64,
    /// Grid query seconds per frame.
    pub grid_query: f64,
}

impl StructureCosts {
    /// The BVH's total seconds per frame.
    pub fn bvh(&self) -> f64 {
        self.bvh_update + self.bvh_query
    }

    /// The grid's total seconds per frame.
    pub fn grid(&self) -> f64 {
        self.grid_build + self.grid_query
    }
}

/// What [`choose_structure`] decides from.
#[derive(Clone, Copy, Debug, Default)]
pub struct ChoiceInput<'a> {
    /// The characteriser's profile of the mesh, if it has one.
    pub profile: Option<&'a SceneProfile>,
    /// Measured or predicted costs of both structures, if known.
    pub costs: Option<StructureCosts>,
    /// The structure in use now, if any (measured choices keep it within [`SWITCH_MARGIN`]).
    pub current: Option<StructureKind>,
}

/// Why [`choose_structure`] chose what it chose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ChoiceReason {
    /// Measured costs, seconds per frame of each structure.
    Measured {
        /// The BVH's.
        bvh: f64,
        /// The grid's.
        grid: f64,
    },
    /// No profile and no costs yet: the BVH.
    NoProfile,
    /// Fewer than [`MIN_GRID_TRIANGLES`] triangles.
    FewTriangles(usize),
    /// More than [`MAX_EMPTY_BIN_FRACTION`] of the histogram's bins are empty (the fraction).
    Clustered(f64),
    /// Triangle-size spread above [`MAX_SIZE_SPREAD`] (the spread).
    MixedSizes(f64),
    /// The profile passed every test: evenly spread, alike triangles (the empty-bin fraction, the size
    /// spread, and the χ² test's verdict, for the record).
    EvenlySpread {
        /// Fraction of empty histogram bins.
        empty_bins: f64,
        /// Triangle-size spread.
        size_spread: f64,
        /// Whether χ² accepted uniformity.
        chi_square_uniform: bool,
    },
}

/// The decision: a structure and the reason.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StructureChoice {
    /// The structure that answers.
    pub structure: StructureKind,
    /// Why.
    pub reason: ChoiceReason,
}

/// The rule of the [module docs](self). Pure and O(1).
pub fn choose_structure(input: &ChoiceInput<'_>) -> StructureChoice {
    let choice = |structure, reason| StructureChoice { structure, reason };
    if let Some(c) = input.costs {
        let (bvh, grid) = (c.bvh(), c.grid());
        let reason = ChoiceReason::Measured { bvh, grid };
        let structure = match input.current {
            Some(StructureKind::Grid) if bvh >= grid * (1.0 - SWITCH_MARGIN) => StructureKind::Grid,
            Some(StructureKind::Bvh) if grid >= bvh * (1.0 - SWITCH_MARGIN) => StructureKind::Bvh,
            _ if grid < bvh => StructureKind::Grid,
            _ => StructureKind::Bvh,
        };
        return choice(structure, reason);
    }
    let Some(p) = input.profile else {
        return choice(StructureKind::Bvh, ChoiceReason::NoProfile);
    };
    if p.primitives < MIN_GRID_TRIANGLES {
        return choice(StructureKind::Bvh, ChoiceReason::FewTriangles(p.primitives));
    }
    let empty = empty_bin_fraction(p);
    if empty > MAX_EMPTY_BIN_FRACTION {
        return choice(StructureKind::Bvh, ChoiceReason::Clustered(empty));
    }
    if p.size_spread > MAX_SIZE_SPREAD {
        return choice(StructureKind::Bvh, ChoiceReason::MixedSizes(p.size_spread));
    }
    choice(
        StructureKind::Grid,
        ChoiceReason::EvenlySpread {
            empty_bins: empty,
            size_spread: p.size_spread,
            chi_square_uniform: p.uniform,
        },
    )
}

/// The fraction of the profile's histogram bins that are empty (0 for a profile without bins).
pub fn empty_bin_fraction(p: &SceneProfile) -> f64 {
    if p.bins == 0 {
        0.0
    } else {
        p.empty_bins as f64 / p.bins as f64
    }
}
