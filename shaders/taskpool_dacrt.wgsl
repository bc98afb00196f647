
// Divide-and-conquer ray tracing (DACRT, seed 004 §5; src/gpu/taskpool/dacrt.rs) as a task kind of the
// pool, appended to ray_tests.wgsl and taskpool.wgsl. A task holds a list of rays and a list of triangles
// (ranges of two index arrays) and a box. A split task counts, then scatters, its triangles and rays into
// the two halves of its box split at the middle of its longest axis (a triangle whose bounds reach into a
// half goes there, a ray whose conservative slab test enters a half goes there); the halves, shrunk to
// their triangles' bounds, become child tasks. A task small enough by the seed's cost rule (tris · rays < 80 · (tris + rays)) tests all its pairs
// instead, keeping each ray's nearest distance with an atomic minimum, and is parked; once every task is
// done, the parked tasks run again to name, for each ray, the lowest triangle hit at exactly that distance
// (the crate's tie rule). Children get fresh index ranges (appended, never swapped in place), so no two
// live tasks share data and no task waits on another.
//
// Why every hit is found: the hit point lies in the root box (the triangles' bounds); at each split it lies
// in one closed half, whose triangle list holds the triangle (its bounds contain the point) and whose ray
// list holds the ray (the slab test is conservative). Parameters: `leaf` = index slots for triangles,
// `chunk` = index slots for rays. Kind state: 10 triangle slots used, 11 ray slots used, 12 triangle
// slots and 13 ray slots asked for past the capacity.
//
// Task record (24 words): 0 ray lo, 1 ray hi, 2 phase, 3 chunks of the current step, 4 triangle lo,
// 5 triangle hi, 6 depth, 7 first child, 8..11 box min (f32 bits) and 11 split axis, 12..15 box max and
// 15 split position (f32 bits), 16..20 counts of triangles left and right, rays left and right,
// 24..27 and 28..31 the bounds of the triangles scattered into the task (order-preserving u32 of f32).

const STRIDE: u32 = 32u;
const COUNT: u32 = 0u;
const SCATTER: u32 = 1u;
const INTERSECT: u32 = 2u;
const RESOLVE: u32 = 3u;
const DONE: u32 = 4u;
// Elements per counting or scattering chunk; triangles per intersection chunk (one ray).
const ELEMS: u32 = 64u;
const TRI_BLOCK: u32 = 32u;
const C_SORT: f32 = 80.0;
const MAX_DEPTH: u32 = 40u;

@group(0) @binding(0) var<storage, read> verts: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> rays: array<GpuRay>;
// Per ray: nearest distance (f32 bits, starts at the ray's tmax) and triangle (NONE for a miss).
@group(0) @binding(8) var<storage, read_write> hits: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read_write> tri_idx: array<u32>;
@group(0) @binding(10) var<storage, read_write> ray_idx: array<u32>;

fn fbits(t: u32, f: u32) -> f32 { return bitcast<f32>(field(t, f)); }

fn box_min(t: u32) -> vec3<f32> { return vec3<f32>(fbits(t, 8u), fbits(t, 9u), fbits(t, 10u)); }
fn box_max(t: u32) -> vec3<f32> { return vec3<f32>(fbits(t, 12u), fbits(t, 13u), fbits(t, 14u)); }

// Chunks of a counting or scattering step.
fn sort_chunks(nt: u32, nr: u32) -> u32 { return groups(nt, ELEMS) + groups(nr, ELEMS); }

// Which halves a triangle's bounds reach: bit 0 the lower, bit 1 the upper.
fn tri_sides(id: u32, axis: u32, mid: f32) -> u32 {
    let a = verts[3u * id][axis];
    let b = verts[3u * id + 1u][axis];
    let c = verts[3u * id + 2u][axis];
    return select(0u, 1u, min(a, min(b, c)) <= mid) | select(0u, 2u, max(a, max(b, c)) >= mid);
}

// Which halves a ray enters within its range (the ray's own tmax, so that counting and scattering agree).
fn ray_sides(t: u32, r: u32, axis: u32, mid: f32) -> u32 {
    let ray = rays[r];
    if (ray.dir_bits & 0x80000000u) != 0u { return 0u; }
    let lo = box_min(t);
    let hi = box_max(t);
    var lo_hi = hi;
    lo_hi[axis] = mid;
    var hi_lo = lo;
    hi_lo[axis] = mid;
    let l = entered(slab(ray, Node(lo, 0u, lo_hi, 0.0), ray.tmax, 0.0));
    let u = entered(slab(ray, Node(hi_lo, 0u, hi, 0.0), ray.tmax, 0.0));
    return select(0u, 1u, l) | select(0u, 2u, u);
}

fn child_slot(child: u32, f: u32) -> u32 { return atomicAdd(&tasks[child * STRIDE + f], 1u); }

fn grow_bounds(c: u32, lo: vec3<f32>, hi: vec3<f32>) {
    for (var k = 0u; k < 3u; k++) {
        atomicMin(&tasks[c * STRIDE + 24u + k], ordered(lo[k]));
        atomicMax(&tasks[c * STRIDE + 28u + k], ordered(hi[k]));
    }
}

