// Sums of f32 arrays in double-float arithmetic (hi + lo pairs, Knuth's TwoSum), so that the degradation
// metric summed on the GPU matches the CPU's f64 sum to well under 1e-5 relative, without float atomics.
// Pass 1 (`sum_blocks`): each workgroup folds 256 values (stride loop) into one pair; pass 2
// (`sum_pairs`): one workgroup folds the pairs. WGSL guarantees correctly rounded + and -, which TwoSum
// needs.

struct SumParams { n: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> values: array<f32>;
@group(0) @binding(1) var<storage, read_write> pairs: array<vec2<f32>>;
@group(0) @binding(2) var<uniform> params: SumParams;

var<workgroup> acc: array<vec2<f32>, 256>;

fn two_sum(a: f32, b: f32) -> vec2<f32> {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    return vec2<f32>(s, e);
}

fn add_df(x: vec2<f32>, y: vec2<f32>) -> vec2<f32> {
    let s = two_sum(x.x, y.x);
    let e = s.y + x.y + y.y;
    return two_sum(s.x, e);
}

fn fold(lid: u32) {
    for (var off = WG / 2u; off > 0u; off = off >> 1u) {
        workgroupBarrier();
        if lid < off { acc[lid] = add_df(acc[lid], acc[lid + off]); }
    }
    workgroupBarrier();
}

// Folds the workgroup's values (`v` from each invocation) and stores the block's pair. Blocks past the end
// of a folded (x, y) dispatch write nothing (a clamped index would race).
fn store_block(v: f32, lid: u32, block: u32) {
    acc[lid] = vec2<f32>(v, 0.0);
    fold(lid);
    if lid == 0u && block * WG < params.n { pairs[block] = acc[0]; }
}

@compute @workgroup_size(256)
fn sum_blocks(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    let i = block * WG + lid.x;
    var v = 0.0;
    if i < params.n { v = values[i]; }
    store_block(v, lid.x, block);
}

@compute @workgroup_size(256)
fn sum_pairs(@builtin(local_invocation_id) lid: vec3<u32>) {
    var v = vec2<f32>(0.0);
    for (var b = lid.x; b < params.n; b += WG) { v = add_df(v, pairs[b]); }
    acc[lid.x] = v;
    fold(lid.x);
    if lid.x == 0u { pairs[0] = acc[0]; }
}
