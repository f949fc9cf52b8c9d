//! `edgenerf eval`: every image and geometry metric of a trained run under its scene's
//! protocol, with per-view renders and error maps, `metrics.json` and a printed table.
//!
//! Owns the `metrics.json` layout of `eval` (which `bench` reads back); the protocol
//! and the metrics come from the engine, so that `eval` and the end of `train` give the
//! same figures for the same checkpoint:
//! * PSNR, SSIM and geometry: [`edgenerf::train::evaluate_view`], under the scene's
//!   protocol ([`edgenerf::metrics::protocol`]: **DTU masked** for DTU scenes, PSNR over
//!   the object mask and SSIM on white composites, the unmasked figures kept as
//!   `full_image`; **full image** for LLFF and synthetic scenes); geometry is depth
//!   AbsRel / RMSE / delta, normal angles, each split by the GT edge band, DBE;
//! * LPIPS (VGG, Alex) when the weights are installed (`tools/lpips/fetch-weights`), on
//!   the protocol's image pair ([`edgenerf::metrics::protocol::comparison_images`]);
//! * maps: depth error, normal angle error ([`edgenerf::metrics::maps`]) and an edge
//!   overlay: the DBE's Canny edges of GT and predicted depth where the scene has GT
//!   depth, else Canny edges of the GT and rendered images' luma.
//!
//! * mesh: where the scene has a `gt_mesh.ply` (the synthetic scenes), the run's mesh
//!   (`export mesh` at `--mesh-resolution`, default level) against it: Chamfer distance
//!   and F-score ([`edgenerf::metrics::mesh`]); `--no-mesh` skips it.
//!
//! `metrics.json` holds `metrics` (means over the views of every per-view figure,
//! flattened to dotted names such as `depth.non_edge.abs_rel`, see
//! [`flatten_view_metrics`]) and `views` (the per-view records).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use edgenerf::data::Scene;
use edgenerf::edges::{CannyParams, canny, luma, mask_stem};
use edgenerf::gpu::GpuOptions;
use edgenerf::metrics::boundary::{DbeParams, dbe_edges, normalize_depth};
use edgenerf::metrics::maps::{depth_error_map, edge_overlay, normal_error_map};
use edgenerf::metrics::lpips::{Lpips, LpipsNet};
use edgenerf::mesh::ply::read_ply;
use edgenerf::metrics::mesh::{MeshMetricParams, MeshMetrics, mesh_metrics};
use edgenerf::metrics::protocol::{Protocol, comparison_images};
use edgenerf::metrics::{Covisibility, GeometryMetrics, ImageMetrics};
use edgenerf::train::export::{MeshOptions, extract_mesh};
use edgenerf::train::{RenderedView, evaluate_view};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

#[derive(clap::Args)]
pub struct Args {
    /// A run directory (holding checkpoint.safetensors) or a checkpoint file.
    run: PathBuf,
    /// Which views: test, train, val (neither trained nor tested on) or all.
    #[arg(long, default_value = "test", value_parser = ["test", "train", "val", "all"])]
    split: String,
    /// LPIPS networks. Default: both where the weights are installed, none (with a
    /// note) where not; asking explicitly makes missing weights an error.
    #[arg(long, value_enum)]
    lpips: Option<LpipsChoice>,
    /// Output directory (default: `eval/` beside the checkpoint, `eval-<split>/` for
    /// other splits than test).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Scene directory (default: the path recorded in the checkpoint's config).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Override one setting of the checkpoint's config for this evaluation, e.g.
    /// `--set field.normal_level_weights=[1,1,1,1,1,1,0,0]` (repeatable). Settings
    /// that change the parameters' shapes are refused when the checkpoint loads.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Use a --scene other than the one the run was trained on (refused otherwise).
    #[arg(long, requires = "scene")]
    allow_other_scene: bool,
    /// Skip the mesh metrics (done by default when the scene has a gt_mesh.ply).
    #[arg(long)]
    no_mesh: bool,
    /// Grid cells along the longest side of the box for the mesh metrics' export
    /// (`export mesh --resolution`; its default level).
    #[arg(long, default_value_t = 128, value_name = "N", value_parser = clap::value_parser!(u32).range(2..=1024))]
    mesh_resolution: u32,
    /// Density level of the mesh metrics' export (default: `export mesh`'s, ln 2 / the
    /// run's sampler step).
    #[arg(long, value_name = "L")]
    mesh_level: Option<f32>,
}

