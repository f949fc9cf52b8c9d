//! `edgenerf speed`: training speed on the adapter in use, per stage of a step, for the
//! demo and the sparse-view preset (or any scene and config): steps/s of plain steps,
//! then the same steps profiled stage by stage ([`edgenerf::train::profile`]), field
//! samples per second of the forward and backward passes, as a table and as JSON; with
//! `--kernels`, the wall time of every kernel timed on its own
//! ([`edgenerf::gpu::KernelTimes`]). The timed steps are those of the rest of a run:
//! every regularizer at full weight and every grid level active from the first step,
//! with the config's `[with_cameras_inside]` and `[[with_views]]` tables applied to the
//! scene as `train` applies them.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::train::{RunConfig, Stage, StageTimes, Trainer};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Args)]
pub struct Args {
    /// What to time: the demo (smooth, all views, tools/configs/demo.toml), the
    /// sparse-view preset (creases, 3 views, tools/configs/sparse-small.toml), or both.
    /// Paths are relative to the repository root; use --scene/--config for others.
    #[arg(long, value_parser = ["demo", "sparse-small", "all"], default_value = "all", conflicts_with = "scene")]
    preset: String,
    /// A scene of your own (with --config and --views).
    #[arg(long, requires = "config")]
    scene: Option<PathBuf>,
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, short = 'k')]
    views: Option<usize>,
    /// Steps before timing (the occupancy grid's warm-up and the sample capacity settle).
    #[arg(long, default_value_t = 20)]
    warmup: u64,
    /// Steps timed plain, then as many profiled.
    #[arg(long, default_value_t = 30)]
    steps: u64,
    /// Then as many steps again with every kernel timed on its own (slower; the waits
    /// serialize the step): the slowest kernels per step, and all of them in the JSON.
    #[arg(long)]
    kernels: bool,
    /// The sampler's visibility pass (`sampler.visibility`) in the timed steps: as the
    /// config has it, off, on, or each case timed without and then with it.
    #[arg(long, value_parser = ["config", "off", "on", "both"], default_value = "config")]
    visibility: String,
    /// With the pass on: drop samples whose opacity is below this
    /// (`sampler.visibility.min_alpha`; default: the config's).
    #[arg(long)]
    min_alpha: Option<f32>,
    /// With the pass on: the most opacity a ray may lose to `--min-alpha`
    /// (`sampler.visibility.max_dropped_opacity`; default: the config's).
    #[arg(long)]
    max_dropped_opacity: Option<f32>,
    /// Directory for speed.json.
    #[arg(long, default_value = "runs/speed")]
    out: PathBuf,
}

/// One timed configuration.
struct Case {
    name: String,
    scene: PathBuf,
    config: PathBuf,
    views: Option<usize>,
    /// Whether the visibility pass runs (`None`: as the config says).
    visibility: Option<bool>,
}

#[derive(serde::Serialize)]
struct StageRow {
    stage: &'static str,
    ms_per_step: f64,
    share: f64,
}

#[derive(serde::Serialize)]
struct CaseResult {
    name: String,
    scene: String,
    config: String,
    /// The assignments of the config's `[with_cameras_inside]` and `[[with_views]]`
    /// tables that this scene and view count applied (as `train` applies them).
    tables_applied: Vec<String>,
    train_views: usize,
    rays_per_step: u32,
    steps: u64,
    steps_per_s: f64,
    /// Training rays per second of the plain steps (every ray a step renders).
    rays_per_s: f64,
    /// Whether the visibility pass ran, and the mean samples per ray of the plain steps:
    /// those the field ran on and those the march placed.
    visibility: bool,
    samples_per_ray: f64,
    marched_samples_per_ray: f64,
    ms_per_step: f64,
    /// Command buffers submitted per plain step: 1, plus an occupancy grid update's
    /// own every `sampler.update_interval` steps.
    submissions_per_step: f64,
    /// Of `ms_per_step`, the host's time in the driver's submission and in waits for
    /// the GPU (`gpu::DriverTime`); the rest is the host's own work (drawing the batch,
    /// recording the commands).
    submit_ms_per_step: f64,
    wait_ms_per_step: f64,
    /// Bind groups created per plain step (`gpu::bind_cache`): none once the step's
    /// buffers have settled, as every step binds the same ones.
    bind_groups_per_step: f64,
    profiled_ms_per_step: f64,
    samples_per_step: f64,
    field_forward_samples_per_s: f64,
    field_backward_samples_per_s: f64,
    stages: Vec<StageRow>,
    /// With `--kernels`: every kernel's wall time per step, the slowest first.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    kernels: Vec<KernelRow>,
    /// How `kernels` were timed: the GPU's timestamps around each dispatch, or the wall
    /// time of its submission and wait (`gpu::kernel_timing`).
    #[serde(skip_serializing_if = "Option::is_none")]
    kernel_timer: Option<&'static str>,
}

