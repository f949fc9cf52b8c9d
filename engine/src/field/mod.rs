//! The field room: what maps a sample (position, direction) to density, colour and an
//! analytic normal, with the exact backward pass to its parameters.
//!
//! Owns the backend-neutral [`Field`] trait and its backends: [`grid`] (multiresolution
//! hash encoding + tiny MLPs, Instant-NGP style) and [`mlp`] (the mip-NeRF / RegNeRF
//! MLP with tiled matrix kernels). Nothing outside this room knows which backend runs;
//! `test_support` holds the helpers both backends' tests share.
//!
//! # Contract of a field (every backend)
//! * Inputs are the [`SampleBatch`] of the sampler: one value per sample, dispatched
//!   over the batch capacity, samples past `count[0]` untouched. Positions are in the
//!   field's space (world, or NDC for forward-facing scenes), directions unit vectors.
//! * [`Field::forward`] writes post-activation density `sigma >= 0`, colour in
//!   `[0, 1]` and (if asked) the unit normal `n = -grad_x sigma / |grad_x sigma|`
//!   (zero where the gradient vanishes) into [`FieldOutputs`].
//! * [`Field::backward`] takes `dL/dsigma`, `dL/drgb` and `dL/dn` per sample
//!   ([`FieldGrads`]) and **adds** exact parameter gradients into the gradient buffers
//!   of [`Field::params`] (second order through the normals when asked). It recomputes
//!   what it needs from the parameters, so it only requires that the parameters did not
//!   change since the forward pass whose outputs the gradients refer to (after
//!   [`Field::forward_for_backward`], nor the batch: the grid then reads the encoding
//!   that forward kept). The caller clears gradients with [`Field::zero_grads`]
//!   before a step. Given the list of the
//!   samples that carry gradient ([`LiveSamples`]), the grid runs only those; the MLP
//!   runs every sample (its zero-gradient samples add exact zeros).
//! * Parameters live on the GPU in `f32` buffers, grouped for the optimizer
//!   ([`ParamGroup`], with per-group hints); [`Field::export`] / [`Field::import`]
//!   move them to and from the host as named arrays (checkpoints).
//! * GPU work is queued, never waited for (readbacks wait).

pub mod grid;
pub mod mlp;
#[cfg(test)]
pub(crate) mod test_support;

pub use grid::{DensityActivation, GridConfig, GridField};
pub use mlp::{Footprint, MlpConfig, MlpField, PositionEncoding};

use crate::gpu::{Encoder, Gpu, GpuBuffer, GpuError};
pub use crate::optim::ParamGroup;
use crate::layout::{FieldGrads, FieldOutputs, LiveSamples, SampleBatch};

/// A named host-side parameter array (row-major `shape`), for checkpoints.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NamedArray {
    pub name: String,
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Errors of the field room beyond the GPU's own.
#[derive(Debug, thiserror::Error)]
pub enum FieldError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("invalid field configuration: {0}")]
    Config(String),
    #[error("parameters do not fit this field: {0} (was the checkpoint written with another field configuration?)")]
    Import(String),
}

/// A radiance field with analytic normals and an exact backward pass. See the module doc.
pub trait Field {
    /// Short backend name for logs and checkpoints (`"grid"`, `"mlp"`).
    fn kind(&self) -> &'static str;

    /// Post-activation densities of `count` points (`xyz` of each `[f32; 4]`, `w`
    /// ignored) into `out[..count]`: occupancy-grid queries, no colour, no normals.
    fn density(&self, gpu: &Gpu, points: &GpuBuffer<[f32; 4]>, count: u32, out: &GpuBuffer<f32>)
    -> Result<(), GpuError> {
        gpu.submit_recorded(|enc| self.record_density(enc, points, count, out))
    }

    /// [`Field::density`] recorded into `enc` (the caller submits; an occupancy update
    /// records its query, these densities and its own kernels into one encoder).
    fn record_density(&self, enc: &mut Encoder, points: &GpuBuffer<[f32; 4]>, count: u32, out: &GpuBuffer<f32>)
    -> Result<(), GpuError>;

    /// Density, colour and (when `normals`) unit normals of every sample of `batch`,
    /// recorded into `enc` (the caller submits; a training step records its whole
    /// step into one encoder). Without `normals`, `out.normal` is left untouched.
    fn record_forward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError>;

