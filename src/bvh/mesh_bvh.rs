//! A BVH over the triangles of a [`Mesh`], with ray queries.

use super::traverse::{Counter, TraversalStats, traverse};
use super::wide::compact::CompactWideBvh;
use super::wide::simd::RayLanes;
use super::wide::{DiscCache, Job, LaneDiscs, Visit, WideBvh, interleaved};
use super::{BuildOptions, Bvh, PartialOptions, PartialRebuild, refit::refit_pass};
use crate::geometry::{Aabb, Ray, TriangleRay, hit_limit};
use crate::mesh::{Mesh, check_positions};
use crate::{Error, Result, parallel};
use glam::{Vec3, Vec3A};
use std::cell::Cell;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Rays one task of the batched queries ([`MeshBvh::closest_hits`], [`MeshBvh::any_hits`]) answers.
const RAYS_PER_TASK: usize = 256;

/// Runs `batch(rays, out)` on [`RAYS_PER_TASK`]-ray pieces of `rays` and `out` (as long as `rays`), on
/// all threads with the `parallel` feature: the batched queries' split into tasks.
fn in_tasks<T: Send>(rays: &[Ray], out: &mut [T], batch: impl Fn(&[Ray], &mut [T]) + Sync) {
    assert_eq!(rays.len(), out.len(), "one output per ray");
    parallel::fill_chunks(true, out, RAYS_PER_TASK, |c, out| {
        let first = c * RAYS_PER_TASK;
        batch(&rays[first..first + out.len()], out);
    });
}

/// What an interleaved any-hit walk's leaves test a ray with ([`MeshBvh::any_job`]).
#[derive(Clone, Copy)]
pub(crate) struct LeafRay {
    tr: TriangleRay,
    tmin: f32,
    tmax: f32,
}

impl LeafRay {
    /// For `ray`, over its whole range.
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        Self {
            tr: TriangleRay::new(ray),
            tmin: ray.tmin,
            tmax: ray.tmax,
        }
    }

    /// Whether the ray hits any of the triangles `tris[slots]`.
    #[inline(always)]
    pub(crate) fn hits(&self, tris: &[[Vec3; 3]], slots: Range<usize>) -> bool {
        (slots.map(|s| tris[s]))
            .any(|[a, b, c]| self.tr.intersect(a, b, c, self.tmin, self.tmax).is_some())
    }

    /// [`hits`](Self::hits) for a job's tagged ray, as [`interleaved`] calls its leaf test.
    #[inline(always)]
    pub(crate) fn hits_tagged<X>(
        (_, ray): &mut (X, LeafRay),
        tris: &[[Vec3; 3]],
        slots: Range<usize>,
        _limit: &mut f32,
    ) -> bool {
        ray.hits(tris, slots)
    }
}

/// An interleaved closest-hit walk's state ([`MeshBvh::closest_job`]): its caller's tag, and what its
/// leaves need.
struct ClosestWalk<'a, X> {
    tag: X,
    /// The mesh's primitive per slot.
    prims: &'a [u32],
    /// The ray's slack for the tree's boxes ([`Ray::hit_slack`]).
    slack: f32,
    ray: ClosestRay,
}

impl<X> ClosestWalk<'_, X> {
    /// The leaf test: the triangles `tris[slots]` against the walk's ray, keeping its nearest hit;
    /// where one was nearer, the walk's box `limit` shrinks to it and the answer is true.
    #[inline(always)]
    fn test(&mut self, tris: &[[Vec3; 3]], slots: Range<usize>, limit: &mut f32) -> bool {
        let nearer = self.ray.test(tris, self.prims, slots);
        if nearer {
            *limit = hit_limit(self.ray.tmax, self.slack);
        }
        nearer
    }

    /// The walk's nearest hit so far (`tris` its mesh's triangles by slot).
    fn hit(&self, tris: &[[Vec3; 3]]) -> Option<Hit> {
        self.ray.hit(tris)
    }
}

/// A closest-hit walk's ray at its leaves and its best hit so far: the leaf test of the walk ray by ray
/// and of the interleaved walks alike.
struct ClosestRay {
    tr: TriangleRay,
    tmin: f32,
    /// The best hit's distance; the ray's `tmax` until one is found.
    tmax: f32,
    /// (t, primitive, slot, u, v) of the best hit so far.
    best: Option<(f32, u32, usize, f32, f32)>,
}

