//! The train room: the optimisation loop that ties the rooms together, checkpoints,
//! the run configuration, and rendering with a trained model.
//!
//! One step ([`Trainer::step`]: draw a batch, then [`Trainer::step_on`]; the repository's
//! `docs/ARCHITECTURE.md` shows the same flow room by room):
//! ```text
//! random 2x2 patches of `train.images_per_step` training images (1 by default), or
//!   random pixels -> rays (host)
//! occupancy grid update (every `sampler.update_interval` steps: field densities at
//!   grid query points)
//!   [+ RegNeRF: 8x8 patches from random poses appended; all ranges annealed]
//!   -> sampler (occupancy grid + BVH) -> samples
//! field forward (+ analytic normals when L_n is on) -> composite
//!   -> photometric loss L_c (+ edge-guided L_z, L_n on the patches, + depth TV on the
//!      random-pose patches; rays cut by the sample capacity dropped) -> composite
//!      backward (+ the distortion and occlusion priors when on)
//! zero grads -> field backward (second order through the normals when L_n is on)
//!   -> grad norm / NaN check / clip -> Adam (GPU)
//! ```
//! The total loss is `lambda1 L_c + lambda2 L_z + lambda3 L_n + lambda_tv L_tv` (see
//! [`crate::loss::edge_reg`], [`crate::loss::depth_tv`] and [`regnerf`]); the random-pose
//! rays follow the photometric batch in the same sample batch, with zero photometric
//! weight, so one forward and one backward pass serve every term; the edge masks of the training views are given by the
//! caller (e.g. from a cache next to the run) or computed once, at the first step that
//! draws patches, so rendering a checkpoint never computes them.
//! The host waits for the GPU at up to seven small readbacks per step, for logging and
//! the NaN guard: after the losses, the rays dropped for the capacity, the batch's
//! squared errors and, when their terms are on, the edge-guided losses, the depth TV
//! and the priors' per-ray terms; after Adam, the gradient statistics and the sample
//! count. An occupancy grid update reads its bitfield and density sum as well.
//!
//! Invariants:
//! * A step whose loss or gradients are not finite changes no parameter (the loss is
//!   read back before the backward pass; Adam skips non-finite gradients on the GPU)
//!   and is reported as [`TrainError::NonFinite`];
//!   the caller stops and keeps the last good checkpoint.
//! * Runs are deterministic given the config (seeded pixel choice, jitter, grid
//!   cells), up to the order of float atomic adds on the GPU.
//! * Checkpoints hold everything needed to resume: parameters, Adam state, step,
//!   config and the occupancy grid's densities, which [`Trainer::resume`] restores (so
//!   a resumed or rendered run skips exactly the space training skipped); only a
//!   checkpoint without them (uniform sampling, older files) has its grid rebuilt from
//!   the field.

pub mod checkpoint;
pub mod config;
pub mod model;
pub mod profile;
pub mod random_poses;
pub mod rays;
pub mod regnerf;

use std::path::{Path, PathBuf};

use crate::data::{Camera, DataError, Scene, SceneFormat};
use crate::edges::{EdgeError, EdgeMask};
use crate::field::FieldError;
use crate::gpu::{Gpu, GpuBuffer, GpuError};
use crate::loss::{DepthTv, DropTruncated, EdgeReg, EdgeRegLosses, Photometric, photometric::psnr};
use crate::metrics::MetricsError;
use crate::metrics::geometry::{DepthErrors, GeometryInputs, GeometryMetrics, GeometryParams, NormalErrors, Regions, evaluate_geometry};
use crate::metrics::image::image_metrics;
use crate::optim::{Adam, GradNorm, OptimError, ParamGroup};
use crate::render::{Background, RenderConfig, RenderError, Renderer, random_background};
use crate::sampler::{SamplerError, SamplerMode};
use crate::samples::{self as samples_gpu, FieldGrads, RayOutput};

pub use checkpoint::Checkpoint;
pub use config::{Backend, BatchKind, LevelAnneal, RunConfig, SceneConfig, TrainConfig};
pub use model::{Model, RenderedView};
pub use profile::{Stage, StageTimes};
pub use regnerf::RegNerfConfig;

use model::BatchBuffers;

