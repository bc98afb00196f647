//! The report's structure rows (issue 12): the mesh kept as a uniform grid rebuilt every frame instead of a
//! maintained BVH, traced ray by ray (`grid-single`) or as packets (`grid-packets`), and the structure
//! rule's choice (`auto-structure`).
//!
//! Same ray load and error terms as the BVH strategies, with one mapping: a grid has no tree, so its
//! traversal steps are the **cells visited plus the triangle tests** (a cell step is the grid's unit of
//! traversal work as a node visit is the BVH's), still over the fresh binned-SAH BVH's steps on the same
//! rays; its SAH ratio is undefined and reported as NaN (left out of the figures' scales). The sampled rays
//! are checked against brute force from the answers the timed run gave.
//!
//! The grid is rebuilt on one thread (the BVH strategies build on all): for the report's few thousand
//! triangles the parallel build's task overhead exceeds its work, and on a loaded machine its time varied
//! by an order of magnitude from frame to frame.
//!
//! `grid-overlap` is `grid-single` with the triangle–cell overlap test in the build
//! ([`GridOptions::overlap_test`]): a slower build for fewer references per cell.
//!
//! `grid-packets` traces the report's rays in packets of 16 consecutive rays (a 4×4 tile's size), and the
//! shadow rays of their hits the same way. The report's rays run from random points on a sphere around
//! the scene to random points inside it, so they are *incoherent*: most packets fail the direction-sign
//! or spread test and fall back to single rays (see `kinetrace::grid::PACKET_SPREAD_LIMIT`); this row
//! measures what packets cost on such a load, not their best case (camera tiles: bench suite `grid`).
//!
//! `auto-structure` profiles the first frame (its time charged to that frame), asks
//! [`choose_structure`] with the profile alone — what the ECS does for `Structure::Auto` — and then
//! runs the chosen structure: `grid-single` for the grid, `lauterbach-0.4` (the ECS's default policy) for
//! the BVH. Its choice and the profile's figures are printed, one line per scene.

use super::harness::{
    Frame, FrameRecord, Settings, Strategy, Traced, mismatches, query, run_strategy,
};
use glam::Vec3;
use kinetrace::bvh::{Hit, TraversalStats};
use kinetrace::characterize::profile_mesh;
use kinetrace::grid::choice::empty_bin_fraction;
use kinetrace::grid::{ChoiceInput, GridOptions, StructureKind, UniformGrid, choose_structure};
use kinetrace::{MeshBvh, Ray};
use std::time::Instant;

/// The structure strategies, in their rows' order.
pub const STRATEGIES: [StructureStrategy; 4] = [
    StructureStrategy::GridSingle,
    StructureStrategy::GridPackets,
    StructureStrategy::GridOverlap,
    StructureStrategy::Auto,
];

/// Rays per packet in `grid-packets`: a 4×4 tile.
const PACKET: usize = 16;

/// A structure strategy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StructureStrategy {
    /// A grid rebuilt every frame, single rays.
    GridSingle,
    /// A grid rebuilt every frame, packets of [`PACKET`] rays.
    GridPackets,
    /// A grid rebuilt every frame with the triangle–cell overlap test, single rays.
    GridOverlap,
    /// The structure rule's choice from the first frame's profile.
    Auto,
}

impl StructureStrategy {
    pub fn name(&self) -> &'static str {
        match self {
            StructureStrategy::GridSingle => "grid-single",
            StructureStrategy::GridPackets => "grid-packets",
            StructureStrategy::GridOverlap => "grid-overlap",
            StructureStrategy::Auto => "auto-structure",
        }
    }

    pub fn is_fixed(&self) -> bool {
        *self != StructureStrategy::Auto
    }
}

/// Runs `strategy` over a scene's `frames`.
pub fn run(strategy: StructureStrategy, frames: &[Frame], settings: &Settings) -> Vec<FrameRecord> {
    match strategy {
        StructureStrategy::GridSingle => run_grid(frames, settings, false, false),
        StructureStrategy::GridPackets => run_grid(frames, settings, true, false),
        StructureStrategy::GridOverlap => run_grid(frames, settings, false, true),
        StructureStrategy::Auto => run_auto(frames, settings),
    }
}

/// The rule on the first frame's profile, then the chosen structure's strategy.
fn run_auto(frames: &[Frame], settings: &Settings) -> Vec<FrameRecord> {
    let t = Instant::now();
    let profile = profile_mesh(&frames[0].0);
    let choice = choose_structure(&ChoiceInput {
        profile: Some(&profile),
    });
    let profile_s = t.elapsed().as_secs_f64();
    println!(
        "auto-structure: {} triangles, {}/{} empty bins ({:.2}), size spread {:.2}, χ² uniform {} → {:?}",
        profile.primitives,
        profile.empty_bins,
        profile.bins,
        empty_bin_fraction(&profile),
        profile.size_spread,
        profile.uniform,
        choice.structure
    );
    let mut records = match choice.structure {
        StructureKind::Grid => run_grid(frames, settings, false, false),
        StructureKind::Bvh => run_strategy(Strategy::Lauterbach(0.4), frames, settings, None),
    };
    records[0].update_s += profile_s;
    records
}

