//! Peer BVH crates measured on the same triangles and rays as kinetrace.
//!
//! Everything here takes plain data (positions, triangle indices, rays) and returns plain
//! measurements, so the caller can print them next to its own numbers. Rays are traced
//! single-threaded in a plain loop: the comparison is per-thread traversal speed.
//!
//! Peers:
//! - [`obvhs`] 0.4: PLOC binary BVH (`fastest_build` and `medium_build` presets) traced with
//!   `Bvh2::ray_traverse` / `Bvh2::ray_traverse_miss`, and the compressed wide BVH8 built from the
//!   medium preset traced with `CwBvh::ray_traverse` / `CwBvh::ray_traverse_miss`.
//! - [`bvh`] 0.13: `Bvh::build` / `build_par` (binned SAH, one triangle per leaf) traced with
//!   `traverse_iterator` and with `nearest_traverse_iterator`, testing candidates with a
//!   Möller–Trumbore written here.

use std::time::Duration;

use crate::record::best_of;

use bvh::aabb::{Aabb as BvhAabb, Bounded};
use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
use bvh::bvh::{Bvh, BvhNode};
use bvh::ray::Ray as BvhRay;
use glam::{Vec3, Vec3A};
use nalgebra::{Point3, Vector3};
use obvhs::BvhBuildParams;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray as ObvhsRay, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle as ObvhsTriangle;

/// One ray of a benchmark batch.
#[derive(Clone, Copy)]
pub struct BenchRay {
    /// Ray origin.
    pub origin: Vec3,
    /// Normalised direction.
    pub dir: Vec3,
    /// Far end of the ray interval; the near end is always 0.
    pub tmax: f32,
}

/// What was measured for one peer configuration (one builder + one traversal).
pub struct PeerResult {
    /// Peer and configuration, e.g. `"obvhs ploc-medium bvh2"` or `"bvh crate sah"`.
    pub name: &'static str,
    /// Wall seconds of the best of `reps` builds, including the peer's own preprocessing of the
    /// input (its triangle / shape arrays, and for obvhs the triangle reorder it needs to trace
    /// without an index indirection).
    pub build_s: f64,
    /// SAH cost of the peer's binary tree, `Σ_inner SA(n)/SA(root)·C_TRAV +
    /// Σ_leaf SA(l)/SA(root)·N_l·C_ISECT` with both costs 1 and `SA = 2(dx·dy + dy·dz + dz·dx)`
    /// in f64; `None` where the peer has no binary tree to measure (CWBVH).
    pub sah_cost: Option<f64>,
    /// Wall seconds to trace every ray closest-hit, single thread, best of `reps`; `None` where
    /// this entry only measures a build.
    pub closest_s: Option<f64>,
    /// Wall seconds to trace every ray any-hit (occlusion, stop at the first hit in
    /// `[0, tmax]`), single thread, best of `reps`; `None` where not measured.
    pub any_s: Option<f64>,
    /// Closest hit per ray, as (triangle index in the original `indices.chunks(3)` order, t),
    /// for cross-checking against ours; `None` where closest-hit was not traced.
    pub closest_hits: Option<Vec<Option<(u32, f32)>>>,
}

/// Traversal cost of an inner node in the SAH formula.
const C_TRAV: f64 = 1.0;
/// Cost of one triangle test in the SAH formula.
const C_ISECT: f64 = 1.0;

/// Surface area `2(dx·dy + dy·dz + dz·dx)` of a box, in f64.
fn surface_area(min: [f32; 3], max: [f32; 3]) -> f64 {
    let d = [
        f64::from(max[0]) - f64::from(min[0]),
        f64::from(max[1]) - f64::from(min[1]),
        f64::from(max[2]) - f64::from(min[2]),
    ];
    2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
}

/// SAH cost of a binary tree, from the surface areas of its nodes:
/// `Σ_inner SA(n)/SA(root)·C_TRAV + Σ_leaf SA(l)/SA(root)·N_l·C_ISECT`.
///
/// `nodes` yields `(surface area, None)` for an inner node and `(surface area, Some(N))` for a
/// leaf holding N triangles; the first item must be the root. `None` when the root's area is 0.
fn sah_cost(mut nodes: impl Iterator<Item = (f64, Option<u32>)>) -> Option<f64> {
    let (root_sa, root_leaf) = nodes.next()?;
    if root_sa.is_nan() || root_sa <= 0.0 {
        return None;
    }
    let term = |sa: f64, leaf: Option<u32>| match leaf {
        None => sa / root_sa * C_TRAV,
        Some(n) => sa / root_sa * f64::from(n) * C_ISECT,
    };
    Some(term(root_sa, root_leaf) + nodes.map(|(sa, leaf)| term(sa, leaf)).sum::<f64>())
}

