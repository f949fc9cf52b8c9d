// Indirect dispatch arguments from a GPU-side count (owner: engine/src/gpu/indirect.rs):
// for chunk k of `chunk` threads over the first min(count[0], cap) items, the workgroup
// grid (x, y, 1) of `thread_index` (common/dispatch.wgsl), folded as grid_1d folds it on
// the host. A chunk past the count gets (0, 1, 1): no workgroup runs.

//#include "common/dispatch.wgsl"

struct IndirectParams {
    cap: u32,
    chunk: u32,
    n_chunks: u32,
    max_per_dim: u32,
}

@group(0) @binding(0) var<storage, read> params: IndirectParams;
@group(0) @binding(1) var<storage, read> count: array<u32>;
@group(0) @binding(2) var<storage, read_write> args: array<u32>;

@compute @workgroup_size(WG_SIZE)
fn indirect_args(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = thread_index(gid, nwg);
    if (k >= params.n_chunks) {
        return;
    }
    let total = min(count[0], params.cap);
    let start = k * params.chunk;
    var threads = 0u;
    if (total > start) {
        threads = min(total - start, params.chunk);
    }
    let groups = (threads + WG_SIZE - 1u) / WG_SIZE;
    var x = groups;
    var y = 1u;
    if (groups > params.max_per_dim) {
        y = (groups + params.max_per_dim - 1u) / params.max_per_dim;
        x = (groups + y - 1u) / y;
    }
    args[3u * k] = x;
    args[3u * k + 1u] = y;
    args[3u * k + 2u] = 1u;
}
