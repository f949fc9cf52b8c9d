//! Helpers shared by the field backends' tests: random samples in a box, per-sample
//! loss weights, closeness checks and central differences.

#![allow(clippy::needless_range_loop)]

use glam::Vec3;

use super::grid::SplitMix64;
use crate::gpu::Gpu;
use crate::samples::{FieldOutputs, GpuSample};

pub(crate) fn rng(seed: u64) -> SplitMix64 {
    SplitMix64::new(seed)
}

/// Uniform in `[0, 1)`.
pub(crate) fn unit(rng: &mut SplitMix64) -> f64 {
    0.5 * (rng.uniform(1.0) + 1.0)
}

/// Random samples: mostly inside `aabb`, every 9th outside it; `t` 1, `dt` 0.01.
pub(crate) fn random_samples(aabb: [Vec3; 2], n: usize, seed: u64) -> Vec<GpuSample> {
    let mut r = rng(seed);
    (0..n)
        .map(|i| {
            let margin = if i % 9 == 4 { 0.3 } else { 0.0 };
            let pos: [f32; 3] = std::array::from_fn(|d| {
                let t = unit(&mut r) * (1.0 + 2.0 * margin) - margin;
                aabb[0][d] + (aabb[1][d] - aabb[0][d]) * t as f32
            });
            let dir = Vec3::new(r.uniform(1.0) as f32, r.uniform(1.0) as f32, r.uniform(1.0) as f32 + 0.1).normalize();
            GpuSample { pos, t: 1.0, dir: dir.to_array(), dt: 0.01 }
        })
        .collect()
}

/// Per-sample loss weights a (density), b (rgb), c (normal) of
/// `L = sum_i a_i sigma_i + <b_i, rgb_i> + <c_i, n_i>`.
pub(crate) struct LossWeights {
    pub a: Vec<f32>,
    pub b: Vec<[f32; 4]>,
    pub c: Vec<[f32; 4]>,
}

impl LossWeights {
    pub fn random(n: usize, seed: u64, wa: f32, wb: f32, wc: f32) -> Self {
        let mut r = rng(seed);
        let mut v = |s: f32| r.uniform(1.0) as f32 * s;
        let a = (0..n).map(|_| v(wa)).collect();
        let b = (0..n).map(|_| [v(wb), v(wb), v(wb), 0.0]).collect();
        let c = (0..n).map(|_| [v(wc), v(wc), v(wc), 0.0]).collect();
        Self { a, b, c }
    }

    /// The weights as the per-sample output gradients of a batch of `capacity`.
    pub fn upload(&self, gpu: &Gpu, capacity: u32) -> FieldOutputs {
        let g = FieldOutputs::new(gpu, capacity).unwrap();
        g.density.write(gpu, &self.a);
        g.rgb.write(gpu, &self.b);
        g.normal.write(gpu, &self.c);
        g
    }

    /// Sample `i`'s term of the loss.
    pub fn weighted(&self, i: usize, sigma: f64, rgb: [f64; 3], normal: [f64; 3]) -> f64 {
        let mut l = self.a[i] as f64 * sigma;
        for d in 0..3 {
            l += self.b[i][d] as f64 * rgb[d] + self.c[i][d] as f64 * normal[d];
        }
        l
    }
}

/// `|got - want| <= atol + rtol |want|` elementwise with `atol = rel_of_max * max|want|`.
pub(crate) fn assert_close(what: &str, got: &[f64], want: &[f64], rel_of_max: f64, rtol: f64) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    let max = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let atol = rel_of_max * max.max(1e-30);
    let mut worst = (0.0, 0usize);
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (g - w).abs() / (atol + rtol * w.abs());
        if err.is_nan() || err > worst.0 {
            worst = (err, i);
        }
    }
    let i = worst.1;
    assert!(
        worst.0 <= 1.0,
        "{what}: element {i}: got {} want {} (max |want| {max:e}, {} elements)",
        got[i],
        want[i],
        want.len()
    );
}

pub(crate) fn to_f64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// Central difference of `f` w.r.t. `params[idx]`.
pub(crate) fn central_diff(params: &mut [f64], idx: usize, eps: f64, mut f: impl FnMut(&[f64]) -> f64) -> f64 {
    let old = params[idx];
    params[idx] = old + eps;
    let lp = f(params);
    params[idx] = old - eps;
    let lm = f(params);
    params[idx] = old;
    (lp - lm) / (2.0 * eps)
}
