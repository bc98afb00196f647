// The shadow map of a directional light (src/gpu/shadow_map.rs): the CPU's shadows::ShadowMap rendered
// operation for operation — each corner taken into light space by its group's transform composed with the
// light, the point nearest the light, then every triangle's covered texel centres with the CPU
// rasteriser's edge functions, row spans and depth plane — so each texel gets the CPU's depth. Depths are
// kept as order-preserving keys, complemented, so `atomicMax` keeps the nearest and a cleared buffer (0)
// is an empty texel.

struct MapParams {
    triangles: u32,
    groups: u32,
    res: u32,
    max_groups: u32,
    corner: vec2<f32>,
    per_texel: f32,
    _pad: f32,
}

@group(0) @binding(0) var<storage, read> corners: array<f32>;        // 9 per triangle
@group(0) @binding(1) var<storage, read> starts: array<u32>;         // each group's first triangle, then n
// Per group: m's columns, then t with the CPU's `ToLight::cull` as w (0: every triangle; ±1: only those
// whose area across the map has this sign, a closed group's faces towards the light).
@group(0) @binding(2) var<storage, read> to_light: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> depth: array<atomic<u32>>;
// [0]: the key of the largest `p · towards` (0: none), [1]: how many triangles are listed in `large`.
@group(0) @binding(4) var<storage, read_write> state: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> large: array<u32>;
@group(0) @binding(6) var<storage, read_write> args: array<u32>;
@group(0) @binding(7) var<storage, read> mp: MapParams;

// Triangles spanning more rows of texel centres than this, or more centres in all, are rasterised by
// SPLIT workgroups each (a row per invocation: a triangle under the whole map, the ground, spread over
// several of the GPU's cores), the rest by their own invocation.
const SMALL_ROWS: u32 = 4u;
const SMALL_TEXELS: u32 = 64u;
const SPLIT: u32 = 8u;
// Centres along a row below which each is tested (the CPU's NARROW).
const NARROW: u32 = 4u;
// 2^126 texels²: larger triangles cover nothing (the CPU's MAX_AREA).
const MAX_AREA: u32 = 0x7e800000u;

// Whether no component is infinite or NaN, from the bits (no reliance on the compiler keeping infinities).
fn finite3(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7f800000u);
    return all(e != vec3<u32>(0x7f800000u));
}

// The CPU's `ceil` and `floor` (src/shadows/shadow_map/raster.rs): exact below 2³¹, clamped to ±2³¹ beyond,
// 0 for NaN.
fn ceil_c(x: f32) -> f32 {
    if is_nan(x) { return 0.0; }
    return ceil(clamp(x, -2147483648.0, 2147483648.0));
}

fn floor_c(x: f32) -> f32 {
    if is_nan(x) { return 0.0; }
    return floor(clamp(x, -2147483648.0, 2147483648.0));
}

// The group triangle `i` belongs to: the last whose first triangle is at most `i`.
fn group_of(i: u32) -> u32 {
    var lo = 0u;
    var hi = mp.groups;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if starts[mid] <= i { lo = mid; } else { hi = mid; }
    }
    return lo;
}

// Corner `k` of triangle `i` in light space: glam's `Mat3A * Vec3A` (column by column) plus `t`.
fn in_light(i: u32, g: u32, k: u32) -> vec3<f32> {
    let at = 9u * i + 3u * k;
    let p = vec3<f32>(corners[at], corners[at + 1u], corners[at + 2u]);
    let m0 = to_light[4u * g].xyz;
    let m1 = to_light[4u * g + 1u].xyz;
    let m2 = to_light[4u * g + 2u].xyz;
    let t = to_light[4u * g + 3u].xyz;
    return ((m0 * p.x + m1 * p.y) + m2 * p.z) + t;
}

// A triangle ready to rasterise: corners in texels (z: depth), the three edge functions (a, b, c) with
// weights summing to one, the depth's step along a row, where each edge crosses a row per unit of its
// b·y + c, and the texel centres its bounds span.
struct Setup {
    t0: vec3<f32>,
    t1: vec3<f32>,
    t2: vec3<f32>,
    e0: vec3<f32>,
    e1: vec3<f32>,
    e2: vec3<f32>,
    dz: f32,
    crossing: vec3<f32>,
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    ok: bool,
}

