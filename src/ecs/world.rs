//! The acceleration structures of a world: one BLAS per entity in object space, a TLAS over the entities'
//! world boxes, and the two-level queries.

use super::planned::{CostScript, scripted};
use super::top_level::TopLevelState;
use super::{PlannedOption, QueryFilter, RayHit, StructureWhy};
use crate::Mesh;
use crate::adaptive::Estimate;
use crate::bvh::wide::WideNode;
use crate::bvh::{Bvh, Hit, MeshBvh, TraversalStats, traverse};
use crate::characterize::SceneProfile;
use crate::geometry::{Aabb, Ray};
use crate::grid::{StructureKind, UniformGrid};
use crate::shadows::Occluders;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use glam::{Affine3A, Mat3A, Vec2, Vec3};
use std::sync::Arc;

/// Runs `f` with the thread's scratch list `key`, emptied, and keeps the list for the thread's next call.
/// The list is taken out for the call, so a query that runs inside it on the same thread (a filter's
/// predicate querying the world, or a parallel worker stealing another batch while it waits) gets a
/// fresh list, allocated once, instead of a second borrow's panic; the larger list is kept.
pub(super) fn with_scratch<T, R>(
    key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>,
    f: impl FnOnce(&mut Vec<T>) -> R,
) -> R {
    let mut list = key.take();
    list.clear();
    let r = f(&mut list);
    key.with_borrow_mut(|kept| {
        if list.capacity() > kept.capacity() {
            *kept = list;
        }
    });
    r
}

/// One traceable entity's state.
pub(crate) struct Instance {
    pub bvh: MeshBvh,
    /// The mesh the tree was built for (its buffers shared): its [`topology`](Self::topology), and
    /// [`Mesh::is_closed`], which a selective shadow pass asks (then leaving out its triangles facing
    /// away from the light) when one first renders it, once per topology, re-positioned copies sharing
    /// the answer.
    pub mesh: Mesh,
    pub transform: Affine3A,
    pub inverse: Affine3A,
    /// Inverse transpose of the linear part, for normals.
    pub normal_matrix: Mat3A,
    /// The transform's scale when it is a similarity (shape queries then go into the mesh's frame), else
    /// `None` (see `shape_queries`): worked out with the transform, not per query.
    pub similar_scale: Option<f32>,
    pub world_bounds: Aabb,
    pub layers: u32,
    pub frames_since_rebuild: u32,
    /// The characteriser's last profile of the mesh, and the degradation when it was taken.
    pub profile: Option<Arc<SceneProfile>>,
    pub profiled_at: f32,
    /// Degradation after each of the last refits (oldest first), for motion incoherence.
    pub history: Vec<f32>,
    /// What outlives a rebuild: the adaptive policy's state and the GPU builder.
    pub kept: Kept,
    /// The tree's SAH cost, kept current only under the adaptive policy (0 otherwise).
    pub sah: f64,
    /// Rays that reached the mesh last frame, as attributed: the frame's batched requests × the mesh's
    /// share of the scene's surface area (adaptive policy only). What its costs are learned per.
    pub rays: f64,
    /// Shape queries (casts, closest points, overlaps, containment) that reached the mesh's tree last
    /// frame, counted as [`rays`](Self::rays) are (adaptive policy only).
    pub shapes: f64,
    /// The running means of [`rays`](Self::rays) and [`shapes`](Self::shapes) (an [`Estimate`]: the last
    /// five frames or so weigh most), what the option planners (wide tree, packets, structure, overlap
    /// test) decide for: a load that comes and goes — closest points every other frame — is planned for as
    /// its mean. Planned for last frame's count, the wide tree was dropped on each frame without queries
    /// and collapsed again on the next. Carried over a rebuild, and taken from the sibling a new
    /// instance starts from.
    pub load: QueryLoad,
    /// Which structure answers the mesh's closest-hit and any-hit rays, and why.
    pub structure: StructureKind,
    pub why: StructureWhy,
    /// This frame's refit when it ran ahead of the mesh's turn in maintenance, in parallel with the
    /// other meshes' (see `maintain::refit_ahead`); `None`: the mesh's turn refits it, if it is to be.
    pub prefit: Option<Prefit>,
}

