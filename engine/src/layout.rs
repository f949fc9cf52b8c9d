//! The per-ray and per-sample buffers that flow between sampler, field and renderer.
//!
//! This module owns only layouts (Rust structs mirrored by `kernels/common/layout.wgsl`),
//! the buffers that carry them, and the host copy of the kernels' ray/box slab test
//! ([`GpuRay::box_range`]); each room fills its part:
//!
//! ```text
//! rays (train/)      -> Sampler -> SampleBatch { ranges, samples, count }
//! SampleBatch        -> Field   -> FieldOutputs { rgb_density, normal } per sample
//! SampleBatch + FieldOutputs -> Renderer -> RayOutputs per ray
//! d RayOutputs (loss/) -> Renderer backward -> FieldGrads per sample
//!                      -> sampler's live compaction -> LiveSamples -> Field backward
//! ```
//!
//! # Invariants
//! * Samples of ray `r` are contiguous: `samples[ranges[r].start ..][.. ranges[r].count]`,
//!   ordered by increasing `t`, non-overlapping (`t + dt/2 <= next.t - next.dt/2`).
//! * `count[0]` is the number of samples written (<= `SampleBatch::capacity`); kernels
//!   that run per sample are dispatched over the capacity and return early past `count[0]`.
//! * Positions and directions are in the field's space: world, or NDC for forward-facing
//!   scenes. `t` and `dt` are in units of the ray parameter (ray distance in world
//!   space; NDC parameter in `[0, 1]` for LLFF).
//! * Normals travelling per sample are unit vectors (zero where the density gradient
//!   vanishes); rendered normals are `sum_i w_i n_i`, not renormalised.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Gpu, GpuBuffer, GpuError};

/// A ray as kernels read it. `dir` is unit length in world space; NDC rays keep
/// NeRF's non-unit direction (so `t` in `[0, 1]` spans near plane to infinity). The
/// sampler's step is a length, `dt = step / |dir|`, so both work.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct GpuRay {
    pub origin: [f32; 3],
    pub t_min: f32,
    pub dir: [f32; 3],
    pub t_max: f32,
}

impl GpuRay {
    /// `[t_near, t_far]` of the whole line `origin + t dir` against the box
    /// `[min, max]` (slab test; empty when `t_near > t_far`, and `t_near` may be
    /// negative). Bit for bit the kernels' `safe_inverse_dir` + `ray_box`
    /// (`kernels/sampler/common.wgsl`): direction components under `1e-30` in
    /// magnitude count as `+-1e-30`, so no `0 * inf` arises.
    pub fn box_range(&self, min: [f32; 3], max: [f32; 3]) -> [f32; 2] {
        let (mut near, mut far) = (f32::MIN, f32::MAX);
        for k in 0..3 {
            let d = self.dir[k];
            let inv = if d.abs() < 1e-30 { if d >= 0.0 { 1e30 } else { -1e30 } } else { 1.0 / d };
            let t1 = (min[k] - self.origin[k]) * inv;
            let t2 = (max[k] - self.origin[k]) * inv;
            near = near.max(t1.min(t2));
            far = far.min(t1.max(t2));
        }
        [near, far]
    }
}

/// Per-ray side output of the renderer's forward pass, read by its backward pass and
/// by the photometric loss (the background behind the ray).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct RayAux {
    /// The background colour composited behind this ray.
    pub background: [f32; 3],
    /// `K`: the number of leading samples that contributed (before early termination).
    pub n_contrib: u32,
    /// The ray's distortion `D` and occlusion `O` ([`crate::render::priors`], unweighted; `O` over
    /// the renderer's occlusion range, 0 when none is set).
    pub distortion: f32,
    pub occlusion: f32,
    /// The ray's orientation penalty `R` ([`crate::render::priors`], unweighted; 0 when the
    /// field computed no normals).
    pub orientation: f32,
    /// Input, written by the caller before the forward pass (which keeps it): the ray
    /// parameter before which the stereo free-space prior penalises density
    /// ([`crate::render::priors`]); 0 (the default) for none.
    pub free_end: f32,
}

/// Where the samples of one ray are.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq, Eq)]
pub struct SampleRange {
    pub start: u32,
    pub count: u32,
}

/// One sample along a ray: the midpoint `pos` of the segment `[t - dt/2, t + dt/2]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct GpuSample {
    pub pos: [f32; 3],
    pub t: f32,
    pub dir: [f32; 3],
    pub dt: f32,
}

/// Per-ray result of volume rendering.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct RayOutput {
    /// Composited colour (including the background term) and accumulated opacity.
    pub rgb: [f32; 3],
    pub opacity: f32,
    /// `sum_i w_i n_i` (not renormalised) and expected ray distance `sum_i w_i t_i`.
    pub normal: [f32; 3],
    pub depth: f32,
}

/// The sampler's output for a batch of rays.
pub struct SampleBatch {
    pub ranges: GpuBuffer<SampleRange>,
    pub samples: GpuBuffer<GpuSample>,
    /// `[samples written, samples wanted before the capacity cap]`.
    pub count: GpuBuffer<u32>,
    pub n_rays: u32,
    pub capacity: u32,
}

impl SampleBatch {
    pub fn new(gpu: &Gpu, n_rays: u32, capacity: u32) -> Result<Self, GpuError> {
        Ok(Self {
            ranges: GpuBuffer::zeros(gpu, "sample ranges", n_rays as usize)?,
            samples: GpuBuffer::zeros(gpu, "samples", capacity as usize)?,
            count: GpuBuffer::zeros(gpu, "sample count", 2)?,
            n_rays,
            capacity,
        })
    }
}