#[derive(serde::Serialize)]
struct KernelRow {
    kernel: String,
    ms_per_step: f64,
    dispatches_per_step: f64,
    share: f64,
}

#[derive(serde::Serialize)]
struct Report {
    adapter: String,
    backend: String,
    warmup: u64,
    cases: Vec<CaseResult>,
}

fn cases(args: &Args) -> Vec<Case> {
    let base = if let (Some(scene), Some(config)) = (&args.scene, &args.config) {
        vec![Case { name: "custom".into(), scene: scene.clone(), config: config.clone(), views: args.views, visibility: None }]
    } else {
        let demo = Case {
            name: "demo".into(),
            scene: "synthetic-scenes/small/smooth".into(),
            config: "tools/configs/demo.toml".into(),
            views: None,
            visibility: None,
        };
        let sparse = Case {
            name: "sparse-small".into(),
            scene: "synthetic-scenes/small/creases".into(),
            config: "tools/configs/sparse-small.toml".into(),
            views: Some(3),
            visibility: None,
        };
        match args.preset.as_str() {
            "demo" => vec![demo],
            "sparse-small" => vec![sparse],
            _ => vec![demo, sparse],
        }
    };
    let with = |c: &Case, on: bool| Case {
        name: if args.visibility == "both" && on { format!("{} + visibility", c.name) } else { c.name.clone() },
        scene: c.scene.clone(),
        config: c.config.clone(),
        views: c.views,
        visibility: Some(on),
    };
    match args.visibility.as_str() {
        "off" => base.iter().map(|c| with(c, false)).collect(),
        "on" => base.iter().map(|c| with(c, true)).collect(),
        "both" => base.iter().flat_map(|c| [with(c, false), with(c, true)]).collect(),
        _ => base,
    }
}