/// A refit run ahead of the mesh's turn in maintenance.
#[derive(Debug)]
pub(crate) struct Prefit {
    /// The degradation and the SAH cost (if measured in the pass), or the error.
    pub result: crate::Result<(f32, Option<f64>)>,
    /// The time it took.
    pub took: std::time::Duration,
}

/// The state of an entity that a rebuild carries over to the new tree.
#[derive(Default)]
pub(crate) struct Kept {
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy): the mesh's learned cost model.
    pub adaptive: Option<crate::adaptive::AdaptivePolicy>,
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy): whether the mesh keeps the wide query
    /// tree, decided from its measured maintenance and query costs with and without it.
    pub wide: Option<crate::adaptive::Choice<bool>>,
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy): whether packet requests meet the mesh as
    /// packets (`true`) or ray by ray, decided from the measured seconds per ray of each way.
    pub packets: Option<crate::adaptive::Choice<bool>>,
    /// Under [`RebuildPolicy::Adaptive`](super::RebuildPolicy) and [`Structure::Auto`](super::Structure):
    /// whether the mesh's rays meet its BVH or its grid (see `planned`).
    pub structure: Option<crate::adaptive::Choice<StructureKind>>,
    /// Under the planner's structure choice: whether the mesh's grid uses the triangle–cell overlap
    /// test (see `planned`).
    pub overlap: Option<crate::adaptive::Choice<bool>>,
    /// The mesh's GPU build buffers, made at its first GPU rebuild (same topology only).
    #[cfg(feature = "gpu")]
    pub gpu: Option<crate::gpu::GpuMeshBvh>,
    /// The scratch of the mesh's GPU SAH or hybrid builds over `gpu`, made at the first such build.
    #[cfg(feature = "gpu")]
    pub gpu_sah: Option<crate::gpu::GpuSahBuilder>,
    /// The mesh's GPU PLOC buffers, made at its first GPU PLOC rebuild (same topology and radius only).
    #[cfg(feature = "gpu")]
    pub gpu_ploc: Option<crate::gpu::GpuPloc>,
    /// The mesh's grid, made the first time it is kept as one and kept (with its buffers) from then on;
    /// queries read it only while [`Instance::structure`] is the grid.
    pub grid: Option<UniformGrid>,
}

/// The queries a mesh is expected to receive per frame, as the option planners see them (see
/// [`Instance::load`]).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct QueryLoad {
    rays: Estimate,
    shapes: Estimate,
}

impl QueryLoad {
    /// Learns a frame's attributed rays and shape queries.
    fn add(&mut self, rays: f64, shapes: f64) {
        self.rays.add(rays);
        self.shapes.add(shapes);
    }

    /// Rays expected per frame (0 before any frame was attributed).
    pub fn rays(&self) -> f64 {
        self.rays.mean().unwrap_or(0.0)
    }

    /// Rays and shape queries expected per frame: what the mesh's tree serves.
    pub fn tree_queries(&self) -> f64 {
        self.rays() + self.shapes.mean().unwrap_or(0.0)
    }
}

/// Refits remembered for motion incoherence.
pub(crate) const HISTORY: usize = 16;

impl Instance {
    /// How incoherently the mesh moves: the mean rise of the degradation metric per refit over the last
    /// refits (0 for rigid or coherent motion; large when neighbouring primitives scatter).
    pub fn motion_incoherence(&self) -> f32 {
        match self.history.len() {
            0 | 1 => 0.0,
            n => ((self.history[n - 1] - self.history[0]) / (n - 1) as f32).max(0.0),
        }
    }

    /// Queries that reached the mesh's tree last frame: its rays and its shape queries (what its rebuild
    /// policy and its wide-tree choice serve).
    pub fn tree_queries(&self) -> f64 {
        self.rays + self.shapes
    }

    /// Records a refit's degradation.
    pub fn remember(&mut self, degradation: f32) {
        if self.history.len() == HISTORY {
            self.history.remove(0);
        }
        self.history.push(degradation);
    }

