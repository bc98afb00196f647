//! The 4-wide query tree: its answers equal brute force and the binary tree's through refits, its leaves
//! cover every triangle once inside boxes that hold them, refits never re-collapse, and the SIMD box test
//! equals the portable one bit for bit.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::wide::WideBvh;
use kinetrace::bvh::wide::simd::{self, RayLanes};
use kinetrace::bvh::{BuildOptions, LEAF_BIT, PartialOptions};
use kinetrace::{Aabb, Hit, Mesh, MeshBvh, Ray};
use rand::Rng;
use rand::rngs::SmallRng;

/// Random rays aimed at triangles, random rays, and short rays from inside the scene's box.
fn rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let mut r = rng(seed);
    let b = m
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t));
    let inside =
        |r: &mut SmallRng| b.min + (b.max - b.min) * Vec3::new(r.random(), r.random(), r.random());
    (0..n)
        .map(|i| match i % 3 {
            0 => {
                let [a, bb, c] = m.triangle(r.random_range(0..m.triangle_count()));
                let target = (a + bb + c) / 3.0;
                let o = inside(&mut r) * 2.0 - b.center();
                Ray::new(o, target - o)
            }
            1 => Ray::new(inside(&mut r), rand_dir(&mut r)),
            _ => Ray::with_range(
                inside(&mut r),
                rand_dir(&mut r),
                0.0,
                r.random_range(0.0..0.3),
            ),
        })
        .collect()
}

/// Every slot lies in exactly one wide leaf, children follow parents, and every lane box is exactly the
/// union of the boxes of `m`'s triangles below it (the tight box a refit must produce).
fn check_structure(m: &Mesh, bvh: &MeshBvh, what: &str) {
    let wide = bvh.wide().expect("a wide tree");
    let boxes = m.triangle_bounds();
    let prims = bvh.bvh().prim_indices();
    let mut seen = vec![0u32; prims.len()];
    // The union of the triangle boxes under a lane payload.
    fn union_below(wide: &WideBvh, c: u32, prims: &[u32], boxes: &[Aabb]) -> Aabb {
        if c & LEAF_BIT != 0 {
            let first = (c & ((1 << 27) - 1)) as usize;
            let count = ((c >> 27) & 0xf) as usize;
            (first..first + count).fold(Aabb::EMPTY, |b, s| b.union(&boxes[prims[s] as usize]))
        } else {
            let n = &wide.nodes()[c as usize];
            (0..4)
                .filter(|&l| n.child[l] != u32::MAX)
                .fold(Aabb::EMPTY, |b, l| {
                    b.union(&union_below(wide, n.child[l], prims, boxes))
                })
        }
    }
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let node = &wide.nodes()[i];
        for lane in 0..4 {
            let c = node.child[lane];
            if c == u32::MAX {
                continue;
            }
            let b = node.lane_box(lane);
            assert_eq!(
                b,
                union_below(wide, c, prims, &boxes),
                "{what}: node {i} lane {lane} box"
            );
            if c & LEAF_BIT != 0 {
                let first = (c & ((1 << 27) - 1)) as usize;
                let count = ((c >> 27) & 0xf) as usize;
                assert!((1..=15).contains(&count), "{what}: leaf of {count}");
                for k in &mut seen[first..first + count] {
                    *k += 1;
                }
            } else {
                assert!(c as usize > i, "{what}: child {c} before its parent {i}");
                stack.push(c as usize);
            }
        }
    }
    assert!(
        seen.iter().all(|&k| k == 1),
        "{what}: slots not covered exactly once"
    );
}

/// Wide answers against the brute-force oracle, and against the same tree's binary traversal: the same
/// triangle, or one hit at exactly the same `t`.
fn check_answers(m: &Mesh, bvh: &MeshBvh, rays: &[Ray], what: &str) -> usize {
    let mut binary = bvh.clone();
    binary.set_wide(false);
    let mut hits = 0;
    for (i, ray) in rays.iter().enumerate() {
        let oracle = RayOracle::of_mesh(m, ray);
        let got = bvh.closest_hit(ray);
        oracle.check_closest(got.map(|h| (h.primitive, h.t)), &format!("{what} ray {i}"));
        oracle.check_any(bvh.any_hit(ray), &format!("{what} any-hit ray {i}"));
        let bin = binary.closest_hit(ray);
        assert_eq!(
            got.map(|h| h.t),
            bin.map(|h| h.t),
            "{what} ray {i}: wide {got:?}, binary {bin:?}"
        );
        let mut all = Vec::new();
        bvh.all_hits(ray, &mut all);
        let mut all_bin = Vec::new();
        binary.all_hits(ray, &mut all_bin);
        let key = |v: &mut Vec<kinetrace::Hit>| {
            let mut k: Vec<(u32, u32)> = v.iter().map(|h| (h.primitive, h.t.to_bits())).collect();
            k.sort_unstable();
            k
        };
        assert_eq!(key(&mut all), key(&mut all_bin), "{what} ray {i}: all hits");
        hits += got.is_some() as usize;
    }
    hits
}

