//! The optimizer room: Adam on the GPU over named parameter groups, global gradient
//! norm / non-finite detection / clipping on the GPU, and host-side learning-rate
//! schedules.
//!
//! Owns `kernels/optim/*.wgsl` (`adam.wgsl` through [`adam`], `grad_norm.wgsl` and
//! its include `grad_stats.wgsl` through [`grad`]).
//!
//! # One training step
//! ```text
//! backward passes  --grads-->  GradNorm::record      (norm, non-finite count, clip scale
//!                                                    stay on the GPU in a stats buffer)
//!                              Adam::record_step     (reads the scale from that buffer,
//!                                                    skips the step if a grad is not finite)
//! trainer: GradNorm::read once per step for logging and the NaN guard (optional)
//! lr for the step: LrSchedule::lr(step)
//! ```
//! A field hands its parameters over as a slice of [`ParamGroup`]s (parameter buffer,
//! gradient buffer, per-group learning-rate multiplier and optional overrides of
//! betas / eps / weight decay). Nothing here knows what the parameters mean.
//!
//! # Invariants
//! * The optimizer owns its state (first and second moments `m`, `v` per group and the
//!   step counter `t`); parameters and gradients stay owned by the field.
//! * Group names are unique within an optimizer and are the keys of the checkpoint
//!   state ([`Adam::export_state`]).
//! * Everything is deterministic for given inputs: element-wise kernels without
//!   atomics, reductions in an order fixed by the buffer sizes alone, schedules
//!   computed in `f64`.
//! * Nothing here zeroes gradients; the trainer clears them before each backward pass.

pub mod adam;
pub mod grad;
pub mod schedule;

#[cfg(test)]
mod tests;

pub use adam::{Adam, AdamConfig, AdamState, GroupSpec, ParamGroup, WeightDecay};
pub use grad::{ClipConfig, GradNorm, GradStats, Guard};
pub use schedule::{LrDecay, LrSchedule};

use crate::gpu::GpuError;

/// Errors of the optimizer room.
#[derive(Debug, thiserror::Error)]
pub enum OptimError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("parameter group {name:?}: {params} parameters but {grads} gradients (a field must hand over equal-length buffers)")]
    GradLength { name: String, params: usize, grads: usize },
    #[error("parameter group {name:?} has {got} parameters, but the optimizer was built for {expected}")]
    GroupSize { name: String, expected: usize, got: usize },
    #[error("parameter group {0:?} is unknown to this optimizer (it was built for: {1})")]
    UnknownGroup(String, String),
    #[error("parameter group {0:?} appears more than once")]
    DuplicateGroup(String),
    #[error("optimizer state: {0}")]
    State(String),
    #[error("invalid optimizer configuration: {0}")]
    Config(String),
}

/// The optimizer room's configuration: one typed struct, serialized into the run's
/// config file. The default is the Instant-NGP grid setting (see [`OptimConfig::instant_ngp`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimConfig {
    pub adam: AdamConfig,
    pub clip: ClipConfig,
    pub schedule: LrSchedule,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self::instant_ngp()
    }
}

impl OptimConfig {
    /// Instant-NGP: Adam (0.9, 0.99, eps 1e-15), lr 1e-2 with a 100-step linear warm-up
    /// from 0.01x (as nerfacc does) and decay by 0.33 every 10k steps from step 20k
    /// (Instant-NGP's NeRF config); no clipping.
    pub fn instant_ngp() -> Self {
        Self { adam: AdamConfig::default(), clip: ClipConfig::default(), schedule: LrSchedule::default() }
    }

    /// RegNeRF / EdgeNeRF (mip-NeRF backbone): flax Adam defaults (0.9, 0.999, eps
    /// 1e-8), clipping by value 0.1 then by global norm 0.1, lr 2e-3 -> 2e-5
    /// log-linear over `max_steps` with a 512-step warm-up from 0.01x.
    pub fn regnerf(max_steps: u64) -> Self {
        Self { adam: AdamConfig::mipnerf(), clip: ClipConfig::regnerf(), schedule: LrSchedule::regnerf(max_steps) }
    }

    /// Checks every part; the message names the offending field.
    pub fn validate(&self) -> Result<(), OptimError> {
        self.adam.validate()?;
        self.clip.validate()?;
        self.schedule.validate()
    }
}
