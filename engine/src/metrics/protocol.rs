//! The evaluation protocol: which pixels of a view its image metrics count, decided by
//! the scene's format, so that every evaluation of a view (the end of a training run,
//! `edgenerf eval`) scores it the same way.
//!
//! * **DTU masked** ([`Protocol::DtuMasked`], RegNeRF's DTU protocol) for the views of
//!   DTU scenes that have an object mask: PSNR over the mask, SSIM on the composites
//!   `img * m + (1 - m)` of both images over white ([`masked_image_metrics`]), and
//!   perceptual metrics (LPIPS) on the same composites ([`comparison_images`]); the
//!   unmasked figures are kept as [`ImageScore::full_image`].
//! * **Full image** ([`Protocol::FullImage`]) everywhere else: LLFF and synthetic scenes
//!   (whose ground-truth masks are not part of their protocol) and DTU views without a
//!   mask; every pixel counts.
//!
//! Invariant: [`Protocol::of_view`] is the one place that decides; [`score_view`] and
//! [`comparison_images`] follow it.

use crate::data::Scene;

use super::MetricsError;
use super::image::{ImageMetrics, image_metrics, masked_image_metrics, white_composite};

/// How a view is scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    /// PSNR over the object mask; SSIM and LPIPS on white composites (RegNeRF's DTU).
    DtuMasked,
    /// Every pixel counts (LLFF, synthetic; DTU views without a mask).
    FullImage,
}

impl Protocol {
    /// The protocol of view `v` of `scene`, with its object mask where masked.
    fn with_mask(scene: &Scene, v: usize) -> (Protocol, Option<&[f32]>) {
        match scene.views[v].mask.as_deref().filter(|_| scene.is_dtu()) {
            Some(mask) => (Protocol::DtuMasked, Some(mask)),
            None => (Protocol::FullImage, None),
        }
    }

    /// The protocol of view `v` of `scene`.
    pub fn of_view(scene: &Scene, v: usize) -> Protocol {
        Self::with_mask(scene, v).0
    }
}

/// A view's image figures under its protocol.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImageScore {
    pub protocol: Protocol,
    /// PSNR (dB) and SSIM under `protocol`.
    pub psnr: f64,
    pub ssim: f64,
    /// The unmasked figures, where `protocol` is masked.
    pub full_image: Option<ImageMetrics>,
}

/// Scores `rgb` (RGB interleaved, the view's size) against the image of view `v` of
/// `scene` under the view's protocol.
pub fn score_view(scene: &Scene, v: usize, rgb: &[f32]) -> Result<ImageScore, MetricsError> {
    let image = &scene.views[v].image;
    let full = image_metrics(image.width, image.height, rgb, &image.data)?;
    Ok(match Protocol::with_mask(scene, v) {
        (protocol, Some(mask)) => {
            let m = masked_image_metrics(image.width, image.height, rgb, &image.data, mask)?;
            ImageScore { protocol, psnr: m.psnr, ssim: m.ssim, full_image: Some(full) }
        }
        (protocol, None) => ImageScore { protocol, psnr: full.psnr, ssim: full.ssim, full_image: None },
    })
}

/// The image pair perceptual metrics (LPIPS) compare for view `v` under its protocol:
/// `(rendered, ground truth)`, both composited over white outside the object mask
/// where masked, as they are otherwise. Checks `rgb`'s size.
pub fn comparison_images(scene: &Scene, v: usize, rgb: &[f32]) -> Result<(Vec<f32>, Vec<f32>), MetricsError> {
    let image = &scene.views[v].image.data;
    MetricsError::check_len("rendered image", image.len(), rgb.len())?;
    Ok(match Protocol::with_mask(scene, v) {
        (_, Some(mask)) => (white_composite(rgb, mask), white_composite(image, mask)),
        (_, None) => (rgb.to_vec(), image.clone()),
    })
}
