//! The train room: the optimisation loop that ties the rooms together, checkpoints,
//! the run configuration, and rendering with a trained model.
//!
//! One step ([`Trainer::step`]):
//! ```text
//! occupancy grid update (every 16 steps: field densities at grid query points)
//! random training pixels -> rays (host) -> sampler (occupancy grid + BVH) -> samples
//! field forward -> composite -> photometric loss -> composite backward
//! zero grads -> field backward -> grad norm / NaN check / clip -> Adam (GPU)
//! ```
//! The host reads back one small set of numbers per step (the batch's squared errors,
//! the gradient statistics and the sample count) for logging and the NaN guard.
//!
//! Invariants:
//! * A step whose loss or gradients are not finite changes no parameter (the loss is
//!   read back before the backward pass; Adam skips non-finite gradients on the GPU)
//!   and is reported as [`TrainError::NonFinite`];
//!   the caller stops and keeps the last good checkpoint.
//! * Runs are deterministic given the config (seeded pixel choice, jitter, grid
//!   cells), up to the order of float atomic adds on the GPU.
//! * Checkpoints hold everything needed to resume: parameters, Adam state, step and
//!   config; the occupancy grid is rebuilt from the field on load.

pub mod checkpoint;
pub mod config;
pub mod model;
pub mod rays;

use std::path::{Path, PathBuf};

use crate::data::{DataError, Scene};
use crate::field::FieldError;
use crate::gpu::{Gpu, GpuBuffer, GpuError};
use crate::loss::{Photometric, photometric::psnr};
use crate::optim::{Adam, GradNorm, OptimError, ParamGroup};
use crate::render::{Background, RenderConfig, RenderError, Renderer, random_background};
use crate::sampler::SamplerError;
use crate::samples::{FieldGrads, RayOutput};

pub use checkpoint::Checkpoint;
pub use config::{Backend, LevelAnneal, RunConfig, SceneConfig, TrainConfig};
pub use model::{Model, RenderedView};

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
    pub loss: f32,
    pub psnr: f32,
    pub lr: f32,
    pub grad_norm: f32,
    /// Samples evaluated, and their mean per ray.
    pub samples: u32,
    pub samples_per_ray: f32,
    /// Samples the rays wanted beyond the batch capacity (0 when nothing was cut).
    pub samples_truncated: u32,
    /// Occupied fraction of the occupancy grid after this step's update, if any.
    pub occupied_fraction: Option<f32>,
}

/// Test-view evaluation.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Evaluation {
    pub per_view: Vec<ViewEvaluation>,
    /// Mean of the per-view PSNRs (the convention of NeRF papers).
    pub mean_psnr: f32,
    /// Means over the views that have ground truth (see [`ViewEvaluation`]).
    pub mean_depth_abs_error: Option<f32>,
    pub mean_normal_angle_deg: Option<f32>,
}

/// One rendered test view against its image and, where the scene has them, its
/// ground-truth depth and normals.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewEvaluation {
    pub view: usize,
    pub psnr: f32,
    /// Mean |rendered - GT ray distance| over pixels with GT depth (world units;
    /// world-space scenes only). The rendered distance is
    /// [`RenderedView::terminated_depth`], the expected distance given termination.
    pub depth_abs_error: Option<f32>,
    /// Mean angle in degrees between the renormalised rendered normal and the GT
    /// normal, over pixels with a GT normal.
    pub normal_angle_deg: Option<f32>,
}

fn mean_of(values: impl Iterator<Item = Option<f32>>) -> Option<f32> {
    let v: Vec<f32> = values.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f32>() / v.len() as f32)
}

