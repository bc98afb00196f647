//! Suite `ecs-gpu`: the GPU-resident frame (`TraceConfig::resident`, `Latency::NextFrame`, characters
//! marked `GpuOnly`) against the CPU mode, for crowds of animated humanoids queried with batched rays and
//! shadow rays: per frame the bytes uploaded and read back, the submissions and blocking waits (means over
//! the frames after the first, which uploads the meshes), and the time per frame. The full run measures
//! 16, 64 and 256 characters of 10k triangles with 10k rays; `--quick` 4 and 16 of 2k with 1k. Crowds of at
//! most 16 also run with every character a `Collider` (the resident frame traverses on the GPU the pairs
//! whose world boxes overlap, culled on the CPU: O(n²) box tests, rows `pairs traversed / frame`). The
//! resident frame also runs under `RebuildPolicy::ADAPTIVE` (row `rebuilds / frame` for each resident
//! run, and `SAH/hybrid rebuilds / frame`: those of them with the builds the planner chose over GPU
//! LBVH, and `builds measured (run)`: trees built only to measure a build nobody measured, on the pose of
//! an asset's first rebuild that came due). Each crowd also runs resident with every character keeping its CPU mirror (no `GpuOnly`, the
//! default): what immediate queries cost a resident crowd, the CPU's skinning and maintenance beside the
//! GPU's (row `CPU skin + maintain / frame`). Every resident run reports `GPU bytes / triangle`
//! (`ResidentStats::bytes_per_triangle` of its last frame: trees, builders, the device's shared slots;
//! issue 15's target is 113). On a device with timestamp queries the resident runs add the
//! GPU's time per phase (means of `TraceStats::gpu_phases`). Where the
//! only adapter is a software one (lavapipe), its times say nothing of a GPU: the note says which adapter.

use crate::record::Records;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Vec3};
use kinetrace::Ray;
use kinetrace::anim::humanoid;
use kinetrace::ecs::*;
use kinetrace::scenes::SceneRng;
use std::sync::Arc;
use std::time::Instant;

const SUITE: &str = "ecs-gpu";
/// The rows of `TraceStats::gpu_phases`' fields, in their order.
const PHASE_METRICS: [&str; 4] = [
    "GPU maintain / frame",
    "GPU top level / frame",
    "GPU queries / frame",
    "GPU pairs / frame",
];

pub fn run(rec: &mut Records) {
    let adapter = match rec.gpu() {
        Ok(ctx) => ctx.adapter_name().to_string(),
        Err(e) => {
            println!("suite ecs-gpu skipped: {e}");
            return;
        }
    };
    println!(
        "suite ecs-gpu on {} with {adapter}",
        crate::record::machine()
    );
    let (counts, triangles, rays, frames): (&[usize], _, _, _) = if rec.quick {
        (&[4, 16], 2_000, 1_000, 6)
    } else {
        (&[16, 64, 256], 10_000, 10_000, 20)
    };
    let asset = Arc::new(humanoid(triangles));
    for &n in counts {
        let scene = format!("{n} characters x {triangles} tris + {rays} rays");
        println!("\n{scene}");
        for resident in [false, true] {
            crowd(
                rec,
                &scene,
                &asset,
                (n, false, false, false),
                rays,
                frames,
                resident,
            );
            if n <= 16 {
                crowd(
                    rec,
                    &scene,
                    &asset,
                    (n, true, false, false),
                    rays,
                    frames,
                    resident,
                );
            }
        }
        let adaptive = (n, false, true, false);
        crowd(rec, &scene, &asset, adaptive, rays, frames, true);
        let mirrored = (n, false, false, true);
        crowd(rec, &scene, &asset, mirrored, rays, frames, true);
    }
}

