//! The broad phase of collision detection on the GPU (shaders/collide.wgsl): the leaf pairs of two BVHs, or
//! of one BVH and itself, whose boxes overlap. The exact triangle–triangle tests stay on the CPU (they
//! need exact f64 predicates); the GPU does the traversal, which is where the time goes in a large contact.
//!
//! The walk is the CPU's (`collide::bvtt`) level by level: same box test, same split rule, so the GPU finds
//! every leaf pair the CPU finds — the same pairs exactly when both trees share a frame (or in self mode),
//! where boxes are compared as stored; when tree `b` is moved into `a`'s frame both devices widen the moved
//! boxes by a relative slack far above their rounding, so the candidate sets may differ by pairs that only
//! touch within that slack, which the exact tests then reject on both.

use super::GpuContext;
use super::buffers::{GpuBuffer, ParamSlots, Readback, STORAGE, bind_group};
use super::tree::{GpuTree, node_depths};
use crate::bvh::{MAX_DEPTH, Node};
use crate::geometry::check_finite;
use crate::{Error, Result};
use bytemuck::{Pod, Zeroable};
use glam::Affine3A;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};

/// Bytes of a queued BVTT node (`Item` in the shader: a, b, packed depths).
const ITEM_BYTES: u64 = 12;
/// Bytes of a leaf pair in the output.
const PAIR_BYTES: u64 = 8;
/// Enough rounds for any two trees: a pair's depth sum grows by one per round, by two in self mode's
/// (x, x) splits, and no tree is deeper than [`MAX_DEPTH`].
const MAX_ROUNDS: usize = 2 * MAX_DEPTH + 2;
/// Counter words: leaf pairs emitted, then the queue length of each round and of the one after the last.
const COUNT_WORDS: usize = 1 + MAX_ROUNDS + 1;
/// Counters at or past this value have saturated (the shader's `SATURATED`): capacities stay below it.
const SATURATED: u32 = 1 << 31;
/// Capacities a [`GpuPairs::new`] starts with (queue items, leaf pairs); they grow on demand.
const START_CAPACITY: u32 = 1 << 14;
/// Tries of [`GpuPairs::leaf_pairs`] before it gives up: every overflow at least doubles a buffer, so
/// this is reached only past the device's buffer limits, which [`GpuPairs::record`] reports first.
const MAX_TRIES: usize = 64;

/// The shader's `CollideParams` (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CollideParams {
    /// `b_to_a`'s linear part, columns x, y, z (w unused).
    columns: [[f32; 4]; 3],
    /// `b_to_a`'s translation (w unused).
    translation: [f32; 4],
    /// 0: boxes compared as stored; 1: `b`'s boxes moved into `a`'s frame; 2: a tree against itself.
    mode: u32,
    /// Items each queue buffer holds.
    queue_cap: u32,
    /// Leaf pairs the output holds.
    pair_cap: u32,
    /// The device's largest workgroup count per dimension.
    max_groups: u32,
}

const _: () = assert!(std::mem::size_of::<CollideParams>() == 80);

const MODE_SAME: u32 = 0;
const MODE_MOVED: u32 = 1;
const MODE_SELF: u32 = 2;

/// How much room the last query that overflowed wanted, shared by a [`GpuPairs`] and its read-backs.
#[derive(Default)]
struct Demand {
    queue: AtomicU32,
    pairs: AtomicU32,
}

