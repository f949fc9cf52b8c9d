//! Scenes: images, cameras, optional ground truth, and the train/test split.
//!
//! Owns the one [`Scene`] type every format loads into, the camera model and ray
//! generation ([`camera`], lens distortion in `lens`), novel-view camera paths for
//! videos ([`paths`]), the format readers (`blender`, `nerfstudio`, `colmap`, `llff`,
//! `dtu`, plus the NumPy readers they share), the scene bounds of captures without any
//! (`bounds`), the one image resampler ([`resample`]) and numpy's [`quantile`].
//! Nothing here touches the GPU.
//!
//! # Conventions (stated once, used everywhere)
//! * **Camera frame**: OpenGL / NeRF. The camera looks down its local `-z`, `+x` is
//!   right and `+y` is up. `Camera::c2w` maps camera to world. Loaders of OpenCV-style
//!   data (DTU, COLMAP) flip `y` and `z` on load so everything downstream sees one convention.
//! * **Pixels**: `(x, y)` with `x` to the right, `y` down, origin at the top-left
//!   corner of the image; the pixel centre is at `(x + 0.5, y + 0.5)` (mip-NeRF /
//!   RegNeRF convention).
//! * **Rays**: world-space origin and *unit* direction; a ray parameter `t` is the
//!   Euclidean distance from the camera centre. `Ray::z_scale` converts it to depth
//!   along the camera axis: `z = t * z_scale`.
//! * **Ground-truth depth** (synthetic scenes): ray distance `t` in world units, as
//!   Mitsuba's `aov` integrator writes it; `0` on pixels that hit nothing.
//! * **Ground-truth normals**: world space, unit length, oriented toward the camera;
//!   `(0, 0, 0)` where nothing was hit.
//! * **Forward-facing scenes** (LLFF) additionally carry [`NdcParams`]; rays are
//!   generated in world space and mapped to NDC by [`NdcParams::ray_to_ndc`]
//!   (NeRF's `ndc_rays`), where near/far become 0/1. NDC rays keep NeRF's *non-unit*
//!   direction (so `t` in `[0, 1]` spans the near plane to infinity, NDC `z = 2t - 1`)
//!   and have `z_scale = 1`.
//! * **Intrinsics** are in pixels of the *loaded* images (loaders rescale them when the
//!   camera file describes another resolution). Lens distortion (COLMAP and nerfstudio's
//!   OPENCV and OPENCV_FISHEYE models) stays in the camera ([`Camera::lens`]): rays are
//!   generated through the distorted lens, images are never undistorted.
//!
//! # Invariants
//! * Every view of a scene has the same image size; loaders enforce it.
//! * `Scene::split.train` and `Scene::split.test` are disjoint indices into `views`.
//! * Images are linear-in-file (sRGB-encoded as stored, no conversion), RGB, `f32` in
//!   `[0, 1]`, row-major, `3` floats per pixel.

mod bounds;
pub mod camera;
mod error;
mod image_io;
mod lens;
pub mod npy;
pub mod paths;
pub mod resample;
mod split;
mod stats;

mod blender;
mod colmap;
mod dtu;
mod llff;
mod nerfstudio;

use std::path::{Path, PathBuf};

pub use camera::{Camera, Lens, NdcParams, Ray};
pub use error::DataError;
pub use llff::NDC_FAR_MARGIN;
pub use image_io::{
    ImageInfo, ImageRgb, image_info, load_depth_exr, load_mask, load_normal_exr, save_depth_exr,
    save_normal_exr,
};
pub use paths::{PathError, PathKind, camera_path};
pub use stats::quantile;
pub use split::{DTU_EXCLUDED_VIEWS, DTU_TRAIN_VIEWS, LLFF_HOLD, Split, dtu_split, linspace_indices, llff_split};

