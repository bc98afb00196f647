//! Ray keys, sorting and the ray-space hierarchies (seed 002) against brute force: every strategy's answer
//! to shadow and reflection rays from the crowd, the cloth and a closed room is one the independent oracle
//! allows; the sort is a stable permutation; every ray lies inside its hierarchy nodes.

mod common;
#[path = "../examples/report/scenes.rs"]
#[allow(dead_code)]
mod scenes;

use common::*;
use glam::{DVec3, Vec3};
use kinetrace::bvh::{BuildOptions, Builder};
use kinetrace::raysort::{
    Answer, KeyLayout, RayHierarchy, RayKind, RayScene, SecondaryRay, SortScratch, SortedRays,
    Strategy, sort_rays,
};
use kinetrace::scenes::{folded_sheet, icosphere};
use kinetrace::{Aabb, Error, Mesh, Ray};
use std::path::Path;

/// Every strategy, hierarchies at the seed's shapes and one odd shape.
fn strategies() -> Vec<Strategy> {
    let mut v = vec![Strategy::Bvh, Strategy::SortedBvh];
    for size in [1, 3, 16, 64, 100] {
        v.push(Strategy::SortedPackets { size });
    }
    // Runs cut at every key, at blocks of the default layout's directions, and never (drop_bits clamped).
    for (size, drop_bits) in [(64, 0), (64, 10), (3, 10), (100, 40)] {
        v.push(Strategy::SortedRuns { size, drop_bits });
    }
    for (branching, depth) in [(8, 2), (8, 3), (8, 4), (16, 2), (16, 3), (16, 4), (3, 1)] {
        v.push(Strategy::Crsh { branching, depth });
        v.push(Strategy::Rah { branching, depth });
    }
    v
}

fn concat(meshes: &[Mesh]) -> Mesh {
    let (mut pos, mut idx) = (Vec::new(), Vec::new());
    for m in meshes {
        let base = pos.len() as u32;
        pos.extend_from_slice(m.positions());
        idx.extend(m.indices().iter().map(|&i| i + base));
    }
    Mesh::new(pos, idx).unwrap()
}

/// A closed box room (each wall 4 × 4 quads) around the origin with an icosphere of radius 0.5 inside it.
fn room() -> Mesh {
    let mut pos = Vec::new();
    let mut idx = Vec::new();
    let n = 4u32;
    for axis in 0..3 {
        for side in [-2.0f32, 2.0] {
            let base = pos.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    let (u, v) = (
                        i as f32 / n as f32 * 4.0 - 2.0,
                        j as f32 / n as f32 * 4.0 - 2.0,
                    );
                    let mut p = Vec3::ZERO;
                    p[axis] = side;
                    p[(axis + 1) % 3] = u;
                    p[(axis + 2) % 3] = v;
                    pos.push(p);
                }
            }
            for j in 0..n {
                for i in 0..n {
                    let a = base + j * (n + 1) + i;
                    idx.extend([a, a + 1, a + n + 2, a, a + n + 2, a + n + 1]);
                }
            }
        }
    }
    let walls = Mesh::new(pos, idx).unwrap();
    let ball = map_mesh(&icosphere(2), |p| p * 0.5 + Vec3::new(0.3, -0.2, 0.1));
    concat(&[walls, ball])
}

