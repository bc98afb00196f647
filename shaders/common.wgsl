// Shared definitions, prepended to every kernel module by src/gpu/kernels.rs.

// The crate's 32-byte node (src/bvh/node.rs): inner nodes hold the left child index (right = left + 1),
// leaves set bit 31, the count in bits 27..=30 and the first slot in bits 0..=26.
struct Node {
    min: vec3<f32>,
    index: u32,
    max: vec3<f32>,
    sa_ratio: f32,
}

const LEAF_BIT: u32 = 0x80000000u;
const WG: u32 = 256u;
const MAX_RATIO: f32 = 1024.0;

// glam's Vec3::dot and Vec3::cross, operation for operation. WGSL's `dot` and `cross` leave the order of
// their multiplies and adds, and whether they fuse, to the driver; these round as the CPU does once the
// kernels are compiled without contraction (src/gpu/precise.rs).
fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 { return a.x * b.x + a.y * b.y + a.z * b.z; }
fn cross3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

// Veltkamp split of a (no overflow for |a| < 2^115): a = hi + lo exactly, each with at most 12 bits.
fn split(a: f32) -> vec2<f32> {
    let c = 4097.0 * a;
    let hi = c - (c - a);
    return vec2<f32>(hi, a - hi);
}

// The exact error of fl(a * b): a * b = fl(a * b) + err (Dekker).
fn product_error(a: f32, b: f32, p: f32) -> f32 {
    let x = split(a);
    let y = split(b);
    return ((x.x * y.x - p) + x.x * y.y + x.y * y.x) + x.y * y.y;
}

// a / b rounded to nearest, as the CPU divides. Vulkan lets a driver's division err by 2.5 ulp, and
// NVIDIA's does: the mantissas' quotient (in (1/2, 2), scaled by a power of two, exactly) is moved to the
// neighbour with the smaller exact remainder m − c·n (Dekker's product error: exact without contraction,
// no underflow at these magnitudes) until neither neighbour is nearer. A quotient that is zero, not
// finite, or below the smallest normal (where the scaling back would round again) is the driver's.
fn div_rn(a: f32, b: f32) -> f32 {
    let q = a / b;
    if a == 0.0 || !(abs(q) >= 1.17549435e-38 && abs(q) <= fmax()) || !(abs(b) <= fmax()) { return q; }
    let fa = frexp(a);
    let fb = frexp(b);
    let m = fa.fract;
    let n = fb.fract;
    var c = m / n;
    var r = remainder_of(m, n, c);
    for (var k = 0u; k < 3u; k++) {
        // The true quotient lies beyond c in the direction of r / n: one ulp that way.
        let away = ((r > 0.0) == (n > 0.0)) == (c > 0.0);
        let d = bitcast<f32>(select(bitcast<u32>(c) - 1u, bitcast<u32>(c) + 1u, away));
        let rd = remainder_of(m, n, d);
        if !(abs(rd) < abs(r)) { break; }
        c = d;
        r = rd;
    }
    return ldexp(c, fa.exp - fb.exp);
}

// m − c·n for c·n within a few ulp of m: m − fl(c·n) is exact (Sterbenz), then the product's error.
fn remainder_of(m: f32, n: f32, c: f32) -> f32 {
    let p = c * n;
    return (m - p) - product_error(c, n, p);
}

// √x rounded to nearest, as the CPU's `f32::sqrt`. Vulkan lets a driver's square root err by several
// ulp (and leaves √0 undefined); sqrt_from corrects it, and a zero is its own root.
fn sqrt_rn(x: f32) -> f32 {
    if (bitcast<u32>(x) & 0x7fffffffu) == 0u { return x; }
    return sqrt_from(x, sqrt(x));
}

