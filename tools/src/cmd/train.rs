//! `edgenerf train`: the front end of a training run. Parses the flags into a
//! [`RunConfig`], prepares the run directory (refusing an `--out` in the scene or
//! holding its inputs, taking the directory's lock so that one run writes there at a
//! time, refusing to mix runs), loads the scene and edge masks, then hands the loop to
//! the engine ([`run::train_run`]: checkpoints, `log.csv`, `config.json`, the time
//! limit) with a progress bar and Ctrl-C, SIGTERM and SIGHUP as its observer, and ends
//! with the test-view evaluation ([`crate::cmd::render::evaluate_and_write`]).

use std::path::PathBuf;

use anyhow::{Context, bail};
use edgenerf::data::{LoadOptions, Scene, SceneFormat};
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::loss::RegVariant;
use edgenerf::train::{Backend, Checkpoint, RunConfig, RunEnd, RunObserver, StepStats, TrainError, Trainer, run};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    input: super::SceneArgs,
    /// Run directory: config.json, log.csv, checkpoint.safetensors, test renders.
    #[arg(long)]
    out: PathBuf,
    /// Optimisation steps (train.iters).
    #[arg(long)]
    iters: Option<u64>,
    /// Stop once training has run this many seconds (train.max_seconds; the
    /// learning-rate schedule still follows --iters): equal-wall-time comparisons.
    #[arg(long, allow_negative_numbers = true, value_name = "SECONDS")]
    max_seconds: Option<f64>,
    /// Field backend: the hash grid, or the mip-NeRF MLP (whose defaults include
    /// RegNeRF's optimizer and schedule). Recorded in the checkpoint.
    #[arg(long, value_parser = ["grid", "mlp"])]
    backend: Option<String>,
    /// Switch off the edge-guided depth terms (reg.depth = false): L_z, and with it the
    /// planarity L_pl and the cross-view reprojection L_rp.
    #[arg(long)]
    no_depth_reg: bool,
    /// Switch off the edge-guided normal terms (reg.normal = false): L_n, and with it
    /// the depth-normal consistency L_dn.
    #[arg(long)]
    no_normal_reg: bool,
    /// `paper`: the paper's equations; `official`: the authors' code (stop-gradient
    /// means, squared normal error without hinge, lambda3 0.01).
    #[arg(long, value_parser = ["paper", "official"])]
    reg_variant: Option<String>,
    /// lambda2, the weight of L_z (reg.lambda_depth; paper 0.1).
    #[arg(long, allow_negative_numbers = true)]
    lambda_depth: Option<f32>,
    /// lambda3, the weight of L_n (reg.lambda_normal; paper 0.1, 0.001 on DTU; official 0.01).
    #[arg(long, allow_negative_numbers = true)]
    lambda_normal: Option<f32>,
    /// RegNeRF's depth smoothness: total variation of the depth of 8x8 patches rendered
    /// from random unobserved poses (regnerf.depth_tv; weights regnerf.tv_weight*).
    #[arg(long)]
    regnerf_depth_tv: bool,
    /// RegNeRF's sample-space annealing: ray ranges start around their midpoint and
    /// widen to the full range (regnerf.anneal; regnerf.anneal_steps/_start/_mid).
    #[arg(long)]
    anneal_sample_space: bool,
    /// Edge maps for the regularizers' masks (edges.* in the config).
    #[command(flatten)]
    edges: crate::cmd::edges::EdgeArgs,
    /// A folder of monocular depth maps, one per training image (`<image stem>.npy` or a
    /// grey `.png`, relative disparity as Depth Anything or MiDaS write it): each is
    /// fitted to the stereo sweep and gives the pixels the sweep left a depth target
    /// (priors.mono_depth_dir; turns the stereo depth prior on at 0.1 where the config
    /// has it off; see docs/guide/configuration.md).
    #[arg(long, value_name = "DIR")]
    mono_depth: Option<PathBuf>,
    /// Config file (TOML or JSON) with any subset of the run configuration. Without it,
    /// a sparse-view run (--views) of the grid uses the shipped preset for the scene's
    /// format (LLFF tools/configs/sparse-llff.toml, DTU sparse-dtu.toml, Blender
    /// sparse-small.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Without --config, use the engine's defaults (the paper's equations and weights,
    /// unscaled) instead of the sparse-view preset.
    #[arg(long, conflicts_with = "config")]
    no_preset: bool,
    /// Override one setting, e.g. `--set train.rays_per_batch=2048` (repeatable;
    /// applied after --config and the flags above).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Continue from the run directory's checkpoint. Its config is used: only --iters
    /// (to extend the run), --max-seconds and --no-eval may change; flags that would
    /// change the run are refused.
    #[arg(long, conflicts_with_all = [
        "config", "no_preset", "overrides", "backend", "views", "llff_factor", "no_depth_reg", "no_normal_reg", "reg_variant",
        "lambda_depth", "lambda_normal", "regnerf_depth_tv", "anneal_sample_space", "edges", "mono_depth",
        "edge_polarity", "tau_e", "no_dilate", "canny_sigma", "canny_low", "canny_high", "overwrite",
    ])]
    resume: bool,
    /// Replace the run already in --out (its checkpoint, config.json, log.csv and test
    /// renders are deleted first). Without it, `train` refuses a directory holding a run.
    #[arg(long)]
    overwrite: bool,
    /// Skip the final test-view evaluation and renders.
    #[arg(long)]
    no_eval: bool,
}

