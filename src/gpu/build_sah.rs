//! GPU binned SAH builder with breadth-first work queues (Lauterbach thesis §5.2), driving
//! `shaders/sah_build.wgsl` into a [`GpuMeshBvh`]'s buffers.
//!
//! Each level of the tree is one round of fixed passes over a queue of nodes: centroid bounds and 16 bins
//! per axis filled in parallel over the primitives, 45 split candidates per node evaluated in parallel and
//! min-reduced, and the primitives of every node partitioned stably by a flag and a prefix sum. Nodes of at
//! most [`SWEEP_MAX`] triangles are not binned but swept exactly, as the CPU binned SAH sweeps its small
//! nodes: every cut between the primitives sorted along each axis (§5.2.2's "as many candidates as
//! primitives"). Subtrees of at most 64 triangles go, when [`GpuSahOptions::small_split`] is on, to one
//! workgroup each that finishes them in workgroup memory (§5.2.3); the tree is the same either way. Leaves
//! hold one triangle, so the tree can be refitted and traced on the GPU like an LBVH build, and read back
//! for CPU queries.
//!
//! The tree does not depend on float rounding: centroids and boxes are quantised to a 16-bit grid by a
//! power-of-two scale (per axis for centroids, one for all axes for boxes, so that grid areas are
//! proportional to true areas), bins are integer ratios and SAH costs 64-bit integers, ties go to the more
//! balanced cut, then the lower axis, then the lower bin (the fewer on the left for a sweep). Where no cut separates the centroids (all coincide on
//! the grid), and from depth 36 on, a node is halved in slot order. The grid spans the whole mesh, so
//! triangles whose centroids lie closer than 1/65536 of its extent (a 10⁻⁶ teapot in a 10⁴ stadium) are
//! not told apart: such a cluster is split in slot order (as GPU LBVH's 10-bit grid splits it by index). `tests/gpu_sah.rs` holds a CPU
//! reference of exactly this algorithm and compares node for node.
//!
//! When to use: GPU rebuilds where tree quality matters more than build time (SAH cost close to the CPU
//! binned SAH's, against about 1.3× for LBVH on uneven meshes). Cost: per tree level, about ten dispatches
//! (indirect, so levels past the tree's depth cost empty dispatches only), 21 atomics per primitive for the
//! bins and a prefix sum over all primitives; all recorded into the caller's encoder, one submission.

use super::buffers::{GpuBuffer, ParamSlots, Readback, STORAGE, bind_group};
use super::scan::Scan;
use super::{GpuContext, GpuMeshBvh};
use crate::bvh::{Builder, MeshBvh, MortonBits};
use crate::{Error, Mesh, Result};

/// Tree levels the queue loop records (no leaf is deeper than [`crate::bvh::MAX_DEPTH`] - 1).
const LEVELS: usize = crate::bvh::MAX_DEPTH;
/// From this depth on the shader halves nodes in slot order (as the CPU builders' balanced depth).
const BALANCED: u32 = 36;
/// Subtrees of at most this many triangles go to the small-split kernel: twice the thesis's 32 (§5.2.3),
/// so that only nodes of 65 or more triangles are queued and binned, which halves the bins' memory (one
/// entry per 65 triangles, about 21 B per triangle); a node's triangles fill the 64 invocations.
pub const SMALL_SPLIT_MAX: u32 = 64;
/// Nodes of at most this many triangles are swept exactly instead of binned (the shader's SWEEP): up to
/// 189 cuts of one workgroup, each costing a pass over the node's boxes in workgroup memory.
pub const SWEEP_MAX: u32 = 64;
/// Words of the bins of one queue entry: 3 axes × 16 bins × (count, 3 minima, 3 maxima).
const ENTRY_BIN_WORDS: u64 = 3 * 16 * 7;
/// `state` words: entries per level, the small-subtree count, the scene's centroid and box bounds, and
/// the round under way and the rounds begun (the queue level every pass of a round reads).
const STATE_WORDS: u64 = LEVELS as u64 + 1 + 12 + 2;
/// Indirect argument triples: primitive passes, split pass, 4 scan levels, small subtrees.
const ARG_TRIPLES: u64 = 7;
const ARG_SPLIT: u64 = 12;
const ARG_SCAN: u64 = 24;
const ARG_SMALL: u64 = 72;