/// Which reader produced a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SceneFormat {
    /// NeRF-synthetic / Blender `transforms_*.json`, including our Mitsuba scenes.
    Blender,
    /// LLFF `poses_bounds.npy` + `images_N/` (forward-facing, NDC rays).
    Llff,
    /// DTU in the IDR layout (`cameras_sphere.npz`, `image/`, `mask/`).
    DtuIdr,
    /// DTU in the pixelNeRF / RegNeRF layout (`cameras.npz`, `image/`, `mask/`).
    DtuPixelNerf,
    /// nerfstudio's single `transforms.json` (`ns-process-data`'s output).
    Nerfstudio,
    /// A COLMAP sparse model (`sparse/0/` or `sparse/`, text or binary) + `images/`.
    Colmap,
}

impl SceneFormat {
    /// Whether this is a DTU layout (IDR or pixelNeRF): the one test of "is this scene
    /// DTU" that the DTU-specific defaults (lambda3, RegNeRF's options) and the masked
    /// evaluation protocol follow.
    pub fn is_dtu(self) -> bool {
        matches!(self, SceneFormat::DtuIdr | SceneFormat::DtuPixelNerf)
    }

    /// The image downsampling factor [`LoadOptions::llff_factor`] means when unset: 8
    /// for LLFF (RegNeRF's protocol), 1 (the images as they are) for every other format.
    pub fn default_downscale(self) -> u32 {
        if self == SceneFormat::Llff { 8 } else { 1 }
    }
}

impl std::fmt::Display for SceneFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SceneFormat::Blender => "blender (transforms_*.json)",
            SceneFormat::Llff => "llff (poses_bounds.npy)",
            SceneFormat::DtuIdr => "dtu (IDR layout, cameras_sphere.npz)",
            SceneFormat::DtuPixelNerf => "dtu (pixelNeRF layout, cameras.npz)",
            SceneFormat::Nerfstudio => "nerfstudio (transforms.json)",
            SceneFormat::Colmap => "colmap (sparse model)",
        })
    }
}

/// How to load a scene.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LoadOptions {
    /// Number of training views `k` for the sparse-view split (RegNeRF protocol);
    /// `None` means every non-test view is a training view.
    pub views: Option<usize>,
    /// Background colour that RGBA images are composited over (Blender format).
    pub background: [f32; 3],
    /// Image downsampling factor `N` (the name is LLFF's, where it began): LLFF, COLMAP
    /// and nerfstudio scenes read `images_N` (`images` for 1), or downsample the full
    /// images on load ([`resample`]) when there is no such folder; other formats ignore
    /// it. `None`: [`SceneFormat::default_downscale`] (8 for LLFF: 504x378 for its scenes).
    pub llff_factor: Option<u32>,
    /// Load the image pixels. `false` reads only cameras and sizes (fast `info`).
    pub load_images: bool,
    /// Scale of the format's scene box about its centre ([`Scene::scale_box`]); 1 keeps it.
    pub box_scale: f32,
    /// Also load the training-side views a sparse split leaves out, after the test views
    /// (Blender format, whose loader otherwise skips them; the other formats always hold
    /// every view): the `val` split ([`Split::unused`]). Training leaves it off.
    pub unused_views: bool,
    /// Forward-facing (NDC) scenes: rays end just past the capture's far bound
    /// ([`NDC_FAR_MARGIN`]) instead of at infinity (NDC `t = 1`, NeRF's). Off: a
    /// capture's sky may lie far beyond every point it reconstructed.
    pub ndc_far_bound: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            views: None,
            background: [1.0, 1.0, 1.0],
            llff_factor: None,
            load_images: true,
            box_scale: 1.0,
            unused_views: false,
            ndc_far_bound: false,
        }
    }
}

