//! The train room: what ties the rooms together. The run configuration ([`config`]),
//! the [`Model`] (field, occupancy grid, sampler, renderer; built fresh or from a
//! checkpoint, [`model`]), the per-batch training pipeline ([`pipeline`]), the
//! [`Trainer`] (batches, optimizer, schedules, steps), the loop of a whole run in its
//! run directory ([`run`]: cadence, log, time limit, stop requests), checkpoints
//! ([`checkpoint`]), the evaluation of test views ([`evaluate`]), the files a run
//! writes ([`output`]), and per-stage profiling ([`profile`]).
//!
//! One step ([`Trainer::step`]: draw a batch, then [`Trainer::step_on`]; the repository's
//! `docs/ARCHITECTURE.md` shows the same flow room by room):
//! ```text
//! Trainer: random 2x2 patches of `train.images_per_step` training images (1 by
//!   default), or random pixels -> rays (host) [+ RegNeRF: 8x8 patches from random poses]
//!   [+ planarity: triplets of pixels on a line inside non-edge regions]
//! Trainer: coarse-to-fine levels; occupancy grid update (every
//!   `sampler.update_interval` steps: field densities at grid query points);
//!   the step's StepPlan (loss weights, jitter)
//! Pipeline::forward: random backgrounds, random-pose rays and triplets appended,
//!   ranges annealed
//!   -> sampler (occupancy grid + BVH) -> samples -> field forward (+ analytic normals
//!   when L_n, L_dn or the orientation prior is on) -> composite -> photometric loss
//!   L_c (+ edge-guided L_z, L_n, L_dn on the patches, + the planarity L_pl on the
//!   triplets, + the cross-view reprojection L_rp on the patches' rays, + depth TV on
//!   the random-pose patches; rays cut by the sample capacity dropped) -> composite backward (+ the distortion, occlusion and orientation
//!   priors)
//! Pipeline::backward: zero grads -> field backward (second order through the normals)
//! Trainer: grad norm / NaN count of gradients and losses / clip -> Adam (GPU; skips the
//!   step when a loss is not finite) -> the step's one readback: losses, counts and
//!   gradient statistics -> non-finite loss? -> TrainError::NonFinite -> StepStats
//! ```
//! The total loss is `lambda1 L_c + lambda2 L_z + lambda3 L_n + lambda_dn L_dn +
//! lambda_pl L_pl + lambda_rp L_rp + lambda_tv L_tv` plus the weighted priors (see
//! [`crate::loss::edge_reg`], [`crate::loss::depth_normal`],
//! [`crate::loss::planarity`], [`crate::loss::reprojection`], [`crate::loss::depth_tv`],
//! [`regnerf`] and [`crate::render::priors`]). The edge masks of the training views are
//! given by the caller (e.g. from a cache next to the run) or computed once, at the
//! first step that draws patches, so rendering a checkpoint never computes them.
//! A step is one submission and one wait: after Adam, one batched readback of the rays
//! dropped for the capacity, the sample counts, the batch's squared errors and, when
//! their terms are on, the edge-guided, planarity, reprojection and depth TV losses and
//! the priors' per-ray terms, and the gradient statistics. An occupancy grid update
//! reads its bitfield and density sum as well. [`Trainer::step`] waits for its own
//! readback; [`Trainer::step_pipelined`] (what [`run::train_run`] and `edgenerf speed`
//! use) waits for the previous step's instead, after submitting its own, so the host
//! draws, uploads and records a step while the GPU runs the one before.
//!
//! Invariants:
//! * A step whose loss or gradients are not finite changes no parameter and is
//!   reported as [`TrainError::NonFinite`]; the caller stops and keeps the last good
//!   checkpoint. The loss is read after the backward and Adam ran, so the GPU guards
//!   it: the gradient norm counts the NaN / Inf words of the loss buffers the host
//!   reads ([`crate::optim::Guard`]) and Adam skips the step when there is any (and on
//!   non-finite gradients when `optim.adam.skip_nonfinite`, the default); the trainer
//!   then puts Adam's step counter back. (A loss that only the host's sum makes
//!   infinite, from finite per-ray values, is reported but not guarded.)
//! * Runs are deterministic given the config (seeded pixel choice, jitter, grid
//!   cells), up to the order of float atomic adds on the GPU.
//! * Checkpoints hold everything needed to resume: parameters, Adam state, step,
//!   config and the occupancy grid's densities, which [`Model::from_checkpoint`]
//!   restores (so a resumed or rendered run skips exactly the space training skipped);
//!   only a checkpoint without them (uniform sampling, older files) has its grid
//!   rebuilt from the field. Rendering a checkpoint builds a [`Model`] only: no
//!   optimizer, loss kernels or batch buffers.

