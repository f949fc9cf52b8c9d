//! Photometric loss `L_c` (the paper's colour term): the weighted mean squared error
//! over rays and RGB channels,
//! `L_c = sum_r w_r |c_r - c*_r|^2 / (3 sum_r w_r)`, so `dL/dc_r = 2 w_r (c_r - c*_r) / (3 sum w)`.
//! PSNR of a batch is `-10 log10(L_c)` (with unit weights).
//!
//! Random backgrounds (scenes with alpha): the images were composited over one colour
//! when loaded (`loaded_over`); the renderer draws a random background per ray and
//! stores it in [`RayAux::background`]. With [`Recomposite`] the kernel composites each
//! target with alpha onto that same background first,
//! `c* = c + (background - loaded_over) (1 - alpha)`, so the target and the render
//! agree on what lies behind the object (no host round trip of the backgrounds).
//!
//! Owner of `kernels/loss/photometric.wgsl`.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::{RayAux, RayOutput};

const SPEC: KernelSpec = KernelSpec {
    file: "loss/photometric.wgsl",
    entry: "photometric",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
        Binding::ReadOnly,
        Binding::ReadOnly,
    ],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_rays: u32,
    scale: f32,
    recomposite: u32,
    sparsity: f32,
    loaded_over: [f32; 3],
    entropy: f32,
}

/// The priors on each photometric ray's opacity `o_r`, as weights of batch means over
/// the rays (weights `w_r`); both 0 by default (off).
///
/// - `sparsity`: `L_sp = lambda_sp sum_r w_r o_r / sum_r w_r` (`priors.sparsity`), so
///   `dL/d o_r = lambda_sp w_r / sum w`.
/// - `entropy`: the binary entropy `L_H = lambda_H sum_r w_r H(o_r) / sum_r w_r`,
///   `H(o) = -o ln o - (1 - o) ln(1 - o)` (`priors.opacity_entropy`), so
///   `dL/d o_r = lambda_H w_r ln((1 - o_r) / o_r) / sum w`, taken at `o_r` clamped to
///   `[1e-4, 1 - 1e-4]`: each ray is pushed toward fully opaque or fully transparent,
///   whichever it is nearer.
///
/// Their values are not logged.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpacityPriors {
    pub sparsity: f32,
    pub entropy: f32,
}

/// Targets with alpha to composite onto the rendered backgrounds (module doc).
pub struct Recomposite<'a> {
    /// The renderer's side output of the rays being scored.
    pub aux: &'a GpuBuffer<RayAux>,
    /// Each target's alpha; 1 where the pixel is opaque or its image has none.
    pub alpha: &'a GpuBuffer<f32>,
    /// The colour the loaded images were composited over.
    pub loaded_over: [f32; 3],
}

/// The photometric loss kernel and its per-ray error buffer.
pub struct Photometric {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Weighted squared error per ray (sum over channels) of the last launch.
    pub sq_error: GpuBuffer<f32>,
    /// Bound in place of the recompositing inputs when there are none.
    placeholder_aux: GpuBuffer<RayAux>,
    placeholder_alpha: GpuBuffer<f32>,
}