/// The wide tree's child payloads, node by node: its topology.
fn wide_topology(bvh: &MeshBvh) -> Vec<[u32; 4]> {
    bvh.wide()
        .unwrap()
        .nodes()
        .iter()
        .map(|n| n.child)
        .collect()
}

#[test]
fn wide_answers_equal_brute_force_and_the_binary_tree_through_refits() {
    let scenes = [
        ("soup", soup(11, 3000)),
        ("icosphere", icosphere(3)),
        ("cube sphere", cube_sphere(6)),
    ];
    for (name, m) in &scenes {
        let rays = rays(m, 5, 300);
        for opt in all_build_options().into_iter().filter(|o| o.wide) {
            let what = format!("{name} {opt:?}");
            let mut bvh = MeshBvh::build(m, &opt).unwrap();
            check_structure(m, &bvh, &what);
            let hits = check_answers(m, &bvh, &rays, &what);
            assert!(hits > rays.len() / 4, "{what}: only {hits} hits");
            let children = wide_topology(&bvh);
            // Two deformations, refitted in place: the wide topology stays, the boxes follow.
            for frame in 1..=2 {
                let f = frame as f32;
                let pos: Vec<Vec3> = m
                    .positions()
                    .iter()
                    .map(|&p| {
                        p + Vec3::new((p.y * 3.0 * f).sin(), (p.z * 2.0).cos() * f, 0.0) * 0.15
                    })
                    .collect();
                bvh.refit(&pos).unwrap();
                let moved = m.with_positions(pos).unwrap();
                let what = format!("{what} refit {frame}");
                let now = wide_topology(&bvh);
                assert_eq!(children, now, "{what}: the refit changed the wide topology");
                check_structure(&moved, &bvh, &what);
                check_answers(&moved, &bvh, &rays, &what);
            }
        }
    }
}

/// Batched any-hit and closest-hit queries, whose walks run four at a time interleaved node by node
/// (`MeshBvh::any_hits_interleaved` and `closest_hits_interleaved`, and `any_hits` and `closest_hits`
/// on all threads), answer every ray as the brute-force oracle allows and exactly as `any_hit` and
/// `closest_hit` ray by ray (the same triangle at the same distance, bit for bit): on the wide, compact
/// and binary trees, in batches of every size around the four walks (none, fewer, as many, one more,
/// several rounds of refills), with invalid rays (which hit nothing) and the box test's hard rays mixed
/// in.
#[test]
fn interleaved_any_and_closest_hits_answer_as_brute_force_and_ray_by_ray() {
    for (name, m) in [("soup", soup(12, 2000)), ("icosphere", icosphere(3))] {
        let wide = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let mut compact = wide.clone();
        compact.set_compact(true);
        assert!(compact.compact().is_some(), "{name}: compact tree");
        let mut binary = wide.clone();
        binary.set_wide(false);
        let mut all = rays(&m, 9, 240);
        all.extend(hard_rays(&wide, 10));
        let o = Vec3::splat(0.1);
        for (k, bad) in [
            Ray::new(Vec3::NAN, Vec3::X),
            Ray::new(o, Vec3::ZERO),
            Ray::with_range(o, Vec3::Y, f32::NAN, 1.0),
        ]
        .into_iter()
        .enumerate()
        {
            all.insert(3 + 37 * k, bad);
        }
        for (tree, bvh) in [("wide", &wide), ("compact", &compact), ("binary", &binary)] {
            let one_by_one: Vec<bool> = all.iter().map(|r| bvh.any_hit(r)).collect();
            let mut hits = 0;
            for (i, (r, &got)) in all.iter().zip(&one_by_one).enumerate() {
                assert_any_hit(&m, r, got, &format!("{name} {tree} ray {i}"));
                hits += got as usize;
            }
            assert!(
                hits > all.len() / 4 && hits < all.len(),
                "{name} {tree}: {hits} hits"
            );
            let what = format!("{name} {tree}: any hits");
            in_batches(
                &all,
                &one_by_one,
                true,
                |r, o| bvh.any_hits_interleaved(r, o),
                &what,
            );
            let mut out = vec![true; all.len()];
            bvh.any_hits(&all, &mut out);
            assert_eq!(out, one_by_one, "{name} {tree}: any_hits");

            let one_by_one: Vec<_> = all.iter().map(|r| bvh.closest_hit(r)).collect();
            for (i, (r, got)) in all.iter().zip(&one_by_one).enumerate() {
                RayOracle::of_mesh(&m, r).check_closest(
                    got.map(|h| (h.primitive, h.t)),
                    &format!("{name} {tree} ray {i}"),
                );
            }
            let dummy = Some(Hit {
                t: -1.0,
                primitive: u32::MAX,
                u: 0.0,
                v: 0.0,
                normal: Vec3::ZERO,
            });
            let what = format!("{name} {tree}: closest hits");
            let interleaved = |r: &[Ray], o: &mut [_]| bvh.closest_hits_interleaved(r, o);
            in_batches(&all, &one_by_one, dummy, interleaved, &what);
            let mut out = vec![dummy; all.len()];
            bvh.closest_hits(&all, &mut out);
            assert_eq!(out, one_by_one, "{name} {tree}: closest_hits");
        }
    }
}

