//! Volume rendering: compositing per-sample field values into per-ray colour, opacity,
//! expected depth and normal, and the exact backward pass back to the samples.
//!
//! Owns `kernels/render/composite.wgsl` (entry points `forward` and `backward`, bind
//! layouts [`FORWARD`] and [`BACKWARD`]) and its CPU reference ([`reference`](mod@reference)). The
//! renderer never knows which field produced the samples: it reads a
//! [`SampleBatch`] (for `t`, `dt` and the per-ray ranges) and [`FieldOutputs`], writes
//! [`RayOutput`]s, and on the way back turns `dL/d RayOutput` into [`FieldGrads`].
//!
//! # Forward (one GPU thread per ray, samples front to back)
//! For the samples `i = 0, 1, ...` of a ray, with post-activation density `sigma_i`,
//! colour `c_i`, unit normal `n_i`, midpoint distance `t_i` and length `dt_i`:
//! ```text
//! tau_i = sigma_i dt_i      trans_i = exp(-tau_i)      alpha_i = 1 - trans_i
//! T_0 = 1                   T_{i+1} = T_i trans_i      w_i = T_i alpha_i
//! rgb     = sum_i w_i c_i + (1 - opacity) bg
//! opacity = sum_i w_i
//! depth   = sum_i w_i t_i          (expected ray distance, not z-depth)
//! normal  = sum_i w_i n_i          (not renormalised; see [`unit_normal`])
//! ```
//! `alpha_i` is evaluated with a 5-term series for `tau_i < 0.1` (where
//! `1 - exp(-tau)` loses digits to cancellation), so weights of nearly transparent
//! samples are accurate to float precision.
//!
//! **z-depth.** `depth` is the expected distance along the ray parameter. The z-depth of
//! a pinhole camera is `depth * z_scale`, where `z_scale = <dir, camera forward axis>`
//! is a property of the ray the caller (train/metrics) holds; the renderer does not
//! compute it. Likewise `depth` is not divided by `opacity`: divide on the caller's side
//! where a "depth given a hit" is wanted.
//!
//! **Early termination.** Sample `i` contributes iff `T_i >= transmittance_threshold`
//! (default `1e-4`, as Instant-NGP), tested *before* the sample. `K`, the number of
//! contributing samples of a ray, is the first `i` with `T_i < threshold` (or the
//! ray's sample count). The forward pass stores `K` per ray in [`RayAux::n_contrib`]
//! and the backward pass walks exactly those `K` samples, so forward and backward
//! agree by construction. Samples past `K` get weight 0 and zero gradients; the
//! residual transmittance `T_K` is given to the background through `1 - opacity`.
//! A threshold of 0 disables termination.
//!
//! **Background.** [`Background::Black`] (no background), a constant colour, a
//! random colour per ray (uniform in `[0, 1)^3`, a hash of a per-launch seed and the
//! ray index, see [`random_background`]), or [`Background::Learned`]: a colour per ray
//! that the caller wrote into [`RayAux::background`] before the forward pass
//! ([`background`]: the learned background of captures without alpha). The forward pass writes the colour it used
//! to [`RayAux::background`], which the backward pass reads and the photometric loss
//! composites targets with alpha onto (`loss::photometric`).
//!
//! # Backward
//! Given `g = dL/d RayOutput` per ray (same struct: `d rgb, d opacity, d normal,
//! d depth`), `L = sum_r <g_r, RayOutput_r>` locally. With `b = <g.rgb, bg>` and
//! `u_i = <g.rgb, c_i - bg> + g.opacity + g.depth t_i + <g.normal, n_i>`, the ray's
//! loss is `sum_{i<K} w_i u_i + b`, and since `dw_i/dtau_i = T_{i+1}` and
//! `dw_j/dtau_i = -w_j` for `j > i`:
//! ```text
//! dL/dc_i     = w_i g.rgb                        (vec4, w = 0)
//! dL/dn_i     = w_i g.normal                     (vec4, w = 0)
//! dL/dsigma_i = dt_i (T_{i+1} u_i - sum_{i<j<K} w_j u_j)
//! ```
//! The suffix sum is `total - prefix_i` with `total = <g.rgb, rgb - bg> +
//! g.opacity opacity + g.depth depth + <g.normal, normal>` read from the forward
//! outputs (Instant-NGP / nerfacc): one pass, no scratch. Its rounding error is
//! about `1e-7 * sum_j |w_j u_j|` absolute, i.e. exact to float precision relative to
//! the ray's terms. The background enters only through `u_i` (the `- bg` term), which
//! is exactly the derivative of `(1 - opacity) bg`.
//!
//! **Priors.** The forward pass also stores per ray the distortion, occlusion and
//! orientation measures of [`priors`] in [`RayAux`]; with [`Renderer::set_priors`] the
//! backward adds their gradients (mip-NeRF 360's distortion loss, FreeNeRF's occlusion
//! regularization, Ref-NeRF's orientation penalty) in the same pass.
//!
//! # Invariants
//! * The ranges obey [`crate::layout`]'s invariants and lie inside the field buffers;
//!   samples outside every range (gaps, past `count[0]`) are neither read nor written.
//! * The forward outputs and [`RayAux`] passed to [`Renderer::backward`] come from a
//!   [`Renderer::forward`] over the same batch and field values.
//! * The backward pass overwrites the gradients of every sample in a range (zeros
//!   past `K`), or with `accumulate` adds to them: each sample belongs to one ray, so
//!   no atomics are needed.

