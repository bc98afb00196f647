//! The report's planned-option rows: the per-mesh options the ECS's planner picks under the adaptive
//! policy ([`Choice`]: structure, wide query tree, packets), each fixed alternative as a row beside the
//! planner's pick. All on `lauterbach-0.4` maintenance (the ECS's default; that row is the BVH with the
//! wide tree on and single rays):
//! - `bvh-packets`: the BVH's queries in packets of 16 consecutive rays (the report's rays are incoherent:
//!   see `grid_rows`), shadow rays too;
//! - `wide-off`: the binary tree only (no collapse per build, no wide refit);
//! - `planned-options`: per frame, the structure (`Choice::structure`, the BVH first, the profile rule's
//!   pick of the first frame as the grid's prior, its overhead expected at the grid frames' learned
//!   seconds per triangle, `GRID_RATE`; the BVH is only refitted under the grid, as in the ECS, and rebuilt by
//!   lauterbach-0.4's rule while it answers), then for the BVH the wide tree and packets
//!   (`Choice::wide`, `Choice::incoherent_packets`: the rays are incoherent), for the grid its
//!   overlap test (`Choice::overlap`), each learning the frame's measured update and query seconds
//!   (the structure not the first frame's update nor a switch's, which catches the BVH up, and nothing
//!   from a frame in which an option under it is tried; while a structure is tried, the options under
//!   it are held as settled, `Choice::hold`). Its picks (frames per option, and the structure's
//!   re-tries of a stale estimate, `Choice::retry_stale`) are in the summary's planned-options section.
//!
//! Same error terms and brute-force checks as every row: the answers checked are those the timed run gave.

use super::grid_rows::Scratch;
use super::harness::{Frame, FrameRecord, Settings, mismatches, query};
use kinetrace::adaptive::{Choice, Estimate};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::characterize::profile_mesh;
use kinetrace::grid::{ChoiceInput, GridOptions, StructureKind, UniformGrid, choose_structure};
use kinetrace::{MeshBvh, Ray};
use std::fmt::Write as _;
use std::sync::Mutex;
use std::time::Instant;

/// The option strategies, in their rows' order.
pub const STRATEGIES: [OptionStrategy; 3] = [
    OptionStrategy::BvhPackets,
    OptionStrategy::WideOff,
    OptionStrategy::Planned,
];

/// An option strategy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OptionStrategy {
    BvhPackets,
    WideOff,
    Planned,
}

impl OptionStrategy {
    pub fn name(&self) -> &'static str {
        match self {
            OptionStrategy::BvhPackets => "bvh-packets",
            OptionStrategy::WideOff => "wide-off",
            OptionStrategy::Planned => "planned-options",
        }
    }

    pub fn is_fixed(&self) -> bool {
        *self != OptionStrategy::Planned
    }
}

/// Frames of `planned-options` on each option: grid, wide off, packets on, overlap test on (of
/// `frames`; wide and packets counted over the BVH's frames, `bvh_frames`, the overlap test over the
/// grid's).
#[derive(Clone, Copy, Debug, Default)]
pub struct Picks {
    pub frames: usize,
    pub grid: usize,
    pub bvh_frames: usize,
    pub wide_off: usize,
    pub packets: usize,
    pub overlap: usize,
    /// Re-tries of the structure not in use, its estimate stale (`Choice::retry_stale`).
    pub retries: usize,
}

/// The picks of every `planned-options` run since the last [`take_picks`], in run order.
static PICKS: Mutex<Vec<Picks>> = Mutex::new(Vec::new());

/// The picks of the `planned-options` runs since the last call, summed (one scene's runs).
pub fn take_picks() -> Picks {
    let runs = std::mem::take(&mut *PICKS.lock().expect("not poisoned"));
    runs.iter().fold(Picks::default(), |a, p| Picks {
        frames: a.frames + p.frames,
        grid: a.grid + p.grid,
        bvh_frames: a.bvh_frames + p.bvh_frames,
        wide_off: a.wide_off + p.wide_off,
        packets: a.packets + p.packets,
        overlap: a.overlap + p.overlap,
        retries: a.retries + p.retries,
    })
}

/// Seconds per triangle of the `planned-options` grid frames' update (the grid's rebuild and the BVH's
/// refit under it), learned over every scene's runs since the report started: the structure choice's
/// expected grid overhead (`Choice::expect_overhead`) before a scene's grid was measured — on the rigid
/// bodies, whose BVH only refits, the priors' 2 × a refit was a third of the grid's update (issue 12).
static GRID_RATE: Mutex<Option<Estimate>> = Mutex::new(None);

