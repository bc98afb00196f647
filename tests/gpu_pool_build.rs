//! The BVH build on the GPU task pool (`kinetrace::gpu::taskpool::build_bvh`): at sizes 0 to 1025 and on the
//! extreme scenes the tree validates, every box is exactly its triangle's box or the union of its children's
//! (computed here from the vertices), every inner node's area ratio matches one computed in f64, closest and
//! any hits through it equal the brute-force oracle's (an independent exact triangle test), rounds grow with
//! the tree's height, and the SAH cost stays within a band of CPU binned SAH's (a spatial-median split, not
//! the same algorithm). Where no range of more than 32 triangles needs a fallback cut, the tree equals the
//! CPU spatial-median builder's node for node. Runs on lavapipe in CI (`KINETRACE_REQUIRE_GPU=1`
//! makes a missing adapter a failure; without it the tests skip).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, Bvh};
use kinetrace::gpu::GpuContext;
use kinetrace::gpu::taskpool::{PoolBuild, build_bvh, build_bvh_from_capacity};
use kinetrace::scenes::soup;
use kinetrace::{Aabb, Mesh, MeshBvh, Ray};

const SIZES: [usize; 9] = [0, 1, 2, 3, 31, 32, 33, 1023, 1025];

/// The triangle's box from its vertices.
fn tri_box(m: &Mesh, i: usize) -> Aabb {
    let [a, b, c] = m.triangle(i);
    Aabb::new(a.min(b).min(c), a.max(b).max(c))
}

fn half_area(n: &kinetrace::bvh::Node) -> f64 {
    let e = [0, 1, 2].map(|k| (n.max[k] as f64 - n.min[k] as f64).max(0.0));
    e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
}

/// Depth of the deepest leaf (root 0).
fn height(t: &Bvh) -> u32 {
    let mut best = 0;
    if t.nodes().is_empty() {
        return 0;
    }
    let mut stack = vec![(0usize, 0u32)];
    while let Some((i, d)) = stack.pop() {
        let n = &t.nodes()[i];
        best = best.max(d);
        if !n.is_leaf() {
            stack.extend([(n.left(), d + 1), (n.left() + 1, d + 1)]);
        }
    }
    best
}

/// Checks the tree's structure and boxes against the mesh, without trusting the builder's arithmetic.
fn check_structure(m: &Mesh, b: &PoolBuild, what: &str) {
    let t = b.bvh.bvh();
    let n = m.triangle_count();
    t.validate(Some(&m.triangle_bounds()))
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    if n == 0 {
        return;
    }
    assert_eq!(t.nodes().len(), 2 * n - 1, "{what}: node count");
    // Boxes from the leaves up (children sit after their parents): exact, since min and max round nothing.
    let mut boxes = vec![Aabb::EMPTY; t.nodes().len()];
    for (i, node) in t.nodes().iter().enumerate().rev() {
        boxes[i] = if node.is_leaf() {
            assert_eq!(node.count(), 1, "{what}: leaf {i} holds one triangle");
            tri_box(m, t.prim_indices()[node.first()] as usize)
        } else {
            let (l, r) = (&t.nodes()[node.left()], &t.nodes()[node.left() + 1]);
            // The area ratio, where it is neither clamped nor guarded.
            let (p, c) = (half_area(node), half_area(l) + half_area(r));
            if p > 0.0 && c > 0.0 && p / c < 512.0 {
                let want = p / c;
                let got = node.sa_ratio as f64;
                assert!(
                    (got - want).abs() <= 1e-5 * want,
                    "{what}: node {i} area ratio {got}, want {want}"
                );
            }
            boxes[node.left()].union(&boxes[node.left() + 1])
        };
        assert_eq!(node.aabb(), boxes[i], "{what}: node {i}'s box");
    }
    // Every subtree's descendants fill one block of the node array: their largest index minus the smallest
    // (the left child) is one less than their count (validate already saw every node reached once).
    let mut size = vec![1usize; t.nodes().len()];
    let mut last = (0..t.nodes().len()).collect::<Vec<usize>>();
    for (i, node) in t.nodes().iter().enumerate().rev() {
        if !node.is_leaf() {
            let c = node.left();
            size[i] = 1 + size[c] + size[c + 1];
            last[i] = last[c].max(last[c + 1]);
            assert_eq!(
                last[i] - c + 1,
                size[i] - 1,
                "{what}: node {i}'s descendants"
            );
        }
    }
}

