//! The `edgenerf` binary as a user runs it: `info` on real and synthetic scenes, a
//! short `train` that writes its run directory, `render` of the checkpoint, and clear
//! errors for bad input.

use std::path::PathBuf;
mod common;

use common::{edgenerf, repo, text};




/// The real data directory, or `None` (with a message) when absent and not required.
fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("EDGENERF_DATA").map(PathBuf::from).unwrap_or_else(|| repo().join("../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(std::env::var("EDGENERF_REQUIRE_DATA").as_deref() != Ok("1"), "real data required but {} is absent", dir.display());
    eprintln!("skipping: real data not found at {} (set EDGENERF_DATA)", dir.display());
    None
}

#[test]
fn info_prints_the_llff_split_and_the_adapter() {
    let Some(data) = data_dir() else { return };
    let o = edgenerf(&["info", data.join("llff/fern").to_str().unwrap(), "--views", "3"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("llff"), "{t}");
    assert!(t.contains("20 of 504x378"), "{t}");
    assert!(t.contains("train ids   [1, 10, 19]"), "{t}");
    assert!(t.contains("test ids    [0, 8, 16]"), "{t}");
    assert!(t.contains("adapter"), "{t}");
}

#[test]
fn info_prints_dtu_masks_and_split() {
    let Some(data) = data_dir() else { return };
    let o = edgenerf(&["info", data.join("dtu/scan24").to_str().unwrap(), "--views", "3", "--no-gpu"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("49 of 400x300"), "{t}");
    assert!(t.contains("train ids   [25, 22, 28]"), "{t}");
    assert!(t.contains("masks: yes"), "{t}");
}

#[test]
fn bad_input_gives_a_clear_error_and_a_failure_status() {
    let o = edgenerf(&["info", "/definitely/not/here", "--no-gpu"]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("/definitely/not/here") && t.contains("not found"), "{t}");
    assert!(!t.contains("stack backtrace"), "users see the message, not a backtrace: {t}");

    let o = edgenerf(&["--adapter", "no-such-gpu", "info", repo().join("synthetic-scenes/small/creases").to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("adapters present"), "{}", text(&o));

    let out = tempfile::tempdir().unwrap();
    let o = edgenerf(&[
        "train",
        repo().join("synthetic-scenes/small/creases").to_str().unwrap(),
        "--out",
        out.path().to_str().unwrap(),
        "--set",
        "train.itres=5",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("unknown key"), "{}", text(&o));
}

#[test]
fn train_writes_its_run_directory_and_render_reads_it_back() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scene = repo().join("synthetic-scenes/small/turntable");
    let o = edgenerf(&[
        "train",
        scene.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--config",
        repo().join("tools/configs/demo.toml").to_str().unwrap(),
        "--iters",
        "4",
        "--set",
        "train.checkpoint_every=2",
        // An untrained grid is occupied everywhere: march coarsely to keep renders short.
        "--set",
        "sampler.steps_per_diagonal=48",
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("test PSNR"), "{t}");
    for f in ["config.json", "log.csv", "checkpoint.safetensors", "test/metrics.json", "test/r_000_rgb.png", "test/r_000_depth.exr", "test/r_000_depth.png", "test/r_000_normal.exr", "test/r_000_normal.png", "test/r_000_opacity.png"] {
        assert!(run.join(f).is_file(), "{f} missing; output:\n{t}");
    }
    let log = std::fs::read_to_string(run.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 1 + 4, "header and one row per step:\n{log}");
    let config: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["train"]["iters"], 4);
    assert_eq!(config["field"]["n_levels"], 8, "the config file's values are in the effective config");
    // Values that default by scene are recorded as used, not null (issue 16): a Blender
    // scene's images are read as they are (factor 1; 8 is LLFF's default).
    assert_eq!(config["scene"]["llff_factor"], 1);
    assert!(config["regnerf"]["poses"].is_string() && config["regnerf"]["anneal_steps"].is_u64(), "{}", config["regnerf"]);

    // Resume extends the run from its checkpoint.
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--resume", "--iters", "6", "--no-eval"]);
    assert!(o.status.success(), "{}", text(&o));
    let log = std::fs::read_to_string(run.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 1 + 6, "{log}");

    // A second `train` into the finished run is refused and changes nothing ...
    let before = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--iters", "1", "--no-eval"]);
    assert!(!o.status.success() && text(&o).contains("--overwrite"), "{}", text(&o));
    assert_eq!(std::fs::read(run.join("checkpoint.safetensors")).unwrap(), before);
    assert_eq!(std::fs::read_to_string(run.join("log.csv")).unwrap().lines().count(), 1 + 6);

    // ... and `render` from another directory finds the scene (the config records it absolutely).
    let renders = out.path().join("renders");
    let elsewhere = tempfile::tempdir().unwrap();
    let o = common::command()
        .current_dir(elsewhere.path())
        .args(["render", run.to_str().unwrap(), "--split", "test", "--out", renders.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("test PSNR"), "{}", text(&o));
    let n = std::fs::read_dir(&renders).unwrap().filter(|e| e.as_ref().unwrap().path().to_string_lossy().ends_with("_rgb.png")).count();
    assert_eq!(n, 8, "one render per test view");

    // --overwrite replaces the run: a fresh log, no old test renders.
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--overwrite", "--iters", "1", "--no-eval"]
        .into_iter()
        .chain(["--config", repo().join("tools/configs/demo.toml").to_str().unwrap(), "--set", "sampler.steps_per_diagonal=48"])
        .collect::<Vec<_>>());
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(std::fs::read_to_string(run.join("log.csv")).unwrap().lines().count(), 1 + 1);
    assert!(!run.join("test").exists(), "the old run's test renders are gone");
}

#[test]
fn train_refuses_to_overwrite_or_mix_runs_and_checks_outputs_first() {
    let out = tempfile::tempdir().unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let scene = scene.to_str().unwrap();
    // A run directory (files stand in for a finished run): refused, byte for byte intact.
    let run = out.path().join("run");
    std::fs::create_dir_all(run.join("test")).unwrap();
    for f in ["checkpoint.safetensors", "config.json", "log.csv", "test/metrics.json"] {
        std::fs::write(run.join(f), format!("the old {f}")).unwrap();
    }
    let o = edgenerf(&["train", scene, "--out", run.to_str().unwrap(), "--iters", "1"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("already holds a run") && t.contains("--resume") && t.contains("--overwrite"), "{t}");
    for f in ["checkpoint.safetensors", "config.json", "log.csv", "test/metrics.json"] {
        assert_eq!(std::fs::read_to_string(run.join(f)).unwrap(), format!("the old {f}"), "{f} changed");
    }
    // --resume keeps the run's config: flags that would change it are refused.
    for extra in [&["--config", "x.toml"][..], &["--views", "3"], &["--set", "train.seed=2"], &["--backend", "mlp"], &["--tau-e", "100"], &["--overwrite"]] {
        let mut args = vec!["train", scene, "--out", run.to_str().unwrap(), "--resume"];
        args.extend_from_slice(extra);
        let o = edgenerf(&args);
        assert!(!o.status.success() && text(&o).contains("cannot be used with"), "{extra:?}: {}", text(&o));
    }
    let o = edgenerf(&["train", scene, "--out", out.path().join("empty").to_str().unwrap(), "--resume"]);
    assert!(!o.status.success() && text(&o).contains("holds no checkpoint"), "{}", text(&o));
    // Outputs that are files are refused before any work.
    let file = out.path().join("a-file");
    std::fs::write(&file, "keep me").unwrap();
    for cmd in [&["train", scene, "--out", file.to_str().unwrap()][..], &["render", run.to_str().unwrap(), "--out", file.to_str().unwrap()]] {
        let o = edgenerf(cmd);
        assert!(!o.status.success() && text(&o).contains("is a file"), "{cmd:?}: {}", text(&o));
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
    // Impossible batch sizes (they trained and logged PSNR 100).
    for set in ["train.rays_per_batch=0", "train.max_samples=0"] {
        let o = edgenerf(&["train", scene, "--out", out.path().join("zero").to_str().unwrap(), "--set", set, "--no-eval"]);
        assert!(!o.status.success() && text(&o).contains("must both be positive"), "{set}: {}", text(&o));
    }
    // Out-of-range edge options (--canny-sigma 1e9 hung allocating its kernel).
    let o = edgenerf(&["edges", scene, "--canny-sigma", "1e9", "--out", out.path().join("edges").to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("canny.sigma"), "{}", text(&o));
    let o = edgenerf(&["train", scene, "--tau-e", "300", "--views", "3", "--out", out.path().join("tau").to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("0..=255"), "{}", text(&o));
}

/// Ctrl-C during training saves a checkpoint at the step reached (it lost every step
/// since the last periodic one), and `--resume` continues from it.
#[cfg(unix)]
#[test]
fn ctrl_c_saves_a_checkpoint_that_resume_continues() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scene = repo().join("synthetic-scenes/small/turntable");
    let demo = repo().join("tools/configs/demo.toml");
    let child = common::command()
        .args(["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--config", demo.to_str().unwrap()])
        .args(["--iters", "100000", "--set", "train.checkpoint_every=0", "--set", "sampler.steps_per_diagonal=48", "--no-eval"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let rows = || std::fs::read_to_string(run.join("log.csv")).map_or(0, |l| l.lines().count().saturating_sub(1));
    let start = std::time::Instant::now();
    while rows() < 2 {
        assert!(start.elapsed().as_secs() < 600, "training never logged two steps");
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    assert!(std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let t = text(&o);
    assert!(!o.status.success() && t.contains("interrupted at step") && t.contains("--resume"), "{t}");
    let steps = rows();
    assert!(steps >= 2 && run.join("checkpoint.safetensors").is_file(), "{steps} steps logged\n{t}");

    let iters = (steps + 1).to_string();
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--resume", "--iters", &iters, "--no-eval"]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(rows(), steps + 1, "the resumed run starts at the interrupted step");
}

/// A scene path that is not UTF-8 cannot be recorded in config.json: a clear error
/// (it panicked serializing the config).
#[cfg(unix)]
#[test]
fn a_non_utf8_scene_path_is_a_clear_error() {
    use std::os::unix::ffi::OsStrExt;
    let out = tempfile::tempdir().unwrap();
    let scene = out.path().join(std::ffi::OsStr::from_bytes(b"scene\xff"));
    std::fs::create_dir(&scene).unwrap();
    let o = common::command()
        .arg("train")
        .arg(&scene)
        // A --set too: it failed on the path, blaming the --set.
        .args(["--out", out.path().join("run").to_str().unwrap(), "--set", "train.seed=1"])
        .output()
        .unwrap();
    let t = text(&o);
    assert!(!o.status.success() && t.contains("not valid UTF-8") && !t.contains("panicked"), "{t}");
}

#[test]
fn train_with_edge_guided_regularizers_logs_each_term_and_caches_masks() {
    let out = tempfile::tempdir().unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let config = repo().join("tools/configs/sparse-small.toml");
    let run = |name: &str, extra: &[&str]| {
        let dir = out.path().join(name);
        let mut args = vec!["train", scene.to_str().unwrap(), "--views", "3", "--config", config.to_str().unwrap()];
        args.extend_from_slice(&["--out", dir.to_str().unwrap(), "--iters", "2", "--no-eval"]);
        // The preset switches the terms on at step 100; start them at once here.
        args.extend_from_slice(&["--set", "reg.start_step=0", "--set", "reg.warmup_steps=0"]);
        args.extend_from_slice(extra);
        let o = edgenerf(&args);
        assert!(o.status.success(), "{}", text(&o));
        let log = std::fs::read_to_string(dir.join("log.csv")).unwrap();
        let header: Vec<&str> = log.lines().next().unwrap().split(',').collect();
        let row: Vec<&str> = log.lines().nth(2).unwrap().split(',').collect();
        let col = |k: &str| row[header.iter().position(|h| *h == k).unwrap_or_else(|| panic!("no {k} column"))].parse::<f64>().unwrap();
        (dir, [col("loss_depth"), col("loss_normal"), col("lambda_depth"), col("lambda_normal")])
    };
    let (dir, v) = run("edge", &[]);
    let close = |a: f64, b: f64| (a - b).abs() < 1e-6;
    assert!(v[0] > 0.0 && v[1] > 0.0 && close(v[2], 0.0333) && close(v[3], 0.00333), "the preset's weights, both terms measured: {v:?}");
    let masks = std::fs::read_dir(dir.join("edges")).unwrap().filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "png")).count();
    assert_eq!(masks, 3, "one cached mask per training view");
    let (_, v) = run("official", &["--reg-variant", "official", "--no-depth-reg", "--edges", "none"]);
    // L_z is still measured (weight 0) while L_n is on: a free monitor.
    assert!(v[2] == 0.0 && close(v[3], 0.00333) && v[1] > 0.0, "the preset's lambda3 under the official variant, depth off: {v:?}");
    let config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.path().join("official/config.json")).unwrap()).unwrap();
    assert_eq!(config["edges"]["source"], "none");
    assert_eq!(config["reg"]["variant"], "official");
}

/// A Blender scene without transforms_test.json trained, then failed with a bare "No
/// such file or directory": now refused before any work, saying what to do.
#[test]
fn a_scene_without_test_views_is_refused_before_training() {
    let out = tempfile::tempdir().unwrap();
    let scene = out.path().join("no-test");
    let src = repo().join("synthetic-scenes/small/creases");
    std::fs::create_dir_all(scene.join("train")).unwrap();
    std::fs::copy(src.join("transforms_train.json"), scene.join("transforms_train.json")).unwrap();
    for e in std::fs::read_dir(src.join("train")).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, scene.join("train").join(p.file_name().unwrap())).unwrap();
    }
    let run = out.path().join("run");
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--iters", "1"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("no test views") && t.contains("transforms_test.json") && t.contains("--no-eval"), "{t}");
    assert!(!run.join("log.csv").exists() && !run.join("checkpoint.safetensors").exists(), "refused before training");
}

/// An LLFF capture of `n` 16x12 images in `images_4/` (pixels from `pixel`), cameras
/// 0.1 apart along x.
fn tiny_llff(n: usize, pixel: impl Fn(u32, u32) -> image::Rgb<u8>) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let mut rows = Vec::new();
    for i in 0..n {
        rows.extend_from_slice(&[1.0, 0.0, 0.0, i as f64 * 0.1, 48.0, 0.0, 1.0, 0.0, 0.0, 64.0, 0.0, 0.0, 1.0, 0.0, 80.0, 2.0, 20.0]);
        let p = dir.path().join(format!("images_4/img{i}.png"));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        image::RgbImage::from_fn(16, 12, &pixel).save(&p).unwrap();
    }
    edgenerf::data::npy::write_npy_f64(&dir.path().join("poses_bounds.npy"), &[n, 17], &rows).unwrap();
    dir
}

/// `--llff-factor N` reads images_N (there was no flag; the error for a missing images_8
/// cited an internal API).
#[test]
fn llff_factor_flag_reads_another_image_folder() {
    let dir = tiny_llff(3, |_, _| image::Rgb([0, 0, 0]));
    let scene = dir.path().to_str().unwrap();
    let o = edgenerf(&["info", scene, "--no-gpu"]);
    assert!(!o.status.success() && text(&o).contains("images_4 (--llff-factor 4)"), "{}", text(&o));
    let o = edgenerf(&["info", scene, "--no-gpu", "--llff-factor", "4"]);
    assert!(o.status.success() && text(&o).contains("3 of 16x12"), "{}", text(&o));
    let o = edgenerf(&["info", scene, "--no-gpu", "--llff-factor", "0"]);
    assert!(!o.status.success() && text(&o).contains("--llff-factor"), "{}", text(&o));
}

/// The stereo depth prior sweeps an LLFF capture along its NDC rays; the planes across
/// up are world-space planes it does not have, which `train` says before it computes
/// edge maps.
#[test]
fn the_stereo_prior_runs_on_ndc_scenes_without_the_planes_across_up() {
    let dir = tiny_llff(9, |x, y| image::Rgb([(x * 15) as u8, (y * 20) as u8, 90]));
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scene = dir.path().to_str().unwrap();
    let train = |extra: &[&str]| {
        let mut args = vec!["train", scene, "--llff-factor", "4", "--iters", "2", "--no-eval", "--out", run.to_str().unwrap(), "--overwrite", "--set", "priors.stereo_depth=0.03"];
        args.extend_from_slice(extra);
        edgenerf(&args)
    };
    let o = train(&["--set", "priors.stereo_horizontal=true"]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("NDC") && t.contains("priors.stereo_horizontal = false"), "{t}");
    assert!(!run.join("edges").exists(), "refused before the edge maps");
    let o = train(&[]);
    let t = text(&o);
    assert!(o.status.success() && t.contains("stereo depth prior: a sweep of"), "{t}");
    assert!(run.join("stereo").is_dir(), "the NDC sweep's targets are written beside the run");
}

/// With a stereo prior on, `train` says how many pixels the sweep confirmed and filled
/// (and which planes it swept) and writes each training view's targets as images beside the run.
#[test]
fn the_stereo_targets_are_reported_and_written_as_images() {
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let scene = repo().join("synthetic-scenes/small/creases");
    let o = edgenerf(&[
        "train",
        scene.to_str().unwrap(),
        "--views",
        "3",
        "--iters",
        "1",
        "--no-eval",
        "--out",
        run.to_str().unwrap(),
        "--set",
        "priors.stereo_depth=0.03",
        "--set",
        "priors.stereo_fill=4",
        "--set",
        "priors.stereo_uniqueness=0.9",
        "--set",
        "priors.stereo_horizontal=true",
    ]);
    let t = text(&o);
    assert!(o.status.success() && t.contains("another view confirms") && t.contains("filled within their edge regions"), "{t}");
    assert!(t.contains("128 depth planes and 128 planes across the cameras' mean up vector ("), "{t}");
    let names: Vec<String> = std::fs::read_dir(run.join("stereo")).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    for kind in ["_depth.png", "_confidence.png"] {
        assert_eq!(names.iter().filter(|n| n.ends_with(kind)).count(), 3, "{kind} per training view: {names:?}");
    }
    let depth = image::open(run.join("stereo").join(names.iter().find(|n| n.ends_with("_depth.png")).unwrap())).unwrap().to_rgb8();
    assert!(depth.pixels().any(|p| p.0 != [0, 0, 0]), "a textured scene gets depths");
}

/// Printing into a closed pipe (`edgenerf info ... | head -1`) panicked with a backtrace;
/// it now ends quietly on SIGPIPE, as other Unix tools do.
#[cfg(unix)]
#[test]
fn a_closed_stdout_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = common::command()
        .args(["info", repo().join("synthetic-scenes/small/creases").to_str().unwrap(), "--no-gpu"])
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    const SIGPIPE: i32 = 13;
    assert_eq!(o.status.signal(), Some(SIGPIPE), "{:?} {err}", o.status);
}

/// Numeric flags are range-checked before any work, negative values included (clap
/// took `-1` for a flag), NaN included (it became `null`, i.e. the default, through
/// --set), and whether or not the run reads the value (`--tau-e 300` passed on a run
/// without edge masks).
#[test]
fn numeric_flags_are_range_checked_before_any_work() {
    let out = tempfile::tempdir().unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let demo = repo().join("tools/configs/demo.toml");
    for (flag, value, key) in [
        ("--lambda-depth", "-1", "reg.lambda_depth"),
        ("--lambda-normal", "nan", "reg.lambda_normal"),
        ("--max-seconds", "-1", "train.max_seconds"),
        ("--max-seconds", "nan", "train.max_seconds"),
        ("--iters", "0", "train.iters"),
        ("--tau-e", "300", "tau_e"),
        ("--canny-low", "-0.5", "canny thresholds"),
    ] {
        let run = out.path().join("run");
        let o = edgenerf(&[
            "train", scene.to_str().unwrap(), "--out", run.to_str().unwrap(), "--config", demo.to_str().unwrap(),
            "--set", "sampler.steps_per_diagonal=48", "--no-eval", flag, value,
        ]);
        let t = text(&o);
        assert!(!o.status.success() && t.contains(key), "{flag} {value}: {t}");
        assert!(!run.join("log.csv").exists(), "{flag} {value}: refused before training");
    }
}

/// Without `--config`, a sparse-view run of the grid takes the shipped preset for its
/// scene format (the measured configuration, not the paper's unscaled weights) and says
/// so; `--no-preset` gives the engine defaults, and a dense run is left alone.
#[test]
fn a_sparse_run_without_config_uses_the_format_preset() {
    let out = tempfile::tempdir().unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let scene = scene.to_str().unwrap();
    let run = |name: &str, extra: &[&str]| {
        let dir = out.path().join(name);
        let mut args = vec!["train", scene, "--out", dir.to_str().unwrap(), "--iters", "1", "--no-eval"];
        args.extend_from_slice(&["--set", "sampler.steps_per_diagonal=48"]);
        // The preset's grid everywhere: the engine default's larger grid would compile
        // its own kernels on lavapipe (minutes) for a test of the reg settings only.
        for f in ["field.n_levels=8", "field.log2_hashmap_size=16", "field.finest_resolution=256", "field.hidden_width=32"] {
            args.extend_from_slice(&["--set", f]);
        }
        args.extend_from_slice(extra);
        let o = edgenerf(&args);
        assert!(o.status.success(), "{name}: {}", text(&o));
        let config: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("config.json")).unwrap()).unwrap();
        (text(&o), config)
    };
    let preset = edgenerf::train::RunConfig::from_file(&repo().join("tools/configs/sparse-small.toml")).unwrap();
    let (t, config) = run("preset", &["--views", "3"]);
    assert!(t.contains("tools/configs/sparse-small.toml"), "{t}");
    assert_eq!(config["reg"]["lambda_depth"].as_f64().unwrap() as f32, preset.reg.lambda_depth);
    assert_eq!(config["reg"]["start_step"], serde_json::json!(preset.reg.start_step));
    let (t, config) = run("defaults", &["--views", "3", "--no-preset"]);
    assert!(!t.contains("preset tools/configs"), "{t}");
    let defaults = edgenerf::train::RunConfig::default();
    assert_eq!(config["reg"]["lambda_depth"].as_f64().unwrap() as f32, defaults.reg.lambda_depth);
    assert_ne!(defaults.reg.lambda_depth, preset.reg.lambda_depth, "the test must tell the two apart");
    let (t, config) = run("dense", &[]);
    assert!(!t.contains("preset tools/configs"), "{t}");
    assert_eq!(config["reg"]["lambda_depth"].as_f64().unwrap() as f32, defaults.reg.lambda_depth);
}

/// A config's `[[with_views]]` tables apply from their view count (`--views K`, or the
/// scene's training views without it), under `--iters` and `--set`, and leave
/// `config.json` with the values they set and without the tables.
#[test]
fn with_views_tables_follow_the_view_count() {
    let out = tempfile::tempdir().unwrap();
    let file = out.path().join("views.toml");
    std::fs::write(
        &file,
        "[field]\nn_levels = 8\nlog2_hashmap_size = 16\nfinest_resolution = 256.0\nhidden_width = 32\n\n\
         [sampler]\nsteps_per_diagonal = 48.0\n\n[train]\niters = 1\n\n\
         [[with_views]]\nmin_views = 3\nset = [\"train.rays_per_batch=512\", \"train.iters=2\"]\n",
    )
    .unwrap();
    let scene = repo().join("synthetic-scenes/small/creases");
    let run = |name: &str, extra: &[&str]| {
        let dir = out.path().join(name);
        let mut args = vec!["train", scene.to_str().unwrap(), "--config", file.to_str().unwrap(), "--out", dir.to_str().unwrap(), "--no-eval"];
        args.extend_from_slice(extra);
        let o = edgenerf(&args);
        assert!(o.status.success(), "{name}: {}", text(&o));
        let config: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("config.json")).unwrap()).unwrap();
        assert!(config.get("with_views").is_none(), "{name}: config.json keeps the tables");
        (text(&o), config["train"]["rays_per_batch"].as_u64().unwrap(), config["train"]["iters"].as_u64().unwrap())
    };
    let (t, rays, iters) = run("three", &["--views", "3"]);
    assert_eq!((rays, iters), (512, 2), "{t}");
    let log = "views.toml sets train.rays_per_batch=512, train.iters=2";
    assert!(t.contains("3 training views: [[with_views]] in ") && t.contains(log), "{t}");
    assert_eq!(run("two", &["--views", "2"]).1, 4096, "2 views are under min_views = 3");
    assert_eq!(run("all", &[]).1, 512, "every training view of the scene (more than 3)");
    let (_, rays, iters) = run("flags", &["--views", "3", "--iters", "1", "--set", "train.rays_per_batch=256"]);
    assert_eq!((rays, iters), (256, 1), "--iters and --set win over the tables");

    // A wrong assignment in a table names the file and the table, before any run folder.
    let bad = out.path().join("bad.toml");
    std::fs::write(&bad, "[[with_views]]\nmin_views = 2\nset = [\"train.no_such_key=1\"]\n").unwrap();
    let dir = out.path().join("bad-run");
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--config", bad.to_str().unwrap(), "--out", dir.to_str().unwrap()]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("bad.toml") && t.contains("min_views = 2") && t.contains("no_such_key"), "{t}");
    assert!(!dir.exists(), "a refused config wrote {}", dir.display());
}