/// Per-sample field values: the colour and the post-activation density packed as
/// `[r, g, b, sigma]`, and the unit normal (`w` unused). Colour and density share one
/// buffer so that the renderer's backward binds 10 storage buffers, the most some
/// Vulkan implementations allow per stage (SwiftShader; 12 with them apart).
pub struct FieldOutputs {
    pub rgb_density: GpuBuffer<[f32; 4]>,
    pub normal: GpuBuffer<[f32; 4]>,
}

impl FieldOutputs {
    /// Panics unless every buffer holds `capacity` samples (a caller bug: buffers are
    /// sized with their batch). `what` names the caller and role.
    pub fn assert_capacity(&self, capacity: u32, what: &str) {
        let cap = capacity as usize;
        assert!(self.rgb_density.len() >= cap && self.normal.len() >= cap, "{what}: buffers smaller than the batch capacity {capacity}");
    }

    pub fn new(gpu: &Gpu, capacity: u32) -> Result<Self, GpuError> {
        let n = capacity as usize;
        Ok(Self { rgb_density: GpuBuffer::zeros(gpu, "rgb density", n)?, normal: GpuBuffer::zeros(gpu, "normal", n)? })
    }

    /// Writes `density`, `rgb` (`w` ignored) and `normal` from the host into the first
    /// samples (tests and reference comparisons).
    pub fn write(&self, gpu: &Gpu, density: &[f32], rgb: &[[f32; 4]], normal: &[[f32; 4]]) {
        assert_eq!(density.len(), rgb.len(), "FieldOutputs::write: lengths differ");
        let packed: Vec<[f32; 4]> = rgb.iter().zip(density).map(|(c, &d)| [c[0], c[1], c[2], d]).collect();
        self.rgb_density.write(gpu, &packed);
        self.normal.write(gpu, normal);
    }

    /// `(density, rgb with w = 0, normal)` on the host.
    #[allow(clippy::type_complexity)]
    pub fn read(&self, gpu: &Gpu) -> Result<(Vec<f32>, Vec<[f32; 4]>, Vec<[f32; 4]>), GpuError> {
        let packed = self.rgb_density.read(gpu)?;
        let density = packed.iter().map(|v| v[3]).collect();
        let rgb = packed.iter().map(|v| [v[0], v[1], v[2], 0.0]).collect();
        Ok((density, rgb, self.normal.read(gpu)?))
    }
}

/// Gradients of the loss with respect to [`FieldOutputs`], same layout (`d rgb` and
/// `d sigma` packed as `[dr, dg, db, d sigma]`).
pub type FieldGrads = FieldOutputs;

/// The samples of a batch whose [`FieldGrads`] are not all zero, in increasing order:
/// the list a field's backward may restrict itself to (every other sample carries no
/// gradient, e.g. past its ray's early termination). Written by the sampler's live
/// compaction after the renderer's backward.
///
/// One `u32` buffer, so that it takes the binding of [`SampleBatch::count`] in the
/// kernels that read it: `list[0]` is the number of live samples `n` (a count in
/// `count[0]`'s place), `list[1..4]` are unused, `list[4 + k]` is the index of the
/// `k`-th live sample for `k < n`.
pub struct LiveSamples {
    pub list: GpuBuffer<u32>,
}

impl LiveSamples {
    /// Entries before the first index (a `vec4` of header, so the indices stay aligned);
    /// `LIVE_HEADER` in `common/layout.wgsl`.
    pub const HEADER: u32 = 4;

    pub fn new(gpu: &Gpu, capacity: u32) -> Result<Self, GpuError> {
        let len = (capacity + Self::HEADER) as usize;
        Ok(Self { list: GpuBuffer::zeros(gpu, "live samples", len)? })
    }

    /// Samples the list has room for.
    pub fn capacity(&self) -> u32 {
        self.list.len() as u32 - Self::HEADER
    }

    /// Writes the list `indices` from the host (tests).
    pub fn write(&self, gpu: &Gpu, indices: &[u32]) {
        assert!(indices.len() <= self.capacity() as usize, "{} live samples, room for {}", indices.len(), self.capacity());
        let mut list = vec![0; Self::HEADER as usize];
        list[0] = indices.len() as u32;
        list.extend_from_slice(indices);
        self.list.write(gpu, &list);
    }

    /// The live samples' indices (waits for the GPU).
    pub fn read(&self, gpu: &Gpu) -> Result<Vec<u32>, GpuError> {
        let list = self.list.read(gpu)?;
        let n = (list[0] as usize).min(self.capacity() as usize);
        let h = Self::HEADER as usize;
        Ok(list[h..h + n].to_vec())
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(GpuRay, "common/layout.wgsl", "Ray", [origin, t_min, dir, t_max]);
        crate::assert_wgsl_mirror!(RayAux, "common/layout.wgsl", "RayAux", [background, n_contrib, distortion, occlusion, orientation, free_end]);
        crate::assert_wgsl_mirror!(SampleRange, "common/layout.wgsl", "SampleRange", [start, count]);
        crate::assert_wgsl_mirror!(GpuSample, "common/layout.wgsl", "Sample", [pos, t, dir, dt]);
        crate::assert_wgsl_mirror!(RayOutput, "common/layout.wgsl", "RayOutput", [rgb, opacity, normal, depth]);
        // Included by both kernels that read a LiveSamples list (sampler/live.wgsl,
        // field/grid_backward.wgsl).
        if let Err(e) = crate::gpu::kernel::tests::check_wgsl_u32_const("common/layout.wgsl", "LIVE_HEADER", LiveSamples::HEADER) {
            panic!("{e}");
        }
    }
}
