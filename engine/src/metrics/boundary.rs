//! The iBims-1 depth boundary error (DBE; Koch et al. 2018), as NOTES.md section 5
//! defines it: how close the depth edges of a prediction lie to those of the ground
//! truth (accuracy) and how many of either are matched (completeness), in pixels.
//!
//! # Definition
//! 1. **Normalise** both depth maps with the ground truth's range: with `lo`, `hi` the
//!    min and max of the GT depth over its valid pixels (`> 0`, finite),
//!    `n = clamp((d - lo) / (hi - lo), 0, 1)`; a value that is not a valid depth (GT
//!    background 0, a non-finite prediction) becomes 1, the far end. (iBims' MATLAB code
//!    normalises each map by its own range and sets missing values to 0; its GT edges
//!    are hand-made and its predictions dense. Here the GT edges come from the GT depth
//!    and the background has no depth, so it is put behind everything, and one range
//!    keeps a perfect prediction's map identical to the GT's.)
//! 2. **Edges** `E_gt`, `E_est`: [`canny()`](crate::edges::canny()) on the normalised maps, with
//!    `sigma = sqrt(2)` and hysteresis thresholds `0.1` / `0.2` of the largest gradient
//!    magnitude (iBims' MATLAB `edge(d, 'canny', [0.1 0.2], sqrt(2))`).
//! 3. **Distances** `D_gt`, `D_est`: exact Euclidean distance transforms of `E_gt`,
//!    `E_est` ([`super::distance`]).
//! 4. With the cut-off `t = 10` px:
//!    * `accuracy = sum(D_gt E_est [D_gt < t]) / sum(E_est [D_gt < t])`: mean distance
//!      from a predicted edge to the nearest GT edge, over predicted edges near one;
//!    * `completeness = (sum min(D_gt E_est, t) + sum min(D_est E_gt, t)) /
//!      (sum E_est + sum E_gt)`: the symmetric chamfer distance, capped at `t`.
//!
//! Empty cases: no edge in either map gives 0 and 0 (nothing to miss); otherwise no
//! predicted edge within `t` of a GT edge gives `accuracy = t` (iBims' convention),
//! and `completeness` follows its formula (`t` when one map has no edge).
//!
//! [`depth_boundary_error`] runs all four steps; [`depth_boundary_error_from_edges`]
//! is step 4 (with 3) on edge maps made any other way.

use serde::{Deserialize, Serialize};

use super::distance::distance_transform;
use super::{MetricsError, valid_depth};
use crate::edges::{CannyParams, canny};

/// Parameters of the depth boundary error.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DbeParams {
    /// Canny on the normalised depth: iBims' `sigma = sqrt(2)`, `low = 0.1`, `high = 0.2`
    /// (relative to the largest gradient magnitude).
    pub canny: CannyParams,
    /// Distance cut-off `t` in pixels (iBims: 10).
    pub max_dist: f32,
}

impl Default for DbeParams {
    fn default() -> Self {
        Self { canny: CannyParams { sigma: std::f32::consts::SQRT_2, low: 0.1, high: 0.2 }, max_dist: 10.0 }
    }
}

/// The depth boundary error of one view, in pixels, with what it was computed from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthBoundaryError {
    /// Mean distance of predicted edges to the GT edges (those within the cut-off).
    pub accuracy: f64,
    /// Symmetric chamfer distance between the two edge sets, capped at the cut-off.
    pub completeness: f64,
    /// Pixels of the GT edge map.
    pub gt_edge_pixels: usize,
    /// Pixels of the predicted edge map.
    pub est_edge_pixels: usize,
    pub params: DbeParams,
}

/// Depth normalised to `[0, 1]` with the GT's range for edge detection (step 1 of the
/// module docs): `clamp((d - lo) / (hi - lo), 0, 1)`, invalid values 1. `gt` sets the
/// range; `depth` is the map normalised (the GT itself or a prediction).
pub fn normalize_depth(gt: &[f32], depth: &[f32]) -> Result<Vec<f32>, MetricsError> {
    MetricsError::check_len("depth", gt.len(), depth.len())?;
    let (lo, hi) = gt
        .iter()
        .filter(|&&g| valid_depth(g))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &g| (lo.min(g), hi.max(g)));
    let span = (hi - lo).max(f32::MIN_POSITIVE);
    Ok(depth.iter().map(|&d| if valid_depth(d) && lo.is_finite() { ((d - lo) / span).clamp(0.0, 1.0) } else { 1.0 }).collect())
}

/// The DBE edge maps `(E_gt, E_est)` of a GT and a predicted depth map (steps 1-2).
pub fn dbe_edges(
    width: u32,
    height: u32,
    gt: &[f32],
    pred: &[f32],
    params: &DbeParams,
) -> Result<(Vec<bool>, Vec<bool>), MetricsError> {
    MetricsError::check_len("GT depth", width as usize * height as usize, gt.len())?;
    MetricsError::check_len("predicted depth", gt.len(), pred.len())?;
    let e_gt = canny(&normalize_depth(gt, gt)?, width, height, &params.canny);
    let e_est = canny(&normalize_depth(gt, pred)?, width, height, &params.canny);
    Ok((e_gt, e_est))
}

/// The depth boundary error of `pred` against `gt` (ray distances, `width * height`).
pub fn depth_boundary_error(
    width: u32,
    height: u32,
    gt: &[f32],
    pred: &[f32],
    params: &DbeParams,
) -> Result<DepthBoundaryError, MetricsError> {
    let (e_gt, e_est) = dbe_edges(width, height, gt, pred, params)?;
    depth_boundary_error_from_edges(width, height, &e_gt, &e_est, params)
}

