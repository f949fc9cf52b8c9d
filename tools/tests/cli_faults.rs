//! Faults and concurrency (issue 52): signals, two writers, crashes mid-run, corrupt
//! checkpoints, outputs aimed at inputs. Each test makes tiny runs (the demo config on a
//! committed 128x128 scene, a few steps).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use common::{edgenerf, repo, text};

fn turntable() -> PathBuf {
    repo().join("synthetic-scenes/small/turntable")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The rows of a run's `log.csv` (0 when it does not exist yet).
fn rows(run: &Path) -> usize {
    std::fs::read_to_string(run.join("log.csv")).map_or(0, |l| l.lines().count().saturating_sub(1))
}

/// The step column of a run's `log.csv`.
fn logged_steps(run: &Path) -> Vec<u64> {
    common::read_log(run).1.iter().map(|r| r[0] as u64).collect()
}

/// A child process killed when dropped (a failed assertion must not leave a
/// 100000-step run behind).
struct Run(Option<Child>);

impl Run {
    fn child(&mut self) -> &mut Child {
        self.0.as_mut().unwrap()
    }

    fn wait_with_output(mut self) -> std::process::Output {
        self.0.take().unwrap().wait_with_output().unwrap()
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Some(c) = &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// A `train` of the demo config on `scene` into `run` that runs until stopped
/// (100000 steps, no periodic checkpoint unless `extra` sets one), output piped.
fn spawn_long_run(scene: &Path, run: &Path, extra: &[&str]) -> Run {
    let demo = repo().join("tools/configs/demo.toml");
    Run(Some(
        common::command()
            .args(["train", s(scene), "--out", s(run), "--config", s(&demo)])
            .args(["--iters", "100000", "--set", "sampler.steps_per_diagonal=48", "--no-eval"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    ))
}

/// A short finished run of the demo config (`iters` steps, no evaluation).
fn short_run(scene: &Path, run: &Path, iters: u32, extra: &[&str]) {
    let demo = repo().join("tools/configs/demo.toml");
    let iters = iters.to_string();
    let mut args = vec!["train", s(scene), "--out", s(run), "--config", s(&demo), "--iters", &iters];
    args.extend_from_slice(&["--set", "sampler.steps_per_diagonal=48", "--no-eval"]);
    args.extend_from_slice(extra);
    let o = edgenerf(&args);
    assert!(o.status.success(), "{}", text(&o));
}

/// Waits until `run` has logged `n` steps (10 minutes at most: a first run compiles kernels).
fn wait_rows(run: &Path, n: usize, child: &mut Run) {
    let child = child.child();
    let start = Instant::now();
    while rows(run) < n {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("training ended ({status}) before logging {n} steps");
        }
        assert!(start.elapsed().as_secs() < 600, "training never logged {n} steps");
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn signal(child: &mut Run, sig: &str) {
    let pid = child.child().id().to_string();
    assert!(std::process::Command::new("kill").args([sig, &pid]).status().unwrap().success());
}

/// SIGTERM (what `timeout` and cluster schedulers send) and SIGHUP (a closed terminal)
/// save a checkpoint as Ctrl-C does, and `--resume` continues from it. Before, SIGTERM
/// ended the process at once (exit 143) with no checkpoint.
#[cfg(unix)]
#[test]
fn sigterm_and_sighup_save_a_checkpoint_that_resume_continues() {
    let out = tempfile::tempdir().unwrap();
    for sig in ["-TERM", "-HUP"] {
        let run = out.path().join(format!("run{sig}"));
        let mut child = spawn_long_run(&turntable(), &run, &["--set", "train.checkpoint_every=0"]);
        wait_rows(&run, 2, &mut child);
        signal(&mut child, sig);
        let o = child.wait_with_output();
        let t = text(&o);
        assert!(o.status.code() == Some(1) && t.contains("interrupted at step") && t.contains("--resume"), "{sig}: {:?}\n{t}", o.status);
        let steps = rows(&run);
        assert!(steps >= 2 && run.join("checkpoint.safetensors").is_file(), "{sig}: {steps} steps logged\n{t}");
        if sig == "-TERM" {
            let iters = (steps + 1).to_string();
            let o = edgenerf(&["train", s(&turntable()), "--out", s(&run), "--resume", "--iters", &iters, "--no-eval"]);
            assert!(o.status.success(), "{}", text(&o));
            assert_eq!(logged_steps(&run), (0..steps as u64 + 1).collect::<Vec<_>>(), "the resumed run starts at the stopped step");
        }
    }
}

/// Waits until one of `children` exits (`secs` at most) and returns its index.
fn first_to_exit(children: &mut [Run], secs: u64) -> usize {
    let start = Instant::now();
    loop {
        for (i, c) in children.iter_mut().enumerate() {
            if c.child().try_wait().unwrap().is_some() {
                return i;
            }
        }
        if start.elapsed().as_secs() > secs {
            panic!("neither of two runs into one directory was refused within {secs} s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Two `train` runs started together into one `--out`: one is refused at once with
/// what holds the directory (before, both ran: log.csv held every step twice, the
/// config one run's and the checkpoint the other's). The winner killed with SIGKILL,
/// checkpointing every step (a kill during a checkpoint write, likely), leaves no
/// stale lock: `--resume` continues it, its log each step once.
#[cfg(unix)]
#[test]
fn two_runs_into_one_directory_one_is_refused_and_a_killed_run_leaves_no_lock() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scenes = [turntable(), repo().join("synthetic-scenes/small/creases")];
    let every = ["--set", "train.checkpoint_every=1"];
    let mut children = vec![spawn_long_run(&scenes[0], &run, &every), spawn_long_run(&scenes[1], &run, &every)];
    let loser = first_to_exit(&mut children, 120);
    let winner = 1 - loser;
    let mut survivor = children.remove(winner);
    let o = children.remove(0).wait_with_output();
    let t = text(&o);
    assert!(o.status.code() == Some(1) && t.contains("is in use") && t.contains("is training into it"), "{t}");

    wait_rows(&run, 4, &mut survivor);
    signal(&mut survivor, "-KILL");
    let _ = survivor.wait_with_output();
    // The kill released the lock (the kernel drops a flock with its process).
    let iters = (rows(&run) + 2).to_string();
    let o = edgenerf(&["train", s(&scenes[winner]), "--out", s(&run), "--resume", "--iters", &iters, "--no-eval"]);
    assert!(o.status.success(), "{}", text(&o));
    let n: u64 = iters.parse().unwrap();
    assert_eq!(logged_steps(&run), (0..n).collect::<Vec<_>>(), "every step once, in order");
}

/// A resumed run drops the rows its checkpoint does not hold (logged after it, before
/// a crash or a second Ctrl-C) instead of logging those steps twice.
#[test]
fn a_resumed_log_continues_from_the_checkpoint_step() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    short_run(&turntable(), &run, 2, &[]);
    let ckpt = run.join("checkpoint.safetensors");
    let at_2 = std::fs::read(&ckpt).unwrap();
    let resume = |iters: &str| {
        let o = edgenerf(&["train", s(&turntable()), "--out", s(&run), "--resume", "--iters", iters, "--no-eval"]);
        assert!(o.status.success(), "{}", text(&o));
    };
    resume("4");
    assert_eq!(logged_steps(&run), [0, 1, 2, 3]);
    // The run "crashed" after logging steps 2 and 3 but before their checkpoint.
    std::fs::write(&ckpt, &at_2).unwrap();
    resume("3");
    assert_eq!(logged_steps(&run), [0, 1, 2], "rows after the checkpoint's step were kept");
}

/// The header of a safetensors file as JSON, and where its data starts.
fn header(bytes: &[u8]) -> (serde_json::Value, usize) {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    (serde_json::from_slice(&bytes[8..8 + n]).unwrap(), 8 + n)
}

/// `bytes` with its header replaced by `h` (padded to 8 bytes as safetensors writes it).
fn with_header(bytes: &[u8], h: &serde_json::Value) -> Vec<u8> {
    let (_, data) = header(bytes);
    let mut text = h.to_string().into_bytes();
    while text.len() % 8 != 0 {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&text);
    out.extend_from_slice(&bytes[data..]);
    out
}

/// Checkpoints prove their integrity: a flipped weight, an edited config, a tensor
/// reshaped to the same element count (kept consistent with the record, as a tool
/// rewriting the file would), or a non-finite weight are refused, naming the file;
/// a finite weight large enough to overflow the gradient's norm stops a resumed run
/// with the divergence message. Before, `render` exited 0 on each of them and
/// `--resume` trained on with grad_norm = inf.
#[test]
fn damaged_or_edited_checkpoints_are_refused() {
    use edgenerf::train::Checkpoint;
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    short_run(&turntable(), &run, 2, &[]);
    let good = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let render = |ckpt: &Path| {
        let o = edgenerf(&["render", s(ckpt), "--out", s(&out.path().join("renders"))]);
        (o.status.success(), text(&o))
    };

    // One byte of the hash table flipped.
    let flipped = out.path().join("flipped.safetensors");
    let (h, data) = header(&good);
    let table = h.as_object().unwrap().iter().find(|(k, _)| k.starts_with("field.")).unwrap().1;
    let start = data + table["data_offsets"][0].as_u64().unwrap() as usize;
    let mut bytes = good.clone();
    bytes[start + 2] ^= 0x40;
    std::fs::write(&flipped, &bytes).unwrap();
    let (ok, t) = render(&flipped);
    assert!(!ok && t.contains("flipped.safetensors") && t.contains("damaged") && t.contains("checksum"), "{t}");

    // The embedded config edited (another seed).
    let edited = out.path().join("edited.safetensors");
    let mut h2 = h.clone();
    let config = h2["__metadata__"]["config"].as_str().unwrap().to_string();
    let mut c: serde_json::Value = serde_json::from_str(&config).unwrap();
    c["train"]["seed"] = serde_json::json!(12345);
    h2["__metadata__"]["config"] = serde_json::Value::String(c.to_string());
    std::fs::write(&edited, with_header(&good, &h2)).unwrap();
    let (ok, t) = render(&edited);
    assert!(!ok && t.contains("edited.safetensors") && t.contains("config"), "{t}");

    // A 2-D parameter saved with its shape transposed, checksums recomputed.
    let reshaped = out.path().join("reshaped.safetensors");
    let mut ck = Checkpoint::load(&run.join("checkpoint.safetensors")).unwrap();
    let a = ck.field.iter_mut().find(|a| a.shape.len() == 2 && a.shape[0] != a.shape[1]).expect("a non-square matrix");
    a.shape.reverse();
    ck.save(&reshaped).unwrap();
    let (ok, t) = render(&reshaped);
    assert!(!ok && t.contains("shape"), "{t}");

    // A NaN weight.
    let nan = out.path().join("nan.safetensors");
    let mut ck = Checkpoint::load(&run.join("checkpoint.safetensors")).unwrap();
    ck.field[0].data[3] = f32::NAN;
    ck.save(&nan).unwrap();
    let (ok, t) = render(&nan);
    assert!(!ok && t.contains("nan.safetensors") && t.contains("non-finite"), "{t}");

    // A huge finite weight in the run's own checkpoint: --resume stops as diverged and
    // keeps that checkpoint.
    let mut ck = Checkpoint::load(&run.join("checkpoint.safetensors")).unwrap();
    for a in &mut ck.field {
        a.data[0] = -7.96e37;
    }
    ck.save(&run.join("checkpoint.safetensors")).unwrap();
    let kept = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let o = edgenerf(&["train", s(&turntable()), "--out", s(&run), "--resume", "--iters", "6", "--no-eval"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("training diverged") && t.contains("last good checkpoint"), "{t}");
    assert_eq!(std::fs::read(run.join("checkpoint.safetensors")).unwrap(), kept, "no new checkpoint after divergence");
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    let mut files = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    files
}

/// A copy of a committed scene under `dir`.
fn copy_scene(from: &Path, to: &Path) {
    for (p, bytes) in snapshot(from) {
        let dest = to.join(p.strip_prefix(from).unwrap());
        std::fs::create_dir_all(dest.parent().unwrap()).unwrap();
        std::fs::write(dest, bytes).unwrap();
    }
}

/// No command writes into a scene's folder, `--overwrite` or not, nor render or eval
/// into the run directory, nor `export` over an existing file without `--overwrite`;
/// the scene is byte for byte intact after each attempt. Before: `train --overwrite`
/// deleted the scene's test views, `edges`, `render` and `eval` overwrote its images
/// and ground truth, `export` replaced the file.
#[test]
fn no_command_writes_into_its_inputs() {
    let out = tempfile::tempdir().unwrap();
    let scene = out.path().join("scene");
    copy_scene(&turntable(), &scene);
    let before = snapshot(&scene);
    let refused = |args: &[&str], words: &[&str]| {
        let o = edgenerf(args);
        let t = text(&o);
        assert!(!o.status.success() && words.iter().all(|w| t.contains(w)), "{args:?}:\n{t}");
        assert!(snapshot(&scene) == before, "{args:?} changed the scene:\n{t}");
    };
    let sc = s(&scene);
    let train_dir = scene.join("train");
    let test_dir = scene.join("test");
    refused(&["train", sc, "--out", sc, "--overwrite", "--iters", "1", "--no-eval"], &["is the scene directory"]);
    refused(&["train", sc, "--out", s(&test_dir), "--overwrite", "--iters", "1", "--no-eval"], &["lies inside the scene directory"]);
    // A scene where a run writes: `--out PARENT` of a scene at PARENT/test.
    let parent = out.path().join("parent");
    copy_scene(&turntable(), &parent.join("test"));
    let o = edgenerf(&["train", s(&parent.join("test")), "--out", s(&parent), "--overwrite", "--iters", "1", "--no-eval"]);
    assert!(!o.status.success() && text(&o).contains("which a run writes"), "{}", text(&o));
    assert!(parent.join("test/transforms_train.json").is_file());
    refused(&["edges", sc, "--views", "3", "--out", s(&train_dir)], &["lies inside the scene directory"]);

    let run = out.path().join("run");
    short_run(&scene, &run, 1, &[]);
    let r = s(&run);
    refused(&["render", r, "--scene", sc, "--split", "train", "--out", s(&train_dir)], &["lies inside the scene directory"]);
    refused(&["eval", r, "--scene", sc, "--lpips", "none", "--out", s(&test_dir)], &["lies inside the scene directory"]);
    refused(&["export", "mesh", r, "--resolution", "8", "--out", s(&scene.join("gt_mesh.ply")), "--overwrite"], &["lies inside"]);
    let run_files = snapshot(&run);
    for cmd in ["render", "eval"] {
        let o = edgenerf(&[cmd, r, "--out", r]);
        assert!(!o.status.success() && text(&o).contains("is the run directory"), "{cmd}: {}", text(&o));
    }
    assert!(snapshot(&run) == run_files, "the run changed");

    let existing = out.path().join("existing.txt");
    std::fs::write(&existing, "keep me").unwrap();
    let o = edgenerf(&["export", "mesh", r, "--resolution", "8", "--out", s(&existing)]);
    assert!(!o.status.success() && text(&o).contains("already exists") && text(&o).contains("--overwrite"), "{}", text(&o));
    assert_eq!(std::fs::read_to_string(&existing).unwrap(), "keep me");
    // An untrained field's density is about 1 everywhere: a level inside its range.
    let o = edgenerf(&["export", "mesh", r, "--resolution", "8", "--level", "1.0", "--out", s(&existing), "--overwrite"]);
    assert!(o.status.success(), "{}", text(&o));
    assert_ne!(std::fs::read(&existing).unwrap(), b"keep me");
}

/// `render` and `eval` with a `--scene` other than the run's are refused unless
/// `--allow-other-scene` (they rendered and scored the other scene's views without a
/// word); a run whose cameras all look away from the scene's box stops within a few
/// steps saying so (it trained on 0 samples per ray and exited 0).
#[test]
fn another_scene_is_refused_and_rays_that_miss_the_box_stop_the_run() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    short_run(&turntable(), &run, 1, &[]);
    let other = repo().join("synthetic-scenes/small/creases");
    for cmd in ["render", "eval"] {
        let o = edgenerf(&[cmd, s(&run), "--scene", s(&other), "--out", s(&out.path().join(cmd))]);
        let t = text(&o);
        assert!(!o.status.success() && t.contains("not the scene") && t.contains("--allow-other-scene"), "{cmd}: {t}");
        assert!(!out.path().join(cmd).exists(), "{cmd} created its --out");
    }

    // Every training camera turned to look away from the scene (x and z axes negated).
    let away = out.path().join("away");
    copy_scene(&turntable(), &away);
    let path = away.join("transforms_train.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        for row in f["transform_matrix"].as_array_mut().unwrap().iter_mut().take(3) {
            for col in [0, 2] {
                row[col] = serde_json::json!(-row[col].as_f64().unwrap());
            }
        }
    }
    std::fs::write(&path, t.to_string()).unwrap();
    let demo = repo().join("tools/configs/demo.toml");
    let o = edgenerf(&["train", s(&away), "--out", s(&out.path().join("run-away")), "--config", s(&demo), "--iters", "50", "--no-eval"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("no ray entered the scene's box"), "{t}");
    assert!(rows(&out.path().join("run-away")) < 10, "stopped within a few steps:\n{t}");
}

/// A bench suite with `repeats = 0` is refused (it ran each run once), and a sweep
/// whose only run failed exits non-zero (it exited 0).
#[test]
fn bench_refuses_zero_repeats_and_fails_when_no_run_finished() {
    let dir = tempfile::tempdir().unwrap();
    let suite = |name: &str, extra: &str| {
        let path = dir.path().join(format!("{name}.toml"));
        let text = format!(
            "scenes = [\"synthetic-scenes/small/turntable\"]\nbase_config = \"tools/configs/demo.toml\"\niters = 1\n{extra}\n\
             [[config]]\nname = \"broken\"\nset = {{ \"train.no_such_key\" = 1 }}\n"
        );
        std::fs::write(&path, text).unwrap();
        path
    };
    let zero = suite("zero", "repeats = 0");
    let o = edgenerf(&["bench", s(&zero), "--out", s(&dir.path().join("out0")), "--lpips", "none"]);
    assert!(!o.status.success() && text(&o).contains("repeats = 0"), "{}", text(&o));
    let failing = suite("failing", "");
    let o = edgenerf(&["bench", s(&failing), "--out", s(&dir.path().join("out1")), "--lpips", "none"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("no run of the suite finished"), "{t}");
    assert!(dir.path().join("out1/report.md").is_file(), "the report is still written:\n{t}");
}

/// Training views that cannot teach anything are refused before training (they trained
/// and exited 0): every camera at one pose, every image fully transparent.
#[test]
fn identical_poses_and_transparent_images_are_refused() {
    let out = tempfile::tempdir().unwrap();
    let demo = repo().join("tools/configs/demo.toml");
    let train = |scene: &Path| {
        let o = edgenerf(&["train", s(scene), "--out", s(&scene.with_extension("run")), "--config", s(&demo), "--iters", "3", "--no-eval"]);
        (o.status.success(), text(&o))
    };
    let same = out.path().join("same");
    copy_scene(&turntable(), &same);
    let path = same.join("transforms_train.json");
    let mut t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let first = t["frames"][0]["transform_matrix"].clone();
    for f in t["frames"].as_array_mut().unwrap() {
        f["transform_matrix"] = first.clone();
    }
    std::fs::write(&path, t.to_string()).unwrap();
    let (ok, t) = train(&same);
    assert!(!ok && t.contains("the same camera pose"), "{t}");

    let clear = out.path().join("clear");
    copy_scene(&turntable(), &clear);
    for e in std::fs::read_dir(clear.join("train")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_str().unwrap().to_string();
        if name.ends_with(".png") && !name.ends_with("_mask.png") {
            let mut img = image::open(&p).unwrap().to_rgba8();
            img.pixels_mut().for_each(|px| px.0[3] = 0);
            img.save(&p).unwrap();
        }
    }
    let (ok, t) = train(&clear);
    assert!(!ok && t.contains("fully transparent"), "{t}");
}

/// A write that fails (here: a file-size limit, as a full disk fails it) is said to be
/// a failed write of the output, not a bad input ("bad OpenEXR file ...: No space left
/// on device"), leaves no `.partial` file, and a `--out` that `render` created and
/// could not write into is removed again (a failed render left an empty --out).
#[cfg(unix)]
#[test]
fn a_failed_write_names_the_output_and_leaves_nothing_behind() {
    use std::os::unix::process::CommandExt;
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    short_run(&turntable(), &run, 1, &[]);
    // `limit` bytes per file; SIGXFSZ ignored, so a write past it fails with EFBIG.
    let render = |dest: &Path, split: &str, limit: u64| {
        let mut c = common::command();
        c.args(["render", s(&run), "--split", split, "--out", s(dest)]);
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            c.pre_exec(move || {
                libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
                let lim = libc::rlimit { rlim_cur: limit, rlim_max: libc::RLIM_INFINITY };
                if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let o = c.output().unwrap();
        (o.status.success(), text(&o))
    };
    // Nothing fits: the first image fails, the new --out is gone again.
    let empty = out.path().join("r-empty");
    let (ok, t) = render(&empty, "train", 100);
    assert!(!ok && t.contains("writing this output failed") && t.contains("free space"), "{t}");
    assert!(!empty.exists(), "an empty --out was left:\n{t}");
    // The images fit, the depth EXR (64 KB) does not.
    let part = out.path().join("r-part");
    let (ok, t) = render(&part, "train", 40_000);
    assert!(!ok && t.contains("_depth.exr") && t.contains("writing this output failed") && !t.contains("bad OpenEXR"), "{t}");
    let partial: Vec<_> = snapshot(&part).into_keys().filter(|p| p.to_string_lossy().ends_with(".partial")).collect();
    assert!(partial.is_empty(), "{partial:?}");
}
