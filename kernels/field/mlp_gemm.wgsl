// Tiled matrix products of the MLP field (owner: engine/src/field/mlp/gemm.rs).
//
//   C[m, n] = sum_k A(m, k) B(k, n)      A(m, k) = a[a_off + m a_sm + k a_sk]
//                                        B(k, n) = b[b_off + k b_sk + n b_sn]
//
// A workgroup of 8 x 8 threads owns a 64 x 64 tile of C and walks k in steps of 16,
// staging a 64 x 16 tile of A and a 16 x 64 tile of B in workgroup memory; each thread
// accumulates an 8 x 8 block in 16 vec4 registers (8 vec4 FMAs per 4 vec4 reads of
// workgroup memory). Out-of-range rows, columns and k read as zero.
//
// Entry points differ only in the epilogue:
// * forward:      C = act(acc + bias[n] on primal rows); with ReLU a tangent row takes
//                 the mask of its primal row (relu'' = 0, so tangents are linear).
// * grad_input:   C (+)= acc * [M(primal row of m, n) > 0] when FLAG_MASK (the ReLU mask
//                 of the layer that produced the input), M(m, n) = mask[mask_off +
//                 (m - m % mask_streams) mask_sm + n].
// * weight_grad:  k split over workgroups z: partial[z][m][n] = sum over k in chunk z;
//                 column n == bias_col of B is the bias input (1 on primal rows k).
// * reduce:       grad[w_off + m in + n] += sum_z partial (n < in); grad[w_off + M in
//                 + m] += ... for n == in (the bias stored after the weights).

struct Gemm {
    m: u32,
    n: u32,
    k: u32,
    flags: u32,
    a_off: u32,
    a_sm: u32,
    a_sk: u32,
    streams: u32,
    b_off: u32,
    b_sk: u32,
    b_sn: u32,
    bias_off: u32,
    c_off: u32,
    c_sm: u32,
    k_chunk: u32,
    bias_col: u32,
    mask_off: u32,
    mask_sm: u32,
    mask_streams: u32,
    splits: u32,
}

const FLAG_BIAS: u32 = 1u;
const FLAG_RELU: u32 = 2u;
const FLAG_ACCUMULATE: u32 = 4u;
const FLAG_MASK: u32 = 8u;
const FLAG_BIAS_COL: u32 = 16u;

const TILE: u32 = 64u;
const TK: u32 = 16u;

@group(0) @binding(0) var<storage, read> G_buffer: Gemm;
// Copied to private memory as the first statement of each entry point, before any
// branch (see gpu/kernel.rs, "Uniform buffers": storage reads inside branches are
// lane by lane on lavapipe).
var<private> G: Gemm;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read> mask: array<f32>;
@group(0) @binding(4) var<storage, read_write> c: array<f32>;

// Tiles stored so that each thread reads its 8 rows and 8 columns as vec4s:
// tile_a[k * 16 + q] = A(m0 + 4 q + 0..3, k0 + k), tile_b[k * 16 + q] =
// B(k0 + k, n0 + 4 q + 0..3).
var<workgroup> tile_a: array<vec4<f32>, 256>;
var<workgroup> tile_b: array<vec4<f32>, 256>;
// Thread (tx, ty) of the 8 x 8 workgroup owns rows 8 ty + i (i = 0..7, consecutive,
// so with 4 streams it holds two samples' primal and tangent rows) and columns
// 4 tx + 0..3 (acc_il) and 32 + 4 tx + 0..3 (acc_ih).
var<private> acc0l: vec4<f32>;
var<private> acc0h: vec4<f32>;
var<private> acc1l: vec4<f32>;
var<private> acc1h: vec4<f32>;
var<private> acc2l: vec4<f32>;
var<private> acc2h: vec4<f32>;
var<private> acc3l: vec4<f32>;
var<private> acc3h: vec4<f32>;
var<private> acc4l: vec4<f32>;
var<private> acc4h: vec4<f32>;
var<private> acc5l: vec4<f32>;
var<private> acc5h: vec4<f32>;
var<private> acc6l: vec4<f32>;
var<private> acc6h: vec4<f32>;
var<private> acc7l: vec4<f32>;
var<private> acc7h: vec4<f32>;

fn load_b(k: u32, n: u32) -> f32 {
    if ((G.flags & FLAG_BIAS_COL) != 0u && n == G.bias_col) {
        return select(0.0, 1.0, k % G.streams == 0u);
    }
    return b[G.b_off + k * G.b_sk + n * G.b_sn];
}

