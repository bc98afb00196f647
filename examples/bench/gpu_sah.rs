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
    let mut times = [None; 3];
    for (k, (method, options)) in [
        ("gpu sah", GpuSahOptions::SAH),
        (
            "gpu sah no small split",
            GpuSahOptions::SAH.small_split(false),
        ),
        ("gpu hybrid", GpuSahOptions::hybrid(HYBRID_LEVELS)),
    ]
    .into_iter()
    .enumerate()
    {
        let mut bvh = GpuMeshBvh::new(ctx, mesh).expect("upload");
        // Without the small-split kernel the bins are their own buffer, past the binding limit at a few
        // million triangles on most devices: the row says so instead.
        let sah = match GpuSahBuilder::new(ctx, &bvh, options) {
            Ok(sah) => sah,
            Err(e) => {
                println!("  {method:<34} skipped: {e}");
                continue;
            }
        };
        let (t, _) = best_of(rec.reps(), || {
            let mut enc = ctx.encoder();
            sah.record(ctx, &mut bvh, &mut enc);
            ctx.submit(enc);
            ctx.wait().expect("gpu")
        });
        times[k] = Some(t);
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
    if let [Some(on), Some(off), _] = times {
        rec.add(
            SUITE,
            name,
            "gpu sah",
            "small split off / on time",
            off / on,
            "ratio",
        );
    }
}
