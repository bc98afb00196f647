// Binned SAH construction with breadth-first work queues (Lauterbach thesis §5.2), one triangle per leaf,
// writing the crate's node layout (src/bvh/layout.rs: a subtree of m triangles owns a block of 2m - 2
// descendants after its root). src/gpu/build_sah.rs drives it; the boxes and SA ratios come afterwards,
// bottom-up, from levels.wgsl as for LBVH.
//
// Scratch lives where the tree has room until its boxes are made: the builder writes only a node's index
// and depth (words 3 and 7 of its 8), so node s's min field holds slot s's scratch id, queue entry and
// scratch entry, and in `mode` bit 1 the bins live in the nodes' max fields (3 words per node). A
// triangle's quantised centroid and box are computed again from the mesh wherever they are needed.
//
// Every quantity that decides the tree is an integer, so the tree does not depend on the device's float
// rounding: centroids and triangle boxes are quantised once to a 16-bit grid whose scale is a power of two
// (exact products, no division; one scale for the boxes' three axes, so grid areas are true areas scaled),
// bins are integer ratios, SAH costs are 64-bit integers (two u32 words).
// Steps per level L (each its own dispatch; indirect, sized from the level's queue count, so levels
// past the tree's depth cost empty dispatches only):
//   sah_args     indirect arguments of the level's passes from the queue count
//   sah_bounds   per primitive: the quantised centroid bounds of its node (atomic max)
//   sah_bin      per primitive: count and quantised box of its bin on each axis (atomic add / max)
//   sah_split    per node (64 invocations): 45 candidate cuts evaluated in parallel, min-reduction (nodes
//                of at most SWEEP primitives: every cut of an exact sweep instead), children written
//                (leaf / small queue / next level's queue), the node's bins zeroed for reuse
//   sah_flag     per primitive: 1 when it goes to the left child; scan.wgsl makes exclusive prefix sums
//   sah_scatter  per primitive: stable partition by the prefix sums into the scratch order
//   sah_copy     scratch order back
// Then sah_small builds each queued subtree of 2..=64 triangles in one workgroup (§5.2.3), sweeping every
// node. The slot order is kept in `vals` throughout, so the leaves' triangles need no last pass. Minima are stored as 0xffff - q under atomicMax, so zero is the identity of
// every accumulator and buffers are cleared by zeroing.

// mode: bit 0 small-split kernel on, bit 1 bins in the nodes' max fields, bits 8.. the LBVH levels of a
// hybrid build (0: pure SAH). One slot per builder: the queue level is counted in `state` (LEVEL).
struct SahParams { tris: u32, pad: u32, mode: u32, cap: u32 }

@group(0) @binding(0) var<storage, read> positions: array<f32>;
@group(0) @binding(1) var<storage, read> indices: array<u32>;
// Partition flags, scanned in place (the tree's level order, rewritten by every build's schedule).
@group(0) @binding(2) var<storage, read_write> flags: array<u32>;
// vec4 words: [0, 2 cap) entries (first, count, node, descendants) of even / odd levels; [2 cap, 4 cap)
// split records, two per entry. The radix tree's parents where they have room, else a buffer of its own.
@group(0) @binding(3) var<storage, read_write> queues: array<vec4<u32>>;
// Small subtrees (first, count | depth << 16, node, descendants), at most n / 2: in the tree's radix-tree
// children (8 bytes per triangle), which only an LBVH build's tree phase and a refit use.
@group(0) @binding(4) var<storage, read_write> small: array<vec4<u32>>;
// Words through bin_word: [0, 336 cap) bins (entry, axis, bin: count, 0xffff - min xyz, max xyz);
// [336 cap, 342 cap) centroid bounds. The node buffer (mode bit 1) or a buffer of its own.
@group(0) @binding(5) var<storage, read_write> bins: array<atomic<u32>>;
// [0, 64) entries per level, [64] small subtrees, [65, 71) centroid bounds, [71, 77) box bounds (ordered
// float bits, minima complemented), [77] the queue level of the round under way, [78] rounds begun.
@group(0) @binding(6) var<storage, read_write> state: array<atomic<u32>>;
// The node buffer as words (8 per node): index (3) and depth (7) of the tree being built; slot s's scratch
// id (8s), queue entry (8s + 1) and scratch entry (8s + 2); bins in the max fields when they are bound here.
@group(0) @binding(7) var<storage, read_write> nodes: array<atomic<u32>>;
// Triangle ids in slot order: the tree's slot ids, kept current by every pass that reorders.
@group(0) @binding(8) var<storage, read_write> vals: array<u32>;
// Indirect arguments (3 words each): 0 primitive passes, 1 split pass, 2.. 5 scan levels, 6 small subtrees.
// Bound only by the argument kernels; the others see a stand-in.
@group(0) @binding(9) var<storage, read_write> args: array<u32>;
// Morton codes in slot order, sorted by the LBVH sort (hybrid builds only).
@group(0) @binding(10) var<storage, read> keys: array<u32>;
@group(0) @binding(11) var<uniform> params: SahParams;