    /// Identity of the topology the tree was built for ([`topology_id`] of its mesh): a different one
    /// means a topology change.
    pub fn topology(&self) -> u64 {
        topology_id(&self.mesh)
    }

    /// The entity's state around a freshly built tree for `mesh` (its topology: its index buffer).
    pub fn new(bvh: MeshBvh, mesh: &Mesh, kept: Kept) -> Instance {
        let mut inst = Instance {
            bvh,
            mesh: mesh.clone(),
            transform: Affine3A::IDENTITY,
            inverse: Affine3A::IDENTITY,
            normal_matrix: Mat3A::IDENTITY,
            similar_scale: Some(1.0),
            world_bounds: Aabb::EMPTY,
            layers: u32::MAX,
            frames_since_rebuild: 0,
            profile: None,
            profiled_at: 0.0,
            history: Vec::with_capacity(HISTORY),
            kept,
            sah: 0.0,
            rays: 0.0,
            shapes: 0.0,
            load: QueryLoad::default(),
            structure: StructureKind::Bvh,
            why: StructureWhy::Fixed,
            prefit: None,
        };
        inst.update_world_bounds();
        inst
    }

    /// Sets the transform (which must be finite and invertible).
    pub fn set_transform(&mut self, t: Affine3A) {
        self.transform = t;
        self.inverse = t.inverse();
        self.normal_matrix = self.inverse.matrix3.transpose();
        self.similar_scale = super::shape_queries::similarity_scale(&t);
        self.update_world_bounds();
    }

    /// The world box of the transformed root box (its eight corners).
    pub fn update_world_bounds(&mut self) {
        let b = self.bvh.bvh().bounds();
        self.world_bounds = if b.is_empty() {
            Aabb::EMPTY
        } else {
            b.corners().iter().fold(Aabb::EMPTY, |mut acc, &c| {
                acc.grow(self.transform.transform_point3(c));
                acc
            })
        };
    }

    /// The world ray in object space: same `t` values, since origin and direction go through the same
    /// affine map.
    pub(super) fn object_ray(&self, ray: &Ray, tmax: f32) -> Ray {
        Ray::with_range(
            self.inverse.transform_point3(ray.origin),
            self.inverse.transform_vector3(ray.dir()),
            ray.tmin,
            tmax,
        )
    }

    /// The grid that answers the mesh's rays, when it is kept as one.
    fn grid(&self) -> Option<&UniformGrid> {
        match self.structure {
            StructureKind::Grid => self.kept.grid.as_ref(),
            StructureKind::Bvh => None,
        }
    }

    /// Whether a choice under the structure in use (the wide tree and packets for the BVH, the overlap
    /// test for the grid) tried an option at its last decision: such a frame measures the try, and
    /// teaches the mesh's structure choice nothing.
    pub(super) fn sub_option_tried(&self) -> bool {
        let tried =
            |c: &Option<crate::adaptive::Choice<bool>>| c.as_ref().is_some_and(|c| c.explored());
        match self.structure {
            StructureKind::Bvh => tried(&self.kept.wide) || tried(&self.kept.packets),
            StructureKind::Grid => tried(&self.kept.overlap),
        }
    }

    /// Whether packet requests meet the mesh as packets: its planner's pick under the adaptive policy,
    /// always otherwise.
    fn packets_on(&self) -> bool {
        self.kept.packets.as_ref().is_none_or(|c| c.current())
    }

    /// The nearest hit of an object-space ray, through the mesh's structure, counted into `stats` if given.
    fn closest_hit(&self, ray: &Ray, stats: Option<&mut TraversalStats>) -> Option<Hit> {
        match (self.grid(), stats) {
            (Some(g), Some(s)) => g.closest_hit_counted(ray, s),
            (Some(g), None) => g.closest_hit(ray),
            (None, Some(s)) => self.bvh.closest_hit_counted(ray, s),
            (None, None) => self.bvh.closest_hit(ray),
        }
    }

    /// Whether an object-space ray hits the mesh, through the mesh's structure.
    pub(super) fn any_hit(&self, ray: &Ray) -> bool {
        match self.grid() {
            Some(g) => g.any_hit(ray),
            None => self.bvh.any_hit(ray),
        }
    }

