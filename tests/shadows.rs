//! Selective ray-traced hard shadows (`kinetrace::shadows`) against independent answers: an analytic
//! shadow of a square, brute-force occlusion over every triangle (the exact ray oracle) for the fully
//! ray-traced image, and the fully ray-traced image for the selective one on crowd frames.

#[allow(dead_code)]
#[path = "../examples/crowd.rs"]
mod crowd;

mod common;

use common::RayOracle;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, TraversalStats};
use kinetrace::ecs::TraceWorld;
use kinetrace::shadows::{
    CpuMap, GBuffer, HardShadows, LightDisc, Occluders, Packets, ShadowMode, ShadowSettings,
};
use kinetrace::{Error, Mesh, MeshBvh, Ray};

fn settings(mode: ShadowMode, towards_light: Vec3) -> ShadowSettings {
    ShadowSettings {
        mode,
        towards_light,
        parallel: false,
        ..Default::default()
    }
}

/// A unit square at height 1 over a 6 × 6 ground (its triangles, their BVH) and a 97 × 97 grid of ground
/// receivers whose lines avoid the square's edges.
fn square_over_ground() -> (Vec<[Vec3; 3]>, MeshBvh, GBuffer) {
    let square = [
        Vec3::new(-0.5, 1.0, -0.5),
        Vec3::new(0.5, 1.0, -0.5),
        Vec3::new(0.5, 1.0, 0.5),
        Vec3::new(-0.5, 1.0, 0.5),
    ];
    let ground = square.map(|p| Vec3::new(p.x * 6.0, 0.0, p.z * 6.0));
    let pos: Vec<Vec3> = square.into_iter().chain(ground).collect();
    let mesh = Mesh::new(pos, vec![0, 2, 1, 0, 3, 2, 4, 6, 5, 4, 7, 6]).unwrap();
    let tris: Vec<[Vec3; 3]> = (0..4).map(|i| mesh.triangle(i)).collect();
    let bvh = MeshBvh::build(&mesh, &BuildOptions::new(Builder::SAH)).unwrap();
    let n = 97; // receivers at -2.4 + 0.05·k: never on |x| = 0.5
    let mut g = GBuffer::new(n, n);
    for j in 0..n {
        for i in 0..n {
            let p = Vec3::new(
                -2.4 + 0.05 * i as f32 + 0.0125,
                0.0,
                -2.4 + 0.05 * j as f32 + 0.0125,
            );
            g.set(j * n + i, p, Vec3::Y);
        }
    }
    (tris, bvh, g)
}

/// Broken occluders (triangles with an infinite or NaN corner, as a corrupt mesh gives, or corners so far
/// out that their projection along the light passes `f32`) are left out of the map: the same map and image
/// as without them, hard and soft, where one infinite corner once made the nearest point, and so every
/// depth, infinite. The rays see only the square (the BVH's triangles).
#[test]
fn non_finite_triangles_leave_the_map_alone() {
    let (tris, bvh, g) = square_over_ground();
    let occluded = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    let mut broken = tris.clone();
    broken.push([Vec3::new(0.0, f32::INFINITY, 0.0), Vec3::X, Vec3::Z]);
    broken.push([Vec3::ONE, Vec3::splat(f32::NAN), Vec3::Y]);
    broken.push([
        Vec3::new(f32::NEG_INFINITY, 2.0, 0.0),
        Vec3::Y * 2.0,
        Vec3::ONE * 2.0,
    ]);
    // Finite corners, but beyond `f32` once projected along the light.
    broken.push([
        Vec3::splat(3e38),
        Vec3::splat(3e38) - Vec3::X * 1e38,
        Vec3::splat(2.9e38),
    ]);
    for (mode, angle) in [
        (ShadowMode::Selective, 0.0),
        (ShadowMode::ShadowMap, 0.0),
        (ShadowMode::Selective, 0.05),
    ] {
        let mut s = settings(mode, Vec3::new(0.3, 1.0, 0.2));
        (s.map_resolution, s.light_angle) = (64, angle);
        let mut pass = HardShadows::new();
        let want = pass.run(&s, &tris, &g, occluded).unwrap().to_vec();
        let (want_rays, want_texel) = (pass.stats().rays, pass.shadow_map().texel_size());
        let got = pass.run(&s, &broken, &g, occluded).unwrap().to_vec();
        assert_eq!(
            pass.shadow_map().texel_size(),
            want_texel,
            "{mode:?} {angle}"
        );
        assert_eq!(pass.stats().rays, want_rays, "{mode:?} {angle}");
        assert_eq!(got, want, "{mode:?} {angle}");
    }
}

