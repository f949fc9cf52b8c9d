//! nerfstudio scenes: one `transforms.json` with every frame, as `ns-process-data`
//! writes it (conventions of nerfstudio's `nerfstudio_dataparser.py`).
//!
//! * Cameras: `transform_matrix` is camera-to-world in the OpenGL frame (nerfstudio's
//!   own convention, ours too), used as written. Intrinsics and lens (`fl_x`, `fl_y`,
//!   `cx`, `cy`, `w`, `h`, `camera_model`, `k1..k4`, `p1`, `p2`) at the top level or per
//!   frame, as the Blender reader reads them ([`super::blender`]); distorted cameras give
//!   distorted rays ([`super::Lens`]).
//! * `applied_transform` (3x4) is the world transform `ns-process-data` already applied
//!   to every `transform_matrix`: it maps the original (COLMAP) world to the file's
//!   (`[[1,0,0],[0,0,1],[0,-1,0]]` for COLMAP input, so that COLMAP's `-y` up becomes
//!   `+z`). The poses are *not* transformed again; the reader uses it (times
//!   `applied_scale`, if present) to bring the COLMAP model's points into the file's
//!   frame. nerfstudio's own orientation, centring and scaling at training time
//!   (`auto_orient_and_center_poses`) are not applied: the scene keeps the file's frame.
//! * Points: the PLY point cloud named by `ply_file_path` (relative to the folder, as
//!   `ns-process-data` writes `sparse_pc.ply`; ASCII or binary little-endian, `x y z`
//!   per vertex, already in the file's frame as nerfstudio reads it, so neither
//!   `applied_transform` nor `applied_scale` applies to it); without that key the COLMAP
//!   model `ns-process-data` leaves beside the file (`colmap/sparse/0`), else a
//!   `sparse/0` or `sparse` model in the same folder, if any. They bound the scene
//!   ([`super::bounds`]). A `ply_file_path` whose file is missing or not a PLY point
//!   cloud is an error (nerfstudio would fail on it too). The top-level `near`, `far`
//!   and `aabb` keys, when present, win over the points.
//! * Frames are sorted by `file_path` (as nerfstudio sorts them). Split: the file's
//!   `train_filenames` and `test_filenames` (else `val_filenames`) when present
//!   (training frames default to every frame not listed for testing); otherwise
//!   nerfstudio's default `fraction` mode with 0.9: `ceil(0.9 n)` training frames at
//!   `floor(linspace(0, n - 1, ceil(0.9 n)))`, the others test frames. With `k` views
//!   the training frames are `k` of those ([`super::linspace_indices`]).
//! * Per frame, optional: `mask_path` (grey image, 0 = pixel to ignore, nerfstudio's
//!   meaning; loaded as the view's mask and its training mask: batches draw only
//!   pixels above 0.5), `depth_file_path` (16-bit PNG or `.npy`
//!   z-depth times nerfstudio's `depth_unit_scale_factor` 1e-3, i.e. millimetres, stored
//!   as the view's ground-truth ray distance `z / cos`). Each must be given for every
//!   frame or none, and match the image size.
//! * Downsampling factor `N` ([`LoadOptions::llff_factor`], default 1): the image
//!   `images_N/<file name>` (masks `masks_N/`, depths `depths_N/`) when it exists, as
//!   nerfstudio looks them up, else the full file downsampled on load.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3, Mat4, Vec3};
use serde::Deserialize;

use super::blender::{Intrinsics, find_image, resolve};
use super::bounds::{Capture, finish_capture};
use super::colmap::{model_dir, read_model};
use super::image_io::{SizeGuard, load_grey16, load_mask, read_view_image_downscaled};
use super::npy::read_npy;
use super::resample::{resize_area, resize_nearest};
use super::split::{Split, subset_split};
use super::{DataError, LoadOptions, Scene, SceneFormat};

/// nerfstudio's default `depth_unit_scale_factor` (millimetres to metres).
const DEPTH_UNIT_SCALE: f32 = 1e-3;
/// nerfstudio's default `train_split_fraction`.
const TRAIN_FRACTION: f64 = 0.9;

