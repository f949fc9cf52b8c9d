//! The edge room: per-pixel edge masks of the training images (EdgeNeRF, section 3.3),
//! which the patch sampler and the edge-guided depth/normal losses read.
//!
//! Owns the edge sources ([`EdgeSource`]: our [`canny()`] detector on the image's Rec. 601
//! luma, precomputed external maps such as DexiNed's, or none), the binarization
//! `B = [E >= tau_e]` with its polarity, the 3x3 dilation of edge regions, the mask
//! images and the per-run mask cache. Nothing here touches the GPU.
//!
//! Pipeline for one view (paper, eq. for `B_i`):
//! ```text
//! Canny(luma(image)) -> E = 255 on edges, 0 elsewhere -> edge where E >= tau_e
//! external map       -> E in 0..255 (grey)            -> DarkEdges:   non-edge where E >= tau_e
//!                                                        BrightEdges: edge where E >= tau_e
//! -> edge regions dilated by a 3x3 all-ones kernel (= erosion of the non-edge mask)
//! None               -> every pixel non-edge (the global-smoothing baseline)
//! ```
//!
//! Invariants:
//! * An [`EdgeMask`] uses the paper's convention: `1` on **non-edge** pixels (where the
//!   losses smooth), `0` on edge pixels; it has exactly the size of its view's image.
//!   External maps of another size are an error, never resized silently.
//! * Masks depend only on the image pixels, the external map and the [`EdgeConfig`];
//!   [`edge_masks_cached`] reuses a cache only when a stamp of all three matches.
//! * Mask files are 8-bit grey PNGs: white (255) = non-edge, black (0) = edge. Such a
//!   file is itself a valid external map with [`Polarity::DarkEdges`].

pub mod canny;
mod cache;
mod external;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::data::Scene;

pub use cache::edge_masks_cached;
pub use canny::{canny, gaussian_blur, luma};

/// Where the edge maps come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EdgeSource {
    /// Our [`canny()`] detector on the training image's luma, with [`EdgeConfig::canny`].
    Canny,
    /// Precomputed maps (DexiNed or any detector) in [`EdgeConfig::dir`].
    External,
    /// No edges: every pixel is non-edge (global smoothing, the RegNeRF-like baseline).
    None,
}

/// How an external edge map encodes edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// Dark edges on white (DexiNed's inverted output, and our own mask PNGs): a pixel is
    /// non-edge where `E >= tau_e` (the paper's `B = 1 if E >= tau_e`).
    DarkEdges,
    /// Bright edges on black (raw detector responses): a pixel is edge where `E >= tau_e`.
    BrightEdges,
}

/// Parameters of the [`canny()`] detector.
///
/// The defaults (sigma 2 px, thresholds 0.05 / 0.15) were tuned on LLFF fern
/// (504x378), DTU scan 24 (400x300) and the committed 128 px synthetic scenes: they give
/// continuous object outlines and strong texture edges without speckle, about 27 % edge
/// pixels after dilation on fern and 15 % on scan 24, and cover 90-97 % of the synthetic
/// scenes' ground-truth depth discontinuities within 1 px (`tests/edges_synthetic.rs`).
/// A smaller sigma (1.4) fragments the outlines on real images; higher thresholds
/// (0.1 / 0.2) drop low-contrast occlusion boundaries.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CannyParams {
    /// Standard deviation of the Gaussian blur, in pixels (`0`: no blur). Default 2.
    pub sigma: f32,
    /// Low (hysteresis) threshold as a fraction of the image's largest gradient
    /// magnitude, in `[0, high]`. Default 0.05.
    pub low: f32,
    /// High threshold, same units, in `[low, 1]`. Default 0.15.
    pub high: f32,
}

impl Default for CannyParams {
    fn default() -> Self {
        Self { sigma: 2.0, low: 0.05, high: 0.15 }
    }
}

/// The largest Canny blur [`EdgeConfig::validate`] accepts, in pixels.
pub const MAX_CANNY_SIGMA: f32 = 64.0;

/// How a run gets its edge masks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EdgeConfig {
    /// Where edges come from. Default [`EdgeSource::Canny`].
    pub source: EdgeSource,
    /// Directory of external edge maps (needed when `source` is `External`): one PNG or
    /// JPEG per view, named after the view's image (`image006.png` for
    /// `images_8/image006.png`; see [`mask_stem`] for repeated names).
    pub dir: Option<PathBuf>,
    /// Polarity of external maps. Default [`Polarity::DarkEdges`] (DexiNed).
    pub polarity: Polarity,
    /// Binarization threshold on the map's grey level `0..=255` (maps of any bit depth
    /// are scaled to that range). Default 125 (the paper's `tau_e`).
    pub tau_e: f32,
    /// Widen edge regions with a 3x3 all-ones dilation (the paper's `B'`). Default true.
    pub dilate: bool,
    /// Detector parameters for `source = Canny`.
    pub canny: CannyParams,
}

impl Default for EdgeConfig {
    fn default() -> Self {
        Self {
            source: EdgeSource::Canny,
            dir: None,
            polarity: Polarity::DarkEdges,
            tau_e: 125.0,
            dilate: true,
            canny: CannyParams::default(),
        }
    }
}

