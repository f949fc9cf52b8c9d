//! The stereo depth prior: each photometric ray's depth given termination pulled toward
//! the depth that plane-sweep stereo over the training views found at its pixel
//! (`crate::train::stereo` computes those targets once, on the host). Owner of
//! `kernels/loss/stereo_depth.wgsl` and its `f64` reference ([`reference`]).
//!
//! The reprojection term ([`super::reprojection`]) asks the same question of the
//! photographs, but only about a pixel around the depth the field has: a surface the
//! field put 10 % too near never feels it. A sweep over the whole depth range finds the
//! depth where the views agree wherever the colour varies (DS-NeRF's depth supervision,
//! with the depth from classical stereo instead of COLMAP's points).
//!
//! # The loss
//! For photometric ray `k` with drop weight `w_k`, stereo target `(t*_k, c_k)` (`c_k` the
//! target's confidence, 0 where stereo found none), rendered `depth` and `opacity`:
//! ```text
//! t   = depth / max(opacity, eps)          m_k = c_k w_k opacity_k   (constant)
//! L   = lambda / n sum_k m_k rho((t - t*_k) / t*_k)        rho(r) = sqrt(r^2 + delta^2) - delta
//! ```
//! The relative error makes the term independent of the scene's units; the Charbonnier
//! `rho` is L1 past `delta`, so a wrong stereo depth pulls no harder than a right one.
//! `m_k` holds the term off transparent rays and is not differentiated: the term
//! moves depth, never opacity for its own sake.
//!
//! # Gradients (added to `dL/d RayOutput`)
//! ```text
//! g = lambda / n m_k rho'(r) / t*_k          d depth += g / A     d opacity -= g t / A (opacity > eps)
//! ```
//! with `A = max(opacity, eps)`.
//!
//! Invariants: the kernel only *adds* to `d_rays` (the photometric loss writes first);
//! it reads rays `0 .. n` of the batch (the photometric rays).

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::RayOutput;

// `eps` of the division by the opacity: the reprojection term's, whose depth given
// termination this term reads the same way.
use super::reprojection::OPACITY_EPS;

const SPEC: KernelSpec = KernelSpec {
    file: "loss/stereo_depth.wgsl",
    entry: "stereo_depth",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_rays: u32,
    scale: f32,
    delta: f32,
    eps: f32,
}

/// The kernel, each photometric ray's stereo target and its per-ray loss terms.
pub struct StereoDepth {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Per photometric ray: `(t*, c)`, written by the caller (`c = 0`: no target).
    pub targets: GpuBuffer<[f32; 2]>,
    /// Per photometric ray: its term (lambda and the batch mean included).
    pub ray_loss: GpuBuffer<f32>,
}

impl StereoDepth {
    /// The term over batches of up to `max_rays` photometric rays.
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, GpuError> {
        let n = max_rays.max(1) as usize;
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            targets: GpuBuffer::zeros(gpu, "stereo depth targets", n)?,
            ray_loss: GpuBuffer::zeros(gpu, "stereo depth ray losses", n)?,
        })
    }

    /// Records the term over rays `0 .. n_rays` (`outs` their outputs, `targets` their
    /// colours and drop weights, [`StereoDepth::targets`] filled), adding its gradient
    /// into `d_rays`; `lambda` its weight, `delta` the Charbonnier scale.
    #[allow(clippy::too_many_arguments)]
    pub fn record(&self, enc: &mut Encoder, outs: &GpuBuffer<RayOutput>, targets: &GpuBuffer<[f32; 4]>, d_rays: &GpuBuffer<RayOutput>, n_rays: u32, lambda: f32, delta: f32) {
        let n = n_rays as usize;
        assert!(outs.len() >= n && targets.len() >= n && d_rays.len() >= n);
        assert!(self.targets.len() >= n, "stereo depth buffers for {} rays", self.targets.len());
        let params = enc.params(&Params { n_rays, scale: lambda / n_rays.max(1) as f32, delta, eps: OPACITY_EPS });
        enc.dispatch_threads(&self.kernel, &[&params, &outs.buffer, &targets.buffer, &self.targets.buffer, &d_rays.buffer, &self.ray_loss.buffer], n_rays);
    }

    /// The loss of the last launch over `n_rays` (waits for the GPU).
    pub fn loss(&self, gpu: &Gpu, n_rays: u32) -> Result<f32, GpuError> {
        super::sum_of_terms(gpu, &self.ray_loss, n_rays)
    }
}

/// `f64` CPU reference of the loss (tests).
pub mod reference {
    use super::OPACITY_EPS;

