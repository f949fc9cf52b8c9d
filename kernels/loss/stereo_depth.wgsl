// The stereo depth prior (owner: engine/src/loss/stereo_depth.rs, which documents the
// math and holds the f64 reference). One thread per photometric ray k < n_rays with a
// target (t*, c) (c = 0: none): the ray's depth given termination
//   t = depth / max(opacity, eps)
// is pulled toward the stereo depth t* by the Charbonnier penalty of the relative error
//   L_k = scale m_k rho((t - t*) / t*),   rho(r) = sqrt(r^2 + delta^2) - delta,
// with the constant weight m_k = c * target.w * opacity (stop-gradient: the term moves
// depth, never opacity for its own sake). Adds its gradient into d_rays and writes L_k.
//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    // lambda / n: the factor that makes the loss a mean over the batch's rays.
    scale: f32,
    delta: f32,
    eps: f32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
// (r, g, b, drop weight w) of each photometric ray.
@group(0) @binding(2) var<storage, read> targets: array<vec4<f32>>;
// (t*, c) of each photometric ray.
@group(0) @binding(3) var<storage, read> stereo: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(5) var<storage, read_write> ray_loss: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn stereo_depth(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = thread_index(gid, nwg);
    if (k >= params.n_rays) {
        return;
    }
    let s = stereo[k];
    let out = rays[k];
    let m = s.y * targets[k].w * out.opacity;
    if (!(m > 0.0 && s.x > 0.0)) {
        ray_loss[k] = 0.0;
        return;
    }
    let a_hat = max(out.opacity, params.eps);
    let t = out.depth / a_hat;
    let r = (t - s.x) / s.x;
    let root = sqrt(r * r + params.delta * params.delta);
    ray_loss[k] = params.scale * m * (root - params.delta);
    // dL/dt = scale m rho'(r) / t*;  dt/d depth = 1 / A;  dt/d opacity = -t / A.
    let g = params.scale * m * (r / root) / s.x;
    var d = d_rays[k];
    d.depth += g / a_hat;
    if (out.opacity > params.eps) {
        d.opacity -= g * t / a_hat;
    }
    d_rays[k] = d;
}
