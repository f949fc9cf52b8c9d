//! COLMAP sparse models: `cameras`, `images` and `points3D`, text (`.txt`) or binary
//! (`.bin`), as COLMAP's mapper writes them, with the pictures in `images/`.
//!
//! * Layout: the model in `sparse/0/` (the mapper's first model) or directly in
//!   `sparse/`; binary files win when both kinds are present. The images are
//!   `images/<NAME>` (`NAME` as `images.txt` / `images.bin` stores it, subfolders
//!   allowed), or with a downsampling factor `N` ([`LoadOptions::llff_factor`], default 1)
//!   `images_N/<NAME>`, else `images/<NAME>` downsampled on load ([`super::resample`]).
//! * Cameras: `SIMPLE_PINHOLE` (`f cx cy`), `PINHOLE` (`fx fy cx cy`), `SIMPLE_RADIAL`
//!   (`f cx cy k`), `RADIAL` (`f cx cy k1 k2`), `OPENCV` (`fx fy cx cy k1 k2 p1 p2`) and
//!   `OPENCV_FISHEYE` (`fx fy cx cy k1 k2 k3 k4`) ([`Lens`]); other models are refused
//!   with a hint (undistort with COLMAP's `image_undistorter`). COLMAP's pixel centres are
//!   at `+0.5` like ours, so `cx`, `cy` are used as they are; intrinsics are scaled to the
//!   loaded image size per axis (the aspect ratio must agree to 2 %).
//! * Poses: `images` stores world-to-camera `(qw, qx, qy, qz)`, `t` in OpenCV's camera
//!   frame (`x` right, `y` down, `z` forward): `c2w = [R^T | -R^T t]` with its `y` and
//!   `z` columns negated into the OpenGL frame. The world frame is COLMAP's own.
//! * Points: `points3D` positions bound the scene ([`super::bounds`]: forward-facing
//!   captures become LLFF-style NDC scenes, others keep COLMAP's frame and units).
//! * Pictures with alpha are composited over [`LoadOptions::background`] (white by
//!   default), recorded as `Scene::background`, as the Blender reader does.
//! * Views: sorted by image name; split as LLFF ([`super::llff_split`]: every 8th image
//!   is a test image, `k` training views spread over the rest), the rule nerfstudio's
//!   `interval` mode and LLFF share.
//!
//! Invariants: binary counts are checked against the bytes left before anything is
//! allocated, so a truncated or corrupt file is an error naming it, never a panic or a
//! huge allocation; every camera passes [`Camera::check`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DQuat, DVec3, Vec3};

use super::bounds::{Capture, finish_capture};
use super::image_io::{SizeGuard, read_view_image_downscaled};
use super::llff::image_folder;
use super::{Camera, DataError, Lens, LoadOptions, Scene, SceneFormat, llff_split};

/// One camera of `cameras.txt` / `.bin`: the model's name, size and parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub model: String,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

/// One registered image: world-to-camera rotation `(qw, qx, qy, qz)` and translation.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
}

/// A sparse model as read from disk.
#[derive(Clone, Debug, Default)]
pub struct ColmapModel {
    pub cameras: HashMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<Vec3>,
}

/// COLMAP's camera models by id (`colmap/src/colmap/sensor/models.h`), with their
/// parameter count.
const MODELS: [(&str, usize); 11] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
];

const SUPPORTED: &str = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE";

/// The model folder of a scene: `sparse/0` or `sparse`, the first holding
/// `cameras.bin` or `cameras.txt`, and whether it is binary.
pub(super) fn model_dir(root: &Path) -> Result<(PathBuf, bool), DataError> {
    for dir in [root.join("sparse").join("0"), root.join("sparse")] {
        if dir.join("cameras.bin").is_file() {
            return Ok((dir, true));
        }
        if dir.join("cameras.txt").is_file() {
            return Ok((dir, false));
        }
    }
    Err(DataError::invalid(
        root.join("sparse"),
        "a COLMAP model needs cameras.bin or cameras.txt (with images and points3D of the same kind) in sparse/0/ \
         or sparse/; none was found: point to the folder that holds sparse/, or export the model with COLMAP's \
         model_converter",
    ))
}

