//! The GPU sorted order of secondary rays against the CPU sort and the standard library's stable sort, on
//! lavapipe in CI (`KINETRACE_REQUIRE_GPU=1` makes a missing adapter a failure; without it these tests skip
//! and say so).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::Ray;
use kinetrace::raysort::{KeyLayout, RayKind, SecondaryRay, SortedRays, sort_rays, sort_rays_gpu};
use rand::Rng;
use std::io::Write;

/// Shadow rays from six lights toward random surface points and reflection rays from random points, every
/// `invalid_every`-th ray made invalid in one of four ways (NaN origin, zero, infinite direction, NaN range).
fn batch(n: usize, seed: u64, invalid_every: usize) -> Vec<SecondaryRay> {
    let mut r = rng(seed);
    let lights: Vec<Vec3> = (0..6).map(|_| rand_vec(&mut r, -5.0, 5.0)).collect();
    (0..n)
        .map(|i| {
            let p = rand_vec(&mut r, -1.0, 1.0);
            let (ray, kind) = if r.random_bool(0.5) {
                let l = r.random_range(0..lights.len());
                let light = lights[l];
                let ray = Ray::with_range(light, p - light, 0.0, 0.999);
                (ray, RayKind::Shadow { light: l as u32 })
            } else {
                (Ray::new(p, rand_dir(&mut r)), RayKind::Reflection)
            };
            let ray = if invalid_every > 0 && i % invalid_every == invalid_every - 1 {
                match (i / invalid_every) % 4 {
                    0 => Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
                    1 => Ray::new(p, Vec3::ZERO),
                    2 => Ray::new(p, Vec3::new(f32::INFINITY, 1.0, 0.0)),
                    _ => Ray::with_range(p, Vec3::Y, 0.0, f32::NAN),
                }
            } else {
                ray
            };
            SecondaryRay {
                ray,
                kind,
                tag: 1000 + i as u32,
            }
        })
        .collect()
}

/// Oracle independent of both sorts: the standard library's stable sort of the request indices by
/// (invalid, key), keys given per request index (invalid rays' keys unused).
fn stable_order(rays: &[SecondaryRay], key: impl Fn(usize) -> u32) -> Vec<u32> {
    let mut order: Vec<u32> = (0..rays.len() as u32).collect();
    order.sort_by_key(|&i| {
        let i = i as usize;
        if rays[i].ray.is_valid() {
            (0, key(i))
        } else {
            (1, 0)
        }
    });
    order
}

/// The GPU's key per request index (None for the invalid rays, which carry none).
fn keys_by_request(rays: &[SecondaryRay], s: &SortedRays) -> Vec<Option<u32>> {
    let mut k = vec![None; rays.len()];
    for (&i, &key) in s.order.iter().zip(&s.keys) {
        k[i as usize] = Some(key);
    }
    k
}

#[test]
fn gpu_order_is_the_stable_order_of_its_keys() {
    let Some(g) = gpu_or_skip() else { return };
    let layout = KeyLayout::default();
    for n in [0, 1, 2, 3, 255, 257, 1025, 20_000] {
        let rays = batch(n, n as u64 + 7, 37);
        let got = sort_rays_gpu(&g, &rays, &layout).unwrap();
        assert_eq!(got.order.len(), n, "n = {n}");
        let valid = rays.iter().filter(|r| r.ray.is_valid()).count();
        assert_eq!(got.valid(), valid, "valid count, n = {n}");
        let keys = keys_by_request(&rays, &got);
        // Every valid ray got a key: the order is a permutation with the valid rays first.
        for (i, r) in rays.iter().enumerate() {
            assert_eq!(keys[i].is_some(), r.ray.is_valid(), "ray {i}, n = {n}");
        }
        let expect = stable_order(&rays, |i| keys[i].unwrap());
        assert_eq!(got.order, expect, "order, n = {n}");
        // Tags travel with the request index.
        for &i in &got.order {
            assert_eq!(rays[i as usize].tag, 1000 + i);
        }
    }
}

/// (θ step, φ step) and the rest of a key (light or origin cell) under the default layout.
fn fields(key: u32, kind: RayKind) -> (i64, i64, u32) {
    let bits = match kind {
        RayKind::Shadow { .. } => 14,
        RayKind::Reflection => 10,
    };
    let (mut theta, mut phi) = (0i64, 0i64);
    for b in 0..bits {
        phi |= (((key >> (2 * b)) & 1) as i64) << b;
        theta |= (((key >> (2 * b + 1)) & 1) as i64) << b;
    }
    (theta, phi, key >> (2 * bits))
}

