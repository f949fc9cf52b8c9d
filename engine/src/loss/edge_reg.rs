//! The edge-guided depth and normal regularizers of EdgeNeRF (paper, section 3), on
//! batches of 2x2 patches: owner of `kernels/loss/edge_reg.wgsl` and its CPU
//! reference ([`reference`]).
//!
//! # The losses
//! A batch of `M` patches is `4 M` rays; rays `4m .. 4m+3` are patch `m`, in the order
//! `(x, y), (x+1, y), (x, y+1), (x+1, y+1)` (the order does not matter to the losses).
//! Per ray the caller gives `e` (1 on non-edge pixels, 0 on edge pixels, the paper's
//! convention after the 3x3 dilation of edges) and `z_scale`. The regularized depth
//! is `z = depth * z_scale`, where `depth = sum_i w_i t_i` is the renderer's expected
//! ray parameter (not divided by opacity, as the paper's integral):
//! * world-space scenes: `z_scale = <dir, camera axis>`, so `z` is the expected depth
//!   along the camera axis. The authors' mip-NeRF rays have un-normalised directions
//!   with unit z, so their `t` is this z-depth; a plane facing the camera then has the
//!   same `z` at the four pixels of a patch, while ray distances would differ;
//! * NDC scenes (LLFF): `z_scale = 1`; `t` is the NDC parameter in `[0, 1]`, the
//!   space the paper (and its code) regularizes for forward-facing scenes.
//!
//! With `reg.depth_estimate = "given_termination"` (the authors' code) the depth is
//! divided by the ray's opacity first, `z = depth / max(opacity, OPACITY_FLOOR) *
//! z_scale`: where the ray ends, whatever its opacity, so the loss cannot lower a
//! patch's spread by thinning or thickening its rays.
//!
//! The rendered normal is `n = sum_i w_i n_i` (not renormalised, as the authors), in
//! the field's space (NDC for LLFF). With `S = sum e_i`, `zbar = sum e_i z_i / S`,
//! `nbar = sum e_i n_i / S` per patch:
//!
//! ```text
//! paper:    L_z = 1/M sum_m sum_i max(e_i |z_i - zbar| - tau1, 0)
//!           L_n = 1/M sum_m sum_i max(e_i |n_i - nbar|^2 - tau2, 0)
//!           gradients flow through zbar and nbar
//! official: L_z as above with zbar a constant (stop-gradient)
//!           L_n = 1/(12 M) sum_m sum_i e_i |n_i - nbar|^2, nbar a constant, no hinge
//! plane:    L_z = 1/M sum_m max(E_m |z_0 - z_1 - z_2 + z_3| - tau1, 0),  E_m = e_0 e_1 e_2 e_3
//!           (`reg.depth_target = "plane"`, either variant)
//! ```
//! The paper's `L_z` pulls the four depths of a non-edge patch to their mean: a face
//! at 45 degrees to the view has depths a pixel footprint apart, so every slanted
//! patch pays and is pushed toward fronto-parallel. The plane target is the patch's
//! second difference, zero for any depth that is affine in the pixel coordinates (a
//! plane, to first order over a 2x2 patch), and only defined where all four pixels are
//! non-edge (any three points lie on a plane).
//! The paper writes both losses as sums over patches and pixels next to a photometric
//! sum over rays; we divide every term by the batch size (`L_c` is the mean over rays
//! and channels, these by the patch count), which keeps the paper's balance between
//! `lambda2` and `lambda3` and matches the authors' `L_z` normalisation exactly. The
//! official `L_n` is the authors' `mean(e * (n - nbar)^2)` over all `4 M` pixels and
//! 3 components. A patch whose four pixels are all edge (`S = 0`) contributes nothing
//! (the authors' 0/0 guard).
//!
//! # Gradients (added to `dL/d RayOutput`)
//! With `g_i = e_i sign(z_i - zbar)` where the hinge is active (else 0) and
//! `G_i = 2 e_i (n_i - nbar)` where active (always, official):
//! ```text
//! paper:    dL_z/dz_j = (g_j - e_j/S sum_i g_i) / M
//!           dL_n/dn_j = (G_j - e_j/S sum_i G_i) / M
//! official: dL_z/dz_j = g_j / M,    dL_n/dn_j = G_j / (12 M)
//! plane:    dL_z/dz_j = E_m sign(r_m) c_j / M where active, c = (1, -1, -1, 1)
//! ```
//! `d depth = lambda_z dL_z/dz * z_scale`, `d normal = lambda_n dL_n/dn`; given
//! termination, `d depth = lambda_z dL_z/dz * z_scale / o` and `d opacity = -lambda_z
//! dL_z/dz * z / o` with `o = max(opacity, OPACITY_FLOOR)` (0 below the floor). The renderer's
//! backward takes these through the weights (to density) and, for the normals, to the
//! per-sample analytic normals, whose backward in the field is second order.
//!
//! Invariants: the kernel only *adds* to `d_rays` (the photometric loss writes first);
//! it reads the forward outputs of the same batch; `n_rays = 4 * n_patches`.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::RayOutput;
pub use super::depth_estimate::{DepthEstimate, OPACITY_FLOOR};
use super::depth_normal::{DepthNormalResidual, DepthNormalTerm};
use super::planarity::PlanarityTerm;

