//! The loss room: per-ray losses and their gradients with respect to the rendered
//! [`RayOutput`](crate::layout::RayOutput)s.
//!
//! Owns the photometric loss ([`photometric`]) and the edge-guided depth/normal
//! regularizers of EdgeNeRF ([`edge_reg`]), the edge-guided depth-normal consistency on
//! the same patches ([`depth_normal`]), their long-range planarity on triplets of
//! pixels inside non-edge regions ([`planarity`]), the cross-view photometric
//! consistency of the rendered depth ([`reprojection`]) and RegNeRF's depth total
//! variation on patches from random poses ([`depth_tv`]); the stereo depth prior toward
//! the depths a plane sweep over the training views found ([`stereo_depth`]). The depth the edge-guided
//! terms regularize and its opacity floor live below all three in [`depth_estimate`].
//! Invariant: a loss *writes* or *adds*
//! `dL/d RayOutput` per ray into one shared gradient buffer, never touching sampler,
//! field or renderer state; the photometric loss writes (it runs first), the others add.

pub mod depth_estimate;
pub mod depth_normal;
pub mod depth_tv;
pub mod edge_reg;
pub mod photometric;
pub mod planarity;
pub mod reprojection;
pub mod stereo_depth;
#[cfg(test)]
pub(crate) mod test_support;

pub use depth_normal::{DepthNormal, DepthNormalResidual, DepthNormalTerm};
pub use depth_tv::DepthTv;
pub use edge_reg::{EdgeReg, EdgeRegLosses, EdgeRegWeights, RegConfig, RegVariant};
pub use photometric::Photometric;
pub use planarity::{Planarity, PlanarityTerm};
pub use reprojection::{Reprojection, ReprojectionViews};

/// The sum (in `f64`) of the first `n` per-ray or per-patch loss terms a kernel wrote into
/// `terms` (waits for the GPU).
pub(crate) fn sum_of_terms(gpu: &crate::gpu::Gpu, terms: &crate::gpu::GpuBuffer<f32>, n: u32) -> Result<f32, crate::gpu::GpuError> {
    Ok(sum_terms(&terms.read(gpu)?[..n as usize]))
}

/// The sum (in `f64`) of per-ray or per-patch loss terms read back from a kernel.
pub fn sum_terms(values: &[f32]) -> f32 {
    values.iter().map(|&v| v as f64).sum::<f64>() as f32
}
