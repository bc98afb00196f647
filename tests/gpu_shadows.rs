//! The shadow map rendered on the GPU (`gpu::GpuShadowMap`) against the CPU's, texel for texel, and whole
//! shadow passes with either map against each other — on lavapipe in CI (`KINETRACE_REQUIRE_GPU=1` makes a
//! missing adapter a failure; without it these tests skip and say so). What makes the CPU map right is
//! tested in `tests/shadows.rs` and the map's unit tests (analytic shadows, brute-force coverage).
#![cfg(feature = "gpu")]

#[allow(dead_code)]
#[path = "../examples/crowd.rs"]
mod crowd;

mod common;
use common::*;
use glam::{Affine3A, Quat, Vec3};
use kinetrace::Error;
use kinetrace::gpu::{GpuContext, GpuOptions, GpuShadowMap};
use kinetrace::shadows::{GBuffer, HardShadows, Occluders, ShadowMode, ShadowSettings};
use rand::Rng;

/// Groups of triangles, each with its own placement.
struct Groups(Vec<(Vec<[Vec3; 3]>, Option<Affine3A>)>);

impl Occluders for Groups {
    fn groups(&self) -> usize {
        self.0.len()
    }

    fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
        (&self.0[g].0, self.0[g].1)
    }
}

/// Triangles over a 100 × 100 area: mostly smaller than a texel, some tens of texels wide, a few far off
/// the map, needles and collinear ones, and broken ones (a NaN or infinite corner); in groups placed by
/// rotations, scales and translations, one in world space, two empty (one of them the last), one with a
/// NaN transform.
fn scene(seed: u64) -> Groups {
    let mut r = rng(seed);
    let tri = |k: usize, r: &mut rand::rngs::SmallRng| {
        let size = if k.is_multiple_of(53) { 40.0 } else { 0.4 };
        let far = if k.is_multiple_of(1001) { 700.0 } else { 0.0 };
        let o = rand_vec(r, 0.0, 100.0) * Vec3::new(1.0, 0.2, 1.0) + Vec3::X * far;
        let mut t = [o, o + rand_vec(r, 0.0, size), o + rand_vec(r, 0.0, size)];
        match k % 397 {
            1 => t[2] = t[0] + (t[1] - t[0]) * 0.5,       // collinear
            2 => t[2] = t[1] + Vec3::new(1e-6, 0.0, 0.0), // needle
            3 => t[1].y = f32::NAN,                       // broken
            4 => t[2].x = f32::INFINITY,                  // broken
            _ => {}
        }
        t
    };
    let mut groups = Vec::new();
    let mut k = 0;
    for g in 0..10 {
        let n = if g == 3 || g == 9 { 0 } else { 1500 + 700 * g };
        let tris: Vec<[Vec3; 3]> = (0..n)
            .map(|_| {
                k += 1;
                tri(k, &mut r)
            })
            .collect();
        let place = match g {
            0 => None,
            5 => Some(Affine3A::from_translation(Vec3::NAN)),
            _ => Some(Affine3A::from_scale_rotation_translation(
                Vec3::splat(r.random_range(0.5..1.5)),
                Quat::from_rotation_y(r.random_range(-0.3..0.3)),
                rand_vec(&mut r, -10.0, 10.0) * Vec3::new(1.0, 0.1, 1.0),
            )),
        };
        groups.push((tris, place));
    }
    Groups(groups)
}

/// A `side × side` grid of ground receivers over the scene, facing up.
fn ground(side: usize) -> GBuffer {
    let mut g = GBuffer::new(side, side);
    for j in 0..side {
        for i in 0..side {
            let at = |k: usize| 110.0 * (k as f32 + 0.37) / side as f32 - 5.0;
            g.set(j * side + i, Vec3::new(at(i), 0.0, at(j)), Vec3::Y);
        }
    }
    g
}

/// A context of its own on the shared context's adapter (`None`, skipping, where there is none): for
/// tests that read the upload and read-back counters, which other tests sharing a context move.
fn own_context() -> Option<GpuContext> {
    gpu_or_skip()?;
    let options = GpuOptions {
        hardware_only: false,
        ..Default::default()
    };
    Some(GpuContext::with_options(&options).expect("the adapter the shared context found"))
}

