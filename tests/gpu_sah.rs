//! The GPU binned SAH builder against a CPU reference of the same algorithm written here (same 16-bit
//! grid, bins, integer costs, tie rules and stable partition), node for node; its trees validate and
//! answer closest-hit queries as brute force does. On lavapipe in CI (`KINETRACE_REQUIRE_GPU=1`); without
//! an adapter these tests skip and say so.
#![cfg(feature = "gpu")]

mod common;
use common::*;
use glam::Vec3;
use kinetrace::bvh::{BuildOptions, Builder, Bvh, LEAF_BIT};
use kinetrace::geometry::morton30;
use kinetrace::gpu::{
    CLUSTERED_HYBRID_LEVELS, FrameBuilder, GpuContext, GpuMeshBvh, GpuSahBuilder, GpuSahOptions,
    HYBRID_LEVELS, Maintained, MeshUpdate, ResidentMesh, SMALL_SPLIT_MAX, SWEEP_MAX,
};
use kinetrace::{Aabb, Mesh, MeshBvh, Ray};

const SIZES: [usize; 11] = [0, 1, 2, 3, 31, 32, 33, 64, 65, 1023, 1025];
/// The largest size run by default (well under 20 s on lavapipe); 2^20 + 7 is the ignored test below.
const LARGE: usize = (1 << 16) + 7;
const HUGE: usize = (1 << 20) + 7;

// ---- the CPU reference: src/gpu/build_sah.rs's algorithm, written independently ----

const BINS: u32 = 16;
const BALANCED: u32 = 36;

fn pow2_scale(e: f32) -> f32 {
    if e.is_nan() || e <= 0.0 {
        return 0.0;
    }
    let ex = ((e.to_bits() >> 23) & 0xff) as i32 - 127;
    let k = (15 - ex).clamp(-126, 127);
    f32::from_bits(((k + 127) as u32) << 23)
}

fn quantise(x: f32) -> u32 {
    x.clamp(0.0, 65535.0) as u32
}

struct Prims {
    centroid: Vec<[u32; 3]>,
    lo: Vec<[u32; 3]>,
    hi: Vec<[u32; 3]>,
}

fn quantised(m: &Mesh) -> Prims {
    let boxes: Vec<(Vec3, Vec3)> = (0..m.triangle_count())
        .map(|i| {
            let [a, b, c] = m.triangle(i);
            (a.min(b).min(c), a.max(b).max(c))
        })
        .collect();
    let cen: Vec<Vec3> = boxes.iter().map(|(l, h)| (*l + *h) * 0.5).collect();
    let fold = |it: &mut dyn Iterator<Item = Vec3>| {
        it.fold((Vec3::MAX, Vec3::MIN), |(l, h), p| (l.min(p), h.max(p)))
    };
    let (clo, chi) = fold(&mut cen.iter().copied());
    let (blo, _) = fold(&mut boxes.iter().map(|b| b.0));
    let (_, bhi) = fold(&mut boxes.iter().map(|b| b.1));
    let scale = |e: Vec3| Vec3::new(pow2_scale(e.x), pow2_scale(e.y), pow2_scale(e.z));
    // Centroids per axis (only their order and bins matter), boxes on one grid for all axes (their areas).
    let (cs, bs) = (
        scale(chi - clo),
        Vec3::splat(pow2_scale((bhi - blo).max_element())),
    );
    let q = |v: Vec3| [quantise(v.x), quantise(v.y), quantise(v.z)];
    Prims {
        centroid: cen.iter().map(|&c| q((c - clo) * cs)).collect(),
        lo: boxes
            .iter()
            .map(|b| q(((b.0 - blo) * bs).floor()))
            .collect(),
        hi: boxes.iter().map(|b| q(((b.1 - blo) * bs).ceil())).collect(),
    }
}

fn half_area(lo: [u32; 3], hi: [u32; 3]) -> u64 {
    let d = [0, 1, 2].map(|a| (hi[a] - lo[a]) as u64);
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// Builds the subtree of `ids` (slots `first..`) at node `pos` with descendants from `desc`: writes node
/// indices (leaves of one triangle) and reorders `ids`.
/// In a hybrid's top levels, nodes are split as LBVH splits them: `codes` (sorted, in slot order).
struct Hybrid<'a> {
    codes: &'a [u32],
    levels: u32,
}

