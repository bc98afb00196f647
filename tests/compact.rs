//! The compact (quantised) wide tree: every dequantised lane box contains the float box it replaces, and
//! ray answers equal brute force (the independent oracle) — far from the origin, for tiny triangles,
//! through refits — while the node count stays that of the float tree.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::BuildOptions;
use kinetrace::bvh::wide::compact::CompactWideBvh;
use kinetrace::{Mesh, MeshBvh};

/// Every lane of every node: the compact box holds the float box, unused lanes stay unused.
fn assert_conservative(tree: &MeshBvh, what: &str) {
    let wide = tree.wide().expect("a wide tree");
    let compact = CompactWideBvh::quantise(wide);
    assert_eq!(
        compact.nodes().len(),
        wide.nodes().len(),
        "{what}: node count"
    );
    for (i, (w, c)) in wide.nodes().iter().zip(compact.nodes()).enumerate() {
        assert_eq!(w.child, c.child, "{what}: node {i} payloads");
        for lane in 0..4 {
            let (f, q) = (w.lane_box(lane), compact.lane_box(i, lane));
            if w.child[lane] == u32::MAX {
                assert!(
                    q.is_empty(),
                    "{what}: node {i} lane {lane} unused but not empty"
                );
            } else {
                assert!(
                    q.contains_box(&f),
                    "{what}: node {i} lane {lane}: {q:?} does not hold {f:?}"
                );
                // And no looser than the encoding needs: each plane within one step of 2^exp plus the
                // rounding of the addition (one ulp where the plane lies).
                for a in 0..3 {
                    let step = 2f32.powi(i32::from(c.exp[a]));
                    for (got, want) in [(f.min[a], q.min[a]), (q.max[a], f.max[a])] {
                        let gap = got - want;
                        let ulp = got.abs().max(want.abs());
                        let ulp = ulp.next_up() - ulp;
                        assert!(
                            gap <= step + ulp,
                            "{what}: node {i} lane {lane} axis {a}: {gap} past the plane, step {step}"
                        );
                    }
                }
            }
        }
    }
}

/// Closest and any hit of the compact tree against the oracle, on `n` rays.
fn assert_exact(tree: &MeshBvh, m: &Mesh, seed: u64, n: usize, what: &str) {
    assert!(
        tree.compact().is_some() && tree.wide().is_none(),
        "{what}: compact tree in use"
    );
    for (i, ray) in scene_rays(m, seed, n).iter().enumerate() {
        let oracle = RayOracle::of_mesh(m, ray);
        let got = tree.closest_hit(ray).map(|h| (h.primitive, h.t));
        oracle.check_closest(got, &format!("{what} ray {i}"));
        oracle.check_any(tree.any_hit(ray), &format!("{what} any-hit ray {i}"));
    }
}

fn scenes() -> Vec<(&'static str, Mesh)> {
    vec![
        ("icosphere", icosphere(3)),
        ("soup", soup(21, 4000)),
        ("torus", kinetrace::scenes::bumpy_torus(4000)),
        ("sheet", kinetrace::scenes::folded_sheet(32, 0.7)),
        // 1e5 from the origin: plane steps of a few f32 ulps there.
        (
            "far soup",
            map_mesh(&soup(22, 3000), |p| p * 50.0 + Vec3::splat(1e5)),
        ),
        (
            "far sphere",
            map_mesh(&icosphere(3), |p| p + Vec3::new(-1e5, 1e5, 3e5)),
        ),
        // Tiny boxes: exponents near the bottom of the normal range.
        ("tiny soup", map_mesh(&soup(23, 2000), |p| p * 1e-30)),
    ]
}

#[test]
fn quantised_boxes_hold_the_float_boxes_and_answers_stay_exact() {
    for (name, m) in scenes() {
        let mut tree = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        assert_conservative(&tree, name);
        tree.set_compact(true);
        assert_exact(&tree, &m, 31, 300, name);
        let float = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
        tree.set_compact(false);
        assert_eq!(
            tree.wide(),
            float.wide(),
            "{name}: the float tree comes back"
        );
    }
}

#[test]
fn a_refitted_compact_tree_stays_exact() {
    let m = icosphere(3);
    let mut tree = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    tree.set_compact(true);
    let pos: Vec<Vec3> = m
        .positions()
        .iter()
        .map(|&p| p + Vec3::new((p.y * 5.0).sin(), 0.0, (p.x * 3.0).cos()) * 0.3)
        .collect();
    tree.refit(&pos).unwrap();
    let moved = m.with_positions(pos).unwrap();
    assert_exact(&tree, &moved, 32, 300, "refitted icosphere");
    let mut float = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    float.refit(moved.positions()).unwrap();
    assert_conservative(&float, "refitted icosphere");
}
