//! Edge-guided depth-normal consistency on 2x2 patches: owner of
//! `kernels/loss/depth_normal.wgsl` and its `f64` reference ([`reference`]).
//!
//! The rendered normal of a ray (`n = sum_i w_i n_i`, the analytic density-gradient
//! normals composited) and the normal of the rendered depth map are two estimates of
//! the same surface. 2DGS and PGSR tie them together everywhere; EdgeNeRF's idea is
//! that smoothness priors belong only inside non-edge regions, so here the term acts
//! only on patches whose four pixels are all non-edge (an edge in the image is where
//! the depth map may jump and its normal means nothing).
//!
//! # The loss
//! A batch of `M` patches is `4 M` rays, patch `m` the rays `4m .. 4m+3` in the order
//! `(x, y), (x+1, y), (x, y+1), (x+1, y+1)` (as [`super::edge_reg`]). Per ray the point
//! where it ends is `P_i = o_i + t_i d_i` in the field's space (world, or NDC for LLFF:
//! the normals live there too), with `t_i` the rendered ray parameter `depth_i`, or the
//! depth given termination `depth_i / max(opacity_i, OPACITY_FLOOR)` (the setting of
//! `reg.depth_estimate`). The depth normal of the patch is
//! ```text
//! a = P1 - P0 + P3 - P2,  b = P2 - P0 + P3 - P1,  c = a x b,
//! n_d = s c / |c|,  s = -sign(<c, d0 + d1 + d2 + d3>)      (facing the cameras)
//! L_dn = 1/M sum_m E_m / 4 sum_i (1 - <n_i, n_d>),          E_m = e0 e1 e2 e3
//! ```
//! Gradients flow to both sides: the rendered normals (toward `n_d`) and, through
//! `n_d`, the depths (the depth map turns its surface toward the normals). The
//! rendered normal is not renormalised. With the `dot` residual (2DGS), `1 - <n, n_d>`
//! also falls as the ray's opacity rises toward 1 along a consistent normal, so the
//! loss rewards density wherever it acts: on the untuned `room` it grows fog sheets
//! facing the training cameras. Two residuals without that reward
//! (`reg.depth_normal_residual`) replace the 1 by
//! * `|n_i|` (`direction`): `|n_i| (1 - cos)`, zero for any normal along `n_d` whatever
//!   its length; only the normals' direction and the depths are pulled;
//! * `opacity_i` (`per_sample`): `opacity_i - <n_i, n_d> = sum_j w_j (1 - <n_j, n_d>)`
//!   over the ray's samples, each sample's normal against the depth normal weighted by
//!   its share of the ray: zero for a ray whose samples all face `n_d`, and density
//!   whose normals disagree with the surface (fog) is pushed down.
//!
//! # Coherence gate
//! With `reg.depth_normal_coherence = p > 0` each patch's term is scaled by
//! `g = (1/4 sum_i c_i)^p`, `c_i = min(1, |n_i| / max(opacity_i, OPACITY_FLOOR))`, held
//! constant in the backward (stop-gradient). `c` is how much the samples of a ray agree
//! on their normal: near 1 where the ray ends on one surface, small in fog whose
//! normals cancel out. Where the geometry is still fog the term then waits, instead of
//! shaping the fog into sheets facing the training cameras (the `room` failure).
//!
//! Invariants: the kernel only *adds* to `d_rays`; it reads the forward outputs of the
//! same batch and the rays they were rendered from (`GpuRay`, unit directions); the
//! edge weights are [`super::EdgeReg::pixel`]'s `e` (zeroed for rays the sample
//! capacity cut, so their patches drop out); patches with `E = 0` or a degenerate cross
//! product (`|c| <= 1e-20`) contribute nothing.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::{GpuRay, RayOutput};

use super::depth_estimate::{DepthEstimate, OPACITY_FLOOR};

/// The per-ray residual of `L_dn` (`reg.depth_normal_residual`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthNormalResidual {
    /// `1 - <n, n_d>` (2DGS): also lowered by raising the ray's opacity.
    #[default]
    Dot,
    /// `|n| - <n, n_d>`: zero for any normal along `n_d`; no pull on opacity.
    Direction,
    /// `opacity - <n, n_d>`: every sample's `1 - <n_j, n_d>` weighted by `w_j`.
    PerSample,
}

