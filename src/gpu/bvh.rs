//! One mesh's BVH on the GPU: LBVH construction, refit with the degradation metric, and the buffers the
//! ray kernels read. The node buffer holds exactly the CPU [`Bvh`] layout.

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, Readback, bind_group};
use super::sort::RadixSort;
use super::tree::{GpuTree, node_depths};
use crate::bvh::{Bvh, MAX_DEPTH, MeshBvh, Node};
use crate::{Error, Mesh, Result};
use glam::Vec3;

/// Depth buckets of the level schedule (no tree is deeper than [`crate::bvh::MAX_DEPTH`]).
const LEVELS: usize = 64;
/// The `levels` buffer (u32s): counts, cursors and offsets per depth, then the depth the bottom-up pass
/// runs next, its workgroups finished, and the deepest depth.
const LEVEL_WORDS: u64 = 3 * LEVELS as u64 + 3;

/// The two halves of an LBVH build.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuildPhase {
    /// Triangle bounds, scene bounds, Morton codes and their radix sort.
    Sort,
    /// Radix tree, layout, level schedule, and boxes bottom-up.
    Tree,
}

/// A mesh's BVH kept on the GPU.
///
/// [`record_build`](Self::record_build) rebuilds it with LBVH (30-bit Morton codes, one triangle per leaf)
/// and [`record_refit`](Self::record_refit) refits it to the current vertex positions — uploaded with
/// [`upload_positions`](Self::upload_positions) or written by the skinning kernel into
/// [`positions`](Self::positions) with no CPU round trip. Both record into the caller's encoder, so a
/// frame's work for all meshes goes into one submission. Buffers are allocated once per mesh size.
///
/// Memory ([`memory_bytes`](Self::memory_bytes), per triangle, `n` triangles, `2n - 1` nodes): the mesh
/// (positions 12 per vertex, indices 12), the tree (nodes 64, slot ids 4, Morton codes 4), refit's level
/// schedule (the inner nodes' order by depth 4, during a build the radix tree's range starts), and LBVH
/// build scratch: radix-tree links 8 + 8 (children and parents, first the radix sort's ping-pong keys and
/// ids; a refit's degradation terms, 4 per node, live in the children). About 110 bytes per triangle for
/// a closed mesh (vertices ≈ n / 2) plus about 4 KiB of parameters (the sort's digits are the device's
/// pass slots, [`GpuContext::shared_tree_bytes`]). The centroids are computed twice (bounds,
/// then codes) rather than cached: 16 bytes per triangle less for three more vertex reads per triangle.
/// The SAH builder keeps its scratch in these buffers and in the nodes' box fields.
/// No buffer keeps node depths: a builder leaves each node's depth in its `sa_ratio`, the schedule
/// buckets the inner nodes by it, and the bottom-up pass overwrites it with the ratio.
///
/// The ray kernels and the leaf boxes read a leaf's triangle through its slot id and the mesh's indices
/// (`indices[3 · ids[slot] ..]`), not through a 16-byte copy of the indices in slot order: 16 bytes per
/// triangle less, for one more dependent read per triangle tested.
pub struct GpuMeshBvh {
    tris: u32,
    vertices: u32,
    positions: GpuBuffer,
    _indices: GpuBuffer,
    nodes: GpuBuffer,
    /// Per leaf slot, its triangle's id: what the ray kernels and the leaf boxes read the triangle's
    /// vertex indices through.
    vals: GpuBuffer,
    /// Morton codes, sorted with `vals` by an LBVH sort.
    keys: GpuBuffer,
    level_args: GpuBuffer,
    sums: GpuBuffer,
    params: ParamSlots,
    /// Counts of the characteriser's Morton-code histogram (MAX_HISTOGRAM_BINS words).
    histogram: GpuBuffer,
    histogram_group: wgpu::BindGroup,
    sort: RadixSort,
    lbvh_group: wgpu::BindGroup,
    /// For the schedule kernels (writes the indirect arguments).
    levels_group: wgpu::BindGroup,
    /// For bounds_level (a stand-in where the indirect arguments are bound).
    bounds_group: wgpu::BindGroup,
    reduce_group: wgpu::BindGroup,
    built: bool,
    /// The Morton codes of the current positions are sorted in `keys` (a GPU build ran, not an upload).
    coded: bool,
    /// False for an uploaded CPU tree with several triangles per leaf: traceable, not refittable here.
    refittable: bool,
    /// Depth of the deepest leaf: exact for an uploaded CPU tree, the bound MAX_DEPTH after a GPU build.
    height: u32,
    /// The level order (4 B per triangle), which holds the radix-tree range starts during an LBVH build
    /// and the SAH builder's partition flags during an SAH build: the schedule rewrites it after every
    /// build.
    order: GpuBuffer,
    /// The radix tree's children (8 B per triangle) and parents (8), first the sort's ping-pong buffers;
    /// the children hold a refit's degradation terms (4 B per node), which no build needs.
    links: [GpuBuffer; 2],
    _scratch: Vec<GpuBuffer>,
}

