//! The planner's sections of the report: the goal over the median of several runs, the cold start (the
//! first 30 frames of every scene) and a crowd of 256 instances of one character, whose planners share
//! one cost table (against one table per instance).

use super::harness::{FrameRecord, Settings, Strategy};
use glam::{Mat4, Vec3};
use kinetrace::adaptive::{AdaptivePolicy, Asset, Build, CostTable, TreeCost};
use kinetrace::anim::{humanoid, skin_positions};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::scenes::SceneRng;
use kinetrace::{Mesh, MeshBvh, Ray};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

fn total_s(records: &[FrameRecord]) -> f64 {
    records.iter().map(|r| r.update_s + r.query_s).sum()
}

/// Per strategy, the run (of `runs`, each a record list per strategy) whose total time is the median:
/// the one the report's rows, plots and goal are taken from. The lower median for an even count.
pub fn median_run(mut runs: Vec<Vec<Vec<FrameRecord>>>) -> Vec<Vec<FrameRecord>> {
    let strategies = runs.first().map_or(0, Vec::len);
    (0..strategies)
        .map(|s| {
            let mut order: Vec<usize> = (0..runs.len()).collect();
            order.sort_by(|&a, &b| total_s(&runs[a][s]).total_cmp(&total_s(&runs[b][s])));
            let median = order[(order.len() - 1) / 2];
            std::mem::take(&mut runs[median][s])
        })
        .collect()
}

/// Frames of the cold-start table.
const COLD_FRAMES: usize = 30;

/// One scene's first frames: mean milliseconds per frame of the adaptive strategy, of the fastest fixed
/// strategy over the same frames, and of lauterbach-0.4, with the adaptive strategy's rebuilds.
pub struct ColdStart {
    scene: &'static str,
    adaptive_ms: f64,
    best: (String, f64),
    lauterbach_ms: f64,
    rebuilds: usize,
}

