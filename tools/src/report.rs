//! The results of a benchmark sweep: one [`Row`] per run read back from its run
//! directory (record, `log.csv`, `config.json`, `eval/metrics.json`), written as
//! `results.csv` / `results.json`, and `report.md` with markdown tables and the plots
//! of [`crate::plot`].
//!
//! Tables average the finished repeats of each (scene, config); a run that failed or
//! has not run shows in the failures table and nowhere else.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use edgenerf::train::RunConfig;
use serde::Serialize;

use crate::suite::{RunRecord, RunSpec, Suite, read_record};

/// One run of the sweep, as found on disk.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub id: String,
    pub scene: String,
    pub config: String,
    pub repeat: u32,
    /// `None`: the run has not finished (never started, or interrupted).
    pub record: Option<RunRecord>,
    /// Training steps done and the training loop's own time (log.csv).
    pub steps: Option<u64>,
    pub train_s: Option<f64>,
    pub steps_per_s: Option<f64>,
    pub samples_per_s: Option<f64>,
    /// Mean training-batch PSNR over the last 10% of steps.
    pub final_train_psnr: Option<f64>,
    pub adapter: Option<String>,
    pub config_hash: Option<String>,
    /// Test-split means of `eval` (dotted names, see `cmd::eval::flatten_view_metrics`).
    pub metrics: BTreeMap<String, f64>,
    /// The run's log: its Slurm task's log where the bench set one, else the last of
    /// its `train.log` / `eval.log` present.
    pub log: Option<PathBuf>,
    /// Evaluation directory and the first evaluated view's file stem (image strips).
    #[serde(skip)]
    pub eval_dir: PathBuf,
    #[serde(skip)]
    pub first_view: Option<String>,
    /// `(elapsed s, training PSNR smoothed)` along the run, for the plots.
    #[serde(skip)]
    pub curve: Vec<(f64, f64)>,
}

impl Row {
    pub fn ok(&self) -> bool {
        self.record.as_ref().is_some_and(|r| r.status == "ok")
    }
}

/// Columns of `log.csv` read back: elapsed seconds, PSNR and samples per step.
fn read_log(path: &Path) -> Option<Vec<(f64, f64, f64)>> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next()?.split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (t, p, s) = (col("elapsed_s")?, col("psnr")?, col("samples")?);
    let rows: Vec<(f64, f64, f64)> = lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((f.get(t)?.parse().ok()?, f.get(p)?.parse().ok()?, f.get(s)?.parse().ok()?))
        })
        .collect();
    (!rows.is_empty()).then_some(rows)
}

/// Reads every run of `runs` from `runs_dir`.
pub fn collect(runs: &[RunSpec], runs_dir: &Path) -> Vec<Row> {
    runs.iter()
        .map(|spec| {
            let dir = runs_dir.join(&spec.id);
            let mut row = Row {
                id: spec.id.clone(),
                scene: spec.scene_name.clone(),
                config: spec.config.name.clone(),
                repeat: spec.repeat,
                record: read_record(&dir),
                steps: None,
                train_s: None,
                steps_per_s: None,
                samples_per_s: None,
                final_train_psnr: None,
                adapter: None,
                config_hash: RunConfig::from_file(&dir.join("config.json")).ok().map(|c| c.hash()),
                metrics: BTreeMap::new(),
                log: ["eval.log", "train.log"].iter().map(|f| dir.join(f)).find(|p| p.is_file()),
                eval_dir: dir.join("eval"),
                first_view: None,
                curve: Vec::new(),
            };
            if let Some(log) = read_log(&dir.join("log.csv")) {
                let elapsed = log.last().map_or(0.0, |r| r.0).max(1e-9);
                row.steps = Some(log.len() as u64);
                row.train_s = Some(elapsed);
                row.steps_per_s = Some(log.len() as f64 / elapsed);
                row.samples_per_s = Some(log.iter().map(|r| r.2).sum::<f64>() / elapsed);
                let tail = &log[log.len() - (log.len() / 10).max(1)..];
                row.final_train_psnr = Some(tail.iter().map(|r| r.1).sum::<f64>() / tail.len() as f64);
                let mut ema = None::<f64>;
                let every = (log.len() / 300).max(1);
                for (i, &(t, p, _)) in log.iter().enumerate() {
                    let e = ema.map_or(p, |e| 0.9 * e + 0.1 * p);
                    ema = Some(e);
                    if i % every == 0 || i + 1 == log.len() {
                        row.curve.push((t, e));
                    }
                }
            }
            if let Ok(text) = std::fs::read_to_string(row.eval_dir.join("metrics.json"))
                && let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
            {
                row.adapter = v["adapter"].as_str().map(String::from);
                row.first_view = v["views"][0]["name"].as_str().map(String::from);
                if let Some(m) = v["metrics"].as_object() {
                    row.metrics = m.iter().filter_map(|(k, x)| Some((k.clone(), x.as_f64()?))).collect();
                }
            }
            row
        })
        .collect()
}