/// Parameter slots: 0 mesh, 1 node count (the schedule, and the level passes of a build), 2 the same for
/// a refit's, 3 sum over nodes, 4 sum over pairs, 5 histogram. The level passes find their depth in the
/// schedule, not in a slot per depth.
const SLOT_MESH: usize = 0;
const SLOT_BUILD: usize = 1;
const SLOT_REFIT: usize = 2;
const SLOT_SUM: usize = 3;
const SLOT_PAIRS: usize = 4;
const SLOT_HISTOGRAM: usize = 5;

/// The most bins [`GpuMeshBvh::record_histogram`] counts (Doane's rule asks for about 40 at 10⁷ triangles
/// even for strongly skewed codes).
pub const MAX_HISTOGRAM_BINS: usize = 256;

impl GpuMeshBvh {
    /// Uploads `mesh` and allocates everything its tree needs. Nothing is built until
    /// [`record_build`](Self::record_build).
    pub fn new(ctx: &GpuContext, mesh: &Mesh) -> Result<Self> {
        let tris = mesh.triangle_count() as u32;
        let vertices = mesh.positions().len() as u32;
        let n = tris.max(1) as u64;
        let node_count = (2 * n - 1) as u32;
        for (what, bytes) in [
            ("positions", vertices as u64 * 12),
            ("indices", tris as u64 * 12),
            ("nodes", node_count as u64 * 32),
        ] {
            ctx.check_storage(what, bytes)?;
        }
        ctx.check_threads("tree nodes", node_count as u64, 256)?;
        let positions = GpuBuffer::storage(ctx, "positions", vertices as u64 * 12);
        positions.write(ctx, mesh.positions());
        let indices = GpuBuffer::storage(ctx, "indices", tris as u64 * 12);
        indices.write(ctx, mesh.indices());
        let partials = GpuBuffer::storage(ctx, "partials", n.div_ceil(256) * 32);
        let keys = GpuBuffer::storage(ctx, "morton", n * 4);
        let vals = GpuBuffer::storage(ctx, "sorted ids", n * 4);
        let children = GpuBuffer::storage(ctx, "children", n * 8);
        let parents = GpuBuffer::storage(ctx, "parents", 2 * n * 4);
        let nodes = GpuBuffer::storage(ctx, "nodes", node_count as u64 * 32);
        let levels = GpuBuffer::storage(ctx, "levels", LEVEL_WORDS * 4);
        let level_args = GpuBuffer::new(
            ctx,
            "level dispatch args",
            12 * LEVELS as u64,
            super::buffers::STORAGE | wgpu::BufferUsages::INDIRECT,
        );
        let stand_in = GpuBuffer::storage(ctx, "stand-in", 16);
        // Inner nodes only (n - 1), or the radix tree's range starts (n - 1).
        let order = GpuBuffer::storage(ctx, "level order", n * 4);
        // The radix tree's range starts (4 bytes per triangle) live in the level order, which the
        // schedule rewrites after the tree phase.
        let first = &order;
        // A refit's degradation terms (4 bytes per node, 2n - 1 of them) live in the radix tree's
        // children (8 per triangle), which only a build uses.
        let terms = &children;
        let sum_blocks = node_count.div_ceil(256);
        let sums = GpuBuffer::storage(ctx, "degradation sums", sum_blocks as u64 * 8);
        if tris == 1 {
            // No inner node writes the root's parent link: mark it here.
            parents.write(ctx, &[u32::MAX]);
        }
        let mut slots = vec![[0u32; 4]; SLOT_HISTOGRAM + 1];
        slots[SLOT_MESH] = [tris, 0, 0, 0];
        slots[SLOT_BUILD] = [node_count, 0, 0, ctx.max_groups()];
        slots[SLOT_REFIT] = [node_count, 1, 0, ctx.max_groups()];
        slots[SLOT_SUM] = [node_count, 0, 0, 0];
        slots[SLOT_PAIRS] = [sum_blocks, 0, 0, 0];
        let params = ParamSlots::new(ctx, &slots);
        let k = &ctx.kernels;
        let lbvh_group = bind_group(
            ctx,
            &k.lbvh.layout,
            &[
                positions.binding(),
                indices.binding(),
                partials.binding(),
                keys.binding(),
                vals.binding(),
                children.binding(),
                parents.binding(),
                first.binding(),
                nodes.binding(),
                params.binding(),
            ],
        );
        let levels_with = |args: &GpuBuffer| {
            bind_group(
                ctx,
                &k.levels.layout,
                &[
                    positions.binding(),
                    indices.binding(),
                    vals.binding(),
                    nodes.binding(),
                    levels.binding(),
                    order.binding(),
                    terms.binding(),
                    params.binding(),
                    args.binding(),
                ],
            )
        };
        let levels_group = levels_with(&level_args);
        let bounds_group = levels_with(&stand_in);
        let reduce_group = bind_group(
            ctx,
            &k.reduce.layout,
            &[terms.binding(), sums.binding(), params.binding()],
        );
        let histogram = GpuBuffer::storage(ctx, "histogram", MAX_HISTOGRAM_BINS as u64 * 4);
        let histogram_group = bind_group(
            ctx,
            &k.histogram.layout,
            &[keys.binding(), histogram.binding(), params.binding()],
        );
        // The sort ping-pongs through the radix-tree links, which the tree phase writes after it.
        let sort = RadixSort::with_scratch(ctx, &keys, &vals, [&children, &parents], tris, 30);
        Ok(Self {
            tris,
            vertices,
            positions,
            _indices: indices,
            nodes,
            vals,
            keys,
            level_args,
            sums,
            params,
            histogram,
            histogram_group,
            sort,
            lbvh_group,
            levels_group,
            bounds_group,
            reduce_group,
            built: false,
            coded: false,
            refittable: true,
            height: MAX_DEPTH as u32,
            order,
            links: [children, parents],
            _scratch: vec![partials, levels, stand_in],
        })
    }