const SPEC: KernelSpec = KernelSpec {
    file: "loss/edge_reg.wgsl",
    entry: "edge_reg",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

/// Which definition of the losses (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegVariant {
    /// The paper's equations: hinges on both losses, gradients through the means.
    #[default]
    Paper,
    /// The authors' code: stop-gradient means, squared normal error without hinge
    /// averaged over pixels and components, `lambda3 = 0.01`.
    Official,
}

/// What `L_z` pulls a non-edge patch's depths toward (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthTarget {
    /// The patch mean (the paper and the authors' code): fronto-parallel patches.
    #[default]
    Mean,
    /// Any plane: the 2x2 patch's second difference.
    Plane,
}

/// Bounds of the planarity settings: the triplet rays are allocated with the batch.
pub const MAX_PLANARITY_TRIPLETS: u32 = 1 << 16;
pub const MAX_PLANARITY_STRIDE: u32 = 1024;

/// The regularizers' settings in a run configuration (`[reg]`).
///
/// Defaults are the paper's (section 4.1): `lambda2 = 0.1`, `tau1 = 1e-4`, `tau2 = 0`,
/// `lambda3 = 0.1`, or `0.001` on DTU scenes; the official variant's `lambda3` is the
/// authors' `0.01`. The weights ramp linearly from 0 at `start_step` to full at
/// `start_step + warmup_steps` (0: full weight from `start_step`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegConfig {
    /// Edge-guided depth regularization `L_z`.
    pub depth: bool,
    /// Edge-guided normal regularization `L_n` (needs analytic normals and the
    /// second-order backward: the costlier of the two).
    pub normal: bool,
    pub variant: RegVariant,
    /// `lambda2`.
    pub lambda_depth: f32,
    /// `lambda3`; `None`: the variant's default (see the type doc).
    pub lambda_normal: Option<f32>,
    /// `tau1` (depth tolerance, in the units of the regularized depth).
    pub tau_depth: f32,
    /// `tau2` (paper variant only; the official `L_n` has no hinge).
    pub tau_normal: f32,
    /// What `L_z` pulls toward: the patch mean (the paper) or any plane.
    pub depth_target: DepthTarget,
    /// Which depth `L_z` regularizes: the expected depth (the paper) or the depth
    /// given termination (the authors' code).
    pub depth_estimate: DepthEstimate,
    pub start_step: u64,
    pub warmup_steps: u64,
    /// `lambda1`, the weight of the photometric `L_c` (the paper: 1).
    pub lambda_color: f32,
    /// Weight of the edge-guided depth-normal consistency ([`super::depth_normal`]) on
    /// the same patches and schedule (0: off). A normal regularizer: `normal = false`
    /// switches it off with `L_n`, so `--no-depth-reg --no-normal-reg` is no
    /// regularizer with any preset.
    pub lambda_depth_normal: f32,
    /// Its per-ray residual: `dot` (`1 - <n, n_d>`, 2DGS), `direction`
    /// (`|n| - <n, n_d>`) or `per_sample` (`opacity - <n, n_d>`); the last two do not
    /// reward opacity ([`super::depth_normal`]).
    pub depth_normal_residual: DepthNormalResidual,
    /// Exponent of `L_dn`'s coherence gate (0: none; [`super::depth_normal`]).
    pub depth_normal_coherence: f32,
    /// Weight of the edge-guided planarity `L_pl` ([`super::planarity`]) on triplets of
    /// pixels inside non-edge regions, on the same schedule (0: off). A depth
    /// regularizer: `depth = false` switches it off with `L_z`.
    pub lambda_planarity: f32,
    /// Triplets a step draws for it (3 rays each, appended to the batch with zero
    /// photometric weight).
    pub planarity_triplets: u32,
    /// The largest spacing of a triplet's pixels, in pixels (spacings are uniform in
    /// `1..=max`; a triplet spans twice its spacing).
    pub planarity_max_stride: u32,
    /// Scale `c` of `L_pl`'s robust penalty (0: L1; [`super::planarity`]).
    pub planarity_scale: f32,
    /// Exponent of `L_pl`'s coherence gate (0: none; [`super::planarity`]).
    pub planarity_coherence: f32,
    /// Largest colour variation (per channel, max - min, in [0, 1]) a triplet's segment
    /// may have in its training image (0: any): `L_pl` only where the colour is flat
    /// ([`crate::train::rays::random_triplets`]).
    pub planarity_color_range: f32,
    /// Weight of the cross-view photometric consistency of the rendered depth
    /// ([`super::reprojection`]) on the batch's photometric rays, on the same schedule
    /// (0: off). A depth regularizer: `depth = false` switches it off with `L_z`.
    pub lambda_reprojection: f32,
    /// Scale `delta` of its Charbonnier penalty, in colour units.
    pub reprojection_delta: f32,
    /// Standard deviation (pixels) of the Gaussian blur of the images it compares (0:
    /// none): its reach in disparity.
    pub reprojection_blur: f32,
}