pub mod background;
pub mod priors;
pub mod reference;
#[cfg(test)]
mod tests;

pub use background::{LearnedBackground, LearnedBackgroundConfig, Prefit, ShellShape};
pub use priors::{MonoDepthKind, PriorConfig, PriorTerms, RayPriors, StereoTargetSource};

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, Kernel, KernelSpec};
use crate::rng::{pcg_hash, unit_f32};
pub use crate::layout::RayAux;
use crate::layout::{FieldGrads, FieldOutputs, RayOutput, SampleBatch};

/// Bind layout of `composite.wgsl::forward`: params, ranges, samples, rgb + density,
/// normal, ray outputs, ray aux, per-sample weights.
pub const FORWARD: KernelSpec = KernelSpec {
    file: "render/composite.wgsl",
    entry: "forward",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

/// Bind layout of `composite.wgsl::backward`: params, ranges, samples, rgb + density,
/// normal, ray outputs (read), ray aux (read), d ray outputs, d rgb + d density,
/// d normal: 10 storage buffers, the most SwiftShader allows per stage (a test checks
/// every kernel against that floor). Ray outputs and aux are declared read-write in
/// WGSL (shared with the forward entry point) but only read here.
pub const BACKWARD: KernelSpec = KernelSpec {
    file: "render/composite.wgsl",
    entry: "backward",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

/// Errors of the renderer.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("render buffer {what} holds {len} elements, the batch needs {needed}")]
    BufferTooSmall { what: &'static str, len: usize, needed: usize },
    #[error("transmittance threshold must be finite and in [0, 1), got {0}")]
    BadThreshold(f32),
}

/// What shows through where a ray's opacity is below 1.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind", deny_unknown_fields)]
pub enum Background {
    /// No background: black, `rgb = sum_i w_i c_i`.
    #[default]
    Black,
    /// A constant colour.
    Color { rgb: [f32; 3] },
    /// A random colour per ray and launch, uniform in `[0, 1)^3` (Instant-NGP's
    /// trick for scenes with alpha): [`random_background`] of the launch seed.
    Random,
    /// A colour per ray that the caller writes into [`RayAux::background`] before the
    /// forward pass: the [`LearnedBackground`] of captures without alpha.
    Learned,
    /// Chosen per scene by the trainer (`train::model::background_of`): the scene's
    /// colour where it has one, a [`LearnedBackground`] for world-space scenes whose
    /// training images have no alpha (photographs), else black. The renderer treats
    /// an unresolved `Auto` as black.
    Auto,
}

/// Configuration of the render room.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderConfig {
    pub background: Background,
    /// Early termination: samples with transmittance below this do not contribute.
    pub transmittance_threshold: f32,
    /// The maps of [`Background::Learned`] (unused otherwise).
    pub learned_background: LearnedBackgroundConfig,
}

impl Default for RenderConfig {
    fn default() -> Self {
        Self { background: Background::Auto, transmittance_threshold: 1e-4, learned_background: LearnedBackgroundConfig::default() }
    }
}

/// Uniform of both entry points (mirror of `Params` in `composite.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Params {
    n_rays: u32,
    bg_mode: u32,
    seed: u32,
    write_weights: u32,
    background: [f32; 4],
    t_threshold: f32,
    accumulate: u32,
    distortion: f32,
    occlusion: f32,
    occlusion_end: f32,
    orientation: f32,
    free_space: f32,
    _pad: u32,
}