const BINS: u32 = 16u;
const CANDIDATES: u32 = 45u; // 3 axes × 15 cuts
const BIN_WORDS: u32 = 7u;
const ENTRY_BINS: u32 = 336u; // 3 · BINS · BIN_WORDS
const QMAX: u32 = 0xffffu;
const SMALL: u32 = 64u;
const NONE: u32 = 0xffffffffu;
const LEVELS: u32 = 64u;
const SMALL_COUNT: u32 = 64u;
const FRAME: u32 = 65u;
// The queue level of the round under way, and the rounds begun: sah_args counts the rounds, so the
// passes of round l read l here and no dispatch needs a parameter slot of its own per level.
const LEVEL: u32 = 77u;
const ROUNDS: u32 = 78u;

fn level() -> u32 { return atomicLoad(&state[LEVEL]); }
// From this depth on, nodes are halved by slot order (as topdown.rs's BALANCED_DEPTH), so no leaf is
// deeper than 63 for up to 2^27 triangles.
const BALANCED: u32 = 36u;
// Indices of argument triples.
const ARG_PRIMS: u32 = 0u;
const ARG_SPLIT: u32 = 1u;
const ARG_SCAN: u32 = 2u;
const ARG_SMALL: u32 = 6u;

fn small_on() -> bool { return (params.mode & 1u) != 0u; }

// Where bin word w is: the max field of node w / 3 when the bins share the node buffer, else word w.
fn bin_word(w: u32) -> u32 {
    if (params.mode & 2u) != 0u { return 8u * (w / 3u) + 4u + w % 3u; }
    return w;
}

// Slot s's queue entry (NONE: its node is done), scratch id and scratch entry, in node s's min field.
fn entry_of(s: u32) -> u32 { return atomicLoad(&nodes[8u * s + 1u]); }
fn set_entry(s: u32, e: u32) { atomicStore(&nodes[8u * s + 1u], e); }

// Whether nodes at `depth` are split as LBVH splits them (hybrid builds, the top levels).
fn radix_level(depth: u32) -> bool { return depth < ((params.mode >> 8u) & 0xffu); }

// LBVH's split of the Morton-sorted slots first .. first + m (Karras 2012): where the highest bit that
// differs between the first and the last code turns on; equal codes are extended by their slot index.
// Returns the left count.
fn radix_cut(first: u32, m: u32) -> u32 {
    let last = first + m - 1u;
    let x = keys[first] ^ keys[last];
    if x == 0u {
        let b = 31u - countLeadingZeros(first ^ last);
        return ((last >> b) << b) - first;
    }
    let b = 31u - countLeadingZeros(x);
    var lo = first;
    var hi = last;
    // The first slot whose code has bit b set: keys[lo] has it clear, keys[hi] set.
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if ((keys[mid] >> b) & 1u) == 1u { hi = mid; } else { lo = mid; }
    }
    return hi - first;
}

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

fn tri_box(t: u32) -> array<vec3<f32>, 2> {
    let a = vertex(indices[3u * t]);
    let b = vertex(indices[3u * t + 1u]);
    let c = vertex(indices[3u * t + 2u]);
    return array<vec3<f32>, 2>(min(min(a, b), c), max(max(a, b), c));
}

// Order-preserving map of finite floats to u32.
fn ordered(f: f32) -> u32 {
    let b = bitcast<u32>(f);
    return select(b | 0x80000000u, ~b, (b >> 31u) == 1u);
}

fn unordered(u: u32) -> f32 {
    return bitcast<f32>(select(~u, u & 0x7fffffffu, (u >> 31u) == 1u));
}