pub mod atomic_file;
pub mod checkpoint;
pub mod config;
pub mod evaluate;
pub mod export;
pub mod model;
pub mod mono_depth;
pub mod output;
pub mod pipeline;
pub mod profile;
pub mod random_poses;
pub mod render_segments;
pub mod rays;
pub mod regnerf;
pub mod reprojection_views;
pub mod run;
pub mod stereo;

use std::path::{Path, PathBuf};

use crate::data::{Camera, DataError, Scene};
use crate::edges::{EdgeError, EdgeMask};
use crate::field::FieldError;
use crate::gpu::{Gpu, GpuError, PendingRead, ReadBatch, ReadSlot};
use crate::metrics::MetricsError;
use crate::metrics::image::psnr_from_mse;
use crate::optim::{Adam, GradNorm, GradStats, OptimError, ParamGroup};
use crate::render::RenderError;
use crate::sampler::SamplerError;
use crate::layout as samples_gpu;

pub use checkpoint::Checkpoint;
pub use config::{Backend, BatchKind, LevelAnneal, RunConfig, SceneConfig, TrainConfig};
pub use evaluate::{Evaluation, ViewEvaluation, evaluate, evaluate_view};
pub use model::{Model, RenderedView};
pub use pipeline::{BatchLosses, LossReads, Pipeline, StepPlan};
pub use profile::{Stage, StageTimes};
use profile::end_recorded_stage;
pub use regnerf::RegNerfConfig;
pub use run::{RunEnd, RunObserver, RunSummary, train_run, write_evaluation};

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
    #[error(
        "no ray entered the scene's box in the first {steps} steps (0 samples per ray, nothing to learn): the \
         training cameras look away from the scene, or its bounds (the aabb `edgenerf info` prints) miss what the \
         cameras see; check the camera poses and bounds of the scene"
    )]
    RaysMissScene { steps: u64 },
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
    /// Samples the field ran on, and their mean per ray.
    pub samples: u32,
    pub samples_per_ray: f32,
    /// Samples the march placed per ray (the occupancy grid's cut), before the
    /// visibility pass kept `samples_per_ray` of them (equal without the pass).
    pub marched_samples_per_ray: f32,
    /// Samples the rays wanted beyond the batch capacity (0 when nothing was cut).
    pub samples_truncated: u32,
    /// Fraction of the occupancy grid's cells marked occupied as of this step (1 before
    /// the first update, and in uniform mode, where the grid is never updated).
    pub occupied_fraction: f32,
    /// RegNeRF's depth TV on the random-pose patches (0 when inactive) and its weight.
    pub loss_tv: f32,
    pub lambda_tv: f32,
    /// Photometric rays the sample capacity cut, dropped from the losses
    /// ([`crate::sampler::truncated`]); `loss_color` and `psnr` are over the others.
    pub rays_dropped: u32,
    /// The sparse-view priors ([`crate::render::priors`]; 0 when off), unweighted: mip-NeRF
    /// 360's distortion and FreeNeRF's occlusion term.
    pub loss_distortion: f32,
    pub loss_occlusion: f32,
    /// Ref-NeRF's orientation penalty on the analytic normals.
    pub loss_orientation: f32,
    /// The edge-guided depth-normal consistency (unweighted) and its weight this step.
    pub loss_depth_normal: f32,
    pub lambda_depth_normal: f32,
    /// The edge-guided planarity (unweighted) and its weight this step.
    pub loss_planarity: f32,
    pub lambda_planarity: f32,
    /// The cross-view reprojection term (unweighted) and its weight this step.
    pub loss_reprojection: f32,
    pub lambda_reprojection: f32,
    /// Samples the step's batch could hold ([`crate::train::TrainConfig::grow_capacity`]
    /// raises it for the next step when rays were cut).
    pub sample_capacity: u32,
}

