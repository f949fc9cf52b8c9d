//! `edgenerf bench <suite>`: a benchmark sweep. Expands a suite file
//! ([`crate::suite`]) into runs (scene x configuration x repeat), trains and evaluates
//! each in its own subprocess of this binary (`train --no-eval`, then `eval`), so a
//! crash or an error stays in its run; then collects every run into `results.csv`,
//! `results.json` and `report.md` with plots ([`crate::report`]).
//!
//! Layout of the output directory (default `runs/bench/<suite>[-quick]`):
//! `runs/<id>/` (the run directory: config.json, log.csv, checkpoint, `train.log`,
//! `eval/` with metrics.json, renders and error maps, `eval.log`, and `bench.json`,
//! the run's record), `gt-edges/<scene>/` (ground-truth edge maps for the `gt` edge
//! source), `results.*`, `report.md`, `*.png`.
//!
//! Resumability: a run whose `bench.json` says `ok` is skipped; a failed or unfinished
//! run is started again from scratch. A failure (non-zero exit of `train` or `eval`)
//! is recorded with the error lines of its log, and the sweep goes on.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use edgenerf::data::{LoadOptions, Scene};
use edgenerf::edges::{EdgeMask, mask_stem};
use edgenerf::metrics::{EdgeMapParams, gt_edge_map};
use indicatif::{ProgressBar, ProgressStyle};

use crate::suite::{RunRecord, RunSpec, Suite, read_record};

#[derive(clap::Args)]
pub struct Args {
    /// Suite name (tools/suites/<name>.toml) or a suite file.
    suite: String,
    /// The suite's quick variant (its [quick] section).
    #[arg(long)]
    quick: bool,
    /// Output directory (default runs/bench/<suite>, or <suite>-quick).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Repeats of each (scene, config) (default: the suite's).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    repeats: Option<u32>,
    /// Train nothing: rebuild results and report from the runs present.
    #[arg(long)]
    report_only: bool,
    /// LPIPS networks of each run's `eval` (default: those whose weights are installed).
    #[arg(long, value_enum)]
    lpips: Option<crate::cmd::eval::LpipsChoice>,
}

/// The repository root: the nearest ancestor of the working directory holding
/// `tools/suites`, else the tree this binary was built from.
pub fn repo_root() -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_default();
    cwd.ancestors()
        .find(|d| d.join("tools/suites").is_dir())
        .map(Path::to_path_buf)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new(".")).to_path_buf())
}

