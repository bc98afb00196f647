//! PLOC on the GPU (shaders/ploc.wgsl): the clustering rounds of [`Builder::Ploc`](crate::bvh::Builder::Ploc)
//! after the LBVH builder's Morton sort, with the CPU builder's tie rules, so the tree equals a CPU PLOC build
//! node for node.
//!
//! Use it where the GPU clusters faster than the CPU (large meshes, a real GPU) and the tree is wanted on the
//! CPU or re-uploaded for GPU tracing. The merge tree is read back and laid out in the crate's node order on
//! the CPU (O(n), the same code as the CPU builder); the rounds themselves never wait for the host.

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, Readback, bind_group};
use super::bvh::{BuildPhase, GpuMeshBvh};
use crate::bvh::build_ploc::{MAX_PLOC_RADIUS, MergeTree, lay_out};
use crate::bvh::{Bvh, MeshBvh};
use crate::{Error, Mesh, Result};

/// Rounds recorded per submission after the first batch; finished rounds cost empty indirect dispatches.
const ROUNDS_PER_BATCH: u32 = 8;
/// Dispatches per clustering round (nearest, merge + local scan, block scan, compact, advance).
const DISPATCHES_PER_ROUND: u32 = 5;
/// Words of the state buffer: (unused 0..3), clusters left, next node id, next count, rounds run.
const STATE_WORDS: u64 = 8;

/// What one GPU PLOC build did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlocBuildCounts {
    /// Clustering rounds that merged something.
    pub rounds: u32,
    /// Compute dispatches recorded (sort and rounds, finished rounds' empty ones included).
    pub dispatches: u32,
    /// Queue submissions, each followed by a blocking read-back of the cluster count or the tree.
    pub submissions: u32,
}

/// A mesh's PLOC builder on the GPU: buffers for one mesh size, reused across builds.
///
/// Memory (see [`memory_bytes`](Self::memory_bytes)): the LBVH builder's buffers it sorts with (about 110
/// bytes per triangle, see [`GpuMeshBvh`]) and nothing per triangle beyond them: the clustering state
/// (cluster boxes 64 over `2n - 1` ids, the cluster list in the unused fourth word of the first `n`
/// boxes' minima, the survivors' list, neighbours and scan offsets 12, merge links 8) lives in that
/// tree's buffers that the sort leaves free (`GpuMeshBvh`'s PLOC scratch); only the scan's block sums
/// (4 bytes per 256 triangles) and a few words of state are its own.
pub struct GpuPloc {
    lbvh: GpuMeshBvh,
    radius: u32,
    state: GpuBuffer,
    args: GpuBuffer,
    _params: ParamSlots,
    /// [0] writes the indirect arguments (direct dispatches), [1] binds a stand-in (indirect dispatches).
    groups: [wgpu::BindGroup; 2],
    _scratch: Vec<GpuBuffer>,
    counts: PlocBuildCounts,
}

impl GpuPloc {
    /// Uploads `mesh` and allocates everything a build needs. Errors: [`Error::InvalidOption`] for a radius
    /// outside `1..=MAX_PLOC_RADIUS`.
    pub fn new(ctx: &GpuContext, mesh: &Mesh, radius: u32) -> Result<Self> {
        if !(1..=MAX_PLOC_RADIUS).contains(&radius) {
            return Err(Error::InvalidOption(format!(
                "PLOC radius {radius} is outside 1..={MAX_PLOC_RADIUS}"
            )));
        }
        let lbvh = GpuMeshBvh::new(ctx, mesh)?;
        lbvh.use_cube_codes(ctx);
        let n = lbvh.triangle_count().max(1) as u64;
        // Boxes over the node buffer, the clusters in its boxes' spare words, survivors over the level
        // order, neighbours over the parents, scan offsets over the Morton codes, merge links over the
        // children.
        let [boxes, offsets, next, children, nn] = lbvh.ploc_scratch();
        let sums = GpuBuffer::storage(ctx, "ploc block sums", n.div_ceil(256) * 4);
        let state = GpuBuffer::storage(ctx, "ploc state", STATE_WORDS * 4);
        let args = GpuBuffer::new(
            ctx,
            "ploc dispatch args",
            12,
            super::buffers::STORAGE | wgpu::BufferUsages::INDIRECT,
        );
        let stand_in = GpuBuffer::storage(ctx, "ploc stand-in", 16);
        // The device's workgroups per dimension: where the kernels' own indirect sizes fold.
        let params = ParamSlots::new(
            ctx,
            &[[
                lbvh.triangle_count(),
                radius,
                ctx.max_groups().min(0xffff),
                0,
            ]],
        );
        let with = |a: &GpuBuffer| {
            bind_group(
                ctx,
                &ctx.kernels.ploc.layout,
                &[
                    lbvh.positions_binding(),
                    lbvh.indices_binding(),
                    lbvh.sorted_ids_binding(),
                    boxes.binding(),
                    boxes.binding(),
                    next.binding(),
                    nn.binding(),
                    offsets.binding(),
                    sums.binding(),
                    children.binding(),
                    state.binding(),
                    params.binding(),
                    a.binding(),
                ],
            )
        };
        let groups = [with(&args), with(&stand_in)];
        Ok(Self {
            lbvh,
            radius,
            state,
            args,
            _params: params,
            groups,
            _scratch: vec![sums, stand_in],
            counts: PlocBuildCounts::default(),
        })
    }

    /// The search radius.
    pub fn radius(&self) -> u32 {
        self.radius
    }