/// Every texel of the two passes' maps holds the same depth (equal as floats: a zero's sign aside), and
/// their visibility and marked pixels are the same.
fn assert_same_pass(cpu: &HardShadows, gpu: &HardShadows, what: &str) {
    assert!(
        !cpu.stats().map_on_gpu && gpu.stats().map_on_gpu,
        "{what}: where the maps were rendered"
    );
    let (a, b) = (cpu.shadow_map(), gpu.shadow_map());
    assert_eq!(a.resolution(), b.resolution(), "{what}");
    assert_eq!(a.texel_size(), b.texel_size(), "{what}: the map's frame");
    let res = a.resolution();
    let mut covered = 0;
    for j in 0..res {
        for i in 0..res {
            let (da, db) = (a.depth(i, j), b.depth(i, j));
            assert!(da == db, "{what}: texel ({i}, {j}): CPU {da}, GPU {db}");
            covered += da.is_finite() as usize;
        }
    }
    assert!(
        covered > res * res / 4,
        "{what}: only {covered} texels covered"
    );
    assert_eq!(cpu.marked(), gpu.marked(), "{what}: marked pixels");
    assert_eq!(cpu.visibility(), gpu.visibility(), "{what}: visibility");
}

#[test]
fn gpu_map_is_the_cpu_map_texel_for_texel() {
    let Some(ctx) = gpu_or_skip() else { return };
    let occluders = scene(11);
    let world: Vec<[Vec3; 3]> = (occluders.0.iter())
        .flat_map(|(tris, place)| {
            let a = place.unwrap_or(Affine3A::IDENTITY);
            tris.iter().map(move |t| t.map(|p| a.transform_point3(p)))
        })
        .collect();
    // Brute force: any triangle crossing the segment (f64 Möller–Trumbore).
    let rays = |from: Vec3, to: Vec3| {
        (world.iter())
            .any(|&t| moller_trumbore(from, to - from, t).is_some_and(|h| h.0 > 0.0 && h.0 < 1.0))
    };
    let g = ground(64);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    for (mode, angle) in [
        (ShadowMode::ShadowMap, 0.0),
        (ShadowMode::Selective, 0.0),
        (ShadowMode::Selective, 0.03),
    ] {
        for (towards, res) in [(Vec3::new(0.3, 1.0, 0.2), 256), (Vec3::Y, 200)] {
            let s = ShadowSettings {
                mode,
                towards_light: towards,
                map_resolution: res,
                light_angle: angle,
                samples: 4,
                ..Default::default()
            };
            let what = format!("{mode:?}, light angle {angle}, towards {towards}, {res}²");
            let mut cpu = HardShadows::new();
            cpu.run(&s, &occluders, &g, rays).expect("the CPU pass");
            let mut gpu = HardShadows::new();
            gpu.run_with(&s, &occluders, &g, rays, &mut on_gpu)
                .expect("the GPU pass");
            assert_same_pass(&cpu, &gpu, &what);
        }
    }
}

/// Where triangles' corners sit on texel centres and their edges run along rows and columns through
/// them — the rasteriser's ties, its row spans' ends and its slack — the GPU map is the CPU's: a light
/// straight down, receivers on the integers 0..=126 (a 128² map of unit texels whose centres lie on
/// the half-integers), occluders with corners on the half-integer lattice (right triangles with
/// axis-aligned legs, thin slivers a centre wide, and lattice triangles of any shape).
#[test]
fn gpu_map_is_the_cpu_map_where_edges_run_through_texel_centres() {
    let Some(ctx) = gpu_or_skip() else { return };
    let mut r = rng(23);
    let half = |r: &mut rand::rngs::SmallRng, hi: i32| r.random_range(0..hi) as f32 + 0.5;
    let mut tris = Vec::new();
    for k in 0..3000 {
        let (x, z, y) = (half(&mut r, 120), half(&mut r, 120), half(&mut r, 20));
        let (w, d) = (r.random_range(1..9) as f32, r.random_range(1..9) as f32);
        let t = match k % 3 {
            0 => [
                Vec3::new(x, y, z),
                Vec3::new(x + w, y, z),
                Vec3::new(x, y + 1.0, z + d),
            ],
            1 => [
                Vec3::new(x, y, z),
                Vec3::new(x + w, y, z + 1.0),
                Vec3::new(x, y, z + 1.0),
            ],
            _ => [
                Vec3::new(x, y, z),
                Vec3::new(half(&mut r, 126), y + 2.0, half(&mut r, 126)),
                Vec3::new(half(&mut r, 126), y, half(&mut r, 126)),
            ],
        };
        tris.push(t);
    }
    let side = 127;
    let mut g = GBuffer::new(side, side);
    for j in 0..side {
        for i in 0..side {
            g.set(j * side + i, Vec3::new(i as f32, 0.0, j as f32), Vec3::Y);
        }
    }
    let rays = |from: Vec3, to: Vec3| {
        (tris.iter())
            .any(|&t| moller_trumbore(from, to - from, t).is_some_and(|h| h.0 > 0.0 && h.0 < 1.0))
    };
    let mut on_gpu = GpuShadowMap::new(&ctx);
    for mode in [ShadowMode::ShadowMap, ShadowMode::Selective] {
        let s = ShadowSettings {
            mode,
            towards_light: Vec3::Y,
            map_resolution: 128,
            ..Default::default()
        };
        let mut cpu = HardShadows::new();
        cpu.run(&s, &tris, &g, rays).expect("the CPU pass");
        assert_eq!(cpu.shadow_map().texel_size(), 1.0, "unit texels");
        let mut gpu = HardShadows::new();
        gpu.run_with(&s, &tris, &g, rays, &mut on_gpu)
            .expect("the GPU pass");
        assert_same_pass(&cpu, &gpu, &format!("lattice, {mode:?}"));
    }
}