/// The stereo depth prior's weight `--mono-depth` turns it on at where a config has it
/// off (the inside-out presets' and DTU's weight).
const MONO_STEREO_DEPTH: f32 = 0.1;

fn build_config(args: &Args) -> anyhow::Result<RunConfig> {
    // The backend first: its defaults (the MLP's RegNeRF optimizer) sit under the file.
    let backend = args.backend.as_deref().map(str::parse::<Backend>).transpose().map_err(anyhow::Error::msg)?;
    // `source`: the file the config came from, named by the [[with_views]] messages.
    let (mut config, source) = match (&args.config, default_preset(args, backend)?) {
        (Some(path), _) => (RunConfig::from_file_for(path, backend)?, path.display().to_string()),
        (None, Some(preset)) => {
            (RunConfig::from_text_for(preset.text, true, preset.path, backend)?, preset.path.to_string())
        }
        (None, None) => (RunConfig::defaults_for(backend.unwrap_or_default()), "the engine defaults".to_string()),
    };
    // Absolute, so that `render`/`eval` of the checkpoint work from any directory.
    config.scene.path = absolute_scene(&args.input.scene)?;
    if args.input.views.is_some() {
        config.scene.views = args.input.views;
    }
    if args.input.llff_factor.is_some() {
        config.scene.llff_factor = args.input.llff_factor;
    }
    // The preset's settings for more views and for inside-out captures, under every
    // option of the command line.
    apply_scene_tables(&mut config, &source)?;
    if let Some(iters) = args.iters {
        config.train.iters = iters;
    }
    if args.max_seconds.is_some() {
        config.train.max_seconds = args.max_seconds;
    }
    args.edges.apply(&mut config.edges);
    if args.no_depth_reg {
        config.reg.depth = false;
    }
    if args.no_normal_reg {
        config.reg.normal = false;
    }
    if let Some(v) = &args.reg_variant {
        config.reg.variant = if v == "official" { RegVariant::Official } else { RegVariant::Paper };
    }
    if let Some(l) = args.lambda_depth {
        config.reg.lambda_depth = l;
    }
    if args.lambda_normal.is_some() {
        config.reg.lambda_normal = args.lambda_normal;
    }
    if args.regnerf_depth_tv {
        config.regnerf.depth_tv = true;
    }
    if args.anneal_sample_space {
        config.regnerf.anneal = true;
    }
    if let Some(dir) = &args.mono_depth {
        if !dir.is_dir() {
            bail!("--mono-depth {}: no such directory; write one monocular depth map per training image there (<image stem>.npy or .png)", dir.display());
        }
        // Absolute, as the scene's path: config.json names the maps wherever it is read.
        config.priors.mono_depth_dir = Some(std::path::absolute(dir)?);
        if config.priors.stereo_depth <= 0.0 {
            config.priors.stereo_depth = MONO_STEREO_DEPTH;
            eprintln!(
                "--mono-depth: the maps are fitted to the stereo sweep's depths, and this configuration has the stereo depth prior off: priors.stereo_depth = {MONO_STEREO_DEPTH} (the inside-out presets' weight)"
            );
        }
    }
    // Before any --set: `set` goes through JSON, which cannot hold a non-UTF-8 path
    // (the error blamed the --set instead of the path) nor a NaN (`--lambda-normal nan`
    // became null, i.e. the default, without a word).
    config.check_paths().map_err(anyhow::Error::msg)?;
    let mut resolved = config.clone();
    resolved.resolve();
    resolved.validate().map_err(|m| anyhow::anyhow!("configuration: {m}"))?;
    for o in &args.overrides {
        config.set(o)?;
    }
    config.resolve();
    config.check_paths().map_err(anyhow::Error::msg)?;
    // Every range before any work, whether or not this run reads the value (a --tau-e
    // 300 on a run without edge masks passed unnoticed).
    config.validate().map_err(|m| anyhow::anyhow!("configuration: {m}"))?;
    if config.train.iters == 0 {
        bail!("train.iters = 0 (--iters): nothing to train; ask for at least 1 step");
    }
    if let Some(dir) = config.edges.dir.as_ref().filter(|_| config.edges.source == edgenerf::edges::EdgeSource::External)
        && !dir.is_dir()
    {
        bail!("--edges {}: no such directory of edge maps (or pass canny or none)", dir.display());
    }
    Ok(config)
}

