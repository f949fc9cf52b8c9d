//! CPU reference of the compositing forward pass, in `f64`, for tests (GPU comparison
//! and finite differences of the backward pass) and for host-side per-sample weights.
//!
//! Same math as the kernel (see the [parent module](super)): `alpha_i = -expm1(-tau_i)`,
//! `T_{i+1} = T_i exp(-tau_i)`, `w_i = T_i alpha_i`, early termination before sample
//! `i` when `T_i < threshold`, `rgb = sum w c + (1 - opacity) bg`. Computed in `f64` so
//! that finite differences of it are accurate well beyond `f32` precision.
//!
//! Invariant: [`composite`] reads only the samples it is given, so the per-ray
//! function is all a finite-difference test needs; [`forward_batch`] gathers rays
//! from the flat GPU-layout arrays exactly as the kernel indexes them.

use crate::layout::{GpuSample, RayOutput, SampleRange};

/// One sample's inputs to compositing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RefSample {
    pub sigma: f64,
    pub rgb: [f64; 3],
    pub normal: [f64; 3],
    pub t: f64,
    pub dt: f64,
    /// The ray's unit direction at the sample (only the orientation prior reads it).
    pub dir: [f64; 3],
}

/// One ray's composited result with its per-sample intermediates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefRay {
    pub rgb: [f64; 3],
    pub opacity: f64,
    pub normal: [f64; 3],
    pub depth: f64,
    /// `w_i` for every sample of the ray (0 past `n_contrib`).
    pub weights: Vec<f64>,
    /// `K`: the number of leading samples that contributed.
    pub n_contrib: usize,
    /// `T_0 ..= T_K` (the last one is the residual, or the value that stopped the ray).
    pub transmittance: Vec<f64>,
}

impl RefRay {
    /// `<g, output>` with `g` laid out as a [`RayOutput`] (the test loss).
    #[allow(clippy::needless_range_loop)]
    pub fn dot(&self, g: &RayOutput) -> f64 {
        let mut s = g.opacity as f64 * self.opacity + g.depth as f64 * self.depth;
        for k in 0..3 {
            s += g.rgb[k] as f64 * self.rgb[k] + g.normal[k] as f64 * self.normal[k];
        }
        s
    }

    /// The result rounded to the GPU struct.
    pub fn to_ray_output(&self) -> RayOutput {
        RayOutput {
            rgb: self.rgb.map(|v| v as f32),
            opacity: self.opacity as f32,
            normal: self.normal.map(|v| v as f32),
            depth: self.depth as f32,
        }
    }
}

/// Composites one ray's samples (front to back) over `background`.
#[allow(clippy::needless_range_loop)]
pub fn composite(samples: &[RefSample], background: [f64; 3], threshold: f64) -> RefRay {
    let mut out = RefRay { weights: vec![0.0; samples.len()], ..Default::default() };
    let mut t_acc = 1.0f64;
    out.transmittance.push(t_acc);
    for (i, s) in samples.iter().enumerate() {
        if t_acc < threshold {
            break;
        }
        let tau = s.sigma * s.dt;
        let alpha = -(-tau).exp_m1();
        let w = t_acc * alpha;
        out.weights[i] = w;
        for k in 0..3 {
            out.rgb[k] += w * s.rgb[k];
            out.normal[k] += w * s.normal[k];
        }
        out.opacity += w;
        out.depth += w * s.t;
        t_acc *= (-tau).exp();
        out.transmittance.push(t_acc);
        out.n_contrib = i + 1;
    }
    for k in 0..3 {
        out.rgb[k] += (1.0 - out.opacity) * background[k];
    }
    out
}

/// The [`super::priors`] measures `(D, O, R)` of a composited ray, straight from their
/// definitions (the double sum, not the kernel's prefix sums), over its `n_contrib`
/// contributing samples; `O` counts the samples with `t < occlusion_end`.
pub fn ray_priors(samples: &[RefSample], ray: &RefRay, occlusion_end: f64) -> (f64, f64, f64) {
    let live = &samples[..ray.n_contrib];
    let w = &ray.weights;
    let mut d = 0.0;
    for (i, si) in live.iter().enumerate() {
        for (j, sj) in live.iter().enumerate() {
            d += w[i] * w[j] * (si.t - sj.t).abs();
        }
        d += w[i] * w[i] * si.dt / 3.0;
    }
    let o = live.iter().filter(|s| s.t < occlusion_end).map(|s| s.sigma * s.dt).sum();
    let r = live
        .iter()
        .zip(w)
        .map(|(s, w)| {
            let facing = (0..3).map(|k| s.normal[k] * s.dir[k]).sum::<f64>().max(0.0);
            w * facing * facing
        })
        .sum();
    (d, o, r)
}

