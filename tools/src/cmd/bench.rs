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
//!
//! Beyond one machine: `--run-index N` runs run N alone through the same path
//! ([`Sweep::run_and_record`]); `--slurm` writes a job array whose task N does that
//! ([`crate::slurm`]), and `--report-only` gathers what the tasks wrote, with each
//! task's log.

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
    /// Train and evaluate only run N of the suite (0-based, the manifest's task id;
    /// what each Slurm array task runs), skipped if it has finished; no report.
    #[arg(long, value_name = "N", conflicts_with = "report_only")]
    run_index: Option<usize>,
    #[command(flatten)]
    slurm: crate::slurm::SlurmArgs,
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
/// as `--edges DIR` looks them up. Written once (a `.complete` marker), into a folder
/// beside `dir` renamed into place: the tasks of a Slurm array may write them at once.
pub fn write_gt_edge_maps(scene_path: &Path, dir: &Path) -> anyhow::Result<()> {
    if dir.join(".complete").is_file() {
        return Ok(());
    }
    let scene = Scene::load(scene_path, &LoadOptions::default()).with_context(|| format!("loading {}", scene_path.display()))?;
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.with_file_name(format!(".{name}.partial-{}-{nanos}", std::process::id()));
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let params = EdgeMapParams { dilate_px: 0.0, ..Default::default() };
    for (v, view) in scene.views.iter().enumerate() {
        let depth = view.depth.as_deref().filter(|_| scene.ndc.is_none());
        if depth.is_none() && view.normal.is_none() {
            let _ = std::fs::remove_dir_all(&tmp);
            bail!("edges = \"gt\" needs ground-truth depth or normals, and {} has none for view {}", scene_path.display(), view.name);
        }
        let (w, h) = (view.camera.width, view.camera.height);
        let edges = gt_edge_map(w, h, depth, view.normal.as_deref(), &params)?;
        let mask = EdgeMask { width: w, height: h, non_edge: edges.iter().map(|&e| u8::from(!e)).collect() };
        mask.save_png(&tmp.join(format!("{}.png", mask_stem(&scene, v))))?;
    }
    std::fs::write(tmp.join(".complete"), "")?;
    if dir.is_dir() && !dir.join(".complete").is_file() {
        // Left by an interrupted write of an older version.
        let _ = std::fs::remove_dir_all(dir);
    }
    match std::fs::rename(&tmp, dir) {
        Ok(()) => Ok(()),
        Err(_) if dir.join(".complete").is_file() => {
            // Another run wrote them first.
            let _ = std::fs::remove_dir_all(&tmp);
            Ok(())
        }
        Err(e) => Err(e).with_context(|| format!("renaming {} to {}", tmp.display(), dir.display())),
    }
}

/// The error lines of a failed subprocess's log ([`crate::suite::log_error_lines`]).
fn error_text(log: &Path, what: &str, status: std::process::ExitStatus) -> String {
    let msg = crate::suite::log_error_lines(log);
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

/// What every run of a sweep shares.
struct Sweep<'a> {
    exe: PathBuf,
    adapter: Option<&'a str>,
    lpips: Option<String>,
    commit: String,
    out: PathBuf,
}

impl Sweep<'_> {
    /// Trains and evaluates `spec` from scratch (its directory emptied first) and writes
    /// its record, `bench.json`, whichever way it ended.
    fn run_and_record(&self, spec: &RunSpec) -> anyhow::Result<RunRecord> {
        let dir = self.out.join("runs").join(&spec.id);
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| format!("clearing the unfinished run {}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let t = Instant::now();
        let result = run_one(&self.exe, self.adapter, self.lpips.as_deref(), spec, &dir);
        let record = RunRecord {
            id: spec.id.clone(),
            scene: spec.scene_name.clone(),
            scene_path: spec.scene.clone(),
            config: spec.config.name.clone(),
            repeat: spec.repeat,
            status: if result.is_ok() { "ok" } else { "failed" }.into(),
            error: result.err(),
            wall_s: t.elapsed().as_secs_f64(),
            git_commit: self.commit.clone(),
            train_args: spec.train_args.clone(),
        };
        let path = dir.join("bench.json");
        edgenerf::train::output::write_atomic(&path, serde_json::to_string_pretty(&record)?.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(record)
    }

    /// Whether run `spec` has finished (its record says `ok`).
    fn finished(&self, spec: &RunSpec) -> bool {
        read_record(&self.out.join("runs").join(&spec.id)).is_some_and(|rec| rec.status == "ok")
    }
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
    crate::output::refuse_file(&out, "--out")?;
    std::fs::create_dir_all(out.join("runs")).with_context(|| format!("creating {}", out.display()))?;
    let runs = suite.runs(&repo, args.repeats, &out.join("gt-edges"))?;
    let sweep = Sweep {
        exe: std::env::current_exe().context("locating the edgenerf binary")?,
        adapter,
        lpips: args.lpips.and_then(|l| clap::ValueEnum::to_possible_value(&l)).map(|v| v.get_name().to_string()),
        commit: git_commit(&repo),
        out: out.clone(),
    };
    let start = Instant::now();

    if let Some(i) = args.run_index {
        return run_single(&sweep, &runs, i);
    }
    if args.slurm.slurm {
        return write_slurm_job(&args, &sweep, &runs, &repo, &path, &title);
    }
    let mut none_finished = false;
    if !args.report_only {
        let todo: Vec<&RunSpec> = runs.iter().filter(|r| !sweep.finished(r)).collect();
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
            let record = sweep.run_and_record(spec)?;
            match &record.error {
                None => ok += 1,
                Some(e) => {
                    failed += 1;
                    let line = format!("{} failed: {e}", spec.id);
                    if bar.is_hidden() { eprintln!("{line}") } else { bar.println(line) }
                }
            }
            bar.inc(1);
        }
        bar.finish_and_clear();
        eprintln!("{ok} runs finished, {failed} failed, in {:.0} s", start.elapsed().as_secs_f64());
        none_finished = ok == 0 && failed > 0;
    }

    let mut rows = crate::report::collect(&runs, &out.join("runs"));
    // Runs of a Slurm array: each task's log (it holds what ended a task Slurm killed).
    if let Some(manifest) = crate::slurm::Manifest::read(&out)? {
        let logs = manifest.logs_by_run(&out);
        for row in &mut rows {
            if let Some(log) = logs.get(&row.id).filter(|l| l.is_file()) {
                row.log = Some(log.clone());
            }
        }
    }
    crate::report::write_all(&crate::report::ReportInput { title: &title, suite: &suite, suite_path: &path, repo: &repo, out: &out, rows: &rows, quick: args.quick })?;
    let failed = rows.iter().filter(|r| r.record.as_ref().is_none_or(|r| r.status != "ok")).count();
    eprintln!(
        "wrote {} ({} rows, {} not ok), results.csv, results.json and plots",
        out.join("report.md").display(),
        rows.len(),
        failed
    );
    // A failed run does not fail the sweep, but a sweep whose every run failed has
    // nothing to report (it exited 0). `--report-only` only reports.
    if none_finished && failed == rows.len() {
        bail!(
            "no run of the suite finished ({} of {} failed or missing); the errors are in {} and each run's train.log",
            failed,
            rows.len(),
            out.join("report.md").display()
        );
    }
    Ok(())
}