/// One image of a scene with its camera and optional ground truth.
#[derive(Clone, Debug)]
pub struct View {
    /// File stem of the image (`r_0`, `image006`, ...): the key external edge maps use.
    pub name: String,
    /// Path of the image file.
    pub path: PathBuf,
    pub camera: Camera,
    /// RGB pixels; empty (`width * height == 0` data) when loaded without images.
    pub image: ImageRgb,
    /// Object / valid mask in `[0, 1]`, one value per pixel (DTU masks, synthetic GT).
    pub mask: Option<Vec<f32>>,
    /// The image file's own alpha (RGBA files), one value per pixel: `image` is the
    /// file composited over the load background with it. Training uses it to
    /// re-composite targets over random backgrounds.
    pub alpha: Option<Vec<f32>>,
    /// Ground-truth ray distance per pixel (0 = no surface).
    pub depth: Option<Vec<f32>>,
    /// Ground-truth world-space unit normal per pixel, toward the camera.
    pub normal: Option<Vec<[f32; 3]>>,
    /// Pixels training may draw (value > 0.5), one value per pixel: nerfstudio's
    /// `mask_path` (0 = ignore the pixel). `None`: every pixel. Unlike [`View::mask`]
    /// (evaluation), this only changes which pixels a batch draws.
    pub train_mask: Option<Vec<f32>>,
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    pub root: PathBuf,
    pub format: SceneFormat,
    pub views: Vec<View>,
    pub split: Split,
    /// Near and far ray distances (world units), or NDC ray parameters for
    /// forward-facing scenes (0, and 1 for infinity; [`LoadOptions::ndc_far_bound`]).
    pub near: f32,
    pub far: f32,
    /// Present for forward-facing scenes whose rays are mapped to NDC.
    pub ndc: Option<NdcParams>,
    /// Axis-aligned box (world units, or NDC cube for LLFF) that holds the content;
    /// the field's grid is laid over it.
    pub aabb: [glam::Vec3; 2],
    /// Background colour for rays that hit nothing (RGBA data), if the format has one.
    pub background: Option<[f32; 3]>,
}

impl Scene {
    /// Detects the format of `root` and loads it.
    pub fn load(root: impl AsRef<Path>, opts: &LoadOptions) -> Result<Scene, DataError> {
        let root = root.as_ref();
        let mut scene = match detect_format(root)? {
            SceneFormat::Blender => blender::load(root, opts),
            SceneFormat::Llff => llff::load(root, opts),
            f @ (SceneFormat::DtuIdr | SceneFormat::DtuPixelNerf) => dtu::load(root, f, opts),
            SceneFormat::Nerfstudio => nerfstudio::load(root, opts),
            SceneFormat::Colmap => colmap::load(root, opts),
        }?;
        if opts.box_scale != 1.0 {
            scene.scale_box(opts.box_scale)?;
        }
        if !opts.ndc_far_bound && scene.ndc.is_some() {
            scene.far = 1.0;
        }
        Ok(scene)
    }

    /// Scales the scene box by `scale` about its centre, and moves `far` out so that
    /// every camera's rays reach the far side of the larger box. Refused for NDC scenes,
    /// whose box is the NDC cube (every forward-facing ray already ends at infinity).
    pub fn scale_box(&mut self, scale: f32) -> Result<(), DataError> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(DataError::invalid(&self.root, format!("box scale {scale}: must be a positive number")));
        }
        if self.ndc.is_some() {
            return Err(DataError::invalid(
                &self.root,
                format!(
                    "box scale {scale}: this forward-facing scene's rays are in NDC, whose box already reaches \
                     infinity; leave scene.box_scale at 1"
                ),
            ));
        }
        let [lo, hi] = self.aabb;
        let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5 * scale);
        let [lo, hi] = [centre - half, centre + half];
        self.aabb = [lo, hi];
        // A camera's farthest corner takes, on each axis, the farther of the two faces.
        let farthest_corner = |o: glam::Vec3| (o - lo).abs().max((o - hi).abs()).length();
        let reach = self.views.iter().map(|v| farthest_corner(v.camera.origin())).fold(0.0f32, f32::max);
        self.far = self.far.max(reach);
        Ok(())
    }

    /// Image size shared by every view.
    pub fn image_size(&self) -> (u32, u32) {
        self.views.first().map_or((0, 0), |v| (v.camera.width, v.camera.height))
    }

    /// Whether the scene is a DTU scan ([`SceneFormat::is_dtu`]).
    pub fn is_dtu(&self) -> bool {
        self.format.is_dtu()
    }

    /// Whether every training camera stands inside the scene box (an inside-out capture:
    /// a room seen from within); false for NDC scenes and scenes without training views.
    pub fn cameras_inside_box(&self) -> bool {
        let [lo, hi] = self.aabb;
        self.ndc.is_none()
            && !self.split.train.is_empty()
            && self.train_views().all(|v| {
                let o = v.camera.origin();
                o.cmpge(lo).all() && o.cmple(hi).all()
            })
    }

    /// Indices of the training views.
    pub fn train_views(&self) -> impl Iterator<Item = &View> {
        self.split.train.iter().map(|&i| &self.views[i])
    }

    /// Indices of the test views.
    pub fn test_views(&self) -> impl Iterator<Item = &View> {
        self.split.test.iter().map(|&i| &self.views[i])
    }

    /// The ray through the centre of pixel `(x, y)` of view `view`, in the space the
    /// field works in: world space, or NDC for forward-facing scenes.
    pub fn ray(&self, view: usize, x: u32, y: u32) -> Ray {
        let ray = self.views[view].camera.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
        match &self.ndc {
            Some(ndc) => ndc.ray_to_ndc(ray),
            None => ray,
        }
    }

    /// [`Scene::ray`] for every pixel of view `view`, row-major.
    pub fn image_rays(&self, view: usize) -> Vec<Ray> {
        self.camera_rays(&self.views[view].camera)
    }

    /// The rays through every pixel of `camera` (any pose, e.g. a [`paths`] camera),
    /// row-major, in the space the field works in: world space, or NDC.
    pub fn camera_rays(&self, camera: &Camera) -> Vec<Ray> {
        let rays = camera.pixel_rays();
        match &self.ndc {
            Some(ndc) => rays.into_iter().map(|r| ndc.ray_to_ndc(r)).collect(),
            None => rays,
        }
    }
}