/// The samples of ray `range` from the flat arrays the kernels read.
pub fn gather(
    range: SampleRange,
    samples: &[GpuSample],
    density: &[f32],
    rgb: &[[f32; 4]],
    normal: &[[f32; 4]],
) -> Vec<RefSample> {
    (range.start as usize..(range.start + range.count) as usize)
        .map(|s| RefSample {
            sigma: density[s] as f64,
            rgb: [0, 1, 2].map(|k| rgb[s][k] as f64),
            normal: [0, 1, 2].map(|k| normal[s][k] as f64),
            t: samples[s].t as f64,
            dt: samples[s].dt as f64,
            dir: samples[s].dir.map(|v| v as f64),
        })
        .collect()
}

/// Composites every ray of a batch; `backgrounds[r]` is ray `r`'s background (see
/// [`super::background_of`]).
pub fn forward_batch(
    ranges: &[SampleRange],
    samples: &[GpuSample],
    density: &[f32],
    rgb: &[[f32; 4]],
    normal: &[[f32; 4]],
    backgrounds: &[[f32; 3]],
    threshold: f32,
) -> Vec<RefRay> {
    ranges
        .iter()
        .zip(backgrounds)
        .map(|(&range, bg)| {
            composite(&gather(range, samples, density, rgb, normal), bg.map(|v| v as f64), threshold as f64)
        })
        .collect()
}

/// Per-sample weights of a batch on the host, indexed like the samples (0 outside
/// every range and past early termination): the CPU counterpart of
/// [`super::RenderOutputs::weights`].
pub fn sample_weights(
    ranges: &[SampleRange],
    samples: &[GpuSample],
    density: &[f32],
    threshold: f32,
) -> Vec<f32> {
    let mut w = vec![0.0f32; density.len()];
    for range in ranges {
        let ray: Vec<RefSample> = (range.start as usize..(range.start + range.count) as usize)
            .map(|s| RefSample { sigma: density[s] as f64, t: samples[s].t as f64, dt: samples[s].dt as f64, ..Default::default() })
            .collect();
        let r = composite(&ray, [0.0; 3], threshold as f64);
        for (i, wi) in r.weights.iter().enumerate() {
            w[range.start as usize + i] = *wi as f32;
        }
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(sigma: f64, t: f64, dt: f64) -> RefSample {
        RefSample { sigma, rgb: [0.2, 0.5, 0.9], normal: [0.0, 0.0, 1.0], t, dt, dir: [0.0, 0.0, -1.0] }
    }

    #[test]
    fn weights_telescope_to_one_minus_transmittance() {
        let ray: Vec<_> = (0..20).map(|i| s(0.3 + i as f64 * 0.1, 1.0 + i as f64 * 0.1, 0.1)).collect();
        let r = composite(&ray, [1.0; 3], 0.0);
        assert_eq!(r.n_contrib, 20);
        let t_end = *r.transmittance.last().unwrap();
        assert!((r.opacity - (1.0 - t_end)).abs() < 1e-14);
        // rgb = c * opacity + (1 - opacity) * bg for a constant colour.
        assert!((r.rgb[0] - (0.2 * r.opacity + t_end)).abs() < 1e-14);
    }

    #[test]
    fn termination_is_tested_before_each_sample() {
        // tau = 10 on sample 1: T_2 = e^-10.3 < 1e-4, so samples 0 and 1 contribute.
        let ray = vec![s(3.0, 1.0, 0.1), s(100.0, 1.1, 0.1), s(1.0, 1.2, 0.1), s(1.0, 1.3, 0.1)];
        let r = composite(&ray, [0.0; 3], 1e-4);
        assert_eq!(r.n_contrib, 2);
        assert_eq!(r.weights[2..], [0.0, 0.0]);
        assert_eq!(r.transmittance.len(), 3);
        let all = composite(&ray, [0.0; 3], 0.0);
        assert_eq!(all.n_contrib, 4);
        assert!(all.weights[2] > 0.0);
    }
}
