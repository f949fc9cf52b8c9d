//! LLFF forward-facing scenes: `poses_bounds.npy` + `images_{factor}/`, NeRF/RegNeRF style.
//!
//! Processing, in order (all in `f64`, as NeRF's `load_llff_data` with `recenter=True`,
//! `bd_factor=0.75`, no spherify):
//! 1. `poses_bounds.npy` is `N x 17`: a row-major `3 x 5` matrix `[R | t | (h, w, f)]`
//!    per image, then the near and far scene bounds.
//! 2. Axis fix from LLFF's `[down, right, back]` camera axes to `[right, up, back]`
//!    (OpenGL): columns `(c0, c1, c2)` become `(c1, -c0, c2)`.
//! 3. Rescale so the closest bound sits at 1/0.75: `sc = 1 / (min bound * 0.75)`
//!    multiplies every camera position (and the bounds).
//! 4. Recentre: the average pose (mean centre, summed `z` and `up` axes
//!    re-orthonormalised) is inverted and applied to every pose.
//! 5. Focal length `f` is scaled by the ratio of the loaded image size to the `(h, w)`
//!    stored in the file (per axis); the principal point is the image centre.
//!
//! Rays are NDC rays ([`NdcParams`] with `near = 1.0`): the scene's `near` is `0`, its
//! `far` `1` (infinity; with [`super::LoadOptions::ndc_far_bound`] the NDC ray parameter
//! of [`NDC_FAR_MARGIN`] times the largest far bound, [`ndc_far`]), and its `aabb` is the
//! NDC slab `[-1.5, 1.5]^2 x [-1, 1]`: wider than the
//! NDC cube in x and y because cameras rotated off the mean axis (fern: up to ~9 deg)
//! send border rays up to ~1.44 sideways before they reach z = 1. Images are the image files of
//! `images_{factor}` (`images` for factor 1; [`LoadOptions::llff_factor`], the CLI's
//! `--llff-factor`, default 8) sorted by name, one per pose in order; without that folder
//! the images of `images` are downsampled by the factor on load ([`super::resample`],
//! area averaging to `round(size / factor)`, as NeRF's `_minify` writes `images_N`), and
//! without either the error lists the image folders the scene has. Every pose must be rigid ([`super::camera::check_rigid`]).
//! Split: [`llff_split`].

use std::path::Path;

use glam::{DMat4, DVec3, Vec3};

use super::image_io::{SizeGuard, list_images, read_view_image_downscaled};
use super::npy::read_npy;
use super::{Camera, DataError, LoadOptions, NdcParams, Scene, SceneFormat, View, llff_split};

/// NeRF's `bd_factor`: the closest scene bound ends up at `1 / BD_FACTOR`.
pub(super) const BD_FACTOR: f64 = 0.75;
/// World distance of the NDC near plane after rescaling.
const NDC_NEAR: f32 = 1.0;
/// With [`super::LoadOptions::ndc_far_bound`], forward-facing rays end at this multiple
/// of the capture's farthest content depth (LLFF's largest far bound, a COLMAP model's
/// farthest points) rather than at infinity: behind every surface the capture saw
/// there is nothing a photograph needs, and the march there is spent on fog. The
/// margin covers cameras off the mean plane (depths are per view, the NDC plane is the
/// mean pose's). Val views, 3 views (2026-12-08, docs/results/fern.md, "Rays that end
/// past the far bound"): fern at seeds 0 / 1, 1.1 against 1.5, and the kept-aside
/// `hallway` as a nerfstudio capture.
pub const NDC_FAR_MARGIN: f64 = 1.1;

/// The NDC ray parameter at which forward-facing rays end: that of [`NDC_FAR_MARGIN`]
/// times `far_depth`, the capture's farthest content depth in the rescaled units
/// (`t = 1 - near / depth`); 1 (infinity) without a finite depth past the near plane.
pub(super) fn ndc_far(far_depth: Option<f64>) -> f32 {
    match far_depth.map(|d| d * NDC_FAR_MARGIN) {
        Some(d) if d.is_finite() && d > f64::from(NDC_NEAR) => (1.0 - f64::from(NDC_NEAR) / d) as f32,
        _ => 1.0,
    }
}

