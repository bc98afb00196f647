//! GPU kernels against their CPU references, on lavapipe in CI (`KINETRACE_REQUIRE_GPU=1` makes a missing
//! adapter a failure; without it these tests skip and say so).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::{Mat4, Quat, Vec3};
use kinetrace::anim::{SkinWeights, skin_positions};
use kinetrace::bvh::{BuildOptions, Builder, Bvh};
use kinetrace::gpu::{GpuContext, GpuMeshBvh, GpuRays, GpuSkin, Query, sort_pairs};
use kinetrace::{Aabb, Mesh, MeshBvh, Ray};
use rand::Rng;

fn gpu() -> Option<GpuContext> {
    gpu_or_skip()
}

/// On Vulkan (lavapipe in CI, NVIDIA's and every other driver: wgpu passes SPIR-V through) every kernel is compiled
/// without floating-point contraction: the premise of the exact comparisons in this file on drivers
/// that would fuse multiplies and adds.
#[test]
fn vulkan_kernels_are_compiled_without_contraction() {
    let Some(g) = gpu() else { return };
    let vulkan = g.adapter_info().backend == wgpu::Backend::Vulkan;
    assert_eq!(g.contraction_free(), vulkan, "{}", g.adapter_details());
}

/// A float of random sign and mantissa with an exponent in `-e..e`.
fn random_float(r: &mut impl Rng, e: i32) -> f32 {
    let exp = (r.random_range(-e..e) + 127) as u32;
    f32::from_bits(
        (r.random::<u32>() & 0x8000_0000) | (exp << 23) | (r.random::<u32>() & 0x7f_ffff),
    )
}

/// The kernels' division (`div_rn`) equals Rust's IEEE division bit for bit wherever the quotient is a
/// finite normal number: random operands across 2^±60, small integers (exact and inexact quotients), equal
/// operands and powers of two. Lavapipe divides exactly already; NVIDIA's driver may err by the 2.5 ulp
/// Vulkan allows, and this checks the correction.
#[test]
fn division_rounds_as_the_cpu_does() {
    let Some(g) = gpu() else { return };
    let mut r = rng(11);
    let (mut a, mut b): (Vec<f32>, Vec<f32>) = (0..1 << 20)
        .map(|_| (random_float(&mut r, 60), random_float(&mut r, 60)))
        .unzip();
    for i in 1..=64 {
        for j in 1..=64 {
            a.push(i as f32);
            b.push(j as f32);
        }
        a.extend([i as f32 * 0.1, 1.0, -3.0]);
        b.extend([i as f32 * 0.1, (2.0f32).powi(i - 32), i as f32 * 1e-30]);
    }
    let q = kinetrace::gpu::divide(&g, &a, &b).unwrap();
    let mut checked = 0;
    for ((&x, &y), &got) in a.iter().zip(&b).zip(&q) {
        let want = x / y;
        if want.is_normal() {
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "{x:e} / {y:e}: {got:e} vs {want:e}"
            );
            checked += 1;
        }
    }
    assert!(checked > a.len() * 9 / 10, "{checked} of {}", a.len());
}

