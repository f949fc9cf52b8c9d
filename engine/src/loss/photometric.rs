//! Photometric loss `L_c` (the paper's colour term): the weighted mean squared error
//! over rays and RGB channels,
//! `L_c = sum_r w_r |c_r - c*_r|^2 / (3 sum_r w_r)`, so `dL/dc_r = 2 w_r (c_r - c*_r) / (3 sum w)`.
//! PSNR of a batch is `-10 log10(L_c)` (with unit weights).
//!
//! Owner of `kernels/loss/photometric.wgsl`.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::samples::RayOutput;

const SPEC: KernelSpec = KernelSpec {
    file: "loss/photometric.wgsl",
    entry: "photometric",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_rays: u32,
    scale: f32,
    _pad: [u32; 2],
}

/// The photometric loss kernel and its per-ray error buffer.
pub struct Photometric {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Weighted squared error per ray (sum over channels) of the last launch.
    pub sq_error: GpuBuffer<f32>,
}

impl Photometric {
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, GpuError> {
        Ok(Self { kernel: gpu.kernel(&SPEC)?, sq_error: GpuBuffer::zeros(gpu, "photometric error", max_rays as usize)? })
    }

    /// Records the loss of `rays[..n]` against `targets[..n]` (rgb + weight), writing
    /// `d_rays[..n]` (overwritten). `weight_sum` is the sum of the targets' weights;
    /// `lambda` scales the loss.
    pub fn record(
        &self,
        enc: &mut Encoder,
        rays: &GpuBuffer<RayOutput>,
        targets: &GpuBuffer<[f32; 4]>,
        d_rays: &GpuBuffer<RayOutput>,
        n: u32,
        weight_sum: f32,
        lambda: f32,
    ) {
        assert!(rays.len() >= n as usize && targets.len() >= n as usize && d_rays.len() >= n as usize);
        assert!(self.sq_error.len() >= n as usize, "photometric buffer for {} rays, batch of {n}", self.sq_error.len());
        let scale = if weight_sum > 0.0 { lambda / (3.0 * weight_sum) } else { 0.0 };
        let params = enc.params(&Params { n_rays: n, scale, _pad: [0; 2] });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &rays.buffer, &targets.buffer, &d_rays.buffer, &self.sq_error.buffer],
            n,
        );
    }

    /// Mean squared error of the last launch over `n` rays with weights summing to
    /// `weight_sum` (waits for the GPU).
    pub fn mse(&self, gpu: &Gpu, n: usize, weight_sum: f32) -> Result<f32, GpuError> {
        let errors = self.sq_error.read(gpu)?;
        let sum: f64 = errors[..n].iter().map(|&e| e as f64).sum();
        Ok(if weight_sum > 0.0 { (sum / (3.0 * weight_sum as f64)) as f32 } else { 0.0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences_and_mse_is_the_mean() {
        let gpu = crate::gpu::test_gpu(false);
        let n = 37u32;
        let rays: Vec<RayOutput> = (0..n)
            .map(|i| {
                let f = i as f32;
                RayOutput { rgb: [(f * 0.37).sin().abs(), (f * 0.11).cos().abs(), 0.5], ..Default::default() }
            })
            .collect();
        let targets: Vec<[f32; 4]> =
            (0..n).map(|i| [0.3, 0.6, (i as f32 * 0.2).fract(), if i % 5 == 0 { 0.0 } else { 1.0 }]).collect();
        let weight_sum: f32 = targets.iter().map(|t| t[3]).sum();
        let loss_of = |rays: &[RayOutput]| -> f64 {
            let mut s = 0.0f64;
            for (r, t) in rays.iter().zip(&targets) {
                for c in 0..3 {
                    s += t[3] as f64 * ((r.rgb[c] - t[c]) as f64).powi(2);
                }
            }
            s / (3.0 * weight_sum as f64)
        };
        let loss = Photometric::new(&gpu, n).unwrap();
        let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &rays).unwrap();
        let targets_buf = GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap();
        let d = GpuBuffer::<RayOutput>::zeros(&gpu, "d", n as usize).unwrap();
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, &d, n, weight_sum, 1.0);
        enc.submit();
        let mse = loss.mse(&gpu, n as usize, weight_sum).unwrap();
        assert!((mse as f64 - loss_of(&rays)).abs() < 1e-6);
        let grads = d.read(&gpu).unwrap();
        let h = 1e-3f32;
        for r in [0usize, 1, 7, 36] {
            for c in 0..3 {
                let mut plus = rays.clone();
                plus[r].rgb[c] += h;
                let mut minus = rays.clone();
                minus[r].rgb[c] -= h;
                let fd = (loss_of(&plus) - loss_of(&minus)) / (2.0 * h as f64);
                assert!((grads[r].rgb[c] as f64 - fd).abs() < 1e-4, "ray {r} channel {c}: {} vs {fd}", grads[r].rgb[c]);
            }
            assert_eq!(grads[r].depth, 0.0);
        }
    }
}