    /// `L` of the module doc over rays `(depth, opacity, w, t*, c)`, with each ray's
    /// weight `m_k` taken at `opacity_for_m[k]` (held constant under differentiation).
    pub fn loss(rays: &[(f64, f64, f64, f64, f64)], opacity_for_m: &[f64], lambda: f64, delta: f64) -> f64 {
        let n = rays.len().max(1) as f64;
        rays.iter()
            .zip(opacity_for_m)
            .map(|(&(depth, opacity, w, t_star, c), &o_m)| {
                let m = c * w * o_m;
                if !(m > 0.0 && t_star > 0.0) {
                    return 0.0;
                }
                let t = depth / opacity.max(OPACITY_EPS as f64);
                let r = (t - t_star) / t_star;
                lambda / n * m * ((r * r + delta * delta).sqrt() - delta)
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences_of_the_reference() {
        let gpu = crate::gpu::test_gpu(false);
        // (depth, opacity, drop weight, t*, confidence): near and far of the target, on
        // it, without a target, dropped, and nearly transparent.
        let rays: Vec<(f64, f64, f64, f64, f64)> = vec![
            (1.8, 0.9, 1.0, 2.5, 1.0),
            (2.4, 0.8, 1.0, 2.0, 0.5),
            (2.0, 1.0, 1.0, 2.0, 1.0),
            (1.0, 0.7, 1.0, 0.0, 0.0),
            (1.0, 0.7, 0.0, 2.0, 1.0),
            (0.02, 0.01, 1.0, 2.0, 1.0),
            (3.05, 0.99, 1.0, 3.0, 1.0),
        ];
        let (lambda, delta) = (0.7f64, 0.01f64);
        let n = rays.len() as u32;
        let outs: Vec<RayOutput> =
            rays.iter().map(|r| RayOutput { rgb: [0.3; 3], opacity: r.1 as f32, normal: [0.0; 3], depth: r.0 as f32 }).collect();
        let targets: Vec<[f32; 4]> = rays.iter().map(|r| [0.5, 0.5, 0.5, r.2 as f32]).collect();
        let stereo: Vec<[f32; 2]> = rays.iter().map(|r| [r.3 as f32, r.4 as f32]).collect();
        let term = StereoDepth::new(&gpu, n).unwrap();
        term.targets.write(&gpu, &stereo);
        let outs_buf = GpuBuffer::from_slice(&gpu, "outs", &outs).unwrap();
        let targets_buf = GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap();
        // The kernel adds: start from a known gradient.
        let base = vec![RayOutput { rgb: [0.1; 3], opacity: 0.2, normal: [0.0; 3], depth: -0.3 }; n as usize];
        let d = GpuBuffer::from_slice(&gpu, "d", &base).unwrap();
        let mut enc = gpu.encoder();
        term.record(&mut enc, &outs_buf, &targets_buf, &d, n, lambda as f32, delta as f32);
        enc.submit();
        let got = d.read(&gpu).unwrap();
        let o_m: Vec<f64> = rays.iter().map(|r| r.1).collect();
        let want_loss = reference::loss(&rays, &o_m, lambda, delta);
        let got_loss = term.loss(&gpu, n).unwrap() as f64;
        assert!((got_loss - want_loss).abs() < 1e-5 * want_loss.max(1.0), "loss {got_loss} vs {want_loss}");
        for k in 0..rays.len() {
            let fd = |field: usize| {
                let h = 1e-6;
                let (mut plus, mut minus) = (rays.clone(), rays.clone());
                if field == 0 {
                    plus[k].0 += h;
                    minus[k].0 -= h;
                } else {
                    plus[k].1 += h;
                    minus[k].1 -= h;
                }
                (reference::loss(&plus, &o_m, lambda, delta) - reference::loss(&minus, &o_m, lambda, delta)) / (2.0 * h)
            };
            let (dd, dop) = (got[k].depth as f64 - base[k].depth as f64, got[k].opacity as f64 - base[k].opacity as f64);
            let (fd_d, fd_o) = (fd(0), fd(1));
            assert!((dd - fd_d).abs() < 2e-4 * fd_d.abs().max(1.0), "ray {k}: d depth {dd} vs {fd_d}");
            assert!((dop - fd_o).abs() < 2e-4 * fd_o.abs().max(1.0), "ray {k}: d opacity {dop} vs {fd_o}");
            assert_eq!(got[k].rgb, base[k].rgb, "ray {k}: the term leaves the colour gradient");
        }
        // No target, a dropped ray: nothing added; a depth short of its target is pulled out.
        assert_eq!((got[3].depth, got[4].depth), (base[3].depth, base[4].depth));
        assert!(got[0].depth < base[0].depth, "a depth short of t* gets a negative gradient (moves out)");
        assert!(got[1].depth > base[1].depth);
    }
}

/// The `#[repr(C)]` mirror of this file against its WGSL struct (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/stereo_depth.wgsl", "Params", [n_rays, scale, delta, eps]);
    }
}
