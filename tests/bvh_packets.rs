//! Ray packets through the binary BVH: every ray of a packet gets what it gets alone (the same distance, and
//! the same triangle or an exactly tied one) and what brute force over every triangle gives, for coherent
//! camera tiles, shadow packets toward a point light, deliberately incoherent packets and edge cases.

mod common;

use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, MAX_PACKET, TraversalStats};
use kinetrace::scenes::bumpy_torus;
use kinetrace::{Mesh, MeshBvh, Ray};

/// Packets of `size` consecutive rays against single rays (exact `t`, closest and any hit) and brute force.
fn check(m: &Mesh, rays: &[Ray], what: &str) {
    let brute: Vec<_> = rays.iter().map(|r| brute_closest(m, r)).collect();
    for opts in all_build_options() {
        let bvh = MeshBvh::build(m, &opts).unwrap();
        for size in [16, MAX_PACKET] {
            let what = format!(
                "{what}, {:?} leaf {}, packet {size}",
                opts.builder, opts.max_leaf_size
            );
            let (mut out, mut any) = (vec![None; rays.len()], vec![false; rays.len()]);
            let mut stats = TraversalStats::default();
            for (r, (o, a)) in rays
                .chunks(size)
                .zip(out.chunks_mut(size).zip(any.chunks_mut(size)))
            {
                bvh.closest_hits_packet(r, o, &mut stats);
                bvh.any_hits_packet(r, a, &mut stats);
            }
            for (i, ray) in rays.iter().enumerate() {
                let single = bvh.closest_hit(ray);
                let got = out[i];
                assert_eq!(
                    got.map(|h| h.t.to_bits()),
                    single.map(|h| h.t.to_bits()),
                    "{what} ray {i}: packet and single ray at different distances"
                );
                let got = got.map(|h| (h.primitive, h.t));
                if got != brute[i] {
                    assert_same_hit(m, ray, got, brute[i], &format!("{what} ray {i}"));
                }
                assert_eq!(any[i], bvh.any_hit(ray), "{what} any-hit ray {i}");
                assert_eq!(any[i], got.is_some(), "{what} any-hit vs closest ray {i}");
            }
        }
    }
}

fn bounds(m: &Mesh) -> kinetrace::Aabb {
    m.triangle_bounds()
        .iter()
        .fold(kinetrace::Aabb::EMPTY, |a, b| a.union(b))
}

#[test]
fn camera_tiles_equal_single_rays_and_brute_force() {
    for (name, m) in [
        ("torus", bumpy_torus(3000)),
        ("soup", soup(4, 1500)),
        ("cube sphere", cube_sphere(8)),
    ] {
        let b = bounds(&m);
        for (eye, tile) in [
            (
                b.center() + Vec3::new(0.3, 0.4, 1.0) * b.extent().length(),
                8,
            ),
            (
                b.center() - Vec3::new(0.0, 0.0, 1.5) * b.extent().length(),
                4,
            ),
            (b.center() + Vec3::new(0.1, -0.05, 0.02), 8), // from inside
        ] {
            check(&m, &camera(eye, b.center(), 32, tile, 0.9), name);
        }
    }
}

#[test]
fn shadow_packets_toward_a_point_light() {
    let m = bumpy_torus(3000);
    let bvh = MeshBvh::build(&m, &BuildOptions::new(Builder::SAH)).unwrap();
    let b = bounds(&m);
    let eye = b.center() + Vec3::new(0.3, 0.8, 1.0) * b.extent().length();
    let light = b.center() + Vec3::new(-0.2, 1.0, 0.3) * b.extent().length() * 0.6;
    // Shadow segments from the visible points toward the light, in the camera's tile order, and from
    // points scattered over the box (different origins, one common end).
    let mut rays: Vec<Ray> = camera(eye, b.center(), 32, 8, 0.9)
        .iter()
        .filter_map(|r| bvh.closest_hit(r).map(|h| r.at(h.t)))
        .map(|p| Ray::with_range(p, light - p, 1e-4, 1.0))
        .collect();
    assert!(rays.len() > 150, "{} visible points", rays.len());
    let mut r = rng(8);
    rays.extend(
        (0..256)
            .map(|_| Ray::segment(b.center() + rand_vec(&mut r, -0.5, 0.5) * b.extent(), light)),
    );
    check(&m, &rays, "shadow");
}

