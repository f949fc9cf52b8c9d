//! Files a run writes: the renders of a view (RGB PNG, depth EXR (`sum w t`) and a
//! colourised PNG (`depth / opacity` where opacity > 0.1), normals EXR and PNG, opacity
//! PNG), and the atomic replacement of a file, which checkpoints, `config.json` and
//! `metrics.json` use.
//!
//! Invariant: [`write_atomic`] never leaves a half-written file under the final name
//! (written beside it, then renamed), so an interrupted write keeps the previous file.

use std::path::Path;

use crate::data::{ImageRgb, save_depth_exr, save_normal_exr};
use crate::viz;

use super::TrainError;
use super::model::RenderedView;

/// Replaces `path` with `bytes` atomically: written to `<path>.partial`, then renamed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = std::path::PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).map_err(|e| TrainError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e))
}

/// The rendered colour as an image.
pub fn rgb_image(r: &RenderedView) -> ImageRgb {
    let mut rgb = ImageRgb::new(r.width, r.height);
    for (i, px) in r.rgb.iter().enumerate() {
        rgb.data[3 * i..3 * i + 3].copy_from_slice(px);
    }
    rgb
}

/// The depth a picture shows, and where: the distance given termination (depth /
/// opacity) wherever the ray has some opacity (> 0.1), not where it has next to none
/// (an early or forward-facing model is often only partly opaque; 0.5 hid most of an
/// LLFF scene). The EXR holds `sum_i w_i t_i` instead.
pub fn shown_depth(r: &RenderedView) -> (Vec<f32>, Vec<bool>) {
    (r.terminated_depth(f32::INFINITY), r.opacity.iter().map(|&a| a > 0.1).collect())
}

/// Writes `<dir>/<name>_{rgb,depth,normal,opacity}.*` (creating `dir`).
pub fn write_view(dir: &Path, name: &str, r: &RenderedView) -> Result<(), TrainError> {
    std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    let (w, h) = (r.width, r.height);
    rgb_image(r).save_png(dir.join(format!("{name}_rgb.png")))?;
    save_depth_exr(dir.join(format!("{name}_depth.exr")), w, h, &r.depth)?;
    let (shown, valid) = shown_depth(r);
    viz::depth_image(w, h, &shown, Some(&valid)).0.save_png(dir.join(format!("{name}_depth.png")))?;
    save_normal_exr(dir.join(format!("{name}_normal.exr")), w, h, &r.normal)?;
    viz::normal_image(w, h, &r.unit_normals()).save_png(dir.join(format!("{name}_normal.png")))?;
    viz::grey_image(w, h, &r.opacity).save_png(dir.join(format!("{name}_opacity.png")))?;
    Ok(())
}
