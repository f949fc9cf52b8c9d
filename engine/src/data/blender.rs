//! NeRF-synthetic / Blender scenes (`transforms_{train,val,test}.json`), including our
//! Mitsuba-rendered synthetic scenes with ground truth.
//!
//! * Cameras: `transform_matrix` is the camera-to-world matrix (rows, OpenGL frame),
//!   rigid ([`Camera::check`]). Intrinsics: `fl_x` (and `fl_y`, `cx`, `cy`, defaulting
//!   to `fl_x` and the image centre) for an image of `w x h` (default: the image's
//!   size), scaled to the loaded image size; otherwise `camera_angle_x` with a centred
//!   principal point. Each key may also be given per frame (nerfstudio does so when
//!   cameras differ), where it wins over the top level's. Lens: nerfstudio's
//!   `camera_model` (`PINHOLE`, `SIMPLE_PINHOLE`, `SIMPLE_RADIAL`, `RADIAL`, `OPENCV`
//!   with `k1..k4`, `p1`, `p2`; `OPENCV_FISHEYE` with `k1..k4`; default `PINHOLE`, with
//!   the distortion keys still applied, as nerfstudio does), rays generated through it
//!   ([`Lens`]); any other model and Instant-NGP's `is_fisheye` are errors, never
//!   silently dropped. nerfstudio's single `transforms.json` has its own reader
//!   (`super::nerfstudio`) on the same keys.
//! * Frames: `file_path` relative to the scene root, a leading `./` allowed, with or
//!   without extension (`.png`, `.jpg`, `.jpeg` are tried). RGBA images are composited
//!   over [`LoadOptions::background`] and `Scene::background` is set to it.
//! * Ground truth (optional per-frame keys): `depth_path` (EXR, channel `Y`, ray
//!   distance), `normal_path` (EXR, `R`,`G`,`B` = world normal), `mask_path` (8-bit
//!   grayscale PNG, 255 = object). Without `mask_path`, the alpha channel (if any) is the
//!   view's mask. All must match the image size.
//! * Scene: `near`/`far` from the top-level keys, else NeRF-synthetic's 2 / 6. `aabb`
//!   (`[[minx, miny, minz], [maxx, maxy, maxz]]`) from the top-level key, else
//!   `[-1.5, 1.5]^3` when the file has no `near`/`far` either (NeRF-synthetic), else a
//!   cube centred at the origin with half-size `mean camera distance - near` (or
//!   `(far - near) / 2` when the cameras are closer than `near`).
//! * Split: train = `transforms_train.json`, or `k` of its frames at
//!   `round(linspace(0, n_train - 1, k))`; test = `transforms_test.json`
//!   (`transforms_val.json` only when there is no test file). `Scene::views` holds the
//!   selected training frames (in that order) followed by the test frames; unselected
//!   training frames follow those with [`LoadOptions::unused_views`] (the `val` split),
//!   and are not loaded otherwise.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};
use serde::Deserialize;

use super::image_io::{
    SizeGuard, file_stem, load_depth_exr, load_normal_exr, read_view_image, read_view_mask,
};
use super::split::{Split, subset_split};
use super::{Camera, DataError, Lens, LoadOptions, Scene, SceneFormat, View};

/// NeRF-synthetic's near / far.
const DEFAULT_NEAR_FAR: (f32, f32) = (2.0, 6.0);
/// NeRF-synthetic's scene box half-size.
const DEFAULT_HALF_EXTENT: f32 = 1.5;
const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "PNG", "JPG"];

#[derive(Deserialize)]
struct Transforms {
    #[serde(flatten)]
    intrinsics: Intrinsics,
    near: Option<f32>,
    far: Option<f32>,
    aabb: Option<[[f32; 3]; 2]>,
    frames: Vec<Frame>,
}

#[derive(Deserialize)]
struct Frame {
    file_path: String,
    transform_matrix: [[f32; 4]; 4],
    depth_path: Option<String>,
    normal_path: Option<String>,
    mask_path: Option<String>,
    /// nerfstudio writes intrinsics per frame when the cameras differ.
    #[serde(flatten)]
    intrinsics: Intrinsics,
}

