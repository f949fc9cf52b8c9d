//! RegNeRF's depth smoothness regularizer: total variation of the rendered depth over
//! square patches (8x8 in RegNeRF) rendered from random unobserved poses. Owner of
//! `kernels/loss/depth_tv.wgsl` and its `f64` reference ([`reference`]).
//!
//! # The loss (RegNeRF's `compute_tv_norm`, `depth_tvnorm_type = 'l2'`)
//! A launch covers `P` patches of `ps x ps` rays, row-major within a patch. Per ray the
//! depth is RegNeRF's `distance_mean_save`: the expected ray parameter given that the
//! ray terminates, clipped to the ray's sample range, here along the camera axis:
//! ```text
//! z = z_scale clamp(depth / max(opacity, eps), t_min, t_max)      eps = 2^-23
//! L = 1 / (P (ps-1)^2) sum_patches sum_{i,j < ps-1} w_ij ((z_ij - z_i,j+1)^2 + (z_ij - z_i+1,j)^2)
//! ```
//! `depth = sum w_i t_i` and `opacity = sum w_i` are the renderer's outputs; `z_scale`
//! turns the ray parameter into the depth along the camera axis (RegNeRF's rays have
//! unnormalised directions with unit camera-z, so its `t` is this z-depth; 1 in NDC).
//! The mean runs over the `(ps-1)^2` top-left entries of each patch, as RegNeRF's
//! `v00 = values[:, :-1, :-1]` and `.mean()`: the last row's horizontal and the last
//! column's vertical differences are not included. `w_ij = acc_weight * opacity_ij`
//! (a constant of the backward pass: RegNeRF's `stop_gradient(acc) *
//! depth_tvnorm_mask_weight`, 1 in its DTU configs) when `acc_weight > 0`, else 1.
//! (RegNeRF's LLFF configs leave the mask weight at its default 0, which multiplied
//! literally would switch the term off; we read 0 as "no weighting", the paper's loss.)
//!
//! # Gradients (added to `dL/d RayOutput`)
//! `g_k = dL/dz_k` collects the terms where ray `k` is `v00`, `v01` or `v10`; then, where
//! the clamp is inactive (`t_min < depth / A < t_max`, `A = max(opacity, eps)`):
//! ```text
//! d depth   += lambda g_k z_scale / A
//! d opacity -= lambda g_k z_scale depth / A^2          (only where opacity > eps)
//! ```
//! and zero where the clamp is active. The renderer's backward takes both through the
//! weights into the densities, so the term reaches any [`crate::field::Field`].
//!
//! Invariants: the kernel only *adds* to `d_rays` (the photometric loss writes first);
//! it reads the forward outputs of the same batch and the rays' `[t_min, t_max]`; the
//! patch rays are a contiguous range `offset .. offset + P ps^2` of the batch.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::{GpuRay, RayOutput};