/// Möller–Trumbore without backface culling: the hit distance in `[0, tmax]`, if any.
#[inline]
fn ray_triangle(origin: Vec3, dir: Vec3, tmax: f32, v: &[Vec3; 3]) -> Option<f32> {
    let e1 = v[1] - v[0];
    let e2 = v[2] - v[0];
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = origin - v[0];
    let u = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let w = dir.dot(q) * inv_det;
    if w < 0.0 || u + w > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv_det;
    (t >= 0.0 && t <= tmax).then_some(t)
}

/// Corner positions of one triangle (three vertex indices).
fn corners(positions: &[Vec3], tri: &[u32]) -> [Vec3; 3] {
    [
        positions[tri[0] as usize],
        positions[tri[1] as usize],
        positions[tri[2] as usize],
    ]
}

// ---------------------------------------------------------------------------------------------
// obvhs
// ---------------------------------------------------------------------------------------------

/// An obvhs BVH2 or CWBVH plus its triangles reordered to its primitive order, as obvhs's own
/// examples trace them (`bvh_tris[id]` instead of `tris[primitive_indices[id]]`).
struct ObvhsScene<B> {
    bvh: B,
    tris: Vec<RtTriangle>,
}

/// obvhs's triangle array from our mesh.
fn obvhs_triangles(positions: &[Vec3], indices: &[u32]) -> Vec<ObvhsTriangle> {
    indices
        .chunks_exact(3)
        .map(|tri| {
            let [v0, v1, v2] = corners(positions, tri).map(Vec3A::from);
            ObvhsTriangle { v0, v1, v2 }
        })
        .collect()
}

/// Reorders `tris` into obvhs's primitive order, in its ray-tracing triangle layout.
fn obvhs_reorder(tris: &[ObvhsTriangle], primitive_indices: &[u32]) -> Vec<RtTriangle> {
    primitive_indices
        .iter()
        .map(|&i| RtTriangle::from(&tris[i as usize]))
        .collect()
}

/// obvhs's ray for `r`. Adding `+0.0` turns `-0.0` direction components into `+0.0` and leaves
/// every other value as it is: obvhs 0.4's CWBVH node test picks slab sides by `dir < 0.0` but
/// inverts `-0.0` to `-1/ε`, so it misses every hit of a ray with a `-0.0` component (e.g.
/// `-Vec3::Y`, whose x and z are `-0.0`).
fn obvhs_ray(r: &BenchRay) -> ObvhsRay {
    let dir = Vec3A::from(r.dir) + Vec3A::ZERO;
    ObvhsRay::new(Vec3A::from(r.origin), dir, 0.0, r.tmax)
}

/// SAH cost of an obvhs BVH2 (children of inner node `n` are `nodes[n.first_index]` and
/// `nodes[n.first_index + 1]`; a leaf holds `prim_count` primitives).
fn obvhs_bvh2_sah(bvh: &Bvh2) -> Option<f64> {
    if bvh.nodes.is_empty() {
        return None;
    }
    let mut stack = vec![0usize];
    sah_cost(std::iter::from_fn(|| {
        let node = &bvh.nodes[stack.pop()?];
        let aabb = node.aabb();
        let sa = surface_area(aabb.min.to_array(), aabb.max.to_array());
        if node.is_leaf() {
            Some((sa, Some(node.prim_count)))
        } else {
            stack.push(node.first_index as usize);
            stack.push(node.first_index as usize + 1);
            Some((sa, None))
        }
    }))
}

/// Traces every ray closest-hit through an obvhs BVH2, mapping hits to original triangles.
fn obvhs_bvh2_closest(scene: &ObvhsScene<Bvh2>, rays: &[BenchRay]) -> Vec<Option<(u32, f32)>> {
    let ObvhsScene { bvh, tris } = scene;
    rays.iter()
        .map(|r| {
            let mut hit = RayHit::none();
            bvh.ray_traverse(obvhs_ray(r), &mut hit, |ray, id| tris[id].intersect(ray))
                .then(|| (bvh.primitive_indices[hit.primitive_id as usize], hit.t))
        })
        .collect()
}

