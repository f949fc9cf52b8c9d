//! Benchmark suite files (`tools/suites/<name>.toml`, format in docs/bench.md): parsing,
//! the `[quick]` variant, and expansion into the list of runs `edgenerf bench` trains,
//! each with the `edgenerf train` arguments that make it, and the record each finished
//! run leaves (`runs/<id>/bench.json`), which the bench command writes and the report
//! reads.
//!
//! Invariants: unknown keys are errors (typos in a suite do not pass silently); run
//! ids (`<scene>__<config>__r<k>`) are unique within a suite and stable across
//! invocations, which is what makes a sweep resumable.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

/// A suite file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Suite {
    /// One line on what the suite measures.
    #[serde(default)]
    pub description: String,
    /// Scenes: a directory relative to the repository root, or `data:NAME` for a scene
    /// under `$EDGENERF_DATA` (default `../shared/data` beside the repository); or a
    /// table `{ path = ..., base_config = ... }` giving the scene its own base config.
    pub scenes: Vec<SceneEntry>,
    /// Base run config (TOML/JSON, relative to the repository root).
    pub base_config: Option<PathBuf>,
    /// Training views (`--views`); `None`: all.
    pub views: Option<usize>,
    /// Training steps (`--iters`); `None`: the base config's.
    pub iters: Option<u64>,
    /// Times each (scene, config) is trained (different seeds: `train.seed = repeat`).
    #[serde(default = "one")]
    pub repeats: u32,
    /// `--set` overrides for every run (dotted key -> value).
    #[serde(default)]
    pub set: BTreeMap<String, toml::Value>,
    /// The configurations compared, in table order.
    #[serde(rename = "config")]
    pub configs: Vec<ConfigSpec>,
    /// The quick variant: what it replaces.
    pub quick: Option<Quick>,
}

/// One scene of a suite.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum SceneEntry {
    Path(String),
    Table {
        path: String,
        /// Replaces the suite's base config for this scene (a config's own wins).
        base_config: Option<PathBuf>,
    },
}

impl SceneEntry {
    fn path(&self) -> &str {
        match self {
            SceneEntry::Path(p) | SceneEntry::Table { path: p, .. } => p,
        }
    }

    fn base_config(&self) -> Option<&PathBuf> {
        match self {
            SceneEntry::Path(_) => None,
            SceneEntry::Table { base_config, .. } => base_config.as_ref(),
        }
    }
}

fn one() -> u32 {
    1
}

/// One configuration: a named set of overrides of the base config.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigSpec {
    pub name: String,
    /// Shown in the report's tables (default: empty).
    #[serde(default)]
    pub label: String,
    /// `grid` or `mlp` (`--backend`).
    pub backend: Option<String>,
    /// `reg.depth` / `reg.normal` switches (`--no-depth-reg`, `--no-normal-reg`).
    pub depth_reg: Option<bool>,
    pub normal_reg: Option<bool>,
    /// `paper` or `official` (`--reg-variant`).
    pub reg_variant: Option<String>,
    pub lambda_depth: Option<f32>,
    pub lambda_normal: Option<f32>,
    /// Edge source: `canny`, `none`, `gt` (ground-truth edge maps the bench writes from
    /// the scene's GT depth and normals) or a directory of external maps.
    pub edges: Option<String>,
    /// `dark` or `bright` (external maps).
    pub edge_polarity: Option<String>,
    /// Overrides the suite's views / iters / base config.
    pub views: Option<usize>,
    pub iters: Option<u64>,
    pub base_config: Option<PathBuf>,
    /// More `--set` overrides (after the suite's).
    #[serde(default)]
    pub set: BTreeMap<String, toml::Value>,
    /// Extra `edgenerf train` arguments, verbatim.
    #[serde(default)]
    pub args: Vec<String>,
    /// Only on these scenes (directory names; default: every scene of the suite).
    pub scenes: Option<Vec<String>>,
}

/// The `[quick]` section: each key present replaces the suite's.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Quick {
    pub scenes: Option<Vec<SceneEntry>>,
    /// Names of the configurations kept (default: all).
    pub configs: Option<Vec<String>>,
    pub iters: Option<u64>,
    pub views: Option<usize>,
    pub repeats: Option<u32>,
    /// Merged over the suite's `set`.
    #[serde(default)]
    pub set: BTreeMap<String, toml::Value>,
}

