//! Gradient utilities on the GPU: global L2 norm over all groups, non-finite
//! detection, clipping by value and by global norm. Owner of
//! `kernels/optim/grad_norm.wgsl` (and of the stats layout in
//! `kernels/optim/grad_stats.wgsl`, mirrored by [`stat`]).
//!
//! # Formulas (mip-NeRF / RegNeRF order: by value, then by global norm)
//! Over all elements `g` of all gradient buffers handed to [`GradNorm::record`],
//! counting only finite elements in the sums and the maximum:
//! ```text
//! raw_norm  = sqrt(sum g^2)                   abs_max = max |g|
//! norm      = sqrt(sum clamp(g, -c, c)^2)     (= raw_norm when c = max_value = 0)
//! nonfinite = number of NaN / +-Inf elements
//! scale     = 0                                          if nonfinite > 0
//!           = min(1, max_norm / (norm_eps + norm))       if max_norm > 0
//!           = 1                                          otherwise
//! clipped g = clamp(g, -c, c) * scale
//! ```
//! Guard buffers ([`GradNorm::record_guarded`], a batch's per-ray losses) add only a
//! count: `guard = number of NaN / +-Inf words in them`; any makes Adam skip the step
//! whatever its `skip_nonfinite`, so a training step can run the loss, the backward
//! and Adam in one submission and read the losses afterwards, and still change no
//! parameter when its loss is not finite.
//!
//! `norm_eps` defaults to `f32::EPSILON` as in RegNeRF (mip-NeRF used 1e-7). RegNeRF
//! logs `norm` as its `grad_norm` and `norm * scale` as `grad_norm_clipped`. Finite
//! gradients whose squares overflow give an infinite norm and a scale of 0 (no step),
//! without counting as non-finite.
//!
//! # Invariants
//! * The result stays on the GPU in [`GradNorm::stats`] (8 `f32`, layout [`stat`]);
//!   [`crate::optim::Adam::record_step`] reads the clip from there, so no CPU round
//!   trip is needed. [`GradNorm::read`] is the one optional readback per step.
//! * The clip is applied once: either by Adam (fused, the default) or in place by
//!   [`GradNorm::record_clip_in_place`], which marks the stats as applied so Adam does
//!   not apply it again. Gradients with a non-finite element are never modified.
//! * Deterministic: workgroup `b` of buffer `k` reduces elements
//!   `[2048 b, 2048 (b + 1))` in a fixed tree; one workgroup reduces the partials in a
//!   fixed order. The result depends on the buffer sizes and contents only.

use serde::{Deserialize, Serialize};

use super::OptimError;
use crate::gpu::kernel::grid_1d;
use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec};

/// Indices into the stats buffer (mirror of `kernels/optim/grad_stats.wgsl`).
pub mod stat {
    pub const RAW_NORM: usize = 0;
    pub const NORM: usize = 1;
    pub const SCALE: usize = 2;
    pub const NONFINITE: usize = 3;
    pub const ABS_MAX: usize = 4;
    pub const CLIP_VALUE: usize = 5;
    pub const APPLIED: usize = 6;
    pub const GUARD: usize = 7;
    /// Length of the stats buffer.
    pub const LEN: usize = 8;
}

/// Stats that change nothing: scale 1, no value clip, all finite.
pub(super) fn unit_stats() -> [f32; stat::LEN] {
    let mut s = [0.0; stat::LEN];
    s[stat::SCALE] = 1.0;
    s
}

/// Elements reduced by one workgroup of `partial_sums` (256 threads x 64: on lavapipe
/// every workgroup barrier of the tree reduction is a coroutine switch per SIMD group,
/// so fewer, longer workgroups reduce the table 2.5x faster than 256 x 8 did).
const BLOCK: usize = 16384;

