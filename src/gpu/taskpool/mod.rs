//! The persistent task pool of seed 004 (shaders/taskpool.wgsl): tasks → phases → steps → work chunks.
//!
//! A task owns a range of elements and walks through phases; each phase runs steps, and a step is cut into
//! work chunks that any invocation may run. The pool keeps a compact task record (8 words) per task in one
//! array, two live lists of task ids (this round's and the next's), and a word of chunk offsets per live
//! task. Atomics hand out chunks (one claim counter per round), accumulate chunk results into their task, and
//! allocate ids for child tasks that a finishing phase inserts.
//!
//! # Bounded rounds, bounded claims
//!
//! WGSL promises no forward progress between workgroups, so no invocation here ever waits for another: a
//! round is a fixed sequence of dispatches (plan, the crate's scan, size, work, advance,
//! finish). `size` reads the round's chunk total and sizes the work dispatch so that its invocations, each
//! claiming at most a few chunks (4) from one atomic cursor, cover every chunk; an invocation that finds no
//! chunk left leaves. Phase changes and child insertion read chunk results only in the next dispatch, after
//! the boundary that makes them visible. Rounds are recorded in batches; `finish` writes the next round's
//! indirect workgroup counts, which are zero once the pool is empty, so surplus rounds of a batch cost only
//! empty dispatches. After each batch the host reads three words and records another batch only while
//! tasks are live.
//!
//! Why the claims are bounded: an earlier version ran 32 persistent workgroups that claimed chunks until
//! none were left. On lavapipe, whose few threads run workgroups one after the other, the first workgroups
//! took nearly every chunk, and llvmpipe stops any shader invocation's loops after 65535 iterations in all
//! (its loop limiter): past about 2^15 chunks in one round the chunk search left its loop early and 8
//! chunks were summed into the wrong task (`tests/gpu_taskpool.rs`, the 2^16-task case). Bounded claims
//! keep every invocation's loop count small on any driver.
//!
//! # Task kinds
//!
//! A kind appends its WGSL to the pool's core and defines its record, chunks and phase changes:
//! [`build_bvh`] (a BVH build, public), [`dacrt`] (divide-and-conquer ray tracing, public) and the toy `sum_tree` (a test hook, feature
//! `testing`). When to use the pool: for divide-and-conquer work whose parallelism changes shape as it
//! runs (few large tasks, then many small ones) without a host round trip per level. Cost per round: 6
//! dispatches plus the scan's (2 per factor of 256 live tasks), no host work; one submission and a
//! blocking 64-byte read per 8 rounds.
//!
//! # Bounds
//!
//! A pool holds at most `capacity` tasks over a whole run (task records are kept so that results can be read
//! back), and at most [`MAX_TASK_CAPACITY`] (2^22; the indirect dispatches over live tasks then stay within
//! 16384 workgroups of 256). A run that asks for more tasks stops inserting, finishes the tasks it has, and
//! returns [`Error::TaskPoolFull`] with the number of tasks it asked for. Every round retires, parks or
//! advances every live task, a task kind gives each task finitely many phases, and parked tasks run once
//! more, so a run ends.

mod build;
mod dacrt;
#[cfg(feature = "testing")]
mod sum_tree;
#[cfg(feature = "testing")]
pub use build::build_bvh_from_capacity;
pub use build::{POOL_SMALL, PoolBuild, build_bvh};
pub use dacrt::{DacrtHit, DacrtOptions, dacrt};
#[cfg(feature = "testing")]
pub use sum_tree::{SumTask, sum_tree};

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, Readback, STORAGE, bind_group};
use super::kernels::{Kernels, Module};
use super::scan::Scan;
use crate::{Error, Result};

/// The most tasks a pool can hold.
pub const MAX_TASK_CAPACITY: u32 = 1 << 22;
/// Words of the pool state (the core's 10, then the task kind's).
const STATE_WORDS: usize = 16;
/// Indirect argument words: per-task kernels, the work kernel, three scan levels.
const ARG_WORDS: usize = 15;
/// Rounds recorded per submission.
const ROUNDS_PER_BATCH: u32 = 8;
/// Dispatches per round besides the scan's.
const POOL_DISPATCHES: u32 = 5;

