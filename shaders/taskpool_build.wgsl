// A BVH build as a task kind of the pool (src/gpu/taskpool/build.rs), appended to taskpool.wgsl. A task owns
// a range of triangle ids (in one of two id arrays) and one node of the tree. Its box and centroid bounds are
// known when it is planned (its parent's split accumulated them, or its own BOUNDS step did); planning picks
// the middle of the centroid bounds' longest axis, and a SPLIT step's chunks scatter the ids into the other
// array, those left of the middle from the range's start up, the others from its end down, accumulating each
// side's box and centroid bounds. When the step ends the task writes its node and its children are built:
// a child of at most SMALL triangles by the advancing invocation alone (build_small), a larger one as a child
// task that is planned at once. Where the middle separates nothing (coincident centroids), and from depth
// BALANCED on, a range is halved in slot order instead; its halves then run a BOUNDS step first, and the task
// is parked to fill its node's surface-area ratio once every node exists.
//
// Leaves hold one triangle, so a range of k triangles owns exactly 2k - 1 nodes: a task's node and the
// 2k - 2 nodes of its descendants (`desc`, a contiguous block) are fixed by its range alone, children sit at
// desc and desc + 1, the left child's descendants at desc + 2 and the right's at desc + 2·k_left. So no two
// tasks ever write the same node or id slot, and no task waits for another (see taskpool.wgsl).
//
// Task record (48 words): 0 lo, 1 hi (the id range), 2 phase, 3 chunks of the current step, 4 node, 5 desc,
// 6 depth, 7 source id array (0 or 1), 8..20 the task's bounds, 20..32 and 32..44 the left and right sides'
// bounds as a split accumulates them, 44 split axis, 45 split position (f32 bits), 46 and 47 the ids sent
// left and right. Bounds are 12 order-preserving words (see `ordered`): box min, box max, centroid min,
// centroid max. Parameters: `leaf` = the triangle count (unused by the kernels), `chunk` unused.

const STRIDE: u32 = 48u;
const BOUNDS: u32 = 0u;
const SPLIT: u32 = 1u;
const LINK: u32 = 2u;
const DONE: u32 = 3u;
const OWN: u32 = 8u;
const LEFT: u32 = 20u;
const RIGHT: u32 = 32u;
// Ids per BOUNDS or SPLIT chunk.
const ELEMS: u32 = 64u;
// Ranges of at most this many triangles are built by one invocation (src/gpu/taskpool/build.rs SMALL).
const SMALL: u32 = 32u;
// From this depth on ranges are halved in slot order, so no leaf is deeper than 36 + 27 < MAX_DEPTH.
const BALANCED: u32 = 36u;

@group(0) @binding(0) var<storage, read> positions: array<f32>;
@group(0) @binding(7) var<storage, read> indices: array<u32>;
// Triangle ids; `ids_a` ends up holding the tree's slot order.
@group(0) @binding(8) var<storage, read_write> ids_a: array<u32>;
@group(0) @binding(9) var<storage, read_write> ids_b: array<u32>;
@group(0) @binding(10) var<storage, read_write> nodes: array<Node>;

struct Bounds { lo: vec3<f32>, hi: vec3<f32>, clo: vec3<f32>, chi: vec3<f32> }

fn empty_bounds() -> Bounds {
    let big = vec3<f32>(fmax());
    return Bounds(big, -big, big, -big);
}

fn vertex(i: u32) -> vec3<f32> {
    let v = indices[i];
    return vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
}

// A triangle's box: (min, max).
fn tri_box(id: u32) -> array<vec3<f32>, 2> {
    let a = vertex(3u * id);
    let b = vertex(3u * id + 1u);
    let c = vertex(3u * id + 2u);
    return array<vec3<f32>, 2>(min(a, min(b, c)), max(a, max(b, c)));
}

// The centroid a split compares: its box's centre, rounded as the CPU's `Prim::centroid` rounds it.
fn centroid(b: array<vec3<f32>, 2>) -> vec3<f32> { return (b[0] + b[1]) * 0.5; }

fn grow(acc: ptr<function, Bounds>, b: array<vec3<f32>, 2>) {
    let c = centroid(b);
    (*acc).lo = min((*acc).lo, b[0]);
    (*acc).hi = max((*acc).hi, b[1]);
    (*acc).clo = min((*acc).clo, c);
    (*acc).chi = max((*acc).chi, c);
}