fn time_case(gpu: &Gpu, case: &Case, args: &Args) -> anyhow::Result<CaseResult> {
    for p in [&case.scene, &case.config] {
        if !p.exists() {
            bail!("{} not found: run `edgenerf speed` from the repository root, or pass --scene and --config", p.display());
        }
    }
    let mut config = RunConfig::from_file_for(&case.config, None)?;
    config.scene.path = case.scene.clone();
    config.scene.views = case.views;
    let tables_applied = super::train::apply_scene_tables(&mut config, &case.config.display().to_string())?;
    // Every term of the config at full weight and every grid level active from the
    // first step: the timed steps are those of the rest of a run (a preset's
    // regularizer schedule starts the terms later, its level annealing the fine levels).
    config.reg.start_step = 0;
    config.reg.warmup_steps = 0;
    config.train.level_anneal = None;
    let visibility = &mut config.sampler.visibility;
    if let Some(on) = case.visibility {
        visibility.train = on;
        visibility.start_step = 0;
    }
    if let Some(a) = args.min_alpha {
        visibility.min_alpha = a;
    }
    if let Some(o) = args.max_dropped_opacity {
        visibility.max_dropped_opacity = o;
    }
    config.resolve();
    let scene = super::train::load_scene(&config)?;
    let mut trainer = Trainer::new(gpu.clone(), scene, config)?;
    // Plain and profiled steps, and with --kernels as many again timed kernel by kernel.
    let timed_passes = if args.kernels { 3 } else { 2 };
    let bar = ProgressBar::new(args.warmup + timed_passes * args.steps);
    bar.set_style(ProgressStyle::with_template("{prefix:>12} {bar:30} {pos}/{len} {msg}").unwrap());
    bar.set_prefix(case.name.clone());
    bar.set_message(super::train::first_step_message(gpu));
    bar.enable_steady_tick(std::time::Duration::from_secs(1));
    // Steps as a run takes them: each read back while the next one runs, the phase's
    // last one drained (`drain`), so a phase's time covers its steps' GPU work.
    let step = |trainer: &mut Trainer, phase: &str, drain: bool| -> anyhow::Result<Vec<edgenerf::train::StepStats>> {
        let read_back = trainer.step_pipelined(drain).with_context(|| format!("{}: {phase} step", case.name))?;
        // The first step's message stays until that step is read back (its kernels built).
        if !read_back.is_empty() {
            bar.set_message(phase.to_string());
        }
        bar.inc(1);
        Ok(read_back)
    };
    for i in 0..args.warmup {
        step(&mut trainer, "warm-up", i + 1 == args.warmup)?;
    }
    let (start, submitted, driver) = (Instant::now(), gpu.submissions(), gpu.driver_time());
    let bind_groups = gpu.bind_groups_made();
    let mut plain = Vec::new();
    for i in 0..args.steps {
        plain.extend(step(&mut trainer, "plain", i + 1 == args.steps)?);
    }
    let mean_of = |f: fn(&edgenerf::train::StepStats) -> f32| plain.iter().map(|s| f(s) as f64).sum::<f64>() / plain.len().max(1) as f64;
    let plain_s = start.elapsed().as_secs_f64();
    let submissions = gpu.submissions() - submitted;
    let driver_end = gpu.driver_time();
    let bind_groups = gpu.bind_groups_made() - bind_groups;
    let per_step = |x: f64| x / args.steps.max(1) as f64;
    let per_step_ms = |d: std::time::Duration| per_step(1e3 * d.as_secs_f64());
    trainer.set_profiling(true);
    for _ in 0..args.steps {
        step(&mut trainer, "profiled", true)?;
    }
    let times: StageTimes = trainer.stage_times().cloned().expect("profiling is on");
    trainer.set_profiling(false);
    let kernels = if args.kernels {
        gpu.set_kernel_timing(true);
        for _ in 0..args.steps {
            step(&mut trainer, "kernels timed", true)?;
        }
        let times = gpu.kernel_times().expect("kernel timing is on");
        gpu.set_kernel_timing(false);
        let (n, total) = (args.steps as f64, times.total_seconds().max(1e-12));
        times
            .totals()
            .into_iter()
            .map(|k| KernelRow {
                ms_per_step: 1e3 * k.seconds / n,
                dispatches_per_step: k.dispatches as f64 / n,
                share: k.seconds / total,
                kernel: k.kernel,
            })
            .collect()
    } else {
        Vec::new()
    };
    bar.finish_and_clear();
    let n = times.steps.max(1) as f64;
    let total_s = times.total();
    let per_s = |samples: u64, seconds: f64| samples as f64 / seconds.max(1e-12);
    Ok(CaseResult {
        name: case.name.clone(),
        scene: case.scene.display().to_string(),
        config: case.config.display().to_string(),
        tables_applied,
        train_views: trainer.scene.split.train.len(),
        rays_per_step: trainer.config().train.rays_per_batch,
        steps: args.steps,
        steps_per_s: args.steps as f64 / plain_s.max(1e-12),
        rays_per_s: trainer.rays_per_step() as f64 * args.steps as f64 / plain_s.max(1e-12),
        visibility: trainer.config().sampler.visibility.training_rule_at(trainer.step_count()).is_some(),
        samples_per_ray: mean_of(|s| s.samples_per_ray),
        marched_samples_per_ray: mean_of(|s| s.marched_samples_per_ray),
        ms_per_step: per_step(1e3 * plain_s),
        submissions_per_step: per_step(submissions as f64),
        submit_ms_per_step: per_step_ms(driver_end.submit - driver.submit),
        wait_ms_per_step: per_step_ms(driver_end.wait - driver.wait),
        bind_groups_per_step: per_step(bind_groups as f64),
        profiled_ms_per_step: 1e3 * total_s / n,
        samples_per_step: times.field_samples as f64 / n,
        field_forward_samples_per_s: per_s(times.field_samples, times.of(Stage::FieldForward)),
        field_backward_samples_per_s: per_s(times.field_samples, times.of(Stage::FieldBackward)),
        stages: Stage::ALL
            .iter()
            .map(|&s| StageRow { stage: s.name(), ms_per_step: 1e3 * times.of(s) / n, share: times.of(s) / total_s.max(1e-12) })
            .collect(),
        kernel_timer: args.kernels.then_some(if gpu.adapter().timestamps {
            "GPU timestamps"
        } else {
            "wall time of each dispatch's submission and wait"
        }),
        kernels,
    })
}