/// `git rev-parse HEAD` of the repository, or `unknown`.
fn git_commit(repo: &Path) -> String {
    Command::new("git")
        .arg("-C")
        .arg(repo)
        .args(["rev-parse", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".into())
}

/// Ground-truth edge maps of every view of a scene, as external edge maps (`dark`
/// polarity: black edges on white; undilated, the trainer's 3x3 dilation applies), named
/// as `--edges DIR` looks them up. Written once (a `.complete` marker).
pub fn write_gt_edge_maps(scene_path: &Path, dir: &Path) -> anyhow::Result<()> {
    if dir.join(".complete").is_file() {
        return Ok(());
    }
    let scene = Scene::load(scene_path, &LoadOptions::default()).with_context(|| format!("loading {}", scene_path.display()))?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let params = EdgeMapParams { dilate_px: 0.0, ..Default::default() };
    for (v, view) in scene.views.iter().enumerate() {
        let depth = view.depth.as_deref().filter(|_| scene.ndc.is_none());
        if depth.is_none() && view.normal.is_none() {
            bail!("edges = \"gt\" needs ground-truth depth or normals, and {} has none for view {}", scene_path.display(), view.name);
        }
        let (w, h) = (view.camera.width, view.camera.height);
        let edges = gt_edge_map(w, h, depth, view.normal.as_deref(), &params)?;
        let mask = EdgeMask { width: w, height: h, non_edge: edges.iter().map(|&e| u8::from(!e)).collect() };
        mask.save_png(&dir.join(format!("{}.png", mask_stem(&scene, v))))?;
    }
    std::fs::write(dir.join(".complete"), "")?;
    Ok(())
}

/// The error lines of a failed subprocess's log (from its first `error:` line on, or
/// its last lines), at most ~1000 characters.
fn error_text(log: &Path, what: &str, status: std::process::ExitStatus) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let start = lines.iter().position(|l| l.starts_with("error:") || l.starts_with("thread '")).unwrap_or(lines.len().saturating_sub(5));
    let mut msg = lines[start..].join(" | ");
    if msg.len() > 1000 {
        let cut = (0..=1000).rev().find(|&i| msg.is_char_boundary(i)).unwrap_or(0);
        msg.truncate(cut);
        msg.push_str(" ...");
    }
    if msg.is_empty() { format!("{what} exited with {status}") } else { format!("{what}: {msg}") }
}

/// Runs `exe args...` with stdout and stderr into `log`; `Err` with the error text on a
/// non-zero exit.
fn subprocess(exe: &Path, args: &[String], log: &Path, what: &str) -> Result<(), String> {
    let file = std::fs::File::create(log).map_err(|e| format!("creating {}: {e}", log.display()))?;
    let err = file.try_clone().map_err(|e| e.to_string())?;
    let status = Command::new(exe)
        .args(args)
        .stdout(file)
        .stderr(err)
        .status()
        .map_err(|e| format!("starting {}: {e}", exe.display()))?;
    if status.success() { Ok(()) } else { Err(error_text(log, what, status)) }
}

/// Trains and evaluates one run in `dir` (emptied first).
fn run_one(exe: &Path, adapter: Option<&str>, lpips: Option<&str>, spec: &RunSpec, dir: &Path) -> Result<(), String> {
    if let Some(gt) = &spec.gt_edges {
        write_gt_edge_maps(&spec.scene, gt).map_err(|e| format!("ground-truth edge maps: {e:#}"))?;
    }
    let global: Vec<String> = adapter.map(|a| vec!["--adapter".to_string(), a.to_string()]).unwrap_or_default();
    let mut train = global.clone();
    train.push("train".into());
    train.extend(spec.train_args.iter().cloned());
    train.extend(["--out".into(), dir.display().to_string(), "--no-eval".into()]);
    subprocess(exe, &train, &dir.join("train.log"), "train")?;
    let mut eval = global;
    eval.extend(["eval".into(), dir.display().to_string(), "--out".into(), dir.join("eval").display().to_string()]);
    if let Some(l) = lpips {
        eval.extend(["--lpips".into(), l.to_string()]);
    }
    subprocess(exe, &eval, &dir.join("eval.log"), "eval")
}

pub fn run(args: Args, adapter: Option<&str>) -> anyhow::Result<()> {
    let repo = repo_root();
    let path = crate::suite::resolve(&args.suite, &repo)?;
    let mut suite = Suite::load(&path)?;
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "suite".into());
    if args.quick {
        if suite.quick.is_none() {
            bail!("suite {} has no [quick] section", path.display());
        }
        suite = suite.quick();
    }
    let title = if args.quick { format!("{name}-quick") } else { name.clone() };
    let out = args.out.clone().unwrap_or_else(|| repo.join("runs/bench").join(&title));
    std::fs::create_dir_all(out.join("runs")).with_context(|| format!("creating {}", out.display()))?;
    let runs = suite.runs(&repo, args.repeats, &out.join("gt-edges"))?;
    let commit = git_commit(&repo);
    let exe = std::env::current_exe().context("locating the edgenerf binary")?;
    let start = Instant::now();
    let lpips = args.lpips.and_then(|l| clap::ValueEnum::to_possible_value(&l)).map(|v| v.get_name().to_string());

    if !args.report_only {
        let todo: Vec<&RunSpec> =
            runs.iter().filter(|r| read_record(&out.join("runs").join(&r.id)).is_none_or(|rec| rec.status != "ok")).collect();
        eprintln!(
            "suite {title} ({}): {} runs, {} finished before, {} to do; output {}",
            path.display(),
            runs.len(),
            runs.len() - todo.len(),
            todo.len(),
            out.display()
        );
        let bar = ProgressBar::new(runs.len() as u64);
        bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} runs [{elapsed_precise}<{eta_precise}] {msg}").unwrap());
        bar.set_position((runs.len() - todo.len()) as u64);
        let (mut ok, mut failed) = (0, 0);
        for spec in todo {
            bar.set_message(spec.id.clone());
            let dir = out.join("runs").join(&spec.id);
            if dir.exists() {
                std::fs::remove_dir_all(&dir).with_context(|| format!("clearing the unfinished run {}", dir.display()))?;
            }
            std::fs::create_dir_all(&dir)?;
            let t = Instant::now();
            let result = run_one(&exe, adapter, lpips.as_deref(), spec, &dir);
            let record = RunRecord {
                id: spec.id.clone(),
                scene: spec.scene_name.clone(),
                scene_path: spec.scene.clone(),
                config: spec.config.name.clone(),
                repeat: spec.repeat,
                status: if result.is_ok() { "ok" } else { "failed" }.into(),
                error: result.err(),
                wall_s: t.elapsed().as_secs_f64(),
                git_commit: commit.clone(),
                train_args: spec.train_args.clone(),
            };
            match &record.error {
                None => ok += 1,
                Some(e) => {
                    failed += 1;
                    let line = format!("{} failed: {e}", spec.id);
                    if bar.is_hidden() { eprintln!("{line}") } else { bar.println(line) }
                }
            }
            std::fs::write(dir.join("bench.json"), serde_json::to_string_pretty(&record)?)?;
            bar.inc(1);
        }
        bar.finish_and_clear();
        eprintln!("{ok} runs finished, {failed} failed, in {:.0} s", start.elapsed().as_secs_f64());
    }

    let rows = crate::report::collect(&runs, &out.join("runs"));
    crate::report::write_all(&crate::report::ReportInput { title: &title, suite: &suite, suite_path: &path, repo: &repo, out: &out, rows: &rows, quick: args.quick })?;
    let failed = rows.iter().filter(|r| r.record.as_ref().is_none_or(|r| r.status != "ok")).count();
    eprintln!(
        "wrote {} ({} rows, {} not ok), results.csv, results.json and plots",
        out.join("report.md").display(),
        rows.len(),
        failed
    );
    Ok(())
}