/// What one pool run did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolCounts {
    /// Rounds that had live tasks.
    pub rounds: u32,
    /// Tasks created, the root included.
    pub tasks: u32,
    /// Work chunks run.
    pub chunks: u32,
    /// Compute dispatches recorded (empty ones of finished rounds included).
    pub dispatches: u32,
    /// Queue submissions, each followed by a blocking read of the pool state.
    pub submissions: u32,
}

/// One kind of task: its kernels (taskpool.wgsl with the kind's file appended) and record size.
pub(crate) struct TaskKind {
    /// The kind's module among the crate's kernels.
    pub module: fn(&Kernels) -> &Module,
    /// Words per task record.
    pub words: u32,
}

/// Buffers of one pool: task records, live lists, offsets and their scan, state and indirect arguments.
/// Memory: 4 bytes per record word and task, 16 bytes per task of lists and offsets, plus the scan's
/// scratch.
pub(crate) struct TaskPool {
    capacity: u32,
    kind: TaskKind,
    tasks: GpuBuffer,
    live: GpuBuffer,
    state: GpuBuffer,
    args: GpuBuffer,
    scan: Scan,
    _params: ParamSlots,
    /// [0] binds the indirect arguments (the `finish` kernel), [1] a stand-in (indirect dispatches).
    groups: [wgpu::BindGroup; 2],
    _scratch: Vec<GpuBuffer>,
}

impl TaskPool {
    /// A pool of `capacity` tasks of `kind`; the kind's buffers are `data[0]` at binding 0 and the rest
    /// from binding 7 on, and its two parameters (`leaf` and `chunk` in the shader) are `kind_params`.
    /// Errors: [`Error::InvalidOption`] for a capacity outside `1..=MAX_TASK_CAPACITY`.
    pub fn new(
        ctx: &GpuContext,
        kind: TaskKind,
        data: &[&GpuBuffer],
        capacity: u32,
        kind_params: [u32; 2],
    ) -> Result<Self> {
        if !(1..=MAX_TASK_CAPACITY).contains(&capacity) {
            return Err(Error::InvalidOption(format!(
                "task pool capacity {capacity} is outside 1..={MAX_TASK_CAPACITY}"
            )));
        }
        let c = capacity as u64;
        let tasks = GpuBuffer::storage(ctx, "pool tasks", c * kind.words as u64 * 4);
        let live = GpuBuffer::storage(ctx, "pool live lists", 3 * c * 4);
        let offsets = GpuBuffer::storage(ctx, "pool offsets", c * 4);
        let state = GpuBuffer::storage(ctx, "pool state", STATE_WORDS as u64 * 4);
        let args = GpuBuffer::new(
            ctx,
            "pool dispatch args",
            ARG_WORDS as u64 * 4,
            STORAGE | wgpu::BufferUsages::INDIRECT,
        );
        let stand_in = GpuBuffer::storage(ctx, "pool stand-in", ARG_WORDS as u64 * 4);
        let scan = Scan::new(ctx, &offsets, capacity);
        let [a, b] = kind_params;
        let params = ParamSlots::new(ctx, &[[capacity, a, b, ctx.max_groups()]]);
        let with = |args: &GpuBuffer| {
            let mut entries = vec![
                data[0].binding(),
                tasks.binding(),
                live.binding(),
                offsets.binding(),
                state.binding(),
                params.binding(),
                args.binding(),
            ];
            entries.extend(data[1..].iter().map(|d| d.binding()));
            bind_group(ctx, &(kind.module)(&ctx.kernels).layout, &entries)
        };
        let groups = [with(&args), with(&stand_in)];
        Ok(Self {
            capacity,
            kind,
            tasks,
            live,
            state,
            args,
            scan,
            _params: params,
            groups,
            _scratch: vec![offsets, stand_in],
        })
    }

