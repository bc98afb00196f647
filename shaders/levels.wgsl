// Bottom-up passes over a tree in the crate's layout without arrival counters: inner nodes are bucketed by
// depth once per topology (level_count, level_offsets, level_scatter; the depth is what the builder left in
// sa_ratio), then `leaf_bounds` makes every leaf's box in one pass and `bounds_level` runs once per depth,
// deepest first, one indirect dispatch each, so a parent only ever reads children written by an earlier
// dispatch. The same passes serve LBVH construction (storing the build-time SA ratios) and refit
// (producing the per-node terms of the degradation metric, summed by `reduce_terms`).

const MAX_DEPTH: u32 = 64u;

// max_groups: the device's workgroups per dimension (level_offsets folds each level's dispatch into y past it).
// One slot per mesh and mode; bounds_level counts its depth in `levels` (NEXT), with no slot per depth.
struct LevelParams { nodes: u32, mode: u32, pad: u32, max_groups: u32 }

@group(0) @binding(0) var<storage, read> positions: array<f32>;
@group(0) @binding(1) var<storage, read> indices: array<u32>;
// Per leaf slot the triangle's id.
@group(0) @binding(2) var<storage, read> ids: array<u32>;
@group(0) @binding(3) var<storage, read_write> nodes: array<Node>;
// [0, 64): nodes per depth; [64, 128): cursors; [128, 192): offsets; [192] the depth bounds_level runs
// next, [193] its workgroups finished, [194] the deepest depth with inner nodes.
@group(0) @binding(4) var<storage, read_write> levels: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> order: array<u32>;
@group(0) @binding(6) var<storage, read_write> terms: array<f32>;
@group(0) @binding(7) var<uniform> params: LevelParams;
// Indirect dispatch arguments of bounds_level, 3 words per depth. A buffer used for indirect arguments
// cannot be bound as storage by the same dispatch, so bounds_level binds a stand-in here.
@group(0) @binding(8) var<storage, read_write> args: array<u32>;

const CURSOR: u32 = 64u;
const OFFSET: u32 = 128u;
const NEXT: u32 = 192u;
const DONE: u32 = 193u;
const DEEPEST: u32 = 194u;
const MODE_BUILD: u32 = 0u;

// A node's depth: the builders store it in sa_ratio, which bounds_level then overwrites in build mode (the
// schedule is made once per build, and refit reuses it), so no buffer keeps it between builds.
fn depth(i: u32) -> u32 { return u32(nodes[i].sa_ratio); }

var<workgroup> local_count: array<atomic<u32>, 64>;

@compute @workgroup_size(256)
fn level_count(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    if lid.x < MAX_DEPTH { atomicStore(&local_count[lid.x], 0u); }
    workgroupBarrier();
    let i = linear_id(gid, nwg);
    if i < params.nodes && !is_leaf(nodes[i]) { atomicAdd(&local_count[depth(i)], 1u); }
    workgroupBarrier();
    if lid.x < MAX_DEPTH {
        let c = atomicLoad(&local_count[lid.x]);
        if c > 0u { atomicAdd(&levels[lid.x], c); }
    }
}

// One invocation: offsets, zeroed cursors, and the indirect dispatch arguments of every level.
@compute @workgroup_size(1)
fn level_offsets() {
    var sum = 0u;
    var deepest = 0u;
    for (var d = 0u; d < MAX_DEPTH; d++) {
        let c = atomicLoad(&levels[d]);
        if c > 0u { deepest = d; }
        atomicStore(&levels[OFFSET + d], sum);
        atomicStore(&levels[CURSOR + d], 0u);
        let g = (c + WG - 1u) / WG;
        args[3u * d] = min(g, params.max_groups);
        args[3u * d + 1u] = (g + params.max_groups - 1u) / params.max_groups;
        args[3u * d + 2u] = 1u;
        sum += c;
    }
    atomicStore(&levels[DEEPEST], deepest);
}

@compute @workgroup_size(256)
fn level_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.nodes || is_leaf(nodes[i]) { return; }
    let d = depth(i);
    let at = atomicLoad(&levels[OFFSET + d]) + atomicAdd(&levels[CURSOR + d], 1u);
    order[at] = i;
}

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

// Boxes of every leaf from its triangles' current vertices (one pass over all nodes, before the inner levels:
// the schedule orders inner nodes only, 4 bytes per triangle). Build mode clears the depth the builder left
// in sa_ratio (a leaf's is 0).
@compute @workgroup_size(256)
fn leaf_bounds(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i == 0u {
        // The levels below start at the deepest.
        atomicStore(&levels[NEXT], atomicLoad(&levels[DEEPEST]));
        atomicStore(&levels[DONE], 0u);
    }
    if i >= params.nodes { return; }
    var node = nodes[i];
    if !is_leaf(node) { return; }
    var lo = vec3<f32>(fmax());
    var hi = vec3<f32>(-fmax());
    let f = leaf_first(node);
    for (var s = f; s < f + leaf_count(node); s++) {
        let t = 3u * ids[s];
        let a = vertex(indices[t]);
        let b = vertex(indices[t + 1u]);
        let c = vertex(indices[t + 2u]);
        lo = min(lo, min(min(a, b), c));
        hi = max(hi, max(max(a, b), c));
    }
    node.min = lo;
    node.max = hi;
    if params.mode == MODE_BUILD { node.sa_ratio = 0.0; }
    terms[i] = 0.0;
    nodes[i] = node;
}

var<workgroup> wg_depth: u32;

// Boxes of every inner node at one depth from its children. Build mode stores the SA ratio; refit mode
// writes ratio − stored ratio to `terms`. The depth is NEXT: the levels are dispatched deepest first, one
// dispatch per depth, those deeper than the tree with no workgroup, and the depths of a tree's inner nodes
// run without a gap from DEEPEST to 0, so the last workgroup of each dispatch to finish steps NEXT up
// one depth for the next (every workgroup reads it before it counts itself finished).
@compute @workgroup_size(256)
fn bounds_level(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    if lid.x == 0u { wg_depth = atomicLoad(&levels[NEXT]); }
    let d = workgroupUniformLoad(&wg_depth);
    let k = linear_id(gid, nwg);
    if k < atomicLoad(&levels[d]) {
        inner_bounds(order[atomicLoad(&levels[OFFSET + d]) + k]);
    }
    if lid.x == 0u && atomicAdd(&levels[DONE], 1u) + 1u == nwg.x * nwg.y * nwg.z {
        atomicStore(&levels[DONE], 0u);
        atomicStore(&levels[NEXT], d - 1u);
    }
}

fn inner_bounds(i: u32) {
    var node = nodes[i];
    let l = nodes[node.index];
    let r = nodes[node.index + 1u];
    node.min = min(l.min, r.min);
    node.max = max(l.max, r.max);
    let ratio = sa_ratio(node.min, node.max, l.min, l.max, r.min, r.max);
    if params.mode == MODE_BUILD {
        node.sa_ratio = ratio;
        terms[i] = 0.0;
    } else {
        terms[i] = ratio - node.sa_ratio;
    }
    nodes[i] = node;
}

// Zeroes the per-depth counts before level_count.
@compute @workgroup_size(64)
fn level_reset(@builtin(local_invocation_id) lid: vec3<u32>) {
    atomicStore(&levels[lid.x], 0u);
}
