//! The GPU pair traversal (broad phase of collision queries) against brute force over all pairs of leaves,
//! on lavapipe in CI (`KINETRACE_REQUIRE_GPU=1` makes a missing adapter a failure; without it these tests
//! skip and say so).
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::{Affine3A, DMat3, DVec3, Quat, Vec3};
use kinetrace::bvh::{BuildOptions, Builder, Node};
use kinetrace::gpu::{GpuContext, GpuMeshBvh, GpuPairs, GpuTree, PairsResult};
use kinetrace::{Error, Mesh, MeshBvh};
use std::collections::BTreeSet;

/// The crate's relative slack of a moved box, 8 · f32::EPSILON (`collide::bvtt::PLACE_SLACK`).
const PLACE_SLACK: f64 = 8.0 * f32::EPSILON as f64;

fn gpu() -> Option<GpuContext> {
    gpu_or_skip()
}

/// The builds every scene is tried with: both builders, one and four triangles per leaf.
const BUILDS: [(Builder, u32); 4] = [
    (Builder::LBVH, 1),
    (Builder::SAH, 4),
    (Builder::SAH, 1),
    (Builder::LBVH, 4),
];

fn tree(m: &Mesh, (builder, leaf): (Builder, u32)) -> Vec<Node> {
    MeshBvh::build(m, &BuildOptions::new(builder).max_leaf_size(leaf))
        .unwrap()
        .bvh()
        .nodes()
        .to_vec()
}

fn leaves(nodes: &[Node]) -> Vec<u32> {
    (0..nodes.len() as u32)
        .filter(|&i| nodes[i as usize].is_leaf())
        .collect()
}

/// A box in f64.
#[derive(Clone, Copy)]
struct DBox {
    lo: DVec3,
    hi: DVec3,
}

impl DBox {
    fn of(n: &Node) -> Self {
        DBox {
            lo: DVec3::from_array(n.min.map(f64::from)),
            hi: DVec3::from_array(n.max.map(f64::from)),
        }
    }

    fn overlaps(&self, o: &DBox) -> bool {
        self.lo.cmple(o.hi).all() && o.lo.cmple(self.hi).all()
    }
}

/// `b_to_a` in f64.
struct DTransform {
    m: DMat3,
    t: DVec3,
}

impl DTransform {
    fn new(b_to_a: &Affine3A) -> Self {
        let m = b_to_a.matrix3;
        DTransform {
            m: DMat3::from_cols(
                m.x_axis.as_dvec3(),
                m.y_axis.as_dvec3(),
                m.z_axis.as_dvec3(),
            ),
            t: b_to_a.translation.as_dvec3(),
        }
    }