impl ClosestRay {
    /// For `ray` (valid).
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        Self {
            tr: TriangleRay::new(ray),
            tmin: ray.tmin,
            tmax: ray.tmax,
            best: None,
        }
    }

    /// Tests the triangles `tris[slots]` (slot `s` is primitive `prims[s]`) and keeps the nearest hit,
    /// the lower primitive on a tie: whether one was nearer than the best so far.
    #[inline(always)]
    fn test(&mut self, tris: &[[Vec3; 3]], prims: &[u32], slots: Range<usize>) -> bool {
        let mut nearer = false;
        for s in slots {
            let [a, b, c] = tris[s];
            if let Some(h) = self.tr.intersect(a, b, c, self.tmin, self.tmax) {
                let p = prims[s];
                if self.best.is_none_or(|(bt, bp, ..)| h.t < bt || p < bp) {
                    self.best = Some((h.t, p, s, h.u, h.v));
                    self.tmax = h.t;
                    nearer = true;
                }
            }
        }
        nearer
    }

    /// The best hit, with the geometric normal of its triangle (`tris` indexed by slot).
    fn hit(&self, tris: &[[Vec3; 3]]) -> Option<Hit> {
        self.best.map(|(t, primitive, s, u, v)| {
            let [a, b, c] = tris[s];
            Hit {
                t,
                primitive,
                u,
                v,
                normal: (b - a).cross(c - a).normalize_or_zero(),
            }
        })
    }
}

/// The nearest intersection of a ray with a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray, in units of its direction.
    pub t: f32,
    /// Index of the triangle in the mesh (`indices[3·primitive ..]`).
    pub primitive: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the third vertex (the first has `1 - u - v`).
    pub v: f32,
    /// Unit geometric normal, `normalize((v1 - v0) × (v2 - v0))`: facing follows the winding, not the ray.
    pub normal: Vec3,
}

/// A [`Bvh`] over a mesh's triangles plus the triangles' corners in leaf order, so traversal reads them
/// sequentially instead of through the index buffer.
///
/// Memory: 32 bytes per node (about 64 per triangle with one triangle per leaf), 36 bytes of corners and 12
/// of indices per triangle.
///
/// Closest-hit queries return the smallest `t`, and exactly one hit, also for a ray through a shared edge or
/// vertex of a closed mesh. Among triangles hit at exactly the same `t`, the lowest index that traversal
/// reaches wins: the box test and the triangle test round differently, so at a vertex fan a tied triangle in
/// another box may be skipped, and two trees can name different triangles of the fan — always at the same
/// distance.
///
/// ```
/// use kinetrace::{Mesh, MeshBvh, Ray, bvh::BuildOptions};
/// use glam::Vec3;
/// let mesh = Mesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![0, 1, 2])?;
/// let mut bvh = MeshBvh::build(&mesh, &BuildOptions::default())?;
/// let hit = bvh.closest_hit(&Ray::new(Vec3::new(0.2, 0.2, 1.0), -Vec3::Z)).unwrap();
/// assert_eq!((hit.primitive, hit.t), (0, 1.0));
/// // The mesh deforms: refit, and the tree follows.
/// let degradation = bvh.refit(&[Vec3::Z, Vec3::X + Vec3::Z, Vec3::Y + Vec3::Z])?;
/// assert!(degradation.abs() < 1e-6);
/// assert!(bvh.any_hit(&Ray::new(Vec3::new(0.2, 0.2, 2.0), -Vec3::Z)));
/// # Ok::<(), kinetrace::Error>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct MeshBvh {
    bvh: Bvh,
    /// Corners of each slot's triangle; zero-area triangles are collapsed to one point, which no ray hits.
    tris: Vec<[Vec3; 3]>,
    /// Vertex indices of each slot's triangle. This and `slot_of` are topology, shared by clones until a
    /// partial rebuild changes them: a copy per deforming instance owns only its boxes and corners.
    slot_indices: Arc<[[u32; 3]]>,
    vertex_count: usize,
    /// The mesh's index buffer (shared with it) and each triangle's slot: refit walks triangles in mesh
    /// order and scatters to slots, so the vertex reads stream through memory.
    indices: Arc<[u32]>,
    slot_of: Arc<[u32]>,
    /// Refit scratch: each slot's triangle box, kept between calls; only meshes past
    /// [`GATHER_BELOW_BYTES`] of vertices use it, the others keep it empty.
    slot_bounds: Vec<Aabb>,
    /// Identity of this build's topology (see [`MeshBvh::topology_id`]).
    topology: u64,
    /// The 4-wide query tree collapsed from `bvh`, refitted with it; ray queries walk it when present.
    wide: Option<WideBvh>,
    /// The quantised form of the wide tree, in its place when asked for ([`MeshBvh::set_compact`]).
    compact: Option<CompactWideBvh>,
    /// The wide tree while it is out of use for a try ([`MeshBvh::suspend_wide`]): not refitted, and
    /// dropped when the binary tree's topology changes. Taking it back costs a refit, not a collapse.
    suspended: Option<WideBvh>,
    /// The wide tree's lane discs for closest points and sphere overlaps, fitted when first asked for.
    discs: DiscCache,
}