/// The kernels' square root (`sqrt_rn`, corrected from a guess by `sqrt_from`) equals Rust's bit for bit
/// from 2^-100 to 2^126: random positive floats across 2^±100, the arguments the shadow classification takes
/// (`1 − c²` for `c` in [1/64, 1]), perfect squares and their neighbours, powers of two (whose roots'
/// lower neighbours are twice as dense); each from the driver's root (and zeros of either sign, their own
/// roots) and from the exact root moved up to eight floats either way. Lavapipe's roots are exact
/// already, so the moved guesses are what exercise the correction, as NVIDIA's driver's (which may err
/// by several ulp) would.
#[test]
fn square_root_rounds_as_the_cpu_does() {
    let Some(g) = gpu() else { return };
    let mut r = rng(12);
    let mut xs: Vec<f32> = (0..1 << 16)
        .map(|_| random_float(&mut r, 100).abs())
        .collect();
    xs.extend((0..1 << 14).map(|_| {
        let c = r.random_range(1.0f32 / 64.0..=1.0);
        (1.0 - c * c).max(0.0)
    }));
    for k in 1..=4096u32 {
        let sq = (k * k) as f32;
        xs.extend([
            sq,
            f32::from_bits(sq.to_bits() + 1),
            f32::from_bits(sq.to_bits() - 1),
        ]);
    }
    xs.extend((-100..=126).map(|e| 2f32.powi(e)));
    xs.extend([f32::from_bits(2f32.powi(126).to_bits() - 1), 0.0, -0.0]);
    // Wrapping: the zeros' moved guesses are nonsense, and unchecked.
    let moved =
        |x: f32, floats: i32| f32::from_bits(x.sqrt().to_bits().wrapping_add_signed(floats));
    let mut checked = 0;
    let moves = (1..=8).flat_map(|k| [Some(-k), Some(k)]);
    for ulps in std::iter::once(None).chain(moves) {
        let guess: Vec<f32> = match ulps {
            None => xs.iter().map(|x| x.sqrt()).collect(),
            Some(u) => xs.iter().map(|&x| moved(x, u)).collect(),
        };
        let got = match ulps {
            // The driver's own root, corrected.
            None => kinetrace::gpu::square_root(&g, &xs, &vec![f32::NAN; xs.len()]).unwrap(),
            Some(_) => kinetrace::gpu::square_root(&g, &xs, &guess).unwrap(),
        };
        for (&x, &got) in xs.iter().zip(&got) {
            if (2f32.powi(-100)..=2f32.powi(126)).contains(&x) || (ulps.is_none() && x == 0.0) {
                let want = x.sqrt();
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "√{x:e} from {ulps:?}: {got:e} vs {want:e}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > xs.len() * 16, "{checked} of {}", xs.len() * 17);
}

const SIZES: [usize; 6] = [0, 1, 2, 3, 1023, 1025];
const BIG: usize = (1 << 20) + 7;

#[test]
fn radix_sort_equals_cpu_stable_sort() {
    let Some(g) = gpu() else { return };
    let mut r = rng(1);
    for n in SIZES.into_iter().chain([BIG]) {
        for spread in [1u32 << 30, 37] {
            let keys: Vec<u32> = (0..n).map(|_| r.random_range(0..spread)).collect();
            let vals: Vec<u32> = (0..n as u32).collect();
            let (gk, gv) = sort_pairs(&g, &keys, &vals, 30).unwrap();
            // Oracle: the standard library's stable sort of the (key, value) pairs by key.
            let mut expect: Vec<(u32, u32)> = keys.iter().copied().zip(vals).collect();
            expect.sort_by_key(|&(k, _)| k);
            let (ek, ev): (Vec<u32>, Vec<u32>) = expect.into_iter().unzip();
            assert_eq!(gk, ek, "keys, n = {n}");
            assert_eq!(gv, ev, "values (stability), n = {n}");
        }
    }
}

fn gpu_lbvh(g: &GpuContext, m: &Mesh) -> (GpuMeshBvh, Bvh) {
    let mut bvh = GpuMeshBvh::new(g, m).unwrap();
    let mut enc = g.encoder();
    bvh.record_build(g, &mut enc);
    g.submit(enc);
    let tree = bvh.read_tree(g).unwrap();
    (bvh, tree)
}

#[test]
fn lbvh_build_equals_cpu_lbvh() {
    let Some(g) = gpu() else { return };
    for n in SIZES.into_iter().chain([BIG]) {
        let m = soup(n as u64 + 5, n);
        let (_, tree) = gpu_lbvh(&g, &m);
        let bounds = m.triangle_bounds();
        tree.validate(Some(&bounds))
            .unwrap_or_else(|e| panic!("n = {n}: {e}"));
        let cpu = Bvh::build(&bounds, &BuildOptions::new(Builder::LBVH)).unwrap();
        let (gc, cc) = (tree.sah_cost(), cpu.sah_cost());
        assert!(
            (gc - cc).abs() <= 1e-3 * cc.max(1e-30),
            "n = {n}: SAH {gc} vs {cc}"
        );
        // Same codes give the same tree: boxes are exact; ratios may differ by the GPU's division.
        let same = tree
            .nodes()
            .iter()
            .zip(cpu.nodes())
            .filter(|(a, b)| a.index == b.index && a.min == b.min && a.max == b.max)
            .count();
        assert!(
            same as f64 >= 0.999 * cpu.nodes().len() as f64,
            "n = {n}: {same} of {} nodes equal",
            cpu.nodes().len()
        );
    }
}

#[test]
fn refit_equals_cpu_refit() {
    let Some(g) = gpu() else { return };
    for n in [1usize, 2, 3, 1023, 1025, 50_000] {
        let m = soup(n as u64 + 9, n);
        let (bvh, mut tree) = gpu_lbvh(&g, &m);
        let mut r = rng(n as u64);
        let moved: Vec<Vec3> = m
            .positions()
            .iter()
            .map(|p| *p + rand_vec(&mut r, -0.05, 0.05))
            .collect();
        bvh.upload_positions(&g, &moved).unwrap();
        let mut enc = g.encoder();
        bvh.record_refit(&g, &mut enc).unwrap();
        let d = bvh.record_degradation(&g, &mut enc);
        g.submit(enc);
        let gpu_d = d.wait(&g).unwrap();
        let after = bvh.read_tree(&g).unwrap();
        let m2 = m.with_positions(moved).unwrap();
        let cpu_d = tree.refit(&m2.triangle_bounds()).unwrap();
        for (i, (a, b)) in after.nodes().iter().zip(tree.nodes()).enumerate() {
            assert_eq!(
                (a.min, a.max, a.index),
                (b.min, b.max, b.index),
                "n = {n}: node {i}"
            );
        }
        assert!(
            (gpu_d - cpu_d).abs() <= 1e-5 * cpu_d.abs().max(1e-3),
            "n = {n}: degradation {gpu_d} vs {cpu_d}"
        );
    }
}

fn check_traversal(g: &GpuContext, m: &Mesh, rays: &[Ray], what: &str) -> usize {
    let mut gr = GpuRays::new(g);
    let mut hits = 0;
    for opt in [
        BuildOptions::new(Builder::SAH),
        BuildOptions::new(Builder::LBVH).max_leaf_size(4),
    ] {
        let cpu = MeshBvh::build(m, &opt).unwrap();
        let gb = GpuMeshBvh::from_cpu(g, m, &cpu).unwrap();
        let closest = gr.run(g, &gb, rays, Query::Closest).unwrap();
        let any = gr.run(g, &gb, rays, Query::Any).unwrap();
        hits = 0;
        for (i, ray) in rays.iter().enumerate() {
            let c = cpu.closest_hit(ray);
            let gh = closest[i];
            match c {
                Some(h) => {
                    hits += 1;
                    let t_ok = gh.t == h.t;
                    assert!(t_ok, "{what} {opt:?} ray {i}: t {} vs {}", gh.t, h.t);
                    if gh.primitive() != Some(h.primitive) {
                        // Only an exact tie may name another triangle (see MeshBvh's docs).
                        assert_same_hit(
                            m,
                            ray,
                            gh.primitive().map(|p| (p, gh.t)),
                            Some((h.primitive, h.t)),
                            what,
                        );
                    }
                }
                None => assert_eq!(gh.primitive(), None, "{what} {opt:?} ray {i}"),
            }
            assert_eq!(
                any[i].primitive().is_some(),
                cpu.any_hit(ray),
                "{what} {opt:?} any-hit ray {i}"
            );
        }
    }
    hits
}

fn random_rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let b = m
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t));
    let mut r = rng(seed);
    (0..n)
        .map(|i| {
            let o = b.min + b.extent() * Vec3::new(r.random(), r.random(), r.random());
            if i % 2 == 0 {
                Ray::new(o, rand_dir(&mut r))
            } else {
                let [a, bb, c] = m.triangle(r.random_range(0..m.triangle_count()));
                Ray::new(o - b.extent(), (a + bb + c) / 3.0 - (o - b.extent()))
            }
        })
        .collect()
}

