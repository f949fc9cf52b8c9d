//! Shared by the CLI test files: running the `edgenerf` binary and reading its output.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test, XDG_RUNTIME_DIR set (lavapipe wants it); add arguments,
/// a working directory, ...
pub fn command() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_edgenerf"));
    c.env("XDG_RUNTIME_DIR", std::env::temp_dir());
    c
}

/// Runs the binary under test with `args`.
pub fn edgenerf(args: &[&str]) -> Output {
    command().args(args).output().expect("run edgenerf")
}

/// The repository root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// stdout and stderr together.
pub fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}
