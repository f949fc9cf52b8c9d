// Exclusive prefix sum of u32 (owner: engine/src/sampler/scan.rs). A block of
// SCAN_BLOCK elements per workgroup (4 per thread, then a Hillis-Steele scan of the
// 256 thread totals in workgroup memory); the block totals are scanned by the same
// kernel one level up and added back with `add_block_offsets`. No atomics and no
// subgroup operations: the result is exact and independent of the subgroup size.

const SCAN_WG: u32 = 256u;
const PER_THREAD: u32 = 4u;
const SCAN_BLOCK: u32 = 1024u;

struct Params {
    n: u32,
    n_blocks: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> scan_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> scan_out: array<u32>;
@group(0) @binding(3) var<storage, read_write> block_sums: array<u32>;

var<workgroup> totals: array<u32, SCAN_WG>;

fn block_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// scan_out[i] = sum of scan_in[block start .. i); block_sums[block] = block total.
@compute @workgroup_size(SCAN_WG)
fn scan_blocks(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = block_index(wid, nwg);
    let base = block * SCAN_BLOCK + lid * PER_THREAD;
    var local_prefix: array<u32, PER_THREAD>;
    var s = 0u;
    for (var j = 0u; j < PER_THREAD; j++) {
        local_prefix[j] = s;
        if (base + j < params.n) {
            s += scan_in[base + j];
        }
    }
    totals[lid] = s;
    workgroupBarrier();
    for (var offset = 1u; offset < SCAN_WG; offset *= 2u) {
        var t = 0u;
        if (lid >= offset) {
            t = totals[lid - offset];
        }
        workgroupBarrier();
        totals[lid] += t;
        workgroupBarrier();
    }
    let before = totals[lid] - s;
    for (var j = 0u; j < PER_THREAD; j++) {
        if (base + j < params.n) {
            scan_out[base + j] = before + local_prefix[j];
        }
    }
    if (lid == SCAN_WG - 1u && block < params.n_blocks) {
        block_sums[block] = totals[lid];
    }
}

@group(0) @binding(0) var<storage, read> add_params: Params;
@group(0) @binding(1) var<storage, read_write> add_out: array<u32>;
@group(0) @binding(2) var<storage, read> block_offsets: array<u32>;

// add_out[i] += block_offsets[block of i].
@compute @workgroup_size(SCAN_WG)
fn add_block_offsets(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = block_index(wid, nwg);
    if (block >= add_params.n_blocks) {
        return;
    }
    let off = block_offsets[block];
    let base = block * SCAN_BLOCK + lid * PER_THREAD;
    for (var j = 0u; j < PER_THREAD; j++) {
        if (base + j < add_params.n) {
            add_out[base + j] += off;
        }
    }
}