impl StepStats {
    /// The stats of step `plan.step`: its losses, learning rate, gradient norm, the
    /// sampler's `counts` (field samples, wanted, marched) over `n_rays` rays, the occupancy grid's
    /// occupied fraction and the batch's sample capacity.
    #[allow(clippy::too_many_arguments)]
    fn new(
        plan: &StepPlan,
        losses: &BatchLosses,
        lr: f32,
        grad_norm: f32,
        counts: [u32; 3],
        n_rays: u32,
        occupied_fraction: f32,
        sample_capacity: u32,
    ) -> StepStats {
        let (lambda_depth, lambda_normal) = plan.reg.map_or((0.0, 0.0), |w| (w.lambda_depth, w.lambda_normal));
        StepStats {
            step: plan.step,
            loss: losses.total(plan),
            loss_color: losses.color,
            psnr: psnr_from_mse(losses.color as f64) as f32,
            loss_depth: losses.depth,
            loss_normal: losses.normal,
            lambda_depth,
            lambda_normal,
            lr,
            grad_norm,
            samples: counts[0],
            samples_per_ray: counts[0] as f32 / n_rays as f32,
            marched_samples_per_ray: counts[2] as f32 / n_rays as f32,
            samples_truncated: counts[1].saturating_sub(counts[2]),
            occupied_fraction,
            loss_tv: losses.tv,
            lambda_tv: plan.tv.unwrap_or(0.0),
            rays_dropped: losses.rays_dropped,
            sample_capacity,
            loss_distortion: losses.distortion,
            loss_occlusion: losses.occlusion,
            loss_orientation: losses.orientation,
            loss_depth_normal: losses.depth_normal,
            lambda_depth_normal: plan.reg.map_or(0.0, |w| w.lambda_depth_normal),
            loss_planarity: losses.planarity,
            lambda_planarity: plan.reg.map_or(0.0, |w| w.lambda_planarity),
            loss_reprojection: losses.reprojection,
            lambda_reprojection: plan.reg.map_or(0.0, |w| w.lambda_reprojection),
        }
    }

    /// Header of the per-step CSV log (`log.csv`), matching [`StepStats::csv_row`].
    pub const CSV_HEADER: &'static str = "step,loss,loss_color,loss_depth,loss_normal,lambda_depth,lambda_normal,psnr,lr,grad_norm,samples,samples_per_ray,samples_truncated,elapsed_s,loss_tv,lambda_tv,rays_dropped,occupied_fraction,sample_capacity,loss_distortion,loss_occlusion,loss_orientation,loss_depth_normal,lambda_depth_normal,loss_planarity,lambda_planarity,loss_reprojection,lambda_reprojection,marched_samples_per_ray";

    /// One CSV row, `elapsed_s` since the start of the run inserted where the header
    /// has it (later columns were appended after it, so older logs stay a prefix).
    pub fn csv_row(&self, elapsed_s: f64) -> String {
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
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
            self.loss_occlusion,
            self.loss_orientation,
            self.loss_depth_normal,
            self.lambda_depth_normal,
            self.loss_planarity,
            self.lambda_planarity,
            self.loss_reprojection,
            self.lambda_reprojection,
            self.marched_samples_per_ray
        )
    }
}