/// Karras's split of sorted slots `first..first + m`: the left count.
fn radix_cut(codes: &[u32], first: u32, m: u32) -> u32 {
    let (lo, hi) = (first as usize, (first + m - 1) as usize);
    let x = codes[lo] ^ codes[hi];
    if x == 0 {
        let b = 31 - ((lo ^ hi) as u32).leading_zeros();
        return ((hi >> b << b) - lo) as u32;
    }
    let b = 31 - x.leading_zeros();
    (codes[lo..=hi].iter().position(|c| c >> b & 1 == 1).unwrap()) as u32
}

#[allow(clippy::too_many_arguments)]
fn reference_node(
    p: &Prims,
    hybrid: &Hybrid,
    ids: &mut [u32],
    first: u32,
    pos: u32,
    desc: u32,
    depth: u32,
    index: &mut [u32],
) {
    let m = ids.len() as u32;
    if m == 1 {
        index[pos as usize] = LEAF_BIT | 1 << 27 | first;
        return;
    }
    let recurse = |ids: &mut [u32], nl: u32, index: &mut [u32]| {
        index[pos as usize] = desc;
        let (li, ri) = ids.split_at_mut(nl as usize);
        reference_node(p, hybrid, li, first, desc, desc + 2, depth + 1, index);
        reference_node(
            p,
            hybrid,
            ri,
            first + nl,
            desc + 1,
            desc + 2 * nl,
            depth + 1,
            index,
        );
    };
    if depth < hybrid.levels {
        return recurse(ids, radix_cut(hybrid.codes, first, m), index);
    }
    if m <= SWEEP_MAX && depth < BALANCED {
        let nl = sweep(p, ids);
        return recurse(ids, nl, index);
    }
    let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
    for &t in ids.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(p.centroid[t as usize][a]);
            hi[a] = hi[a].max(p.centroid[t as usize][a]);
        }
    }
    let bin = |t: u32, a: usize| (p.centroid[t as usize][a] - lo[a]) * BINS / (hi[a] - lo[a] + 1);
    // Per axis and bin: count, box.
    let mut bins = [[(0u32, [u32::MAX; 3], [0u32; 3]); BINS as usize]; 3];
    for &t in ids.iter() {
        for (a, axis_bins) in bins.iter_mut().enumerate() {
            let b = &mut axis_bins[bin(t, a) as usize];
            b.0 += 1;
            for k in 0..3 {
                b.1[k] = b.1[k].min(p.lo[t as usize][k]);
                b.2[k] = b.2[k].max(p.hi[t as usize][k]);
            }
        }
    }
    // (cost, imbalance, candidate), the lowest wins.
    let mut best: Option<(u64, u32, u32, u32)> = None;
    for c in 0..45u32 {
        let (axis, cut) = ((c / 15) as usize, c % 15 + 1);
        let mut side = [(0u32, [u32::MAX; 3], [0u32; 3]); 2];
        for (b, &(count, blo, bhi)) in bins[axis].iter().enumerate() {
            if count == 0 {
                continue;
            }
            let s = &mut side[usize::from(b as u32 >= cut)];
            s.0 += count;
            for k in 0..3 {
                s.1[k] = s.1[k].min(blo[k]);
                s.2[k] = s.2[k].max(bhi[k]);
            }
        }
        let [(nl, llo, lhi), (nr, rlo, rhi)] = side;
        if nl == 0 || nr == 0 {
            continue;
        }
        let cost = half_area(llo, lhi) * nl as u64 + half_area(rlo, rhi) * nr as u64;
        let key = (cost, nl.abs_diff(nr), c, nl);
        if best.is_none_or(|b| (key.0, key.1, key.2) < (b.0, b.1, b.2)) {
            best = Some(key);
        }
    }
    let (left, nl): (Vec<bool>, u32) = match best {
        Some((_, _, c, nl)) if depth < BALANCED => {
            let (axis, cut) = ((c / 15) as usize, c % 15 + 1);
            (ids.iter().map(|&t| bin(t, axis) < cut).collect(), nl)
        }
        _ => ((0..m).map(|i| i < m / 2).collect(), m / 2),
    };
    // Stable partition: the left side's triangles first, each side in slot order.
    let (mut l, mut r) = (Vec::new(), Vec::new());
    for (&t, &goes_left) in ids.iter().zip(&left) {
        if goes_left { l.push(t) } else { r.push(t) }
    }
    for (slot, t) in ids.iter_mut().zip(l.into_iter().chain(r)) {
        *slot = t;
    }
    recurse(ids, nl, index);
}

