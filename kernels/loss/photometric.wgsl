// Photometric loss L_c (owner: engine/src/loss/photometric.rs): mean squared error
// over rays and RGB channels, with per-ray weights. Writes dL/d(RayOutput) (colour
// part; the other fields zero, so regularizers add onto it) and each ray's weighted
// squared error for logging.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    // weight / (3 * sum of ray weights): the factor that makes L a mean.
    scale: f32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
// Target colour and the ray's weight in w (0 drops the ray).
@group(0) @binding(2) var<storage, read> targets: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(4) var<storage, read_write> sq_error: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn photometric(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays) {
        return;
    }
    let want = targets[r];
    let diff = rays[r].rgb - want.xyz;
    var d: RayOutput;
    d.rgb = 2.0 * params.scale * want.w * diff;
    d.opacity = 0.0;
    d.normal = vec3<f32>(0.0);
    d.depth = 0.0;
    d_rays[r] = d;
    sq_error[r] = want.w * dot(diff, diff);
}
