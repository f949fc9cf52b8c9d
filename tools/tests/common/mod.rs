//! Shared by the CLI test files: running the `edgenerf` binary and reading its output.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the binary under test with `args` (XDG_RUNTIME_DIR set, as lavapipe wants).
pub fn edgenerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_edgenerf"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("run edgenerf")
}

/// The repository root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// stdout and stderr together.
pub fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}