impl Default for RegConfig {
    fn default() -> Self {
        Self {
            depth: true,
            normal: true,
            variant: RegVariant::Paper,
            lambda_depth: 0.1,
            lambda_normal: None,
            tau_depth: 1e-4,
            tau_normal: 0.0,
            depth_target: DepthTarget::Mean,
            depth_estimate: DepthEstimate::Expected,
            start_step: 0,
            warmup_steps: 0,
            lambda_color: 1.0,
            lambda_depth_normal: 0.0,
            depth_normal_residual: DepthNormalResidual::Dot,
            depth_normal_coherence: 0.0,
            lambda_planarity: 0.0,
            planarity_triplets: 256,
            planarity_max_stride: 16,
            planarity_scale: 0.0,
            planarity_coherence: 0.0,
            planarity_color_range: 0.0,
            lambda_reprojection: 0.0,
            reprojection_delta: 0.02,
            reprojection_blur: 0.0,
        }
    }
}

impl RegConfig {
    /// `lambda3` in effect: the configured one, else the variant's default.
    pub fn lambda_normal_for(&self, dtu_scene: bool) -> f32 {
        self.lambda_normal.unwrap_or(match self.variant {
            RegVariant::Paper if dtu_scene => 0.001,
            RegVariant::Paper => 0.1,
            RegVariant::Official => 0.01,
        })
    }