// The power of two 2^k with e · 2^k in [2^15, 2^16): quantising by it is exact scaling, the same on every
// device. 0 for an empty extent.
fn pow2_scale(e: f32) -> f32 {
    if !(e > 0.0) { return 0.0; }
    let ex = i32((bitcast<u32>(e) >> 23u) & 0xffu) - 127;
    let k = clamp(15 - ex, -126, 127);
    return bitcast<f32>(u32(k + 127) << 23u);
}

fn quantise(x: f32) -> u32 {
    return u32(min(max(x, 0.0), 65535.0));
}

fn frame_min(w: u32) -> f32 { return unordered(~atomicLoad(&state[w])); }
fn frame_max(w: u32) -> f32 { return unordered(atomicLoad(&state[w])); }

var<workgroup> wmin: array<vec3<u32>, 256>;
var<workgroup> wmax: array<vec3<u32>, 256>;

// Scene bounds of the centroids and of the triangle boxes.
@compute @workgroup_size(256)
fn sah_frame(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    var cmin = vec3<u32>(0u);
    var cmax = vec3<u32>(0u);
    var bmin = vec3<u32>(0u);
    var bmax = vec3<u32>(0u);
    if i < params.tris {
        let b = tri_box(i);
        let c = (b[0] + b[1]) * 0.5;
        cmin = ~vec3<u32>(ordered(c.x), ordered(c.y), ordered(c.z));
        cmax = vec3<u32>(ordered(c.x), ordered(c.y), ordered(c.z));
        bmin = ~vec3<u32>(ordered(b[0].x), ordered(b[0].y), ordered(b[0].z));
        bmax = vec3<u32>(ordered(b[1].x), ordered(b[1].y), ordered(b[1].z));
    }
    for (var round = 0u; round < 2u; round++) {
        wmin[lid.x] = select(bmin, cmin, round == 0u);
        wmax[lid.x] = select(bmax, cmax, round == 0u);
        for (var off = WG / 2u; off > 0u; off = off >> 1u) {
            workgroupBarrier();
            if lid.x < off {
                wmin[lid.x] = max(wmin[lid.x], wmin[lid.x + off]);
                wmax[lid.x] = max(wmax[lid.x], wmax[lid.x + off]);
            }
        }
        workgroupBarrier();
        if lid.x < 3u {
            let w = FRAME + 6u * round;
            atomicMax(&state[w + lid.x], wmin[0][lid.x]);
            atomicMax(&state[w + 3u + lid.x], wmax[0][lid.x]);
        }
        workgroupBarrier();
    }
}

// Node i's index and, until the boxes are made bottom-up, its depth in sa_ratio (levels.wgsl buckets by
// it). The box fields are left alone: they hold scratch.
fn write_node(i: u32, index: u32, depth: u32) {
    atomicStore(&nodes[8u * i + 3u], index);
    atomicStore(&nodes[8u * i + 7u], bitcast<u32>(f32(depth)));
}

fn leaf_node(i: u32, slot: u32, depth: u32) {
    write_node(i, LEAF_BIT | (1u << 27u) | slot, depth);
}

// A triangle's centroid and box on the 16-bit grids of the scene's frame (sah_frame's bounds in state),
// computed from the mesh each time: the same integers wherever they are needed.
struct Quantised { c: vec3<u32>, lo: vec3<u32>, hi: vec3<u32> }

fn quantised(t: u32) -> Quantised {
    let clo = vec3<f32>(frame_min(FRAME), frame_min(FRAME + 1u), frame_min(FRAME + 2u));
    let chi = vec3<f32>(frame_max(FRAME + 3u), frame_max(FRAME + 4u), frame_max(FRAME + 5u));
    let blo = vec3<f32>(frame_min(FRAME + 6u), frame_min(FRAME + 7u), frame_min(FRAME + 8u));
    let bhi = vec3<f32>(frame_max(FRAME + 9u), frame_max(FRAME + 10u), frame_max(FRAME + 11u));
    let ce = chi - clo;
    let be = bhi - blo;
    let cs = vec3<f32>(pow2_scale(ce.x), pow2_scale(ce.y), pow2_scale(ce.z));
    // One scale for all axes: box areas in grid units are then proportional to the true areas.
    let bs = vec3<f32>(pow2_scale(max(be.x, max(be.y, be.z))));
    let b = tri_box(t);
    let c = (b[0] + b[1]) * 0.5;
    let qc = (c - clo) * cs;
    let qlo = floor((b[0] - blo) * bs);
    let qhi = ceil((b[1] - blo) * bs);
    return Quantised(
        vec3<u32>(quantise(qc.x), quantise(qc.y), quantise(qc.z)),
        vec3<u32>(quantise(qlo.x), quantise(qlo.y), quantise(qlo.z)),
        vec3<u32>(quantise(qhi.x), quantise(qhi.y), quantise(qhi.z)),
    );
}