/// Tests on real data: the scene `rel` (`llff/fern`) under `$EDGENERF_DATA` (default
/// `../shared/data` beside the repository), or `None` after a note when it is absent
/// (a failure with `EDGENERF_REQUIRE_DATA=1`, as in the integration tests).
#[cfg(test)]
pub(crate) fn real_scene_dir(rel: &str) -> Option<PathBuf> {
    let root = std::env::var_os("EDGENERF_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    let dir = root.join(rel);
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(std::env::var("EDGENERF_REQUIRE_DATA").as_deref() != Ok("1"), "real data required but {} is absent", dir.display());
    eprintln!("skipping: {} not found (set EDGENERF_DATA)", dir.display());
    None
}

/// Finds which reader understands `root`, by the files that identify each layout, in
/// this order: `transforms_train.json` (Blender; with a `transforms.json` beside it the
/// scene is ambiguous, an error), `transforms.json` (nerfstudio), `poses_bounds.npy`
/// (LLFF, which often keeps its COLMAP model in `sparse/0` too), `cameras_sphere.npz`,
/// `cameras.npz` (DTU), then a COLMAP model (`sparse/0/` or `sparse/` holding
/// `cameras.bin` or `cameras.txt`; a `sparse` folder without one is an error naming
/// what is missing).
pub fn detect_format(root: &Path) -> Result<SceneFormat, DataError> {
    if !root.is_dir() {
        return Err(DataError::NotFound { path: root.to_path_buf(), what: "scene directory" });
    }
    let blender = root.join("transforms_train.json").is_file();
    let ns = root.join("transforms.json").is_file();
    if blender && ns {
        return Err(DataError::invalid(
            root,
            "both transforms_train.json (Blender layout) and transforms.json (nerfstudio) are present, so the \
             layout is ambiguous; move the one you do not mean to train on out of the folder",
        ));
    }
    if blender {
        Ok(SceneFormat::Blender)
    } else if ns {
        Ok(SceneFormat::Nerfstudio)
    } else if root.join("poses_bounds.npy").is_file() {
        Ok(SceneFormat::Llff)
    } else if root.join("cameras_sphere.npz").is_file() {
        Ok(SceneFormat::DtuIdr)
    } else if root.join("cameras.npz").is_file() {
        Ok(SceneFormat::DtuPixelNerf)
    } else if root.join("sparse").is_dir() {
        colmap::model_dir(root).map(|_| SceneFormat::Colmap)
    } else {
        Err(DataError::UnknownFormat { path: root.to_path_buf() })
    }
}