    /// The wide tree's nodes when the mesh's single rays walk it (no grid, no compact tree): what an
    /// interleaved walk ([`TraceWorld::occluded_interleaved`]) can run.
    pub(super) fn interleaved_tree(&self) -> Option<&[WideNode]> {
        match (self.grid(), self.bvh.compact(), self.bvh.wide()) {
            (None, None, Some(w)) => Some(w.nodes()),
            _ => None,
        }
    }

    /// The nearest hits of a packet of object-space rays (up to [`crate::bvh::MAX_PACKET`]), through the
    /// mesh's structure: grid packets for a mesh kept as a grid, BVH packets otherwise.
    /// Ray by ray instead when the mesh's packets option is off (same answers).
    pub(super) fn closest_hits_packet(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        if !self.packets_on() {
            for (r, o) in rays.iter().zip(out.iter_mut()) {
                *o = self.closest_hit(r, None);
            }
            return;
        }
        let mut stats = TraversalStats::default();
        match self.grid() {
            Some(g) => g.closest_hits_packet(rays, out, &mut stats),
            None => self.bvh.closest_hits_packet(rays, out, &mut stats),
        }
    }

    /// Whether each object-space ray of a packet hits the mesh, through the mesh's structure.
    /// Ray by ray instead when the mesh's packets option is off (same answers).
    pub(super) fn any_hits_packet(&self, rays: &[Ray], out: &mut [bool]) {
        if !self.packets_on() {
            for (r, o) in rays.iter().zip(out.iter_mut()) {
                *o = self.any_hit(r);
            }
            return;
        }
        let mut stats = TraversalStats::default();
        match self.grid() {
            Some(g) => g.any_hits_packet(rays, out, &mut stats),
            None => self.bvh.any_hits_packet(rays, out, &mut stats),
        }
    }

    pub(super) fn world_hit(&self, entity: Entity, ray: &Ray, h: &Hit) -> RayHit {
        RayHit {
            entity,
            distance: h.t,
            point: ray.at(h.t),
            normal: (self.normal_matrix * glam::Vec3A::from(h.normal))
                .normalize_or_zero()
                .into(),
            triangle: h.primitive,
            barycentrics: Vec2::new(h.u, h.v),
        }
    }
}

/// The accepted entities of a [`TraceWorld`] as shadow-map occluders, one group per entity in top-level
/// order (an entity the filter rejects is an empty group): see [`TraceWorld::occluders`].
#[derive(Clone, Copy)]
pub struct WorldOccluders<'a> {
    world: &'a TraceWorld,
    filter: &'a QueryFilter,
}

impl Occluders for WorldOccluders<'_> {
    fn groups(&self) -> usize {
        self.world.tlas_entities.len()
    }

    fn group(&self, g: usize) -> (&[[Vec3; 3]], Option<Affine3A>) {
        let e = self.world.tlas_entities[g];
        let inst = &self.world.instances[&e];
        if self.filter.accepts(e, inst.layers) {
            (inst.bvh.slot_triangles(), Some(inst.transform))
        } else {
            (&[], None)
        }
    }

    fn closed(&self, g: usize) -> bool {
        // A rejected entity's group is empty: nothing to ask its mesh about.
        let e = self.world.tlas_entities[g];
        let inst = &self.world.instances[&e];
        self.filter.accepts(e, inst.layers) && inst.mesh.is_closed()
    }
}

/// Triangles one worker transforms at a time in [`TraceWorld::world_triangles`].
const WORLD_CHUNK: usize = 4096;

/// A stable identity for a mesh's topology, shared by the clones of one [`Mesh`] (never reused, unlike
/// the index buffer's address, which a later mesh may get once the first is freed).
pub(crate) fn topology_id(mesh: &Mesh) -> u64 {
    mesh.topology()
}