/// Finds the overlapping leaf pairs of two BVHs, or of one BVH and itself, on the GPU: the broad phase of a
/// collision query, whose pairs go to the CPU's exact triangle tests. Use it where trees are large and
/// in deep contact (cloth, crowds of skinned characters, self-collision); a small query costs less on the
/// CPU, which needs no round trip.
///
/// Cost: one round per level of the pair tree, `height_a + height_b + 2` rounds of two dispatches each
/// (rounds past the last level dispatch no workgroups), all recorded into the caller's encoder with no
/// CPU wait between them; one box test per visited pair; then one read-back of the counters and the
/// output buffer. Memory: two work queues of 12 bytes per pair in the widest level and 8 bytes per leaf
/// pair found, grown by doubling when a query overflows them (the query is then run again) and reused, so
/// a steady state allocates nothing.
pub struct GpuPairs {
    /// Ping-pong queues: round `r` reads `queues[r % 2]` and appends to the other.
    queues: [GpuBuffer; 2],
    /// Leaf pairs found.
    pairs: GpuBuffer,
    /// [`COUNT_WORDS`] atomic counters.
    counts: GpuBuffer,
    /// Indirect dispatch arguments, 3 words per round.
    args: GpuBuffer,
    /// Bound where `args` would be when a dispatch reads `args` as its indirect arguments.
    stand_in: GpuBuffer,
    params: GpuBuffer,
    /// Slot `r` holds round index `r`.
    rounds: ParamSlots,
    demand: Arc<Demand>,
    /// Bind groups (even rounds, odd rounds, init and argument kernels) for the last pair of node
    /// buffers, reused while neither they nor the queues and the output change.
    groups: Option<(wgpu::Buffer, wgpu::Buffer, [wgpu::BindGroup; 3])>,
    /// Most workgroups a round dispatches (the device's limit per dimension); invocations stride over
    /// the rest of the queue.
    max_groups: u32,
    /// Node buffers that [`leaf_pairs`](Self::leaf_pairs) uploads CPU trees into.
    uploads: [GpuBuffer; 2],
    depths: Vec<u32>,
}

impl GpuPairs {
    /// Buffers for a few thousand pairs; they grow with the largest query seen.
    pub fn new(ctx: &GpuContext) -> Self {
        Self::with_capacity(ctx, START_CAPACITY, START_CAPACITY)
    }

    /// Buffers for `queue` pairs in the widest level of the traversal and `pairs` leaf pairs found (at
    /// least a few dozen each), for callers who know their queries' sizes.
    pub fn with_capacity(ctx: &GpuContext, queue: u32, pairs: u32) -> Self {
        let queue_bytes = queue as u64 * ITEM_BYTES;
        let slots: Vec<[u32; 4]> = (0..MAX_ROUNDS as u32).map(|r| [r, 0, 0, 0]).collect();
        Self {
            queues: [
                GpuBuffer::storage(ctx, "pair queue", queue_bytes),
                GpuBuffer::storage(ctx, "pair queue", queue_bytes),
            ],
            pairs: GpuBuffer::storage(ctx, "leaf pairs", pairs as u64 * PAIR_BYTES),
            counts: GpuBuffer::storage(ctx, "pair counts", COUNT_WORDS as u64 * 4),
            args: GpuBuffer::new(
                ctx,
                "pair dispatch args",
                MAX_ROUNDS as u64 * 12,
                STORAGE | wgpu::BufferUsages::INDIRECT,
            ),
            stand_in: GpuBuffer::storage(ctx, "stand-in", 16),
            params: GpuBuffer::uniform(ctx, "collide params"),
            rounds: ParamSlots::new(ctx, &slots),
            demand: Default::default(),
            groups: None,
            max_groups: ctx.device.limits().max_compute_workgroups_per_dimension,
            uploads: [
                GpuBuffer::storage(ctx, "pair nodes a", 0),
                GpuBuffer::storage(ctx, "pair nodes b", 0),
            ],
            depths: Vec::new(),
        }
    }

