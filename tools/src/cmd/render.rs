//! `edgenerf render`: render views of a trained run (RGB, depth, normals, opacity),
//! the loading of a run's model for `render` and `eval` (no optimizer state), and the
//! test-view evaluation shared with `train`.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use edgenerf::data::Scene;
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::train::{Checkpoint, Model};
use indicatif::ProgressBar;

#[derive(clap::Args)]
pub struct Args {
    /// A checkpoint file, or a run directory holding checkpoint.safetensors.
    checkpoint: PathBuf,
    /// Which views: test, train or all.
    #[arg(long, default_value = "test", value_parser = ["test", "train", "all"])]
    split: String,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Scene directory (default: the path recorded in the checkpoint's config).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// The field backend expected in the checkpoint (it records its own; this only
    /// checks, e.g. in scripts comparing backends).
    #[arg(long, value_parser = ["grid", "mlp"])]
    backend: Option<String>,
    /// Sample placement for this render (default: the run's, the occupancy grid).
    /// `uniform` marches every step of each ray: the "without" side of the
    /// empty-space-skipping comparison (same samples where space is occupied).
    #[arg(long, value_parser = ["occupancy", "uniform"])]
    sampler: Option<String>,
    /// Override one setting of the checkpoint's config for this render, e.g.
    /// `--set field.normal_level_weights=[1,1,1,1,1,1,0,0]` (repeatable). Settings
    /// that change the parameters' shapes are refused when the checkpoint loads.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    crate::output::ensure_dir(&args.out, "--out")?;
    let mut run = load_run(&args.checkpoint, args.scene.as_deref(), &args.overrides, gpu_opts)?;
    if let Some(b) = &args.backend {
        let want: edgenerf::train::Backend = b.parse().map_err(anyhow::Error::msg)?;
        let got = run.model.config.backend;
        if got != want {
            bail!("{} was trained with the {} backend, not {b} (--backend {b})", args.checkpoint.display(), got.name());
        }
    }
    if let Some(mode) = &args.sampler {
        run.model.config.sampler.mode = serde_json::from_value(serde_json::Value::String(mode.clone()))?;
    }
    let views = split_views(&run.scene, &args.split)?;
    if args.split == "test" {
        return evaluate_and_write(&run.gpu, &mut run.model, &run.scene, &args.out);
    }
    let bar = ProgressBar::new(views.len() as u64);
    for v in views {
        let r = run.model.render_view(&run.gpu, &run.scene, v)?;
        edgenerf::train::output::write_view(&args.out, &run.scene.views[v].name, &r)?;
        bar.inc(1);
    }
    bar.finish();
    eprintln!("wrote renders to {}", args.out.display());
    Ok(())
}

/// A trained run ready to render: its model (no optimizer state), scene and GPU.
pub struct LoadedRun {
    pub gpu: Gpu,
    pub scene: Scene,
    pub model: Model,
    /// The checkpoint's step.
    pub step: u64,
}

/// The run of a checkpoint (a file, or a run directory holding
/// `checkpoint.safetensors`) on its scene (the path recorded in its config, or
/// `scene`), on the GPU ([`Model::from_checkpoint`]), with the `--set` `overrides`
/// applied to its config. Shared by `render` and `eval`.
pub fn load_run(checkpoint: &Path, scene: Option<&Path>, overrides: &[String], gpu_opts: &GpuOptions) -> anyhow::Result<LoadedRun> {
    let path = if checkpoint.is_dir() { checkpoint.join("checkpoint.safetensors") } else { checkpoint.to_path_buf() };
    let mut ckpt = Checkpoint::load(&path)?;
    if let Some(scene) = scene {
        ckpt.config.scene.path = scene.to_path_buf();
    }
    for o in overrides {
        ckpt.config.set(o)?;
    }
    if !overrides.is_empty() {
        ckpt.config.resolve();
        ckpt.config.validate().map_err(|m| anyhow::anyhow!("configuration: {m}"))?;
    }
    let scene_path = ckpt.config.scene.path.clone();
    let scene = Scene::load(&scene_path, &ckpt.config.scene.load_options())
        .with_context(|| format!("loading the checkpoint's scene {} (pass --scene to point elsewhere)", scene_path.display()))?;
    let gpu = Gpu::new(gpu_opts)?;
    let model = Model::from_checkpoint(&gpu, &scene, &ckpt)?;
    Ok(LoadedRun { gpu, scene, model, step: ckpt.step })
}

/// The view indices of a split name: `test`, `train` or `all`.
pub fn split_views(scene: &Scene, split: &str) -> anyhow::Result<Vec<usize>> {
    Ok(match split {
        "test" => scene.split.test.clone(),
        "train" => scene.split.train.clone(),
        "all" => (0..scene.views.len()).collect(),
        other => bail!("unknown split {other} (test, train or all)"),
    })
}

/// The message for a scene without test views, ending with what to do instead (`hint`).
pub fn no_test_views(scene: &Scene, hint: &str) -> String {
    let files = match scene.format {
        edgenerf::data::SceneFormat::Blender => "no transforms_test.json or transforms_val.json",
        _ => "every view is a training view of this split",
    };
    format!("{} has no test views ({files}), so there is nothing to evaluate; {hint}", scene.root.display())
}

/// Renders the test views and writes them and `metrics.json` under `dir`
/// ([`edgenerf::train::write_evaluation`]), then prints the per-view and mean figures.
pub fn evaluate_and_write(gpu: &Gpu, model: &mut Model, scene: &Scene, dir: &Path) -> anyhow::Result<()> {
    if scene.split.test.is_empty() {
        bail!("{}", no_test_views(scene, "render --split train or --split all instead"));
    }
    let eval = edgenerf::train::write_evaluation(gpu, model, scene, dir)?;
    let fmt = |x: Option<f32>, unit: &str| x.map_or("-".to_string(), |x| format!("{x:.3}{unit}"));
    for e in &eval.per_view {
        let depth = e.geometry.as_ref().and_then(|g| g.depth.as_ref()).and_then(|d| d.all).map(|d| d.abs as f32);
        let normal = e.geometry.as_ref().and_then(|g| g.normal.as_ref()).and_then(|n| n.all).map(|n| n.mean_deg as f32);
        println!(
            "test view {:>3} ({}): PSNR {:.2} dB  SSIM {:.3}  depth error {}  normal error {}",
            e.view,
            scene.views[e.view].name,
            e.psnr,
            e.ssim,
            fmt(depth, ""),
            fmt(normal, " deg")
        );
    }
    println!(
        "test PSNR {:.2} dB, SSIM {:.3} (mean over {} views); {:.1} samples per ray",
        eval.mean_psnr,
        eval.mean_ssim,
        eval.per_view.len(),
        eval.mean_samples_per_ray,
    );
    if eval.mean_depth_abs_error.is_some() || eval.mean_normal_angle_deg.is_some() {
        println!(
            "geometry vs ground truth: depth error {} (non-edge {}, within the GT edge band {}); normal error {} (non-edge {}, edge {}); depth boundary error acc {} comp {} px",
            fmt(eval.mean_depth_abs_error, ""),
            fmt(eval.mean_depth_abs_error_non_edge, ""),
            fmt(eval.mean_depth_abs_error_edge, ""),
            fmt(eval.mean_normal_angle_deg, " deg"),
            fmt(eval.mean_normal_angle_deg_non_edge, " deg"),
            fmt(eval.mean_normal_angle_deg_edge, " deg"),
            fmt(eval.mean_dbe_accuracy, ""),
            fmt(eval.mean_dbe_completeness, ""),
        );
    }
    Ok(())
}
