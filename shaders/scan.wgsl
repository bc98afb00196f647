// Exclusive prefix sums of u32 arrays of any length, portable (no subgroup operations): each workgroup
// scans 256 elements in workgroup memory and writes its total; the totals are scanned by the same kernel
// one level up, then added back. src/gpu/sort.rs drives the levels.

struct ScanParams { n: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read_write> data: array<u32>;
@group(0) @binding(1) var<storage, read_write> sums: array<u32>;
@group(0) @binding(2) var<uniform> params: ScanParams;

var<workgroup> tile: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    let i = block * WG + lid.x;
    var v = 0u;
    if i < params.n { v = data[i]; }
    tile[lid.x] = v;
    workgroupBarrier();
    // Hillis-Steele inclusive scan.
    for (var off = 1u; off < WG; off = off << 1u) {
        var add = 0u;
        if lid.x >= off { add = tile[lid.x - off]; }
        workgroupBarrier();
        tile[lid.x] = tile[lid.x] + add;
        workgroupBarrier();
    }
    if i < params.n { data[i] = tile[lid.x] - v; }
    // Folded (x, y) dispatches run whole blocks past the end: they must not write a total (robust access
    // would clamp the index onto the last real block's total and race with it).
    if lid.x == WG - 1u && block * WG < params.n { sums[block] = tile[lid.x]; }
}

@compute @workgroup_size(256)
fn add_offsets(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_group(wid, nwg);
    let i = block * WG + lid.x;
    if i < params.n { data[i] = data[i] + sums[block]; }
}