/// One training run of a sweep.
#[derive(Clone, Debug)]
pub struct RunSpec {
    /// `<scene>__<config>__r<repeat>`: the run's directory name.
    pub id: String,
    pub scene_name: String,
    pub scene: PathBuf,
    pub config: ConfigSpec,
    pub repeat: u32,
    /// `edgenerf train` arguments without `--out` (the scene first). An edge source
    /// `gt` is passed as `--edges <gt_edges_dir>/<scene>` (the caller writes the maps).
    pub train_args: Vec<String>,
    /// The run needs ground-truth edge maps of its scene in this directory.
    pub gt_edges: Option<PathBuf>,
}

/// Where `data:` scenes live: `$EDGENERF_DATA`, else `../shared/data` beside the repo.
pub fn data_dir(repo: &Path) -> PathBuf {
    std::env::var_os("EDGENERF_DATA").map(PathBuf::from).unwrap_or_else(|| repo.join("../shared/data"))
}

/// The suite file of `name_or_path`: an existing path, else `tools/suites/<name>.toml`.
pub fn resolve(name_or_path: &str, repo: &Path) -> anyhow::Result<PathBuf> {
    let direct = PathBuf::from(name_or_path);
    if direct.is_file() {
        return Ok(direct);
    }
    let named = repo.join("tools/suites").join(format!("{name_or_path}.toml"));
    if named.is_file() {
        return Ok(named);
    }
    let known: Vec<String> = std::fs::read_dir(repo.join("tools/suites"))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| e.path().file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    bail!("no suite {name_or_path:?}: not a file, and not in {} (suites: {})", repo.join("tools/suites").display(), known.join(", "))
}

impl Suite {
    /// Reads and checks a suite file.
    pub fn load(path: &Path) -> anyhow::Result<Suite> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading suite {}", path.display()))?;
        let suite: Suite = toml::from_str(&text).with_context(|| format!("parsing suite {}", path.display()))?;
        if suite.configs.is_empty() || suite.scenes.is_empty() {
            bail!("suite {} needs at least one scene and one [[config]]", path.display());
        }
        let mut names = std::collections::HashSet::new();
        for c in &suite.configs {
            if c.name.is_empty() || c.name.contains(['/', ' ']) || c.name.contains("__") || !names.insert(&c.name) {
                bail!("suite {}: config names must be unique, non-empty, without '/', spaces or '__' ({:?})", path.display(), c.name);
            }
        }
        // repeats = 0 ran each run once without a word.
        if suite.repeats == 0 || suite.quick.as_ref().and_then(|q| q.repeats) == Some(0) {
            bail!("suite {}: repeats = 0 would train nothing; write repeats = 1 or more", path.display());
        }
        if let Some(q) = &suite.quick {
            for n in q.configs.iter().flatten() {
                if !suite.configs.iter().any(|c| &c.name == n) {
                    bail!("suite {}: [quick] names config {n:?}, which is not defined", path.display());
                }
            }
        }
        Ok(suite)
    }

    /// The suite with its `[quick]` section applied.
    pub fn quick(mut self) -> Suite {
        let Some(q) = self.quick.take() else { return self };
        if let Some(s) = q.scenes {
            self.scenes = s;
        }
        if let Some(keep) = q.configs {
            self.configs.retain(|c| keep.contains(&c.name));
        }
        self.iters = q.iters.or(self.iters);
        self.views = q.views.or(self.views);
        self.repeats = q.repeats.unwrap_or(self.repeats);
        self.set.extend(q.set);
        self
    }

    /// Every run, scene-major, then config, then repeat. `repeats` overrides the
    /// suite's; `gt_edges_root` is where ground-truth edge maps go, one folder per scene.
    pub fn runs(&self, repo: &Path, repeats: Option<u32>, gt_edges_root: &Path) -> anyhow::Result<Vec<RunSpec>> {
        let mut runs = Vec::new();
        let mut scene_names = std::collections::HashSet::new();
        for entry in &self.scenes {
            let scene = entry.path();
            let path = match scene.strip_prefix("data:") {
                Some(rel) => data_dir(repo).join(rel),
                None => repo.join(scene),
            };
            let scene_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| scene.to_string());
            if !scene_names.insert(scene_name.clone()) {
                bail!("two scenes of the suite are named {scene_name}");
            }
            for config in &self.configs {
                if config.scenes.as_ref().is_some_and(|only| !only.contains(&scene_name)) {
                    continue;
                }
                for repeat in 0..repeats.unwrap_or(self.repeats).max(1) {
                    let base = config.base_config.as_ref().or(entry.base_config()).or(self.base_config.as_ref());
                    let (train_args, gt_edges) = self.train_args(repo, &path, &scene_name, base, config, repeat, gt_edges_root);
                    runs.push(RunSpec {
                        id: format!("{scene_name}__{}__r{repeat}", config.name),
                        scene_name: scene_name.clone(),
                        scene: path.clone(),
                        config: config.clone(),
                        repeat,
                        train_args,
                        gt_edges,
                    });
                }
            }
        }
        Ok(runs)
    }

    #[allow(clippy::too_many_arguments)]
    fn train_args(
        &self,
        repo: &Path,
        scene: &Path,
        scene_name: &str,
        base: Option<&PathBuf>,
        c: &ConfigSpec,
        repeat: u32,
        gt_edges_root: &Path,
    ) -> (Vec<String>, Option<PathBuf>) {
        let mut a = vec![scene.display().to_string()];
        let mut push = |flag: &str, value: String| {
            a.push(flag.to_string());
            a.push(value);
        };
        if let Some(base) = base {
            push("--config", repo.join(base).display().to_string());
        }
        if let Some(k) = c.views.or(self.views) {
            push("--views", k.to_string());
        }
        if let Some(n) = c.iters.or(self.iters) {
            push("--iters", n.to_string());
        }
        if let Some(b) = &c.backend {
            push("--backend", b.clone());
        }
        if let Some(v) = &c.reg_variant {
            push("--reg-variant", v.clone());
        }
        if let Some(l) = c.lambda_depth {
            push("--lambda-depth", l.to_string());
        }
        if let Some(l) = c.lambda_normal {
            push("--lambda-normal", l.to_string());
        }
        let mut gt_edges = None;
        match c.edges.as_deref() {
            None => {}
            Some("gt") => {
                let dir = gt_edges_root.join(scene_name);
                push("--edges", dir.display().to_string());
                push("--edge-polarity", "dark".into());
                gt_edges = Some(dir);
            }
            Some(e @ ("canny" | "none")) => push("--edges", e.to_string()),
            Some(dir) => push("--edges", repo.join(dir).display().to_string()),
        }
        if let Some(p) = &c.edge_polarity {
            push("--edge-polarity", p.clone());
        }
        let mut set = self.set.clone();
        set.extend(c.set.clone());
        set.entry("train.seed".into()).or_insert(toml::Value::Integer(repeat as i64));
        for (k, v) in set {
            // `--set` parses values as JSON; TOML strings, numbers and booleans print as such.
            let value = match v {
                toml::Value::String(s) => s,
                other => serde_json::to_string(&other).unwrap_or_else(|_| other.to_string()),
            };
            push("--set", format!("{k}={value}"));
        }
        if c.depth_reg == Some(false) {
            a.push("--no-depth-reg".into());
        }
        if c.normal_reg == Some(false) {
            a.push("--no-normal-reg".into());
        }
        if c.depth_reg == Some(true) {
            a.extend(["--set".into(), "reg.depth=true".into()]);
        }
        if c.normal_reg == Some(true) {
            a.extend(["--set".into(), "reg.normal=true".into()]);
        }
        a.extend(c.args.iter().cloned());
        (a, gt_edges)
    }
}