/// The shipped preset a run without `--config` uses: sparse-view runs (`--views`) of
/// the grid on a scene format that has one, unless `--no-preset` (announced on stderr,
/// so that nobody mistakes it for the engine defaults).
fn default_preset(args: &Args, backend: Option<Backend>) -> anyhow::Result<Option<crate::presets::Preset>> {
    if args.config.is_some() || args.no_preset || args.input.views.is_none() || backend.unwrap_or_default() != Backend::Grid {
        return Ok(None);
    }
    // A scene that cannot be read gets its error from loading, as without a preset.
    let Ok(format) = edgenerf::data::detect_format(&args.input.scene) else {
        return Ok(None);
    };
    // nerfstudio and COLMAP captures: the layout they load as (cameras only) decides.
    let forward_facing = matches!(format, SceneFormat::Nerfstudio | SceneFormat::Colmap) && {
        let opts = LoadOptions { views: args.input.views, llff_factor: args.input.llff_factor, load_images: false, ..Default::default() };
        Scene::load(&args.input.scene, &opts).is_ok_and(|s| s.ndc.is_some())
    };
    let preset = crate::presets::sparse_preset(format, forward_facing);
    let layout = match format {
        SceneFormat::Nerfstudio | SceneFormat::Colmap if forward_facing => " (forward-facing)",
        SceneFormat::Nerfstudio | SceneFormat::Colmap => " (object-centric)",
        _ => "",
    };
    eprintln!("no --config: using the sparse-view preset {} for this {format}{layout} scene (--no-preset for the engine defaults)", preset.path);
    Ok(Some(preset))
}

/// Refuses, from the image sizes and cameras and before the edge detection, a scene too
/// large for the reprojection term's one storage binding (a 6000x6000 capture was
/// refused only after 48 s of edge detection) or a stereo sweep it cannot take (the
/// planes across up on NDC rays).
fn check_terms_fit_scene(gpu: &Gpu, config: &RunConfig, scene: &Scene) -> anyhow::Result<()> {
    if config.reg.reprojection_on() && config.train.batch == edgenerf::train::BatchKind::Patches {
        edgenerf::train::pipeline::check_reprojection_fits(scene, gpu.limits().max_storage_buffer_binding_size)?;
    }
    if config.priors.mono_depth_dir.is_some() {
        edgenerf::train::mono_depth::check_scene(scene).map_err(anyhow::Error::msg)?;
    }
    if config.priors.stereo_on() {
        edgenerf::train::stereo::check_scene(scene, config.priors.stereo_horizontal).map_err(|m| anyhow::anyhow!("configuration: {m}"))?;
    }
    Ok(())
}

/// Applies a config's `[with_cameras_inside]` and `[[with_views]]` tables for its scene
/// (`config.scene`, with `--views` already in `scene.views`), printing what each set,
/// and returns every assignment applied. `train` and `speed` both run it, so that
/// `speed` times the configuration a run of the same scene and views trains. The
/// scene's cameras are loaded (without images) once, and only if a table needs them.
pub(crate) fn apply_scene_tables(config: &mut RunConfig, source: &str) -> anyhow::Result<Vec<String>> {
    let mut all = Vec::new();
    let mut cameras = None;
    if config.with_cameras_inside.is_some() {
        let scene = cameras.insert(load_scene_cameras(config)?);
        let applied = config.apply_with_cameras_inside(scene.cameras_inside_box(), source)?;
        if !applied.is_empty() {
            eprintln!("every training camera stands inside the scene box: [with_cameras_inside] in {source} sets {}", applied.join(", "));
        }
        all.extend(applied);
    }
    if !config.with_views.is_empty() {
        // `--views` is in `scene.views` by now, as is a config file's own.
        let views = match (config.scene.views, cameras) {
            (Some(k), _) => k,
            (None, Some(scene)) => scene.split.train.len(),
            (None, None) => load_scene_cameras(config)?.split.train.len(),
        };
        let applied = config.apply_with_views(views, source)?;
        if !applied.is_empty() {
            eprintln!("{views} training views: [[with_views]] in {source} sets {}", applied.join(", "));
        }
        all.extend(applied);
    }
    Ok(all)
}

/// The scene's cameras and splits without its images (how many training views a run has).
fn load_scene_cameras(config: &RunConfig) -> anyhow::Result<Scene> {
    let opts = LoadOptions { load_images: false, ..config.scene.load_options() };
    Scene::load(&config.scene.path, &opts).with_context(|| format!("loading {}", config.scene.path.display()))
}

pub(crate) fn load_scene(config: &RunConfig) -> anyhow::Result<Scene> {
    Scene::load(&config.scene.path, &config.scene.load_options()).with_context(|| format!("loading {}", config.scene.path.display()))
}

/// The training views' edge masks, cached in `<out>/edges/` (PNG per view, reused while
/// the edge settings and images are unchanged); `None` when the run reads no masks.
fn edge_masks(args: &Args, config: &RunConfig, scene: &Scene) -> anyhow::Result<Option<Vec<edgenerf::edges::EdgeMask>>> {
    if !Trainer::needs_edge_masks(config, scene) {
        return Ok(None);
    }
    let dir = args.out.join("edges");
    let masks = edgenerf::edges::edge_masks_cached(scene, &scene.split.train, &config.edges, &dir)
        .with_context(|| format!("edge masks of the training views (cache {})", dir.display()))?;
    let mean_edge = masks.iter().map(|m| m.edge_fraction()).sum::<f32>() / masks.len().max(1) as f32;
    eprintln!("edge masks: {} views, {:.1}% edge pixels on average, in {}", masks.len(), 100.0 * mean_edge, dir.display());
    Ok(Some(masks))
}