/// A triangle under the whole of a map of more rows than its workgroups' invocations cover in one step
/// (8 × 256) — the ground under a 2,600² map, the map's rows shared out among the workgroups — renders
/// as on the CPU, as do the small triangles standing on it.
#[test]
fn gpu_map_of_a_ground_under_more_rows_than_one_step_is_the_cpu_map() {
    let Some(ctx) = gpu_or_skip() else { return };
    let s = ShadowSettings {
        mode: ShadowMode::ShadowMap,
        towards_light: Vec3::new(0.3, 1.0, 0.2),
        map_resolution: 2600,
        ..Default::default()
    };
    let (cpu, gpu) = both_passes(
        &s,
        &cluttered_ground(),
        &ground(32),
        &mut GpuShadowMap::new(&ctx),
    );
    assert_same_pass(&cpu, &gpu, "ground under a 2,600² map");
}

/// Uploads of several mebibytes, copied a mebibyte per task across threads (or not): triangles in groups
/// of odd sizes, some empty, whose bounds fall inside the chunks, and a G-buffer of 3.5 MB an array;
/// the map and the classes are the CPU's, and every byte is counted once (a context of its own, whose
/// counters no other test moves).
#[test]
fn large_uploads_split_across_threads_arrive_whole() {
    let Some(ctx) = own_context() else { return };
    let mut r = rng(41);
    let mut groups = Vec::new();
    for n in [0, 40_001, 1, 33_333, 0, 29_000] {
        let tris: Vec<[Vec3; 3]> = (0..n)
            .map(|_| {
                let o = rand_vec(&mut r, 0.0, 100.0) * Vec3::new(1.0, 0.1, 1.0);
                [
                    o,
                    o + rand_vec(&mut r, 0.0, 0.6),
                    o + rand_vec(&mut r, 0.0, 0.6),
                ]
            })
            .collect();
        groups.push((tris, None));
    }
    let floor = cluttered_ground()[..2].to_vec();
    groups.push((floor, None));
    let occluders = Groups(groups);
    let triangles: u64 = occluders.0.iter().map(|(t, _)| t.len() as u64).sum();
    let g = ground(540);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    for parallel in [true, false] {
        let s = ShadowSettings {
            towards_light: Vec3::new(0.3, 1.0, 0.2),
            map_resolution: 256,
            parallel,
            ..Default::default()
        };
        let no_ray = |_: Vec3, _: Vec3| false;
        let mut cpu = HardShadows::new();
        cpu.run(&s, &occluders, &g, no_ray).expect("the CPU pass");
        let mut gpu = HardShadows::new();
        let before = ctx.counters();
        gpu.run_with(&s, &occluders, &g, no_ray, &mut on_gpu)
            .expect("the GPU pass");
        let d = ctx.counters().since(&before);
        let what = format!("parallel {parallel}");
        assert!(
            gpu.stats().classified_on_gpu && !gpu.stats().refitted,
            "{what}"
        );
        assert!(
            cpu.stats().rays > 1000,
            "{what}: {} marked",
            cpu.stats().rays
        );
        assert_same_pass(&cpu, &gpu, &what);
        let groups = occluders.0.len() as u64;
        let pixels = (540 * 540) as u64;
        assert_eq!(
            d.uploaded_bytes,
            36 * triangles + 4 * (groups + 1) + 64 * groups + 32 + 24 * pixels + 112,
            "{what}"
        );
    }
}

