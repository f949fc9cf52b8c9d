// Cross-view photometric consistency of the rendered depth (owner:
// engine/src/loss/reprojection.rs, which documents the math and holds the f64 reference).
// One thread per photometric ray k < n_rays. The ray's depth given termination,
//   t = clamp(depth / max(opacity, eps), t_min, t_max),   x = origin + t dir
// (NDC rays: that point mapped back to world space),
// is projected into every training view j other than the ray's own s = source[k]; where
// it lands inside view j (in front of the camera, a whole bilinear footprint inside the
// image), the view's colour there is compared with the ray's own colour, read from the
// same (optionally blurred) images at the ray's pixel, I_s(pi_s(x)):
//   E_j = 1/3 sum_c rho(I_j(pi_j(x))_c - I_s(pi_s(x))_c),   rho(r) = sqrt(r^2 + delta^2) - delta
// and the ray's term is m_k min_j E_j (the view that sees x best: another view may see
// an occluder there), with the constant weight m_k = target.w * opacity (stop-gradient).
//   L = 1/n_rays sum_k m_k min_j E_j
// The gradient runs through t (the bilinear image derivative and the projection's
// Jacobian) into depth and opacity, as in depth_tv.wgsl. Gradients are ADDED to d_rays;
// per-ray terms (normalised, lambda not included) go to ray_loss.
//
// views: one u32 array holding, per training view v, a header of HEADER words at
// v * HEADER (the world-to-camera rows [R | T] as 12 floats, fx, fy, cx, cy as floats,
// then width, height and the word offset of its pixels in this same array, one pad
// word), and after all headers every view's pixels, RGBA8 (unpack4x8unorm), row-major.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_rays: u32,
    n_views: u32,
    // 1: the rays are NeRF's NDC rays, mapped back to world space with ndc_near and
    // ndc_scale = (-width / (2 focal_x), -height / (2 focal_y)).
    ndc: u32,
    _pad0: u32,
    lambda: f32,
    delta: f32,
    eps: f32,
    ndc_near: f32,
    ndc_scale: vec2<f32>,
    _pad1: vec2<f32>,
}

const HEADER: u32 = 20u;

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
@group(0) @binding(2) var<storage, read> in_rays: array<Ray>;
@group(0) @binding(3) var<storage, read> targets: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> source: array<u32>;
@group(0) @binding(5) var<storage, read> views: array<u32>;
@group(0) @binding(6) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(7) var<storage, read_write> ray_loss: array<f32>;

fn header_f32(v: u32, i: u32) -> f32 {
    return bitcast<f32>(views[v * HEADER + i]);
}

fn texel(offset: u32, width: u32, x: u32, y: u32) -> vec3<f32> {
    return unpack4x8unorm(views[offset + y * width + x]).xyz;
}

// View v's projection of x: camera-frame point q, its rate dq along dir, and the
// continuous pixel coordinates (pixel centres at +0.5) of q.
struct Projection {
    q: vec3<f32>,
    dq: vec3<f32>,
    uv: vec2<f32>,
}

fn project(v: u32, x: vec3<f32>, dir: vec3<f32>) -> Projection {
    let r0 = vec4<f32>(header_f32(v, 0u), header_f32(v, 1u), header_f32(v, 2u), header_f32(v, 3u));
    let r1 = vec4<f32>(header_f32(v, 4u), header_f32(v, 5u), header_f32(v, 6u), header_f32(v, 7u));
    let r2 = vec4<f32>(header_f32(v, 8u), header_f32(v, 9u), header_f32(v, 10u), header_f32(v, 11u));
    let q = vec3<f32>(dot(r0.xyz, x) + r0.w, dot(r1.xyz, x) + r1.w, dot(r2.xyz, x) + r2.w);
    let dq = vec3<f32>(dot(r0.xyz, dir), dot(r1.xyz, dir), dot(r2.xyz, dir));
    let z = -q.z;
    let uv = vec2<f32>(header_f32(v, 14u) + header_f32(v, 12u) * q.x / z, header_f32(v, 15u) - header_f32(v, 13u) * q.y / z);
    return Projection(q, dq, uv);
}

// The bilinear interpolant of view v's image at continuous pixel coordinates uv (clamped
// to the pixel centres), and its derivatives along u and v.
struct Bilinear {
    rgb: vec3<f32>,
    d_du: vec3<f32>,
    d_dv: vec3<f32>,
}