    /// Whether any term is switched on (with a nonzero weight).
    pub fn any(&self, dtu_scene: bool) -> bool {
        (self.depth && self.lambda_depth > 0.0)
            || (self.normal && self.lambda_normal_for(dtu_scene) > 0.0)
            || (self.normal && self.lambda_depth_normal > 0.0)
            || self.planarity_on()
            || self.reprojection_on()
    }

    /// Whether the reprojection term runs (weight above 0 with `L_z`'s switch on).
    pub fn reprojection_on(&self) -> bool {
        self.depth && self.lambda_reprojection > 0.0
    }

    /// Whether the planarity term runs (weight above 0 with `L_z`'s switch on).
    pub fn planarity_on(&self) -> bool {
        self.depth && self.lambda_planarity > 0.0 && self.planarity_triplets > 0
    }

    /// Triplets a step's batch carries for the planarity term (0 when it is off).
    pub fn planarity_triplets_per_step(&self) -> u32 {
        if self.planarity_on() { self.planarity_triplets } else { 0 }
    }

    /// The weights of step `step` (schedule applied), `None` when nothing is active.
    pub fn weights_at(&self, step: u64, dtu_scene: bool) -> Option<EdgeRegWeights> {
        if step < self.start_step {
            return None;
        }
        let ramp = if self.warmup_steps == 0 {
            1.0
        } else {
            (((step - self.start_step) + 1) as f64 / self.warmup_steps as f64).min(1.0) as f32
        };
        let w = EdgeRegWeights {
            variant: self.variant,
            lambda_depth: if self.depth { ramp * self.lambda_depth } else { 0.0 },
            lambda_normal: if self.normal { ramp * self.lambda_normal_for(dtu_scene) } else { 0.0 },
            tau_depth: self.tau_depth,
            tau_normal: self.tau_normal,
            depth_target: self.depth_target,
            depth_estimate: self.depth_estimate,
            lambda_depth_normal: if self.normal { ramp * self.lambda_depth_normal } else { 0.0 },
            depth_normal_residual: self.depth_normal_residual,
            depth_normal_coherence: self.depth_normal_coherence,
            lambda_planarity: if self.planarity_on() { ramp * self.lambda_planarity } else { 0.0 },
            planarity_scale: self.planarity_scale,
            planarity_coherence: self.planarity_coherence,
            lambda_reprojection: if self.reprojection_on() { ramp * self.lambda_reprojection } else { 0.0 },
            reprojection_delta: self.reprojection_delta,
        };
        let any = [w.lambda_depth, w.lambda_normal, w.lambda_depth_normal, w.lambda_planarity, w.lambda_reprojection];
        any.iter().any(|&l| l > 0.0).then_some(w)
    }

    pub fn validate(&self) -> Result<(), String> {
        let values = [
            ("lambda_depth", Some(self.lambda_depth)),
            ("lambda_normal", self.lambda_normal),
            ("lambda_color", Some(self.lambda_color)),
            ("lambda_depth_normal", Some(self.lambda_depth_normal)),
            ("depth_normal_coherence", Some(self.depth_normal_coherence)),
            ("tau_depth", Some(self.tau_depth)),
            ("tau_normal", Some(self.tau_normal)),
            ("lambda_planarity", Some(self.lambda_planarity)),
            ("planarity_scale", Some(self.planarity_scale)),
            ("planarity_coherence", Some(self.planarity_coherence)),
            ("planarity_color_range", Some(self.planarity_color_range)),
            ("lambda_reprojection", Some(self.lambda_reprojection)),
            ("reprojection_delta", Some(self.reprojection_delta)),
            ("reprojection_blur", Some(self.reprojection_blur)),
        ];
        for (key, v) in values {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err(format!("reg.{key} = {v}: weights and thresholds must be finite and >= 0"));
            }
        }
        if self.reprojection_delta <= 0.0 {
            return Err(format!("reg.reprojection_delta = {}: the Charbonnier scale must be > 0", self.reprojection_delta));
        }
        if self.planarity_triplets > MAX_PLANARITY_TRIPLETS {
            return Err(format!("reg.planarity_triplets = {} must be at most {MAX_PLANARITY_TRIPLETS}", self.planarity_triplets));
        }
        if self.planarity_on() && !(1..=MAX_PLANARITY_STRIDE).contains(&self.planarity_max_stride) {
            return Err(format!("reg.planarity_max_stride = {} must lie in 1..={MAX_PLANARITY_STRIDE} pixels", self.planarity_max_stride));
        }
        Ok(())
    }
}

