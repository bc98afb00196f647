// The hard selective classification of every pixel against the shadow map the map kernels left in
// `depth` (src/gpu/shadow_map.rs): the CPU's `classify::facing` and `classify::selective`
// (src/shadows/classify.rs) with its operations in its order, so each pixel gets the CPU's class. Four
// pixels an invocation, one byte each in a word, as the CPU's `Class`. Infinities and NaNs from the
// G-buffer are told apart by their bits (WGSL implementations may assume none occurs).

struct ClassifyParams {
    u: vec4<f32>,
    v: vec4<f32>,
    towards: vec4<f32>,
    // The receivers' bounds across the light the map was fitted to (with `check`).
    lo: vec2<f32>,
    hi: vec2<f32>,
    corner: vec2<f32>,
    per_texel: f32,
    // The key of the map's point nearest the light (the map kernels' state, copied), 0 for none.
    top: u32,
    texel: f32,
    bias_texels: f32,
    edge: f32,
    // The map's resolution − 1, as a float: the interior's end.
    last: f32,
    pixels: u32,
    res: u32,
    check: u32,
    _pad: u32,
}

// The map's depths as the map kernels leave them: each the complement of its key, 0 for an empty texel.
@group(0) @binding(0) var<storage, read> depth: array<u32>;
@group(0) @binding(1) var<storage, read> positions: array<f32>;
@group(0) @binding(2) var<storage, read> normals: array<f32>;
@group(0) @binding(3) var<storage, read_write> classes: array<u32>;
// [0]: 1 when a receiver facing the light lies outside the bounds.
@group(0) @binding(4) var<storage, read_write> flags: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read> cp: ClassifyParams;

// The CPU's `shadow_map::nearest`: the float of key `k`, the lowest finite one for none (0).
fn nearest(k: u32) -> f32 { return select(unkey(k), -fmax(), k == 0u); }

// The CPU's `Class`.
const EMPTY: u32 = 0u;
const FACING_AWAY: u32 = 1u;
const LIT: u32 = 2u;
const SHADOWED: u32 = 3u;
const MARKED: u32 = 4u;

// Texel (i, j)'s depth; not finite where it is empty.
fn depth_at(i: u32, j: u32) -> f32 {
    let d = depth[j * cp.res + i];
    return select(unkey(~d), bitcast<f32>(0x7f800000u), d == 0u);
}

// Whether interior texel (i, j), of finite depth `s`, is smooth: its eight neighbours are not empty and
// none differs from it by more than the edge threshold (the CPU's `Deltas`).
fn smooth_texel(i: u32, j: u32, s: f32) -> bool {
    for (var dj = 0u; dj < 3u; dj++) {
        for (var di = 0u; di < 3u; di++) {
            let n = depth_at(i + di - 1u, j + dj - 1u);
            if !finite(n) || !(abs(n - s) <= cp.edge) { return false; }
        }
    }
    return true;
}

// The CPU's `slope_bias`: the constant bias plus the receiver's reach within one texel.
fn slope_bias(cos: f32) -> f32 {
    let c = max(cos, 0.015625);
    let tan = div_rn(sqrt_rn(max(1.0 - c * c, 0.0)), c);
    let w = cp.texel;
    return w * cp.bias_texels + w * bitcast<f32>(0x3fb504f3u) * tan;
}

// The class of the pixel at `p` with normal `n`; with `cp.check`, flags it when it faces the light
// outside the bounds.
fn classify(p: vec3<f32>, n: vec3<f32>) -> u32 {
    let t = cp.towards.xyz;
    let cos = dot3(n, t);
    // The receiver across the light and along it, for both the bounds and the map.
    let q = vec3<f32>(dot3(p, cp.u.xyz), dot3(p, cp.v.xyz), dot3(p, t));
    if cp.check != 0u && !is_nan(cos) && cos > 0.0 {
        let within = !is_nan(q.x) && q.x >= cp.lo.x && q.x <= cp.hi.x
            && !is_nan(q.y) && q.y >= cp.lo.y && q.y <= cp.hi.y && !is_nan(q.z);
        if !within { atomicOr(&flags[0], 1u); }
    }
    if all((bitcast<vec3<u32>>(n) & vec3<u32>(0x7fffffffu)) == vec3<u32>(0u)) { return EMPTY; }
    if !is_nan(cos) && cos <= 0.0 { return FACING_AWAY; }
    let x = (q.x - cp.corner.x) * cp.per_texel;
    let y = (q.y - cp.corner.y) * cp.per_texel;
    if !(finite(x) && finite(y) && x >= 1.0 && y >= 1.0 && x < cp.last && y < cp.last) {
        return MARKED;
    }
    if !finite(cos) { return MARKED; }
    let d = nearest(cp.top) - q.z;
    let i = u32(x);
    let j = u32(y);
    let s = depth_at(i, j);
    if !finite(s) { return MARKED; }
    if smooth_texel(i, j, s) {
        let lit = !is_nan(d) && (d <= s + cp.texel * cp.bias_texels || d <= s + slope_bias(cos));
        return select(SHADOWED, LIT, lit);
    }
    // An edge texel: the four texels whose centres surround the receiver against its tangent plane.
    let i0 = u32(x - 0.5);
    let j0 = u32(y - 0.5);
    let first = vec2<f32>((f32(i0) + 0.5) - x, (f32(j0) + 0.5) - y);
    let k = div_rn(cp.texel, max(cos, 0.015625));
    let slope = vec2<f32>(dot3(n, cp.u.xyz) * k, dot3(n, cp.v.xyz) * k);
    if !(finite(slope.x) && finite(slope.y)) { return MARKED; }
    let bias = cp.texel * cp.bias_texels;
    var front = 0u;
    for (var c = 0u; c < 4u; c++) {
        let at = first + vec2<f32>(f32(c & 1u), f32(c >> 1u));
        let sc = depth_at(i0 + (c & 1u), j0 + (c >> 1u));
        // An empty texel lies in front of nothing.
        if finite(sc) && !is_nan(d) && sc < d + slope.x * at.x + slope.y * at.y - bias { front += 1u; }
    }
    if front == 0u { return LIT; }
    if front == 4u { return SHADOWED; }
    return MARKED;
}

@compute @workgroup_size(256)
fn classify_hard(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = linear_id(gid, nwg);
    let first = 4u * w;
    if first >= cp.pixels { return; }
    var word = 0u;
    for (var k = 0u; k < 4u && first + k < cp.pixels; k++) {
        let at = 3u * (first + k);
        let p = vec3<f32>(positions[at], positions[at + 1u], positions[at + 2u]);
        let n = vec3<f32>(normals[at], normals[at + 1u], normals[at + 2u]);
        word |= classify(p, n) << (8u * k);
    }
    classes[w] = word;
}