/// Every traceable entity's tree and the top-level tree over them: what queries read. Maintained by the
/// plugin's systems; read it through [`SpatialRays`](super::SpatialRays) or directly.
#[derive(Resource, Default)]
pub struct TraceWorld {
    pub(crate) instances: EntityHashMap<Instance>,
    pub(super) tlas: Bvh,
    /// TLAS primitive id → entity.
    pub(super) tlas_entities: Vec<Entity>,
    pub(super) tlas_bounds: Vec<Aabb>,
    /// The top level's rebuild rule state and report (see `top_level`).
    pub(super) top: TopLevelState,
    /// Set when an entity was added, removed, moved or refitted since the TLAS was made.
    pub(crate) tlas_dirty: bool,
    /// Set when the set of entities changed (the TLAS is rebuilt rather than refitted).
    pub(crate) membership_changed: bool,
    /// Incremented whenever anything a query reads changed (for GPU uploads).
    pub(crate) version: u64,
    /// Test hook: scripted costs for the option planners (see [`script_costs`](Self::script_costs)).
    pub(crate) script: Option<CostScript>,
    /// Seconds per triangle of a planned mesh's frame on the grid (its rebuild and the refit under it),
    /// learned on every mesh: the grid's expected overhead for a mesh that has not measured its own
    /// (`ecs::planned`).
    pub(crate) grid_rate: crate::adaptive::Estimate,
}

impl TraceWorld {
    /// Number of traceable entities.
    pub fn len(&self) -> usize {
        self.instances.len()
    }

    /// True when nothing is traceable.
    pub fn is_empty(&self) -> bool {
        self.instances.is_empty()
    }

    /// Whether the entity is traceable right now.
    pub fn contains(&self, e: Entity) -> bool {
        self.instances.contains_key(&e)
    }

    /// The entity's object-space tree.
    pub fn blas(&self, e: Entity) -> Option<&MeshBvh> {
        self.instances.get(&e).map(|i| &i.bvh)
    }

    /// The entity's grid, when its rays are answered by one (see [`Structure`](super::Structure)).
    pub fn grid(&self, e: Entity) -> Option<&UniformGrid> {
        self.instances.get(&e).and_then(Instance::grid)
    }

    /// Which structure answers the entity's closest-hit and any-hit rays, and why.
    pub fn structure(&self, e: Entity) -> Option<(StructureKind, StructureWhy)> {
        self.instances.get(&e).map(|i| (i.structure, i.why))
    }

    /// The characteriser's current profile of the entity's mesh (see [`TraceSystems::Characterize`](super::TraceSystems)).
    pub fn profile(&self, e: Entity) -> Option<&Arc<SceneProfile>> {
        self.instances.get(&e).and_then(|i| i.profile.as_ref())
    }

    /// How incoherently the entity's mesh has been moving (see `Instance::motion_incoherence`): the mean rise
    /// of the degradation metric per refit over the last 16 refits.
    pub fn motion_incoherence(&self, e: Entity) -> Option<f32> {
        self.instances.get(&e).map(Instance::motion_incoherence)
    }

    /// The top-level tree (primitives are entities, see [`tlas_entity`](Self::tlas_entity)).
    pub fn tlas(&self) -> &Bvh {
        &self.tlas
    }

    /// The entity of a TLAS primitive id.
    pub fn tlas_entity(&self, prim: u32) -> Entity {
        self.tlas_entities[prim as usize]
    }

    /// Test hook: from now on the per-mesh option planners (structure, wide tree, packets) learn the
    /// seconds `script` gives for the option in use instead of what they measure (`None`: measure again).
    /// For tests of the planners' decisions with known costs; not for production use.
    #[doc(hidden)]
    pub fn script_costs(&mut self, script: Option<CostScript>) {
        self.script = script;
    }

    pub(crate) fn remove(&mut self, e: Entity) -> bool {
        let gone = self.instances.remove(&e).is_some();
        if gone {
            self.tlas_dirty = true;
            self.membership_changed = true;
        }
        gone
    }

