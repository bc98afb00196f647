// The SAH cost of a resident tree (src/gpu/frame/sah.rs), reduced on the GPU beside the degradation
// metric: Σ_inner A(n)/A(root) + Σ_leaf A(l)/A(root) · N(l), as Bvh::sah_cost with C_TRAV = C_ISECT = 1.
// Appended to reduce.wgsl (its `pairs`, `params` and `store_block`): `sah_blocks` folds 256 nodes' terms
// per workgroup into a double-float pair, reduce.wgsl's `sum_pairs` folds the pairs.

@group(0) @binding(3) var<storage, read> nodes: array<Node>;

// Node i's term. Areas are scaled by the root's largest extent (the ratio is scale-free), so huge
// coordinates do not overflow; a root without area counts every node with probability 1.
fn sah_term(i: u32) -> f32 {
    let root = nodes[0];
    let re = root.max - root.min;
    let scale = max(max(re.x, re.y), re.z);
    let n = nodes[i];
    let weight = select(1.0, f32(leaf_count(n)), is_leaf(n));
    if !(scale > 0.0 && scale <= fmax()) { return weight; }
    let inv = div_rn(1.0, scale);
    let ra = half_area_scaled(re, inv);
    if !(ra > 0.0) { return weight; }
    return div_rn(half_area_scaled(n.max - n.min, inv), ra) * weight;
}

@compute @workgroup_size(256)
fn sah_blocks(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    let i = block * WG + lid.x;
    var v = 0.0;
    if i < params.n { v = sah_term(i); }
    store_block(v, lid.x, block);
}