/// Options of [`GpuSahBuilder`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuSahOptions {
    /// Levels split as LBVH splits them before binned SAH takes over (thesis §5.3, the GPU hybrid): 0 for
    /// pure binned SAH, [`HYBRID_LEVELS`] by default for a hybrid. The top levels then cost one Morton sort
    /// and a binary search per node instead of binning passes; lower it for clustered scenes (a teapot in
    /// a stadium), where the Morton grid's top splits are poor.
    pub lbvh_levels: u32,
    /// Finish subtrees of at most [`SMALL_SPLIT_MAX`] triangles in one workgroup each (default on). Off,
    /// they go through the level queues like larger nodes: the same tree, more dispatched levels, and bins
    /// for up to `n / 2` nodes per level instead of `n / 65` (much more memory). For measuring the kernel.
    pub small_split: bool,
}

/// The thesis's LBVH levels for the hybrid.
pub const HYBRID_LEVELS: u32 = 6;

impl GpuSahOptions {
    /// Pure binned SAH with the small-split kernel.
    pub const SAH: GpuSahOptions = GpuSahOptions {
        lbvh_levels: 0,
        small_split: true,
    };

    /// The hybrid: `lbvh_levels` LBVH levels, binned SAH below, the small-split kernel on.
    pub const fn hybrid(lbvh_levels: u32) -> GpuSahOptions {
        GpuSahOptions {
            lbvh_levels,
            small_split: true,
        }
    }

    /// The same with the small-split kernel on or off.
    pub const fn small_split(self, on: bool) -> GpuSahOptions {
        GpuSahOptions {
            small_split: on,
            ..self
        }
    }
}

/// LBVH levels of a GPU hybrid on a clustered mesh (the characteriser's non-uniform profile): the thesis
/// (§5.3) finds Morton splits poor on a teapot in a stadium, so binned SAH takes over after at most this
/// many. Our rule, **not yet backed by our data**: on a radius-50 icosphere in a 10⁴ box (lavapipe,
/// 2026-11-24), 500 rays aimed at the teapot visited 5,986 nodes with k = 6, 6,726 with k = 2 and
/// 10,087 with pure GPU SAH; the SAH costs of the three trees are equal to 4 digits.
pub const CLUSTERED_HYBRID_LEVELS: u32 = 2;

/// A hybrid's LBVH levels: `k`, lowered to [`CLUSTERED_HYBRID_LEVELS`] on clustered meshes.
pub fn hybrid_levels(k: u32, clustered: bool) -> u32 {
    if clustered {
        k.min(CLUSTERED_HYBRID_LEVELS)
    } else {
        k
    }
}

impl GpuSahOptions {
    /// How the GPU runs `builder`: `Some(None)` for LBVH over 30-bit codes ([`GpuMeshBvh::record_build`]),
    /// `Some(Some(options))` for 16-bin SAH or a 16-bin hybrid over 30-bit codes (its levels through
    /// [`hybrid_levels`]), `None` for what the GPU does not build (other bin counts, 63-bit codes, median).
    pub fn for_builder(builder: Builder, clustered: bool) -> Option<Option<GpuSahOptions>> {
        match builder {
            Builder::Lbvh {
                morton: MortonBits::Bits30,
            } => Some(None),
            Builder::Sah { bins: GPU_BINS } => Some(Some(GpuSahOptions::SAH)),
            Builder::Hybrid {
                lbvh_levels,
                bins: GPU_BINS,
                morton: MortonBits::Bits30,
            } => Some(Some(GpuSahOptions::hybrid(hybrid_levels(
                lbvh_levels,
                clustered,
            )))),
            _ => None,
        }
    }
}

/// Bins per axis of the GPU builder (those of [`Builder::SAH`]).
pub const GPU_BINS: u32 = 16;

impl Default for GpuSahOptions {
    fn default() -> Self {
        Self::SAH
    }
}

/// Counts of one GPU SAH build, for the bench and the planner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuBuildCounts {
    /// Compute dispatches recorded: fixed per mesh size and options (a round per level that can hold a
    /// queued node, most of them empty).
    pub dispatches_recorded: u32,
    /// Dispatches that had work: those of the levels whose queue was not empty, plus the fixed ones.
    pub dispatches_run: u32,
    /// Queue levels that had nodes (the binned part of the tree's depth).
    pub levels: u32,
    /// Subtrees finished by the small-split kernel.
    pub small_subtrees: u32,
    /// Submissions per build: the builder records into the caller's encoder, so 1.
    pub submissions: u32,
}