/// Compares a rendered view with the image and ground truth of `scene.views[v]`.
pub fn evaluate_view(scene: &Scene, v: usize, r: &RenderedView) -> ViewEvaluation {
    let view = &scene.views[v];
    let img = &view.image.data;
    let mut se = 0.0f64;
    for (p, px) in r.rgb.iter().enumerate() {
        for c in 0..3 {
            se += ((px[c] - img[3 * p + c]) as f64).powi(2);
        }
    }
    let mse = se / (3 * r.rgb.len()).max(1) as f64;
    let depth_abs_error = view.depth.as_ref().filter(|_| scene.ndc.is_none()).and_then(|gt| {
        let errs: Vec<f64> =
            gt.iter().zip(&r.terminated_depth(scene.far)).filter(|(g, _)| **g > 0.0).map(|(g, d)| (*d - *g).abs() as f64).collect();
        (!errs.is_empty()).then(|| (errs.iter().sum::<f64>() / errs.len() as f64) as f32)
    });
    let normal_angle_deg = view.normal.as_ref().and_then(|gt| {
        let unit = r.unit_normals();
        let angles: Vec<f64> = gt
            .iter()
            .zip(&unit)
            .filter(|(g, _)| g.iter().any(|&c| c != 0.0))
            .map(|(g, n)| {
                let dot = (g[0] * n[0] + g[1] * n[1] + g[2] * n[2]).clamp(-1.0, 1.0);
                (dot as f64).acos().to_degrees()
            })
            .collect();
        (!angles.is_empty()).then(|| (angles.iter().sum::<f64>() / angles.len() as f64) as f32)
    });
    ViewEvaluation { view: v, psnr: psnr(mse as f32), depth_abs_error, normal_angle_deg }
}

/// The optimisation loop of one run.
pub struct Trainer {
    pub gpu: Gpu,
    pub scene: Scene,
    pub model: Model,
    adam: Adam,
    grad_norm: GradNorm,
    photometric: Photometric,
    bufs: BatchBuffers,
    /// Renders training batches over random backgrounds (images with alpha and
    /// `train.random_background`); `None`: the model's own renderer.
    random_bg_renderer: Option<Renderer>,
    targets: GpuBuffer<[f32; 4]>,
    d_rays: GpuBuffer<RayOutput>,
    field_grads: FieldGrads,
    step: u64,
}

impl Trainer {
    /// A new run on `scene` with `config` (the scene path in the config is informative).
    pub fn new(gpu: Gpu, scene: Scene, config: RunConfig) -> Result<Trainer, TrainError> {
        config.optim.validate()?;
        if scene.split.train.is_empty() {
            return Err(TrainError::Config { source_name: "scene".into(), message: "no training views".into() });
        }
        let model = Model::new(&gpu, &scene, config.clone())?;
        let adam = Adam::for_groups(&gpu, &model.field.params(), config.optim.adam.clone())?;
        let n = config.train.rays_per_batch;
        let capacity = config.train.max_samples;
        let has_alpha = scene.train_views().any(|v| v.alpha.is_some());
        let random_bg_renderer = (config.train.random_background && has_alpha)
            .then(|| Renderer::new(&gpu, RenderConfig { background: Background::Random, ..*model.renderer.config() }))
            .transpose()?;
        Ok(Trainer {
            random_bg_renderer,
            grad_norm: GradNorm::new(&gpu)?,
            photometric: Photometric::new(&gpu, n)?,
            bufs: BatchBuffers::new(&gpu, n, capacity)?,
            targets: GpuBuffer::zeros(&gpu, "targets", n as usize)?,
            d_rays: GpuBuffer::zeros(&gpu, "d rays", n as usize)?,
            field_grads: FieldGrads::new(&gpu, capacity)?,
            gpu,
            scene,
            model,
            adam,
            step: 0,
        })
    }