/// The GPU key's steps come from WGSL division and square root, not correctly rounded ones, so a ray
/// whose direction lies within rounding of a step boundary may quantise to the neighbouring step on the
/// GPU. Everything else
/// must agree: the same valid rays, the same light or origin cell, angles at most one step apart; and
/// where every key agrees the order is the CPU sort's exactly.
#[test]
fn gpu_keys_match_cpu_keys_up_to_one_angle_step() {
    let Some(g) = gpu_or_skip() else { return };
    let layout = KeyLayout::default();
    for n in [0, 1, 2, 1025, 20_000] {
        let rays = batch(n, n as u64 + 11, 29);
        let got = sort_rays_gpu(&g, &rays, &layout).unwrap();
        let cpu = sort_rays(&rays, &layout, false).unwrap();
        let gk = keys_by_request(&rays, &got);
        let ck = keys_by_request(&rays, &cpu);
        let mut differ = 0;
        for (i, (a, b)) in gk.iter().zip(&ck).enumerate() {
            assert_eq!(a.is_some(), b.is_some(), "validity of ray {i}, n = {n}");
            let (Some(a), Some(b)) = (a, b) else { continue };
            if a != b {
                differ += 1;
                let (ta, pa, ra) = fields(*a, rays[i].kind);
                let (tb, pb, rb) = fields(*b, rays[i].kind);
                assert_eq!(ra, rb, "light/origin field of ray {i}, n = {n}");
                assert!(
                    (ta - tb).abs() <= 1 && (pa - pb).abs() <= 1,
                    "ray {i}: {a:#x} vs {b:#x}"
                );
            }
        }
        let _ = writeln!(std::io::stderr(), "n = {n}: {differ} keys one step apart");
        if differ == 0 {
            assert_eq!(got, cpu, "n = {n}");
        }
    }
}

/// Directions at the centre of a 14-bit polar and azimuth step (half a step from any boundary: far beyond
/// rounding) and origins on the corners of their bounds: keys, order and chunks equal the CPU sort's exactly.
#[test]
fn gpu_sort_equals_cpu_sort_on_exact_keys() {
    let Some(g) = gpu_or_skip() else { return };
    let mut r = rng(5);
    let centre = |m: u32| (m as f32 + 0.5) / 16384.0;
    let dirs: Vec<Vec3> = (0..40)
        .map(|_| {
            // cos θ in equal steps from +z; the diamond angle (four units a turn, from -x) back to (x, y)
            // with |x| + |y| = 1, then scaled to sin θ.
            let cos = 1.0 - 2.0 * centre(r.random_range(0..16384));
            let diamond = 4.0 * centre(r.random_range(0..16384));
            let (x, y) = if diamond <= 2.0 {
                let x = diamond - 1.0;
                (x, x.abs() - 1.0)
            } else {
                let x = 3.0 - diamond;
                (x, 1.0 - x.abs())
            };
            let k = (1.0 - cos * cos).max(0.0).sqrt() / (x * x + y * y).sqrt();
            Vec3::new(x * k, y * k, cos)
        })
        .collect();
    let corners = [Vec3::ZERO, Vec3::ONE, Vec3::new(1.0, 0.0, 1.0)];
    let rays: Vec<SecondaryRay> = (0..5000u32)
        .map(|i| {
            let d = dirs[r.random_range(0..dirs.len())];
            let o = corners[r.random_range(0..3)];
            let kind = if r.random_bool(0.5) {
                RayKind::Shadow {
                    light: r.random_range(0..20),
                }
            } else {
                RayKind::Reflection
            };
            let ray = if i % 97 == 0 {
                Ray::new(o, Vec3::ZERO)
            } else {
                Ray::new(o, d)
            };
            SecondaryRay { ray, kind, tag: i }
        })
        .collect();
    let layout = KeyLayout::default();
    let got = sort_rays_gpu(&g, &rays, &layout).unwrap();
    let cpu = sort_rays(&rays, &layout, false).unwrap();
    assert_eq!(got, cpu);
}