    /// The post-activation density of every sample of `batch` into the `w` of
    /// `out.rgb_density[..count[0]]` (the sampler's visibility pass,
    /// [`crate::sampler::visibility`]); the other components and `out.normal` are
    /// unspecified. The density equals what [`Field::record_forward`] writes. By default
    /// the whole forward; a backend with a cheaper density-only path overrides it.
    fn record_sample_density(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs) -> Result<(), GpuError> {
        self.record_forward(enc, batch, out, false)
    }

    /// [`Field::record_forward`] in its own submission (does not wait).
    fn forward(&mut self, gpu: &Gpu, batch: &SampleBatch, out: &FieldOutputs, normals: bool) -> Result<(), GpuError> {
        gpu.submit_recorded(|enc| self.record_forward(enc, batch, out, normals))
    }

    /// [`Field::record_forward`] for a training step whose [`Field::record_backward`] on
    /// the same `batch` follows with the same parameters: a backend may keep what that
    /// backward would otherwise recompute (the grid keeps each sample's encoding). The
    /// backward gives the same gradients either way; by default this is the forward.
    fn record_forward_for_backward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError> {
        self.record_forward(enc, batch, out, normals)
    }

    /// [`Field::record_forward_for_backward`] in its own submission.
    fn forward_for_backward(&mut self, gpu: &Gpu, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError> {
        gpu.submit_recorded(|enc| self.record_forward_for_backward(enc, batch, out, normals))
    }

    /// Records the addition of `dL/dparams` for the per-sample output gradients `grads`
    /// into the gradient buffers; `normal_grads` enables the second-order path through
    /// the normals (`grads.normal` is ignored without it). `live`, when given, lists
    /// every sample whose `grads` may be non-zero (the sampler's live compaction): a
    /// backend may run only those, or ignore the list; the gradients are the same
    /// either way.
    fn record_backward(
        &mut self,
        enc: &mut Encoder,
        batch: &SampleBatch,
        grads: &FieldGrads,
        live: Option<&LiveSamples>,
        normal_grads: bool,
    ) -> Result<(), GpuError>;

    /// [`Field::record_backward`] in its own submission.
    fn backward(&mut self, gpu: &Gpu, batch: &SampleBatch, grads: &FieldGrads, live: Option<&LiveSamples>, normal_grads: bool)
    -> Result<(), GpuError> {
        gpu.submit_recorded(|enc| self.record_backward(enc, batch, grads, live, normal_grads))
    }

    /// Parameter groups for the optimizer, in a fixed order with unique names.
    fn params(&self) -> Vec<ParamGroup<'_>>;

    /// Total number of scalar parameters.
    fn n_params(&self) -> usize {
        self.params().iter().map(|g| g.params.len()).sum()
    }

    /// Records the clearing of every gradient buffer.
    fn record_zero_grads(&self, enc: &mut Encoder);

    /// Clears every gradient buffer (queued).
    fn zero_grads(&self, gpu: &Gpu) {
        let mut enc = gpu.encoder();
        self.record_zero_grads(&mut enc);
        enc.submit();
    }

    /// Reads the parameters back as named arrays (waits for queued work).
    fn export(&self, gpu: &Gpu) -> Result<Vec<NamedArray>, GpuError>;

    /// Overwrites the parameters from arrays written by [`Field::export`] of a field of
    /// the same configuration; every array must be present with its exact length.
    fn import(&mut self, gpu: &Gpu, arrays: &[NamedArray]) -> Result<(), FieldError>;

    /// Number of levels of the coarse-to-fine schedule (grid levels; frequency bands of
    /// a positional encoding). 0 when the backend has no such schedule.
    fn encoding_levels(&self) -> u32 {
        0
    }

    /// Enables only the first `n` encoding levels (the others contribute zero features
    /// and receive zero gradients); `n >= encoding_levels()` enables all. Set per step
    /// by the trainer; a no-op for backends without levels.
    fn set_active_levels(&mut self, n: u32) {
        let _ = n;
    }

    /// The cell edge of the finest level [`Field::set_active_levels`] left on, in the
    /// field's space along the box's shortest axis; `None` for backends without a grid.
    fn finest_active_cell(&self) -> Option<f32> {
        None
    }
}