#[test]
fn ray_queries_equal_cpu_queries() {
    let Some(g) = gpu() else { return };
    let m = soup(3, 3000);
    assert!(check_traversal(&g, &m, &random_rays(&m, 4, 4000), "soup") > 1000);
    let m = icosphere(3);
    assert!(check_traversal(&g, &m, &random_rays(&m, 5, 4000), "icosphere") > 1000);
    // GPU-built tree: the same answers.
    let (gb, _) = gpu_lbvh(&g, &m);
    let rays = random_rays(&m, 6, 2000);
    let hits = GpuRays::new(&g)
        .run(&g, &gb, &rays, Query::Closest)
        .unwrap();
    for (ray, h) in rays.iter().zip(&hits) {
        assert_brute_hit(&m, ray, h.primitive().map(|p| (p, h.t)), "gpu lbvh");
    }
}

/// A negative `tmin` reaches behind the origin on the GPU as on the CPU: rays from inside a closed sphere
/// and a closed box (flat, axis-aligned walls: boxes without thickness behind the origin) over
/// `[tmin, ∞)` with `tmin` negative enough to take in the wall behind them find it first.
#[test]
fn negative_tmin_reaches_behind_the_origin_as_on_the_cpu() {
    let Some(g) = gpu() else { return };
    let walls = kinetrace::scenes::shoebox(Vec3::splat(-0.5), Vec3::splat(0.5));
    for (m, what) in [(icosphere(3), "sphere"), (walls, "box")] {
        let mut r = rng(8);
        let rays: Vec<Ray> = (0..3000)
            .map(|i| {
                let o = rand_vec(&mut r, -0.4, 0.4);
                let tmin = [f32::NEG_INFINITY, -3.0, -1e-3][i % 3];
                Ray::with_range(o, rand_dir(&mut r), tmin, f32::INFINITY)
            })
            .collect();
        assert_eq!(check_traversal(&g, &m, &rays, what), rays.len());
        // Brute force over every triangle, for the GPU's own answers. The walls lie within 1.7 of every
        // origin and more than 0.09 away: the rays whose `tmin` is -∞ or -3 (two in three) find one
        // behind them first, the others one ahead.
        let cpu = MeshBvh::build(&m, &BuildOptions::new(Builder::SAH)).unwrap();
        let gb = GpuMeshBvh::from_cpu(&g, &m, &cpu).unwrap();
        let hits = GpuRays::new(&g)
            .run(&g, &gb, &rays, Query::Closest)
            .unwrap();
        for (ray, h) in rays.iter().zip(&hits) {
            assert_brute_hit(&m, ray, h.primitive().map(|p| (p, h.t)), what);
        }
        let behind = hits.iter().map(|h| h.t < 0.0);
        let reaching_back = rays.iter().map(|r| r.tmin < -1.0);
        assert!(
            behind.eq(reaching_back),
            "{what}: hits behind for the rays reaching back only"
        );
    }
}

