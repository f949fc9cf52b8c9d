//! Image figures split by how many training views see each pixel's surface: where a
//! sparse-view render fails for want of evidence (a surface no training view saw) and
//! where it fails although the evidence was there (a surface two or more views saw,
//! whose place the photographs fix). SPARF and other sparse-view papers score novel
//! views on the co-visible pixels for the same reason.
//!
//! For each pixel of a view with ground-truth depth, the surface point is
//! `origin + depth * dir` along the pixel-centre ray; a training view *sees* it when the
//! point projects in front of that camera and inside its frame, and that view's own
//! ground-truth ray distance at the pixel it lands on agrees with the point's distance
//! within [`CovisibilityParams::rel_tolerance`] (nothing nearer hides it). Pixels
//! without a ground-truth surface are in no class.
//!
//! Scenes with more than [`MAX_TRAINING_VIEWS`] training views are not split.
//!
//! Invariants: pure CPU on per-pixel slices in [`crate::data`]'s conventions (depth is
//! the ray distance, `> 0` where there is a surface); a view is never counted as seeing
//! itself (callers leave it out of `train`); a class without pixels is `None`.

use rayon::prelude::*;

use crate::data::camera::Camera;

use super::image::psnr_from_mse;
use super::{MetricsError, valid_depth};

/// How strictly a training view's depth must agree with a surface point to see it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CovisibilityParams {
    /// Largest `|d_train - |p - o_train|| / |p - o_train|` at which the training view
    /// sees the point (its depth at the nearest pixel, so also a pixel's footprint at
    /// grazing angles and depth edges).
    pub rel_tolerance: f32,
}

impl Default for CovisibilityParams {
    fn default() -> Self {
        Self { rel_tolerance: 0.03 }
    }
}

/// A view's camera and ground-truth depth (ray distance per pixel, row-major).
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    pub camera: &'a Camera,
    pub depth: &'a [f32],
}

/// One class of pixels: its PSNR and the share of the view's pixels in it.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ClassScore {
    pub psnr: f64,
    pub fraction: f64,
}

/// PSNR of a view over the pixels whose surface no training view sees, exactly one
/// sees, and two or more see (each `None` without pixels).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Covisibility {
    pub unseen: Option<ClassScore>,
    pub seen_once: Option<ClassScore>,
    pub seen_twice_or_more: Option<ClassScore>,
    pub params: CovisibilityParams,
}

/// Marks a pixel without a ground-truth surface in [`views_seeing`].
pub const NO_SURFACE: u8 = u8::MAX;

/// Most training views the evaluation splits PSNR by (`train::evaluate`): the split is
/// for sparse views, and its cost grows with pixels times training views (a dense
/// capture of 100 views at 800 x 800 would project 64 M points per test view, and
/// nearly every pixel is seen twice there anyway).
pub const MAX_TRAINING_VIEWS: usize = 16;

/// Per pixel of `view`, how many of `train` see its ground-truth surface point (at most
/// 254), or [`NO_SURFACE`].
pub fn views_seeing(view: DepthView, train: &[DepthView], params: &CovisibilityParams) -> Result<Vec<u8>, MetricsError> {
    let (w, h) = (view.camera.width, view.camera.height);
    MetricsError::check_len("ground-truth depth", (w * h) as usize, view.depth.len())?;
    for t in train {
        MetricsError::check_len("a training view's ground-truth depth", (t.camera.width * t.camera.height) as usize, t.depth.len())?;
    }
    let w2c: Vec<_> = train.iter().map(|t| t.camera.w2c()).collect();
    let count = |i: usize| {
        let d = view.depth[i];
        if !valid_depth(d) {
            return NO_SURFACE;
        }
        let (x, y) = ((i as u32 % w) as f32 + 0.5, (i as u32 / w) as f32 + 0.5);
        let p = view.camera.pixel_ray(x, y).at(d);
        let mut n = 0u8;
        for (t, w2c) in train.iter().zip(&w2c) {
            let Some((px, _)) = t.camera.project_with(w2c, p) else { continue };
            if !t.camera.in_frame(px) {
                continue;
            }
            let (tx, ty) = ((px.x.floor() as u32).min(t.camera.width - 1), (px.y.floor() as u32).min(t.camera.height - 1));
            let seen = t.depth[(ty * t.camera.width + tx) as usize];
            let dist = (p - t.camera.origin()).length();
            if valid_depth(seen) && (seen - dist).abs() <= params.rel_tolerance * dist {
                n = n.saturating_add(1).min(NO_SURFACE - 1);
            }
        }
        n
    };
    Ok((0..view.depth.len()).into_par_iter().with_min_len(1024).map(count).collect())
}