// Triangle or ray lists: element `i` of the index array, and its store.
fn elem(tri: bool, i: u32) -> u32 {
    if tri { return tri_idx[i]; }
    return ray_idx[i];
}

fn put(tri: bool, i: u32, v: u32) {
    if tri { tri_idx[i] = v; } else { ray_idx[i] = v; }
}

// One chunk of a counting or scattering step: ELEMS triangles (the first chunks), or ELEMS rays. A
// triangle's range sits in record words 4..6, a ray's in 0..2; the counts go to words 16, 17 (triangles)
// or 18, 19 (rays).
fn sort_chunk(t: u32, c: u32, scatter: bool) {
    let axis = field(t, 11u);
    let mid = fbits(t, 15u);
    let ct = groups(field(t, 5u) - field(t, 4u), ELEMS);
    let tri = c < ct;
    let f = select(0u, 4u, tri);
    let lo = field(t, f);
    let n = field(t, f + 1u) - lo;
    let b = select(c - ct, c, tri);
    let first = field(t, 7u);
    var n0 = 0u;
    var n1 = 0u;
    // The bounds of the triangles scattered to each child.
    var lo0 = vec3<f32>(BIG);
    var hi0 = vec3<f32>(-BIG);
    var lo1 = lo0;
    var hi1 = hi0;
    for (var k = b * ELEMS; k < min(b * ELEMS + ELEMS, n); k++) {
        let id = elem(tri, lo + k);
        var s = 0u;
        var tlo = vec3<f32>(0.0);
        var thi = tlo;
        if tri {
            s = tri_sides(id, axis, mid);
            let v0 = verts[3u * id].xyz;
            let v1 = verts[3u * id + 1u].xyz;
            let v2 = verts[3u * id + 2u].xyz;
            tlo = min(v0, min(v1, v2));
            thi = max(v0, max(v1, v2));
        } else {
            s = ray_sides(t, id, axis, mid);
        }
        if (s & 1u) != 0u {
            n0++;
            lo0 = min(lo0, tlo);
            hi0 = max(hi0, thi);
            if scatter { put(tri, child_slot(first, f + 1u), id); }
        }
        if (s & 2u) != 0u {
            n1++;
            lo1 = min(lo1, tlo);
            hi1 = max(hi1, thi);
            if scatter { put(tri, child_slot(first + 1u, f + 1u), id); }
        }
    }
    if scatter && tri {
        if n0 > 0u { grow_bounds(first, lo0, hi0); }
        if n1 > 0u { grow_bounds(first + 1u, lo1, hi1); }
    }
    if !scatter {
        let w = select(18u, 16u, tri);
        atomicAdd(&tasks[t * STRIDE + w], n0);
        atomicAdd(&tasks[t * STRIDE + w + 1u], n1);
    }
}

// f32 bits of a distance, ordered like the distance (t >= 0; -0 counts as 0).
fn t_bits(t: f32) -> u32 {
    let b = bitcast<u32>(t);
    return select(b, 0u, b == 0x80000000u);
}

// One chunk of an intersection task: one ray against TRI_BLOCK triangles. The first run lowers the ray's
// nearest distance; the parked run names the lowest triangle hit at exactly the final distance.
fn intersect_chunk(t: u32, c: u32, resolve: bool) {
    let t_lo = field(t, 4u);
    let nt = field(t, 5u) - t_lo;
    let tb = groups(nt, TRI_BLOCK);
    let r = ray_idx[field(t, 0u) + c / tb];
    let ray = rays[r];
    let j = (c % tb) * TRI_BLOCK;
    var best = atomicLoad(&hits[2u * r]);
    var found = false;
    for (var k = j; k < min(j + TRI_BLOCK, nt); k++) {
        let id = tri_idx[t_lo + k];
        let h = intersect(ray, verts[3u * id].xyz, verts[3u * id + 1u].xyz, verts[3u * id + 2u].xyz,
                          bitcast<f32>(best));
        if !h.ok { continue; }
        let b = t_bits(h.t);
        if resolve {
            if b == best { atomicMin(&hits[2u * r + 1u], id); }
        } else if b <= best {
            best = b;
            found = true;
        }
    }
    if found { atomicMin(&hits[2u * r], best); }
}

fn run_chunk(t: u32, c: u32) {
    switch field(t, 2u) {
        case COUNT: { sort_chunk(t, c, false); }
        case SCATTER: { sort_chunk(t, c, true); }
        case INTERSECT: { intersect_chunk(t, c, false); }
        case RESOLVE: { intersect_chunk(t, c, true); }
        default: {}
    }
}

// Reserves `k` index slots from the cursor in state word `w` (limit `cap`), or NONE.
fn alloc_slots(w: u32, k: u32, cap: u32) -> u32 {
    let base = atomicAdd(&state[w], k);
    if base + k > cap {
        atomicMax(&state[w + 2u], base + k);
        return NONE;
    }
    return base;
}

