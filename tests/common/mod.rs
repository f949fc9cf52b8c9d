//! Shared helpers of the integration tests: where the real datasets live, and small
//! synthetic camera sets for loader tests.
//!
//! Real data (`llff/fern`, `dtu/scan24`) is looked up under `EDGENERF_DATA`, by default
//! `<workspace>/../shared/data`. Tests that need it call [`data_dir`] and return early
//! when it is absent, unless `EDGENERF_REQUIRE_DATA=1` makes that a failure (CI with data).

#![allow(dead_code)]

use std::path::PathBuf;

pub mod colmap;
mod dtu_arc;

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

#[allow(unused_imports)] // not every test crate that declares `mod common` builds DTU scans
pub use dtu_arc::dtu_camera_matrices;
