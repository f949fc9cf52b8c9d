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

/// `edgenerf train` of the committed `creases` on 3 views with `sparse-small.toml`,
/// `iters` steps, no test evaluation, into `dir`, with `extra` arguments after those.
pub fn train_creases_3v(dir: &Path, iters: u32, extra: &[&str]) -> Output {
    let scene = repo().join("synthetic-scenes/small/creases");
    let config = repo().join("tools/configs/sparse-small.toml");
    let iters = iters.to_string();
    let mut args = vec!["train", scene.to_str().unwrap(), "--views", "3", "--config", config.to_str().unwrap()];
    args.extend_from_slice(&["--out", dir.to_str().unwrap(), "--iters", &iters, "--no-eval"]);
    args.extend_from_slice(extra);
    edgenerf(&args)
}

/// A run's `log.csv`: the header's column names and every row parsed as numbers.
pub fn read_log(dir: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let log = std::fs::read_to_string(dir.join("log.csv")).unwrap();
    let header = log.lines().next().unwrap().split(',').map(str::to_string).collect();
    let rows = log.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    (header, rows)
}
