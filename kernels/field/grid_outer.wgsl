// Weight gradients of the hash-grid field's MLPs (owner: engine/src/field/grid/mod.rs):
// grad[o][i] += sum_s d_s[o] x_s[i] over the samples of one backward chunk, with d and
// x per-sample rows of the backward scratch (see grid_backward.wgsl), for every product
// of the chunk (W1, W2, C1, C2, C3 and the normal path's M) in one launch: thread t
// belongs to the last product whose `first_thread` is <= t. A product's thread works
// on one (8x8 tile of the weight matrix, group of `spt` samples): it sums its samples
// in 64 registers (4 vec4 loads per 64 FMAs) and adds the partial sums with float
// atomics, so there is one atomic per weight per sample group, not per sample. Rows/
// columns past the matrix (when out4 or in4 is odd) are read but never written. With
// `mask_d`, d is replaced by [d > 0] (the ReLU mask m from the stored activations a1).
// With `to_m`, the product adds into `grad_m` (the normal path's M) instead of `grad`.

//#include "common/dispatch.wgsl"

// Products of one launch at most (five weight matrices and M).
const MAX_PRODUCTS: u32 = 6u;

struct OuterProduct {
    d_off: u32,
    d_stride: u32,
    x_off: u32,
    x_stride: u32,
    out4: u32,
    in4: u32,
    // tiles of 8 columns: ceil(in4 / 2)
    tiles_i: u32,
    tiles_o: u32,
    n_out: u32,
    mask_d: u32,
    grad_off: u32,
    grad_stride: u32,
    to_m: u32,
    // the product's first thread in the launch (products in order, tiles x groups each)
    first_thread: u32,
    _pad0: u32,
    _pad1: u32,
}

struct OuterParams {
    chunk_start: u32,
    chunk_len: u32,
    spt: u32,
    capacity: u32,
    n_products: u32,
    // threads of all products
    threads: u32,
    _pad0: u32,
    _pad1: u32,
    products: array<OuterProduct, MAX_PRODUCTS>,
}

@group(0) @binding(0) var<storage, read> params: OuterParams;
@group(0) @binding(1) var<storage, read> count: array<u32>;
@group(0) @binding(2) var<storage, read> scratch: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> grad: array<AtomicF32>;
@group(0) @binding(4) var<storage, read_write> grad_m: array<AtomicF32>;

// This thread's product, copied before any branch (storage reads inside branches are
// lane by lane on lavapipe; see gpu/kernel.rs, "Uniform buffers").
var<private> pr: OuterProduct;

@compute @workgroup_size(WG_SIZE)
fn outer(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = thread_index(gid, nwg);
    let n_products = params.n_products;
    let threads = params.threads;
    let chunk_start = params.chunk_start;
    let chunk_len = params.chunk_len;
    let spt = params.spt;
    let capacity = params.capacity;
    let total = min(count[0], capacity);
    var q = 0u;
    for (var i = 1u; i < MAX_PRODUCTS; i++) {
        q = select(q, i, i < n_products && t >= params.products[i].first_thread);
    }
    pr = params.products[q];
    if (t >= threads) {
        return;
    }
    let tiles = pr.tiles_o * pr.tiles_i;
    let local = t - pr.first_thread;
    let tile = local % tiles;
    let sg = local / tiles;
    var n_valid = 0u;
    if (total > chunk_start) {
        n_valid = min(total - chunk_start, chunk_len);
    }
    let s0 = sg * spt;
    if (s0 >= n_valid) {
        return;
    }
    let s1 = min(s0 + spt, n_valid);
    let o4 = 2u * (tile / pr.tiles_i);
    let i4 = 2u * (tile % pr.tiles_i);
    // a<r><c>: rows 4(o4+r).., columns of x vec4 (i4 + c / 4), component c % 4.
    var a00 = vec4<f32>(0.0); var a01 = vec4<f32>(0.0); var a02 = vec4<f32>(0.0); var a03 = vec4<f32>(0.0);
    var a04 = vec4<f32>(0.0); var a05 = vec4<f32>(0.0); var a06 = vec4<f32>(0.0); var a07 = vec4<f32>(0.0);
    var a10 = vec4<f32>(0.0); var a11 = vec4<f32>(0.0); var a12 = vec4<f32>(0.0); var a13 = vec4<f32>(0.0);
    var a14 = vec4<f32>(0.0); var a15 = vec4<f32>(0.0); var a16 = vec4<f32>(0.0); var a17 = vec4<f32>(0.0);
    for (var s = s0; s < s1; s++) {
        let db = pr.d_off + s * pr.d_stride + o4;
        var d0 = scratch[db];
        var d1 = scratch[db + 1u];
        if (pr.mask_d != 0u) {
            d0 = select(vec4<f32>(0.0), vec4<f32>(1.0), d0 > vec4<f32>(0.0));
            d1 = select(vec4<f32>(0.0), vec4<f32>(1.0), d1 > vec4<f32>(0.0));
        }
        let xb = pr.x_off + s * pr.x_stride + i4;
        let x0 = scratch[xb];
        let x1 = scratch[xb + 1u];
        a00 += d0 * x0.x; a01 += d0 * x0.y; a02 += d0 * x0.z; a03 += d0 * x0.w;
        a04 += d0 * x1.x; a05 += d0 * x1.y; a06 += d0 * x1.z; a07 += d0 * x1.w;
        a10 += d1 * x0.x; a11 += d1 * x0.y; a12 += d1 * x0.z; a13 += d1 * x0.w;
        a14 += d1 * x1.x; a15 += d1 * x1.y; a16 += d1 * x1.z; a17 += d1 * x1.w;
    }
    write_tile(o4, i4, a00, a01, a02, a03, a04, a05, a06, a07);
    write_tile(o4 + 1u, i4, a10, a11, a12, a13, a14, a15, a16, a17);
}

// Adds rows 4 r4 .. 4 r4 + 3, columns 4 i4 .. 4 i4 + 7 of a tile (column c in a<c>).
fn write_tile(r4: u32, i4: u32, c0: vec4<f32>, c1: vec4<f32>, c2: vec4<f32>, c3: vec4<f32>, c4: vec4<f32>,
              c5: vec4<f32>, c6: vec4<f32>, c7: vec4<f32>) {
    if (r4 >= pr.out4) {
        return;
    }
    var n_cols = 8u;
    if (i4 + 1u >= pr.in4) {
        n_cols = 4u;
    }
    for (var r = 0u; r < 4u; r++) {
        let o = 4u * r4 + r;
        if (o >= pr.n_out) {
            return;
        }
        let row = pr.grad_off + o * pr.grad_stride + 4u * i4;
        let lo = vec4<f32>(c0[r], c1[r], c2[r], c3[r]);
        let hi = vec4<f32>(c4[r], c5[r], c6[r], c7[r]);
        for (var c = 0u; c < n_cols; c++) {
            let idx = row + c;
            let val = select(hi[c & 3u], lo[c & 3u], c < 4u);
            if (val != 0.0) {
                if (pr.to_m != 0u) {
                    atomicAddF32(grad_m, idx, val);
                } else {
                    atomicAddF32(grad, idx, val);
                }
            }
        }
    }
}