/// A G-buffer with broken pixels (infinite and NaN positions under a normal facing the light) gets the
/// same map and the same image at every other pixel as without them: the broken pixels widen nothing
/// (an infinite position once made the receivers' bounds, and so every texel of the map, NaN, and every
/// pixel was marked). The clean image is the analytic one (`square_casts_its_analytic_shadow`).
#[test]
fn non_finite_receivers_leave_the_map_and_the_other_pixels_alone() {
    let (tris, bvh, clean) = square_over_ground();
    let occluded = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    let mut broken = clean.clone();
    let bad = [
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::new(0.0, 0.0, f32::NEG_INFINITY),
        Vec3::splat(f32::NAN),
        Vec3::new(0.0, f32::NAN, 0.0),
    ];
    let at = [0, 500, 4000, 9000];
    for (&k, &p) in at.iter().zip(&bad) {
        broken.positions[k] = p;
    }
    for mode in [ShadowMode::Selective, ShadowMode::ShadowMap] {
        let mut s = settings(mode, Vec3::new(0.3, 1.0, 0.2));
        s.map_resolution = 64;
        let mut pass = HardShadows::new();
        let want = pass.run(&s, &tris, &clean, occluded).unwrap().to_vec();
        let (want_rays, want_texel) = (pass.stats().rays, pass.shadow_map().texel_size());
        let got = pass.run(&s, &tris, &broken, occluded).unwrap().to_vec();
        assert_eq!(pass.shadow_map().texel_size(), want_texel, "{mode:?}");
        assert!(
            pass.stats().rays <= want_rays + at.len(),
            "{mode:?}: {:?}",
            pass.stats()
        );
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            if !at.contains(&k) {
                assert_eq!(g, w, "{mode:?} at pixel {k}");
            }
        }
    }
}

/// The square's shadow with the light straight above: the ground is in shadow exactly where `|x| < 0.5`
/// and `|z| < 0.5`.
#[test]
fn square_casts_its_analytic_shadow() {
    let (tris, bvh, g) = square_over_ground();
    let n = g.width;
    let occluded = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    let inside = |p: Vec3| p.x.abs() < 0.5 && p.z.abs() < 0.5;
    let mut pass = HardShadows::new();
    for mode in [
        ShadowMode::RayTraced,
        ShadowMode::Selective,
        ShadowMode::ShadowMap,
    ] {
        let mut s = settings(mode, Vec3::Y);
        s.map_resolution = 64;
        let vis = pass.run(&s, &tris, &g, occluded).unwrap().to_vec();
        let texel = pass.shadow_map().texel_size();
        for (k, p) in g.positions.iter().enumerate() {
            let want = if inside(*p) { 0.0 } else { 1.0 };
            // The shadow map alone may be wrong only within a texel's diagonal of the shadow's edge.
            let near_edge = (p.x.abs() - 0.5).abs().min((p.z.abs() - 0.5).abs()) < texel * 1.5;
            if mode != ShadowMode::ShadowMap || !near_edge {
                assert_eq!(vis[k], want, "{mode:?} at {p}");
            }
        }
        let stats = pass.stats();
        match mode {
            ShadowMode::RayTraced => assert_eq!(stats.rays, n * n),
            ShadowMode::ShadowMap => assert_eq!(stats.rays, 0),
            ShadowMode::Selective => {
                assert!(stats.rays > 0 && stats.rays < n * n / 4, "{stats:?}")
            }
        }
    }
}

/// The crowd demo's world after `frames` frames (small: 12 characters of 1500 triangles).
fn crowd_world(frames: usize) -> bevy_ecs::world::World {
    let opt = crowd::Options {
        characters: 12,
        triangles: 1_500,
        gpu: false,
        ..Default::default()
    };
    let (mut world, mut schedule) = crowd::setup(&opt).expect("the crowd sets up");
    for _ in 0..frames {
        crowd::step(&mut world, &mut schedule);
    }
    world
}

/// Visibility of every pixel of a crowd frame under `mode`, the sun `light_angle` radians wide (16 samples
/// where soft), and the pass's statistics.
fn crowd_shadows(
    world: &bevy_ecs::world::World,
    g: &GBuffer,
    mode: ShadowMode,
    light_angle: f32,
) -> (Vec<f32>, kinetrace::shadows::ShadowStats) {
    let s = ShadowSettings {
        light_angle,
        samples: 16,
        ..settings(mode, crowd::sun())
    };
    let mut pass = HardShadows::new();
    let vis = crowd::sun_visibility(world, g, &s, &mut pass)
        .unwrap()
        .to_vec();
    (vis, pass.stats())
}

/// The fixed crowd frames the image tests use: frame number and the G-buffer of a 320 × 180 view, with
/// the world it shows.
fn crowd_frames() -> impl Iterator<Item = (usize, bevy_ecs::world::World, GBuffer)> {
    [1, 60, 150].into_iter().map(|frames| {
        let world = crowd_world(frames);
        let (_, g) = crowd::primary_hits(&world, 320, 180, &crowd::Camera::default());
        (frames, world, g)
    })
}

