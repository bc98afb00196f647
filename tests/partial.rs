//! Partial rebuilds: on deforming scenes the tree validates, answers equal brute force (the independent
//! oracle), its SAH cost is no worse than the refitted tree's, nodes and slots outside the rebuilt subtrees
//! keep their bytes, and the triangles rebuilt follow the part of the mesh that was torn apart.

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, Bvh, PartialOptions, PartialRebuild};
use kinetrace::{Error, Mesh, MeshBvh};
use rand::Rng;

/// The soup explosion: the triangles whose centroid lies in the corner cube `[0, cut)³` fly apart (each
/// along its own random direction, up to `reach`), the rest stay. Returns the new positions and which
/// triangles moved.
fn explode(m: &Mesh, cut: f32, reach: f32, seed: u64) -> (Vec<Vec3>, Vec<u32>) {
    let mut r = rng(seed);
    let mut pos = m.positions().to_vec();
    let mut moved = Vec::new();
    for t in 0..m.triangle_count() {
        let [a, b, c] = m.triangle(t);
        if ((a + b + c) / 3.0).max_element() < cut {
            let d = rand_dir(&mut r) * r.random_range(0.0..reach);
            for k in 0..3 {
                let i = m.indices()[3 * t + k] as usize;
                pos[i] += d;
            }
            moved.push(t as u32);
        }
    }
    (pos, moved)
}

/// A cloth torn in one corner: the folded sheet's vertices with `x < 0.25` and `y < 0.5` jump by up to
/// `reach` in random directions, the rest of the cloth waves on (`phase`).
fn torn_cloth(n: u32, phase: f32, reach: f32, seed: u64) -> Vec<Vec3> {
    let mut r = rng(seed);
    folded_sheet(n, phase)
        .positions()
        .iter()
        .map(|&p| {
            let d = rand_dir(&mut r) * r.random_range(0.0..reach);
            if p.x < 0.25 && p.y < 0.5 { p + d } else { p }
        })
        .collect()
}

fn folded_sheet(n: u32, phase: f32) -> Mesh {
    kinetrace::scenes::folded_sheet(n, phase)
}

/// Nodes and slots outside the rebuilt subtrees of `part` are bit for bit those of `refit` (the same tree,
/// refitted only); a rebuilt subtree's root keeps its box bit for bit and its slots the same primitives.
fn assert_untouched(refit: &Bvh, part: &Bvh, done: &PartialRebuild, what: &str) {
    let (old, new) = (refit.nodes(), part.nodes());
    assert_eq!(old.len(), new.len(), "{what}: node count");
    let mut rebuilt = vec![false; old.len()];
    for &root in &done.roots {
        // Descendants in the old structure.
        let mut stack = vec![root];
        while let Some(i) = stack.pop() {
            if i != root {
                rebuilt[i] = true;
            }
            if !old[i].is_leaf() {
                stack.extend([old[i].left(), old[i].left() + 1]);
            }
        }
        assert_eq!(
            (
                old[root].min.map(f32::to_bits),
                old[root].max.map(f32::to_bits)
            ),
            (
                new[root].min.map(f32::to_bits),
                new[root].max.map(f32::to_bits)
            ),
            "{what}: root {root} of a rebuilt subtree changed its box"
        );
    }
    for (i, (a, b)) in old.iter().zip(new).enumerate() {
        if !rebuilt[i] && !done.roots.contains(&i) {
            assert_eq!(
                bytemuck::bytes_of(a),
                bytemuck::bytes_of(b),
                "{what}: node {i} outside the rebuilt subtrees changed"
            );
        }
    }
    let mut in_range = vec![false; refit.primitive_count()];
    for r in &done.slots {
        in_range[r.clone()].fill(true);
        let (mut a, mut b) = (
            refit.prim_indices()[r.clone()].to_vec(),
            part.prim_indices()[r.clone()].to_vec(),
        );
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b, "{what}: slots {r:?} hold other primitives");
    }
    for (s, &inside) in in_range.iter().enumerate() {
        if !inside {
            assert_eq!(
                refit.prim_indices()[s],
                part.prim_indices()[s],
                "{what}: slot {s} outside the rebuilt subtrees changed"
            );
        }
    }
}