#[derive(Deserialize)]
struct Transforms {
    #[serde(flatten)]
    intrinsics: Intrinsics,
    frames: Vec<Frame>,
    applied_transform: Option<[[f64; 4]; 3]>,
    applied_scale: Option<f64>,
    train_filenames: Option<Vec<String>>,
    val_filenames: Option<Vec<String>>,
    test_filenames: Option<Vec<String>>,
    near: Option<f32>,
    far: Option<f32>,
    aabb: Option<[[f32; 3]; 2]>,
    /// A PLY point cloud in the file's frame (`sparse_pc.ply` of `ns-process-data`).
    ply_file_path: Option<String>,
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: [[f32; 4]; 4],
    mask_path: Option<String>,
    depth_file_path: Option<String>,
    #[serde(flatten)]
    intrinsics: Intrinsics,
}

/// `rel` without leading `./`, for comparing file names across lists.
fn normal_name(rel: &str) -> &str {
    let mut r = rel;
    while let Some(s) = r.strip_prefix("./") {
        r = s;
    }
    r
}

/// nerfstudio's `get_train_eval_split_fraction`: training indices and test indices.
fn fraction_split(n: usize) -> (Vec<usize>, Vec<usize>) {
    let n_train = ((n as f64 * TRAIN_FRACTION).ceil() as usize).min(n);
    let train: Vec<usize> = match n_train {
        0 => Vec::new(),
        1 => vec![0],
        // np.linspace(0, n - 1, k, dtype=int): i * step, the last exactly n - 1, truncated.
        k => {
            let step = (n - 1) as f64 / (k - 1) as f64;
            (0..k).map(|i| if i == k - 1 { n - 1 } else { (i as f64 * step) as usize }).collect()
        }
    };
    let test = (0..n).filter(|i| !train.contains(i)).collect();
    (train, test)
}

/// The auxiliary file of a frame (mask or depth) at downsampling `factor`:
/// `<prefix>_N/<file name>` when it exists (and is then used as it is), else the
/// file itself, to be resampled; the bool says whether to resample.
fn aux_file(root: &Path, rel: &str, prefix: &str, factor: u32) -> (PathBuf, bool) {
    let full = resolve(root, rel);
    if factor > 1
        && let Some(name) = full.file_name()
    {
        let small = root.join(format!("{prefix}_{factor}")).join(name);
        if small.is_file() {
            return (small, false);
        }
    }
    (full, factor > 1)
}

/// A depth file's z-depth in scene units: `.npy` (2D, or 3D with one channel) or a grey
/// image, times [`DEPTH_UNIT_SCALE`].
fn load_depth_file(path: &Path) -> Result<(u32, u32, Vec<f32>), DataError> {
    if !path.is_file() {
        return Err(DataError::NotFound { path: path.to_path_buf(), what: "depth file (depth_file_path)" });
    }
    let (w, h, raw) = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy")) {
        let a = read_npy(path)?;
        match a.shape[..] {
            [h, w] | [h, w, 1] => (w as u32, h as u32, a.data.iter().map(|&v| v as f32).collect()),
            _ => {
                return Err(DataError::invalid(
                    path,
                    format!("depth array of shape {}: expected (height, width) or (height, width, 1)", a.shape_string()),
                ));
            }
        }
    } else {
        load_grey16(path)?
    };
    Ok((w, h, raw.into_iter().map(|v| v * DEPTH_UNIT_SCALE).collect()))
}

/// `applied_transform` (times `applied_scale`) as a map of points, checked rigid.
fn applied_map(t: &Transforms, json: &Path) -> Result<impl Fn(Vec3) -> Vec3, DataError> {
    let m = t.applied_transform.unwrap_or([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]);
    let r = DMat3::from_cols_array_2d(&[[m[0][0], m[1][0], m[2][0]], [m[0][1], m[1][1], m[2][1]], [m[0][2], m[1][2], m[2][2]]]);
    let tr = DVec3::new(m[0][3], m[1][3], m[2][3]);
    let s = t.applied_scale.unwrap_or(1.0);
    let gram = r.transpose() * r;
    let rigid = (gram - DMat3::IDENTITY).to_cols_array().iter().all(|v| v.abs() < 1e-3) && r.determinant() > 0.0;
    if !(rigid && tr.is_finite() && s.is_finite() && s > 0.0) {
        return Err(DataError::invalid(
            json,
            "applied_transform must be a 3x4 rotation-and-translation matrix (and applied_scale positive); fix or remove it",
        ));
    }
    Ok(move |p: Vec3| ((r * p.as_dvec3() + tr) * s).as_vec3())
}