/// The image folder for a downsampling factor.
pub(crate) fn image_dir_name(factor: u32) -> String {
    if factor <= 1 {
        "images".to_string()
    } else {
        format!("images_{factor}")
    }
}

/// Where the images of downsampling `factor` come from: `root/images_{factor}` read as
/// they are (resample factor 1), else `root/images` downsampled by `factor` on load;
/// `None` when neither folder exists.
pub(super) fn image_folder(root: &Path, factor: u32) -> Option<(std::path::PathBuf, u32)> {
    let wanted = root.join(image_dir_name(factor));
    if wanted.is_dir() {
        return Some((wanted, 1));
    }
    let full = root.join("images");
    full.is_dir().then_some((full, factor))
}

/// The error for a missing `images_{factor}` folder: which image folders the scene
/// has, and the `--llff-factor` that reads one.
fn missing_image_dir(root: &Path, factor: u32) -> DataError {
    let mut present: Vec<String> = std::fs::read_dir(root)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .filter(|e| e.path().is_dir())
                .filter_map(|e| e.file_name().to_str().map(str::to_string))
                .filter(|n| n == "images" || n.strip_prefix("images_").is_some_and(|f| f.parse::<u32>().is_ok()))
                .collect()
        })
        .unwrap_or_default();
    present.sort();
    let wanted = image_dir_name(factor);
    let hint = match present.first() {
        None => "the scene has no images or images_N folder: add the images (LLFF's imgs2poses writes images/, \
                 NeRF's loader images_N/ downsampled by N)"
            .to_string(),
        Some(_) => {
            let flags: Vec<String> = present
                .iter()
                .map(|n| format!("{n} (--llff-factor {})", n.strip_prefix("images_").unwrap_or("1")))
                .collect();
            format!("the scene has {}; pass the factor of one of them, or create {wanted} by downsampling the images", flags.join(", "))
        }
    };
    DataError::invalid(
        root.join(&wanted),
        format!("LLFF image folder {wanted} (downsampling factor {factor}) not found; {hint}"),
    )
}

/// One pose from `poses_bounds.npy`, after the axis fix.
struct RawPose {
    c2w: DMat4,
    /// Original image height, width and focal length in pixels.
    hwf: [f64; 3],
    bounds: [f64; 2],
}

fn parse_row(row: &[f64]) -> RawPose {
    let m = |r: usize, c: usize| row[r * 5 + c];
    let col = |c: usize| DVec3::new(m(0, c), m(1, c), m(2, c));
    // [down, right, back] -> [right, up, back].
    let (x, y, z) = (col(1), -col(0), col(2));
    RawPose {
        c2w: DMat4::from_cols(
            x.extend(0.0),
            y.extend(0.0),
            z.extend(0.0),
            col(3).extend(1.0),
        ),
        hwf: [m(0, 4), m(1, 4), m(2, 4)],
        bounds: [row[15], row[16]],
    }
}

/// NeRF's `poses_avg`: mean centre, axes from the summed `z` and `up` vectors.
fn average_pose(poses: &[DMat4]) -> DMat4 {
    let n = poses.len() as f64;
    let center = poses.iter().map(|p| p.w_axis.truncate()).sum::<DVec3>() / n;
    let z = poses
        .iter()
        .map(|p| p.z_axis.truncate())
        .sum::<DVec3>()
        .normalize();
    let up = poses.iter().map(|p| p.y_axis.truncate()).sum::<DVec3>();
    let x = up.cross(z).normalize();
    let y = z.cross(x).normalize();
    DMat4::from_cols(
        x.extend(0.0),
        y.extend(0.0),
        z.extend(0.0),
        center.extend(1.0),
    )
}

