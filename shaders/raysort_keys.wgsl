// Ray keys (src/raysort/key.rs, the same layouts and arithmetic) and the gathers around the two radix sorts
// that make the sorted order of src/raysort/gpu.rs: valid rays by key, stable, then the invalid rays in
// request order.
//
// Validity is decided on the bits (exponent all ones = not finite), never with float comparisons against
// infinity or NaN, which WGSL implementations may assume away.

struct SecondaryRay {
    origin: vec3<f32>,
    light: u32,
    dir: vec3<f32>,
    tmin: f32,
    tmax: f32,
    kind: u32,     // 0 shadow (toward `light`), 1 reflection
    _pad0: u32,
    _pad1: u32,
}

// n; the layout's four bit counts, 8 bits each: light | shadow dir | origin | reflection dir (low byte).
struct KeyParams { n: u32, bits: u32, _pad0: u32, _pad1: u32 }

@group(0) @binding(0) var<storage, read> rays: array<SecondaryRay>;
@group(0) @binding(1) var<storage, read_write> keys: array<u32>;
@group(0) @binding(2) var<storage, read_write> vals: array<u32>;
// Per request index: (key, 1 if the ray is invalid).
@group(0) @binding(3) var<storage, read_write> info: array<vec2<u32>>;
// Origin bounds of the valid rays as order-preserving integers: min x, y, z, max x, y, z.
@group(0) @binding(4) var<storage, read_write> bounds: array<atomic<u32>, 6>;
@group(0) @binding(5) var<uniform> params: KeyParams;

fn valid(r: SecondaryRay) -> bool {
    let o = finite(r.origin.x) && finite(r.origin.y) && finite(r.origin.z);
    let d = finite(r.dir.x) && finite(r.dir.y) && finite(r.dir.z);
    let nonzero = any(r.dir != vec3<f32>(0.0));
    return o && d && nonzero && !is_nan(r.tmin) && !is_nan(r.tmax);
}

// f32 bits mapped so that unsigned integer order is float order.
fn ordered(x: f32) -> u32 {
    let b = bitcast<u32>(x);
    return select(b ^ 0x80000000u, ~b, (b & 0x80000000u) != 0u);
}

fn unordered(u: u32) -> f32 {
    return bitcast<f32>(select(~u, u ^ 0x80000000u, (u & 0x80000000u) != 0u));
}

fn mask(bits: u32) -> u32 { return select((1u << bits) - 1u, 0xffffffffu, bits >= 32u); }

// f in [0, 1] in 2^bits equal steps; out of range and NaN clamp to the ends (as key.rs's `quantise`).
fn quantise(f: f32, bits: u32) -> u32 {
    let steps = f32(1u << bits);
    let x = f * steps;
    if !(x > 0.0) { return 0u; }
    return min(u32(min(x, steps)), mask(bits));
}

fn interleave2(a: u32, b: u32, bits: u32) -> u32 {
    var out = 0u;
    for (var i = bits; i > 0u; i--) {
        out = (out << 2u) | (((a >> (i - 1u)) & 1u) << 1u) | ((b >> (i - 1u)) & 1u);
    }
    return out;
}

fn interleave3(a: u32, b: u32, c: u32, bits: u32) -> u32 {
    var out = 0u;
    for (var i = bits; i > 0u; i--) {
        let s = i - 1u;
        out = (out << 3u) | (((a >> s) & 1u) << 2u) | (((b >> s) & 1u) << 1u) | ((c >> s) & 1u);
    }
    return out;
}

// The polar step (cos θ in equal steps from +z) and the azimuth step (the diamond angle of (x, y) from -x,
// 1 + x' for y <= 0 and 3 - x' above, x' = x / (|x| + |y|), -1 along ±z), as key.rs's `direction`.
fn direction(d: vec3<f32>, bits: u32) -> u32 {
    let polar = quantise((1.0 - d.z / sqrt(dot3(d, d))) * 0.5, bits);
    let s = abs(d.x) + abs(d.y);
    var x = -1.0;
    if s > 0.0 { x = div_rn(d.x, s); }
    var diamond = 3.0 - x;
    if d.y <= 0.0 { diamond = 1.0 + x; }
    return interleave2(polar, quantise(diamond * 0.25, bits), bits);
}

fn shl(x: u32, s: u32) -> u32 { return select(x << s, 0u, s >= 32u); }

@compute @workgroup_size(256)
fn origin_bounds(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.n { return; }
    let r = rays[i];
    if !valid(r) { return; }
    for (var a = 0u; a < 3u; a++) {
        let o = ordered(r.origin[a]);
        atomicMin(&bounds[a], o);
        atomicMax(&bounds[a + 3u], o);
    }
}

@compute @workgroup_size(256)
fn ray_keys(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.n { return; }
    let r = rays[i];
    vals[i] = i;
    if !valid(r) {
        keys[i] = 0u;
        info[i] = vec2<u32>(0u, 1u);
        return;
    }
    let light_bits = (params.bits >> 24u) & 0xffu;
    let shadow_bits = (params.bits >> 16u) & 0xffu;
    let origin_bits = (params.bits >> 8u) & 0xffu;
    let reflection_bits = params.bits & 0xffu;
    var key = 0u;
    if r.kind == 0u {
        key = shl(r.light & mask(light_bits), 2u * shadow_bits) | direction(r.dir, shadow_bits);
    } else {
        var cell = vec3<u32>(0u);
        for (var a = 0u; a < 3u; a++) {
            let lo = unordered(atomicLoad(&bounds[a]));
            let extent = unordered(atomicLoad(&bounds[a + 3u])) - lo;
            var f = 0.0;
            if extent > 0.0 { f = div_rn(r.origin[a] - lo, extent); }
            cell[a] = quantise(f, origin_bits);
        }
        let origin = interleave3(cell.x, cell.y, cell.z, origin_bits);
        key = shl(origin, 2u * reflection_bits) | direction(r.dir, reflection_bits);
    }
    keys[i] = key;
    info[i] = vec2<u32>(key, 0u);
}

// After the key sort: each position's invalid flag becomes its key, for the stable 1-bit sort that moves
// the invalid rays (all of key 0, so still in request order) behind the valid ones.
@compute @workgroup_size(256)
fn gather_invalid(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.n { return; }
    keys[i] = info[vals[i]].y;
}

// After both sorts: each position's ray key back in place.
@compute @workgroup_size(256)
fn gather_keys(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= params.n { return; }
    keys[i] = info[vals[i]].x;
}