/// Source of [`MeshBvh::topology_id`]s.
static BUILDS: AtomicU64 = AtomicU64::new(1);

/// The vertex indices of each slot's triangle, for a tree built over a mesh's triangles.
pub(crate) fn slot_indices(bvh: &Bvh, indices: &[u32]) -> Vec<[u32; 3]> {
    bvh.prim_indices()
        .iter()
        .map(|&p| {
            let p = p as usize * 3;
            [indices[p], indices[p + 1], indices[p + 2]]
        })
        .collect()
}

/// A topology id no tree has had yet.
pub(crate) fn next_topology_id() -> u64 {
    BUILDS.fetch_add(1, Ordering::Relaxed)
}

/// Vertex arrays up to this size (about 1.4M vertices) are refitted by reading vertices in leaf order;
/// larger ones by walking triangles in mesh order (see [`MeshBvh::refit`]).
pub const GATHER_BELOW_BYTES: usize = 16 << 20;

/// True for a triangle [`query_corners`] collapsed to one point (zero area): every query treats it as
/// absent, so grids do not bin it and point queries skip it.
#[inline]
pub(crate) fn is_collapsed(t: &[Vec3; 3]) -> bool {
    t[0] == t[1] && t[1] == t[2]
}

/// The corners a query tests: the triangle itself, or a single point for a zero-area triangle (exactly zero
/// cross product in `f32`), so that rounding in the ray's frame can never turn a degenerate triangle into a hit.
#[inline]
pub(crate) fn query_corners(t: [Vec3; 3]) -> [Vec3; 3] {
    // In SIMD lanes: the same products and differences as `Vec3`'s, a third of the instructions.
    let [a, b, c] = t.map(Vec3A::from);
    if (b - a).cross(c - a) == Vec3A::ZERO {
        [t[0]; 3]
    } else {
        t
    }
}

impl MeshBvh {
    /// Builds the tree over `mesh`'s triangles. An empty mesh gives an empty tree that no ray hits.
    pub fn build(mesh: &Mesh, options: &BuildOptions) -> Result<MeshBvh> {
        let bvh = Bvh::build(&mesh.triangle_bounds(), options)?;
        Ok(Self::pair(mesh, bvh, options.wide))
    }

    /// Pairs `bvh`, a valid tree over `mesh`'s triangle boxes (as a GPU build reads back), with the mesh,
    /// and derives the wide query tree. O(n), allocates the per-slot arrays; the tree gets a new
    /// [`topology_id`](Self::topology_id).
    #[cfg(feature = "gpu")]
    pub(crate) fn from_tree(mesh: &Mesh, bvh: Bvh) -> MeshBvh {
        Self::pair(mesh, bvh, true)
    }

    fn pair(mesh: &Mesh, bvh: Bvh, wide: bool) -> MeshBvh {
        let slot_indices = slot_indices(&bvh, mesh.indices());
        let pos = mesh.positions();
        let tris = slot_indices
            .iter()
            .map(|t| query_corners(t.map(|i| pos[i as usize])))
            .collect();
        let n = bvh.primitive_count();
        let mut slot_of = vec![0u32; n];
        for (slot, &p) in bvh.prim_indices().iter().enumerate() {
            slot_of[p as usize] = slot as u32;
        }
        MeshBvh {
            tris,
            slot_indices: slot_indices.into(),
            vertex_count: pos.len(),
            indices: mesh.indices_arc(),
            slot_of: slot_of.into(),
            slot_bounds: if std::mem::size_of_val(pos) > GATHER_BELOW_BYTES {
                vec![Aabb::EMPTY; n]
            } else {
                Vec::new()
            },
            topology: next_topology_id(),
            wide: wide.then(|| WideBvh::collapse(bvh.nodes())),
            compact: None,
            suspended: None,
            discs: DiscCache::default(),
            bvh,
        }
    }