/// On fixed crowd frames the selective image differs from the fully ray-traced one in at most 0.1% of the
/// pixels, with the closed characters' faces away from the light left out of the map (the default) and
/// with every face in it; the shadow map alone (every face) is measured beside it, and the marked
/// fraction is reported.
#[test]
fn selective_matches_ray_traced_on_crowd_frames() {
    for (frames, world, g) in crowd_frames() {
        let (w, h) = (g.width, g.height);
        let (traced, _) = crowd_shadows(&world, &g, ShadowMode::RayTraced, 0.0);
        let (selective, stats) = crowd_shadows(&world, &g, ShadowMode::Selective, 0.0);
        let (map, map_stats) = crowd_shadows(&world, &g, ShadowMode::ShadowMap, 0.0);
        let all_faces = ShadowSettings {
            closed_culling: false,
            ..settings(ShadowMode::Selective, crowd::sun())
        };
        let mut pass = HardShadows::new();
        let every_face = crowd::sun_visibility(&world, &g, &all_faces, &mut pass)
            .unwrap()
            .to_vec();
        // The characters are closed; the ground (two triangles) is not.
        let tw = world.resource::<kinetrace::ecs::TraceWorld>();
        let all = tw
            .occluders(&kinetrace::ecs::QueryFilter::default())
            .triangle_count();
        assert_eq!(stats.closed_triangles, all - 2);
        assert_eq!(pass.stats().closed_triangles, 0);
        // The shadow map alone keeps every face (a pinhole there would be a speck of light).
        assert_eq!(map_stats.closed_triangles, 0);
        let differ = |a: &[f32]| a.iter().zip(&traced).filter(|(x, y)| x != y).count();
        let (sel_diff, map_diff) = (differ(&selective), differ(&map));
        let every_diff = differ(&every_face);
        let shadowed = traced.iter().filter(|v| **v == 0.0).count();
        println!(
            "frame {frames}: {:.2}% of pixels marked ({} rays), selective differs in {sel_diff} pixels \
             (with every face in the map: {every_diff}), the shadow map alone in {map_diff}, of {} \
             ({shadowed} in shadow)",
            100.0 * stats.ray_fraction(),
            stats.rays,
            w * h
        );
        assert!(
            sel_diff.max(every_diff) * 1000 <= w * h,
            "frame {frames}: selective differs from ray traced in {sel_diff} pixels ({every_diff})"
        );
        assert!(stats.rays > 0 && sel_diff <= map_diff);
        assert!(shadowed > 0, "the frame has shadows to get right");
    }
}

/// The crowd demo sends the marked pixels' shadow rays as packets or as single rays walked four at a
/// time interleaved (`TraceWorld::occluded_interleaved`), as its planner picks
/// (`crowd::sun_visibility_with`): two traversals, one answer. On fixed crowd frames, hard and
/// soft, the selective image is the same pixel for pixel either way, and the planner's passes,
/// whichever way each went, give it too. For hard shadows every marked pixel's visibility is also the
/// brute-force oracle's (exact arithmetic over every triangle of the scene, as
/// `ray_traced_equals_brute_force_occlusion`).
#[test]
fn marked_rays_as_packets_or_single_interleaved_give_one_image() {
    for (frames, world, g) in crowd_frames() {
        let mut tris = Vec::new();
        world
            .resource::<TraceWorld>()
            .world_triangles(&Default::default(), &mut tris);
        for light_angle in [0.0, 0.02] {
            let s = ShadowSettings {
                light_angle,
                samples: 16,
                ..settings(ShadowMode::Selective, crowd::sun())
            };
            let image = |as_packets| {
                let mut pass = HardShadows::new();
                let vis =
                    crowd::sun_visibility_rays(&world, &g, &s, &mut pass, &mut CpuMap, as_packets)
                        .unwrap()
                        .to_vec();
                (vis, pass.marked().to_vec())
            };
            let ((packets, marked), (single, _)) = (image(true), image(false));
            let rays = marked.len();
            assert!(rays > 0, "frame {frames}: rays to compare");
            if light_angle == 0.0 {
                for &i in &marked {
                    let (p, n) = (g.positions[i as usize], g.normals[i as usize]);
                    let from = p + n * s.normal_offset;
                    let ray = Ray::segment(from, from + s.towards_light * s.ray_length);
                    RayOracle::new(&ray, tris.iter().copied())
                        .check_any(single[i as usize] == 0.0, &format!("frame {frames}, {i}"));
                }
            }
            let differ = packets.iter().zip(&single).filter(|(a, b)| a != b).count();
            assert_eq!(
                differ, 0,
                "frame {frames}, light {light_angle}: {rays} rays"
            );
            let mut pass = HardShadows::new();
            for _ in 0..4 {
                let planned = crowd::sun_visibility(&world, &g, &s, &mut pass).unwrap();
                assert!(
                    planned == single.as_slice(),
                    "frame {frames}, light {light_angle}"
                );
            }
        }
    }
}

