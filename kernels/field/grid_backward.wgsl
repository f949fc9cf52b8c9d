// Hash-grid field backward (owner: engine/src/field/grid/mod.rs, which derives the
// math): one thread per sample of one chunk of a SampleBatch. Recomputes the forward
// pass, back-propagates dL/dsigma, dL/drgb and (with FLAG_NORMALS) dL/dn through the
// analytic normal (second order), scatters hash-feature gradients with float atomics,
// and writes the per-sample layer inputs and deltas to `scratch` for the weight-gradient
// reduction (grid_outer.wgsl, grid_finalize.wgsl).
//
// A sample whose output gradients are all zero (every sample past a ray's early
// termination, whose gradients the renderer zeroes) contributes exactly nothing: its
// thread writes zero rows (so that the weight-gradient reduction reads finite zeros,
// whatever a previous chunk left there) and returns without recomputing the field.
// Samples of a ray are contiguous, so whole SIMD groups skip together.
//
// Scratch regions (vec4 offsets P.scratch[r], per-sample rows of dim4 vec4s, indexed
// by the sample's position in the chunk):
//   0 e (in4)     1 delta1 (width4)   2 a1 (width4)   3 dh (4)      4 dL/dg (in4)
//   5 xc (8)      6 deltac1 (width4)  7 ac1 (width4)  8 deltac2 (width4)
//   9 ac2 (width4)  10 delta_out (1)

//#include "field/grid_lib.wgsl"

@group(0) @binding(3) var<storage, read> samples: array<Sample>;
@group(0) @binding(4) var<storage, read> count: array<u32>;
// (dL/drgb, dL/dsigma) packed as FieldOutputs packs (rgb, sigma).
@group(0) @binding(5) var<storage, read> d_rgb_density: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> d_normal: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> table_grad: array<AtomicF32>;
@group(0) @binding(8) var<storage, read_write> scratch: array<vec4<f32>>;

const R_E: u32 = 0u;
const R_D1: u32 = 1u;
const R_A1: u32 = 2u;
const R_DH: u32 = 3u;
const R_DG: u32 = 4u;
const R_XC: u32 = 5u;
const R_DC1: u32 = 6u;
const R_AC1: u32 = 7u;
const R_DC2: u32 = 8u;
const R_AC2: u32 = 9u;
const R_DO: u32 = 10u;

fn region(r: u32) -> u32 {
    return P.scratch[r >> 2u][r & 3u];
}

fn store(r: u32, dim4: u32, local: u32, v: ptr<function, Vec64>) {
    let b = region(r) + local * dim4;
    for (var j = 0u; j < dim4; j++) {
        scratch[b + j] = (*v)[j];
    }
}

// Every per-sample row of the weight-gradient reduction, for sample `local` of the chunk.
fn store_rows(
    local: u32,
    e: ptr<function, Vec64>,
    d1: ptr<function, Vec64>,
    a1: ptr<function, Vec64>,
    dh: ptr<function, Vec64>,
    dg: ptr<function, Vec64>,
    xc: ptr<function, Vec64>,
    dc1: ptr<function, Vec64>,
    ac1: ptr<function, Vec64>,
    dc2: ptr<function, Vec64>,
    ac2: ptr<function, Vec64>,
    dout: vec4<f32>,
) {
    let w4 = P.width4;
    store(R_E, P.in4, local, e);
    store(R_D1, w4, local, d1);
    store(R_A1, w4, local, a1);
    store(R_DH, 4u, local, dh);
    store(R_DG, P.in4, local, dg);
    store(R_XC, 8u, local, xc);
    store(R_DC1, w4, local, dc1);
    store(R_AC1, w4, local, ac1);
    store(R_DC2, w4, local, dc2);
    store(R_AC2, w4, local, ac2);
    scratch[region(R_DO) + local] = dout;
}