/// The exact sweep of a node of at most `SWEEP_MAX` triangles: on each axis the triangles sorted by (quantised
/// centroid, slot), every cut's cost from the boxes of both sides; the cheapest wins, then the more balanced,
/// then the lower axis, then the fewer on the left. Partitions `ids` stably and returns the left count.
fn sweep(p: &Prims, ids: &mut [u32]) -> u32 {
    let m = ids.len();
    // (cost, imbalance, axis, N_L)
    let mut best = (u64::MAX, 0, 0, 0);
    let mut best_order = Vec::new();
    for a in 0..3 {
        let mut order: Vec<usize> = (0..m).collect();
        order.sort_by_key(|&i| (p.centroid[ids[i] as usize][a], i));
        for cut in 1..m {
            let union = |side: &[usize]| {
                side.iter()
                    .fold(([u32::MAX; 3], [0u32; 3]), |(lo, hi), &i| {
                        let t = ids[i] as usize;
                        (
                            [0, 1, 2].map(|k| lo[k].min(p.lo[t][k])),
                            [0, 1, 2].map(|k| hi[k].max(p.hi[t][k])),
                        )
                    })
            };
            let (l, r) = (union(&order[..cut]), union(&order[cut..]));
            let cost = half_area(l.0, l.1) * cut as u64 + half_area(r.0, r.1) * (m - cut) as u64;
            let key = (cost, cut.abs_diff(m - cut), a, cut);
            if key < best {
                best = key;
                best_order = order[..cut].to_vec();
            }
        }
    }
    let nl = best.3;
    let mut left = vec![false; m];
    for i in best_order {
        left[i] = true;
    }
    let (l, r): (Vec<u32>, Vec<u32>) = (
        ids.iter()
            .zip(&left)
            .filter(|x| *x.1)
            .map(|x| *x.0)
            .collect(),
        ids.iter()
            .zip(&left)
            .filter(|x| !*x.1)
            .map(|x| *x.0)
            .collect(),
    );
    for (slot, t) in ids.iter_mut().zip(l.into_iter().chain(r)) {
        *slot = t;
    }
    nl as u32
}

/// The reference tree with `lbvh_levels` LBVH levels on top: node indices and the triangle of every slot.
fn reference(m: &Mesh, lbvh_levels: u32) -> (Vec<u32>, Vec<u32>) {
    let n = m.triangle_count();
    if n == 0 {
        return (Vec::new(), Vec::new());
    }
    let p = quantised(m);
    // 30-bit Morton codes of the triangle-box centres in their bounds, stably sorted (ties by id).
    let centres: Vec<Vec3> = m.triangle_bounds().iter().map(|b| b.center()).collect();
    let cb = centres
        .iter()
        .fold(Aabb::EMPTY, |b, &c| b.union(&Aabb::new(c, c)));
    let mut keyed: Vec<(u32, u32)> = (0..n as u32)
        .map(|i| (morton30(centres[i as usize], &cb), i))
        .collect();
    keyed.sort_by_key(|&(k, _)| k);
    let codes: Vec<u32> = keyed.iter().map(|k| k.0).collect();
    let mut ids: Vec<u32> = if lbvh_levels > 0 {
        keyed.iter().map(|k| k.1).collect()
    } else {
        (0..n as u32).collect()
    };
    let hybrid = Hybrid {
        codes: &codes,
        levels: lbvh_levels,
    };
    let mut index = vec![0u32; 2 * n - 1];
    reference_node(&p, &hybrid, &mut ids, 0, 0, 1, 0, &mut index);
    (index, ids)
}

