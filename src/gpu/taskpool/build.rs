//! A BVH build on the task pool (seed 004 §4, thesis §5.2's top-down split; shaders/taskpool_build.wgsl):
//! one task per node of more than [`POOL_SMALL`] triangles, splitting its range at the middle of its
//! centroid bounds' longest axis. A split is one step of work chunks (64 ids each) that scatter the ids
//! into a second array, left side from the range's start, right side from its end, with atomic cursors,
//! and accumulate each side's box and centroid bounds; when the step ends, the task writes its node and
//! its children follow — a child of at most [`POOL_SMALL`] triangles is built whole by the invocation that
//! advances the parent (leaves of one triangle, the same split rule), a larger one becomes a child task,
//! planned at once because its bounds are already known. Ranges whose centroids the middle cannot separate
//! (identical triangles), and every range from depth 36 on, are halved in slot order instead (their halves
//! then run one step to find their bounds), which keeps every leaf above [`MAX_DEPTH`](crate::bvh::MAX_DEPTH).
//!
//! Leaves hold one triangle, so a range of `k` triangles owns exactly `2k − 1` nodes and every task knows
//! where its node and its descendants' block lie from its range alone: the tree comes out in the crate's
//! layout (children side by side, each subtree's descendants one contiguous block) with no layout pass,
//! and is read back for CPU queries. The split is [`Builder::Median`](crate::bvh::Builder::Median)'s, with
//! its rounding and tie rules, so the tree equals a CPU median build with leaves of one triangle node for
//! node wherever no range of more than [`POOL_SMALL`] triangles needs a fallback cut (there the CPU cuts at
//! the object median, the pool halves the range in slot order, which may differ between runs since chunks
//! scatter ids in the order they claim slots). Binned SAH did not fit the time (16 bins × 3 axes × 7 words
//! per live task); the tree's SAH cost is reported against [`Builder::SAH`](crate::bvh::Builder::SAH)'s
//! (1.11 on soups of 1k triangles, 1.29 at 2^20, 0.85 to 1.0 on the extreme scenes).
//!
//! Why no invocation spin-waits on another workgroup: the pool's rounds are fixed sequences of dispatches
//! (see [the pool](super)); inside one, chunks only add to atomic cursors and atomic minima and maxima, and
//! a task reads what its chunks accumulated only in the advancing dispatch that follows. Tasks own
//! disjoint id ranges and node blocks, so none reads another's unfinished data.
//!
//! When to use it: a GPU rebuild without the SAH builder's per-level bins (scratch about 13 bytes per
//! triangle of task records, against the SAH builder's ~50), or as the pool's example of a build. Cost:
//! one round of the pool per level of tasks (about `log2(n / 32)` on even meshes, two more per halved
//! level, one parked round for halved nodes' area ratios), each a fixed sequence of dispatches; one
//! submission per 8 rounds with a blocking 64-byte read; then the read-back of 36 bytes per triangle.
//! Memory: see [`PoolBuild::bytes`].

use super::{MAX_TASK_CAPACITY, PoolCounts, TaskKind, TaskPool};
use crate::bvh::{Bvh, MeshBvh, Node};
use crate::gpu::GpuContext;
use crate::gpu::buffers::{GpuBuffer, Readback};
use crate::{Error, Mesh, Result};

/// Ranges of at most this many triangles are built by one invocation (the shader's `SMALL`).
pub const POOL_SMALL: u32 = 32;
/// Words per build task record (the shader's `STRIDE`).
const WORDS: u32 = 48;
/// Ids per work chunk (the shader's `ELEMS`).
const ELEMS: u32 = 64;

/// A tree built on the task pool, and what the build did.
#[derive(Clone, Debug)]
pub struct PoolBuild {
    /// The tree over the mesh, one triangle per leaf.
    pub bvh: MeshBvh,
    /// Rounds, tasks, chunks, dispatches and submissions of the pool run that succeeded (a run that ran out
    /// of task records first is not counted), plus the read-back's submission.
    pub counts: PoolCounts,
    /// GPU memory the build held: positions, indices, two id arrays (8 bytes per triangle), the nodes
    /// (64), the pool's task records (192 bytes per task) and lists, in bytes.
    pub bytes: u64,
}

/// Task records a first run gets: a tree whose every task has more than [`POOL_SMALL`] triangles has
/// about `n / 22` tasks on even meshes (47 for a soup of 1025); a run that needs more is run again with
/// [`worst_capacity`].
fn first_capacity(n: u32) -> u32 {
    (n / 16 + 64).min(MAX_TASK_CAPACITY)
}