/// Builds a [`GpuMeshBvh`]'s tree with binned SAH on the GPU. Make one per mesh size (buffers are sized for
/// its triangle count) and record builds with [`record`](Self::record).
///
/// Memory (see [`memory_bytes`](Self::memory_bytes)): nothing per triangle on top of the tree's
/// [`GpuMeshBvh::memory_bytes`] for meshes of a few hundred triangles or more with the small-split kernel
/// on. The scratch lives in the tree's buffers that the build leaves free: the slot order in the slot ids,
/// each slot's scratch id, queue entry and scratch entry (12 B) in its node's min field, the partition
/// flags (4 B) in the level order, the small subtrees (16 B each, at most `n / 2`) in the radix tree's
/// children, the level queues (64 B per queued node) in its parents, and the bins (1 368 B per queued
/// node, at most `n / 65 + 1` of them: about 21 B per triangle) in the nodes' max fields (24 B per
/// triangle), all of which the bottom-up pass overwrites. Triangles' quantised centroids and boxes are
/// computed again from the mesh where a pass needs them (three index and nine position reads instead of
/// a 20-byte cache). Where the max fields or the parents are too small (small meshes), or without the
/// small-split kernel (bins for up to `n / 2` nodes per level), bins and queues get buffers of their own.
pub struct GpuSahBuilder {
    tris: u32,
    options: GpuSahOptions,
    _params: ParamSlots,
    state: GpuBuffer,
    /// Bins and level queues of their own, where the tree's node max fields and parents are too small
    /// (else the bins are cleared in the node buffer). Boxed: most builders have none.
    own: Option<Box<[GpuBuffer; 2]>>,
    args: GpuBuffer,
    /// Binds the argument buffer (for the argument kernels).
    args_group: wgpu::BindGroup,
    /// Binds a stand-in where the arguments are (for the indirectly dispatched kernels).
    work_group: wgpu::BindGroup,
    scan: Scan,
    /// Dispatches of the mesh's LBVH sort phase (hybrid builds record it first).
    sort_phase: u32,
    /// Bound where the argument kernels bind the arguments, for the indirectly dispatched kernels.
    stand_in: GpuBuffer,
}

impl GpuSahBuilder {
    /// Allocates the scratch for building `bvh`'s mesh.
    pub fn new(ctx: &GpuContext, bvh: &GpuMeshBvh, options: GpuSahOptions) -> Result<Self> {
        let tris = bvh.triangle_count();
        let n = tris.max(1) as u64;
        // Queued nodes per level: more than SMALL_SPLIT_MAX triangles each with the kernel, 2 without.
        let per = if options.small_split {
            SMALL_SPLIT_MAX as u64 + 1
        } else {
            2
        };
        let cap = (n / per + 1) as u32;
        // Flags (4 B per triangle), the small subtrees (at most n / 2, 16 B each) and the level queues
        // live in the tree's LBVH scratch, the slot order in its slot ids and the slots' links in its nodes.
        let [flags, small, parents] = bvh.lbvh_scratch();
        // Entries and split records of two levels (4 per queued node).
        let queue_bytes = 4 * cap as u64 * 16;
        let bin_words = cap as u64 * (ENTRY_BIN_WORDS + 6);
        // The bins fit the nodes' max fields (3 words of each of the 2n - 1 nodes) and the queues the parents.
        let shared = options.small_split
            && bin_words <= 3 * (2 * n - 1)
            && queue_bytes <= parents.buffer().size();
        if !shared {
            ctx.check_storage("sah bins", bin_words * 4)?;
            ctx.check_storage("sah queues", queue_bytes)?;
        }
        let own = (!shared).then(|| {
            Box::new([
                GpuBuffer::storage(ctx, "sah bins", bin_words * 4),
                GpuBuffer::storage(ctx, "sah queues", queue_bytes),
            ])
        });
        let [positions, indices, nodes, vals, keys] = bvh.build_targets();
        let (bins, queues) = match own.as_deref() {
            Some([b, q]) => (b, q),
            None => (nodes, parents),
        };
        let state = GpuBuffer::storage(ctx, "sah state", STATE_WORDS * 4);
        let args = GpuBuffer::new(
            ctx,
            "sah dispatch args",
            ARG_TRIPLES * 12,
            STORAGE | wgpu::BufferUsages::INDIRECT,
        );
        let stand_in = GpuBuffer::storage(ctx, "sah stand-in", 16);
        // Bit 0: the small-split kernel; bit 1: bins in the node buffer; bits 8..16: LBVH levels; bits
        // 16..32: the device's workgroups per dimension, where the indirect arguments fold into y.
        let mode = u32::from(options.small_split)
            | u32::from(shared) << 1
            | options.lbvh_levels.min(LEVELS as u32) << 8
            | ctx.max_groups().min(0xffff) << 16;
        let params = ParamSlots::new(ctx, &[[tris, 0, mode, cap]]);
        let group = |a: &GpuBuffer| {
            bind_group(
                ctx,
                &ctx.kernels.sah.layout,
                &[
                    positions.binding(),
                    indices.binding(),
                    flags.binding(),
                    queues.binding(),
                    small.binding(),
                    bins.binding(),
                    state.binding(),
                    nodes.binding(),
                    vals.binding(),
                    a.binding(),
                    keys.binding(),
                    params.binding(),
                ],
            )
        };
        let args_group = group(&args);
        let work_group = group(&stand_in);
        let scan = Scan::new(ctx, flags, tris);
        Ok(Self {
            tris,
            options,
            _params: params,
            state,
            own,
            args,
            args_group,
            work_group,
            scan,
            sort_phase: bvh.sort_phase_dispatches(),
            stand_in,
        })
    }

