//! Device limits: work past `max_compute_workgroups_per_dimension` is folded over (x, y) dispatches and
//! still equals brute force; what no dispatch or binding can hold is refused with `Error::Gpu`; a device
//! error in a submission comes back as `Error::Gpu`, not a panic. Runs on lavapipe in CI.
#![cfg(feature = "gpu")]

mod common;
use common::*;
use kinetrace::gpu::{
    GpuContext, GpuMeshBvh, GpuOptions, GpuPloc, GpuRays, GpuSahBuilder, GpuSahOptions, Query,
};
use kinetrace::{Error, Mesh, Ray};

/// Workgroups per dimension of the small-limit device: 8 × 8 groups of 256 cover 16,384 tree nodes, of 64
/// cover 4,096 rays.
const GROUPS: u32 = 8;

/// A device on this machine's adapter with its own limits except the ones `change` sets.
fn small(change: impl FnOnce(&mut wgpu::Limits)) -> Option<kinetrace::Result<GpuContext>> {
    let shared = gpu_or_skip()?;
    let mut limits = shared.limits();
    change(&mut limits);
    Some(GpuContext::with_options(&GpuOptions {
        limits: Some(limits),
        ..Default::default()
    }))
}

fn rays_at(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let mut r = rng(seed);
    let bounds = m.triangle_bounds();
    let (lo, hi) = bounds.iter().fold(
        (glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)),
        |(lo, hi), b| (lo.min(b.min), hi.max(b.max)),
    );
    (0..n)
        .map(|_| {
            let o = lo + (hi - lo) * rand_vec(&mut r, 0.0, 1.0);
            Ray::new(o, rand_dir(&mut r))
        })
        .collect()
}

fn expect_gpu_error<T>(r: kinetrace::Result<T>, what: &str) {
    match r {
        Err(Error::Gpu(msg)) => eprintln!("{what}: refused as expected: {msg}"),
        Err(e) => panic!("{what}: expected Error::Gpu, got {e}"),
        Ok(_) => panic!("{what}: expected Error::Gpu, got a result"),
    }
}

#[test]
fn folded_dispatches_build_and_trace_like_brute_force() {
    let Some(g) = small(|l| l.max_compute_workgroups_per_dimension = GROUPS) else {
        return;
    };
    let g = g.expect("a device with fewer workgroups per dimension");
    // 5,000 triangles: 9,999 nodes need 40 groups of 256 (8 × 5), 3,000 rays 47 groups of 64 (8 × 6).
    let m = soup(11, 5000);
    let mut bvh = GpuMeshBvh::new(&g, &m).unwrap();
    let mut enc = g.encoder();
    bvh.record_build(&g, &mut enc);
    g.submit(enc);
    let tree = bvh.read_tree(&g).unwrap();
    tree.validate(Some(&m.triangle_bounds())).unwrap();
    let rays = rays_at(&m, 12, 3000);
    let mut gr = GpuRays::new(&g);
    let closest = gr.run(&g, &bvh, &rays, Query::Closest).unwrap();
    let any = gr.run(&g, &bvh, &rays, Query::Any).unwrap();
    let mut hits = 0;
    for (i, ray) in rays.iter().enumerate() {
        let got = closest[i].primitive().map(|p| (p, closest[i].t));
        hits += got.is_some() as usize;
        assert_brute_hit(&m, ray, got, &format!("closest ray {i}"));
        assert_any_hit(
            &m,
            ray,
            any[i].primitive().is_some(),
            &format!("any-hit ray {i}"),
        );
    }
    assert!(
        hits > 100,
        "only {hits} of the rays hit: the test says little"
    );
}

#[test]
fn work_past_the_dispatch_limit_is_refused() {
    let Some(g) = small(|l| l.max_compute_workgroups_per_dimension = GROUPS) else {
        return;
    };
    let g = g.expect("a device with fewer workgroups per dimension");
    // 9,000 triangles: 17,999 nodes > 8 × 8 × 256.
    expect_gpu_error(
        GpuMeshBvh::new(&g, &soup(13, 9000)),
        "tree past the dispatch limit",
    );
    let m = soup(14, 100);
    let mut bvh = GpuMeshBvh::new(&g, &m).unwrap();
    let mut enc = g.encoder();
    bvh.record_build(&g, &mut enc);
    g.submit(enc);
    // 5,000 rays > 8 × 8 × 64.
    let rays = rays_at(&m, 15, 5000);
    let mut gr = GpuRays::new(&g);
    expect_gpu_error(
        gr.run(&g, &bvh, &rays, Query::Closest),
        "rays past the dispatch limit",
    );
    // Recorded without the check, the same dispatch is a device error: it comes back as Error::Gpu from
    // the submission's error scope, and the device goes on working afterwards.
    let mut enc = g.encoder();
    let readback = gr.record(&g, &mut enc, &bvh, &rays, Query::Closest);
    g.submit(enc);
    expect_gpu_error(readback.wait(&g), "a dispatch past the limit, submitted");
    let ok = gr.run(&g, &bvh, &rays[..100], Query::Closest).unwrap();
    for (i, ray) in rays[..100].iter().enumerate() {
        let got = ok[i].primitive().map(|p| (p, ok[i].t));
        assert_brute_hit(&m, ray, got, &format!("after the error, ray {i}"));
    }
}

