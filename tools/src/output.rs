//! Output directories given on the command line (the files of a rendered view are
//! written by the engine, `edgenerf::train::output`).

use std::path::Path;

use anyhow::Context;

/// Creates the output directory `dir` (given as `flag`) before any work, with a clear
/// error when a file is in the way (found only after rendering before).
pub fn ensure_dir(dir: &Path, flag: &str) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("{flag} {} is a file; pass a directory (it is created when missing)", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {flag} {}", dir.display()))
}
