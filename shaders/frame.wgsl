// The GPU-resident frame's top level (src/gpu/frame/): per instance its world box from the root of its
// tree, written as a triangle (min, max, max) whose box is that box, so the LBVH builder over those
// triangles builds the top-level tree; then the instances in the order of the tree's leaf slots, for the
// scene kernel (scene.wgsl), which reads instance `s` at leaf slot `s`.

struct FrameParams { instances: u32, _a: u32, _b: u32, _c: u32 }

// One instance is 36 words (GpuInstance in scene.rs); word 28 is the root of its tree in `blas`.
const INSTANCE_WORDS: u32 = 36u;
const NODE_OFFSET_WORD: u32 = 28u;

@group(0) @binding(0) var<storage, read> blas: array<Node>;
@group(0) @binding(1) var<storage, read> by_id: array<u32>;
// Object-to-world transform per instance: columns x, y, z, translation.
@group(0) @binding(2) var<storage, read> forward: array<vec4<f32>>;
// The top-level tree's slots: the instance at each leaf slot, after its build.
@group(0) @binding(3) var<storage, read> tlas_ids: array<u32>;
@group(0) @binding(4) var<storage, read_write> tlas_positions: array<f32>;
@group(0) @binding(5) var<storage, read_write> sorted: array<u32>;
@group(0) @binding(6) var<uniform> params: FrameParams;

fn put(v: u32, p: vec3<f32>) {
    tlas_positions[3u * v] = p.x;
    tlas_positions[3u * v + 1u] = p.y;
    tlas_positions[3u * v + 2u] = p.z;
}

// The world box of instance i: its root box's eight corners transformed, widened by a relative 2^-20 so
// that the rounding of this transform against the CPU's never makes it smaller than the geometry.
@compute @workgroup_size(256)
fn instance_boxes(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.instances { return; }
    let root = blas[by_id[i * INSTANCE_WORDS + NODE_OFFSET_WORD]];
    let c0 = forward[4u * i].xyz;
    let c1 = forward[4u * i + 1u].xyz;
    let c2 = forward[4u * i + 2u].xyz;
    let c3 = forward[4u * i + 3u].xyz;
    var lo = vec3<f32>(3.4e38);
    var hi = vec3<f32>(-3.4e38);
    for (var k = 0u; k < 8u; k++) {
        let c = select(root.min, root.max, (vec3<u32>(k) & vec3<u32>(1u, 2u, 4u)) != vec3<u32>(0u));
        let w = c0 * c.x + c1 * c.y + c2 * c.z + c3;
        lo = min(lo, w);
        hi = max(hi, w);
    }
    let pad = (abs(lo) + abs(hi) + (hi - lo)) * 9.5367431640625e-7 + vec3<f32>(1.17549435e-38);
    put(3u * i, lo - pad);
    put(3u * i + 1u, hi + pad);
    put(3u * i + 2u, hi + pad);
}

// sorted[s] = by_id[the instance at leaf slot s of the top-level tree].
@compute @workgroup_size(256)
fn order_instances(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if s >= params.instances { return; }
    let at = tlas_ids[s] * INSTANCE_WORDS;
    for (var k = 0u; k < INSTANCE_WORDS; k++) {
        sorted[s * INSTANCE_WORDS + k] = by_id[at + k];
    }
}