#[test]
fn equal_keys_keep_request_order() {
    let Some(g) = gpu_or_skip() else { return };
    let r = SecondaryRay {
        ray: Ray::new(Vec3::ONE, Vec3::new(0.3, -0.2, 0.9)),
        kind: RayKind::Shadow { light: 2 },
        tag: 0,
    };
    let rays = vec![r; 3000];
    let got = sort_rays_gpu(&g, &rays, &KeyLayout::default()).unwrap();
    assert_eq!(got.order, (0..3000).collect::<Vec<u32>>());
    assert_eq!(got.chunks, 1);
    let invalid = vec![
        SecondaryRay {
            ray: Ray::new(Vec3::NAN, Vec3::X),
            ..r
        };
        5
    ];
    let got = sort_rays_gpu(&g, &invalid, &KeyLayout::default()).unwrap();
    assert_eq!(got.order, (0..5).collect::<Vec<u32>>());
    assert_eq!(got.valid(), 0);
}

#[test]
fn layouts_over_32_bits_are_errors() {
    let Some(g) = gpu_or_skip() else { return };
    let layout = KeyLayout {
        light_bits: 5,
        ..Default::default()
    };
    let rays = batch(4, 1, 0);
    assert!(matches!(
        sort_rays_gpu(&g, &rays, &layout),
        Err(kinetrace::Error::InvalidOption(_))
    ));
}

/// A sphere of radius 1 and a folded sheet through it: one mesh, closed and open parts.
fn crsh_scene() -> kinetrace::raysort::RayScene {
    use kinetrace::scenes::{folded_sheet, icosphere};
    let (a, b) = (icosphere(3), folded_sheet(10, 0.4));
    let mut pos = a.positions().to_vec();
    pos.extend(b.positions().iter().map(|p| *p * 1.5));
    let base = a.positions().len() as u32;
    let mut idx = a.indices().to_vec();
    idx.extend(b.indices().iter().map(|&i| i + base));
    let mesh = kinetrace::Mesh::new(pos, idx).unwrap();
    kinetrace::raysort::RayScene::build(&mesh, &kinetrace::bvh::BuildOptions::default()).unwrap()
}

#[test]
fn gpu_crsh_answers_equal_cpu_crsh() {
    use kinetrace::raysort::{Answer, Strategy, trace_crsh_gpu};
    let Some(g) = gpu_or_skip() else { return };
    let scene = crsh_scene();
    let layout = KeyLayout::default();
    for (n, branching, depth) in [
        (3000, 8, 2),
        (3000, 16, 3),
        (1000, 3, 1),
        (5, 8, 4),
        (0, 8, 2),
    ] {
        let mut rays = batch(n, n as u64 + branching as u64, 41);
        // Every seventh ray reaches behind its origin, outside the cones: the BVH answers it on both.
        for r in rays.iter_mut().step_by(7) {
            r.ray = kinetrace::Ray::with_range(r.ray.origin, r.ray.dir(), -2.0, r.ray.tmax);
        }
        let crsh = Strategy::Crsh { branching, depth };
        let cpu = scene.trace(&rays, crsh, &layout, true).unwrap().answers;
        let gpu = trace_crsh_gpu(&g, &scene, &rays, &layout, branching, depth).unwrap();
        assert_eq!(gpu.len(), n);
        let (mut hits, mut occluded) = (0, 0);
        for (i, (c, d)) in cpu.iter().zip(&gpu).enumerate() {
            let what = format!("s{branching} D{depth} ray {i}: cpu {c:?} gpu {d:?}");
            match (c, d) {
                (Answer::Hit(c), Answer::Hit(d)) => {
                    assert_eq!((c.primitive, c.normal), (d.primitive, d.normal), "{what}");
                    assert_eq!([c.t, c.u, c.v], [d.t, d.u, d.v], "{what}");
                    hits += 1;
                }
                _ => assert_eq!(c, d, "{what}"),
            }
            occluded += (*c == Answer::Occluded) as usize;
        }
        if n >= 1000 {
            assert!(
                hits > n / 10 && occluded > n / 10,
                "{hits} hits, {occluded} occluded"
            );
        }
    }
}

#[test]
fn gpu_crsh_rejects_wide_nodes() {
    let Some(g) = gpu_or_skip() else { return };
    let rays = batch(100, 3, 0);
    let got =
        kinetrace::raysort::trace_crsh_gpu(&g, &crsh_scene(), &rays, &KeyLayout::default(), 65, 1);
    assert!(matches!(got, Err(kinetrace::Error::InvalidOption(_))));
}
