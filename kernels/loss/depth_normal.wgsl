// Edge-guided depth-normal consistency on 2x2 patches (owner:
// engine/src/loss/depth_normal.rs, which documents the math and holds the f64
// reference). One thread per patch: rays 4m .. 4m+3 of the batch are patch m, in the
// order (x, y), (x+1, y), (x, y+1), (x+1, y+1).
//
// Per ray: t_i = depth_i (expected) or depth_i / max(opacity_i, floor) (given
// termination), P_i = o_i + t_i d_i. The patch's depth normal is the cross product of
// its two central differences, a = P1 - P0 + P3 - P2, b = P2 - P0 + P3 - P1,
// c = a x b, n_d = s c / |c| with s = -sign(<c, d0 + d1 + d2 + d3>) (facing the
// cameras). With E = e0 e1 e2 e3 (all four pixels non-edge) and the residual
// r_i = b_i - <n_i, n_d>, b_i = 1 ("dot", 2DGS), |n_i| ("direction": zero for any
// normal along n_d whatever its length) or the ray's opacity ("per_sample": since
// n_i = sum_j w_j n_j, opacity_i - <n_i, n_d> = sum_j w_j (1 - <n_j, n_d>)):
//   L = 1/M sum_m E_m / 4 sum_i r_i
// Gradients (added to d_rays, times lambda), k = E / (4M):
//   dL/dn_i = k (-n_d [+ n_i / |n_i| for "direction"]);  dL/dopacity_i = k ("per_sample")
//   q = dL/dn_d = -k sum_i n_i
// With coherence_power p > 0, k is scaled by the patch's gate g = (mean_i c_i)^p,
// c_i = min(1, |n_i| / max(opacity_i, floor)), a constant of the backward.
//   dL/dc = s (q - <q, c^> c^) / |c|,  dL/da = b x dL/dc,  dL/db = dL/dc x a
//   dL/dP0 = -ga - gb, dL/dP1 = ga - gb, dL/dP2 = gb - ga, dL/dP3 = ga + gb
//   dL/dt_i = <dL/dP_i, d_i>, then to depth (and opacity, given termination).
// Patches with E = 0 or a degenerate cross product contribute nothing.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_patches: u32,
    // 1: t is the depth given termination (divided by the ray's opacity).
    given_termination: u32,
    lambda: f32,
    opacity_floor: f32,
    // b_i of the residual: RESIDUAL_DOT (1), RESIDUAL_DIRECTION (|n_i|) or
    // RESIDUAL_PER_SAMPLE (opacity_i); DepthNormalResidual::code in depth_normal.rs.
    residual: u32,
    // Exponent of the coherence gate (0: none).
    coherence_power: f32,
}

const RESIDUAL_DOT: u32 = 0u;
const RESIDUAL_DIRECTION: u32 = 1u;
const RESIDUAL_PER_SAMPLE: u32 = 2u;

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
@group(0) @binding(2) var<storage, read> geometry: array<Ray>;
// Per ray: (e, z_scale) of the edge-guided terms; only e is read.
@group(0) @binding(3) var<storage, read> pixel: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> d_rays: array<RayOutput>;
// Per patch: its contribution to L, normalisation included, lambda not.
@group(0) @binding(5) var<storage, read_write> patch_loss: array<f32>;

@compute @workgroup_size(WG_SIZE)
fn depth_normal(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let m = thread_index(gid, nwg);
    if (m >= params.n_patches) {
        return;
    }
    let base = 4u * m;
    let all_non_edge = pixel[base].x * pixel[base + 1u].x * pixel[base + 2u].x * pixel[base + 3u].x;
    if (all_non_edge <= 0.0) {
        patch_loss[m] = 0.0;
        return;
    }
    var p: array<vec3<f32>, 4>;
    var dir: array<vec3<f32>, 4>;
    var dt_ddepth: array<f32, 4>;
    var dt_dopacity: array<f32, 4>;
    var normal: array<vec3<f32>, 4>;
    var n_len: array<f32, 4>;
    var n_sum = vec3<f32>(0.0);
    var b_sum = 0.0;
    var coherence = 0.0;
    var d_sum = vec3<f32>(0.0);
    for (var i = 0u; i < 4u; i++) {
        let out = rays[base + i];
        let ray = geometry[base + i];
        var t = out.depth;
        dt_ddepth[i] = 1.0;
        dt_dopacity[i] = 0.0;
        if (params.given_termination != 0u) {
            let o = max(out.opacity, params.opacity_floor);
            t = out.depth / o;
            dt_ddepth[i] = 1.0 / o;
            dt_dopacity[i] = select(0.0, -t / o, out.opacity > params.opacity_floor);
        }
        dir[i] = ray.dir;
        p[i] = ray.origin + t * ray.dir;
        normal[i] = out.normal;
        n_len[i] = length(out.normal);
        n_sum += out.normal;
        coherence += min(1.0, n_len[i] / max(out.opacity, params.opacity_floor));
        switch params.residual {
            case RESIDUAL_DIRECTION: { b_sum += n_len[i]; }
            case RESIDUAL_PER_SAMPLE: { b_sum += out.opacity; }
            default: { b_sum += 1.0; }
        }
        d_sum += ray.dir;
    }
    let a = p[1] - p[0] + p[3] - p[2];
    let b = p[2] - p[0] + p[3] - p[1];
    let c = cross(a, b);
    let len = length(c);
    if (!(len > 1e-20)) {
        patch_loss[m] = 0.0;
        return;
    }
    let c_hat = c / len;
    let s = select(1.0, -1.0, dot(c_hat, d_sum) > 0.0);
    let n_d = s * c_hat;
    var gate = 1.0;
    if (params.coherence_power > 0.0) {
        gate = pow(0.25 * coherence, params.coherence_power);
    }
    let k = gate * all_non_edge / (4.0 * f32(params.n_patches));
    patch_loss[m] = k * (b_sum - dot(n_sum, n_d));
    let q = -k * n_sum;
    let g_c = s * (q - dot(q, c_hat) * c_hat) / len;
    let g_a = cross(b, g_c);
    let g_b = cross(g_c, a);
    var g_p: array<vec3<f32>, 4>;
    g_p[0] = -g_a - g_b;
    g_p[1] = g_a - g_b;
    g_p[2] = g_b - g_a;
    g_p[3] = g_a + g_b;
    let lambda = params.lambda;
    for (var i = 0u; i < 4u; i++) {
        let g_t = dot(g_p[i], dir[i]);
        var d = d_rays[base + i];
        d.depth += lambda * g_t * dt_ddepth[i];
        d.opacity += lambda * g_t * dt_dopacity[i];
        var g_n = -n_d;
        if (params.residual == RESIDUAL_DIRECTION) {
            g_n += normal[i] / max(n_len[i], 1e-12);
        }
        d.normal += (lambda * k) * g_n;
        if (params.residual == RESIDUAL_PER_SAMPLE) {
            d.opacity += lambda * k;
        }
        d_rays[base + i] = d;
    }
}
