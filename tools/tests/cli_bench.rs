//! `edgenerf bench` and `edgenerf eval` as a user runs them: a tiny suite (one scene,
//! two working configurations and a broken one, a few steps) gives results rows,
//! a report with a PNG plot, skips its finished runs on a second invocation and records
//! the broken run's error; `eval` of a trained run writes metrics and error maps.

mod common;

use common::{edgenerf, repo, text};

/// A suite on the committed `turntable` scene: 3 views, a few steps, coarse marching
/// (an untrained grid is occupied everywhere), at most one checkpoint.
fn tiny_suite(dir: &std::path::Path) -> std::path::PathBuf {
    let suite = dir.join("tiny.toml");
    std::fs::write(
        &suite,
        r#"
description = "CLI test suite"
scenes = ["synthetic-scenes/small/turntable"]
base_config = "tools/configs/sparse-small.toml"
views = 3
iters = 3
set = { "sampler.steps_per_diagonal" = 48, "train.checkpoint_every" = 0 }

[[config]]
name = "none"
label = "no regularizer"
depth_reg = false
normal_reg = false

[[config]]
name = "edge-gt"
label = "edge-guided, ground-truth edge maps"
edges = "gt"

[[config]]
name = "broken"
set = { "train.no_such_key" = 1 }

[quick]
iters = 2
configs = ["none"]
"#,
    )
    .unwrap();
    suite
}

#[test]
fn bench_runs_a_suite_resumes_and_records_failures() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path());
    let out = dir.path().join("out");
    let args = ["bench", suite.to_str().unwrap(), "--out", out.to_str().unwrap(), "--lpips", "none"];
    let o = edgenerf(&args);
    let t = text(&o);
    assert!(o.status.success(), "a failed run does not fail the sweep: {t}");
    assert!(t.contains("2 runs finished, 1 failed"), "{t}");

    let rows: Vec<serde_json::Value> = serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(rows.len(), 3, "one row per (scene, config, repeat)");
    let row = |config: &str| rows.iter().find(|r| r["config"] == config).unwrap_or_else(|| panic!("no {config} row"));
    for config in ["none", "edge-gt"] {
        let r = row(config);
        assert_eq!(r["record"]["status"], "ok", "{r}");
        assert_eq!(r["steps"], 3, "{r}");
        assert!(r["metrics"]["psnr"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["metrics"]["normal.all.mean_deg"].is_number(), "GT geometry metrics: {r}");
        assert!(r["metrics"]["boundary.accuracy"].is_number(), "{r}");
        assert!(r["steps_per_s"].as_f64().unwrap() > 0.0 && r["samples_per_s"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["adapter"].is_string() && r["config_hash"].as_str().unwrap().len() == 16, "{r}");
        assert!(r["record"]["git_commit"].is_string(), "{r}");
    }
    let broken = row("broken");
    assert_eq!(broken["record"]["status"], "failed");
    assert!(broken["record"]["error"].as_str().unwrap().contains("no_such_key"), "the error text is recorded: {broken}");
    // The ground-truth edge maps became the run's external masks.
    assert!(out.join("gt-edges/turntable/r_000.png").is_file());
    let cfg = std::fs::read_to_string(out.join("runs/turntable__edge-gt__r0/config.json")).unwrap();
    assert!(cfg.contains("gt-edges"), "{cfg}");

    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    for col in ["status", "error", "wall_s", "steps_per_s", "samples_per_s", "adapter", "git_commit", "config_hash", "psnr", "ssim", "depth.all.abs_rel", "normal.edge.mean_deg"] {
        assert!(header.contains(&col), "results.csv lacks {col}: {header:?}");
    }
    assert_eq!(csv.lines().count(), 4, "{csv}");

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for s in ["## Image metrics per scene", "## Geometry against ground truth", "| turntable | `edge-gt` |", "no_such_key", "psnr_vs_time.png", "strip_turntable.png"] {
        assert!(report.contains(s), "report.md lacks {s:?}:\n{report}");
    }
    for png in ["psnr_vs_time.png", "geometry.png", "strip_turntable.png"] {
        let img = image::open(out.join(png)).unwrap_or_else(|e| panic!("{png}: {e}"));
        assert!(img.width() > 200 && img.height() > 200, "{png} {}x{}", img.width(), img.height());
    }

    // Second invocation: the finished runs are skipped, the failed one is tried again.
    let before = std::fs::metadata(out.join("runs/turntable__none__r0/bench.json")).unwrap().modified().unwrap();
    let o = edgenerf(&args);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("2 finished before, 1 to do"), "{t}");
    assert!(t.contains("0 runs finished, 1 failed"), "{t}");
    let after = std::fs::metadata(out.join("runs/turntable__none__r0/bench.json")).unwrap().modified().unwrap();
    assert_eq!(before, after, "a finished run is not redone");
}

