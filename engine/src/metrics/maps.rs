//! Error maps for people to look at: RGB images (`ImageRgb`, `[0, 1]`) of where a
//! prediction is wrong. The colours come from [`crate::viz`] (its Turbo-like map and
//! grey images), so every picture of the project reads the same way.
//!
//! * [`depth_error_map`]: `|d - g|` over pixels with GT depth, blue (0) to red (the
//!   scale: given, or the 98th percentile of the errors); no GT: black.
//! * [`normal_error_map`]: the angle of [`super::geometry::normal_angle_deg`], blue
//!   (0 deg) to red (45 deg and more, [`NORMAL_ERROR_MAX_DEG`]); no GT normal: black.
//! * [`edge_overlay`]: two edge maps over a grey base (dimmed to `0.15 + 0.5 v`): GT
//!   edges only [`GT_EDGE_COLOR`] (green), estimated edges only [`EST_EDGE_COLOR`]
//!   (magenta), both [`BOTH_EDGE_COLOR`] (white).
//!
//! Invariant: maps have the size of their inputs; sizes are checked like every
//! metric's.

use super::MetricsError;
use super::geometry::normal_angle_deg;
use super::{valid_depth, valid_normal};
use crate::data::ImageRgb;
use crate::viz::{grey_image, turbo};

/// Normal errors at or above this angle (degrees) are drawn at the top of the colour map.
pub const NORMAL_ERROR_MAX_DEG: f64 = 45.0;
/// Overlay colour of pixels that are edges of the ground truth only.
pub const GT_EDGE_COLOR: [f32; 3] = [0.1, 0.9, 0.1];
/// Overlay colour of pixels that are edges of the estimate only.
pub const EST_EDGE_COLOR: [f32; 3] = [0.95, 0.1, 0.95];
/// Overlay colour of pixels that are edges of both.
pub const BOTH_EDGE_COLOR: [f32; 3] = [1.0, 1.0, 1.0];

/// Absolute depth error, colour-mapped over `[0, scale]`; `scale` defaults to the 98th
/// percentile of the finite errors. Returns the image and the scale used.
pub fn depth_error_map(
    width: u32,
    height: u32,
    gt: &[f32],
    pred: &[f32],
    scale: Option<f32>,
) -> Result<(ImageRgb, f32), MetricsError> {
    MetricsError::check_len("GT depth", width as usize * height as usize, gt.len())?;
    MetricsError::check_len("predicted depth", gt.len(), pred.len())?;
    let err: Vec<Option<f64>> =
        gt.iter().zip(pred).map(|(&g, &d)| valid_depth(g).then(|| (d as f64 - g as f64).abs())).collect();
    let scale = scale.unwrap_or_else(|| {
        let mut finite: Vec<f64> = err.iter().flatten().copied().filter(|e| e.is_finite()).collect();
        super::quantile(&mut finite, 0.98).unwrap_or(1.0) as f32
    });
    let scale = scale.max(1e-6);
    let values: Vec<Option<f32>> = err.iter().map(|e| e.map(|e| if e.is_nan() { 1.0 } else { e as f32 / scale })).collect();
    Ok((colour_map(width, height, &values), scale))
}

/// Normal angle error, colour-mapped over `[0, 45]` degrees.
pub fn normal_error_map(width: u32, height: u32, gt: &[[f32; 3]], pred: &[[f32; 3]]) -> Result<ImageRgb, MetricsError> {
    MetricsError::check_len("GT normals", width as usize * height as usize, gt.len())?;
    MetricsError::check_len("predicted normals", gt.len(), pred.len())?;
    let values: Vec<Option<f32>> = gt
        .iter()
        .zip(pred)
        .map(|(g, p)| valid_normal(g).then(|| (normal_angle_deg(g, p) / NORMAL_ERROR_MAX_DEG) as f32))
        .collect();
    Ok(colour_map(width, height, &values))
}

/// GT and estimated edges over a grey `base` (`width * height` values in `[0, 1]`,
/// e.g. a normalised depth map or the image's luma).
pub fn edge_overlay(
    width: u32,
    height: u32,
    base: &[f32],
    gt_edges: &[bool],
    est_edges: &[bool],
) -> Result<ImageRgb, MetricsError> {
    let n = width as usize * height as usize;
    MetricsError::check_len("overlay base", n, base.len())?;
    MetricsError::check_len("GT edge map", n, gt_edges.len())?;
    MetricsError::check_len("estimated edge map", n, est_edges.len())?;
    let dimmed: Vec<f32> = base.iter().map(|v| 0.15 + 0.5 * v.clamp(0.0, 1.0)).collect();
    let mut img = grey_image(width, height, &dimmed);
    for (i, (&g, &e)) in gt_edges.iter().zip(est_edges).enumerate() {
        let colour = match (g, e) {
            (true, true) => BOTH_EDGE_COLOR,
            (true, false) => GT_EDGE_COLOR,
            (false, true) => EST_EDGE_COLOR,
            (false, false) => continue,
        };
        img.data[3 * i..3 * i + 3].copy_from_slice(&colour);
    }
    Ok(img)
}

/// `turbo(v)` where a value is present (clamped to `[0, 1]` by the map), black elsewhere.
fn colour_map(width: u32, height: u32, values: &[Option<f32>]) -> ImageRgb {
    let mut img = ImageRgb::new(width, height);
    for (i, v) in values.iter().enumerate() {
        if let Some(v) = v {
            img.data[3 * i..3 * i + 3].copy_from_slice(&turbo(*v));
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn px(img: &ImageRgb, i: usize) -> [f32; 3] {
        [img.data[3 * i], img.data[3 * i + 1], img.data[3 * i + 2]]
    }

    #[test]
    fn depth_error_map_scales_and_blacks_out_missing_gt() {
        let gt = [1.0, 1.0, 1.0, 0.0];
        let pred = [1.0, 1.5, 3.0, 9.0];
        let (img, scale) = depth_error_map(2, 2, &gt, &pred, Some(1.0)).unwrap();
        assert_eq!(scale, 1.0);
        assert_eq!(px(&img, 0), turbo(0.0));
        assert_eq!(px(&img, 1), turbo(0.5));
        assert_eq!(px(&img, 2), turbo(1.0)); // error 2 saturates
        assert_eq!(px(&img, 3), [0.0; 3]);
        let (_, auto) = depth_error_map(2, 2, &gt, &pred, None).unwrap();
        assert!(auto > 1.5 && auto <= 2.0, "{auto}");
        assert!(depth_error_map(2, 2, &gt, &pred[..3], None).is_err());
    }

    #[test]
    fn normal_error_map_runs_from_0_to_45_degrees() {
        let z = [0.0, 0.0, 1.0];
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let img = normal_error_map(3, 1, &[z, z, [0.0; 3]], &[z, [0.0, s, s], z]).unwrap();
        assert_eq!(px(&img, 0), turbo(0.0));
        let top = turbo(1.0);
        assert!(px(&img, 1).iter().zip(&top).all(|(a, b)| (a - b).abs() < 1e-4));
        assert_eq!(px(&img, 2), [0.0; 3]);
    }

    #[test]
    fn edge_overlay_colours() {
        let img = edge_overlay(4, 1, &[1.0, 0.0, 0.0, 0.0], &[false, true, true, false], &[false, false, true, true]).unwrap();
        assert_eq!(px(&img, 0), [0.65; 3]);
        assert_eq!(px(&img, 1), GT_EDGE_COLOR);
        assert_eq!(px(&img, 2), BOTH_EDGE_COLOR);
        assert_eq!(px(&img, 3), EST_EDGE_COLOR);
    }
}
