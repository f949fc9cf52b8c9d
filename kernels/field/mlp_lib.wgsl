// Shared parameters and per-sample math of the MLP field's encoding and head kernels
// (owner: engine/src/field/mlp/mod.rs; the math is in its module doc).

//#include "common/dispatch.wgsl"

struct MlpParams {
    center: vec3<f32>,
    scale: f32,
    n: u32,
    streams: u32,
    flags: u32,
    pos_min_deg: u32,
    pos_bands: u32,
    active_bands: u32,
    dir_deg: u32,
    pos_dim: u32,
    enc_off: u32,
    enc_stride: u32,
    dir_off: u32,
    dir_stride: u32,
    density_bias: f32,
    normal_eps: f32,
    radius0: f32,
    radius1: f32,
    point_var: f32,
    chunk_start: u32,
}

const FLAG_IPE: u32 = 1u;
const FLAG_NORMALS: u32 = 2u;
const FLAG_COLOR: u32 = 4u;

@group(0) @binding(0) var<storage, read> P_buffer: MlpParams;
// Copied to private memory as the first statement of each entry point, before any
// branch (see gpu/kernel.rs, "Uniform buffers": storage reads inside branches are
// lane by lane on lavapipe).
var<private> P: MlpParams;

fn softplus(x: f32) -> f32 {
    return max(x, 0.0) + log(1.0 + exp(-abs(x)));
}

fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}