    /// Uploads CPU trees, runs the traversal (again with grown buffers until nothing overflows) and waits:
    /// the blocking convenience, and the path for trees that live on the CPU. Pairs as in
    /// [`PairsResult::Done`].
    pub fn leaf_pairs(
        &mut self,
        ctx: &GpuContext,
        a: &[Node],
        b: Option<(&[Node], &Affine3A)>,
    ) -> Result<Vec<[u32; 2]>> {
        let height_a = self.upload(ctx, 0, a);
        let moved = b.map(|(nodes, b_to_a)| (self.upload(ctx, 1, nodes), nodes.len(), *b_to_a));
        // Handles, so that the trees borrow nothing of `self` (cloning one allocates nothing).
        let [ua, ub] = self.uploads.each_ref().map(|u| u.buffer().clone());
        for _ in 0..MAX_TRIES {
            let b = moved.map(|(h, n, t)| (tree(&ub, n, h), t));
            let mut encoder = ctx.encoder();
            let readback = self.record(ctx, &mut encoder, tree(&ua, a.len(), height_a), b)?;
            ctx.submit(encoder);
            if let PairsResult::Done(pairs) = readback.wait(ctx)? {
                return Ok(pairs);
            }
        }
        Err(Error::Gpu(format!(
            "pair traversal still overflowed after {MAX_TRIES} tries"
        )))
    }

    /// Writes `nodes` into upload buffer `i`; returns the tree's height.
    fn upload(&mut self, ctx: &GpuContext, i: usize, nodes: &[Node]) -> u32 {
        self.uploads[i].ensure(ctx, std::mem::size_of_val(nodes) as u64);
        self.uploads[i].write(ctx, nodes);
        node_depths(nodes, &mut self.depths);
        self.depths.iter().copied().max().unwrap_or(0)
    }

    /// Test hook (feature `testing`): dispatches at most `groups` workgroups per round (at least 1, at most
    /// the device's limit), so that tests reach the stride over queues wider than a dispatch without
    /// millions of pairs.
    #[cfg(feature = "testing")]
    pub fn limit_workgroups(&mut self, ctx: &GpuContext, groups: u32) {
        let device = ctx.device.limits().max_compute_workgroups_per_dimension;
        self.max_groups = groups.clamp(1, device);
    }

    /// Capacities now: pairs the widest level may hold, and leaf pairs.
    pub fn capacity(&self) -> (u32, u32) {
        let items = |b: &GpuBuffer, bytes: u64| {
            (b.buffer().size() / bytes).min(SATURATED as u64 - 1) as u32
        };
        (
            items(&self.queues[0], ITEM_BYTES),
            items(&self.pairs, PAIR_BYTES),
        )
    }

    /// Grows the buffers to what the last overflow asked for (at least doubling), within the device's
    /// limits.
    fn grow(&mut self, ctx: &GpuContext) -> Result<()> {
        let limit = ctx.storage_limit();
        let (queue, pairs) = self.capacity();
        let want = [
            (self.demand.queue.load(Ordering::Relaxed), queue, ITEM_BYTES),
            (self.demand.pairs.load(Ordering::Relaxed), pairs, PAIR_BYTES),
        ];
        for (k, &(need, have, bytes)) in want.iter().enumerate() {
            if need <= have {
                continue;
            }
            if need >= SATURATED || need as u64 * bytes > limit {
                return Err(Error::Gpu(format!(
                    "pair traversal needs room for {need} {} ({} bytes), past the device's buffer limit of {limit} bytes",
                    ["queued pairs", "leaf pairs"][k],
                    need as u64 * bytes,
                )));
            }
            let buffers = if k == 0 {
                &mut self.queues[..]
            } else {
                std::slice::from_mut(&mut self.pairs)
            };
            for b in buffers {
                b.ensure_within(ctx, need as u64 * bytes, limit);
            }
            self.groups = None;
        }
        Ok(())
    }