const FILE: &str = "optim/grad_norm.wgsl";
const PARTIAL: KernelSpec = KernelSpec {
    file: FILE,
    entry: "partial_sums",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite],
};
const FINALIZE: KernelSpec = KernelSpec {
    file: FILE,
    entry: "finalize",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite],
};
const CLIP: KernelSpec = KernelSpec {
    file: FILE,
    entry: "clip_in_place",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadWrite],
};
const MARK: KernelSpec = KernelSpec { file: FILE, entry: "mark_applied", bindings: &[Binding::ReadWrite] };

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PartialParams {
    n: u32,
    offset: u32,
    blocks: u32,
    clip_value: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FinalParams {
    count: u32,
    max_norm: f32,
    clip_value: f32,
    norm_eps: f32,
    guards: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ClipParams {
    n: u32,
    _pad: [u32; 3],
}

/// Gradient clipping settings (0 disables a clip).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClipConfig {
    /// Clip by global L2 norm (after the value clip); 0: off.
    pub max_norm: f32,
    /// Clip each element to `[-max_value, max_value]` first; 0: off.
    pub max_value: f32,
    /// Added to the norm in the scale's denominator.
    pub norm_eps: f32,
}

impl Default for ClipConfig {
    /// No clipping.
    fn default() -> Self {
        Self { max_norm: 0.0, max_value: 0.0, norm_eps: f32::EPSILON }
    }
}

impl ClipConfig {
    /// RegNeRF's LLFF/DTU setting: by value 0.1, then by global norm 0.1.
    pub fn regnerf() -> Self {
        Self { max_norm: 0.1, max_value: 0.1, norm_eps: f32::EPSILON }
    }

    pub fn validate(&self) -> Result<(), OptimError> {
        for (name, x) in [("max_norm", self.max_norm), ("max_value", self.max_value), ("norm_eps", self.norm_eps)] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(OptimError::Config(format!("clip: {name} = {x} must be finite and >= 0 (0 disables)")));
            }
        }
        Ok(())
    }
}

/// The stats buffer read back (see the module doc for the formulas).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GradStats {
    /// Norm of the finite gradients before any clip.
    pub raw_norm: f32,
    /// Norm after the value clip (what the norm clip compares with `max_norm`).
    pub norm: f32,
    /// Factor applied after the value clip (0 when `nonfinite > 0`).
    pub scale: f32,
    /// Number of NaN / Inf gradient elements.
    pub nonfinite: u32,
    /// Largest |g| among the finite gradients, before any clip.
    pub abs_max: f32,
    /// Value-clip bound in effect (0: off).
    pub clip_value: f32,
    /// Whether the clip was already applied to the buffers in place.
    pub applied: bool,
    /// Number of NaN / Inf words in the guard buffers (0 without guards).
    pub guard_nonfinite: u32,
}

impl GradStats {
    /// The stats of a stats buffer read back (e.g. in a [`crate::gpu::ReadBatch`]).
    pub fn from_buffer(s: &[f32]) -> Self {
        assert_eq!(s.len(), stat::LEN, "a gradient stats buffer has {} values", stat::LEN);
        GradStats {
            raw_norm: s[stat::RAW_NORM],
            norm: s[stat::NORM],
            scale: s[stat::SCALE],
            nonfinite: s[stat::NONFINITE] as u32,
            abs_max: s[stat::ABS_MAX],
            clip_value: s[stat::CLIP_VALUE],
            applied: s[stat::APPLIED] != 0.0,
            guard_nonfinite: s[stat::GUARD] as u32,
        }
    }


    /// Whether every gradient element is finite (the NaN guard's question).
    pub fn all_finite(&self) -> bool {
        self.nonfinite == 0
    }

    /// Norm of the gradients after both clips (`norm * scale`).
    pub fn clipped_norm(&self) -> f32 {
        self.norm * self.scale
    }
}

/// A buffer whose words [`GradNorm::record_guarded`] checks for NaN / Inf: the first
/// `words` 4-byte words of `buffer`. Every word must be a float or an integer below
/// 2^23 (a count, padding), whose bits are a finite (subnormal) float.
#[derive(Clone, Copy)]
pub struct Guard<'a> {
    buffer: &'a wgpu::Buffer,
    words: usize,
}

impl<'a> Guard<'a> {
    /// The first `len` elements of `buffer`.
    pub fn of<T: bytemuck::Pod>(buffer: &'a GpuBuffer<T>, len: usize) -> Self {
        assert!(len <= buffer.len(), "guard of {len} elements of a buffer of {}", buffer.len());
        assert_eq!(std::mem::size_of::<T>() % 4, 0, "guarded elements are whole 4-byte words");
        Self { buffer: &buffer.buffer, words: len * std::mem::size_of::<T>() / 4 }
    }
}

/// The reduction's buffers: per-workgroup partials (grown on demand) and the stats.
pub struct GradNorm {
    partials: GpuBuffer<[f32; 4]>,
    stats: GpuBuffer<f32>,
}

impl GradNorm {
    /// Stats start as the unit stats (scale 1, nothing to skip).
    pub fn new(gpu: &Gpu) -> Result<Self, OptimError> {
        Ok(Self {
            partials: GpuBuffer::zeros(gpu, "grad_norm.partials", 1024)?,
            stats: GpuBuffer::from_slice(gpu, "grad_norm.stats", &unit_stats())?,
        })
    }

    /// The stats buffer ([`stat`] layout), for kernels that consume the clip.
    pub fn stats(&self) -> &GpuBuffer<f32> {
        &self.stats
    }