/// The forward pass's per-ray (and optional per-sample) outputs.
pub struct RenderOutputs {
    pub rays: GpuBuffer<RayOutput>,
    pub aux: GpuBuffer<RayAux>,
    /// Per-sample weights `w_i` (0 past early termination; samples outside every
    /// range untouched), written when present. Indexed like the batch's samples.
    pub weights: Option<GpuBuffer<f32>>,
}

impl RenderOutputs {
    /// Buffers for `n_rays` rays; `weights_capacity` asks for per-sample weights over
    /// that many samples (the batch's capacity).
    pub fn new(gpu: &Gpu, n_rays: u32, weights_capacity: Option<u32>) -> Result<Self, GpuError> {
        Ok(Self {
            rays: GpuBuffer::zeros(gpu, "ray outputs", n_rays as usize)?,
            aux: GpuBuffer::zeros(gpu, "ray aux", n_rays as usize)?,
            weights: weights_capacity.map(|c| GpuBuffer::zeros(gpu, "sample weights", c as usize)).transpose()?,
        })
    }
}

/// Owner of the compositing kernels.
pub struct Renderer {
    config: RenderConfig,
    priors: RayPriors,
    forward: Arc<Kernel>,
    backward: Arc<Kernel>,
    /// Bound in place of the weights buffer when none is wanted (never written).
    no_weights: GpuBuffer<f32>,
}

fn check_len(what: &'static str, len: usize, needed: usize) -> Result<(), RenderError> {
    if len < needed { Err(RenderError::BufferTooSmall { what, len, needed }) } else { Ok(()) }
}