/// The pixels the selective classification (thesis §6.3.3) marks, recomputed from the pass's shadow map
/// through its public accessors alone — the oracle for the pass, which reads `Δ` from a table computed
/// for every texel beforehand and takes short cuts in the verdict: the texel under the receiver and `Δ`
/// from its eight neighbours read one by one; at an edge, the receiver's tangent plane, its depth slope
/// across the map found by projecting the point one normal away (`ShadowMap::project`), in f64, extended
/// to the four texels whose centres (`i + ½`) surround the receiver and compared with their depths less
/// the constant bias: lit when none lies in front, shadowed when all do, else marked (marked, too, where
/// the normal is not finite). A plane within rounding of a texel's depth leaves the pixel undecided (left
/// out of the comparison both ways).
fn full_classification(pass: &HardShadows, s: &ShadowSettings, g: &GBuffer) -> Classified {
    let map = pass.shadow_map();
    let (res, w) = (map.resolution(), map.texel_size());
    let towards = s.towards_light.normalize();
    let edge = s.edge_texels * w;
    let (mut marked, mut unsure, mut edges) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (&p, &n)) in g.positions.iter().zip(&g.normals).enumerate() {
        let cos = n.dot(towards);
        if n == Vec3::ZERO || cos <= 0.0 {
            continue;
        }
        let q = map.project(p);
        let (i, j) = (q.x.floor(), q.y.floor());
        if !(i >= 1.0 && j >= 1.0 && i < (res - 1) as f32 && j < (res - 1) as f32) {
            marked.push(k as u32);
            continue;
        }
        let (i, j) = (i as usize, j as usize);
        let depth = map.depth(i, j);
        if !depth.is_finite() || !cos.is_finite() {
            marked.push(k as u32);
            continue;
        }
        let mut delta = 0f32;
        for y in j - 1..=j + 1 {
            for x in i - 1..=i + 1 {
                delta = delta.max((map.depth(x, y) - depth).abs());
            }
        }
        if delta <= edge {
            continue;
        }
        // `reach` normals away (the map's width, so that rounding is small beside the move) the point
        // moves `reach · (n·u, n·v) / w` texels across: the plane's depth changes by
        // `w · (n·u, n·v) / cos` a texel, `cos` kept above 1/64 (a grazing plane steep but finite).
        let reach = res as f32 * w;
        let across = (map.project(p + n * reach) - q).truncate().as_dvec2() / reach as f64;
        let slope = across * (w as f64 * w as f64 / cos.max(1.0 / 64.0) as f64);
        if !slope.is_finite() {
            // A broken normal: no plane, a ray decides.
            marked.push(k as u32);
            continue;
        }
        let (qx, qy, d) = (q.x as f64, q.y as f64, q.z as f64);
        let (i0, j0) = ((q.x - 0.5).floor() as usize, (q.y - 0.5).floor() as usize);
        let bias = (w * s.bias_texels) as f64;
        // f32 rounding of the pass's plane: a few units in the last place of its largest term.
        let rounding = 1e-5 * (d.abs() + 2.0 * slope.abs().element_sum() + bias);
        let (mut front, mut close) = (0, false);
        for (x, y) in [(i0, j0), (i0 + 1, j0), (i0, j0 + 1), (i0 + 1, j0 + 1)] {
            let plane = d + slope.x * (x as f64 + 0.5 - qx) + slope.y * (y as f64 + 0.5 - qy);
            let margin = map.depth(x, y) as f64 - (plane - bias);
            front += (margin < 0.0) as u32;
            close |= margin.abs() <= rounding;
        }
        match (close, front) {
            (true, _) => unsure.push(k as u32),
            (false, 0) => edges.push((k, 1.0)),
            (false, 4) => edges.push((k, 0.0)),
            _ => marked.push(k as u32),
        }
    }
    Classified {
        marked,
        unsure,
        edges,
    }
}

/// What [`full_classification`] found: the pixels it marks, those it leaves undecided (ascending), and the
/// edge pixels it decides, each with its visibility (1 lit, 0 shadowed).
struct Classified {
    marked: Vec<u32>,
    unsure: Vec<u32>,
    edges: Vec<(usize, f32)>,
}

impl Classified {
    /// Asserts that `pass` marked the pixels marked here (but the undecided ones) and gave the decided
    /// edge pixels their visibility; returns how many pixels it checked and left out.
    fn check(&self, pass: &HardShadows, what: &str) -> (usize, usize) {
        assert!(
            self.unsure.len() * 100 < self.marked.len(),
            "{what}: {:?} undecided",
            self.unsure
        );
        assert_eq!(decided(pass.marked(), &self.unsure), self.marked, "{what}");
        for &(k, v) in &self.edges {
            assert_eq!(pass.visibility()[k], v, "{what}: edge pixel {k}");
        }
        (self.marked.len() + self.edges.len(), self.unsure.len())
    }
}

/// The marked pixels but those the oracle left `undecided`, in ascending order.
fn decided(marked: &[u32], undecided: &[u32]) -> Vec<u32> {
    let mut v: Vec<u32> = (marked.iter().copied())
        .filter(|k| undecided.binary_search(k).is_err())
        .collect();
    v.sort_unstable();
    v
}

