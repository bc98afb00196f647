// Two-level ray queries over a whole scene, the GPU path of the ECS layer's batched queries: the top-level
// tree over entities (world space), then each reached entity's own tree in its object space. Same rules as
// TraceWorld::cast_ray / occluded on the CPU: an entity is tested when the request's layer mask shares a bit
// with its layers and it is not the excluded entity; across entities the strictly nearest hit wins, inside
// one entity the nearest then the lowest triangle index.

struct Instance {
    // The world-to-object transform as columns (x, y, z axes, translation).
    c0: vec4<f32>,
    c1: vec4<f32>,
    c2: vec4<f32>,
    c3: vec4<f32>,
    // Object-to-world normal matrix (inverse transpose of the linear part) as columns.
    n0: vec4<f32>,
    n1: vec4<f32>,
    n2: vec4<f32>,
    node_offset: u32,
    slot_offset: u32,
    vertex_offset: u32,
    layers: u32,
    entity_lo: u32,
    entity_hi: u32,
    _pad0: u32,
    _pad1: u32,
}

// The world normal is computed here, so that answers collected a frame later do not depend on how the
// meshes changed since.
// `entity_lo` and `entity_hi` name the instance hit by its id, so that answers need no slot table.
struct SceneHit { t: f32, prim: u32, u: f32, v: f32, instance: u32, entity_lo: u32, entity_hi: u32, _c: u32, normal: vec3<f32>, _d: f32 }