/// `--lpips` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LpipsChoice {
    Vgg,
    Alex,
    Both,
    None,
}

/// One LPIPS network ready to score image pairs: `(width, height, a, b) -> distance`.
type LpipsScorer = Box<dyn Fn(u32, u32, &[f32], &[f32]) -> anyhow::Result<f64>>;

/// The LPIPS networks of a run of `eval`, and what to say about those left out.
struct LpipsSet {
    vgg: Option<LpipsScorer>,
    alex: Option<LpipsScorer>,
    /// What was left out and why (one line), where a network is absent.
    notes: Vec<String>,
}

/// Loads one LPIPS network from the default weights directory.
fn load_lpips_net(net: LpipsNet) -> anyhow::Result<LpipsScorer> {
    let model = Lpips::from_default_dir(net)?;
    Ok(Box::new(move |w, h, a, b| Ok(model.distance(w, h, a, b)?)))
}

impl LpipsSet {
    /// Resolves `--lpips`: explicit choices must load (else an error naming the fetch
    /// script), the default takes what loads and notes the rest.
    fn load(choice: Option<LpipsChoice>) -> anyhow::Result<LpipsSet> {
        let wanted: &[LpipsNet] = match choice {
            Some(LpipsChoice::None) => &[],
            Some(LpipsChoice::Vgg) => &[LpipsNet::Vgg],
            Some(LpipsChoice::Alex) => &[LpipsNet::Alex],
            Some(LpipsChoice::Both) | None => &[LpipsNet::Vgg, LpipsNet::Alex],
        };
        let mut set = LpipsSet { vgg: None, alex: None, notes: Vec::new() };
        let mut missing = Vec::new();
        for &net in wanted {
            match load_lpips_net(net) {
                Ok(scorer) => *(if net == LpipsNet::Vgg { &mut set.vgg } else { &mut set.alex }) = Some(scorer),
                Err(e) if choice.is_some() => {
                    return Err(e.context(format!("--lpips {}: install the weights with tools/lpips/fetch-weights", net.name())));
                }
                Err(e) => missing.push(format!("{}: {e:#}", net.name())),
            }
        }
        if !missing.is_empty() {
            set.notes.push(format!(
                "LPIPS left out, its fields null ({}); tools/lpips/fetch-weights installs the weights",
                missing.join("; ")
            ));
        }
        Ok(set)
    }
}

/// Every figure of one view.
#[derive(Clone, Debug, Serialize)]
pub struct ViewRecord {
    pub view: usize,
    /// File stem of its renders and maps (unique within the scene).
    pub name: String,
    pub protocol: Protocol,
    /// Under `protocol`.
    pub psnr: f64,
    pub ssim: f64,
    pub lpips_vgg: Option<f64>,
    pub lpips_alex: Option<f64>,
    /// Unmasked PSNR / SSIM where the protocol is masked.
    pub full_image: Option<ImageMetrics>,
    pub geometry: Option<GeometryMetrics>,
    /// PSNR over the pixels whose ground-truth surface no training view, one, or two
    /// or more see (scenes with ground-truth depth in world space).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub covisibility: Option<Covisibility>,
    /// Field samples per pixel ray of its render.
    pub samples_per_ray: f64,
}

/// What `eval` writes as `metrics.json`.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub checkpoint: PathBuf,
    pub scene: PathBuf,
    pub split: String,
    pub step: u64,
    pub adapter: String,
    pub protocol: Protocol,
    /// Why LPIPS fields are null, where they are.
    pub notes: Vec<String>,
    /// Means over the views of each flattened per-view figure, and the mesh figures
    /// (`mesh.chamfer`, `mesh.fscore`, ...) where computed.
    pub metrics: BTreeMap<String, f64>,
    /// The exported mesh against the scene's ground-truth mesh (`None` without one,
    /// or with `--no-mesh`).
    pub mesh: Option<MeshMetrics>,
    /// What rendering the views cost: seconds (all views, without scoring) and field
    /// samples per pixel ray (their mean).
    pub render_seconds: f64,
    pub samples_per_ray: f64,
    pub views: Vec<ViewRecord>,
}