/// The optimisation loop of one run: the model, the batch pipeline, and what training
/// needs beyond one batch (batch drawing, the optimizer, schedules, the step counter).
pub struct Trainer {
    pub gpu: Gpu,
    pub scene: Scene,
    pub model: Model,
    pipeline: Pipeline,
    adam: Adam,
    grad_norm: GradNorm,
    /// RegNeRF's pool of random poses (when its depth TV is on).
    tv_poses: Vec<Camera>,
    /// Edge mask of each training view (`scene.split.train` order); computed at the
    /// first step that draws patches unless given (rendering never needs them).
    edge_masks: Option<Vec<EdgeMask>>,
    step: u64,
    /// The step [`Trainer::step_pipelined`] submitted and has not read back yet.
    in_flight: Option<InFlight>,
    /// Per-stage timing ([`profile`]); `None`: off.
    profile: Option<StageTimes>,
}

/// A step submitted with its readback not yet waited for: what its [`StepStats`] need
/// besides the values read back.
struct InFlight {
    step: u64,
    plan: StepPlan,
    lr: f32,
    /// The capacity the step ran with (a later step's readback may grow it).
    sample_capacity: u32,
    occupied_fraction: f32,
    losses: LossReads,
    stats: ReadSlot<f32>,
    read: PendingRead,
    /// With a learned background: the directions of the step's photometric rays.
    background_dirs: Option<Vec<[f32; 3]>>,
}

impl Trainer {
    /// A new run on `scene` with `config` (the scene path in the config is informative);
    /// the edge masks are computed from `config.edges` when the regularizers need them.
    pub fn new(gpu: Gpu, scene: Scene, config: RunConfig) -> Result<Trainer, TrainError> {
        Self::with_edge_masks(gpu, scene, config, None)
    }

    /// Whether a run with `config` on `scene` reads edge masks.
    pub fn needs_edge_masks(config: &RunConfig, scene: &Scene) -> bool {
        config.train.batch == BatchKind::Patches && config.reg.any(scene.is_dtu())
    }

    /// [`Trainer::new`] with the training views' edge masks given (`scene.split.train`
    /// order), e.g. read from a cache; `None`: computed here when needed.
    pub fn with_edge_masks(gpu: Gpu, scene: Scene, mut config: RunConfig, masks: Option<Vec<EdgeMask>>) -> Result<Trainer, TrainError> {
        config.resolve_for(&scene)?;
        check_edge_masks(&scene, masks.as_deref())?;
        let mut model = Model::new(&gpu, &scene, config)?;
        if let Some(bg) = &mut model.background {
            let (rays, colors) = model::frame_pixels(&scene);
            bg.prefit(&bg.ray_dirs(&rays), &colors);
        }
        Self::with_model(gpu, scene, model, masks)
    }

    /// Resumes from a checkpoint: the model as [`Model::from_checkpoint`] restores it
    /// (parameters and occupancy grid), then the optimizer state and the step. `masks`
    /// as in [`Trainer::with_edge_masks`].
    pub fn resume(gpu: Gpu, scene: Scene, ckpt: Checkpoint, masks: Option<Vec<EdgeMask>>) -> Result<Trainer, TrainError> {
        check_edge_masks(&scene, masks.as_deref())?;
        let model = Model::from_checkpoint(&gpu, &scene, &ckpt)?;
        let mut t = Self::with_model(gpu, scene, model, masks)?;
        t.adam.import_state(&t.gpu, &ckpt.optimizer)?;
        t.step = ckpt.step;
        Ok(t)
    }

    /// A trainer at step 0 around `model`, whose config is resolved for `scene`.
    fn with_model(gpu: Gpu, scene: Scene, model: Model, masks: Option<Vec<EdgeMask>>) -> Result<Trainer, TrainError> {
        let config = &model.config;
        let adam = Adam::for_groups(&gpu, &model.field.params(), config.optim.adam)?;
        let pipeline = Pipeline::new(&gpu, &scene, &model, config, masks.as_deref())?;
        let tv_poses = if pipeline.tv_rays() > 0 {
            let r = &config.regnerf;
            random_poses::random_poses(&scene, r.pose_kind_for(&scene), r.n_poses, config.train.seed)
        } else {
            Vec::new()
        };
        Ok(Trainer {
            grad_norm: GradNorm::new(&gpu)?,
            pipeline,
            tv_poses,
            edge_masks: masks,
            gpu,
            scene,
            model,
            adam,
            step: 0,
            in_flight: None,
            profile: None,
        })
    }