/// A scene built to trip a classification that skips work: over a ground that leaves an empty strip
/// (empty texels), a field of 0.07-wide square towers whose neighbouring heights differ by half, just
/// under, just over and twice the edge threshold (at every offset against the map's texels and rows),
/// and slivers thinner than a texel high above (single-texel spikes, or nothing); receivers at random
/// places on the tower tops, just under them and on the ground, with random normals (some facing away,
/// some pixels empty).
fn adversarial_scene(seed: u64, towards: Vec3) -> (Vec<[Vec3; 3]>, GBuffer) {
    use rand::Rng;
    let mut r = common::rng(seed);
    let quad = |x0: f32, z0: f32, x1: f32, z1: f32, y: f32| {
        let [a, b, c, d] =
            [(x0, z0), (x1, z0), (x1, z1), (x0, z1)].map(|(x, z)| Vec3::new(x, y, z));
        [[a, c, b], [a, d, c]]
    };
    let mut tris: Vec<[Vec3; 3]> = quad(-0.8, -1.0, 1.0, 1.0, 0.0).to_vec();
    // The threshold in world units: 1.5 texels of a 64-texel map over the receivers' ~2-unit span.
    let edge = 1.5 * 2.0 / 62.0;
    let (cell, cells) = (0.07, 24);
    let mut heights = vec![0.0f32; cells * cells];
    for k in 0..cells * cells {
        let step = [0.5, 0.999, 1.001, 2.0][r.random_range(0..4)] * edge;
        let prev = if k % cells == 0 { 0.3 } else { heights[k - 1] };
        heights[k] = (prev + if r.random_bool(0.5) { step } else { -step }).clamp(0.1, 0.9);
    }
    let origin = -0.84;
    for (k, &h) in heights.iter().enumerate() {
        let (x0, z0) = (
            origin + cell * (k % cells) as f32,
            origin + cell * (k / cells) as f32,
        );
        tris.extend(quad(x0, z0, x0 + cell, z0 + cell, h));
    }
    for _ in 0..60 {
        let (x, z) = (r.random_range(-0.9..0.9), r.random_range(-0.9..0.9));
        tris.extend(quad(x, z, x + 0.004, z + 0.2, 1.2));
    }
    let height = |x: f32, z: f32| {
        let (i, j) = (((x - origin) / cell).floor(), ((z - origin) / cell).floor());
        if (0.0..cells as f32).contains(&i) && (0.0..cells as f32).contains(&j) {
            heights[j as usize * cells + i as usize]
        } else {
            0.0
        }
    };
    let n = 64;
    let mut g = GBuffer::new(n, n);
    for k in 0..n * n {
        if r.random_bool(0.05) {
            continue; // no surface
        }
        let (x, z) = (r.random_range(-1.0..1.0), r.random_range(-1.0..1.0));
        let y = match r.random_range(0..3) {
            0 => height(x, z),
            1 => height(x, z) - r.random_range(0.0..2.0 * edge),
            _ => 0.0,
        };
        let normal =
            (towards * r.random_range(-0.3..1.0) + common::rand_dir(&mut r)).normalize_or(towards);
        // A few broken normals: a NaN or an infinite component.
        let normal = match r.random_range(0..100) {
            0 => Vec3::new(f32::NAN, 1.0, 0.0),
            1 => Vec3::new(f32::INFINITY, 1.0, 0.0),
            _ => normal,
        };
        g.set(k, Vec3::new(x, y, z), normal);
    }
    (tris, g)
}

/// The pass marks exactly the pixels the full classification marks — in particular it never skips one the
/// full classification marks — on crowd frames and on adversarial depth maps, on one thread and on all.
#[test]
fn selective_marks_what_the_full_classification_marks() {
    let never = |_: Vec3, _: Vec3| false;
    let (mut checked, mut left_out) = (0, 0);
    // A pass kept from frame to frame samples the receivers' bounds where the last frame's extremes were.
    let mut warm = [HardShadows::new(), HardShadows::new()];
    for (frames, world, g) in crowd_frames() {
        for (parallel, warm) in [false, true].into_iter().zip(&mut warm) {
            let s = ShadowSettings {
                parallel,
                ..settings(ShadowMode::Selective, crowd::sun())
            };
            let mut pass = HardShadows::new();
            crowd::sun_visibility(&world, &g, &s, &mut pass).unwrap();
            let want = full_classification(&pass, &s, &g);
            assert!(!want.marked.is_empty(), "frame {frames} marks pixels");
            let (n, left) = want.check(&pass, &format!("frame {frames}, parallel {parallel}"));
            let vis = crowd::sun_visibility(&world, &g, &s, warm).unwrap();
            assert_eq!(vis, pass.visibility(), "frame {frames}, warm pass");
            assert_eq!(warm.marked(), pass.marked(), "frame {frames}, warm pass");
            (checked, left_out) = (checked + n, left_out + left);
        }
    }
    for seed in 0..6 {
        let towards = [Vec3::Y, Vec3::new(0.6, 1.0, 0.3)][seed as usize % 2];
        let (tris, g) = adversarial_scene(seed, towards.normalize());
        for parallel in [false, true] {
            let s = ShadowSettings {
                map_resolution: 64,
                parallel,
                ..settings(ShadowMode::Selective, towards)
            };
            let mut pass = HardShadows::new();
            pass.run(&s, &tris, &g, never).unwrap();
            let want = full_classification(&pass, &s, &g);
            assert!(want.marked.len() > 200, "seed {seed}: {:?}", want.marked);
            let (n, left) = want.check(&pass, &format!("seed {seed}, parallel {parallel}"));
            (checked, left_out) = (checked + n, left_out + left);
        }
    }
    println!("{checked} marked and decided edge pixels agree, {left_out} undecided by the oracle");
}