#[test]
fn incoherent_packets_equal_single_rays() {
    let m = bumpy_torus(2000);
    let b = bounds(&m);
    let mut r = rng(3);
    // Random origins and directions: no axis shares a sign, the packet goes ray by ray.
    let mut rays: Vec<Ray> = (0..256)
        .map(|_| {
            Ray::new(
                b.center() + rand_vec(&mut r, -0.5, 0.5) * b.extent(),
                rand_dir(&mut r),
            )
        })
        .collect();
    // Directions that share the sign of one axis only, origins spread over the box: the packet is culled
    // on that axis and its ranges stay wide.
    rays.extend((0..256).map(|_| {
        let mut d = rand_dir(&mut r);
        d.y = d.y.abs() + 0.05;
        let o = b.center() + rand_vec(&mut r, -0.5, 0.5) * b.extent() - Vec3::Y * b.extent().y;
        Ray::new(o, d)
    }));
    // Coherent directions, origins from both sides of the mesh.
    rays.extend((0..128).map(|i| {
        let o = b.center() + rand_vec(&mut r, -1.0, 1.0) * b.extent();
        Ray::new(o, Vec3::new(0.1, 0.2, if i % 2 == 0 { 1.0 } else { 0.9 }))
    }));
    check(&m, &rays, "incoherent");
}

#[test]
fn axis_parallel_rays_signed_zeros_ranges_and_invalid_lanes() {
    let m = cube_sphere(6);
    let b = bounds(&m);
    let mut rays = Vec::new();
    // Axis-parallel rays with +0 and −0 in their zero components, through face planes, edges and
    // vertices of the grid-aligned sphere, from outside and inside.
    for a in 0..3 {
        for i in 0..=12 {
            for zero in [0.0f32, -0.0] {
                let mut o = b.center();
                o[(a + 1) % 3] = b.min[(a + 1) % 3] + b.extent()[(a + 1) % 3] * i as f32 / 12.0;
                o[a] = b.min[a] - 1.0;
                let mut d = Vec3::splat(zero);
                d[a] = 1.0;
                rays.push(Ray::new(o, d));
                o[a] = b.center()[a];
                d[a] = -1.0;
                rays.push(Ray::new(o, d));
            }
        }
    }
    // Limited ranges, and invalid rays mixed into coherent packets.
    let cam = camera(b.center() + Vec3::Z * 3.0, b.center(), 16, 8, 0.8);
    for (i, r) in cam.iter().enumerate() {
        rays.push(match i % 7 {
            0 => Ray::new(Vec3::NAN, r.dir()),
            1 => Ray::new(r.origin, Vec3::ZERO),
            2 => Ray::with_range(r.origin, r.dir(), 2.5, 3.0),
            3 => Ray::with_range(r.origin, r.dir(), 0.0, 2.0),
            _ => *r,
        });
    }
    check(&m, &rays, "axis-parallel");
}

