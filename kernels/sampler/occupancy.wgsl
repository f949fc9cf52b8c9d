// Occupancy grid maintenance (owner: engine/src/sampler/occupancy.rs): choosing and
// jittering the query points of an update, the scatter-max of the densities the caller
// evaluated there, the EMA step, a deterministic sum of the grid for its mean, and
// the thresholded occupancy bitfield.

//#include "common/dispatch.wgsl"
//#include "sampler/common.wgsl"

const REDUCE_WG: u32 = 256u;

struct QueryParams {
    geom: OccupancyGeom,
    // Points to produce.
    count: u32,
    seed: u32,
    // 1: point i is in cell i mod n_cells (warm-up, all cells, count / n_cells points
    // each); 0: random selection below.
    all_cells: u32,
    // Points [0, n_uniform) are in uniformly random cells; the others come from
    // `occupied` (list_len entries): entry i - n_uniform when list_len fits
    // (count - n_uniform == list_len), else a uniformly random entry.
    n_uniform: u32,
    list_len: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct CountParams {
    n: u32,
    n_cells: u32,
    decay: f32,
    threshold: f32,
}

@group(0) @binding(0) var<storage, read> qp: QueryParams;
@group(0) @binding(1) var<storage, read> occupied: array<u32>;
@group(0) @binding(2) var<storage, read_write> query_pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> query_cell: array<u32>;

// One point per query, uniformly jittered inside its cell (each point its own draw); w = 0.
@compute @workgroup_size(WG_SIZE)
fn query_points(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    if (i >= qp.count) {
        return;
    }
    let n_cells = qp.geom.n_cells;
    var cell = i % n_cells;
    if (qp.all_cells == 0u) {
        if (i < qp.n_uniform) {
            cell = rand_u32(qp.seed, i, 0u) % n_cells;
        } else if (qp.count - qp.n_uniform == qp.list_len) {
            cell = occupied[i - qp.n_uniform];
        } else {
            cell = occupied[rand_u32(qp.seed, i, 0u) % qp.list_len];
        }
    }
    let res = qp.geom.res;
    let c = vec3<u32>(cell % res, (cell / res) % res, cell / (res * res));
    let jitter = vec3<f32>(
        unit_f32(rand_u32(qp.seed, i, 1u)),
        unit_f32(rand_u32(qp.seed, i, 2u)),
        unit_f32(rand_u32(qp.seed, i, 3u)),
    );
    let extent = qp.geom.aabb_max - qp.geom.aabb_min;
    let p = qp.geom.aabb_min + extent * ((vec3<f32>(c) + jitter) / f32(res));
    query_pos[i] = vec4<f32>(p, 0.0);
    query_cell[i] = cell;
}

@group(0) @binding(0) var<storage, read> cp: CountParams;
@group(0) @binding(1) var<storage, read> upd_cell: array<u32>;
@group(0) @binding(2) var<storage, read> upd_density: array<f32>;
@group(0) @binding(3) var<storage, read_write> scratch_max: array<atomic<u32>>;

// scratch[cell] = max over the cell's queries of (bits of the clean density) + 1, so
// that 0 means "not queried". Non-negative floats order like their bits, which makes
// the result independent of thread order. NaN and negative densities count as 0.
@compute @workgroup_size(WG_SIZE)
fn scatter_max(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg);
    if (i >= cp.n) {
        return;
    }
    let d = upd_density[i];
    let clean = select(0.0, min(d, 3.0e38), d > 0.0);
    let cell = upd_cell[i];
    if (cell < cp.n_cells) {
        atomicMax(&scratch_max[cell], bitcast<u32>(clean) + 1u);
    }
}

@group(0) @binding(0) var<storage, read> ep: CountParams;
@group(0) @binding(1) var<storage, read_write> scratch: array<u32>;
@group(0) @binding(2) var<storage, read_write> density_grid: array<f32>;

// EMA of the queried cells: cell <- max(decay * cell, new density); resets scratch.
@compute @workgroup_size(WG_SIZE)
fn ema(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let c = thread_index(gid, nwg);
    if (c >= ep.n_cells) {
        return;
    }
    let s = scratch[c];
    if (s != 0u) {
        density_grid[c] = max(density_grid[c] * ep.decay, bitcast<f32>(s - 1u));
        scratch[c] = 0u;
    }
}

@group(0) @binding(0) var<storage, read> rp: CountParams;
@group(0) @binding(1) var<storage, read> reduce_in: array<f32>;
@group(0) @binding(2) var<storage, read_write> reduce_out: array<f32>;

var<workgroup> partial: array<f32, REDUCE_WG>;

// Sum of reduce_in[0..n): workgroup w writes the sum of its strided share to
// reduce_out[w]. The order of additions is fixed (no atomics): deterministic.
// Dispatched over a one-dimensional grid of workgroups.
@compute @workgroup_size(REDUCE_WG)
fn reduce_sum(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let stride = nwg.x * REDUCE_WG;
    var s = 0.0;
    for (var i = wid.x * REDUCE_WG + lid; i < rp.n; i += stride) {
        s += reduce_in[i];
    }
    partial[lid] = s;
    workgroupBarrier();
    for (var half = REDUCE_WG / 2u; half > 0u; half /= 2u) {
        if (lid < half) {
            partial[lid] += partial[lid + half];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        reduce_out[wid.x] = partial[0];
    }
}

@group(0) @binding(0) var<storage, read> tp: CountParams;
@group(0) @binding(1) var<storage, read> grid_values: array<f32>;
@group(0) @binding(2) var<storage, read> grid_sum: array<f32>;
@group(0) @binding(3) var<storage, read_write> bits: array<u32>;

// Occupied iff value > min(threshold, mean of all cells); one thread per 32 cells.
@compute @workgroup_size(WG_SIZE)
fn threshold_bits(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = thread_index(gid, nwg);
    let n_words = (tp.n_cells + 31u) / 32u;
    if (w >= n_words) {
        return;
    }
    let thr = min(tp.threshold, grid_sum[0] / f32(tp.n_cells));
    var word = 0u;
    for (var b = 0u; b < 32u; b++) {
        let c = w * 32u + b;
        if (c < tp.n_cells && grid_values[c] > thr) {
            word |= 1u << b;
        }
    }
    bits[w] = word;
}
