// Backward of the MLP field's output heads (owner: engine/src/field/mlp/mod.rs): one
// thread per sample of a chunk. From dL/dsigma, dL/drgb and (FLAG_NORMALS) dL/dn of
// the batch it writes the gradients of the raw density rows (primal and, with 4
// streams, the 3 tangent rows) and of the raw colour, the seeds of the matrix
// backward. The math is in the module doc.

//#include "field/mlp_lib.wgsl"

@group(0) @binding(1) var<storage, read> sig: array<f32>;
@group(0) @binding(2) var<storage, read> rgb_raw: array<f32>;
// (dL/drgb, dL/dsigma) packed as FieldOutputs packs (rgb, sigma).
@group(0) @binding(3) var<storage, read> d_rgb_density: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> d_normal: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> g_sig: array<f32>;
@group(0) @binding(6) var<storage, read_write> g_rgb: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn heads_backward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let s = thread_index(gid, nwg);
    if (s >= P.n) {
        return;
    }
    let g = P.chunk_start + s;
    let S = P.streams;
    let o = vec3<f32>(rgb_raw[3u * s], rgb_raw[3u * s + 1u], rgb_raw[3u * s + 2u]);
    let rgb = 1.0 / (1.0 + exp(-o));
    let d_out = d_rgb_density[g];
    let d_o = d_out.xyz * rgb * (vec3<f32>(1.0) - rgb);
    g_rgb[3u * s] = d_o.x;
    g_rgb[3u * s + 1u] = d_o.y;
    g_rgb[3u * s + 2u] = d_o.z;

    let raw = sig[s * S] + P.density_bias;
    let s1 = sigmoid(raw);
    var d_raw = d_out.w * s1;
    if ((P.flags & FLAG_NORMALS) != 0u) {
        let gr = vec3<f32>(sig[s * S + 1u], sig[s * S + 2u], sig[s * S + 3u]);
        let u = s1 * P.scale * gr;
        let len = length(u);
        var d_gr = vec3<f32>(0.0);
        if (len > P.normal_eps) {
            let n = -u / len;
            let c = d_normal[g].xyz;
            let du = -(c - n * dot(n, c)) / len;
            d_gr = s1 * P.scale * du;
            d_raw += s1 * (1.0 - s1) * P.scale * dot(gr, du);
        }
        g_sig[s * S + 1u] = d_gr.x;
        g_sig[s * S + 2u] = d_gr.y;
        g_sig[s * S + 3u] = d_gr.z;
    }
    g_sig[s * S] = d_raw;
}