/// Closest and any hits through the tree equal brute force.
fn check_rays(m: &Mesh, b: &PoolBuild, rays: &[Ray], what: &str) {
    for (i, ray) in rays.iter().enumerate() {
        let hit = b.bvh.closest_hit(ray).map(|h| (h.primitive, h.t));
        assert_brute_hit(m, ray, hit, &format!("{what} ray {i}"));
        assert_any_hit(
            m,
            ray,
            b.bvh.any_hit(ray),
            &format!("{what} any-hit ray {i}"),
        );
    }
}

/// Random rays through the mesh, plus rays at the tiny mesh of a teapot in a stadium.
fn rays_for(m: &Mesh, n: usize) -> Vec<Ray> {
    let mut rays = if m.triangle_count() == 0 {
        vec![Ray::new(Vec3::ZERO, Vec3::X)]
    } else {
        scene_rays(m, 3, n)
    };
    rays.extend([Vec3::X, -Vec3::Y, -Vec3::Z].map(|d| Ray::new(Vec3::splat(0.25) - d * 4e3, d)));
    rays.extend((0..100).map(|i| {
        let d = Vec3::new((i as f32).sin(), (i as f32).cos(), -3.0);
        Ray::new(Vec3::splat(0.25) + Vec3::new(0.0, 0.0, 3e-6), d)
    }));
    rays
}

/// SAH cost of the pool's tree over CPU binned SAH's (leaves of one triangle for both).
fn sah_ratio(m: &Mesh, b: &PoolBuild) -> f64 {
    let cpu = MeshBvh::build(m, &BuildOptions::new(Builder::SAH).max_leaf_size(1)).unwrap();
    b.bvh.bvh().sah_cost() / cpu.bvh().sah_cost()
}

fn build(g: &GpuContext, m: &Mesh, what: &str) -> PoolBuild {
    let b = build_bvh(g, m).unwrap_or_else(|e| panic!("{what}: {e}"));
    check_structure(m, &b, what);
    let t = b.bvh.bvh();
    if m.triangle_count() > 0 {
        // One round per level of tasks, one more for the root's bounds, one for parked halved nodes.
        assert!(
            b.counts.rounds <= height(t) + 2,
            "{what}: {} rounds for height {}",
            b.counts.rounds,
            height(t)
        );
    }
    eprintln!(
        "{what}: height {}, {:?}, {:.0} B/triangle{}",
        height(t),
        b.counts,
        b.bytes as f64 / m.triangle_count().max(1) as f64,
        if m.triangle_count() > 1 {
            format!(", SAH / CPU binned SAH {:.3}", sah_ratio(m, &b))
        } else {
            String::new()
        }
    );
    b
}

#[test]
fn pool_build_at_every_size_answers_as_brute_force() {
    let Some(g) = gpu_or_skip() else { return };
    for n in SIZES {
        let m = soup(n as u64 + 1, n);
        let what = format!("soup {n}");
        let b = build(&g, &m, &what);
        check_rays(&m, &b, &rays_for(&m, 300), &what);
        if n > 1 {
            // A spatial-median split on an even soup: within 20% of binned SAH's cost (1.11 measured).
            let r = sah_ratio(&m, &b);
            assert!(r < 1.2, "{what}: SAH ratio {r}");
        }
    }
}

