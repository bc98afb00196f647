//! Rows of suite `gpu` for the BVH build on the task pool (`gpu::taskpool::build_bvh`): build throughput,
//! the SAH cost of the tree over a CPU binned-SAH tree's, GPU memory per triangle, and the rounds,
//! dispatches and submissions of one build (they follow the tree's height, not the triangle count). Timed
//! as a caller of the CPU tree pays it: buffers, upload, the pool's rounds (each batch waited for) and the
//! read-back.

use crate::record::{Records, best_of};
use kinetrace::Mesh;
use kinetrace::bvh::{BuildOptions, Builder, MeshBvh};
use kinetrace::gpu::GpuContext;
use kinetrace::gpu::taskpool::build_bvh;

const SUITE: &str = "gpu";

pub fn rows(rec: &mut Records, ctx: &GpuContext, name: &str, mesh: &Mesh) {
    let n = mesh.triangle_count() as f64;
    let (t, build) = best_of(rec.reps(), || build_bvh(ctx, mesh).expect("gpu"));
    let sah = MeshBvh::build(mesh, &BuildOptions::new(Builder::SAH).wide(false)).unwrap();
    let c = build.counts;
    let rows = [
        ("build", n / t / 1e6, "Mtris/s"),
        (
            "SAH cost / cpu sah",
            build.bvh.bvh().sah_cost() / sah.bvh().sah_cost(),
            "",
        ),
        ("memory during build", build.bytes as f64 / n, "bytes/tri"),
        ("dispatches per build", c.dispatches as f64, ""),
        ("submissions per build", c.submissions as f64, ""),
        ("pool rounds", c.rounds as f64, ""),
        ("pool tasks", c.tasks as f64, ""),
    ];
    for (metric, value, unit) in rows {
        rec.add(SUITE, name, "gpu pool build", metric, value, unit);
    }
}