// ---- helpers ----

/// A GPU SAH build read back for CPU queries, its builder (for the counts), and its tree.
fn build(g: &GpuContext, m: &Mesh, options: GpuSahOptions) -> (MeshBvh, GpuSahBuilder, Bvh) {
    let mut bvh = GpuMeshBvh::new(g, m).unwrap();
    let sah = GpuSahBuilder::new(g, &bvh, options).unwrap();
    let mesh_bvh = sah.build_for_cpu(g, &mut bvh, m).unwrap();
    let tree = mesh_bvh.bvh().clone();
    (mesh_bvh, sah, tree)
}

/// Depth of the deepest leaf.
fn height(t: &Bvh) -> u32 {
    if t.nodes().is_empty() {
        return 0;
    }
    let mut stack = vec![(0usize, 0u32)];
    let mut h = 0;
    while let Some((i, d)) = stack.pop() {
        let n = &t.nodes()[i];
        h = h.max(d);
        if !n.is_leaf() {
            stack.extend([(n.left(), d + 1), (n.left() + 1, d + 1)]);
        }
    }
    h
}

/// The tree validates, equals the reference node for node (topology, slot order, and boxes recomputed
/// from the triangles), and a closest-hit query through it agrees with brute force.
fn check(g: &GpuContext, m: &Mesh, options: GpuSahOptions, rays: &[Ray], what: &str) -> Bvh {
    let (mesh_bvh, sah, tree) = build(g, m, options);
    assert_reference(m, options, &tree, what);
    for ray in rays {
        let hit = mesh_bvh.closest_hit(ray).map(|h| (h.primitive, h.t));
        assert_brute_hit(m, ray, hit, what);
    }
    let counts = sah.read_counts(g).unwrap();
    assert!(counts.levels <= height(&tree), "{what}: {counts:?}");
    tree
}

/// `tree` validates and equals the reference with `options`' LBVH levels node for node: topology, slot
/// order, and boxes recomputed from the triangles.
fn assert_reference(m: &Mesh, options: GpuSahOptions, tree: &Bvh, what: &str) {
    let bounds = m.triangle_bounds();
    tree.validate(Some(&bounds))
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    let (index, ids) = reference(m, options.lbvh_levels);
    let got: Vec<u32> = tree.nodes().iter().map(|n| n.index).collect();
    let diff = got.iter().zip(&index).position(|(a, b)| a != b);
    assert_eq!(diff, None, "{what}: first differing node");
    assert_eq!(tree.prim_indices(), &ids[..], "{what}: slot order");
    // Boxes: every node's box is the exact union of its triangles' boxes.
    let mut boxes = vec![None; tree.nodes().len()];
    for i in (0..tree.nodes().len()).rev() {
        let n = &tree.nodes()[i];
        let b = if n.is_leaf() {
            bounds[tree.prim_indices()[n.first()] as usize]
        } else {
            let (l, r): (Aabb, Aabb) = (boxes[n.left()].unwrap(), boxes[n.left() + 1].unwrap());
            l.union(&r)
        };
        assert_eq!(
            (n.min, n.max),
            (b.min.to_array(), b.max.to_array()),
            "{what}: box of node {i}"
        );
        boxes[i] = Some(b);
    }
}

fn random_rays(m: &Mesh, seed: u64, n: usize) -> Vec<Ray> {
    let b = m
        .triangle_bounds()
        .iter()
        .fold(Aabb::EMPTY, |a, b| a.union(b));
    let mut r = rng(seed);
    let (c, e) = (b.center(), b.extent().max_element().max(1e-3));
    (0..n)
        .map(|_| {
            let o = c + rand_dir(&mut r) * 2.0 * e;
            let target = c + (rand_vec(&mut r, -0.5, 0.5) * e);
            Ray::new(o, target - o)
        })
        .collect()
}

// ---- tests ----

