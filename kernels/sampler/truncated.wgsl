// Drops the rays the batch's sample capacity cut (owner: engine/src/sampler/truncated.rs):
// one thread per photometric ray r < n_rays. A ray is cut iff it kept fewer samples
// than it wanted (ranges[r].count < wanted[r]); it then renders without its far
// samples (or none at all), so it must not be compared with its pixel: its target
// weight becomes 0 and, with patch batches, the edge weight e of its whole 2x2 patch
// becomes 0 (an all-edge patch contributes nothing to L_z and L_n). Counts the cut rays.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    patches: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> ranges: array<SampleRange>;
@group(0) @binding(2) var<storage, read> wanted: array<u32>;
@group(0) @binding(3) var<storage, read_write> targets: array<vec4<f32>>;
// Per pixel (e, z_scale) of the edge-guided losses (patch batches only).
@group(0) @binding(4) var<storage, read_write> pixel: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read_write> dropped: array<atomic<u32>>;

@compute @workgroup_size(WG_SIZE)
fn drop_truncated(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays || ranges[r].count >= wanted[r]) {
        return;
    }
    targets[r].w = 0.0;
    atomicAdd(&dropped[0], 1u);
    if (params.patches != 0u) {
        let p = r - r % 4u;
        for (var j = 0u; j < 4u; j++) {
            pixel[p + j].x = 0.0;
        }
    }
}