/// The stereo priors' targets as images, per training view: `<view>_depth.png` (turbo,
/// near blue to far red over the view's own range; black: no target) and
/// `<view>_confidence.png` (grey: white a confirmed depth, darker a filled one).
fn write_stereo_maps(trainer: &Trainer, dir: &std::path::Path) -> anyhow::Result<()> {
    let Some(maps) = trainer.stereo_targets() else { return Ok(()) };
    std::fs::create_dir_all(dir)?;
    for (view, targets) in trainer.scene.views.iter().zip(maps) {
        let Some(targets) = targets else { continue };
        let (w, h) = (view.camera.width, view.camera.height);
        let depth: Vec<f32> = targets.iter().map(|t| t[0]).collect();
        let valid: Vec<bool> = targets.iter().map(|t| t[1] > 0.0).collect();
        let stem = std::path::Path::new(&view.name).file_stem().map_or_else(|| view.name.clone(), |s| s.to_string_lossy().into_owned());
        edgenerf::viz::depth_image(w, h, &depth, Some(&valid)).0.save_png(dir.join(format!("{stem}_depth.png")))?;
        let confidence: Vec<f32> = targets.iter().map(|t| t[1]).collect();
        edgenerf::viz::grey_image(w, h, &confidence).save_png(dir.join(format!("{stem}_confidence.png")))?;
    }
    Ok(())
}

/// The final evaluation needs test views: without them, refuse before training (a
/// scene without `transforms_test.json` trained, then failed with a bare "No such file
/// or directory").
fn check_test_views(args: &Args, scene: &Scene) -> anyhow::Result<()> {
    if !args.no_eval && scene.split.test.is_empty() {
        bail!("{}", crate::cmd::render::no_test_views(scene, "pass --no-eval to train without the final evaluation"));
    }
    Ok(())
}

/// Training views that cannot teach a field anything are refused before any work
/// (they trained with 0 samples or on empty targets and exited 0): every training
/// camera at one and the same pose, or every training image fully transparent.
fn check_training_views(scene: &Scene) -> anyhow::Result<()> {
    let train: Vec<&edgenerf::data::View> = scene.split.train.iter().map(|&v| &scene.views[v]).collect();
    if train.len() >= 2 && train.iter().all(|v| v.camera.c2w.abs_diff_eq(train[0].camera.c2w, 1e-6)) {
        bail!(
            "every training view of {} ({}) has the same camera pose, so no depth can be learned from them; check \
             the poses (transform_matrix) of its frames",
            scene.root.display(),
            train.len()
        );
    }
    let transparent = |v: &&edgenerf::data::View| v.alpha.as_ref().is_some_and(|a| a.iter().all(|&x| x == 0.0));
    if !train.is_empty() && train.iter().all(transparent) {
        bail!(
            "every training image of {} is fully transparent (alpha 0 in every pixel), so there is nothing to \
             learn; check the images' alpha channel (an export that dropped the object?)",
            scene.root.display()
        );
    }
    Ok(())
}

/// What a run writes into its directory; any of them there means the directory holds a
/// run (an empty directory, or one holding only other files such as a suite's
/// `train.log`, is free).
const RUN_FILES: [&str; 4] = ["checkpoint.safetensors", "config.json", "log.csv", "test"];

/// Makes `--out` ready: refuses a file, takes the run directory's lock (one writer per
/// directory: two runs started together into one `--out` interleaved their logs and
/// mixed their files), refuses a directory holding a run unless `--resume` or
/// `--overwrite` says what to do with it (before this check, a second `train` into a
/// finished run replaced its checkpoint and appended to its log), deletes the old
/// run's files with `--overwrite`. The lock lives as long as the value returned.
fn prepare_run_dir(args: &Args) -> anyhow::Result<crate::output::RunLock> {
    if args.resume {
        if !args.out.join("checkpoint.safetensors").is_file() {
            let present: Vec<&str> = RUN_FILES.into_iter().filter(|f| args.out.join(f).exists()).collect();
            if present.is_empty() {
                bail!(
                    "--resume: {} holds no checkpoint.safetensors to continue from; train without --resume to start a \
                     run there",
                    args.out.display()
                );
            }
            bail!(
                "--resume: {} holds a run that stopped before its first checkpoint ({} but no \
                 checkpoint.safetensors), so there is nothing to continue from; start it again with --overwrite \
                 (train.checkpoint_every sets how often a run saves one)",
                args.out.display(),
                present.join(", ")
            );
        }
        return crate::output::lock_run_dir(&args.out);
    }
    crate::output::ensure_dir(&args.out, "--out")?;
    let lock = crate::output::lock_run_dir(&args.out)?;
    let present: Vec<&str> = RUN_FILES.into_iter().filter(|f| args.out.join(f).exists()).collect();
    if !present.is_empty() {
        if !args.overwrite {
            bail!(
                "{} already holds a run ({}); nothing was changed. Pass --resume to continue it, --overwrite to \
                 replace it, or choose another --out",
                args.out.display(),
                present.join(", ")
            );
        }
        for f in present {
            let p = args.out.join(f);
            let removed = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
            removed.with_context(|| format!("--overwrite: removing {}", p.display()))?;
        }
    }
    Ok(lock)
}