/// The keys that define how pixels map to rays, at the top level of the file or per
/// frame (a frame's own value wins), nerfstudio's lens keys included ([`Lens`]).
#[derive(Clone, Debug, Default, Deserialize)]
pub(super) struct Intrinsics {
    camera_angle_x: Option<f32>,
    fl_x: Option<f32>,
    fl_y: Option<f32>,
    cx: Option<f32>,
    cy: Option<f32>,
    w: Option<f32>,
    h: Option<f32>,
    /// nerfstudio / COLMAP camera model name.
    camera_model: Option<String>,
    /// Instant-NGP's fisheye switch.
    is_fisheye: Option<bool>,
    k1: Option<f32>,
    k2: Option<f32>,
    k3: Option<f32>,
    k4: Option<f32>,
    p1: Option<f32>,
    p2: Option<f32>,
}

/// Camera models with a perspective projection, read with [`Lens::OpenCv`] (zero
/// terms: [`Lens::Pinhole`]); nerfstudio's `CAMERA_MODEL_TO_TYPE` maps them to its
/// `PERSPECTIVE` type.
const PERSPECTIVE_MODELS: [&str; 5] = ["PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL"];
/// The fisheye model ([`Lens::Fisheye`]).
const FISHEYE_MODEL: &str = "OPENCV_FISHEYE";

impl Intrinsics {
    /// `frame`'s keys over `self` (the file's top level). The focal length is taken
    /// whole: a frame that sets `camera_angle_x` and no `fl_x` uses the angle, not the
    /// top level's `fl_x`, and one that sets `fl_x` without `fl_y` has `fl_y = fl_x`.
    pub(super) fn under(&self, frame: &Intrinsics) -> Intrinsics {
        let angle_only = frame.camera_angle_x.is_some() && frame.fl_x.is_none();
        let pick = |f: Option<f32>, t: Option<f32>| f.or(t);
        Intrinsics {
            camera_angle_x: pick(frame.camera_angle_x, self.camera_angle_x),
            fl_x: if angle_only { None } else { pick(frame.fl_x, self.fl_x) },
            fl_y: match (angle_only, frame.fl_x) {
                (true, _) => None,
                (false, Some(_)) => frame.fl_y,
                (false, None) => pick(frame.fl_y, self.fl_y),
            },
            cx: pick(frame.cx, self.cx),
            cy: pick(frame.cy, self.cy),
            w: pick(frame.w, self.w),
            h: pick(frame.h, self.h),
            camera_model: frame.camera_model.clone().or_else(|| self.camera_model.clone()),
            is_fisheye: frame.is_fisheye.or(self.is_fisheye),
            k1: pick(frame.k1, self.k1),
            k2: pick(frame.k2, self.k2),
            k3: pick(frame.k3, self.k3),
            k4: pick(frame.k4, self.k4),
            p1: pick(frame.p1, self.p1),
            p2: pick(frame.p2, self.p2),
        }
    }

    /// The lens the keys describe: `camera_model` (default `PINHOLE`) with `k1..k4`,
    /// `p1`, `p2` (default 0). Refuses what the ray generator cannot honour (other models,
    /// Instant-NGP's `is_fisheye`, tangential terms on a fisheye) instead of dropping it.
    fn lens(&self) -> Result<Lens, String> {
        const MODELS: &str = "PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV (k1..k4, p1, p2) or OPENCV_FISHEYE (k1..k4)";
        let z = |v: Option<f32>| v.unwrap_or(0.0);
        let k = [z(self.k1), z(self.k2), z(self.k3), z(self.k4)];
        let p = [z(self.p1), z(self.p2)];
        if self.is_fisheye == Some(true) {
            return Err(format!(
                "is_fisheye (Instant-NGP's switch) is not supported; write camera_model OPENCV_FISHEYE with k1..k4 instead (supported models: {MODELS})"
            ));
        }
        let lens = match self.camera_model.as_deref() {
            None => Lens::opencv(k, p),
            Some(m) if PERSPECTIVE_MODELS.contains(&m) => Lens::opencv(k, p),
            Some(FISHEYE_MODEL) if p.iter().any(|&v| v != 0.0) => {
                return Err(format!("camera_model OPENCV_FISHEYE has no tangential terms but p1 {} / p2 {} are set", p[0], p[1]));
            }
            Some(FISHEYE_MODEL) => Lens::Fisheye { k },
            Some(m) => {
                return Err(format!(
                    "camera_model {m:?} is not supported (supported: {MODELS}); undistort the images (e.g. COLMAP's image_undistorter) and write PINHOLE"
                ));
            }
        };
        lens.check()?;
        Ok(lens)
    }

