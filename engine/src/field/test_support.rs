//! Helpers shared by the field backends' tests: random samples in a box, per-sample
//! loss weights, closeness checks and central differences.

#![allow(clippy::needless_range_loop)]

use glam::Vec3;

use super::Field;
use crate::gpu::{Gpu, GpuBuffer};
use crate::rng::SplitMix64;
use crate::layout::{FieldOutputs, GpuSample, SampleBatch};

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
        g.write(gpu, &self.a, &self.b, &self.c);
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

/// Checks the GPU's gradients of a scalar loss with respect to a hash-grid model's
/// parameters (`table_grad`, `mlp_grad`, in the layout of `model.table` / `model.mlp`)
/// against central differences of `loss` (the CPU pipeline), at 16 random touched
/// table entries and 16 random nonzero MLP weights (`seed` picks them). Tolerance:
/// `3e-3` of the largest gradient plus 2 % of the difference quotient.
pub(crate) fn check_grid_grads_against_fd(
    what: &str,
    model: &super::grid::reference::GridModel,
    table_grad: &[f32],
    mlp_grad: &[f32],
    seed: u64,
    loss: impl Fn(&super::grid::reference::GridModel) -> f64,
) {
    let mut r = rng(seed);
    let touched: Vec<usize> = (0..table_grad.len()).filter(|&i| table_grad[i] != 0.0).collect();
    let nonzero_mlp: Vec<usize> = (0..mlp_grad.len()).filter(|&i| mlp_grad[i] != 0.0).collect();
    assert!(!touched.is_empty() && !nonzero_mlp.is_empty(), "{what}: no gradient reached the table or the MLP");
    let mut checks: Vec<(bool, usize)> = (0..16).map(|_| (true, touched[r.below(touched.len() as u64) as usize])).collect();
    checks.extend((0..16).map(|_| (false, nonzero_mlp[r.below(nonzero_mlp.len() as u64) as usize])));
    let scale = table_grad.iter().chain(mlp_grad).fold(0.0f32, |a, v| a.max(v.abs())) as f64;
    let eps = 1e-5;
    for (is_table, idx) in checks {
        let (mut plus, mut minus) = (model.clone(), model.clone());
        let (p, m) = if is_table { (&mut plus.table, &mut minus.table) } else { (&mut plus.mlp, &mut minus.mlp) };
        p[idx] += eps;
        m[idx] -= eps;
        let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps);
        let got = if is_table { table_grad[idx] } else { mlp_grad[idx] } as f64;
        assert!(
            (got - fd).abs() <= 3e-3 * scale + 2e-2 * fd.abs(),
            "{what} {}[{idx}]: GPU {got} vs finite differences {fd} (scale {scale})",
            if is_table { "table" } else { "mlp" }
        );
    }
}

/// The samples' positions as density-query points (`Field::density`'s input).
pub(crate) fn sample_points(gpu: &Gpu, samples: &[GpuSample]) -> GpuBuffer<[f32; 4]> {
    let pts: Vec<[f32; 4]> = samples.iter().map(|s| [s.pos[0], s.pos[1], s.pos[2], 0.0]).collect();
    GpuBuffer::from_slice(gpu, "points", &pts).unwrap()
}

/// `field`'s density queries at the samples' positions.
pub(crate) fn query_densities(gpu: &Gpu, field: &dyn Field, samples: &[GpuSample]) -> Vec<f32> {
    let out = GpuBuffer::<f32>::zeros(gpu, "densities", samples.len()).unwrap();
    field.density(gpu, &sample_points(gpu, samples), samples.len() as u32, &out).unwrap();
    out.read(gpu).unwrap()
}

/// Prints forward / backward / density-query throughput of `field` on `n` random
/// samples in `aabb`: wall time, and the process's CPU time (lavapipe runs in-process),
/// which is steadier than wall time when other jobs share the cores.
pub(crate) fn measure_throughput(gpu: &Gpu, field: &mut dyn Field, aabb: [Vec3; 2], n: usize) {
    let samples = random_samples(aabb, n, 1);
    let batch = SampleBatch::new(gpu, 1, n as u32).unwrap();
    batch.samples.write(gpu, &samples);
    batch.count.write(gpu, &[n as u32, n as u32]);
    let out = FieldOutputs::new(gpu, n as u32).unwrap();
    let grads = LossWeights::random(n, 2, 1.0, 1.0, 1.0).upload(gpu, n as u32);
    let cpu_seconds = || -> f64 {
        let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
        let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
        let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
        (ticks(11) + ticks(12)) / 100.0
    };
    let time = |label: &str, f: &mut dyn FnMut()| {
        f();
        gpu.wait().unwrap();
        let reps = 3;
        let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
        for _ in 0..reps {
            f();
        }
        gpu.wait().unwrap();
        let dt = t0.elapsed().as_secs_f64() / reps as f64;
        let dc = (cpu_seconds() - c0) / reps as f64;
        eprintln!(
            "{label}: {:.1} ms wall, {:.3} M samples/s; {:.1} ms CPU, {:.3} M samples per CPU-second",
            dt * 1e3,
            n as f64 / dt / 1e6,
            dc * 1e3,
            n as f64 / dc.max(1e-9) / 1e6
        );
    };
    eprintln!("adapter: {}, field {} ({} parameters)", gpu.adapter(), field.kind(), field.n_params());
    time("forward (no normals)", &mut || field.forward(gpu, &batch, &out, false).unwrap());
    time("forward (normals)", &mut || field.forward(gpu, &batch, &out, true).unwrap());
    time("backward (first order)", &mut || field.backward(gpu, &batch, &grads, None, false).unwrap());
    time("backward (with normals)", &mut || field.backward(gpu, &batch, &grads, None, true).unwrap());
    let pts = sample_points(gpu, &samples);
    let dens = GpuBuffer::<f32>::zeros(gpu, "densities", n).unwrap();
    time("density queries", &mut || field.density(gpu, &pts, n as u32, &dens).unwrap());
}