/// The camera of `c` for an image of `width x height` with pose `c2w`.
pub(super) fn camera_of(c: &ColmapCamera, width: u32, height: u32, c2w: glam::Mat4) -> Result<Camera, String> {
    let p = &c.params;
    let (fx, fy, cx, cy, lens) = match c.model.as_str() {
        "SIMPLE_PINHOLE" => (p[0], p[0], p[1], p[2], Lens::Pinhole),
        "PINHOLE" => (p[0], p[1], p[2], p[3], Lens::Pinhole),
        "SIMPLE_RADIAL" => (p[0], p[0], p[1], p[2], Lens::opencv([p[3] as f32, 0.0, 0.0, 0.0], [0.0; 2])),
        "RADIAL" => (p[0], p[0], p[1], p[2], Lens::opencv([p[3] as f32, p[4] as f32, 0.0, 0.0], [0.0; 2])),
        "OPENCV" => (p[0], p[1], p[2], p[3], Lens::opencv([p[4] as f32, p[5] as f32, 0.0, 0.0], [p[6] as f32, p[7] as f32])),
        "OPENCV_FISHEYE" => (p[0], p[1], p[2], p[3], Lens::Fisheye { k: [p[4] as f32, p[5] as f32, p[6] as f32, p[7] as f32] }),
        m => {
            return Err(format!(
                "camera model {m} is not supported (supported: {SUPPORTED}); undistort the images with COLMAP's \
                 image_undistorter, which writes a PINHOLE model"
            ));
        }
    };
    if !(c.width > 0 && c.height > 0) {
        return Err(format!("camera size {}x{} must be positive", c.width, c.height));
    }
    let (sx, sy) = (width as f64 / c.width as f64, height as f64 / c.height as f64);
    if (sx / sy - 1.0).abs() > 0.02 {
        return Err(format!(
            "the image is {width}x{height} but its camera describes a {}x{} image (another aspect ratio); the images \
             do not belong to this model",
            c.width, c.height
        ));
    }
    let camera = Camera {
        width,
        height,
        fx: (fx * sx) as f32,
        fy: (fy * sy) as f32,
        cx: (cx * sx) as f32,
        cy: (cy * sy) as f32,
        c2w,
        lens,
    };
    camera.check()?;
    Ok(camera)
}

/// COLMAP's world-to-camera `(q, t)` (OpenCV camera frame) as an OpenGL camera-to-world.
pub fn colmap_c2w(qvec: [f64; 4], tvec: [f64; 3]) -> Result<DMat4, String> {
    let [w, x, y, z] = qvec;
    let q = DQuat::from_xyzw(x, y, z, w);
    let norm = q.length();
    if !(norm.is_finite() && norm > 1e-9) || !tvec.iter().all(|t| t.is_finite()) {
        return Err(format!("pose q {qvec:?} t {tvec:?} is not a finite rotation and translation"));
    }
    let r = DMat3::from_quat(q / norm);
    let rt = r.transpose();
    let centre = -(rt * DVec3::from(tvec));
    Ok(DMat4::from_cols(rt.x_axis.extend(0.0), (-rt.y_axis).extend(0.0), (-rt.z_axis).extend(0.0), centre.extend(1.0)))
}

// ------------------------------------------------------------------------ text files

/// The data lines of a text file with their 1-based line numbers (`#` comments dropped;
/// blank lines kept, since `images.txt`'s point lists may be empty).
fn text_lines(path: &Path) -> Result<Vec<(usize, String)>, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    Ok(text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim_start().starts_with('#'))
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect())
}

fn field<T: std::str::FromStr>(path: &Path, line: usize, tokens: &[&str], i: usize, what: &str) -> Result<T, DataError> {
    tokens
        .get(i)
        .and_then(|t| t.parse().ok())
        .ok_or_else(|| DataError::invalid(path, format!("line {line}: {what} (field {}) is missing or not a number", i + 1)))
}

fn read_cameras_txt(path: &Path) -> Result<HashMap<u32, ColmapCamera>, DataError> {
    let mut cameras = HashMap::new();
    for (line, text) in text_lines(path)? {
        let t: Vec<&str> = text.split_whitespace().collect();
        if t.is_empty() {
            continue;
        }
        let id: u32 = field(path, line, &t, 0, "CAMERA_ID")?;
        let model = t.get(1).map(|m| m.to_string()).unwrap_or_default();
        let Some(&(_, n)) = MODELS.iter().find(|(name, _)| *name == model) else {
            return Err(DataError::invalid(
                path,
                format!("line {line}: unknown camera model {model:?} (supported: {SUPPORTED})"),
            ));
        };
        let width = field(path, line, &t, 2, "WIDTH")?;
        let height = field(path, line, &t, 3, "HEIGHT")?;
        if t.len() != 4 + n {
            return Err(DataError::invalid(path, format!("line {line}: {model} takes {n} parameters, found {}", t.len().saturating_sub(4))));
        }
        let params = (0..n).map(|i| field(path, line, &t, 4 + i, "a parameter")).collect::<Result<_, _>>()?;
        cameras.insert(id, ColmapCamera { model, width, height, params });
    }
    Ok(cameras)
}