#[test]
fn offsets_of_1e5_empty_mesh_and_one_triangle() {
    let base = icosphere(3);
    let m = map_mesh(&base, |p| p + Vec3::new(1e5, -1e5, 3.0));
    let b = bounds(&m);
    check(
        &m,
        &camera(
            b.center() + Vec3::new(0.5, 1.0, 3.0),
            b.center(),
            16,
            8,
            0.9,
        ),
        "offset",
    );
    let one = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2]).unwrap();
    check(
        &one,
        &camera(
            Vec3::new(0.3, 0.3, 2.0),
            Vec3::new(0.3, 0.3, 0.0),
            16,
            4,
            1.2,
        ),
        "one triangle",
    );
    let empty = Mesh::new(Vec::new(), Vec::new()).unwrap();
    let bvh = MeshBvh::build(&empty, &BuildOptions::default()).unwrap();
    let rays = camera(Vec3::Z, Vec3::ZERO, 8, 8, 1.0);
    let mut out = vec![
        Some(kinetrace::Hit {
            t: 0.0,
            primitive: 0,
            u: 0.0,
            v: 0.0,
            normal: Vec3::Z
        });
        64
    ];
    bvh.closest_hits_packet(&rays, &mut out, &mut TraversalStats::default());
    assert!(out.iter().all(Option::is_none));
}

/// A 20k-triangle torus, its LBVH (with or without the wide tree) and 64² camera rays in 8×8 tiles.
fn torus_tiles(wide: bool) -> (Mesh, MeshBvh, Vec<Ray>) {
    let m = bumpy_torus(20_000);
    let bvh = MeshBvh::build(&m, &BuildOptions::new(Builder::LBVH).wide(wide)).unwrap();
    let b = bounds(&m);
    let rays = camera(
        b.center() + Vec3::new(0.3, 0.4, 1.0) * b.extent().length(),
        b.center(),
        64,
        8,
        0.9,
    );
    (m, bvh, rays)
}

#[test]
fn batched_packets_equal_packet_by_packet_and_share_node_visits() {
    // Binary only: packets walk the binary tree, so single rays must walk it too for the visit count.
    let (_, bvh, rays) = torus_tiles(false);
    let mut single = vec![None; rays.len()];
    bvh.closest_hits(&rays, &mut single);
    let mut batched = vec![None; rays.len()];
    bvh.closest_hits_packets(&rays, 64, &mut batched);
    let mut occluded = vec![false; rays.len()];
    bvh.any_hits_packets(&rays, 64, &mut occluded);
    for i in 0..rays.len() {
        assert_eq!(batched[i].map(|h| h.t), single[i].map(|h| h.t), "ray {i}");
        assert_eq!(occluded[i], single[i].is_some(), "ray {i}");
    }
    // The point of packets: an 8×8 camera tile visits each node once for all its rays, so the packets
    // visit far fewer inner nodes than the rays do one by one (a work count, not a timing).
    let (mut alone, mut packets) = (TraversalStats::default(), TraversalStats::default());
    for r in &rays {
        bvh.closest_hit_counted(r, &mut alone);
    }
    bvh.closest_hits_packet(&rays, &mut batched, &mut packets);
    assert!(
        packets.inner_visits * 3 < alone.inner_visits,
        "packets {packets:?} single {alone:?}"
    );
}

#[test]
fn wide_tree_packets_equal_single_rays_and_share_node_visits() {
    // The default build derives the 4-wide tree: packets and single rays both walk it.
    let (m, bvh, rays) = torus_tiles(true);
    assert!(bvh.wide().is_some());
    let (mut alone, mut packets) = (TraversalStats::default(), TraversalStats::default());
    let single: Vec<_> = rays
        .iter()
        .map(|r| bvh.closest_hit_counted(r, &mut alone))
        .collect();
    let mut packed = vec![None; rays.len()];
    bvh.closest_hits_packet(&rays, &mut packed, &mut packets);
    for (i, ray) in rays.iter().enumerate() {
        assert_eq!(
            packed[i].map(|h| h.t.to_bits()),
            single[i].map(|h| h.t.to_bits()),
            "ray {i}"
        );
        let got = packed[i].map(|h| (h.primitive, h.t));
        let brute = brute_closest(&m, ray);
        if got != brute {
            assert_same_hit(&m, ray, got, brute, &format!("ray {i}"));
        }
    }
    // An 8×8 tile visits each wide node once for all its rays (a work count, not a timing).
    assert!(
        packets.inner_visits * 3 < alone.inner_visits,
        "packets {packets:?} single {alone:?}"
    );
}
