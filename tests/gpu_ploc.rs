//! PLOC (Meister and Bittner 2018) on the CPU and the GPU: trees validate, the GPU's equals the CPU's node for
//! node (same tie rules), ray queries through them equal the independent brute-force oracle, and the SAH cost
//! is reported against CPU binned SAH. GPU parts run on lavapipe in CI (`KINETRACE_REQUIRE_GPU=1` makes a
//! missing adapter a failure; without it they skip and say so).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::gpu::{GpuContext, GpuPloc};
use kinetrace::scenes::{bumpy_torus, folded_sheet, shoebox};
use kinetrace::{Error, Mesh, MeshBvh, Ray};

const SIZES: [usize; 9] = [0, 1, 2, 3, 31, 32, 33, 1023, 1025];

/// The scenes of `src/scenes.rs` and the numerically extreme ones of `tests/extreme.rs`.
fn scenes() -> Vec<(&'static str, Mesh)> {
    let tiny = map_mesh(&icosphere(2), |p| p * 1e-6 + Vec3::splat(0.25));
    let stadium = map_mesh(&cube_sphere(2), |p| p.signum() * 5e3);
    let mut pos = tiny.positions().to_vec();
    let mut idx = tiny.indices().to_vec();
    let off = pos.len() as u32;
    pos.extend_from_slice(stadium.positions());
    idx.extend(stadium.indices().iter().map(|i| i + off));
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(300)).unwrap();
    let line = collinear_zero_area(600);
    vec![
        ("icosphere", icosphere(3)),
        ("cube sphere", cube_sphere(6)),
        ("bumpy torus", bumpy_torus(2000)),
        ("folded sheet", folded_sheet(20, 0.7)),
        (
            "shoebox",
            shoebox(Vec3::splat(-2.0), Vec3::new(3.0, 1.0, 2.0)),
        ),
        (
            "huge offset",
            map_mesh(&icosphere(2), |p| Vec3::splat(1e6) + p * 1e3),
        ),
        ("teapot in a stadium", Mesh::new(pos, idx).unwrap()),
        ("repeated triangle", same),
        ("collinear zero-area", line),
    ]
}

/// Rays from a sphere around the mesh at its box, aimed at random points inside the box.
fn rays_at(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let b = m
        .triangle_bounds()
        .iter()
        .fold(kinetrace::Aabb::EMPTY, |a, x| a.union(x));
    let (c, r) = (b.center(), (b.max - b.min).length().max(1e-3));
    let mut g = rng(seed);
    (0..n)
        .map(|_| {
            let o = c + rand_dir(&mut g) * r;
            let t = rand_vec(&mut g, 0.0, 1.0);
            Ray::new(o, b.min + (b.max - b.min) * t - o)
        })
        .collect()
}

/// Validates, checks closest and any hits against brute force, prints the SAH cost over binned SAH's and
/// returns it (1 for a mesh of at most one triangle).
fn check_tree(m: &Mesh, bvh: &MeshBvh, what: &str) -> f64 {
    let bounds = m.triangle_bounds();
    bvh.bvh()
        .validate(Some(&bounds))
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    for (i, ray) in rays_at(m, m.triangle_count() as u64, 64).iter().enumerate() {
        let hit = bvh.closest_hit(ray).map(|h| (h.primitive, h.t));
        assert_brute_hit(m, ray, hit, &format!("{what} ray {i}"));
        assert_any_hit(m, ray, bvh.any_hit(ray), &format!("{what} any-hit ray {i}"));
    }
    if m.triangle_count() <= 1 {
        return 1.0;
    }
    let sah = MeshBvh::build(m, &BuildOptions::new(Builder::SAH)).unwrap();
    let ratio = bvh.bvh().sah_cost() / sah.bvh().sah_cost();
    eprintln!("{what}: PLOC SAH cost / binned SAH = {ratio:.3}");
    ratio
}

fn cpu_ploc(m: &Mesh, radius: u32) -> MeshBvh {
    MeshBvh::build(m, &BuildOptions::new(Builder::Ploc { radius })).unwrap()
}

