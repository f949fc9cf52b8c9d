// Weight gradients of the hash-grid field's MLPs (owner: engine/src/field/grid/mod.rs):
// grad[o][i] += sum_s d_s[o] x_s[i] over the samples of one backward chunk, with d and
// x per-sample rows of the backward scratch (see grid_backward.wgsl). One thread per
// (4x4 tile of the weight matrix, group of `spt` samples): it sums its samples in
// registers and adds the 16 partial sums with float atomics, so there is one atomic
// per weight per sample group, not per sample. With `mask_d`, d is replaced by
// [d > 0] (the ReLU mask m from the stored activations a1).

//#include "common/dispatch.wgsl"

struct OuterParams {
    d_off: u32,
    d_stride: u32,
    x_off: u32,
    x_stride: u32,
    out4: u32,
    in4: u32,
    n_out: u32,
    mask_d: u32,
    grad_off: u32,
    grad_stride: u32,
    chunk_start: u32,
    chunk_len: u32,
    spt: u32,
    capacity: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: OuterParams;
@group(0) @binding(1) var<storage, read> count: array<u32>;
@group(0) @binding(2) var<storage, read> scratch: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> grad: array<AtomicF32>;

@compute @workgroup_size(WG_SIZE)
fn outer(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = thread_index(gid, nwg);
    let tiles = params.out4 * params.in4;
    let tile = t % tiles;
    let sg = t / tiles;
    let total = min(count[0], params.capacity);
    var n_valid = 0u;
    if (total > params.chunk_start) {
        n_valid = min(total - params.chunk_start, params.chunk_len);
    }
    let s0 = sg * params.spt;
    if (s0 >= n_valid) {
        return;
    }
    let s1 = min(s0 + params.spt, n_valid);
    let o4 = tile / params.in4;
    let i4 = tile % params.in4;
    var a0 = vec4<f32>(0.0);
    var a1 = vec4<f32>(0.0);
    var a2 = vec4<f32>(0.0);
    var a3 = vec4<f32>(0.0);
    for (var s = s0; s < s1; s++) {
        var d = scratch[params.d_off + s * params.d_stride + o4];
        if (params.mask_d != 0u) {
            d = select(vec4<f32>(0.0), vec4<f32>(1.0), d > vec4<f32>(0.0));
        }
        let x = scratch[params.x_off + s * params.x_stride + i4];
        a0 += d * x.x;
        a1 += d * x.y;
        a2 += d * x.z;
        a3 += d * x.w;
    }
    for (var r = 0u; r < 4u; r++) {
        let o = 4u * o4 + r;
        if (o >= params.n_out) {
            break;
        }
        let row = params.grad_off + o * params.grad_stride + 4u * i4;
        let v = vec4<f32>(a0[r], a1[r], a2[r], a3[r]);
        for (var c = 0u; c < 4u; c++) {
            let idx = row + c;
            let val = v[c];
            if (val != 0.0) {
                atomicAddF32(grad, idx, val);
            }
        }
    }
}
