//! Rows of suite `gpu` for the work-queue binned SAH builder and the hybrid (issue 14): build throughput,
//! SAH cost over the CPU binned SAH's, bytes per triangle, dispatches and submissions per build, and the
//! small-split kernel's on/off time ratio. Wall-clock per build, submitted and waited for.

use crate::record::{Records, best_of};
use kinetrace::Mesh;
use kinetrace::bvh::{BuildOptions, Builder, Bvh};
use kinetrace::gpu::{GpuContext, GpuMeshBvh, GpuSahBuilder, GpuSahOptions, HYBRID_LEVELS};

const SUITE: &str = "gpu";

/// Builds `mesh` with GPU SAH (small-split kernel on and off) and the GPU hybrid, recording the rows.
pub fn rows(rec: &mut Records, ctx: &GpuContext, name: &str, mesh: &Mesh) {
    let n = mesh.triangle_count() as f64;
    let cpu_sah = Bvh::build(&mesh.triangle_bounds(), &BuildOptions::new(Builder::SAH))
        .expect("cpu sah")
        .sah_cost();
    let mut times = Vec::new();
    for (method, options) in [
        ("gpu sah", GpuSahOptions::SAH),
        (
            "gpu sah no small split",
            GpuSahOptions::SAH.small_split(false),
        ),
        ("gpu hybrid", GpuSahOptions::hybrid(HYBRID_LEVELS)),
    ] {
        let mut bvh = GpuMeshBvh::new(ctx, mesh).expect("upload");
        let sah = GpuSahBuilder::new(ctx, &bvh, options).expect("scratch");
        let (t, _) = best_of(rec.reps(), || {
            let mut enc = ctx.encoder();
            sah.record(ctx, &mut bvh, &mut enc);
            ctx.submit(enc);
            ctx.wait().expect("gpu")
        });
        times.push(t);
        let tree = bvh.read_tree(ctx).expect("read back");
        let counts = sah.read_counts(ctx).expect("counts");
        let bytes = (bvh.memory_bytes() + sah.memory_bytes()) as f64 / n;
        for (metric, value, unit) in [
            ("build", n / t / 1e6, "Mtris/s"),
            (
                "SAH cost / cpu binned sah",
                tree.sah_cost() / cpu_sah,
                "ratio",
            ),
            ("memory during build", bytes, "bytes/tri"),
            ("dispatches run", counts.dispatches_run as f64, "per build"),
            (
                "dispatches recorded",
                counts.dispatches_recorded as f64,
                "per build",
            ),
            ("submissions", counts.submissions as f64, "per build"),
        ] {
            rec.add(SUITE, name, method, metric, value, unit);
        }
    }
    rec.add(
        SUITE,
        name,
        "gpu sah",
        "small split off / on time",
        times[1] / times[0],
        "ratio",
    );
}