/// Primary rays from `eye` over the mesh's box (some axis-aligned), their hits, and from those: one shadow
/// ray per hit from each light toward the point (ending exactly on the surface, and short of it), one
/// reflection ray per hit starting on the surface, axis-aligned reflection rays, and invalid rays.
fn secondary(m: &Mesh, eye: Vec3, lights: &[Vec3], side: usize) -> Vec<SecondaryRay> {
    let bvh = kinetrace::MeshBvh::build(m, &BuildOptions::new(Builder::SAH)).unwrap();
    let b = m
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t));
    let mut out = Vec::new();
    let mut tag = 0u32;
    let mut push = |out: &mut Vec<SecondaryRay>, ray: Ray, kind: RayKind| {
        tag = tag.wrapping_mul(2654435761).wrapping_add(17);
        out.push(SecondaryRay { ray, kind, tag });
    };
    for y in 0..side {
        for x in 0..side {
            let target = b.min
                + b.extent()
                    * Vec3::new(
                        (x as f32 + 0.5) / side as f32,
                        (y as f32 + 0.5) / side as f32,
                        0.5,
                    );
            let primary = Ray::new(eye, target - eye);
            let Some(h) = bvh.closest_hit(&primary) else {
                continue;
            };
            let p = primary.at(h.t);
            for (l, &light) in lights.iter().enumerate() {
                let kind = RayKind::Shadow { light: l as u32 };
                let tmax = if (x + y) % 2 == 0 { 1.0 } else { 1.0 - 1e-3 };
                push(&mut out, Ray::with_range(light, p - light, 0.0, tmax), kind);
            }
            let d = primary.dir();
            let r = d - 2.0 * d.dot(h.normal) * h.normal;
            push(&mut out, Ray::new(p, r), RayKind::Reflection);
        }
    }
    let c = b.center();
    for d in [
        Vec3::X,
        -Vec3::Y,
        Vec3::Z,
        Vec3::new(1.0, 0.0, -1.0),
        Vec3::new(0.0, -0.0, 2.0),
    ] {
        push(&mut out, Ray::new(c, d), RayKind::Reflection);
        push(
            &mut out,
            Ray::new(b.min + Vec3::splat(1e-3), d),
            RayKind::Reflection,
        );
        let to = c + d;
        push(
            &mut out,
            Ray::segment(lights[0], to),
            RayKind::Shadow { light: 0 },
        );
    }
    push(&mut out, Ray::new(c, Vec3::ZERO), RayKind::Reflection);
    push(
        &mut out,
        Ray::new(Vec3::NAN, Vec3::X),
        RayKind::Shadow { light: 1 },
    );
    out
}

/// Every strategy's answers against the oracle; returns (shadow rays occluded, reflection rays hit).
fn check(m: &Mesh, rays: &[SecondaryRay], what: &str) -> (usize, usize) {
    let scene = RayScene::build(m, &BuildOptions::new(Builder::LBVH)).unwrap();
    let layout = KeyLayout::default();
    let traced: Vec<_> = strategies()
        .into_iter()
        .map(|s| (s, scene.trace(rays, s, &layout, true).unwrap()))
        .collect();
    let (mut occluded, mut hit) = (0, 0);
    for (i, r) in rays.iter().enumerate() {
        let oracle = RayOracle::of_mesh(m, &r.ray);
        match r.kind {
            RayKind::Shadow { .. } => occluded += oracle.any() as usize,
            RayKind::Reflection => hit += oracle.closest().is_some() as usize,
        }
        for (s, t) in &traced {
            let what = format!("{what} {s:?} ray {i}");
            match (r.kind, t.answers[i]) {
                (RayKind::Shadow { .. }, Answer::Occluded) => oracle.check_any(true, &what),
                (RayKind::Shadow { .. }, Answer::Miss) => oracle.check_any(false, &what),
                (RayKind::Reflection, Answer::Hit(h)) => {
                    oracle.check_closest(Some((h.primitive, h.t)), &what)
                }
                (RayKind::Reflection, Answer::Miss) => oracle.check_closest(None, &what),
                (kind, a) => panic!("{what}: {a:?} answers a {kind:?} ray"),
            }
        }
    }
    (occluded, hit)
}

fn crowd() -> Mesh {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets");
    let (all, _) = scenes::Scene::all(2000, &assets);
    let s = all.iter().find(|s| s.name == "crowd").unwrap();
    let mut pos = Vec::new();
    s.positions(30, &mut pos);
    s.mesh(&pos)
}

#[test]
fn crowd_rays_equal_brute_force() {
    let m = crowd();
    let b = m
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, t| a.union(t));
    let lights = [
        b.center() + Vec3::new(1.0, 6.0, 2.0),
        b.max + Vec3::new(2.0, 1.0, 0.0),
    ];
    let rays = secondary(&m, b.center() + Vec3::new(0.5, 2.0, 8.0), &lights, 24);
    let (occluded, hit) = check(&m, &rays, "crowd");
    assert!(occluded > 10 && hit > 10, "{occluded} occluded, {hit} hit");
}

#[test]
fn cloth_rays_equal_brute_force() {
    let m = folded_sheet(12, 0.7);
    let lights = [Vec3::new(0.5, 0.5, 2.0), Vec3::new(-1.0, 0.3, 0.2)];
    let rays = secondary(&m, Vec3::new(0.4, -1.5, 1.5), &lights, 24);
    let (occluded, hit) = check(&m, &rays, "cloth");
    assert!(occluded > 10 && hit > 10, "{occluded} occluded, {hit} hit");
}