fn read_images_txt(path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let lines = text_lines(path)?;
    let mut images = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let (line, text) = &lines[i];
        let t: Vec<&str> = text.split_whitespace().collect();
        if t.is_empty() {
            i += 1;
            continue;
        }
        if t.len() < 10 {
            return Err(DataError::invalid(
                path,
                format!("line {line}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, found {} fields", t.len()),
            ));
        }
        let num = |j: usize| field::<f64>(path, *line, &t, j, "a pose value");
        images.push(ColmapImage {
            id: field(path, *line, &t, 0, "IMAGE_ID")?,
            qvec: [num(1)?, num(2)?, num(3)?, num(4)?],
            tvec: [num(5)?, num(6)?, num(7)?],
            camera_id: field(path, *line, &t, 8, "CAMERA_ID")?,
            // A name may hold spaces: everything after the camera id.
            name: t[9..].join(" "),
        });
        // The next line lists the image's 2D points (possibly empty).
        i += 2;
    }
    Ok(images)
}

fn read_points_txt(path: &Path) -> Result<Vec<Vec3>, DataError> {
    let mut points = Vec::new();
    for (line, text) in text_lines(path)? {
        let t: Vec<&str> = text.split_whitespace().collect();
        if t.is_empty() {
            continue;
        }
        let c = |i: usize| field::<f64>(path, line, &t, i, "a coordinate");
        points.push(DVec3::new(c(1)?, c(2)?, c(3)?).as_vec3());
    }
    Ok(points)
}

// ---------------------------------------------------------------------- binary files

/// A little-endian reader over a whole file whose every read is bounds-checked.
struct Bin<'a> {
    path: &'a Path,
    bytes: Vec<u8>,
    at: usize,
}

impl Bin<'_> {
    fn open(path: &Path) -> Result<Bin<'_>, DataError> {
        Ok(Bin { path, bytes: std::fs::read(path).map_err(|e| DataError::io(path, e))?, at: 0 })
    }

    fn truncated(&self, what: &str) -> DataError {
        DataError::invalid(
            self.path,
            format!(
                "truncated or corrupt COLMAP binary file: {what} at byte {} runs past its end ({} bytes); re-export the model \
                 (COLMAP's model_converter --output_type BIN or TXT)",
                self.at,
                self.bytes.len()
            ),
        )
    }

    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N], DataError> {
        let end = self.at.checked_add(N).filter(|&e| e <= self.bytes.len()).ok_or_else(|| self.truncated(what))?;
        let out = self.bytes[self.at..end].try_into().expect("slice of length N");
        self.at = end;
        Ok(out)
    }

    fn u64(&mut self, what: &str) -> Result<u64, DataError> {
        self.take::<8>(what).map(u64::from_le_bytes)
    }

    fn i32(&mut self, what: &str) -> Result<i32, DataError> {
        self.take::<4>(what).map(i32::from_le_bytes)
    }

    fn f64(&mut self, what: &str) -> Result<f64, DataError> {
        self.take::<8>(what).map(f64::from_le_bytes)
    }

    /// A count of records of at least `min_size` bytes each, checked against the bytes left.
    fn count(&mut self, what: &str, min_size: usize) -> Result<usize, DataError> {
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.at) as u64;
        if n.checked_mul(min_size as u64).is_none_or(|b| b > left) {
            return Err(self.truncated(&format!("{what} ({n} records)")));
        }
        Ok(n as usize)
    }

    fn skip(&mut self, n: usize, what: &str) -> Result<(), DataError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len()).ok_or_else(|| self.truncated(what))?;
        self.at = end;
        Ok(())
    }

    fn finish(&self) -> Result<(), DataError> {
        if self.at != self.bytes.len() {
            return Err(DataError::invalid(
                self.path,
                format!("{} bytes left after the last record: not a COLMAP model file, or a corrupt one", self.bytes.len() - self.at),
            ));
        }
        Ok(())
    }
}

fn read_cameras_bin(path: &Path) -> Result<HashMap<u32, ColmapCamera>, DataError> {
    let mut b = Bin::open(path)?;
    let n = b.count("the camera count", 24)?;
    let mut cameras = HashMap::new();
    for _ in 0..n {
        let id = b.i32("a camera id")?;
        let model_id = b.i32("a camera model id")?;
        let width = b.u64("a camera width")?;
        let height = b.u64("a camera height")?;
        let Some(&(model, n_params)) = usize::try_from(model_id).ok().and_then(|m| MODELS.get(m)) else {
            return Err(DataError::invalid(
                path,
                format!("camera {id}: unknown camera model id {model_id} (supported: {SUPPORTED}; ids 0-5)"),
            ));
        };
        let params = (0..n_params).map(|_| b.f64("a camera parameter")).collect::<Result<_, _>>()?;
        cameras.insert(id as u32, ColmapCamera { model: model.to_string(), width, height, params });
    }
    b.finish()?;
    Ok(cameras)
}