fn get_id(src: u32, i: u32) -> u32 {
    if src == 0u { return ids_a[i]; }
    return ids_b[i];
}

fn put_id(dst: u32, i: u32, v: u32) {
    if dst == 0u { ids_a[i] = v; } else { ids_b[i] = v; }
}

// Merges `b` into the bounds block at word `at` of task t (atomic, from any chunk).
fn merge_bounds(t: u32, at: u32, b: Bounds) {
    let w = t * STRIDE + at;
    for (var k = 0u; k < 3u; k++) {
        atomicMin(&tasks[w + k], ordered(b.lo[k]));
        atomicMax(&tasks[w + 3u + k], ordered(b.hi[k]));
        atomicMin(&tasks[w + 6u + k], ordered(b.clo[k]));
        atomicMax(&tasks[w + 9u + k], ordered(b.chi[k]));
    }
}

fn read_bounds(t: u32, at: u32) -> Bounds {
    var b = empty_bounds();
    for (var k = 0u; k < 3u; k++) {
        b.lo[k] = unordered(field(t, at + k));
        b.hi[k] = unordered(field(t, at + 3u + k));
        b.clo[k] = unordered(field(t, at + 6u + k));
        b.chi[k] = unordered(field(t, at + 9u + k));
    }
    return b;
}

// Writes `b` as the bounds block at word `at` (an empty block for `empty_bounds()`'s identity).
fn set_bounds(t: u32, at: u32, b: Bounds) {
    for (var k = 0u; k < 3u; k++) {
        set_field(t, at + k, ordered(b.lo[k]));
        set_field(t, at + 3u + k, ordered(b.hi[k]));
        set_field(t, at + 6u + k, ordered(b.clo[k]));
        set_field(t, at + 9u + k, ordered(b.chi[k]));
    }
}

fn longest(e: vec3<f32>) -> u32 {
    return select(select(2u, 1u, e.y >= e.z), 0u, e.x >= e.y && e.x >= e.z);
}

fn inner_node(i: u32, left: u32, b: Bounds, l: Bounds, r: Bounds) {
    nodes[i] = Node(b.lo, left, b.hi, sa_ratio(b.lo, b.hi, l.lo, l.hi, r.lo, r.hi));
}

// Whether triangle x comes before y in the object median's order: centroid along `axis`, then id.
fn before(x: u32, y: u32, axis: u32) -> bool {
    let cx = ordered(centroid(tri_box(x))[axis]);
    let cy = ordered(centroid(tri_box(y))[axis]);
    return cx < cy || (cx == cy && x < y);
}

// Builds the subtree of ids lo..hi (at most SMALL, read from array `src`) in this invocation: the same
// middle splits as the tasks' and, where they cannot split (or from depth BALANCED on), the CPU median
// builder's object median; nodes at `node` and from `desc` on, the ids in leaf order into ids_a[lo..hi).
fn build_small(src: u32, lo: u32, hi: u32, node: u32, desc: u32, depth: u32) {
    var ids: array<u32, SMALL>;
    let k = hi - lo;
    for (var i = 0u; i < k; i++) { ids[i] = get_id(src, lo + i); }
    // Pending subtrees: (first, end, node, desc) in `ids`, and their depths; at most one per level plus one.
    var stack: array<vec4<u32>, SMALL>;
    var depths: array<u32, SMALL>;
    stack[0] = vec4<u32>(0u, k, node, desc);
    depths[0] = depth;
    var sp = 1u;
    while sp > 0u {
        sp--;
        let e = stack[sp];
        let d = depths[sp];
        var b = empty_bounds();
        for (var i = e.x; i < e.y; i++) { grow(&b, tri_box(ids[i])); }
        if e.y - e.x == 1u {
            nodes[e.z] = Node(b.lo, LEAF_BIT | (1u << 27u) | (lo + e.x), b.hi, 0.0);
            ids_a[lo + e.x] = ids[e.x];
            continue;
        }
        let axis = longest(b.chi - b.clo);
        let mid = (b.clo[axis] + b.chi[axis]) * 0.5;
        var m = e.x;
        if d < BALANCED && mid > b.clo[axis] {
            for (var i = e.x; i < e.y; i++) {
                if centroid(tri_box(ids[i]))[axis] < mid {
                    let s = ids[i];
                    ids[i] = ids[m];
                    ids[m] = s;
                    m++;
                }
            }
        }
        if m == e.x || m == e.y {
            // The CPU's object median: the first half in (centroid, id) order, by insertion.
            for (var i = e.x + 1u; i < e.y; i++) {
                let x = ids[i];
                var j = i;
                while j > e.x && before(x, ids[j - 1u], axis) {
                    ids[j] = ids[j - 1u];
                    j--;
                }
                ids[j] = x;
            }
            m = e.x + (e.y - e.x) / 2u;
        }
        var l = empty_bounds();
        for (var i = e.x; i < m; i++) { grow(&l, tri_box(ids[i])); }
        var r = empty_bounds();
        for (var i = m; i < e.y; i++) { grow(&r, tri_box(ids[i])); }
        inner_node(e.z, e.w, b, l, r);
        stack[sp] = vec4<u32>(m, e.y, e.w + 1u, e.w + 2u * (m - e.x));
        depths[sp] = d + 1u;
        stack[sp + 1u] = vec4<u32>(e.x, m, e.w, e.w + 2u);
        depths[sp + 1u] = d + 1u;
        sp += 2u;
    }
}

