// RegNeRF's depth smoothness: total variation of the expected depth over square patches
// rendered from random poses (owner: engine/src/loss/depth_tv.rs, which documents the
// math and holds the f64 reference). One thread per patch ray; the patch rays are
// rays offset .. offset + n_rays of the batch, patch p = rays [p ps^2, (p+1) ps^2),
// row-major. Per ray:
//   z = z_scale * clamp(depth / max(opacity, eps), t_min, t_max)
// (RegNeRF's `distance_mean_save`, along the camera axis). With v00 = z(i, j),
// v01 = z(i, j+1), v10 = z(i+1, j) for i, j < ps - 1:
//   L = 1 / (P (ps-1)^2) sum w00 ((v00 - v01)^2 + (v00 - v10)^2)
// w00 = acc_weight * opacity(i, j) (a constant in the backward pass) when acc_weight > 0,
// else 1. Gradients are ADDED to d_rays (depth and opacity); per-ray terms (loss of the
// ray as v00, lambda not included) go to ray_loss.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    offset: u32,
    patch_size: u32,
    _pad0: u32,
    lambda: f32,
    acc_weight: f32,
    eps: f32,
    _pad1: f32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
@group(0) @binding(2) var<storage, read> in_rays: array<Ray>;
@group(0) @binding(3) var<storage, read> z_scale: array<f32>;
@group(0) @binding(4) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(5) var<storage, read_write> ray_loss: array<f32>;

// z of patch ray k (local index).
fn z_of(k: u32) -> f32 {
    let g = params.offset + k;
    let out = rays[g];
    let r = in_rays[g];
    return z_scale[k] * clamp(out.depth / max(out.opacity, params.eps), r.t_min, r.t_max);
}

// The constant weight of the terms where ray k is v00.
fn w_of(k: u32) -> f32 {
    if (params.acc_weight > 0.0) {
        return params.acc_weight * rays[params.offset + k].opacity;
    }
    return 1.0;
}

@compute @workgroup_size(WG_SIZE)
fn depth_tv(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = thread_index(gid, nwg);
    if (k >= params.n_rays) {
        return;
    }
    let ps = params.patch_size;
    let per_patch = ps * ps;
    let n_patches = params.n_rays / per_patch;
    let norm = 1.0 / (f32(n_patches) * f32((ps - 1u) * (ps - 1u)));
    let local = k % per_patch;
    let i = local / ps;
    let j = local % ps;
    let z = z_of(k);
    var g = 0.0;
    var loss = 0.0;
    if (i + 1u < ps && j + 1u < ps) {
        let w = w_of(k);
        let a = z - z_of(k + 1u);
        let b = z - z_of(k + ps);
        loss = w * (a * a + b * b);
        g += 2.0 * w * (a + b);
    }
    if (j >= 1u && i + 1u < ps) {
        g -= 2.0 * w_of(k - 1u) * (z_of(k - 1u) - z);
    }
    if (i >= 1u && j + 1u < ps) {
        g -= 2.0 * w_of(k - ps) * (z_of(k - ps) - z);
    }
    ray_loss[k] = loss * norm;
    // Through the clamp and the division by the opacity.
    let gi = params.offset + k;
    let out = rays[gi];
    let r = in_rays[gi];
    let a_hat = max(out.opacity, params.eps);
    let t = out.depth / a_hat;
    if (t > r.t_min && t < r.t_max) {
        let dz = params.lambda * norm * g * z_scale[k];
        var d = d_rays[gi];
        d.depth += dz / a_hat;
        if (out.opacity > params.eps) {
            d.opacity -= dz * t / a_hat;
        }
        d_rays[gi] = d;
    }
}
