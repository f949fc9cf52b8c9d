// Normal-path weight gradients of the hash-grid density MLP (owner:
// engine/src/field/grid/mod.rs). With M = sum_s m_s (x) dL/dg_s (accumulated by
// grid_outer.wgsl, m the ReLU mask of layer 1) and g = W1^T (m * W2[0,:]):
//   dL/dW1[j][k] += W2[0][j] M[j][k]        dL/dW2[0][j] += sum_k W1[j][k] M[j][k]
// One thread per hidden unit j; plain (non-atomic) adds, each element has one writer.

//#include "common/dispatch.wgsl"

struct FinalizeParams {
    w1: u32,
    w2: u32,
    in4: u32,
    width: u32,
}

@group(0) @binding(0) var<storage, read> params: FinalizeParams;
@group(0) @binding(1) var<storage, read> weights: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> m: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> grad: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn finalize(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = thread_index(gid, nwg);
    if (j >= params.width) {
        return;
    }
    let w20 = weights[params.w2 + (j >> 2u)][j & 3u];
    var s = 0.0;
    for (var k4 = 0u; k4 < params.in4; k4++) {
        let mv = m[j * params.in4 + k4];
        let wi = params.w1 + j * params.in4 + k4;
        s += dot(weights[wi], mv);
        let gb = 4u * wi;
        grad[gb] += w20 * mv.x;
        grad[gb + 1u] += w20 * mv.y;
        grad[gb + 2u] += w20 * mv.z;
        grad[gb + 3u] += w20 * mv.w;
    }
    grad[4u * params.w2 + j] += s;
}