/// The scene's depth bounds (the smallest near and the largest far bound of
/// `poses_bounds.npy`) in the units [`load`] gives the scene: rescaled as the camera
/// positions are (the near bound becomes `1 / BD_FACTOR`). The loaded scene keeps at
/// most the far one, as the NDC ray parameter its rays end at
/// ([`super::LoadOptions::ndc_far_bound`]); NeRF's spiral path focuses between these
/// (`super::paths`).
pub(super) fn world_bounds(root: &Path) -> Result<[f32; 2], DataError> {
    let path = root.join("poses_bounds.npy");
    let array = read_npy(&path)?;
    array.expect_shape(&path, "poses_bounds", &[None, Some(17)])?;
    let (near, far) = (0..array.shape[0])
        .map(|i| array.row(i))
        .fold((f64::INFINITY, 0.0f64), |(n, f), row| (n.min(row[15]), f.max(row[16])));
    if !(near > 0.0 && near.is_finite() && far.is_finite() && far >= near) {
        return Err(DataError::invalid(
            &path,
            format!("scene bounds near {near} / far {far}: need finite 0 < near <= far; regenerate it with LLFF's imgs2poses"),
        ));
    }
    let sc = 1.0 / (near * BD_FACTOR);
    Ok([(near * sc) as f32, (far * sc) as f32])
}

pub(super) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let poses_path = root.join("poses_bounds.npy");
    let array = read_npy(&poses_path)?;
    array.expect_shape(&poses_path, "poses_bounds", &[None, Some(17)])?;
    let n = array.shape[0];
    if n == 0 {
        return Err(DataError::invalid(
            &poses_path,
            "the file holds no poses (shape (0, 17))",
        ));
    }
    let mut raw = Vec::with_capacity(n);
    for i in 0..n {
        let row = array.row(i);
        if let Some(j) = row.iter().position(|v| !v.is_finite()) {
            return Err(DataError::NonFinite {
                path: poses_path.clone(),
                what: format!(
                    "row {i} (pose of image {i}) has value {} at column {j}",
                    row[j]
                ),
            });
        }
        let pose = parse_row(row);
        if let Err(m) = super::camera::check_rigid(&pose.c2w.as_mat4()) {
            return Err(DataError::NonFinite {
                path: poses_path.clone(),
                what: format!("row {i} (pose of image {i}): {m}"),
            });
        }
        if pose.bounds[0] <= 0.0 || pose.hwf.iter().any(|&v| v <= 0.0) {
            return Err(DataError::invalid(
                &poses_path,
                format!(
                    "row {i} has a non-positive near bound, image size or focal length; regenerate it with LLFF's imgs2poses"
                ),
            ));
        }
        raw.push(pose);
    }

    let factor = opts.llff_factor.unwrap_or(SceneFormat::Llff.default_downscale());
    let (image_dir, resample_factor) = image_folder(root, factor).ok_or_else(|| missing_image_dir(root, factor))?;
    let files = list_images(&image_dir, "LLFF image folder")?;
    if files.len() != n {
        return Err(DataError::CountMismatch {
            path: image_dir,
            images: files.len(),
            cameras: n,
        });
    }

    // Rescale and recentre the poses.
    let min_bound = raw
        .iter()
        .map(|p| p.bounds[0])
        .fold(f64::INFINITY, f64::min);
    let (poses, sc) = normalize_forward_facing(&raw.iter().map(|p| p.c2w).collect::<Vec<_>>(), min_bound);
    let far_bound = raw.iter().map(|p| p.bounds[1]).fold(0.0, f64::max);

    let mut guard = SizeGuard::default();
    let mut views = Vec::with_capacity(n);
    for (i, (path, pose)) in files.iter().zip(&poses).enumerate() {
        let img = read_view_image_downscaled(path, resample_factor, opts.load_images, [0.0; 3], &mut guard)?;
        let (w, h) = (img.info.width, img.info.height);
        let [h0, w0, f] = raw[i].hwf;
        let (sx, sy) = (w as f64 / w0, h as f64 / h0);
        if (sx / sy - 1.0).abs() > 0.02 {
            return Err(DataError::invalid(
                path,
                format!(
                    "image is {w}x{h} but poses_bounds.npy row {i} describes a {w0}x{h0} image \
                     (different aspect ratio); the images do not belong to these poses"
                ),
            ));
        }
        let camera = Camera {
            width: w,
            height: h,
            fx: (f * sx) as f32,
            fy: (f * sy) as f32,
            cx: 0.5 * w as f32,
            cy: 0.5 * h as f32,
            c2w: pose.as_mat4(),
            lens: Default::default(),
        };
        if let Err(m) = camera.check() {
            return Err(DataError::NonFinite {
                path: poses_path.clone(),
                what: format!("row {i} (pose of image {i}), after recentring: {m}"),
            });
        }
        views.push(img.into_view(path.clone(), camera));
    }

    let split = llff_split(n, opts.views).map_err(|m| DataError::invalid(root, m))?;
    Ok(ndc_scene(root, SceneFormat::Llff, views, split, Some(far_bound * sc)))
}