pub(super) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let json = root.join("transforms.json");
    let text = std::fs::read_to_string(&json).map_err(|e| DataError::io(&json, e))?;
    let mut t: Transforms = serde_json::from_str(&text).map_err(|source| DataError::Json { path: json.clone(), source })?;
    if t.frames.is_empty() {
        return Err(DataError::invalid(&json, "the file lists no frames; add at least one frame"));
    }
    t.frames.sort_by(|a, b| a.file_path.cmp(&b.file_path));
    let n = t.frames.len();
    for (key, count) in [
        ("mask_path", t.frames.iter().filter(|f| f.mask_path.is_some()).count()),
        ("depth_file_path", t.frames.iter().filter(|f| f.depth_file_path.is_some()).count()),
    ] {
        if count != 0 && count != n {
            return Err(DataError::invalid(&json, format!("{key} is given for {count} of {n} frames: give it for every frame or none")));
        }
    }

    // The split over the sorted frames.
    let names: Vec<&str> = t.frames.iter().map(|f| normal_name(&f.file_path)).collect();
    let listed = |list: &Option<Vec<String>>, key: &str| -> Result<Option<Vec<usize>>, DataError> {
        let Some(list) = list else { return Ok(None) };
        let wanted: HashSet<&str> = list.iter().map(|s| normal_name(s)).collect();
        if let Some(missing) = wanted.iter().find(|w| !names.contains(w)) {
            return Err(DataError::invalid(&json, format!("{key} names {missing:?}, which is no frame's file_path")));
        }
        Ok(Some((0..n).filter(|&i| wanted.contains(names[i])).collect()))
    };
    let test_list = match listed(&t.test_filenames, "test_filenames")? {
        Some(l) => Some(l),
        None => listed(&t.val_filenames, "val_filenames")?,
    };
    let (candidates, test) = match (listed(&t.train_filenames, "train_filenames")?, test_list) {
        (None, None) => fraction_split(n),
        (train, test) => {
            let test = test.unwrap_or_default();
            (train.unwrap_or_else(|| (0..n).filter(|i| !test.contains(i)).collect()), test)
        }
    };
    if let Some(i) = candidates.iter().find(|i| test.contains(i)) {
        return Err(DataError::invalid(&json, format!("frame {:?} is listed for both training and testing", names[*i])));
    }
    let chosen = subset_split(candidates.len(), opts.views).map_err(|m| DataError::invalid(&json, m))?;
    let split = Split { train: chosen.into_iter().map(|i| candidates[i]).collect(), test };

    let factor = opts.llff_factor.unwrap_or(SceneFormat::Nerfstudio.default_downscale());
    let mut guard = SizeGuard::default();
    let mut any_alpha = false;
    let mut views = Vec::with_capacity(n);
    for frame in &t.frames {
        let what = || format!("frame '{}' of {}", frame.file_path, json.display());
        let (path, resample) = match aux_file(root, &frame.file_path, "images", factor) {
            (p, false) if factor > 1 => (p, 1),
            _ => {
                let p = find_image(root, &frame.file_path)
                    .ok_or_else(|| DataError::MissingImage { path: resolve(root, &frame.file_path), pose: what() })?;
                (p, factor)
            }
        };
        let c2w = Mat4::from_cols_array_2d(&frame.transform_matrix).transpose();
        let intrinsics = t.intrinsics.under(&frame.intrinsics);
        let img = read_view_image_downscaled(&path, resample, opts.load_images, opts.background, &mut guard)?;
        let size = (img.info.width, img.info.height);
        any_alpha |= img.info.has_alpha;
        let camera = intrinsics
            .camera(size.0, size.1, c2w)
            .and_then(|c| c.check().map(|()| c))
            .map_err(|m| DataError::NonFinite { path: json.clone(), what: format!("{}: {m}", what()) })?;
        let mut view = img.into_view(path, camera);
        if let Some(rel) = frame.mask_path.as_deref().filter(|_| opts.load_images) {
            let (p, resample) = aux_file(root, rel, "masks", factor);
            let (w, h, mask) = load_mask(&p)?;
            let mask = fit(&p, &view.path, (w, h), size, resample, mask, false)?;
            view.train_mask = Some(mask.clone());
            view.mask = Some(mask);
        }
        if let Some(rel) = frame.depth_file_path.as_deref().filter(|_| opts.load_images) {
            let (p, resample) = aux_file(root, rel, "depths", factor);
            let (w, h, z) = load_depth_file(&p)?;
            let z = fit(&p, &view.path, (w, h), size, resample, z, true)?;
            // z-depth to ray distance along each pixel's ray.
            let rays = view.camera.pixel_rays();
            view.depth = Some(z.iter().zip(&rays).map(|(&z, r)| if r.z_scale > 0.0 { z / r.z_scale } else { 0.0 }).collect());
        }
        views.push(view);
    }

    // The file's point cloud, else the COLMAP model beside the file brought into the
    // file's frame.
    let to_file = applied_map(&t, &json)?;
    let mut points = Vec::new();
    if let Some(rel) = &t.ply_file_path {
        points = read_point_cloud(&resolve(root, rel), &json)?;
    } else {
        for dir in [root.join("colmap"), root.to_path_buf()] {
            if let Ok((model, binary)) = model_dir(&dir) {
                points = read_model(&model, binary)?.points.into_iter().map(&to_file).collect();
                break;
            }
        }
    }
    let capture = Capture {
        views,
        split,
        points,
        near_far: [t.near, t.far],
        aabb: t.aabb.map(|[lo, hi]| [Vec3::from(lo), Vec3::from(hi)]),
        background: any_alpha.then_some(opts.background),
    };
    finish_capture(root, SceneFormat::Nerfstudio, &json, capture)
}