impl EdgeConfig {
    /// Checks the values: finite `tau_e`, `0 <= low <= high <= 1`, `sigma >= 0`, and a
    /// `dir` when the source is external.
    pub fn validate(&self) -> Result<(), EdgeError> {
        let bad = |message: String| Err(EdgeError::Config { message });
        // 255 would mark every pixel an edge and 0 (nearly) none: both are allowed, as
        // the extremes of the paper's threshold, but nothing outside the grey levels.
        if !(0.0..=255.0).contains(&self.tau_e) {
            return bad(format!("tau_e is {}; use a grey level in 0..=255 (the paper uses 125)", self.tau_e));
        }
        let c = &self.canny;
        // The blur kernel spans 6 sigma: past MAX_CANNY_SIGMA it is wider than any image
        // we train on and its allocation grows without bound.
        if !(0.0..=MAX_CANNY_SIGMA).contains(&c.sigma) {
            return bad(format!("canny.sigma is {}; use a blur in pixels in 0..={MAX_CANNY_SIGMA} (default 2)", c.sigma));
        }
        if !(0.0 <= c.low && c.low <= c.high && c.high <= 1.0) {
            return bad(format!(
                "canny thresholds low {} / high {} must satisfy 0 <= low <= high <= 1 (fractions of the \
                 largest gradient magnitude; default 0.05 / 0.15)",
                c.low, c.high
            ));
        }
        if self.source == EdgeSource::External && self.dir.is_none() {
            return Err(EdgeError::NoDir);
        }
        Ok(())
    }
}

/// Per-pixel mask of one image in the paper's convention: 1 on NON-edge pixels, 0 on
/// edge pixels (after dilation).
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeMask {
    pub width: u32,
    pub height: u32,
    /// `0` (edge) or `1` (non-edge) per pixel, row-major from the top-left pixel.
    pub non_edge: Vec<u8>,
}

impl EdgeMask {
    /// A mask without edges.
    pub fn all_non_edge(width: u32, height: u32) -> EdgeMask {
        EdgeMask { width, height, non_edge: vec![1; width as usize * height as usize] }
    }

    /// `1.0` on a non-edge pixel, `0.0` on an edge pixel; panics outside the image.
    pub fn at(&self, x: u32, y: u32) -> f32 {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}x{}", self.width, self.height);
        f32::from(self.non_edge[y as usize * self.width as usize + x as usize])
    }

    /// `true` on an edge pixel; panics outside the image.
    pub fn is_edge(&self, x: u32, y: u32) -> bool {
        self.at(x, y) == 0.0
    }

    /// Fraction of pixels that are edge pixels (`0` for an empty mask).
    pub fn edge_fraction(&self) -> f32 {
        if self.non_edge.is_empty() {
            return 0.0;
        }
        self.non_edge.iter().filter(|&&v| v == 0).count() as f32 / self.non_edge.len() as f32
    }

    /// Writes an 8-bit grey PNG: white = non-edge, black = edge.
    pub fn save_png(&self, path: &Path) -> Result<(), EdgeError> {
        let bytes = self.non_edge.iter().map(|&v| if v != 0 { 255 } else { 0 }).collect();
        let img = image::GrayImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| EdgeError::Config { message: format!("mask data does not match its size {}x{}", self.width, self.height) })?;
        img.save_with_format(path, image::ImageFormat::Png).map_err(|source| EdgeError::Image { path: path.to_path_buf(), source })
    }

    /// Reads a mask PNG written by [`EdgeMask::save_png`] (non-edge where grey >= 128).
    pub fn load_png(path: &Path) -> Result<EdgeMask, EdgeError> {
        let (width, height, grey) = external::read_grey(path)?;
        Ok(EdgeMask { width, height, non_edge: grey.iter().map(|&g| u8::from(g >= 127.5)).collect() })
    }

    /// Widens edge regions by one pixel in each of the 8 directions (3x3 all-ones
    /// dilation of the edges, i.e. erosion of the non-edge set). Pixels outside the
    /// image count as non-edge, so the border is not made an edge.
    pub fn dilate_edges(&self) -> EdgeMask {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut out = self.non_edge.clone();
        for y in 0..h {
            for x in 0..w {
                if self.non_edge[y * w + x] != 0 {
                    continue;
                }
                for ny in y.saturating_sub(1)..(y + 2).min(h) {
                    for nx in x.saturating_sub(1)..(x + 2).min(w) {
                        out[ny * w + nx] = 0;
                    }
                }
            }
        }
        EdgeMask { width: self.width, height: self.height, non_edge: out }
    }
}

/// Binarizes an edge image `E` (grey levels `0..=255`, row-major) into a mask:
/// with [`Polarity::DarkEdges`] a pixel is non-edge where `E >= tau_e`, with
/// [`Polarity::BrightEdges`] it is edge where `E >= tau_e`. No dilation.
pub fn binarize(width: u32, height: u32, e: &[f32], polarity: Polarity, tau_e: f32) -> EdgeMask {
    assert_eq!(e.len(), width as usize * height as usize, "binarize: {} values for {width}x{height}", e.len());
    let non_edge = e
        .iter()
        .map(|&v| {
            let above = v >= tau_e;
            u8::from(match polarity {
                Polarity::DarkEdges => above,
                Polarity::BrightEdges => !above,
            })
        })
        .collect();
    EdgeMask { width, height, non_edge }
}