/// PSNR of `rgb` against `gt` (RGB interleaved, `view`'s size) over each class of
/// [`views_seeing`].
pub fn covisibility(rgb: &[f32], gt: &[f32], view: DepthView, train: &[DepthView], params: &CovisibilityParams) -> Result<Covisibility, MetricsError> {
    MetricsError::check_len("rendered image", gt.len(), rgb.len())?;
    MetricsError::check_len("image", 3 * view.depth.len(), gt.len())?;
    let counts = views_seeing(view, train, params)?;
    let mut sums = [(0.0f64, 0usize); 3];
    for (i, &c) in counts.iter().enumerate() {
        if c == NO_SURFACE {
            continue;
        }
        let e: f64 = (0..3).map(|k| (rgb[3 * i + k] as f64 - gt[3 * i + k] as f64).powi(2)).sum();
        let s = &mut sums[c.min(2) as usize];
        s.0 += e;
        s.1 += 1;
    }
    let score = |(sse, n): (f64, usize)| (n > 0).then(|| ClassScore { psnr: psnr_from_mse(sse / (3 * n) as f64), fraction: n as f64 / counts.len() as f64 });
    Ok(Covisibility { unseen: score(sums[0]), seen_once: score(sums[1]), seen_twice_or_more: score(sums[2]), params: *params })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec3};

    /// A camera at `eye` looking at `target` (z up), 32x24 pixels, 60 degrees wide.
    fn camera(eye: Vec3, target: Vec3) -> Camera {
        let f = (target - eye).normalize();
        let r = f.cross(Vec3::Z).normalize();
        let c2w = Mat4::from_cols(r.extend(0.0), r.cross(f).extend(0.0), (-f).extend(0.0), eye.extend(1.0));
        Camera::from_fov_x(32, 24, 60f32.to_radians(), c2w)
    }

    /// Ground-truth ray distances of `cam` for the floor plane z = 0 (0 where a ray
    /// misses it), with a wall x = `wall` in front of it where `wall` is set.
    fn floor_depth(cam: &Camera, wall: Option<f32>) -> Vec<f32> {
        cam.pixel_rays()
            .iter()
            .map(|r| {
                let floor = if r.dir.z < 0.0 { -r.origin.z / r.dir.z } else { f32::INFINITY };
                let wall = wall.map_or(f32::INFINITY, |x| {
                    let t = (x - r.origin.x) / r.dir.x;
                    if t > 0.0 { t } else { f32::INFINITY }
                });
                let t = floor.min(wall);
                if t.is_finite() { t } else { 0.0 }
            })
            .collect()
    }

    #[test]
    fn counts_the_training_views_that_see_each_surface_point() {
        let target = camera(Vec3::new(0.0, -3.0, 2.0), Vec3::ZERO);
        let near = camera(Vec3::new(0.3, -3.0, 2.0), Vec3::ZERO);
        let other = camera(Vec3::new(-0.3, -3.0, 2.0), Vec3::ZERO);
        let away = camera(Vec3::new(0.0, 3.0, 2.0), Vec3::new(0.0, 6.0, 0.0));
        let (dt, dn, do_, da) = (floor_depth(&target, None), floor_depth(&near, None), floor_depth(&other, None), floor_depth(&away, None));
        let view = DepthView { camera: &target, depth: &dt };
        let dv = |camera, depth| DepthView { camera, depth };
        let p = CovisibilityParams::default();
        // The centre of the target's image is on the floor both neighbours see; the
        // camera looking away sees none of it.
        let centre = (12 * 32 + 16) as usize;
        assert_eq!(views_seeing(view, &[dv(&near, &dn), dv(&other, &do_)], &p).unwrap()[centre], 2);
        assert_eq!(views_seeing(view, &[dv(&near, &dn)], &p).unwrap()[centre], 1);
        assert_eq!(views_seeing(view, &[dv(&away, &da)], &p).unwrap()[centre], 0);
        // A wall between the neighbour and the floor hides the floor from it.
        let walled = floor_depth(&near, Some(0.2));
        assert_eq!(views_seeing(view, &[dv(&near, &walled)], &p).unwrap()[centre], 0);
        // Pixels above the horizon have no surface and are in no class.
        let level = camera(Vec3::new(0.0, -3.0, 2.0), Vec3::new(0.0, 0.0, 2.0));
        let dl = floor_depth(&level, None);
        let counts = views_seeing(DepthView { camera: &level, depth: &dl }, &[dv(&near, &dn)], &p).unwrap();
        assert!(counts[..32].iter().all(|&c| c == NO_SURFACE));
        assert!(views_seeing(view, &[dv(&near, &dn)], &p).unwrap().iter().filter(|&&c| c == 1).count() > 100);
    }

    #[test]
    fn psnr_per_class_counts_only_that_class() {
        let target = camera(Vec3::new(0.0, -3.0, 2.0), Vec3::ZERO);
        let near = camera(Vec3::new(0.3, -3.0, 2.0), Vec3::ZERO);
        let (dt, dn) = (floor_depth(&target, None), floor_depth(&near, None));
        let view = DepthView { camera: &target, depth: &dt };
        let train = [DepthView { camera: &near, depth: &dn }];
        let p = CovisibilityParams::default();
        let counts = views_seeing(view, &train, &p).unwrap();
        let gt = vec![0.5f32; 3 * dt.len()];
        // Errors of 0.1 on pixels seen once, 0.01 on the unseen, nothing without a surface.
        let rgb: Vec<f32> = counts.iter().flat_map(|&c| [0.5 + if c == 1 { 0.1 } else if c == 0 { 0.01 } else { 0.0 }; 3]).collect();
        let c = covisibility(&rgb, &gt, view, &train, &p).unwrap();
        assert!((c.seen_once.unwrap().psnr - 20.0).abs() < 1e-4, "{c:?}");
        assert!((c.unseen.unwrap().psnr - 40.0).abs() < 1e-4, "{c:?}");
        assert_eq!(c.seen_twice_or_more, None);
        let frac = |s: Option<ClassScore>| s.map_or(0.0, |s| s.fraction);
        let surface = counts.iter().filter(|&&c| c != NO_SURFACE).count() as f64 / counts.len() as f64;
        assert!((frac(c.unseen) + frac(c.seen_once) - surface).abs() < 1e-12);
        assert!(matches!(covisibility(&rgb[3..], &gt, view, &train, &p), Err(MetricsError::SizeMismatch { .. })));
    }
}