#[test]
fn gpu_sah_equals_the_reference_at_every_size() {
    let Some(g) = gpu_or_skip() else { return };
    for n in SIZES.into_iter().chain([LARGE]) {
        let m = soup(n as u64 + 11, n);
        let rays = random_rays(&m, n as u64, if n > 5000 { 64 } else { 200 });
        for opt in [GpuSahOptions::SAH, GpuSahOptions::hybrid(HYBRID_LEVELS)] {
            let tree = check(&g, &m, opt, &rays, &format!("soup of {n}, {opt:?}"));
            assert_eq!(tree.nodes().len(), (2 * n).saturating_sub(1));
        }
    }
}

/// Meshes of different sizes built in one encoder and one submission, as the resident frame records
/// them, each with a different builder — binned SAH, the hybrid, LBVH — all reading their per-level
/// parameters from the device's one set of pass slots: every SAH and hybrid tree equals its reference
/// node for node and every LBVH tree the CPU's LBVH (same topology and boxes; the GPU's division may
/// round a ratio differently), so no mesh's build saw another's parameters or scratch.
#[test]
fn meshes_of_different_sizes_built_in_one_submission_equal_their_references() {
    let Some(g) = gpu_or_skip() else { return };
    let sizes = [1025usize, 33, 4099, 2, 700, 65, 9000, 1];
    let kinds = [
        Some(GpuSahOptions::SAH),
        Some(GpuSahOptions::hybrid(HYBRID_LEVELS)),
        None,
    ];
    let meshes: Vec<Mesh> = sizes.iter().map(|&n| soup(n as u64 * 3 + 1, n)).collect();
    let mut resident: Vec<ResidentMesh> = meshes
        .iter()
        .map(|m| ResidentMesh::new(&g, m, None).unwrap())
        .collect();
    // Three frames: each rebuilds every mesh (its positions uploaded again) with the next builder, over
    // the trees of the frame before.
    for frame in 0..3 {
        let mut enc = g.encoder();
        for (i, (mesh, m)) in resident.iter_mut().zip(&meshes).enumerate() {
            let builder = match kinds[(i + frame) % kinds.len()] {
                Some(o) => FrameBuilder::Sah(o),
                None => FrameBuilder::Lbvh,
            };
            let update = MeshUpdate::Positions(m.positions());
            let done = mesh
                .record(&g, &mut enc, update, |_, _| Some(builder))
                .unwrap();
            assert_eq!(done, Maintained::Rebuilt(builder));
        }
        g.submit(enc);
        for (i, (mesh, m)) in resident.iter().zip(&meshes).enumerate() {
            let what = format!("frame {frame}, mesh {i} of {}", sizes[i]);
            let tree = mesh.bvh().read_tree(&g).unwrap();
            match kinds[(i + frame) % kinds.len()] {
                Some(o) => assert_reference(m, o, &tree, &format!("{what}, {o:?}")),
                None => {
                    tree.validate(Some(&m.triangle_bounds()))
                        .unwrap_or_else(|e| panic!("{what}, LBVH: {e}"));
                    // LBVH's own check against the CPU is tests/gpu.rs; here, the same mesh built
                    // alone, in a submission of its own.
                    let mut alone = GpuMeshBvh::new(&g, m).unwrap();
                    let mut enc = g.encoder();
                    alone.record_build(&g, &mut enc);
                    g.submit(enc);
                    let alone = alone.read_tree(&g).unwrap();
                    assert_eq!(tree.nodes(), alone.nodes(), "{what}, LBVH");
                    assert_eq!(tree.prim_indices(), alone.prim_indices(), "{what}, LBVH");
                }
            }
        }
    }
}

#[test]
#[ignore = "2^20 + 7 triangles: about 23 s on lavapipe on the loaded 2-core VM (passes)"]
fn gpu_sah_equals_the_reference_at_a_million() {
    let Some(g) = gpu_or_skip() else { return };
    let m = soup(3, HUGE);
    check(
        &g,
        &m,
        GpuSahOptions::SAH,
        &random_rays(&m, 3, 32),
        "soup of 2^20 + 7",
    );
}

