//! Per-stage timing of training steps, for `edgenerf speed`: where a step's wall time
//! goes on the adapter in use.
//!
//! With profiling on ([`super::Trainer::set_profiling`]) the trainer waits for the GPU
//! at the end of every stage and charges the wall time since the previous stage's end
//! to this one, so each figure includes the stage's GPU work and its host work
//! (uploads, readbacks, BVH rebuilds). The waits serialize what would otherwise
//! overlap, so a profiled step is a little slower than a plain one: compare the sum of
//! the stages with unprofiled steps/s, which the speed command reports beside them.
//!
//! Invariant: profiling changes no result, only when the host waits.

use std::time::Instant;

use crate::gpu::{Encoder, Gpu, GpuError};

/// The stages of a step, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Drawing the batch on the host (pixels, patches, edge weights) and uploading it.
    Batch,
    /// The occupancy grid update (every `sampler.update_interval` steps): density
    /// queries through the field, EMA, bitfield readback, BVH rebuild.
    OccupancyGrid,
    /// Marching the rays through the occupancy grid into samples.
    Sampler,
    /// The field's forward pass over the samples (with normals when `L_n` is on).
    FieldForward,
    /// Compositing, every loss and the compositing backward, with the loss readbacks.
    RenderAndLosses,
    /// The field's backward pass (second order with `L_n`).
    FieldBackward,
    /// Gradient norm, clipping, Adam, and the statistics readback.
    Optimizer,
}

impl Stage {
    pub const ALL: [Stage; 7] = [
        Stage::Batch,
        Stage::OccupancyGrid,
        Stage::Sampler,
        Stage::FieldForward,
        Stage::RenderAndLosses,
        Stage::FieldBackward,
        Stage::Optimizer,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Batch => "batch (host)",
            Stage::OccupancyGrid => "occupancy grid",
            Stage::Sampler => "sampler",
            Stage::FieldForward => "field forward",
            Stage::RenderAndLosses => "render + losses",
            Stage::FieldBackward => "field backward",
            Stage::Optimizer => "optimizer",
        }
    }
}

/// Accumulated wall time per stage over the profiled steps.
#[derive(Clone, Debug)]
pub struct StageTimes {
    /// Seconds per stage, indexed like [`Stage::ALL`].
    pub seconds: [f64; 7],
    /// Steps profiled.
    pub steps: u64,
    /// Field samples evaluated by those steps' forward (and backward) passes.
    pub field_samples: u64,
    last: Instant,
}

impl Default for StageTimes {
    fn default() -> Self {
        Self { seconds: [0.0; 7], steps: 0, field_samples: 0, last: Instant::now() }
    }
}

impl StageTimes {
    /// Starts the clock of a step's first stage.
    pub(super) fn begin(&mut self) {
        self.last = Instant::now();
    }

    /// Ends `stage` now (the caller has waited for the GPU).
    pub(super) fn end(&mut self, stage: Stage) {
        let now = Instant::now();
        self.seconds[stage as usize] += (now - self.last).as_secs_f64();
        self.last = now;
    }

    /// Seconds of `stage`.
    pub fn of(&self, stage: Stage) -> f64 {
        self.seconds[stage as usize]
    }

    pub fn total(&self) -> f64 {
        self.seconds.iter().sum()
    }
}

/// [`end_stage`] for a stage recorded into `enc`, a step's one encoder: with profiling
/// on, what `enc` holds is submitted first (so a profiled step submits once per stage).
pub(super) fn end_recorded_stage(profile: &mut Option<StageTimes>, enc: &mut Encoder, stage: Stage) -> Result<(), GpuError> {
    if profile.is_some() {
        enc.flush();
    }
    end_stage(profile, enc.gpu(), stage)
}

/// With profiling on (`profile` is `Some`), waits for the GPU and charges the time since
/// the last stage's end to `stage`; does nothing otherwise.
pub(super) fn end_stage(profile: &mut Option<StageTimes>, gpu: &Gpu, stage: Stage) -> Result<(), GpuError> {
    if let Some(p) = profile {
        gpu.wait()?;
        p.end(stage);
    }
    Ok(())
}
