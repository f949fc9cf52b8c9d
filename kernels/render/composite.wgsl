// Volume rendering (compositing) forward and backward. Owner: engine/src/render/mod.rs,
// which holds the bind layouts below and documents the math; the CPU reference of the
// forward pass is engine/src/render/reference.rs. One thread per ray, walking the
// ray's contiguous samples front to back.
//
// Forward, per ray, over samples i = 0 .. K-1 (K = contributing samples, see below):
//   tau_i = sigma_i dt_i,  trans_i = exp(-tau_i),  alpha_i = 1 - trans_i
//   (alpha from a 5-term series when tau < 0.1, where 1 - exp(-tau) would cancel),
//   T_0 = 1,  T_{i+1} = T_i trans_i,  w_i = T_i alpha_i,
//   rgb = sum w_i c_i + (1 - opacity) bg,  opacity = sum w_i,
//   depth = sum w_i t_i,  normal = sum w_i n_i (not renormalised).
// Early termination: sample i contributes iff T_i >= t_threshold, checked before the
// sample; K is the first i with T_i < t_threshold (or the ray's count). The forward
// pass stores K in aux.n_contrib and the backward pass walks exactly K samples, so
// the two agree by construction.
//
// Backward, with g = dL/d(RayOutput) of the ray, b = <g.rgb, bg> and per sample
//   u_i = <g.rgb, c_i - bg> + g.opacity + g.depth t_i + <g.normal, n_i>
// (so that L = sum_i w_i u_i + b up to terms independent of the field):
//   dL/dc_i = w_i g.rgb,  dL/dn_i = w_i g.normal,
//   dL/dsigma_i = dt_i (T_{i+1} u_i - sum_{j>i, j<K} w_j u_j),
// the suffix sum taken as total - prefix, with
//   total = <g.rgb, rgb - bg> + g.opacity opacity + g.depth depth + <g.normal, normal>
// read from the forward outputs (the Instant-NGP / nerfacc trick: one pass, no
// per-sample scratch). Samples at or past K get zero gradients.
//
// Sparse-view priors on the weights and densities (render/priors.rs has the math),
// over the same K samples, with m_i = t_i the sample midpoints:
//   distortion (mip-NeRF 360) D = sum_{i,j} w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 dt_i
//   occlusion  (FreeNeRF)     O = sum_{i: t_i < occlusion_end} sigma_i dt_i
//   orientation (Ref-NeRF)    R = sum_i w_i max(0, <n_i, d_i>)^2
// The forward pass stores all three per ray in aux. The backward adds
//   params.distortion * D + params.occlusion * O + params.orientation * R
// to the ray's loss: dD/dw_i = 2 (m_i W_<i - M_<i + M_>i - m_i W_>i) + 2/3 w_i dt_i
// (W, M: prefix and suffix sums of w and w m, the suffixes from opacity and depth)
// enters u_i, and sum_i w_i dD/dw_i = 2 D (D is homogeneous of degree 2 in w) enters
// total; dO/dsigma_i = dt_i is added to the density gradient directly; dR/dw_i =
// max(0, <n_i, d_i>)^2 enters u_i and R (degree 1) total, and dR/dn_i =
// 2 w_i max(0, <n_i, d_i>) d_i the normal gradient.
// The stereo free-space prior, per ray up to the caller's aux.free_end (0: none),
//   F = sum_{i: t_i < free_end} sigma_i dt_i,
// adds params.free_space * F: dF/dsigma_i = dt_i, to the density gradient directly as
// the occlusion term (its value is not stored).

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"
//#include "common/hash.wgsl"
//#include "common/opacity.wgsl"

struct Params {
    n_rays: u32,
    // 0: no background (black); 1: the constant `background`; 2: random per ray;
    // 3: per ray, as the caller wrote it into aux[r].background (learned background).
    bg_mode: u32,
    seed: u32,
    // Forward: write per-sample weights into `weights`.
    write_weights: u32,
    background: vec4<f32>,
    t_threshold: f32,
    // Backward: add into the gradient buffers instead of overwriting them.
    accumulate: u32,
    // Backward: the weights of the distortion, occlusion and orientation priors (0: off).
    distortion: f32,
    occlusion: f32,
    // Samples with t below this are in the occlusion prior's range.
    occlusion_end: f32,
    orientation: f32,
    // Backward: the weight of the stereo free-space prior (0: off).
    free_space: f32,
    _pad2: u32,
}

// RayAux (common/layout.wgsl): per-ray side output of the forward pass.

@group(0) @binding(0) var<storage, read> params_buffer: Params;
// Copied to private memory as the first statement of each entry point, before any
// branch (see gpu/kernel.rs, "Uniform buffers": storage reads inside branches are
// lane by lane on lavapipe).
var<private> params: Params;
@group(0) @binding(1) var<storage, read> ranges: array<SampleRange>;
@group(0) @binding(2) var<storage, read> samples: array<Sample>;
// The field's (r, g, b, sigma) per sample, and its gradients packed the same way (one
// binding each: the backward's 10 storage buffers are the most SwiftShader allows).
@group(0) @binding(3) var<storage, read> rgb_density: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> normal: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> rays: array<RayOutput>;
@group(0) @binding(6) var<storage, read_write> aux: array<RayAux>;
// Forward only.
@group(0) @binding(7) var<storage, read_write> weights: array<f32>;
// Backward only.
@group(0) @binding(7) var<storage, read> d_rays: array<RayOutput>;
@group(0) @binding(8) var<storage, read_write> grad_rgb_density: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> grad_normal: array<vec4<f32>>;


