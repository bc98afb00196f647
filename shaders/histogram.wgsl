// Histogram of a build's sorted 30-bit Morton codes for the scene characteriser (src/characterize.rs):
// `bins` bins of integer width ⌈(hi − lo + 1) / bins⌉ over [lo, hi] = [codes[0], codes[n − 1]], the last
// bin clamped, exactly as characterize::bin_width / bin_of. Counts are integers, so the result equals the
// CPU histogram bin for bin. Each workgroup counts into workgroup memory first, then adds its non-zero bins
// to the global counts (one global atomic per bin per workgroup, not one per code).

struct HistParams { n: u32, bins: u32, _a: u32, _b: u32 }

const MAX_BINS: u32 = 256u;

@group(0) @binding(0) var<storage, read> codes: array<u32>;
@group(0) @binding(1) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(2) var<uniform> params: HistParams;

var<workgroup> local_counts: array<atomic<u32>, MAX_BINS>;

@compute @workgroup_size(256)
fn histogram_clear(@builtin(local_invocation_id) lid: vec3<u32>) {
    if lid.x < params.bins { atomicStore(&counts[lid.x], 0u); }
}

@compute @workgroup_size(256)
fn histogram(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let bins = params.bins;
    if lid.x < bins { atomicStore(&local_counts[lid.x], 0u); }
    workgroupBarrier();
    let i = linear_id(gid, nwg);
    if i < params.n {
        let lo = codes[0];
        let width = max((codes[params.n - 1u] - lo + bins) / bins, 1u);
        let bin = min((codes[i] - lo) / width, bins - 1u);
        atomicAdd(&local_counts[bin], 1u);
    }
    workgroupBarrier();
    if lid.x < bins {
        let c = atomicLoad(&local_counts[lid.x]);
        if c > 0u { atomicAdd(&counts[lid.x], c); }
    }
}