/// `batch(rays, out)` over `all` cut in batches of every size around the four interleaved walks (none,
/// fewer, as many, one more, several rounds of refills, the rest), each `out` first filled with `stale`,
/// against `want` (the answers ray by ray).
fn in_batches<T: Clone + PartialEq + std::fmt::Debug>(
    all: &[Ray],
    want: &[T],
    stale: T,
    batch: impl Fn(&[Ray], &mut [T]),
    what: &str,
) {
    let mut from = 0;
    for len in [0, 1, 2, 3, 4, 5, 8, 9, 31, usize::MAX] {
        let to = from + len.min(all.len() - from);
        let mut out = vec![stale.clone(); to - from];
        batch(&all[from..to], &mut out);
        assert_eq!(out, want[from..to], "{what}: rays {from}..{to}");
        from = to;
    }
}

/// A wide tree taken out of use for a try of the binary tree ([`MeshBvh::suspend_wide`]) comes back
/// refitted to the positions of the meantime without a new collapse (the same wide topology); after a
/// partial rebuild changed the binary tree's topology it comes back collapsed anew, never stale.
#[test]
fn a_suspended_wide_tree_comes_back_refitted_or_collapsed_anew() {
    let m = soup(11, 3000);
    let rays = rays(&m, 6, 300);
    let mut bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let children = wide_topology(&bvh);
    bvh.suspend_wide();
    assert!(bvh.wide().is_none());
    // Two frames of the binary tree alone: each refit leaves the suspended tree as it was.
    let wave = |f: f32| -> Vec<Vec3> {
        (m.positions().iter())
            .map(|&p| p + Vec3::new((p.y * 3.0 * f).sin(), (p.z * 2.0).cos() * f, 0.0) * 0.15)
            .collect()
    };
    for f in [1.0, 2.0] {
        bvh.refit(&wave(f)).unwrap();
    }
    let moved = m.with_positions(wave(2.0)).unwrap();
    bvh.set_wide(true);
    assert_eq!(children, wide_topology(&bvh), "re-collapsed, not refitted");
    check_structure(&moved, &bvh, "back from a try");
    check_answers(&moved, &bvh, &rays, "back from a try");

    // The corner below x = 0.25 scattered: the partial rebuild changes the binary topology.
    bvh.suspend_wide();
    let mut r = rng(12);
    let mut pos = wave(2.0);
    for t in 0..m.triangle_count() {
        let [a, b, c] = m.triangle(t);
        if ((a + b + c) / 3.0).max_element() < 0.25 {
            let d = rand_dir(&mut r) * r.random_range(0.0..0.5);
            for &i in &m.indices()[3 * t..3 * t + 3] {
                pos[i as usize] += d;
            }
        }
    }
    let (_, done) = bvh.refit_partial(&pos, &PartialOptions::default()).unwrap();
    assert!(done.subtrees > 0, "nothing rebuilt");
    bvh.set_wide(true);
    let fresh = WideBvh::collapse(bvh.bvh().nodes());
    assert_eq!(bvh.wide(), Some(&fresh), "a stale wide tree came back");
    let exploded = m.with_positions(pos).unwrap();
    check_structure(&exploded, &bvh, "back after a partial rebuild");
    check_answers(&exploded, &bvh, &rays, "back after a partial rebuild");
}