fn coef(a: vec3<f32>, b: vec3<f32>, per_area: f32) -> vec3<f32> {
    let ea = (a.y - b.y) * per_area;
    let eb = (b.x - a.x) * per_area;
    return vec3<f32>(ea, eb, -(ea * a.x + eb * a.y));
}

// `span` of the CPU: the first and last centre (i + 0.5) in [lo, hi], clamped to 0..n, as floats.
fn span(lo: f32, hi: f32, n: u32) -> vec2<f32> {
    return vec2<f32>(max(ceil_c(lo - 0.5), 0.0), min(floor_c(hi - 0.5), f32(n) - 1.0));
}

// Triangle `i` set up as the CPU's `rasterise` sets it up; `ok` false when it covers nothing.
fn setup(i: u32) -> Setup {
    var s: Setup;
    s.ok = false;
    let g = group_of(i);
    let q0 = in_light(i, g, 0u);
    let q1 = in_light(i, g, 1u);
    let q2 = in_light(i, g, 2u);
    if !finite3((q0 + q1) + q2) { return s; }
    let top = unkey(atomicLoad(&state[0]));
    let per = mp.per_texel;
    s.t0 = vec3<f32>((q0.xy - mp.corner) * per, top - q0.z);
    s.t1 = vec3<f32>((q1.xy - mp.corner) * per, top - q1.z);
    s.t2 = vec3<f32>((q2.xy - mp.corner) * per, top - q2.z);
    let lo = min(min(s.t0, s.t1), s.t2);
    let hi = max(max(s.t0, s.t1), s.t2);
    let ys = span(lo.y, hi.y, mp.res);
    let xs = span(lo.x, hi.x, mp.res);
    if ys.y < ys.x || xs.y < xs.x { return s; }
    let area = (s.t1.x - s.t0.x) * (s.t2.y - s.t0.y) - (s.t1.y - s.t0.y) * (s.t2.x - s.t0.x);
    // The CPU's MAX_AREA: beyond it 1 / area would be subnormal, which a GPU may flush to zero.
    if area == 0.0 || !(abs(area) < bitcast<f32>(MAX_AREA)) { return s; }
    // A closed group's faces away from the light (the CPU's `faces`).
    let cull = to_light[4u * g + 3u].w;
    if cull != 0.0 && !(area * cull > 0.0) { return s; }
    let per_area = div_rn(1.0, area);
    s.e0 = coef(s.t1, s.t2, per_area);
    s.e1 = coef(s.t2, s.t0, per_area);
    s.e2 = coef(s.t0, s.t1, per_area);
    s.dz = (s.e0.x * s.t0.z + s.e1.x * s.t1.z) + s.e2.x * s.t2.z;
    let a = vec3<f32>(s.e0.x, s.e1.x, s.e2.x);
    // Used only where a ≠ 0.
    let safe = select(a, vec3<f32>(1.0), a == vec3<f32>(0.0));
    s.crossing = -vec3<f32>(div_rn(1.0, safe.x), div_rn(1.0, safe.y), div_rn(1.0, safe.z));
    s.x0 = u32(xs.x);
    s.x1 = u32(xs.y);
    s.y0 = u32(ys.x);
    s.y1 = u32(ys.y);
    s.ok = true;
    return s;
}

fn weight(e: vec3<f32>, cx: f32, cy: f32) -> f32 {
    return (e.x * cx + e.y * cy) + e.z;
}

fn inside(s: Setup, cx: f32, cy: f32) -> bool {
    return weight(s.e0, cx, cy) >= 0.0 && weight(s.e1, cx, cy) >= 0.0 && weight(s.e2, cx, cy) >= 0.0;
}

fn centre(x: u32) -> f32 {
    return f32(x) + 0.5;
}

// The CPU's `d.min(z)`: a NaN depth changes nothing.
fn write(x: u32, y: u32, z: f32) {
    if is_nan(z) { return; }
    atomicMax(&depth[y * mp.res + x], ~key(z));
}