/// Refuses an `--out` that is the scene directory or the edge maps' directory, lies
/// inside one, or would hold the scene where the run writes (`--out PARENT` of a scene
/// at `PARENT/test`): `train SCENE --out SCENE --overwrite` deleted the scene's test
/// views.
fn check_out_apart_from_inputs(args: &Args, config: Option<&RunConfig>) -> anyhow::Result<()> {
    let scene = config.map_or(args.input.scene.as_path(), |c| c.scene.path.as_path());
    let mut inputs = vec![(scene, "the scene directory")];
    if let Some(dir) = config
        .filter(|c| c.edges.source == edgenerf::edges::EdgeSource::External)
        .and_then(|c| c.edges.dir.as_deref())
    {
        inputs.push((dir, "the edge maps' directory"));
    }
    crate::output::refuse_inside_inputs(&args.out, "--out", &inputs)?;
    for (dir, what) in inputs {
        let dir = crate::output::resolved(dir);
        for f in RUN_FILES.into_iter().chain(["edges"]) {
            let written = args.out.join(f);
            if dir.starts_with(crate::output::resolved(&written)) {
                bail!(
                    "--out {}: {what} {} lies in {}, which a run writes (and --overwrite deletes); nothing was \
                     changed. Choose another --out",
                    args.out.display(),
                    dir.display(),
                    written.display()
                );
            }
        }
    }
    Ok(())
}

/// With `--resume`, the scene on the command line must be the run's (its config records
/// an absolute path; older runs a path relative to where they were trained, then the
/// command line's is used).
fn resumed_scene(args: &Args, recorded: &std::path::Path) -> anyhow::Result<PathBuf> {
    let given = &args.input.scene;
    let same = match (given.canonicalize(), recorded.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => !recorded.exists(),
    };
    if !same {
        bail!(
            "--resume: the run in {} was trained on {}, not {}; pass that scene (or train a new run without --resume)",
            args.out.display(),
            recorded.display(),
            given.display()
        );
    }
    absolute_scene(given)
}

/// The scene directory as an absolute path, `..` and links resolved where that gives a
/// UTF-8 path (a UTF-8 link is how a user reaches a directory whose name is not).
fn absolute_scene(path: &std::path::Path) -> anyhow::Result<PathBuf> {
    match path.canonicalize() {
        Ok(p) if p.to_str().is_some() => Ok(p),
        _ => std::path::absolute(path).with_context(|| format!("resolving {}", path.display())),
    }
}

/// Ctrl-C, SIGTERM or SIGHUP while training (what a user, `timeout`, a cluster
/// scheduler or a closed terminal sends): the first asks the loop to stop after the
/// current step and save a checkpoint; a second, or one outside the loop (loading,
/// evaluation), exits at once as without a handler.
mod interrupt {
    use std::io::Write;
    use std::sync::atomic::{AtomicU8, Ordering};

    const IDLE: u8 = 0;
    const TRAINING: u8 = 1;
    const REQUESTED: u8 = 2;
    static STATE: AtomicU8 = AtomicU8::new(IDLE);

    /// Installs the handler (once per process; later calls keep the first).
    pub fn install() {
        let _ = ctrlc::set_handler(|| {
            if STATE.compare_exchange(TRAINING, REQUESTED, Ordering::SeqCst, Ordering::SeqCst).is_err() {
                std::process::exit(130);
            }
            // Not eprintln!: after SIGHUP the terminal may be gone, and a failed write
            // must not panic the handler.
            let _ = writeln!(
                std::io::stderr(),
                "\ninterrupt (Ctrl-C, SIGTERM or SIGHUP): stopping after this step and saving a checkpoint (again to quit at once)"
            );
        });
    }

    /// Marks the training loop as running (`true`) or not.
    pub fn set_training(on: bool) {
        STATE.store(if on { TRAINING } else { IDLE }, Ordering::SeqCst);
    }

    /// Whether Ctrl-C asked the loop to stop.
    pub fn requested() -> bool {
        STATE.load(Ordering::SeqCst) == REQUESTED
    }
}

/// The progress bar's message while a run's first step runs. The first step builds
/// every kernel the run uses: lavapipe compiles each with LLVM at its first dispatch,
/// which takes minutes for a field it has not seen (about 5 at the default width-64,
/// 16-level grid on a 2-core CPU; README, "The first run of a field configuration
/// compiles for minutes on a CPU"). Mesa keeps the result in its shader cache, so only
/// the first run of a field configuration on a machine waits.
pub(crate) fn first_step_message(gpu: &Gpu) -> &'static str {
    if gpu.adapter().is_cpu() {
        "first step: compiling kernels (on a CPU, minutes for a new field config; cached after)"
    } else {
        "first step: compiling kernels"
    }
}

