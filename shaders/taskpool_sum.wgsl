
// The pool's toy task (src/gpu/taskpool/sum_tree.rs), appended to taskpool.wgsl: a recursive halving of a
// range whose tasks sum their elements in work chunks. Parameters: `leaf` (longest range that does not
// split) and `chunk` (elements per work chunk).
//
// Task record (8 words): 0 lo, 1 hi (the element range), 2 phase, 3 chunks of the current step, 4 parent
// (NONE for the root), 5 depth, 6 accumulator, 7 first child (0 for none).

const STRIDE: u32 = 8u;
const PHASE_SUM: u32 = 0u;

@group(0) @binding(0) var<storage, read> values: array<u32>;

// Writes a new task record; its first step's chunk count comes from its range.
fn init_task(t: u32, lo: u32, hi: u32, parent: u32, depth: u32) {
    set_field(t, 0u, lo);
    set_field(t, 1u, hi);
    set_field(t, 2u, PHASE_SUM);
    set_field(t, 3u, (hi - lo + params.chunk - 1u) / params.chunk);
    set_field(t, 4u, parent);
    set_field(t, 5u, depth);
    set_field(t, 6u, 0u);
    set_field(t, 7u, 0u);
}

// One work chunk: sums `chunk` elements of the task's range into its accumulator.
fn run_chunk(t: u32, c: u32) {
    let lo = field(t, 0u) + c * params.chunk;
    let hi = min(lo + params.chunk, field(t, 1u));
    var s = 0u;
    for (var k = lo; k < hi; k++) { s += values[k]; }
    atomicAdd(&tasks[t * STRIDE + 6u], s);
}

// The toy task has one phase; when it ends, a range larger than a leaf splits into two child tasks.
fn advance_task(t: u32) {
    let lo = field(t, 0u);
    let hi = field(t, 1u);
    set_field(t, 3u, 0u);
    if hi - lo <= params.leaf { return; }
    let first = alloc_tasks(2u);
    if first == NONE { return; }
    let mid = lo + (hi - lo) / 2u;
    let depth = field(t, 5u) + 1u;
    init_task(first, lo, mid, t, depth);
    init_task(first + 1u, mid, hi, t, depth);
    set_field(t, 7u, first);
    push_next(first);
    push_next(first + 1u);
}