    /// The camera of a `width x height` image with pose `c2w`, its lens included.
    pub(super) fn camera(&self, width: u32, height: u32, c2w: Mat4) -> Result<Camera, String> {
        let lens = self.lens()?;
        let (w, h) = (width as f32, height as f32);
        if let Some(fl_x) = self.fl_x {
            let (w0, h0) = (self.w.unwrap_or(w), self.h.unwrap_or(h));
            if !(w0 > 0.0 && h0 > 0.0) {
                return Err(format!("w {w0} / h {h0} must be positive"));
            }
            let (sx, sy) = (w / w0, h / h0);
            return Ok(Camera {
                width,
                height,
                fx: fl_x * sx,
                fy: self.fl_y.unwrap_or(fl_x) * sy,
                cx: self.cx.unwrap_or(0.5 * w0) * sx,
                cy: self.cy.unwrap_or(0.5 * h0) * sy,
                c2w,
                lens,
            });
        }
        match self.camera_angle_x {
            Some(angle) if angle > 0.0 && angle < std::f32::consts::PI => {
                Ok(Camera { lens, ..Camera::from_fov_x(width, height, angle, c2w) })
            }
            Some(angle) => Err(format!("camera_angle_x = {angle} must be a field of view in radians, in (0, pi)")),
            None => Err("no intrinsics: add camera_angle_x or fl_x/fl_y/cx/cy/w/h".into()),
        }
    }
}

fn read_transforms(path: &Path) -> Result<Transforms, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    serde_json::from_str(&text).map_err(|source| DataError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// `rel` (optionally starting with `./`) under `root`.
pub(super) fn resolve(root: &Path, rel: &str) -> PathBuf {
    let mut rel = rel;
    while let Some(r) = rel.strip_prefix("./") {
        rel = r;
    }
    root.join(rel)
}

/// The image of a frame: `file_path` as given, or with an image extension appended.
pub(super) fn find_image(root: &Path, file_path: &str) -> Option<PathBuf> {
    let base = resolve(root, file_path);
    if base.is_file() {
        return Some(base);
    }
    IMAGE_EXTENSIONS
        .iter()
        .map(|ext| PathBuf::from(format!("{}.{ext}", base.display())))
        .find(|p| p.is_file())
}

/// Per-scene state shared by the frames being loaded.
struct Loader<'a> {
    root: &'a Path,
    opts: &'a LoadOptions,
    guard: SizeGuard,
    any_alpha: bool,
}

impl Loader<'_> {
    fn frame(&mut self, json: &Path, t: &Transforms, i: usize) -> Result<View, DataError> {
        let frame = &t.frames[i];
        let what = || format!("frame {i} ('{}') of {}", frame.file_path, json.display());
        let path =
            find_image(self.root, &frame.file_path).ok_or_else(|| DataError::MissingImage {
                path: resolve(self.root, &frame.file_path),
                pose: what(),
            })?;
        let c2w = Mat4::from_cols_array_2d(&frame.transform_matrix).transpose();
        let intrinsics = t.intrinsics.under(&frame.intrinsics);
        intrinsics.lens().map_err(|m| DataError::invalid(json, format!("{}: {m}", what())))?;
        let img = read_view_image(
            &path,
            self.opts.load_images,
            self.opts.background,
            &mut self.guard,
        )?;
        let size = (img.info.width, img.info.height);
        self.any_alpha |= img.info.has_alpha;
        let camera = intrinsics
            .camera(size.0, size.1, c2w)
            .and_then(|c| c.check().map(|()| c))
            .map_err(|m| DataError::NonFinite { path: json.to_path_buf(), what: format!("{}: {m}", what()) })?;
        let mut view = View {
            name: file_stem(&path),
            path,
            camera,
            image: img.image,
            mask: img.alpha.clone(),
            alpha: img.alpha,
            depth: None,
            normal: None,
            train_mask: None,
        };
        if !self.opts.load_images {
            return Ok(view);
        }
        let mismatch = |gt: &Path, got: (u32, u32), image: &Path| DataError::SizeMismatch {
            path: gt.to_path_buf(),
            reference: image.to_path_buf(),
            got,
            expected: size,
        };
        if let Some(rel) = &frame.mask_path {
            view.mask = Some(read_view_mask(&resolve(self.root, rel), &view.path, size)?);
        }
        if let Some(rel) = &frame.depth_path {
            let p = resolve(self.root, rel);
            let (w, h, depth) = load_depth_exr(&p)?;
            if (w, h) != size {
                return Err(mismatch(&p, (w, h), &view.path));
            }
            view.depth = Some(depth);
        }
        if let Some(rel) = &frame.normal_path {
            let p = resolve(self.root, rel);
            let (w, h, normal) = load_normal_exr(&p)?;
            if (w, h) != size {
                return Err(mismatch(&p, (w, h), &view.path));
            }
            view.normal = Some(normal);
        }
        Ok(view)
    }
}