/// The map is fitted to every receiver facing the light, whatever rows the pass samples first: with two
/// lone receivers far beyond the others in rows between the sampled ones (one of them extreme along any
/// axis across the light), every receiver lies inside the map's one-texel margin and the extremes on it
/// (the exact fit); the pass says it fitted the map twice, a second pass over the same image finds the
/// extremes from the first's and fits once, with the same map and image, for hard and soft shadows.
#[test]
fn the_map_covers_every_receiver_whatever_rows_are_sampled() {
    let (tris, bvh, mut g) = square_over_ground();
    let occluded = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    let w = g.width;
    g.set(5 * w + 40, Vec3::new(-8.0, 0.0, -8.0), Vec3::Y);
    g.set(7 * w + 60, Vec3::new(8.0, 0.0, -8.0), Vec3::Y);
    for light_angle in [0.0, 0.02] {
        let s = ShadowSettings {
            map_resolution: 64,
            light_angle,
            ..settings(ShadowMode::Selective, Vec3::new(0.3, 1.0, 0.2))
        };
        let mut pass = HardShadows::new();
        let first = pass.run(&s, &tris, &g, occluded).unwrap().to_vec();
        assert!(pass.stats().refitted, "the sample skips the lone receivers");
        let map = pass.shadow_map();
        let res = map.resolution() as f32;
        let q: Vec<Vec3> = g.positions.iter().map(|&p| map.project(p)).collect();
        let (lo, hi) = q.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &q| {
            (lo.min(q), hi.max(q))
        });
        // The lowest receiver `m` texels in on both axes: the one-texel margin, plus for soft shadows the
        // penumbra's reach; the highest as far in on the map's longer axis, no further out on the other.
        let (eps, m) = (1e-3, lo.x.min(lo.y));
        assert!(
            (lo.x - m).abs() < eps && (lo.y - m).abs() < eps,
            "lowest {lo}"
        );
        assert!(
            m >= 1.0 - eps && (light_angle > 0.0 || m < 1.0 + eps),
            "lowest {lo}"
        );
        assert!(
            hi.x <= res - m + eps && hi.y <= res - m + eps,
            "highest {hi}"
        );
        assert!((hi.x.max(hi.y) - (res - m)).abs() < eps, "highest {hi}");
        let depths: Vec<f32> = (0..64 * 64).map(|k| map.depth(k % 64, k / 64)).collect();
        let again = pass.run(&s, &tris, &g, occluded).unwrap().to_vec();
        assert!(
            !pass.stats().refitted,
            "the last pass's extremes are sampled"
        );
        let map = pass.shadow_map();
        assert!((0..64 * 64).all(|k| map.depth(k % 64, k / 64).to_bits() == depths[k].to_bits()));
        assert_eq!(again, first, "light angle {light_angle}");
    }
}

/// Every pixel of the fully ray-traced image that faces the sun is lit exactly when the brute-force oracle
/// finds no triangle on its shadow ray (exact arithmetic over every triangle of the scene).
#[test]
fn ray_traced_equals_brute_force_occlusion() {
    let world = crowd_world(40);
    let (w, h) = (128, 72);
    let (_, g) = crowd::primary_hits(&world, w, h, &crowd::Camera::default());
    let (vis, _) = crowd_shadows(&world, &g, ShadowMode::RayTraced, 0.0);
    let mut tris = Vec::new();
    world
        .resource::<TraceWorld>()
        .world_triangles(&Default::default(), &mut tris);
    let s = settings(ShadowMode::RayTraced, crowd::sun());
    let sun = crowd::sun();
    let (mut checked, mut blocked) = (0, 0);
    for (i, (&p, &n)) in g.positions.iter().zip(&g.normals).enumerate() {
        if n == Vec3::ZERO {
            assert_eq!(vis[i], 1.0, "no surface: nothing to shadow");
        } else if n.dot(sun) <= 0.0 {
            assert_eq!(vis[i], 0.0, "facing away from the sun");
        } else {
            let from = p + n * s.normal_offset;
            let ray = Ray::segment(from, from + sun * s.ray_length);
            RayOracle::new(&ray, tris.iter().copied())
                .check_any(vis[i] == 0.0, &format!("pixel {i}"));
            checked += 1;
            blocked += (vis[i] == 0.0) as usize;
        }
    }
    assert!(
        checked > 2000 && blocked >= 10,
        "{checked} checked, {blocked} in shadow"
    );
}