/// Everything the partial rebuild must keep, on one mesh moved to `pos`: returns what it did.
fn check_partial(m: &Mesh, pos: &[Vec3], options: &PartialOptions, what: &str) -> PartialRebuild {
    let built = MeshBvh::build(m, &BuildOptions::new(Builder::SAH)).unwrap();
    let mut refit = built.clone();
    refit.refit(pos).unwrap();
    let mut part = built.clone();
    let predicted = refit.bvh().degraded_primitives(options).unwrap();
    let (degradation, done) = part.refit_partial(pos, options).unwrap();
    assert_eq!(
        predicted, done.primitives,
        "{what}: dry run and rebuild disagree"
    );
    assert_eq!(
        degradation,
        refit.bvh().degradation(),
        "{what}: the refit's metric"
    );
    assert_eq!(
        done.primitives,
        done.slots.iter().map(|r| r.len()).sum::<usize>(),
        "{what}: work count"
    );
    let moved = m.with_positions(pos.to_vec()).unwrap();
    part.bvh()
        .validate(Some(&moved.triangle_bounds()))
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    assert_untouched(refit.bvh(), part.bvh(), &done, what);
    let (rc, pc) = (refit.bvh().sah_cost(), part.bvh().sah_cost());
    assert!(
        pc <= rc,
        "{what}: SAH cost {pc} after partial rebuilds, {rc} refitted"
    );
    if done.subtrees > 0 {
        assert_ne!(
            part.topology_id(),
            built.topology_id(),
            "{what}: topology id"
        );
    }
    let mut binary = part.clone();
    binary.set_wide(false);
    for (i, ray) in scene_rays(&moved, 7, 400).iter().enumerate() {
        let oracle = RayOracle::of_mesh(&moved, ray);
        for (tree, name) in [(&part, "wide"), (&binary, "binary")] {
            let got = tree.closest_hit(ray).map(|h| (h.primitive, h.t));
            oracle.check_closest(got, &format!("{what} {name} ray {i}"));
            oracle.check_any(tree.any_hit(ray), &format!("{what} {name} any-hit ray {i}"));
        }
    }
    done
}

#[test]
fn a_partly_exploding_soup_rebuilds_the_exploded_part_only() {
    let m = soup(11, 8000);
    let options = PartialOptions::default();
    for reach in [0.1f32, 0.5] {
        // 1/64 of the volume explodes: the part of the tree rebuilt is of the size of the exploded part
        // (at least half of it, at most four times), far from the whole tree.
        let (pos, moved) = explode(&m, 0.25, reach, 3);
        let what = format!("corner explosion, reach {reach}");
        let done = check_partial(&m, &pos, &options, &what);
        assert!(done.subtrees > 0, "{what}: nothing rebuilt");
        assert!(
            done.primitives <= 4 * moved.len()
                && 2 * done.primitives >= moved.len()
                && done.primitives < m.triangle_count() / 4,
            "{what}: {} triangles rebuilt for {} exploded",
            done.primitives,
            moved.len()
        );
    }
    // Half the scene's extent explodes across all of it: whatever is rebuilt, everything holds.
    let (pos, _) = explode(&m, 0.5, 0.5, 4);
    check_partial(&m, &pos, &options, "half explosion");
}

/// Clones of a tree share its topology (slot order and slot triangles) — what lets a crowd's copies of
/// one character's tree pay for their boxes only — until one is partially rebuilt, which gives that one
/// its own: the original keeps its slots, valid and exact on its own mesh.
#[test]
fn clones_share_topology_until_a_partial_rebuild() {
    let m = soup(11, 8000);
    let built = MeshBvh::build(&m, &BuildOptions::new(Builder::SAH)).unwrap();
    let slots = built.bvh().prim_indices().to_vec();
    let mut copy = built.clone();
    let shared = |a: &MeshBvh, b: &MeshBvh| {
        (
            std::ptr::eq(a.bvh().prim_indices(), b.bvh().prim_indices()),
            std::ptr::eq(a.slot_indices(), b.slot_indices()),
        )
    };
    assert_eq!(shared(&built, &copy), (true, true));
    let (pos, _) = explode(&m, 0.25, 0.5, 3);
    let (_, done) = copy
        .refit_partial(&pos, &PartialOptions::default())
        .unwrap();
    assert!(done.subtrees > 0, "the explosion rebuilds something");
    assert_eq!(shared(&built, &copy), (false, false));
    assert_ne!(
        copy.bvh().prim_indices(),
        &slots[..],
        "the copy's own order"
    );
    assert_eq!(built.bvh().prim_indices(), &slots[..]);
    built.bvh().validate(Some(&m.triangle_bounds())).unwrap();
    for (i, ray) in scene_rays(&m, 5, 200).iter().enumerate() {
        let oracle = RayOracle::of_mesh(&m, ray);
        let got = built.closest_hit(ray).map(|h| (h.primitive, h.t));
        oracle.check_closest(got, &format!("original ray {i}"));
    }
}