impl ColdStart {
    pub fn of(
        scene: &'static str,
        strategies: &[Strategy],
        records: &[Vec<FrameRecord>],
    ) -> ColdStart {
        let ms = |r: &[FrameRecord]| {
            let first = &r[..r.len().min(COLD_FRAMES)];
            1e3 * total_s(first) / first.len().max(1) as f64
        };
        let find = |name: &str| strategies.iter().position(|s| s.name() == name);
        let best = strategies
            .iter()
            .zip(records)
            .filter(|(s, _)| s.is_fixed())
            .map(|(s, r)| (s.name(), ms(r)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or_default();
        let adaptive = find("adaptive")
            .map(|i| &records[i][..])
            .unwrap_or_default();
        ColdStart {
            scene,
            adaptive_ms: ms(adaptive),
            best,
            lauterbach_ms: find("lauterbach-0.4").map_or(f64::NAN, |i| ms(&records[i])),
            rebuilds: adaptive
                .iter()
                .take(COLD_FRAMES)
                .filter(|r| r.rebuilt)
                .count(),
        }
    }
}

/// The cold-start section of the summary.
pub fn cold_start_table(rows: &[ColdStart]) -> String {
    let mut s = format!(
        "\n## Cold start: the first {COLD_FRAMES} frames\n\nMean ms per frame over the first {COLD_FRAMES} \
         frames (the first build excluded, as in the table above), where exploration costs most.\n\n\
         | scene | adaptive ms | best fixed (first frames) | ms | adaptive / best | lauterbach-0.4 ms | \
         adaptive rebuilds |\n|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {:.3} | {} | {:.3} | {:.3} | {:.3} | {} |",
            r.scene,
            r.adaptive_ms,
            r.best.0,
            r.best.1,
            r.adaptive_ms / r.best.1,
            r.lauterbach_ms,
            r.rebuilds
        );
    }
    s
}

/// A crowd of instances of one character, each with its own tree and planner.
pub struct InstanceCrowd {
    pub instances: usize,
    pub shared: bool,
    /// Whether the process's heap was on transparent huge pages ([`huge_page_crowd`]).
    pub huge_pages: bool,
    /// Milliseconds of the first frame (every tree built or, with a shared table, copied from the first) and the median of the later half's frames.
    pub first_ms: f64,
    pub steady_ms: f64,
    /// Rebuilds with a build the instance's table had not measured on the asset (first builds excluded).
    pub explorations: usize,
    /// Rebuilds per build, first builds included.
    pub builds: Vec<(Build, usize)>,
    /// Instances that started from a copy of the first one's tree instead of a build.
    pub siblings: usize,
    /// Builds run only to measure them ([`AdaptivePolicy::calibration`]).
    pub calibrations: usize,
    /// Minor page faults of the first frame and of the steady frame (the one whose time is
    /// `steady_ms`), where the system counts them ([`minor_faults`]).
    pub first_faults: Option<u64>,
    pub steady_faults: Option<u64>,
}

/// The minor page faults this thread has taken so far (Linux: `getrusage(RUSAGE_THREAD)`), `None`
/// elsewhere. A fault is the kernel giving the process a fresh page on first touch: memory the heap had
/// not handed out before.
#[cfg(target_os = "linux")]
fn minor_faults() -> Option<u64> {
    #[repr(C)]
    struct Rusage {
        /// `ru_utime` and `ru_stime` (two `timeval`s).
        times: [i64; 4],
        /// `ru_maxrss` … `ru_nivcsw`; `ru_minflt` is the fifth.
        counts: [i64; 14],
    }
    unsafe extern "C" {
        fn getrusage(who: i32, usage: *mut Rusage) -> i32;
    }
    let mut r = Rusage {
        times: [0; 4],
        counts: [0; 14],
    };
    // SAFETY: `r` is a writable `struct rusage` (as laid out on 64-bit Linux); 1 is RUSAGE_THREAD.
    let ok = unsafe { getrusage(1, &mut r) } == 0;
    ok.then(|| r.counts[4] as u64)
}

#[cfg(not(target_os = "linux"))]
fn minor_faults() -> Option<u64> {
    None
}

/// Runs `instances` instances of one ~500-triangle character for `settings.frames` frames (at least 8),
/// each animated at its own phase, refitted or rebuilt as its planner says and queried by its share of
/// `settings.rays` (at least 2 rays each). With `shared`, every planner learns into one cost table;
/// otherwise each has its own and builds its own first tree; with one, every instance after the first
/// starts from a copy of the first one's tree and planner. Skinning is not timed; maintenance (copies
/// included) and queries are.
pub fn instance_crowd(settings: &Settings, instances: usize, shared: bool) -> InstanceCrowd {
    let asset = humanoid(500);
    let indices: std::sync::Arc<[u32]> = asset.mesh.indices().into();
    let key = Asset::of_indices(&indices);
    let builds = [Builder::LBVH, Builder::HYBRID, Builder::SAH].map(Build::cpu);
    let table = CostTable::new();
    let mut policies: Vec<AdaptivePolicy> = (0..instances)
        .map(|_| {
            let own = CostTable::new();
            let mut p = AdaptivePolicy::shared(&builds, if shared { &table } else { &own }, key);
            p.calibrates = true;
            p
        })
        .collect();
    let mut trees: Vec<Option<MeshBvh>> = (0..instances).map(|_| None).collect();
    let rays_each = (settings.rays / instances.max(1)).max(2);
    let (mut pose, clip) = (asset.skeleton.rest_pose(), &asset.clips[0]);
    let mut mats = vec![Mat4::IDENTITY; asset.skeleton.joints.len()];
    let rest = asset.mesh.positions();
    let mut crowd = InstanceCrowd {
        instances,
        shared,
        huge_pages: false,
        first_ms: 0.0,
        steady_ms: 0.0,
        explorations: 0,
        builds: Vec::new(),
        siblings: 0,
        calibrations: 0,
        first_faults: None,
        steady_faults: None,
    };
    let mut frame_ms = Vec::new();
    let mut frame_faults = Vec::new();
    for f in 0..settings.frames.max(8) {
        let t = f as f32 / 60.0;
        let meshes: Vec<Mesh> = (0..instances)
            .map(|i| {
                clip.sample(t + 0.37 * i as f32, &mut pose);
                asset.skeleton.skin_matrices(&pose, &mut mats);
                let mut skinned = vec![Vec3::ZERO; rest.len()];
                skin_positions(rest, &asset.weights, &mats, &mut skinned).expect("valid asset");
                Mesh::new(skinned, indices.clone()).expect("finite")
            })
            .collect();
        let faults = minor_faults();
        let start = Instant::now();
        for i in 0..instances {
            // With a shared table, an instance after the first starts from a copy of the first one's
            // tree and planner (`AdaptivePolicy::sibling`), refitted below like any tree.
            if shared && i > 0 && trees[i].is_none() {
                trees[i] = trees[0].clone();
                policies[i] = policies[0].sibling();
                crowd.siblings += 1;
            }
            let (mesh, tree, policy) = (&meshes[i], &mut trees[i], &mut policies[i]);
            let build = match tree {
                None => Some(policy.next_build()),
                Some(bvh) => {
                    bvh.refit(mesh.positions()).expect("same topology");
                    policy
                        .after_refit(TreeCost::of(bvh.bvh()), rays_each as f64)
                        .then(|| policy.prediction().build)
                }
            };
            if let Some(b) = build {
                let first = tree.is_none();
                crowd.explorations += (!first && !policy.costs().measured(&key, b)) as usize;
                match crowd.builds.iter_mut().find(|c| c.0 == b) {
                    Some(c) => c.1 += 1,
                    None => crowd.builds.push((b, 1)),
                }
                let t = Instant::now();
                let bvh = MeshBvh::build(mesh, &BuildOptions::new(b.builder)).expect("valid");
                let cost = TreeCost::of(bvh.bvh());
                policy.built(b, mesh.triangle_count(), t.elapsed().as_secs_f64(), cost);
                while let Some(c) = policy.calibration() {
                    let t = Instant::now();
                    let other = MeshBvh::build(mesh, &BuildOptions::new(c.builder)).expect("valid");
                    let s = t.elapsed().as_secs_f64();
                    policy.calibrated(c, mesh.triangle_count(), s, other.bvh().sah_cost());
                    crowd.calibrations += 1;
                }
                *tree = Some(bvh);
            }
            let bvh = tree.as_ref().expect("built");
            let bounds = bvh.bvh().bounds();
            let mut r = SceneRng::new(f as u64);
            let q = Instant::now();
            for _ in 0..rays_each {
                let from = bounds.center() + r.direction() * bounds.extent().length();
                let to = bounds.min + (bounds.max - bounds.min) * r.vec3(0.0, 1.0);
                std::hint::black_box(bvh.closest_hit(&Ray::new(from, to - from)));
            }
            let sah = bvh.bvh().sah_cost();
            policy.queried(rays_each as f64, sah, q.elapsed().as_secs_f64());
        }
        frame_ms.push(1e3 * start.elapsed().as_secs_f64());
        frame_faults.push(faults.zip(minor_faults()).map(|(a, b)| b - a));
    }
    crowd.first_ms = frame_ms[0];
    crowd.first_faults = frame_faults[0];
    let mut later: Vec<usize> = (frame_ms.len() / 2..frame_ms.len()).collect();
    later.sort_by(|&a, &b| frame_ms[a].total_cmp(&frame_ms[b]));
    let steady = later[later.len() / 2];
    crowd.steady_ms = frame_ms[steady];
    crowd.steady_faults = frame_faults[steady];
    crowd
}

/// Instances in the report's crowd.
pub const CROWD: usize = 256;

/// The environment that puts a glibc heap on transparent huge pages (glibc 2.35 or later; other C
/// libraries ignore it).
pub const HUGE_PAGE_HEAP: (&str, &str) = ("GLIBC_TUNABLES", "glibc.malloc.hugetlb=1");

/// The option that makes the report run only [`huge_page_crowd`]'s child part: the shared crowd, its
/// table row printed to standard output.
pub const CROWD_CHILD: &str = "--crowd-child";

/// The shared crowd again, in a child process (`exe`: the report's executable) whose heap glibc backs
/// with transparent huge pages ([`HUGE_PAGE_HEAP`]): the same work, with a page fault per 2 MiB of fresh
/// heap instead of per 4 KiB, so the table shows how much of the first frame is the kernel's. Its table
/// row, or why there is none (not Linux, or the child failed). Costs one more crowd run (about a second).
pub fn huge_page_crowd(exe: &Path, settings: &Settings) -> Result<String, String> {
    if !cfg!(target_os = "linux") {
        return Err("only on Linux".into());
    }
    let out = std::process::Command::new(exe)
        .args([CROWD_CHILD, "--frames", &settings.frames.to_string()])
        .args(["--rays", &settings.rays.to_string()])
        .env(HUGE_PAGE_HEAP.0, HUGE_PAGE_HEAP.1)
        .output()
        .map_err(|e| e.to_string())?;
    let row = String::from_utf8_lossy(&out.stdout);
    match (
        out.status.success(),
        row.lines().find(|l| l.starts_with('|')),
    ) {
        (true, Some(row)) => Ok(row.to_owned()),
        _ => Err(format!(
            "the child run failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )),
    }
}

/// The crowd's goal: the first frame costs at most twice a steady frame.
const FIRST_OVER_STEADY: f64 = 2.0;

/// One row of the instance-crowd table.
pub fn instance_crowd_row(r: &InstanceCrowd) -> String {
    let builds: Vec<String> = r.builds.iter().map(|(b, n)| format!("{b} {n}")).collect();
    let faults = match (r.first_faults, r.steady_faults) {
        (Some(a), Some(b)) => format!("{a} / {b}"),
        _ => "not counted".into(),
    };
    let table = match (r.shared, r.huge_pages) {
        (true, false) => "shared",
        (true, true) => "shared, heap on huge pages",
        (false, _) => "per instance",
    };
    let ratio = r.first_ms / r.steady_ms;
    // The goal is the shared table's (the plugin's); one table per instance is the comparison.
    let goal = match r.shared {
        true if ratio <= FIRST_OVER_STEADY && r.explorations == 0 => "yes",
        true => "NO",
        false => "—",
    };
    format!(
        "| {} | {table} | {:.3} | {:.3} | {ratio:.2} | {goal} | {faults} | {} | {} | {} | {} |",
        r.instances,
        r.first_ms,
        r.steady_ms,
        r.explorations,
        r.calibrations,
        r.siblings,
        builds.join(", ")
    )
}

/// The instance-crowd section of the summary, from [`instance_crowd_row`]s and, in place of the row
/// on huge pages, why it is missing.
pub fn instance_crowd_table(rows: &[String], huge_pages: Option<&str>) -> String {
    let mut s = format!(
        "\n## A crowd of instances of one character\n\nEvery instance has its own tree and planner; in the \
         first frame the first instance builds its tree and, with a shared table, every other one starts \
         from a copy of it refitted to its own pose (`AdaptivePolicy::sibling`; per instance, each \
         builds its own); a steady frame is the median of the later half. Goal: with the shared table, \
         the first frame costs at most {FIRST_OVER_STEADY} × a steady frame and no instance but the first \
         explores. The planners calibrate (`AdaptivePolicy::calibration`): an asset's builds are measured \
         at its first rebuild, not tried on frames of their own.\n\n\
         The crowd runs before the scenes, on a heap nothing has grown yet, so its first frame also \
         pays the kernel for every fresh page its trees take (the page faults: a steady frame takes \
         none). A process whose heap has held as much before (the scenes' meshes, freed) pays fewer. \
         The row on huge pages is the shared crowd in a child process started with `{}={}`: glibc \
         then asks for transparent huge pages for its heap, one fault per 2 MiB instead of per 4 KiB; \
         what its first frame saves is what the kernel charged (when the kernel has free 2 MiB blocks; \
         where it must compact memory first, that frame can cost more, not less).\n\n\
         | instances | cost table | first frame ms | steady frame ms | first / steady | goal | page \
         faults, first / steady | explorations | calibrations | sibling starts | builds |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
        HUGE_PAGE_HEAP.0, HUGE_PAGE_HEAP.1
    );
    for r in rows {
        s.push_str(r);
        s.push('\n');
    }
    if let Some(why) = huge_pages {
        let _ = writeln!(s, "\nNo row on huge pages: {why}.");
    }
    s
}