fn print_case(r: &CaseResult) {
    println!(
        "{} ({}, {} training views, {} rays/step, {:.0} field samples/step)",
        r.name, r.scene, r.train_views, r.rays_per_step, r.samples_per_step
    );
    println!(
        "  plain: {:.2} steps/s ({:.1} ms/step, {:.2} submissions/step); profiled stage by stage: {:.1} ms/step",
        r.steps_per_s, r.ms_per_step, r.submissions_per_step, r.profiled_ms_per_step
    );
    println!(
        "  training rays/s: {:.0}; samples per ray: {:.1} through the field, {:.1} marched (visibility pass {})",
        r.rays_per_s,
        r.samples_per_ray,
        r.marched_samples_per_ray,
        if r.visibility { "on" } else { "off" }
    );
    println!(
        "  host per plain step: {:.2} ms submitting, {:.2} ms waiting for the GPU, {:.2} ms its own work; {:.1} bind groups made",
        r.submit_ms_per_step,
        r.wait_ms_per_step,
        (r.ms_per_step - r.submit_ms_per_step - r.wait_ms_per_step).max(0.0),
        r.bind_groups_per_step
    );
    println!("  {:<18} {:>9} {:>6}", "stage", "ms/step", "share");
    for s in &r.stages {
        println!("  {:<18} {:>9.2} {:>5.1}%", s.stage, s.ms_per_step, 100.0 * s.share);
    }
    println!(
        "  field samples/s: forward {:.3} M, backward {:.3} M",
        r.field_forward_samples_per_s / 1e6,
        r.field_backward_samples_per_s / 1e6
    );
    if !r.kernels.is_empty() {
        let total: f64 = r.kernels.iter().map(|k| k.ms_per_step).sum();
        let timer = r.kernel_timer.unwrap_or("wall time");
        println!("  kernels timed one by one ({timer}): {total:.1} ms/step; the slowest (all in speed.json):");
        println!("  {:<44} {:>9} {:>6} {:>10}", "kernel", "ms/step", "share", "launches");
        for k in r.kernels.iter().take(KERNELS_SHOWN) {
            println!("  {:<44} {:>9.2} {:>5.1}% {:>10.1}", k.kernel, k.ms_per_step, 100.0 * k.share, k.dispatches_per_step);
        }
    }
}

/// Kernels listed in the table of `--kernels` (speed.json has every one).
const KERNELS_SHOWN: usize = 15;

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    if args.steps == 0 {
        bail!("--steps must be at least 1");
    }
    crate::output::ensure_dir(&args.out, "--out")?;
    let gpu = Gpu::new(gpu_opts)?;
    let adapter = gpu.adapter().clone();
    println!("adapter: {} ({}, {})", adapter.name, adapter.backend, adapter.driver);
    let mut results = Vec::new();
    for case in cases(&args) {
        let r = time_case(&gpu, &case, &args)?;
        print_case(&r);
        results.push(r);
    }
    let report = Report { adapter: adapter.name.clone(), backend: adapter.backend.clone(), warmup: args.warmup, cases: results };
    let path = args.out.join("speed.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?).with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}
