// The edge-guided planarity term: the second difference of the rendered depth over
// triplets of pixels on a line, spaced up to tens of pixels apart inside one non-edge
// region (owner: engine/src/loss/planarity.rs, which documents the math and holds the
// f64 reference). One thread per triplet; triplet k is rays offset + 3k .. offset + 3k + 2
// (p0, p1 = p0 + s u, p2 = p0 + 2 s u). Per ray, the depth given termination along the
// camera axis:
//   z = z_scale * depth / max(opacity, floor)
// Residual (world space: inverse depth is affine in the pixel coordinates on a plane;
// NDC: the NDC parameter itself is):
//   world  r = z1 / z0 + z1 / z2 - 2      ((1/z0 - 2/z1 + 1/z2) * z1)
//   ndc    r = z0 - 2 z1 + z2
//   L = 1 / n_triplets * sum_k w_k rho(r_k)
//   rho(r) = |r|                              (scale = 0)
//   rho(r) = scale r^2 / (r^2 + scale^2)      (scale > 0: Geman-McClure, bounded by
//                                              scale, its slope falling past r ~ scale)
// A triplet with a ray below the opacity floor (background, a hole) pays nothing.
// With coherence_power p > 0, w_k is scaled by the triplet's gate (mean_j c_j)^p,
// c_j = min(1, |n_j| / max(opacity_j, floor)) (the rendered normal's length over the
// opacity: near 1 where a ray's samples agree on one surface, small in fog), held
// constant in the backward pass (as L_dn's gate, loss/depth_normal.wgsl).
// Gradients are ADDED to d_rays (depth and opacity); per-triplet terms (lambda not
// included) go to triplet_loss.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

struct Params {
    n_triplets: u32,
    offset: u32,
    ndc: u32,
    _pad0: u32,
    lambda: f32,
    opacity_floor: f32,
    scale: f32,
    coherence_power: f32,
}

// rho(r) and its derivative (see the header).
fn rho(r: f32) -> vec2<f32> {
    if (params.scale > 0.0) {
        let c = params.scale;
        let q = r * r + c * c;
        return vec2<f32>(c * r * r / q, 2.0 * r * c * c * c / (q * q));
    }
    return vec2<f32>(abs(r), sign(r));
}

@group(0) @binding(0) var<storage, read> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<RayOutput>;
// Per triplet ray: (w, z_scale); w is the triplet's weight (1, or 0 for a triplet the
// draw could not place), the same on its three rays.
@group(0) @binding(2) var<storage, read> pixel: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> d_rays: array<RayOutput>;
@group(0) @binding(4) var<storage, read_write> triplet_loss: array<f32>;

// Whether ray `local` renders a surface (opacity at least the floor): otherwise its
// depth given termination is an average over a trace of weights.
fn opaque(local: u32) -> bool {
    return rays[params.offset + local].opacity >= params.opacity_floor;
}

fn z_of(local: u32) -> f32 {
    let out = rays[params.offset + local];
    return pixel[local].y * out.depth / max(out.opacity, params.opacity_floor);
}

// Adds dL/dz of triplet ray `local`, whose depth is `z` (z_of), to its depth and
// opacity gradients.
fn add_grad(local: u32, dl_dz: f32, z: f32) {
    let g = params.offset + local;
    let out = rays[g];
    let o = max(out.opacity, params.opacity_floor);
    var d = d_rays[g];
    d.depth += dl_dz * pixel[local].y / o;
    if (out.opacity > params.opacity_floor) {
        d.opacity -= dl_dz * z / o;
    }
    d_rays[g] = d;
}

@compute @workgroup_size(WG_SIZE)
fn planarity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = thread_index(gid, nwg);
    if (k >= params.n_triplets) {
        return;
    }
    let base = 3u * k;
    var w = pixel[base].x;
    if (!(opaque(base) && opaque(base + 1u) && opaque(base + 2u))) {
        w = 0.0;
    }
    if (params.coherence_power > 0.0) {
        var coherence = 0.0;
        for (var j = 0u; j < 3u; j++) {
            let out = rays[params.offset + base + j];
            coherence += min(1.0, length(out.normal) / max(out.opacity, params.opacity_floor));
        }
        w *= pow(coherence / 3.0, params.coherence_power);
    }
    let z0 = z_of(base);
    let z1 = z_of(base + 1u);
    let z2 = z_of(base + 2u);
    var r: f32;
    var c: vec3<f32>;
    if (params.ndc != 0u) {
        r = z0 - 2.0 * z1 + z2;
        c = vec3<f32>(1.0, -2.0, 1.0);
    } else if (z0 > 0.0 && z1 > 0.0 && z2 > 0.0) {
        r = z1 / z0 + z1 / z2 - 2.0;
        c = vec3<f32>(-z1 / (z0 * z0), 1.0 / z0 + 1.0 / z2, -z1 / (z2 * z2));
    } else {
        // A ray with no depth (nothing rendered): no plane to speak of.
        r = 0.0;
        c = vec3<f32>(0.0);
    }
    let norm = 1.0 / f32(params.n_triplets);
    let p = rho(r);
    triplet_loss[k] = w * p.x * norm;
    if (w == 0.0 || r == 0.0) {
        return;
    }
    let g = params.lambda * norm * w * p.y;
    add_grad(base, g * c.x, z0);
    add_grad(base + 1u, g * c.y, z1);
    add_grad(base + 2u, g * c.z, z2);
}
