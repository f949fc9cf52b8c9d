//! `edgenerf bench --slurm` against a real single-node Slurm (Debian's `slurm-wlm` and
//! `munge`): the test starts munged, slurmctld and slurmd itself from a generated
//! slurm.conf in a temporary directory (its own ports and socket, so it meets no
//! cluster of the machine), submits a tiny suite as a job array, waits for it, and
//! checks `--report-only`'s results; a guard stops the daemons however the test ends.
//! Skipped with a message when Slurm is not installed, unless EDGENERF_REQUIRE_SLURM=1.
//! Without Slurm: the script, the manifest, `--run-index` and the report of a killed
//! task.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{command, text};

/// Two working runs on `scene` (3 views, 3 steps, coarse marching) and, `with_broken`,
/// one that fails at once (an unknown config key).
fn tiny_suite(dir: &Path, scene: &str, with_broken: bool) -> PathBuf {
    let suite = dir.join("tiny.toml");
    let broken = "\n[[config]]\nname = \"broken\"\nset = { \"train.no_such_key\" = 1 }\n";
    std::fs::write(
        &suite,
        format!(
            r#"
description = "Slurm test suite"
scenes = ["{}"]
base_config = "tools/configs/sparse-small.toml"
views = 3
iters = 3
set = {{ "sampler.steps_per_diagonal" = 48, "train.checkpoint_every" = 0 }}

[[config]]
name = "none"
depth_reg = false
normal_reg = false

[[config]]
name = "edge-gt"
edges = "gt"
{}"#,
            scene,
            if with_broken { broken } else { "" }
        ),
    )
    .unwrap();
    suite
}

fn bench(args: &[&str]) -> std::process::Output {
    command().arg("bench").args(args).current_dir(common::repo()).output().unwrap()
}

fn read_rows(out: &Path) -> Vec<serde_json::Value> {
    serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap()
}

#[test]
fn slurm_script_manifest_run_index_and_killed_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path(), "synthetic-scenes/small/turntable", true);
    let out = dir.path().join("out");
    let (s, o) = (suite.to_str().unwrap(), out.to_str().unwrap());
    let slurm_opts =
        ["--slurm", "--partition", "gpu", "--time", "0:30:00", "--cpus-per-task", "4", "--gres", "gpu:1", "--mem", "8G", "--array-parallelism", "2", "--account", "proj"];
    let r = bench(&[&[s, "--out", o, "--lpips", "none"], &slurm_opts[..], &["--sbatch-arg=--qos=short"]].concat());
    let t = text(&r);
    assert!(r.status.success(), "{t}");
    assert!(t.contains("3 of 3 runs to do") && t.contains("sbatch "), "{t}");
    let script = std::fs::read_to_string(out.join("slurm/bench.sbatch")).unwrap();
    let exe = std::fs::canonicalize(env!("CARGO_BIN_EXE_edgenerf")).unwrap();
    for line in [
        "#SBATCH --array=0-2%2".to_string(),
        format!("#SBATCH --output={o}/slurm/logs/task-%a.log"),
        "#SBATCH --partition=gpu".into(),
        "#SBATCH --time=0:30:00".into(),
        "#SBATCH --cpus-per-task=4".into(),
        "#SBATCH --gres=gpu:1".into(),
        "#SBATCH --mem=8G".into(),
        "#SBATCH --account=proj".into(),
        "#SBATCH --qos=short".into(),
        format!("cd {}", common::repo().display()),
        format!("exec {} bench {s} --out {o} --lpips none --run-index \"$SLURM_ARRAY_TASK_ID\"", exe.display()),
    ] {
        assert!(script.lines().any(|l| l == line), "no line {line:?} in\n{script}");
    }
    let manifest = std::fs::read_to_string(out.join("slurm/manifest.tsv")).unwrap();
    assert_eq!(manifest.lines().nth(3), Some(format!("2\tturntable__broken__r0\t{o}/slurm/logs/task-2.log").as_str()), "{manifest}");

    // The failing run alone, as its array task would run it: recorded, and the exit fails.
    let r = bench(&[s, "--out", o, "--lpips", "none", "--run-index", "2"]);
    assert!(!r.status.success());
    assert!(text(&r).contains("run turntable__broken__r0 failed") && text(&r).contains("no_such_key"), "{}", text(&r));
    let rec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("runs/turntable__broken__r0/bench.json")).unwrap()).unwrap();
    assert_eq!(rec["status"], "failed");
    let r = bench(&[s, "--out", o, "--run-index", "3"]);
    assert!(!r.status.success() && text(&r).contains("the suite has 3 runs (0 to 2)"), "{}", text(&r));

    // A task Slurm killed leaves no record, only its log: the report shows why, and where.
    std::fs::write(out.join("slurm/logs/task-1.log"), "run 1 of 3: turntable__edge-gt__r0\nslurmstepd-n1: error: *** JOB 7 ON n1 CANCELLED AT 2026-01-01T00:00:00 DUE TO TIME LIMIT ***\n").unwrap();
    let r = bench(&[s, "--out", o, "--report-only"]);
    assert!(r.status.success(), "{}", text(&r));
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for want in [
        "| `turntable__edge-gt__r0` | unfinished; its log ends: slurmstepd-n1: error: *** JOB 7 ON n1 CANCELLED AT 2026-01-01T00:00:00 DUE TO TIME LIMIT *** | `slurm/logs/task-1.log` |",
        "| `turntable__none__r0` | not run yet (or interrupted) | - |",
        "no_such_key",
    ] {
        assert!(report.contains(want), "report.md lacks {want:?}:\n{report}");
    }

    // The suite changed after the script was written: a task refuses to run another run.
    std::fs::write(&suite, std::fs::read_to_string(&suite).unwrap().replace("name = \"none\"", "name = \"plain\"")).unwrap();
    let r = bench(&[s, "--out", o, "--run-index", "0"]);
    assert!(!r.status.success() && text(&r).contains("the suite changed"), "{}", text(&r));
    // --submit without --slurm is refused by the parser.
    let r = bench(&[s, "--out", o, "--submit"]);
    assert!(!r.status.success() && text(&r).contains("--slurm"), "{}", text(&r));
}