/// The large triangles' indirect dispatch (eight workgroups a listed triangle) folded into its second
/// and third dimensions, as it is past the device's limit of workgroups per dimension, here at two and
/// three a dimension: the same map as the CPU's.
#[test]
fn gpu_map_with_its_large_triangles_dispatch_folded_is_the_cpu_map() {
    let Some(ctx) = gpu_or_skip() else { return };
    let s = ShadowSettings {
        mode: ShadowMode::ShadowMap,
        towards_light: Vec3::new(0.3, 1.0, 0.2),
        map_resolution: 1024,
        ..Default::default()
    };
    for groups in [2, 3] {
        let mut on_gpu = GpuShadowMap::new(&ctx);
        on_gpu.limit_workgroups(groups);
        let (cpu, gpu) = both_passes(&s, &cluttered_ground(), &ground(32), &mut on_gpu);
        assert_same_pass(&cpu, &gpu, &format!("folded at {groups} workgroups"));
    }
}

/// `settings`' pass over `occluders` and the receivers `g` (no shadow rays) with the CPU's map and with
/// `on_gpu`'s.
fn both_passes(
    settings: &ShadowSettings,
    occluders: &(impl Occluders + ?Sized),
    g: &GBuffer,
    on_gpu: &mut GpuShadowMap,
) -> (HardShadows, HardShadows) {
    let no_ray = |_: Vec3, _: Vec3| false;
    let mut cpu = HardShadows::new();
    cpu.run(settings, occluders, g, no_ray)
        .expect("the CPU pass");
    let mut gpu = HardShadows::new();
    gpu.run_with(settings, occluders, g, no_ray, on_gpu)
        .expect("the GPU pass");
    (cpu, gpu)
}

/// A 130-unit floor (two triangles, each spanning most of the map's rows) under 200 random triangles up
/// to 3 units across.
fn cluttered_ground() -> Vec<[Vec3; 3]> {
    let mut r = rng(31);
    let floor = [
        Vec3::new(-10.0, 0.0, -10.0),
        Vec3::new(120.0, 0.0, -10.0),
        Vec3::new(120.0, 0.0, 120.0),
        Vec3::new(-10.0, 0.0, 120.0),
    ];
    let mut tris = vec![
        [floor[0], floor[2], floor[1]],
        [floor[0], floor[3], floor[2]],
    ];
    for _ in 0..200 {
        let o = rand_vec(&mut r, 0.0, 100.0) * Vec3::new(1.0, 0.1, 1.0);
        tris.push([
            o,
            o + rand_vec(&mut r, 0.0, 3.0),
            o + rand_vec(&mut r, 0.0, 3.0),
        ]);
    }
    tris
}

/// Nothing to render — no occluder, only broken ones, or no receiver — gives the CPU's empty map and
/// image on the GPU too, with no error.
#[test]
fn gpu_map_of_nothing_is_the_cpu_map() {
    let Some(ctx) = gpu_or_skip() else { return };
    let broken = vec![
        [Vec3::NAN, Vec3::ONE, Vec3::ZERO],
        [Vec3::ZERO, Vec3::INFINITY, Vec3::X],
    ];
    let none: Vec<[Vec3; 3]> = Vec::new();
    let sky = GBuffer::new(16, 16);
    let g = ground(16);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    let s = ShadowSettings {
        towards_light: Vec3::new(0.3, 1.0, 0.2),
        map_resolution: 64,
        ..Default::default()
    };
    for (what, occluders, g) in [
        ("no occluder", &none, &g),
        ("broken", &broken, &g),
        ("no receiver", &broken, &sky),
    ] {
        let mut cpu = HardShadows::new();
        cpu.run(&s, occluders, g, |_: Vec3, _: Vec3| false)
            .expect("the CPU pass");
        let mut gpu = HardShadows::new();
        gpu.run_with(&s, occluders, g, |_: Vec3, _: Vec3| false, &mut on_gpu)
            .expect("the GPU pass");
        let (a, b) = (cpu.shadow_map(), gpu.shadow_map());
        assert_eq!(a.resolution(), b.resolution(), "{what}");
        for k in 0..64 * 64 {
            let (x, y) = (k % 64, k / 64);
            assert_eq!(a.depth(x, y), f32::INFINITY, "{what}: the CPU map is empty");
            assert_eq!(b.depth(x, y), f32::INFINITY, "{what}: texel ({x}, {y})");
        }
        assert_eq!(cpu.visibility(), gpu.visibility(), "{what}");
    }
}

/// Groups said to be closed or not ([`Occluders::closed`]).
struct Claimed(Groups, Vec<bool>);

impl Occluders for Claimed {
    fn groups(&self) -> usize {
        self.0.groups()
    }

    fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
        self.0.group(g)
    }

    fn closed(&self, g: usize) -> bool {
        self.1[g]
    }
}

