//! Images a person looks at: depth colourised with the turbo colour map, normals
//! mapped to RGB, opacity as grey. Pure functions from per-pixel values to
//! [`ImageRgb`]; the CLI writes them as PNGs next to the raw EXRs.
//!
//! Invariants: depth colour ranges are robust (2nd-98th percentile of the pixels
//! where `valid`), so one floater does not flatten the map; normals map
//! `n -> (n + 1) / 2` (world space, the usual convention), zero normals to black.

use crate::data::{ImageRgb, quantile};

/// Keypoints of the depth colour map: a piecewise-linear approximation of Google's
/// Turbo (dark blue, blue, cyan, green, yellow, orange, dark red), evenly spaced.
const TURBO_KEYS: [[f32; 3]; 7] = [
    [0.19, 0.07, 0.23],
    [0.27, 0.45, 0.93],
    [0.10, 0.85, 0.80],
    [0.45, 0.99, 0.35],
    [0.90, 0.85, 0.20],
    [0.98, 0.45, 0.10],
    [0.48, 0.02, 0.01],
];

/// The Turbo-like colour map at `t` in `[0, 1]` (clamped): near = blue, far = red.
pub fn turbo(t: f32) -> [f32; 3] {
    let x = t.clamp(0.0, 1.0) * (TURBO_KEYS.len() - 1) as f32;
    let i = (x.floor() as usize).min(TURBO_KEYS.len() - 2);
    let f = x - i as f32;
    let (a, b) = (TURBO_KEYS[i], TURBO_KEYS[i + 1]);
    [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]
}

/// Depth colourised near = blue .. far = red over the robust range of the pixels
/// where `valid` (all when `None`); invalid pixels black. Returns the range used.
pub fn depth_image(width: u32, height: u32, depth: &[f32], valid: Option<&[bool]>) -> (ImageRgb, [f32; 2]) {
    let range = depth_range(depth, valid);
    (depth_image_in_range(width, height, depth, valid, range), range)
}

/// The robust depth range (2nd-98th percentile) of the finite `depth` values where
/// `valid` (all when `None`); `[0, 1]` when there are none. A video's frames share the
/// range of all of them, so the colours do not flicker.
pub fn depth_range(depth: &[f32], valid: Option<&[bool]>) -> [f32; 2] {
    let mut vals: Vec<f64> =
        (0..depth.len()).filter(|&i| is_valid_depth(depth, valid, i)).map(|i| depth[i] as f64).collect();
    let lo = quantile(&mut vals, 0.02).unwrap_or(0.0) as f32;
    let hi = quantile(&mut vals, 0.98).unwrap_or(1.0) as f32;
    [lo, hi]
}

fn is_valid_depth(depth: &[f32], valid: Option<&[bool]>, i: usize) -> bool {
    valid.is_none_or(|v| v[i]) && depth[i].is_finite()
}

/// Depth colourised over `lo..hi` (clamped outside), invalid pixels black.
pub fn depth_image_in_range(width: u32, height: u32, depth: &[f32], valid: Option<&[bool]>, [lo, hi]: [f32; 2]) -> ImageRgb {
    let span = (hi - lo).max(1e-6);
    let mut img = ImageRgb::new(width, height);
    for (i, &d) in depth.iter().enumerate() {
        let rgb = if is_valid_depth(depth, valid, i) { turbo((d - lo) / span) } else { [0.0; 3] };
        img.data[3 * i..3 * i + 3].copy_from_slice(&rgb);
    }
    img
}

/// Normals to RGB: `(n + 1) / 2`.
pub fn normal_image(width: u32, height: u32, normals: &[[f32; 3]]) -> ImageRgb {
    let mut img = ImageRgb::new(width, height);
    for (i, n) in normals.iter().enumerate() {
        let zero = n.iter().all(|&c| c == 0.0);
        for c in 0..3 {
            img.data[3 * i + c] = if zero { 0.0 } else { (n[c] * 0.5 + 0.5).clamp(0.0, 1.0) };
        }
    }
    img
}

/// A scalar in `[0, 1]` as grey.
pub fn grey_image(width: u32, height: u32, values: &[f32]) -> ImageRgb {
    let mut img = ImageRgb::new(width, height);
    for (i, &v) in values.iter().enumerate() {
        img.data[3 * i..3 * i + 3].fill(v.clamp(0.0, 1.0));
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_blue_to_red() {
        let lo = turbo(0.0);
        let hi = turbo(1.0);
        assert!(lo[2] > lo[0] && hi[0] > hi[2]);
        assert_eq!(turbo(-1.0), lo);
        assert_eq!(turbo(0.5), TURBO_KEYS[3]);
        let mid = turbo(0.25);
        assert!(mid.iter().all(|c| (0.0..=1.0).contains(c)));
    }

    #[test]
    fn depth_range_ignores_outliers_and_invalid_pixels() {
        let mut depth: Vec<f32> = (0..100).map(|i| 1.0 + i as f32 / 100.0).collect();
        depth[0] = 1000.0;
        let valid: Vec<bool> = (0..100).map(|i| i != 50).collect();
        let (img, [lo, hi]) = depth_image(10, 10, &depth, Some(&valid));
        assert!(lo >= 1.0 && hi < 2.0, "range {lo}..{hi}");
        assert_eq!(&img.data[150..153], &[0.0, 0.0, 0.0]);
        // A fixed range (a video's): colours on that range, clamped beyond it.
        let fixed = depth_image_in_range(10, 10, &depth, Some(&valid), [0.0, 4.0]);
        assert_eq!(&fixed.data[..3], &turbo(1.0));
        assert_eq!(&fixed.data[3 * 99..], &turbo(depth[99] / 4.0));
        assert_eq!(&fixed.data[150..153], &[0.0, 0.0, 0.0]);
        assert_eq!(depth_range(&[f32::NAN], None), [0.0, 1.0]);
    }

    #[test]
    fn normals_map_to_rgb() {
        let img = normal_image(2, 1, &[[0.0, 0.0, 1.0], [0.0; 3]]);
        assert_eq!(&img.data[..3], &[0.5, 0.5, 1.0]);
        assert_eq!(&img.data[3..], &[0.0, 0.0, 0.0]);
    }
}