    /// Records the reduction over `grads` (all buffers together, e.g.
    /// [`crate::optim::ParamGroup::grads_of`]) with the clip settings `clip`; the
    /// result lands in [`GradNorm::stats`]. Empty buffers are allowed.
    pub fn record(
        &mut self,
        gpu: &Gpu,
        enc: &mut Encoder,
        grads: &[&GpuBuffer<f32>],
        clip: &ClipConfig,
    ) -> Result<(), OptimError> {
        self.record_guarded(gpu, enc, grads, &[], clip)
    }

    /// [`GradNorm::record`] that also counts the NaN / Inf words of `guards` (a batch's
    /// losses) into [`GradStats::guard_nonfinite`]; any makes Adam skip the step.
    pub fn record_guarded(
        &mut self,
        gpu: &Gpu,
        enc: &mut Encoder,
        grads: &[&GpuBuffer<f32>],
        guards: &[Guard],
        clip: &ClipConfig,
    ) -> Result<(), OptimError> {
        clip.validate()?;
        let parts: Vec<(&wgpu::Buffer, usize)> =
            grads.iter().map(|g| (&g.buffer, g.len())).chain(guards.iter().map(|g| (g.buffer, g.words))).collect();
        let blocks: Vec<usize> = parts.iter().map(|&(_, n)| n.div_ceil(BLOCK)).collect();
        let total: usize = blocks.iter().sum();
        let gradient_blocks: usize = blocks[..grads.len()].iter().sum();
        if total > self.partials.len() {
            let cap = total.next_power_of_two();
            self.partials = GpuBuffer::zeros(gpu, "grad_norm.partials", cap)?;
        }
        let partial = gpu.kernel(&PARTIAL)?;
        let finalize = gpu.kernel(&FINALIZE)?;
        let max_dim = gpu.limits().max_compute_workgroups_per_dimension;
        let mut offset = 0usize;
        for (&(buffer, n), &b) in parts.iter().zip(&blocks) {
            if b == 0 {
                continue;
            }
            let params = PartialParams {
                n: n as u32,
                offset: offset as u32,
                blocks: b as u32,
                clip_value: clip.max_value,
            };
            let params_buf = enc.params(&params);
            // grid_1d counts 64-thread groups: ask for `b` workgroups, folded.
            let grid = grid_1d((b * 64) as u32, max_dim);
            enc.dispatch(&partial, &[&params_buf, buffer, &self.partials.buffer], grid);
            offset += b;
        }
        let params = FinalParams {
            count: gradient_blocks as u32,
            max_norm: clip.max_norm,
            clip_value: clip.max_value,
            norm_eps: clip.norm_eps,
            guards: (total - gradient_blocks) as u32,
            _pad: [0; 3],
        };
        let params_buf = enc.params(&params);
        enc.dispatch(&finalize, &[&params_buf, &self.partials.buffer, &self.stats.buffer], [1, 1, 1]);
        Ok(())
    }

    /// Records the clip of `grads` in place (value clip, then the scale), and marks the
    /// stats as applied. Must follow [`GradNorm::record`] over the same buffers. Does
    /// nothing if the stats count a non-finite element or are already applied.
    pub fn record_clip_in_place(
        &self,
        gpu: &Gpu,
        enc: &mut Encoder,
        grads: &[&GpuBuffer<f32>],
    ) -> Result<(), OptimError> {
        let clip = gpu.kernel(&CLIP)?;
        let mark = gpu.kernel(&MARK)?;
        for g in grads {
            let params_buf = enc.params(&ClipParams { n: g.len() as u32, _pad: [0; 3] });
            enc.dispatch_threads(&clip, &[&params_buf, &self.stats.buffer, &g.buffer], g.len() as u32);
        }
        enc.dispatch(&mark, &[&self.stats.buffer], [1, 1, 1]);
        Ok(())
    }

    /// Reads the stats back (waits for all submitted work).
    pub fn read(&self, gpu: &Gpu) -> Result<GradStats, OptimError> {
        Ok(GradStats::from_buffer(&self.stats.read(gpu)?))
    }

    /// [`GradNorm::record`], submit, [`GradNorm::read`].
    pub fn compute(
        &mut self,
        gpu: &Gpu,
        grads: &[&GpuBuffer<f32>],
        clip: &ClipConfig,
    ) -> Result<GradStats, OptimError> {
        let mut enc = gpu.encoder();
        self.record(gpu, &mut enc, grads, clip)?;
        enc.submit();
        self.read(gpu)
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(PartialParams, "optim/grad_norm.wgsl", "PartialParams", [n, offset, blocks, clip_value]);
        crate::assert_wgsl_mirror!(FinalParams, "optim/grad_norm.wgsl", "FinalParams", [count, max_norm, clip_value, norm_eps, guards]);
        crate::assert_wgsl_mirror!(ClipParams, "optim/grad_norm.wgsl", "ClipParams", [n]);
    }
}