/// Steps 3 and 4 of the module doc on camera-to-world poses (OpenGL frame) whose
/// closest scene content lies `min_near` in front of them: the poses rescaled by
/// `sc = 1 / (min_near * BD_FACTOR)` and recentred on their average pose, and `sc`.
/// COLMAP and nerfstudio captures that face one way go through it too.
pub(super) fn normalize_forward_facing(c2w: &[DMat4], min_near: f64) -> (Vec<DMat4>, f64) {
    let sc = 1.0 / (min_near * BD_FACTOR);
    let mut poses: Vec<DMat4> = c2w
        .iter()
        .map(|p| {
            let mut c2w = *p;
            c2w.w_axis = (c2w.w_axis.truncate() * sc).extend(1.0);
            c2w
        })
        .collect();
    let inv_avg = average_pose(&poses).inverse();
    for pose in &mut poses {
        *pose = inv_avg * *pose;
    }
    (poses, sc)
}

/// A forward-facing scene of normalised views ([`normalize_forward_facing`]): NDC
/// rays from the first view's intrinsics, near 0, far [`ndc_far`] of `far_depth` (the
/// farthest content depth in the normalised units, if the capture gives one) and the
/// NDC slab of the module doc.
pub(super) fn ndc_scene(root: &Path, format: SceneFormat, views: Vec<View>, split: super::Split, far_depth: Option<f64>) -> Scene {
    let c0 = views[0].camera;
    Scene {
        root: root.to_path_buf(),
        format,
        views,
        split,
        near: 0.0,
        far: ndc_far(far_depth),
        ndc: Some(NdcParams {
            focal_x: c0.fx,
            focal_y: c0.fy,
            width: c0.width as f32,
            height: c0.height as f32,
            near: NDC_NEAR,
        }),
        aabb: [Vec3::new(-1.5, -1.5, -1.0), Vec3::new(1.5, 1.5, 1.0)],
        background: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_end_past_the_far_bound_or_at_infinity() {
        // t = 1 - near / (1.1 depth): a far bound of 10 ends the rays at 1 - 1 / 11.
        assert!((ndc_far(Some(10.0)) - (1.0 - 1.0 / 11.0)).abs() < 1e-7);
        // Farther content ends them later, never past infinity.
        assert!(ndc_far(Some(100.0)) > ndc_far(Some(10.0)) && ndc_far(Some(1e30)) <= 1.0);
        // No bound, or none past the near plane: infinity.
        for depth in [None, Some(0.5), Some(f64::INFINITY), Some(f64::NAN)] {
            assert_eq!(ndc_far(depth), 1.0, "{depth:?}");
        }
    }
}