/// Closed groups leave out the same faces away from the light on the GPU as on the CPU: icospheres placed
/// by a rotation and scale, by a mirroring transform (their winding turned over) and in world space,
/// one turned inside out but said to be closed (its far side kept), above an open scene of random
/// triangles — the same map texel for texel and the same passes, with culling and without.
#[test]
fn gpu_map_leaves_out_the_faces_of_closed_groups_the_cpu_map_leaves_out() {
    let Some(ctx) = gpu_or_skip() else { return };
    let sphere = kinetrace::scenes::icosphere(4);
    let tris = |m: &kinetrace::Mesh| (0..m.triangle_count()).map(|i| m.triangle(i)).collect();
    let outwards: Vec<[Vec3; 3]> = tris(&sphere);
    let inwards = outwards.iter().map(|t| [t[0], t[2], t[1]]).collect();
    let at = |scale: Vec3, turn: Quat, to: Vec3| {
        Some(Affine3A::from_scale_rotation_translation(scale, turn, to))
    };
    let mut groups = scene(21).0;
    let open = vec![false; groups.len()];
    groups.extend([
        (
            outwards.clone(),
            at(
                Vec3::new(9.0, 6.0, 7.0),
                Quat::from_rotation_y(0.4),
                Vec3::new(30.0, 35.0, 40.0),
            ),
        ),
        (
            outwards.clone(),
            at(
                Vec3::new(-8.0, 7.0, 8.0),
                Quat::from_rotation_x(0.7),
                Vec3::new(70.0, 40.0, 65.0),
            ),
        ),
        (
            outwards
                .iter()
                .map(|t| t.map(|p| p * 10.0 + Vec3::new(50.0, 45.0, 20.0)))
                .collect(),
            None,
        ),
        (
            inwards,
            at(
                Vec3::splat(8.0),
                Quat::IDENTITY,
                Vec3::new(20.0, 38.0, 80.0),
            ),
        ),
    ]);
    let occluders = Claimed(Groups(groups), [open, vec![true; 4]].concat());
    let g = ground(200);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    for closed_culling in [true, false] {
        let s = ShadowSettings {
            towards_light: Vec3::new(0.3, 1.0, 0.2),
            map_resolution: 256,
            closed_culling,
            ..Default::default()
        };
        let (cpu, gpu) = both_passes(&s, &occluders, &g, &mut on_gpu);
        let closed = if closed_culling {
            4 * outwards.len()
        } else {
            0
        };
        assert_eq!(cpu.stats().closed_triangles, closed);
        assert_eq!(gpu.stats().closed_triangles, closed);
        assert_same_pass(&cpu, &gpu, &format!("closed culling {closed_culling}"));
    }
}

/// A crowd frame's selective pass with the map rendered on the GPU from the world's meshes and transforms
/// is the CPU pass: same map, same marked pixels, same image.
#[test]
fn crowd_pass_with_the_gpu_map_is_the_cpu_pass() {
    let Some(ctx) = gpu_or_skip() else { return };
    let opt = crowd::Options {
        characters: 6,
        triangles: 1_500,
        gpu: false,
        ..Default::default()
    };
    let (mut world, mut schedule) = crowd::setup(&opt).expect("the crowd sets up");
    for _ in 0..20 {
        crowd::step(&mut world, &mut schedule);
    }
    let (_, g) = crowd::primary_hits(&world, 160, 120, &crowd::Camera::default());
    let tw = world.resource::<kinetrace::ecs::TraceWorld>();
    let all = kinetrace::ecs::QueryFilter::default();
    let rays = |from: Vec3, to: Vec3| tw.occluded(from, to, &all);
    let s = ShadowSettings {
        towards_light: crowd::sun(),
        map_resolution: 256,
        ..Default::default()
    };
    let mut cpu = HardShadows::new();
    cpu.run(&s, &tw.occluders(&all), &g, rays)
        .expect("the CPU pass");
    let mut gpu = HardShadows::new();
    gpu.run_with(
        &s,
        &tw.occluders(&all),
        &g,
        rays,
        &mut GpuShadowMap::new(&ctx),
    )
    .expect("the GPU pass");
    assert!(cpu.stats().rays > 0, "some pixels get rays");
    assert!(gpu.stats().classified_on_gpu, "classified where the map is");
    // The characters are closed: their faces away from the light left out on both.
    let characters = tw.occluders(&all).triangle_count() - 2;
    assert_eq!(cpu.stats().closed_triangles, characters);
    assert_eq!(gpu.stats().closed_triangles, characters);
    assert_same_pass(&cpu, &gpu, "crowd frame 20");
    // The GPU's map classified on the CPU.
    let mut on_gpu = GpuShadowMap::new(&ctx);
    on_gpu.set_classify(false);
    let mut mixed = HardShadows::new();
    mixed
        .run_with(&s, &tw.occluders(&all), &g, rays, &mut on_gpu)
        .expect("the GPU-map pass");
    assert!(!mixed.stats().classified_on_gpu, "classified on the CPU");
    assert_same_pass(&cpu, &mixed, "crowd frame 20, classified on the CPU");
}