/// A view's figures as `name -> value`: `psnr`, `ssim`, `lpips_vgg`, `lpips_alex` and
/// the numeric leaves of its geometry with dotted paths (`depth.edge.rmse`,
/// `normal.all.under_11_25`, `boundary.accuracy`); parameters and pixel counts are left
/// out, and so are figures that are absent (null).
pub fn flatten_view_metrics(v: &ViewRecord) -> BTreeMap<String, f64> {
    fn walk(prefix: &str, value: &serde_json::Value, out: &mut BTreeMap<String, f64>) {
        match value {
            serde_json::Value::Object(map) => {
                for (k, v) in map {
                    if k == "params" || k.ends_with("pixels") {
                        continue;
                    }
                    walk(&if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") }, v, out);
                }
            }
            serde_json::Value::Number(n) => {
                if let Some(x) = n.as_f64() {
                    out.insert(prefix.to_string(), x);
                }
            }
            _ => {}
        }
    }
    let mut out = BTreeMap::from([("psnr".to_string(), v.psnr), ("ssim".to_string(), v.ssim)]);
    for (k, x) in [("lpips_vgg", v.lpips_vgg), ("lpips_alex", v.lpips_alex)] {
        if let Some(x) = x {
            out.insert(k.to_string(), x);
        }
    }
    if let Some(g) = &v.geometry {
        walk("", &serde_json::to_value(g).expect("metrics serialize"), &mut out);
    }
    if let Some(c) = &v.covisibility {
        walk("covisibility", &serde_json::to_value(c).expect("metrics serialize"), &mut out);
    }
    out
}

/// Means over views of [`flatten_view_metrics`] (each over the views that have it).
pub fn mean_metrics(views: &[ViewRecord]) -> BTreeMap<String, f64> {
    let mut sums: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    for v in views {
        for (k, x) in flatten_view_metrics(v) {
            let e = sums.entry(k).or_default();
            e.0 += x;
            e.1 += 1;
        }
    }
    sums.into_iter().map(|(k, (s, n))| (k, s / n as f64)).collect()
}

/// Scores one rendered view and writes its renders and error maps into `out`.
fn evaluate_one(scene: &Scene, v: usize, r: &RenderedView, lpips: &LpipsSet, out: &Path) -> anyhow::Result<ViewRecord> {
    let view = &scene.views[v];
    let name = mask_stem(scene, v);
    let (w, h) = (r.width, r.height);
    let base = evaluate_view(scene, v, r).with_context(|| format!("metrics of view {name}"))?;
    let rgb = r.rgb.as_flattened();
    let (lp_a, lp_b) = comparison_images(scene, v, rgb)?;
    let score = |s: &Option<LpipsScorer>| s.as_ref().map(|f| f(w, h, &lp_a, &lp_b)).transpose();
    let (lpips_vgg, lpips_alex) = (score(&lpips.vgg)?, score(&lpips.alex)?);

    edgenerf::train::output::write_view(out, &name, r)?;
    let save = |img: edgenerf::data::ImageRgb, what: &str| img.save_png(out.join(format!("{name}_{what}.png")));
    let gt_depth = view.depth.as_deref().filter(|_| scene.ndc.is_none());
    let depth = r.terminated_depth(scene.far);
    if let Some(gt) = gt_depth {
        save(depth_error_map(w, h, gt, &depth, None)?.0, "depth_error")?;
        let (e_gt, e_est) = dbe_edges(w, h, gt, &depth, &DbeParams::default())?;
        save(edge_overlay(w, h, &normalize_depth(gt, &depth)?, &e_gt, &e_est)?, "edge_overlay")?;
    } else {
        let params = CannyParams::default();
        let e_gt = canny(&luma(&view.image.data), w, h, &params);
        let e_est = canny(&luma(rgb), w, h, &params);
        save(edge_overlay(w, h, &luma(&view.image.data), &e_gt, &e_est)?, "edge_overlay")?;
    }
    if let Some(gt) = view.normal.as_deref() {
        save(normal_error_map(w, h, gt, &r.unit_normals())?, "normal_error")?;
    }
    Ok(ViewRecord {
        view: v,
        name,
        protocol: base.protocol,
        psnr: base.psnr as f64,
        ssim: base.ssim as f64,
        lpips_vgg,
        lpips_alex,
        full_image: base.full_image,
        geometry: base.geometry,
        covisibility: base.covisibility,
        samples_per_ray: base.samples_per_ray as f64,
    })
}

pub fn run(args: Args, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    let lpips = LpipsSet::load(args.lpips)?;
    if !lpips.notes.is_empty() {
        eprintln!("note: {}", lpips.notes.join("; "));
    }
    let out = args.out.clone().unwrap_or_else(|| {
        let dir = if args.run.is_dir() { args.run.clone() } else { args.run.parent().map(Path::to_path_buf).unwrap_or_default() };
        dir.join(if args.split == "test" { "eval".to_string() } else { format!("eval-{}", args.split) })
    });
    crate::output::refuse_file(&out, "--out")?;
    let check = crate::cmd::render::OutputCheck { out: &out, allow_other_scene: args.allow_other_scene };
    let unused_views = crate::cmd::render::split_needs_unused_views(&args.split);
    let mut run = crate::cmd::render::load_run(&args.run, args.scene.as_deref(), &args.overrides, gpu_opts, check, unused_views)?;
    // Created once the run loaded; removed again if nothing gets written into it.
    let _out = crate::output::OutDir::create(&out, "--out")?;
    let views = crate::cmd::render::split_views(&run.scene, &args.split)?;

    let bar = ProgressBar::new(views.len() as u64);
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} views [{elapsed_precise}] {msg}").unwrap());
    let mut records = Vec::new();
    let mut render_seconds = 0.0;
    for v in views {
        bar.set_message(run.scene.views[v].name.clone());
        let start = std::time::Instant::now();
        let r = run.model.render_view(&run.gpu, &run.scene, v)?;
        render_seconds += start.elapsed().as_secs_f64();
        records.push(evaluate_one(&run.scene, v, &r, &lpips, &out)?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    if records.is_empty() {
        if args.split == "test" {
            bail!("{}", crate::cmd::render::no_test_views(&run.scene, "eval --split train or --split all instead"));
        }
        bail!("the {} split of {} has no view", args.split, run.scene.root.display());
    }
    let protocol = records[0].protocol;
    let mesh = if args.no_mesh { None } else { mesh_metrics_of(&mut run, args.mesh_resolution, args.mesh_level)? };
    let mut metrics = mean_metrics(&records);
    if let Some(m) = &mesh {
        let d = &m.distances;
        for (k, x) in [
            ("chamfer", d.chamfer),
            ("accuracy", d.accuracy),
            ("completeness", d.completeness),
            ("precision", d.precision),
            ("recall", d.recall),
            ("fscore", d.fscore),
        ] {
            if x.is_finite() {
                metrics.insert(format!("mesh.{k}"), x);
            }
        }
    }
    let report = EvalReport {
        checkpoint: args.run.clone(),
        scene: run.scene.root.clone(),
        split: args.split.clone(),
        step: run.step,
        adapter: run.gpu.adapter().name.clone(),
        protocol,
        notes: lpips.notes,
        metrics,
        mesh,
        render_seconds,
        samples_per_ray: records.iter().map(|r| r.samples_per_ray).sum::<f64>() / records.len() as f64,
        views: records,
    };
    print_table(&report);
    let path = out.join("metrics.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?).with_context(|| format!("writing {}", path.display()))?;
    eprintln!("wrote {} and per-view renders and error maps to {}", path.display(), out.display());
    Ok(())
}

/// The scene's `gt_mesh.ply` against the run's mesh (`export mesh` at `resolution`
/// and `level`), `None` where the scene has no ground-truth mesh. An empty mesh scores
/// infinite distances, left out of `metrics` (JSON has no infinity).
fn mesh_metrics_of(run: &mut crate::cmd::render::LoadedRun, resolution: u32, level: Option<f32>) -> anyhow::Result<Option<MeshMetrics>> {
    let path = run.scene.root.join("gt_mesh.ply");
    if !path.is_file() || run.scene.ndc.is_some() {
        return Ok(None);
    }
    let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let gt = read_ply(&bytes).with_context(|| format!("reading {} (--no-mesh skips the mesh metrics)", path.display()))?;
    let opts = MeshOptions { resolution, level, bbox: None, keep_ndc: false };
    let mesh = extract_mesh(&run.gpu, &mut run.model, &run.scene, &opts, &mut |_, _| {})?.mesh;
    Ok(Some(mesh_metrics(&mesh, &gt, &run.scene, &MeshMetricParams::default())?))
}

/// The per-view table and the mean row.
fn print_table(report: &EvalReport) {
    let cols = [
        ("PSNR", "psnr", 2),
        ("SSIM", "ssim", 3),
        ("LPIPSv", "lpips_vgg", 3),
        ("LPIPSa", "lpips_alex", 3),
        ("AbsRel", "depth.all.abs_rel", 3),
        ("d<1.25", "depth.all.delta_1", 3),
        ("n_mean", "normal.all.mean_deg", 1),
        ("n_med", "normal.all.median_deg", 1),
        ("n_edge", "normal.edge.mean_deg", 1),
        ("n_nonedge", "normal.non_edge.mean_deg", 1),
        ("DBEacc", "boundary.accuracy", 2),
        ("DBEcomp", "boundary.completeness", 2),
    ];
    let row = |label: &str, m: &BTreeMap<String, f64>| {
        let cells: String = cols
            .iter()
            .map(|(h, k, d)| {
                let cell = m.get(*k).map_or("-".to_string(), |x| format!("{x:.*}", *d));
                format!(" {cell:>w$}", w = h.len().max(6))
            })
            .collect();
        println!("{label:<14}{cells}");
    };
    println!(
        "rendering: {:.1} s for {} views, {:.1} field samples per ray",
        report.render_seconds,
        report.views.len(),
        report.samples_per_ray
    );
    println!(
        "{} views of {} ({} split, step {}, protocol {}, {})",
        report.views.len(),
        report.scene.display(),
        report.split,
        report.step,
        serde_json::to_value(report.protocol).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
        report.adapter
    );
    let header: String = cols.iter().map(|(h, _, _)| format!(" {h:>w$}", w = h.len().max(6))).collect();
    println!("{:<14}{header}", "view");
    for v in &report.views {
        row(&v.name, &flatten_view_metrics(v));
    }
    row("mean", &report.metrics);
    if let Some(line) = covisibility_line(&report.metrics) {
        println!("{line}");
    }
    if let Some(m) = &report.mesh {
        let d = &m.distances;
        println!(
            "mesh vs gt_mesh.ply: Chamfer {:.4} (accuracy {:.4}, completeness {:.4}); F-score {:.3} at {:.4} (precision {:.3}, recall {:.3})",
            d.chamfer, d.accuracy, d.completeness, d.fscore, d.threshold, d.precision, d.recall
        );
    }
}

/// The printed line of the covisibility split's means (`None` where no view has it):
/// per class, its mean PSNR and mean share of the pixels.
fn covisibility_line(metrics: &BTreeMap<String, f64>) -> Option<String> {
    let classes = [("none", "unseen"), ("one", "seen_once"), ("two or more", "seen_twice_or_more")];
    let cells: Vec<String> = classes
        .iter()
        .filter_map(|(label, key)| {
            let psnr = metrics.get(&format!("covisibility.{key}.psnr"))?;
            let share = metrics.get(&format!("covisibility.{key}.fraction")).copied().unwrap_or(0.0);
            Some(format!("{label} {psnr:.2} dB ({:.0} % of pixels)", 100.0 * share))
        })
        .collect();
    (!cells.is_empty()).then(|| format!("PSNR by how many training views see the surface (means over the views with such pixels): {}", cells.join(", ")))
}