/// Weights and thresholds of one launch (the trainer applies the schedule).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeRegWeights {
    pub variant: RegVariant,
    /// `lambda2` of `L_z` (0: off).
    pub lambda_depth: f32,
    /// `lambda3` of `L_n` (0: off).
    pub lambda_normal: f32,
    /// `tau1`, `tau2`.
    pub tau_depth: f32,
    pub tau_normal: f32,
    pub depth_target: DepthTarget,
    pub depth_estimate: DepthEstimate,
    /// The depth-normal consistency's weight (0: off), on the same patches.
    pub lambda_depth_normal: f32,
    pub depth_normal_residual: DepthNormalResidual,
    pub depth_normal_coherence: f32,
    /// The planarity term's weight (0: off), on the batch's triplets, and its robust
    /// scale (0: L1).
    pub lambda_planarity: f32,
    pub planarity_scale: f32,
    /// Its coherence gate's exponent (0: none).
    pub planarity_coherence: f32,
    /// The reprojection term's weight (0: off) and its Charbonnier scale.
    pub lambda_reprojection: f32,
    pub reprojection_delta: f32,
}

impl EdgeRegWeights {
    /// The depth-normal consistency's launch settings, `None` when its weight is 0.
    pub fn depth_normal_term(&self) -> Option<DepthNormalTerm> {
        (self.lambda_depth_normal > 0.0).then_some(DepthNormalTerm {
            lambda: self.lambda_depth_normal,
            estimate: self.depth_estimate,
            residual: self.depth_normal_residual,
            coherence_power: self.depth_normal_coherence,
        })
    }

    /// The planarity term's launch settings, `None` when its weight is 0.
    pub fn planarity_term(&self) -> Option<PlanarityTerm> {
        (self.lambda_planarity > 0.0).then_some(PlanarityTerm {
            lambda: self.lambda_planarity,
            scale: self.planarity_scale,
            coherence_power: self.planarity_coherence,
        })
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_patches: u32,
    official: u32,
    depth_plane: u32,
    depth_given_termination: u32,
    lambda_depth: f32,
    lambda_normal: f32,
    tau_depth: f32,
    tau_normal: f32,
    opacity_floor: f32,
    _pad: [u32; 3],
}

/// The unweighted loss values of one launch.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct EdgeRegLosses {
    pub depth: f32,
    pub normal: f32,
}

/// The regularizer kernel, its per-ray inputs and per-patch losses.
pub struct EdgeReg {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Per ray `(e, z_scale)`, written by the caller.
    pub pixel: GpuBuffer<[f32; 2]>,
    /// Per patch `(L_z, L_n)` contributions of the last launch.
    pub patch_loss: GpuBuffer<[f32; 2]>,
}