fn read_images_bin(path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let mut b = Bin::open(path)?;
    let n = b.count("the image count", 64 + 1 + 8)?;
    let mut images = Vec::with_capacity(n);
    for _ in 0..n {
        let id = b.i32("an image id")? as u32;
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = b.f64("a rotation")?;
        }
        let mut t = [0.0; 3];
        for v in &mut t {
            *v = b.f64("a translation")?;
        }
        let camera_id = b.i32("a camera id")? as u32;
        let start = b.at;
        let len = b.bytes[start..].iter().position(|&c| c == 0).ok_or_else(|| b.truncated("an image name"))?;
        let name = String::from_utf8_lossy(&b.bytes[start..start + len]).into_owned();
        b.at = start + len + 1;
        let n_points = b.count("a 2D point count", 24)?;
        b.skip(n_points * 24, "the 2D points")?;
        images.push(ColmapImage { id, qvec: q, tvec: t, camera_id, name });
    }
    b.finish()?;
    Ok(images)
}

fn read_points_bin(path: &Path) -> Result<Vec<Vec3>, DataError> {
    let mut b = Bin::open(path)?;
    let n = b.count("the point count", 43 + 8)?;
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        b.skip(8, "a point id")?;
        let p = DVec3::new(b.f64("a point")?, b.f64("a point")?, b.f64("a point")?);
        b.skip(3 + 8, "a point colour and error")?;
        let track = b.count("a track length", 8)?;
        b.skip(track * 8, "a track")?;
        points.push(p.as_vec3());
    }
    b.finish()?;
    Ok(points)
}

/// Reads the model in `dir` (binary or text files, as `binary` says).
pub fn read_model(dir: &Path, binary: bool) -> Result<ColmapModel, DataError> {
    let ext = if binary { "bin" } else { "txt" };
    let file = |name: &str| {
        let p = dir.join(format!("{name}.{ext}"));
        if p.is_file() {
            Ok(p)
        } else {
            Err(DataError::NotFound { path: p, what: "COLMAP model file (cameras, images and points3D must all be .bin or all .txt)" })
        }
    };
    let (cameras, images, points) = (file("cameras")?, file("images")?, file("points3D")?);
    Ok(if binary {
        ColmapModel { cameras: read_cameras_bin(&cameras)?, images: read_images_bin(&images)?, points: read_points_bin(&points)? }
    } else {
        ColmapModel { cameras: read_cameras_txt(&cameras)?, images: read_images_txt(&images)?, points: read_points_txt(&points)? }
    })
}

pub(super) fn load(root: &Path, opts: &LoadOptions) -> Result<Scene, DataError> {
    let (dir, binary) = model_dir(root)?;
    let model = read_model(&dir, binary)?;
    let source = dir.join(if binary { "images.bin" } else { "images.txt" });
    if model.images.is_empty() {
        return Err(DataError::invalid(&source, "the model has no registered images; run COLMAP's mapper on more overlapping photos"));
    }
    let factor = opts.llff_factor.unwrap_or(SceneFormat::Colmap.default_downscale());
    let (image_dir, resample) = image_folder(root, factor).ok_or_else(|| DataError::NotFound {
        path: root.join(super::llff::image_dir_name(factor)),
        what: "COLMAP image folder (images/, or images_N/ for --llff-factor N)",
    })?;
    let mut images = model.images.clone();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut guard = SizeGuard::default();
    let mut any_alpha = false;
    let mut views = Vec::with_capacity(images.len());
    for im in &images {
        let what = || format!("image {} ({}) of {}", im.id, im.name, source.display());
        let camera = model.cameras.get(&im.camera_id).ok_or_else(|| {
            DataError::invalid(&source, format!("{} uses camera {}, which cameras.{} does not define", what(), im.camera_id, if binary { "bin" } else { "txt" }))
        })?;
        let path = image_dir.join(&im.name);
        if !path.is_file() {
            return Err(DataError::MissingImage { path, pose: what() });
        }
        let img = read_view_image_downscaled(&path, resample, opts.load_images, opts.background, &mut guard)?;
        any_alpha |= img.info.has_alpha;
        let c2w = colmap_c2w(im.qvec, im.tvec).map_err(|m| DataError::NonFinite { path: source.clone(), what: format!("{}: {m}", what()) })?;
        let camera = camera_of(camera, img.info.width, img.info.height, c2w.as_mat4())
            .map_err(|m| DataError::invalid(&source, format!("{}: {m}", what())))?;
        views.push(img.into_view(path, camera));
    }
    let split = llff_split(views.len(), opts.views).map_err(|m| DataError::invalid(root, m))?;
    // RGBA pictures are composited over the load background, which the scene records
    // (training re-composites them over random backgrounds from it).
    let background = any_alpha.then_some(opts.background);
    let capture = Capture { views, split, points: model.points, near_far: [None; 2], aabb: None, background };
    finish_capture(root, SceneFormat::Colmap, &source, capture)
}
