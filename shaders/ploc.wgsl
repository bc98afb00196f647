// PLOC clustering (Meister and Bittner 2018) over one mesh whose triangle ids are already sorted along the
// Morton curve (lbvh.wgsl's sort phase, in `vals`). The rules are src/bvh/build_ploc.rs's, so the merge tree
// has the CPU's shape exactly: the distance is the half area of the union, computed as
// (d.x*d.y + d.y*d.z) + d.z*d.x with every product kept out of an FMA (max(p, 0) between the multiply and the
// add: WGSL lets a driver contract a*b + c, and a fused result could round differently from the CPU's);
// equal distances go to the smaller pair key (lower position odd, gap, lower position), compared
// lexicographically; the merged cluster takes the lower position and has it as its left child.
//
// One round is five dispatches, each reading only what earlier dispatches wrote (WGSL atomics are relaxed
// and barriers are workgroup-scoped; no invocation ever waits on another workgroup):
//   ploc_nearest      per cluster: its nearest neighbour within params.radius positions
//   ploc_merge        per cluster: survive, merge (the lower of a mutual pair: new node, id from an atomic
//                     counter) or vanish (the higher); workgroup-local exclusive scan of the survivors
//   ploc_block_scan   one workgroup: exclusive scan of the per-workgroup totals, and the next cluster count
//   ploc_compact      survivors to their scanned positions (order kept)
//   ploc_advance      one invocation: the new count, the round counter and the next round's indirect sizes
// The three per-cluster kernels are dispatched indirectly from `args`, sized by the clusters left, and with
// zero workgroups once one cluster is left, so the host records rounds in batches without reading back.

struct PlocParams { n: u32, radius: u32, max_groups: u32, _b: u32 }

@group(0) @binding(0) var<storage, read> positions: array<f32>;
@group(0) @binding(1) var<storage, read> indices: array<u32>;
@group(0) @binding(2) var<storage, read> sorted_ids: array<u32>;
// Cluster boxes by node id (leaves 0..n in Morton order, merged clusters n..2n-1): min, max.
@group(0) @binding(3) var<storage, read_write> boxes: array<vec4<f32>>;
// The same node buffer as words: the node ids of the clusters in order, the k-th in word 3 of node k
// (the w of its box minimum, which no box of a cluster k < n uses); `next` holds a round's survivors
// before compaction.
@group(0) @binding(4) var<storage, read_write> words: array<u32>;
@group(0) @binding(5) var<storage, read_write> next: array<u32>;
@group(0) @binding(6) var<storage, read_write> nn: array<u32>;
@group(0) @binding(7) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(8) var<storage, read_write> sums: array<u32>;
// children[id - n] = (left, right) of merged cluster id.
@group(0) @binding(9) var<storage, read_write> children: array<vec2<u32>>;
// 3 clusters left, 4 next node id, 5 next count, 6 rounds run.
@group(0) @binding(10) var<storage, read_write> state: array<atomic<u32>>;
@group(0) @binding(11) var<uniform> params: PlocParams;
// The indirect workgroup counts (x, y, z) of the per-cluster kernels; a stand-in is bound while they run, as a
// buffer cannot be an indirect argument and writable storage in one dispatch.
@group(0) @binding(12) var<storage, read_write> args: array<u32>;

const GONE: u32 = 0xffffffffu;

fn cluster(k: u32) -> u32 { return words[8u * k + 3u]; }
fn set_cluster(k: u32, id: u32) { words[8u * k + 3u] = id; }

var<workgroup> tile: array<u32, 256>;
var<workgroup> clusters_left: u32;

// Hillis-Steele inclusive scan of `tile` (written by every invocation before the call), in place.
fn scan_tile(lid: u32) {
    workgroupBarrier();
    for (var off = 1u; off < WG; off = off << 1u) {
        var add = 0u;
        if lid >= off { add = tile[lid - off]; }
        workgroupBarrier();
        tile[lid] = tile[lid] + add;
        workgroupBarrier();
    }
}

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

// True when the pair (i, j) has a smaller tie key than (i, k): build_ploc.rs's pair_key.
fn key_less(i: u32, j: u32, k: u32) -> bool {
    let a = vec3<u32>(min(i, j) & 1u, max(i, j) - min(i, j), min(i, j));
    let b = vec3<u32>(min(i, k) & 1u, max(i, k) - min(i, k), min(i, k));
    if a.x != b.x { return a.x < b.x; }
    if a.y != b.y { return a.y < b.y; }
    return a.z < b.z;
}

fn merge_area(amin: vec3<f32>, amax: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>) -> f32 {
    let d = max(amax, bmax) - min(amin, bmin);
    let xy = max(d.x * d.y, 0.0);
    let yz = max(d.y * d.z, 0.0);
    let zx = max(d.z * d.x, 0.0);
    return (xy + yz) + zx;
}