// The identity order (or a hybrid's sorted one), every slot's queue entry, and the root's.
@compute @workgroup_size(256)
fn sah_prims(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let n = params.tris;
    if i >= n { return; }
    // The root is queued as level 0's entry 0 unless it is a leaf or a small subtree.
    let small_root = small_on() && n <= SMALL;
    // A hybrid build starts from the LBVH sort's order.
    vals[i] = select(i, vals[i], radix_level(0u));
    set_entry(i, select(0u, NONE, n == 1u || small_root));
    if i == 0u {
        if n == 1u {
            leaf_node(0u, 0u, 0u);
        } else if small_root {
            small[0] = vec4<u32>(0u, n, 0u, 1u);
            atomicStore(&state[SMALL_COUNT], 1u);
        } else {
            queues[0] = vec4<u32>(0u, n, 0u, 1u);
            atomicStore(&state[0], 1u);
        }
    }
}

fn centroid_q(t: u32) -> vec3<u32> { return quantised(t).c; }

// The bin of quantised coordinate q in [lo, hi]: ⌊(q - lo) · 16 / (hi - lo + 1)⌋, exact.
fn bin_of(q: u32, lo: u32, hi: u32) -> u32 {
    return ((q - lo) * BINS) / (hi - lo + 1u);
}

// Workgroup counts for g groups at the device's groups per dimension (mode bits 16..32, at most 65535).
fn split_threads(g: u32) -> vec3<u32> {
    return fold_groups(g, params.mode >> 16u);
}

fn write_args(at: u32, g: vec3<u32>) {
    args[3u * at] = g.x;
    args[3u * at + 1u] = g.y;
    args[3u * at + 2u] = g.z;
}

fn in_base() -> u32 { return (level() & 1u) * params.cap; }
fn out_base() -> u32 { return ((level() + 1u) & 1u) * params.cap; }

// One invocation at the start of every round: the round's level (the rounds begun so far, from 0), and
// its indirect arguments, all zero when its queue is empty.
@compute @workgroup_size(1)
fn sah_args() {
    let l = atomicAdd(&state[ROUNDS], 1u);
    atomicStore(&state[LEVEL], l);
    let live = atomicLoad(&state[l]) > 0u;
    let on = select(0u, 1u, live);
    write_args(ARG_PRIMS, split_threads(((params.tris + WG - 1u) / WG) * on));
    write_args(ARG_SPLIT, split_threads(atomicLoad(&state[l])));
    // Scan level l runs over ⌈n / 256^l⌉ elements (src/gpu/scan.rs).
    var size = params.tris;
    for (var l = 0u; l < 4u; l++) {
        write_args(ARG_SCAN + l, split_threads(((size + WG - 1u) / WG) * on));
        size = (size + WG - 1u) / WG;
    }
}

@compute @workgroup_size(1)
fn sah_small_args() {
    write_args(ARG_SMALL, split_threads(atomicLoad(&state[SMALL_COUNT])));
}

@compute @workgroup_size(256)
fn sah_bounds(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if s >= params.tris || radix_level(level()) { return; }
    let e = entry_of(s);
    if e == NONE { return; }
    let q = centroid_q(vals[s]);
    let cb = ENTRY_BINS * params.cap + 6u * e;
    for (var a = 0u; a < 3u; a++) {
        atomicMax(&bins[bin_word(cb + a)], QMAX - q[a]);
        atomicMax(&bins[bin_word(cb + 3u + a)], q[a]);
    }
}