    /// Feeds the adaptive policies a frame's batched queries: `rays` ray requests answered in
    /// `ray_seconds` and `shapes` shape, point, overlap and containment requests ([`ShapeQueue`](super::ShapeQueue))
    /// in `shape_seconds`.
    ///
    /// The time is apportioned by expected traversal work: the top level's, its SAH cost `C_tlas` (every
    /// query enters it), and each mesh's, `p_i · C_i` with `p_i` the mesh's world-box area over the scene
    /// box's (the chance that a ray through the scene reaches it) and `C_i` its SAH cost; each mesh is told
    /// it received `rays · p_i` rays and `shapes · p_i` shape queries, the top level all of them (meshes
    /// kept as grids take no share: their time is not BVH time; except where the planner chooses the
    /// structure, whose grid takes the share its BVH would, `C_i` its BVH's last cost, and teaches only
    /// that choice). The shares add up to the measured time; how far each is off is discussed at
    /// [`RebuildPolicy::Adaptive`](super::RebuildPolicy). Shape queries are charged by the same model
    /// (a point query's box test is a ray's, and its cost grows with the tree's as a ray's does) to what
    /// answers them: the mesh's tree — its rebuild policy (rent, builder) and its wide-tree choice — never
    /// the grid, packet or overlap-test choices, which they do not use. So a mesh queried mostly by
    /// closest points gets the builder and the wide tree that pay for those queries. O(meshes), no
    /// allocation.
    pub(crate) fn attribute_queries(
        &mut self,
        rays: usize,
        ray_seconds: f64,
        shapes: usize,
        shape_seconds: f64,
    ) {
        let scene = self.tlas.bounds().half_area_f64();
        let share = |i: &Instance| {
            if scene > 0.0 {
                (i.world_bounds.half_area_f64() / scene).min(1.0)
            } else {
                1.0
            }
        };
        // A mesh kept as a grid is answered by its grid: its BVH's SAH cost says nothing of its query time,
        // and its time must not teach the planner's shared BVH rates. It gets no share of the work.
        let bvh_sah = |i: &Instance| match i.structure {
            StructureKind::Grid if i.kept.structure.is_none() => 0.0,
            _ => i.sah,
        };
        let work = self.top.sah
            + self
                .instances
                .values()
                .map(|i| share(i) * bvh_sah(i))
                .sum::<f64>();
        self.attribute_top_level(rays + shapes, ray_seconds + shape_seconds, work);
        let script = self.script.as_ref();
        for (&e, inst) in self.instances.iter_mut() {
            let p = share(inst);
            inst.rays = rays as f64 * p;
            inst.shapes = shapes as f64 * p;
            inst.load.add(inst.rays, inst.shapes);
            if work <= 0.0 || inst.kept.adaptive.is_none() {
                continue;
            }
            let part = |seconds: f64| seconds * p * bvh_sah(inst) / work;
            let (ray_share, shape_share) = (part(ray_seconds), part(shape_seconds));
            let (rays, tree_queries) = (inst.rays, inst.tree_queries());
            let learned = |option, seconds, units: f64| {
                scripted(script, e, option, seconds, |c| c.per_ray_s * units)
            };
            let sub_try = inst.sub_option_tried();
            if let Some(structure) = inst.kept.structure.as_mut().filter(|_| !sub_try) {
                let kind = inst.structure;
                let option = PlannedOption::Structure(kind);
                structure.served(kind, rays, learned(option, ray_share, rays));
            }
            if let Some(overlap) = inst.kept.overlap.as_mut()
                && inst.structure == StructureKind::Grid
            {
                let on = overlap.current();
                let option = PlannedOption::Overlap(on);
                overlap.served(on, rays, learned(option, ray_share, rays));
            }
            if let Some(policy) = inst.kept.adaptive.as_mut()
                && inst.structure == StructureKind::Bvh
            {
                let tree_share = ray_share + shape_share;
                policy.queried(tree_queries, inst.sah, tree_share);
                if let Some(wide) = inst.kept.wide.as_mut() {
                    let on = inst.bvh.wide().is_some();
                    let option = PlannedOption::Wide(on);
                    wide.served(on, tree_queries, learned(option, tree_share, tree_queries));
                }
                if let Some(packets) = inst.kept.packets.as_mut() {
                    let on = packets.current();
                    let option = PlannedOption::Packets(on);
                    packets.served(on, rays, learned(option, ray_share, rays));
                }
            }
        }
    }