// Writes the indirect sizes for `c` invocations of 256 (none once at most one cluster is left).
fn set_args(c: u32) {
    var g = (c + WG - 1u) / WG;
    if c <= 1u { g = 0u; }
    let a = fold_groups(g, params.max_groups);
    args[0] = a.x;
    args[1] = a.y;
    args[2] = a.z;
}

@compute @workgroup_size(256)
fn ploc_init(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i == 0u {
        atomicStore(&state[3], params.n);
        atomicStore(&state[4], params.n);
        atomicStore(&state[5], params.n);
        atomicStore(&state[6], 0u);
        set_args(params.n);
    }
    if i >= params.n { return; }
    let t = sorted_ids[i];
    let a = vertex(indices[3u * t]);
    let b = vertex(indices[3u * t + 1u]);
    let c = vertex(indices[3u * t + 2u]);
    // The minimum's w is the cluster slot: written through `words` only.
    let lo = min(min(a, b), c);
    boxes[2u * i].x = lo.x;
    boxes[2u * i].y = lo.y;
    boxes[2u * i].z = lo.z;
    boxes[2u * i + 1u] = vec4<f32>(max(max(a, b), c), 0.0);
    set_cluster(i, i);
}

@compute @workgroup_size(256)
fn ploc_nearest(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let c = atomicLoad(&state[3]);
    if i >= c { return; }
    let own = cluster(i);
    let omin = boxes[2u * own].xyz;
    let omax = boxes[2u * own + 1u].xyz;
    let lo = i - min(i, params.radius);
    let hi = min(i + params.radius, c - 1u);
    var best = i;
    var best_d = 0.0;
    for (var j = lo; j <= hi; j++) {
        if j == i { continue; }
        let o = cluster(j);
        let d = merge_area(omin, omax, boxes[2u * o].xyz, boxes[2u * o + 1u].xyz);
        if best == i || d < best_d || (d == best_d && key_less(i, j, best)) {
            best = j;
            best_d = d;
        }
    }
    nn[i] = best;
}

@compute @workgroup_size(256)
fn ploc_merge(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
              @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let c = atomicLoad(&state[3]);
    var keep = 0u;
    if i < c {
        let j = nn[i];
        if nn[j] != i {
            keep = 1u;
            next[i] = cluster(i);
        } else if i < j {
            keep = 1u;
            let l = cluster(i);
            let r = cluster(j);
            let id = atomicAdd(&state[4], 1u);
            children[id - params.n] = vec2<u32>(l, r);
            boxes[2u * id] = min(boxes[2u * l], boxes[2u * r]);
            boxes[2u * id + 1u] = max(boxes[2u * l + 1u], boxes[2u * r + 1u]);
            next[i] = id;
        } else {
            next[i] = GONE;
        }
    }
    // Inclusive scan of the survivors in the workgroup (every invocation reaches the barriers).
    tile[lid.x] = keep;
    scan_tile(lid.x);
    if i < c { offsets[i] = tile[lid.x] - keep; }
    // Blocks past the end of a folded (x, y) dispatch write no total (a clamped index would race).
    let block = linear_group(wid, nwg);
    if lid.x == WG - 1u && block * WG < c { sums[block] = tile[lid.x]; }
}

@compute @workgroup_size(256)
fn ploc_block_scan(@builtin(local_invocation_id) lid: vec3<u32>) {
    if lid.x == 0u { clusters_left = atomicLoad(&state[3]); }
    let c = workgroupUniformLoad(&clusters_left);
    if c <= 1u { return; }
    let blocks = (c + WG - 1u) / WG;
    var carry = 0u;
    for (var base = 0u; base < blocks; base += WG) {
        let b = base + lid.x;
        var v = 0u;
        if b < blocks { v = sums[b]; }
        tile[lid.x] = v;
        scan_tile(lid.x);
        if b < blocks { sums[b] = carry + tile[lid.x] - v; }
        carry += tile[WG - 1u];
        workgroupBarrier();
    }
    if lid.x == 0u { atomicStore(&state[5], carry); }
}

@compute @workgroup_size(256)
fn ploc_compact(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let c = atomicLoad(&state[3]);
    if i >= c { return; }
    let v = next[i];
    if v != GONE { set_cluster(offsets[i] + sums[linear_group(wid, nwg)], v); }
}

@compute @workgroup_size(1)
fn ploc_advance() {
    let c = atomicLoad(&state[3]);
    if c <= 1u { return; }
    let k = atomicLoad(&state[5]);
    atomicStore(&state[3], k);
    atomicAdd(&state[6], 1u);
    set_args(k);
}
