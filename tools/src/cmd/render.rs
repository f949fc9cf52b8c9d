//! `edgenerf render`: render views of a trained run (RGB, depth, normals, opacity), or
//! a novel-view camera path (`--path`: frames and an animation per stream), the loading
//! of a run's model for `render` and `eval` (no optimizer state), and the test-view
//! evaluation shared with `train`.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use edgenerf::data::{Camera, LoadOptions, PathKind, Scene};
use edgenerf::gpu::{Gpu, GpuOptions};
use edgenerf::train::{Checkpoint, Model};
use indicatif::{ProgressBar, ProgressStyle};

use crate::video::{self, VideoFormat};

#[derive(clap::Args)]
pub struct Args {
    /// A checkpoint file, or a run directory holding checkpoint.safetensors.
    checkpoint: PathBuf,
    /// Which views: test, train, val (the views the run neither trains nor tests on,
    /// for choosing settings without the test views) or all.
    #[arg(long, default_value = "test", value_parser = ["test", "train", "val", "all"])]
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
    /// Render a novel-view camera path instead of dataset views: `spiral` (NeRF's LLFF
    /// spiral), `orbit` (around an object-centric scene) or `interpolate` (a loop through
    /// the training poses). Writes DIR/rgb, DIR/depth and DIR/normals (0000.png, ...),
    /// DIR/path.json (the cameras) and one animation per stream.
    #[arg(long, value_parser = ["spiral", "orbit", "interpolate"], conflicts_with = "split")]
    path: Option<String>,
    /// Frames of the path (NeRF's 120: 4 s at 30 fps).
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u32).range(1..=100_000), requires = "path")]
    frames: u32,
    /// Frames per second of the animation.
    #[arg(long, default_value_t = 30.0, value_parser = parse_fps, requires = "path")]
    fps: f32,
    /// The animations: mp4 (H.264 through ffmpeg), gif, auto (mp4 when ffmpeg is on
    /// PATH, else gif) or none (frames only).
    #[arg(long, default_value = "auto", value_parser = ["auto", "mp4", "gif", "none"], requires = "path")]
    video: String,
    /// Size of the path's frames relative to the training images (0.5: half the width
    /// and height, a quick preview).
    #[arg(long, default_value_t = 1.0, value_parser = parse_scale, requires = "path")]
    scale: f32,
    /// Replace the frames and animations of an earlier path render in --out.
    #[arg(long, requires = "path")]
    overwrite: bool,
    /// Use a --scene other than the one the run was trained on (refused otherwise).
    #[arg(long, requires = "scene")]
    allow_other_scene: bool,
}

fn parse_fps(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.1..=240.0).contains(&v) { Ok(v) } else { Err(format!("{v} is outside 0.1..=240 frames per second")) }
}