/// `frames` frames of `n` characters of `asset` on a grid (colliders when `colliders`, under the adaptive
/// policy when `adaptive`, resident characters keeping their CPU mirror when `mirror`), each queried with
/// `rays` closest-hit rays and as many shadow rays; records the per-frame means.
fn crowd(
    rec: &mut Records,
    scene: &str,
    asset: &Arc<kinetrace::anim::CharacterAsset>,
    (n, colliders, adaptive, mirror): (usize, bool, bool, bool),
    rays: usize,
    frames: usize,
    resident: bool,
) {
    let config = TraceConfig {
        mode: if resident {
            TraceMode::GpuRequired
        } else {
            TraceMode::Cpu
        },
        latency: Latency::NextFrame,
        resident,
        policy: if adaptive {
            RebuildPolicy::ADAPTIVE
        } else {
            RebuildPolicy::default()
        },
        ..Default::default()
    };
    let mut world = World::new();
    let mut schedule = Schedule::default();
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    let plugin = KinetracePlugin {
        config,
        ..Default::default()
    };
    if let Err(e) = plugin.try_build(&mut world, &mut schedule) {
        println!("  resident frame skipped: {e}");
        return;
    }
    let side = (n as f32).sqrt().ceil() as usize;
    for i in 0..n {
        let at = Vec3::new((i % side) as f32, 0.0, (i / side) as f32) * 1.5;
        let mut e = world.spawn(AnimationPlayer::bundle(
            asset,
            i % asset.clips.len(),
            0.1 * i as f32,
        ));
        e.insert(TraceTransform(Affine3A::from_translation(at)));
        if resident && !mirror {
            e.insert(GpuOnly);
        }
        if colliders {
            e.insert(Collider::default());
        }
    }
    let extent = side as f32 * 1.5;
    let mut r = SceneRng::new(3);
    let mut point = || {
        Vec3::new(
            r.range(-0.5, extent),
            r.range(0.0, 1.8),
            r.range(-0.5, extent),
        )
    };
    let requests: Vec<(Ray, Vec3, Vec3)> = (0..rays)
        .map(|_| {
            let (from, to) = (point() + Vec3::Y * 3.0, point());
            let light = point() + Vec3::new(0.0, 5.0, 0.0);
            (Ray::new(from, (to - from).normalize()), to, light)
        })
        .collect();
    let (mut up, mut down, mut submissions, mut waits, mut seconds) = (0, 0, 0, 0, 0.0);
    // GPU seconds per phase and the frames that reported them.
    let (mut phases, mut timed) = ([0.0; 4], 0);
    // Pairs traversed and trees rebuilt by the resident frame.
    let (mut traversed, mut rebuilds, mut sah_rebuilds) = (0, 0, 0);
    // Trees the adaptive planner built only to measure them (the first frame's too).
    let mut calibrations = 0;
    // The CPU's skinning and maintenance (the CPU mirror's cost in a resident run), seconds.
    let mut mirror_s = 0.0;
    // The resident trees' and builders' GPU bytes per triangle, as of the last frame (issue 15).
    let mut bytes_per_triangle = 0.0;
    for frame in 0..frames {
        let mut queue = world.resource_mut::<RayQueue>();
        for (i, (ray, to, light)) in requests.iter().enumerate() {
            queue.cast(i as u64, *ray, QueryFilter::default());
            queue.shadow(i as u64, *to, *light, QueryFilter::default());
        }
        let t = Instant::now();
        schedule.run(&mut world);
        let elapsed = t.elapsed().as_secs_f64();
        world.clear_trackers();
        calibrations += world.resource::<TraceStats>().resident.calibrations;
        // The first frame uploads the meshes and builds every tree: left out of the means.
        if frame > 0 {
            let c = world.resource::<TraceStats>().gpu;
            (up, down) = (up + c.uploaded_bytes, down + c.read_back_bytes);
            (submissions, waits) = (submissions + c.submissions, waits + c.blocking_waits);
            seconds += elapsed;
            let done = world.resource::<TraceStats>().resident;
            (traversed, rebuilds) = (traversed + done.pairs_traversed, rebuilds + done.rebuilds);
            bytes_per_triangle = done.bytes_per_triangle();
            sah_rebuilds += done.sah_rebuilds;
            let stats = world.resource::<TraceStats>();
            mirror_s += (stats.skin_time + stats.maintain_time).as_secs_f64();
            if let Some(p) = world.resource::<TraceStats>().gpu_phases {
                let spans = [p.maintain, p.top_level, p.queries, p.pairs];
                for (sum, d) in phases.iter_mut().zip(spans) {
                    *sum += d.as_secs_f64();
                }
                timed += 1;
            }
        }
    }
    let per = (frames - 1) as f64;
    let subject = match (resident, colliders, adaptive) {
        (true, _, true) => "GPU-resident, adaptive",
        (true, false, _) if mirror => "GPU-resident + CPU mirror",
        (true, false, _) => "GPU-resident",
        (true, true, _) => "GPU-resident + colliders",
        (false, false, _) => "CPU mode",
        (false, true, _) => "CPU mode + colliders",
    };
    rec.add(
        SUITE,
        scene,
        subject,
        "time per frame",
        seconds / per * 1e3,
        "ms",
    );
    if resident {
        rec.add(
            SUITE,
            scene,
            subject,
            "uploaded per frame",
            up as f64 / per,
            "B",
        );
        rec.add(
            SUITE,
            scene,
            subject,
            "read back per frame",
            down as f64 / per,
            "B",
        );
        rec.add(
            SUITE,
            scene,
            subject,
            "submissions per frame",
            submissions as f64 / per,
            "",
        );
        rec.add(
            SUITE,
            scene,
            subject,
            "blocking waits per frame",
            waits as f64 / per,
            "",
        );
        rec.add(
            SUITE,
            scene,
            subject,
            "rebuilds / frame",
            rebuilds as f64 / per,
            "",
        );
        rec.add(
            SUITE,
            scene,
            subject,
            "GPU bytes / triangle",
            bytes_per_triangle,
            "B",
        );
        if mirror {
            let ms = mirror_s / per * 1e3;
            rec.add(
                SUITE,
                scene,
                subject,
                "CPU skin + maintain / frame",
                ms,
                "ms",
            );
        }
        if adaptive {
            let sah = sah_rebuilds as f64 / per;
            rec.add(
                SUITE,
                scene,
                subject,
                "SAH/hybrid rebuilds / frame",
                sah,
                "",
            );
            let measured = calibrations as f64;
            rec.add(SUITE, scene, subject, "builds measured (run)", measured, "");
        }
        if colliders {
            let pairs = traversed as f64 / per;
            rec.add(SUITE, scene, subject, "pairs traversed / frame", pairs, "");
        }
        for (metric, sum) in PHASE_METRICS.into_iter().zip(phases) {
            if timed > 0 {
                rec.add(
                    SUITE,
                    scene,
                    subject,
                    metric,
                    sum / timed as f64 * 1e3,
                    "ms",
                );
            }
        }
    }
}
