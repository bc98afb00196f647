// The task pool of seed 004 (src/gpu/taskpool/): tasks -> phases -> steps -> work chunks, run in rounds.
//
// A round is six dispatches: `pool_plan` lists the chunk count of every live task's current step, the
// crate's scan (src/gpu/scan.rs) turns the counts into offsets, `pool_size` (one invocation) sizes the work
// dispatch to the round's chunk total, `pool_work` runs workgroups whose invocations each claim up to
// CLAIMS chunks with one atomic counter, `pool_advance` moves each live task to its next phase (inserting
// child tasks into the next round's live list, or retiring it), and `pool_finish` (one invocation) swaps the
// live lists and writes the indirect arguments of the next round (zero workgroups once the pool is empty).
//
// Why each invocation claims at most CLAIMS chunks, with enough workgroups that every chunk is claimed:
// an invocation may not run an unbounded share of a round. On a CPU driver (lavapipe) a few threads run
// the workgroups one after the other, so the first workgroups used to claim nearly every chunk, and
// llvmpipe caps the loop iterations of one shader invocation at 65535 (its loop limiter, shared by all
// loops of the shader): past that count the chunk search's loop left early and its chunks were summed
// into the wrong task, from about 2^15 chunks a round on. With `pool_size`'s workgroup count,
// groups · 64 · CLAIMS ≥ chunks, and an invocation stops early only when the cursor has passed the total,
// so every chunk is still claimed exactly once.
//
// Why no invocation ever waits on another workgroup: the only cross-invocation operations inside a dispatch
// are atomic increments that never retry (claiming a chunk, accumulating into a task, allocating task ids);
// an invocation that finds no chunk left leaves the loop. Every read of another invocation's plain writes
// (chunk counts, offsets, task records, accumulated results) happens in a later dispatch, and a dispatch
// boundary makes all writes visible. So the pool needs no forward-progress guarantee between workgroups,
// which WGSL does not give. The persistent loop is bounded: the claim cursor only grows and the round's
// chunk total is fixed before the dispatch starts.
//
// This file is the pool's core; a task kind (taskpool_sum.wgsl, taskpool_dacrt.wgsl) is appended and
// defines STRIDE (words per task record), binding 0 and any bindings from 7 on, `run_chunk(t, c)` and
// `advance_task(t)`. Task records are all atomic words; word 3 of a record is the chunk count of the task's
// current step, the only word the core reads.
// State words: 0 live count, 1 next live count, 2 tasks allocated, 3 chunk cursor, 4 tasks asked for past
//   the capacity (0 when none were), 5 rounds with live tasks, 6 live list (0, 1: the two halves, 2: the
//   parked list), 7 chunks run, 8 parked count, 9 parked list taken, 10..16 the task kind's.
// Parked tasks: a task kind may park a task (instead of retiring it) to run it once more after every other
//   task is done; when the pool first runs empty, the parked list becomes the live list for more rounds.
// Indirect arguments (u32): 0..3 per-live-task kernels, 3..6 the work kernel, 6..15 scan levels 0..2.

struct PoolParams { capacity: u32, leaf: u32, chunk: u32, max_groups: u32 }

const NONE: u32 = 0xffffffffu;
// Chunks one invocation of `pool_work` claims at most; its workgroups have WORK_SIZE invocations.
const CLAIMS: u32 = 4u;
const WORK_SIZE: u32 = 64u;

@group(0) @binding(1) var<storage, read_write> tasks: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read_write> live: array<u32>;
@group(0) @binding(3) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> state: array<atomic<u32>>;
@group(0) @binding(5) var<uniform> params: PoolParams;
@group(0) @binding(6) var<storage, read_write> args: array<u32>;

fn field(t: u32, f: u32) -> u32 { return atomicLoad(&tasks[t * STRIDE + f]); }
fn set_field(t: u32, f: u32, v: u32) { atomicStore(&tasks[t * STRIDE + f], v); }

fn live_task(i: u32) -> u32 {
    return live[atomicLoad(&state[6]) * params.capacity + i];
}