#[test]
fn cpu_ploc_trees_validate_and_answer_as_brute_force() {
    for n in SIZES {
        let m = soup(n as u64 + 11, n);
        for radius in [1, 16] {
            check_tree(&m, &cpu_ploc(&m, radius), &format!("soup {n} r = {radius}"));
        }
        // Leaves of up to four: the collapsed subtrees still validate and answer the same.
        let four = MeshBvh::build(&m, &BuildOptions::new(Builder::PLOC).max_leaf_size(4)).unwrap();
        check_tree(&m, &four, &format!("soup {n} leaves of 4"));
    }
    for (name, m) in scenes() {
        let ratio = check_tree(&m, &cpu_ploc(&m, 16), name);
        if name == "folded sheet" {
            // Issue 14's quality target. Per-axis Morton cells stretched the sheet's 0.16 thickness to the
            // grid's 1024 cells and gave 1.158; the cubic cells of PLOC's order give about 1.06.
            assert!(ratio <= 1.15, "{name}: PLOC / binned SAH = {ratio:.3}");
        }
    }
}

#[test]
fn cpu_ploc_is_deterministic_across_threads() {
    let m = soup(3, 20_000);
    let one = MeshBvh::build(&m, &BuildOptions::new(Builder::PLOC).parallel(false)).unwrap();
    let all = cpu_ploc(&m, 16);
    assert_eq!(one.bvh(), all.bvh());
}

#[test]
fn ploc_radius_out_of_range_is_an_error() {
    let m = soup(1, 10);
    for radius in [0, kinetrace::bvh::MAX_PLOC_RADIUS + 1] {
        let e = MeshBvh::build(&m, &BuildOptions::new(Builder::Ploc { radius }));
        assert!(matches!(e, Err(Error::InvalidOption(_))), "radius {radius}");
        if let Some(g) = gpu_or_skip() {
            assert!(matches!(
                GpuPloc::new(&g, &m, radius),
                Err(Error::InvalidOption(_))
            ));
        }
    }
}

/// Returns the rounds the GPU build ran.
fn gpu_equals_cpu(g: &GpuContext, m: &Mesh, radius: u32, what: &str) -> u32 {
    let mut b = GpuPloc::new(g, m, radius).unwrap();
    let gpu = b.build_for_cpu(g, m).unwrap();
    let cpu = cpu_ploc(m, radius);
    assert_eq!(
        gpu.bvh().prim_indices(),
        cpu.bvh().prim_indices(),
        "{what}: slot order"
    );
    assert_eq!(gpu.bvh().nodes(), cpu.bvh().nodes(), "{what}: nodes");
    let c = b.counts();
    let n = m.triangle_count();
    eprintln!(
        "{what}: {} rounds, {} dispatches, {} submissions, {:.0} bytes/triangle",
        c.rounds,
        c.dispatches,
        c.submissions,
        b.memory_bytes() as f64 / n.max(1) as f64
    );
    if n > 1 {
        assert!(c.rounds >= 1 && c.rounds < n as u32, "{what}: {c:?}");
    }
    check_tree(m, &gpu, &format!("{what} (GPU)"));
    // A second build on the same buffers gives the same tree.
    assert_eq!(
        b.build_for_cpu(g, m).unwrap().bvh(),
        cpu.bvh(),
        "{what}: rebuild"
    );
    c.rounds
}

#[test]
fn gpu_ploc_equals_cpu_ploc_node_for_node() {
    let Some(g) = gpu_or_skip() else { return };
    for n in SIZES {
        let m = soup(n as u64 + 11, n);
        for radius in [1, 16] {
            gpu_equals_cpu(&g, &m, radius, &format!("soup {n} r = {radius}"));
        }
    }
    for (name, m) in scenes() {
        let rounds = gpu_equals_cpu(&g, &m, 16, name);
        if name == "repeated triangle" {
            // All distances tie: the pair key pairs (0, 1), (2, 3), … so the count halves every round.
            assert_eq!(
                rounds,
                m.triangle_count().next_power_of_two().ilog2(),
                "{name}"
            );
        }
    }
}

#[test]
#[ignore = "2^20 + 7 triangles: about 45 s on lavapipe on the 2-core VM (passes); run with --ignored"]
fn gpu_ploc_equals_cpu_ploc_at_a_million() {
    let Some(g) = gpu_or_skip() else { return };
    let n = (1 << 20) + 7;
    gpu_equals_cpu(&g, &soup(7, n), 16, "soup 2^20 + 7");
}

#[test]
fn gpu_ploc_wrong_mesh_size_is_an_error() {
    let Some(g) = gpu_or_skip() else { return };
    let mut b = GpuPloc::new(&g, &soup(1, 10), 16).unwrap();
    assert!(matches!(
        b.build_for_cpu(&g, &soup(1, 11)),
        Err(Error::InvalidOption(_))
    ));
}
