//! Shared helpers of the integration tests: where the real datasets live, and small
//! synthetic camera sets for loader tests.
//!
//! Real data (`llff/fern`, `dtu/scan24`) is looked up under `EDGENERF_DATA`, by default
//! `<workspace>/../shared/data`. Tests that need it call [`data_dir`] and return early
//! when it is absent, unless `EDGENERF_REQUIRE_DATA=1` makes that a failure (CI with data).

#![allow(dead_code)]

use std::path::PathBuf;

/// The real-data root, or `None` (after a note on stderr) when it is not available.
/// Panics instead when `EDGENERF_REQUIRE_DATA=1`.
pub fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("EDGENERF_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("..")
                .join("shared")
                .join("data")
        });
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("EDGENERF_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!(
            "real data not found at {} but EDGENERF_REQUIRE_DATA=1; set EDGENERF_DATA to the \
             directory holding llff/ and dtu/",
            dir.display()
        );
    }
    eprintln!(
        "skipping: real data not found at {}, set EDGENERF_DATA",
        dir.display()
    );
    None
}

/// A scene directory under the real-data root (e.g. `"llff/fern"`), with the same
/// skip/require policy as [`data_dir`] when the scene itself is missing.
pub fn scene_dir(rel: &str) -> Option<PathBuf> {
    let dir = data_dir()?.join(rel);
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("EDGENERF_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!(
            "scene {} not found but EDGENERF_REQUIRE_DATA=1",
            dir.display()
        );
    }
    eprintln!(
        "skipping: scene not found at {}, set EDGENERF_DATA",
        dir.display()
    );
    None
}

/// The `world_mat_i` / `scale_mat_i` pairs of a small DTU-layout scan of `n` views
/// (row-major 4x4): cameras on an arc looking at the origin through 8x6-pixel
/// intrinsics, every `scale_mat` a uniform `scale`.
pub fn dtu_camera_matrices(n: usize, scale: f64) -> Vec<(String, Vec<f64>)> {
    use glam::{DMat4, DVec3, DVec4};
    let k = DMat4::from_cols(DVec4::new(10.0, 0.0, 0.0, 0.0), DVec4::new(0.0, 10.0, 0.0, 0.0), DVec4::new(4.0, 3.0, 1.0, 0.0), DVec4::W);
    let rows = |m: DMat4| (0..4).flat_map(|r| m.row(r).to_array()).collect::<Vec<f64>>();
    let mut arrays = Vec::new();
    for i in 0..n {
        let a = i as f64 * 0.05;
        let c = DVec3::new(2.5 * a.cos(), 1.0, 2.5 * a.sin());
        let f = (-c).normalize();
        let r = f.cross(DVec3::Y).normalize();
        let d = f.cross(r);
        let w2c = DMat4::from_cols(r.extend(0.0), d.extend(0.0), f.extend(0.0), DVec4::W).transpose() * DMat4::from_translation(-c);
        arrays.push((format!("world_mat_{i}"), rows(k * w2c)));
        arrays.push((format!("scale_mat_{i}"), rows(DMat4::from_scale(DVec3::splat(scale)))));
    }
    arrays
}
