// Linear-blend skinning, 4 joints per vertex: p' = Σ w_k · (M_{j_k} · (p, 1)), with p the rest position
// plus the blend shapes, p = rest + Σ_t weight_t · delta_t (added in target order, as the CPU's
// MorphTargets::apply). Writes the positions that the refit and LBVH kernels read, in the same flat xyz
// layout, with no CPU round trip.

struct SkinParams { vertices: u32, targets: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> rest: array<f32>;
@group(0) @binding(1) var<storage, read> joints: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> weights: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> matrices: array<mat4x4<f32>>;
@group(0) @binding(4) var<storage, read_write> positions: array<f32>;
@group(0) @binding(5) var<uniform> params: SkinParams;
// deltas[(t · vertices + i) · 3 ..]: target t's displacement of vertex i; one weight per target.
@group(0) @binding(6) var<storage, read> deltas: array<f32>;
@group(0) @binding(7) var<storage, read> morph_weights: array<f32>;

// `m · (p, 1)` in glam's order (`Mat4::transform_point3`: x, plus y, plus z, then the translation), not
// the driver's matrix product, so that the GPU rounds as the CPU's `skin_positions` does.
fn transform_point(m: mat4x4<f32>, p: vec3<f32>) -> vec3<f32> {
    return ((m[0].xyz * p.x + m[1].xyz * p.y) + m[2].xyz * p.z) + m[3].xyz;
}

@compute @workgroup_size(256)
fn skin(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.vertices { return; }
    var r = vec3<f32>(rest[3u * i], rest[3u * i + 1u], rest[3u * i + 2u]);
    for (var t = 0u; t < params.targets; t++) {
        let w = morph_weights[t];
        if w != 0.0 {
            let d = 3u * (t * params.vertices + i);
            r += vec3<f32>(deltas[d], deltas[d + 1u], deltas[d + 2u]) * w;
        }
    }
    let j = joints[i];
    let w = weights[i];
    let q = transform_point(matrices[j.x], r) * w.x + transform_point(matrices[j.y], r) * w.y
          + transform_point(matrices[j.z], r) * w.z + transform_point(matrices[j.w], r) * w.w;
    positions[3u * i] = q.x;
    positions[3u * i + 1u] = q.y;
    positions[3u * i + 2u] = q.z;
}
