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

/// A batched closest hit as bits: (mesh's spawn index, triangle, distance).
type HitBits = Option<(usize, u32, u32)>;

/// What an ECS run produces per frame, as bits: the maintenance counts, each mesh's action and
/// degradation (by spawn index), and the batched closest hits.
#[derive(PartialEq, Debug)]
struct Frame {
    refits_ahead: usize,
    refits: usize,
    rebuilds: usize,
    meshes: Vec<(usize, String, u32)>,
    hits: Vec<(u64, HitBits)>,
}

/// Six deforming meshes under Lauterbach's rule at 0.05 (rebuilds now and then, decided by the
/// degradation alone, no timing), twelve frames of 400 batched rays.
fn ecs_run() -> Vec<Frame> {
    use bevy_ecs::prelude::*;
    use kinetrace::ecs::*;
    use kinetrace::scenes::{bumpy_torus, icosphere};
    let (mut world, mut schedule) = common::ecs::app_with(TraceConfig {
        policy: RebuildPolicy::Lauterbach { threshold: 0.05 },
        ..Default::default()
    });
    let meshes: Vec<Mesh> = (0..6)
        .map(|i| match i % 2 {
            0 => icosphere(3 + i as u32 / 4),
            _ => bumpy_torus(2000 + 700 * i),
        })
        .collect();
    let entities: Vec<Entity> = (meshes.iter().enumerate())
        .map(|(i, m)| {
            let at = glam::Affine3A::from_translation(Vec3::new(3.0 * i as f32, 0.0, 0.0));
            world.spawn((TraceMesh(m.clone()), TraceTransform(at))).id()
        })
        .collect();
    let index = |e: Entity| entities.iter().position(|&x| x == e).unwrap();
    let mut r = rng(23);
    let mut frames = Vec::new();
    for f in 0..12 {
        for (i, (&e, m)) in entities.iter().zip(&meshes).enumerate() {
            let phase = 0.4 * f as f32 + i as f32;
            let moved: Vec<Vec3> = (m.positions().iter())
                .map(|p| {
                    *p + Vec3::new((p.y * 4.0 + phase).sin(), 0.0, (p.x * 3.0).cos())
                        * 0.03
                        * f as f32
                })
                .collect();
            world.entity_mut(e).insert(VertexPositions(moved));
        }
        for tag in 0..400 {
            let from = rand_vec(&mut r, -2.0, 17.0) * Vec3::new(1.0, 0.0, 0.2) + Vec3::Y * 5.0;
            let ray = Ray::new(from, rand_vec(&mut r, -1.0, 1.0) - Vec3::Y * 2.0);
            (world.resource_mut::<RayQueue>()).cast(tag, ray, QueryFilter::default());
        }
        schedule.run(&mut world);
        world.clear_trackers();
        let stats = world.resource::<TraceStats>();
        let mut meshes: Vec<(usize, String, u32)> = (stats.meshes.iter())
            .map(|m| {
                (
                    index(m.entity),
                    format!("{:?}", m.action),
                    m.degradation.to_bits(),
                )
            })
            .collect();
        meshes.sort_by_key(|m| m.0);
        let hits = (world.resource::<RayResults>().hits.iter())
            .map(|(tag, h)| {
                (
                    *tag,
                    h.as_ref()
                        .map(|h| (index(h.entity), h.triangle, h.distance.to_bits())),
                )
            })
            .collect();
        frames.push(Frame {
            refits_ahead: stats.refits_ahead,
            refits: stats.refits,
            rebuilds: stats.rebuilds,
            meshes,
            hits,
        });
    }
    frames
}

/// Through the ECS: the refits run ahead of the maintenance loop in parallel across meshes
/// (`TraceStats::refits_ahead`) leave every frame's actions, degradations and batched answers bit for
/// bit those of a one-thread pool, on 2 and 7 threads; and every kept mesh is refitted ahead.
#[test]
fn ecs_frames_are_bit_equal_on_every_thread_count() {
    let on = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        pool.install(ecs_run)
    };
    let reference = on(1);
    assert_eq!(
        reference[0].rebuilds, 6,
        "the first frame builds every mesh"
    );
    for f in &reference[1..] {
        // Refitted ahead, then kept or rebuilt by the rule on the refit's degradation.
        assert_eq!(f.refits_ahead, 6, "every mesh refitted ahead: {f:?}");
        assert_eq!(f.refits + f.rebuilds, 6);
    }
    let rebuilt: usize = reference[1..].iter().map(|f| f.rebuilds).sum();
    assert!(rebuilt > 0, "the rule rebuilds some refitted meshes");
    let hits = reference.iter().flat_map(|f| &f.hits);
    assert!(hits.clone().any(|h| h.1.is_some()) && hits.clone().any(|h| h.1.is_none()));
    for n in [2, 7] {
        let got = on(n);
        for (f, (a, b)) in reference.iter().zip(&got).enumerate() {
            assert!(a == b, "frame {f} on {n} threads: {b:?} against {a:?}");
        }
    }
}