    /// Resumes from a checkpoint: parameters, optimizer state and step; the occupancy
    /// grid is rebuilt from the restored field.
    pub fn resume(gpu: Gpu, scene: Scene, ckpt: Checkpoint) -> Result<Trainer, TrainError> {
        let mut t = Trainer::new(gpu, scene, ckpt.config)?;
        t.model.field.import(&t.gpu, &ckpt.field)?;
        t.adam.import_state(&t.gpu, &ckpt.optimizer)?;
        t.step = ckpt.step;
        t.model.update_grid(&t.gpu, t.step, t.grid_seed(), true)?;
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
        let gpu = self.gpu.clone();
        let step = self.step;
        let seed = self.config().train.seed;
        self.apply_level_anneal();
        let update = self.model.update_grid(&gpu, step, self.grid_seed(), false)?;

        let n = self.config().train.rays_per_batch;
        let mut batch = rays::random_pixels(&self.scene, n, seed, step);
        let bg_seed = step as u32;
        if self.random_bg_renderer.is_some() {
            let loaded_over = self.scene.background.unwrap_or([1.0; 3]);
            batch.recomposite(loaded_over, |ray| random_background(bg_seed, ray));
        }
        self.bufs.rays.write(&gpu, &batch.rays);
        self.targets.write(&gpu, &batch.targets);
        let jitter = (rays::Rng::new(seed ^ step.rotate_left(17)).next_u32()) | 1;
        self.model.sample_and_shade(&gpu, &self.bufs, Some(jitter), false)?;

        let bufs = &self.bufs;
        let renderer = self.random_bg_renderer.as_ref().unwrap_or(&self.model.renderer);
        let mut enc = gpu.encoder();
        renderer.forward(&mut enc, &bufs.batch, &bufs.field_out, &bufs.render_out, bg_seed)?;
        self.photometric.record(&mut enc, &bufs.render_out.rays, &self.targets, &self.d_rays, n, n as f32, 1.0);
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
        let mse = self.photometric.mse(&gpu, n as usize, n as f32)?;
        if !mse.is_finite() {
            self.step += 1;
            return Err(TrainError::NonFinite { step, what: "the photometric loss".into() });
        }
        self.model.field.zero_grads(&gpu);
        self.model.field.backward(&gpu, &bufs.batch, &self.field_grads, false)?;

        // Schedules count steps from 1 (mip-NeRF convention).
        let lr = self.config().optim.schedule.lr(step + 1);
        let clip = self.config().optim.clip;
        let groups: Vec<ParamGroup> = self.model.field.params();
        let mut enc = gpu.encoder();
        self.grad_norm.record(&gpu, &mut enc, &ParamGroup::grads_of(&groups), &clip)?;
        self.adam.record_step(&gpu, &mut enc, &groups, lr, Some(&self.grad_norm))?;
        enc.submit();

        let grad = self.grad_norm.read(&gpu)?;
        let counts = bufs.batch.count.read(&gpu)?;
        self.step += 1;
        if !grad.all_finite() {
            return Err(TrainError::NonFinite { step, what: format!("the gradient ({} non-finite entries)", grad.nonfinite) });
        }
        let n_cells = self.config().sampler.resolution.pow(3) as f32;
        Ok(StepStats {
            step,
            loss: mse,
            psnr: psnr(mse),
            lr,
            grad_norm: grad.raw_norm,
            samples: counts[0],
            samples_per_ray: counts[0] as f32 / n as f32,
            samples_truncated: counts[1].saturating_sub(counts[0]),
            occupied_fraction: update.map(|u| u.occupied_cells as f32 / n_cells),
        })
    }

    /// A checkpoint of the current state (reads the GPU).
    pub fn checkpoint(&self) -> Result<Checkpoint, TrainError> {
        Ok(Checkpoint {
            step: self.step,
            config: self.config().clone(),
            field: self.model.field.export(&self.gpu)?,
            optimizer: self.adam.export_state(&self.gpu)?,
        })
    }

    /// Renders every test view and measures PSNR against the images.
    pub fn evaluate(&mut self) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
        evaluate(&self.gpu, &mut self.model, &self.scene)
    }
}

/// Renders the test views of `scene` with `model` and measures each against its image
/// and ground truth.
pub fn evaluate(gpu: &Gpu, model: &mut Model, scene: &Scene) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
    let mut per_view = Vec::new();
    let mut renders = Vec::new();
    for &v in &scene.split.test {
        let r = model.render_view(gpu, scene, v)?;
        per_view.push(evaluate_view(scene, v, &r));
        renders.push((v, r));
    }
    let mean_psnr = mean_of(per_view.iter().map(|e| Some(e.psnr))).unwrap_or(0.0);
    Ok((
        Evaluation {
            mean_psnr,
            mean_depth_abs_error: mean_of(per_view.iter().map(|e| e.depth_abs_error)),
            mean_normal_angle_deg: mean_of(per_view.iter().map(|e| e.normal_angle_deg)),
            per_view,
        },
        renders,
    ))
}