/// The per-mesh planners of `planned-options`.
struct Planners {
    structure: Choice<StructureKind>,
    wide: Choice<bool>,
    packets: Choice<bool>,
    overlap: Choice<bool>,
}

/// Runs `strategy` over a scene's `frames`.
pub fn run(strategy: OptionStrategy, frames: &[Frame], settings: &Settings) -> Vec<FrameRecord> {
    let mut planners = (strategy == OptionStrategy::Planned).then(|| {
        let prior = choose_structure(&ChoiceInput {
            profile: Some(&profile_mesh(&frames[0].0)),
        });
        Planners {
            structure: Choice::structure(&prior),
            wide: Choice::wide(),
            packets: Choice::incoherent_packets(),
            overlap: Choice::overlap(),
        }
    });
    let build = |mesh, wide| {
        let options = BuildOptions::new(Builder::LBVH).wide(wide);
        MeshBvh::build(mesh, &options).expect("scene meshes are valid")
    };
    let options = GridOptions {
        parallel: false,
        ..Default::default()
    };
    let mut grid = UniformGrid::new(options).expect("λ 5, macrocells of 6: valid");
    let mut bvh = build(&frames[0].0, strategy != OptionStrategy::WideOff);
    let mut scratch = Scratch::default();
    let mut picks = Picks::default();
    let mut previous = None;
    let mut records = Vec::with_capacity(frames.len());
    for (f, (mesh, rays, light, reference)) in frames.iter().enumerate() {
        let n = rays.len() as f64;
        let triangles = mesh.triangle_count() as f64;
        if let Some(p) = &mut planners
            && let Some(rate) = GRID_RATE.lock().expect("not poisoned").as_ref()
            && let Some(per_triangle) = rate.mean()
        {
            p.structure
                .expect_overhead(StructureKind::Grid, per_triangle * triangles);
        }
        let (kind, wide, packets, overlap) = match (&mut planners, strategy) {
            (Some(p), _) => match p.structure.decide(n) {
                // A structure being tried is measured with its sub-options as settled (`Choice::hold`).
                StructureKind::Bvh if p.structure.explored() => {
                    (StructureKind::Bvh, p.wide.hold(), p.packets.hold(), false)
                }
                StructureKind::Bvh => (
                    StructureKind::Bvh,
                    p.wide.decide(n),
                    p.packets.decide(n),
                    false,
                ),
                StructureKind::Grid if p.structure.explored() => (
                    StructureKind::Grid,
                    p.wide.current(),
                    false,
                    p.overlap.hold(),
                ),
                StructureKind::Grid => (
                    StructureKind::Grid,
                    p.wide.current(),
                    false,
                    p.overlap.decide(n),
                ),
            },
            (None, s) => (
                StructureKind::Bvh,
                s != OptionStrategy::WideOff,
                s == OptionStrategy::BvhPackets,
                false,
            ),
        };
        let start = Instant::now();
        let mut rebuilt = f == 0;
        // Under the grid the BVH is only refitted, as in the ECS; it catches up when it answers again.
        let degradation = if f > 0 {
            bvh.refit(mesh.positions()).expect("same topology")
        } else {
            0.0
        };
        if kind == StructureKind::Bvh && degradation > 0.4 {
            bvh = build(mesh, wide);
            rebuilt = true;
        }
        bvh.set_wide(wide);
        if kind == StructureKind::Grid {
            grid.set_overlap_test(overlap);
            grid.rebuild(mesh).expect("scene meshes are valid");
            rebuilt = true;
        }
        let update_s = if f == 0 {
            0.0
        } else {
            start.elapsed().as_secs_f64()
        };
        let (query_s, steps) = match (kind, packets) {
            (StructureKind::Grid, _) => query(&grid, rays, *light),
            (StructureKind::Bvh, true) => scratch.query_packets(&bvh, rays, *light),
            (StructureKind::Bvh, false) => query(&bvh, rays, *light),
        };
        if let Some(p) = &mut planners {
            // The first frame has no update, and a switch's frame pays the catch-up of a BVH refitted
            // under the grid: neither is what the structure costs per frame. A frame in which the
            // wide tree or packets are tried measures that try, not the structure: it teaches only them.
            let sub_try = match kind {
                StructureKind::Bvh => p.wide.explored() || p.packets.explored(),
                StructureKind::Grid => p.overlap.explored(),
            };
            if f > 0 && previous == Some(kind) && !sub_try {
                p.structure.kept(kind, update_s);
                if kind == StructureKind::Grid {
                    let mut rate = GRID_RATE.lock().expect("not poisoned");
                    rate.get_or_insert_with(Estimate::default)
                        .add(update_s / triangles.max(1.0));
                }
            }
            previous = Some(kind);
            if !sub_try {
                p.structure.served(kind, n, query_s);
            }
            picks.frames += 1;
            picks.grid += (kind == StructureKind::Grid) as usize;
            if kind == StructureKind::Bvh {
                p.wide.kept(wide, update_s);
                p.wide.served(wide, n, query_s);
                p.packets.served(packets, n, query_s);
                picks.bvh_frames += 1;
                picks.wide_off += !wide as usize;
                picks.packets += packets as usize;
            } else if f > 0 {
                p.overlap.kept(overlap, update_s);
                p.overlap.served(overlap, n, query_s);
                picks.overlap += overlap as usize;
            }
        }
        let checked = &rays[..settings.checked_rays.min(rays.len())];
        let answer = |r: &Ray| match (kind, packets) {
            (StructureKind::Grid, _) => grid.closest_hit(r).map(|h| h.t),
            (StructureKind::Bvh, true) => {
                // The timed run's answer for this ray.
                let i = checked.iter().position(|c| std::ptr::eq(c, r))?;
                scratch.hits[i].map(|h| h.t)
            }
            (StructureKind::Bvh, false) => bvh.closest_hit(r).map(|h| h.t),
        };
        records.push(FrameRecord {
            frame: f as u32,
            update_s,
            query_s,
            rebuilt,
            sah_ratio: match kind {
                StructureKind::Bvh => bvh.bvh().sah_cost() / reference.sah.max(1e-30),
                StructureKind::Grid => f64::NAN,
            },
            steps_ratio: steps as f64 / n.max(1.0) / reference.steps.max(1e-30),
            mismatches: mismatches(answer, mesh, checked),
            guard_ratio: f64::NAN,
        });
    }
    if let Some(p) = &planners {
        picks.retries = p.structure.retries() as usize;
        PICKS.lock().expect("not poisoned").push(picks);
    }
    records
}