    pub fn config(&self) -> &RunConfig {
        &self.model.config
    }

    /// With the stereo priors: the fractions of the training views' pixels the plane
    /// sweep gave a confirmed and a filled depth ([`Pipeline::stereo_coverage`]).
    pub fn stereo_coverage(&self) -> Option<(f64, f64)> {
        self.pipeline.stereo_coverage()
    }

    /// With the stereo priors, on a scene with ground-truth depth: how well the confirmed
    /// targets agree with it ([`stereo::accuracy`]).
    pub fn stereo_accuracy(&self) -> Option<stereo::Accuracy> {
        stereo::accuracy(&self.scene, self.pipeline.stereo_targets()?)
    }

    /// With monocular depth maps (`priors.mono_depth_dir`): each training view's fit.
    pub fn mono_fits(&self) -> &[mono_depth::MonoFit] {
        self.pipeline.mono_fits()
    }

    /// With monocular depth maps, on a scene with ground-truth depth: how well the
    /// monocular targets agree with it ([`stereo::accuracy_where`]).
    pub fn mono_accuracy(&self) -> Option<stereo::Accuracy> {
        let confidence = self.config().priors.mono_depth_confidence;
        stereo::accuracy_where(&self.scene, self.pipeline.stereo_targets()?, |c| c == confidence)
    }

    /// The stereo priors' targets `[depth, confidence]` per scene view and pixel
    /// ([`stereo::StereoTargets`]), when one of them is on.
    pub fn stereo_targets(&self) -> Option<&stereo::StereoTargets> {
        self.pipeline.stereo_targets()
    }

    /// Steps done so far.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// One optimisation step (see the module doc).
    pub fn step(&mut self) -> Result<StepStats, TrainError> {
        let batch = self.draw_timed_batch()?;
        self.step_on(batch)
    }

    /// [`Trainer::draw_batch`] as a step's first stage: with profiling on, the step's
    /// clock starts here and the drawing is charged to [`Stage::Batch`].
    fn draw_timed_batch(&mut self) -> Result<rays::PixelBatch, TrainError> {
        if let Some(p) = &mut self.profile {
            p.begin();
        }
        let batch = self.draw_batch()?;
        self.end_stage(Stage::Batch)?;
        Ok(batch)
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
        Ok(profile::end_stage(&mut self.profile, &self.gpu, stage)?)
    }

    /// The batch [`Trainer::step`] trains on next: 2x2 patches with their edge masks or
    /// single pixels, as `train.batch` says, and RegNeRF's random-pose patches when its
    /// depth TV is on (a pure function of the seed and step).
    pub fn draw_batch(&mut self) -> Result<rays::PixelBatch, TrainError> {
        let mut batch = self.draw_photometric_batch()?;
        (batch.tv_rays, batch.tv_z_scale) = self.draw_tv_patches();
        batch.triplets = self.draw_triplets()?;
        Ok(batch)
    }

    /// The planarity term's triplets of this step (empty when it is off).
    fn draw_triplets(&mut self) -> Result<rays::Triplets, TrainError> {
        let n = self.pipeline.triplets();
        if n == 0 {
            return Ok(rays::Triplets::default());
        }
        let reg = &self.config().reg;
        let draw = rays::TripletDraw { n, max_stride: reg.planarity_max_stride, color_range: reg.planarity_color_range };
        let seed = self.config().train.seed;
        self.ensure_edge_masks()?;
        let masks = self.edge_masks.as_deref().expect("computed above");
        Ok(rays::random_triplets(&self.scene, masks, draw, seed, self.step))
    }