    /// Derives the wide query tree (`true`, a collapse pass when there is none yet) or drops it and its
    /// compact form (`false`, queries walk the binary tree again). See [`BuildOptions::wide`].
    ///
    /// Taking the tree back after [`suspend_wide`](Self::suspend_wide) refits the suspended one (O(wide
    /// nodes), no allocation) where the binary tree kept its topology meanwhile.
    pub fn set_wide(&mut self, on: bool) {
        self.discs.clear();
        if !on {
            self.wide = None;
            self.compact = None;
            self.suspended = None;
        } else if self.wide.is_none() && self.compact.is_none() {
            self.wide = Some(self.take_wide());
        }
    }

    /// The wide tree in use, else the suspended one refitted, else a new collapse; none is left in place.
    fn take_wide(&mut self) -> WideBvh {
        match (self.wide.take(), self.suspended.take()) {
            (Some(w), _) => w,
            (None, Some(mut w)) => {
                w.refit(self.bvh.nodes());
                w
            }
            (None, None) => WideBvh::collapse(self.bvh.nodes()),
        }
    }

    /// Takes the wide query tree out of use as [`set_wide(false)`](Self::set_wide) does, but keeps its
    /// nodes, so that [`set_wide(true)`](Self::set_wide) brings it back by a refit instead of a collapse
    /// (which allocates): for a try of the binary tree that may end after a frame — what the planner does.
    /// Holds the wide tree's memory until then; the compact tree, if any, is dropped.
    pub fn suspend_wide(&mut self) {
        self.discs.clear();
        self.compact = None;
        if let Some(w) = self.wide.take() {
            self.suspended = Some(w);
        }
    }

    /// Replaces the wide query tree by its quantised form (`true`; see
    /// [`compact`](super::wide::compact): about half the bytes, exact answers, slower visits) or restores
    /// the float one (`false`). For large static meshes: while compact, a refit or partial rebuild
    /// re-derives it (collapse and quantise, O(n)) and [`wide`](Self::wide) is `None`.
    pub fn set_compact(&mut self, on: bool) {
        self.discs.clear();
        if on && self.compact.is_none() {
            let wide = self.take_wide();
            self.compact = Some(CompactWideBvh::quantise(&wide));
        } else if !on && self.compact.take().is_some() {
            self.wide = Some(WideBvh::collapse(self.bvh.nodes()));
        }
    }

    /// The wide query tree, when derived (and not replaced by its compact form).
    pub fn wide(&self) -> Option<&WideBvh> {
        self.wide.as_ref()
    }

    /// The wide tree's lane discs (see [`DiscCache`]), fitted now if they are not yet; none without a wide
    /// tree.
    pub(crate) fn lane_discs(&self) -> &[LaneDiscs] {
        match &self.wide {
            Some(w) => self.discs.get(w, &self.tris),
            None => &[],
        }
    }

    /// The compact query tree, when asked for with [`set_compact`](Self::set_compact).
    pub fn compact(&self) -> Option<&CompactWideBvh> {
        self.compact.as_ref()
    }

    /// Re-derives the query trees after the binary tree changed its topology.
    fn rederive(&mut self) {
        self.discs.clear();
        self.suspended = None;
        if self.wide.is_some() {
            self.wide = Some(WideBvh::collapse(self.bvh.nodes()));
        }
        if self.compact.is_some() {
            self.compact = Some(CompactWideBvh::quantise(&WideBvh::collapse(
                self.bvh.nodes(),
            )));
        }
    }