/// One scene's line of the planned-options section: the picks, and the planner's mean ms per frame
/// against each fixed alternative's, from the scene's `rows` (strategy name, mean total ms); `None`
/// where the scene did not run `planned-options` (a `--strategies` filter that leaves it out).
pub fn picks_row(scene: &str, picks: &Picks, rows: &[(String, f64)]) -> Option<String> {
    let find = |name: &str| rows.iter().find(|(n, _)| n == name).map(|r| r.1);
    let planned = find(OptionStrategy::Planned.name())?;
    let ms = |name: &str| find(name).unwrap_or(f64::NAN);
    let mut s = format!(
        "| {scene} | grid {}/{}, {} re-tries | wide off {}/{} | packets {}/{} | overlap {}/{} | {planned:.3} |",
        picks.grid,
        picks.frames,
        picks.retries,
        picks.wide_off,
        picks.bvh_frames,
        picks.packets,
        picks.bvh_frames,
        picks.overlap,
        picks.grid
    );
    for alt in ALTERNATIVES {
        let _ = write!(s, " {:.3} ({:.2}) |", ms(alt), planned / ms(alt));
    }
    Some(s)
}

/// The fixed alternatives of the planned options, in the section's columns.
const ALTERNATIVES: [&str; 5] = [
    "lauterbach-0.4",
    "grid-single",
    "grid-overlap",
    "wide-off",
    "bvh-packets",
];

/// The planned-options section of the summary, around the scenes' [`picks_row`]s; empty where no
/// scene has one.
pub fn picks_table(lines: &[String]) -> String {
    if lines.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "\n## Planned options\n\nThe ECS planner's per-mesh options (`planned-options`: structure, wide \
         tree, packets, each a `Choice` learning measured seconds) against each fixed alternative, all on \
         lauterbach-0.4 maintenance. Picks in frames (wide and packets over the BVH's frames, the \
         overlap test over the grid's); mean ms \
         per frame, the planner's over the alternative's in parentheses.\n\n\
         | scene | structure | wide | packets | overlap | planned ms |",
    );
    for alt in ALTERNATIVES {
        let _ = write!(s, " {alt} ms (planned /) |");
    }
    s.push('\n');
    s.push_str(&"|---".repeat(6 + ALTERNATIVES.len()));
    s.push_str("|\n");
    for l in lines {
        s.push_str(l);
        s.push('\n');
    }
    s
}