    /// The options this builder was made with.
    pub fn options(&self) -> GpuSahOptions {
        self.options
    }

    /// Scratch memory held, in bytes (the tree and mesh are [`GpuMeshBvh::memory_bytes`]).
    pub fn memory_bytes(&self) -> u64 {
        [&self.state, &self.args, &self.stand_in]
            .into_iter()
            .chain(self.own.iter().flat_map(|b| b.iter()))
            .map(|b| b.buffer().size())
            .sum::<u64>()
            + self.scan.memory_bytes()
            + self._params.memory_bytes()
    }

    /// Queue levels recorded: enough for every node of two or more triangles. Below depth 36 (the shader's
    /// BALANCED) nodes are halved, so none of them is deeper than `36 + ⌈log2 n⌉`; LBVH levels past 36 can
    /// reach 63. None when the small-split kernel takes the whole mesh.
    fn rounds(&self) -> usize {
        let n = self.tris;
        if n < 2 || (self.options.small_split && n <= SMALL_SPLIT_MAX) {
            return 0;
        }
        if self.options.lbvh_levels > BALANCED {
            return LEVELS;
        }
        LEVELS.min((BALANCED + 32 - (n - 1).leading_zeros()) as usize)
    }

    /// Dispatches one level of the queue loop records.
    fn level_dispatches(&self) -> u32 {
        7 + self.scan.dispatches()
    }

    /// Dispatches one build records, the bottom-up boxes included.
    pub fn dispatches_recorded(&self) -> u32 {
        if self.tris == 0 {
            return 0;
        }
        2 + self.rounds() as u32 * self.level_dispatches()
            + 2
            + GpuMeshBvh::BOXES_DISPATCHES
            + self.sort_dispatches()
    }

    /// Dispatches of a hybrid's Morton codes and sort (none for pure SAH).
    fn sort_dispatches(&self) -> u32 {
        if self.options.lbvh_levels == 0 || self.tris == 0 {
            0
        } else {
            self.sort_phase
        }
    }

