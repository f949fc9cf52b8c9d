// Hash-grid field backward (owner: engine/src/field/grid/mod.rs, which derives the
// math): one thread per sample of one chunk of a SampleBatch. Recomputes the forward
// pass, back-propagates dL/dsigma, dL/drgb and (with FLAG_NORMALS) dL/dn through the
// analytic normal (second order), scatters hash-feature gradients with float atomics,
// and writes the per-sample layer inputs and deltas to `scratch` for the weight-gradient
// reduction (grid_outer.wgsl, grid_finalize.wgsl).
//
// A sample whose output gradients are all zero (every sample past a ray's early
// termination, whose gradients the renderer zeroes) contributes exactly nothing: its
// deltas are exact zeros, so its rows add zeros to the weight gradients and its scatter
// adds nothing. (It used to return early; on lavapipe that put the whole kernel under
// an execution mask and saved nothing, see grid_forward.wgsl.) With FLAG_LIVE the
// caller skips them instead: `count` is the list of the samples that carry gradient
// (LiveSamples, from sampler/live.wgsl), the chunks run over its entries, and a
// scratch row belongs to the entry at that position of the chunk.
//
// Scratch regions (vec4 offsets P.scratch[r], per-sample rows of dim4 vec4s, indexed
// by the sample's position in the chunk):
//   0 e (in4)     1 delta1 (width4)   2 a1 (width4)   3 dh (4)      4 dL/dg (in4)
//   5 xc (8)      6 deltac1 (width4)  7 ac1 (width4)  8 deltac2 (width4)
//   9 ac2 (width4)  10 delta_out (1)
// and, indexed by sample rather than by position in the chunk,
//   11 the kept encoding: e (in4) and the packed normal Jacobian, written by the
//      training forward (codegen's ForwardKeep) and read here instead of gathering the
//      table again (codegen's BackwardKept; the Backward variant recomputes).

//#include "field/grid_lib.wgsl"
// encode, the MLP products and the other vector code: generated per configuration.
//#generated

@group(0) @binding(3) var<storage, read> samples: array<Sample>;
// SampleBatch::count, or with FLAG_LIVE the LiveSamples list.
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
// The kept encoding (BackwardKept): rows indexed by sample, not by position in the chunk.
const R_KEPT: u32 = 11u;

fn region(r: u32) -> u32 {
    return P.scratch[r >> 2u][r & 3u];
}

// dL/dF[c] = w_c dL/de + g (grad w_c . dv) * beta_l * scale / extent for the 8 corners of
// level `l` (the generated scatter_table_grads calls it per active level).
fn scatter_level(l: u32, p: vec3<f32>, dek: vec2<f32>, gk: vec2<f32>, dv: vec3<f32>) {
    let scale = P.levels[l].scale;
    let pos = p * scale + vec3<f32>(0.5);
    let fl = floor(pos);
    let f = pos - fl;
    let c0 = vec3<u32>(fl);
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

@compute @workgroup_size(WG_SIZE)
fn backward(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    P = P_buffer;
    load_shared_weights(li);
    // No early return (see grid_forward.wgsl): a thread past the chunk or the count
    // recomputes a valid sample with zero output gradients and writes nothing.
    let t = thread_index(gid, nwg);
    let n_valid = min(count[0], P.n);
    let in_chunk = t < P.chunk_len && P.chunk_start + t < n_valid;
    let local = min(t, max(P.chunk_len, 1u) - 1u);
    var i = min(P.chunk_start + local, max(n_valid, 1u) - 1u);
    if ((P.flags & FLAG_LIVE) != 0u) {
        // Clamped: past the list's end (in_chunk false) the entry may be stale.
        i = min(count[LIVE_HEADER + i], max(P.n, 1u) - 1u);
    }
    let d_out = select(vec4<f32>(0.0), d_rgb_density[i], in_chunk);
    let with_normals = (P.flags & FLAG_NORMALS) != 0u;
    let smp = samples[i];
    let up = to_unit(smp.pos);
    let normal_grads = with_normals && up.inside && in_chunk;

    // Forward recomputation (the encoding from the table, or kept by the forward).
    var e: Vec64;
    var jac: Jac64;
    backward_encoding(i, up.p, normal_grads, &e, &jac);
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
    var dc1: Vec64;
    var dh: Vec64;
    color_backward(dout, &ac1, &ac2, &dc1, &dc2, &dh);

    // Density output: first order, then the normal path (second order).
    var dh0 = 0.0;
    if (up.inside) {
        dh0 = d_out.w * density_act_d1(h0);
    }
    // g = dh0/de, computed outside the branch as in grid_forward.wgsl; it only enters
    // the gradients multiplied by dv, which is zero without the normal path.
    var g: Vec64;
    density_dir(&a1, &g);
    var dg: Vec64;
    var dv = vec3<f32>(0.0);
    if (normal_grads) {
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
            normal_dg(&jac, dv, &dg);
        }
    }
    dh[0].x += dh0;

    // Density MLP backward, then the hash features.
    var d1: Vec64;
    var de: Vec64;
    density_backward(&dh, &a1, &d1, &de);
    scatter_table_grads(up.p, &de, &g, dv);

    // Per-sample rows for the weight gradients. A sample whose output gradients are all
    // zero (past its ray's early termination) has exactly zero deltas here, so its rows
    // add exact zeros to the weight gradients and its scatter adds nothing.
    if (in_chunk) {
        store_rows(local, &e, &d1, &a1, &dh, &dg, &xc, &dc1, &ac1, &dc2, &ac2, dout);
    }
}
