//! The pool's toy task (test hook, feature `testing`): a recursive halving of `0..n` into a tree of ranges,
//! each task summing its range in work chunks. It exercises every part of the pool — chunks claimed by
//! atomics, accumulation, phase ends, child insertion, the capacity bound — against an answer the CPU can
//! compute independently.

use super::{PoolCounts, TaskKind, TaskPool};
use crate::Result;
use crate::gpu::GpuContext;
use crate::gpu::buffers::GpuBuffer;

/// One task of a finished sum tree, as read back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SumTask {
    /// The task's range of elements.
    pub range: (u32, u32),
    /// The parent task's id (`None` for the root).
    pub parent: Option<u32>,
    /// Depth below the root.
    pub depth: u32,
    /// The sum of the range's values (wrapping).
    pub sum: u32,
    /// The first of the two children's ids (`None` for a leaf).
    pub first_child: Option<u32>,
}

/// Runs the sum tree over `values` on the GPU: ranges longer than `leaf` split in halves (the lower half
/// gets `len / 2`), `chunk` elements per work chunk, at most `capacity` tasks. Blocking.
///
/// Errors: [`Error::InvalidOption`](crate::Error::InvalidOption) for a bad capacity, chunk or a zero leaf,
/// [`Error::TaskPoolFull`](crate::Error::TaskPoolFull) when the tree needs more than `capacity` tasks.
pub fn sum_tree(
    ctx: &GpuContext,
    values: &[u32],
    leaf: u32,
    chunk: u32,
    capacity: u32,
) -> Result<(Vec<SumTask>, PoolCounts)> {
    if leaf == 0 || chunk == 0 {
        return Err(crate::Error::InvalidOption(format!(
            "sum tree leaf size {leaf} or chunk {chunk} is 0"
        )));
    }
    let buf = GpuBuffer::storage(ctx, "sum tree values", values.len() as u64 * 4);
    buf.write(ctx, values);
    let kind = TaskKind {
        module: |k| &k.taskpool,
        words: 8,
    };
    let pool = TaskPool::new(ctx, kind, &[&buf], capacity, [leaf, chunk])?;
    let n = values.len() as u32;
    // The root's record, its chunk count as the shader's `init_task` computes it for other tasks.
    let root = [0, n, 0, n.div_ceil(chunk), u32::MAX, 0, 0, 0];
    let (counts, _) = pool.run(ctx, &root, &[])?;
    let some = |v: u32| (v != u32::MAX).then_some(v);
    let tasks = pool
        .read_tasks(ctx, counts.tasks)?
        .chunks_exact(8)
        .map(|t| SumTask {
            range: (t[0], t[1]),
            parent: some(t[4]),
            depth: t[5],
            sum: t[6],
            first_child: (t[7] != 0).then_some(t[7]),
        })
        .collect();
    Ok((tasks, counts))
}