fn node_frame(e: u32) -> array<vec3<u32>, 2> {
    let cb = ENTRY_BINS * params.cap + 6u * e;
    var lo: vec3<u32>;
    var hi: vec3<u32>;
    for (var a = 0u; a < 3u; a++) {
        lo[a] = QMAX - atomicLoad(&bins[bin_word(cb + a)]);
        hi[a] = atomicLoad(&bins[bin_word(cb + 3u + a)]);
    }
    return array<vec3<u32>, 2>(lo, hi);
}

@compute @workgroup_size(256)
fn sah_bin(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if s >= params.tris || radix_level(level()) { return; }
    let e = entry_of(s);
    if e == NONE { return; }
    let f = node_frame(e);
    let p = quantised(vals[s]);
    for (var a = 0u; a < 3u; a++) {
        let at = (e * 3u + a) * BINS * BIN_WORDS + bin_of(p.c[a], f[0][a], f[1][a]) * BIN_WORDS;
        atomicAdd(&bins[bin_word(at)], 1u);
        for (var k = 0u; k < 3u; k++) {
            atomicMax(&bins[bin_word(at + 1u + k)], QMAX - p.lo[k]);
            atomicMax(&bins[bin_word(at + 4u + k)], p.hi[k]);
        }
    }
}

// ---- split choice, shared by the queue path and the small-split kernel (both fill wbins first) ----

var<workgroup> wbins: array<atomic<u32>, 336>;
var<workgroup> wkey: array<vec4<u32>, 64>;

fn mul_wide(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    return vec2<u32>((p00 & 0xffffu) | (mid << 16u), a1 * b1 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u));
}

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

// Half the surface area of a quantised box (each extent below 2^16), as 64 bits.
fn half_area(lo: vec3<u32>, hi: vec3<u32>) -> vec2<u32> {
    let d = hi - lo;
    return add64(add64(vec2<u32>(d.x * d.y, 0u), vec2<u32>(d.y * d.z, 0u)), vec2<u32>(d.z * d.x, 0u));
}

// area · n for an area below 2^35.
fn times(a: vec2<u32>, n: u32) -> vec2<u32> {
    let p = mul_wide(a.x, n);
    return vec2<u32>(p.x, p.y + a.y * n);
}

fn key_less(a: vec4<u32>, b: vec4<u32>) -> bool {
    if a.x != b.x { return a.x < b.x; }
    if a.y != b.y { return a.y < b.y; }
    if a.z != b.z { return a.z < b.z; }
    return a.w < b.w;
}

// Candidate `c` (axis c / 15, first right bin c % 15 + 1) over wbins: (cost high, cost low, |N_L - N_R|, c),
// all ones when a side is empty; and N_L in `left` of the winner recomputed by the caller.
fn candidate(c: u32) -> vec4<u32> {
    let axis = c / 15u;
    let cut = c % 15u + 1u;
    var n = vec2<u32>(0u);
    var lo = array<vec3<u32>, 2>(vec3<u32>(QMAX), vec3<u32>(QMAX));
    var hi = array<vec3<u32>, 2>(vec3<u32>(0u), vec3<u32>(0u));
    for (var b = 0u; b < BINS; b++) {
        let at = (axis * BINS + b) * BIN_WORDS;
        let count = atomicLoad(&wbins[at]);
        if count == 0u { continue; }
        let side = select(1u, 0u, b < cut);
        n[side] += count;
        for (var k = 0u; k < 3u; k++) {
            lo[side][k] = min(lo[side][k], QMAX - atomicLoad(&wbins[at + 1u + k]));
            hi[side][k] = max(hi[side][k], atomicLoad(&wbins[at + 4u + k]));
        }
    }
    if n.x == 0u || n.y == 0u { return vec4<u32>(NONE); }
    let cost = add64(times(half_area(lo[0], hi[0]), n.x), times(half_area(lo[1], hi[1]), n.y));
    return vec4<u32>(cost.y, cost.x, max(n.x, n.y) - min(n.x, n.y), c);
}

// The number of primitives left of the cut of candidate c.
fn left_count(c: u32) -> u32 {
    let axis = c / 15u;
    let cut = c % 15u + 1u;
    var n = 0u;
    for (var b = 0u; b < cut; b++) {
        n += atomicLoad(&wbins[(axis * BINS + b) * BIN_WORDS]);
    }
    return n;
}

