//! The GPU task pool of seed 004 (`kinetrace::gpu::taskpool`) on its toy task, a recursive halving of a range
//! into a tree whose tasks sum their ranges in work chunks: the tree read back equals the one a plain CPU
//! recursion builds (ranges, parents, depths, sums), across sizes, leaf sizes and chunk sizes that make
//! tasks of zero, one and many chunks; a pool too small fails with `Error::TaskPoolFull`. DACRT on the pool:
//! closest hits against brute force and the GPU BVH traversal. Runs on lavapipe
//! in CI (`KINETRACE_REQUIRE_GPU=1` makes a missing adapter a failure; without it the tests skip).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::gpu::taskpool::{SumTask, sum_tree};
use kinetrace::scenes::soup;
use kinetrace::{Error, Ray};

/// A task as the oracle sees it: (range, parent range, depth, sum).
type Task = ((u32, u32), Option<(u32, u32)>, u32, u32);

/// The CPU oracle: the same halving by recursion.
fn cpu_tree(
    values: &[u32],
    range: (u32, u32),
    parent: Option<(u32, u32)>,
    depth: u32,
    leaf: u32,
    out: &mut Vec<Task>,
) {
    let (lo, hi) = range;
    let sum = values[lo as usize..hi as usize]
        .iter()
        .fold(0u32, |a, &v| a.wrapping_add(v));
    out.push((range, parent, depth, sum));
    if hi - lo > leaf {
        let mid = lo + (hi - lo) / 2;
        cpu_tree(values, (lo, mid), Some(range), depth + 1, leaf, out);
        cpu_tree(values, (mid, hi), Some(range), depth + 1, leaf, out);
    }
}

/// Pseudo-random values (an LCG), large enough that sums wrap.
fn values(n: usize) -> Vec<u32> {
    let mut x = 0x9e37_79b9u32;
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            x
        })
        .collect()
}

/// GPU tasks in the oracle's terms, sorted; also checks the child links the GPU wrote.
fn as_oracle(tasks: &[SumTask]) -> Vec<Task> {
    for (id, t) in tasks.iter().enumerate() {
        if let Some(c) = t.first_child {
            for child in [c, c + 1] {
                assert_eq!(tasks[child as usize].parent, Some(id as u32));
            }
            let (l, r) = (tasks[c as usize].range, tasks[c as usize + 1].range);
            assert_eq!((l.0, l.1, r.1), (t.range.0, r.0, t.range.1));
        }
    }
    let mut v: Vec<_> = tasks
        .iter()
        .map(|t| {
            let parent = t.parent.map(|p| tasks[p as usize].range);
            (t.range, parent, t.depth, t.sum)
        })
        .collect();
    v.sort();
    v
}

#[test]
fn sum_tree_equals_cpu_recursion() {
    let Some(gpu) = gpu_or_skip() else { return };
    for n in [0usize, 1, 2, 3, 31, 32, 33, 1023, 1025, 20_000] {
        for (leaf, chunk) in [(1, 1), (4, 3), (64, 256), (1000, 7)] {
            let v = values(n);
            let (tasks, counts) = sum_tree(&gpu, &v, leaf, chunk, 4 * n as u32 + 1).unwrap();
            let mut want = Vec::new();
            cpu_tree(&v, (0, n as u32), None, 0, leaf, &mut want);
            want.sort();
            let got = as_oracle(&tasks);
            let first_diff = got.iter().zip(&want).position(|(g, w)| g != w);
            assert!(
                got.len() == want.len() && first_diff.is_none(),
                "n {n} leaf {leaf} chunk {chunk}: {} tasks for {}, first difference at {first_diff:?}: {:?} vs {:?}",
                got.len(),
                want.len(),
                first_diff.map(|i| got[i]),
                first_diff.map(|i| want[i]),
            );
            let depth = want.iter().map(|t| t.2).max().unwrap();
            assert_eq!(counts.rounds, depth + 1, "one round per level");
            let chunks: u32 = want.iter().map(|t| (t.0.1 - t.0.0).div_ceil(chunk)).sum();
            assert_eq!(counts.chunks, chunks, "every chunk ran once");
        }
    }
}

#[test]
fn pool_too_small_is_an_error() {
    let Some(gpu) = gpu_or_skip() else { return };
    let v = values(1000);
    // Halving 1000 elements down to 1 needs 1999 tasks.
    let (tasks, _) = sum_tree(&gpu, &v, 1, 16, 1999).unwrap();
    assert_eq!(tasks.len(), 1999);
    match sum_tree(&gpu, &v, 1, 16, 1998) {
        Err(Error::TaskPoolFull { capacity, asked }) => {
            assert_eq!(capacity, 1998);
            assert!(asked > capacity);
        }
        other => panic!("expected TaskPoolFull, got {other:?}"),
    }
    assert!(matches!(
        sum_tree(&gpu, &v, 1, 16, 0),
        Err(Error::InvalidOption(_))
    ));
}