// A new task over ids lo..hi of array `src` owning `node` and the block from `desc`, in phase `phase`.
fn init_task(c: u32, src: u32, lo: u32, hi: u32, node: u32, desc: u32, depth: u32) {
    set_field(c, 0u, lo);
    set_field(c, 1u, hi);
    set_field(c, 4u, node);
    set_field(c, 5u, desc);
    set_field(c, 6u, depth);
    set_field(c, 7u, src);
}

// A child over ids lo..hi with bounds `b`: built here when small (returns NONE), else a new task's id (NONE
// too when the pool is full).
fn new_child(src: u32, lo: u32, hi: u32, node: u32, desc: u32, depth: u32, b: Bounds) -> u32 {
    if hi - lo <= SMALL {
        build_small(src, lo, hi, node, desc, depth);
        return NONE;
    }
    let c = alloc_tasks(1u);
    if c != NONE {
        init_task(c, src, lo, hi, node, desc, depth);
        set_bounds(c, OWN, b);
    }
    return c;
}

// A child whose bounds are unknown: a task first runs a BOUNDS step. (Not merged with spawn_known, which
// plans, since plan → halve → spawn_unknown would make the call graph cyclic, which WGSL forbids.)
fn spawn_unknown(src: u32, lo: u32, hi: u32, node: u32, desc: u32, depth: u32) {
    let c = new_child(src, lo, hi, node, desc, depth, empty_bounds());
    if c == NONE { return; }
    set_field(c, 2u, BOUNDS);
    set_field(c, 3u, groups(hi - lo, ELEMS));
    push_next(c);
}

// A child whose bounds `b` its parent's split accumulated: a task is planned at once.
fn spawn_known(src: u32, lo: u32, hi: u32, node: u32, desc: u32, depth: u32, b: Bounds) {
    let c = new_child(src, lo, hi, node, desc, depth, b);
    if c != NONE { plan(c); }
}

// Halves task t's range of array `src` in slot order; the node's ratio waits for the parked round.
fn halve(t: u32, src: u32) {
    let lo = field(t, 0u);
    let hi = field(t, 1u);
    let desc = field(t, 5u);
    let depth = field(t, 6u) + 1u;
    let m = lo + (hi - lo) / 2u;
    let b = read_bounds(t, OWN);
    nodes[field(t, 4u)] = Node(b.lo, desc, b.hi, 1.0);
    set_field(t, 2u, LINK);
    set_field(t, 3u, 0u);
    park(t);
    spawn_unknown(src, lo, m, desc, desc + 2u, depth);
    spawn_unknown(src, m, hi, desc + 1u, desc + 2u * (m - lo), depth);
}