// Min-reduction of every invocation's candidate over the 64 invocations; the winner is in wkey[0].
fn best_candidate(lid: u32) {
    reduce_key(lid, select(vec4<u32>(NONE), candidate(lid), lid < CANDIDATES));
}

// Min-reduction of the 64 invocations' keys into wkey[0].
fn reduce_key(lid: u32, key: vec4<u32>) {
    wkey[lid] = key;
    for (var off = 32u; off > 0u; off = off >> 1u) {
        workgroupBarrier();
        if lid < off && key_less(wkey[lid + off], wkey[lid]) {
            wkey[lid] = wkey[lid + off];
        }
    }
    workgroupBarrier();
}

// ---- the exact sweep for nodes of at most SWEEP primitives (as the CPU builder sweeps small nodes) ----

const SWEEP: u32 = 64u;
// The node's primitives by local position: quantised centroids and boxes; per axis the positions sorted by
// (centroid, position).
var<workgroup> wq: array<vec3<u32>, 64>;
var<workgroup> wlo: array<vec3<u32>, 64>;
var<workgroup> whi: array<vec3<u32>, 64>;
var<workgroup> worder: array<u32, 192>;

// Every cut of the m primitives wids[base .. base + m] in (centroid, position) order on each axis: the winner
// in wkey[0] as (cost high, cost low, |N_L - N_R|, axis · SWEEP + N_L), all ones when m > SWEEP. Its barriers
// are unconditional: call it in uniform control flow.
fn best_sweep(lid: u32, base: u32, m: u32) {
    let mine = lid < m && m <= SWEEP;
    if mine {
        let p = quantised(wids[base + lid]);
        wq[lid] = p.c;
        wlo[lid] = p.lo;
        whi[lid] = p.hi;
    }
    workgroupBarrier();
    if mine {
        for (var a = 0u; a < 3u; a++) {
            let q = wq[lid][a];
            var rank = 0u;
            for (var j = 0u; j < m; j++) {
                let o = wq[j][a];
                rank += select(0u, 1u, o < q || (o == q && j < lid));
            }
            worder[a * SWEEP + rank] = lid;
        }
    }
    workgroupBarrier();
    var key = vec4<u32>(NONE);
    for (var c = lid; c < 3u * SWEEP && m <= SWEEP; c += 64u) {
        let a = c / SWEEP;
        let cut = c % SWEEP;
        if cut == 0u || cut >= m { continue; }
        var lo = array<vec3<u32>, 2>(vec3<u32>(QMAX), vec3<u32>(QMAX));
        var hi = array<vec3<u32>, 2>(vec3<u32>(0u), vec3<u32>(0u));
        for (var r = 0u; r < m; r++) {
            let p = worder[a * SWEEP + r];
            let side = select(1u, 0u, r < cut);
            lo[side] = min(lo[side], wlo[p]);
            hi[side] = max(hi[side], whi[p]);
        }
        let cost = add64(times(half_area(lo[0], hi[0]), cut), times(half_area(lo[1], hi[1]), m - cut));
        let k = vec4<u32>(cost.y, cost.x, max(cut, m - cut) - min(cut, m - cut), c);
        if key_less(k, key) { key = k; }
    }
    reduce_key(lid, key);
}

// The split of a node of m primitives at `depth` as its record (code, N_L, a, b), from the winner in wkey[0]
// (the sweep's for m <= SWEEP, else the bins') and, for bins, the node's centroid bounds lo, hi:
// code = axis | cut << 2 with (a, b) the bounds on the axis; SWEEP_CODE | axis with (a, b) the centroid and
// position of the last primitive on the left; or MEDIAN for a cut of the slot order: LBVH's in a hybrid's
// top levels (slots first ..), else in halves (no cut between centroids, or past BALANCED).
const MEDIAN: u32 = 0x100u;
const SWEEP_CODE: u32 = 0x200u;

fn choose(first: u32, m: u32, depth: u32, lo: vec3<u32>, hi: vec3<u32>) -> vec4<u32> {
    if radix_level(depth) {
        return vec4<u32>(MEDIAN, radix_cut(first, m), 0u, 0u);
    }
    let w = wkey[0];
    if w.x == NONE || depth >= BALANCED {
        return vec4<u32>(MEDIAN, m / 2u, 0u, 0u);
    }
    if m <= SWEEP {
        let a = w.w / SWEEP;
        let cut = w.w % SWEEP;
        let p = worder[a * SWEEP + cut - 1u];
        return vec4<u32>(SWEEP_CODE | a, cut, wq[p][a], p);
    }
    let a = w.w / 15u;
    return vec4<u32>(a | ((w.w % 15u + 1u) << 2u), left_count(w.w), lo[a], hi[a]);
}