/// Past 2^16 tasks (32768 live tasks and chunks in one round): a work kernel whose few persistent
/// workgroups claimed every chunk ran past llvmpipe's 65535 loop iterations per invocation, and 8 chunks
/// were summed into the wrong task. Each invocation now claims a bounded number of chunks.
#[test]
fn sum_tree_past_two_to_the_sixteen_tasks() {
    let Some(gpu) = gpu_or_skip() else { return };
    let n = 32769;
    let v = values(n);
    let (tasks, counts) = sum_tree(&gpu, &v, 1, 1, 2 * n as u32).unwrap();
    let mut want = Vec::new();
    cpu_tree(&v, (0, n as u32), None, 0, 1, &mut want);
    want.sort();
    let got = as_oracle(&tasks);
    let wrong = got.iter().zip(&want).filter(|(g, w)| g != w).count();
    assert!(
        got.len() == want.len() && wrong == 0,
        "{wrong} tasks differ"
    );
    assert_eq!(counts.chunks, 16 * n as u32 + 2, "every chunk ran once");
}

/// DACRT's closest hits equal the GPU BVH traversal's (same triangle test) or, where they differ (ties at
/// shared edges), both are allowed by the oracle, and the brute-force oracle's (an independent exact triangle test), on meshes of 0 to 1025
/// triangles and on the extreme scenes (identical triangles, a tiny mesh in a huge one).
#[test]
fn dacrt_equals_bvh_traversal_and_brute_force() {
    use kinetrace::bvh::{BuildOptions, Builder};
    use kinetrace::gpu::taskpool::{DacrtOptions, dacrt};
    use kinetrace::gpu::{GpuMeshBvh, GpuRays, Query};
    use kinetrace::{Mesh, MeshBvh};
    let Some(gpu) = gpu_or_skip() else { return };
    let mut scenes: Vec<(String, Mesh)> = [0usize, 1, 2, 3, 31, 32, 33, 1023, 1025]
        .iter()
        .map(|&n| (format!("soup {n}"), soup(n as u64 + 1, n)))
        .collect();
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(300)).unwrap();
    scenes.push(("identical".into(), same));
    scenes.push(("teapot in a stadium".into(), teapot_in_stadium(2)));
    for (name, m) in &scenes {
        let mut rays = if m.triangle_count() == 0 {
            vec![Ray::new(Vec3::ZERO, Vec3::X)]
        } else {
            scene_rays(m, 3, 1000)
        };
        // Rays at the tiny mesh, from afar and from just above it.
        rays.extend(
            [Vec3::X, -Vec3::Y, -Vec3::Z].map(|d| Ray::new(Vec3::splat(0.25) - d * 4e3, d)),
        );
        rays.extend((0..200).map(|i| {
            let d = Vec3::new((i as f32).sin(), (i as f32).cos(), -3.0);
            Ray::new(Vec3::splat(0.25) + Vec3::new(0.0, 0.0, 3e-6), d)
        }));
        let (hits, _) = dacrt(&gpu, m, &rays, &DacrtOptions::default()).unwrap();
        assert_eq!(hits.len(), rays.len());
        for (ray, h) in rays.iter().zip(&hits) {
            assert_brute_hit(m, ray, h.prim.map(|p| (p, h.t)), name);
        }
        let (mut found, mut differ) = (0, 0);
        if m.triangle_count() > 0 {
            let cpu = MeshBvh::build(m, &BuildOptions::new(Builder::SAH)).unwrap();
            let gb = GpuMeshBvh::from_cpu(&gpu, m, &cpu).unwrap();
            let bvh = GpuRays::new(&gpu)
                .run(&gpu, &gb, &rays, Query::Closest)
                .unwrap();
            for (i, ((d, b), ray)) in hits.iter().zip(&bvh).zip(&rays).enumerate() {
                let (got, want) = (d.prim.map(|p| (p, d.t)), b.primitive().map(|p| (p, b.t)));
                found += got.is_some() as usize;
                // Equal as numbers (DACRT orders distances by their bits and reports -0 as 0), or both
                // allowed by the oracle: at an exact tie DACRT names the lowest triangle at that distance,
                // the traversal the lowest it reached (see MeshBvh's docs).
                if got != want {
                    assert_same_hit(m, ray, got, want, &format!("{name} ray {i}"));
                    differ += 1;
                }
            }
        }
        eprintln!("{name}: {found} hits, {differ} differ from the traversal's, both allowed");
        if name.starts_with("soup") && m.triangle_count() >= 31 {
            assert!(found > rays.len() / 4, "{name}: only {found} hits");
        }
    }
}

#[test]
fn dacrt_out_of_slots_is_an_error() {
    use kinetrace::gpu::taskpool::{DacrtOptions, dacrt};
    let Some(gpu) = gpu_or_skip() else { return };
    let m = soup(5, 1025);
    let rays = scene_rays(&m, 6, 1000);
    // One slot per ray and triangle: the first split, which copies straddling rays into both halves,
    // already needs more.
    let tight = DacrtOptions {
        slot_factor: 1,
        ..DacrtOptions::default()
    };
    match dacrt(&gpu, &m, &rays, &tight) {
        Err(Error::TaskPoolFull { capacity, asked }) => assert!(asked > capacity),
        other => panic!("expected TaskPoolFull, got {other:?}"),
    }
    let zero = DacrtOptions {
        slot_factor: 0,
        ..DacrtOptions::default()
    };
    assert!(matches!(
        dacrt(&gpu, &m, &rays, &zero),
        Err(Error::InvalidOption(_))
    ));
}