pub(super) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let train_json = root.join("transforms_train.json");
    let train = read_transforms(&train_json)?;
    let test_json = ["transforms_test.json", "transforms_val.json"]
        .map(|f| root.join(f))
        .into_iter()
        .find(|p| p.is_file());
    let test = test_json.as_deref().map(read_transforms).transpose()?;
    if train.frames.is_empty() {
        return Err(DataError::invalid(
            &train_json,
            "the file lists no frames; add at least one training frame",
        ));
    }

    let selected = subset_split(train.frames.len(), opts.views)
        .map_err(|m| DataError::invalid(&train_json, m))?;
    let mut loader = Loader {
        root,
        opts,
        guard: SizeGuard::default(),
        any_alpha: false,
    };
    let mut views = Vec::new();
    for &i in &selected {
        views.push(loader.frame(&train_json, &train, i)?);
    }
    let n_train = views.len();
    if let (Some(json), Some(test)) = (&test_json, &test) {
        for i in 0..test.frames.len() {
            views.push(loader.frame(json, test, i)?);
        }
    }
    let split = Split {
        train: (0..n_train).collect(),
        test: (n_train..views.len()).collect(),
    };
    if opts.unused_views {
        for i in (0..train.frames.len()).filter(|i| !selected.contains(i)) {
            views.push(loader.frame(&train_json, &train, i)?);
        }
    }

    let near = train.near.unwrap_or(DEFAULT_NEAR_FAR.0);
    let far = train.far.unwrap_or(DEFAULT_NEAR_FAR.1);
    if !(near.is_finite() && far.is_finite() && 0.0 <= near && near < far) {
        return Err(DataError::invalid(
            &train_json,
            format!("near {near} / far {far}: need 0 <= near < far"),
        ));
    }
    let aabb = match train.aabb {
        Some([lo, hi]) => [Vec3::from(lo), Vec3::from(hi)],
        None if train.near.is_none() && train.far.is_none() => [
            Vec3::splat(-DEFAULT_HALF_EXTENT),
            Vec3::splat(DEFAULT_HALF_EXTENT),
        ],
        None => {
            let n = n_train.max(1) as f32;
            let mean_dist = views[..n_train]
                .iter()
                .map(|v| v.camera.origin().length())
                .sum::<f32>()
                / n;
            let half = if mean_dist > near {
                mean_dist - near
            } else {
                0.5 * (far - near)
            };
            [Vec3::splat(-half), Vec3::splat(half)]
        }
    };
    if !(aabb[0].is_finite() && aabb[1].is_finite() && aabb[0].cmplt(aabb[1]).all()) {
        return Err(DataError::invalid(
            &train_json,
            "aabb must be [[minx, miny, minz], [maxx, maxy, maxz]] with min < max",
        ));
    }
    Ok(Scene {
        root: root.to_path_buf(),
        format: SceneFormat::Blender,
        views,
        split,
        near,
        far,
        ndc: None,
        aabb,
        background: loader.any_alpha.then_some(opts.background),
    })
}