    /// Records the traversal of trees `a` and `b` — `b` placed in `a`'s frame by its transform, or `None`
    /// for `a` against itself — into `encoder`, followed by a read-back of the leaf pairs found. Record
    /// at most one query per [`GpuPairs`] per submission (its parameters are written at submit).
    ///
    /// Errors: [`Error::InvalidTransform`] for a transform that is not finite; [`Error::Gpu`] for a node
    /// buffer smaller than its count, or when an earlier overflow asks for buffers past the device's
    /// limits.
    pub fn record(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        a: GpuTree<'_>,
        b: Option<(GpuTree<'_>, Affine3A)>,
    ) -> Result<PairsReadback> {
        if let Some((_, b_to_a)) = &b {
            check_finite(b_to_a)?;
        }
        let (tree_b, b_to_a, mode) = match b {
            None => (a, Affine3A::IDENTITY, MODE_SELF),
            Some((t, m)) if m == Affine3A::IDENTITY => (t, m, MODE_SAME),
            Some((t, m)) => (t, m, MODE_MOVED),
        };
        for t in [&a, &tree_b] {
            if t.nodes.size() < t.count as u64 * std::mem::size_of::<Node>() as u64 {
                return Err(Error::Gpu(format!(
                    "a node buffer of {} bytes cannot hold {} nodes",
                    t.nodes.size(),
                    t.count
                )));
            }
        }
        if a.count == 0 || tree_b.count == 0 {
            return Ok(PairsReadback::empty());
        }
        self.grow(ctx)?;
        let (queue_cap, pair_cap) = self.capacity();
        let m = b_to_a.matrix3;
        let params = CollideParams {
            columns: [m.x_axis, m.y_axis, m.z_axis].map(|c| c.extend(0.0).to_array()),
            translation: b_to_a.translation.extend(0.0).to_array(),
            mode,
            queue_cap,
            pair_cap,
            max_groups: self.max_groups,
        };
        ctx.write_buffer(self.params.buffer(), 0, bytemuck::bytes_of(&params));
        let rounds =
            (a.height.min(MAX_DEPTH as u32) + tree_b.height.min(MAX_DEPTH as u32) + 2) as usize;
        let groups = self.bind_groups(ctx, a.nodes, tree_b.nodes);
        let k = &ctx.kernels.collide;
        encoder.clear_buffer(self.counts.buffer(), 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("kinetrace pair traversal"),
                timestamp_writes: None,
            });
            let [even, odd, setup] = groups;
            pass.set_bind_group(0, &setup, &[0, ParamSlots::offset(0)]);
            pass.set_pipeline(k.pipeline("pairs_init"));
            pass.dispatch_workgroups(1, 1, 1);
            for r in 0..rounds {
                let offsets = [0, ParamSlots::offset(r)];
                pass.set_bind_group(0, &setup, &offsets);
                pass.set_pipeline(k.pipeline("pairs_args"));
                pass.dispatch_workgroups(1, 1, 1);
                pass.set_bind_group(0, if r % 2 == 0 { &even } else { &odd }, &offsets);
                pass.set_pipeline(k.pipeline("pairs_round"));
                pass.dispatch_workgroups_indirect(self.args.buffer(), 12 * r as u64);
            }
        }
        let data = Readback::record_parts(
            ctx,
            encoder,
            &[
                (self.counts.buffer(), COUNT_WORDS),
                (self.pairs.buffer(), 2 * pair_cap as usize),
            ],
        );
        Ok(PairsReadback {
            data: Some(data),
            rounds,
            capacity: (queue_cap, pair_cap),
            demand: self.demand.clone(),
        })
    }

    /// The bind groups for trees in `a` and `b` (handles: cloning one allocates nothing): made anew only
    /// when those or the queues and the output changed since the last query.
    fn bind_groups(
        &mut self,
        ctx: &GpuContext,
        a: &wgpu::Buffer,
        b: &wgpu::Buffer,
    ) -> [wgpu::BindGroup; 3] {
        match &self.groups {
            Some((ga, gb, groups)) if ga == a && gb == b => groups.clone(),
            _ => {
                let layout = &ctx.kernels.collide.layout;
                let group = |from: usize, args: &GpuBuffer| {
                    bind_group(
                        ctx,
                        layout,
                        &[
                            a.as_entire_binding(),
                            b.as_entire_binding(),
                            self.queues[from].binding(),
                            self.queues[1 - from].binding(),
                            self.pairs.binding(),
                            self.counts.binding(),
                            args.binding(),
                            slot(self.params.buffer()),
                            self.rounds.binding(),
                        ],
                    )
                };
                let groups = [
                    group(0, &self.stand_in),
                    group(1, &self.stand_in),
                    group(1, &self.args),
                ];
                self.groups = Some((a.clone(), b.clone(), groups.clone()));
                groups
            }
        }
    }
}