fn check_field(what: [&'static str; 2], field: &FieldOutputs, capacity: u32) -> Result<(), RenderError> {
    let c = capacity as usize;
    check_len(what[0], field.rgb_density.len(), c)?;
    check_len(what[1], field.normal.len(), c)
}

impl Renderer {
    /// Builds the kernels for `gpu`.
    pub fn new(gpu: &Gpu, config: RenderConfig) -> Result<Self, RenderError> {
        let th = config.transmittance_threshold;
        if !(th.is_finite() && (0.0..1.0).contains(&th)) {
            return Err(RenderError::BadThreshold(th));
        }
        Ok(Self {
            config,
            priors: RayPriors::default(),
            forward: gpu.kernel(&FORWARD)?,
            backward: gpu.kernel(&BACKWARD)?,
            no_weights: GpuBuffer::zeros(gpu, "no weights", 1)?,
        })
    }

    pub fn config(&self) -> &RenderConfig {
        &self.config
    }

    /// The sparse-view priors the backward pass adds (none by default).
    pub fn set_priors(&mut self, priors: RayPriors) {
        self.priors = priors;
    }

    pub fn priors(&self) -> &RayPriors {
        &self.priors
    }

    fn params(&self, n_rays: u32, seed: u32) -> Params {
        let c = self.priors.coefficients();
        let (bg_mode, rgb) = match self.config.background {
            Background::Black | Background::Auto => (0, [0.0; 3]),
            Background::Color { rgb } => (1, rgb),
            Background::Random => (2, [0.0; 3]),
            Background::Learned => (3, [0.0; 3]),
        };
        Params {
            n_rays,
            bg_mode,
            seed,
            background: [rgb[0], rgb[1], rgb[2], 0.0],
            t_threshold: self.config.transmittance_threshold,
            distortion: c.distortion,
            occlusion: c.occlusion,
            occlusion_end: self.priors.occlusion_end,
            orientation: c.orientation,
            free_space: c.free_space,
            ..Default::default()
        }
    }

    /// Records the forward pass over the `batch.n_rays` rays of `batch`. `seed` picks
    /// the random backgrounds (ignored for the other modes); change it every step.
    pub fn forward(
        &self,
        enc: &mut Encoder,
        batch: &SampleBatch,
        field: &FieldOutputs,
        out: &RenderOutputs,
        seed: u32,
    ) -> Result<(), RenderError> {
        check_field(["rgb density", "normal"], field, batch.capacity)?;
        check_len("ray outputs", out.rays.len(), batch.n_rays as usize)?;
        check_len("ray aux", out.aux.len(), batch.n_rays as usize)?;
        if let Some(w) = &out.weights {
            check_len("sample weights", w.len(), batch.capacity as usize)?;
        }
        let mut p = self.params(batch.n_rays, seed);
        p.write_weights = out.weights.is_some() as u32;
        let params = enc.params(&p);
        let weights = out.weights.as_ref().unwrap_or(&self.no_weights);
        enc.dispatch_threads(
            &self.forward,
            &[
                &params,
                &batch.ranges.buffer,
                &batch.samples.buffer,
                &field.rgb_density.buffer,
                &field.normal.buffer,
                &out.rays.buffer,
                &out.aux.buffer,
                &weights.buffer,
            ],
            batch.n_rays,
        );
        Ok(())
    }

    /// Records the backward pass: `d_rays[r] = dL/d out.rays[r]` into per-sample
    /// `grads`. `out` must hold this batch's forward outputs. With `accumulate` the
    /// gradients are added to `grads`, else every in-range sample's entry is
    /// overwritten.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        enc: &mut Encoder,
        batch: &SampleBatch,
        field: &FieldOutputs,
        out: &RenderOutputs,
        d_rays: &GpuBuffer<RayOutput>,
        grads: &FieldGrads,
        accumulate: bool,
    ) -> Result<(), RenderError> {
        check_field(["rgb density", "normal"], field, batch.capacity)?;
        check_field(["d rgb density", "d normal"], grads, batch.capacity)?;
        let n = batch.n_rays as usize;
        check_len("ray outputs", out.rays.len(), n)?;
        check_len("ray aux", out.aux.len(), n)?;
        check_len("d ray outputs", d_rays.len(), n)?;
        let mut p = self.params(batch.n_rays, 0);
        p.accumulate = accumulate as u32;
        let params = enc.params(&p);
        enc.dispatch_threads(
            &self.backward,
            &[
                &params,
                &batch.ranges.buffer,
                &batch.samples.buffer,
                &field.rgb_density.buffer,
                &field.normal.buffer,
                &out.rays.buffer,
                &out.aux.buffer,
                &d_rays.buffer,
                &grads.rgb_density.buffer,
                &grads.normal.buffer,
            ],
            batch.n_rays,
        );
        Ok(())
    }
}

/// The random background of ray `ray` for launch seed `seed`: bit-identical to the
/// kernel's, uniform in `[0, 1)^3`.
pub fn random_background(seed: u32, ray: u32) -> [f32; 3] {
    let base = pcg_hash(seed ^ pcg_hash(ray));
    [0, 1, 2].map(|k| unit_f32(pcg_hash(base.wrapping_add(k))))
}

/// The background colour the forward pass composites behind ray `ray`; `None` for
/// [`Background::Learned`], whose colours are the caller's ([`RayAux::background`]).
pub fn background_of(background: &Background, seed: u32, ray: u32) -> Option<[f32; 3]> {
    match *background {
        Background::Black | Background::Auto => Some([0.0; 3]),
        Background::Color { rgb } => Some(rgb),
        Background::Random => Some(random_background(seed, ray)),
        Background::Learned => None,
    }
}

/// The rendered normal renormalised to unit length (zero where it vanishes). The
/// paper's losses use the raw `sum_i w_i n_i`; this is for display and metrics.
pub fn unit_normal(out: &RayOutput) -> [f32; 3] {
    let [x, y, z] = out.normal;
    let len = (x * x + y * y + z * z).sqrt();
    if len > 1e-20 { [x / len, y / len, z / len] } else { [0.0; 3] }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "render/composite.wgsl", "Params", [n_rays, bg_mode, seed, write_weights, background, t_threshold, accumulate, distortion, occlusion, occlusion_end, orientation, free_space]);
    }
}