/// The file stem under which view `view`'s mask is written and its external map is
/// looked up: `View::name`, except for a view whose name an earlier view of the scene
/// already has (Blender scenes repeat `r_000` in `train/` and `test/`), which gets the
/// name of its image's folder as a prefix (`test_r_000`). Training views come first
/// in every loader, so they keep their plain names.
pub fn mask_stem(scene: &Scene, view: usize) -> String {
    let v = &scene.views[view];
    if scene.views[..view].iter().any(|u| u.name == v.name) {
        let folder = v.path.parent().and_then(|p| p.file_name()).map(|f| f.to_string_lossy().into_owned());
        let folder = folder.unwrap_or_else(|| format!("view{view}"));
        format!("{folder}_{}", v.name)
    } else {
        v.name.clone()
    }
}

/// The mask of one view of `scene` (no cache).
pub fn edge_mask(scene: &Scene, view: usize, cfg: &EdgeConfig) -> Result<EdgeMask, EdgeError> {
    cfg.validate()?;
    let Some(v) = scene.views.get(view) else {
        return Err(EdgeError::NoSuchView { view, count: scene.views.len() });
    };
    let (w, h) = (v.camera.width, v.camera.height);
    let mask = match cfg.source {
        EdgeSource::None => return Ok(EdgeMask::all_non_edge(w, h)),
        EdgeSource::Canny => {
            if v.image.is_empty() {
                return Err(EdgeError::NoPixels { view: v.name.clone(), path: v.path.clone() });
            }
            let edges = canny(&luma(&v.image.data), v.image.width, v.image.height, &cfg.canny);
            let e: Vec<f32> = edges.iter().map(|&b| if b { 255.0 } else { 0.0 }).collect();
            binarize(v.image.width, v.image.height, &e, Polarity::BrightEdges, cfg.tau_e)
        }
        EdgeSource::External => {
            let dir = cfg.dir.as_deref().ok_or(EdgeError::NoDir)?;
            let path = external::find_map(scene, view, dir)?;
            let (mw, mh, e) = external::read_grey(&path)?;
            if (mw, mh) != (w, h) {
                return Err(EdgeError::MapSize { path, got: (mw, mh), expected: (w, h), image: v.path.clone() });
            }
            binarize(w, h, &e, cfg.polarity, cfg.tau_e)
        }
    };
    Ok(if cfg.dilate { mask.dilate_edges() } else { mask })
}

/// The masks of `views` of `scene` (training views usually), in the order of `views`.
pub fn edge_masks(scene: &Scene, views: &[usize], cfg: &EdgeConfig) -> Result<Vec<EdgeMask>, EdgeError> {
    cfg.validate()?;
    views.iter().map(|&v| edge_mask(scene, v, cfg)).collect()
}

/// Everything that can go wrong while making edge masks.
#[derive(Debug, thiserror::Error)]
pub enum EdgeError {
    /// The edge configuration holds an impossible value.
    #[error("bad edge configuration: {message}")]
    Config { message: String },

    /// `source = external` without a directory.
    #[error(
        "edge source `external` needs the directory of edge maps: set the edge config's `dir` (CLI: \
         --edges DIR), or use the canny or none source"
    )]
    NoDir,

    /// A view index past the scene's views.
    #[error("no view {view}: the scene has {count} views")]
    NoSuchView { view: usize, count: usize },

    /// Canny needs pixels but the scene was loaded without them.
    #[error("view {view} ({path}) has no pixels: load the scene with images (LoadOptions::load_images) to detect edges")]
    NoPixels { view: String, path: PathBuf },

    /// The external edge-map directory does not exist.
    #[error("edge map directory not found: {dir} (pass the directory holding one edge map per image, or --edges canny)")]
    DirNotFound { dir: PathBuf },

    /// No external map for a view.
    #[error(
        "no edge map for view {view}: expected {expected} (or .jpg/.jpeg) in {dir}, which holds {present}; \
         write one map per training image, named after the image"
    )]
    MissingMap { view: String, expected: PathBuf, dir: PathBuf, present: String },

    /// An external map whose size differs from its image.
    #[error(
        "edge map {path} is {}x{} but its image {image} is {}x{}; edge maps must have exactly the image's \
         size (compute them on the images the scene loads, e.g. images_8 for LLFF)",
        got.0, got.1, expected.0, expected.1
    )]
    MapSize { path: PathBuf, got: (u32, u32), expected: (u32, u32), image: PathBuf },

    /// An image file (map or mask) could not be read or written.
    #[error("cannot read or write image {path}: {source} (PNG and JPEG are supported)")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },

    /// The operating system refused to read or write a file or directory.
    #[error("cannot access {path}: {source} (check that it exists and is readable/writable)")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl EdgeError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        EdgeError::Io { path: path.into(), source }
    }
}

#[cfg(test)]
mod tests;