    /// The nearest hit within `[ray.tmin, min(ray.tmax, max_t)]` on an entity the filter accepts (of hits
    /// at the same distance, the one on the entity with the lowest [`Entity::to_bits`], then the lowest
    /// triangle index; batched and GPU answers keep the same rule). `None`
    /// for an invalid ray ([`Ray::is_valid`]: non-finite origin or direction, zero direction, NaN range)
    /// and for a NaN `max_t`.
    pub fn cast_ray(&self, ray: &Ray, max_t: f32, filter: &QueryFilter) -> Option<RayHit> {
        self.cast(ray, max_t, filter, None)
    }

    /// [`cast_ray`](Self::cast_ray), adding the work of both levels to `stats` (for cost heatmaps).
    pub fn cast_ray_counted(
        &self,
        ray: &Ray,
        max_t: f32,
        filter: &QueryFilter,
        stats: &mut TraversalStats,
    ) -> Option<RayHit> {
        self.cast(ray, max_t, filter, Some(stats))
    }

    fn cast(
        &self,
        ray: &Ray,
        max_t: f32,
        filter: &QueryFilter,
        stats: Option<&mut TraversalStats>,
    ) -> Option<RayHit> {
        let ray = ray.clipped(max_t);
        if !ray.is_valid() {
            return None;
        }
        let counting = stats.is_some();
        let (mut top, mut bottom) = (TraversalStats::default(), TraversalStats::default());
        let mut best: Option<(Entity, Hit)> = None;
        traverse(self.tlas.nodes(), &ray, &mut top, |slots, tmax| {
            for s in slots {
                let e = self.tlas_entities[self.tlas.prim_indices()[s] as usize];
                let inst = &self.instances[&e];
                if !filter.accepts(e, inst.layers) {
                    continue;
                }
                let oray = inst.object_ray(&ray, *tmax);
                let h = inst.closest_hit(&oray, counting.then_some(&mut bottom));
                if let Some(h) = h
                    && nearer(h.t, e, &best)
                {
                    *tmax = h.t;
                    best = Some((e, h));
                }
            }
            false
        });
        if let Some(s) = stats {
            s.add(&top);
            s.add(&bottom);
        }
        best.map(|(e, h)| self.instances[&e].world_hit(e, &ray, &h))
    }

    /// True when an accepted entity lies on the segment from `from` to `to` (shadow / line of sight).
    pub fn occluded(&self, from: Vec3, to: Vec3, filter: &QueryFilter) -> bool {
        let ray = Ray::segment(from, to);
        if !ray.is_valid() {
            return false;
        }
        let mut hit = false;
        traverse(self.tlas.nodes(), &ray, &mut (), |slots, tmax| {
            for s in slots {
                let e = self.tlas_entities[self.tlas.prim_indices()[s] as usize];
                let inst = &self.instances[&e];
                if filter.accepts(e, inst.layers) && inst.any_hit(&inst.object_ray(&ray, *tmax)) {
                    hit = true;
                    return true;
                }
            }
            false
        });
        hit
    }

    /// The accepted entities' triangles as the occluders of a shadow map
    /// ([`HardShadows::run`](crate::shadows::HardShadows::run)): one group per entity, its mesh's triangles
    /// with its transform, so the map projects them straight from the meshes instead of from a copy in world
    /// space ([`world_triangles`](Self::world_triangles): on a crowd of 700k triangles, 25 MB each way and
    /// 3–4 ms a frame on 2 cores). Allocates nothing; the world cannot change while it is borrowed.
    ///
    /// ```
    /// # use kinetrace::ecs::{QueryFilter, TraceWorld};
    /// # use kinetrace::shadows::{GBuffer, HardShadows, ShadowSettings};
    /// # let (world, gbuffer) = (TraceWorld::default(), GBuffer::new(4, 4));
    /// let all = QueryFilter::default();
    /// let rays = |from, to| world.occluded(from, to, &all);
    /// let mut pass = HardShadows::new();
    /// let visibility = pass.run(&ShadowSettings::default(), &world.occluders(&all), &gbuffer, rays)?;
    /// # assert_eq!(visibility, [1.0; 16]);
    /// # Ok::<(), kinetrace::Error>(())
    /// ```
    pub fn occluders<'a>(&'a self, filter: &'a QueryFilter) -> WorldOccluders<'a> {
        WorldOccluders {
            world: self,
            filter,
        }
    }

