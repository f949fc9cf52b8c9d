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
    foreground: f32,
    fg_gate_scale: f32,
    _pad: [u32; 2],
}

/// The priors on each photometric ray's opacity `o_r`, as weights of batch means over
/// the rays (weights `w_r`); all 0 by default (off).
///
/// - `sparsity`: `L_sp = lambda_sp sum_r w_r o_r / sum_r w_r` (`priors.sparsity`), so
///   `dL/d o_r = lambda_sp w_r / sum w`.
/// - `entropy`: the binary entropy `L_H = lambda_H sum_r w_r H(o_r) / sum_r w_r`,
///   `H(o) = -o ln o - (1 - o) ln(1 - o)` (`priors.opacity_entropy`), so
///   `dL/d o_r = lambda_H w_r ln((1 - o_r) / o_r) / sum w`, taken at `o_r` clamped to
///   `[1e-4, 1 - 1e-4]`: each ray is pushed toward fully opaque or fully transparent,
///   whichever it is nearer.
/// - `foreground`: the foreground opacity prior
///   `L_f = lambda_f sum_r w_r g_r (1 - o_r) / sum_r w_r` (`priors.foreground_opacity`),
///   with the gate `g_r = 1 - exp(-|c*_r - b_r|^2 / (3 tol^2))` of the target `c*_r`
///   against the background `b_r` the renderer put behind the ray (`tol`:
///   `foreground_tolerance`), taken as a constant: `dL/d o_r = -lambda_f w_r g_r / sum w`.
///   A pixel the background cannot show (its colour far from what lies behind the ray)
///   is the object's, so its ray is pushed toward opaque: a translucent surface whose
///   darker colour blends with the backdrop into the photograph's grey would otherwise
///   fit the training views as well as an opaque one. Pixels that match the background
///   are left alone.
///
/// Their values are not logged.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpacityPriors {
    pub sparsity: f32,
    pub entropy: f32,
    pub foreground: f32,
    pub foreground_tolerance: f32,
}

/// Targets with alpha to composite onto the rendered backgrounds (module doc).
pub struct Recomposite<'a> {
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
    /// Bound in place of the targets' alpha when there is no recompositing.
    placeholder_alpha: GpuBuffer<f32>,
}