impl DepthNormalResidual {
    /// The kernel's `Params::residual`.
    fn code(self) -> u32 {
        match self {
            Self::Dot => 0,
            Self::Direction => 1,
            Self::PerSample => 2,
        }
    }
}

const SPEC: KernelSpec = KernelSpec {
    file: "loss/depth_normal.wgsl",
    entry: "depth_normal",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_patches: u32,
    given_termination: u32,
    lambda: f32,
    opacity_floor: f32,
    residual: u32,
    coherence_power: f32,
}

/// One launch's settings of `L_dn` (the trainer applies the schedule to `lambda`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthNormalTerm {
    pub lambda: f32,
    pub estimate: DepthEstimate,
    pub residual: DepthNormalResidual,
    /// The coherence gate's exponent `p` (0: no gate).
    pub coherence_power: f32,
}

/// The depth-normal consistency kernel and its per-patch losses.
pub struct DepthNormal {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Per patch contribution to `L_dn` of the last launch.
    pub patch_loss: GpuBuffer<f32>,
}

impl DepthNormal {
    pub fn new(gpu: &Gpu, max_patches: u32) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            patch_loss: GpuBuffer::zeros(gpu, "depth-normal patch losses", max_patches.max(1) as usize)?,
        })
    }

    /// Records `L_dn` over `n_patches` patches of `rays` (rendered from `geometry`; `pixel`
    /// holds each ray's `(e, _)`), adding `lambda dL/d RayOutput` into `d_rays`.
    pub fn record(
        &self,
        enc: &mut Encoder,
        rays: &GpuBuffer<RayOutput>,
        geometry: &GpuBuffer<GpuRay>,
        pixel: &GpuBuffer<[f32; 2]>,
        d_rays: &GpuBuffer<RayOutput>,
        n_patches: u32,
        term: &DepthNormalTerm,
    ) {
        let n_rays = 4 * n_patches as usize;
        assert!(rays.len() >= n_rays && geometry.len() >= n_rays && pixel.len() >= n_rays && d_rays.len() >= n_rays);
        assert!(self.patch_loss.len() >= n_patches as usize, "depth-normal buffers for {} patches", self.patch_loss.len());
        let params = enc.params(&Params {
            n_patches,
            given_termination: (term.estimate == DepthEstimate::GivenTermination) as u32,
            lambda: term.lambda,
            opacity_floor: OPACITY_FLOOR,
            residual: term.residual.code(),
            coherence_power: term.coherence_power,
        });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &rays.buffer, &geometry.buffer, &pixel.buffer, &d_rays.buffer, &self.patch_loss.buffer],
            n_patches,
        );
    }

    /// `L_dn` of the last launch over `n_patches` (waits for the GPU).
    pub fn loss(&self, gpu: &Gpu, n_patches: u32) -> Result<f32, GpuError> {
        super::sum_of_terms(gpu, &self.patch_loss, n_patches)
    }
}

/// `f64` CPU reference of the loss and its gradients (tests; the kernel in plain Rust).
pub mod reference {
    use super::{DepthEstimate, DepthNormalResidual, OPACITY_FLOOR};
    use glam::DVec3;