/// Soft shadows of a disc light straight above the square (angular radius 0.1 rad, 16 samples): every
/// pixel's visibility is the fraction of its sample directions whose ray misses the square, found
/// analytically (where the ray crosses the square's plane); pixels with a crossing within 1e-4 of the
/// square's outline are skipped (the triangle test's rounding may go either way there). The
/// ray-traced and the selective pass must both match exactly, and the selective one traces only part.
/// Besides the whole ground, a strip of receivers just outside the square's shadow, in its penumbra: the
/// square's edge lies off the receivers' footprint, so the map must reach past them to see it.
#[test]
fn square_casts_its_analytic_soft_shadow() {
    let (tris, bvh, ground) = square_over_ground();
    let mut strip = GBuffer::new(20, 20);
    for k in 0..400 {
        let (i, j) = ((k % 20) as f32, (k / 20) as f32);
        let p = Vec3::new(0.5125 + 0.0125 * i, 0.0, -0.1 + 0.01 * j);
        strip.set(k, p, Vec3::Y);
    }
    let occluded = |from: Vec3, to: Vec3| bvh.any_hit(&Ray::segment(from, to));
    let (angle, samples) = (0.1, 16);
    let disc = LightDisc::new(Vec3::Y, angle, samples);
    let mut pass = HardShadows::new();
    let (mut penumbra, mut checked) = (0, 0);
    for (g, mode) in [
        (&ground, ShadowMode::RayTraced),
        (&ground, ShadowMode::Selective),
        (&strip, ShadowMode::Selective),
    ] {
        let s = ShadowSettings {
            light_angle: angle,
            samples,
            map_resolution: 64,
            ..settings(mode, Vec3::Y)
        };
        let vis = pass.run(&s, &tris, g, occluded).unwrap().to_vec();
        // The same rays as packets through the tree's packet traversal: the same image.
        let packets = Packets(|segments: &[(Vec3, Vec3)], out: &mut [bool]| {
            let rays: Vec<Ray> = segments.iter().map(|&(a, b)| Ray::segment(a, b)).collect();
            bvh.any_hits_packet(&rays, out, &mut TraversalStats::default());
        });
        assert_eq!(
            pass.run(&s, &tris, g, packets).unwrap(),
            &vis[..],
            "{mode:?}"
        );
        'pixel: for (i, &p) in g.positions.iter().enumerate() {
            let from = p + Vec3::Y * s.normal_offset;
            let mut reach = 0;
            for k in 0..samples {
                let d = disc.direction(i as u32, k);
                let q = from + d * ((1.0 - from.y) / d.y);
                let (x, z, eps) = (q.x.abs(), q.z.abs(), 1e-4);
                let on_square = x <= 0.5 && z <= 0.5;
                let near = |a: f32, b: f32| (a - 0.5).abs() < eps && b < 0.5 + eps;
                if near(x, z) || near(z, x) {
                    continue 'pixel;
                }
                reach += !on_square as u32;
            }
            let want = reach as f32 / samples as f32;
            assert_eq!(vis[i], want, "{mode:?} at {p}");
            checked += 1;
            penumbra += (want > 0.0 && want < 1.0) as usize;
        }
        let stats = pass.stats();
        if g.width == ground.width && mode == ShadowMode::Selective {
            assert!(stats.rays < g.width * g.height / 4, "{stats:?}");
        }
    }
    assert!(
        penumbra > 300 && checked > 2 * 9000,
        "{penumbra} in penumbra, {checked} checked"
    );
}

/// On fixed crowd frames, soft shadows of a disc sun (0.05 rad, 16 samples): the selective image differs
/// from sampling every pixel with the same pattern in at most 0.1% of the pixels; the marked fraction is
/// reported.
#[test]
fn soft_selective_matches_ray_traced_on_crowd_frames() {
    for (frames, world, g) in crowd_frames() {
        let (w, h) = (g.width, g.height);
        let image = |mode| crowd_shadows(&world, &g, mode, 0.05);
        let (traced, _) = image(ShadowMode::RayTraced);
        let (selective, stats) = image(ShadowMode::Selective);
        let differ = selective
            .iter()
            .zip(&traced)
            .filter(|(a, b)| a != b)
            .count();
        let penumbra = traced.iter().filter(|v| **v > 0.0 && **v < 1.0).count();
        println!(
            "frame {frames}: {:.2}% of pixels marked, {penumbra} in penumbra, selective differs in \
             {differ} of {}",
            100.0 * stats.ray_fraction(),
            w * h
        );
        assert!(
            differ * 1000 <= w * h,
            "frame {frames}: soft selective differs from ray traced in {differ} pixels"
        );
        assert!(penumbra >= 50, "the frame has penumbrae to get right");
        assert!(stats.ray_fraction() < 0.25, "{stats:?}");
    }
}