/// A warning for a new run on the engine defaults (no `--config`, no preset: a dense
/// run, `--no-preset`, or the MLP) on a CPU adapter: they are sized for a GPU (the grid's
/// 5000 steps of 4096 rays through a 2^19-entry table take about 8 s a step, 11 hours,
/// on a 2-core CPU), and a newcomer's first `edgenerf train SCENE` should not find that
/// out from the progress bar's estimate. `None` when the run has a config or preset, or
/// runs on a GPU.
fn engine_defaults_on_cpu_hint(args: &Args, gpu: &Gpu, config: &RunConfig) -> Option<String> {
    let preset = args.input.views.is_some() && !args.no_preset && config.backend == Backend::Grid;
    let engine_defaults = !args.resume && args.config.is_none() && !preset;
    if !(engine_defaults && gpu.adapter().is_cpu() && takes_hours_on_a_cpu(config)) {
        return None;
    }
    Some(format!(
        "note: no --config{}: the engine defaults, sized for a GPU ({} steps of {} rays), take hours on a CPU adapter \
         such as this one; for a dense capture on a CPU use --config tools/configs/demo.toml (600 steps, minutes), \
         for a few views --views K (a preset), or --iters / --max-seconds to bound this run",
        if args.input.views.is_some() { "" } else { " and no --views" },
        config.train.iters,
        config.train.rays_per_batch
    ))
}

/// Whether `config` asks a CPU adapter for hours: more than 4 M training rays (the
/// demo: 0.6 M; the grid's defaults 20 M) and no time limit.
fn takes_hours_on_a_cpu(config: &RunConfig) -> bool {
    config.train.max_seconds.is_none() && config.train.iters * u64::from(config.train.rays_per_batch) > 4_000_000
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_gpu_sized_defaults_warn_on_a_cpu() {
        let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        assert!(takes_hours_on_a_cpu(&RunConfig::default()), "the grid's defaults");
        assert!(takes_hours_on_a_cpu(&RunConfig::defaults_for(Backend::Mlp)), "the MLP's defaults");
        let mut bounded = RunConfig::default();
        bounded.train.max_seconds = Some(60.0);
        assert!(!takes_hours_on_a_cpu(&bounded));
        bounded.train.max_seconds = None;
        bounded.train.iters = 100;
        assert!(!takes_hours_on_a_cpu(&bounded));
        for name in ["demo.toml", "sparse-small.toml", "sparse-llff.toml", "sparse-dtu.toml", "sparse-object.toml"] {
            let c = RunConfig::from_file(&repo.join("tools/configs").join(name)).unwrap();
            assert!(!takes_hours_on_a_cpu(&c), "{name}");
        }
    }
}

/// The progress bar and its message, fed by the library's run loop; Ctrl-C asks it to stop.
struct Progress {
    bar: ProgressBar,
    first_step: u64,
    psnr_ema: Option<f32>,
    /// Which prior terms the message shows.
    distortion: bool,
    occlusion: bool,
    orientation: bool,
}

impl RunObserver for Progress {
    fn step(&mut self, _trainer: &Trainer, stats: &StepStats, elapsed_s: f64) {
        let ema = self.psnr_ema.map_or(stats.psnr, |p| 0.9 * p + 0.1 * stats.psnr);
        self.psnr_ema = Some(ema);
        // Steps read back so far (a run reads each one back while the next one runs,
        // so `trainer.step_count()` may be one ahead).
        let done = stats.step + 1;
        let steps_per_s = (done - self.first_step) as f64 / elapsed_s.max(1e-9);
        self.bar.set_position(done);
        let mut reg = if stats.lambda_depth > 0.0 || stats.lambda_normal > 0.0 {
            format!(" Lz {:.2e} Ln {:.2e}", stats.loss_depth, stats.loss_normal)
        } else {
            String::new()
        };
        if stats.lambda_tv > 0.0 {
            reg += &format!(" Ltv {:.2e}", stats.loss_tv);
        }
        if self.distortion {
            reg += &format!(" Ldist {:.2e}", stats.loss_distortion);
        }
        if self.occlusion {
            reg += &format!(" Locc {:.2e}", stats.loss_occlusion);
        }
        if self.orientation {
            reg += &format!(" Lori {:.2e}", stats.loss_orientation);
        }
        if stats.lambda_depth_normal > 0.0 {
            reg += &format!(" Ldn {:.2e}", stats.loss_depth_normal);
        }
        if stats.lambda_planarity > 0.0 {
            reg += &format!(" Lpl {:.2e}", stats.loss_planarity);
        }
        if stats.lambda_reprojection > 0.0 {
            reg += &format!(" Lrp {:.2e}", stats.loss_reprojection);
        }
        self.bar.set_message(format!(
            "Lc {:.5}{reg} psnr {:.2} | {:.0} samples/ray | {:.2} steps/s",
            stats.loss_color, ema, stats.samples_per_ray, steps_per_s
        ));
    }

    fn stop_requested(&mut self) -> bool {
        interrupt::requested()
    }