#[test]
fn a_torn_cloth_rebuilds_the_torn_corner_and_a_waving_one_stays_valid() {
    let m = folded_sheet(48, 0.0);
    // Tearing makes siblings overlap, which moves a node's ratio by at most about 0.5 (explosions, whose
    // children shrink inside a growing parent, by far more): the torn subtrees' means sit near 0.1–0.2,
    // under the thesis's 0.40 for a whole tree.
    let options = PartialOptions {
        threshold: 0.1,
        ..PartialOptions::default()
    };
    let pos = torn_cloth(48, 0.3, 0.3, 5);
    let torn = m
        .indices()
        .chunks_exact(3)
        .filter(|t| {
            t.iter()
                .any(|&i| pos[i as usize] != m.positions()[i as usize])
        })
        .count();
    let done = check_partial(&m, &pos, &options, "torn cloth");
    assert!(done.subtrees > 0, "torn cloth: nothing rebuilt");
    assert!(
        done.primitives <= 2 * torn,
        "torn cloth: {} triangles rebuilt for {torn} torn",
        done.primitives
    );
    // A coherently waving cloth: whatever is rebuilt, everything above holds.
    for phase in [0.5f32, 2.0] {
        let pos = folded_sheet(48, phase).positions().to_vec();
        check_partial(&m, &pos, &options, &format!("waving cloth {phase}"));
    }
}

#[test]
fn thresholds_decide_how_much_is_rebuilt() {
    let m = soup(12, 3000);
    let (pos, _) = explode(&m, 0.5, 0.5, 4);
    let nothing = PartialOptions {
        threshold: 1e30,
        ..PartialOptions::default()
    };
    assert_eq!(
        check_partial(&m, &pos, &nothing, "threshold 1e30").subtrees,
        0
    );
    let everything = PartialOptions {
        threshold: -1e30,
        ..PartialOptions::default()
    };
    let done = check_partial(&m, &pos, &everything, "threshold -1e30");
    assert_eq!((done.subtrees, done.roots.as_slice()), (1, &[0][..]));
    assert_eq!(done.primitives, m.triangle_count());
    // An unmoved mesh rebuilds nothing and keeps its bytes and identity.
    let built = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let mut same = built.clone();
    let (_, done) = same
        .refit_partial(m.positions(), &PartialOptions::default())
        .unwrap();
    assert_eq!(done, PartialRebuild::default());
    assert_eq!(same.bvh(), built.bvh());
    assert_eq!(same.topology_id(), built.topology_id());
}

