//! Determinism across thread counts: every builder, refit and the batch queries give byte-equal trees and
//! answers with parallelism off and on rayon pools of 1, 2 and 7 threads (`ThreadPoolBuilder::install`, so
//! the work really is split differently; 7 oversubscribes a 2-core machine on purpose).
#![cfg(feature = "parallel")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::BuildOptions;
use kinetrace::{Hit, Mesh, MeshBvh, Ray};

/// Everything a run produces, as bytes: tree, slots, answers before and after a refit.
#[derive(PartialEq, Eq, Debug)]
struct Outcome {
    nodes: Vec<u8>,
    prims: Vec<u32>,
    slots: Vec<u8>,
    closest: Vec<u8>,
    any: Vec<bool>,
    refit_degradation: u32,
    refit_nodes: Vec<u8>,
    refit_closest: Vec<u8>,
    refit_any: Vec<bool>,
}

/// A hit record's bits (none: an empty record).
fn hit_bytes(hits: &[Option<Hit>]) -> Vec<u8> {
    let mut out = Vec::new();
    for h in hits.iter().flatten() {
        for w in [h.primitive, h.t.to_bits(), h.u.to_bits(), h.v.to_bits()]
            .into_iter()
            .chain(h.normal.to_array().map(f32::to_bits))
        {
            out.extend(w.to_le_bytes());
        }
    }
    out.extend(hits.iter().map(|h| h.is_some() as u8));
    out
}

fn answers(bvh: &MeshBvh, rays: &[Ray]) -> (Vec<u8>, Vec<bool>) {
    let mut closest = vec![None; rays.len()];
    bvh.closest_hits(rays, &mut closest);
    let mut any = vec![false; rays.len()];
    bvh.any_hits(rays, &mut any);
    (hit_bytes(&closest), any)
}

fn run(m: &Mesh, moved: &[Vec3], rays: &[Ray], opt: &BuildOptions) -> Outcome {
    let mut bvh = MeshBvh::build(m, opt).unwrap();
    let nodes = bytemuck::cast_slice(bvh.bvh().nodes()).to_vec();
    let prims = bvh.bvh().prim_indices().to_vec();
    let slots = bytemuck::cast_slice(bvh.slot_triangles()).to_vec();
    let (closest, any) = answers(&bvh, rays);
    let refit_degradation = bvh.refit(moved).unwrap().to_bits();
    let refit_nodes = bytemuck::cast_slice(bvh.bvh().nodes()).to_vec();
    let (refit_closest, refit_any) = answers(&bvh, rays);
    Outcome {
        nodes,
        prims,
        slots,
        closest,
        any,
        refit_degradation,
        refit_nodes,
        refit_closest,
        refit_any,
    }
}

#[test]
fn trees_and_answers_are_byte_equal_on_every_thread_count() {
    // 60k triangles: several 2^14-primitive chunks for the parallel binning and Morton passes, and subtrees
    // far above the parallel split size.
    let m = soup(21, 60_000);
    let moved: Vec<Vec3> = m
        .positions()
        .iter()
        .map(|p| *p + Vec3::new((p.y * 7.0).sin(), (p.z * 5.0).cos(), p.x) * 0.05)
        .collect();
    let mut r = rng(22);
    let rays: Vec<Ray> = (0..4000)
        .map(|_| Ray::new(rand_vec(&mut r, -0.5, 1.5), rand_dir(&mut r)))
        .collect();
    let pools: Vec<(usize, rayon::ThreadPool)> = [1, 2, 7]
        .map(|n| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap();
            (n, pool)
        })
        .into();
    for opt in all_build_options() {
        let reference = run(&m, &moved, &rays, &opt.parallel(false));
        assert!(
            reference.any.iter().any(|&h| h) && reference.any.iter().any(|&h| !h),
            "the rays must both hit and miss"
        );
        for (n, pool) in &pools {
            let got = pool.install(|| {
                assert_eq!(rayon::current_num_threads(), *n);
                run(&m, &moved, &rays, &opt.parallel(true))
            });
            // Field by field, so that a failure names what differs without printing megabytes.
            let what = format!("{opt:?} on {n} threads");
            assert!(got.nodes == reference.nodes, "{what}: nodes");
            assert!(got.prims == reference.prims, "{what}: primitive order");
            assert!(got.slots == reference.slots, "{what}: slot triangles");
            assert!(got.closest == reference.closest, "{what}: closest hits");
            assert!(got.any == reference.any, "{what}: any hits");
            assert_eq!(
                got.refit_degradation, reference.refit_degradation,
                "{what}: refit degradation"
            );
            assert!(
                got.refit_nodes == reference.refit_nodes,
                "{what}: refit nodes"
            );
            assert!(
                got.refit_closest == reference.refit_closest,
                "{what}: closest hits after refit"
            );
            assert!(
                got.refit_any == reference.refit_any,
                "{what}: any hits after refit"
            );
        }
    }
}