#[test]
fn extreme_scenes_on_the_gpu() {
    let Some(g) = gpu() else { return };
    // Identical centroids.
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(500)).unwrap();
    let (_, tree) = gpu_lbvh(&g, &same);
    tree.validate(Some(&same.triangle_bounds())).unwrap();
    check_traversal(&g, &same, &random_rays(&same, 7, 300), "identical");
    // Offsets of 1e7 (sphere radius 1e3 so the f32 grid resolves it) and a 1e-6 teapot in a 1e4 stadium.
    let far = map_mesh(&icosphere(2), |p| p * 1e3 + Vec3::new(1e7, -1e7, 5e6));
    check_traversal(&g, &far, &random_rays(&far, 8, 500), "1e7 offset");
    let teapot = teapot_in_stadium(2);
    let mut rays: Vec<Ray> = [Vec3::X, -Vec3::Y, -Vec3::Z]
        .iter()
        .map(|&d| Ray::new(Vec3::splat(0.25) - d * 4e3, d))
        .collect();
    rays.extend((0..200).map(|i| {
        Ray::new(
            Vec3::splat(0.25) + Vec3::new(0.0, 0.0, 3e-6),
            Vec3::new((i as f32).sin(), (i as f32).cos(), -3.0),
        )
    }));
    check_traversal(&g, &teapot, &rays, "teapot");
    let (_, tree) = gpu_lbvh(&g, &teapot);
    tree.validate(Some(&teapot.triangle_bounds())).unwrap();
    // Axis-parallel rays with exact zero components, inside face planes of a box.
    let cube = map_mesh(&cube_sphere(1), |p| p.signum());
    let mut rays = Vec::new();
    for x in [-1.0f32, -0.5, 0.0, 0.5, 1.0] {
        for y in [-1.0f32, 0.0, 0.3, 1.0] {
            for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
                rays.push(Ray::new(Vec3::new(x, y, x * 0.5) - d * 3.0, d));
                rays.push(Ray::new(Vec3::new(x, y, 0.0), d));
            }
        }
    }
    check_traversal(&g, &cube, &rays, "axis-parallel");
    // Watertightness: rays from inside closed meshes never miss, on a GPU-built tree.
    for m in [icosphere(4), cube_sphere(24)] {
        let (gb, _) = gpu_lbvh(&g, &m);
        let mut r = rng(9);
        let rays: Vec<Ray> = (0..200_000)
            .map(|_| {
                Ray::new(
                    rand_dir(&mut r) * r.random_range(0.0f32..0.9),
                    rand_dir(&mut r),
                )
            })
            .collect();
        let hits = GpuRays::new(&g)
            .run(&g, &gb, &rays, Query::Closest)
            .unwrap();
        assert_eq!(hits.iter().filter(|h| h.primitive().is_none()).count(), 0);
    }
}