/// What the report is about.
pub struct ReportInput<'a> {
    pub title: &'a str,
    pub suite: &'a Suite,
    pub suite_path: &'a Path,
    pub repo: &'a Path,
    pub out: &'a Path,
    pub rows: &'a [Row],
    /// The suite's `--quick` variant.
    pub quick: bool,
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

fn opt<T: ToString>(x: &Option<T>) -> String {
    x.as_ref().map_or(String::new(), T::to_string)
}

/// `results.csv`: one row per run, every metric a column (empty where absent).
fn write_csv(rows: &[Row], path: &Path) -> anyhow::Result<()> {
    let keys: std::collections::BTreeSet<&String> = rows.iter().flat_map(|r| r.metrics.keys()).collect();
    let mut s = String::from(
        "id,scene,config,repeat,status,error,wall_s,train_s,steps,steps_per_s,samples_per_s,final_train_psnr,adapter,git_commit,config_hash",
    );
    for k in &keys {
        s.push(',');
        s.push_str(k);
    }
    s.push('\n');
    for r in rows {
        let rec = r.record.as_ref();
        let fields = [
            r.id.clone(),
            r.scene.clone(),
            r.config.clone(),
            r.repeat.to_string(),
            rec.map_or("missing".into(), |x| x.status.clone()),
            rec.and_then(|x| x.error.clone()).unwrap_or_default(),
            rec.map_or(String::new(), |x| format!("{:.1}", x.wall_s)),
            opt(&r.train_s.map(|x| format!("{x:.1}"))),
            opt(&r.steps),
            opt(&r.steps_per_s.map(|x| format!("{x:.3}"))),
            opt(&r.samples_per_s.map(|x| format!("{x:.0}"))),
            opt(&r.final_train_psnr.map(|x| format!("{x:.3}"))),
            opt(&r.adapter),
            rec.map_or(String::new(), |x| x.git_commit.clone()),
            opt(&r.config_hash),
        ];
        let mut line: Vec<String> = fields.iter().map(|f| csv_field(f)).collect();
        line.extend(keys.iter().map(|k| r.metrics.get(*k).map_or(String::new(), |x| format!("{x}"))));
        s.push_str(&line.join(","));
        s.push('\n');
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// Mean of `f` over the finished repeats in `rows`.
fn mean(rows: &[&Row], f: impl Fn(&Row) -> Option<f64>) -> Option<f64> {
    let v: Vec<f64> = rows.iter().filter_map(|r| f(r)).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn cell(x: Option<f64>, digits: usize) -> String {
    x.map_or("-".into(), |x| format!("{x:.digits$}"))
}

/// A markdown table: header, then rows.
fn table(out: &mut String, header: &[&str], rows: &[Vec<String>]) {
    let _ = writeln!(out, "| {} |", header.join(" | "));
    let _ = writeln!(out, "|{}", "---|".repeat(header.len()));
    for r in rows {
        let _ = writeln!(out, "| {} |", r.join(" | "));
    }
    out.push('\n');
}

/// A metric column of the tables: header, key in `Row::metrics`, digits, scale.
struct Col(&'static str, &'static str, usize, f64);

const IMAGE_COLS: &[Col] = &[Col("PSNR", "psnr", 2, 1.0), Col("SSIM", "ssim", 3, 1.0), Col("LPIPS vgg", "lpips_vgg", 3, 1.0), Col("LPIPS alex", "lpips_alex", 3, 1.0)];

const GEOMETRY_COLS: &[Col] = &[
    Col("depth abs", "depth.all.abs", 3, 1.0),
    Col("non-edge", "depth.non_edge.abs", 3, 1.0),
    Col("edge", "depth.edge.abs", 3, 1.0),
    Col("AbsRel", "depth.all.abs_rel", 3, 1.0),
    Col("RMSE", "depth.all.rmse", 3, 1.0),
    Col("d<1.25 %", "depth.all.delta_1", 1, 100.0),
    Col("normal deg", "normal.all.mean_deg", 1, 1.0),
    Col("non-edge", "normal.non_edge.mean_deg", 1, 1.0),
    Col("edge", "normal.edge.mean_deg", 1, 1.0),
    Col("median", "normal.all.median_deg", 1, 1.0),
    Col("<11.25 %", "normal.all.under_11_25", 1, 100.0),
    Col("<22.5 %", "normal.all.under_22_5", 1, 100.0),
    Col("<30 %", "normal.all.under_30", 1, 100.0),
    Col("DBE acc", "boundary.accuracy", 2, 1.0),
    Col("DBE comp", "boundary.completeness", 2, 1.0),
    Col("Chamfer", "mesh.chamfer", 4, 1.0),
    Col("F-score", "mesh.fscore", 3, 1.0),
    Col("precision", "mesh.precision", 3, 1.0),
    Col("recall", "mesh.recall", 3, 1.0),
];

fn metric_cells(rows: &[&Row], cols: &[Col]) -> Vec<String> {
    cols.iter().map(|c| cell(mean(rows, |r| r.metrics.get(c.1).map(|x| x * c.3)), c.2)).collect()
}

/// Finished rows of `scene` (or every scene with `None`) and `config`.
fn select<'a>(rows: &'a [Row], scene: Option<&str>, config: &str) -> Vec<&'a Row> {
    rows.iter().filter(|r| r.ok() && r.config == config && scene.is_none_or(|s| r.scene == s)).collect()
}

/// Scenes and configs in suite order.
fn axes(rows: &[Row]) -> (Vec<String>, Vec<String>) {
    let mut scenes: Vec<String> = Vec::new();
    let mut configs: Vec<String> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene) {
            scenes.push(r.scene.clone());
        }
        if !configs.contains(&r.config) {
            configs.push(r.config.clone());
        }
    }
    (scenes, configs)
}