// acc = the (m0, n0) tile of A B over k in [k_begin, k_end).
fn gemm_tile(lid: vec3<u32>, m0: u32, n0: u32, k_begin: u32, k_end: u32) {
    let t = lid.x + 8u * lid.y;
    acc0l = vec4<f32>(0.0);
    acc0h = vec4<f32>(0.0);
    acc1l = vec4<f32>(0.0);
    acc1h = vec4<f32>(0.0);
    acc2l = vec4<f32>(0.0);
    acc2h = vec4<f32>(0.0);
    acc3l = vec4<f32>(0.0);
    acc3h = vec4<f32>(0.0);
    acc4l = vec4<f32>(0.0);
    acc4h = vec4<f32>(0.0);
    acc5l = vec4<f32>(0.0);
    acc5h = vec4<f32>(0.0);
    acc6l = vec4<f32>(0.0);
    acc6h = vec4<f32>(0.0);
    acc7l = vec4<f32>(0.0);
    acc7h = vec4<f32>(0.0);
    for (var k0 = k_begin; k0 < k_end; k0 += TK) {
        for (var j = 0u; j < 16u; j++) {
            let idx = t + 64u * j;
            let mm = idx / TK;
            let ka = idx % TK;
            var va = 0.0;
            if (m0 + mm < G.m && k0 + ka < k_end) {
                va = a[G.a_off + (m0 + mm) * G.a_sm + (k0 + ka) * G.a_sk];
            }
            tile_a[ka * 16u + mm / 4u][mm % 4u] = va;
            let kb = idx / TILE;
            let nn = idx % TILE;
            var vb = 0.0;
            if (n0 + nn < G.n && k0 + kb < k_end) {
                vb = load_b(k0 + kb, n0 + nn);
            }
            tile_b[kb * 16u + nn / 4u][nn % 4u] = vb;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < TK; kk++) {
            let alo = tile_a[kk * 16u + 2u * lid.y];
            let ahi = tile_a[kk * 16u + 2u * lid.y + 1u];
            let bl = tile_b[kk * 16u + lid.x];
            let bh = tile_b[kk * 16u + 8u + lid.x];
            acc0l += alo.x * bl;
            acc0h += alo.x * bh;
            acc1l += alo.y * bl;
            acc1h += alo.y * bh;
            acc2l += alo.z * bl;
            acc2h += alo.z * bh;
            acc3l += alo.w * bl;
            acc3h += alo.w * bh;
            acc4l += ahi.x * bl;
            acc4h += ahi.x * bh;
            acc5l += ahi.y * bl;
            acc5h += ahi.y * bh;
            acc6l += ahi.z * bl;
            acc6h += ahi.z * bh;
            acc7l += ahi.w * bl;
            acc7h += ahi.w * bh;
        }
        workgroupBarrier();
    }
}

// The accumulator as [row][column group] (for the epilogues): row i, column
// 4 tx + j + 32 h is acc_rows()[2 i + h][j].
fn acc_rows() -> array<vec4<f32>, 16> {
    return array<vec4<f32>, 16>(acc0l, acc0h, acc1l, acc1h, acc2l, acc2h, acc3l, acc3h, acc4l, acc4h, acc5l, acc5h, acc6l, acc6h, acc7l, acc7h);
}

// Column of the thread's (h, j) accumulator entry.
fn col(lid: vec3<u32>, n0: u32, q: u32) -> u32 {
    return n0 + 4u * lid.x + (q % 4u) + 32u * (q / 4u);
}

@compute @workgroup_size(8, 8)
fn forward(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    G = G_buffer;
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    gemm_tile(lid, m0, n0, 0u, G.k);
    var acc = acc_rows();
    for (var q = 0u; q < 8u; q++) {
        let n = col(lid, n0, q);
        var primal = 0.0;
        for (var i = 0u; i < 8u; i++) {
            let m = m0 + 8u * lid.y + i;
            var v = acc[2u * i + q / 4u][q % 4u];
            let is_primal = m % G.streams == 0u;
            if ((G.flags & FLAG_BIAS) != 0u && is_primal && n < G.n) {
                v += b[G.bias_off + n];
            }
            if ((G.flags & FLAG_RELU) != 0u) {
                // Rows of a thread are consecutive and start at a multiple of 8, so
                // with 4 streams rows 0 and 4 are the primals of the rows after them.
                if (is_primal) {
                    primal = v;
                }
                v = select(0.0, v, primal > 0.0);
            }
            if (m < G.m && n < G.n) {
                c[G.c_off + m * G.c_sm + n] = v;
            }
        }
    }
}

@compute @workgroup_size(8, 8)
fn grad_input(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    G = G_buffer;
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    gemm_tile(lid, m0, n0, 0u, G.k);
    var acc = acc_rows();
    for (var i = 0u; i < 8u; i++) {
        let m = m0 + 8u * lid.y + i;
        for (var q = 0u; q < 8u; q++) {
            let n = col(lid, n0, q);
            if (m < G.m && n < G.n) {
                var v = acc[2u * i + q / 4u][q % 4u];
                if ((G.flags & FLAG_MASK) != 0u) {
                    let mp = m - m % G.mask_streams;
                    v = select(0.0, v, mask[G.mask_off + mp * G.mask_sm + n] > 0.0);
                }
                let o = G.c_off + m * G.c_sm + n;
                if ((G.flags & FLAG_ACCUMULATE) != 0u) {
                    v += c[o];
                }
                c[o] = v;
            }
        }
    }
}

@compute @workgroup_size(8, 8)
fn weight_grad(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    G = G_buffer;
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    let k_begin = wid.z * G.k_chunk;
    let k_end = min(G.k, k_begin + G.k_chunk);
    gemm_tile(lid, m0, n0, k_begin, k_end);
    var acc = acc_rows();
    let base = wid.z * G.m * G.n;
    for (var i = 0u; i < 8u; i++) {
        let m = m0 + 8u * lid.y + i;
        for (var q = 0u; q < 8u; q++) {
            let n = col(lid, n0, q);
            if (m < G.m && n < G.n) {
                c[base + m * G.n + n] = acc[2u * i + q / 4u][q % 4u];
            }
        }
    }
}

// One thread per (m, n) of the partials (a 1-D dispatch of 64-thread groups folded
// into x and y): the sum over the splits, added into the layer's weights (n < bias_col)
// or its bias (n == bias_col). Binding a: the partials; c: the gradient buffer.
@compute @workgroup_size(64)
fn reduce(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    G = G_buffer;
    let idx = gid.x + gid.y * nwg.x * 64u;
    if (idx >= G.m * G.n) {
        return;
    }
    var s = 0.0;
    for (var z = 0u; z < G.splits; z++) {
        s += a[z * G.m * G.n + idx];
    }
    let m = idx / G.n;
    let n = idx % G.n;
    var o = G.c_off + m * G.bias_col + n;
    if (n == G.bias_col) {
        o = G.c_off + G.m * G.bias_col + m;
    }
    c[o] += s;
}