    /// Uploads a CPU-built tree (any builder, any leaf size) so the GPU can trace it. With one triangle per
    /// leaf it can be refitted on the GPU too.
    pub fn from_cpu(ctx: &GpuContext, mesh: &Mesh, bvh: &MeshBvh) -> Result<Self> {
        let mut g = Self::new(ctx, mesh)?;
        g.vals.write(ctx, bvh.bvh().prim_indices());
        g.built = true;
        g.refittable = bvh.bvh().nodes().len() == g.node_count() as usize;
        let mut depths = Vec::new();
        node_depths(bvh.bvh().nodes(), &mut depths);
        g.height = depths.iter().copied().max().unwrap_or(0);
        if g.refittable {
            g.cpu_levels(ctx, bvh.bvh().nodes(), &depths);
        }
        g.nodes.write(ctx, bvh.bvh().nodes());
        Ok(g)
    }

    /// Makes refit's level schedule of a CPU-built tree on the GPU as for an LBVH build: uploads the nodes
    /// with each one's depth where the schedule reads it (`sa_ratio`, as the GPU builders leave it);
    /// the caller uploads the real nodes afterwards.
    fn cpu_levels(&self, ctx: &GpuContext, nodes: &[Node], depths: &[u32]) {
        let marked: Vec<Node> = nodes
            .iter()
            .zip(depths)
            .map(|(n, &d)| Node {
                sa_ratio: d as f32,
                ..*n
            })
            .collect();
        self.nodes.write(ctx, &marked);
        let mut enc = ctx.encoder();
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.record_schedule(ctx, &mut pass);
        }
        ctx.submit(enc);
    }

    /// GPU memory held for this mesh (buffers of the mesh, the tree and all build scratch), in bytes.
    pub fn memory_bytes(&self) -> u64 {
        let own = [
            &self.positions,
            &self._indices,
            &self.nodes,
            &self.vals,
            &self.keys,
            &self.level_args,
            &self.sums,
            &self.histogram,
        ];
        own.into_iter()
            .chain([&self.order])
            .chain(&self.links)
            .chain(&self._scratch)
            .map(|b| b.buffer().size())
            .sum::<u64>()
            + self.sort.memory_bytes()
            + self.params.memory_bytes()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> u32 {
        self.tris
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> u32 {
        self.vertices
    }

    /// Number of nodes the GPU builder makes (`2 · triangles − 1`; 0 for an empty mesh). An uploaded CPU
    /// tree with several triangles per leaf fills only the first `nodes().len()` of them.
    pub fn node_count(&self) -> u32 {
        (2 * self.tris.max(1) - 1) * (self.tris > 0) as u32
    }

    /// The vertex positions the kernels read (flat `x, y, z` f32 triples): the skinning kernel's output.
    pub fn positions(&self) -> &wgpu::Buffer {
        self.positions.buffer()
    }

    /// The node buffer (the CPU [`Node`] layout, root at index 0), for the ray and pair kernels.
    pub fn nodes(&self) -> &wgpu::Buffer {
        self.nodes.buffer()
    }

    /// The tree as [`GpuPairs`](super::GpuPairs) reads it: the node buffer, the node count (0, an empty
    /// tree, before a build is recorded) and the height (exact for an uploaded CPU tree, the bound
    /// [`MAX_DEPTH`] after a GPU build, whose pair queries then record more, mostly empty, rounds).
    pub fn tree(&self) -> GpuTree<'_> {
        GpuTree {
            nodes: self.nodes(),
            count: if self.built { self.node_count() } else { 0 },
            height: self.height,
        }
    }

    /// Bindings for the PLOC builder, which clusters after this builder's Morton sort: positions, indices,
    /// and the triangle ids in Morton order (after [`BuildPhase::Sort`]).
    pub(crate) fn positions_binding(&self) -> wgpu::BindingResource<'_> {
        self.positions.binding()
    }

    pub(crate) fn indices_binding(&self) -> wgpu::BindingResource<'_> {
        self._indices.binding()
    }

    pub(crate) fn sorted_ids_binding(&self) -> wgpu::BindingResource<'_> {
        self.vals.binding()
    }

    /// Sorts by Morton codes on cubic cells ([`morton30_cube`](crate::geometry::morton30_cube)) from the
    /// next submission on, as PLOC's order; the LBVH tree and the characteriser's histogram keep per-axis
    /// codes, so only a PLOC builder's own tree calls this.
    pub(crate) fn use_cube_codes(&self, ctx: &GpuContext) {
        self.params.write(ctx, SLOT_MESH, [self.tris, 1, 0, 0]);
    }

    /// Records the read-back of the triangle ids in Morton order.
    pub(crate) fn record_sorted_ids(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
    ) -> Readback<u32> {
        Readback::record(ctx, encoder, self.vals.buffer(), self.tris as usize)
    }

    /// Per slot, the id of its triangle (what [`read_tree`](Self::read_tree) reads as the primitive order).
    pub(crate) fn slot_ids(&self) -> &wgpu::Buffer {
        self.vals.buffer()
    }

    /// The mesh's vertex indices, three per triangle in id order.
    pub(crate) fn indices(&self) -> &wgpu::Buffer {
        self._indices.buffer()
    }

    /// Replaces the vertex positions (same count as the mesh); takes effect at the next submission.
    pub fn upload_positions(&self, ctx: &GpuContext, positions: &[Vec3]) -> Result<()> {
        if positions.len() != self.vertices as usize {
            return Err(Error::VertexCountMismatch {
                expected: self.vertices as usize,
                got: positions.len(),
            });
        }
        crate::mesh::check_positions(positions)?;
        self.positions.write(ctx, positions);
        Ok(())
    }

    /// Records a full LBVH rebuild from the current positions: bounds, Morton codes, sort, radix tree,
    /// layout, level schedule, then boxes and build-time SA ratios bottom-up.
    pub fn record_build(&mut self, ctx: &GpuContext, encoder: &mut wgpu::CommandEncoder) {
        self.record_build_phase(ctx, encoder, BuildPhase::Sort);
        self.record_build_phase(ctx, encoder, BuildPhase::Tree);
    }

    /// Records one phase of [`record_build`](Self::record_build), so that the phases can be timed apart;
    /// [`BuildPhase::Tree`] must follow a [`BuildPhase::Sort`] of the same positions.
    pub fn record_build_phase(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        phase: BuildPhase,
    ) {
        if self.tris == 0 {
            return;
        }
        let k = &ctx.kernels;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(match phase {
                BuildPhase::Sort => "kinetrace lbvh sort",
                BuildPhase::Tree => "kinetrace lbvh tree",
            }),
            timestamp_writes: None,
        });
        let mesh = [ParamSlots::offset(SLOT_MESH)];
        let run = |pass: &mut wgpu::ComputePass<'_>, entry: &str, threads: u32| {
            let (x, y) = ctx.groups(threads, 256);
            pass.set_pipeline(k.lbvh.pipeline(entry));
            pass.set_bind_group(0, &self.lbvh_group, &mesh);
            pass.dispatch_workgroups(x, y, 1);
        };
        match phase {
            BuildPhase::Sort => {
                run(&mut pass, "tri_bounds", self.tris);
                run(&mut pass, "reduce_bounds", 1);
                run(&mut pass, "morton", self.tris);
                self.sort.record(ctx, &mut pass);
                self.coded = true;
            }
            BuildPhase::Tree => {
                run(&mut pass, "karras", self.tris);
                run(&mut pass, "walk_up", self.node_count());
                self.record_boxes(ctx, &mut pass, true);
            }
        }
    }

    /// The buffers another GPU builder writes before [`record_boxes`](Self::record_boxes): positions and
    /// indices (read), nodes (topology, each node's depth in its `sa_ratio`), slot ids, and the Morton
    /// codes the LBVH sort ([`BuildPhase::Sort`]) leaves sorted beside the ids.
    pub(crate) fn build_targets(&self) -> [&GpuBuffer; 5] {
        [
            &self.positions,
            &self._indices,
            &self.nodes,
            &self.vals,
            &self.keys,
        ]
    }

    /// Records the second half of every GPU build once a builder has written each node's `index` (leaves
    /// of one triangle), its depth (as `sa_ratio`), and the slots' triangle ids: the level schedule, then boxes and
    /// build-time SA ratios bottom-up. Marks the tree built; `coded` says whether this build sorted the
    /// current positions' Morton codes (for [`record_histogram`](Self::record_histogram)).
    pub(crate) fn record_boxes(
        &mut self,
        ctx: &GpuContext,
        pass: &mut wgpu::ComputePass<'_>,
        coded: bool,
    ) {
        self.coded &= coded;
        self.height = MAX_DEPTH as u32;
        self.record_schedule(ctx, pass);
        self.record_levels(ctx, pass, SLOT_BUILD);
        self.built = true;
    }

    /// LBVH scratch free during another builder's build (after a hybrid's [`BuildPhase::Sort`]): the
    /// level order, the radix tree's children and its parents, 4, 8 and 8 bytes per triangle (at least
    /// 256 bytes each). An LBVH build overwrites them, every build's schedule
    /// ([`record_boxes`](Self::record_boxes)) the first, and every refit the second.
    pub(crate) fn lbvh_scratch(&self) -> [&GpuBuffer; 3] {
        [&self.order, &self.links[0], &self.links[1]]
    }

    /// What a PLOC build clusters in after [`BuildPhase::Sort`], none of it read again by this tree until
    /// its next build: the node buffer (32 bytes per node id, `2n - 1` of them: the clusters' boxes), the
    /// Morton codes (4 B per triangle), the level order (4), and the radix tree's children (8) and
    /// parents (8). A PLOC builder's own tree is never traced, refitted or read back.
    pub(crate) fn ploc_scratch(&self) -> [&GpuBuffer; 5] {
        let [children, parents] = &self.links;
        [&self.nodes, &self.keys, &self.order, children, parents]
    }

    /// Dispatches recorded by the [`BuildPhase::Sort`] phase.
    pub(crate) fn sort_phase_dispatches(&self) -> u32 {
        3 + self.sort.dispatches()
    }

    /// Dispatches recorded by [`record_boxes`](Self::record_boxes).
    pub(crate) const BOXES_DISPATCHES: u32 = 5 + LEVELS as u32;

    /// Buckets the inner nodes by depth (once per topology).
    fn record_schedule(&self, ctx: &GpuContext, pass: &mut wgpu::ComputePass<'_>) {
        let k = &ctx.kernels;
        let off = [ParamSlots::offset(SLOT_BUILD)];
        pass.set_bind_group(0, &self.levels_group, &off);
        // level_count adds to zeroed counts; level_offsets rewrites everything else.
        pass.set_pipeline(k.levels.pipeline("level_reset"));
        pass.dispatch_workgroups(1, 1, 1);
        let (x, y) = ctx.groups(self.node_count(), 256);
        pass.set_pipeline(k.levels.pipeline("level_count"));
        pass.dispatch_workgroups(x, y, 1);
        pass.set_pipeline(k.levels.pipeline("level_offsets"));
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(k.levels.pipeline("level_scatter"));
        pass.dispatch_workgroups(x, y, 1);
    }

    /// The leaves' boxes, then one indirect dispatch per depth of inner nodes, deepest first (each finds
    /// its depth in the schedule: no parameter slot per depth); `mode_slot` is [`SLOT_BUILD`] or
    /// [`SLOT_REFIT`].
    fn record_levels(&self, ctx: &GpuContext, pass: &mut wgpu::ComputePass<'_>, mode_slot: usize) {
        let k = &ctx.kernels;
        pass.set_bind_group(0, &self.bounds_group, &[ParamSlots::offset(mode_slot)]);
        pass.set_pipeline(k.levels.pipeline("leaf_bounds"));
        let (x, y) = ctx.groups(self.node_count(), 256);
        pass.dispatch_workgroups(x, y, 1);
        pass.set_pipeline(k.levels.pipeline("bounds_level"));
        for d in (0..LEVELS).rev() {
            pass.dispatch_workgroups_indirect(self.level_args.buffer(), 12 * d as u64);
        }
    }

    /// Records a refit to the current positions and the degradation metric's reduction. The metric arrives
    /// through [`record_degradation`](Self::record_degradation).
    pub fn record_refit(&self, ctx: &GpuContext, encoder: &mut wgpu::CommandEncoder) -> Result<()> {
        if self.tris == 0 {
            return Ok(());
        }
        if !self.built {
            return Err(Error::Gpu("refit before the tree was built".into()));
        }
        if !self.refittable {
            return Err(Error::Gpu(
                "this uploaded tree has several triangles per leaf; GPU refit needs one".into(),
            ));
        }
        let k = &ctx.kernels;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace refit"),
            timestamp_writes: None,
        });
        self.record_levels(ctx, &mut pass, SLOT_REFIT);
        let (x, y) = ctx.groups(self.node_count(), 256);
        pass.set_pipeline(k.reduce.pipeline("sum_blocks"));
        pass.set_bind_group(0, &self.reduce_group, &[ParamSlots::offset(SLOT_SUM)]);
        pass.dispatch_workgroups(x, y, 1);
        pass.set_pipeline(k.reduce.pipeline("sum_pairs"));
        pass.set_bind_group(0, &self.reduce_group, &[ParamSlots::offset(SLOT_PAIRS)]);
        pass.dispatch_workgroups(1, 1, 1);
        Ok(())
    }

    /// Records the read-back of the last refit's degradation metric.
    pub fn record_degradation(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
    ) -> DegradationReadback {
        DegradationReadback {
            sum: Readback::record(ctx, encoder, self.sums.buffer(), 1),
            inner: self.tris.saturating_sub(1),
        }
    }

    /// Records the histogram of the last GPU build's Morton codes in `bins` bins, and its read-back: the
    /// characteriser's histogram ([`crate::characterize`]), equal bin for bin to the CPU's for the same
    /// bin count — pass [`SceneProfile::bins`](crate::characterize::SceneProfile::bins) of a CPU profile,
    /// or [`doane_bins`](crate::characterize::doane_bins) of a skewness you track. Costs one pass over
    /// the codes the build sorted anyway (no extra memory beyond 1 KiB of counts).
    ///
    /// The bin count is a per-mesh parameter written at the next submission: record one histogram per
    /// mesh per submission. Errors before a GPU build (an uploaded CPU tree has no codes) or for a bin
    /// count outside `1..=MAX_HISTOGRAM_BINS`.
    pub fn record_histogram(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        bins: usize,
    ) -> Result<Readback<u32>> {
        if !(1..=MAX_HISTOGRAM_BINS).contains(&bins) {
            return Err(Error::Gpu(format!(
                "histogram bin count {bins} is outside 1..={MAX_HISTOGRAM_BINS}"
            )));
        }
        if self.tris > 0 && !self.coded {
            return Err(Error::Gpu(
                "histogram before a GPU build: the Morton codes come from record_build".into(),
            ));
        }
        self.params
            .write(ctx, SLOT_HISTOGRAM, [self.tris, bins as u32, 0, 0]);
        let k = &ctx.kernels;
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace histogram"),
                timestamp_writes: None,
            });
            pass.set_bind_group(
                0,
                &self.histogram_group,
                &[ParamSlots::offset(SLOT_HISTOGRAM)],
            );
            pass.set_pipeline(k.histogram.pipeline("histogram_clear"));
            pass.dispatch_workgroups(1, 1, 1);
            if self.tris > 0 {
                let (x, y) = ctx.groups(self.tris, 256);
                pass.set_pipeline(k.histogram.pipeline("histogram"));
                pass.dispatch_workgroups(x, y, 1);
            }
        }
        Ok(Readback::record(
            ctx,
            encoder,
            self.histogram.buffer(),
            bins,
        ))
    }

    /// Reads the current vertex positions back (blocking), e.g. after GPU skinning.
    pub fn read_positions(&self, ctx: &GpuContext) -> Result<Vec<Vec3>> {
        let mut enc = ctx.encoder();
        let r = Readback::<Vec3>::record(
            ctx,
            &mut enc,
            self.positions.buffer(),
            self.vertices as usize,
        );
        ctx.submit(enc);
        r.wait(ctx)
    }

    /// Rebuilds with LBVH from `mesh`'s positions and reads the tree back as a [`MeshBvh`] over `mesh`: a
    /// GPU build for CPU queries, equal to a CPU LBVH build (see [`read_tree`](Self::read_tree)). `mesh`
    /// must have the topology this tree was made for. Blocking: costs the upload of the positions (12 bytes
    /// per vertex), the build, the read-back of 36 bytes per triangle and the pairing with the mesh, O(n)
    /// on the CPU. Use it where the GPU builds faster than the CPU even with the round trip (large meshes,
    /// a fast GPU); [`AdaptivePolicy`](crate::adaptive::AdaptivePolicy) measures that per mesh.
    ///
    /// Errors: [`Error::VertexCountMismatch`] or [`Error::InvalidOption`] for a mesh of another size,
    /// [`Error::NonFiniteVertex`], or a GPU error.
    pub fn build_for_cpu(&mut self, ctx: &GpuContext, mesh: &Mesh) -> Result<MeshBvh> {
        if mesh.triangle_count() != self.tris as usize {
            return Err(Error::InvalidOption(format!(
                "a GPU tree for {} triangles cannot be built over {}",
                self.tris,
                mesh.triangle_count()
            )));
        }
        self.upload_positions(ctx, mesh.positions())?;
        let mut enc = ctx.encoder();
        self.record_build(ctx, &mut enc);
        ctx.submit(enc);
        Ok(MeshBvh::from_tree(mesh, self.read_tree(ctx)?))
    }

    /// Reads the tree back (blocking): the same [`Bvh`] a CPU build produces.
    pub fn read_tree(&self, ctx: &GpuContext) -> Result<Bvh> {
        if self.tris == 0 {
            return Ok(Bvh::default());
        }
        let mut enc = ctx.encoder();
        let nodes = Readback::<Node>::record(
            ctx,
            &mut enc,
            self.nodes.buffer(),
            self.node_count() as usize,
        );
        let prims = Readback::<u32>::record(ctx, &mut enc, self.vals.buffer(), self.tris as usize);
        ctx.submit(enc);
        Ok(Bvh::from_parts(nodes.wait(ctx)?, prims.wait(ctx)?))
    }
}

/// The degradation metric of a GPU refit on its way back.
pub struct DegradationReadback {
    sum: Readback<[f32; 2]>,
    inner: u32,
}

impl DegradationReadback {
    /// The metric (see [`Bvh::refit`]), blocking until the GPU is done.
    pub fn wait(self, ctx: &GpuContext) -> Result<f32> {
        let inner = self.inner;
        let s = self.sum.wait(ctx)?[0];
        Ok(metric(s, inner))
    }

    /// The metric if the GPU has finished it, without blocking (for decisions one frame late).
    pub fn try_take(&self, ctx: &GpuContext) -> Option<Result<f32>> {
        (self.sum.try_take(ctx)).map(|r| r.map(|s| metric(s[0], self.inner)))
    }
}

/// The degradation metric from the reduction's two partial sums over `inner` inner nodes.
fn metric(s: [f32; 2], inner: u32) -> f32 {
    let total = s[0] as f64 + s[1] as f64;
    if inner == 0 {
        0.0
    } else {
        (total / inner as f64) as f32
    }
}