/// Pixels drawn to reach every branch of the classification: receivers on the floor and up to half a
/// unit above it; normals up, random, grazing, facing away, zero (either sign), NaN, infinite and far
/// from unit length; on an image whose rows do not start at a word of four pixels. The first row holds
/// the corners of the receivers' box, facing the light, so the first fit (to a sample of the rows) is
/// the whole image's. With `wild`, receivers off the map, far away and not finite as well: the first fit
/// misses some, and the map is fitted twice.
fn hostile(towards: Vec3, wild: bool, seed: u64) -> GBuffer {
    let (w, h) = (37, 23);
    let mut r = rng(seed);
    let mut g = GBuffer::new(w, h);
    for k in 0..w * h {
        let floor = Vec3::new(
            r.random_range(-5.0..115.0),
            0.0,
            r.random_range(-5.0..115.0),
        );
        let p = match r.random_range(0..20) {
            0 if wild => Vec3::new(f32::NAN, 0.0, 1.0),
            1 if wild => Vec3::new(0.0, f32::INFINITY, 1.0),
            2 if wild => floor * 1e30,
            3 if wild => floor + Vec3::X * 500.0,
            4..=7 => floor + Vec3::Y * r.random_range(0.0..0.5),
            _ => floor,
        };
        let random = rand_vec(&mut r, -1.0, 1.0).normalize_or_zero();
        let n = match r.random_range(0..24) {
            0 => Vec3::ZERO,
            1 => Vec3::new(-0.0, 0.0, -0.0),
            2 => Vec3::new(f32::NAN, 1.0, 0.0),
            3 => Vec3::new(0.0, f32::INFINITY, 0.0),
            4 => Vec3::new(0.0, f32::NEG_INFINITY, 0.0),
            5 => -towards,
            6 => towards.any_orthonormal_vector(),
            7 => (towards.any_orthonormal_vector() + towards * 1e-3).normalize(),
            8 => Vec3::Y * 3.0,
            9 => random * 1e-3,
            10 => random * 1e37,
            11..=15 => random,
            _ => Vec3::Y,
        };
        g.set(k, p, n);
    }
    for c in 0..8 {
        let corner = |bit: usize, lo: f32, hi: f32| if c >> bit & 1 == 0 { lo } else { hi };
        let p = Vec3::new(
            corner(0, -5.0, 115.0),
            corner(1, 0.0, 0.5),
            corner(2, -5.0, 115.0),
        );
        g.set(c, p, towards);
    }
    g
}

