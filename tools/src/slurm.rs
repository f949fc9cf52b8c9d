//! `edgenerf bench SUITE --slurm`: a sweep as a Slurm job array. Writes, under
//! `<out>/slurm/`, `bench.sbatch` (one array task per run still to do; task N runs
//! `edgenerf bench SUITE --run-index N`, the single-run path of the local bench, into
//! the same run directories) and `manifest.tsv` (task id -> run id -> task log), and
//! with `--submit` hands the script to `sbatch --parsable`.
//!
//! Invariants: task ids are the runs' indices in the suite's expansion (stable across
//! invocations, like the run ids), so a resubmission after some runs finished names
//! only the others; every path in the script is absolute (a task starts wherever the
//! cluster puts it); the manifest lets `--run-index` refuse a suite that changed since
//! the script was written, and lets `--report-only` show each task's log.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

use crate::suite::RunSpec;

/// Slurm options of `edgenerf bench`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SlurmArgs {
    /// Write a Slurm job array script (one task per run still to do) and a manifest
    /// under <out>/slurm/ instead of running the sweep here.
    #[arg(long, conflicts_with_all = ["report_only", "run_index"])]
    pub slurm: bool,
    /// With --slurm: submit the script (`sbatch --parsable`) and print the job id.
    #[arg(long, requires = "slurm")]
    pub submit: bool,
    /// With --slurm: the partition (#SBATCH --partition).
    #[arg(long, requires = "slurm", value_name = "NAME")]
    pub partition: Option<String>,
    /// With --slurm: each task's time limit (#SBATCH --time, e.g. 30:00 or 1-00:00:00).
    #[arg(long, requires = "slurm", value_name = "LIMIT")]
    pub time: Option<String>,
    /// With --slurm: CPUs per task (#SBATCH --cpus-per-task).
    #[arg(long, requires = "slurm", value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub cpus_per_task: Option<u32>,
    /// With --slurm: generic resources per task (#SBATCH --gres, e.g. gpu:1).
    #[arg(long, requires = "slurm", value_name = "SPEC")]
    pub gres: Option<String>,
    /// With --slurm: memory per task (#SBATCH --mem, e.g. 16G).
    #[arg(long, requires = "slurm", value_name = "SIZE")]
    pub mem: Option<String>,
    /// With --slurm: at most this many tasks at once (the array's %N).
    #[arg(long, requires = "slurm", value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub array_parallelism: Option<u32>,
    /// With --slurm: the account charged (#SBATCH --account).
    #[arg(long, requires = "slurm", value_name = "NAME")]
    pub account: Option<String>,
    /// With --slurm: another #SBATCH line, verbatim (repeatable: --sbatch-arg=--qos=long).
    #[arg(long = "sbatch-arg", requires = "slurm", value_name = "ARG", allow_hyphen_values = true)]
    pub sbatch_args: Vec<String>,
    /// With --slurm: the edgenerf binary the tasks run (default: this one).
    #[arg(long, requires = "slurm", value_name = "PATH")]
    pub exe: Option<PathBuf>,
}

/// The folder of the script, the manifest and the task logs.
pub fn slurm_dir(out: &Path) -> PathBuf {
    out.join("slurm")
}

/// Task `index`'s log (the script's `--output`, `%a` being the task id).
fn task_log(out: &Path, index: usize) -> PathBuf {
    slurm_dir(out).join("logs").join(format!("task-{index}.log"))
}

/// `manifest.tsv`: task id -> run id (and its log), for every run of the suite.
pub struct Manifest {
    /// Run ids, by task id.
    pub runs: Vec<String>,
}

const MANIFEST_HEADER: &str = "task\trun\tlog";

impl Manifest {
    fn path(out: &Path) -> PathBuf {
        slurm_dir(out).join("manifest.tsv")
    }

