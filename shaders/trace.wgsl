// Closest-hit and any-hit traversal of one ray per invocation, the same algorithm as src/bvh/traverse.rs:
// conservative slab test (Ize 2013), near child first, far child pushed with its
// entry distance, a 64-entry stack (no tree is deeper), and the watertight triangle test of Woop et al.
// 2013 with the ray's shear rows precomputed on the CPU (so both devices compute identical edge functions).
// An edge function that rounds to exactly zero is recomputed exactly: products split with Veltkamp's method
// (WGSL's + and * are correctly rounded), which gives the same value as the CPU's f64 fallback.

struct GpuRay {
    origin: vec3<f32>,
    tmin: f32,
    inv_dir: vec3<f32>,
    tmax: f32,
    row_x: vec3<f32>,
    dir_bits: u32,    // bit k: component k of the direction has its sign bit set; bit 3 + k: it is zero
    row_y: vec3<f32>,
    _pad0: u32,
    row_z: vec3<f32>,
    _pad1: u32,
}

struct GpuHit { t: f32, prim: u32, u: f32, v: f32 }

struct TraceParams { rays: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> nodes: array<Node>;
@group(0) @binding(1) var<storage, read> slot_tris: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> positions: array<f32>;
@group(0) @binding(3) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(4) var<storage, read_write> hits: array<GpuHit>;
@group(0) @binding(5) var<uniform> params: TraceParams;

const MISS: u32 = 0xffffffffu;

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

const ROBUST_TMAX_SCALE: f32 = 1.0000002384185791; // 1 + 2 ulp

const BIG: f32 = 3.0e38;

fn bits3(b: u32) -> vec3<bool> {
    return vec3<bool>((b & 1u) != 0u, (b & 2u) != 0u, (b & 4u) != 0u);
}

// Entry distance into the node's box within [tmin, tmax], or -1 for a miss (tmin >= 0 is enforced on
// upload). WGSL lets implementations assume no NaN or infinity, so instead of the CPU's 0·∞ = NaN that
// drops out of max/min, an axis along which the ray does not move (its inv_dir is uploaded as 0) is
// decided by whether the origin lies within the slab: unbounded if it does, empty if not. Same answers.
fn slab(ray: GpuRay, n: Node, tmax: f32) -> f32 {
    let t0 = (n.min - ray.origin) * ray.inv_dir;
    let t1 = (n.max - ray.origin) * ray.inv_dir;
    let neg = bits3(ray.dir_bits);
    let zero = bits3(ray.dir_bits >> 3u);
    let inside = (ray.origin >= n.min) & (ray.origin <= n.max);
    let near = select(select(t0, t1, neg), select(vec3<f32>(BIG), vec3<f32>(-BIG), inside), zero);
    let far = select(select(t1, t0, neg), select(vec3<f32>(-BIG), vec3<f32>(BIG), inside), zero);
    let tnear = max(near.x, max(near.y, max(near.z, ray.tmin)));
    let tfar = min(far.x, min(far.y, far.z));
    if tnear <= min(tfar * ROBUST_TMAX_SCALE, tmax) { return tnear; }
    return -1.0;
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

// p·q' − p'·q rounded once: when the two rounded products are equal, the exact difference is the
// difference of their rounding errors, which is what the CPU's f64 fallback rounds to f32.
fn edge(px: f32, py: f32, qx: f32, qy: f32) -> f32 {
    let a = px * qy;
    let b = py * qx;
    if a != b { return a - b; }
    return product_error(px, qy, a) - product_error(py, qx, b);
}

struct TriHit { ok: bool, t: f32, u: f32, v: f32 }

fn intersect(ray: GpuRay, v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>, tmax: f32) -> TriHit {
    var miss = TriHit(false, 0.0, 0.0, 0.0);
    // Zero-area triangles never hit (the CPU stores them collapsed to a point).
    let n = cross(v1 - v0, v2 - v0);
    if all(n == vec3<f32>(0.0)) { return miss; }
    let a = v0 - ray.origin;
    let b = v1 - ray.origin;
    let c = v2 - ray.origin;
    let ax = dot(ray.row_x, a);
    let ay = dot(ray.row_y, a);
    let bx = dot(ray.row_x, b);
    let by = dot(ray.row_y, b);
    let cx = dot(ray.row_x, c);
    let cy = dot(ray.row_y, c);
    var u = cx * by - cy * bx;
    var v = ax * cy - ay * cx;
    var w = bx * ay - by * ax;
    if u == 0.0 || v == 0.0 || w == 0.0 {
        u = edge(cx, cy, bx, by);
        v = edge(ax, ay, cx, cy);
        w = edge(bx, by, ax, ay);
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) { return miss; }
    let det = u + v + w;
    if det == 0.0 { return miss; }
    let big_t = u * dot(ray.row_z, a) + v * dot(ray.row_z, b) + w * dot(ray.row_z, c);
    let rcp = 1.0 / det;
    let t = big_t * rcp;
    if !(t >= ray.tmin && t <= tmax) { return miss; }
    return TriHit(true, t, v * rcp, w * rcp);
}

fn trace(ray: GpuRay, any: bool) -> GpuHit {
    var best = GpuHit(ray.tmax, MISS, 0.0, 0.0);
    if (ray.dir_bits & 0x80000000u) != 0u { return best; } // invalid ray
    if arrayLength(&nodes) == 0u || slab(ray, nodes[0], ray.tmax) < 0.0 { return best; }
    var stack_node: array<u32, 64>;
    var stack_t: array<f32, 64>;
    var sp = 0u;
    var cur = 0u;
    loop {
        let n = nodes[cur];
        var next = MISS;
        if is_leaf(n) {
            let f = leaf_first(n);
            for (var s = f; s < f + leaf_count(n); s++) {
                let tri = slot_tris[s];
                let h = intersect(ray, vertex(tri.x), vertex(tri.y), vertex(tri.z), best.t);
                if h.ok && (best.prim == MISS || h.t < best.t || tri.w < best.prim) {
                    best = GpuHit(h.t, tri.w, h.u, h.v);
                    if any { return best; }
                }
            }
        } else {
            let c = n.index;
            let ta = slab(ray, nodes[c], best.t);
            let tb = slab(ray, nodes[c + 1u], best.t);
            if ta >= 0.0 && tb >= 0.0 {
                let a_first = ta <= tb;
                next = select(c + 1u, c, a_first);
                stack_node[sp] = select(c, c + 1u, a_first);
                stack_t[sp] = select(ta, tb, a_first);
                sp += 1u;
            } else if ta >= 0.0 {
                next = c;
            } else if tb >= 0.0 {
                next = c + 1u;
            }
        }
        if next == MISS {
            // Pop the next subtree that can still hold something nearer than the best hit.
            loop {
                if sp == 0u { return best; }
                sp -= 1u;
                if stack_t[sp] <= best.t {
                    next = stack_node[sp];
                    break;
                }
            }
        }
        cur = next;
    }
    return best;
}

@compute @workgroup_size(64)
fn closest(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if i >= params.rays { return; }
    hits[i] = trace(rays[i], false);
}

@compute @workgroup_size(64)
fn any_hit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if i >= params.rays { return; }
    hits[i] = trace(rays[i], true);
}
