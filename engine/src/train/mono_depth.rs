//! Monocular depth maps as the stereo depth prior's targets where the sweep found none
//! (`priors.mono_depth_dir`): reading a training view's map, aligning it to the sweep's
//! confirmed depths, and merging it into the targets ([`super::stereo`]).
//!
//! A monocular network (Depth Anything, MiDaS, DPT, ZoeDepth) predicts each
//! photograph's depth up to an unknown scale and shift: MiDaS and Depth Anything give
//! relative inverse depth (`disparity`), metric models depth. Its errors are smooth,
//! not random, and it has an answer on surfaces only one photograph saw, where a sweep
//! cannot match anything. The plane sweep's confirmed depths are metric and sparse. So
//! each view's map is fitted to them by a robust affine fit in the map's own quantity
//! (`y = a m + b`, `y` the confirmed pixels' inverse z-depth for `disparity` maps, their
//! z-depth for `depth` maps; least squares over the residuals' best [`INLIER_SHARE`],
//! refitted [`FIT_ROUNDS`] times, so the sweep's outliers do not tilt it), and every
//! pixel without a confirmed depth gets the fitted depth as a target of confidence
//! `priors.mono_depth_confidence`, where it lies inside the ray's span in the box.
//! Confirmed depths stay (confidence 1); the free-space prior reads only those.
//!
//! Files: view `v`'s map is `<dir>/<stem>.npy` (a 2-D array of any real dtype, `(H,
//! W)`) or `<dir>/<stem>.png` (grey, 8 or 16 bits; the level is the value), `<stem>`
//! the image's file stem ([`crate::data::View::name`]). A map of another size than the
//! view is resampled bilinearly (pixel centres aligned); its aspect ratio must match
//! within 1 %. Non-finite values, and non-positive ones in a `depth` map, are holes.
//!
//! Invariants: merging never changes a confirmed target (confidence 1) and only writes
//! `[t, c]` with `t` inside the ray's span and `c = confidence < 1`; a view whose fit
//! has fewer than [`MIN_FIT_PIXELS`] confirmed pixels, or a fit that inverts the map's
//! order (`a <= 0`), gets no monocular target and is reported ([`MonoFit::used`]).

use std::path::{Path, PathBuf};

use super::rays::to_gpu_ray;
use super::stereo::StereoTargets;
use crate::data::Scene;
use crate::render::MonoDepthKind;

/// Share of the confirmed pixels (those with the smallest residuals) each refit uses.
pub const INLIER_SHARE: f64 = 0.75;
/// Refits of the trimmed affine fit after the first over every confirmed pixel.
pub const FIT_ROUNDS: usize = 5;
/// Fewer confirmed pixels with a map value than this: the view's map is not used.
pub const MIN_FIT_PIXELS: usize = 32;

/// One training view's fit of its monocular map to the sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct MonoFit {
    /// Index into `Scene::views`.
    pub view: usize,
    /// `y = scale m + shift` (see the module doc).
    pub scale: f64,
    pub shift: f64,
    /// Confirmed pixels with a map value the fit saw.
    pub pixels: usize,
    /// The median over those pixels of `|t_fit - t| / t` (`t` the confirmed depth).
    pub median_error: f64,
    /// Pixels that got a monocular target.
    pub filled: usize,
    /// Whether the map was used (enough pixels and a positive scale).
    pub used: bool,
}

/// Refuses a scene whose maps cannot be fitted: they are fitted to the sweep's depths as
/// distances along world-space rays, and on LLFF's NDC rays the sweep's targets are NDC
/// ray parameters (inverse depth), which a monocular map's scale and shift do not fit.
pub fn check_scene(scene: &Scene) -> Result<(), String> {
    if scene.ndc.is_some() {
        return Err("monocular depth maps (--mono-depth, priors.mono_depth_dir) are fitted to the stereo sweep's depths along world-space rays; this scene's rays are NDC (a forward-facing LLFF capture), where the sweep gives NDC ray parameters, so the maps cannot be used on it: train without --mono-depth".into());
    }
    Ok(())
}