/// A run's record, `runs/<id>/bench.json`: written when the run has finished, either
/// way.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunRecord {
    pub id: String,
    pub scene: String,
    pub scene_path: PathBuf,
    pub config: String,
    pub repeat: u32,
    /// `ok` or `failed`.
    pub status: String,
    pub error: Option<String>,
    /// Seconds of the whole run: training, evaluation and process start-ups.
    pub wall_s: f64,
    pub git_commit: String,
    /// The `edgenerf train` command line (without `--out`).
    pub train_args: Vec<String>,
}

/// Reads a run's record, if it has finished.
pub fn read_record(dir: &Path) -> Option<RunRecord> {
    serde_json::from_str(&std::fs::read_to_string(dir.join("bench.json")).ok()?).ok()
}

/// The error lines of a run's or a task's log: from its first `error:` line (or a panic,
/// or Slurm's `slurmstepd[-<host>]: error: *** JOB ... CANCELLED ...` when it ended the
/// task) on, else its last 5 lines,
/// joined by ` | `, at most ~1000 characters; empty when the log is missing or empty.
pub fn log_error_lines(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let start = lines
        .iter()
        .position(|l| l.starts_with("error:") || l.starts_with("thread '") || (l.starts_with("slurmstepd") && l.contains(": error:")))
        .unwrap_or(lines.len().saturating_sub(5));
    let mut msg = lines[start..].join(" | ");
    if msg.len() > 1000 {
        let cut = (0..=1000).rev().find(|&i| msg.is_char_boundary(i)).unwrap_or(0);
        msg.truncate(cut);
        msg.push_str(" ...");
    }
    msg
}
