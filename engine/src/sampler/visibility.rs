//! The visibility pass: of the samples the march placed, keep those a ray can still
//! see, before the field's full forward and backward run on them.
//!
//! The occupancy grid skips space the field has emptied; it cannot skip space behind
//! the first surface, nor fog whose every sample is nearly transparent. This pass
//! (nerfacc's `OccGridEstimator.sampling` with `early_stop_eps` and `alpha_thre`) takes
//! the marched batch and each sample's density (a field's cheap density-only pass,
//! [`crate::field::Field::record_sample_density`]), composites each ray front to back,
//! and packs into a second batch the samples before the ray's transmittance falls
//! under `min_transmittance` whose opacity `alpha = 1 - exp(-sigma dt)` is at least
//! `min_alpha` (kernel: `kernels/sampler/visibility.wgsl`, which has the exact rule).
//!
//! With `min_alpha = 0` and `min_transmittance` equal to the renderer's early
//! termination threshold the pass is exact: the renderer composites the same samples
//! (every dropped one lies past its termination), so images, losses and gradients are
//! those without the pass; what it saves is the forward pass of those samples. With
//! `min_alpha > 0` it also drops faint samples anywhere on the ray (fog, the field's
//! untrained haze): they no longer render nor get gradient, which biases the result by
//! at most their opacity, as in nerfacc. `max_dropped_opacity < 1` bounds that per
//! ray: faint samples are dropped front to back only while the opacity of those
//! dropped together stays under it, so a ray of fog keeps most of its samples.
//!
//! Invariants: the output is a valid [`SampleBatch`] (the layout's invariants: per-ray
//! ranges packed in ray order, samples in increasing `t`, unchanged); a kept sample is
//! bit-identical to its marched one; `count[0]` is the number kept and `count[1]` the
//! marched batch's wanted count (what the capacity grows from). GPU work is queued,
//! never waited for.

use bytemuck::{Pod, Zeroable};

use super::{ExclusiveScan, SamplerError};
use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec};
use crate::layout::{FieldOutputs, SampleBatch};

const BINDINGS: &[Binding] = &[
    Binding::Params,
    Binding::ReadOnly,  // marched ranges
    Binding::ReadOnly,  // marched samples
    Binding::ReadOnly,  // marched count
    Binding::ReadOnly,  // densities (.w)
    Binding::ReadWrite, // per-ray counts
    Binding::ReadOnly,  // offsets
    Binding::ReadWrite, // kept samples
    Binding::ReadWrite, // kept ranges
    Binding::ReadWrite, // kept count
];
const COUNT: KernelSpec = KernelSpec { file: "sampler/visibility.wgsl", entry: "count_visible", bindings: BINDINGS };
const WRITE: KernelSpec = KernelSpec { file: "sampler/visibility.wgsl", entry: "write_visible", bindings: BINDINGS };

/// Mirror of `Params` in `kernels/sampler/visibility.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    n_rays: u32,
    min_transmittance: f32,
    min_alpha: f32,
    max_dropped_tau: f32,
}

/// What a sample must pass to be kept (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Visibility {
    /// The walk stops at the first sample whose transmittance is below this.
    pub min_transmittance: f32,
    /// Samples whose opacity `1 - exp(-sigma dt)` is below this are dropped...
    pub min_alpha: f32,
    /// ... while the dropped samples' opacity together stays at most this (1: no bound).
    pub max_dropped_opacity: f32,
}

impl Visibility {
    /// Checks the three thresholds' ranges; the message names the one out of range.
    pub fn validate(&self) -> Result<(), String> {
        for (name, x) in [("min_transmittance", self.min_transmittance), ("min_alpha", self.min_alpha)] {
            if !(x.is_finite() && (0.0..1.0).contains(&x)) {
                return Err(format!("visibility.{name} = {x} must lie in [0, 1)"));
            }
        }
        if !(self.max_dropped_opacity > 0.0 && self.max_dropped_opacity <= 1.0) {
            return Err(format!("visibility.max_dropped_opacity = {} must lie in (0, 1] (1: no bound)", self.max_dropped_opacity));
        }
        Ok(())
    }

    /// The bound on the dropped samples' summed optical thickness `sum sigma dt` that
    /// `max_dropped_opacity` gives (`-ln(1 - o)`; no bound at 1).
    pub fn max_dropped_tau(&self) -> f32 {
        if self.max_dropped_opacity >= 1.0 { f32::MAX } else { -(1.0 - self.max_dropped_opacity).ln() }
    }
}

/// The pass's scratch for batches of up to `max_rays` rays.
pub struct VisibilityPass {
    max_rays: u32,
    counts: GpuBuffer<u32>,
    offsets: GpuBuffer<u32>,
    scan: ExclusiveScan,
}