/// `--run-index N`: run N alone (what a Slurm array task does), unless it has finished.
/// Fails when the run fails (the task shows as failed in Slurm), after recording it.
fn run_single(sweep: &Sweep, runs: &[RunSpec], i: usize) -> anyhow::Result<()> {
    let Some(spec) = runs.get(i) else {
        bail!("--run-index {i}: the suite has {} runs (0 to {})", runs.len(), runs.len().saturating_sub(1));
    };
    if let Some(manifest) = crate::slurm::Manifest::read(&sweep.out)? {
        manifest.check(i, &spec.id)?;
    }
    if sweep.finished(spec) {
        eprintln!("run {i} ({}) finished before: skipped", spec.id);
        return Ok(());
    }
    let dir = sweep.out.join("runs").join(&spec.id);
    eprintln!("run {i} of {}: {} into {}", runs.len(), spec.id, dir.display());
    let record = sweep.run_and_record(spec)?;
    match record.error {
        None => {
            eprintln!("{} finished in {:.1} s", spec.id, record.wall_s);
            Ok(())
        }
        Some(e) => bail!("run {} failed: {e} (recorded in {})", spec.id, dir.join("bench.json").display()),
    }
}

/// `--slurm`: the job array script and manifest (and with `--submit`, the job).
fn write_slurm_job(args: &Args, sweep: &Sweep, runs: &[RunSpec], repo: &Path, suite_path: &Path, title: &str) -> anyhow::Result<()> {
    let abs = |p: &Path| std::path::absolute(p).with_context(|| format!("making {} absolute", p.display()));
    let exe = match &args.slurm.exe {
        Some(e) if !e.is_file() => bail!("--exe {}: no such file; pass the edgenerf binary the tasks should run", e.display()),
        Some(e) => abs(e)?,
        None => sweep.exe.clone(),
    };
    let out = abs(&sweep.out)?;
    let mut command = vec![exe.display().to_string()];
    if let Some(a) = sweep.adapter {
        command.extend(["--adapter".into(), a.to_string()]);
    }
    command.extend(["bench".into(), abs(suite_path)?.display().to_string(), "--out".into(), out.display().to_string()]);
    if args.quick {
        command.push("--quick".into());
    }
    if let Some(n) = args.repeats {
        command.extend(["--repeats".into(), n.to_string()]);
    }
    if let Some(l) = &sweep.lpips {
        command.extend(["--lpips".into(), l.clone()]);
    }
    // `data:` scenes resolve where the script was written, not where a task runs.
    let data = abs(&crate::suite::data_dir(repo))?;
    let env = if runs.iter().any(|r| r.scene.starts_with(&data)) {
        vec![("EDGENERF_DATA".to_string(), data.display().to_string())]
    } else {
        Vec::new()
    };
    let todo: Vec<usize> = (0..runs.len()).filter(|&i| !sweep.finished(&runs[i])).collect();
    let workdir = abs(repo)?;
    let job = crate::slurm::Job { title, runs, todo: &todo, out: &out, workdir: &workdir, env, command: command.clone(), opts: &args.slurm };
    let report = format!("{} --report-only", command.join(" "));
    let manifest = crate::slurm::slurm_dir(&out).join("manifest.tsv");
    let Some(script) = crate::slurm::write(&job)? else {
        eprintln!("all {} runs have finished: nothing to submit (wrote {}). The report: {report}", runs.len(), manifest.display());
        return Ok(());
    };
    eprintln!(
        "wrote {} ({} of {} runs to do, one array task each) and {}",
        script.display(),
        todo.len(),
        runs.len(),
        manifest.display()
    );
    if !args.slurm.submit {
        eprintln!("submit it with: sbatch {}
when the array has ended: {report}", script.display());
        return Ok(());
    }
    let id = crate::slurm::submit(&script)?;
    eprintln!("submitted job array {id}; follow it with: squeue -j {id}
when it has ended: {report}");
    println!("{id}");
    Ok(())
}