#[test]
fn gpu_sah_on_extreme_scenes() {
    let Some(g) = gpu_or_skip() else { return };
    let same = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], [0u32, 1, 2].repeat(500)).unwrap();
    let both = [
        GpuSahOptions::SAH,
        GpuSahOptions::hybrid(HYBRID_LEVELS),
        GpuSahOptions::hybrid(2),
    ];
    let check_all = |m: &Mesh, rays: &[Ray], what: &str| {
        for opt in both {
            check(&g, m, opt, rays, &format!("{what}, {opt:?}"));
        }
    };
    check_all(&same, &random_rays(&same, 1, 100), "identical triangles");
    let far = map_mesh(&icosphere(2), |p| p * 1e3 + Vec3::new(1e7, -1e7, 5e6));
    check_all(&far, &random_rays(&far, 2, 200), "1e7 offset");
    let teapot = teapot_in_stadium(2);
    let mut rays = random_rays(&teapot, 3, 100);
    rays.extend((0..100).map(|i| {
        Ray::new(
            Vec3::splat(0.25) + Vec3::new(0.0, 0.0, 3e-6),
            Vec3::new((i as f32).sin(), (i as f32).cos(), -3.0),
        )
    }));
    check_all(&teapot, &rays, "teapot in a stadium");
    let flat = kinetrace::scenes::folded_sheet(24, 0.0);
    check_all(&flat, &random_rays(&flat, 4, 200), "folded sheet");
    let cube = map_mesh(&cube_sphere(1), |p| p.signum());
    check_all(&cube, &random_rays(&cube, 5, 200), "axis-aligned cube");
}

#[test]
fn small_split_kernel_makes_the_same_tree() {
    let Some(g) = gpu_or_skip() else { return };
    for n in [2, 31, 32, 33, 64, 65, 1025, 5000] {
        let m = soup(n as u64 * 3, n);
        let (_, on_b, on) = build(&g, &m, GpuSahOptions::SAH);
        let (_, off_b, off) = build(&g, &m, GpuSahOptions::SAH.small_split(false));
        assert_eq!(on.nodes(), off.nodes(), "n = {n}");
        assert_eq!(on.prim_indices(), off.prim_indices(), "n = {n}");
        let (c_on, c_off) = (
            on_b.read_counts(&g).unwrap(),
            off_b.read_counts(&g).unwrap(),
        );
        // Without the kernel every node of two or more triangles is queued, so the levels are the height.
        assert_eq!(c_off.levels, height(&off), "n = {n}");
        assert_eq!(c_off.small_subtrees, 0);
        assert!(c_on.levels <= c_off.levels, "n = {n}: {c_on:?} {c_off:?}");
    }
}

#[test]
fn dispatches_grow_with_depth_not_size() {
    let Some(g) = gpu_or_skip() else { return };
    let mut last: Option<(u32, usize)> = None;
    for n in [1025usize, 4096, 16384, 65536] {
        let m = soup(n as u64, n);
        let (_, sah, tree) = build(&g, &m, GpuSahOptions::SAH);
        let c = sah.read_counts(&g).unwrap();
        assert_eq!(c.submissions, 1);
        // Recorded dispatches: one more round of about ten per doubling (the depth bound 36 + log2 n)…
        if let Some((rec, prev)) = last {
            let doublings = (n / prev).ilog2() + 1;
            assert!(
                c.dispatches_recorded <= rec + 12 * doublings,
                "n = {n}: {} after {rec}",
                c.dispatches_recorded
            );
        }
        // …and the run ones bounded by the tree's height, whatever the size.
        let h = height(&tree);
        assert!(
            c.dispatches_run <= 150 + 10 * h,
            "n = {n}: {c:?}, height {h}"
        );
        last = Some((c.dispatches_recorded, n));
    }
}

