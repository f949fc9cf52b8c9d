//! The atomic replacement of a file: what checkpoints, `config.json`, `metrics.json`
//! and a resumed `log.csv` are written with. Below `checkpoint`, `output` and `model`
//! in the train room (it imports none of them), so they form no import circle.
//!
//! Invariant: [`write_atomic`] never leaves a half-written file under the final name
//! (written beside it, then renamed), so an interrupted write keeps the previous file,
//! and a failed one leaves no `.partial` file behind.

use std::path::Path;

use super::TrainError;

/// Replaces `path` with `bytes` atomically: written to `<path>.partial`, then renamed.
/// A failed write removes the `.partial` file (a full disk kept it, filling the disk).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = std::path::PathBuf::from(tmp);
    let written = std::fs::write(&tmp, bytes)
        .map_err(|e| TrainError::io(&tmp, e))
        .and_then(|()| std::fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e)));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    /// A write that fails leaves no `.partial` file behind (a full disk kept one).
    #[test]
    fn a_failed_write_leaves_no_partial_file() {
        let dir = tempfile::tempdir().unwrap();
        // The rename fails: a directory that is not empty stands at the final name.
        let target = dir.path().join("metrics.json");
        std::fs::create_dir_all(target.join("x")).unwrap();
        assert!(super::write_atomic(&target, b"{}").is_err());
        assert!(!dir.path().join("metrics.json.partial").exists());
        assert!(target.join("x").is_dir(), "what stood there is untouched");
    }
}