/// The Slurm programs the test needs, found on PATH or in the sbin folders.
fn find(prog: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/usr/local/sbin", "/sbin"].map(PathBuf::from))
        .map(|d| d.join(prog))
        .find(|p| p.is_file())
}

/// A free TCP port on this machine (bound, then released).
fn free_port() -> std::net::TcpListener {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap()
}

/// A one-node Slurm of our own: munged, slurmctld and slurmd as child processes.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    daemons: Vec<(&'static str, Child)>,
    /// A job to cancel if the test ends early.
    job: Option<String>,
}

impl Cluster {
    fn start(progs: &[PathBuf; 4]) -> Cluster {
        let [munged, slurmctld, slurmd, _] = progs;
        // Short paths: the munge socket path must fit in 108 bytes.
        let dir = tempfile::Builder::new().prefix("edgenerf-slurm").tempdir_in("/tmp").unwrap();
        let d = dir.path();
        for sub in ["state", "spool"] {
            std::fs::create_dir(d.join(sub)).unwrap();
        }
        // A munge key of our own (munged wants it readable by its owner only).
        let key = d.join("munge.key");
        let mut bytes = vec![0u8; 1024];
        use std::io::Read;
        std::fs::File::open("/dev/urandom").unwrap().read_exact(&mut bytes).unwrap();
        std::fs::write(&key, bytes).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o400)).unwrap();
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap().trim().split('.').next().unwrap().to_string();
        let user = String::from_utf8(Command::new("id").arg("-un").output().unwrap().stdout).unwrap().trim().to_string();
        let (p1, p2) = (free_port(), free_port());
        let (ctld_port, d_port) = (p1.local_addr().unwrap().port(), p2.local_addr().unwrap().port());
        drop((p1, p2));
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let ds = d.display();
        let conf = d.join("slurm.conf");
        std::fs::write(
            &conf,
            format!(
                "ClusterName=edgenerftest\nSlurmctldHost={host}(127.0.0.1)\nSlurmctldPort={ctld_port}\nSlurmdPort={d_port}\n\
                 SlurmUser={user}\nSlurmdUser={user}\nAuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={ds}/munge.sock\n\
                 StateSaveLocation={ds}/state\nSlurmdSpoolDir={ds}/spool\nSlurmctldPidFile={ds}/slurmctld.pid\n\
                 SlurmdPidFile={ds}/slurmd.pid\nSlurmctldLogFile={ds}/slurmctld.log\nSlurmdLogFile={ds}/slurmd.log\n\
                 ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nSelectType=select/cons_tres\n\
                 SelectTypeParameters=CR_Core\nSchedulerType=sched/builtin\nJobAcctGatherType=jobacct_gather/none\n\
                 AccountingStorageType=accounting_storage/none\nJobCompType=jobcomp/none\nMpiDefault=none\nMailProg=/bin/true\n\
                 ReturnToService=2\nSlurmdParameters=config_overrides\nSchedulerParameters=sched_interval=1\n\
                 NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN\n\
                 PartitionName=test Nodes={host} Default=YES MaxTime=INFINITE State=UP\n"
            ),
        )
        .unwrap();
        let mut cluster = Cluster { conf, daemons: Vec::new(), job: None, dir };
        let d = cluster.dir.path().to_path_buf();
        let spawn = |name: &'static str, prog: &Path, args: &[String]| -> (&'static str, Child) {
            let log = std::fs::File::create(d.join(format!("{name}.out"))).unwrap();
            let child = Command::new(prog)
                .args(args)
                .env("SLURM_CONF", d.join("slurm.conf"))
                .stdin(Stdio::null())
                .stdout(log.try_clone().unwrap())
                .stderr(log)
                .spawn()
                .unwrap_or_else(|e| panic!("starting {}: {e}", prog.display()));
            (name, child)
        };
        let p = |s: &str| d.join(s).display().to_string();
        cluster.daemons.push(spawn(
            "munged",
            munged,
            &[
                "-F".into(),
                "--force".into(),
                format!("--key-file={}", p("munge.key")),
                format!("--socket={}", p("munge.sock")),
                format!("--pid-file={}", p("munged.pid")),
                format!("--seed-file={}", p("munged.seed")),
                format!("--log-file={}", p("munged.log")),
            ],
        ));
        cluster.wait_for("the munge socket", Duration::from_secs(20), || d.join("munge.sock").exists().then_some(()));
        let conf = cluster.conf.display().to_string();
        cluster.daemons.push(spawn("slurmctld", slurmctld, &["-D".into(), "-f".into(), conf.clone()]));
        cluster.daemons.push(spawn("slurmd", slurmd, &["-D".into(), "-f".into(), conf, "-N".into(), host]));
        cluster.wait_for("the node to be idle", Duration::from_secs(60), || {
            let o = cluster.slurm("sinfo").args(["-h", "-o", "%t"]).output().ok()?;
            (String::from_utf8_lossy(&o.stdout).trim() == "idle").then_some(())
        });
        cluster
    }

    /// A Slurm client command aimed at this cluster.
    fn slurm(&self, prog: &str) -> Command {
        let mut c = Command::new(prog);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// Polls `f` every 0.5 s until it gives a value; panics with the daemons' logs after `limit`.
    fn wait_for<T>(&self, what: &str, limit: Duration, mut f: impl FnMut() -> Option<T>) -> T {
        let t = Instant::now();
        loop {
            if let Some(v) = f() {
                return v;
            }
            assert!(t.elapsed() < limit, "waited {limit:?} for {what}; logs:\n{}", self.logs());
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    /// The last lines of every daemon's log, for failure messages.
    fn logs(&self) -> String {
        let mut s = String::new();
        for f in ["munged.out", "slurmctld.out", "slurmctld.log", "slurmd.out", "slurmd.log"] {
            let text = std::fs::read_to_string(self.dir.path().join(f)).unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            s += &format!("--- {f}\n{}\n", lines[lines.len().saturating_sub(15)..].join("\n"));
        }
        s
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        if let Some(job) = &self.job {
            // Cancel what is left of the job (its processes outlive slurmd), briefly wait.
            let _ = self.slurm("scancel").arg(job).status();
            for _ in 0..20 {
                match self.slurm("squeue").args(["-h", "-j", job]).output() {
                    Ok(o) if o.status.success() && !o.stdout.is_empty() => std::thread::sleep(Duration::from_millis(500)),
                    _ => break,
                }
            }
        }
        for (_, child) in self.daemons.iter_mut().rev() {
            // SIGTERM first (slurmctld then stops its slurmscriptd helper), SIGKILL after 5 s.
            let _ = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
            let t = Instant::now();
            while t.elapsed() < Duration::from_secs(5) && matches!(child.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(100));
            }
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

#[test]
fn bench_runs_a_suite_as_a_slurm_job_array() {
    let names = ["munged", "slurmctld", "slurmd", "sbatch"];
    let found: Vec<Option<PathBuf>> = names.iter().map(|n| find(n)).collect();
    if found.iter().any(Option::is_none) {
        let missing: Vec<&str> = names.iter().zip(&found).filter(|(_, f)| f.is_none()).map(|(n, _)| *n).collect();
        let msg = format!("Slurm is not installed ({} missing): 'apt-get install slurm-wlm munge' as root enables this test", missing.join(", "));
        assert!(std::env::var("EDGENERF_REQUIRE_SLURM").as_deref() != Ok("1"), "EDGENERF_REQUIRE_SLURM=1: {msg}");
        eprintln!("skipped: {msg}");
        return;
    }
    let progs: [PathBuf; 4] = found.into_iter().map(Option::unwrap).collect::<Vec<_>>().try_into().unwrap();
    let started = Instant::now();
    let mut cluster = Cluster::start(&progs);
    eprintln!("Slurm up in {:.1} s", started.elapsed().as_secs_f64());

    // The committed `turntable` with one test view (evaluation is most of a short run).
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("turntable");
    let src = common::repo().join("synthetic-scenes/small/turntable");
    let r = Command::new("cp").arg("-r").arg(&src).arg(&scene).status().unwrap();
    assert!(r.success());
    let mut test: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(scene.join("transforms_test.json")).unwrap()).unwrap();
    test["frames"].as_array_mut().unwrap().truncate(1);
    std::fs::write(scene.join("transforms_test.json"), test.to_string()).unwrap();
    let suite = tiny_suite(dir.path(), scene.to_str().unwrap(), false);
    let out = dir.path().join("out");
    let (s, o) = (suite.to_str().unwrap(), out.to_str().unwrap());
    let r = command()
        .args(["bench", s, "--out", o, "--lpips", "none", "--slurm", "--submit", "--time", "10:00"])
        .env("SLURM_CONF", &cluster.conf)
        .current_dir(common::repo())
        .output()
        .unwrap();
    let t = text(&r);
    assert!(r.status.success(), "{t}\n{}", cluster.logs());
    let job = String::from_utf8_lossy(&r.stdout).trim().to_string();
    assert!(!job.is_empty() && job.chars().all(|c| c.is_ascii_digit()), "stdout is the job id: {t}");
    cluster.job = Some(job.clone());
    assert!(t.contains(&format!("submitted job array {job}")), "{t}");

    // Wait for the array: squeue lists none of its tasks any more.
    cluster.wait_for("the job array to end", Duration::from_secs(240), || {
        let o = cluster.slurm("squeue").args(["-h", "-j", &job, "-o", "%i %T"]).output().ok()?;
        let gone = String::from_utf8_lossy(&o.stderr).contains("Invalid job id");
        ((o.status.success() && o.stdout.is_empty()) || gone).then_some(())
    });
    eprintln!("array done after {:.1} s", started.elapsed().as_secs_f64());
    for i in 0..2 {
        let log = std::fs::read_to_string(out.join(format!("slurm/logs/task-{i}.log"))).unwrap_or_default();
        assert!(log.contains("finished in"), "task {i} log:\n{log}\n{}", cluster.logs());
    }

    let r = command().args(["bench", s, "--out", o, "--report-only"]).current_dir(common::repo()).output().unwrap();
    assert!(r.status.success(), "{}", text(&r));
    let rows = read_rows(&out);
    assert_eq!(rows.len(), 2, "{rows:?}");
    for (r, config) in rows.iter().zip(["none", "edge-gt"]) {
        assert_eq!(r["config"], config);
        assert_eq!(r["record"]["status"], "ok", "{r}");
        assert_eq!(r["steps"], 3, "{r}");
        let m = &r["metrics"];
        let psnr = m["psnr"].as_f64().unwrap();
        assert!(psnr.is_finite() && (5.0..40.0).contains(&psnr), "{r}");
        let ssim = m["ssim"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&ssim), "{r}");
        let normal = m["normal.all.mean_deg"].as_f64().unwrap();
        assert!((0.0..=180.0).contains(&normal), "{r}");
        assert!(m["depth.all.abs"].as_f64().unwrap().is_finite(), "{r}");
        assert!(r["log"].as_str().unwrap().ends_with(&format!("slurm/logs/task-{}.log", if config == "none" { 0 } else { 1 })), "{r}");
    }
    // The same runs trained by the local bench give the same figures.
    let local = dir.path().join("local");
    let r = command().args(["bench", s, "--out", local.to_str().unwrap(), "--lpips", "none"]).current_dir(common::repo()).output().unwrap();
    assert!(r.status.success(), "{}", text(&r));
    let local_rows = read_rows(&local);
    for (a, b) in rows.iter().zip(&local_rows) {
        let (ma, mb) = (a["metrics"].as_object().unwrap(), b["metrics"].as_object().unwrap());
        assert_eq!(ma.len(), mb.len(), "{a}\n{b}");
        for (k, x) in ma {
            let (x, y) = (x.as_f64().unwrap(), mb[k].as_f64().unwrap());
            assert!((x - y).abs() <= 1e-4 * x.abs().max(1.0), "{}: {k} {x} under Slurm, {y} locally", a["id"]);
        }
    }
    eprintln!("local bench done after {:.1} s", started.elapsed().as_secs_f64());

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("2 runs: 2 finished, 0 failed") && report.contains("| turntable | `edge-gt` |"), "{report}");

    // Everything finished: a second --slurm has nothing to submit.
    let r = command().args(["bench", s, "--out", o, "--slurm", "--submit"]).env("SLURM_CONF", &cluster.conf).current_dir(common::repo()).output().unwrap();
    assert!(r.status.success() && text(&r).contains("all 2 runs have finished: nothing to submit"), "{}", text(&r));
    eprintln!("done after {:.1} s", started.elapsed().as_secs_f64());
}