    /// Computes the training views' edge masks at the first call unless given (all
    /// non-edge when no regularizer reads them).
    fn ensure_edge_masks(&mut self) -> Result<(), TrainError> {
        if self.edge_masks.is_none() {
            self.edge_masks = Some(if Self::needs_edge_masks(&self.model.config, &self.scene) {
                crate::edges::edge_masks(&self.scene, &self.scene.split.train, &self.model.config.edges)?
            } else {
                let (w, h) = self.scene.image_size();
                vec![EdgeMask::all_non_edge(w, h); self.scene.split.train.len()]
            });
        }
        Ok(())
    }

    /// RegNeRF's random-pose patches of this step (empty when its depth TV is off).
    fn draw_tv_patches(&self) -> (Vec<samples_gpu::GpuRay>, Vec<f32>) {
        let n_tv = self.pipeline.tv_rays();
        if n_tv == 0 {
            return (Vec::new(), Vec::new());
        }
        let (r, seed) = (&self.config().regnerf, self.config().train.seed);
        let n_patches = n_tv / (r.patch_size * r.patch_size);
        random_poses::patch_rays(&self.scene, &self.tv_poses, n_patches, r.patch_size, seed, self.step)
    }

    fn draw_photometric_batch(&mut self) -> Result<rays::PixelBatch, TrainError> {
        let (step, seed) = (self.step, self.config().train.seed);
        let n = self.config().train.rays_per_batch;
        if self.config().train.batch == BatchKind::Pixels {
            return Ok(rays::random_pixels(&self.scene, n, seed, step));
        }
        let n_patches = self.config().train.patches_per_batch();
        self.ensure_edge_masks()?;
        let masks = self.edge_masks.as_deref().expect("computed above");
        let train = &self.config().train;
        let shape = rays::PatchShape { images_per_step: train.images_per_step, stride: train.patch_stride };
        Ok(rays::random_patches(&self.scene, masks, n_patches, n - 4 * n_patches, shape, seed, step))
    }

    /// One optimisation step on a given batch of `train.rays_per_batch` rays (patch
    /// batches carry their edge masks in [`rays::PixelBatch::reg`]; the regularizers
    /// run on them when `train.batch` is `patches`). With RegNeRF's depth TV on, the
    /// batch's random-pose patches are used, or drawn for the step when it has none.
    ///
    /// Panics when a step of [`Trainer::step_pipelined`] is still in flight (finish it
    /// with [`Trainer::finish_pending`] first).
    pub fn step_on(&mut self, batch: rays::PixelBatch) -> Result<StepStats, TrainError> {
        assert!(self.in_flight.is_none(), "Trainer::step_on with a pipelined step in flight: call finish_pending first");
        let submitted = self.submit_step(batch)?;
        self.complete(submitted)
    }

    /// One step with its readback deferred: submits this step, then reads back and
    /// returns the one submitted before it (`None` at the first), so the host draws and
    /// records a step while the GPU still runs the previous one. With `drain`, or with
    /// profiling on, this step is read back too (then none is left in flight). The
    /// steps are exactly those of [`Trainer::step`]; only when their figures come back
    /// differs. A non-finite loss or gradient of the earlier step is reported here,
    /// when the later one already ran (its own guard still applies to it). The step
    /// in flight counts in [`Trainer::step_count`] and its update is in what
    /// [`Trainer::checkpoint`] reads; [`Trainer::finish_pending`] returns its stats.
    pub fn step_pipelined(&mut self, drain: bool) -> Result<Vec<StepStats>, TrainError> {
        let batch = self.draw_timed_batch()?;
        let submitted = self.submit_step(batch)?;
        let mut done = Vec::with_capacity(2);
        let previous = self.in_flight.replace(submitted);
        if let Some(previous) = previous {
            done.push(self.complete(previous)?);
        }
        if drain || self.profile.is_some() {
            done.extend(self.finish_pending()?);
        }
        Ok(done)
    }

