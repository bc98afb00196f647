// Ray–box and ray–triangle tests shared by the single-mesh (trace.wgsl) and two-level (scene.wgsl) ray
// kernels; prepended after common.wgsl.

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

const MISS: u32 = 0xffffffffu;

const ROBUST_FAR_SLACK: f32 = 2.384185791015625e-7; // 2 ulp(1), as src/geometry/ray.rs robust_far

const HIT_SLACK: f32 = 1.9073486328125e-6; // 16 ulp(1), as src/geometry/ray.rs HIT_SLACK

const BIG: f32 = 3.0e38;

// `slab`'s answer for a box the ray misses: the most negative finite float, below `-BIG`.
const NO_ENTRY: f32 = -3.4028234663852886e38;

fn bits3(b: u32) -> vec3<bool> {
    return vec3<bool>((b & 1u) != 0u, (b & 2u) != 0u, (b & 4u) != 0u);
}

// Entry distance into the node's box within [tmin, tmax], or NO_ENTRY for a miss (below every entry
// distance: tmin >= -BIG is enforced on upload, so a negative tmin reaches behind the origin as on the
// CPU). WGSL lets implementations assume no NaN or infinity, so instead of the CPU's 0·∞ = NaN that
// drops out of max/min, an axis along which the ray does not move (its inv_dir is uploaded as 0) is
// decided by whether the origin lies within the slab: unbounded if it does, empty if not. Same answers.
// The far distance is moved outward by the slack (`robust_far`), and so is `tmax`, plus the ray's
// `slack` for the tree (`hit_slack`): the nearer of the two bounds the entry, as on the CPU
// (src/bvh/traverse.rs says why), so that the hit kept does not depend on the order in which this tree,
// built here, is visited.
fn slab(ray: GpuRay, n: Node, tmax: f32, slack: f32) -> f32 {
    let t0 = (n.min - ray.origin) * ray.inv_dir;
    let t1 = (n.max - ray.origin) * ray.inv_dir;
    let neg = bits3(ray.dir_bits);
    let zero = bits3(ray.dir_bits >> 3u);
    let inside = (ray.origin >= n.min) & (ray.origin <= n.max);
    let near = select(select(t0, t1, neg), select(vec3<f32>(BIG), vec3<f32>(-BIG), inside), zero);
    let far = select(select(t1, t0, neg), select(vec3<f32>(-BIG), vec3<f32>(BIG), inside), zero);
    let tnear = max(near.x, max(near.y, max(near.z, ray.tmin)));
    let tfar = min(far.x, min(far.y, far.z));
    if tnear <= min(robust_far(tfar), robust_far(tmax) + slack) { return tnear; }
    return NO_ENTRY;
}

// src/geometry/ray.rs Ray::hit_slack: HIT_SLACK times the largest `t` at which the ray reaches a corner
// coordinate of the box `n` (the tree's root). `inv_dir` is uploaded as 0 along an axis the ray does not
// move on, where the CPU's is infinite: skipped alike.
fn hit_slack(ray: GpuRay, n: Node) -> f32 {
    let reach = max(abs(n.min - ray.origin), abs(n.max - ray.origin));
    let inv = abs(ray.inv_dir);
    let m = select(inv, vec3<f32>(BIG), inv == vec3<f32>(0.0));
    return HIT_SLACK * max(reach.x, max(reach.y, reach.z)) * min(m.x, min(m.y, m.z));
}

// src/geometry/ray.rs robust_far: `far` moved outward (away from 0) by 2 ulp of its size.
fn robust_far(far: f32) -> f32 {
    return far * (1.0 + select(ROBUST_FAR_SLACK, -ROBUST_FAR_SLACK, far < 0.0));
}

// Whether `t`, from `slab`, is an entry distance rather than NO_ENTRY.
fn entered(t: f32) -> bool {
    return t > NO_ENTRY;
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
    let n = cross3(v1 - v0, v2 - v0);
    if all(n == vec3<f32>(0.0)) { return miss; }
    let a = v0 - ray.origin;
    let b = v1 - ray.origin;
    let c = v2 - ray.origin;
    let ax = dot3(ray.row_x, a);
    let ay = dot3(ray.row_y, a);
    let bx = dot3(ray.row_x, b);
    let by = dot3(ray.row_y, b);
    let cx = dot3(ray.row_x, c);
    let cy = dot3(ray.row_y, c);
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
    let big_t = u * dot3(ray.row_z, a) + v * dot3(ray.row_z, b) + w * dot3(ray.row_z, c);
    let rcp = div_rn(1.0, det);
    let t = big_t * rcp;
    if !(t >= ray.tmin && t <= tmax) { return miss; }
    return TriHit(true, t, v * rcp, w * rcp);
}


// The traversal stack of one ray: farther children waiting, with their entry distances. 64 entries: no
// tree is deeper (src/bvh/node.rs MAX_DEPTH).
struct Stack {
    node: array<u32, 64>,
    t: array<f32, 64>,
    sp: u32,
}

// After testing an inner node's children (at `c` and `c + 1`, entry distances `ta`, `tb`, NO_ENTRY for a
// miss): the child to visit next, the nearer one, with the farther pushed; MISS when neither was hit.
fn descend(stack: ptr<function, Stack>, c: u32, ta: f32, tb: f32) -> u32 {
    if entered(ta) && entered(tb) {
        let a_first = ta <= tb;
        (*stack).node[(*stack).sp] = select(c, c + 1u, a_first);
        (*stack).t[(*stack).sp] = select(ta, tb, a_first);
        (*stack).sp += 1u;
        return select(c + 1u, c, a_first);
    }
    if entered(ta) { return c; }
    if entered(tb) { return c + 1u; }
    return MISS;
}

// The next waiting subtree that can still hold something within `tmax` (moved outward as in `slab`), or
// MISS when none is left.
fn pop(stack: ptr<function, Stack>, tmax: f32, slack: f32) -> u32 {
    let limit = robust_far(tmax) + slack;
    loop {
        if (*stack).sp == 0u { return MISS; }
        (*stack).sp -= 1u;
        if (*stack).t[(*stack).sp] <= limit { return (*stack).node[(*stack).sp]; }
    }
    return MISS;
}