/// Errors of training and rendering runs.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Field(#[from] FieldError),
    #[error(transparent)]
    Sampler(#[from] SamplerError),
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Optim(#[from] OptimError),
    #[error("edge maps: {0}")]
    Edges(#[from] EdgeError),
    #[error("evaluation: {0}")]
    Metrics(#[from] MetricsError),
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("configuration from {source_name}: {message}")]
    Config { source_name: String, message: String },
    #[error("checkpoint {path}: {message}")]
    Checkpoint { path: PathBuf, message: String },
    #[error(
        "training diverged at step {step}: {what} is not finite; no parameter was updated by this step. \
         Lower the learning rate (optim.schedule) or enable gradient clipping (optim.clip.max_norm)"
    )]
    NonFinite { step: u64, what: String },
}

impl TrainError {
    pub fn io(path: &Path, e: std::io::Error) -> TrainError {
        TrainError::Io { path: path.to_path_buf(), message: e.to_string() }
    }
}

/// What one step did (for progress display and logs).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct StepStats {
    pub step: u64,
    /// Total loss `lambda1 L_c + lambda2 L_z + lambda3 L_n + lambda_tv L_tv + lambda_dist L_dist + lambda_occ L_occ` with this step's weights.
    pub loss: f32,
    /// Photometric `L_c` (mean squared error) and the PSNR of the batch from it.
    pub loss_color: f32,
    pub psnr: f32,
    /// Unweighted `L_z` and `L_n` (0 when inactive) and the weights they entered with.
    pub loss_depth: f32,
    pub loss_normal: f32,
    pub lambda_depth: f32,
    pub lambda_normal: f32,
    pub lr: f32,
    pub grad_norm: f32,
    /// Samples evaluated, and their mean per ray.
    pub samples: u32,
    pub samples_per_ray: f32,
    /// Samples the rays wanted beyond the batch capacity (0 when nothing was cut).
    pub samples_truncated: u32,
    /// Fraction of the occupancy grid's cells marked occupied as of this step (1 before
    /// the first update, and in uniform mode, where the grid is never updated).
    pub occupied_fraction: f32,
    /// RegNeRF's depth TV on the random-pose patches (0 when inactive) and its weight.
    pub loss_tv: f32,
    pub lambda_tv: f32,
    /// Photometric rays the sample capacity cut, dropped from the losses
    /// ([`crate::loss::truncated`]); `loss_color` and `psnr` are over the others.
    pub rays_dropped: u32,
    /// The sparse-view priors ([`crate::render::priors`]; 0 when off), unweighted: mip-NeRF
    /// 360's distortion and FreeNeRF's occlusion term.
    pub loss_distortion: f32,
    pub loss_occlusion: f32,
    /// Samples the step's batch could hold ([`crate::train::TrainConfig::grow_capacity`]
    /// raises it for the next step when rays were cut).
    pub sample_capacity: u32,
}

impl StepStats {
    /// Header of the per-step CSV log (`log.csv`), matching [`StepStats::csv_row`].
    pub const CSV_HEADER: &'static str = "step,loss,loss_color,loss_depth,loss_normal,lambda_depth,lambda_normal,psnr,lr,grad_norm,samples,samples_per_ray,samples_truncated,elapsed_s,loss_tv,lambda_tv,rays_dropped,occupied_fraction,sample_capacity,loss_distortion,loss_occlusion";

    /// One CSV row, `elapsed_s` since the start of the run inserted where the header
    /// has it (later columns were appended after it, so older logs stay a prefix).
    pub fn csv_row(&self, elapsed_s: f64) -> String {
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{},{},{},{},{},{},{}",
            self.step,
            self.loss,
            self.loss_color,
            self.loss_depth,
            self.loss_normal,
            self.lambda_depth,
            self.lambda_normal,
            self.psnr,
            self.lr,
            self.grad_norm,
            self.samples,
            self.samples_per_ray,
            self.samples_truncated,
            elapsed_s,
            self.loss_tv,
            self.lambda_tv,
            self.rays_dropped,
            self.occupied_fraction,
            self.sample_capacity,
            self.loss_distortion,
            self.loss_occlusion
        )
    }
}