// Whether a primitive with centroid q (or at position `at` of its node) goes left.
fn goes_left(code: u32, left: u32, at: u32, q: vec3<u32>, a: u32, b: u32) -> bool {
    if code == MEDIAN { return at < left; }
    if (code & SWEEP_CODE) != 0u {
        let c = q[code & 3u];
        return c < a || (c == a && at <= b);
    }
    return bin_of(q[code & 3u], a, b) < (code >> 2u);
}

// ---- the queue path ----

var<workgroup> wcount: u32;

// Places child (first, count, node, descendants) at `depth`: a leaf, a small subtree, or an entry of the
// next level. Returns its entry (NONE unless queued for the next level).
fn place_child(c: vec4<u32>, depth: u32) -> u32 {
    if c.y == 1u {
        leaf_node(c.z, c.x, depth);
        return NONE;
    }
    if small_on() && c.y <= SMALL {
        let k = atomicAdd(&state[SMALL_COUNT], 1u);
        small[k] = vec4<u32>(c.x, c.y | (depth << 16u), c.z, c.w);
        return NONE;
    }
    let k = atomicAdd(&state[level() + 1u], 1u);
    queues[out_base() + k] = c;
    return k;
}

var<workgroup> wm: u32;

@compute @workgroup_size(64)
fn sah_split(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_group(wid, nwg);
    if lid.x == 0u { wcount = atomicLoad(&state[level()]); }
    if e >= workgroupUniformLoad(&wcount) { return; }
    let ent = queues[in_base() + e];
    if lid.x == 0u { wm = ent.y; }
    let base = e * ENTRY_BINS;
    // Nodes of at most SWEEP primitives are swept exactly, larger ones choose among the bins' cuts.
    if workgroupUniformLoad(&wm) <= SWEEP {
        if lid.x < ent.y { wids[lid.x] = vals[ent.x + lid.x]; }
        best_sweep(lid.x, 0u, ent.y);
    } else {
        for (var w = lid.x; w < ENTRY_BINS; w += 64u) {
            atomicStore(&wbins[w], atomicLoad(&bins[bin_word(base + w)]));
        }
        workgroupBarrier();
        best_candidate(lid.x);
    }
    if lid.x == 0u {
        let f = node_frame(e);
        let sp = choose(ent.x, ent.y, level(), f[0], f[1]);
        write_node(ent.z, ent.w, level());
        let l = vec4<u32>(ent.x, sp.y, ent.w, ent.w + 2u);
        let r = vec4<u32>(ent.x + sp.y, ent.y - sp.y, ent.w + 1u, ent.w + 2u * sp.y);
        let le = place_child(l, level() + 1u);
        let re = place_child(r, level() + 1u);
        queues[2u * params.cap + 2u * e] = sp;
        queues[2u * params.cap + 2u * e + 1u] = vec4<u32>(le, re, ent.x, ent.y);
    }
    workgroupBarrier();
    // Zero this entry's bins and bounds for the next level (the frame was read above).
    for (var w = lid.x; w < ENTRY_BINS; w += 64u) {
        atomicStore(&bins[bin_word(base + w)], 0u);
    }
    if lid.x < 6u { atomicStore(&bins[bin_word(ENTRY_BINS * params.cap + 6u * e + lid.x)], 0u); }
}

fn side_of(s: u32, e: u32) -> bool {
    let sp = queues[2u * params.cap + 2u * e];
    let first = queues[2u * params.cap + 2u * e + 1u].z;
    return goes_left(sp.x, sp.y, s - first, centroid_q(vals[s]), sp.z, sp.w);
}

@compute @workgroup_size(256)
fn sah_flag(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if s >= params.tris { return; }
    let e = entry_of(s);
    flags[s] = select(0u, select(0u, 1u, side_of(s, e)), e != NONE);
}