struct SceneParams { rays: u32, any: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> tlas: array<Node>;
@group(0) @binding(1) var<storage, read> instances: array<Instance>;
@group(0) @binding(2) var<storage, read> blas: array<Node>;
// Per leaf slot (from the instance's slot_offset) its triangle's id; the triangle's corners are
// indices[3 (slot_offset + id) ..], relative to the instance's vertex_offset.
@group(0) @binding(3) var<storage, read> ids: array<u32>;
@group(0) @binding(4) var<storage, read> indices: array<u32>;
@group(0) @binding(5) var<storage, read> positions: array<f32>;
@group(0) @binding(6) var<storage, read> rays: array<GpuRay>;
// Per ray: layer mask, excluded entity (lo, hi; all ones for none), unused.
@group(0) @binding(7) var<storage, read> filters: array<vec4<u32>>;
@group(0) @binding(8) var<storage, read_write> hits: array<SceneHit>;
@group(0) @binding(9) var<uniform> params: SceneParams;

const MIN_NORMAL: f32 = 1.17549435e-38;

fn vertex(i: u32) -> vec3<f32> {
    return vec3<f32>(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
}

fn unit(k: u32) -> vec3<f32> {
    return select(vec3<f32>(0.0), vec3<f32>(1.0), vec3<u32>(0u, 1u, 2u) == vec3<u32>(k));
}

// Ray::with_range + TriangleRay::new, in the object space of an instance.
fn object_ray(inst: Instance, world: GpuRay, dir: vec3<f32>, tmax: f32) -> GpuRay {
    let o = inst.c0.xyz * world.origin.x + inst.c1.xyz * world.origin.y + inst.c2.xyz * world.origin.z + inst.c3.xyz;
    var d = inst.c0.xyz * dir.x + inst.c1.xyz * dir.y + inst.c2.xyz * dir.z;
    d = select(d, d * 0.0, abs(d) < vec3<f32>(MIN_NORMAL)); // flush subnormals, keeping the sign
    let zero = d == vec3<f32>(0.0);
    let sign = (bitcast<vec3<u32>>(d) >> vec3<u32>(31u)) & vec3<u32>(1u);
    var bits = sign.x | (sign.y << 1u) | (sign.z << 2u);
    bits |= (select(0u, 1u, zero.x) << 3u) | (select(0u, 1u, zero.y) << 4u) | (select(0u, 1u, zero.z) << 5u);
    let a = abs(d);
    var kz = 2u;
    if a.x >= a.y && a.x >= a.z { kz = 0u; } else if a.y >= a.z { kz = 1u; }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let t = kx;
        kx = ky;
        ky = t;
    }
    let sx = div_rn(d[kx], d[kz]);
    let sy = div_rn(d[ky], d[kz]);
    let sz = div_rn(1.0, d[kz]);
    var r: GpuRay;
    r.origin = o;
    r.tmin = world.tmin;
    r.inv_dir = select(div3_rn(vec3<f32>(1.0), d), vec3<f32>(0.0), zero);
    r.tmax = tmax;
    r.row_x = unit(kx) - sx * unit(kz);
    r.dir_bits = bits;
    r.row_y = unit(ky) - sy * unit(kz);
    r.row_z = sz * unit(kz);
    return r;
}

struct Best { t: f32, prim: u32, u: f32, v: f32, normal: vec3<f32>, found: bool }

// The entity's own tree: nearest hit within (ray.tmin, best.t], or any hit.
fn trace_blas(inst: Instance, ray: GpuRay, any: bool) -> Best {
    var best = Best(ray.tmax, MISS, 0.0, 0.0, vec3<f32>(0.0), false);
    let root = blas[inst.node_offset];
    let slack = hit_slack(ray, root);
    if !entered(slab(ray, root, best.t, slack)) { return best; }
    var stack: Stack;
    stack.sp = 0u;
    var cur = 0u;
    loop {
        let n = blas[inst.node_offset + cur];
        var next = MISS;
        if is_leaf(n) {
            let f = leaf_first(n) + inst.slot_offset;
            for (var s = f; s < f + leaf_count(n); s++) {
                let t = ids[s];
                let i = 3u * (inst.slot_offset + t);
                let v = inst.vertex_offset;
                let a = vertex(v + indices[i]);
                let b = vertex(v + indices[i + 1u]);
                let c = vertex(v + indices[i + 2u]);
                let h = intersect(ray, a, b, c, best.t);
                if h.ok && (!best.found || h.t < best.t || t < best.prim) {
                    best = Best(h.t, t, h.u, h.v, cross3(b - a, c - a), true);
                    if any { return best; }
                }
            }
        } else {
            let c = n.index;
            let o = inst.node_offset;
            next = descend(&stack, c, slab(ray, blas[o + c], best.t, slack), slab(ray, blas[o + c + 1u], best.t, slack));
        }
        if next == MISS {
            next = pop(&stack, best.t, slack);
            if next == MISS { return best; }
        }
        cur = next;
    }
    return best;
}

fn accepts(inst: Instance, rule: vec4<u32>) -> bool {
    let mask = select(rule.x, 0xffffffffu, rule.x == 0u);
    let excluded = inst.entity_lo == rule.y && inst.entity_hi == rule.z;
    return (mask & inst.layers) != 0u && !excluded;
}

@compute @workgroup_size(64)
fn scene_trace(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if i >= params.rays { return; }
    let ray = rays[i];
    let any = params.any != 0u;
    var out = SceneHit(ray.tmax, MISS, 0.0, 0.0, MISS, 0u, 0u, 0u, vec3<f32>(0.0), 0.0);
    // Scene rays are tested against triangles only in object space, so the CPU sends the world direction in
    // row_x (the world-space shear rows would be unused).
    let dir = ray.row_x;
    if (ray.dir_bits & 0x80000000u) != 0u || arrayLength(&tlas) == 0u {
        hits[i] = out;
        return;
    }
    let slack = hit_slack(ray, tlas[0]);
    if !entered(slab(ray, tlas[0], ray.tmax, slack)) {
        hits[i] = out;
        return;
    }
    var stack: Stack;
    stack.sp = 0u;
    var cur = 0u;
    loop {
        let n = tlas[cur];
        var next = MISS;
        if is_leaf(n) {
            let f = leaf_first(n);
            for (var s = f; s < f + leaf_count(n); s++) {
                let inst = instances[s];
                if !accepts(inst, filters[i]) { continue; }
                let b = trace_blas(inst, object_ray(inst, ray, dir, out.t), any);
                // Nearer, or as near on a lower entity id (src/ecs/world.rs `nearer`): the same answer in
                // whatever order the top level is visited.
                let lower = inst.entity_hi < out.entity_hi || (inst.entity_hi == out.entity_hi && inst.entity_lo < out.entity_lo);
                if b.found && (out.prim == MISS || b.t < out.t || (b.t == out.t && lower)) {
                    let n = normalize(b.normal);
                    let wn = normalize(inst.n0.xyz * n.x + inst.n1.xyz * n.y + inst.n2.xyz * n.z);
                    out = SceneHit(b.t, b.prim, b.u, b.v, s, inst.entity_lo, inst.entity_hi, 0u, wn, 0.0);
                    if any { break; }
                }
            }
            if any && out.prim != MISS { break; }
        } else {
            let c = n.index;
            next = descend(&stack, c, slab(ray, tlas[c], out.t, slack), slab(ray, tlas[c + 1u], out.t, slack));
        }
        if next == MISS {
            next = pop(&stack, out.t, slack);
            if next == MISS { break; }
        }
        cur = next;
    }
    hits[i] = out;
}