/// A closed room: reflection rays from inside always hit; a light inside the ball is occluded from every
/// wall point, a light in the room from the points the ball hides.
#[test]
fn closed_room_rays_equal_brute_force() {
    let m = room();
    let inside_ball = Vec3::new(0.3, -0.2, 0.1);
    let lights = [Vec3::new(-1.0, 1.5, 1.0), inside_ball];
    let rays = secondary(&m, Vec3::new(1.5, 1.2, 1.7), &lights, 24);
    let (occluded, hit) = check(&m, &rays, "room");
    let shadow_from_ball = rays
        .iter()
        .filter(|r| r.kind == RayKind::Shadow { light: 1 } && r.ray.is_valid())
        .count();
    assert!(
        occluded >= shadow_from_ball && hit > 100,
        "{occluded} occluded, {hit} hit"
    );
}

fn scatter(n: usize) -> Vec<SecondaryRay> {
    let mut r = rng(5);
    (0..n)
        .map(|i| {
            // Runs of a few equal rays, so that chunks hold more than one ray.
            let kind = if (i / 9) % 3 == 0 {
                RayKind::Reflection
            } else {
                RayKind::Shadow {
                    light: (i / 9 % 5) as u32,
                }
            };
            // Few distinct directions and origins, so that many keys repeat.
            let d = [
                Vec3::X,
                -Vec3::Z,
                Vec3::new(1.0, 1.0, 0.0),
                rand_dir(&mut r),
            ][i / 7 % 4];
            let o = [Vec3::ZERO, Vec3::ONE, rand_vec(&mut r, -1.0, 1.0)][i / 5 % 3];
            let ray = if i % 97 == 5 {
                Ray::new(o, Vec3::ZERO)
            } else {
                Ray::new(o, d)
            };
            SecondaryRay {
                ray,
                kind,
                tag: i as u32 ^ 0xabcd,
            }
        })
        .collect()
}

/// The order is a permutation; valid rays come first, sorted by key with ties in request order (std's
/// stable sort as the oracle); trimmed rays follow in request order; tags travel with their rays.
#[test]
fn sort_is_a_stable_permutation() {
    let rays = scatter(5000);
    for layout in [
        KeyLayout::default(),
        KeyLayout {
            light_bits: 2,
            shadow_direction_bits: 3,
            origin_bits: 1,
            reflection_direction_bits: 2,
        },
    ] {
        let sorted = sort_rays(&rays, &layout, true).unwrap();
        let mut seen = vec![false; rays.len()];
        for &i in &sorted.order {
            assert!(!std::mem::replace(&mut seen[i as usize], true), "{i} twice");
        }
        assert!(seen.iter().all(|&s| s));
        let origins = rays
            .iter()
            .filter(|r| r.ray.is_valid())
            .fold(Aabb::EMPTY, |mut b, r| {
                b.grow(r.ray.origin);
                b
            });
        let mut expect: Vec<(u32, u32)> = (0..rays.len() as u32)
            .filter(|&i| rays[i as usize].ray.is_valid())
            .map(|i| (layout.key(&rays[i as usize], &origins), i))
            .collect();
        expect.sort_by_key(|&(k, _)| k);
        let valid = sorted.valid();
        assert_eq!(valid, expect.len());
        let got: Vec<(u32, u32)> = sorted
            .keys
            .iter()
            .copied()
            .zip(sorted.order[..valid].iter().copied())
            .collect();
        assert_eq!(got, expect);
        let trimmed: Vec<u32> = (0..rays.len() as u32)
            .filter(|&i| !rays[i as usize].ray.is_valid())
            .collect();
        assert_eq!(sorted.order[valid..], trimmed[..]);
        assert!(sorted.chunks < valid, "repeated keys compress");
        let permuted: Vec<u32> = sorted.order.iter().map(|&i| rays[i as usize].tag).collect();
        assert!(
            permuted
                .iter()
                .zip(&sorted.order)
                .all(|(&t, &i)| t == i ^ 0xabcd)
        );
        // Sequential and parallel agree.
        assert_eq!(sort_rays(&rays, &layout, false).unwrap(), sorted);
        // On the bits above the low ones only: the same, with keys cut there (all of them at 32 and
        // beyond: request order).
        for low in [1, 10, 13, 31, 32, 40] {
            let cut = |k: u32| ((k as u64 >> low.min(32)) << low.min(32)) as u32;
            let mut expect: Vec<(u32, u32)> = expect.iter().map(|&(k, i)| (cut(k), i)).collect();
            expect.sort_by_key(|&(k, i)| (k, i));
            for parallel in [false, true] {
                let mut above = SortedRays::default();
                let scratch = &mut SortScratch::default();
                (above.sort_above(&rays, &layout, low, parallel, scratch)).unwrap();
                let got: Vec<(u32, u32)> = (above.keys.iter().copied())
                    .zip(above.order[..valid].iter().copied())
                    .collect();
                assert_eq!(got, expect, "low {low}");
                assert_eq!(above.order[valid..], trimmed[..]);
                assert!(
                    above.chunks <= sorted.chunks,
                    "coarser keys, no more chunks"
                );
            }
        }
    }
}