    /// Node `n` of tree b in a's frame: the box of its eight corners moved in f64, widened on each side by
    /// `widen` times the magnitudes a moved box's rounding scales with.
    fn place(&self, n: &Node, widen: f64) -> DBox {
        let b = DBox::of(n);
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for k in 0..8 {
            let c = DVec3::new(
                if k & 1 == 0 { b.lo.x } else { b.hi.x },
                if k & 2 == 0 { b.lo.y } else { b.hi.y },
                if k & 4 == 0 { b.lo.z } else { b.hi.z },
            );
            let p = self.m * c + self.t;
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let abs_m = DMat3::from_cols(
            self.m.x_axis.abs(),
            self.m.y_axis.abs(),
            self.m.z_axis.abs(),
        );
        let (c, e) = ((b.lo + b.hi) * 0.5, (b.hi - b.lo) * 0.5);
        let w = (abs_m * (c.abs() + e) + self.t.abs()) * widen;
        DBox {
            lo: lo - w,
            hi: hi + w,
        }
    }
}

/// Brute force: every pair of leaves whose boxes overlap, b's moved into a's frame in f64 and widened by
/// `widen` (see [`DTransform::place`]).
fn brute_pairs(a: &[Node], b: &[Node], b_to_a: &Affine3A, widen: f64) -> BTreeSet<[u32; 2]> {
    let t = DTransform::new(b_to_a);
    let lb: Vec<(u32, DBox)> = leaves(b)
        .into_iter()
        .map(|j| (j, t.place(&b[j as usize], widen)))
        .collect();
    let mut out = BTreeSet::new();
    for i in leaves(a) {
        let ba = DBox::of(&a[i as usize]);
        out.extend(
            lb.iter()
                .filter(|(_, bb)| ba.overlaps(bb))
                .map(|&(j, _)| [i, j]),
        );
    }
    out
}

/// Brute force of a tree against itself: every leaf with itself, every unordered pair of distinct leaves
/// whose boxes overlap (as `[min, max]`).
fn brute_self(nodes: &[Node]) -> BTreeSet<[u32; 2]> {
    let l = leaves(nodes);
    let mut out: BTreeSet<[u32; 2]> = l.iter().map(|&x| [x, x]).collect();
    for (k, &x) in l.iter().enumerate() {
        let bx = DBox::of(&nodes[x as usize]);
        for &y in &l[k + 1..] {
            if bx.overlaps(&DBox::of(&nodes[y as usize])) {
                out.insert([x.min(y), x.max(y)]);
            }
        }
    }
    out
}

/// The GPU's pairs as a set, after checking that none comes twice.
fn as_set(pairs: &[[u32; 2]], what: &str) -> BTreeSet<[u32; 2]> {
    let set: BTreeSet<[u32; 2]> = pairs.iter().copied().collect();
    assert_eq!(set.len(), pairs.len(), "{what}: a pair came twice");
    assert!(pairs.is_sorted(), "{what}: pairs are not sorted");
    set
}

/// Checks the GPU's pairs of trees `a` and `b` (moved by `b_to_a`) against brute force: equal for the
/// identity, else containing every pair that truly overlaps and nothing that does not overlap within four
/// times the slack. Returns the number of pairs.
fn check_pairs(
    gp: &mut GpuPairs,
    g: &GpuContext,
    a: &[Node],
    b: &[Node],
    b_to_a: &Affine3A,
    what: &str,
) -> usize {
    let got = gp.leaf_pairs(g, a, Some((b, b_to_a))).unwrap();
    check_against_brute(&got, a, b, b_to_a, what);
    got.len()
}

fn check_against_brute(got: &[[u32; 2]], a: &[Node], b: &[Node], b_to_a: &Affine3A, what: &str) {
    let got = as_set(got, what);
    let exact = brute_pairs(a, b, b_to_a, 0.0);
    if *b_to_a == Affine3A::IDENTITY {
        assert_eq!(got, exact, "{what}: identity transform");
        return;
    }
    let missing: Vec<_> = exact.difference(&got).take(5).collect();
    assert!(
        missing.is_empty(),
        "{what}: GPU misses overlapping pairs {missing:?}"
    );
    let loose = brute_pairs(a, b, b_to_a, 4.0 * PLACE_SLACK);
    let extra: Vec<_> = got.difference(&loose).take(5).collect();
    assert!(
        extra.is_empty(),
        "{what}: GPU pairs {extra:?} do not overlap"
    );
}

fn check_self(gp: &mut GpuPairs, g: &GpuContext, nodes: &[Node], what: &str) -> usize {
    let got = gp.leaf_pairs(g, nodes, None).unwrap();
    let normalised: Vec<[u32; 2]> = got.iter().map(|&[x, y]| [x.min(y), x.max(y)]).collect();
    let set: BTreeSet<[u32; 2]> = normalised.iter().copied().collect();
    assert_eq!(set.len(), got.len(), "{what}: a pair came twice");
    assert_eq!(set, brute_self(nodes), "{what}: self pairs");
    got.len()
}

/// A `n × n` grid sheet over the unit square at z = 0, each vertex mapped by `f(u, v)`.
fn sheet(n: u32, f: impl Fn(f32, f32) -> Vec3) -> Mesh {
    let mut pos = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            pos.push(f(i as f32 / n as f32, j as f32 / n as f32));
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    let mut idx = Vec::new();
    for j in 0..n {
        for i in 0..n {
            idx.extend([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            idx.extend([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Mesh::new(pos, idx).unwrap()
}

/// A sheet folded onto itself at x = 0.5 and crumpled by random jitter of about a cell: many distant parts
/// of the sheet touch.
fn crumpled_sheet(seed: u64, n: u32) -> Mesh {
    let mut r = rng(seed);
    let jitter: Vec<Vec3> = (0..(n + 1) * (n + 1))
        .map(|_| rand_vec(&mut r, -1.5, 1.5) / n as f32)
        .collect();
    let m = sheet(n, |u, v| {
        Vec3::new((u - 0.5).abs(), v, 0.02 * (u * 25.0).sin())
    });
    Mesh::new(
        m.positions()
            .iter()
            .zip(&jitter)
            .map(|(p, j)| *p + *j)
            .collect::<Vec<_>>(),
        m.indices().to_vec(),
    )
    .unwrap()
}

/// Pairs of meshes in contact: two overlapping spheres, two crossing wavy sheets, two random soups.
fn scenes() -> Vec<(&'static str, Mesh, Mesh)> {
    let sphere = icosphere(3);
    let wavy = |u: f32, v: f32| Vec3::new(u, v, 0.1 * (u * 9.0).sin() * (v * 7.0).cos());
    let crossing = |u: f32, v: f32| Vec3::new(u, 0.5 + 0.1 * (u * 5.0).cos(), v - 0.5);
    vec![
        (
            "spheres",
            sphere.clone(),
            map_mesh(&sphere, |p| p * 0.8 + Vec3::new(0.9, 0.3, 0.1)),
        ),
        ("sheets", sheet(30, wavy), sheet(28, crossing)),
        ("soups", soup(1, 2000), soup(2, 2500)),
    ]
}

#[test]
fn identity_pairs_equal_brute_force() {
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    for (what, ma, mb) in scenes() {
        for (k, &build) in BUILDS.iter().enumerate() {
            let (a, b) = (tree(&ma, build), tree(&mb, BUILDS[(k + 1) % 4]));
            let what = format!("{what} {build:?}");
            let n = check_pairs(&mut gp, &g, &a, &b, &Affine3A::IDENTITY, &what);
            assert!(n > 50, "{what}: only {n} pairs");
        }
    }
}

#[test]
fn moved_pairs_are_conservative_and_tight() {
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    let skew = Affine3A::from_scale_rotation_translation(
        Vec3::new(1.3, 0.7, 1.1),
        Quat::from_euler(glam::EulerRot::XYZ, 0.4, -0.7, 1.1),
        Vec3::new(0.2, -0.1, 0.05),
    );
    for (what, ma, mb) in scenes() {
        for (k, &build) in BUILDS.iter().enumerate() {
            let (a, b) = (tree(&ma, build), tree(&mb, BUILDS[(k + 2) % 4]));
            let what = format!("{what} {build:?} moved");
            let n = check_pairs(&mut gp, &g, &a, &b, &skew, &what);
            assert!(n > 50, "{what}: only {n} pairs");
        }
    }
    // Far from the origin: tree a sits at 1e5, tree b at the origin, moved there by a rotation.
    let far = Vec3::new(1e5, -1e5, 5e4);
    let turn = Affine3A::from_rotation_translation(Quat::from_rotation_y(0.3), far);
    for (what, ma, mb) in scenes() {
        let ma = map_mesh(&ma, |p| p + far);
        for &build in &BUILDS[..2] {
            let (a, b) = (tree(&ma, build), tree(&mb, build));
            let what = format!("{what} {build:?} at 1e5");
            let n = check_pairs(&mut gp, &g, &a, &b, &turn, &what);
            assert!(n > 50, "{what}: only {n} pairs");
        }
    }
}

#[test]
fn self_pairs_equal_brute_force() {
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    let meshes = [
        ("crumpled sheet", crumpled_sheet(3, 40)),
        ("soup", soup(4, 2000)),
    ];
    for (what, m) in &meshes {
        for &build in &BUILDS {
            let nodes = tree(m, build);
            let n = check_self(&mut gp, &g, &nodes, &format!("{what} {build:?}"));
            assert!(
                n > 2 * leaves(&nodes).len(),
                "{what} {build:?}: only {n} pairs"
            );
        }
    }
}

#[test]
fn rounds_wider_than_a_dispatch() {
    let Some(g) = gpu() else { return };
    let m = crumpled_sheet(5, 30);
    let (a, b) = (tree(&m, BUILDS[0]), tree(&soup(9, 1500), BUILDS[1]));
    let moved = Affine3A::from_rotation_translation(Quat::from_rotation_z(0.3), Vec3::Y * 0.2);
    for groups in [1, 3] {
        let mut gp = GpuPairs::new(&g);
        gp.limit_workgroups(&g, groups);
        check_self(&mut gp, &g, &a, &format!("self, {groups} workgroups"));
        check_pairs(
            &mut gp,
            &g,
            &a,
            &b,
            &moved,
            &format!("moved, {groups} workgroups"),
        );
    }
}

#[test]
fn tiny_and_empty_trees() {
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    let tri = |k: f32| {
        [
            Vec3::new(k, 0.0, 0.0),
            Vec3::new(k + 1.0, 0.0, 0.0),
            Vec3::new(k, 1.0, 0.5),
        ]
    };
    let meshes: Vec<Mesh> = (0..4)
        .map(|n| {
            let pos: Vec<Vec3> = (0..n).flat_map(|k| tri(k as f32 * 0.5)).collect();
            Mesh::new(pos, (0..3 * n as u32).collect::<Vec<_>>()).unwrap()
        })
        .collect();
    let moved = Affine3A::from_rotation_translation(Quat::from_rotation_z(0.2), Vec3::X * 0.3);
    for (i, ma) in meshes.iter().enumerate() {
        for build in [BUILDS[0], BUILDS[1]] {
            let a = tree(ma, build);
            check_self(&mut gp, &g, &a, &format!("{i} triangles {build:?}"));
            for (j, mb) in meshes.iter().enumerate() {
                let b = tree(mb, build);
                for t in [Affine3A::IDENTITY, moved] {
                    let what = format!("{i} vs {j} triangles {build:?}");
                    let n = check_pairs(&mut gp, &g, &a, &b, &t, &what);
                    assert_eq!(n == 0, i == 0 || j == 0, "{what}: {n} pairs");
                }
            }
        }
    }
}

/// A transform that is not finite is the caller's error, reported as such; a flattening one is legal (the
/// moved tree is only ever mapped forwards).
#[test]
fn non_finite_transforms_are_invalid() {
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    let a = tree(&crumpled_sheet(3, 8), BUILDS[0]);
    for bad in [
        Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0)),
        Affine3A::from_scale(Vec3::new(1.0, f32::INFINITY, 1.0)),
    ] {
        let r = gp.leaf_pairs(&g, &a, Some((&a, &bad)));
        assert!(matches!(r, Err(Error::InvalidTransform(_))), "{r:?}");
    }
    let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    check_pairs(&mut gp, &g, &a, &a, &flat, "flattened b");
}

#[test]
fn overflow_grows_and_reruns() {
    let Some(g) = gpu() else { return };
    let (ma, mb) = (soup(5, 3000), soup(6, 3000));
    let (a, b) = (tree(&ma, BUILDS[0]), tree(&mb, BUILDS[0]));
    let mut small = GpuPairs::with_capacity(&g, 1, 1);
    let before = small.capacity();
    assert!(before.0 < 100 && before.1 < 100, "{before:?}");
    let n = check_pairs(&mut small, &g, &a, &b, &Affine3A::IDENTITY, "tiny capacity");
    let after = small.capacity();
    assert!(after.1 as usize >= n && after.0 > before.0, "{after:?}");
    // Self mode through the same grown buffers, then a larger query that overflows them again.
    check_self(&mut small, &g, &a, "tiny capacity, self");
    let big = tree(&soup(7, 6000), BUILDS[0]);
    check_pairs(&mut small, &g, &a, &big, &Affine3A::IDENTITY, "grown again");
    // The recording API reports an overflow and grows at the next record.
    let mut gp = GpuPairs::with_capacity(&g, 1, 1);
    let (ga, gb) = (gpu_tree(&g, &ma), gpu_tree(&g, &mb));
    let ta = ga.tree();
    let mut outcomes = Vec::new();
    loop {
        let mut enc = g.encoder();
        let r = gp
            .record(&g, &mut enc, ta, Some((gb.tree(), Affine3A::IDENTITY)))
            .unwrap();
        g.submit(enc);
        match r.wait(&g).unwrap() {
            PairsResult::Overflowed => outcomes.push(()),
            PairsResult::Done(pairs) => {
                let (na, nb) = (read_nodes(&g, &ga), read_nodes(&g, &gb));
                check_against_brute(&pairs, &na, &nb, &Affine3A::IDENTITY, "record");
                break;
            }
        }
        assert!(outcomes.len() < 20, "never fits");
    }
    assert!(!outcomes.is_empty(), "a capacity of one never overflowed");
}

/// A mesh's tree built on the GPU.
fn gpu_tree(g: &GpuContext, m: &Mesh) -> GpuMeshBvh {
    let mut bvh = GpuMeshBvh::new(g, m).unwrap();
    let mut enc = g.encoder();
    bvh.record_build(g, &mut enc);
    g.submit(enc);
    bvh
}

fn read_nodes(g: &GpuContext, bvh: &GpuMeshBvh) -> Vec<Node> {
    bvh.read_tree(g).unwrap().nodes().to_vec()
}

#[test]
fn gpu_built_and_uploaded_trees_in_one_submission() {
    let Some(g) = gpu() else { return };
    let (ma, mb) = (
        icosphere(3),
        map_mesh(&cube_sphere(12), |p| p * 0.9 + Vec3::X),
    );
    let skew = Affine3A::from_scale_rotation_translation(
        Vec3::new(0.9, 1.2, 1.0),
        Quat::from_rotation_x(0.5),
        Vec3::new(-0.2, 0.1, 0.0),
    );
    // Tree a built on the GPU (height unknown: the bound), tree b a CPU SAH tree uploaded (exact height).
    let cpu_b = MeshBvh::build(&mb, &BuildOptions::new(Builder::SAH).max_leaf_size(4)).unwrap();
    let ga = gpu_tree(&g, &ma);
    let gb = GpuMeshBvh::from_cpu(&g, &mb, &cpu_b).unwrap();
    assert!(gb.tree().height < ga.tree().height);
    let mut pair = GpuPairs::new(&g);
    let mut itself = GpuPairs::new(&g);
    let mut enc = g.encoder();
    let moved = pair
        .record(&g, &mut enc, ga.tree(), Some((gb.tree(), skew)))
        .unwrap();
    let own = itself.record(&g, &mut enc, ga.tree(), None).unwrap();
    g.submit(enc);
    let na = read_nodes(&g, &ga);
    let nb = cpu_b.bvh().nodes();
    let PairsResult::Done(moved) = moved.wait(&g).unwrap() else {
        panic!("overflowed")
    };
    assert!(moved.len() > 50, "{} pairs", moved.len());
    check_against_brute(&moved, &na, nb, &skew, "GPU-built a, uploaded b");
    let PairsResult::Done(own) = own.wait(&g).unwrap() else {
        panic!("overflowed")
    };
    let own: BTreeSet<[u32; 2]> = own.iter().map(|&[x, y]| [x.min(y), x.max(y)]).collect();
    assert_eq!(own, brute_self(&na), "GPU-built tree against itself");
}

#[test]
fn misuse_is_an_error() {
    let Some(g) = gpu() else { return };
    let m = soup(8, 500);
    let bvh = gpu_tree(&g, &m);
    let mut gp = GpuPairs::new(&g);
    // A stated height below the real one leaves work undone: an error, not a silent miss.
    let short = GpuTree {
        height: 2,
        ..bvh.tree()
    };
    let mut enc = g.encoder();
    let r = gp.record(&g, &mut enc, short, None).unwrap();
    g.submit(enc);
    assert!(r.wait(&g).is_err(), "a tree deeper than its height");
    // More nodes than the buffer holds.
    let long = GpuTree {
        count: bvh.node_count() * 3,
        ..bvh.tree()
    };
    assert!(gp.record(&g, &mut g.encoder(), long, None).is_err());
    // A tree not built yet is empty.
    let unbuilt = GpuMeshBvh::new(&g, &m).unwrap();
    let mut enc = g.encoder();
    let r = gp.record(&g, &mut enc, unbuilt.tree(), None).unwrap();
    g.submit(enc);
    assert_eq!(r.wait(&g).unwrap(), PairsResult::Done(Vec::new()));
}

/// The whole GPU path of a collision query — traversal on the GPU, exact tests on the CPU — gives the
/// contacts of the CPU query, bit for bit: for two meshes in one frame, moved apart by a skewing
/// transform, and for a mesh against itself.
#[test]
fn gpu_contacts_equal_cpu_contacts() {
    use kinetrace::collide::{PairQuery, Placed};
    let Some(g) = gpu() else { return };
    let mut gp = GpuPairs::new(&g);
    let mut q = PairQuery::new();
    let (mut cpu, mut via_gpu) = (Vec::new(), Vec::new());
    let skew = Affine3A::from_scale_rotation_translation(
        Vec3::new(1.3, 0.7, 1.1),
        Quat::from_euler(glam::EulerRot::XYZ, 0.4, -0.7, 1.1),
        Vec3::new(0.2, -0.1, 0.05),
    );
    let placed_a = Affine3A::from_translation(Vec3::new(3.0, -2.0, 1.0));
    for (what, ma, mb) in scenes() {
        for (k, &(builder, leaf)) in BUILDS.iter().enumerate() {
            let opts = |(b, l): (Builder, u32)| BuildOptions::new(b).max_leaf_size(l);
            let ta = MeshBvh::build(&ma, &opts((builder, leaf))).unwrap();
            let tb = MeshBvh::build(&mb, &opts(BUILDS[(k + 1) % 4])).unwrap();
            for (a_to_world, b_to_world) in [
                (Affine3A::IDENTITY, Affine3A::IDENTITY),
                (placed_a, placed_a * skew),
            ] {
                let (a, b) = (Placed::new(&ta, a_to_world), Placed::new(&tb, b_to_world));
                q.meshes(a, b, &mut cpu).unwrap();
                let b_to_a = a_to_world.inverse() * b_to_world;
                let pairs = gp
                    .leaf_pairs(&g, ta.bvh().nodes(), Some((tb.bvh().nodes(), &b_to_a)))
                    .unwrap();
                q.meshes_from_leaf_pairs(a, b, &pairs, &mut via_gpu)
                    .unwrap();
                assert!(!cpu.is_empty(), "{what}: no contacts");
                assert_eq!(via_gpu, cpu, "{what} {builder:?} leaf {leaf}");
            }
            let m = Placed::new(&ta, placed_a);
            q.itself(m, &mut cpu).unwrap();
            let pairs = gp.leaf_pairs(&g, ta.bvh().nodes(), None).unwrap();
            q.itself_from_leaf_pairs(m, &pairs, &mut via_gpu).unwrap();
            assert_eq!(via_gpu, cpu, "{what} {builder:?} leaf {leaf} self");
        }
    }
    // A pair that names no leaf is an error, not a panic.
    let t = MeshBvh::build(&icosphere(1), &BuildOptions::default()).unwrap();
    let p = Placed::new(&t, Affine3A::IDENTITY);
    assert!(
        q.meshes_from_leaf_pairs(p, p, &[[0, 9999]], &mut via_gpu)
            .is_err()
    );
}