/// Writes results.csv, results.json, the plots and report.md.
pub fn write_all(input: &ReportInput) -> anyhow::Result<()> {
    let ReportInput { title, suite, suite_path, repo, out, rows, quick } = *input;
    write_csv(rows, &out.join("results.csv"))?;
    std::fs::write(out.join("results.json"), serde_json::to_string_pretty(rows)?)?;
    let (scenes, configs) = axes(rows);
    let has_geometry = rows.iter().any(|r| r.metrics.contains_key("depth.all.abs") || r.metrics.contains_key("normal.all.mean_deg"));

    let mut md = String::new();
    let _ = writeln!(md, "# Benchmark `{title}`\n");
    if !suite.description.is_empty() {
        let _ = writeln!(md, "{}\n", suite.description);
    }
    let done: Vec<&Row> = rows.iter().filter(|r| r.ok()).collect();
    let commits: std::collections::BTreeSet<&str> = rows.iter().filter_map(|r| r.record.as_ref()).map(|r| r.git_commit.as_str()).collect();
    let adapters: std::collections::BTreeSet<&str> = rows.iter().filter_map(|r| r.adapter.as_deref()).collect();
    let wall: f64 = rows.iter().filter_map(|r| r.record.as_ref()).map(|r| r.wall_s).sum();
    let suite_shown = suite_path.strip_prefix(repo).unwrap_or(suite_path);
    let _ = writeln!(
        md,
        "Suite `{}`; {} runs: {} finished, {} failed or missing; {:.1} min of runs in all. \
         Commit {}; adapter {}. Regenerate with `edgenerf bench {}{} --report-only`.\n",
        suite_shown.display(),
        rows.len(),
        done.len(),
        rows.len() - done.len(),
        wall / 60.0,
        commits.into_iter().collect::<Vec<_>>().join(", "),
        adapters.into_iter().collect::<Vec<_>>().join(", "),
        suite_shown.display(),
        if quick { " --quick" } else { "" },
    );
    let _ = writeln!(md, "Configurations:\n");
    for c in &suite.configs {
        let _ = writeln!(md, "* `{}`: {}", c.name, if c.label.is_empty() { "(no description)" } else { &c.label });
    }
    md.push('\n');

    // Per configuration, over every scene: the paper's tables average over scenes.
    let _ = writeln!(md, "## Per configuration (mean over scenes)\n");
    let mut header = vec!["config", "runs"];
    header.extend(IMAGE_COLS.iter().map(|c| c.0));
    if has_geometry {
        header.extend(["AbsRel", "normal deg", "DBE acc"]);
    }
    header.extend(["train s", "steps/s"]);
    let mut body = Vec::new();
    for c in &configs {
        let sel = select(rows, None, c);
        let mut r = vec![format!("`{c}`"), sel.len().to_string()];
        r.extend(metric_cells(&sel, IMAGE_COLS));
        if has_geometry {
            r.extend(metric_cells(&sel, &[Col("", "depth.all.abs_rel", 3, 1.0), Col("", "normal.all.mean_deg", 1, 1.0), Col("", "boundary.accuracy", 2, 1.0)]));
        }
        r.push(cell(mean(&sel, |r| r.train_s), 0));
        r.push(cell(mean(&sel, |r| r.steps_per_s), 2));
        body.push(r);
    }
    table(&mut md, &header, &body);

    let _ = writeln!(
        md,
        "## Image metrics per scene\n\nTest-view means; `train PSNR`: the last 10% of training batches; `run s`: the whole \
         run (training, evaluation, start-ups), `train s`: the training loop.\n"
    );
    let mut header = vec!["scene", "config", "runs"];
    header.extend(IMAGE_COLS.iter().map(|c| c.0));
    header.extend(["train PSNR", "run s", "train s", "steps/s", "samples/s"]);
    let mut body = Vec::new();
    for s in &scenes {
        for c in &configs {
            let sel = select(rows, Some(s), c);
            let mut r = vec![s.clone(), format!("`{c}`"), sel.len().to_string()];
            r.extend(metric_cells(&sel, IMAGE_COLS));
            r.push(cell(mean(&sel, |r| r.final_train_psnr), 2));
            r.push(cell(mean(&sel, |r| r.record.as_ref().map(|x| x.wall_s)), 0));
            r.push(cell(mean(&sel, |r| r.train_s), 0));
            r.push(cell(mean(&sel, |r| r.steps_per_s), 2));
            r.push(cell(mean(&sel, |r| r.samples_per_s).map(|x| x / 1e6), 2) + " M");
            body.push(r);
        }
    }
    table(&mut md, &header, &body);

    if has_geometry {
        let _ = writeln!(
            md,
            "## Geometry against ground truth\n\nDepth errors in scene units (mean absolute, overall / outside / inside the GT \
             edge band of 2 px), AbsRel, RMSE, % of pixels with delta < 1.25; normal angle errors in degrees (mean overall / \
             non-edge / edge, median, % under 11.25 / 22.5 / 30 deg); iBims-1 depth boundary error in pixels; the exported mesh \
             against the scene's gt_mesh.ply (Chamfer distance in scene units, F-score, precision and recall at 1 % of the \
             box diagonal; `edgenerf eval`).\n"
        );
        let mut header = vec!["scene", "config"];
        header.extend(GEOMETRY_COLS.iter().map(|c| c.0));
        let mut body = Vec::new();
        for s in &scenes {
            for c in &configs {
                let sel = select(rows, Some(s), c);
                if sel.is_empty() {
                    continue;
                }
                let mut r = vec![s.clone(), format!("`{c}`")];
                r.extend(metric_cells(&sel, GEOMETRY_COLS));
                body.push(r);
            }
        }
        table(&mut md, &header, &body);
    }

    let failed: Vec<&Row> = rows.iter().filter(|r| !r.ok()).collect();
    if !failed.is_empty() {
        let _ = writeln!(md, "## Runs that failed or did not finish\n");
        let body: Vec<Vec<String>> = failed
            .iter()
            .map(|r| {
                let why = match (r.record.as_ref().and_then(|x| x.error.clone()), &r.log) {
                    (Some(e), _) => e,
                    (None, Some(log)) => format!("unfinished; its log ends: {}", crate::suite::log_error_lines(log)),
                    (None, None) => "not run yet (or interrupted)".into(),
                };
                let log = r.log.as_ref().map_or("-".into(), |l| format!("`{}`", l.strip_prefix(out).unwrap_or(l).display()));
                vec![format!("`{}`", r.id), why.replace('|', "\\|"), log]
            })
            .collect();
        table(&mut md, &["run", "error", "log"], &body);
    }

    let _ = writeln!(md, "## Plots\n");
    let curves: Vec<crate::plot::Curves> = scenes
        .iter()
        .map(|s| crate::plot::Curves {
            title: s.clone(),
            lines: configs
                .iter()
                .filter_map(|c| select(rows, Some(s), c).first().filter(|r| !r.curve.is_empty()).map(|r| (c.clone(), r.curve.clone())))
                .collect(),
        })
        .filter(|c| !c.lines.is_empty())
        .collect();
    if !curves.is_empty() {
        crate::plot::psnr_vs_time(&curves, &configs, &out.join("psnr_vs_time.png"))?;
        let _ = writeln!(md, "Training PSNR (batch PSNR, smoothed) against wall time, first repeat of each run:\n\n![PSNR vs time](psnr_vs_time.png)\n");
    }
    if has_geometry {
        let bars = |key: &str| -> Vec<Vec<Option<f64>>> {
            scenes.iter().map(|s| configs.iter().map(|c| mean(&select(rows, Some(s), c), |r| r.metrics.get(key).copied())).collect()).collect()
        };
        let panels = [
            crate::plot::BarPanel { title: "mean normal angle error (deg)".into(), values: bars("normal.all.mean_deg") },
            crate::plot::BarPanel { title: "depth AbsRel".into(), values: bars("depth.all.abs_rel") },
            crate::plot::BarPanel { title: "depth boundary error, accuracy (px)".into(), values: bars("boundary.accuracy") },
        ];
        crate::plot::grouped_bars(&panels, &scenes, &configs, &out.join("geometry.png"))?;
        let _ = writeln!(md, "Geometry metrics per scene (lower is better):\n\n![geometry](geometry.png)\n");
    }
    for s in &scenes {
        let columns: Vec<(String, PathBuf, String)> = configs
            .iter()
            .filter_map(|c| {
                let r = select(rows, Some(s), c).into_iter().next()?;
                Some((c.clone(), r.eval_dir.clone(), r.first_view.clone()?))
            })
            .collect();
        let Some(scene_path) = rows.iter().find(|r| &r.scene == s).and_then(|r| r.record.as_ref()).map(|r| r.scene_path.clone()) else {
            continue;
        };
        if columns.is_empty() {
            continue;
        }
        let file = format!("strip_{s}.png");
        match crate::plot::image_strip(&scene_path, &columns, &out.join(&file)) {
            Ok(()) => {
                let _ = writeln!(md, "`{s}`, test view `{}`: ground truth, then each configuration (RGB, depth, normals):\n\n![{s}]({file})\n", columns[0].2);
            }
            Err(e) => {
                let _ = writeln!(md, "(no image strip for `{s}`: {e:#})\n");
            }
        }
    }
    std::fs::write(out.join("report.md"), md).with_context(|| format!("writing {}", out.join("report.md").display()))
}
