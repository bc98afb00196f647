// The coherent ray-space hierarchy's traversal (seed 002; src/raysort/gpu_crsh.rs): one workgroup per
// level-1 node of the hierarchy, one thread per ray of that node. The node's top ancestor is tested
// against the mesh's bounding sphere; then, 64 triangles at a time, each thread tests one triangle's
// sphere against the node's ancestors from level 1 up to the top (a triangle survives for the node's rays
// only if every ancestor may reach it, as on the CPU's top-down walk), and every ray runs the exact
// watertight test (ray_tests.wgsl, the CPU's edge functions) on the survivors in triangle order: any hit
// for shadow rays, closest (smallest t, then first in order) for the others.

// A sphere–cone node (src/raysort/cone.rs RayNode), 48 bytes.
struct RayNode {
    center: vec3<f32>,
    radius: f32,
    axis: vec3<f32>,
    cos_spread: f32,
    sin_spread: f32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

// A triangle of non-zero area with its bounding sphere, 64 bytes.
struct Tri {
    v0: vec3<f32>,
    _p0: u32,
    v1: vec3<f32>,
    _p1: u32,
    v2: vec3<f32>,
    _p2: u32,
    center: vec3<f32>,
    radius: f32,
}

struct CrshHit { t: f32, tri: u32, u: f32, v: f32 }

@group(0) @binding(0) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(1) var<storage, read> any_hit: array<u32>;
@group(0) @binding(2) var<storage, read> nodes: array<RayNode>;
@group(0) @binding(3) var<storage, read> tris: array<Tri>;
// rays, s, D, triangles, level-1 nodes, mesh sphere (4 × f32 bits), then the first node of each level.
@group(0) @binding(4) var<storage, read> info: array<u32>;
@group(0) @binding(5) var<storage, read_write> hits: array<CrshHit>;

var<workgroup> survives: array<u32, 64>;

// RayNode::hits_sphere: false only when no ray of the node can meet the sphere at t >= 0, with the
// CPU's 1e-5 slack (conservative on both devices).
fn node_hits_sphere(n: RayNode, c: vec3<f32>, r: f32) -> bool {
    let v = c - n.center;
    let len = sqrt(dot3(v, v));
    let along = dot3(v, n.axis);
    let m = abs(n.center);
    let reach = r + n.radius + 1e-5 * (len + max(m.x, max(m.y, m.z)));
    if along >= len * n.cos_spread { return true; }
    let w = cross3(v, n.axis);
    let s = sqrt(dot3(w, w));
    var dist = len;
    if along * n.cos_spread + s * n.sin_spread > 0.0 {
        dist = s * n.cos_spread - along * n.sin_spread;
    }
    return dist <= reach;
}

@compute @workgroup_size(64)
fn crsh_trace(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let node = linear_group(wid, nwg);
    let n_rays = info[0];
    let s = info[1];
    let depth = info[2];
    let n_tris = info[3];
    let live = node < info[4];
    let ray_i = node * s + lid;
    let has_ray = live && lid < s && ray_i < n_rays;
    var ray: GpuRay;
    var any = false;
    if has_ray {
        ray = rays[ray_i];
        any = any_hit[ray_i] != 0u;
    }
    var best = CrshHit(ray.tmax, MISS, 0.0, 0.0);
    var top = node;
    for (var k = 1u; k < depth; k++) { top = top / s; }
    let sphere = vec4<f32>(
        bitcast<f32>(info[5]), bitcast<f32>(info[6]), bitcast<f32>(info[7]), bitcast<f32>(info[8]),
    );
    var reached = false;
    if live { reached = node_hits_sphere(nodes[info[9u + depth - 1u] + top], sphere.xyz, sphere.w); }
    let chunks = (n_tris + 63u) / 64u;
    for (var chunk = 0u; chunk < chunks; chunk++) {
        let t = chunk * 64u + lid;
        var ok = reached && t < n_tris;
        if ok {
            let tri = tris[t];
            var idx = node;
            for (var k = 0u; k < depth; k++) {
                if !node_hits_sphere(nodes[info[9u + k] + idx], tri.center, tri.radius) {
                    ok = false;
                    break;
                }
                idx = idx / s;
            }
        }
        survives[lid] = select(0u, 1u, ok);
        workgroupBarrier();
        for (var j = 0u; j < 64u; j++) {
            if !has_ray || (any && best.tri != MISS) { break; }
            if survives[j] == 0u { continue; }
            let tri = tris[chunk * 64u + j];
            let h = intersect(ray, tri.v0, tri.v1, tri.v2, best.t);
            if h.ok && (best.tri == MISS || h.t < best.t) {
                best = CrshHit(h.t, chunk * 64u + j, h.u, h.v);
            }
        }
        workgroupBarrier();
    }
    if has_ray { hits[ray_i] = best; }
}