#[test]
fn gpu_skinning_equals_cpu_skinning_and_feeds_refit() {
    let Some(g) = gpu() else { return };
    let m = cube_sphere(20);
    let n = m.positions().len();
    let skin = SkinWeights {
        joints: (0..n)
            .map(|i| [(i % 3) as u16, ((i + 1) % 3) as u16, 2, 0])
            .collect(),
        weights: m
            .positions()
            .iter()
            .map(|p| {
                let a = 0.5 + 0.5 * p.y;
                [a * 0.7, (1.0 - a) * 0.7, 0.2, 0.1]
            })
            .collect(),
    };
    let mats = [
        Mat4::from_rotation_translation(Quat::from_rotation_z(0.4), Vec3::new(0.1, 0.2, 0.0)),
        Mat4::from_scale_rotation_translation(
            Vec3::splat(1.2),
            Quat::from_rotation_x(-0.3),
            Vec3::ZERO,
        ),
        Mat4::from_translation(Vec3::new(0.0, -0.3, 0.5)),
    ];
    let mut cpu = vec![Vec3::ZERO; n];
    skin_positions(m.positions(), &skin, &mats, &mut cpu).unwrap();
    let (bvh, _) = gpu_lbvh(&g, &m);
    let gskin = GpuSkin::new(&g, m.positions(), &skin, 3, &bvh).unwrap();
    let mut enc = g.encoder();
    gskin.record(&g, &mut enc, &mats).unwrap();
    bvh.record_refit(&g, &mut enc).unwrap();
    g.submit(enc);
    let skinned = bvh.read_positions(&g).unwrap();
    let worst = skinned
        .iter()
        .zip(&cpu)
        .map(|(a, b)| (*a - *b).abs().max_element())
        .fold(0.0, f32::max);
    assert_eq!(worst, 0.0, "GPU and CPU skinning differ");
    assert!(
        skinned
            .iter()
            .zip(m.positions())
            .any(|(a, b)| (*a - *b).length() > 0.1),
        "nothing moved"
    );
    // The refit read the skinned positions on the GPU: its tree bounds exactly the GPU-skinned triangles.
    let tree = bvh.read_tree(&g).unwrap();
    tree.validate(Some(&m.with_positions(skinned).unwrap().triangle_bounds()))
        .unwrap();
    // Bad palettes are errors.
    assert!(gskin.record(&g, &mut g.encoder(), &mats[..2]).is_err());
    let bad = SkinWeights {
        joints: vec![[0, 0, 0, 7]; n],
        weights: skin.weights.clone(),
    };
    assert!(GpuSkin::new(&g, m.positions(), &bad, 3, &bvh).is_err());
}