    /// Reads back the step [`Trainer::step_pipelined`] left in flight, if any.
    pub fn finish_pending(&mut self) -> Result<Option<StepStats>, TrainError> {
        self.in_flight.take().map(|f| self.complete(f)).transpose()
    }

    /// Records and submits step `self.step` on `batch` (one encoder, one submission;
    /// the losses, counts and gradient stats copied out at its end) and counts it.
    fn submit_step(&mut self, mut batch: rays::PixelBatch) -> Result<InFlight, TrainError> {
        let (gpu, step) = (self.gpu.clone(), self.step);
        if self.pipeline.tv_rays() > 0 && batch.tv_rays.is_empty() {
            (batch.tv_rays, batch.tv_z_scale) = self.draw_tv_patches();
        }
        if self.pipeline.triplets() > 0 && batch.triplets.is_empty() {
            batch.triplets = self.draw_triplets()?;
        }
        self.pipeline.check_batch(&batch)?;
        self.model.set_levels_for_step(step);
        self.model.update_occupancy(&gpu, step, self.model.occupancy_seed(step), false)?;
        self.end_stage(Stage::OccupancyGrid)?;
        let plan = self.plan(&batch);
        let background_dirs = self.model.background.as_ref().map(|bg| bg.ray_dirs(&batch.rays));
        // The whole step goes into one encoder and one submission, with the readback at
        // its end (profiling submits once per stage instead).
        let mut enc = gpu.encoder();
        self.pipeline.forward(&mut enc, &mut self.model, &self.scene, batch, &plan, &mut self.profile)?;
        // Whether the sampler counted the rays' wanted samples (it may start at this step).
        let cut = self.model.wanted_counts().is_some();
        end_recorded_stage(&mut self.profile, &mut enc, Stage::RenderAndLosses)?;
        self.pipeline.backward(&mut enc, &mut self.model, &plan)?;
        end_recorded_stage(&mut self.profile, &mut enc, Stage::FieldBackward)?;

        // Schedules count steps from 1 (mip-NeRF convention).
        let lr = self.config().optim.schedule.lr(step + 1);
        let groups: Vec<ParamGroup> = self.model.field.params();
        // The losses guard the step on the GPU: Adam skips it when one is not finite,
        // so the losses need not be read before the backward and Adam run.
        let guards = self.pipeline.loss_guards(&plan);
        self.grad_norm.record_guarded(&gpu, &mut enc, &ParamGroup::grads_of(&groups), &guards, &self.model.config.optim.clip)?;
        self.adam.record_step(&gpu, &mut enc, &groups, lr, Some(&self.grad_norm))?;
        self.model.forget_render_grid();
        // The step's one wait, in Trainer::complete: losses, counts and gradient stats.
        let mut reads = ReadBatch::new();
        let losses = self.pipeline.add_loss_reads(&mut reads, &plan, cut);
        let stats = reads.add(self.grad_norm.stats(), self.grad_norm.stats().len());
        let read = reads.submit_after(enc);
        self.step += 1;
        Ok(InFlight {
            step,
            plan,
            lr,
            sample_capacity: self.pipeline.sample_capacity(),
            occupied_fraction: self.model.occupied_fraction(),
            losses,
            stats,
            read,
            background_dirs,
        })
    }