/// The file of view `view`'s map in `dir`, with what to do where there is none.
pub fn find_map(scene: &Scene, view: usize, dir: &Path) -> Result<PathBuf, String> {
    if !dir.is_dir() {
        return Err(format!(
            "priors.mono_depth_dir = {}: not a directory; write one monocular depth map per training image there (<image stem>.npy or .png, see docs/guide/configuration.md)",
            dir.display()
        ));
    }
    let name = &scene.views[view].name;
    for ext in ["npy", "png", "NPY", "PNG"] {
        let p = dir.join(format!("{name}.{ext}"));
        if p.is_file() {
            return Ok(p);
        }
    }
    Err(format!(
        "priors.mono_depth_dir = {}: no monocular depth map for training view {name} (expected {name}.npy or {name}.png)",
        dir.display()
    ))
}

/// Reads a map file as `(width, height, values)`, row-major.
pub fn read_map(path: &Path) -> Result<(u32, u32, Vec<f32>), String> {
    let is_npy = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    if is_npy {
        let a = crate::data::npy::read_npy(path).map_err(|e| e.to_string())?;
        let [h, w] = a.shape[..] else {
            return Err(format!("{}: a monocular depth map must be a 2-D array (H, W), got shape {}", path.display(), a.shape_string()));
        };
        if w == 0 || h == 0 {
            return Err(format!("{}: an empty monocular depth map (shape {})", path.display(), a.shape_string()));
        }
        return Ok((w as u32, h as u32, a.data.iter().map(|&v| v as f32).collect()));
    }
    let img = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| format!("{}: {e}", path.display()))?
        .decode()
        .map_err(|e| format!("{}: not a readable image ({e})", path.display()))?;
    if img.color().has_color() {
        return Err(format!("{}: a monocular depth map must be a grey image (one channel) or .npy, not colour", path.display()));
    }
    let (w, h) = (img.width(), img.height());
    Ok((w, h, img.into_luma16().into_raw().into_iter().map(|v| v as f32).collect()))
}

/// `values` (a `w x h` map) resampled bilinearly to `width x height`, pixel centres
/// aligned; a hole (non-finite) among the four neighbours makes a hole.
fn resample(values: &[f32], w: u32, h: u32, width: u32, height: u32) -> Vec<f32> {
    if (w, h) == (width, height) {
        return values.to_vec();
    }
    let (sx, sy) = (w as f32 / width as f32, h as f32 / height as f32);
    let at = |x: i64, y: i64| values[(y.clamp(0, h as i64 - 1) * w as i64 + x.clamp(0, w as i64 - 1)) as usize];
    (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (fx, fy) = ((x as f32 + 0.5) * sx - 0.5, (y as f32 + 0.5) * sy - 0.5);
            let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
            let (a, b) = (fx - x0 as f32, fy - y0 as f32);
            (at(x0, y0) * (1.0 - a) + at(x0 + 1, y0) * a) * (1.0 - b) + (at(x0, y0 + 1) * (1.0 - a) + at(x0 + 1, y0 + 1) * a) * b
        })
        .collect()
}

/// The map's quantity for a z-depth `z`: inverse depth for disparity maps.
fn quantity(kind: MonoDepthKind, z: f64) -> f64 {
    match kind {
        MonoDepthKind::Disparity => 1.0 / z,
        MonoDepthKind::Depth => z,
    }
}

/// The z-depth a fitted value `y` stands for (`None`: behind the camera).
fn depth_of(kind: MonoDepthKind, y: f64) -> Option<f64> {
    let z = match kind {
        MonoDepthKind::Disparity => 1.0 / y,
        MonoDepthKind::Depth => y,
    };
    (z.is_finite() && z > 0.0).then_some(z)
}

/// Least squares `y = a m + b` over `pairs` (`(m, y)`); `None` where the `m` are all equal.
fn affine(pairs: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = pairs.len() as f64;
    let (sm, sy) = pairs.iter().fold((0.0, 0.0), |(a, b), &(m, y)| (a + m, b + y));
    let (mm, my) = (sm / n, sy / n);
    let (var, cov) = pairs.iter().fold((0.0, 0.0), |(v, c), &(m, y)| (v + (m - mm) * (m - mm), c + (m - mm) * (y - my)));
    (var > 0.0).then(|| (cov / var, my - cov / var * mm))
}

/// The trimmed affine fit of the module doc over `pairs` (`(m, y)`).
fn robust_affine(pairs: &[(f64, f64)]) -> Option<(f64, f64)> {
    let mut fit = affine(pairs)?;
    let keep = ((pairs.len() as f64 * INLIER_SHARE).ceil() as usize).clamp(2, pairs.len());
    let mut ranked: Vec<(f64, (f64, f64))> = Vec::with_capacity(pairs.len());
    for _ in 0..FIT_ROUNDS {
        ranked.clear();
        ranked.extend(pairs.iter().map(|&(m, y)| ((fit.0 * m + fit.1 - y).abs(), (m, y))));
        ranked.select_nth_unstable_by(keep - 1, |a, b| a.0.total_cmp(&b.0));
        let inliers: Vec<(f64, f64)> = ranked[..keep].iter().map(|r| r.1).collect();
        fit = affine(&inliers)?;
    }
    Some(fit)
}

