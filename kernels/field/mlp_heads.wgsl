// Output heads of the MLP field (owner: engine/src/field/mlp/mod.rs): one thread per
// sample of a chunk, between the last matrix products and the FieldOutputs / FieldGrads
// of the batch (sample index chunk_start + s). The math is in the module doc.

//#include "field/mlp_lib.wgsl"

@group(0) @binding(1) var<storage, read> sig: array<f32>;     // raw density rows (S per sample)
@group(0) @binding(2) var<storage, read> rgb_raw: array<f32>; // 3 per sample

// heads_forward: (rgb, sigma) packed as FieldOutputs holds them, and the unit normal
// (FLAG_NORMALS, 4 streams). heads_density: sigma alone (density queries, no colour).
@group(0) @binding(3) var<storage, read_write> out_rgb_density: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out_normal: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> out_density: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn heads_density(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let s = thread_index(gid, nwg);
    if (s >= P.n) {
        return;
    }
    out_density[P.chunk_start + s] = softplus(sig[s * P.streams] + P.density_bias);
}

@compute @workgroup_size(WG_SIZE)
fn heads_forward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    P = P_buffer;
    let s = thread_index(gid, nwg);
    if (s >= P.n) {
        return;
    }
    let g = P.chunk_start + s;
    let S = P.streams;
    let raw = sig[s * S] + P.density_bias;
    let o = vec3<f32>(rgb_raw[3u * s], rgb_raw[3u * s + 1u], rgb_raw[3u * s + 2u]);
    out_rgb_density[g] = vec4<f32>(1.0 / (1.0 + exp(-o)), softplus(raw));
    if ((P.flags & FLAG_NORMALS) != 0u) {
        let gr = vec3<f32>(sig[s * S + 1u], sig[s * S + 2u], sig[s * S + 3u]);
        let u = sigmoid(raw) * P.scale * gr;
        let len = length(u);
        var n = vec3<f32>(0.0);
        if (len > P.normal_eps) {
            n = -u / len;
        }
        out_normal[g] = vec4<f32>(n, 0.0);
    }
}
