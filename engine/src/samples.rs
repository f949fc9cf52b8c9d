//! The per-ray and per-sample buffers that flow between sampler, field and renderer.
//!
//! This module owns only layouts (Rust structs mirrored by `kernels/common/layout.wgsl`)
//! and the buffers that carry them; each room fills its part:
//!
//! ```text
//! rays (train/)      -> Sampler -> SampleBatch { ranges, samples, count }
//! SampleBatch        -> Field   -> FieldOutputs { density, rgb, normal } per sample
//! SampleBatch + FieldOutputs -> Renderer -> RayOutputs per ray
//! d RayOutputs (loss/) -> Renderer backward -> FieldGrads per sample -> Field backward
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

/// Per-sample field values: post-activation density, RGB and unit normal
/// (`vec4` padded, `w` unused).
pub struct FieldOutputs {
    pub density: GpuBuffer<f32>,
    pub rgb: GpuBuffer<[f32; 4]>,
    pub normal: GpuBuffer<[f32; 4]>,
}

impl FieldOutputs {
    /// Panics unless every buffer holds `capacity` samples (a caller bug: buffers are
    /// sized with their batch). `what` names the caller and role.
    pub fn assert_capacity(&self, capacity: u32, what: &str) {
        let cap = capacity as usize;
        assert!(
            self.density.len() >= cap && self.rgb.len() >= cap && self.normal.len() >= cap,
            "{what}: buffers smaller than the batch capacity {capacity}"
        );
    }

    pub fn new(gpu: &Gpu, capacity: u32) -> Result<Self, GpuError> {
        let n = capacity as usize;
        Ok(Self {
            density: GpuBuffer::zeros(gpu, "density", n)?,
            rgb: GpuBuffer::zeros(gpu, "rgb", n)?,
            normal: GpuBuffer::zeros(gpu, "normal", n)?,
        })
    }
}

/// Gradients of the loss with respect to [`FieldOutputs`], same layout.
pub type FieldGrads = FieldOutputs;