    fn time_limit_reached(&mut self, step: u64, elapsed_s: f64) {
        self.bar.println(format!("stopping at step {step}: {elapsed_s:.0} s of training reached train.max_seconds"));
    }
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    // The config first: it reads files (--config) that --overwrite may be about to
    // delete (`--config RUN/config.json --out RUN --overwrite`).
    let config = if args.resume { None } else { Some(build_config(&args)?) };
    check_out_apart_from_inputs(&args, config.as_ref())?;
    // Held until the run, its evaluation included, is over.
    let _lock = prepare_run_dir(&args)?;
    interrupt::install();
    let ckpt_path = args.out.join(run::CHECKPOINT);
    let gpu = Gpu::new(gpu_opts)?;
    let mut trainer = if args.resume {
        let mut ckpt = Checkpoint::load(&ckpt_path)?;
        if let Some(iters) = args.iters {
            ckpt.config.train.iters = iters;
        }
        if args.max_seconds.is_some() {
            ckpt.config.train.max_seconds = args.max_seconds;
        }
        ckpt.config.scene.path = resumed_scene(&args, &ckpt.config.scene.path)?;
        let scene = load_scene(&ckpt.config)?;
        check_test_views(&args, &scene)?;
        check_training_views(&scene)?;
        check_terms_fit_scene(&gpu, &ckpt.config, &scene)?;
        let masks = edge_masks(&args, &ckpt.config, &scene)?;
        Trainer::resume(gpu, scene, ckpt, masks).with_context(|| format!("resuming from {}", ckpt_path.display()))?
    } else {
        let config = config.expect("built above without --resume");
        let scene = load_scene(&config)?;
        check_test_views(&args, &scene)?;
        check_training_views(&scene)?;
        check_terms_fit_scene(&gpu, &config, &scene)?;
        let masks = edge_masks(&args, &config, &scene)?;
        Trainer::with_edge_masks(gpu, scene, config, masks)?
    };
    let config = trainer.config().clone();
    eprintln!(
        "training {} ({} train views, {} test) on {}; {} parameters; run directory {}",
        config.scene.path.display(),
        trainer.scene.split.train.len(),
        trainer.scene.split.test.len(),
        trainer.gpu.adapter().name,
        trainer.model.field.n_params(),
        args.out.display()
    );
    if let Some(hint) = engine_defaults_on_cpu_hint(&args, &trainer.gpu, &config) {
        eprintln!("{hint}");
    }
    if let Some(bg) = &trainer.model.background {
        let c = bg.config();
        eprintln!(
            "learned background: {} see a learned colour {} (finest map {}x{} texels, {}; --set 'render.background={{\"kind\": \"black\"}}' for none)",
            if trainer.scene.ndc.is_some() {
                "rays that pass the scene's far end (forward-facing, NDC)"
            } else {
                "the training images have no alpha, so rays that leave the scene box"
            },
            if c.shell_radius > 0.0 && c.shell_shape == edgenerf::render::ShellShape::Box {
                format!("where they leave the scene box{}", if c.shell_radius == 1.0 { String::new() } else { format!(" scaled by {}", c.shell_radius) })
            } else if c.shell_radius > 0.0 {
                format!("where they cross a sphere {} box half-diagonals from its centre", c.shell_radius)
            } else {
                "per direction".to_string()
            },
            2 * c.finest_height,
            c.finest_height,
            match c.prefit {
                edgenerf::render::Prefit::All => "fitted first to the images' frames",
                edgenerf::render::Prefit::Coarsest => "its coarsest map fitted first to the images' frames",
                edgenerf::render::Prefit::None => "not fitted to the images before training (render.learned_background.prefit = \"none\")",
            }
        );
    }
    if let Some((confirmed, filled)) = trainer.stereo_coverage() {
        let p = &config.priors;
        let fill = if p.stereo_fill > 0 { format!(", {:.1} % more a depth filled within their edge regions (priors.stereo_fill = {})", 100.0 * filled, p.stereo_fill) } else { String::new() };
        let across = match (p.stereo_horizontal, edgenerf::train::stereo::up_direction(&trainer.scene)) {
            (false, _) => String::new(),
            (true, Some(up)) => format!(" and {} planes across the cameras' mean up vector ({:.2}, {:.2}, {:.2})", p.stereo_planes, up.x, up.y, up.z),
            (true, None) => " (no planes across an up direction: the training cameras disagree about up)".to_string(),
        };
        if p.stereo_targets == edgenerf::render::StereoTargetSource::GroundTruth {
            eprintln!(
                "stereo priors on the scene's ground-truth depth (priors.stereo_targets = \"ground_truth\"): {:.1} % of the training pixels, an upper bound for a depth prior, not a prior (priors.stereo_depth = {})",
                100.0 * confirmed,
                p.stereo_depth
            );
        } else {
            eprintln!(
                "stereo depth prior: a sweep of {} depth planes{across} over the training views gave {:.1} % of their pixels a depth another view confirms (priors.stereo_depth = {}; priors.stereo_consistency = {}){fill}",
                p.stereo_planes,
                100.0 * confirmed,
                p.stereo_depth,
                p.stereo_consistency
            );
            // Targets against the scene's ground-truth depth (synthetic scenes).
            let accuracy = |what: &str, pixels: &str, a: edgenerf::train::stereo::Accuracy| {
                eprintln!(
                    "{what} against the scene's ground-truth depth: {} {pixels}, median error {:.2} % of the depth, {:.1} % of them off by more than {:.0} %",
                    a.pixels,
                    100.0 * a.median_error,
                    100.0 * a.outliers,
                    100.0 * edgenerf::train::stereo::ACCURACY_OUTLIER
                )
            };
            if let Some(a) = trainer.stereo_accuracy() {
                accuracy("stereo depth prior", "confirmed pixels", a);
            }
            if let Some(dir) = &p.mono_depth_dir {
                let fits = trainer.mono_fits();
                let filled: usize = fits.iter().map(|f| f.filled).sum();
                let pixels: usize = trainer.scene.train_views().map(|v| (v.camera.width * v.camera.height) as usize).sum();
                eprintln!(
                    "monocular depth ({} maps in {}): fitted to the confirmed depths, {:.1} % of the training pixels more a target at confidence {} (priors.mono_depth_confidence)",
                    match p.mono_depth_kind {
                        edgenerf::render::MonoDepthKind::Disparity => "disparity",
                        edgenerf::render::MonoDepthKind::Depth => "depth",
                    },
                    dir.display(),
                    100.0 * filled as f64 / pixels.max(1) as f64,
                    p.mono_depth_confidence
                );
                for f in fits {
                    let name = &trainer.scene.views[f.view].name;
                    if f.used {
                        eprintln!(
                            "  {name}: scale {:.4}, shift {:.4} over {} confirmed pixels, their median error after the fit {:.2} % of the depth",
                            f.scale,
                            f.shift,
                            f.pixels,
                            100.0 * f.median_error
                        );
                    } else {
                        eprintln!(
                            "  {name}: map not used ({} confirmed pixels with a value, at least {} needed, and the fit must keep the map's order: scale {:.4})",
                            f.pixels,
                            edgenerf::train::mono_depth::MIN_FIT_PIXELS,
                            f.scale
                        );
                    }
                }
                if let Some(a) = trainer.mono_accuracy() {
                    accuracy("monocular targets", "pixels", a);
                }
            }
        }
        let dir = args.out.join("stereo");
        write_stereo_maps(&trainer, &dir).with_context(|| format!("writing the stereo targets to {}", dir.display()))?;
        eprintln!("stereo targets: depth and confidence per training view in {}", dir.display());
    }
    if let Some(seen) = trainer.model.occupancy.seen_cells() {
        eprintln!(
            "seen cells: {:.1} % of the occupancy grid is imaged by at least {} training camera(s); the rest is never marched (sampler.seen_cells_only, sampler.seen_views)",
            100.0 * seen as f64 / (config.sampler.resolution as f64).powi(3),
            config.sampler.seen_views
        );
    }
    let vis = &config.sampler.visibility;
    if vis.train {
        let faint = if vis.min_alpha > 0.0 {
            let bound = if vis.max_dropped_opacity < 1.0 {
                format!(" while a ray loses at most {} opacity to them", vis.max_dropped_opacity)
            } else {
                String::new()
            };
            format!(", and (from step {}) samples with opacity under {}{bound}", vis.min_alpha_start_step.max(vis.start_step), vis.min_alpha)
        } else {
            String::new()
        };
        eprintln!(
            "visibility pass: from step {}, samples behind the point where a ray's transmittance falls under {}{faint} skip the field's forward and backward (sampler.visibility.train = false for every marched sample)",
            vis.start_step, vis.min_transmittance
        );
    }