fn parse_scale(s: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if v > 0.0 && v <= 4.0 { Ok(v) } else { Err(format!("{v} is outside (0, 4] (1 = the training images' size)")) }
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    crate::output::refuse_file(&args.out, "--out")?;
    // A path render's requests are checked before the model loads.
    let path = match &args.path {
        Some(kind) => Some(prepare_path(&args, kind)?),
        None => None,
    };
    let check = crate::cmd::render::OutputCheck { out: &args.out, allow_other_scene: args.allow_other_scene };
    let unused_views = split_needs_unused_views(&args.split);
    let mut run = load_run(&args.checkpoint, args.scene.as_deref(), &args.overrides, gpu_opts, check, unused_views)?;
    // Created once the run loaded; removed again if nothing gets written into it.
    let _out = crate::output::OutDir::create(&args.out, "--out")?;
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
    if let Some(path) = path {
        return render_path(&args, path, &mut run);
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

/// The streams of a path render: folder (and animation) name.
const STREAMS: [&str; 3] = ["rgb", "depth", "normals"];

/// What `render --path` was asked for, checked before the model loads.
struct PathRequest {
    kind: PathKind,
    video: Option<VideoFormat>,
    /// The files and folders of an earlier path render in --out (replaced with --overwrite).
    earlier: Vec<PathBuf>,
}

/// Parses the path and video requests, and refuses an --out that holds an earlier path
/// render unless --overwrite.
fn prepare_path(args: &Args, kind: &str) -> anyhow::Result<PathRequest> {
    let kind: PathKind = kind.parse().map_err(anyhow::Error::msg)?;
    let video = video::choose(&args.video)?;
    let out = &args.out;
    let earlier: Vec<PathBuf> = STREAMS
        .iter()
        .flat_map(|s| [out.join(s), out.join(format!("{s}.mp4")), out.join(format!("{s}.gif"))])
        .chain([out.join("path.json")])
        .filter(|p| p.exists())
        .collect();
    if !earlier.is_empty() && !args.overwrite {
        bail!(
            "{} already holds a path render ({}); pass --overwrite to replace it, or another --out",
            out.display(),
            earlier.iter().map(|p| p.file_name().unwrap().to_string_lossy()).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(PathRequest { kind, video, earlier })
}

/// `render --path`: the cameras of the path, one frame per camera in each stream (depth
/// coloured over the range of all frames, so it does not flicker), `path.json`, and the
/// animations. An earlier path render in --out is removed once the path's cameras exist.
fn render_path(args: &Args, request: PathRequest, run: &mut LoadedRun) -> anyhow::Result<()> {
    let PathRequest { kind, video: format, earlier } = request;
    let cameras: Vec<Camera> = edgenerf::data::camera_path(&run.scene, kind, args.frames as usize)?
        .into_iter()
        .map(|c| {
            let size = |n: u32| ((n as f32 * args.scale).round() as u32).max(1);
            c.resized(size(c.width), size(c.height))
        })
        .collect();
    let out = &args.out;
    for p in earlier {
        if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) }
            .with_context(|| format!("removing the earlier {}", p.display()))?;
    }
    for s in STREAMS {
        std::fs::create_dir_all(out.join(s)).with_context(|| format!("creating {}", out.join(s).display()))?;
    }
    let (w, h) = (cameras[0].width, cameras[0].height);
    let record = serde_json::json!({ "path": kind, "frames": cameras.len(), "fps": args.fps, "cameras": cameras });
    edgenerf::train::output::write_atomic(&out.join("path.json"), serde_json::to_string_pretty(&record)?.as_bytes())?;
    println!("{} path: {} frames of {w}x{h} from the {} training views of {}", kind.name(), cameras.len(), run.scene.split.train.len(), run.scene.root.display());

    let bar = ProgressBar::new(cameras.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} frames [{elapsed_precise}<{eta_precise}] {msg}").unwrap());
    let mut depths = Vec::with_capacity(cameras.len());
    let mut samples = 0u64;
    for (i, cam) in cameras.iter().enumerate() {
        let r = run.model.render_camera(&run.gpu, &run.scene, cam)?;
        edgenerf::train::output::rgb_image(&r).save_png(video::frame_path(&out.join("rgb"), i))?;
        edgenerf::viz::normal_image(w, h, &r.unit_normals()).save_png(video::frame_path(&out.join("normals"), i))?;
        depths.push(edgenerf::train::output::shown_depth(&r));
        samples += r.samples;
        bar.set_message(format!("{:.1} samples/ray", samples as f64 / ((i + 1) as f64 * (w * h) as f64)));
        bar.inc(1);
    }
    bar.finish();
    // One colour range for the whole path: the robust range of every frame's depth.
    let all: Vec<f32> = depths.iter().flat_map(|(d, _)| d.iter().copied()).collect();
    let valid: Vec<bool> = depths.iter().flat_map(|(_, v)| v.iter().copied()).collect();
    let range = edgenerf::viz::depth_range(&all, Some(&valid));
    for (i, (d, v)) in depths.iter().enumerate() {
        edgenerf::viz::depth_image_in_range(w, h, d, Some(v), range).save_png(video::frame_path(&out.join("depth"), i))?;
    }
    println!(
        "wrote {} frames to {}/{{rgb,depth,normals}}/ and path.json ({:.1} samples per ray; depth colours over {:.3}..{:.3})",
        cameras.len(),
        out.display(),
        samples as f64 / (cameras.len() as f64 * (w * h) as f64),
        range[0],
        range[1]
    );
    let Some(format) = format else { return Ok(()) };
    let bar = ProgressBar::new(STREAMS.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} animations [{elapsed_precise}] {msg}").unwrap());
    let mut written = Vec::new();
    for s in STREAMS {
        let file = out.join(format!("{s}.{}", format.extension()));
        bar.set_message(file.display().to_string());
        video::encode(format, &out.join(s), cameras.len(), args.fps, &file)?;
        written.push(file);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let how = match format {
        VideoFormat::Mp4 => "H.264 MP4 through ffmpeg",
        VideoFormat::Gif => "animated GIF, looping",
    };
    println!(
        "animations ({how}, {} fps): {}",
        args.fps,
        written.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    );
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

/// What a command that loads a run writes, checked against the run's inputs before
/// anything is loaded onto the GPU or written.
pub struct OutputCheck<'a> {
    /// The output directory (`render`, `eval`) or file (`export`).
    pub out: &'a Path,
    /// `--allow-other-scene`: a `--scene` that is not the run's is used anyway.
    pub allow_other_scene: bool,
}

/// The run of a checkpoint (a file, or a run directory holding
/// `checkpoint.safetensors`) on its scene (the path recorded in its config, or
/// `scene`), on the GPU ([`Model::from_checkpoint`]), with the `--set` `overrides`
/// applied to its config. Shared by `render`, `eval` and `export`. Refuses, before the
/// GPU: an output inside the scene directory or equal to the run directory (renders
/// into `SCENE/train` replaced the ground truth), and a `--scene` other than the one
/// the run was trained on unless `allow_other_scene` (it scored against the other
/// scene's cameras without a word).
pub fn load_run(
    checkpoint: &Path,
    scene: Option<&Path>,
    overrides: &[String],
    gpu_opts: &GpuOptions,
    check: OutputCheck,
    unused_views: bool,
) -> anyhow::Result<LoadedRun> {
    let path = if checkpoint.is_dir() { checkpoint.join("checkpoint.safetensors") } else { checkpoint.to_path_buf() };
    let mut ckpt = Checkpoint::load(&path)?;
    let recorded = ckpt.config.scene.path.clone();
    if let Some(scene) = scene {
        let same = match (scene.canonicalize(), recorded.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            // The run's scene is gone (moved): --scene is how to point at it.
            (_, Err(_)) => true,
            (Err(_), Ok(_)) => false,
        };
        if !same && !check.allow_other_scene {
            bail!(
                "--scene {} is not the scene {} was trained on ({}); its cameras and ground truth would score \
                 another scene. Pass --allow-other-scene to use it anyway (a copy or another version of the same \
                 scene), or leave out --scene",
                scene.display(),
                path.display(),
                recorded.display()
            );
        }
        ckpt.config.scene.path = scene.to_path_buf();
    }
    let scene_path = ckpt.config.scene.path.clone();
    crate::output::refuse_inside_inputs(check.out, "--out", &[(&scene_path, "the scene directory")])?;
    if let Some(run_dir) = path.parent()
        && crate::output::resolved(check.out) == crate::output::resolved(run_dir)
    {
        bail!(
            "--out {} is the run directory of {}; its files would mix with the run's. Pass a folder inside it \
             (such as {}) or elsewhere",
            check.out.display(),
            path.display(),
            run_dir.join("renders").display()
        );
    }
    for o in overrides {
        ckpt.config.set(o)?;
    }
    if !overrides.is_empty() {
        ckpt.config.resolve();
        ckpt.config.validate().map_err(|m| anyhow::anyhow!("configuration: {m}"))?;
    }
    let opts = LoadOptions { unused_views, ..ckpt.config.scene.load_options() };
    let scene = Scene::load(&scene_path, &opts).with_context(|| match scene {
        Some(_) => format!("loading --scene {} (the run was trained on {})", scene_path.display(), recorded.display()),
        None => format!("loading the checkpoint's scene {} (pass --scene to point elsewhere)", scene_path.display()),
    })?;
    let gpu = Gpu::new(gpu_opts)?;
    let model = Model::from_checkpoint(&gpu, &scene, &ckpt)
        .with_context(|| format!("loading the model of {} on {}", path.display(), scene_path.display()))?;
    Ok(LoadedRun { gpu, scene, model, step: ckpt.step })
}

/// Whether the views of `split` include those a sparse split leaves out, which a
/// Blender-format scene loads only on request ([`LoadOptions::unused_views`]).
pub fn split_needs_unused_views(split: &str) -> bool {
    matches!(split, "val" | "all")
}

/// The view indices of a split name: `test`, `train`, `val` (every view in neither the
/// training nor the test split: DTU's excluded and unused protocol views, LLFF's
/// training-side views a sparse run leaves out) or `all`.
pub fn split_views(scene: &Scene, split: &str) -> anyhow::Result<Vec<usize>> {
    Ok(match split {
        "test" => scene.split.test.clone(),
        "train" => scene.split.train.clone(),
        "val" => scene.split.unused(scene.views.len()),
        "all" => (0..scene.views.len()).collect(),
        other => bail!("unknown split {other} (test, train, val or all)"),
    })
}

/// The message for a scene without test views, ending with what to do instead (`hint`).
pub fn no_test_views(scene: &Scene, hint: &str) -> String {
    let files = match scene.format {
        // A transforms_test.json without frames is there: say so (it read as missing).
        edgenerf::data::SceneFormat::Blender => match ["transforms_test.json", "transforms_val.json"]
            .into_iter()
            .find(|f| scene.root.join(f).is_file())
        {
            Some(f) => format!("its {f} lists no frames"),
            None => "no transforms_test.json or transforms_val.json".to_string(),
        },
        _ => "every view is a training view of this split".to_string(),
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
