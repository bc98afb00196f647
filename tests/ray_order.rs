//! The nearest hit does not depend on the order a traversal visits a tree in: on faces met at an angle a
//! short way from the ray's origin, whose computed `t` can fall ulps of their corners' depths (not of `t`)
//! below their own box's entry distance, every tree of every builder — binary, 4-wide and quantised walks,
//! packets — and the uniform grid answer what a scan of every triangle in index order answers.
//!
//! The oracle shares only the watertight triangle test with the code under test, by definition: the crate's
//! nearest hit is the least `t` that test computes (the lowest primitive among equal ones), and what is
//! tested is that no traversal culls a box holding it. Before each traversal added
//! [`Ray::hit_slack`](kinetrace::Ray::hit_slack) to its limit, about half of these rays came back with a
//! farther face, a hundred ulps of `t` away, from every builder.

mod common;

use common::all_build_options;
use glam::{Quat, Vec3};
use kinetrace::bvh::{MAX_PACKET, TraversalStats};
use kinetrace::geometry::TriangleRay;
use kinetrace::grid::{GridOptions, UniformGrid};
use kinetrace::scenes::SceneRng;
use kinetrace::{Mesh, MeshBvh, Ray};

/// Stacked square faces in the planes `x = c·(1 + k·δ)` (`δ` a few ulps, `c` small), each a different size
/// and slightly offset, plus scattered small triangles that give the trees depth; `turn` rotates the
/// scene and `shift` moves it (and the ray's origin) away from the origin of coordinates.
fn faces(rng: &mut SceneRng, turn: Quat, shift: Vec3) -> Mesh {
    let (mut pos, mut idx) = (Vec::new(), Vec::new());
    let c = rng.range(0.001, 0.01);
    for k in 0..8 {
        let x = c * (1.0 + (k as f32 - 3.5) * f32::EPSILON * rng.range(0.0, 16.0));
        let (y, z, s) = (
            rng.range(-0.3, 0.3),
            rng.range(-0.3, 0.3),
            rng.range(0.5, 3.0),
        );
        let base = pos.len() as u32;
        pos.extend([
            Vec3::new(x, y - s, z - s),
            Vec3::new(x, y + s, z - s),
            Vec3::new(x, y + s, z + s),
            Vec3::new(x, y - s, z + s),
        ]);
        idx.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    for _ in 0..24 {
        let p = rng.vec3(-3.0, 3.0) + Vec3::new(4.0, 0.0, 0.0);
        let base = pos.len() as u32;
        pos.extend([p, p + rng.vec3(-0.2, 0.2), p + rng.vec3(-0.2, 0.2)]);
        idx.extend([base, base + 1, base + 2]);
    }
    let pos: Vec<Vec3> = pos.into_iter().map(|p| turn * p + shift).collect();
    Mesh::new(pos, idx).expect("finite")
}

/// The least `t` over every triangle in index order, the lowest primitive among equal ones.
fn scan(m: &Mesh, ray: &Ray) -> Option<(u32, f32)> {
    let tr = TriangleRay::new(ray);
    let p = m.positions();
    let mut best: Option<(u32, f32)> = None;
    for (i, t) in m.indices().chunks(3).enumerate() {
        let [a, b, c] = [0, 1, 2].map(|k| p[t[k] as usize]);
        if let Some(h) = tr.intersect(a, b, c, ray.tmin, ray.tmax)
            && best.is_none_or(|(_, bt)| h.t < bt)
        {
            best = Some((i as u32, h.t));
        }
    }
    best
}

/// Rays from `shift` along a direction at 3° to 87° from the faces' planes, one per scene, `rounds` scenes.
fn check(rounds: usize, seed: u64, turned: bool, shifted: bool) {
    let mut rng = SceneRng::new(seed);
    let mut found = 0;
    for round in 0..rounds {
        let turn = if turned {
            Quat::from_axis_angle(rng.direction(), rng.range(0.0, 6.0))
        } else {
            Quat::IDENTITY
        };
        let shift = if shifted {
            rng.vec3(-300.0, 300.0)
        } else {
            Vec3::ZERO
        };
        let m = faces(&mut rng, turn, shift);
        let d = Vec3::new(
            rng.range(0.05, 0.5),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        // A packet of the ray and its neighbours at a few ulps of direction, all with their own answers.
        let rays: Vec<Ray> = (0..MAX_PACKET.min(8))
            .map(|k| Ray::new(shift, turn * (d * (1.0 + k as f32 * f32::EPSILON))))
            .collect();
        let want: Vec<_> = rays.iter().map(|r| scan(&m, r)).collect();
        found += want.iter().filter(|w| w.is_some()).count();
        let what = |how: &str, i: usize| format!("round {round} ray {i}: {how}");
        for opts in all_build_options() {
            let mut bvh = MeshBvh::build(&m, &opts).expect("valid");
            for walk in ["wide", "compact", "binary"] {
                match walk {
                    "compact" => bvh.set_compact(true),
                    "binary" => {
                        bvh.set_compact(false);
                        bvh.set_wide(false);
                    }
                    _ => {}
                }
                let how = format!("{:?} leaf {} {walk}", opts.builder, opts.max_leaf_size);
                let mut packet = vec![None; rays.len()];
                bvh.closest_hits_packet(&rays, &mut packet, &mut TraversalStats::default());
                for (i, r) in rays.iter().enumerate() {
                    let single = bvh.closest_hit(r).map(|h| (h.primitive, h.t));
                    assert_eq!(single, want[i], "{}", what(&how, i));
                    let packet = packet[i].map(|h| (h.primitive, h.t));
                    assert_eq!(packet, want[i], "{} packet", what(&how, i));
                }
            }
        }
        let grid = UniformGrid::build(&m, &GridOptions::default()).expect("valid");
        let mut packet = vec![None; rays.len()];
        grid.closest_hits_packet(&rays, &mut packet, &mut TraversalStats::default());
        for (i, r) in rays.iter().enumerate() {
            let single = grid.closest_hit(r).map(|h| (h.primitive, h.t));
            assert_eq!(single, want[i], "{}", what("grid", i));
            let packet = packet[i].map(|h| (h.primitive, h.t));
            assert_eq!(packet, want[i], "{}", what("grid packet", i));
        }
    }
    // Nearly every ray meets the stacked faces (a few pass beside the smaller ones).
    assert!(
        found * 10 > rounds * 8 * 9,
        "{found} hits of {} rays",
        rounds * 8
    );
}

#[test]
fn faces_met_at_an_angle_near_the_origin() {
    check(150, 5, false, false);
}

#[test]
fn the_same_far_from_the_origin_of_coordinates() {
    check(150, 6, false, true);
}

#[test]
fn the_same_turned_and_shifted() {
    check(150, 7, true, true);
}