#[test]
fn bench_quick_variant_and_unknown_suites() {
    let dir = tempfile::tempdir().unwrap();
    let suite = tiny_suite(dir.path());
    let out = dir.path().join("quick");
    let o = edgenerf(&["bench", suite.to_str().unwrap(), "--quick", "--out", out.to_str().unwrap(), "--lpips", "none"]);
    assert!(o.status.success(), "{}", text(&o));
    let rows: Vec<serde_json::Value> = serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(rows.len(), 1, "[quick] keeps the configs it names");
    assert_eq!(rows[0]["steps"], 2, "and its iters");

    let o = edgenerf(&["bench", "no-such-suite", "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("geometry"), "the error lists the shipped suites: {}", text(&o));
}

#[test]
fn shipped_suites_parse() {
    // --report-only on an empty directory expands every run without training any.
    for (suite, quick_variants) in [
        ("geometry", &[false, true][..]),
        ("paper-ablation", &[false, true]),
        ("backends", &[false, true]),
        ("dense-walls", &[false]),
        ("fern-ablation", &[false]),
        ("dtu-ablation", &[false]),
    ] {
        for &quick in quick_variants {
            let dir = tempfile::tempdir().unwrap();
            let mut args = vec!["bench", suite, "--report-only", "--out", dir.path().to_str().unwrap()];
            if quick {
                args.push("--quick");
            }
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_edgenerf")).args(&args).current_dir(repo()).output().unwrap();
            let t = text(&o);
            assert!(o.status.success(), "{suite} quick={quick}: {t}");
            let rows: Vec<serde_json::Value> =
                serde_json::from_str(&std::fs::read_to_string(dir.path().join("results.json")).unwrap()).unwrap();
            assert!(!rows.is_empty(), "{suite}");
            if suite == "geometry" {
                assert_eq!(rows.len(), if quick { 14 } else { 28 }, "7 scenes x configs");
            }
            if suite == "dense-walls" {
                assert_eq!(rows.len(), 7 * 3 + 3 * 5, "3 configs on every scene, 5 on the forward-facing ones");
            }
            if suite == "fern-ablation" {
                assert_eq!(rows.len(), 11 * 2, "11 configs x 2 seeds on fern");
            }
            if suite == "dtu-ablation" {
                assert_eq!(rows.len(), 6 * 2, "6 configs x 2 seeds on DTU scan 24");
            }
        }
    }
}

#[test]
fn eval_writes_metrics_and_error_maps() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let scene = repo().join("synthetic-scenes/small/creases");
    let o = edgenerf(&[
        "train",
        scene.to_str().unwrap(),
        "--views",
        "3",
        "--config",
        repo().join("tools/configs/sparse-small.toml").to_str().unwrap(),
        "--iters",
        "3",
        "--no-eval",
        "--set",
        "sampler.steps_per_diagonal=48",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));

    // Without LPIPS weights: a one-line note and null LPIPS fields by default.
    let no_weights = dir.path().join("no-lpips-weights");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_edgenerf"))
        .args(["eval", run.to_str().unwrap()])
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .env(edgenerf::metrics::lpips::WEIGHTS_DIR_ENV, &no_weights)
        .output()
        .unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert_eq!(t.lines().filter(|l| l.starts_with("note: LPIPS left out")).count(), 1, "{t}");
    assert!(t.contains("tools/lpips/fetch-weights"), "{t}");
    assert!(t.contains("protocol full-image") && t.contains("mean"), "{t}");
    let out = run.join("eval");
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(m["views"].as_array().unwrap().len(), 8, "every test view");
    assert_eq!(m["protocol"], "full-image");
    for k in ["psnr", "ssim", "depth.all.abs_rel", "depth.all.rmse", "depth.all.delta_1", "depth.edge.abs", "depth.non_edge.abs", "normal.all.median_deg", "normal.all.under_11_25", "normal.edge.mean_deg", "boundary.completeness"] {
        assert!(m["metrics"][k].is_number(), "metrics.{k} missing: {}", m["metrics"]);
    }
    assert!(m["views"][0]["lpips_vgg"].is_null() && m["views"][0]["lpips_alex"].is_null(), "no weights, no LPIPS");
    // PSNR split by how many of the 3 training views see each pixel's surface: per view
    // the classes' shares add up to the object's pixels (never more than the image), and
    // the table prints their means.
    assert!(t.contains("PSNR by how many training views see the surface"), "{t}");
    for v in m["views"].as_array().unwrap() {
        let c = &v["covisibility"];
        let share: f64 = ["unseen", "seen_once", "seen_twice_or_more"].iter().filter_map(|k| c[*k]["fraction"].as_f64()).sum();
        assert!(share > 0.05 && share < 1.0, "the object's pixels only: {c}");
    }
    assert!(m["metrics"]["covisibility.seen_twice_or_more.psnr"].is_number(), "{}", m["metrics"]);
    let first = m["views"][0]["name"].as_str().unwrap();
    for f in ["rgb.png", "depth.png", "normal.png", "depth_error.png", "normal_error.png", "edge_overlay.png"] {
        assert!(out.join(format!("{first}_{f}")).is_file(), "{first}_{f} missing");
    }

    // Asked for explicitly without weights: an error naming the fetch script.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_edgenerf"))
        .args(["eval", run.to_str().unwrap(), "--lpips", "vgg", "--out", dir.path().join("x").to_str().unwrap()])
        .env(edgenerf::metrics::lpips::WEIGHTS_DIR_ENV, &no_weights)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(text(&o).contains("tools/lpips/fetch-weights"), "{}", text(&o));

    // The train split, from the checkpoint file, elsewhere; LPIPS where its weights are
    // installed, and asked for without them, a clear error.
    let other = dir.path().join("train-eval");
    let ckpt = run.join("checkpoint.safetensors");
    let o = edgenerf(&["eval", ckpt.to_str().unwrap(), "--split", "train", "--lpips", "alex", "--out", other.to_str().unwrap()]);
    if edgenerf::metrics::lpips::Lpips::from_default_dir(edgenerf::metrics::lpips::LpipsNet::Alex).is_err() {
        assert!(!o.status.success());
        assert!(text(&o).contains("tools/lpips/fetch-weights"), "{}", text(&o));
        return;
    }
    assert!(o.status.success(), "{}", text(&o));
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(other.join("metrics.json")).unwrap()).unwrap();
    assert!(m["metrics"]["lpips_alex"].as_f64().unwrap() > 0.0, "{}", m["metrics"]);
    assert!(m["views"][0]["lpips_vgg"].is_null(), "only the network asked for");
    assert_eq!(m["views"].as_array().unwrap().len(), 3);
}