#[test]
fn empty_and_single_triangle_meshes() {
    let empty = Mesh::new(Vec::new(), Vec::new()).unwrap();
    let bvh = MeshBvh::build(&empty, &BuildOptions::default()).unwrap();
    assert!(bvh.wide().unwrap().nodes().is_empty());
    assert!(bvh.closest_hit(&Ray::new(Vec3::ZERO, Vec3::Z)).is_none());
    let one = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap();
    let bvh = MeshBvh::build(&one, &BuildOptions::default()).unwrap();
    check_structure(&one, &bvh, "one triangle");
    let hit = bvh
        .closest_hit(&Ray::new(Vec3::new(0.25, 0.25, 2.0), -Vec3::Z))
        .unwrap();
    assert_eq!((hit.primitive, hit.t), (0, 2.0));
    assert!(!bvh.any_hit(&Ray::new(Vec3::new(0.75, 0.75, 2.0), -Vec3::Z)));
}

/// Rays that stress the box test: axis-parallel with signed zeros, origins on lane planes, subnormal
/// components, huge and tiny ranges, and random ones.
fn hard_rays(bvh: &MeshBvh, seed: u64) -> Vec<Ray> {
    let mut r = rng(seed);
    let wide = bvh.wide().unwrap();
    let mut out = Vec::new();
    let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
    for node in wide.nodes().iter().take(200) {
        let lane = r.random_range(0..4);
        if node.child[lane] == u32::MAX {
            continue;
        }
        let b = node.lane_box(lane);
        let corner = b.min;
        for d in axes {
            out.push(Ray::new(corner - d, d));
            out.push(Ray::new(b.max, d));
            out.push(Ray::new(corner, Vec3::new(-0.0, 0.0, -0.0) + d));
        }
        out.push(Ray::new(b.min - Vec3::ONE, Vec3::new(1e-40, 1.0, 1.0)));
        out.push(Ray::with_range(b.center(), rand_dir(&mut r), 0.0, 1e-6));
        out.push(Ray::with_range(
            b.center() * 1e6,
            rand_dir(&mut r),
            -1.0,
            1e30,
        ));
    }
    for _ in 0..500 {
        out.push(Ray::new(rand_vec(&mut r, -3.0, 3.0), rand_dir(&mut r)));
    }
    out
}

#[test]
fn simd_box_test_equals_the_portable_one_bit_for_bit() {
    for m in [
        soup(4, 2000),
        cube_sphere(4),
        map_mesh(&icosphere(2), |p| p * 1e5 + Vec3::X * 3e6),
    ] {
        let bvh = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        let rays = hard_rays(&bvh, 9);
        let mut lanes_hit = 0;
        for ray in &rays {
            let lanes = RayLanes::new(ray);
            for node in bvh.wide().unwrap().nodes() {
                for tmax in [ray.tmax, 0.5, f32::INFINITY] {
                    let p = simd::hit4_portable(node, &lanes, tmax);
                    #[cfg(target_arch = "x86_64")]
                    let s = simd::hit4_sse(node, &lanes, tmax);
                    #[cfg(target_arch = "aarch64")]
                    let s = simd::hit4_neon(node, &lanes, tmax);
                    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
                    let s = p;
                    assert_eq!(p.0, s.0, "masks differ for {ray:?} at {tmax}");
                    assert_eq!(
                        p.1.map(f32::to_bits),
                        s.1.map(f32::to_bits),
                        "entry distances differ for {ray:?}"
                    );
                    assert_eq!(simd::hit4(node, &lanes, tmax).0, p.0);
                    lanes_hit += p.0.count_ones();
                    // The portable lanes agree with the scalar test the binary tree uses.
                    for lane in 0..4 {
                        if node.child[lane] == u32::MAX {
                            assert_eq!(p.0 >> lane & 1, 0, "an unused lane was hit");
                            continue;
                        }
                        let scalar = ray.intersect_aabb(&node.lane_box(lane), tmax);
                        assert_eq!(
                            scalar.is_some(),
                            p.0 >> lane & 1 == 1,
                            "{ray:?} lane {lane}"
                        );
                        if let Some(t) = scalar {
                            assert_eq!(t.to_bits(), p.1[lane].to_bits());
                        }
                    }
                }
            }
        }
        assert!(
            lanes_hit > 1000,
            "too few lanes hit ({lanes_hit}) to mean anything"
        );
    }
}
