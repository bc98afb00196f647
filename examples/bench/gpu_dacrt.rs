//! Rows of suite `gpu` for DACRT on the task pool (seed 004 §6.2): one batch of closest-hit rays traced by
//! DACRT (no tree) against GPU LBVH build + closest-hit traversal of the same batch, as the seed measures
//! it, and the pool's rounds, tasks and submissions. Its own smaller scene (20k triangles, 16k rays of
//! each kind; quick: 10k and 4k), since DACRT copies rays and triangles per level. Both sides timed as a
//! caller sees them: upload, GPU work, read-back.

use crate::record::{Records, best_of};
use kinetrace::gpu::taskpool::{DacrtOptions, dacrt};
use kinetrace::gpu::{GpuContext, GpuMeshBvh, GpuRays, Query};
use kinetrace::scenes::bumpy_torus;

const SUITE: &str = "gpu";

pub fn rows(rec: &mut Records, ctx: &GpuContext) {
    let (tris, ray_count) = if rec.quick {
        (10_000, 1 << 12)
    } else {
        (20_000, 1 << 14)
    };
    let mesh = bumpy_torus(tris);
    let name = format!("dacrt surface {}k", mesh.triangle_count() / 1000);
    let reps = rec.reps();
    println!("\n{name}: {} triangles", mesh.triangle_count());
    for (kind, rays) in crate::rays::camera_and_random(&mesh, ray_count) {
        let m = rays.len() as f64;
        let run = || dacrt(ctx, &mesh, &rays, &DacrtOptions::default());
        let (t_dacrt, out) = best_of(reps, run);
        let counts = match out {
            Ok((_, counts)) => counts,
            Err(e) => {
                println!("dacrt {kind} skipped: {e}");
                continue;
            }
        };
        let (t_bvh, _) = best_of(reps, || {
            let mut bvh = GpuMeshBvh::new(ctx, &mesh).expect("upload");
            let mut enc = ctx.encoder();
            bvh.record_build(ctx, &mut enc);
            ctx.submit(enc);
            GpuRays::new(ctx)
                .run(ctx, &bvh, &rays, Query::Closest)
                .expect("gpu")
        });
        let rows = [
            ("closest", m / t_dacrt / 1e6, "Mrays/s"),
            ("time / (lbvh build + trace)", t_dacrt / t_bvh, "x"),
            ("pool rounds", counts.rounds as f64, "count"),
            ("pool tasks", counts.tasks as f64, "count"),
            ("pool submissions", counts.submissions as f64, "count"),
        ];
        for (metric, value, unit) in rows {
            rec.add(
                SUITE,
                &name,
                &format!("gpu dacrt {kind}"),
                metric,
                value,
                unit,
            );
        }
        rec.add(
            SUITE,
            &name,
            &format!("gpu lbvh build+trace {kind}"),
            "closest",
            m / t_bvh / 1e6,
            "Mrays/s",
        );
    }
}
