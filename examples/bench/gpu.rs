//! Suite `gpu`: LBVH build (and the work-queue SAH and hybrid builds, [`crate::gpu_sah`], PLOC and the
//! task-pool build, [`crate::gpu_pool`]), refit, DACRT
//! against build + trace ([`crate::gpu_dacrt`]), and
//! closest/any-hit throughput on the GPU, for 100k, 1M and 4M
//! triangles (quick: 100k), with 1M coherent and 1M random rays (quick: 64k). Wall-clock per submitted
//! phase, waited for: on a real GPU this includes submission latency, so small sizes understate throughput.

use crate::record::{Records, best_of};
use kinetrace::Mesh;
use kinetrace::gpu::{BuildPhase, GpuContext, GpuMeshBvh, GpuRays, Query};
use kinetrace::scenes::bumpy_torus;

const SUITE: &str = "gpu";

pub fn run(rec: &mut Records) {
    let ctx = match rec.gpu() {
        Ok(c) => c,
        Err(e) => {
            println!("suite gpu skipped: {e}");
            return;
        }
    };
    println!(
        "suite gpu on {} ({})",
        ctx.adapter_name(),
        ctx.adapter_details()
    );
    let sizes: &[usize] = if rec.quick {
        &[100_000]
    } else {
        &[100_000, 1_000_000, 4_000_000]
    };
    let ray_count = if rec.quick { 1 << 16 } else { 1 << 20 };
    for &n in sizes {
        let mesh = bumpy_torus(n);
        scene(
            rec,
            &ctx,
            &format!("surface {}k", mesh.triangle_count() / 1000),
            &mesh,
            ray_count,
        );
    }
    crate::gpu_dacrt::rows(rec, &ctx);
}

fn scene(rec: &mut Records, ctx: &GpuContext, name: &str, mesh: &Mesh, ray_count: usize) {
    let n = mesh.triangle_count() as f64;
    let reps = rec.reps();
    println!("\n{name}: {} triangles", mesh.triangle_count());
    let mut bvh = GpuMeshBvh::new(ctx, mesh).expect("upload");
    let (t_build, _) = best_of(reps, || {
        let mut enc = ctx.encoder();
        bvh.record_build(ctx, &mut enc);
        ctx.submit(enc);
        ctx.wait().expect("gpu")
    });
    rec.add(
        SUITE,
        name,
        "gpu lbvh",
        "build",
        n / t_build / 1e6,
        "Mtris/s",
    );
    // The two phases apart: each submitted and waited for alone (the tree phase after a fresh sort).
    for (phase, label) in [
        (BuildPhase::Sort, "build: bounds+codes+sort"),
        (BuildPhase::Tree, "build: tree+boxes"),
    ] {
        let mut best = f64::INFINITY;
        for _ in 0..reps {
            if phase == BuildPhase::Tree {
                let mut enc = ctx.encoder();
                bvh.record_build_phase(ctx, &mut enc, BuildPhase::Sort);
                ctx.submit(enc);
                ctx.wait().expect("gpu");
            }
            let start = std::time::Instant::now();
            let mut enc = ctx.encoder();
            bvh.record_build_phase(ctx, &mut enc, phase);
            ctx.submit(enc);
            ctx.wait().expect("gpu");
            best = best.min(start.elapsed().as_secs_f64());
        }
        rec.add(SUITE, name, "gpu lbvh", label, n / best / 1e6, "Mtris/s");
    }
    let (t_refit, _) = best_of(reps, || {
        let mut enc = ctx.encoder();
        bvh.record_refit(ctx, &mut enc).expect("built");
        ctx.submit(enc);
        ctx.wait().expect("gpu")
    });
    rec.add(
        SUITE,
        name,
        "gpu refit",
        "refit",
        n / t_refit / 1e6,
        "Mtris/s",
    );
    rec.add(
        SUITE,
        name,
        "gpu lbvh",
        "memory during build",
        bvh.memory_bytes() as f64 / n,
        "bytes/tri",
    );
    crate::gpu_sah::rows(rec, ctx, name, mesh);

    crate::gpu_ploc::rows(rec, ctx, name, mesh);
    crate::gpu_pool::rows(rec, ctx, name, mesh);

    let [(_, camera), (_, random)] = crate::rays::camera_and_random(mesh, ray_count);
    let mut gr = GpuRays::new(ctx);
    for (kind, rays) in [("coherent", &camera), ("random", &random)] {
        for (q, metric) in [(Query::Closest, "closest"), (Query::Any, "any-hit")] {
            let (t, _) = best_of(reps, || gr.run(ctx, &bvh, rays, q).expect("gpu"));
            rec.add(
                SUITE,
                name,
                &format!("gpu {kind}"),
                metric,
                rays.len() as f64 / t / 1e6,
                "Mrays/s",
            );
        }
    }
}