/// Test-view evaluation: per view, and means over views (geometry means over the views
/// that have ground truth; see [`crate::metrics`] for the definitions).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Evaluation {
    pub per_view: Vec<ViewEvaluation>,
    /// Mean of the per-view PSNRs (the convention of NeRF papers), and of the SSIMs.
    pub mean_psnr: f32,
    pub mean_ssim: f32,
    /// Field samples per pixel ray of the test renders (the sampler's cost at render time).
    pub mean_samples_per_ray: f32,
    /// Mean absolute depth error (world units) over all GT pixels, outside and inside
    /// the GT edge band (within `dilate_px` of a GT depth/normal discontinuity).
    pub mean_depth_abs_error: Option<f32>,
    pub mean_depth_abs_error_non_edge: Option<f32>,
    pub mean_depth_abs_error_edge: Option<f32>,
    pub mean_depth_abs_rel: Option<f32>,
    /// Mean normal angle (degrees), likewise split.
    pub mean_normal_angle_deg: Option<f32>,
    pub mean_normal_angle_deg_non_edge: Option<f32>,
    pub mean_normal_angle_deg_edge: Option<f32>,
    /// iBims-1 depth boundary error (pixels): accuracy and completeness.
    pub mean_dbe_accuracy: Option<f32>,
    pub mean_dbe_completeness: Option<f32>,
}

/// One rendered test view against its image and, where the scene has them, its
/// ground-truth depth and normals.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewEvaluation {
    pub view: usize,
    pub psnr: f32,
    pub ssim: f32,
    /// Field samples per pixel ray of this render.
    pub samples_per_ray: f32,
    /// Geometry against ground truth (scenes with GT depth or normals; depth only for
    /// world-space scenes). The rendered depth is [`RenderedView::terminated_depth`]
    /// (expected ray distance given termination), the normals the renormalised
    /// rendered ones.
    pub geometry: Option<GeometryMetrics>,
}

fn mean_of(values: impl Iterator<Item = Option<f64>>) -> Option<f32> {
    let v: Vec<f64> = values.flatten().collect();
    (!v.is_empty()).then(|| (v.iter().sum::<f64>() / v.len() as f64) as f32)
}

/// Compares a rendered view with the image and ground truth of `scene.views[v]`.
pub fn evaluate_view(scene: &Scene, v: usize, r: &RenderedView) -> Result<ViewEvaluation, MetricsError> {
    let view = &scene.views[v];
    let rgb: Vec<f32> = r.rgb.iter().flatten().copied().collect();
    let image = image_metrics(r.width, r.height, &rgb, &view.image.data)?;
    let gt_depth = view.depth.as_deref().filter(|_| scene.ndc.is_none());
    let gt_normal = view.normal.as_deref();
    let geometry = if gt_depth.is_some() || gt_normal.is_some() {
        let depth = r.terminated_depth(scene.far);
        let normal = r.unit_normals();
        Some(evaluate_geometry(
            &GeometryInputs {
                width: r.width,
                height: r.height,
                gt_depth,
                gt_normal,
                depth: gt_depth.map(|_| depth.as_slice()),
                normal: gt_normal.map(|_| normal.as_slice()),
            },
            &GeometryParams::default(),
        )?)
    } else {
        None
    };
    let samples_per_ray = r.samples as f32 / (r.width * r.height).max(1) as f32;
    Ok(ViewEvaluation { view: v, psnr: image.psnr as f32, ssim: image.ssim as f32, samples_per_ray, geometry })
}

impl Evaluation {
    /// Means over `per_view`.
    pub fn new(per_view: Vec<ViewEvaluation>) -> Evaluation {
        let geo = || per_view.iter().filter_map(|e| e.geometry.as_ref());
        let depth = |f: fn(&Regions<DepthErrors>) -> Option<f64>| mean_of(geo().map(|g| g.depth.as_ref().and_then(f)));
        let normal = |f: fn(&Regions<NormalErrors>) -> Option<f64>| mean_of(geo().map(|g| g.normal.as_ref().and_then(f)));
        Evaluation {
            mean_psnr: mean_of(per_view.iter().map(|e| Some(e.psnr as f64))).unwrap_or(0.0),
            mean_ssim: mean_of(per_view.iter().map(|e| Some(e.ssim as f64))).unwrap_or(0.0),
            mean_samples_per_ray: mean_of(per_view.iter().map(|e| Some(e.samples_per_ray as f64))).unwrap_or(0.0),
            mean_depth_abs_error: depth(|d| d.all.map(|e| e.abs)),
            mean_depth_abs_error_non_edge: depth(|d| d.non_edge.map(|e| e.abs)),
            mean_depth_abs_error_edge: depth(|d| d.edge.map(|e| e.abs)),
            mean_depth_abs_rel: depth(|d| d.all.map(|e| e.abs_rel)),
            mean_normal_angle_deg: normal(|n| n.all.map(|e| e.mean_deg)),
            mean_normal_angle_deg_non_edge: normal(|n| n.non_edge.map(|e| e.mean_deg)),
            mean_normal_angle_deg_edge: normal(|n| n.edge.map(|e| e.mean_deg)),
            mean_dbe_accuracy: mean_of(geo().map(|g| g.boundary.as_ref().map(|b| b.accuracy))),
            mean_dbe_completeness: mean_of(geo().map(|g| g.boundary.as_ref().map(|b| b.completeness))),
            per_view,
        }
    }
}

