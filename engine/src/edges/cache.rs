//! The per-run mask cache (`<run>/edges/`): one mask PNG per view, `<mask_stem>.png`,
//! and `stamp.json` recording what they were made from.
//!
//! Invariant: cached masks are returned only when the stamp equals the one the current
//! inputs give (algorithm version, the whole [`EdgeConfig`], and per view its name,
//! size, image path and a hash of its source: the loaded pixels for Canny, the map
//! file's bytes for external maps) and every mask file reads back with the view's
//! size. Otherwise all masks are recomputed and rewritten, the stamp last (written to
//! a temporary file and renamed), so an interrupted write leaves no matching stamp.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{EdgeConfig, EdgeError, EdgeMask, EdgeSource, edge_masks, external, mask_stem};
use crate::data::Scene;

/// Bumped whenever a change to the detector or the pipeline changes masks.
const VERSION: u32 = 1;

const STAMP: &str = "stamp.json";

#[derive(Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Stamp {
    version: u32,
    config: EdgeConfig,
    views: Vec<StampView>,
}

#[derive(Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StampView {
    /// `View::name`.
    name: String,
    /// Mask file name inside the cache directory.
    file: String,
    /// The view's image file.
    image: PathBuf,
    size: [u32; 2],
    /// FNV-1a 64 of the source (hex): the image's loaded pixels (Canny), the external
    /// map's file bytes (with its path), empty for `source = none`.
    source: String,
}

/// 64-bit FNV-1a.
fn fnv1a(bytes: impl IntoIterator<Item = u8>, mut h: u64) -> u64 {
    for b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

fn stamp_of(scene: &Scene, views: &[usize], cfg: &EdgeConfig) -> Result<Stamp, EdgeError> {
    let mut out = Vec::with_capacity(views.len());
    for &i in views {
        let Some(v) = scene.views.get(i) else {
            return Err(EdgeError::NoSuchView { view: i, count: scene.views.len() });
        };
        let source = match cfg.source {
            EdgeSource::None => String::new(),
            EdgeSource::Canny => {
                if v.image.is_empty() {
                    return Err(EdgeError::NoPixels { view: v.name.clone(), path: v.path.clone() });
                }
                format!("{:016x}", fnv1a(v.image.data.iter().flat_map(|x| x.to_bits().to_le_bytes()), FNV_OFFSET))
            }
            EdgeSource::External => {
                let dir = cfg.dir.as_deref().ok_or(EdgeError::NoDir)?;
                let path = external::find_map(scene, i, dir)?;
                let bytes = std::fs::read(&path).map_err(|e| EdgeError::io(&path, e))?;
                let h = fnv1a(path.to_string_lossy().bytes(), FNV_OFFSET);
                format!("{:016x}", fnv1a(bytes, h))
            }
        };
        out.push(StampView {
            name: v.name.clone(),
            file: format!("{}.png", mask_stem(scene, i)),
            image: v.path.clone(),
            size: [v.camera.width, v.camera.height],
            source,
        });
    }
    Ok(Stamp { version: VERSION, config: cfg.clone(), views: out })
}

/// The cached masks, when the stamp in `dir` equals `stamp` and every file reads back.
fn read_cache(dir: &Path, stamp: &Stamp) -> Option<Vec<EdgeMask>> {
    let text = std::fs::read_to_string(dir.join(STAMP)).ok()?;
    let old: Stamp = serde_json::from_str(&text).ok()?;
    if &old != stamp {
        return None;
    }
    stamp
        .views
        .iter()
        .map(|v| EdgeMask::load_png(&dir.join(&v.file)).ok().filter(|m| [m.width, m.height] == v.size))
        .collect()
}

/// Same as [`edge_masks`], but cached in `cache_dir` (e.g. `<run>/edges/`): one PNG per
/// view named after the view's image ([`mask_stem`](super::mask_stem)`.png`), plus
/// `stamp.json` with the config and the images' names and content hashes; reused when
/// the stamp matches, recomputed (and rewritten) otherwise. The directory is created
/// if needed.
pub fn edge_masks_cached(scene: &Scene, views: &[usize], cfg: &EdgeConfig, cache_dir: &Path) -> Result<Vec<EdgeMask>, EdgeError> {
    cfg.validate()?;
    let stamp = stamp_of(scene, views, cfg)?;
    if let Some(masks) = read_cache(cache_dir, &stamp) {
        log::info!("edge masks: reusing the cache in {}", cache_dir.display());
        return Ok(masks);
    }
    log::info!("edge masks: computing {} masks into {}", views.len(), cache_dir.display());
    let masks = edge_masks(scene, views, cfg)?;
    std::fs::create_dir_all(cache_dir).map_err(|e| EdgeError::io(cache_dir, e))?;
    let stamp_path = cache_dir.join(STAMP);
    // Invalidate first, so that a crash between the masks and the stamp never leaves a
    // stamp describing other masks.
    if stamp_path.exists() {
        std::fs::remove_file(&stamp_path).map_err(|e| EdgeError::io(&stamp_path, e))?;
    }
    for (mask, v) in masks.iter().zip(&stamp.views) {
        mask.save_png(&cache_dir.join(&v.file))?;
    }
    let json = serde_json::to_string_pretty(&stamp)
        .map_err(|e| EdgeError::Config { message: format!("cannot record the edge config in {}: {e}", stamp_path.display()) })?;
    let tmp = cache_dir.join(format!("{STAMP}.tmp"));
    std::fs::write(&tmp, json).map_err(|e| EdgeError::io(&tmp, e))?;
    std::fs::rename(&tmp, &stamp_path).map_err(|e| EdgeError::io(&stamp_path, e))?;
    Ok(masks)
}