// Lowers the one edge's bound of the row's covered span, as the CPU does.
fn narrow_span(e: vec3<f32>, cross: f32, cy: f32, fromto: vec2<f32>) -> vec2<f32> {
    var ft = fromto;
    let r = e.y * cy + e.z;
    if e.x > 0.0 {
        ft.x = max(ft.x, ceil_c(r * cross - 0.5) - 1.0);
    } else if e.x < 0.0 {
        ft.y = min(ft.y, floor_c(r * cross - 0.5) + 1.0);
    } else if r < 0.0 {
        ft.y = -1.0;
    }
    return ft;
}

// Row `y` of triangle `s`: the CPU's `rasterise` for one row.
fn raster_row(s: Setup, y: u32) {
    let cy = f32(y) + 0.5;
    let z_row = ((s.e0.y * cy + s.e0.z) * s.t0.z + (s.e1.y * cy + s.e1.z) * s.t1.z)
        + (s.e2.y * cy + s.e2.z) * s.t2.z;
    if s.x1 - s.x0 < NARROW {
        for (var x = s.x0; x <= s.x1; x++) {
            if inside(s, centre(x), cy) { write(x, y, s.dz * centre(x) + z_row); }
        }
        return;
    }
    var ft = vec2<f32>(f32(s.x0), f32(s.x1));
    ft = narrow_span(s.e0, s.crossing.x, cy, ft);
    ft = narrow_span(s.e1, s.crossing.y, cy, ft);
    ft = narrow_span(s.e2, s.crossing.z, cy, ft);
    if ft.y < ft.x { return; }
    var first = u32(ft.x);
    var last = u32(ft.y);
    while first <= last && !inside(s, centre(first), cy) { first++; }
    while last > first && !inside(s, centre(last), cy) { last--; }
    if first > last || !inside(s, centre(first), cy) { return; }
    for (var x = first; x <= last; x++) { write(x, y, s.dz * centre(x) + z_row); }
}

// The largest `p · towards` over every triangle whose light-space corners are finite.
@compute @workgroup_size(256)
fn map_top(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= mp.triangles { return; }
    let g = group_of(i);
    let q0 = in_light(i, g, 0u);
    let q1 = in_light(i, g, 1u);
    let q2 = in_light(i, g, 2u);
    if !finite3((q0 + q1) + q2) { return; }
    // Each corner's key, not the key of `max`: a tie of ±0 goes to +0 whatever the order (as the CPU's).
    atomicMax(&state[0], max(max(key(q0.z), key(q1.z)), key(q2.z)));
}

// Each triangle rasterised by its invocation, or listed for `map_large`.
@compute @workgroup_size(256)
fn map_small(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if i >= mp.triangles { return; }
    let s = setup(i);
    if !s.ok { return; }
    let rows = s.y1 - s.y0 + 1u;
    if rows > SMALL_ROWS || rows * (s.x1 - s.x0 + 1u) > SMALL_TEXELS {
        large[atomicAdd(&state[1], 1u)] = i;
        return;
    }
    for (var y = s.y0; y <= s.y1; y++) { raster_row(s, y); }
}

// The indirect sizes of `map_large`: SPLIT workgroups per listed triangle.
@compute @workgroup_size(1)
fn map_plan() {
    let a = fold_groups(atomicLoad(&state[1]) * SPLIT, mp.max_groups);
    args[0] = a.x;
    args[1] = a.y;
    args[2] = a.z;
}

// A listed triangle per SPLIT workgroups, a row per invocation: workgroup `part` of the triangle takes
// the rows part·WG + lid, then every SPLIT·WG rows on.
@compute @workgroup_size(256)
fn map_large(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let g = linear_group(wid, nwg);
    let k = g / SPLIT;
    if k >= atomicLoad(&state[1]) { return; }
    let s = setup(large[k]);
    if !s.ok { return; }
    for (var y = s.y0 + (g % SPLIT) * WG + lid; y <= s.y1; y += SPLIT * WG) { raster_row(s, y); }
}