/// The optimisation loop of one run.
pub struct Trainer {
    pub gpu: Gpu,
    pub scene: Scene,
    pub model: Model,
    adam: Adam,
    grad_norm: GradNorm,
    photometric: Photometric,
    drop_truncated: DropTruncated,
    edge_reg: EdgeReg,
    depth_tv: DepthTv,
    /// RegNeRF's pool of random poses (when its depth TV is on).
    tv_poses: Vec<Camera>,
    /// Rays of the random-pose patches appended to each batch (0: none).
    n_tv: u32,
    /// Edge mask of each training view (`scene.split.train` order); computed at the
    /// first step that draws patches unless given (rendering never needs them).
    edge_masks: Option<Vec<EdgeMask>>,
    bufs: BatchBuffers,
    /// Renders training batches over random backgrounds (images with alpha and
    /// `train.random_background`); `None`: the model's own renderer.
    random_bg_renderer: Option<Renderer>,
    targets: GpuBuffer<[f32; 4]>,
    d_rays: GpuBuffer<RayOutput>,
    field_grads: FieldGrads,
    step: u64,
    /// Per-stage timing ([`profile`]); `None`: off.
    profile: Option<StageTimes>,
}

impl Trainer {
    /// A new run on `scene` with `config` (the scene path in the config is informative);
    /// the edge masks are computed from `config.edges` when the regularizers need them.
    pub fn new(gpu: Gpu, scene: Scene, config: RunConfig) -> Result<Trainer, TrainError> {
        Self::with_edge_masks(gpu, scene, config, None)
    }

    /// Whether a run with `config` on `scene` reads edge masks.
    pub fn needs_edge_masks(config: &RunConfig, scene: &Scene) -> bool {
        config.train.batch == BatchKind::Patches && config.reg.any(is_dtu(scene))
    }

    /// [`Trainer::new`] with the training views' edge masks given (`scene.split.train`
    /// order), e.g. read from a cache; `None`: computed here when needed.
    pub fn with_edge_masks(gpu: Gpu, scene: Scene, mut config: RunConfig, masks: Option<Vec<EdgeMask>>) -> Result<Trainer, TrainError> {
        config.resolve();
        // The scene decides lambda3's default (0.001 on DTU): record the value in effect,
        // so that config.json and the checkpoint say what ran, not `null`.
        config.reg.lambda_normal = Some(config.reg.lambda_normal_for(is_dtu(&scene)));
        config.regnerf.resolve_for(&scene);
        config.optim.validate()?;
        let config_error = |message: String| TrainError::Config { source_name: "config".into(), message };
        // Every range, reg / regnerf / priors and the batch sizes included.
        config.validate().map_err(config_error)?;
        config.check_paths().map_err(config_error)?;
        if scene.split.train.is_empty() {
            return Err(TrainError::Config { source_name: "scene".into(), message: "no training views".into() });
        }
        if let Some(m) = &masks {
            let (w, h) = scene.image_size();
            if m.len() != scene.split.train.len() || m.iter().any(|m| (m.width, m.height) != (w, h)) {
                return Err(config_error(format!(
                    "{} edge masks given for {} training views of {w}x{h} (sizes {:?})",
                    m.len(),
                    scene.split.train.len(),
                    m.iter().map(|m| (m.width, m.height)).collect::<Vec<_>>()
                )));
            }
        }
        let mut model = Model::new(&gpu, &scene, config.clone())?;
        let adam = Adam::for_groups(&gpu, &model.field.params(), config.optim.adam.clone())?;
        let n = config.train.rays_per_batch;
        let r = &config.regnerf;
        let n_tv = r.patches(n) * r.patch_size * r.patch_size;
        let tv_poses = if n_tv > 0 {
            random_poses::random_poses(&scene, r.pose_kind_for(&scene), r.n_poses, config.train.seed)
        } else {
            Vec::new()
        };
        // The random-pose rays get the photometric rays' share of samples.
        let n_all = n + n_tv;
        let capacity = (config.train.max_samples as u64 * n_all as u64 / n.max(1) as u64).min(u32::MAX as u64) as u32;
        let has_alpha = scene.train_views().any(|v| v.alpha.is_some());
        // The priors apply to every rendered ray of a batch, random-pose rays included.
        let priors = config.priors.weights(n_all, scene.near, scene.far);
        model.renderer.set_priors(priors);
        let random_bg_renderer = (config.train.random_background && has_alpha)
            .then(|| -> Result<Renderer, TrainError> {
                let mut r = Renderer::new(&gpu, RenderConfig { background: Background::Random, ..*model.renderer.config() })?;
                r.set_priors(priors);
                Ok(r)
            })
            .transpose()?;
        Ok(Trainer {
            random_bg_renderer,
            grad_norm: GradNorm::new(&gpu)?,
            photometric: Photometric::new(&gpu, n_all)?,
            drop_truncated: DropTruncated::new(&gpu)?,
            edge_reg: EdgeReg::new(&gpu, n / 4)?,
            depth_tv: DepthTv::new(&gpu, n_tv)?,
            tv_poses,
            n_tv,
            edge_masks: masks,
            bufs: BatchBuffers::new(&gpu, n_all, capacity)?,
            targets: GpuBuffer::zeros(&gpu, "targets", n_all as usize)?,
            d_rays: GpuBuffer::zeros(&gpu, "d rays", n_all as usize)?,
            field_grads: FieldGrads::new(&gpu, capacity)?,
            gpu,
            scene,
            model,
            adam,
            step: 0,
            profile: None,
        })
    }