fn bilinear(v: u32, uv: vec2<f32>) -> Bilinear {
    let width = views[v * HEADER + 16u];
    let height = views[v * HEADER + 17u];
    let offset = views[v * HEADER + 18u];
    let px = clamp(uv.x - 0.5, 0.0, f32(width - 1u));
    let py = clamp(uv.y - 0.5, 0.0, f32(height - 1u));
    let x0 = min(u32(px), width - 2u);
    let y0 = min(u32(py), height - 2u);
    let a = px - f32(x0);
    let b = py - f32(y0);
    let c00 = texel(offset, width, x0, y0);
    let c10 = texel(offset, width, x0 + 1u, y0);
    let c01 = texel(offset, width, x0, y0 + 1u);
    let c11 = texel(offset, width, x0 + 1u, y0 + 1u);
    let rgb = (1.0 - a) * (1.0 - b) * c00 + a * (1.0 - b) * c10 + (1.0 - a) * b * c01 + a * b * c11;
    let d_du = (1.0 - b) * (c10 - c00) + b * (c11 - c01);
    let d_dv = (1.0 - a) * (c01 - c00) + a * (c11 - c10);
    return Bilinear(rgb, d_du, d_dv);
}

// The world point at ray parameter t and its rate along t: origin + t dir, or for NDC
// rays the inverse of NeRF's map (data/camera.rs NdcParams::ndc_to_world) of that point.
struct RayPoint {
    x: vec3<f32>,
    dx: vec3<f32>,
}

fn ray_point(ray: Ray, t: f32) -> RayPoint {
    let p = ray.origin + t * ray.dir;
    if (params.ndc == 0u) {
        return RayPoint(p, ray.dir);
    }
    let z = 2.0 * params.ndc_near / (p.z - 1.0);
    let dz = -z / (p.z - 1.0) * ray.dir.z;
    let s = params.ndc_scale;
    let x = vec3<f32>(s.x * p.x * z, s.y * p.y * z, z);
    let dx = vec3<f32>(s.x * (ray.dir.x * z + p.x * dz), s.y * (ray.dir.y * z + p.y * dz), dz);
    return RayPoint(x, dx);
}

// What view v says about the point x (moving along dir as t grows) against the ray's
// own colour: whether x lands inside it, the error E_v and dE_v/dt.
struct ViewTerm {
    ok: bool,
    err: f32,
    d_err_dt: f32,
}

fn view_term(v: u32, x: vec3<f32>, dir: vec3<f32>, own_rgb: vec3<f32>) -> ViewTerm {
    var out = ViewTerm(false, 0.0, 0.0);
    let p = project(v, x, dir);
    let z = -p.q.z;
    let width = views[v * HEADER + 16u];
    let height = views[v * HEADER + 17u];
    let px = p.uv.x - 0.5;
    let py = p.uv.y - 0.5;
    if (!(z > params.eps && px >= 0.0 && py >= 0.0 && px < f32(width) - 1.0 && py < f32(height) - 1.0)) {
        return out;
    }
    let s = bilinear(v, p.uv);
    let du_dt = header_f32(v, 12u) * (p.dq.x / z + p.q.x * p.dq.z / (z * z));
    let dv_dt = -header_f32(v, 13u) * (p.dq.y / z + p.q.y * p.dq.z / (z * z));
    let r = s.rgb - own_rgb;
    let root = sqrt(r * r + vec3<f32>(params.delta * params.delta));
    let rho = root - vec3<f32>(params.delta);
    let d_rho = r / root;
    out.ok = true;
    out.err = (rho.x + rho.y + rho.z) / 3.0;
    out.d_err_dt = dot(d_rho, s.d_du * du_dt + s.d_dv * dv_dt) / 3.0;
    return out;
}

@compute @workgroup_size(WG_SIZE)
fn reprojection(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = thread_index(gid, nwg);
    if (k >= params.n_rays) {
        return;
    }
    let n_views = params.n_views;
    let own = source[k];
    let target_px = targets[k];
    let out = rays[k];
    let ray = in_rays[k];
    let m = target_px.w * out.opacity;
    let a_hat = max(out.opacity, params.eps);
    let t_raw = out.depth / a_hat;
    let t = clamp(t_raw, ray.t_min, ray.t_max);
    let point = ray_point(ray, t);
    var best = ViewTerm(false, 0.0, 0.0);
    if (m > 0.0 && own < n_views) {
        // The ray's own colour from the same (blurred) images: its view at its pixel.
        let own_rgb = bilinear(own, project(own, point.x, point.dx).uv).rgb;
        for (var v = 0u; v < n_views; v++) {
            if (v == own) {
                continue;
            }
            let term = view_term(v, point.x, point.dx, own_rgb);
            if (term.ok && (!best.ok || term.err < best.err)) {
                best = term;
            }
        }
    }
    let norm = 1.0 / f32(params.n_rays);
    if (!best.ok) {
        ray_loss[k] = 0.0;
        return;
    }
    ray_loss[k] = norm * m * best.err;
    // Through the clamp and the division by the opacity.
    if (t_raw > ray.t_min && t_raw < ray.t_max) {
        let g = params.lambda * norm * m * best.d_err_dt;
        var d = d_rays[k];
        d.depth += g / a_hat;
        if (out.opacity > params.eps) {
            d.opacity -= g * t_raw / a_hat;
        }
        d_rays[k] = d;
    }
}