    /// One ray of a patch as the loss sees it.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct PatchRay {
        pub e: f64,
        pub origin: DVec3,
        pub dir: DVec3,
        pub depth: f64,
        pub opacity: f64,
        pub normal: DVec3,
    }

    /// `dL/d depth`, `dL/d opacity`, `dL/d normal` of one ray.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct RayGrad {
        pub depth: f64,
        pub opacity: f64,
        pub normal: DVec3,
    }

    /// The ray parameter where the ray ends and `(dt/d depth, dt/d opacity)`.
    fn end_of(r: &PatchRay, estimate: DepthEstimate) -> (f64, f64, f64) {
        match estimate {
            DepthEstimate::Expected => (r.depth, 1.0, 0.0),
            DepthEstimate::GivenTermination => {
                let floor = OPACITY_FLOOR as f64;
                let o = r.opacity.max(floor);
                let t = r.depth / o;
                (t, 1.0 / o, if r.opacity > floor { -t / o } else { 0.0 })
            }
        }
    }

    /// The depth normal of a patch (facing its rays), `None` when degenerate.
    pub fn depth_normal(patch: &[PatchRay], estimate: DepthEstimate) -> Option<DVec3> {
        let p: Vec<DVec3> = patch.iter().map(|r| r.origin + end_of(r, estimate).0 * r.dir).collect();
        let c = (p[1] - p[0] + p[3] - p[2]).cross(p[2] - p[0] + p[3] - p[1]);
        let len = c.length();
        if len <= 1e-20 {
            return None;
        }
        let d_sum: DVec3 = patch.iter().map(|r| r.dir).sum();
        Some(if c.dot(d_sum) > 0.0 { -c / len } else { c / len })
    }

    /// The coherence gate of each patch (1 with `power = 0`).
    pub fn coherence_gates(rays: &[PatchRay], power: f64) -> Vec<f64> {
        rays.chunks(4)
            .map(|patch| {
                if power <= 0.0 {
                    return 1.0;
                }
                let c: f64 = patch.iter().map(|r| (r.normal.length() / r.opacity.max(OPACITY_FLOOR as f64)).min(1.0)).sum();
                (c / 4.0).powf(power)
            })
            .collect()
    }

    /// `L_dn` of `rays` (a multiple of 4) and its gradients per ray, each patch scaled
    /// by its gate in `gates` (constants: the backward does not differentiate them).
    pub fn loss(rays: &[PatchRay], estimate: DepthEstimate, residual: DepthNormalResidual, gates: &[f64]) -> (f64, Vec<RayGrad>) {
        assert_eq!(gates.len() * 4, rays.len());
        assert_eq!(rays.len() % 4, 0);
        let m = (rays.len() / 4) as f64;
        let mut total = 0.0;
        let mut grads = vec![RayGrad::default(); rays.len()];
        for (pi, patch) in rays.chunks(4).enumerate() {
            let e: f64 = patch.iter().map(|r| r.e).product();
            if e <= 0.0 {
                continue;
            }
            let ends: Vec<(f64, f64, f64)> = patch.iter().map(|r| end_of(r, estimate)).collect();
            let p: Vec<DVec3> = patch.iter().zip(&ends).map(|(r, t)| r.origin + t.0 * r.dir).collect();
            let (a, b) = (p[1] - p[0] + p[3] - p[2], p[2] - p[0] + p[3] - p[1]);
            let c = a.cross(b);
            let len = c.length();
            if len <= 1e-20 {
                continue;
            }
            let c_hat = c / len;
            let d_sum: DVec3 = patch.iter().map(|r| r.dir).sum();
            let s = if c_hat.dot(d_sum) > 0.0 { -1.0 } else { 1.0 };
            let n_d = s * c_hat;
            let k = gates[pi] * e / (4.0 * m);
            let n_sum: DVec3 = patch.iter().map(|r| r.normal).sum();
            let base: f64 = patch
                .iter()
                .map(|r| match residual {
                    DepthNormalResidual::Dot => 1.0,
                    DepthNormalResidual::Direction => r.normal.length(),
                    DepthNormalResidual::PerSample => r.opacity,
                })
                .sum();
            total += k * (base - n_sum.dot(n_d));
            let q = -k * n_sum;
            let g_c = s * (q - q.dot(c_hat) * c_hat) / len;
            let (g_a, g_b) = (b.cross(g_c), g_c.cross(a));
            let g_p = [-g_a - g_b, g_a - g_b, g_b - g_a, g_a + g_b];
            for (i, r) in patch.iter().enumerate() {
                let g_t = g_p[i].dot(r.dir);
                let along =
                    if residual == DepthNormalResidual::Direction { r.normal / r.normal.length().max(1e-12) } else { DVec3::ZERO };
                let d_opacity = if residual == DepthNormalResidual::PerSample { k } else { 0.0 };
                grads[4 * pi + i] =
                    RayGrad { depth: g_t * ends[i].1, opacity: g_t * ends[i].2 + d_opacity, normal: k * (along - n_d) };
            }
        }
        (total, grads)
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::reference::{PatchRay, coherence_gates, depth_normal};
    use super::*;
    use crate::gpu::test_gpu;
    use crate::rng::SplitMix64;

    /// The reference without a gate.
    fn loss(rays: &[PatchRay], est: DepthEstimate, res: DepthNormalResidual) -> (f64, Vec<super::reference::RayGrad>) {
        super::reference::loss(rays, est, res, &vec![1.0; rays.len() / 4])
    }

    const ESTIMATES: [DepthEstimate; 2] = [DepthEstimate::Expected, DepthEstimate::GivenTermination];
    const RESIDUALS: [DepthNormalResidual; 3] =
        [DepthNormalResidual::Dot, DepthNormalResidual::Direction, DepthNormalResidual::PerSample];

    /// Patches of a pinhole camera at the origin looking down -z at slanted planes,
    /// perturbed, some pixels on edges, some rays below the opacity floor.
    fn random_patches(n_patches: usize, seed: u64) -> Vec<PatchRay> {
        let mut r = SplitMix64::new(seed);
        let mut rays = Vec::with_capacity(4 * n_patches);
        for m in 0..n_patches {
            let (px, py) = (r.range_f32(-40.0, 40.0) as f64, r.range_f32(-40.0, 40.0) as f64);
            let origin = DVec3::new(r.range_f32(-0.1, 0.1) as f64, 0.0, 0.0);
            for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                let dir = DVec3::new((px + dx) / 100.0, -(py + dy) / 100.0, -1.0).normalize();
                let opacity = if r.unit_f32() < 0.15 { r.range_f32(0.01, 0.1) } else { r.range_f32(0.3, 1.0) } as f64;
                let t = 2.0 + 0.3 * px / 40.0 + 0.02 * (dx + 2.0 * dy) + 0.01 * r.range_f32(-1.0, 1.0) as f64;
                rays.push(PatchRay {
                    e: if m % 7 == 3 && dx == 1.0 { 0.0 } else { 1.0 },
                    origin,
                    dir,
                    depth: t * opacity,
                    opacity,
                    normal: DVec3::new(r.range_f32(-0.5, 0.5) as f64, r.range_f32(-0.5, 0.5) as f64, r.range_f32(0.2, 1.0) as f64),
                });
            }
        }
        rays
    }

    #[test]
    fn a_plane_facing_the_camera_has_its_normal() {
        // Four rays from the origin hitting the plane z = -2: the depth normal is +z
        // (toward the camera), and a rendered normal of +z costs nothing.
        let rays: Vec<PatchRay> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
            .iter()
            .map(|&(x, y)| {
                let dir = DVec3::new(x * 0.01, -y * 0.01, -1.0).normalize();
                PatchRay { e: 1.0, origin: DVec3::ZERO, dir, depth: 2.0 / -dir.z, opacity: 1.0, normal: DVec3::Z }
            })
            .collect();
        for est in [DepthEstimate::Expected, DepthEstimate::GivenTermination] {
            let n = depth_normal(&rays, est).unwrap();
            assert!((n - DVec3::Z).length() < 1e-12, "{n}");
            for res in RESIDUALS {
                let (l, g) = loss(&rays, est, res);
                assert!(l.abs() < 1e-12, "{l}");
                assert!(g.iter().all(|g| g.depth.abs() < 1e-12), "a consistent patch pulls no depth");
            }
            // A half-transparent ray along the same normal: the dot residual asks for
            // more opacity (a longer normal), the direction residual is satisfied.
            let faint: Vec<PatchRay> = rays.iter().map(|r| PatchRay { normal: 0.5 * r.normal, ..*r }).collect();
            let (l_dot, g_dot) = loss(&faint, est, DepthNormalResidual::Dot);
            assert!((l_dot - 0.5).abs() < 1e-12 && g_dot.iter().all(|g| g.normal.z < 0.0), "{l_dot}");
            let (l_dir, g_dir) = loss(&faint, est, DepthNormalResidual::Direction);
            assert!(l_dir.abs() < 1e-12 && g_dir.iter().all(|g| g.normal.length() < 1e-12), "{l_dir}");
            // Per sample: the faint rays at half opacity are consistent; at full opacity
            // half their density faces elsewhere (cancelled out), which costs 0.5.
            let half: Vec<PatchRay> = faint.iter().map(|r| PatchRay { opacity: 0.5, depth: 0.5 * r.depth, ..*r }).collect();
            assert!(loss(&half, est, DepthNormalResidual::PerSample).0.abs() < 1e-12);
            let (l_ps, _) = loss(&faint, est, DepthNormalResidual::PerSample);
            assert!((l_ps - 0.5).abs() < 1e-12, "{l_ps}");
        }
    }

    #[test]
    fn the_coherence_gate_is_one_on_a_surface_and_small_in_fog() {
        let surface: Vec<PatchRay> = (0..4).map(|_| PatchRay { opacity: 0.8, normal: DVec3::new(0.0, 0.6, 0.8) * 0.8, ..Default::default() }).collect();
        assert!((coherence_gates(&surface, 2.0)[0] - 1.0).abs() < 1e-12);
        // Fog: opacity 1, the samples' normals cancel down to a tenth.
        let fog: Vec<PatchRay> = (0..4).map(|_| PatchRay { opacity: 1.0, normal: DVec3::new(0.1, 0.0, 0.0), ..Default::default() }).collect();
        assert!((coherence_gates(&fog, 2.0)[0] - 0.01).abs() < 1e-12);
        assert_eq!(coherence_gates(&fog, 0.0)[0], 1.0, "power 0: no gate");
    }

    #[test]
    fn reference_gradients_match_finite_differences() {
        let rays = random_patches(23, 5);
        for ((est, res), power) in ESTIMATES.into_iter().flat_map(|e| RESIDUALS.map(|r| (e, r))).zip([0.0, 2.0].into_iter().cycle()) {
            // The gate is a constant of the backward: frozen at the point differentiated.
            let gates = coherence_gates(&rays, power);
            let loss = |r: &[PatchRay], est, res| super::reference::loss(r, est, res, &gates);
            let (_, grads) = loss(&rays, est, res);
            let mut checked = 0;
            for i in 0..rays.len() {
                let fd = |set: &dyn Fn(&mut PatchRay, f64), x: f64| {
                    let h = 1e-6 * x.abs().max(1.0);
                    let eval = |v: f64| {
                        let mut r = rays.clone();
                        set(&mut r[i], v);
                        loss(&r, est, res).0
                    };
                    (eval(x + h) - eval(x - h)) / (2.0 * h)
                };
                let close = |got: f64, want: f64, what: &str| {
                    assert!((got - want).abs() <= 1e-6 * want.abs().max(1e-3), "{est:?} {res:?} ray {i} {what}: {got} vs fd {want}");
                };
                close(grads[i].depth, fd(&|r, v| r.depth = v, rays[i].depth), "depth");
                // The floor is a kink: only differentiate away from it.
                if (rays[i].opacity - OPACITY_FLOOR as f64).abs() > 1e-4 {
                    close(grads[i].opacity, fd(&|r, v| r.opacity = v, rays[i].opacity), "opacity");
                }
                for k in 0..3 {
                    let g = grads[i].normal.to_array()[k];
                    close(g, fd(&|r, v| r.normal[k] = v, rays[i].normal[k]), "normal");
                }
                checked += 1;
            }
            assert!(checked == rays.len());
            assert!(grads.iter().any(|g| g.depth.abs() > 1e-4), "the depths are pulled");
            let pulls_opacity = est == DepthEstimate::GivenTermination || res == DepthNormalResidual::PerSample;
            assert!(grads.iter().any(|g| g.opacity.abs() > 1e-4) == pulls_opacity);
        }
    }

    #[test]
    fn kernel_matches_reference() {
        let gpu = test_gpu(false);
        let n_patches = 41u32;
        let rays = random_patches(n_patches as usize, 9);
        let dn = DepthNormal::new(&gpu, n_patches).unwrap();
        let outs: Vec<RayOutput> = rays
            .iter()
            .map(|r| RayOutput {
                depth: r.depth as f32,
                opacity: r.opacity as f32,
                normal: r.normal.as_vec3().to_array(),
                ..Default::default()
            })
            .collect();
        let geometry: Vec<GpuRay> =
            rays.iter().map(|r| GpuRay { origin: r.origin.as_vec3().to_array(), t_min: 0.0, dir: r.dir.as_vec3().to_array(), t_max: 10.0 }).collect();
        let pixel: Vec<[f32; 2]> = rays.iter().map(|r| [r.e as f32, 1.0]).collect();
        let outs_buf = GpuBuffer::from_slice(&gpu, "rays", &outs).unwrap();
        let geometry_buf = GpuBuffer::from_slice(&gpu, "geometry", &geometry).unwrap();
        let pixel_buf = GpuBuffer::from_slice(&gpu, "pixel", &pixel).unwrap();
        for ((est, res), power) in ESTIMATES.into_iter().flat_map(|e| RESIDUALS.map(|r| (e, r))).zip([0.0f32, 2.0].into_iter().cycle()) {
            // Pre-filled gradients: the kernel adds.
            let prior: Vec<RayOutput> = (0..rays.len()).map(|i| RayOutput { rgb: [0.5; 3], depth: 0.25, normal: [i as f32 * 0.01, 0.0, -1.0], opacity: 0.125 }).collect();
            let d = GpuBuffer::from_slice(&gpu, "d", &prior).unwrap();
            let lambda = 0.7;
            let mut enc = gpu.encoder();
            let term = DepthNormalTerm { lambda, estimate: est, residual: res, coherence_power: power };
            dn.record(&mut enc, &outs_buf, &geometry_buf, &pixel_buf, &d, n_patches, &term);
            enc.submit();
            let got = dn.loss(&gpu, n_patches).unwrap() as f64;
            // The reference on the f32-rounded inputs the kernel saw.
            let seen: Vec<PatchRay> = rays
                .iter()
                .map(|r| PatchRay {
                    origin: r.origin.as_vec3().as_dvec3(),
                    dir: r.dir.as_vec3().as_dvec3(),
                    depth: r.depth as f32 as f64,
                    opacity: r.opacity as f32 as f64,
                    normal: r.normal.as_vec3().as_dvec3(),
                    ..*r
                })
                .collect();
            let gates = coherence_gates(&seen, power as f64);
            if power > 0.0 {
                assert!(gates.iter().any(|&g| g < 0.8) && gates.iter().any(|&g| g > 0.99), "gates exercised: {gates:?}");
            }
            let (want, grads) = super::reference::loss(&seen, est, res, &gates);
            assert!(want > 0.1, "the random patches are inconsistent: {want}");
            assert!((got - want).abs() <= 1e-5 * want, "{est:?} {res:?} gate^{power}: L_dn {got} vs {want}");
            let d = d.read(&gpu).unwrap();
            let scale = grads.iter().map(|g| g.depth.abs()).fold(0.0, f64::max);
            for (i, (g, p)) in grads.iter().zip(&prior).enumerate() {
                let want_z = p.depth as f64 + lambda as f64 * g.depth;
                assert!((d[i].depth as f64 - want_z).abs() <= 1e-4 * scale + 1e-6, "{est:?} {res:?} ray {i}: d depth {} vs {want_z}", d[i].depth);
                let want_o = p.opacity as f64 + lambda as f64 * g.opacity;
                assert!((d[i].opacity as f64 - want_o).abs() <= 1e-4 * scale + 1e-6, "{est:?} {res:?} ray {i}: d opacity {} vs {want_o}", d[i].opacity);
                for k in 0..3 {
                    let want_n = p.normal[k] as f64 + lambda as f64 * g.normal.to_array()[k];
                    assert!((d[i].normal[k] as f64 - want_n).abs() <= 1e-6, "{est:?} {res:?} ray {i}: d normal {k} {} vs {want_n}", d[i].normal[k]);
                }
                assert_eq!(d[i].rgb, [0.5; 3], "colour gradients untouched");
            }
            let edge_patches = rays.chunks(4).filter(|p| p.iter().any(|r| r.e == 0.0)).count();
            assert!(edge_patches > 3);
            let per_patch = dn.patch_loss.read(&gpu).unwrap();
            for (m, patch) in rays.chunks(4).enumerate() {
                if patch.iter().any(|r| r.e == 0.0) {
                    assert_eq!(per_patch[m], 0.0, "patch {m} touches an edge");
                }
            }
        }
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/depth_normal.wgsl", "Params", [n_patches, given_termination, lambda, opacity_floor, residual, coherence_power]);
        for (res, name) in [
            (DepthNormalResidual::Dot, "RESIDUAL_DOT"),
            (DepthNormalResidual::Direction, "RESIDUAL_DIRECTION"),
            (DepthNormalResidual::PerSample, "RESIDUAL_PER_SAMPLE"),
        ] {
            crate::gpu::kernel::tests::check_wgsl_u32_const("loss/depth_normal.wgsl", name, res.code()).unwrap_or_else(|e| panic!("{e}"));
        }
    }
}
