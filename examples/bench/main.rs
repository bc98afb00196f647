//! kinetrace benchmarks: one binary, one suite per area, peers measured in the same run.
//!
//! ```text
//! cargo run --release --example bench -- [SUITE ...] [--quick] [--json FILE]
//! ```
//! Suites: `cpu` (builders, refit, queries; obvhs and the bvh crate on the same triangles and rays),
//! `gpu` (LBVH build, refit and ray queries on the wgpu back end), `ecs` (the plugin's frame cost and
//! overhead), `skinning` (skinning throughput and crowd frame times), `collide` (collision queries on
//! animated characters and cloth, against parry3d), `grid` (per-frame uniform grid vs LBVH: build rate,
//! single-ray and packet queries), `queries` (sphere and capsule casts, closest points, containment and
//! sphere overlaps on a deforming mesh, refit included, against parry3d),
//! `raysort` (secondary rays: BVH, sorted BVH, CRSH and RAH), `shadows` (selective ray-traced hard shadows
//! on the crowd against the shadow map alone and a shadow ray per pixel), `sound` (order-3 sound propagation:
//! paths against the image-source count, time per ECS update in a room with 16 walking characters).
//! With no suite named, all run. `--quick` uses small scenes and few repetitions (under a minute);
//! `--json FILE` also writes every measurement as JSON: one object with `machine`, `gpu_adapter`
//! (`null` when no suite used a GPU), `gpu_details`, `gpu_error`, `quick`, `threads` and a `records`
//! array. Speed is only ever compared within one run: the tables print kinetrace/peer ratios, which
//! survive a noisy shared machine far better than times.

#[path = "../report/camera.rs"]
mod camera;
mod cli;
mod collide;
mod cpu;
#[path = "../crowd.rs"]
#[allow(dead_code)]
mod crowd;
mod ecs;
mod ecs_gpu;
mod gpu;
mod gpu_dacrt;
mod gpu_ploc;
mod gpu_pool;
mod gpu_sah;
mod grid;
mod peers;
mod queries;
mod rays;
mod raysort;
mod record;
#[path = "../report/scenes.rs"]
#[allow(dead_code)]
mod report_scenes;
mod shadows;
mod skinning;
mod sound;

fn main() -> std::process::ExitCode {
    cli::run(std::env::args().skip(1))
}