impl Photometric {
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            sq_error: GpuBuffer::zeros(gpu, "photometric error", max_rays as usize)?,
            placeholder_alpha: GpuBuffer::zeros(gpu, "photometric: no alpha", 1)?,
        })
    }

    /// Records the loss of `rays[..n]` against `targets[..n]` (rgb + weight), writing
    /// `d_rays[..n]` (overwritten). `weight_sum` is the sum of the targets' weights;
    /// `lambda` scales the loss; `aux`: the renderer's side output of the rays (its
    /// backgrounds), which recompositing and the foreground opacity prior need;
    /// `recomposite`: targets with alpha onto the rendered backgrounds first (module
    /// doc); `opacity`: the priors on each ray's opacity, whose gradients join
    /// `d_rays[..].opacity`.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        enc: &mut Encoder,
        rays: &GpuBuffer<RayOutput>,
        targets: &GpuBuffer<[f32; 4]>,
        aux: &GpuBuffer<RayAux>,
        recomposite: Option<&Recomposite>,
        d_rays: &GpuBuffer<RayOutput>,
        n: u32,
        weight_sum: f32,
        lambda: f32,
        opacity: OpacityPriors,
    ) {
        assert!(rays.len() >= n as usize && targets.len() >= n as usize && d_rays.len() >= n as usize);
        assert!(self.sq_error.len() >= n as usize, "photometric buffer for {} rays, batch of {n}", self.sq_error.len());
        assert!(aux.len() >= n as usize, "the rays' side output is shorter than the batch");
        if let Some(rc) = recomposite {
            assert!(rc.alpha.len() >= n as usize, "alpha shorter than the batch");
        }
        let per_ray = |weight: f32| if weight_sum > 0.0 { weight / weight_sum } else { 0.0 };
        let scale = if weight_sum > 0.0 { lambda / (3.0 * weight_sum) } else { 0.0 };
        let params = enc.params(&Params {
            n_rays: n,
            scale,
            recomposite: recomposite.is_some() as u32,
            sparsity: per_ray(opacity.sparsity),
            loaded_over: recomposite.map_or([0.0; 3], |rc| rc.loaded_over),
            entropy: per_ray(opacity.entropy),
            foreground: per_ray(opacity.foreground),
            fg_gate_scale: if opacity.foreground > 0.0 { 1.0 / (3.0 * opacity.foreground_tolerance.powi(2)) } else { 0.0 },
            _pad: [0; 2],
        });
        let alpha = recomposite.map_or(&self.placeholder_alpha, |rc| rc.alpha);
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
        // The rays' side output: zero backgrounds, read by neither recompositing nor the foreground prior here.
        let no_aux = GpuBuffer::<RayAux>::zeros(&gpu, "aux", n as usize).unwrap();
        let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &rays).unwrap();
        let targets_buf = GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap();
        let d = GpuBuffer::<RayOutput>::zeros(&gpu, "d", n as usize).unwrap();
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, &no_aux, None, &d, n, weight_sum, 1.0, OpacityPriors::default());
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
        loss.record(&mut enc, &rays_buf, &targets_buf, &no_aux, None, &d, n, weight_sum, 1.0, OpacityPriors { sparsity: 0.5, ..Default::default() });
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
        let priors = OpacityPriors { sparsity: 0.5, entropy: lambda_h as f32, ..Default::default() };
        loss.record(&mut enc, &rays_o_buf, &targets_buf, &no_aux, None, &d, n, weight_sum, 1.0, priors);
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
        let rc = Recomposite { alpha: &alpha_buf, loaded_over };
        let mut enc = gpu.encoder();
        loss.record(&mut enc, &rays_buf, &targets_buf, &aux_buf, Some(&rc), &d, 4, 4.0, 1.0, OpacityPriors::default());
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
        loss.record(&mut enc, &rays_buf, &targets_buf, &aux_buf, None, &d, 4, 4.0, 1.0, OpacityPriors::default());
        enc.submit();
        assert!((d.read(&gpu).unwrap()[0].rgb[0] - 2.0 * (rays[0].rgb[0] - 0.8) / 12.0).abs() < 1e-6);
    }

    #[test]
    fn the_foreground_prior_pushes_toward_opaque_where_the_background_cannot_show_the_pixel() {
        let gpu = crate::gpu::test_gpu(false);
        // Ray 0: the target is the background (gate 0); ray 1: a red object over a white
        // backdrop (gate ~1); ray 2: 0.05 off in every channel (gate 1 - e^-1 at tol
        // 0.05); ray 3: as ray 1 but weight 0; ray 4: a pixel with alpha 0 composited
        // onto its background, which then matches it (gate 0 with recompositing, ~1
        // without); ray 5: a grey pixel 0.02 off (gate ~0.15).
        let targets: Vec<[f32; 4]> = vec![
            [1.0; 4],
            [0.8, 0.1, 0.1, 1.0],
            [0.95, 0.95, 0.95, 1.0],
            [0.8, 0.1, 0.1, 0.0],
            [1.0; 4],
            [0.52, 0.52, 0.52, 1.0],
        ];
        let backgrounds = [[1.0f32; 3], [1.0; 3], [1.0; 3], [1.0; 3], [0.2, 0.3, 0.4], [0.5; 3]];
        let alpha = vec![1.0f32, 1.0, 1.0, 1.0, 0.0, 1.0];
        let n = targets.len() as u32;
        let aux: Vec<RayAux> = backgrounds.iter().map(|&background| RayAux { background, ..Default::default() }).collect();
        let rays: Vec<RayOutput> = (0..n).map(|i| RayOutput { rgb: [0.5, 0.1 * i as f32, 0.3], opacity: 0.1 + 0.15 * i as f32, ..Default::default() }).collect();
        let (weight_sum, lambda, tol) = (5.0f32, 0.3f32, 0.05f32);
        let loss = Photometric::new(&gpu, n).unwrap();
        let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &rays).unwrap();
        let targets_buf = GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap();
        let aux_buf = GpuBuffer::from_slice(&gpu, "aux", &aux).unwrap();
        let alpha_buf = GpuBuffer::from_slice(&gpu, "alpha", &alpha).unwrap();
        let d = GpuBuffer::<RayOutput>::zeros(&gpu, "d", n as usize).unwrap();
        let priors = OpacityPriors { foreground: lambda, foreground_tolerance: tol, ..Default::default() };
        let run = |recomposite: Option<&Recomposite>, priors: OpacityPriors| {
            let mut enc = gpu.encoder();
            loss.record(&mut enc, &rays_buf, &targets_buf, &aux_buf, recomposite, &d, n, weight_sum, 1.0, priors);
            enc.submit();
            d.read(&gpu).unwrap()
        };
        // The CPU reference of the prior, L_f = lambda sum_r w_r g_r (1 - o_r) / sum w,
        // with each target composited onto its ray's background when `composite`.
        let target_of = |r: usize, composite: bool| -> [f64; 3] {
            let t = targets[r];
            let k = if composite { 1.0 - alpha[r] as f64 } else { 0.0 };
            [0, 1, 2].map(|c| t[c] as f64 + (backgrounds[r][c] as f64 - 1.0) * k)
        };
        let gate = |r: usize, composite: bool| {
            let t = target_of(r, composite);
            let sq: f64 = (0..3).map(|c| (t[c] - backgrounds[r][c] as f64).powi(2)).sum();
            1.0 - (-sq / (3.0 * (tol as f64).powi(2))).exp()
        };
        let loss_f = |opacities: &[f64], composite: bool| -> f64 {
            let s: f64 = (0..n as usize).map(|r| targets[r][3] as f64 * gate(r, composite) * (1.0 - opacities[r])).sum();
            lambda as f64 * s / weight_sum as f64
        };
        let plain = run(None, OpacityPriors::default());
        for composite in [false, true] {
            let rc = Recomposite { alpha: &alpha_buf, loaded_over: [1.0; 3] };
            let plain_here = if composite { run(Some(&rc), OpacityPriors::default()) } else { plain.clone() };
            let got = run(composite.then_some(&rc), priors);
            let o: Vec<f64> = rays.iter().map(|ray| ray.opacity as f64).collect();
            for r in 0..n as usize {
                let h = 1e-3;
                let (mut plus, mut minus) = (o.clone(), o.clone());
                plus[r] += h;
                minus[r] -= h;
                let fd = (loss_f(&plus, composite) - loss_f(&minus, composite)) / (2.0 * h);
                let prior = got[r].opacity as f64 - plain_here[r].opacity as f64;
                assert!((prior - fd).abs() < 1e-6, "ray {r} (composite {composite}): {prior} vs {fd}");
                assert_eq!(got[r].rgb, plain_here[r].rgb, "ray {r}: the colour gradient is not the prior's");
            }
        }
        let got = run(None, priors);
        let per_ray = lambda / weight_sum;
        assert!(got[0].opacity.abs() < 1e-7, "the backdrop's own colour is not pushed: {}", got[0].opacity);
        assert!((got[1].opacity + per_ray).abs() < 1e-6, "the object is pushed toward opaque at full weight: {}", got[1].opacity);
        assert!((got[2].opacity as f64 + per_ray as f64 * (1.0 - (-1.0f64).exp())).abs() < 1e-6);
        assert_eq!(got[3].opacity, 0.0, "a ray of weight 0");
        assert!((got[4].opacity + per_ray).abs() < 1e-6);
        let rc = Recomposite { alpha: &alpha_buf, loaded_over: [1.0; 3] };
        let composited = run(Some(&rc), priors)[4].opacity;
        assert!(composited.abs() < 1e-7, "a transparent pixel composited onto the background: {composited}");
        // Tolerance sets the gate: at a wider one a pixel near the backdrop's colour weighs less.
        let wide = run(None, OpacityPriors { foreground_tolerance: 0.2, ..priors });
        assert!(wide[5].opacity > got[5].opacity && wide[5].opacity < 0.0, "{} vs {}", wide[5].opacity, got[5].opacity);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/photometric.wgsl", "Params", [n_rays, scale, recomposite, sparsity, loaded_over, entropy, foreground, fg_gate_scale]);
    }
}