/// The characteriser's histogram by definition, from the CPU's Morton codes of box centres.
fn brute_histogram(m: &Mesh, bins: usize) -> Vec<u32> {
    let centres: Vec<Vec3> = m.triangle_bounds().iter().map(|b| b.center()).collect();
    let cb = centres.iter().fold(Aabb::EMPTY, |mut a, &c| {
        a.grow(c);
        a
    });
    let codes: Vec<u64> = centres
        .iter()
        .map(|&c| kinetrace::geometry::morton30(c, &cb) as u64)
        .collect();
    let (lo, hi) = (
        codes.iter().copied().min().unwrap_or(0),
        codes.iter().copied().max().unwrap_or(0),
    );
    let width = (hi - lo + 1).div_ceil(bins as u64);
    let mut h = vec![0u32; bins];
    for c in codes {
        h[(((c - lo) / width) as usize).min(bins - 1)] += 1;
    }
    h
}

#[test]
fn morton_histogram_equals_cpu_histogram() {
    let Some(g) = gpu() else { return };
    let mut r = rng(11);
    let clusters = map_mesh(&soup(3, 20_000), |p| {
        if p.x > 0.5 { p + Vec3::splat(1e4) } else { p }
    });
    let meshes: Vec<Mesh> = SIZES
        .into_iter()
        .chain([BIG])
        .map(|n| soup(n as u64 + 9, n))
        .chain([
            clusters,
            map_mesh(&soup(4, 3000), |p| p * 1e-30 + Vec3::splat(1e6)),
        ])
        .collect();
    for m in &meshes {
        let n = m.triangle_count();
        let (bvh, _) = gpu_lbvh(&g, m);
        let cpu = kinetrace::characterize::profile_mesh(m);
        for bins in [cpu.bins, 1, r.random_range(2..=256)] {
            let mut enc = g.encoder();
            let h = bvh.record_histogram(&g, &mut enc, bins).unwrap();
            g.submit(enc);
            let h = h.wait(&g).unwrap();
            assert_eq!(h, brute_histogram(m, bins), "n = {n}, {bins} bins");
            if bins == cpu.bins {
                assert_eq!(h, cpu.histogram, "n = {n}: the CPU profile's histogram");
            }
        }
    }
}

#[test]
fn histogram_misuse_is_an_error() {
    let Some(g) = gpu() else { return };
    let m = soup(1, 100);
    let bvh = GpuMeshBvh::new(&g, &m).unwrap();
    let mut enc = g.encoder();
    assert!(
        bvh.record_histogram(&g, &mut enc, 8).is_err(),
        "before a build"
    );
    let (bvh, _) = gpu_lbvh(&g, &m);
    for bins in [0, kinetrace::gpu::MAX_HISTOGRAM_BINS + 1] {
        assert!(
            bvh.record_histogram(&g, &mut enc, bins).is_err(),
            "{bins} bins"
        );
    }
}