impl Photometric {
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            sq_error: GpuBuffer::zeros(gpu, "photometric error", max_rays as usize)?,
            placeholder_aux: GpuBuffer::zeros(gpu, "photometric: no aux", 1)?,
            placeholder_alpha: GpuBuffer::zeros(gpu, "photometric: no alpha", 1)?,
        })
    }

    /// Records the loss of `rays[..n]` against `targets[..n]` (rgb + weight), writing
    /// `d_rays[..n]` (overwritten). `weight_sum` is the sum of the targets' weights;
    /// `lambda` scales the loss; `recomposite`: targets with alpha onto the rendered
    /// backgrounds first (module doc); `opacity`: the priors on each ray's opacity, whose
    /// gradients join `d_rays[..].opacity`.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        enc: &mut Encoder,
        rays: &GpuBuffer<RayOutput>,
        targets: &GpuBuffer<[f32; 4]>,
        recomposite: Option<&Recomposite>,
        d_rays: &GpuBuffer<RayOutput>,
        n: u32,
        weight_sum: f32,
        lambda: f32,
        opacity: OpacityPriors,
    ) {
        assert!(rays.len() >= n as usize && targets.len() >= n as usize && d_rays.len() >= n as usize);
        assert!(self.sq_error.len() >= n as usize, "photometric buffer for {} rays, batch of {n}", self.sq_error.len());
        if let Some(rc) = recomposite {
            assert!(rc.aux.len() >= n as usize && rc.alpha.len() >= n as usize, "recompositing inputs shorter than the batch");
        }
        let scale = if weight_sum > 0.0 { lambda / (3.0 * weight_sum) } else { 0.0 };
        let params = enc.params(&Params {
            n_rays: n,
            scale,
            recomposite: recomposite.is_some() as u32,
            sparsity: if weight_sum > 0.0 { opacity.sparsity / weight_sum } else { 0.0 },
            loaded_over: recomposite.map_or([0.0; 3], |rc| rc.loaded_over),
            entropy: if weight_sum > 0.0 { opacity.entropy / weight_sum } else { 0.0 },
        });
        let (aux, alpha) = recomposite.map_or((&self.placeholder_aux, &self.placeholder_alpha), |rc| (rc.aux, rc.alpha));
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &rays.buffer, &targets.buffer, &d_rays.buffer, &self.sq_error.buffer, &aux.buffer, &alpha.buffer],
            n,
        );
    }

    /// Mean squared error of the last launch over `n` rays with weights summing to
    /// `weight_sum` (waits for the GPU).
    pub fn mse(&self, gpu: &Gpu, n: usize, weight_sum: f32) -> Result<f32, GpuError> {
        Ok(Self::mse_of(&self.sq_error.read(gpu)?[..n], weight_sum))
    }

    /// Mean squared error from the per-ray squared errors (`sq_error`'s first `n`, read
    /// back) of rays with weights summing to `weight_sum`.
    pub fn mse_of(errors: &[f32], weight_sum: f32) -> f32 {
        let sum: f64 = errors.iter().map(|&e| e as f64).sum();
        if weight_sum > 0.0 { (sum / (3.0 * weight_sum as f64)) as f32 } else { 0.0 }
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
        loss.record(&mut enc, &rays_buf, &targets_buf, None, &d, n, weight_sum, 1.0, OpacityPriors::default());
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
            assert_eq!((grads[r].depth, grads[r].opacity), (0.0, 0.0));
        }
        // The opacity penalty: lambda_sp w_r / sum w on each ray's opacity, nothing else changed.
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, None, &d, n, weight_sum, 1.0, OpacityPriors { sparsity: 0.5, entropy: 0.0 });
        enc.submit();
        let with = d.read(&gpu).unwrap();
        for r in 0..n as usize {
            assert!((with[r].opacity - 0.5 * targets[r][3] / weight_sum).abs() < 1e-7, "ray {r}: {}", with[r].opacity);
            assert_eq!(with[r].rgb, grads[r].rgb);
        }
        // The opacity entropy against finite differences of L_H = lambda sum w H(o) / sum w,
        // at opacities from near 0 to near 1 (and one beyond the clamp).
        let opacities = [0.02f32, 0.3, 0.5, 0.71, 0.97, 1.0];
        let mut rays_o = rays.clone();
        for (r, ray) in rays_o.iter_mut().enumerate() {
            ray.opacity = opacities[r % opacities.len()];
        }
        let lambda_h = 0.2f64;
        let entropy_of = |o: f64| -o * o.ln() - (1.0 - o) * (1.0 - o).ln();
        let loss_h = |r: usize, o: f64| lambda_h * targets[r][3] as f64 * entropy_of(o) / weight_sum as f64;
        let rays_o_buf = GpuBuffer::from_slice(&gpu, "rays with opacity", &rays_o).unwrap();
        let mut enc = gpu.encoder();
        let priors = OpacityPriors { sparsity: 0.5, entropy: lambda_h as f32 };
        loss.record(&mut enc, &rays_o_buf, &targets_buf, None, &d, n, weight_sum, 1.0, priors);
        enc.submit();
        let with = d.read(&gpu).unwrap();
        for r in 0..n as usize {
            let o = rays_o[r].opacity as f64;
            let h = 1e-4;
            let d_entropy = if o >= 1.0 {
                // Beyond the clamp: the gradient at 1 - 1e-4 (pushing further toward opaque).
                lambda_h * targets[r][3] as f64 * (1e-4f64 / (1.0 - 1e-4)).ln() / weight_sum as f64
            } else {
                (loss_h(r, o + h) - loss_h(r, o - h)) / (2.0 * h)
            };
            let want = 0.5 * targets[r][3] as f64 / weight_sum as f64 + d_entropy;
            assert!((with[r].opacity as f64 - want).abs() < 1e-5 * (1.0 + want.abs()), "ray {r} at opacity {o}: {} vs {want}", with[r].opacity);
            if targets[r][3] > 0.0 {
                // Toward the nearer of 0 and 1: descent lowers an opacity under 1/2, raises one over.
                let d_entropy_gpu = with[r].opacity as f64 - 0.5 * targets[r][3] as f64 / weight_sum as f64;
                assert!(o == 0.5 || d_entropy_gpu.signum() == -(o - 0.5).signum(), "ray {r}: {d_entropy_gpu} at opacity {o}");
            }
        }
    }

    #[test]
    fn targets_with_alpha_are_composited_onto_the_rendered_background() {
        let gpu = crate::gpu::test_gpu(false);
        let loaded_over = [1.0f32, 1.0, 1.0];
        // Ray 0: a quarter-opaque pixel of foreground 0.2 loaded over white (0.8);
        // ray 1: no alpha; ray 2: opaque; ray 3: fully transparent.
        let targets: Vec<[f32; 4]> = vec![[0.8, 0.8, 0.8, 1.0], [0.3, 0.4, 0.5, 1.0], [0.9, 0.9, 0.9, 1.0], [1.0; 4]];
        let alpha = vec![0.25f32, 1.0, 1.0, 0.0];
        let backgrounds = [[0.0, 0.5, 1.0], [0.7, 0.1, 0.3], [0.2, 0.2, 0.9], [0.6, 0.3, 0.0]];
        let aux: Vec<RayAux> = backgrounds.iter().map(|&background| RayAux { background, ..Default::default() }).collect();
        let want: Vec<[f32; 3]> = vec![
            [0.25 * 0.2 + 0.75 * 0.0, 0.25 * 0.2 + 0.75 * 0.5, 0.25 * 0.2 + 0.75 * 1.0],
            [0.3, 0.4, 0.5],
            [0.9, 0.9, 0.9],
            [0.6, 0.3, 0.0],
        ];
        let rays: Vec<RayOutput> = (0..4).map(|i| RayOutput { rgb: [0.1 * i as f32, 0.5, 0.25], ..Default::default() }).collect();
        let loss = Photometric::new(&gpu, 4).unwrap();
        let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &rays).unwrap();
        let targets_buf = GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap();
        let aux_buf = GpuBuffer::from_slice(&gpu, "aux", &aux).unwrap();
        let alpha_buf = GpuBuffer::from_slice(&gpu, "alpha", &alpha).unwrap();
        let d = GpuBuffer::<RayOutput>::zeros(&gpu, "d", 4).unwrap();
        let rc = Recomposite { aux: &aux_buf, alpha: &alpha_buf, loaded_over };
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, Some(&rc), &d, 4, 4.0, 1.0, OpacityPriors::default());
        enc.submit();
        let grads = d.read(&gpu).unwrap();
        let mut sq = 0.0f64;
        for r in 0..4 {
            for c in 0..3 {
                let diff = rays[r].rgb[c] - want[r][c];
                sq += (diff as f64).powi(2);
                // dL/dc = 2 (c - c*) / (3 * 4): zero exactly where the render matches c*.
                assert!((grads[r].rgb[c] - 2.0 * diff / 12.0).abs() < 1e-6, "ray {r} channel {c}: {} vs {}", grads[r].rgb[c], 2.0 * diff / 12.0);
            }
        }
        let mse = loss.mse(&gpu, 4, 4.0).unwrap();
        assert!((mse as f64 - sq / 12.0).abs() < 1e-6, "{mse} vs {}", sq / 12.0);
        // Without recompositing the same call scores the targets as given.
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, None, &d, 4, 4.0, 1.0, OpacityPriors::default());
        enc.submit();
        assert!((d.read(&gpu).unwrap()[0].rgb[0] - 2.0 * (rays[0].rgb[0] - 0.8) / 12.0).abs() < 1e-6);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/photometric.wgsl", "Params", [n_rays, scale, recomposite, sparsity, loaded_over, entropy]);
    }
}
