//! `edgenerf speed` (per-stage and per-kernel timing, JSON: what it reports holds of the
//! steps it timed) and `train` with the sparse-view priors
//! (`priors.distortion`, `priors.occlusion`: logged in `log.csv`'s appended columns).

mod common;

use common::{command, edgenerf, read_log, repo, text, train_creases_3v};

/// What `edgenerf speed` reports must be true of the steps it timed: the preset's
/// edge-guided terms run in them (speed starts every term at step 0, where the preset's
/// schedule would start them at step 200), the kernels' GPU time fits inside the step
/// that ran them, and the field stages carry the samples the report names.
#[test]
fn speed_times_the_steps_of_a_run_with_every_term_on() {
    let out = tempfile::tempdir().unwrap();
    let o = command()
        .current_dir(repo())
        .args(["speed", "--preset", "sparse-small", "--warmup", "5", "--steps", "2", "--kernels", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("field backward") && t.contains("steps/s"), "{t}");
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.path().join("speed.json")).unwrap()).unwrap();
    let case = &json["cases"][0];
    assert_eq!(case["name"], "sparse-small");
    assert_eq!(case["train_views"], 3);
    // creases' cameras stand outside its box and 3 views are under every [[with_views]]:
    // no table of the preset applies.
    assert_eq!(case["tables_applied"], serde_json::json!([]), "{case}");
    let stages = case["stages"].as_array().unwrap();
    assert_eq!(stages.len(), 7);
    let profiled = case["profiled_ms_per_step"].as_f64().unwrap();
    // The field stages saw the step's samples: at least one per ray (3-view creases,
    // untrained: every ray crosses the box) and no more than the batch's capacity.
    let (rays, samples) = (case["rays_per_step"].as_f64().unwrap(), case["samples_per_step"].as_f64().unwrap());
    assert!(samples >= rays && samples <= 512.0 * rays, "{samples} samples for {rays} rays: {case}");
    for key in ["steps_per_s", "samples_per_step", "field_forward_samples_per_s", "field_backward_samples_per_s"] {
        assert!(case[key].as_f64().unwrap() > 0.0, "{key}: {case}");
    }
    // Plain steps 5-6 update no occupancy grid: one submission each.
    assert_eq!(case["submissions_per_step"].as_f64().unwrap(), 1.0, "{case}");
    // The host's split of a plain step: submission and waits inside the step's time.
    let (submit, wait) = (case["submit_ms_per_step"].as_f64().unwrap(), case["wait_ms_per_step"].as_f64().unwrap());
    assert!(submit >= 0.0 && wait >= 0.0 && submit + wait <= case["ms_per_step"].as_f64().unwrap(), "{case}");
    assert!(t.contains("host per plain step"), "{t}");
    // Once the sample buffers have settled (the first steps grow them), a step binds
    // what the step before bound: every bind group comes from the cache.
    assert_eq!(case["bind_groups_per_step"].as_f64().unwrap(), 0.0, "{case}");
    let field_ms = |name: &str| stages.iter().find(|s| s["stage"] == name).unwrap()["ms_per_step"].as_f64().unwrap();
    assert!(field_ms("field forward") > 0.0 && field_ms("field backward") > 0.0);

    // --kernels: every kernel of a step, the slowest first, the field's among them.
    assert!(t.contains("kernels timed one by one"), "{t}");
    // lavapipe and NVIDIA have timestamp queries: the kernels' GPU time, not their
    // submissions and waits (an adapter without them falls back to wall time).
    let adapter = json["adapter"].as_str().unwrap();
    if adapter.contains("llvmpipe") || adapter.contains("NVIDIA") {
        assert_eq!(case["kernel_timer"], "GPU timestamps", "{adapter}: {case}");
    } else {
        assert!(case["kernel_timer"].is_string(), "{case}");
    }
    let kernels = case["kernels"].as_array().unwrap();
    let ms: Vec<f64> = kernels.iter().map(|k| k["ms_per_step"].as_f64().unwrap()).collect();
    assert!(ms.windows(2).all(|w| w[0] >= w[1]), "{ms:?}");
    // The kernels of a step ran inside a step: their time adds up to about the profiled
    // step's (which also waits after every stage; the two passes time different steps,
    // on a shared machine, hence the wide bounds), and on lavapipe, where the field's
    // kernels are most of a step, to a fair part of it. A timer read in the wrong unit,
    // or launches counted several times, lands far outside. (sparse-small, 2-core CPU:
    // 297 ms of kernels in a 279 ms profiled step.)
    let kernel_ms: f64 = ms.iter().sum();
    let why = format!("kernels {kernel_ms} ms against a {profiled} ms step: {case}");
    assert!(kernel_ms <= 4.0 * profiled, "{why}");
    if adapter.contains("llvmpipe") {
        assert!(kernel_ms >= 0.1 * profiled, "{why}");
    }
    // sparse-small's terms run in the timed steps (speed sets reg.start_step = 0; with
    // the preset's own schedule none would run before step 200): L_z and L_n, the
    // depth-normal consistency and the cross-view reprojection each dispatch every step.
    for name in [
        "loss/edge_reg.wgsl:edge_reg",
        "loss/depth_normal.wgsl:depth_normal",
        "loss/reprojection.wgsl:reprojection",
        "field/grid_forward.wgsl:forward",
        "field/grid_backward.wgsl:backward",
        "optim/adam.wgsl:adam_step",
    ] {
        let k = kernels.iter().find(|k| k["kernel"] == name).unwrap_or_else(|| panic!("{name} not timed: {kernels:?}"));
        assert!(k["ms_per_step"].as_f64().unwrap() > 0.0 && k["dispatches_per_step"].as_f64().unwrap() >= 1.0, "{k}");
    }
}