    /// Resumes from a checkpoint: parameters, optimizer state and step; the occupancy
    /// grid gets the checkpoint's densities (so renders skip what training skipped), or
    /// is rebuilt from the restored field where the checkpoint has none. `masks` as in [`Trainer::with_edge_masks`].
    pub fn resume(gpu: Gpu, scene: Scene, ckpt: Checkpoint, masks: Option<Vec<EdgeMask>>) -> Result<Trainer, TrainError> {
        let mut t = Trainer::with_edge_masks(gpu, scene, ckpt.config, masks)?;
        t.model.field.import(&t.gpu, &ckpt.field)?;
        t.adam.import_state(&t.gpu, &ckpt.optimizer)?;
        t.step = ckpt.step;
        match &ckpt.occupancy {
            Some(density) if t.config().sampler.mode == SamplerMode::Occupancy => {
                t.model.grid.restore_density(&t.gpu, density)?;
            }
            _ => {
                t.model.update_grid(&t.gpu, t.step, t.grid_seed(), true)?;
            }
        }
        Ok(t)
    }

    pub fn config(&self) -> &RunConfig {
        &self.model.config
    }

    /// Steps done so far.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    fn grid_seed(&self) -> u32 {
        (self.config().train.seed as u32).wrapping_mul(0x9E37_79B9) ^ (self.step as u32)
    }

    fn apply_level_anneal(&mut self) {
        let levels = self.model.field.encoding_levels();
        if let Some(a) = &self.model.config.train.level_anneal
            && levels > 0
        {
            let frac = if a.steps == 0 { 1.0 } else { (self.step as f64 / a.steps as f64).min(1.0) };
            let start = a.start_levels.min(levels) as f64;
            let active = (start + frac * (levels as f64 - start)).floor() as u32;
            self.model.field.set_active_levels(active.max(1));
        }
    }

    /// One optimisation step (see the module doc).
    pub fn step(&mut self) -> Result<StepStats, TrainError> {
        if let Some(p) = &mut self.profile {
            p.begin();
        }
        let batch = self.draw_batch()?;
        self.end_stage(Stage::Batch)?;
        self.step_on(batch)
    }

    /// Switches per-stage timing on (from zero) or off; see [`profile`].
    pub fn set_profiling(&mut self, on: bool) {
        self.profile = on.then(StageTimes::default);
    }

    /// The stage times accumulated since profiling was switched on.
    pub fn stage_times(&self) -> Option<&StageTimes> {
        self.profile.as_ref()
    }

    /// With profiling on, waits for the GPU and charges the time since the last stage
    /// to `stage`.
    fn end_stage(&mut self, stage: Stage) -> Result<(), TrainError> {
        if let Some(p) = &mut self.profile {
            self.gpu.wait()?;
            p.end(stage);
        }
        Ok(())
    }

    /// The batch [`Trainer::step`] trains on next: 2x2 patches with their edge masks or
    /// single pixels, as `train.batch` says, and RegNeRF's random-pose patches when its
    /// depth TV is on (a pure function of the seed and step).
    pub fn draw_batch(&mut self) -> Result<rays::PixelBatch, TrainError> {
        let mut batch = self.draw_photometric_batch()?;
        (batch.tv_rays, batch.tv_z_scale) = self.draw_tv_patches();
        Ok(batch)
    }

    /// RegNeRF's random-pose patches of this step (empty when its depth TV is off).
    fn draw_tv_patches(&self) -> (Vec<samples_gpu::GpuRay>, Vec<f32>) {
        if self.n_tv == 0 {
            return (Vec::new(), Vec::new());
        }
        let (r, seed) = (&self.config().regnerf, self.config().train.seed);
        let n_patches = self.n_tv / (r.patch_size * r.patch_size);
        random_poses::patch_rays(&self.scene, &self.tv_poses, n_patches, r.patch_size, seed, self.step)
    }

    fn draw_photometric_batch(&mut self) -> Result<rays::PixelBatch, TrainError> {
        let (step, seed) = (self.step, self.config().train.seed);
        let n = self.config().train.rays_per_batch;
        if self.config().train.batch == BatchKind::Pixels {
            return Ok(rays::random_pixels(&self.scene, n, seed, step));
        }
        if self.edge_masks.is_none() {
            self.edge_masks = Some(if Self::needs_edge_masks(&self.model.config, &self.scene) {
                crate::edges::edge_masks(&self.scene, &self.scene.split.train, &self.model.config.edges)?
            } else {
                let (w, h) = self.scene.image_size();
                vec![EdgeMask::all_non_edge(w, h); self.scene.split.train.len()]
            });
        }
        let masks = self.edge_masks.as_deref().expect("computed above");
        Ok(rays::random_patches(&self.scene, masks, n / 4, self.config().train.images_per_step, seed, step))
    }

    /// One optimisation step on a given batch of `train.rays_per_batch` rays (patch
    /// batches carry their edge masks in [`rays::PixelBatch::reg`]; the regularizers
    /// run on them when `train.batch` is `patches`). With RegNeRF's depth TV on, the
    /// batch's random-pose patches are used, or drawn for the step when it has none.
    pub fn step_on(&mut self, mut batch: rays::PixelBatch) -> Result<StepStats, TrainError> {
        let gpu = self.gpu.clone();
        let step = self.step;
        let seed = self.config().train.seed;
        let n = self.config().train.rays_per_batch;
        if batch.rays.len() != n as usize || batch.targets.len() != n as usize {
            return Err(TrainError::Config {
                source_name: "batch".into(),
                message: format!("{} rays given, train.rays_per_batch is {n}", batch.rays.len()),
            });
        }
        self.apply_level_anneal();
        self.model.update_grid(&gpu, step, self.grid_seed(), false)?;
        self.end_stage(Stage::OccupancyGrid)?;
        let patches = self.config().train.batch == BatchKind::Patches && batch.reg.len() == n as usize;
        let reg = if patches { self.config().reg.weights_at(step, is_dtu(&self.scene)) } else { None };
        let normals = reg.is_some_and(|w| w.lambda_normal > 0.0);
        if reg.is_some() {
            self.edge_reg.pixel.write(&gpu, &batch.reg);
        }
        let bg_seed = step as u32;
        if self.random_bg_renderer.is_some() {
            let loaded_over = self.scene.background.unwrap_or([1.0; 3]);
            batch.recomposite(loaded_over, |ray| random_background(bg_seed, ray));
        }
        // RegNeRF: the random-pose patches follow the photometric rays, with zero
        // photometric weight; every range is annealed.
        let n_tv = self.n_tv;
        let tv_weight = self.config().regnerf.tv_weight_at(step).filter(|_| n_tv > 0);
        let mut rays = batch.rays.clone();
        let mut targets = batch.targets.clone();
        if n_tv > 0 {
            if batch.tv_rays.is_empty() {
                (batch.tv_rays, batch.tv_z_scale) = self.draw_tv_patches();
            }
            if batch.tv_rays.len() != n_tv as usize || batch.tv_z_scale.len() != n_tv as usize {
                return Err(TrainError::Config {
                    source_name: "batch".into(),
                    message: format!("{} random-pose patch rays given, the regnerf settings make {n_tv}", batch.tv_rays.len()),
                });
            }
            rays.extend_from_slice(&batch.tv_rays);
            targets.resize(rays.len(), [0.0; 4]);
            self.depth_tv.z_scale.write(&gpu, &batch.tv_z_scale);
        }
        if let Some(anneal) = self.config().regnerf.anneal_for(&self.scene) {
            anneal.apply(&mut rays, step);
        }
        let n_all = n + n_tv;
        self.bufs.rays.write(&gpu, &rays);
        self.targets.write(&gpu, &targets);
        let jitter = (crate::rng::SplitMix64::mixed(seed ^ step.rotate_left(17)).next_u32()) | 1;
        self.model.sample(&gpu, &self.bufs, Some(jitter))?;
        self.end_stage(Stage::Sampler)?;
        self.model.field.forward(&gpu, &self.bufs.batch, &self.bufs.field_out, normals)?;
        self.end_stage(Stage::FieldForward)?;

        let bufs = &self.bufs;
        let renderer = self.random_bg_renderer.as_ref().unwrap_or(&self.model.renderer);
        let mut enc = gpu.encoder();
        // Rays cut by the sample capacity render without their far samples: out of
        // every loss (their weight and their patch's edge weight to 0).
        let wanted = self.model.sampler.wanted_counts();
        if let Some(wanted) = wanted {
            let pixels = reg.is_some().then_some(&self.edge_reg.pixel);
            self.drop_truncated.record(&mut enc, &bufs.batch.ranges, wanted, &self.targets, pixels, n);
        }
        renderer.forward(&mut enc, &bufs.batch, &bufs.field_out, &bufs.render_out, bg_seed)?;
        let lambda_color = self.config().reg.lambda_color;
        self.photometric.record(&mut enc, &bufs.render_out.rays, &self.targets, &self.d_rays, n_all, n as f32, lambda_color);
        if let Some(w) = &reg {
            self.edge_reg.record(&mut enc, &bufs.render_out.rays, &self.d_rays, n / 4, w);
        }
        let regnerf = &self.model.config.regnerf;
        if let Some(lambda) = tv_weight {
            let acc_weight = regnerf.acc_weight_for(&self.scene);
            self.depth_tv.record(&mut enc, &bufs.render_out.rays, &bufs.rays, &self.d_rays, n, n_tv, regnerf.patch_size, lambda, acc_weight);
        }
        renderer.backward(
            &mut enc,
            &bufs.batch,
            &bufs.field_out,
            &bufs.render_out,
            &self.d_rays,
            &self.field_grads,
            false,
        )?;
        enc.submit();
        // The loss is checked before anything touches the parameters: a non-finite
        // loss need not give non-finite gradients (activations can flush NaN), so
        // Adam's own skip of non-finite gradients is not enough on its own.
        let rays_dropped = if wanted.is_some() { self.drop_truncated.dropped(&gpu)? } else { 0 };
        let mse = self.photometric.mse(&gpu, n as usize, n.saturating_sub(rays_dropped).max(1) as f32)?;
        let reg_losses = if reg.is_some() { self.edge_reg.losses(&gpu, n / 4)? } else { EdgeRegLosses::default() };
        let loss_tv = if tv_weight.is_some() { self.depth_tv.loss(&gpu, n_tv)? } else { 0.0 };
        let priors = *renderer.priors();
        let (loss_distortion, loss_occlusion) =
            if self.config().priors.active() { priors.losses(&bufs.render_out.aux.read(&gpu)?) } else { (0.0, 0.0) };
        for (value, what) in [
            (mse, "the photometric loss"),
            (reg_losses.depth, "L_z"),
            (reg_losses.normal, "L_n"),
            (loss_tv, "the depth TV"),
            (loss_distortion, "the distortion prior"),
            (loss_occlusion, "the occlusion prior"),
        ] {
            if !value.is_finite() {
                self.step += 1;
                return Err(TrainError::NonFinite { step, what: what.into() });
            }
        }
        self.end_stage(Stage::RenderAndLosses)?;
        self.model.field.zero_grads(&gpu);
        self.model.field.backward(&gpu, &self.bufs.batch, &self.field_grads, normals)?;
        self.end_stage(Stage::FieldBackward)?;

        // Schedules count steps from 1 (mip-NeRF convention).
        let lr = self.config().optim.schedule.lr(step + 1);
        let clip = self.config().optim.clip;
        let groups: Vec<ParamGroup> = self.model.field.params();
        let mut enc = gpu.encoder();
        self.grad_norm.record(&gpu, &mut enc, &ParamGroup::grads_of(&groups), &clip)?;
        self.adam.record_step(&gpu, &mut enc, &groups, lr, Some(&self.grad_norm))?;
        enc.submit();

        let grad = self.grad_norm.read(&gpu)?;
        let counts = self.bufs.batch.count.read(&gpu)?;
        self.end_stage(Stage::Optimizer)?;
        if let Some(p) = &mut self.profile {
            p.steps += 1;
            p.field_samples += counts[0] as u64;
        }
        self.step += 1;
        let sample_capacity = self.bufs.batch.capacity;
        if self.config().train.grow_capacity {
            self.grow_capacity(counts[1])?;
        }
        if !grad.all_finite() {
            return Err(TrainError::NonFinite { step, what: format!("the gradient ({} non-finite entries)", grad.nonfinite) });
        }
        let n_cells = self.config().sampler.resolution.pow(3) as f32;
        let (lambda_depth, lambda_normal) = reg.map_or((0.0, 0.0), |w| (w.lambda_depth, w.lambda_normal));
        let lambda_tv = tv_weight.unwrap_or(0.0);
        Ok(StepStats {
            step,
            loss: lambda_color * mse
                + lambda_depth * reg_losses.depth
                + lambda_normal * reg_losses.normal
                + lambda_tv * loss_tv
                + priors.lambda_distortion * loss_distortion
                + priors.lambda_occlusion * loss_occlusion,
            loss_color: mse,
            psnr: psnr(mse),
            loss_depth: reg_losses.depth,
            loss_normal: reg_losses.normal,
            lambda_depth,
            lambda_normal,
            lr,
            grad_norm: grad.raw_norm,
            samples: counts[0],
            samples_per_ray: counts[0] as f32 / n_all as f32,
            samples_truncated: counts[1].saturating_sub(counts[0]),
            occupied_fraction: self.model.grid.occupied_cells() as f32 / n_cells,
            loss_tv,
            lambda_tv,
            rays_dropped,
            sample_capacity,
            loss_distortion,
            loss_occlusion,
        })
    }

    /// Samples a step's batch holds before rays are cut.
    pub fn sample_capacity(&self) -> u32 {
        self.bufs.batch.capacity
    }

    /// Grows the batch buffers when a step's rays wanted `wanted` samples, more than the
    /// capacity ([`TrainConfig::grow_capacity`]): to 1.25x `wanted`, rounded up to whole
    /// 4096-sample blocks, at most what one storage binding of the device holds. The
    /// capacity never shrinks (one reallocation per new peak, not one per step).
    fn grow_capacity(&mut self, wanted: u32) -> Result<(), TrainError> {
        let capacity = self.bufs.batch.capacity;
        let limit = (self.gpu.limits().max_storage_buffer_binding_size / std::mem::size_of::<samples_gpu::GpuSample>() as u64)
            .min(u32::MAX as u64) as u32;
        if wanted <= capacity || capacity >= limit {
            return Ok(());
        }
        let grown = (wanted as u64 * 5 / 4).next_multiple_of(4096).min(limit as u64) as u32;
        let n_all = self.bufs.batch.n_rays;
        self.bufs = BatchBuffers::new(&self.gpu, n_all, grown)?;
        self.field_grads = FieldGrads::new(&self.gpu, grown)?;
        log::info!("step {}: rays wanted {wanted} samples, above the capacity {capacity}; capacity now {grown}", self.step);
        Ok(())
    }

    /// A checkpoint of the current state (reads the GPU).
    pub fn checkpoint(&self) -> Result<Checkpoint, TrainError> {
        Ok(Checkpoint {
            step: self.step,
            config: self.config().clone(),
            field: self.model.field.export(&self.gpu)?,
            optimizer: self.adam.export_state(&self.gpu)?,
            occupancy: self.model.grid.export_density(&self.gpu)?,
        })
    }

    /// Renders every test view and measures PSNR against the images.
    pub fn evaluate(&mut self) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
        evaluate(&self.gpu, &mut self.model, &self.scene)
    }
}

/// DTU scenes take the paper's DTU default of `lambda3`.
fn is_dtu(scene: &Scene) -> bool {
    matches!(scene.format, SceneFormat::DtuIdr | SceneFormat::DtuPixelNerf)
}

/// Renders the test views of `scene` with `model` and measures each against its image
/// and ground truth.
pub fn evaluate(gpu: &Gpu, model: &mut Model, scene: &Scene) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
    let mut per_view = Vec::new();
    let mut renders = Vec::new();
    for &v in &scene.split.test {
        let r = model.render_view(gpu, scene, v)?;
        per_view.push(evaluate_view(scene, v, &r)?);
        renders.push((v, r));
    }
    Ok((Evaluation::new(per_view), renders))
}