// √x rounded to nearest from a guess `s` within eight floats of it (four ulp of the larger binade's
// where the root lies just below a power of two): moved to the neighbour with the smaller remainder
// x − c² (from Sterbenz's exact difference and Dekker's product error; rounded at most once, which keeps
// the order of two neighbours' remainders, and never tied: a square root is never halfway between two
// floats) until neither neighbour is nearer. An x outside [2^-100, 2^126] (where c² could underflow or
// overflow), NaN included, keeps the guess; a device that flushes subnormals loses Dekker's smallest
// term below about 2^-80.
fn sqrt_from(x: f32, s: f32) -> f32 {
    if !(x >= 7.88860905e-31 && x <= 8.50705917e37) { return s; }
    var c = s;
    var r = root_remainder(x, c);
    for (var k = 0u; k < 8u; k++) {
        // The root lies beyond c on the side of r's sign: one ulp that way.
        let d = bitcast<f32>(select(bitcast<u32>(c) - 1u, bitcast<u32>(c) + 1u, r > 0.0));
        let rd = root_remainder(x, d);
        if !(abs(rd) < abs(r)) { break; }
        c = d;
        r = rd;
    }
    return c;
}

// x − c·c for c within a few ulp of √x.
fn root_remainder(x: f32, c: f32) -> f32 {
    let p = c * c;
    return (x - p) - product_error(c, c, p);
}

fn div3_rn(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(div_rn(a.x, b.x), div_rn(a.y, b.y), div_rn(a.z, b.z));
}

fn is_leaf(n: Node) -> bool { return (n.index & LEAF_BIT) != 0u; }
fn leaf_first(n: Node) -> u32 { return n.index & 0x07ffffffu; }
fn leaf_count(n: Node) -> u32 { return (n.index >> 27u) & 0xfu; }

// Whether x is neither infinite nor NaN, and whether it is NaN, from its bits (WGSL implementations may
// assume that neither occurs, and fold a comparison that would tell).
fn finite(x: f32) -> bool { return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u; }
fn is_nan(x: f32) -> bool { return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u; }

// An order-preserving key of a float: larger floats, larger keys (−0 below +0); and its float.
fn key(f: f32) -> u32 {
    let b = bitcast<u32>(f);
    return select(b | 0x80000000u, ~b, (b & 0x80000000u) != 0u);
}

fn unkey(k: u32) -> f32 {
    return bitcast<f32>(select(~k, k & 0x7fffffffu, (k & 0x80000000u) != 0u));
}

// The largest finite f32: the identity of min/max over finite data (WGSL implementations may assume that no
// infinity occurs, so none is used).
fn fmax() -> f32 { return bitcast<f32>(0x7f7fffffu); }

// The linear invocation index of a 1D dispatch folded into x, y and z (past the groups per dimension).
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + (gid.y + gid.z * nwg.y) * nwg.x * WG;
}

// The linear workgroup index of a 1D dispatch folded into x, y and z.
fn linear_group(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + (wid.y + wid.z * nwg.y) * nwg.x;
}

// Indirect workgroup counts for g groups at m groups per dimension (the device's limit): folded into y,
// then z. wgpu skips an indirect dispatch with any count past the limit, so nothing may exceed m.
fn fold_groups(g: u32, m: u32) -> vec3<u32> {
    let rows = (g + m - 1u) / m;
    return vec3<u32>(min(g, m), min(rows, m), (rows + m - 1u) / m);
}

// SA(parent) / (SA(left) + SA(right)), scale-free and guarded exactly as geometry::sa_ratio on the CPU.
fn half_area_scaled(e: vec3<f32>, inv: f32) -> f32 {
    let s = max(e * inv, vec3<f32>(0.0));
    return s.x * s.y + s.y * s.z + s.z * s.x;
}

fn sa_ratio(pmin: vec3<f32>, pmax: vec3<f32>, lmin: vec3<f32>, lmax: vec3<f32>, rmin: vec3<f32>, rmax: vec3<f32>) -> f32 {
    let pe = pmax - pmin;
    let scale = max(max(pe.x, pe.y), pe.z);
    if !(scale > 0.0 && scale <= fmax()) { return 1.0; }
    let inv = div_rn(1.0, scale);
    let sp = half_area_scaled(pe, inv);
    let sc = half_area_scaled(lmax - lmin, inv) + half_area_scaled(rmax - rmin, inv);
    if sp <= 0.0 { return 1.0; }
    if sc <= 0.0 { return MAX_RATIO; }
    return min(div_rn(sp, sc), MAX_RATIO);
}