/// Exact (f64) containment: every ray's origin within its nodes' spheres, its direction within their
/// cones, at every level, for sorted and unsorted rays. The nodes carry their own rounding slack (see
/// `kinetrace::raysort::cone`), so the check needs none.
#[test]
fn rays_lie_inside_their_nodes() {
    let rays: Vec<Ray> = scatter(3000)
        .into_iter()
        .map(|r| r.ray)
        .filter(|r| r.is_valid())
        .chain((0..500).map(|i| {
            Ray::new(
                Vec3::splat(1e4 + i as f32),
                Vec3::new(1e-30, 1.0, -(i as f32)),
            )
        }))
        .collect();
    for (s, depth) in [(8, 2), (16, 3), (2, 4)] {
        let h = RayHierarchy::build(&rays, s, depth, true).unwrap();
        assert_eq!(h.depth(), depth);
        for k in 1..=depth {
            let span = s.pow(k as u32);
            assert_eq!(h.level(k).len(), rays.len().div_ceil(span));
            for (j, node) in h.level(k).iter().enumerate() {
                let axis = node.axis.as_dvec3().normalize();
                for r in &rays[j * span..((j + 1) * span).min(rays.len())] {
                    let off = r.origin.as_dvec3() - node.center.as_dvec3();
                    assert!(
                        off.length() <= node.radius as f64,
                        "level {k} node {j}: origin {r:?} outside {node:?}"
                    );
                    let d: DVec3 = r.dir().as_dvec3().normalize();
                    let angle = d.cross(axis).length().atan2(d.dot(axis));
                    assert!(
                        angle <= node.spread as f64,
                        "level {k} node {j}: direction {r:?} outside {node:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn bad_options_are_errors() {
    let m = room();
    let scene = RayScene::build(&m, &BuildOptions::default()).unwrap();
    let rays = scatter(10);
    let layout = KeyLayout::default();
    for s in [
        Strategy::Crsh {
            branching: 1,
            depth: 2,
        },
        Strategy::Rah {
            branching: 8,
            depth: 0,
        },
        Strategy::Crsh {
            branching: 64,
            depth: 5,
        },
        // A depth past u32 must not wrap into a small exponent.
        Strategy::Crsh {
            branching: 2,
            depth: (1usize << 32) + 1,
        },
    ] {
        assert!(
            matches!(
                scene.trace(&rays, s, &layout, false),
                Err(Error::InvalidOption(_))
            ),
            "{s:?}"
        );
    }
    let wide = KeyLayout {
        light_bits: 8,
        ..Default::default()
    };
    assert!(matches!(
        scene.trace(&rays, Strategy::SortedBvh, &wide, false),
        Err(Error::InvalidOption(_))
    ));
    assert!(RayHierarchy::build(&[Ray::new(Vec3::ZERO, Vec3::ZERO)], 8, 2, false).is_err());
}

/// Rays whose range reaches behind their origin (`tmin < 0`): from inside the closed room, every one
/// meets a wall behind it first.
#[test]
fn rays_reaching_behind_their_origin_equal_brute_force() {
    let m = room();
    let mut r = rng(31);
    let rays: Vec<SecondaryRay> = (0..600)
        .map(|i| {
            let o = rand_vec(&mut r, -1.8, 1.8);
            let tmin = [f32::NEG_INFINITY, -8.0, -0.5][i % 3];
            let kind = if i % 2 == 0 {
                RayKind::Reflection
            } else {
                RayKind::Shadow { light: 0 }
            };
            let ray = Ray::with_range(o, rand_dir(&mut r), tmin, 1.0);
            SecondaryRay {
                ray,
                kind,
                tag: i as u32,
            }
        })
        .collect();
    let (occluded, hit) = check(&m, &rays, "behind");
    assert!(
        occluded > 100 && hit > 100,
        "{occluded} occluded, {hit} hit"
    );
}