    /// The manifest written by `--slurm` into `out`, if any.
    pub fn read(out: &Path) -> anyhow::Result<Option<Manifest>> {
        let path = Manifest::path(out);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        };
        let bad = || format!("{} is not a manifest written by `edgenerf bench --slurm`; delete it and run --slurm again", path.display());
        let mut lines = text.lines();
        if lines.next() != Some(MANIFEST_HEADER) {
            bail!(bad());
        }
        let mut runs = Vec::new();
        for (i, line) in lines.enumerate() {
            let f: Vec<&str> = line.split('\t').collect();
            if f.len() != 3 || f[0].parse::<usize>().ok() != Some(i) {
                bail!(bad());
            }
            runs.push(f[1].to_string());
        }
        Ok(Some(Manifest { runs }))
    }

    /// The task log of each run, by run id, under `out` (where the manifest was read:
    /// the output directory may have moved since).
    pub fn logs_by_run(&self, out: &Path) -> BTreeMap<String, PathBuf> {
        self.runs.iter().enumerate().map(|(i, r)| (r.clone(), task_log(out, i))).collect()
    }

    /// Fails when run `index` of the suite as it is now is not the run the manifest
    /// gave that task id (the suite file changed after the script was written).
    pub fn check(&self, index: usize, run: &str) -> anyhow::Result<()> {
        match self.runs.get(index) {
            Some(r) if r == run => Ok(()),
            other => bail!(
                "task {index} is {} in the manifest, but run {index} of the suite is now {run:?}: the suite changed after \
                 `--slurm` wrote the script; write it again (edgenerf bench ... --slurm)",
                other.map_or("absent".into(), |r| format!("{r:?}"))
            ),
        }
    }
}

/// `a-b,c,...` of sorted task ids.
fn array_ranges(ids: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < ids.len() {
        let mut j = i;
        while j + 1 < ids.len() && ids[j + 1] == ids[j] + 1 {
            j += 1;
        }
        parts.push(if j > i { format!("{}-{}", ids[i], ids[j]) } else { ids[i].to_string() });
        i = j + 1;
    }
    parts.join(",")
}

/// `s` quoted for a POSIX shell.
fn sh_quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "/._-=:,+@%".contains(c)) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// What the script is made of.
pub struct Job<'a> {
    /// The suite's title (`<name>[-quick]`): the job name.
    pub title: &'a str,
    pub runs: &'a [RunSpec],
    /// Task ids (run indices) still to do.
    pub todo: &'a [usize],
    /// The output directory (absolute).
    pub out: &'a Path,
    /// The working directory of every task (the repository root, absolute).
    pub workdir: &'a Path,
    /// Environment every task gets (name, value).
    pub env: Vec<(String, String)>,
    /// The task's command line before `--run-index`, the binary first (absolute paths).
    pub command: Vec<String>,
    pub opts: &'a SlurmArgs,
}

