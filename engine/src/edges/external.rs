//! External edge maps (DexiNed or any detector): finding a view's file and reading it
//! as grey levels `0..=255`.
//!
//! Invariant: a view's map is `<dir>/<mask_stem>.{png,jpg,jpeg}` (any case of the
//! extension), else the image's path relative to the scene root mirrored under `dir`
//! with such an extension (`<dir>/test/r_000.png`). Maps of any bit depth and colour
//! type are reduced to grey levels in `0..=255` (Rec. 601 luma for colour files; a
//! 16-bit level `v` becomes `v / 257`); alpha is ignored.

use std::path::{Path, PathBuf};

use super::{EdgeError, mask_stem};
use crate::data::Scene;

const EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The first existing file `<base>.<ext>` over the accepted extensions (any case).
fn with_image_extension(base: &Path) -> Option<PathBuf> {
    EXTENSIONS
        .iter()
        .flat_map(|e| [e.to_string(), e.to_ascii_uppercase()])
        .map(|e| base.with_extension(e))
        .find(|p| p.is_file())
}

/// The path of view `view`'s edge map in `dir`.
pub(super) fn find_map(scene: &Scene, view: usize, dir: &Path) -> Result<PathBuf, EdgeError> {
    if !dir.is_dir() {
        return Err(EdgeError::DirNotFound { dir: dir.to_path_buf() });
    }
    let stem = mask_stem(scene, view);
    // `with_extension` would cut a stem holding a dot; append instead.
    let base = dir.join(format!("{stem}.png"));
    if let Some(p) = with_image_extension(&base) {
        return Ok(p);
    }
    let v = &scene.views[view];
    let mirrored = v.path.strip_prefix(&scene.root).ok().and_then(|rel| with_image_extension(&dir.join(rel)));
    if let Some(p) = mirrored {
        return Ok(p);
    }
    Err(EdgeError::MissingMap { view: v.name.clone(), expected: base, dir: dir.to_path_buf(), present: describe_dir(dir) })
}

/// A short description of the image files in `dir`: count and the first few names.
fn describe_dir(dir: &Path) -> String {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.rsplit_once('.').is_some_and(|(_, ext)| EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str())))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    match names.len() {
        0 => "no PNG or JPEG files".to_string(),
        n => {
            let shown = names.iter().take(4).cloned().collect::<Vec<_>>().join(", ");
            let more = if n > 4 { ", ..." } else { "" };
            format!("{n} image file{} ({shown}{more})", if n == 1 { "" } else { "s" })
        }
    }
}

/// Reads an image file as grey levels in `0..=255`, whatever its bit depth (Rec. 601
/// luma of colour files). Returns `(width, height, grey)`.
pub(super) fn read_grey(path: &Path) -> Result<(u32, u32, Vec<f32>), EdgeError> {
    let img = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| EdgeError::io(path, e))?
        .decode()
        .map_err(|source| EdgeError::Image { path: path.to_path_buf(), source })?;
    let (w, h) = (img.width(), img.height());
    // Exact grey levels for grey files (8-bit: the stored value; 16-bit: value / 257);
    // colour files: luma, rounded to 1e-3 so that a grey level written as RGB compares
    // with `tau_e` as the level itself.
    let grey = if img.color().has_color() {
        img.into_rgb16()
            .pixels()
            .map(|p| {
                let l = (0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2])) / 257.0;
                ((l * 1000.0).round() / 1000.0) as f32
            })
            .collect()
    } else {
        img.into_luma16().pixels().map(|p| f32::from(p[0]) / 257.0).collect()
    };
    Ok((w, h, grey))
}