/// `speed` times what `train` would run: a config's `[with_cameras_inside]` applies to an
/// inside-out scene (`room`: the background on the box, the stereo priors), as it does
/// in `train`, instead of timing the preset's base table (which marched 114 samples per
/// ray on `room` where its run marches 26).
#[test]
fn speed_applies_the_tables_train_applies() {
    let out = tempfile::tempdir().unwrap();
    let o = command()
        .current_dir(repo())
        .args(["speed", "--scene", "synthetic-scenes/small/room", "--config", "tools/configs/sparse-small.toml", "--views", "3"])
        .args(["--warmup", "2", "--steps", "1", "--out"])
        .arg(out.path())
        .output()
        .unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("[with_cameras_inside] in tools/configs/sparse-small.toml sets"), "{t}");
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.path().join("speed.json")).unwrap()).unwrap();
    let applied: Vec<&str> = json["cases"][0]["tables_applied"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
    for key in ["render.learned_background.shell_shape=\"box\"", "priors.stereo_depth=0.1", "sampler.decay=0.9"] {
        assert!(applied.contains(&key), "{key} not applied: {applied:?}");
    }
}

#[test]
fn speed_outside_the_repository_says_what_to_pass() {
    let out = tempfile::tempdir().unwrap();
    let o = command().current_dir(out.path()).args(["speed", "--preset", "demo", "--steps", "1"]).output().unwrap();
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("not found") && t.contains("--scene"), "{t}");
}

#[test]
fn priors_train_and_are_logged() {
    let out = tempfile::tempdir().unwrap();
    let dir = out.path().join("priors");
    let extra = ["--no-depth-reg", "--no-normal-reg", "--set", "priors.distortion=0.01", "--set", "priors.occlusion=0.01"];
    let o = train_creases_3v(&dir, 3, &extra);
    assert!(o.status.success(), "{}", text(&o));
    let (header, rows) = read_log(&dir);
    let log = format!("{header:?}\n{rows:?}");
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name} column"));
    assert_eq!(rows.len(), 3);
    for r in &rows {
        // The untrained field (density ~1 everywhere) spreads every ray's weight along it.
        assert!(r[col("loss_distortion")] > 0.0 && r[col("loss_occlusion")] >= 0.0, "{log}");
        assert!(r[col("loss")] > r[col("loss_color")], "the priors enter the total loss: {log}");
    }
    // Each step trains on one view; some views' rays reach the box within the occlusion
    // range (the first 8 % of near..far), where the untrained density is ~1.
    assert!(rows.iter().any(|r| r[col("loss_occlusion")] > 0.0), "{log}");
    let cfg = std::fs::read_to_string(dir.join("config.json")).unwrap();
    assert!(cfg.contains("\"distortion\": 0.01"), "{cfg}");
    // A bad weight is a config error naming the key.
    let scene = repo().join("synthetic-scenes/small/creases");
    let o = edgenerf(&["train", scene.to_str().unwrap(), "--out", out.path().join("bad").to_str().unwrap(), "--set", "priors.distortion=-1"]);
    assert!(!o.status.success() && text(&o).contains("priors.distortion"), "{}", text(&o));
}