@compute @workgroup_size(256)
fn sah_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    let n = params.tris;
    if s >= n { return; }
    let e = entry_of(s);
    if e == NONE {
        atomicStore(&nodes[8u * s], vals[s]);
        atomicStore(&nodes[8u * s + 2u], NONE);
        return;
    }
    let sp = queues[2u * params.cap + 2u * e];
    let kids = queues[2u * params.cap + 2u * e + 1u];
    let first = kids.z;
    let lefts_before = flags[s] - flags[first];
    var to: u32;
    var child: u32;
    if side_of(s, e) {
        to = first + lefts_before;
        child = kids.x;
    } else {
        to = first + sp.y + (s - first - lefts_before);
        child = kids.y;
    }
    atomicStore(&nodes[8u * to], vals[s]);
    atomicStore(&nodes[8u * to + 2u], child);
}

@compute @workgroup_size(256)
fn sah_copy(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if s >= params.tris { return; }
    vals[s] = atomicLoad(&nodes[8u * s]);
    set_entry(s, atomicLoad(&nodes[8u * s + 2u]));
}

// ---- the small-split kernel: a subtree of 2..=64 triangles in one workgroup ----

var<workgroup> wids: array<u32, 64>;
var<workgroup> wnext: array<u32, 64>;
// Pending nodes (first within the subtree, count, node, descendants) and their depths.
var<workgroup> wstack: array<vec4<u32>, 64>;
var<workgroup> wdepth: array<u32, 64>;
var<workgroup> wsp: u32;
var<workgroup> wnode: vec4<u32>;
var<workgroup> wnode_depth: u32;
var<workgroup> wsplit: vec4<u32>;

@compute @workgroup_size(64)
fn sah_small(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_group(wid, nwg);
    let t = lid.x;
    if t == 0u { wcount = atomicLoad(&state[SMALL_COUNT]); }
    if k >= workgroupUniformLoad(&wcount) { return; }
    let packed = small[k];
    let root = vec4<u32>(packed.x, packed.y & 0xffffu, packed.z, packed.w);
    let first = root.x;
    if t < root.y { wids[t] = vals[first + t]; }
    if t == 0u {
        wstack[0] = vec4<u32>(0u, root.y, root.z, root.w);
        wdepth[0] = packed.y >> 16u;
        wsp = 1u;
    }
    loop {
        if workgroupUniformLoad(&wsp) == 0u { break; }
        if t == 0u {
            wsp -= 1u;
            wnode = wstack[wsp];
            wnode_depth = wdepth[wsp];
        }
        workgroupBarrier();
        let nd = wnode;
        let q = centroid_q(wids[min(nd.x + t, SMALL - 1u)]);
        let mine = t < nd.y;
        best_sweep(t, nd.x, nd.y);
        if t == 0u {
            wsplit = choose(first + nd.x, nd.y, wnode_depth, vec3<u32>(0u), vec3<u32>(0u));
        }
        workgroupBarrier();
        let sp = wsplit;
        // Stable partition of the node's ids: rank among the same side by counting the invocations below.
        var left = false;
        if mine { left = goes_left(sp.x, sp.y, t, q, sp.z, sp.w); }
        if t < SMALL { wnext[t] = select(0u, 1u, left); }
        workgroupBarrier();
        var before = 0u;
        for (var j = 0u; j < min(t, nd.y); j++) { before += wnext[j]; }
        var id = 0u;
        if mine { id = wids[nd.x + t]; }
        workgroupBarrier();
        if mine {
            let to = select(sp.y + (t - before), before, left);
            wids[nd.x + to] = id;
        }
        workgroupBarrier();
        if t == 0u {
            let d = wnode_depth;
            write_node(nd.z, nd.w, d);
            let kids = array<vec4<u32>, 2>(
                vec4<u32>(nd.x, sp.y, nd.w, nd.w + 2u),
                vec4<u32>(nd.x + sp.y, nd.y - sp.y, nd.w + 1u, nd.w + 2u * sp.y),
            );
            for (var c = 0u; c < 2u; c++) {
                let kid = kids[c];
                if kid.y == 1u {
                    leaf_node(kid.z, first + kid.x, d + 1u);
                } else {
                    wstack[wsp] = kid;
                    wdepth[wsp] = d + 1u;
                    wsp += 1u;
                }
            }
        }
        workgroupBarrier();
    }
    if t < root.y { vals[first + t] = wids[t]; }
}
