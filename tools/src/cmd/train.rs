//! `edgenerf train`: train a field on a scene, with progress, checkpoints, a per-step
//! CSV log, the effective config in the run directory, and a test-view evaluation.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use edgenerf::data::{LoadOptions, Scene};
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::train::{Backend, Checkpoint, RunConfig, Trainer, TrainError};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Args)]
pub struct Args {
    /// Scene directory (Blender/NeRF-synthetic, LLFF or DTU layout).
    scene: PathBuf,
    /// Run directory: config.json, log.csv, checkpoint.safetensors, test renders.
    #[arg(long)]
    out: PathBuf,
    /// Training views of the sparse-view split (default: all).
    #[arg(long, short = 'k')]
    views: Option<usize>,
    /// Optimisation steps (train.iters).
    #[arg(long)]
    iters: Option<u64>,
    /// Field backend.
    #[arg(long, value_parser = ["grid"])]
    backend: Option<String>,
    /// Config file (TOML or JSON) with any subset of the run configuration.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override one setting, e.g. `--set train.rays_per_batch=2048` (repeatable;
    /// applied after --config and the flags above).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Continue from the run directory's checkpoint (its config is used; --iters may
    /// extend the run).
    #[arg(long)]
    resume: bool,
    /// Skip the final test-view evaluation and renders.
    #[arg(long)]
    no_eval: bool,
}

fn build_config(args: &Args) -> anyhow::Result<RunConfig> {
    let mut config = match &args.config {
        Some(path) => RunConfig::from_file(path)?,
        None => RunConfig::default(),
    };
    config.scene.path = args.scene.clone();
    if args.views.is_some() {
        config.scene.views = args.views;
    }
    if let Some(iters) = args.iters {
        config.train.iters = iters;
    }
    if let Some(b) = &args.backend {
        config.backend = match b.as_str() {
            "grid" => Backend::Grid,
            other => bail!("unknown backend {other}"),
        };
    }
    for o in &args.overrides {
        config.set(o)?;
    }
    Ok(config)
}

fn load_scene(config: &RunConfig) -> anyhow::Result<Scene> {
    let mut opts = LoadOptions { views: config.scene.views, ..Default::default() };
    if let Some(bg) = config.scene.background {
        opts.background = bg;
    }
    Scene::load(&config.scene.path, &opts).with_context(|| format!("loading {}", config.scene.path.display()))
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    let ckpt_path = args.out.join("checkpoint.safetensors");
    let gpu = Gpu::new(gpu_opts)?;
    let mut trainer = if args.resume {
        let mut ckpt = Checkpoint::load(&ckpt_path)?;
        if let Some(iters) = args.iters {
            ckpt.config.train.iters = iters;
        }
        let scene = load_scene(&ckpt.config)?;
        Trainer::resume(gpu, scene, ckpt)?
    } else {
        let config = build_config(&args)?;
        let scene = load_scene(&config)?;
        Trainer::new(gpu, scene, config)?
    };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let config = trainer.config().clone();
    std::fs::write(args.out.join("config.json"), config.to_json())?;
    eprintln!(
        "training {} ({} train views, {} test) on {}; {} parameters; run directory {}",
        config.scene.path.display(),
        trainer.scene.split.train.len(),
        trainer.scene.split.test.len(),
        trainer.gpu.adapter().name,
        trainer.model.field.n_params(),
        args.out.display()
    );

    let log_path = args.out.join("log.csv");
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .with_context(|| format!("opening {}", log_path.display()))?;
    if log.metadata()?.len() == 0 {
        writeln!(log, "step,loss,psnr,lr,grad_norm,samples,samples_per_ray,samples_truncated,elapsed_s")?;
    }

    let iters = config.train.iters;
    let bar = ProgressBar::new(iters);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}").unwrap(),
    );
    bar.set_position(trainer.step_count());
    let start = Instant::now();
    let first_step = trainer.step_count();
    let mut psnr_ema = None::<f32>;
    while trainer.step_count() < iters {
        let stats = match trainer.step() {
            Ok(s) => s,
            Err(e @ TrainError::NonFinite { .. }) => {
                bar.abandon();
                let kept = if ckpt_path.is_file() { format!("the last good checkpoint is kept at {}", ckpt_path.display()) } else { "no checkpoint had been written yet".into() };
                bail!("{e}\n{kept}");
            }
            Err(e) => return Err(e.into()),
        };
        let elapsed = start.elapsed().as_secs_f64();
        writeln!(
            log,
            "{},{},{},{},{},{},{},{},{:.3}",
            stats.step, stats.loss, stats.psnr, stats.lr, stats.grad_norm, stats.samples, stats.samples_per_ray, stats.samples_truncated, elapsed
        )?;
        let ema = psnr_ema.map_or(stats.psnr, |p| 0.9 * p + 0.1 * stats.psnr);
        psnr_ema = Some(ema);
        let steps_per_s = (trainer.step_count() - first_step) as f64 / elapsed.max(1e-9);
        bar.set_position(trainer.step_count());
        bar.set_message(format!(
            "loss {:.5} psnr {:.2} | {:.0} samples/ray | {:.2} steps/s",
            stats.loss, ema, stats.samples_per_ray, steps_per_s
        ));
        let every = config.train.checkpoint_every;
        if every > 0 && trainer.step_count() % every == 0 && trainer.step_count() < iters {
            trainer.checkpoint()?.save(&ckpt_path)?;
        }
    }
    bar.finish();
    trainer.checkpoint()?.save(&ckpt_path)?;
    let elapsed = start.elapsed().as_secs_f64();
    eprintln!(
        "trained {} steps in {:.1} s ({:.2} steps/s); checkpoint {}",
        trainer.step_count() - first_step,
        elapsed,
        (trainer.step_count() - first_step) as f64 / elapsed.max(1e-9),
        ckpt_path.display()
    );
    if !args.no_eval {
        crate::cmd::render::evaluate_and_write(&mut trainer, &args.out.join("test"))?;
    }
    Ok(())
}