/// A grid rebuilt every frame (the first build, like every strategy's, is not timed), with or without
/// the overlap test, queried with single rays or packets.
fn run_grid(
    frames: &[Frame],
    settings: &Settings,
    packets: bool,
    overlap_test: bool,
) -> Vec<FrameRecord> {
    let options = GridOptions {
        parallel: false,
        overlap_test,
        ..Default::default()
    };
    let mut grid = UniformGrid::new(options).expect("λ 5, macrocells of 6: valid");
    let mut scratch = Scratch::default();
    frames
        .iter()
        .enumerate()
        .map(|(f, (mesh, rays, light, reference))| {
            let start = Instant::now();
            grid.rebuild(mesh).expect("scene meshes are valid");
            let update_s = if f == 0 {
                0.0
            } else {
                start.elapsed().as_secs_f64()
            };
            let (query_s, steps) = if packets {
                scratch.query_packets(&grid, rays, *light)
            } else {
                query(&grid, rays, *light)
            };
            let checked = &rays[..settings.checked_rays.min(rays.len())];
            let answer = |r: &Ray| {
                if packets {
                    // The timed run's answer for this ray.
                    let i = checked.iter().position(|c| std::ptr::eq(c, r))?;
                    scratch.hits[i].map(|h| h.t)
                } else {
                    grid.closest_hit(r).map(|h| h.t)
                }
            };
            FrameRecord {
                frame: f as u32,
                update_s,
                query_s,
                rebuilt: true,
                sah_ratio: f64::NAN,
                steps_ratio: steps as f64 / rays.len().max(1) as f64 / reference.steps.max(1e-30),
                mismatches: mismatches(answer, mesh, checked),
                guard_ratio: f64::NAN,
            }
        })
        .collect()
}

impl Traced for UniformGrid {
    fn closest(&self, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit> {
        self.closest_hit_counted(ray, stats)
    }
    fn any(&self, ray: &Ray, stats: &mut TraversalStats) -> bool {
        self.any_hit_counted(ray, stats)
    }
    /// Cells visited plus triangle tests.
    fn steps(stats: &TraversalStats) -> u64 {
        stats.inner_visits + stats.prim_tests
    }
}

/// A structure that answers the report's ray load in packets too (the grid's and the BVH's packet
/// traversals).
pub trait PacketTraced: Traced {
    fn closest_hits_packet(&self, rays: &[Ray], out: &mut [Option<Hit>], s: &mut TraversalStats);
    fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool], s: &mut TraversalStats);
}

impl PacketTraced for UniformGrid {
    fn closest_hits_packet(&self, rays: &[Ray], out: &mut [Option<Hit>], s: &mut TraversalStats) {
        UniformGrid::closest_hits_packet(self, rays, out, s)
    }
    fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool], s: &mut TraversalStats) {
        UniformGrid::any_hits_packet(self, rays, out, s)
    }
}

impl PacketTraced for MeshBvh {
    fn closest_hits_packet(&self, rays: &[Ray], out: &mut [Option<Hit>], s: &mut TraversalStats) {
        MeshBvh::closest_hits_packet(self, rays, out, s)
    }
    fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool], s: &mut TraversalStats) {
        MeshBvh::any_hits_packet(self, rays, out, s)
    }
}

/// Buffers of the packet queries, grown once.
#[derive(Default)]
pub struct Scratch {
    /// The closest hits of the last [`query_packets`](Self::query_packets), one per ray.
    pub hits: Vec<Option<Hit>>,
    shadows: Vec<Ray>,
    blocked: Vec<bool>,
}

impl Scratch {
    /// The report's ray load through `structure` in packets of [`PACKET`]: the closest hits, then the
    /// shadow rays of the hits toward the light.
    pub fn query_packets<T: PacketTraced>(
        &mut self,
        structure: &T,
        rays: &[Ray],
        light: Vec3,
    ) -> (f64, u64) {
        self.hits.resize(rays.len(), None);
        self.shadows.reserve(rays.len());
        self.blocked.reserve(rays.len());
        let mut stats = TraversalStats::default();
        let start = Instant::now();
        for (r, out) in rays.chunks(PACKET).zip(self.hits.chunks_mut(PACKET)) {
            structure.closest_hits_packet(r, out, &mut stats);
        }
        self.shadows.clear();
        self.shadows
            .extend(rays.iter().zip(&self.hits).filter_map(|(ray, h)| {
                let p = ray.at(h.as_ref()?.t);
                Some(Ray::with_range(p, light - p, 1e-4, 1.0))
            }));
        self.blocked.resize(self.shadows.len(), false);
        for (r, out) in self
            .shadows
            .chunks(PACKET)
            .zip(self.blocked.chunks_mut(PACKET))
        {
            structure.any_hits_packet(r, out, &mut stats);
        }
        (start.elapsed().as_secs_f64(), T::steps(&stats))
    }
}