#[test]
fn bad_input_is_an_error() {
    let g = GBuffer::new(4, 4);
    let never = |_: Vec3, _: Vec3| false;
    let mut pass = HardShadows::new();
    for s in [
        settings(ShadowMode::Selective, Vec3::ZERO),
        settings(ShadowMode::Selective, Vec3::NAN),
        ShadowSettings {
            map_resolution: 2,
            ..Default::default()
        },
        ShadowSettings {
            bias_texels: -1.0,
            ..Default::default()
        },
        ShadowSettings {
            light_angle: 0.6,
            ..Default::default()
        },
        ShadowSettings {
            samples: 0,
            ..Default::default()
        },
    ] {
        assert!(matches!(
            pass.run(&s, &[], &g, never),
            Err(Error::InvalidShadowInput(_))
        ));
    }
    let mut short = GBuffer::new(4, 4);
    short.normals.pop();
    assert!(matches!(
        pass.run(&ShadowSettings::default(), &[], &short, never),
        Err(Error::InvalidShadowInput(_))
    ));
    assert_eq!(
        pass.run(&ShadowSettings::default(), &[], &g, never)
            .unwrap(),
        &[1.0; 16]
    );
}

/// Sets `kinetrace::dispatch::baseline_only_for_tests` for as long as it lives.
struct BaselineOnly;

impl BaselineOnly {
    fn new() -> Self {
        kinetrace::dispatch::baseline_only_for_tests(true);
        Self
    }
}

impl Drop for BaselineOnly {
    fn drop(&mut self) {
        kinetrace::dispatch::baseline_only_for_tests(false);
    }
}

/// What a pass left, bit for bit: every depth of its map, its marked pixels in order, every visibility.
type Outcome = (Vec<u32>, Vec<u32>, Vec<u32>);

/// `run` on a cold pass with the loops' baseline build, then on another with their AVX2-generation build:
/// what each left.
fn in_both_builds(run: impl Fn(&mut HardShadows)) -> [Outcome; 2] {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let outcome = |pass: &HardShadows| {
        let map = pass.shadow_map();
        let res = map.resolution();
        let depths = (0..res * res)
            .map(|k| map.depth(k % res, k / res))
            .collect::<Vec<_>>();
        (
            bits(&depths),
            pass.marked().to_vec(),
            bits(pass.visibility()),
        )
    };
    let (mut base, mut wide) = (HardShadows::new(), HardShadows::new());
    {
        let _only = BaselineOnly::new();
        run(&mut base);
    }
    run(&mut wide);
    [outcome(&base), outcome(&wide)]
}

/// The pass's loops built for the target's baseline and for the AVX2 generation (`kinetrace::dispatch`,
/// which runs the second where the CPU has it) give the same pass bit for bit: the map's every depth, the
/// marked pixels in their order and every visibility, in every mode, hard and soft, on one thread and on
/// all, on a crowd frame and on adversarial scenes (every path of the classification). Both passes start
/// cold, so each fits its map from the same sampled rows.
#[test]
fn baseline_and_wide_builds_give_the_same_pass() {
    if !kinetrace::dispatch::wide_available() {
        eprintln!("SKIPPED: this CPU lacks the AVX2 generation; only the baseline build runs here");
        return;
    }
    let never = |_: Vec3, _: Vec3| false;
    let world = crowd_world(60);
    // A width of 317 ends every row with a run of five pixels (of eight lanes) or one (of four).
    let crowd_gs = [(320, 180), (317, 181)]
        .map(|(w, h)| crowd::primary_hits(&world, w, h, &crowd::Camera::default()).1);
    let mut compared = 0;
    for mode in [
        ShadowMode::ShadowMap,
        ShadowMode::Selective,
        ShadowMode::RayTraced,
    ] {
        for (light_angle, parallel) in [(0.0, false), (0.0, true), (0.02, false), (0.02, true)] {
            let s = ShadowSettings {
                light_angle,
                parallel,
                ..settings(mode, crowd::sun())
            };
            for crowd_g in &crowd_gs {
                let [base, wide] = in_both_builds(|pass| {
                    crowd::sun_visibility(&world, crowd_g, &s, pass).unwrap();
                });
                let width = crowd_g.width;
                assert_eq!(
                    wide, base,
                    "crowd {width} wide, {mode:?}, {light_angle} rad, {parallel}"
                );
                compared += 1;
            }
            for seed in 0..3 {
                let towards = [Vec3::Y, Vec3::new(0.6, 1.0, 0.3)][seed as usize % 2].normalize();
                let (tris, g) = adversarial_scene(seed, towards);
                let s = ShadowSettings {
                    map_resolution: 64,
                    towards_light: towards,
                    ..s
                };
                let [base, wide] = in_both_builds(|pass| {
                    pass.run(&s, &tris, &g, never).unwrap();
                });
                assert_eq!(wide, base, "seed {seed}, {mode:?}, {light_angle} rad");
                compared += 1;
            }
        }
    }
    println!("{compared} passes the same in both builds");
}