#[test]
fn buffers_past_the_binding_limit_are_refused() {
    let Some(g) = small(|l| l.max_storage_buffer_binding_size = 64 << 10) else {
        return;
    };
    let g = g.expect("a device with a small storage binding");
    // 5,000 triangles: 9,999 nodes of 32 bytes = 320 KB > 64 KiB.
    expect_gpu_error(
        GpuMeshBvh::new(&g, &soup(16, 5000)),
        "nodes past the binding limit",
    );
    // 1,000 triangles fit (1,999 × 32 bytes < 64 KiB).
    let bvh = GpuMeshBvh::new(&g, &soup(17, 1000)).unwrap();
    // The SAH builder's bins share the tree's buffers with the small-split kernel; without it they are
    // their own buffer, here 501 queued nodes' bins (hundreds of KB): an error, not wgpu's panic.
    GpuSahBuilder::new(&g, &bvh, GpuSahOptions::default()).unwrap();
    expect_gpu_error(
        GpuSahBuilder::new(&g, &bvh, GpuSahOptions::default().small_split(false)),
        "SAH bins past the binding limit",
    );
}

#[test]
fn too_few_storage_buffers_per_stage_is_an_error() {
    // The LBVH kernels bind 9 storage buffers (the SAH builder 10, PLOC 12); WebGPU's default is 8.
    let Some(g) = small(|l| l.max_storage_buffers_per_shader_stage = 8) else {
        return;
    };
    expect_gpu_error(g, "kernels on a device with 8 storage buffers per stage");
}

/// The GPU SAH and hybrid builders write their own indirect arguments: on a device with 8 workgroups per
/// dimension they fold them over (x, y) at that limit, and build the same trees, node for node, as on
/// the full-limit device (whose trees `tests/gpu_sah.rs` checks against a CPU reference).
#[test]
fn sah_indirect_dispatches_fold_at_the_device_limit() {
    let Some(g) = small(|l| l.max_compute_workgroups_per_dimension = GROUPS) else {
        return;
    };
    let g = g.expect("a device with fewer workgroups per dimension");
    let full = gpu_or_skip().expect("the shared device exists when the small one does");
    // 1,500 triangles: up to 46 queued nodes of more than 32 triangles per level, 6 × 8 groups.
    let m = soup(13, 1500);
    for options in [GpuSahOptions::SAH, GpuSahOptions::hybrid(6)] {
        let tree = |ctx: &GpuContext| {
            let mut bvh = GpuMeshBvh::new(ctx, &m).unwrap();
            let sah = GpuSahBuilder::new(ctx, &bvh, options).unwrap();
            sah.build_for_cpu(ctx, &mut bvh, &m).unwrap().bvh().clone()
        };
        let (folded, reference) = (tree(&g), tree(&full));
        folded.validate(Some(&m.triangle_bounds())).unwrap();
        assert_eq!(folded.nodes(), reference.nodes(), "{options:?}");
    }
}

/// GPU PLOC sizes its per-cluster dispatches itself: on a device with 8 workgroups per dimension it folds
/// them at that limit and builds the same tree, node for node, as on the full-limit device (whose tree
/// `tests/gpu_ploc.rs` checks against CPU PLOC).
#[test]
fn ploc_indirect_dispatches_fold_at_the_device_limit() {
    let Some(g) = small(|l| l.max_compute_workgroups_per_dimension = GROUPS) else {
        return;
    };
    let g = g.expect("a device with fewer workgroups per dimension");
    let full = gpu_or_skip().expect("the shared device exists when the small one does");
    // 5,000 triangles: 20 groups of 256 clusters in the first rounds, 8 × 3 on the small device.
    let m = soup(17, 5000);
    let tree = |ctx: &GpuContext| {
        let mut ploc = GpuPloc::new(ctx, &m, 16).unwrap();
        ploc.build_for_cpu(ctx, &m).unwrap().bvh().clone()
    };
    let (folded, reference) = (tree(&g), tree(&full));
    folded.validate(Some(&m.triangle_bounds())).unwrap();
    assert_eq!(folded.nodes(), reference.nodes());
}