/// The job array script.
pub fn script(job: &Job) -> anyhow::Result<String> {
    let o = job.opts;
    let logs = slurm_dir(job.out).join("logs");
    let logs_s = logs.display().to_string();
    if logs_s.contains(|c: char| c.is_whitespace() || "'\"\\".contains(c)) {
        bail!("the output directory {} holds spaces or quotes, which #SBATCH --output cannot take; pass another --out", job.out.display());
    }
    let mut array = array_ranges(job.todo);
    if let Some(p) = o.array_parallelism {
        array.push_str(&format!("%{p}"));
    }
    let mut s = String::from("#!/bin/bash\n");
    s.push_str(&format!(
        "# edgenerf bench `{}` as a Slurm job array, written by `edgenerf bench --slurm`: {} runs, {} to do.\n\
         # Array task N trains and evaluates run N of manifest.tsv (beside this script) into\n\
         # {}/runs/<run>/; a finished run is skipped, so resubmitting is safe.\n\
         # When the array has ended: {} --report-only\n",
        job.title,
        job.runs.len(),
        job.todo.len(),
        job.out.display(),
        job.command.iter().map(|a| sh_quote(a)).collect::<Vec<_>>().join(" "),
    ));
    let mut sbatch = vec![format!("--job-name=edgenerf-{}", job.title), format!("--array={array}"), format!("--output={logs_s}/task-%a.log")];
    let mut opt = |flag: &str, v: Option<String>| {
        if let Some(v) = v {
            sbatch.push(format!("--{flag}={v}"));
        }
    };
    opt("partition", o.partition.clone());
    opt("time", o.time.clone());
    opt("cpus-per-task", o.cpus_per_task.map(|n| n.to_string()));
    opt("gres", o.gres.clone());
    opt("mem", o.mem.clone());
    opt("account", o.account.clone());
    sbatch.extend(o.sbatch_args.iter().cloned());
    for a in &sbatch {
        if a.contains('\n') {
            bail!("an sbatch option holds a line break: {a:?}");
        }
        s.push_str(&format!("#SBATCH {a}\n"));
    }
    s.push_str("\nset -euo pipefail\n");
    s.push_str(&format!("cd {}\n", sh_quote(&job.workdir.display().to_string())));
    for (k, v) in &job.env {
        s.push_str(&format!("export {k}={}\n", sh_quote(v)));
    }
    let cmd: Vec<String> = job.command.iter().map(|a| sh_quote(a)).collect();
    s.push_str(&format!("exec {} --run-index \"$SLURM_ARRAY_TASK_ID\"\n", cmd.join(" ")));
    Ok(s)
}

/// Writes `manifest.tsv` and, when there is something to do, `bench.sbatch`; returns
/// the script's path (`None`: every run has finished).
pub fn write(job: &Job) -> anyhow::Result<Option<PathBuf>> {
    let dir = slurm_dir(job.out);
    std::fs::create_dir_all(dir.join("logs")).with_context(|| format!("creating {}", dir.join("logs").display()))?;
    let mut manifest = format!("{MANIFEST_HEADER}\n");
    for (i, r) in job.runs.iter().enumerate() {
        manifest.push_str(&format!("{i}\t{}\t{}\n", r.id, task_log(job.out, i).display()));
    }
    let write = |path: &Path, text: &str| edgenerf::train::output::write_atomic(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()));
    write(&Manifest::path(job.out), &manifest)?;
    if job.todo.is_empty() {
        return Ok(None);
    }
    let path = dir.join("bench.sbatch");
    write(&path, &script(job)?)?;
    Ok(Some(path))
}

/// `sbatch --parsable SCRIPT`: the job id.
pub fn submit(script: &Path) -> anyhow::Result<String> {
    let o = Command::new("sbatch").arg("--parsable").arg(script).output().map_err(|e| {
        anyhow::anyhow!(
            "could not run sbatch ({e}): submit from a machine with the Slurm client (a login node), or submit the script \
             yourself: sbatch {}",
            script.display()
        )
    })?;
    if !o.status.success() {
        bail!("sbatch {} failed ({}): {}", script.display(), o.status, String::from_utf8_lossy(&o.stderr).trim());
    }
    // `--parsable` prints `<job id>[;<cluster>]`.
    let stdout = String::from_utf8_lossy(&o.stdout);
    let id = stdout.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        bail!("sbatch accepted {} but printed no job id: {:?}", script.display(), stdout.trim());
    }
    Ok(id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_ranges_compress_runs_of_ids() {
        assert_eq!(array_ranges(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
        assert_eq!(array_ranges(&[3]), "3");
        assert_eq!(array_ranges(&[]), "");
    }

    #[test]
    fn shell_quoting() {
        assert_eq!(sh_quote("/a/b-c_d.toml"), "/a/b-c_d.toml");
        assert_eq!(sh_quote("a b"), "'a b'");
        assert_eq!(sh_quote("it's"), r"'it'\''s'");
        assert_eq!(sh_quote(""), "''");
    }
}