impl EdgeReg {
    pub fn new(gpu: &Gpu, max_patches: u32) -> Result<Self, GpuError> {
        let n = max_patches.max(1) as usize;
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            pixel: GpuBuffer::zeros(gpu, "edge reg pixels", 4 * n)?,
            patch_loss: GpuBuffer::zeros(gpu, "edge reg patch losses", n)?,
        })
    }

    /// Records the losses of `n_patches` patches (`rays[..4 n_patches]`, with
    /// [`EdgeReg::pixel`] filled), adding their gradients into `d_rays`.
    pub fn record(
        &self,
        enc: &mut Encoder,
        rays: &GpuBuffer<RayOutput>,
        d_rays: &GpuBuffer<RayOutput>,
        n_patches: u32,
        w: &EdgeRegWeights,
    ) {
        let n_rays = 4 * n_patches as usize;
        assert!(rays.len() >= n_rays && d_rays.len() >= n_rays && self.pixel.len() >= n_rays);
        assert!(self.patch_loss.len() >= n_patches as usize, "edge reg buffers for {} patches", self.patch_loss.len());
        let params = enc.params(&Params {
            n_patches,
            official: (w.variant == RegVariant::Official) as u32,
            depth_plane: (w.depth_target == DepthTarget::Plane) as u32,
            depth_given_termination: (w.depth_estimate == DepthEstimate::GivenTermination) as u32,
            lambda_depth: w.lambda_depth,
            lambda_normal: w.lambda_normal,
            tau_depth: w.tau_depth,
            tau_normal: w.tau_normal,
            opacity_floor: OPACITY_FLOOR,
            _pad: [0; 3],
        });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &rays.buffer, &self.pixel.buffer, &d_rays.buffer, &self.patch_loss.buffer],
            n_patches,
        );
    }

    /// `L_z` and `L_n` of the last launch over `n_patches` (waits for the GPU).
    pub fn losses(&self, gpu: &Gpu, n_patches: u32) -> Result<EdgeRegLosses, GpuError> {
        Ok(Self::losses_of(&self.patch_loss.read(gpu)?[..n_patches as usize]))
    }

    /// `L_z` and `L_n` from the per-patch terms (`patch_loss`'s first `n_patches`, read
    /// back).
    pub fn losses_of(per_patch: &[[f32; 2]]) -> EdgeRegLosses {
        let (mut d, mut n) = (0.0f64, 0.0f64);
        for p in per_patch {
            d += p[0] as f64;
            n += p[1] as f64;
        }
        EdgeRegLosses { depth: d as f32, normal: n as f32 }
    }
}

/// `f64` CPU reference of the losses and their gradients (tests; documentation of the
/// kernel in plain Rust).
pub mod reference {
    use super::{DepthEstimate, DepthTarget, OPACITY_FLOOR, RegVariant};