/// The depth boundary error of given edge maps (steps 3-4; `params.canny` is only
/// recorded).
pub fn depth_boundary_error_from_edges(
    width: u32,
    height: u32,
    gt_edges: &[bool],
    est_edges: &[bool],
    params: &DbeParams,
) -> Result<DepthBoundaryError, MetricsError> {
    let n = width as usize * height as usize;
    MetricsError::check_len("GT edge map", n, gt_edges.len())?;
    MetricsError::check_len("predicted edge map", n, est_edges.len())?;
    let t = params.max_dist as f64;
    let d_gt = distance_transform(width, height, gt_edges);
    let d_est = distance_transform(width, height, est_edges);
    let (mut near_sum, mut near_count) = (0.0, 0usize);
    let (mut capped_sum, mut n_gt, mut n_est) = (0.0, 0usize, 0usize);
    for i in 0..n {
        if est_edges[i] {
            n_est += 1;
            capped_sum += d_gt[i].min(t);
            if d_gt[i] < t {
                near_sum += d_gt[i];
                near_count += 1;
            }
        }
        if gt_edges[i] {
            n_gt += 1;
            capped_sum += d_est[i].min(t);
        }
    }
    let (accuracy, completeness) = if n_gt + n_est == 0 {
        (0.0, 0.0)
    } else {
        let accuracy = if near_count == 0 { t } else { near_sum / near_count as f64 };
        (accuracy, capped_sum / (n_gt + n_est) as f64)
    };
    Ok(DepthBoundaryError { accuracy, completeness, gt_edge_pixels: n_gt, est_edge_pixels: n_est, params: *params })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` depth map: a box at depth 2 whose left edge is at column `x0`, on a
    /// wall at depth 3, with a background (0) strip along the bottom.
    fn scene(w: u32, h: u32, x0: u32) -> Vec<f32> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| if y >= h - 4 { 0.0 } else if x >= x0 && x < x0 + 20 && y >= 8 && y < h - 12 { 2.0 } else { 3.0 })
            .collect()
    }

    #[test]
    fn a_depth_map_against_itself_has_zero_error() {
        let (w, h) = (64u32, 48u32);
        let gt = scene(w, h, 20);
        let e = depth_boundary_error(w, h, &gt, &gt, &DbeParams::default()).unwrap();
        assert!(e.gt_edge_pixels > 0 && e.gt_edge_pixels == e.est_edge_pixels);
        assert_eq!((e.accuracy, e.completeness), (0.0, 0.0));
    }

    #[test]
    fn a_step_edge_shifted_by_k_pixels_gives_accuracy_k() {
        let (w, h) = (48u32, 32u32);
        let step = |x0: u32| -> Vec<f32> { (0..w * h).map(|i| if i % w < x0 { 1.0 } else { 2.0 }).collect() };
        let gt = step(20);
        for k in 1..=4u32 {
            let e = depth_boundary_error(w, h, &gt, &step(20 + k), &DbeParams::default()).unwrap();
            assert_eq!(e.gt_edge_pixels, h as usize, "one edge pixel per row");
            assert!((e.accuracy - k as f64).abs() < 1e-9, "k = {k}: accuracy {}", e.accuracy);
            assert!((e.completeness - k as f64).abs() < 1e-9, "k = {k}: completeness {}", e.completeness);
        }
        // Beyond the cut-off: accuracy is the cut-off, completeness capped at it.
        let e = depth_boundary_error(w, h, &gt, &step(20 + 12), &DbeParams::default()).unwrap();
        assert_eq!((e.accuracy, e.completeness), (10.0, 10.0));
    }

    #[test]
    fn formulas_on_hand_made_edge_maps() {
        let (w, h) = (6u32, 1u32);
        let params = DbeParams { max_dist: 3.0, ..DbeParams::default() };
        // GT edge at x = 0; predicted edges at x = 1 (d 1) and x = 5 (d 5, beyond t).
        let gt = [true, false, false, false, false, false];
        let est = [false, true, false, false, false, true];
        let e = depth_boundary_error_from_edges(w, h, &gt, &est, &params).unwrap();
        assert_eq!(e.accuracy, 1.0);
        // (min(1,3) + min(5,3) + D_est(0) = 1) / 3
        assert!((e.completeness - 5.0 / 3.0).abs() < 1e-12);
        let none = [false; 6];
        assert_eq!(depth_boundary_error_from_edges(w, h, &none, &none, &params).unwrap().completeness, 0.0);
        let e = depth_boundary_error_from_edges(w, h, &gt, &none, &params).unwrap();
        assert_eq!((e.accuracy, e.completeness), (3.0, 3.0));
        assert!(depth_boundary_error_from_edges(w, h, &gt[..5], &est, &params).is_err());
    }

    #[test]
    fn normalisation_uses_the_gt_range_and_puts_invalid_pixels_far() {
        let gt = [0.0, 2.0, 4.0, 3.0];
        assert_eq!(normalize_depth(&gt, &gt).unwrap(), [1.0, 0.0, 1.0, 0.5]);
        assert_eq!(normalize_depth(&gt, &[1.0, f32::NAN, 10.0, 2.5]).unwrap(), [0.0, 1.0, 1.0, 0.25]);
    }
}