#[test]
fn pool_build_on_extreme_scenes() {
    let Some(g) = gpu_or_skip() else { return };
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(300)).unwrap();
    let line = collinear_zero_area(600);
    // Centroids at powers of 1.1 along x: every middle split peels off the farthest few.
    let far = Mesh::new(
        (0..300)
            .flat_map(|j| {
                let x = 1.1f32.powi(j);
                [
                    Vec3::new(x, 0.0, 0.0),
                    Vec3::new(x, 1.0, 0.0),
                    Vec3::new(x, 0.0, 1.0),
                ]
            })
            .collect::<Vec<Vec3>>(),
        (0..900u32).collect::<Vec<u32>>(),
    )
    .unwrap();
    for (name, m) in [
        ("teapot in a stadium", teapot_in_stadium(2)),
        ("identical triangles", same),
        ("collinear zero-area", line),
        ("exponential spacing", far),
    ] {
        let b = build(&g, &m, name);
        check_rays(&m, &b, &rays_for(&m, 500), name);
        // Binned SAH's 16 bins serve these no better than the middle split (0.85 to 1.0 measured).
        let r = sah_ratio(&m, &b);
        assert!(r < 1.1, "{name}: SAH ratio {r}");
    }
}

/// The CPU spatial-median builder with one triangle per leaf: the same splits wherever the middle separates
/// the centroids of every range of more than 32 triangles (elsewhere the CPU cuts at the object median and
/// the GPU halves the range in slot order).
fn cpu_median(m: &Mesh) -> MeshBvh {
    MeshBvh::build(m, &BuildOptions::new(Builder::Median).max_leaf_size(1)).unwrap()
}

#[test]
fn pool_build_equals_cpu_median_node_for_node() {
    let Some(g) = gpu_or_skip() else { return };
    let mut scenes: Vec<(String, Mesh)> = SIZES
        .iter()
        .map(|&n| (format!("soup {n}"), soup(n as u64 + 1, n)))
        .collect();
    scenes.push(("teapot in a stadium".into(), teapot_in_stadium(2)));
    // 30 identical triangles: one small build, where the GPU cuts at the object median too.
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(30)).unwrap();
    scenes.push(("30 identical triangles".into(), same));
    for (what, m) in &scenes {
        let gpu = build_bvh(&g, m).unwrap();
        let cpu = cpu_median(m);
        // Boxes and links bit for bit; the area ratios (checked in f64 by check_structure) may differ in
        // the last bit, as the GPU's division and products round.
        let without_ratio = |t: &Bvh| {
            t.nodes()
                .iter()
                .map(|n| (n.min, n.index, n.max))
                .collect::<Vec<_>>()
        };
        check_structure(m, &gpu, what);
        assert_eq!(
            without_ratio(gpu.bvh.bvh()),
            without_ratio(cpu.bvh()),
            "{what}: nodes"
        );
        assert_eq!(
            gpu.bvh.bvh().prim_indices(),
            cpu.bvh().prim_indices(),
            "{what}: slot order"
        );
    }
}

#[test]
fn pool_build_that_runs_out_of_tasks_runs_again() {
    let Some(g) = gpu_or_skip() else { return };
    let m = soup(9, 1025);
    let b = build_bvh_from_capacity(&g, &m, 1).unwrap();
    check_structure(&m, &b, "soup 1025 from one task record");
    check_rays(&m, &b, &rays_for(&m, 100), "soup 1025 from one task record");
    assert!(b.counts.tasks > 1, "{:?}", b.counts);
}

#[test]
#[ignore = "2^20 + 7 triangles on lavapipe; run with --ignored"]
fn pool_build_at_a_million() {
    let Some(g) = gpu_or_skip() else { return };
    let n = (1 << 20) + 7;
    let m = soup(7, n);
    let b = build(&g, &m, "soup 2^20 + 7");
    check_rays(&m, &b, &rays_for(&m, 200), "soup 2^20 + 7");
}