    /// Starts a run with one root task (`root`: its record, task id 0) and the task kind's state words
    /// (`kind_state`, from word 10 on) and runs rounds until the pool is empty. Blocking: one submission
    /// per batch of rounds; returns the counts and the final state words. Errors:
    /// [`Error::TaskPoolFull`] when tasks asked for more room than the capacity, or a GPU error.
    pub fn run(
        &self,
        ctx: &GpuContext,
        root: &[u32],
        kind_state: &[u32],
    ) -> Result<(PoolCounts, Vec<u32>)> {
        self.tasks.write(ctx, root);
        self.live.write(ctx, &[0u32]);
        let mut state = [0u32; STATE_WORDS];
        state[..3].copy_from_slice(&[1, 0, 1]);
        state[10..10 + kind_state.len()].copy_from_slice(kind_state);
        self.state.write(ctx, &state);
        let first = [1u32; ARG_WORDS];
        ctx.write_buffer(self.args.buffer(), 0, bytemuck::cast_slice(&first));
        let mut counts = PoolCounts::default();
        loop {
            let mut enc = ctx.encoder();
            self.record_rounds(ctx, &mut enc, ROUNDS_PER_BATCH);
            counts.dispatches += ROUNDS_PER_BATCH * (POOL_DISPATCHES + self.scan.dispatches());
            let state = Readback::<u32>::record(ctx, &mut enc, self.state.buffer(), STATE_WORDS);
            ctx.submit(enc);
            counts.submissions += 1;
            let s = state.wait(ctx)?;
            counts.rounds = s[5] + 1;
            counts.tasks = s[2].min(self.capacity);
            counts.chunks = s[7];
            if s[4] > 0 {
                return Err(Error::TaskPoolFull {
                    capacity: self.capacity as usize,
                    asked: s[4] as usize,
                });
            }
            if s[0] == 0 {
                return Ok((counts, s));
            }
        }
    }

    /// Records `rounds` rounds; a round without live tasks dispatches zero workgroups.
    fn record_rounds(&self, ctx: &GpuContext, enc: &mut wgpu::CommandEncoder, rounds: u32) {
        let k = (self.kind.module)(&ctx.kernels);
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("kinetrace task pool rounds"),
            timestamp_writes: None,
        });
        let [direct, indirect] = &self.groups;
        let args = self.args.buffer();
        for _ in 0..rounds {
            pass.set_bind_group(0, indirect, &[0]);
            pass.set_pipeline(k.pipeline("pool_plan"));
            pass.dispatch_workgroups_indirect(args, 0);
            self.scan.record(ctx, &mut pass, Some((args, 24)));
            pass.set_bind_group(0, direct, &[0]);
            pass.set_pipeline(k.pipeline("pool_size"));
            pass.dispatch_workgroups(1, 1, 1);
            pass.set_bind_group(0, indirect, &[0]);
            pass.set_pipeline(k.pipeline("pool_work"));
            pass.dispatch_workgroups_indirect(args, 12);
            pass.set_pipeline(k.pipeline("pool_advance"));
            pass.dispatch_workgroups_indirect(args, 0);
            pass.set_bind_group(0, direct, &[0]);
            pass.set_pipeline(k.pipeline("pool_finish"));
            pass.dispatch_workgroups(1, 1, 1);
        }
    }

    /// GPU memory the pool holds: task records, lists, offsets, state, arguments and the scan's scratch.
    pub fn memory_bytes(&self) -> u64 {
        [&self.tasks, &self.live, &self.state, &self.args]
            .into_iter()
            .chain(&self._scratch)
            .map(|b| b.buffer().size())
            .sum::<u64>()
            + self.scan.memory_bytes()
            + self._params.memory_bytes()
    }

    /// Reads back the words of the first `count` task records (blocking).
    #[cfg(feature = "testing")]
    pub fn read_tasks(&self, ctx: &GpuContext, count: u32) -> Result<Vec<u32>> {
        let mut enc = ctx.encoder();
        let words = (count * self.kind.words) as usize;
        let r = Readback::<u32>::record(ctx, &mut enc, self.tasks.buffer(), words);
        ctx.submit(enc);
        r.wait(ctx)
    }
}