/// The vertices of the PLY point cloud at `path` (`ply_file_path` of `json`): at least
/// one, each finite (the reader refuses others).
fn read_point_cloud(path: &Path, json: &Path) -> Result<Vec<Vec3>, DataError> {
    let bytes = std::fs::read(path).map_err(|e| {
        DataError::invalid(
            json,
            format!("ply_file_path names {}, which cannot be read ({e}); restore the file or remove the key", path.display()),
        )
    })?;
    let cloud = crate::mesh::ply::read_ply(&bytes).map_err(|e| DataError::invalid(path, format!("the point cloud of ply_file_path: {e}")))?;
    if cloud.positions.is_empty() {
        return Err(DataError::invalid(path, "the point cloud of ply_file_path has no vertices; remove the key or write the points"));
    }
    Ok(cloud.positions)
}

/// A mask or depth map `values` of size `got` from `path`, brought to the image's
/// `size`: resampled when it is the full-resolution file of a downsampled image
/// (`resample`; depth by nearest neighbour, masks by area), else it must match.
fn fit(
    path: &Path,
    image: &Path,
    got: (u32, u32),
    size: (u32, u32),
    resample: bool,
    values: Vec<f32>,
    depth: bool,
) -> Result<Vec<f32>, DataError> {
    if got == size {
        return Ok(values);
    }
    if resample {
        return Ok(if depth { resize_nearest(&values, 1, got, size) } else { resize_area(&values, 1, got, size) });
    }
    Err(DataError::SizeMismatch { path: path.to_path_buf(), reference: image.to_path_buf(), got, expected: size })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nerfstudio_fraction_split() {
        // n = 10: ceil(9) = 9 training frames at floor(linspace(0, 9, 9)) = 0 1 2 3 4 5 6 7 9.
        let (train, test) = fraction_split(10);
        assert_eq!(train, vec![0, 1, 2, 3, 4, 5, 6, 7, 9]);
        assert_eq!(test, vec![8]);
        // n = 24: 22 training frames; floor(linspace(0, 23, 22)) skips 11 and 22.
        let (train, test) = fraction_split(24);
        assert_eq!(train.len(), 22);
        assert_eq!(test, vec![11, 22]);
        assert_eq!(fraction_split(1), (vec![0], vec![]));
    }
}