/// Monocular depth maps (`priors.mono_depth_dir`) reach the stereo depth prior: maps
/// written from creases' true depth as relative disparity (an unknown scale and shift
/// per view, as Depth Anything writes them) are fitted to the sweep and give the
/// pixels the sweep left without a depth targets within a few per cent of the truth,
/// which `train` reports; a missing map is an error naming the view and the file.
#[test]
fn monocular_depth_maps_are_fitted_to_the_sweep_and_reported() {
    let out = tempfile::tempdir().unwrap();
    let maps = out.path().join("mono");
    std::fs::create_dir_all(&maps).unwrap();
    let scene_dir = repo().join("synthetic-scenes/small/creases");
    let opts = edgenerf::data::LoadOptions { views: Some(3), ..Default::default() };
    let scene = edgenerf::data::Scene::load(&scene_dir, &opts).unwrap();
    for (i, &v) in scene.split.train.iter().enumerate() {
        let view = &scene.views[v];
        let (w, h) = (view.camera.width, view.camera.height);
        let depth = view.depth.as_ref().expect("creases has ground-truth depth");
        let (scale, shift) = (2.0 + i as f64, 0.1 * i as f64);
        let disparity: Vec<f64> = (0..h * w)
            .map(|p| {
                let t = depth[p as usize] as f64;
                let z = t * scene.ray(v, p % w, p / w).z_scale as f64;
                if t > 0.0 { scale / z + shift } else { f64::NAN }
            })
            .collect();
        edgenerf::data::npy::write_npy_f64(&maps.join(format!("{}.npy", view.name)), &[h as usize, w as usize], &disparity).unwrap();
    }
    // `--mono-depth` on the object preset for captures, whose stereo depth prior is off:
    // the flag turns it on, since the maps are fitted to its sweep.
    let dir = out.path().join("run");
    let (creases, object) = (repo().join("synthetic-scenes/small/creases"), repo().join("tools/configs/sparse-object.toml"));
    let o = edgenerf(&[
        "train", creases.to_str().unwrap(), "--views", "3", "--config", object.to_str().unwrap(), "--out", dir.to_str().unwrap(),
        "--iters", "2", "--no-eval", "--mono-depth", maps.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("this configuration has the stereo depth prior off: priors.stereo_depth = 0.1"), "{t}");
    let cfg = std::fs::read_to_string(dir.join("config.json")).unwrap();
    assert!(cfg.contains(&format!("\"mono_depth_dir\": \"{}\"", maps.display())), "{cfg}");
    let line = |start: &str| t.lines().find(|l| l.starts_with(start)).unwrap_or_else(|| panic!("no '{start}' line in:\n{t}")).to_string();
    let filled: f64 = line("monocular depth (disparity maps").split(" % of the training pixels").next().unwrap().rsplit(' ').next().unwrap().parse().unwrap();
    assert!(filled > 10.0, "the maps fill the pixels the sweep left: {filled} %\n{t}");
    let accuracy = line("monocular targets against the scene's ground-truth depth");
    let median: f64 = accuracy.split("median error ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(median < 2.0, "{accuracy}");
    // Every view's map must be there.
    let first = &scene.views[scene.split.train[0]].name;
    std::fs::remove_file(maps.join(format!("{first}.npy"))).unwrap();
    let mono = format!("priors.mono_depth_dir=\"{}\"", maps.display());
    let o = train_creases_3v(&out.path().join("missing"), 1, &["--set", "priors.stereo_depth=0.1", "--set", &mono]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains(&format!("no monocular depth map for training view {first}")), "{t}");
    // So must the folder.
    let o = train_creases_3v(&out.path().join("nodir"), 1, &["--mono-depth", out.path().join("absent").to_str().unwrap()]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("--mono-depth") && t.contains("no such directory"), "{t}");
}
