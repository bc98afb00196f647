// Test hook (feature `testing`): common.wgsl's div_rn over pairs, and its sqrt_from over (x, guess) pairs,
// for comparing with the CPU's division and square root.

@group(0) @binding(0) var<storage, read> num: array<f32>;
@group(0) @binding(1) var<storage, read> den: array<f32>;
@group(0) @binding(2) var<storage, read_write> quot: array<f32>;

@compute @workgroup_size(256)
fn divide(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i < arrayLength(&quot) { quot[i] = div_rn(num[i], den[i]); }
}

@compute @workgroup_size(256)
fn root(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= arrayLength(&quot) { return; }
    // A NaN guess stands for the driver's root: sqrt_rn.
    let driver = (bitcast<u32>(den[i]) & 0x7fffffffu) > 0x7f800000u;
    quot[i] = select(sqrt_from(num[i], den[i]), sqrt_rn(num[i]), driver);
}