    /// GPU memory held (the mesh, the sort and all clustering scratch), in bytes.
    pub fn memory_bytes(&self) -> u64 {
        let own = [&self.state, &self.args];
        own.into_iter()
            .chain(&self._scratch)
            .map(|b| b.buffer().size())
            .sum::<u64>()
            + self._params.memory_bytes()
            + self.lbvh.memory_bytes()
    }

    /// What the last [`build_for_cpu`](Self::build_for_cpu) did.
    pub fn counts(&self) -> PlocBuildCounts {
        self.counts
    }

    /// Builds a PLOC tree from `mesh`'s positions on the GPU and returns it paired with `mesh`: equal node
    /// for node to `MeshBvh::build(mesh, &BuildOptions::new(Builder::Ploc { radius }))` with one triangle per
    /// leaf. Blocking: a submission per batch of rounds (about `log n` rounds in all), each ending in a read
    /// of the cluster count, then the read-back of 12 bytes per triangle and the O(n) layout on the CPU.
    ///
    /// Errors: [`Error::InvalidOption`] or [`Error::VertexCountMismatch`] for a mesh of another size,
    /// [`Error::NonFiniteVertex`], or a GPU error.
    pub fn build_for_cpu(&mut self, ctx: &GpuContext, mesh: &Mesh) -> Result<MeshBvh> {
        let n = self.lbvh.triangle_count();
        if mesh.triangle_count() != n as usize {
            return Err(Error::InvalidOption(format!(
                "a GPU PLOC builder for {n} triangles cannot build over {}",
                mesh.triangle_count()
            )));
        }
        self.lbvh.upload_positions(ctx, mesh.positions())?;
        self.counts = PlocBuildCounts::default();
        if n == 0 {
            return Ok(MeshBvh::from_tree(mesh, Bvh::default()));
        }
        let mut enc = ctx.encoder();
        self.lbvh
            .record_build_phase(ctx, &mut enc, BuildPhase::Sort);
        self.counts.dispatches += self.lbvh.sort_phase_dispatches();
        let k = &ctx.kernels.ploc;
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            let (x, y) = ctx.groups(n, 256);
            pass.set_pipeline(k.pipeline("ploc_init"));
            pass.set_bind_group(0, &self.groups[0], &[0]);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.counts.dispatches += 1;
        // A first batch long enough for most meshes (PLOC needs somewhat more than log2 n rounds).
        let mut batch = 2 * (32 - n.leading_zeros()) + ROUNDS_PER_BATCH;
        let mut recorded = 0;
        loop {
            self.record_rounds(ctx, &mut enc, batch);
            recorded += batch;
            let state =
                Readback::<u32>::record(ctx, &mut enc, self.state.buffer(), STATE_WORDS as usize);
            ctx.submit(enc);
            self.counts.submissions += 1;
            let state = state.wait(ctx)?;
            self.counts.rounds = state[6];
            if state[3] <= 1 {
                break;
            }
            // Each round merges at least one pair (see build_ploc.rs), so n - 1 rounds always suffice.
            if recorded >= n {
                return Err(Error::Gpu(format!(
                    "PLOC clustering still has {} clusters after {recorded} rounds",
                    state[3]
                )));
            }
            batch = ROUNDS_PER_BATCH;
            enc = ctx.encoder();
        }
        let mut enc = ctx.encoder();
        let [boxes, _, _, children, _] = self.lbvh.ploc_scratch();
        // The last cluster, the root, is the cluster list's first entry: word 3 of the node buffer.
        let root = Readback::<u32>::record(ctx, &mut enc, boxes.buffer(), 4);
        let children =
            Readback::<[u32; 2]>::record(ctx, &mut enc, children.buffer(), n as usize - 1);
        let leaves = self.lbvh.record_sorted_ids(ctx, &mut enc);
        ctx.submit(enc);
        self.counts.submissions += 1;
        let tree = MergeTree {
            root: root.wait(ctx)?[3],
            children: children.wait(ctx)?,
        };
        let (nodes, prims) = lay_out(&mesh.triangle_bounds(), leaves.wait(ctx)?, &tree, 1, true);
        Ok(MeshBvh::from_tree(mesh, Bvh::from_parts(nodes, prims)))
    }

    fn record_rounds(&mut self, ctx: &GpuContext, enc: &mut wgpu::CommandEncoder, rounds: u32) {
        let k = &ctx.kernels.ploc;
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace ploc rounds"),
            timestamp_writes: None,
        });
        let [direct, indirect] = &self.groups;
        let args = self.args.buffer();
        for _ in 0..rounds {
            pass.set_bind_group(0, indirect, &[0]);
            for entry in ["ploc_nearest", "ploc_merge"] {
                pass.set_pipeline(k.pipeline(entry));
                pass.dispatch_workgroups_indirect(args, 0);
            }
            pass.set_bind_group(0, direct, &[0]);
            pass.set_pipeline(k.pipeline("ploc_block_scan"));
            pass.dispatch_workgroups(1, 1, 1);
            pass.set_bind_group(0, indirect, &[0]);
            pass.set_pipeline(k.pipeline("ploc_compact"));
            pass.dispatch_workgroups_indirect(args, 0);
            pass.set_bind_group(0, direct, &[0]);
            pass.set_pipeline(k.pipeline("ploc_advance"));
            pass.dispatch_workgroups(1, 1, 1);
        }
        self.counts.dispatches += rounds * DISPATCHES_PER_ROUND;
    }
}