/// Traces every ray any-hit through an obvhs BVH2; returns the number of occluded rays.
fn obvhs_bvh2_any(scene: &ObvhsScene<Bvh2>, rays: &[BenchRay]) -> usize {
    let ObvhsScene { bvh, tris } = scene;
    rays.iter()
        .filter(|r| !bvh.ray_traverse_miss(obvhs_ray(r), |ray, id| tris[id].intersect(ray)))
        .count()
}

/// Builds and traces one obvhs BVH2 preset.
fn measure_obvhs_bvh2(
    name: &'static str,
    params: BvhBuildParams,
    positions: &[Vec3],
    indices: &[u32],
    rays: &[BenchRay],
    reps: usize,
) -> PeerResult {
    let (build_s, scene) = best_of(reps, || {
        let tris = obvhs_triangles(positions, indices);
        let bvh = build_bvh2_from_tris(&tris, params, &mut Duration::default());
        let tris = obvhs_reorder(&tris, &bvh.primitive_indices);
        ObvhsScene { bvh, tris }
    });
    let (closest_s, hits) = best_of(reps, || obvhs_bvh2_closest(&scene, rays));
    let (any_s, _) = best_of(reps, || obvhs_bvh2_any(&scene, rays));
    PeerResult {
        name,
        build_s,
        sah_cost: obvhs_bvh2_sah(&scene.bvh),
        closest_s: Some(closest_s),
        any_s: Some(any_s),
        closest_hits: Some(hits),
    }
}

/// Measures obvhs 0.4 on the mesh (`indices` holds three vertex indices per triangle) and rays:
///
/// - `"obvhs ploc-fastest bvh2"`: `build_bvh2_from_tris` with `BvhBuildParams::fastest_build()`
///   (PLOC search distance 1, no reinsertion, one triangle per leaf), traced with
///   `Bvh2::ray_traverse` (closest) and `Bvh2::ray_traverse_miss` (any-hit);
/// - `"obvhs ploc-medium bvh2"`: the same with `BvhBuildParams::medium_build()` (search distance
///   14, reinsertion, leaves collapsed by SAH up to 8 triangles);
/// - `"obvhs cwbvh (medium)"`: `build_cwbvh_from_tris` with the medium preset, traced with
///   `CwBvh::ray_traverse` and `CwBvh::ray_traverse_miss`; no SAH cost (8-wide tree).
///
/// Triangles are tested with obvhs's `RtTriangle::intersect`, reordered to the BVH's primitive
/// order as obvhs's examples do; that reorder is part of `build_s`.
///
/// `threads_all` asks for multi-threaded builds. obvhs only has them behind its `parallel`
/// cargo feature, which this crate does not enable, so its builders always run on one thread
/// here; with `threads_all` set a note saying so goes to stderr.
pub fn measure_obvhs(
    positions: &[Vec3],
    indices: &[u32],
    rays: &[BenchRay],
    reps: usize,
    threads_all: bool,
) -> Vec<PeerResult> {
    if threads_all {
        eprintln!(
            "note: obvhs is built without its `parallel` feature; its builds below use one thread"
        );
    }
    let mut results = vec![
        measure_obvhs_bvh2(
            "obvhs ploc-fastest bvh2",
            BvhBuildParams::fastest_build(),
            positions,
            indices,
            rays,
            reps,
        ),
        measure_obvhs_bvh2(
            "obvhs ploc-medium bvh2",
            BvhBuildParams::medium_build(),
            positions,
            indices,
            rays,
            reps,
        ),
    ];

    let (build_s, scene) = best_of(reps, || {
        let tris = obvhs_triangles(positions, indices);
        let bvh = build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let tris = obvhs_reorder(&tris, &bvh.primitive_indices);
        ObvhsScene { bvh, tris }
    });
    let ObvhsScene { bvh, tris } = &scene;
    let (closest_s, hits) = best_of(reps, || {
        rays.iter()
            .map(|r| {
                let mut hit = RayHit::none();
                bvh.ray_traverse(obvhs_ray(r), &mut hit, |ray, id| tris[id].intersect(ray))
                    .then(|| (bvh.primitive_indices[hit.primitive_id as usize], hit.t))
            })
            .collect::<Vec<_>>()
    });
    let (any_s, _) = best_of(reps, || {
        rays.iter()
            .filter(|r| !bvh.ray_traverse_miss(obvhs_ray(r), |ray, id| tris[id].intersect(ray)))
            .count()
    });
    results.push(PeerResult {
        name: "obvhs cwbvh (medium)",
        build_s,
        sah_cost: None,
        closest_s: Some(closest_s),
        any_s: Some(any_s),
        closest_hits: Some(hits),
    });
    results
}