/// The GPU's classification (the default with a `GpuShadowMap`) gives every pixel the CPU's class — the
/// same visibility, marked pixels and counts — over hostile pixels ([`hostile`]), under lights from
/// several directions, with constant biases and edge thresholds from none to wide, where the first fit
/// covered every receiver and where it missed some (then classified again over the whole image's bounds,
/// the G-buffer not uploaded again: a context of its own, whose counters no other test moves), and where
/// the first fit found no receiver at all (the GPU's first classification is then the second, and
/// uploads the G-buffer); an edge threshold beyond `f32` is classified on the CPU.
#[test]
fn gpu_classification_is_the_cpu_classification_pixel_for_pixel() {
    let Some(ctx) = own_context() else { return };
    let tris = cluttered_ground();
    let mut on_gpu = GpuShadowMap::new(&ctx);
    let (mut cpu, mut gpu) = (HardShadows::new(), HardShadows::new());
    let no_ray = |_: Vec3, _: Vec3| false;
    let mut seen = [0usize; 3];
    for (k, towards) in [
        Vec3::new(0.3, 1.0, 0.2),
        Vec3::new(-0.7, 0.4, 0.1),
        Vec3::Y,
        Vec3::new(0.05, 0.2, -1.0),
    ]
    .into_iter()
    .enumerate()
    {
        // (bias, edge threshold, wild receivers, no receiver in the first fit's sample of rows)
        for (bias_texels, edge_texels, wild, blind) in [
            (1.0, 1.5, false, false),
            (0.0, 0.0, true, false),
            (2.5, 8.0, false, false),
            (1.0, 1.5, true, false),
            (0.0, 0.0, false, false),
            (1.0, 1.5, false, true),
            (1.0, f32::MAX, false, false),
        ] {
            let what = format!("light {towards}, bias {bias_texels}, edge {edge_texels}, {blind}");
            let mut g = hostile(towards.normalize(), wild, k as u64);
            if blind {
                // The first fit of a new pass (rows 0, 16 and the last; a warm pass would sample the rows
                // of its last extremes too) finds nothing to fit: the CPU classifies the first time, the
                // GPU only after the map is fitted to every row.
                for row in [0, 16, 22] {
                    g.normals[row * 37..(row + 1) * 37].fill(Vec3::ZERO);
                }
                (cpu, gpu) = (HardShadows::new(), HardShadows::new());
            }
            let s = ShadowSettings {
                towards_light: towards,
                map_resolution: 64,
                bias_texels,
                edge_texels,
                ..Default::default()
            };
            cpu.run(&s, &tris, &g, no_ray).expect("the CPU pass");
            let before = ctx.counters();
            gpu.run_with(&s, &tris, &g, no_ray, &mut on_gpu)
                .expect("the GPU pass");
            let d = ctx.counters().since(&before);
            let (a, b) = (cpu.stats(), gpu.stats());
            // An edge threshold beyond f32 (the CPU's `Δ ≤ ∞`) is the CPU's to classify.
            let on_gpu = edge_texels < f32::MAX;
            assert!(
                b.classified_on_gpu == on_gpu && !a.classified_on_gpu,
                "{what}"
            );
            assert_eq!(a.refitted, wild || blind, "{what}: fitted twice");
            assert_eq!(b.refitted, a.refitted, "{what}");
            // A map (one group; no parameters where the fit finds no receiver) per fit, a
            // classification per fit on the GPU, and the G-buffer uploaded once a pass where any.
            let fits = 1 + (wild || blind) as u64;
            let map = 36 * tris.len() as u64 + 4 * 2 + 64 + 32;
            let classified = match (on_gpu, blind) {
                (false, _) => 0,
                (true, true) => 1,
                (true, false) => fits,
            };
            let gbuffer = if classified > 0 { 24 * 37 * 23 } else { 0 };
            assert_eq!(
                d.uploaded_bytes,
                fits * map - 32 * blind as u64 + 112 * classified + gbuffer,
                "{what}"
            );
            assert_eq!((b.facing, b.rays), (a.facing, a.rays), "{what}");
            assert_eq!(cpu.marked(), gpu.marked(), "{what}: marked pixels");
            let (va, vb) = (cpu.visibility(), gpu.visibility());
            assert_eq!(va, vb, "{what}: visibility");
            // Marked pixels are lit here (no ray finds a blocker).
            seen[0] += a.rays;
            seen[1] += va.iter().filter(|&&v| v == 0.0).count();
            seen[2] += va.iter().filter(|&&v| v == 1.0).count() - a.rays;
        }
    }
    // Every kind of verdict came up: marked, shadowed (or facing away), lit (or empty).
    assert!(
        seen.iter().all(|&n| n > 200),
        "{seen:?} marked, shadowed, lit"
    );
}

/// A warm GPU map costs, per render, one submission and one blocking wait (two for an area light, whose
/// extent waits for the point nearest the light), the upload of 36 bytes a triangle plus each group's
/// first triangle and transform and the parameters, the read-back of 4 bytes a texel plus the nearest
/// point, and no new buffer (a context of its own: the counters are the context's, and the other tests
/// share theirs). Classifying a hard selective pass too goes in the map's submission and wait, and adds
/// the G-buffer's 24 bytes a pixel and the classification's parameters up, and a byte a pixel and a
/// flag back.
#[test]
fn a_warm_gpu_map_costs_one_submission_its_triangles_and_its_texels_and_classifying_none_more() {
    let Some(ctx) = own_context() else { return };
    let occluders = scene(3);
    let triangles: u64 = occluders.0.iter().map(|(t, _)| t.len() as u64).sum();
    let groups = occluders.0.len() as u64;
    let g = ground(32);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    let mut pass = HardShadows::new();
    let res = 128u64;
    let pixels = 32 * 32;
    for (mode, angle, submissions) in [
        (ShadowMode::ShadowMap, 0.0, 1),
        (ShadowMode::ShadowMap, 0.03, 2),
        (ShadowMode::Selective, 0.0, 1),
    ] {
        let classified = mode == ShadowMode::Selective;
        let s = ShadowSettings {
            mode,
            towards_light: Vec3::new(0.3, 1.0, 0.2),
            map_resolution: res as usize,
            light_angle: angle,
            ..Default::default()
        };
        let no_ray = |_: Vec3, _: Vec3| false;
        pass.run_with(&s, &occluders, &g, no_ray, &mut on_gpu)
            .expect("the warm-up pass");
        let before = ctx.counters();
        pass.run_with(&s, &occluders, &g, no_ray, &mut on_gpu)
            .expect("the GPU pass");
        let d = ctx.counters().since(&before);
        assert!(!pass.stats().refitted, "one map a pass");
        assert!(pass.stats().map_on_gpu);
        assert_eq!(pass.stats().classified_on_gpu, classified);
        let (classify_up, classify_back) = if classified {
            (24 * pixels + 112, pixels + 4)
        } else {
            (0, 0)
        };
        assert_eq!(d.submissions, submissions, "light angle {angle}");
        assert_eq!(
            d.uploaded_bytes,
            36 * triangles + 4 * (groups + 1) + 64 * groups + 32 * submissions + classify_up,
            "{mode:?}, light angle {angle}"
        );
        let nearest = 4 * submissions;
        assert_eq!(
            d.read_back_bytes,
            4 * res * res + nearest + classify_back,
            "{mode:?}, light angle {angle}"
        );
        assert!(d.blocking_waits <= submissions, "light angle {angle}");
        assert_eq!(d.allocated_bytes, 0, "light angle {angle}: no new buffer");
    }
}