// A child record with empty ranges starting at `t_lo`, `r_lo` (the scatter step fills them) and a box.
fn init_child(c: u32, t_lo: u32, r_lo: u32, depth: u32, lo: vec3<f32>, hi: vec3<f32>) {
    for (var k = 0u; k < 3u; k++) {
        set_field(c, 24u + k, 0xffffffffu);
        set_field(c, 28u + k, 0u);
    }
    set_box(c, lo, hi);
    set_field(c, 0u, r_lo);
    set_field(c, 1u, r_lo);
    set_field(c, 2u, DONE);
    set_field(c, 3u, 0u);
    set_field(c, 4u, t_lo);
    set_field(c, 5u, t_lo);
    set_field(c, 6u, depth);
    set_field(c, 7u, 0u);
    for (var k = 16u; k < 20u; k++) { set_field(c, k, 0u); }
}

// Sets a task's box and its split: the middle of the longest axis.
fn set_box(c: u32, lo: vec3<f32>, hi: vec3<f32>) {
    let e = hi - lo;
    let axis = select(select(2u, 1u, e.y >= e.z), 0u, e.x >= e.y && e.x >= e.z);
    for (var k = 0u; k < 3u; k++) {
        set_field(c, 8u + k, bitcast<u32>(lo[k]));
        set_field(c, 12u + k, bitcast<u32>(hi[k]));
    }
    set_field(c, 11u, axis);
    set_field(c, 15u, bitcast<u32>(lo[axis] * 0.5 + hi[axis] * 0.5));
}

// After counting: reserves the children's index ranges and records, then scatters.
fn after_count(t: u32) {
    let tl = field(t, 16u);
    let tr = field(t, 17u);
    let rl = field(t, 18u);
    let rr = field(t, 19u);
    set_field(t, 2u, DONE);
    set_field(t, 3u, 0u);
    let tb = alloc_slots(10u, tl + tr, params.leaf);
    let rb = alloc_slots(11u, rl + rr, params.chunk);
    if tb == NONE || rb == NONE { return; }
    let first = alloc_tasks(2u);
    if first == NONE { return; }
    let lo = box_min(t);
    let hi = box_max(t);
    let axis = field(t, 11u);
    let mid = fbits(t, 15u);
    var lo_hi = hi;
    lo_hi[axis] = mid;
    var hi_lo = lo;
    hi_lo[axis] = mid;
    let depth = field(t, 6u) + 1u;
    init_child(first, tb, rb, depth, lo, lo_hi);
    init_child(first + 1u, tb + tl, rb + rl, depth, hi_lo, hi);
    set_field(t, 7u, first);
    set_field(t, 2u, SCATTER);
    set_field(t, 3u, sort_chunks(field(t, 5u) - field(t, 4u), field(t, 1u) - field(t, 0u)));
    push_next(t);
}

// After scattering: each child's box shrinks to the bounds of its triangles (the hit points it must
// find lie in both), and each child with rays and triangles goes live, split again or tested pair by
// pair. A child that kept all of its parent's triangles in a box that did not shrink (they all straddle
// the split) is tested pair by pair: splitting it further would copy every triangle again and again
// (identical triangles would until the depth bound).
fn after_scatter(t: u32) {
    let pt = field(t, 5u) - field(t, 4u);
    set_field(t, 2u, DONE);
    set_field(t, 3u, 0u);
    let first = field(t, 7u);
    for (var c = first; c < first + 2u; c++) {
        let nt = field(c, 5u) - field(c, 4u);
        let nr = field(c, 1u) - field(c, 0u);
        if nt == 0u || nr == 0u { continue; }
        let lo = box_min(c);
        let hi = box_max(c);
        var tlo = vec3<f32>(0.0);
        var thi = tlo;
        for (var k = 0u; k < 3u; k++) {
            tlo[k] = unordered(field(c, 24u + k));
            thi[k] = unordered(field(c, 28u + k));
        }
        let shrunk = any(tlo > lo) || any(thi < hi);
        if shrunk { set_box(c, max(lo, tlo), min(hi, thi)); }
        let cheap = f32(nt) * f32(nr) < C_SORT * f32(nt + nr);
        if cheap || field(c, 6u) >= MAX_DEPTH || (nt == pt && !shrunk) {
            set_field(c, 2u, INTERSECT);
            set_field(c, 3u, nr * groups(nt, TRI_BLOCK));
        } else {
            set_field(c, 2u, COUNT);
            set_field(c, 3u, sort_chunks(nt, nr));
        }
        push_next(c);
    }
}

fn advance_task(t: u32) {
    switch field(t, 2u) {
        case COUNT: { after_count(t); }
        case SCATTER: { after_scatter(t); }
        case INTERSECT: {
            set_field(t, 2u, RESOLVE);
            park(t);
        }
        default: {
            set_field(t, 2u, DONE);
            set_field(t, 3u, 0u);
        }
    }
}
