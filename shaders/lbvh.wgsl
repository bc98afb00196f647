// LBVH construction over one mesh (Karras 2012), producing the crate's node layout (src/bvh/node.rs) with
// one triangle per leaf. Steps, each its own dispatch so that every read of another invocation's output
// crosses a dispatch boundary (WGSL atomics are relaxed and storageBarrier is workgroup-scoped):
//   tri_bounds   per-workgroup bounds of the triangle centroids
//   reduce_bounds   the scene's centroid bounds (one workgroup)
//   morton       30-bit codes (keys) and triangle ids (values), the centroids computed again (no 16-byte
//                per-triangle cache between the two passes), then sort.wgsl
//   karras       per inner node: range, split, children, parents
//   walk_up      per node: depth and position in the crate's depth-first layout; writes node topology
// Bounds and SA ratios then come bottom-up from levels.wgsl.

// cube: 1 for Morton codes on cubic cells (geometry::morton30_cube, PLOC's order), 0 for per-axis cells.
struct MeshParams { tris: u32, cube: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> positions: array<f32>;
@group(0) @binding(1) var<storage, read> indices: array<u32>;
@group(0) @binding(2) var<storage, read_write> partials: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> keys: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals: array<u32>;
@group(0) @binding(5) var<storage, read_write> children: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read_write> parents: array<u32>;
@group(0) @binding(7) var<storage, read_write> first: array<u32>;
@group(0) @binding(8) var<storage, read_write> nodes: array<Node>;
@group(0) @binding(9) var<uniform> params: MeshParams;

// Node ids of the radix tree: inner nodes 0 .. n-2 (0 is the root), leaves n-1 .. 2n-2.
const NONE: u32 = 0xffffffffu;

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

// Aabb::center() of triangle i's box, as on the CPU.
fn centroid(i: u32) -> vec3<f32> {
    let a = vertex(indices[3u * i]);
    let b = vertex(indices[3u * i + 1u]);
    let c = vertex(indices[3u * i + 2u]);
    return (min(min(a, b), c) + max(max(a, b), c)) * 0.5;
}

var<workgroup> wmin: array<vec3<f32>, 256>;
var<workgroup> wmax: array<vec3<f32>, 256>;

// Tree reduction of (wmin, wmax) over the workgroup; the result is in slot 0.
fn reduce_workgroup(lid: u32) {
    for (var off = WG / 2u; off > 0u; off = off >> 1u) {
        workgroupBarrier();
        if lid < off {
            wmin[lid] = min(wmin[lid], wmin[lid + off]);
            wmax[lid] = max(wmax[lid], wmax[lid + off]);
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(256)
fn tri_bounds(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
              @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    var lo = vec3<f32>(fmax());
    var hi = vec3<f32>(-fmax());
    if i < params.tris {
        let cen = centroid(i);
        lo = cen;
        hi = cen;
    }
    wmin[lid.x] = lo;
    wmax[lid.x] = hi;
    reduce_workgroup(lid.x);
    // Folded (x, y) dispatches run whole blocks past the end: they must not write (robust access would
    // clamp the index onto the last real partial).
    let block = linear_group(wid, nwg);
    if lid.x == 0u && block * WG < params.tris {
        partials[2u * block] = vec4<f32>(wmin[0], 0.0);
        partials[2u * block + 1u] = vec4<f32>(wmax[0], 0.0);
    }
}

// One workgroup folds all per-workgroup partials into partials[0], partials[1].
@compute @workgroup_size(256)
fn reduce_bounds(@builtin(local_invocation_id) lid: vec3<u32>) {
    let blocks = (params.tris + WG - 1u) / WG;
    var lo = vec3<f32>(fmax());
    var hi = vec3<f32>(-fmax());
    for (var b = lid.x; b < blocks; b += WG) {
        lo = min(lo, partials[2u * b].xyz);
        hi = max(hi, partials[2u * b + 1u].xyz);
    }
    wmin[lid.x] = lo;
    wmax[lid.x] = hi;
    reduce_workgroup(lid.x);
    if lid.x == 0u {
        partials[0] = vec4<f32>(wmin[0], 0.0);
        partials[1] = vec4<f32>(wmax[0], 0.0);
    }
}

fn spread10(v: u32) -> u32 {
    var x = v & 0x3ffu;
    x = (x | (x << 16u)) & 0x030000ffu;
    x = (x | (x << 8u)) & 0x0300f00fu;
    x = (x | (x << 4u)) & 0x030c30c3u;
    x = (x | (x << 2u)) & 0x09249249u;
    return x;
}

// geometry::morton30 of `p` in [lo, hi], or geometry::morton30_cube when params.cube is set.
fn morton30(p: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> u32 {
    var e = hi - lo;
    if params.cube != 0u { e = vec3<f32>(max(e.x, max(e.y, e.z))); }
    let inv = select(vec3<f32>(0.0), div3_rn(vec3<f32>(1.0), e), e > vec3<f32>(0.0));
    let n = clamp((p - lo) * inv, vec3<f32>(0.0), vec3<f32>(1.0));
    let q = vec3<u32>(min(n * 1024.0, vec3<f32>(1023.0)));
    return spread10(q.x) | (spread10(q.y) << 1u) | (spread10(q.z) << 2u);
}

@compute @workgroup_size(256)
fn morton(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.tris { return; }
    keys[i] = morton30(centroid(i), partials[0].xyz, partials[1].xyz);
    vals[i] = i;
}

// Karras's δ: common prefix of sorted keys i and j, equal keys extended by their positions; -1 outside.
fn delta(i: u32, j: i32) -> i32 {
    if j < 0 || u32(j) >= params.tris { return -1; }
    let a = keys[i];
    let b = keys[u32(j)];
    if a == b { return 32 + i32(countLeadingZeros(i ^ u32(j))); }
    return i32(countLeadingZeros(a ^ b));
}

// Karras 2012, Algorithm 1.
@compute @workgroup_size(256)
fn karras(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let n = params.tris;
    if i + 1u >= n { return; }
    let ii = i32(i);
    let d = select(-1, 1, delta(i, ii + 1) > delta(i, ii - 1));
    let dmin = delta(i, ii - d);
    var lmax = 2;
    while delta(i, ii + lmax * d) > dmin { lmax *= 2; }
    var l = 0;
    for (var t = lmax / 2; t >= 1; t /= 2) {
        if delta(i, ii + (l + t) * d) > dmin { l += t; }
    }
    let j = ii + l * d;
    let dnode = delta(i, j);
    var s = 0;
    var div = 2;
    loop {
        let t = (l + div - 1) / div;
        if delta(i, ii + (s + t) * d) > dnode { s += t; }
        if t <= 1 { break; }
        div *= 2;
    }
    let gamma = u32(ii + s * d + min(d, 0));
    let lo = u32(min(ii, j));
    let hi = u32(max(ii, j));
    let left = select(gamma, n - 1u + gamma, lo == gamma);
    let right = select(gamma + 1u, n + gamma, hi == gamma + 1u);
    children[i] = vec2<u32>(left, right);
    first[i] = lo;
    parents[left] = i;
    parents[right] = i;
    if i == 0u { parents[0] = NONE; }
}

// Places node v (inner v < n-1, leaf v - (n-1)) in the crate's layout. A node whose range starts at `f` and
// whose path from the root takes L left turns keeps its descendants from index 2f + 1 + 2L on: each subtree
// of m leaves owns a block of 2m - 2 nodes after its root's pair (src/bvh/layout.rs).
@compute @workgroup_size(256)
fn walk_up(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let v = linear_id(gid, nwg);
    let n = params.tris;
    if v >= 2u * n - 1u { return; }
    var lefts = 0u;
    var depth = 0u;
    var cur = v;
    loop {
        let p = parents[cur];
        if p == NONE { break; }
        lefts += select(0u, 1u, children[p].x == cur);
        depth += 1u;
        cur = p;
    }
    var pos = 0u;
    if v != 0u {
        let p = parents[v];
        let is_left = children[p].x == v;
        let parent_lefts = lefts - select(0u, 1u, is_left);
        pos = 2u * first[p] + 1u + 2u * parent_lefts + select(1u, 0u, is_left);
    }
    if v < n - 1u {
        nodes[pos].index = 2u * first[v] + 1u + 2u * lefts;
    } else {
        let slot = v - (n - 1u);
        nodes[pos].index = LEAF_BIT | (1u << 27u) | slot;
    }
    // The depth, until levels.wgsl has bucketed the nodes by it and made the boxes.
    nodes[pos].sa_ratio = f32(depth);
}