/// Tasks any tree can need: tasks with no task child hold disjoint ranges of more than [`POOL_SMALL`]
/// triangles, those with two are fewer, and each one with one task child hands at least one triangle to
/// a small build, so `n + 2n / 33` bounds them.
fn worst_capacity(n: u32) -> u32 {
    (n + 2 * n / (POOL_SMALL + 1) + 1).min(MAX_TASK_CAPACITY)
}

/// Builds a BVH of `mesh` on the GPU task pool and reads it back for CPU queries. Blocking.
///
/// Errors: [`Error::TaskPoolFull`] for a mesh past the pool's [`MAX_TASK_CAPACITY`] that needs more tasks,
/// or a GPU error.
pub fn build_bvh(ctx: &GpuContext, mesh: &Mesh) -> Result<PoolBuild> {
    build_from(ctx, mesh, first_capacity(mesh.triangle_count() as u32))
}

/// [`build_bvh`] whose first run gets `capacity` task records (test hook, feature `testing`): a small one
/// makes the first run fail and the build run again with room for any tree.
#[cfg(feature = "testing")]
pub fn build_bvh_from_capacity(ctx: &GpuContext, mesh: &Mesh, capacity: u32) -> Result<PoolBuild> {
    build_from(ctx, mesh, capacity)
}

fn build_from(ctx: &GpuContext, mesh: &Mesh, first: u32) -> Result<PoolBuild> {
    let n = mesh.triangle_count() as u32;
    if n == 0 {
        return Ok(PoolBuild {
            bvh: MeshBvh::from_tree(mesh, Bvh::default()),
            counts: PoolCounts::default(),
            bytes: 0,
        });
    }
    let positions = GpuBuffer::storage(
        ctx,
        "pool build positions",
        mesh.positions().len() as u64 * 12,
    );
    positions.write(ctx, mesh.positions());
    let indices = GpuBuffer::storage(ctx, "pool build indices", mesh.indices().len() as u64 * 4);
    indices.write(ctx, mesh.indices());
    let ids = GpuBuffer::storage(ctx, "pool build ids", n as u64 * 4);
    let other = GpuBuffer::storage(ctx, "pool build other ids", n as u64 * 4);
    let nodes = GpuBuffer::storage(ctx, "pool build nodes", (2 * n as u64 - 1) * 32);
    let data = [&positions, &indices, &ids, &other, &nodes];
    let inputs: u64 = data.iter().map(|b| b.buffer().size()).sum();
    let mut counts;
    let mut capacity = first;
    let pool = loop {
        ids.write(ctx, &(0..n).collect::<Vec<u32>>());
        let kind = TaskKind {
            module: |k| &k.pool_build,
            words: WORDS,
        };
        let pool = TaskPool::new(ctx, kind, &data, capacity, [n, 0])?;
        match pool.run(ctx, &root(n), &[]) {
            Ok((c, _)) => {
                counts = c;
                break pool;
            }
            Err(Error::TaskPoolFull { .. }) if capacity < worst_capacity(n) => {
                capacity = worst_capacity(n);
            }
            Err(e) => return Err(e),
        }
    };
    let mut enc = ctx.encoder();
    let tree = Readback::<Node>::record(ctx, &mut enc, nodes.buffer(), 2 * n as usize - 1);
    let prims = Readback::<u32>::record(ctx, &mut enc, ids.buffer(), n as usize);
    ctx.submit(enc);
    counts.submissions += 1;
    let bvh = Bvh::from_parts(tree.wait(ctx)?, prims.wait(ctx)?);
    Ok(PoolBuild {
        bvh: MeshBvh::from_tree(mesh, bvh),
        counts,
        bytes: inputs + pool.memory_bytes(),
    })
}

/// The root task: every triangle, node 0 and the block from 1, a BOUNDS step first.
fn root(n: u32) -> Vec<u32> {
    let mut r = vec![0u32; WORDS as usize];
    r[..8].copy_from_slice(&[0, n, 0, n.div_ceil(ELEMS), 0, 1, 0, 0]);
    // Empty bounds in the shader's order-preserving words: minima at f32::MAX, maxima at -f32::MAX.
    for k in 0..3 {
        for (at, word) in [
            (8, 0xff7f_ffff),
            (11, 0x0080_0000),
            (14, 0xff7f_ffff),
            (17, 0x0080_0000),
        ] {
            r[at + k] = word;
        }
    }
    r
}
