//! Rows of suite `gpu` for PLOC: GPU and CPU build throughput, the SAH cost of the tree over a CPU binned-SAH
//! tree's, GPU memory per triangle, and the dispatches, submissions and clustering rounds of one GPU build.
//! The GPU build is timed as `GpuPloc::build_for_cpu`: upload, sort, rounds (each batch waited for), the
//! read-back and the CPU layout — what a caller of the CPU tree pays.

use crate::record::{Records, best_of};
use kinetrace::Mesh;
use kinetrace::bvh::{BuildOptions, Builder, DEFAULT_PLOC_RADIUS, MeshBvh};
use kinetrace::gpu::{GpuContext, GpuPloc};

const SUITE: &str = "gpu";

pub fn rows(rec: &mut Records, ctx: &GpuContext, name: &str, mesh: &Mesh) {
    let n = mesh.triangle_count() as f64;
    let reps = rec.reps();
    let mut ploc = GpuPloc::new(ctx, mesh, DEFAULT_PLOC_RADIUS).expect("upload");
    let (t_gpu, tree) = best_of(reps, || ploc.build_for_cpu(ctx, mesh).expect("gpu"));
    let opt = BuildOptions::new(Builder::PLOC).wide(false);
    let (t_cpu, cpu) = best_of(reps, || MeshBvh::build(mesh, &opt).unwrap());
    let sah = MeshBvh::build(mesh, &BuildOptions::new(Builder::SAH).wide(false)).unwrap();
    let counts = ploc.counts();
    let rows = [
        ("gpu ploc", "build", n / t_gpu / 1e6, "Mtris/s"),
        ("cpu ploc", "build all threads", n / t_cpu / 1e6, "Mtris/s"),
        (
            "gpu ploc",
            "SAH cost / cpu sah",
            tree.bvh().sah_cost() / sah.bvh().sah_cost(),
            "",
        ),
        (
            "gpu ploc",
            "equals cpu ploc",
            (tree.bvh() == cpu.bvh()) as u32 as f64,
            "bool",
        ),
        (
            "gpu ploc",
            "memory during build",
            ploc.memory_bytes() as f64 / n,
            "bytes/tri",
        ),
        (
            "gpu ploc",
            "dispatches per build",
            counts.dispatches as f64,
            "",
        ),
        (
            "gpu ploc",
            "submissions per build",
            counts.submissions as f64,
            "",
        ),
        ("gpu ploc", "clustering rounds", counts.rounds as f64, ""),
    ];
    for (subject, metric, value, unit) in rows {
        rec.add(SUITE, name, subject, metric, value, unit);
    }
}
