// Pair traversal of two BVHs, or of one BVH against itself (thesis §6.2.2–6.2.3): a breadth-first walk of the
// bounding volume test tree whose nodes are pairs (node of tree a, node of tree b), the same walk as the
// CPU's src/collide/bvtt.rs. A pair whose boxes are disjoint ends; a pair of overlapping leaves is appended
// to `pairs`; any other pair splits one of its nodes by the CPU's rule: split `a` when it is an inner node
// and `b` is a leaf or no shallower than `a`, else split `b`. Against itself a tree's pair (x, x) is never
// box-tested: a leaf emits (x, x), an inner node pushes (l, l), (r, r) and (l, r).
//
// One round per BVTT level, recorded by src/gpu/collide.rs in one command encoder:
//   pairs_init               seeds round 0's queue with the pair of the roots,
//   pairs_args(r)            turns round r's queue count into its indirect dispatch arguments,
//   pairs_round(r)           visits round r's pairs (queue_in) and appends their children (queue_out).
// Queues ping-pong between two buffers; counts[QUEUE + r] is the length of round r's queue. No workgroup
// ever waits for another: every read of another workgroup's writes is behind a dispatch boundary. A queue or
// the output that runs out of room keeps counting but drops what does not fit; the host sees a count above
// the capacity, grows the buffers and runs the query again.

// One BVTT node: node indices in trees a and b, and their depths (depth_a | depth_b << 16). 12 bytes.
struct Item { a: u32, b: u32, depths: u32 }

// b_to_a as columns m0..m2 and translation t (w unused), then the mode, the capacities (in items and in
// pairs) and the device's largest workgroup count per dimension. The layout of CollideParams in
// src/gpu/collide.rs.
struct CollideParams {
    m0: vec4<f32>,
    m1: vec4<f32>,
    m2: vec4<f32>,
    t: vec4<f32>,
    mode: u32,
    queue_cap: u32,
    pair_cap: u32,
    max_groups: u32,
}