// Plans task t, whose bounds are known: a small range is built at once, a range whose centroids the middle
// cannot separate (or a deep one) is halved, any other gets a SPLIT step.
fn plan(t: u32) {
    let lo = field(t, 0u);
    let hi = field(t, 1u);
    let src = field(t, 7u);
    if hi - lo <= SMALL {
        set_field(t, 2u, DONE);
        set_field(t, 3u, 0u);
        build_small(src, lo, hi, field(t, 4u), field(t, 5u), field(t, 6u));
        return;
    }
    let b = read_bounds(t, OWN);
    let axis = longest(b.chi - b.clo);
    let mid = (b.clo[axis] + b.chi[axis]) * 0.5;
    if field(t, 6u) >= BALANCED || !(mid > b.clo[axis]) {
        halve(t, src);
        return;
    }
    set_field(t, 44u, axis);
    set_field(t, 45u, bitcast<u32>(mid));
    set_field(t, 46u, 0u);
    set_field(t, 47u, 0u);
    set_bounds(t, LEFT, empty_bounds());
    set_bounds(t, RIGHT, empty_bounds());
    set_field(t, 2u, SPLIT);
    set_field(t, 3u, groups(hi - lo, ELEMS));
    push_next(t);
}

// One BOUNDS chunk: ELEMS ids of the task's range into its bounds.
fn bounds_chunk(t: u32, c: u32) {
    let src = field(t, 7u);
    let lo = field(t, 0u) + c * ELEMS;
    let hi = min(lo + ELEMS, field(t, 1u));
    var b = empty_bounds();
    for (var i = lo; i < hi; i++) { grow(&b, tri_box(get_id(src, i))); }
    merge_bounds(t, OWN, b);
}

// One SPLIT chunk: ELEMS ids scattered into the other array by side, each side's bounds accumulated.
fn split_chunk(t: u32, c: u32) {
    let src = field(t, 7u);
    let lo = field(t, 0u);
    let hi = field(t, 1u);
    let axis = field(t, 44u);
    let mid = bitcast<f32>(field(t, 45u));
    var l = empty_bounds();
    var r = empty_bounds();
    var nl = 0u;
    for (var i = lo + c * ELEMS; i < min(lo + c * ELEMS + ELEMS, hi); i++) {
        let id = get_id(src, i);
        let b = tri_box(id);
        if centroid(b)[axis] < mid {
            put_id(1u - src, lo + atomicAdd(&tasks[t * STRIDE + 46u], 1u), id);
            grow(&l, b);
            nl++;
        } else {
            put_id(1u - src, hi - 1u - atomicAdd(&tasks[t * STRIDE + 47u], 1u), id);
            grow(&r, b);
        }
    }
    let n = min(lo + c * ELEMS + ELEMS, hi) - lo - c * ELEMS;
    if nl > 0u { merge_bounds(t, LEFT, l); }
    if nl < n { merge_bounds(t, RIGHT, r); }
}

fn run_chunk(t: u32, c: u32) {
    switch field(t, 2u) {
        case BOUNDS: { bounds_chunk(t, c); }
        case SPLIT: { split_chunk(t, c); }
        default: {}
    }
}

// After a split: the node, then the children from the other array (or halves, if one side got nothing).
fn after_split(t: u32) {
    let src = 1u - field(t, 7u);
    let nl = field(t, 46u);
    if nl == 0u || field(t, 47u) == 0u {
        halve(t, src);
        return;
    }
    set_field(t, 2u, DONE);
    set_field(t, 3u, 0u);
    let lo = field(t, 0u);
    let hi = field(t, 1u);
    let desc = field(t, 5u);
    let depth = field(t, 6u) + 1u;
    let l = read_bounds(t, LEFT);
    let r = read_bounds(t, RIGHT);
    inner_node(field(t, 4u), desc, read_bounds(t, OWN), l, r);
    spawn_known(src, lo, lo + nl, desc, desc + 2u, depth, l);
    spawn_known(src, lo + nl, hi, desc + 1u, desc + 2u * nl, depth, r);
}

// The parked round of a halved task: every node exists, so its ratio can be filled in.
fn link(t: u32) {
    set_field(t, 2u, DONE);
    let i = field(t, 4u);
    let desc = field(t, 5u);
    let n = nodes[i];
    let l = nodes[desc];
    let r = nodes[desc + 1u];
    nodes[i].sa_ratio = sa_ratio(n.min, n.max, l.min, l.max, r.min, r.max);
}

fn advance_task(t: u32) {
    switch field(t, 2u) {
        case BOUNDS: { plan(t); }
        case SPLIT: { after_split(t); }
        case LINK: { link(t); }
        default: {}
    }
}