impl VisibilityPass {
    pub fn new(gpu: &Gpu, max_rays: u32) -> Result<Self, SamplerError> {
        let max_rays = max_rays.max(1);
        Ok(Self {
            max_rays,
            counts: GpuBuffer::zeros(gpu, "visible sample counts", max_rays as usize + 1)?,
            offsets: GpuBuffer::zeros(gpu, "visible sample offsets", max_rays as usize + 1)?,
            scan: ExclusiveScan::new(gpu, max_rays + 1)?,
        })
    }

    /// Records the pass into `enc`: `marched` with the densities in
    /// `density.rgb_density[..].w` in, the kept samples into `out` (whose capacity must
    /// hold `marched`'s).
    pub fn record(
        &self,
        enc: &mut Encoder,
        marched: &SampleBatch,
        density: &FieldOutputs,
        out: &SampleBatch,
        rule: Visibility,
    ) -> Result<(), SamplerError> {
        let gpu = enc.gpu();
        let n_rays = marched.n_rays;
        assert!(n_rays <= self.max_rays && out.n_rays == n_rays, "visibility pass: {n_rays} rays, room for {}", self.max_rays);
        assert!(out.capacity >= marched.capacity, "visibility pass: the output holds fewer samples than the marched batch");
        density.assert_capacity(marched.capacity, "visibility pass: densities");
        rule.validate().map_err(SamplerError::Config)?;
        let params = enc.params(&Params {
            n_rays,
            min_transmittance: rule.min_transmittance,
            min_alpha: rule.min_alpha,
            max_dropped_tau: rule.max_dropped_tau(),
        });
        let resources: [&dyn crate::gpu::BindResource; _] = [
            &params,
            &marched.ranges.buffer,
            &marched.samples.buffer,
            &marched.count.buffer,
            &density.rgb_density.buffer,
            &self.counts.buffer,
            &self.offsets.buffer,
            &out.samples.buffer,
            &out.ranges.buffer,
            &out.count.buffer,
        ];
        let threads = n_rays.max(1);
        enc.dispatch_threads(&*gpu.kernel(&COUNT)?, &resources, threads);
        self.scan.encode(gpu, enc, &self.counts, &self.offsets, n_rays + 1)?;
        enc.dispatch_threads(&*gpu.kernel(&WRITE)?, &resources, threads);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::{GpuSample, SampleRange};
    use crate::rng::{rand_u32, unit_f32};

    /// CPU reference of the kept indices of one ray (module doc, in f32 as the kernel).
    fn cpu_keep(density: &[f32], dt: &[f32], rule: Visibility) -> Vec<usize> {
        let mut t = 1.0f32;
        let mut dropped = 0.0f32;
        let mut kept = Vec::new();
        for i in 0..density.len() {
            if t < rule.min_transmittance {
                break;
            }
            let tau = density[i] * dt[i];
            let trans = (-tau).exp();
            let alpha = if tau < 0.1 {
                tau * (1.0 - tau * (0.5 - tau * (1.0 / 6.0 - tau * (1.0 / 24.0 - tau * (1.0 / 120.0)))))
            } else {
                1.0 - trans
            };
            if alpha < rule.min_alpha && dropped + tau <= rule.max_dropped_tau() {
                dropped += tau;
            } else {
                kept.push(i);
            }
            t *= trans;
        }
        kept
    }

    #[test]
    fn visibility_pass_keeps_what_the_cpu_rule_keeps_packed_in_ray_order() {
        let gpu = crate::gpu::test_gpu(false);
        let n_rays = 300u32;
        // Rays of 0..60 samples: empty rays, opaque walls, faint fog, a NaN.
        let mut ranges = Vec::new();
        let mut samples = Vec::new();
        let mut density = Vec::new();
        for r in 0..n_rays {
            let n = if r == 9 { 40 } else { rand_u32(5, r, 0) % 61 };
            ranges.push(SampleRange { start: samples.len() as u32, count: n });
            for i in 0..n {
                let u = unit_f32(rand_u32(5, r, i + 1));
                let sigma = match r % 5 {
                    0 => 0.0,
                    1 => 0.05 * u,                  // fog: alpha under 1e-2 mostly
                    2 => if i > 20 { 400.0 } else { u }, // a wall
                    3 => 30.0 * u * u,
                    _ => if r == 9 && i == 7 { f32::NAN } else { 3.0 * u },
                };
                let t = 0.5 + 0.01 * i as f32;
                samples.push(GpuSample { pos: [r as f32, i as f32, 0.5], t, dir: [0.0, 0.0, 1.0], dt: 0.01 + 0.02 * u });
                density.push([0.0, 0.0, 0.0, sigma]);
            }
        }
        let total = samples.len() as u32;
        let capacity = total + 7;
        let marched = SampleBatch::new(&gpu, n_rays, capacity).unwrap();
        marched.ranges.write(&gpu, &ranges);
        let mut padded = samples.clone();
        padded.resize(capacity as usize, GpuSample::default());
        marched.samples.write(&gpu, &padded);
        marched.count.write(&gpu, &[total, total + 123]);
        let dens = FieldOutputs::new(&gpu, capacity).unwrap();
        density.resize(capacity as usize, [0.0; 4]);
        dens.rgb_density.write(&gpu, &density);
        let out = SampleBatch::new(&gpu, n_rays, capacity).unwrap();
        let pass = VisibilityPass::new(&gpu, n_rays).unwrap();
        let mut kept_by_rule = Vec::new();
        for rule in [
            Visibility { min_transmittance: 1e-4, min_alpha: 0.0, max_dropped_opacity: 1.0 },
            Visibility { min_transmittance: 1e-2, min_alpha: 1e-2, max_dropped_opacity: 1.0 },
            Visibility { min_transmittance: 1e-4, min_alpha: 1e-2, max_dropped_opacity: 1.0 },
            Visibility { min_transmittance: 1e-4, min_alpha: 1e-2, max_dropped_opacity: 0.02 },
            Visibility { min_transmittance: 0.0, min_alpha: 0.0, max_dropped_opacity: 1.0 },
        ] {
            let mut enc = gpu.encoder();
            pass.record(&mut enc, &marched, &dens, &out, rule).unwrap();
            enc.submit();
            let got_ranges = out.ranges.read(&gpu).unwrap();
            let got_samples = out.samples.read(&gpu).unwrap();
            let count = out.count.read(&gpu).unwrap();
            assert_eq!(count[1], total + 123, "the marched wanted count is passed on");
            let mut next = 0u32;
            let mut dropped_somewhere = false;
            for (r, rg) in ranges.iter().enumerate() {
                let (s, n) = (rg.start as usize, rg.count as usize);
                let d: Vec<f32> = density[s..s + n].iter().map(|v| v[3]).collect();
                let dt: Vec<f32> = samples[s..s + n].iter().map(|v| v.dt).collect();
                let want = cpu_keep(&d, &dt, rule);
                dropped_somewhere |= want.len() < n;
                assert_eq!(got_ranges[r], SampleRange { start: next, count: want.len() as u32 }, "ray {r} under {rule:?}");
                for (k, &i) in want.iter().enumerate() {
                    assert_eq!(got_samples[next as usize + k], samples[s + i], "ray {r} kept sample {k}");
                }
                next += want.len() as u32;
            }
            assert_eq!(count[0], next);
            kept_by_rule.push(next);
            if rule.min_transmittance > 0.0 {
                assert!(dropped_somewhere, "the test rays must exercise dropping under {rule:?}");
            } else {
                assert_eq!(next, total, "no thresholds keep every sample");
            }
            // The NaN (ray 9, sample 7) keeps its sample and every later one.
            assert!(ranges[9].count > 7 && got_ranges[9].count >= ranges[9].count - 7, "a NaN density must not be dropped");
        }
        // The bound on the dropped opacity keeps faint samples the plain floor drops
        // (the fog rays), and both keep fewer than the exact rule.
        assert!(kept_by_rule[3] > kept_by_rule[2] && kept_by_rule[3] < kept_by_rule[0], "kept per rule: {kept_by_rule:?}");
    }

    #[test]
    fn the_dropped_opacity_bound_is_refused_outside_its_range() {
        crate::assert_wgsl_mirror!(Params, "sampler/visibility.wgsl", "Params", [n_rays, min_transmittance, min_alpha, max_dropped_tau]);
        let gpu = crate::gpu::test_gpu(false);
        let marched = SampleBatch::new(&gpu, 1, 4).unwrap();
        let dens = FieldOutputs::new(&gpu, 4).unwrap();
        let out = SampleBatch::new(&gpu, 1, 4).unwrap();
        let pass = VisibilityPass::new(&gpu, 1).unwrap();
        for bad in [0.0, -0.5, 1.5, f32::NAN] {
            let mut enc = gpu.encoder();
            let rule = Visibility { min_transmittance: 1e-4, min_alpha: 1e-2, max_dropped_opacity: bad };
            let err = pass.record(&mut enc, &marched, &dens, &out, rule).err().unwrap_or_else(|| panic!("{bad} accepted")).to_string();
            assert!(err.contains("max_dropped_opacity") && err.contains("(0, 1]"), "{err}");
        }
        assert_eq!(Visibility { min_transmittance: 1e-4, min_alpha: 1e-2, max_dropped_opacity: 1.0 }.max_dropped_tau(), f32::MAX);
        let tau = Visibility { min_transmittance: 1e-4, min_alpha: 1e-2, max_dropped_opacity: 0.5 }.max_dropped_tau();
        assert!((tau - 2f32.ln()).abs() < 1e-6, "{tau}");
    }
}