/// Fits view `view`'s map `values` (at the view's size) to its targets and writes the
/// monocular targets into the pixels without a confirmed depth.
fn merge_view(scene: &Scene, view: usize, values: &[f32], kind: MonoDepthKind, confidence: f32, targets: &mut [[f32; 2]]) -> MonoFit {
    // Per pixel: the ray's z-scale and its span in the box (`None`: it misses the box).
    let rays: Vec<(f32, Option<(f32, f32)>)> = scene
        .image_rays(view)
        .iter()
        .map(|ray| {
            let g = to_gpu_ray(scene, ray);
            (ray.z_scale, (g.t_max > g.t_min && g.t_min > 0.0).then_some((g.t_min, g.t_max)))
        })
        .collect();
    let usable = |m: f32| m.is_finite() && (kind == MonoDepthKind::Disparity || m > 0.0);
    let confirmed: Vec<usize> = (0..targets.len()).filter(|&p| targets[p][1] >= 1.0 && usable(values[p])).collect();
    let pairs: Vec<(f64, f64)> = confirmed.iter().map(|&p| (values[p] as f64, quantity(kind, (targets[p][0] * rays[p].0) as f64))).collect();
    let mut fit = MonoFit { view, scale: 0.0, shift: 0.0, pixels: pairs.len(), median_error: f64::NAN, filled: 0, used: false };
    let Some((a, b)) = (pairs.len() >= MIN_FIT_PIXELS).then(|| robust_affine(&pairs)).flatten() else { return fit };
    (fit.scale, fit.shift) = (a, b);
    if a <= 0.0 {
        return fit;
    }
    let mut errors: Vec<f64> = confirmed
        .iter()
        .filter_map(|&p| {
            let z = depth_of(kind, a * values[p] as f64 + b)?;
            let t = targets[p][0] as f64;
            Some((z / rays[p].0 as f64 - t).abs() / t)
        })
        .collect();
    fit.median_error = crate::data::quantile(&mut errors, 0.5).unwrap_or(f64::NAN);
    fit.used = true;
    for p in 0..targets.len() {
        if targets[p][1] >= 1.0 || !usable(values[p]) {
            continue;
        }
        let (z_scale, Some((lo, hi))) = rays[p] else { continue };
        let Some(z) = depth_of(kind, a * values[p] as f64 + b) else { continue };
        let t = (z / z_scale as f64) as f32;
        if t >= lo && t <= hi {
            targets[p] = [t, confidence];
            fit.filled += 1;
        }
    }
    fit
}

