// Closest-hit and any-hit traversal of one ray per invocation, the same algorithm as src/bvh/traverse.rs:
// conservative slab test (Ize 2013), near child first, far child pushed with its
// entry distance, a 64-entry stack (no tree is deeper), and the watertight triangle test of Woop et al.
// 2013 with the ray's shear rows precomputed on the CPU (so both devices compute identical edge functions).
// An edge function that rounds to exactly zero is recomputed exactly: products split with Veltkamp's method
// (WGSL's + and * are correctly rounded), which gives the same value as the CPU's f64 fallback.

struct GpuHit { t: f32, prim: u32, u: f32, v: f32 }

struct TraceParams { rays: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> nodes: array<Node>;
// Per leaf slot the triangle's id; its vertices are indices[3 id ..]: 4 bytes per triangle kept beside the
// mesh instead of 16 for a copy of the indices in slot order, for one more dependent read per triangle.
@group(0) @binding(1) var<storage, read> ids: array<u32>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;
@group(0) @binding(3) var<storage, read> positions: array<f32>;
@group(0) @binding(4) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(5) var<storage, read_write> hits: array<GpuHit>;
@group(0) @binding(6) var<uniform> params: TraceParams;

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

fn trace(ray: GpuRay, any: bool) -> GpuHit {
    var best = GpuHit(ray.tmax, MISS, 0.0, 0.0);
    if (ray.dir_bits & 0x80000000u) != 0u { return best; } // invalid ray
    if arrayLength(&nodes) == 0u { return best; }
    let slack = hit_slack(ray, nodes[0]);
    if !entered(slab(ray, nodes[0], ray.tmax, slack)) { return best; }
    var stack: Stack;
    stack.sp = 0u;
    var cur = 0u;
    loop {
        let n = nodes[cur];
        var next = MISS;
        if is_leaf(n) {
            let f = leaf_first(n);
            for (var s = f; s < f + leaf_count(n); s++) {
                let t = ids[s];
                let h = intersect(ray, vertex(indices[3u * t]), vertex(indices[3u * t + 1u]),
                                  vertex(indices[3u * t + 2u]), best.t);
                if h.ok && (best.prim == MISS || h.t < best.t || t < best.prim) {
                    best = GpuHit(h.t, t, h.u, h.v);
                    if any { return best; }
                }
            }
        } else {
            let c = n.index;
            next = descend(&stack, c, slab(ray, nodes[c], best.t, slack), slab(ray, nodes[c + 1u], best.t, slack));
        }
        if next == MISS {
            next = pop(&stack, best.t, slack);
            if next == MISS { return best; }
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
