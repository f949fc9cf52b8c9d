// Tiled matrix products of the MLP field (owner: engine/src/field/mlp/gemm.rs).
//
//   C[m, n] = sum_k A(m, k) B(k, n)      A(m, k) = a[a_off + m a_sm + k a_sk]
//                                        B(k, n) = b[b_off + k b_sk + n b_sn]
//
// A workgroup of 16 x 16 threads owns a 64 x 64 tile of C and walks k in steps of 16,
// staging a 64 x 16 tile of A and a 16 x 64 tile of B in workgroup memory; each thread
// accumulates a 4 x 4 block: rows 4 ty .. 4 ty + 3 (consecutive, so with 4 streams a
// thread holds one sample's primal row and its 3 tangent rows), columns tx + 16 j.
// Out-of-range rows, columns and k read as zero.
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

@group(0) @binding(0) var<uniform> G: Gemm;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read> mask: array<f32>;
@group(0) @binding(4) var<storage, read_write> c: array<f32>;

var<workgroup> tile_a: array<f32, 1024>; // [64 m][16 k]
var<workgroup> tile_b: array<f32, 1024>; // [16 k][64 n]
var<private> acc: array<f32, 16>;        // [4 rows][4 columns]

fn load_b(k: u32, n: u32) -> f32 {
    if ((G.flags & FLAG_BIAS_COL) != 0u && n == G.bias_col) {
        return select(0.0, 1.0, k % G.streams == 0u);
    }
    return b[G.b_off + k * G.b_sk + n * G.b_sn];
}

// acc = the (m0, n0) tile of A B over k in [k_begin, k_end).
fn gemm_tile(lid: vec3<u32>, m0: u32, n0: u32, k_begin: u32, k_end: u32) {
    let t = lid.x + 16u * lid.y;
    for (var i = 0u; i < 16u; i++) {
        acc[i] = 0.0;
    }
    for (var k0 = k_begin; k0 < k_end; k0 += TK) {
        for (var j = 0u; j < 4u; j++) {
            let idx = t + 256u * j;
            let mm = m0 + idx / TK;
            let ka = k0 + idx % TK;
            var va = 0.0;
            if (mm < G.m && ka < k_end) {
                va = a[G.a_off + mm * G.a_sm + ka * G.a_sk];
            }
            tile_a[idx] = va;
            let kb = k0 + idx / TILE;
            let nn = n0 + idx % TILE;
            var vb = 0.0;
            if (nn < G.n && kb < k_end) {
                vb = load_b(kb, nn);
            }
            tile_b[idx] = vb;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < TK; kk++) {
            let b0 = tile_b[kk * TILE + lid.x];
            let b1 = tile_b[kk * TILE + lid.x + 16u];
            let b2 = tile_b[kk * TILE + lid.x + 32u];
            let b3 = tile_b[kk * TILE + lid.x + 48u];
            for (var i = 0u; i < 4u; i++) {
                let av = tile_a[(4u * lid.y + i) * TK + kk];
                acc[4u * i] += av * b0;
                acc[4u * i + 1u] += av * b1;
                acc[4u * i + 2u] += av * b2;
                acc[4u * i + 3u] += av * b3;
            }
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(16, 16)
fn forward(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    gemm_tile(lid, m0, n0, 0u, G.k);
    for (var j = 0u; j < 4u; j++) {
        let n = n0 + lid.x + 16u * j;
        var primal = 0.0;
        for (var i = 0u; i < 4u; i++) {
            let m = m0 + 4u * lid.y + i;
            var v = acc[4u * i + j];
            let is_primal = m % G.streams == 0u;
            if ((G.flags & FLAG_BIAS) != 0u && is_primal && n < G.n) {
                v += b[G.bias_off + n];
            }
            if ((G.flags & FLAG_RELU) != 0u) {
                // Rows of a thread are consecutive and tiles start at multiples of 4,
                // so with 4 streams row i = 0 is the primal of rows 1..3.
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

@compute @workgroup_size(16, 16)
fn grad_input(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    gemm_tile(lid, m0, n0, 0u, G.k);
    for (var i = 0u; i < 4u; i++) {
        let m = m0 + 4u * lid.y + i;
        for (var j = 0u; j < 4u; j++) {
            let n = n0 + lid.x + 16u * j;
            if (m < G.m && n < G.n) {
                var v = acc[4u * i + j];
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

@compute @workgroup_size(16, 16)
fn weight_grad(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    let k_begin = wid.z * G.k_chunk;
    let k_end = min(G.k, k_begin + G.k_chunk);
    gemm_tile(lid, m0, n0, k_begin, k_end);
    let base = wid.z * G.m * G.n;
    for (var i = 0u; i < 4u; i++) {
        let m = m0 + 4u * lid.y + i;
        for (var j = 0u; j < 4u; j++) {
            let n = n0 + lid.x + 16u * j;
            if (m < G.m && n < G.n) {
                c[base + m * G.n + n] = acc[4u * i + j];
            }
        }
    }
}

// One thread per (m, n) of the partials (a 1-D dispatch of 64-thread groups folded
// into x and y): the sum over the splits, added into the layer's weights (n < bias_col)
// or its bias (n == bias_col). Binding a: the partials; c: the gradient buffer.
@compute @workgroup_size(64)
fn reduce(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
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