    /// One ray of a patch as the losses see it.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct PatchRay {
        pub e: f64,
        pub z_scale: f64,
        pub depth: f64,
        pub opacity: f64,
        pub normal: [f64; 3],
    }

    /// What the losses regularize: the depth estimate and the target.
    #[derive(Clone, Copy, Debug)]
    pub struct Setting {
        pub variant: RegVariant,
        pub target: DepthTarget,
        pub estimate: DepthEstimate,
        pub tau_depth: f64,
        pub tau_normal: f64,
    }

    /// The gradients of one ray's losses: `dL_z/d depth`, `dL_z/d opacity`, `dL_n/d normal`.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct RayGrad {
        pub depth: f64,
        pub opacity: f64,
        pub normal: [f64; 3],
    }

    /// The regularized depth `z` of a ray and its derivatives `(dz/d depth, dz/d opacity)`.
    pub fn regularized_depth(r: &PatchRay, estimate: DepthEstimate) -> (f64, f64, f64) {
        match estimate {
            DepthEstimate::Expected => (r.depth * r.z_scale, r.z_scale, 0.0),
            DepthEstimate::GivenTermination => {
                let floor = OPACITY_FLOOR as f64;
                let o = r.opacity.max(floor);
                let z = r.depth * r.z_scale / o;
                (z, r.z_scale / o, if r.opacity > floor { -z / o } else { 0.0 })
            }
        }
    }

    /// Per patch `(zbar, nbar)` of `rays` (a multiple of 4); `None` for all-edge patches.
    pub fn patch_means(rays: &[PatchRay], estimate: DepthEstimate) -> Vec<Option<(f64, [f64; 3])>> {
        rays.chunks(4)
            .map(|patch| {
                let s: f64 = patch.iter().map(|r| r.e).sum();
                (s > 0.0).then(|| {
                    let z_bar = patch.iter().map(|r| r.e * regularized_depth(r, estimate).0).sum::<f64>() / s;
                    let n_bar = [0, 1, 2].map(|c| patch.iter().map(|r| r.e * r.normal[c]).sum::<f64>() / s);
                    (z_bar, n_bar)
                })
            })
            .collect()
    }

    /// `(L_z, L_n)` of `rays` (a multiple of 4) and their gradients per ray.
    pub fn losses(rays: &[PatchRay], setting: &Setting) -> ((f64, f64), Vec<RayGrad>) {
        losses_given_means(rays, &patch_means(rays, setting.estimate), setting)
    }

    /// [`losses`] with the patch means given: with the means of other rays held fixed,
    /// finite differences of this reproduce the stop-gradient of the official variant.
    pub fn losses_given_means(rays: &[PatchRay], means: &[Option<(f64, [f64; 3])>], setting: &Setting) -> ((f64, f64), Vec<RayGrad>) {
        assert_eq!(rays.len() % 4, 0);
        let Setting { variant, target, estimate, tau_depth, tau_normal } = *setting;
        let m = (rays.len() / 4) as f64;
        let official = variant == RegVariant::Official;
        let norm_n = if official { 1.0 / (12.0 * m) } else { 1.0 / m };
        let (mut lz, mut ln) = (0.0, 0.0);
        let mut grads = vec![RayGrad::default(); rays.len()];
        for (p, patch) in rays.chunks(4).enumerate() {
            let Some((z_bar, n_bar)) = means[p] else { continue };
            let s: f64 = patch.iter().map(|r| r.e).sum();
            let z: Vec<(f64, f64, f64)> = patch.iter().map(|r| regularized_depth(r, estimate)).collect();
            let mut g = [0.0; 4];
            let mut gn = [[0.0; 3]; 4];
            let plane = target == DepthTarget::Plane;
            if plane {
                let all_non_edge: f64 = patch.iter().map(|r| r.e).product();
                let second_difference = z[0].0 - z[1].0 - z[2].0 + z[3].0;
                let hz = all_non_edge * second_difference.abs() - tau_depth;
                if hz > 0.0 {
                    lz += hz;
                    let sign = all_non_edge * second_difference.signum();
                    g = [sign, -sign, -sign, sign];
                }
            }
            for (i, r) in patch.iter().enumerate() {
                let hz = r.e * (z[i].0 - z_bar).abs() - tau_depth;
                if !plane && hz > 0.0 {
                    lz += hz;
                    g[i] = r.e * (z[i].0 - z_bar).signum();
                }
                let dn: Vec<f64> = (0..3).map(|c| r.normal[c] - n_bar[c]).collect();
                let sq = r.e * dn.iter().map(|d| d * d).sum::<f64>();
                if official || sq - tau_normal > 0.0 {
                    ln += if official { sq } else { sq - tau_normal };
                    for c in 0..3 {
                        gn[i][c] = 2.0 * r.e * dn[c];
                    }
                }
            }
            let g_sum: f64 = g.iter().sum();
            let gn_sum: Vec<f64> = (0..3).map(|c| gn.iter().map(|v| v[c]).sum()).collect();
            for (i, r) in patch.iter().enumerate() {
                let (mut dz, mut dn) = (g[i], gn[i]);
                if !official && !plane {
                    dz -= r.e / s * g_sum;
                }
                if !official {
                    for c in 0..3 {
                        dn[c] -= r.e / s * gn_sum[c];
                    }
                }
                let (_, dz_ddepth, dz_dopacity) = z[i];
                grads[4 * p + i] = RayGrad { depth: dz / m * dz_ddepth, opacity: dz / m * dz_dopacity, normal: dn.map(|v| v * norm_n) };
            }
        }
        ((lz / m, ln * norm_n), grads)
    }
}

#[cfg(test)]
mod tests;

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/edge_reg.wgsl", "Params", [n_patches, official, depth_plane, depth_given_termination, lambda_depth, lambda_normal, tau_depth, tau_normal, opacity_floor]);
    }
}