/// An uploaded tree of `count` nodes.
fn tree(nodes: &wgpu::Buffer, count: usize, height: u32) -> GpuTree<'_> {
    GpuTree {
        nodes,
        count: count as u32,
        height,
    }
}

/// A one-slot binding of a uniform buffer.
fn slot(buffer: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset: 0,
        size: wgpu::BufferSize::new(std::mem::size_of::<CollideParams>() as u64),
    })
}

/// What a pair traversal found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PairsResult {
    /// Every pair `[a, b]` of leaves (node indices of tree `a` and tree `b`) whose boxes overlap, sorted,
    /// each once. In self mode `[x, x]` stands for leaf `x` against itself (its triangles against each
    /// other), and a pair of distinct leaves comes once, in either order.
    Done(Vec<[u32; 2]>),
    /// A work queue or the output ran out of room and the pairs are incomplete. The [`GpuPairs`] that
    /// recorded the query has been told how much room it needs and grows at its next
    /// [`record`](GpuPairs::record): record the query again.
    Overflowed,
}

/// The answer of a pair traversal on its way back to the CPU; like [`Readback`], it never stalls a
/// frame unless asked to.
pub struct PairsReadback {
    /// Counters, then the leaf pairs; `None` when a tree is empty.
    data: Option<Readback<u32>>,
    rounds: usize,
    capacity: (u32, u32),
    demand: Arc<Demand>,
}

impl PairsReadback {
    fn empty() -> Self {
        Self {
            data: None,
            rounds: 0,
            capacity: (0, 0),
            demand: Default::default(),
        }
    }

    /// The answer if the GPU has finished, without blocking.
    pub fn try_take(&self, ctx: &GpuContext) -> Option<Result<PairsResult>> {
        match &self.data {
            None => Some(Ok(PairsResult::Done(Vec::new()))),
            Some(d) => d
                .try_take(ctx)
                .map(|r| r.and_then(|words| self.parse(&words))),
        }
    }

    /// Whether the answer is there (a [`wait`](Self::wait) would not block), without blocking.
    pub fn ready(&self, ctx: &GpuContext) -> bool {
        self.data.as_ref().is_none_or(|d| d.ready(ctx))
    }

    /// Blocks until the answer is there.
    pub fn wait(self, ctx: &GpuContext) -> Result<PairsResult> {
        loop {
            if let Some(r) = self.try_take(ctx) {
                return r;
            }
            ctx.wait()?;
        }
    }

    fn parse(&self, words: &[u32]) -> Result<PairsResult> {
        let (counts, pairs) = words.split_at(COUNT_WORDS);
        let emitted = counts[0];
        // Round r's queue is counts[1 + r]; what the last round appended, counts[1 + rounds], is empty.
        let queued = &counts[1..=self.rounds + 1];
        let widest = queued.iter().copied().max().unwrap_or(0);
        let (queue_cap, pair_cap) = self.capacity;
        if widest > queue_cap || emitted > pair_cap {
            self.demand.queue.fetch_max(widest, Ordering::Relaxed);
            self.demand.pairs.fetch_max(emitted, Ordering::Relaxed);
            return Ok(PairsResult::Overflowed);
        }
        if queued[self.rounds] > 0 {
            return Err(Error::Gpu(format!(
                "pair traversal unfinished after {} rounds: a tree is deeper than its GpuTree::height",
                self.rounds
            )));
        }
        let mut out: Vec<[u32; 2]> = pairs[..2 * emitted as usize]
            .chunks_exact(2)
            .map(|p| [p[0], p[1]])
            .collect();
        out.sort_unstable();
        Ok(PairsResult::Done(out))
    }
}
