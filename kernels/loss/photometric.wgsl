// Photometric loss L_c (owner: engine/src/loss/photometric.rs): mean squared error
// over rays and RGB channels, with per-ray weights. Writes dL/d(RayOutput) (colour
// part, and the opacity priors' on the opacity; the other fields zero, so regularizers
// add onto it) and each ray's weighted squared error for logging. Targets of pixels
// with alpha are composited here onto the background the renderer put behind the ray
// (RayAux.background; random backgrounds), replacing the colour the images were
// composited over when loaded:
//   c* = c + (background - loaded_over) (1 - alpha).

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    // weight / (3 * sum of ray weights): the factor that makes L a mean.
    scale: f32,
    // 1: composite the targets over the rendered backgrounds (above); 0: as given.
    recomposite: u32,
    // The opacity penalty's weight / (sum of ray weights): dL/d opacity of a ray is
    // this times its weight (priors.sparsity; 0: off).
    sparsity: f32,
    // The colour the loaded images were composited over.
    loaded_over: vec3<f32>,
    // The opacity entropy's weight / (sum of ray weights): dL/d opacity of a ray adds
    // this times its weight times ln((1 - o) / o) (priors.opacity_entropy; 0: off).
    entropy: f32,
    // The foreground opacity prior's weight / (sum of ray weights): dL/d opacity of a
    // ray subtracts this times its weight times the gate
    // 1 - exp(-|c* - background|^2 / (3 tol^2)), c* the target and background what the
    // renderer put behind the ray (priors.foreground_opacity; 0: off).
    foreground: f32,
    // 1 / (3 tol^2) (priors.foreground_tolerance).
    fg_gate_scale: f32,
    _pad0: u32,
    _pad1: u32,
}

// The entropy's gradient is taken at the opacity clamped to [this, 1 - this]: finite at
// a fully transparent or opaque ray (|ln| <= 9.2).
const ENTROPY_CLAMP: f32 = 1e-4;

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
// Target colour and the ray's weight in w (0 drops the ray).
@group(0) @binding(2) var<storage, read> targets: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(4) var<storage, read_write> sq_error: array<f32>;
// The renderer's per-ray side output and each target's alpha (1: opaque or none);
// the side output is read when params.recomposite is 1 or params.foreground > 0, the
// alpha when params.recomposite is 1.
@group(0) @binding(5) var<storage, read> aux: array<RayAux>;
@group(0) @binding(6) var<storage, read> alpha: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn photometric(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays) {
        return;
    }
    var want = targets[r];
    if (params.recomposite != 0u) {
        want = vec4<f32>(want.xyz + (aux[r].background - params.loaded_over) * (1.0 - alpha[r]), want.w);
    }
    let diff = rays[r].rgb - want.xyz;
    var d: RayOutput;
    d.rgb = 2.0 * params.scale * want.w * diff;
    d.opacity = params.sparsity * want.w;
    if (params.entropy > 0.0) {
        let o = clamp(rays[r].opacity, ENTROPY_CLAMP, 1.0 - ENTROPY_CLAMP);
        d.opacity += params.entropy * want.w * log((1.0 - o) / o);
    }
    if (params.foreground > 0.0) {
        let m = want.xyz - aux[r].background;
        d.opacity -= params.foreground * want.w * (1.0 - exp(-dot(m, m) * params.fg_gate_scale));
    }
    d.normal = vec3<f32>(0.0);
    d.depth = 0.0;
    d_rays[r] = d;
    sq_error[r] = want.w * dot(diff, diff);
}
