// Stable LSD radix sort of (u32 key, u32 value) pairs, 4 bits per pass, portable: workgroup atomics and
// barriers only, no subgroup operations. Per pass: `count` builds a digit histogram per block of 256 keys
// (digit-major: hist[digit * blocks + block]); scan.wgsl scans it; `scatter` ranks each key stably inside
// its block and writes it to hist[digit][block] + rank.
//
// Stable in-block ranking without subgroups: the block is cut into 16 sub-blocks of 16 keys. A key's rank
// is (keys of its digit in earlier sub-blocks) + (keys of its digit earlier in its own sub-block); the first
// term comes from a 16 x 16 table of sub-block histograms scanned along the sub-blocks. Every thread does
// at most 31 steps and three barriers.

struct SortParams { n: u32, _unused: u32, blocks: u32, _pad: u32 }

@group(0) @binding(0) var<storage, read> keys_in: array<u32>;
@group(0) @binding(1) var<storage, read> vals_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(3) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> hist: array<u32>;
@group(0) @binding(5) var<uniform> params: SortParams;
// The pass p in x (its digit is bits 4p..4p+4): the device's pass slots, shared by every sorter.
@group(0) @binding(6) var<uniform> pass_slot: vec4<u32>;

var<workgroup> counts: array<atomic<u32>, 16>;
var<workgroup> digits: array<u32, 256>;
var<workgroup> sub_hist: array<u32, 256>;

const NO_DIGIT: u32 = 16u;

fn digit_of(i: u32) -> u32 {
    if i >= params.n { return NO_DIGIT; }
    return (keys_in[i] >> (4u * pass_slot.x)) & 15u;
}

@compute @workgroup_size(256)
fn count(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    if lid.x < 16u { atomicStore(&counts[lid.x], 0u); }
    workgroupBarrier();
    let d = digit_of(block * WG + lid.x);
    if d != NO_DIGIT { atomicAdd(&counts[d], 1u); }
    workgroupBarrier();
    if lid.x < 16u && block < params.blocks {
        hist[lid.x * params.blocks + block] = atomicLoad(&counts[lid.x]);
    }
}

@compute @workgroup_size(256)
fn scatter(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    let i = block * WG + lid.x;
    let d = digit_of(i);
    digits[lid.x] = d;
    workgroupBarrier();
    let sub = lid.x / 16u;
    let lane = lid.x % 16u;
    // Thread (sub, lane) counts digit `lane` in sub-block `sub`.
    var c = 0u;
    for (var j = 0u; j < 16u; j++) {
        c += select(0u, 1u, digits[sub * 16u + j] == lane);
    }
    sub_hist[lid.x] = c;
    workgroupBarrier();
    // Exclusive scan of digit `lane` along the sub-blocks.
    var before = 0u;
    for (var s = 0u; s < sub; s++) { before += sub_hist[s * 16u + lane]; }
    workgroupBarrier();
    sub_hist[lid.x] = before;
    workgroupBarrier();
    if d == NO_DIGIT || block >= params.blocks { return; }
    var rank = sub_hist[sub * 16u + d];
    for (var j = 0u; j < lane; j++) {
        rank += select(0u, 1u, digits[sub * 16u + j] == d);
    }
    let at = hist[d * params.blocks + block] + rank;
    keys_out[at] = keys_in[i];
    vals_out[at] = vals_in[i];
}