@compute @workgroup_size(WG_SIZE)
fn backward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let local = thread_index(gid, nwg);
    if (local >= P.chunk_len) {
        return;
    }
    let i = P.chunk_start + local;
    if (i >= min(count[0], P.n)) {
        return;
    }
    let w4 = P.width4;
    let d_out = d_rgb_density[i];
    let with_normals = (P.flags & FLAG_NORMALS) != 0u;
    let d_n = select(vec3<f32>(0.0), d_normal[i].xyz, with_normals);
    if (all(d_out == vec4<f32>(0.0)) && all(d_n == vec3<f32>(0.0))) {
        var zero: Vec64;
        store_rows(local, &zero, &zero, &zero, &zero, &zero, &zero, &zero, &zero, &zero, &zero, vec4<f32>(0.0));
        return;
    }
    let smp = samples[i];
    let up = to_unit(smp.pos);
    let normal_grads = with_normals && up.inside;

    // Forward recomputation.
    var e: Vec64;
    var jac: Jac64;
    encode(up.p, normal_grads, &e, &jac);
    var a1: Vec64;
    var xc: Vec64;
    density_mlp(&e, &a1, &xc);
    let h0 = xc[0].x;
    sh_encode(smp.dir, &xc);
    var ac1: Vec64;
    var ac2: Vec64;
    let o = color_mlp(&xc, &ac1, &ac2);
    let rgb = sigmoid3(o);

    // Colour MLP backward.
    let dout = vec4<f32>(d_out.xyz * rgb * (vec3<f32>(1.0) - rgb), 0.0);
    var dc2: Vec64;
    for (var j4 = 0u; j4 < w4; j4++) {
        dc2[j4] = weights[P.c3 + j4] * dout.x + weights[P.c3 + w4 + j4] * dout.y
            + weights[P.c3 + 2u * w4 + j4] * dout.z;
    }
    relu_mask_in_place(&dc2, &ac2, w4);
    var dc1: Vec64;
    mat_t_vec(P.c2, w4, w4, &dc2, &dc1);
    relu_mask_in_place(&dc1, &ac1, w4);
    var dh: Vec64;
    mat_t_vec(P.c1, w4, 8u, &dc1, &dh);

    // Density output: first order, then the normal path (second order).
    var dh0 = 0.0;
    if (up.inside) {
        dh0 = d_out.w * density_act_d1(h0);
    }
    var g: Vec64;
    var dg: Vec64;
    var dv = vec3<f32>(0.0);
    if (normal_grads) {
        density_dir(&a1, &g);
        let s1 = density_act_d1(h0);
        let v = jac_t_vec(&g, &jac);
        let u = s1 * v;
        let len = length(u);
        if (len > P.normal_eps) {
            let n = -u / len;
            let c = d_normal[i].xyz;
            let du = -(c - n * dot(n, c)) / len;
            dv = s1 * du;
            dh0 += density_act_d2(h0) * dot(v, du);
            for (var l = 0u; l < P.n_levels; l++) {
                let comp = (l & 1u) * 2u;
                dg[l >> 1u][comp] = dot(jac[2u * l], dv);
                dg[l >> 1u][comp + 1u] = dot(jac[2u * l + 1u], dv);
            }
        }
    }
    dh[0].x += dh0;

    // Density MLP backward.
    var d1: Vec64;
    mat_t_vec(P.w2, 4u, w4, &dh, &d1);
    relu_mask_in_place(&d1, &a1, w4);
    var de: Vec64;
    mat_t_vec(P.w1, w4, P.in4, &d1, &de);

    // Hash features: dL/dF[c] = w_c dL/de + g (grad w_c . dv) * beta_l * scale / extent.
    for (var l = 0u; l < P.n_levels; l++) {
        if (!level_active(l)) {
            continue;
        }
        let scale = P.levels[l].scale;
        let pos = up.p * scale + vec3<f32>(0.5);
        let fl = floor(pos);
        let f = pos - fl;
        let c0 = vec3<u32>(fl);
        let comp = (l & 1u) * 2u;
        let dek = vec2<f32>(de[l >> 1u][comp], de[l >> 1u][comp + 1u]);
        let gk = vec2<f32>(g[l >> 1u][comp], g[l >> 1u][comp + 1u]);
        let sdv = dv * scale * normal_weight(l) * P.inv_extent;
        for (var c = 0u; c < 8u; c++) {
            let bits = corner_bits(c);
            let cw = corner_weight(f, bits);
            let coef = cw.w * dek + gk * dot(cw.dw, sdv);
            let ent = corner_entry(l, c0 + bits);
            let gi0 = 2u * ent;
            let gi1 = gi0 + 1u;
            if (coef.x != 0.0) {
                atomicAddF32(table_grad, gi0, coef.x);
            }
            if (coef.y != 0.0) {
                atomicAddF32(table_grad, gi1, coef.y);
            }
        }
    }

    // Per-sample rows for the weight gradients.
    store_rows(local, &e, &d1, &a1, &dh, &dg, &xc, &dc1, &ac1, &dc2, &ac2, dout);
}