    let iters = config.train.iters;
    let bar = ProgressBar::new(iters);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}] {msg}").unwrap(),
    );
    bar.set_position(trainer.step_count());
    bar.set_message(first_step_message(&trainer.gpu));
    bar.enable_steady_tick(std::time::Duration::from_secs(1));
    let mut progress = Progress {
        bar: bar.clone(),
        first_step: trainer.step_count(),
        psnr_ema: None,
        distortion: config.priors.distortion > 0.0,
        occlusion: config.priors.occlusion > 0.0,
        orientation: config.priors.orientation > 0.0,
    };
    interrupt::set_training(true);
    let result = run::train_run(&mut trainer, &args.out, &mut progress);
    interrupt::set_training(false);
    let summary = match result {
        Ok(s) => s,
        Err(e @ (TrainError::NonFinite { .. } | TrainError::RaysMissScene { .. })) => {
            bar.abandon();
            let kept = if ckpt_path.is_file() { format!("the last good checkpoint is kept at {}", ckpt_path.display()) } else { "no checkpoint had been written yet".into() };
            bail!("{e}\n{kept}");
        }
        Err(e) => {
            bar.abandon();
            return Err(e.into());
        }
    };
    if summary.end == RunEnd::Stopped {
        bar.abandon();
        bail!(
            "interrupted at step {} of {iters}; checkpoint saved to {} (log.csv has every step). Continue with \
             `edgenerf train {} --out {} --resume`",
            summary.last_step,
            summary.checkpoint.display(),
            args.input.scene.display(),
            args.out.display()
        );
    }
    bar.finish();
    let steps = summary.last_step - summary.first_step;
    eprintln!(
        "trained {steps} steps in {:.1} s ({:.2} steps/s); checkpoint {}",
        summary.elapsed_s,
        steps as f64 / summary.elapsed_s.max(1e-9),
        summary.checkpoint.display()
    );
    if !args.no_eval {
        crate::cmd::render::evaluate_and_write(&trainer.gpu, &mut trainer.model, &trainer.scene, &args.out.join(run::TEST_DIR))?;
    }
    Ok(())
}