// The round a dispatch belongs to (one parameter slot per round, selected by dynamic offset).
struct Round { r: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> nodes_a: array<Node>;
@group(0) @binding(1) var<storage, read> nodes_b: array<Node>;
@group(0) @binding(2) var<storage, read> queue_in: array<Item>;
@group(0) @binding(3) var<storage, read_write> queue_out: array<Item>;
@group(0) @binding(4) var<storage, read_write> pairs: array<vec2<u32>>;
// [EMITTED]: leaf pairs appended; [QUEUE + r]: length of round r's queue (zeroed before every query).
@group(0) @binding(5) var<storage, read_write> counts: array<atomic<u32>>;
// Indirect dispatch arguments, 3 words per round. A buffer used for indirect arguments cannot be bound as
// storage by the same dispatch, so pairs_round binds a stand-in here.
@group(0) @binding(6) var<storage, read_write> args: array<u32>;
@group(0) @binding(7) var<uniform> params: CollideParams;
@group(0) @binding(8) var<uniform> round: Round;

const EMITTED: u32 = 0u;
const QUEUE: u32 = 1u;
// Boxes are compared as stored (identity transform).
const MODE_SAME: u32 = 0u;
// Tree b's boxes are moved into a's frame by `place`.
const MODE_MOVED: u32 = 1u;
// One tree against itself.
const MODE_SELF: u32 = 2u;
// Invocations per workgroup of pairs_round.
const WG_PAIRS: u32 = 64u;
// Relative slack of a moved box: 8 · f32::EPSILON = 2^-20, bvtt::PLACE_SLACK on the CPU.
const PLACE_SLACK: f32 = 9.5367431640625e-7;
// A counter at or past this value stops growing. Capacities stay below it, so a saturated counter still
// reads as an overflow, and no counter can wrap around however many pairs a query would produce.
const SATURATED: u32 = 0x80000000u;

struct Box { lo: vec3<f32>, hi: vec3<f32> }

// Node n of tree b in tree a's frame, as bvtt::Frame::place: the moved centre and half-extent, widened by
// PLACE_SLACK times the magnitudes involved, so the box holds every point of the exactly moved box however
// the GPU rounds (fused or not).
fn place(n: Node) -> Box {
    if params.mode != MODE_MOVED { return Box(n.min, n.max); }
    let m = mat3x3<f32>(params.m0.xyz, params.m1.xyz, params.m2.xyz);
    let abs_m = mat3x3<f32>(abs(params.m0.xyz), abs(params.m1.xyz), abs(params.m2.xyz));
    let t = params.t.xyz;
    let c = (n.min + n.max) * 0.5;
    let e = (n.max - n.min) * 0.5;
    let c2 = m * c + t;
    let e2 = abs_m * e + (abs_m * (abs(c) + e) + abs(t)) * PLACE_SLACK;
    return Box(c2 - e2, c2 + e2);
}

// What one pair produces: up to three children and possibly a leaf pair (a, b).
struct Step {
    children: array<Item, 3>,
    count: u32,
    emit: bool,
}

fn item(a: u32, b: u32, depth_a: u32, depth_b: u32) -> Item {
    return Item(a, b, depth_a | (depth_b << 16u));
}

fn visit(p: Item) -> Step {
    var s: Step;
    s.count = 0u;
    s.emit = false;
    let da = p.depths & 0xffffu;
    let db = p.depths >> 16u;
    let na = nodes_a[p.a];
    if params.mode == MODE_SELF && p.a == p.b {
        if is_leaf(na) {
            s.emit = true;
        } else {
            let l = na.index;
            s.children[0] = item(l, l, da + 1u, db + 1u);
            s.children[1] = item(l + 1u, l + 1u, da + 1u, db + 1u);
            s.children[2] = item(l, l + 1u, da + 1u, db + 1u);
            s.count = 3u;
        }
        return s;
    }
    let nb = nodes_b[p.b];
    let bb = place(nb);
    if !(all(na.min <= bb.hi) && all(bb.lo <= na.max)) { return s; }
    if is_leaf(na) && is_leaf(nb) {
        s.emit = true;
    } else if !is_leaf(na) && (is_leaf(nb) || da <= db) {
        s.children[0] = item(na.index, p.b, da + 1u, db);
        s.children[1] = item(na.index + 1u, p.b, da + 1u, db);
        s.count = 2u;
    } else {
        s.children[0] = item(p.a, nb.index, da, db + 1u);
        s.children[1] = item(p.a, nb.index + 1u, da, db + 1u);
        s.count = 2u;
    }
    return s;
}

// Reserves k slots of counter c; the first slot, or SATURATED (past every capacity) once c saturated.
fn reserve(c: u32, k: u32) -> u32 {
    if k == 0u || atomicLoad(&counts[c]) >= SATURATED { return SATURATED; }
    return atomicAdd(&counts[c], k);
}

// One invocation: round 0's queue is the pair of the roots (counts were zeroed by the host).
@compute @workgroup_size(1)
fn pairs_init() {
    queue_out[0] = item(0u, 0u, 0u, 0u);
    atomicStore(&counts[QUEUE], 1u);
}

// One invocation: round r's workgroup count, ⌈n / 64⌉ clamped to the device limit (pairs_round strides
// over the rest); 0 once the queue is empty.
@compute @workgroup_size(1)
fn pairs_args() {
    let n = min(atomicLoad(&counts[QUEUE + round.r]), params.queue_cap);
    args[3u * round.r] = min((n + WG_PAIRS - 1u) / WG_PAIRS, params.max_groups);
    args[3u * round.r + 1u] = 1u;
    args[3u * round.r + 2u] = 1u;
}

var<workgroup> wg_n: u32;
var<workgroup> wg_pushes: atomic<u32>;
var<workgroup> wg_emits: atomic<u32>;
var<workgroup> wg_push_base: u32;
var<workgroup> wg_emit_base: u32;

// Round r: each invocation visits one pair per stride. Appends are gathered per workgroup (one global atomic
// per workgroup and stride for the children, one for the leaf pairs), then written where they fit.
@compute @workgroup_size(64)
fn pairs_round(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = round.r;
    if lid.x == 0u { wg_n = min(atomicLoad(&counts[QUEUE + r]), params.queue_cap); }
    let n = workgroupUniformLoad(&wg_n);
    // The bound is uniform over the workgroup, so the barriers below are reached by every invocation.
    for (var base = wid.x * WG_PAIRS; base < n; base += nwg.x * WG_PAIRS) {
        if lid.x == 0u {
            atomicStore(&wg_pushes, 0u);
            atomicStore(&wg_emits, 0u);
        }
        workgroupBarrier();
        let i = base + lid.x;
        var s: Step;
        s.count = 0u;
        s.emit = false;
        var p: Item;
        if i < n {
            p = queue_in[i];
            s = visit(p);
        }
        let push_at = atomicAdd(&wg_pushes, s.count);
        let emit_at = atomicAdd(&wg_emits, select(0u, 1u, s.emit));
        workgroupBarrier();
        if lid.x == 0u {
            wg_push_base = reserve(QUEUE + r + 1u, atomicLoad(&wg_pushes));
            wg_emit_base = reserve(EMITTED, atomicLoad(&wg_emits));
        }
        workgroupBarrier();
        // Sums of a saturated base and a local offset stay far below 2^32.
        for (var k = 0u; k < s.count; k++) {
            let at = wg_push_base + push_at + k;
            if at < params.queue_cap { queue_out[at] = s.children[k]; }
        }
        if s.emit {
            let at = wg_emit_base + emit_at;
            if at < params.pair_cap { pairs[at] = vec2<u32>(p.a, p.b); }
        }
        // The next stride needs no barrier before it: invocation 0 resets the counters there, which nobody
        // reads after the second barrier above, and rewrites the bases only after that stride's first two
        // barriers, which every invocation reaches after its reads above.
    }
}