const SPEC: KernelSpec = KernelSpec {
    file: "loss/depth_tv.wgsl",
    entry: "depth_tv",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

/// `eps` of the division by the opacity (`jnp.finfo(jnp.float32).eps`, as RegNeRF).
pub const OPACITY_EPS: f32 = f32::EPSILON;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
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

/// The depth TV kernel, its per-ray inputs and per-ray loss terms.
pub struct DepthTv {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Per patch ray: `z_scale`, written by the caller.
    pub z_scale: GpuBuffer<f32>,
    /// Per patch ray: its terms as `v00` (normalized, lambda not included).
    pub ray_loss: GpuBuffer<f32>,
}

impl DepthTv {
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, GpuError> {
        let n = max_rays.max(1) as usize;
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            z_scale: GpuBuffer::zeros(gpu, "depth tv z scale", n)?,
            ray_loss: GpuBuffer::zeros(gpu, "depth tv ray losses", n)?,
        })
    }

    /// Records the loss of the patches of side `patch_size` in `outs[offset ..
    /// offset + n_rays]` (rendered from `rays[offset ..]`, with [`DepthTv::z_scale`]
    /// filled), adding `lambda` times its gradient into `d_rays`.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        enc: &mut Encoder,
        outs: &GpuBuffer<RayOutput>,
        rays: &GpuBuffer<GpuRay>,
        d_rays: &GpuBuffer<RayOutput>,
        offset: u32,
        n_rays: u32,
        patch_size: u32,
        lambda: f32,
        acc_weight: f32,
    ) {
        let end = (offset + n_rays) as usize;
        assert!(patch_size >= 2 && n_rays.is_multiple_of(patch_size * patch_size), "whole patches of side >= 2");
        assert!(outs.len() >= end && rays.len() >= end && d_rays.len() >= end);
        assert!(self.z_scale.len() >= n_rays as usize, "depth tv buffers for {} rays", self.z_scale.len());
        let params = enc.params(&Params { n_rays, offset, patch_size, _pad0: 0, lambda, acc_weight, eps: OPACITY_EPS, _pad1: 0.0 });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &outs.buffer, &rays.buffer, &self.z_scale.buffer, &d_rays.buffer, &self.ray_loss.buffer],
            n_rays,
        );
    }

    /// The loss of the last launch over `n_rays` (waits for the GPU).
    pub fn loss(&self, gpu: &Gpu, n_rays: u32) -> Result<f32, GpuError> {
        super::sum_of_terms(gpu, &self.ray_loss, n_rays)
    }
}

/// `f64` CPU reference of the loss and its gradients (tests; the kernel in plain Rust).
pub mod reference {
    use super::OPACITY_EPS;

    /// One patch ray as the loss sees it.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct TvRay {
        pub depth: f64,
        pub opacity: f64,
        pub z_scale: f64,
        pub t_min: f64,
        pub t_max: f64,
    }

    fn z(r: &TvRay) -> f64 {
        r.z_scale * (r.depth / r.opacity.max(OPACITY_EPS as f64)).clamp(r.t_min, r.t_max)
    }

    /// The constant per-ray weights of [`loss`] (`acc_weight * opacity`, or 1).
    pub fn weights(rays: &[TvRay], acc_weight: f64) -> Vec<f64> {
        rays.iter().map(|r| if acc_weight > 0.0 { acc_weight * r.opacity } else { 1.0 }).collect()
    }

    /// The loss of `rays` (whole patches of side `ps`) with the weights `w` held
    /// constant, and per ray `(dL/d depth, dL/d opacity)`.
    pub fn loss(rays: &[TvRay], ps: usize, w: &[f64]) -> (f64, Vec<(f64, f64)>) {
        let per = ps * ps;
        assert_eq!(rays.len() % per, 0);
        let norm = 1.0 / ((rays.len() / per) as f64 * ((ps - 1) * (ps - 1)) as f64);
        let mut g = vec![0.0; rays.len()];
        let mut total = 0.0;
        for p in 0..rays.len() / per {
            for i in 0..ps - 1 {
                for j in 0..ps - 1 {
                    let (k00, k01, k10) = (p * per + i * ps + j, p * per + i * ps + j + 1, p * per + (i + 1) * ps + j);
                    let (a, b) = (z(&rays[k00]) - z(&rays[k01]), z(&rays[k00]) - z(&rays[k10]));
                    total += w[k00] * (a * a + b * b);
                    g[k00] += 2.0 * w[k00] * (a + b);
                    g[k01] -= 2.0 * w[k00] * a;
                    g[k10] -= 2.0 * w[k00] * b;
                }
            }
        }
        let grads = rays
            .iter()
            .zip(&g)
            .map(|(r, &gk)| {
                let a = r.opacity.max(OPACITY_EPS as f64);
                let t = r.depth / a;
                if t <= r.t_min || t >= r.t_max {
                    return (0.0, 0.0);
                }
                let dz = norm * gk * r.z_scale;
                (dz / a, if r.opacity > OPACITY_EPS as f64 { -dz * t / a } else { 0.0 })
            })
            .collect();
        (total * norm, grads)
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
        crate::assert_wgsl_mirror!(Params, "loss/depth_tv.wgsl", "Params", [n_rays, offset, patch_size, lambda, acc_weight, eps]);
    }
}