// ---------------------------------------------------------------------------------------------
// bvh crate
// ---------------------------------------------------------------------------------------------

/// A triangle as a `bvh` crate shape: its corners, cached box, original index and the BVH node
/// the crate assigns it.
struct BvhTri {
    corners: [Vec3; 3],
    aabb: BvhAabb<f32, 3>,
    index: u32,
    node_index: usize,
}

impl Bounded<f32, 3> for BvhTri {
    fn aabb(&self) -> BvhAabb<f32, 3> {
        self.aabb
    }
}

impl BHShape<f32, 3> for BvhTri {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node_index = index;
    }

    fn bh_node_index(&self) -> usize {
        self.node_index
    }
}

fn point3(v: Vec3) -> Point3<f32> {
    Point3::new(v.x, v.y, v.z)
}

/// The `bvh` crate's shape array from our mesh.
fn bvh_shapes(positions: &[Vec3], indices: &[u32]) -> Vec<BvhTri> {
    (0u32..)
        .zip(indices.chunks_exact(3))
        .map(|(index, tri)| {
            let c = corners(positions, tri);
            let min = c[0].min(c[1]).min(c[2]);
            let max = c[0].max(c[1]).max(c[2]);
            BvhTri {
                corners: c,
                aabb: BvhAabb::with_bounds(point3(min), point3(max)),
                index,
                node_index: 0,
            }
        })
        .collect()
}

fn bvh_ray(r: &BenchRay) -> BvhRay<f32, 3> {
    BvhRay::new(point3(r.origin), Vector3::new(r.dir.x, r.dir.y, r.dir.z))
}

fn bvh_box_sa(aabb: &BvhAabb<f32, 3>) -> f64 {
    surface_area(
        [aabb.min.x, aabb.min.y, aabb.min.z],
        [aabb.max.x, aabb.max.y, aabb.max.z],
    )
}

/// SAH cost of a `bvh` crate tree (root `nodes[0]`; inner nodes hold their children's boxes;
/// every leaf holds one shape).
fn bvh_crate_sah(bvh: &Bvh<f32, 3>, shapes: &[BvhTri]) -> Option<f64> {
    let root_box = match bvh.nodes.first()? {
        BvhNode::Leaf { shape_index, .. } => shapes[*shape_index].aabb,
        BvhNode::Node {
            child_l_aabb,
            child_r_aabb,
            ..
        } => child_l_aabb.join(child_r_aabb),
    };
    let mut stack = vec![(0usize, root_box)];
    sah_cost(std::iter::from_fn(|| {
        let (index, aabb) = stack.pop()?;
        let sa = bvh_box_sa(&aabb);
        match &bvh.nodes[index] {
            BvhNode::Leaf { .. } => Some((sa, Some(1))),
            BvhNode::Node {
                child_l_index,
                child_l_aabb,
                child_r_index,
                child_r_aabb,
                ..
            } => {
                stack.push((*child_l_index, *child_l_aabb));
                stack.push((*child_r_index, *child_r_aabb));
                Some((sa, None))
            }
        }
    }))
}

/// Stack slots `Bvh::traverse_iterator` has (a fixed `[usize; 32]`); it needs one per node on the
/// deepest root-to-leaf path and panics on deeper trees.
const BVH_ITER_STACK: usize = 32;

/// Nodes on the longest root-to-leaf path of a `bvh` crate tree.
fn bvh_crate_max_path(bvh: &Bvh<f32, 3>) -> usize {
    let mut stack = vec![(0usize, 1usize)];
    let mut max = 0;
    while let Some((index, path)) = stack.pop() {
        max = max.max(path);
        if let Some(BvhNode::Node {
            child_l_index,
            child_r_index,
            ..
        }) = bvh.nodes.get(index)
        {
            stack.push((*child_l_index, path + 1));
            stack.push((*child_r_index, path + 1));
        }
    }
    max
}