// The live list the next round reads: the other half (half 0 after the parked list's round).
fn next_half() -> u32 {
    let p = atomicLoad(&state[6]);
    return select(1u - p, 0u, p == 2u);
}

// Puts task t on the next round's live list.
fn push_next(t: u32) {
    let slot = atomicAdd(&state[1], 1u);
    live[next_half() * params.capacity + slot] = t;
}

// Puts task t on the parked list, to run again once the pool has run empty.
fn park(t: u32) {
    let slot = atomicAdd(&state[8], 1u);
    live[2u * params.capacity + slot] = t;
}

// Allocates `k` task ids, or NONE (and records the demand) when the pool is full.
fn alloc_tasks(k: u32) -> u32 {
    let first = atomicAdd(&state[2], k);
    if first + k > params.capacity {
        atomicMax(&state[4], first + k);
        return NONE;
    }
    return first;
}

@compute @workgroup_size(256)
fn pool_plan(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i == 0u {
        atomicStore(&state[3], 0u);
        atomicStore(&state[1], 0u);
    }
    if i < atomicLoad(&state[0]) {
        offsets[i] = field(live_task(i), 3u);
    }
}

// The round's chunk total: the scanned offset of the last live task plus its own count.
fn chunk_total(n: u32) -> u32 {
    return offsets[n - 1u] + field(live_task(n - 1u), 3u);
}

// Sizes the work dispatch so that groups · WORK_SIZE · CLAIMS covers the round's chunks (folded into y past
// the device's per-dimension limit).
@compute @workgroup_size(1)
fn pool_size() {
    let n = atomicLoad(&state[0]);
    var g = 0u;
    if n > 0u { g = groups(chunk_total(n), WORK_SIZE * CLAIMS); }
    let x = min(g, params.max_groups);
    args[3] = x;
    args[4] = select(1u, groups(g, max(x, 1u)), g > 0u);
    args[5] = 1u;
}

@compute @workgroup_size(64)
fn pool_work() {
    let n = atomicLoad(&state[0]);
    if n == 0u { return; }
    let total = chunk_total(n);
    // Bounded: at most CLAIMS claims, and the cursor only grows past the round's `total` chunks.
    for (var k = 0u; k < CLAIMS; k++) {
        let c = atomicAdd(&state[3], 1u);
        if c >= total { break; }
        // The last live slot whose offset is <= c (slots with no chunks share their successor's offset).
        var a = 0u;
        var b = n - 1u;
        while a < b {
            let m = (a + b + 1u) / 2u;
            if offsets[m] <= c { a = m; } else { b = m - 1u; }
        }
        run_chunk(live_task(a), c - offsets[a]);
        atomicAdd(&state[7], 1u);
    }
}

@compute @workgroup_size(256)
fn pool_advance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= atomicLoad(&state[0]) { return; }
    advance_task(live_task(i));
}

fn groups(n: u32, size: u32) -> u32 { return (n + size - 1u) / size; }

// f32 → u32 keeping the order (task kinds accumulate coordinates with atomic min / max), and back.
fn ordered(f: f32) -> u32 {
    let b = bitcast<u32>(f);
    return select(~b, b | 0x80000000u, (b & 0x80000000u) == 0u);
}

fn unordered(u: u32) -> f32 {
    return bitcast<f32>(select(~u, u & 0x7fffffffu, (u & 0x80000000u) != 0u));
}

@compute @workgroup_size(1)
fn pool_finish() {
    var n = atomicLoad(&state[1]);
    var half = next_half();
    if n == 0u && atomicLoad(&state[9]) == 0u && atomicLoad(&state[8]) > 0u {
        n = atomicLoad(&state[8]);
        half = 2u;
        atomicStore(&state[9], 1u);
    }
    atomicStore(&state[0], n);
    atomicStore(&state[6], half);
    if n > 0u { atomicAdd(&state[5], 1u); }
    args[0] = groups(n, 256u);
    args[1] = 1u;
    args[2] = 1u;
    var level = n;
    for (var l = 0u; l < 3u; l++) {
        args[6u + 3u * l] = groups(level, WG);
        args[7u + 3u * l] = 1u;
        args[8u + 3u * l] = 1u;
        level = groups(level, WG);
    }
}
