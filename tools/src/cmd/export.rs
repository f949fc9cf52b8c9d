//! `edgenerf export`: geometry out of a trained run, as binary PLY files: `mesh`
//! (marching tetrahedra on the density field, vertex colours and normals) and `points`
//! (rendered depth of chosen views back-projected, with colours and normals). The
//! geometry is the engine's (`edgenerf::train::export`); this is flags, progress and
//! files.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use edgenerf::gpu::GpuOptions;
use edgenerf::mesh::ply::{mesh_to_ply, points_to_ply};
use edgenerf::train::export::{MeshOptions, default_level, depth_points, extract_mesh};
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Subcommand)]
pub enum Command {
    /// The surface of the density field as a triangle mesh (marching tetrahedra),
    /// with vertex normals and colours.
    Mesh(MeshArgs),
    /// Rendered depth of chosen views as a coloured point cloud with normals.
    Points(PointsArgs),
}

/// What both exports read.
#[derive(clap::Args)]
pub struct RunArgs {
    /// A run directory (holding checkpoint.safetensors) or a checkpoint file.
    run: PathBuf,
    /// Scene directory (default: the path recorded in the checkpoint's config).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Override one setting of the checkpoint's config (repeatable), as for `render`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Use a --scene other than the one the run was trained on (refused otherwise).
    #[arg(long, requires = "scene")]
    allow_other_scene: bool,
    /// Replace an existing file given as --out (the default file beside the checkpoint
    /// is always replaced).
    #[arg(long)]
    overwrite: bool,
}

impl RunArgs {
    /// The run loaded for writing `out` ([`crate::cmd::render::load_run`]), then the
    /// folder of `out` created.
    fn load(&self, out: &Path, gpu_opts: &GpuOptions) -> anyhow::Result<crate::cmd::render::LoadedRun> {
        let check = crate::cmd::render::OutputCheck { out, allow_other_scene: self.allow_other_scene };
        let run = crate::cmd::render::load_run(&self.run, self.scene.as_deref(), &self.overrides, gpu_opts, check, false)?;
        if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        Ok(run)
    }
}

#[derive(clap::Args)]
pub struct MeshArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Grid cells along the longest side of the box (others: cells of the same size).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(2..=1024))]
    resolution: u32,
    /// Density level of the surface (default: ln 2 / the run's sampler step, the
    /// density at which one marching step is half opaque).
    #[arg(long, value_name = "L")]
    level: Option<f32>,
    /// Output file (default: mesh.ply beside the checkpoint).
    #[arg(long, value_name = "FILE.ply")]
    out: Option<PathBuf>,
    /// The box to mesh, `x0,y0,z0,x1,y1,z1` in the field's space (world; NDC for
    /// LLFF scenes) (default: the scene's box).
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", allow_hyphen_values = true)]
    bbox: Option<String>,
    /// LLFF scenes: write NDC coordinates instead of mapping them to world space.
    #[arg(long)]
    ndc: bool,
}

#[derive(clap::Args)]
pub struct PointsArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Which views: train, test, all, or view indices `i,j,k`.
    #[arg(long, default_value = "train")]
    views: String,
    /// Output file (default: points.ply beside the checkpoint).
    #[arg(long, value_name = "FILE.ply")]
    out: Option<PathBuf>,
    /// Pixels whose rendered opacity is below this are skipped.
    #[arg(long, default_value_t = 0.5, value_name = "A")]
    min_opacity: f32,
}

pub fn run(cmd: Command, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    match cmd {
        Command::Mesh(a) => mesh(a, gpu_opts),
        Command::Points(a) => points(a, gpu_opts),
    }
}

/// `--out`, or `name` beside the checkpoint; refuses a directory, and an existing file
/// given as `--out` without `--overwrite` (it was silently replaced).
fn out_path(args: &RunArgs, out: Option<&Path>, name: &str) -> anyhow::Result<PathBuf> {
    let run = &args.run;
    let path = match out {
        Some(p) => p.to_path_buf(),
        None => if run.is_dir() { run.to_path_buf() } else { run.parent().map(Path::to_path_buf).unwrap_or_default() }.join(name),
    };
    if path.is_dir() {
        bail!("--out {} is a directory; pass a file name such as {}", path.display(), path.join(name).display());
    }
    if out.is_some() && path.exists() && !args.overwrite {
        bail!("--out {} already exists; nothing was changed. Pass --overwrite to replace it, or another file name", path.display());
    }
    Ok(path)
}

fn parse_bbox(s: &str) -> anyhow::Result<[Vec3; 2]> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--bbox {s:?}: expected six numbers x0,y0,z0,x1,y1,z1"))?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        bail!("--bbox {s:?}: expected six finite numbers x0,y0,z0,x1,y1,z1");
    }
    let (lo, hi) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
    if !lo.cmplt(hi).all() {
        bail!("--bbox {s:?}: each lower corner coordinate must be below the upper one");
    }
    Ok([lo, hi])
}

fn bar(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    bar.set_style(ProgressStyle::with_template(&format!("{{bar:30}} {{pos}}/{{len}} {what} [{{elapsed_precise}}, ETA {{eta}}]")).unwrap());
    bar
}

fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    edgenerf::train::output::write_atomic(path, bytes).with_context(|| format!("writing {}", path.display()))
}

fn mesh(args: MeshArgs, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    let bbox = args.bbox.as_deref().map(parse_bbox).transpose()?;
    if let Some(l) = args.level
        && !(l.is_finite() && l > 0.0)
    {
        bail!("--level {l}: the density level must be a positive number");
    }
    let out = out_path(&args.run, args.out.as_deref(), "mesh.ply")?;
    let mut run = args.run.load(&out, gpu_opts)?;
    let level = args.level.unwrap_or_else(|| default_level(&run.model, &run.scene));
    let opts = MeshOptions { resolution: args.resolution, level: Some(level), bbox, keep_ndc: args.ndc };
    let [lo, hi] = bbox.unwrap_or(run.scene.aabb);
    let mut progress: Option<ProgressBar> = None;
    let x = extract_mesh(&run.gpu, &mut run.model, &run.scene, &opts, &mut |done, total| {
        progress.get_or_insert_with(|| bar(total, "density queries")).set_position(done as u64)
    })?;
    if let Some(b) = progress {
        b.finish_and_clear();
    }
    let mesh = x.mesh;
    if mesh.triangles.is_empty() {
        let [a, b] = x.density_range;
        bail!("no surface: the density never crosses level {level} inside [{lo}, {hi}] (it ranges from {a} to {b} there); pass a --level between");
    }
    let bytes = mesh_to_ply(&mesh)?;
    write(&out, &bytes)?;
    let e = mesh.edge_counts();
    let area = mesh.area();
    let [blo, bhi] = mesh.bounds().unwrap();
    let [nx, ny, nz] = x.dims;
    println!("box [{lo}, {hi}], grid {nx}x{ny}x{nz} points, density level {level:.3}{}", if args.level.is_none() { " (default: ln 2 / sampler step)" } else { "" });
    println!(
        "mesh: {} vertices, {} triangles, area {:.3}, {} border edges, {} non-manifold edges; bounds [{blo}, {bhi}]",
        mesh.positions.len(),
        mesh.triangles.len(),
        area,
        e.boundary,
        e.non_manifold
    );
    println!("wrote {} ({:.1} MB)", out.display(), bytes.len() as f64 / 1e6);
    let d = hi - lo;
    let box_area = 2.0 * f64::from(d.x * d.y + d.y * d.z + d.z * d.x);
    if area < NEARLY_EMPTY * box_area {
        let [a, b] = x.density_range;
        println!(
            "note: the surface covers {:.2} % of the box's faces' area: the density (from {a} to {b} here) crosses level {level} only at its peaks; a lower --level meshes the field's softer surfaces",
            100.0 * area / box_area
        );
    }
    Ok(())
}

/// A mesh whose area is under this fraction of its box's surface gets a note: the
/// level is above most of the field's surfaces (a 3-view forward scene's field can be
/// soft everywhere, its surfaces spread over several marching steps).
const NEARLY_EMPTY: f64 = 0.01;

/// `--views` of `points`: a split name or comma-separated view indices.
fn parse_views(scene: &edgenerf::data::Scene, s: &str) -> anyhow::Result<Vec<usize>> {
    if matches!(s, "train" | "test" | "all") {
        return crate::cmd::render::split_views(scene, s);
    }
    let n = scene.views.len();
    s.split(',')
        .map(|x| {
            let i: usize = x.trim().parse().map_err(|_| anyhow::anyhow!("--views {s:?}: expected train, test, all or view indices like 0,3,5"))?;
            if i >= n {
                bail!("--views {s:?}: view {i} does not exist (the scene has views 0 to {})", n - 1);
            }
            Ok(i)
        })
        .collect()
}

fn points(args: PointsArgs, gpu_opts: &GpuOptions) -> anyhow::Result<()> {
    if !(0.0..=1.0).contains(&args.min_opacity) {
        bail!("--min-opacity {}: must be between 0 and 1", args.min_opacity);
    }
    let out = out_path(&args.run, args.out.as_deref(), "points.ply")?;
    let mut run = args.run.load(&out, gpu_opts)?;
    let views = parse_views(&run.scene, &args.views)?;
    if views.is_empty() {
        bail!("--views {}: the scene has no such view", args.views);
    }
    let bar = bar(views.len(), "views");
    let cloud = depth_points(&run.gpu, &mut run.model, &run.scene, &views, args.min_opacity, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    let pixels: usize = views.iter().map(|&v| (run.scene.views[v].camera.width * run.scene.views[v].camera.height) as usize).sum();
    if cloud.positions.is_empty() {
        bail!("no pixel of {} view(s) reaches opacity {}; pass a lower --min-opacity", views.len(), args.min_opacity);
    }
    let bytes = points_to_ply(&cloud)?;
    write(&out, &bytes)?;
    let [lo, hi] = cloud.bounds().unwrap();
    println!(
        "points: {} of {} pixels of {} view(s) with opacity >= {}; bounds [{lo}, {hi}]",
        cloud.positions.len(),
        pixels,
        views.len(),
        args.min_opacity
    );
    println!("wrote {} ({:.1} MB)", out.display(), bytes.len() as f64 / 1e6);
    Ok(())
}
