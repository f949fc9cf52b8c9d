// Edge-guided depth and normal regularizers L_z and L_n of EdgeNeRF (owner:
// engine/src/loss/edge_reg.rs, which documents the math and holds the CPU reference).
// One thread per 2x2 patch: rays 4m .. 4m+3 of the batch are patch m. Per ray, `pixel`
// holds e (1 on non-edge pixels, 0 on edge pixels) and the factor that turns the
// rendered ray-parameter depth into the regularized depth z (z = depth * z_scale).
//
// With S = sum_i e_i, zbar = sum_i e_i z_i / S, nbar = sum_i e_i n_i / S:
//   paper:    L_z = sum_i max(e_i |z_i - zbar| - tau1, 0)
//             L_n = sum_i max(e_i |n_i - nbar|^2 - tau2, 0)
//             (gradients flow through zbar and nbar), both divided by the patch count;
//   official: the same L_z with zbar held constant (stop-gradient);
//             L_n = sum_i e_i |n_i - nbar|^2 / (12 M), nbar held constant, no hinge
//             (the authors' mean over the 4M pixels and 3 components);
//   plane target (either variant): L_z = sum_m max(E |z0 - z1 - z2 + z3| - tau1, 0) / M
//             with E = e0 e1 e2 e3: the patch's second difference, zero for any plane.
// z = depth * z_scale, or given termination z = depth / max(opacity, opacity_floor) *
// z_scale, whose gradient also reaches the opacity (0 below the floor).
// Patches with S = 0 (all edge) contribute nothing. Gradients are ADDED to d_rays
// (the photometric loss wrote them first): d depth = lambda_z dL_z/dz * z_scale,
// d normal = lambda_n dL_n/dn.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_patches: u32,
    // 0: the paper's equations; 1: the authors' code.
    official: u32,
    // 1: L_z pulls toward any plane (second difference) instead of the patch mean.
    depth_plane: u32,
    // 1: z is the depth given termination (divided by the ray's opacity).
    depth_given_termination: u32,
    // Loss weights including the schedule's ramp; 0 switches a term off.
    lambda_depth: f32,
    lambda_normal: f32,
    tau_depth: f32,
    tau_normal: f32,
    // Given termination, opacity is floored here (depth_estimate.rs: OPACITY_FLOOR).
    opacity_floor: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
// Per ray: (e, z_scale).
@group(0) @binding(2) var<storage, read> pixel: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> d_rays: array<RayOutput>;
// Per patch: its contributions to (L_z, L_n), normalization included, lambdas not.
@group(0) @binding(4) var<storage, read_write> patch_loss: array<vec2<f32>>;

fn sign_of(x: f32) -> f32 {
    return select(select(0.0, -1.0, x < 0.0), 1.0, x > 0.0);
}

@compute @workgroup_size(WG_SIZE)
fn edge_reg(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let m = thread_index(gid, nwg);
    if (m >= params.n_patches) {
        return;
    }
    let official = params.official != 0u;
    let plane = params.depth_plane != 0u;
    let inv_m = 1.0 / f32(params.n_patches);
    var e: array<f32, 4>;
    var z: array<f32, 4>;
    // dz/d depth and dz/d opacity per ray.
    var dz_ddepth: array<f32, 4>;
    var dz_dopacity: array<f32, 4>;
    var n: array<vec3<f32>, 4>;
    var s = 0.0;
    var z_sum = 0.0;
    var n_sum = vec3<f32>(0.0);
    for (var i = 0u; i < 4u; i++) {
        let r = 4u * m + i;
        let px = pixel[r];
        let out = rays[r];
        e[i] = px.x;
        if (params.depth_given_termination != 0u) {
            let o = max(out.opacity, params.opacity_floor);
            z[i] = out.depth * px.y / o;
            dz_ddepth[i] = px.y / o;
            dz_dopacity[i] = select(0.0, -z[i] / o, out.opacity > params.opacity_floor);
        } else {
            z[i] = out.depth * px.y;
            dz_ddepth[i] = px.y;
            dz_dopacity[i] = 0.0;
        }
        n[i] = out.normal;
        s += e[i];
        z_sum += e[i] * z[i];
        n_sum += e[i] * n[i];
    }
    if (s <= 0.0) {
        patch_loss[m] = vec2<f32>(0.0);
        return;
    }
    let z_bar = z_sum / s;
    let n_bar = n_sum / s;

    // Depth: per-pixel subgradient g_i of the hinge term, and their sum for the
    // gradient through zbar (paper variant).
    var l_z = 0.0;
    var g_z: array<f32, 4>;
    var g_z_sum = 0.0;
    // Normal: per-pixel gradient G_i and their sum.
    var l_n = 0.0;
    var g_n: array<vec3<f32>, 4>;
    var g_n_sum = vec3<f32>(0.0);
    for (var i = 0u; i < 4u; i++) {
        g_z[i] = 0.0;
    }
    if (plane) {
        let all_non_edge = e[0] * e[1] * e[2] * e[3];
        let second_difference = z[0] - z[1] - z[2] + z[3];
        let hz = all_non_edge * abs(second_difference) - params.tau_depth;
        if (hz > 0.0) {
            l_z = hz;
            let sign = all_non_edge * sign_of(second_difference);
            g_z[0] = sign;
            g_z[1] = -sign;
            g_z[2] = -sign;
            g_z[3] = sign;
        }
    }
    for (var i = 0u; i < 4u; i++) {
        let dz = z[i] - z_bar;
        let hz = e[i] * abs(dz) - params.tau_depth;
        if (!plane && hz > 0.0) {
            l_z += hz;
            g_z[i] = e[i] * sign_of(dz);
            g_z_sum += g_z[i];
        }
        let dn = n[i] - n_bar;
        let sq = e[i] * dot(dn, dn);
        g_n[i] = vec3<f32>(0.0);
        if (official) {
            l_n += sq;
            g_n[i] = 2.0 * e[i] * dn;
        } else if (sq - params.tau_normal > 0.0) {
            l_n += sq - params.tau_normal;
            g_n[i] = 2.0 * e[i] * dn;
            g_n_sum += g_n[i];
        }
    }
    let norm_n = select(inv_m, inv_m / 12.0, official);
    for (var i = 0u; i < 4u; i++) {
        let r = 4u * m + i;
        var dz = g_z[i];
        var dn = g_n[i];
        if (!official && !plane) {
            dz -= e[i] / s * g_z_sum;
        }
        if (!official) {
            dn -= e[i] / s * g_n_sum;
        }
        var d = d_rays[r];
        d.depth += params.lambda_depth * inv_m * dz * dz_ddepth[i];
        d.opacity += params.lambda_depth * inv_m * dz * dz_dopacity[i];
        d.normal += params.lambda_normal * norm_n * dn;
        d_rays[r] = d;
    }
    patch_loss[m] = vec2<f32>(l_z * inv_m, l_n * norm_n);
}