    /// Records a full rebuild of `bvh` (the tree this builder was made for: its buffers are bound) from its current positions into
    /// `encoder`: no submission, no read-back.
    pub fn record(
        &self,
        ctx: &GpuContext,
        bvh: &mut GpuMeshBvh,
        encoder: &mut wgpu::CommandEncoder,
    ) {
        if self.tris == 0 {
            return;
        }
        let hybrid = self.options.lbvh_levels > 0;
        if hybrid {
            bvh.record_build_phase(ctx, encoder, super::BuildPhase::Sort);
        }
        encoder.clear_buffer(self.state.buffer(), 0, None);
        let bins = match self.own.as_deref() {
            Some([bins, _]) => bins.buffer(),
            None => bvh.nodes(),
        };
        encoder.clear_buffer(bins, 0, None);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace sah build"),
            timestamp_writes: None,
        });
        let k = &ctx.kernels.sah;
        let (x, y) = ctx.groups(self.tris, 256);
        // One parameter slot: the queue level of every pass is the round's, counted on the GPU.
        let direct = |pass: &mut wgpu::ComputePass<'_>, entry: &str| {
            pass.set_pipeline(k.pipeline(entry));
            pass.set_bind_group(0, &self.work_group, &[0]);
            pass.dispatch_workgroups(x, y, 1);
        };
        let args = self.args.buffer();
        let indirect = |pass: &mut wgpu::ComputePass<'_>, entry: &str, at: u64| {
            pass.set_pipeline(k.pipeline(entry));
            pass.set_bind_group(0, &self.work_group, &[0]);
            pass.dispatch_workgroups_indirect(args, at);
        };
        let single = |pass: &mut wgpu::ComputePass<'_>, entry: &str| {
            pass.set_pipeline(k.pipeline(entry));
            pass.set_bind_group(0, &self.args_group, &[0]);
            pass.dispatch_workgroups(1, 1, 1);
        };
        direct(&mut pass, "sah_frame");
        direct(&mut pass, "sah_prims");
        for _ in 0..self.rounds() {
            single(&mut pass, "sah_args");
            indirect(&mut pass, "sah_bounds", 0);
            indirect(&mut pass, "sah_bin", 0);
            indirect(&mut pass, "sah_split", ARG_SPLIT);
            indirect(&mut pass, "sah_flag", 0);
            self.scan.record(ctx, &mut pass, Some((args, ARG_SCAN)));
            indirect(&mut pass, "sah_scatter", 0);
            indirect(&mut pass, "sah_copy", 0);
        }
        single(&mut pass, "sah_small_args");
        indirect(&mut pass, "sah_small", ARG_SMALL);
        bvh.record_boxes(ctx, &mut pass, hybrid);
    }

    /// Reads the queue counts of the last build back (blocking) and counts its dispatches.
    pub fn read_counts(&self, ctx: &GpuContext) -> Result<GpuBuildCounts> {
        let mut enc = ctx.encoder();
        let r = Readback::<u32>::record(ctx, &mut enc, self.state.buffer(), LEVELS + 1);
        ctx.submit(enc);
        let state = r.wait(ctx)?;
        let levels = state[..LEVELS].iter().filter(|&&c| c > 0).count() as u32;
        let fixed = if self.tris == 0 {
            0
        } else {
            // Frame, primitives, the argument kernel of every level, small arguments, small, boxes, and a
            // hybrid's Morton sort.
            2 + self.rounds() as u32 + 2 + GpuMeshBvh::BOXES_DISPATCHES + self.sort_dispatches()
        };
        Ok(GpuBuildCounts {
            dispatches_recorded: self.dispatches_recorded(),
            dispatches_run: fixed + levels * (self.level_dispatches() - 1),
            levels,
            small_subtrees: state[LEVELS],
            submissions: 1,
        })
    }

    /// Uploads `mesh`'s positions, rebuilds with binned SAH and reads the tree back as a [`MeshBvh`] over
    /// `mesh` (blocking): a GPU build for CPU queries, with the costs and errors of
    /// [`GpuMeshBvh::build_for_cpu`]. `bvh` must be the tree this builder was made for.
    pub fn build_for_cpu(
        &self,
        ctx: &GpuContext,
        bvh: &mut GpuMeshBvh,
        mesh: &Mesh,
    ) -> Result<MeshBvh> {
        if mesh.triangle_count() != self.tris as usize || bvh.triangle_count() != self.tris {
            return Err(Error::InvalidOption(format!(
                "a GPU SAH builder for {} triangles cannot build over {}",
                self.tris,
                mesh.triangle_count()
            )));
        }
        bvh.upload_positions(ctx, mesh.positions())?;
        let mut enc = ctx.encoder();
        self.record(ctx, bvh, &mut enc);
        ctx.submit(enc);
        Ok(MeshBvh::from_tree(mesh, bvh.read_tree(ctx)?))
    }
}