#[test]
fn gpu_sah_cost_against_cpu_binned_sah() {
    let Some(g) = gpu_or_skip() else { return };
    for (name, m) in [
        ("soup", soup(9, 20_000)),
        ("sphere", kinetrace::scenes::icosphere(5)),
        ("torus", kinetrace::scenes::bumpy_torus(20_000)),
    ] {
        let (_, _, tree) = build(&g, &m, GpuSahOptions::SAH);
        let cpu = Bvh::build(&m.triangle_bounds(), &BuildOptions::new(Builder::SAH)).unwrap();
        let ratio = tree.sah_cost() / cpu.sah_cost();
        let (_, _, hybrid) = build(&g, &m, GpuSahOptions::hybrid(HYBRID_LEVELS));
        let hybrid_ratio = hybrid.sah_cost() / cpu.sah_cost();
        eprintln!(
            "{name}: SAH cost / CPU binned SAH: GPU SAH {ratio:.3}, GPU hybrid {hybrid_ratio:.3}"
        );
        assert!(hybrid_ratio <= 1.15, "{name}: hybrid {hybrid_ratio}");
        // Issue 14's target (the thesis's 91–101% of full SAH). Measured 0.998–1.000 on these three since
        // box areas are taken on one grid for all axes (per-axis grids had weighted the torus's thin axis
        // 4×: 1.104) and nodes of ≤ 64 triangles are swept exactly.
        assert!(ratio <= 1.10, "{name}: {ratio}");
    }
}

#[test]
fn gpu_sah_trees_are_traced_and_refitted_on_the_gpu() {
    let Some(g) = gpu_or_skip() else { return };
    let m = kinetrace::scenes::bumpy_torus(3000);
    let moved = map_mesh(&m, |p| p * 1.5 + Vec3::new(0.3 * p.y, 0.0, 0.1));
    for opt in [GpuSahOptions::SAH, GpuSahOptions::hybrid(HYBRID_LEVELS)] {
        let mut bvh = GpuMeshBvh::new(&g, &m).unwrap();
        let sah = GpuSahBuilder::new(&g, &bvh, opt).unwrap();
        sah.build_for_cpu(&g, &mut bvh, &m).unwrap();
        let mut gr = kinetrace::gpu::GpuRays::new(&g);
        // Traced on the GPU as built, then after a GPU refit to moved vertices.
        for mesh in [&m, &moved] {
            if std::ptr::eq(mesh, &moved) {
                bvh.upload_positions(&g, moved.positions()).unwrap();
                let mut enc = g.encoder();
                bvh.record_refit(&g, &mut enc).unwrap();
                g.submit(enc);
            }
            let rays = random_rays(mesh, 21, 300);
            let hits = gr
                .run(&g, &bvh, &rays, kinetrace::gpu::Query::Closest)
                .unwrap();
            for (ray, h) in rays.iter().zip(&hits) {
                assert_brute_hit(
                    mesh,
                    ray,
                    h.primitive().map(|p| (p, h.t)),
                    &format!("{opt:?}"),
                );
            }
        }
    }
}

#[test]
fn clustered_meshes_get_fewer_lbvh_levels() {
    // The planner's mapping: a clustered mesh's hybrid keeps at most CLUSTERED_HYBRID_LEVELS LBVH levels.
    let hybrid6 = Builder::hybrid(6);
    assert_eq!(
        GpuSahOptions::for_builder(hybrid6, false),
        Some(Some(GpuSahOptions::hybrid(6)))
    );
    assert_eq!(
        GpuSahOptions::for_builder(hybrid6, true),
        Some(Some(GpuSahOptions::hybrid(CLUSTERED_HYBRID_LEVELS)))
    );
    assert_eq!(
        GpuSahOptions::for_builder(Builder::Sah { bins: 8 }, false),
        None
    );
}

#[test]
fn small_meshes_record_no_queue_levels() {
    let Some(g) = gpu_or_skip() else { return };
    // With the small-split kernel a mesh of at most SMALL_SPLIT_MAX triangles is one workgroup's work: no
    // queue rounds.
    let n = SMALL_SPLIT_MAX as usize;
    let (_, small, _) = build(&g, &soup(1, n), GpuSahOptions::SAH);
    let (_, big, _) = build(&g, &soup(1, n + 1), GpuSahOptions::SAH);
    let (s, b) = (small.dispatches_recorded(), big.dispatches_recorded());
    assert!(s + 30 * 10 <= b, "{n} triangles: {s}, {}: {b}", n + 1);
}
