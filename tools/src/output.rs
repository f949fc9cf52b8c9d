//! Files a run writes for a rendered view: RGB PNG, depth EXR (`sum w t`) + colourised
//! PNG (`depth / opacity` where opacity > 0.1),
//! normals EXR + PNG, opacity PNG. Shared by `train` (final test renders) and `render`.

use std::path::Path;

use anyhow::Context;
use edgenerf::data::{ImageRgb, save_depth_exr, save_normal_exr};
use edgenerf::train::RenderedView;
use edgenerf::viz;

/// Creates the output directory `dir` (given as `flag`) before any work, with a clear
/// error when a file is in the way (found only after rendering before).
pub fn ensure_dir(dir: &Path, flag: &str) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("{flag} {} is a file; pass a directory (it is created when missing)", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {flag} {}", dir.display()))
}

/// Writes `<dir>/<name>_{rgb,depth,normal,opacity}.*`.
pub fn write_view(dir: &Path, name: &str, r: &RenderedView) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let (w, h) = (r.width, r.height);
    let mut rgb = ImageRgb::new(w, h);
    for (i, px) in r.rgb.iter().enumerate() {
        rgb.data[3 * i..3 * i + 3].copy_from_slice(px);
    }
    rgb.save_png(dir.join(format!("{name}_rgb.png")))?;
    save_depth_exr(dir.join(format!("{name}_depth.exr")), w, h, &r.depth)?;
    // The EXR holds sum_i w_i t_i; the picture shows the distance given termination
    // (depth / opacity) wherever the ray has some opacity, black where it has next to
    // none (an early or forward-facing model is often only partly opaque; 0.5 hid most
    // of an LLFF scene).
    let valid: Vec<bool> = r.opacity.iter().map(|&a| a > 0.1).collect();
    let shown = r.terminated_depth(f32::INFINITY);
    viz::depth_image(w, h, &shown, Some(&valid)).0.save_png(dir.join(format!("{name}_depth.png")))?;
    save_normal_exr(dir.join(format!("{name}_normal.exr")), w, h, &r.normal)?;
    viz::normal_image(w, h, &r.unit_normals()).save_png(dir.join(format!("{name}_normal.png")))?;
    viz::grey_image(w, h, &r.opacity).save_png(dir.join(format!("{name}_opacity.png")))?;
    Ok(())
}