    /// Every triangle of the accepted entities in world space, entity by entity in top-level order, into
    /// `out` (cleared first): what a rasteriser needs (a shadow map renders from
    /// [`occluders`](Self::occluders) without this copy). O(triangles), each entity's transformed on all
    /// threads (feature `parallel`), straight into `out`: memory-bound, 700k triangles (25 MB each way)
    /// take 3–4 ms on a 2-core VM, 5 on one thread. No allocation once `out` is large enough.
    pub fn world_triangles(&self, filter: &QueryFilter, out: &mut Vec<[Vec3; 3]>) {
        out.clear();
        let occluders = self.occluders(filter);
        for g in 0..occluders.groups() {
            // A rejected entity is an empty group, without a transform.
            let (tris, place) = occluders.group(g);
            let t = place.unwrap_or(Affine3A::IDENTITY);
            crate::parallel::extend_mapped(true, out, tris, WORLD_CHUNK, |tri| {
                tri.map(|p| t.transform_point3(p))
            });
        }
    }

    /// Every hit along the ray on accepted entities, nearest first, into `out` (cleared first). Always
    /// through the meshes' BVHs, also for meshes whose closest hits a grid answers.
    pub fn ray_hits(&self, ray: &Ray, filter: &QueryFilter, out: &mut Vec<RayHit>) {
        out.clear();
        if !ray.is_valid() {
            return;
        }
        let mut local = Vec::new();
        traverse(self.tlas.nodes(), ray, &mut (), |slots, _| {
            for s in slots {
                let e = self.tlas_entities[self.tlas.prim_indices()[s] as usize];
                let inst = &self.instances[&e];
                if !filter.accepts(e, inst.layers) {
                    continue;
                }
                local.clear();
                inst.bvh
                    .all_hits(&inst.object_ray(ray, ray.tmax), &mut local);
                out.extend(local.iter().map(|h| inst.world_hit(e, ray, h)));
            }
            false
        });
        out.sort_by(|a, b| {
            a.distance
                .total_cmp(&b.distance)
                .then(a.entity.cmp(&b.entity))
                .then(a.triangle.cmp(&b.triangle))
        });
    }
}

/// Whether a hit at distance `t` on entity `e` replaces the best hit so far: nearer, or as near on an
/// entity with lower [`Entity::to_bits`]. With ties broken by the entity, not by which entity
/// the top level visited first, the answer does not depend on the visiting order (the CPU's top-level
/// tree against the GPU's, single rays against packets); `scene.wgsl` keeps the same rule.
pub(crate) fn nearer(t: f32, e: Entity, best: &Option<(Entity, Hit)>) -> bool {
    best.is_none_or(|(be, b)| t < b.t || (t == b.t && e.to_bits() < be.to_bits()))
}

#[cfg(test)]
mod tests {
    use super::with_scratch;
    use std::cell::RefCell;

    thread_local! {
        static LIST: RefCell<Vec<u32>> = const { RefCell::new(Vec::new()) };
    }

    /// A scratch list used again inside its own use on the same thread gets a list of its own (no
    /// second borrow, no panic), each call sees an empty list, and the larger of the two is kept.
    #[test]
    fn scratch_lists_nest_and_the_larger_one_stays() {
        let outer = with_scratch(&LIST, |a| {
            a.extend([1, 2, 3]);
            let inner = with_scratch(&LIST, |b| {
                assert!(b.is_empty());
                b.extend(0..100);
                b.len()
            });
            assert_eq!(*a, [1, 2, 3]);
            inner + a.len()
        });
        assert_eq!(outer, 103);
        let kept = LIST.with_borrow(|l| l.capacity());
        assert!(kept >= 100, "the larger list is kept: capacity {kept}");
        with_scratch(&LIST, |c| assert!(c.is_empty() && c.capacity() >= 100));
    }
}