/// Measures the `bvh` crate 0.13 (`bvh::bvh::Bvh<f32, 3>`, binned SAH, one triangle per leaf)
/// on the mesh (`indices` holds three vertex indices per triangle) and rays:
///
/// - `"bvh crate sah"`: `Bvh::build` (one thread); closest-hit and any-hit both walk
///   `Bvh::traverse_iterator` (allocation-free stack traversal; the crate's rays have no `tmax`
///   so it cannot prune with the nearest hit so far) and test every candidate with the
///   Möller–Trumbore here, keeping the nearest / stopping at the first hit. That iterator has a
///   fixed 32-slot stack and panics on deeper trees; for those, traversal fields stay `None` and
///   a note goes to stderr;
/// - `"bvh crate sah (nearest_traverse_iterator)"`: the same tree, closest-hit via
///   `Bvh::nearest_traverse_iterator` (candidates by increasing box entry distance, from a
///   heap), stopping once the next candidate's box starts beyond the nearest hit; `build_s`
///   and `sah_cost` repeat the first entry's, `any_s` is `None`;
/// - `"bvh crate sah (build_par)"`: `BoundingHierarchy::build_par` (rayon, all threads of the
///   global pool); build time and SAH cost only, as the tree equals `Bvh::build`'s.
///
/// Shape-array creation (corners and boxes in nalgebra types) is part of `build_s`.
pub fn measure_bvh_crate(
    positions: &[Vec3],
    indices: &[u32],
    rays: &[BenchRay],
    reps: usize,
) -> Vec<PeerResult> {
    let (build_s, (bvh, shapes)) = best_of(reps, || {
        let mut shapes = bvh_shapes(positions, indices);
        let bvh = Bvh::build(&mut shapes);
        (bvh, shapes)
    });
    let sah = bvh_crate_sah(&bvh, &shapes);

    let iterator_fits = bvh_crate_max_path(&bvh) <= BVH_ITER_STACK;
    if !iterator_fits {
        eprintln!(
            "note: bvh crate tree is deeper than traverse_iterator's {BVH_ITER_STACK}-slot stack; \
             not traced with it"
        );
    }
    let closest = iterator_fits.then(|| {
        best_of(reps, || {
            rays.iter()
                .map(|r| {
                    let ray = bvh_ray(r);
                    let mut best: Option<(u32, f32)> = None;
                    for tri in bvh.traverse_iterator(&ray, &shapes) {
                        let tmax = best.map_or(r.tmax, |(_, t)| t);
                        if let Some(t) = ray_triangle(r.origin, r.dir, tmax, &tri.corners)
                            && best.is_none_or(|(_, bt)| t < bt)
                        {
                            best = Some((tri.index, t));
                        }
                    }
                    best
                })
                .collect::<Vec<_>>()
        })
    });
    let any_s = iterator_fits.then(|| {
        best_of(reps, || {
            rays.iter()
                .filter(|r| {
                    let ray = bvh_ray(r);
                    bvh.traverse_iterator(&ray, &shapes)
                        .any(|tri| ray_triangle(r.origin, r.dir, r.tmax, &tri.corners).is_some())
                })
                .count()
        })
        .0
    });
    let (closest_s, hits) = closest.unzip();

    let (nearest_s, nearest_hits) = best_of(reps, || {
        rays.iter()
            .map(|r| {
                let ray = bvh_ray(r);
                let mut best: Option<(u32, f32)> = None;
                for tri in bvh.nearest_traverse_iterator(&ray, &shapes) {
                    let tmax = best.map_or(r.tmax, |(_, t)| t);
                    // Candidates come by increasing box entry distance: once one starts beyond
                    // the nearest hit (or tmax), so do all the rest.
                    if let Some((entry, _)) = ray.intersection_slice_for_aabb(&tri.aabb)
                        && entry > tmax
                    {
                        break;
                    }
                    if let Some(t) = ray_triangle(r.origin, r.dir, tmax, &tri.corners)
                        && best.is_none_or(|(_, bt)| t < bt)
                    {
                        best = Some((tri.index, t));
                    }
                }
                best
            })
            .collect::<Vec<_>>()
    });

    let (par_build_s, (par_bvh, par_shapes)) = best_of(reps, || {
        let mut shapes = bvh_shapes(positions, indices);
        let bvh = Bvh::<f32, 3>::build_par(&mut shapes);
        (bvh, shapes)
    });

    vec![
        PeerResult {
            name: "bvh crate sah",
            build_s,
            sah_cost: sah,
            closest_s,
            any_s,
            closest_hits: hits,
        },
        PeerResult {
            name: "bvh crate sah (nearest_traverse_iterator)",
            build_s,
            sah_cost: sah,
            closest_s: Some(nearest_s),
            any_s: None,
            closest_hits: Some(nearest_hits),
        },
        PeerResult {
            name: "bvh crate sah (build_par)",
            build_s: par_build_s,
            sah_cost: bvh_crate_sah(&par_bvh, &par_shapes),
            closest_s: None,
            any_s: None,
            closest_hits: None,
        },
    ]
}