    /// The traversal every ray query runs: the wide tree when there is one, else the binary tree.
    #[inline]
    fn walk<C: Counter>(
        &self,
        ray: &Ray,
        counter: &mut C,
        leaf: impl FnMut(Range<usize>, &mut f32) -> bool,
    ) {
        // The wide and quantised trees span the binary tree's root box: the slack is the same for all
        // three (the binary walk takes it from its root itself).
        let slack = || ray.hit_slack(&self.bvh.bounds());
        match (&self.compact, &self.wide) {
            (Some(c), _) => c.traverse(&self.tris, ray, slack(), counter, leaf),
            (None, Some(w)) => w.traverse(&self.tris, ray, slack(), counter, leaf),
            (None, None) => traverse(&self.bvh.nodes, ray, counter, leaf),
        }
    }

    /// Refits to new vertex positions (same count and topology as the mesh it was built from) and returns the
    /// degradation metric (see [`Bvh::refit`]). O(n), no allocation.
    ///
    /// Up to [`GATHER_BELOW_BYTES`] of vertices it reads each leaf's vertices in leaf order; above, it walks
    /// the triangles in mesh order and scatters to leaf slots first (one thread, 2-core VM: a 1M-triangle soup
    /// with 3M unshared vertices 14 → 37 Mtris/s; a 1M-triangle surface with 0.5M shared vertices, whose
    /// leaf-order reads stay in cache, 69 Mtris/s gathering against 54 scattering).
    ///
    /// Errors: [`Error::VertexCountMismatch`], [`Error::NonFiniteVertex`]; the tree is unchanged then.
    pub fn refit(&mut self, positions: &[Vec3]) -> Result<f32> {
        Ok(self.refit_measured::<false>(positions)?.0)
    }

    /// [`refit`](Self::refit), returning the degradation metric and the refitted tree's SAH cost
    /// ([`Bvh::sah_cost`], up to the order its terms are summed in), measured in the same pass: a few
    /// operations a node instead of a second pass over the nodes (about an eighth of a refit). For a
    /// caller that weighs the tree every frame, as the adaptive planner does.
    ///
    /// Errors: those of [`refit`](Self::refit).
    pub fn refit_with_sah(&mut self, positions: &[Vec3]) -> Result<(f32, f64)> {
        self.refit_measured::<true>(positions)
    }