/// A G-buffer larger than the device binds is classified on the CPU, not refused: on a device whose
/// storage bindings hold a 64² map and the occluders but not the 360² G-buffer's 1.5 MB arrays, the pass
/// renders its map on the GPU, classifies on the CPU, and gives the CPU pass's map and image.
#[test]
fn a_gbuffer_past_the_devices_buffers_is_classified_on_the_cpu() {
    let Some(shared) = gpu_or_skip() else { return };
    let mut limits = shared.limits();
    limits.max_storage_buffer_binding_size = 1 << 20;
    let ctx = GpuContext::with_options(&GpuOptions {
        limits: Some(limits),
        ..Default::default()
    })
    .expect("smaller limits than the adapter's");
    let s = ShadowSettings {
        towards_light: Vec3::new(0.3, 1.0, 0.2),
        map_resolution: 64,
        ..Default::default()
    };
    let (g, tris) = (ground(360), cluttered_ground());
    let no_ray = |_: Vec3, _: Vec3| false;
    let mut cpu = HardShadows::new();
    cpu.run(&s, &tris, &g, no_ray).expect("the CPU pass");
    let mut gpu = HardShadows::new();
    gpu.run_with(&s, &tris, &g, no_ray, &mut GpuShadowMap::new(&ctx))
        .expect("a G-buffer too large to bind is no error");
    assert!(!gpu.stats().classified_on_gpu, "classified on the CPU");
    assert!(cpu.stats().rays > 0, "some pixels marked");
    assert_same_pass(&cpu, &gpu, "G-buffer past the device's buffers");
}

/// A map larger than the device binds is an error (`Error::Gpu`, saying which buffer), not a panic, and
/// the pass keeps no half-made map; the same renderer then renders a map that fits.
#[test]
fn a_map_past_the_devices_buffers_is_an_error() {
    let Some(ctx) = gpu_or_skip() else { return };
    let limits = ctx.limits();
    let limit = limits
        .max_buffer_size
        .min(limits.max_storage_buffer_binding_size);
    let res = 16_384u64;
    if res * res * 4 <= limit {
        skip("this device binds a 16,384² map (1 GiB): no map past its buffers to ask for");
        return;
    }
    let occluders = scene(5);
    let g = ground(16);
    let mut on_gpu = GpuShadowMap::new(&ctx);
    let mut pass = HardShadows::new();
    let mut s = ShadowSettings {
        towards_light: Vec3::new(0.3, 1.0, 0.2),
        map_resolution: res as usize,
        ..Default::default()
    };
    let no_ray = |_: Vec3, _: Vec3| false;
    match pass.run_with(&s, &occluders, &g, no_ray, &mut on_gpu) {
        Err(Error::Gpu(why)) => assert!(why.contains("shadow map"), "{why}"),
        other => panic!(
            "a {res}² map on a {limit}-byte device: {:?}",
            other.map(|v| v.len())
        ),
    }
    assert_eq!(pass.shadow_map().resolution(), 0, "no map kept");
    s.map_resolution = 64;
    let mut cpu = HardShadows::new();
    cpu.run(&s, &occluders, &g, no_ray).expect("the CPU pass");
    pass.run_with(&s, &occluders, &g, no_ray, &mut on_gpu)
        .expect("a map that fits");
    assert_same_pass(&cpu, &pass, "after the error");
}
