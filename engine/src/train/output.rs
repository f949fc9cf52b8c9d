//! Files a run writes: the renders of a view (RGB PNG, depth EXR (`sum w t`) and a
//! colourised PNG (`depth / opacity` where opacity > 0.1), normals EXR and PNG, opacity
//! PNG). The atomic replacement of a file that checkpoints, `config.json` and
//! `metrics.json` use is [`super::atomic_file`]'s (re-exported here).

use std::path::Path;

use crate::data::{ImageRgb, save_depth_exr, save_normal_exr};
use crate::viz;

use super::TrainError;
pub use super::atomic_file::write_atomic;
use super::model::RenderedView;

/// An error writing the output file `path`, said as one (an image library's "bad
/// OpenEXR file ...: No space left on device" blamed an input).
fn write_failed(path: &Path, e: impl Into<TrainError>) -> TrainError {
    use crate::data::DataError;
    let cause = match e.into() {
        TrainError::Data(DataError::Exr { message, .. }) => message,
        TrainError::Data(DataError::Image { source, .. }) => source.to_string(),
        TrainError::Data(DataError::Io { source, .. }) => source.to_string(),
        other => other.to_string(),
    };
    let _ = std::fs::remove_file(path);
    TrainError::Io {
        path: path.to_path_buf(),
        message: format!("writing this output failed ({cause}); check the free space and write permission there"),
    }
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
    let file = |suffix: &str| dir.join(format!("{name}_{suffix}"));
    let png = |img: ImageRgb, suffix: &str| img.save_png(file(suffix)).map_err(|e| write_failed(&file(suffix), e));
    png(rgb_image(r), "rgb.png")?;
    save_depth_exr(file("depth.exr"), w, h, &r.depth).map_err(|e| write_failed(&file("depth.exr"), e))?;
    let (shown, valid) = shown_depth(r);
    png(viz::depth_image(w, h, &shown, Some(&valid)).0, "depth.png")?;
    save_normal_exr(file("normal.exr"), w, h, &r.normal).map_err(|e| write_failed(&file("normal.exr"), e))?;
    png(viz::normal_image(w, h, &r.unit_normals()), "normal.png")?;
    png(viz::grey_image(w, h, &r.opacity), "opacity.png")?;
    Ok(())
}