    /// Waits for a submitted step's readback and turns it into its [`StepStats`]: the
    /// NaN guard's verdict, the sample capacity grown for the steps after it.
    fn complete(&mut self, f: InFlight) -> Result<StepStats, TrainError> {
        let back = f.read.wait(&self.gpu)?;
        let losses = self.pipeline.losses(&back, &f.losses);
        let grad = GradStats::from_buffer(&back.get(&f.stats));
        if let Err(e) = losses.check_finite(f.step) {
            // Adam skipped the step on the GPU (its guard); its counter goes back too,
            // so the optimizer is exactly as the step found it.
            if grad.guard_nonfinite > 0 {
                self.adam.set_step_count(self.adam.step_count() - 1);
            }
            return Err(e);
        }
        // The learned background's Adam step, on the host, from this step's rays (a
        // pipelined step's update lands one step late, as its figures do).
        if let (Some(bg), Some(dirs), Some((d_rgb, opacity))) =
            (&mut self.model.background, &f.background_dirs, self.pipeline.background_grads(&back, &f.losses))
        {
            bg.step(dirs, &d_rgb, &opacity, f.lr);
        }
        let counts = losses.samples;
        self.end_stage(Stage::Optimizer)?;
        if let Some(p) = &mut self.profile {
            p.steps += 1;
            p.field_samples += counts[0] as u64;
        }
        if self.config().train.grow_capacity
            && let Some(grown) = self.pipeline.grow_capacity(&self.gpu, counts[1])?
        {
            let (step, wanted, capacity) = (f.step + 1, counts[1], f.sample_capacity);
            log::info!("step {step}: rays wanted {wanted} samples, above the capacity {capacity}; capacity now {grown}");
        }
        if !grad.all_finite() {
            return Err(TrainError::NonFinite { step: f.step, what: format!("the gradient ({} non-finite entries)", grad.nonfinite) });
        }
        Ok(StepStats::new(&f.plan, &losses, f.lr, grad.raw_norm, counts, self.pipeline.rays_per_batch(), f.occupied_fraction, f.sample_capacity))
    }

    /// What step `self.step` asks of the pipeline for `batch`: the loss weights in
    /// effect (the edge-guided terms on patch batches only) and the sampler's jitter.
    fn plan(&self, batch: &rays::PixelBatch) -> StepPlan {
        let (config, step) = (self.config(), self.step);
        let patches = self.pipeline.has_patches(config, batch);
        StepPlan {
            step,
            lambda_color: config.reg.lambda_color,
            reg: if patches { config.reg.weights_at(step, self.scene.is_dtu()) } else { None },
            tv: config.regnerf.tv_weight_at(step).filter(|_| self.pipeline.tv_rays() > 0),
            jitter: (crate::rng::SplitMix64::mixed(config.train.seed ^ step.rotate_left(17)).next_u32()) | 1,
            orientation: config.priors.orientation > 0.0,
            visibility: config.sampler.visibility.training_rule_at(step),
            march_step: self.model.training_march_step(),
        }
    }

    /// Rays a step renders: photometric, random-pose and planarity-triplet rays.
    pub fn rays_per_step(&self) -> u32 {
        self.pipeline.rays_per_batch()
    }

    /// Samples a step's batch holds before rays are cut.
    pub fn sample_capacity(&self) -> u32 {
        self.pipeline.sample_capacity()
    }

    /// A checkpoint of the current state (reads the GPU).
    pub fn checkpoint(&self) -> Result<Checkpoint, TrainError> {
        Ok(Checkpoint {
            step: self.step,
            config: self.config().clone(),
            field: self.model.field.export(&self.gpu)?,
            optimizer: self.adam.export_state(&self.gpu)?,
            occupancy: self.model.occupancy.export_density(&self.gpu)?,
            background: self.model.background.as_ref().map(|b| b.export()).unwrap_or_default(),
        })
    }

    /// Renders every test view and measures it against its image and ground truth.
    pub fn evaluate(&mut self) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
        evaluate(&self.gpu, &mut self.model, &self.scene)
    }
}

/// Checks given edge masks: one per training view of `scene`, each of the views' size.
fn check_edge_masks(scene: &Scene, masks: Option<&[EdgeMask]>) -> Result<(), TrainError> {
    let Some(m) = masks else { return Ok(()) };
    let (w, h) = scene.image_size();
    if m.len() != scene.split.train.len() || m.iter().any(|m| (m.width, m.height) != (w, h)) {
        return Err(TrainError::Config {
            source_name: "config".into(),
            message: format!(
                "{} edge masks given for {} training views of {w}x{h} (sizes {:?})",
                m.len(),
                scene.split.train.len(),
                m.iter().map(|m| (m.width, m.height)).collect::<Vec<_>>()
            ),
        });
    }
    Ok(())
}