    /// [`refit`](Self::refit); with `SAH`, also the SAH cost ([`refit_pass`]).
    fn refit_measured<const SAH: bool>(&mut self, positions: &[Vec3]) -> Result<(f32, f64)> {
        if positions.len() != self.vertex_count {
            return Err(Error::VertexCountMismatch {
                expected: self.vertex_count,
                got: positions.len(),
            });
        }
        check_positions(positions)?;
        if std::mem::size_of_val(positions) <= GATHER_BELOW_BYTES {
            // The vertices stay in cache: read them in leaf order, straight into the node pass.
            let (tris, idx) = (&mut self.tris, &self.slot_indices);
            let (d, sah) = refit_pass::<SAH>(&mut self.bvh.nodes, |slot| {
                let t = idx[slot].map(|i| positions[i as usize]);
                tris[slot] = query_corners(t);
                let [a, b, c] = t.map(Vec3A::from);
                (a.min(b).min(c), a.max(b).max(c))
            });
            return Ok((self.refit_wide(d), sah));
        }
        // Triangles in mesh order (vertex reads follow the mesh's own layout), results scattered to slots:
        // stores do not stall the way a gather of vertices in leaf order does once they miss the cache.
        for (t, tri) in self.indices.chunks_exact(3).enumerate() {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| positions[i as usize]);
            let slot = self.slot_of[t] as usize;
            self.tris[slot] = query_corners([a, b, c]);
            self.slot_bounds[slot] = Aabb::from_triangle(a, b, c);
        }
        let boxes = &self.slot_bounds;
        let (d, sah) = refit_pass::<SAH>(&mut self.bvh.nodes, |slot| boxes[slot].lanes());
        Ok((self.refit_wide(d), sah))
    }

    /// Copies the refitted binary boxes into the wide tree's lanes (no re-collapse), or re-derives the
    /// compact tree; passes `degradation` on.
    fn refit_wide(&mut self, degradation: f32) -> f32 {
        if let Some(w) = &mut self.wide {
            w.refit(&self.bvh.nodes);
        }
        self.discs.clear();
        if self.compact.is_some() {
            self.rederive();
        }
        degradation
    }

    /// Refits to new vertex positions as [`refit`](Self::refit) does, then rebuilds the subtrees that
    /// degraded past `options` ([`rebuild_degraded`](Self::rebuild_degraded)); returns the refit's
    /// degradation metric (before the rebuilds) and what was rebuilt.
    ///
    /// Errors: those of [`refit`](Self::refit) and [`Error::InvalidOption`] (checked first: the tree is
    /// unchanged then).
    pub fn refit_partial(
        &mut self,
        positions: &[Vec3],
        options: &PartialOptions,
    ) -> Result<(f32, PartialRebuild)> {
        options.check()?;
        let degradation = self.refit(positions)?;
        Ok((degradation, self.rebuild_degraded(positions, options)?))
    }

    /// Rebuilds the subtrees that degraded past `options` (see [`partial`](super::partial)), after a
    /// [`refit`](Self::refit) to these `positions` — the planner's [`Verdict::Partial`] once it has seen
    /// the refitted tree's cost.
    ///
    /// Cost: a pass over the nodes, a binned SAH build over the rebuilt triangles only, and, when
    /// anything was rebuilt, a new collapse of the whole wide tree (O(n), the price of a derived tree).
    /// Collapsing only the rebuilt subtrees again is not done: the wide nodes lie in the order the
    /// collapse found them, with leaf sizes planned over the whole tree, and a rebuilt subtree may
    /// collapse into another number of wide nodes, so splicing it in would move the rest. `bench cpu
    /// --quick` (2-core VM, loaded) puts the re-collapse at 0.21–0.24 of a partial rebuild's time on
    /// its scattered 100k scene (its surface pose rebuilds nothing). The tree gets a new
    /// [`topology_id`](Self::topology_id) when anything was rebuilt.
    ///
    /// Errors: [`Error::InvalidOption`], [`Error::VertexCountMismatch`], [`Error::NonFiniteVertex`]; the
    /// tree is unchanged then.
    ///
    /// [`Verdict::Partial`]: crate::adaptive::Verdict::Partial
    pub fn rebuild_degraded(
        &mut self,
        positions: &[Vec3],
        options: &PartialOptions,
    ) -> Result<PartialRebuild> {
        options.check()?;
        if positions.len() != self.vertex_count {
            return Err(Error::VertexCountMismatch {
                expected: self.vertex_count,
                got: positions.len(),
            });
        }
        check_positions(positions)?;
        let indices = &self.indices;
        let tri = |p: u32| {
            let p = p as usize * 3;
            [indices[p], indices[p + 1], indices[p + 2]]
        };
        let done = self.bvh.rebuild_degraded_by(options, |p| {
            let [a, b, c] = tri(p).map(|i| positions[i as usize]);
            Aabb::from_triangle(a, b, c)
        })?;
        if done.subtrees == 0 {
            return Ok(done);
        }
        let prims = self.bvh.prim_indices();
        // Shared with clones until now: this tree gets its own.
        let slot_of = Arc::make_mut(&mut self.slot_of);
        let slot_indices = Arc::make_mut(&mut self.slot_indices);
        for range in &done.slots {
            for s in range.clone() {
                let p = prims[s];
                let t = tri(p);
                slot_of[p as usize] = s as u32;
                slot_indices[s] = t;
                self.tris[s] = query_corners(t.map(|i| positions[i as usize]));
            }
        }
        self.rederive();
        self.topology = next_topology_id();
        Ok(done)
    }

    /// A number that changes with every build and stays through refits (clones keep it): two trees with
    /// the same id have the same nodes in the same order, so per-tree caches keyed by it — such as a
    /// collision [`PairFront`](crate::collide::PairFront) — stay valid. The empty default tree has id 0.
    pub fn topology_id(&self) -> u64 {
        self.topology
    }

    /// The tree.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Triangle corners in slot order, as queries see them (zero-area triangles collapsed to a point).
    pub fn slot_triangles(&self) -> &[[Vec3; 3]] {
        &self.tris
    }

    /// Vertex indices in slot order.
    pub fn slot_indices(&self) -> &[[u32; 3]] {
        &self.slot_indices
    }

    /// The nearest hit within the ray's `[tmin, tmax]`, or `None` (also for an invalid ray).
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        self.closest_with(ray, &mut ())
    }

    /// [`closest_hit`](Self::closest_hit), adding the work done to `stats`.
    pub fn closest_hit_counted(&self, ray: &Ray, stats: &mut TraversalStats) -> Option<Hit> {
        self.closest_with(ray, stats)
    }

    /// True when anything lies within the ray's `[tmin, tmax]` (occlusion, shadow rays). Stops at the first
    /// hit found.
    pub fn any_hit(&self, ray: &Ray) -> bool {
        self.any_with(ray, &mut ())
    }

    /// [`any_hit`](Self::any_hit), adding the work done to `stats`.
    pub fn any_hit_counted(&self, ray: &Ray, stats: &mut TraversalStats) -> bool {
        self.any_with(ray, stats)
    }

    /// Every hit within the ray's range, appended to `out` in no particular order (sort by `t` if needed).
    /// The work of a closest-hit query that never shrinks its range.
    pub fn all_hits(&self, ray: &Ray, out: &mut Vec<Hit>) {
        if !ray.is_valid() {
            return;
        }
        let tr = TriangleRay::new(ray);
        let prims = self.bvh.prim_indices();
        self.walk(ray, &mut (), |slots, _| {
            for s in slots {
                let [a, b, c] = self.tris[s];
                if let Some(h) = tr.intersect(a, b, c, ray.tmin, ray.tmax) {
                    out.push(Hit {
                        t: h.t,
                        primitive: prims[s],
                        u: h.u,
                        v: h.v,
                        normal: (b - a).cross(c - a).normalize_or_zero(),
                    });
                }
            }
            false
        });
    }

    /// [`closest_hit`](Self::closest_hit) for every ray, on all threads with the `parallel` feature.
    /// `out` must be as long as `rays`.
    ///
    /// Each thread keeps four rays' walks of the wide or compact tree going at once
    /// ([`closest_hits_interleaved`](Self::closest_hits_interleaved)), as [`any_hits`](Self::any_hits)
    /// does: the same answers as `closest_hit` ray by ray, at 1.3–1.55× the rays a second on random rays
    /// and 1.0–1.2× on coherent camera rays (`bench cpu --quick`, one thread, 2-core Intel VM).
    pub fn closest_hits(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        in_tasks(rays, out, |rays, out| {
            self.closest_hits_interleaved(rays, out)
        });
    }

    /// [`closest_hit`](Self::closest_hit) for every ray on the calling thread, four rays' walks
    /// interleaved on the wide or compact tree, each walk's range shrinking at its own hits; ray by ray
    /// on the binary tree. The same answers and node visits as `closest_hit` ray by ray. `out` must be
    /// as long as `rays`. No allocation.
    pub fn closest_hits_interleaved(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        out.fill(None);
        let hits = Cell::from_mut(out).as_slice_of_cells();
        match (&self.compact, &self.wide) {
            (Some(c), _) => self.closest_interleaved_on(c.nodes(), rays, hits),
            (None, Some(w)) => self.closest_interleaved_on(w.nodes(), rays, hits),
            (None, None) => {
                for (o, r) in hits.iter().zip(rays) {
                    o.set(self.closest_hit(r));
                }
            }
        }
    }

    /// [`closest_hits_interleaved`](Self::closest_hits_interleaved) on the wide or compact tree `nodes`,
    /// into `hits` (all `None`): a walk's answer is written at each nearer hit it finds.
    fn closest_interleaved_on<N: Visit>(
        &self,
        nodes: &[N],
        rays: &[Ray],
        hits: &[Cell<Option<Hit>>],
    ) {
        let start = |i: usize| self.closest_job(nodes, &rays[i], i);
        let leaf = |w: &mut ClosestWalk<usize>, tris: &[[Vec3; 3]], slots, limit: &mut f32| {
            if w.test(tris, slots, limit) {
                hits[w.tag].set(w.hit(tris));
            }
            false
        };
        let never = |_: &ClosestWalk<usize>| false;
        interleaved(rays.len(), start, leaf, |_| {}, never);
    }

    /// Ray `ray`'s closest-hit walk of this mesh's tree `nodes` (its wide or compact one), tagged `tag`,
    /// for [`interleaved`] (its leaf test: [`ClosestWalk::test`]): `None` for an invalid ray, which
    /// hits nothing.
    fn closest_job<'a, N, X>(
        &'a self,
        nodes: &'a [N],
        ray: &Ray,
        tag: X,
    ) -> Option<Job<'a, N, [Vec3; 3], ClosestWalk<'a, X>>> {
        ray.is_valid().then(|| {
            // The ray's slack for the tree's boxes, as the walk ray by ray takes it.
            let slack = ray.hit_slack(&self.bvh.bounds());
            Job {
                nodes,
                slot_data: &self.tris,
                lanes: RayLanes::new(ray),
                limit: hit_limit(ray.tmax, slack),
                data: ClosestWalk {
                    tag,
                    prims: self.bvh.prim_indices(),
                    slack,
                    ray: ClosestRay::new(ray),
                },
            }
        })
    }

    /// [`any_hit`](Self::any_hit) for every ray, on all threads with the `parallel` feature. `out` must
    /// be as long as `rays`.
    ///
    /// Each thread keeps four rays' walks of the wide or compact tree going at once, a node of each in
    /// turn ([`any_hits_interleaved`](Self::any_hits_interleaved)), so that one ray's wait for memory
    /// overlaps the others' work: the same answers and node visits as `any_hit` ray by ray, at 1.2–1.5×
    /// the rays a second where the nodes are not in cache (`bench cpu --quick`, random rays, one thread,
    /// 2-core Intel VM), 1.0–1.25× on coherent camera rays.
    pub fn any_hits(&self, rays: &[Ray], out: &mut [bool]) {
        in_tasks(rays, out, |rays, out| self.any_hits_interleaved(rays, out));
    }

    /// [`any_hit`](Self::any_hit) for every ray on the calling thread, four rays' walks interleaved on
    /// the wide or compact tree (see [`any_hits`](Self::any_hits)); ray by ray on the binary tree.
    /// `out` must be as long as `rays`. No allocation.
    pub fn any_hits_interleaved(&self, rays: &[Ray], out: &mut [bool]) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        out.fill(false);
        let hits = Cell::from_mut(out).as_slice_of_cells();
        match (&self.compact, &self.wide) {
            (Some(c), _) => self.any_interleaved_on(c.nodes(), rays, hits),
            (None, Some(w)) => self.any_interleaved_on(w.nodes(), rays, hits),
            (None, None) => {
                for (o, r) in hits.iter().zip(rays) {
                    o.set(self.any_hit(r));
                }
            }
        }
    }

    /// [`any_hits_interleaved`](Self::any_hits_interleaved) on the wide or compact tree `nodes`, into
    /// `hits` (all false).
    fn any_interleaved_on<N: Visit>(&self, nodes: &[N], rays: &[Ray], hits: &[Cell<bool>]) {
        let start = |i| self.any_job(nodes, &rays[i], i);
        let hit = |&(i, _): &(usize, LeafRay)| hits[i].set(true);
        let never = |_: &(usize, LeafRay)| false;
        interleaved(rays.len(), start, LeafRay::hits_tagged, hit, never);
    }

    /// Ray `ray`'s any-hit walk of this mesh's tree `nodes` (its wide or compact one), tagged `tag`, for
    /// [`interleaved`]: `None` for an invalid ray, which hits nothing.
    pub(crate) fn any_job<'a, N, X>(
        &'a self,
        nodes: &'a [N],
        ray: &Ray,
        tag: X,
    ) -> Option<Job<'a, N, [Vec3; 3], (X, LeafRay)>> {
        ray.is_valid().then(|| Job {
            nodes,
            slot_data: &self.tris,
            lanes: RayLanes::new(ray),
            limit: hit_limit(ray.tmax, ray.hit_slack(&self.bvh.bounds())),
            data: (tag, LeafRay::new(ray)),
        })
    }

    fn closest_with<C: Counter>(&self, ray: &Ray, counter: &mut C) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let prims = self.bvh.prim_indices();
        let mut closest = ClosestRay::new(ray);
        self.walk(ray, counter, |slots, tmax| {
            closest.test(&self.tris, prims, slots);
            *tmax = closest.tmax;
            false
        });
        closest.hit(&self.tris)
    }

    fn any_with<C: Counter>(&self, ray: &Ray, counter: &mut C) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let leaf = LeafRay::new(ray);
        let mut hit = false;
        self.walk(ray, counter, |slots, _| {
            hit = leaf.hits(&self.tris, slots);
            hit
        });
        hit
    }
}