fn background_for(ray: u32) -> vec3<f32> {
    switch params.bg_mode {
        case 1u: {
            return params.background.xyz;
        }
        case 2u: {
            let base = pcg_hash(params.seed ^ pcg_hash(ray));
            return vec3<f32>(unit_f32(pcg_hash(base)), unit_f32(pcg_hash(base + 1u)), unit_f32(pcg_hash(base + 2u)));
        }
        case 3u: {
            return aux[ray].background;
        }
        default: {
            return vec3<f32>(0.0);
        }
    }
}

@compute @workgroup_size(WG_SIZE)
fn forward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays) {
        return;
    }
    let range = ranges[r];
    let bg = background_for(r);
    // The caller's input, kept for the backward.
    let free_end = aux[r].free_end;
    var T = 1.0;
    var acc_rgb = vec3<f32>(0.0);
    var acc_opacity = 0.0;
    var acc_normal = vec3<f32>(0.0);
    var acc_depth = 0.0;
    // Distortion by prefix sums: sum_{i,j} w_i w_j |m_i - m_j| = 2 sum_i w_i (m_i W_<i - M_<i).
    var dist_inter = 0.0;
    var dist_intra = 0.0;
    var occ = 0.0;
    var orient = 0.0;
    var k = 0u;
    for (; k < range.count; k++) {
        if (T < params.t_threshold) {
            break;
        }
        let s = range.start + k;
        let smp = samples[s];
        let field = rgb_density[s];
        let tau = field.w * smp.dt;
        let trans = exp(-tau);
        let w = T * alpha_of(tau, trans);
        acc_rgb += w * field.xyz;
        let n = normal[s].xyz;
        acc_normal += w * n;
        let facing = max(dot(n, smp.dir), 0.0);
        orient += w * facing * facing;
        dist_inter += w * (smp.t * acc_opacity - acc_depth);
        dist_intra += w * w * smp.dt;
        if (smp.t < params.occlusion_end) {
            occ += tau;
        }
        acc_opacity += w;
        acc_depth += w * smp.t;
        if (params.write_weights != 0u) {
            weights[s] = w;
        }
        T *= trans;
    }
    if (params.write_weights != 0u) {
        for (var i = k; i < range.count; i++) {
            weights[range.start + i] = 0.0;
        }
    }
    rays[r] = RayOutput(acc_rgb + (1.0 - acc_opacity) * bg, acc_opacity, acc_normal, acc_depth);
    aux[r] = RayAux(bg, k, 2.0 * dist_inter + dist_intra / 3.0, occ, orient, free_end);
}

@compute @workgroup_size(WG_SIZE)
fn backward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    params = params_buffer;
    let r = thread_index(gid, nwg);
    if (r >= params.n_rays) {
        return;
    }
    let range = ranges[r];
    let fwd = rays[r];
    let side = aux[r];
    let g = d_rays[r];
    let bg = side.background;
    let k_end = min(side.n_contrib, range.count);
    let c_dist = params.distortion;
    let c_ori = params.orientation;
    let total = dot(g.rgb, fwd.rgb - bg) + g.opacity * fwd.opacity + g.depth * fwd.depth + dot(g.normal, fwd.normal)
        + c_dist * 2.0 * side.distortion + c_ori * side.orientation;
    let acc = params.accumulate != 0u;
    var T = 1.0;
    var prefix = 0.0;
    // Prefix sums of w and w t before the current sample (distortion).
    var w_before = 0.0;
    var wt_before = 0.0;
    for (var i = 0u; i < k_end; i++) {
        let s = range.start + i;
        let smp = samples[s];
        let field = rgb_density[s];
        let tau = field.w * smp.dt;
        let trans = exp(-tau);
        let w = T * alpha_of(tau, trans);
        T *= trans;
        let n = normal[s].xyz;
        var u = dot(g.rgb, field.xyz - bg) + g.opacity + g.depth * smp.t + dot(g.normal, n);
        var d_n = w * g.normal;
        if (c_ori != 0.0) {
            let facing = max(dot(n, smp.dir), 0.0);
            u += c_ori * facing * facing;
            d_n += (2.0 * c_ori * w * facing) * smp.dir;
        }
        if (c_dist != 0.0) {
            let w_after = fwd.opacity - w_before - w;
            let wt_after = fwd.depth - wt_before - w * smp.t;
            u += c_dist * (2.0 * (smp.t * w_before - wt_before + wt_after - smp.t * w_after) + (2.0 / 3.0) * w * smp.dt);
            w_before += w;
            wt_before += w * smp.t;
        }
        prefix += w * u;
        var d_sigma = smp.dt * (T * u - (total - prefix));
        if (smp.t < params.occlusion_end) {
            d_sigma += params.occlusion * smp.dt;
        }
        if (smp.t < side.free_end) {
            d_sigma += params.free_space * smp.dt;
        }
        let d_field = vec4<f32>(w * g.rgb, d_sigma);
        let d_normal = vec4<f32>(d_n, 0.0);
        if (acc) {
            grad_rgb_density[s] += d_field;
            grad_normal[s] += d_normal;
        } else {
            grad_rgb_density[s] = d_field;
            grad_normal[s] = d_normal;
        }
    }
    if (!acc) {
        for (var i = k_end; i < range.count; i++) {
            let s = range.start + i;
            grad_rgb_density[s] = vec4<f32>(0.0);
            grad_normal[s] = vec4<f32>(0.0);
        }
    }
}