/// Reads every training view's map from `dir`, fits it to that view's confirmed
/// targets and merges it into `targets` (see the module doc); returns each training
/// view's fit.
pub fn merge(scene: &Scene, targets: &mut StereoTargets, dir: &Path, kind: MonoDepthKind, confidence: f32) -> Result<Vec<MonoFit>, String> {
    let mut fits = Vec::new();
    for &v in &scene.split.train {
        let Some(view_targets) = targets.get_mut(v).and_then(|t| t.as_mut()) else { continue };
        let path = find_map(scene, v, dir)?;
        let (mw, mh, values) = read_map(&path)?;
        let cam = &scene.views[v].camera;
        let (aspect_map, aspect_view) = (mw as f64 / mh as f64, cam.width as f64 / cam.height as f64);
        if (aspect_map / aspect_view - 1.0).abs() > 0.01 {
            return Err(format!(
                "{}: the monocular depth map is {mw} x {mh}, the image {} x {}: the aspect ratios differ (a crop or a rotated map?); write the map at the image's size",
                path.display(),
                cam.width,
                cam.height
            ));
        }
        let values = resample(&values, mw, mh, cam.width, cam.height);
        fits.push(merge_view(scene, v, &values, kind, confidence, view_targets));
    }
    Ok(fits)
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::data::{Camera, ImageRgb, SceneFormat, Split, View};

    const W: u32 = 40;
    const H: u32 = 30;

    /// One camera 2 above a tilted plane `z = 0.3 x`, looking down: z-depth varies over
    /// the image. Returns the scene and each pixel's true ray distance.
    fn plane_scene() -> (Scene, Vec<f32>) {
        let eye = Vec3::new(0.0, 0.0, 2.0);
        let camera = Camera::from_fov_x(W, H, 1.0, crate::data::paths::look_at(eye, Vec3::ZERO, Vec3::Y));
        let truth: Vec<f32> = (0..H)
            .flat_map(|y| (0..W).map(move |x| (x, y)))
            .map(|(x, y)| {
                let r = camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                // (o + t d).z = 0.3 (o + t d).x
                (0.3 * r.origin.x - r.origin.z) / (r.dir.z - 0.3 * r.dir.x)
            })
            .collect();
        let view = View {
            name: "v0".into(),
            path: "v0.png".into(),
            camera,
            image: ImageRgb::new(W, H),
            mask: None,
            alpha: None,
            depth: Some(truth.clone()),
            normal: None,
            train_mask: None,
        };
        let scene = Scene {
            root: ".".into(),
            format: SceneFormat::Blender,
            views: vec![view],
            split: Split { train: vec![0], test: vec![] },
            near: 0.5,
            far: 4.0,
            ndc: None,
            aabb: [Vec3::new(-3.0, -3.0, -1.5), Vec3::new(3.0, 3.0, 1.5)],
            background: None,
        };
        (scene, truth)
    }

    /// Every fifth pixel confirmed at its true depth, one in four of those 30 % short.
    fn sparse_targets(truth: &[f32]) -> Vec<[f32; 2]> {
        truth
            .iter()
            .enumerate()
            .map(|(p, &t)| match (p % 5, p % 20) {
                (0, 0) => [0.7 * t, 1.0],
                (0, _) => [t, 1.0],
                _ => [0.0, 0.0],
            })
            .collect()
    }

    fn z_depth(scene: &Scene, truth: &[f32]) -> Vec<f64> {
        truth.iter().enumerate().map(|(p, &t)| (t * scene.ray(0, p as u32 % W, p as u32 / W).z_scale) as f64).collect()
    }

    #[test]
    fn a_map_fitted_to_the_confirmed_depths_gives_the_true_depth_elsewhere() {
        let (scene, truth) = plane_scene();
        let z = z_depth(&scene, &truth);
        for (kind, map) in [
            (MonoDepthKind::Disparity, z.iter().map(|&z| (3.0 / z + 0.4) as f32).collect::<Vec<_>>()),
            (MonoDepthKind::Depth, z.iter().map(|&z| (0.5 * z - 0.2) as f32).collect()),
        ] {
            let before = sparse_targets(&truth);
            let mut targets = before.clone();
            let fit = merge_view(&scene, 0, &map, kind, 0.5, &mut targets);
            assert!(fit.used && fit.pixels == before.iter().filter(|t| t[1] >= 1.0).count(), "{kind:?}: {fit:?}");
            assert!(fit.median_error < 1e-4, "{kind:?}: the outliers do not tilt the fit: {fit:?}");
            let mut filled = 0;
            for p in 0..targets.len() {
                if before[p][1] >= 1.0 {
                    assert_eq!(targets[p], before[p], "a confirmed target stays, outlier or not");
                    continue;
                }
                let [t, c] = targets[p];
                assert_eq!(c, 0.5);
                assert!((t - truth[p]).abs() < 1e-3 * truth[p], "{kind:?} pixel {p}: {t} against {}", truth[p]);
                filled += 1;
            }
            assert_eq!(fit.filled, filled);
        }
    }

    #[test]
    fn a_view_with_too_few_confirmed_depths_or_an_inverted_map_gets_no_target() {
        let (scene, truth) = plane_scene();
        let z = z_depth(&scene, &truth);
        let map: Vec<f32> = z.iter().map(|&z| (1.0 / z) as f32).collect();
        let few: Vec<[f32; 2]> = truth.iter().enumerate().map(|(p, &t)| if p < MIN_FIT_PIXELS - 1 { [t, 1.0] } else { [0.0, 0.0] }).collect();
        let mut targets = few.clone();
        assert!(!merge_view(&scene, 0, &map, MonoDepthKind::Disparity, 0.5, &mut targets).used);
        assert_eq!(targets, few);
        // A depth map read as disparity: the fit inverts the order.
        let depth_map: Vec<f32> = z.iter().map(|&z| z as f32).collect();
        let mut targets = sparse_targets(&truth);
        let fit = merge_view(&scene, 0, &depth_map, MonoDepthKind::Disparity, 0.5, &mut targets);
        assert!(!fit.used && fit.scale < 0.0, "{fit:?}");
        assert_eq!(targets, sparse_targets(&truth));
    }

    #[test]
    fn maps_are_found_by_image_stem_read_resampled_and_refused_with_what_to_do() {
        let (scene, truth) = plane_scene();
        let dir = std::env::temp_dir().join(format!("edgenerf-mono-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let missing = find_map(&scene, 0, &dir).unwrap_err();
        assert!(missing.contains("not a directory"), "{missing}");
        std::fs::create_dir_all(&dir).unwrap();
        assert!(find_map(&scene, 0, &dir).unwrap_err().contains("v0.npy or v0.png"));
        // The true disparity at twice the view's size, as a network at its own
        // resolution writes it; a plane's disparity is affine in the pixel, so the
        // bilinear resampling keeps it but at the outermost half pixel.
        let fine = Camera::from_fov_x(2 * W, 2 * H, 1.0, scene.views[0].camera.c2w);
        let disparity: Vec<f64> = (0..2 * H)
            .flat_map(|y| (0..2 * W).map(move |x| (x, y)))
            .map(|(x, y)| {
                let r = fine.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
                let t = (0.3 * r.origin.x - r.origin.z) / (r.dir.z - 0.3 * r.dir.x);
                1.0 / (t * r.z_scale) as f64
            })
            .collect();
        crate::data::npy::write_npy_f64(&dir.join("v0.npy"), &[2 * H as usize, 2 * W as usize], &disparity).unwrap();
        let mut targets: StereoTargets = vec![Some(sparse_targets(&truth))];
        let fits = merge(&scene, &mut targets, &dir, MonoDepthKind::Disparity, 0.25).unwrap();
        assert!(fits[0].used && fits[0].filled > 0);
        let interior = |p: usize| (1..W as usize - 1).contains(&(p % W as usize)) && (1..H as usize - 1).contains(&(p / W as usize));
        for (p, [t, c]) in targets[0].as_ref().unwrap().iter().enumerate() {
            if *c == 0.25 && interior(p) {
                assert!((t - truth[p]).abs() < 2e-3 * truth[p], "pixel {p}: {t} against {}", truth[p]);
            }
        }
        // A map of another aspect ratio is refused.
        crate::data::npy::write_npy_f64(&dir.join("v0.npy"), &[H as usize, H as usize], &vec![1.0; (H * H) as usize]).unwrap();
        let err = merge(&scene, &mut vec![Some(sparse_targets(&truth))], &dir, MonoDepthKind::Disparity, 0.5).unwrap_err();
        assert!(err.contains("aspect ratios differ"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_trimmed_fit_ignores_outliers() {
        // y = 2 m + 1 on 80 points, 20 points far off.
        let mut pairs: Vec<(f64, f64)> = (0..80).map(|i| (i as f64 * 0.1, 2.0 * i as f64 * 0.1 + 1.0)).collect();
        pairs.extend((0..20).map(|i| (i as f64 * 0.4, -5.0 + i as f64)));
        let (a, b) = robust_affine(&pairs).unwrap();
        assert!((a - 2.0).abs() < 1e-9 && (b - 1.0).abs() < 1e-9, "{a} {b}");
        let (a, _) = affine(&pairs).unwrap();
        assert!((a - 2.0).abs() > 0.1, "the plain fit is tilted by the outliers: {a}");
    }

    #[test]
    fn resampling_keeps_a_linear_ramp_and_its_holes() {
        // A ramp in x at 8 x 4, resampled to 4 x 2: each output pixel centre maps to
        // the mean of two input centres.
        let ramp: Vec<f32> = (0..4).flat_map(|_| (0..8).map(|x| x as f32)).collect();
        let out = resample(&ramp, 8, 4, 4, 2);
        assert_eq!(out, vec![0.5, 2.5, 4.5, 6.5, 0.5, 2.5, 4.5, 6.5]);
        let mut holed = ramp.clone();
        holed[2] = f32::NAN;
        let out = resample(&holed, 8, 4, 4, 2);
        assert!(out[1].is_nan() && out[0].is_finite() && out[2].is_finite());
        assert_eq!(resample(&ramp, 8, 4, 8, 4), ramp);
    }
}