#[test]
fn box_trees_rebuild_in_place_and_bad_input_is_an_error() {
    let m = soup(13, 2000);
    let (pos, _) = explode(&m, 0.5, 1.0, 6);
    let moved = m.with_positions(pos).unwrap().triangle_bounds();
    let built = Bvh::build(&m.triangle_bounds(), &BuildOptions::new(Builder::LBVH)).unwrap();
    let mut refit = built.clone();
    refit.refit(&moved).unwrap();
    let mut part = refit.clone();
    let done = part
        .rebuild_degraded(&moved, &PartialOptions::default())
        .unwrap();
    assert!(
        done.subtrees > 0,
        "LBVH tree of a half-exploded soup: nothing rebuilt"
    );
    part.validate(Some(&moved)).unwrap();
    assert_untouched(&refit, &part, &done, "LBVH boxes");
    assert!(part.sah_cost() <= refit.sah_cost());

    // Leaves of four: a subtree whose rebuild comes out with another leaf count is skipped, the rest
    // rebuilt; the tree stays valid and untouched outside either way.
    let built4 = Bvh::build(
        &m.triangle_bounds(),
        &BuildOptions::new(Builder::SAH).max_leaf_size(4),
    )
    .unwrap();
    let mut refit4 = built4.clone();
    refit4.refit(&moved).unwrap();
    let mut part4 = refit4.clone();
    let options4 = PartialOptions {
        max_leaf_size: 4,
        ..PartialOptions::default()
    };
    let done4 = part4.rebuild_degraded(&moved, &options4).unwrap();
    assert!(
        done4.subtrees + done4.skipped > 0,
        "leaves of four: nothing selected"
    );
    part4.validate(Some(&moved)).unwrap();
    assert_untouched(&refit4, &part4, &done4, "leaves of four");

    let before = part.clone();
    let bad_bins = PartialOptions {
        bins: 1,
        ..PartialOptions::default()
    };
    assert!(matches!(
        part.rebuild_degraded(&moved, &bad_bins),
        Err(Error::InvalidOption(_))
    ));
    assert!(matches!(
        part.rebuild_degraded(&moved[1..], &PartialOptions::default()),
        Err(Error::VertexCountMismatch { .. })
    ));
    let mut nan = moved.clone();
    nan[7].min.x = f32::NAN;
    assert!(matches!(
        part.rebuild_degraded(&nan, &PartialOptions::default()),
        Err(Error::NonFiniteBounds { primitive: 7 })
    ));
    assert_eq!(part, before, "a rejected call changed the tree");

    let mut mesh_tree = MeshBvh::build(&m, &BuildOptions::default()).unwrap();
    let kept = mesh_tree.bvh().clone();
    let mut p = m.positions().to_vec();
    p[4].y = f32::INFINITY;
    assert!(matches!(
        mesh_tree.refit_partial(&p, &PartialOptions::default()),
        Err(Error::NonFiniteVertex { .. })
    ));
    assert!(matches!(
        mesh_tree.refit_partial(m.positions(), &bad_bins),
        Err(Error::InvalidOption(_))
    ));
    assert_eq!(mesh_tree.bvh(), &kept);
}

/// The planner's third update: when the rent makes a rebuild due, a partial rebuild offered is taken when
/// its predicted time beats the full rebuild's by the margin. Numbers as in the `adaptive` module example:
/// a 10k-triangle LBVH build measured at 4 ms, so binned SAH is predicted at 5 × 4 ms by the prior time
/// ratio, and a partial rebuild of `k` triangles at 20 ms · k·log2 k / (10k·log2 10k), spread 25%.
#[test]
fn the_planner_takes_a_partial_rebuild_when_it_is_cheaper_beyond_the_margin() {
    use kinetrace::adaptive::{AdaptivePolicy, Verdict};
    let run = |k: usize| {
        let mut policy = AdaptivePolicy::new(&[Builder::LBVH]);
        policy.sah_bound = f64::INFINITY;
        policy.built(Builder::LBVH, 10_000, 0.004, 55.0);
        for _ in 0..3 {
            policy.queried(20_000.0, 55.0, 0.010);
        }
        let frame = (1..20)
            .find(|_| policy.after_refit(60.0, 20_000.0))
            .unwrap();
        assert_eq!(policy.prediction().verdict, Verdict::Rent);
        policy.prefer_partial(k);
        (frame, policy)
    };
    let unit = |n: f64| n * n.log2();
    // 500 triangles: 0.67 ms ± 0.17 against 4 ms ± 1: cheaper by more than two spreads of the difference.
    let (frame, mut policy) = run(500);
    let why = policy.prediction();
    assert_eq!((frame, why.verdict), (7, Verdict::Partial));
    let expect = 0.020 * unit(500.0) / unit(10_000.0);
    assert!(
        (why.rebuild_s - expect).abs() <= 1e-12 * expect,
        "{} vs {expect}",
        why.rebuild_s
    );
    // After the partial rebuild the rent starts again from nothing.
    policy.partially_rebuilt(500, 0.0007, 56.0);
    assert!(!policy.after_refit(56.0, 20_000.0));
    assert!(!policy.prefer_partial(500), "a kept tree is not rebuilt");
    assert_eq!(policy.prediction().verdict, Verdict::Keep);
    // 2000 triangles: 3.3 ms against 4 ms, within the margin: the full rebuild stays.
    let (frame, policy) = run(2000);
    assert_eq!((frame, policy.prediction().verdict), (7, Verdict::Rent));
    // Nothing offered: a full rebuild.
    let (_, policy) = run(0);
    assert_eq!(policy.prediction().verdict, Verdict::Rent);
}
