//! The training pipeline of one batch: sampling, the field's forward pass, compositing,
//! every loss, and the backward passes down to the field's gradients.
//!
//! [`Pipeline`] owns what a training batch needs beyond the [`Model`]: the batch's GPU
//! buffers (rays, samples, field outputs, ray outputs, targets, per-ray and per-sample
//! gradients), the loss kernels, the drop of rays the sample capacity cut, and the
//! training renderer (the model's render settings with the run's sparse-view priors
//! and, for images with alpha and `train.random_background`, random backgrounds). The
//! [`Trainer`](super::Trainer) gives it a host batch and the step's [`StepPlan`]; what
//! is left to the trainer is what training needs beyond one batch: drawing batches,
//! the optimizer, schedules and the step counter.
//!
//! A batch runs in two calls; neither waits for the GPU (the caller reads the losses
//! with its step's one readback, after the optimizer):
//! ```text
//! Pipeline::forward:
//!   host: random-pose rays and planarity triplets appended; RegNeRF's annealing of
//!     every ray's range; rays, targets (and their alpha with random backgrounds) and
//!     edge weights to the GPU
//!   sampler (Model::sample) -> field forward (+ analytic normals when L_n is on)
//!   one encoder: drop of capacity-cut rays -> composite forward -> photometric L_c
//!     (targets with alpha onto the rendered random backgrounds; writes dL/d RayOutput)
//!     -> edge-guided L_z, L_n, the planarity term, the cross-view reprojection
//!     (its rays' training views written as their source) and RegNeRF's depth TV (add)
//!     -> composite backward (+ the priors' gradients) -> dL/d field outputs
//!     -> the list of the samples whose gradients are not zero (sampler's LiveCompaction)
//! Pipeline::backward: the field's gradients zeroed, then the field backward over the
//!   listed samples (a fifth to a quarter of a batch past early termination late in a run)
//! then, for the caller: Pipeline::loss_guards (the loss buffers, for the optimizer's
//!   NaN guard), Pipeline::add_loss_reads into its readback -> Pipeline::losses -> BatchLosses
//! ```
//!
//! Invariants:
//! * Neither call changes a parameter: [`Pipeline::forward`] leaves the field's
//!   gradients alone too; [`Pipeline::backward`] overwrites them with this batch's.
//! * The loss buffers, the sampler's counts and the ray aux keep what the forward
//!   wrote until the next forward (the backward and the optimizer write none of them),
//!   so the caller reads them after the optimizer, and guards the optimizer with them.
//! * The random-pose rays, then the planarity triplets' rays, follow the photometric
//!   rays in one sample batch with zero photometric weight, so one forward and one
//!   backward pass serve every term.
//! * The batch buffers hold `train.rays_per_batch` photometric rays plus the
//!   random-pose and triplet ones; the sample capacity only grows
//!   ([`Pipeline::grow_capacity`]).

use crate::data::Scene;
use crate::gpu::{Encoder, Gpu, GpuBuffer, ReadBack, ReadBatch, ReadSlot};
use crate::optim::Guard;
use crate::loss::photometric::{OpacityPriors, Recomposite};
use crate::loss::stereo_depth::StereoDepth;
use crate::loss::{sum_terms, DepthNormal, DepthTv, EdgeReg, EdgeRegWeights, Photometric, Planarity, PlanarityTerm, Reprojection};
use crate::render::{Background, RenderConfig, RayPriors, Renderer, StereoTargetSource};
use crate::sampler::{DropTruncated, LiveCompaction, Visibility};
use crate::layout::{FieldGrads, GpuRay, GpuSample, LiveSamples, RayAux, RayOutput};

use super::TrainError;
use super::config::{BatchKind, RunConfig};
use super::model::{BatchBuffers, Model};
use super::mono_depth::{self, MonoFit};
use super::profile::{Stage, StageTimes, end_recorded_stage};
use super::rays::PixelBatch;
use super::stereo::{self, StereoTargets, SweepSettings};
use crate::edges::EdgeMask;

/// What a step asks of the pipeline besides its batch: the loss weights in effect at
/// the step and its seeds.
#[derive(Clone, Copy, Debug)]
pub struct StepPlan {
    /// The step (0-based): seeds the random backgrounds and RegNeRF's annealing.
    pub step: u64,
    /// `lambda1`, the weight of the photometric loss.
    pub lambda_color: f32,
    /// The edge-guided `L_z` and `L_n` weights (patch batches with a regularizer on at
    /// this step), `None` when they are off.
    pub reg: Option<EdgeRegWeights>,
    /// RegNeRF's depth TV weight (the batch has random-pose patches), `None` when off.
    pub tv: Option<f32>,
    /// Seed of the sampler's jitter.
    pub jitter: u32,
    /// Whether the orientation prior is on (it penalises the analytic normals).
    pub orientation: bool,
    /// The sampler's visibility pass at this step (`sampler.visibility`), `None` when
    /// it does not run.
    pub visibility: Option<Visibility>,
    /// The marching step when it is not the configured one (the coarse start,
    /// [`crate::train::Model::training_march_step`]).
    pub march_step: Option<f32>,
}

impl StepPlan {
    /// Whether the field computes analytic normals (the normal regularizer, the
    /// depth-normal consistency or the orientation prior is on).
    pub fn normals(&self) -> bool {
        self.orientation || self.reg.is_some_and(|w| w.lambda_normal > 0.0 || w.lambda_depth_normal > 0.0)
    }
}

/// A batch's losses, read back after the step ([`Pipeline::losses`]): unweighted, 0 when the term
/// is off.
#[derive(Clone, Copy, Debug, Default)]
pub struct BatchLosses {
    /// The photometric `L_c`: the mean squared error over the rays not dropped.
    pub color: f32,
    /// The edge-guided `L_z` and `L_n`.
    pub depth: f32,
    pub normal: f32,
    /// RegNeRF's depth TV on the random-pose patches.
    pub tv: f32,
    /// The sparse-view priors: mip-NeRF 360's distortion, FreeNeRF's occlusion and
    /// Ref-NeRF's orientation penalty.
    pub distortion: f32,
    pub occlusion: f32,
    pub orientation: f32,
    /// The edge-guided depth-normal consistency `L_dn`.
    pub depth_normal: f32,
    /// The edge-guided planarity `L_pl` on the batch's triplets.
    pub planarity: f32,
    /// The cross-view photometric consistency of the rendered depth.
    pub reprojection: f32,
    /// Photometric rays the sample capacity cut, dropped from the losses.
    pub rays_dropped: u32,
    /// The sampler's counts: samples the field ran on, samples the rays wanted (before
    /// the capacity cut), and samples the march wrote (more than the first when the
    /// visibility pass dropped some).
    pub samples: [u32; 3],
    /// The priors' weights the losses entered with.
    pub priors: RayPriors,
}

impl BatchLosses {
    /// [`TrainError::NonFinite`] naming the first loss that is not finite.
    pub fn check_finite(&self, step: u64) -> Result<(), TrainError> {
        for (value, what) in [
            (self.color, "the photometric loss"),
            (self.depth, "L_z"),
            (self.normal, "L_n"),
            (self.tv, "the depth TV"),
            (self.distortion, "the distortion prior"),
            (self.occlusion, "the occlusion prior"),
            (self.orientation, "the orientation penalty"),
            (self.depth_normal, "the depth-normal consistency"),
            (self.planarity, "the planarity term"),
            (self.reprojection, "the reprojection term"),
        ] {
            if !value.is_finite() {
                return Err(TrainError::NonFinite { step, what: what.into() });
            }
        }
        Ok(())
    }

    /// The total loss with the weights of `plan`: `lambda1 L_c + lambda2 L_z + lambda3
    /// L_n + lambda_dn L_dn + lambda_pl L_pl + lambda_rp L_rp + lambda_tv L_tv +
    /// lambda_dist L_dist + lambda_occ L_occ + lambda_ori L_ori`.
    pub fn total(&self, plan: &StepPlan) -> f32 {
        let (lambda_depth, lambda_normal, lambda_dn, lambda_pl, lambda_rp) = plan.reg.map_or((0.0, 0.0, 0.0, 0.0, 0.0), |w| {
            (w.lambda_depth, w.lambda_normal, w.lambda_depth_normal, w.lambda_planarity, w.lambda_reprojection)
        });
        plan.lambda_color * self.color
            + lambda_depth * self.depth
            + lambda_normal * self.normal
            + lambda_dn * self.depth_normal
            + lambda_pl * self.planarity
            + lambda_rp * self.reprojection
            + plan.tv.unwrap_or(0.0) * self.tv
            + self.priors.lambda_distortion * self.distortion
            + self.priors.lambda_occlusion * self.occlusion
            + self.priors.lambda_orientation * self.orientation
    }
}

/// The per-batch buffers, loss kernels and training renderer of a run.
pub struct Pipeline {
    /// Photometric rays per batch, random-pose rays appended after them, and the
    /// planarity triplets after those.
    n: u32,
    n_tv: u32,
    n_triplets: u32,
    /// Whether the priors are on (their per-ray terms are read back).
    priors_on: bool,
    /// With random backgrounds: each target's alpha (1: none), which the photometric
    /// loss composites onto the renderer's background, and the colour the images were
    /// composited over when loaded.
    random_background: Option<(GpuBuffer<f32>, [f32; 3])>,
    /// The model's renderer settings with the priors, and the random backgrounds.
    renderer: Renderer,
    bufs: BatchBuffers,
    targets: GpuBuffer<[f32; 4]>,
    d_rays: GpuBuffer<RayOutput>,
    field_grads: FieldGrads,
    /// The samples whose `field_grads` are not zero, and what lists them.
    live: (LiveSamples, LiveCompaction),
    photometric: Photometric,
    drop_truncated: DropTruncated,
    edge_reg: EdgeReg,
    depth_normal: DepthNormal,
    depth_tv: DepthTv,
    planarity: Planarity,
    /// The reprojection term when it is on, and each scene view's position in the
    /// training list (what the term's per-ray source index is).
    reprojection: Option<(Reprojection, Vec<u32>)>,
    /// The stereo depth prior when it is on, and the sweep's depth maps per scene view.
    stereo: Option<(StereoDepth, StereoTargets)>,
    /// Each training view's fit of its monocular depth map (`priors.mono_depth_dir`).
    mono_fits: Vec<MonoFit>,
}

impl Pipeline {
    /// The pipeline of a run with `config` on `scene` whose model is `model` (its render
    /// settings are the training renderer's).
    pub fn new(gpu: &Gpu, scene: &Scene, model: &Model, config: &RunConfig, masks: Option<&[EdgeMask]>) -> Result<Pipeline, TrainError> {
        let n = config.train.rays_per_batch;
        let r = &config.regnerf;
        let n_tv = r.patches(n) * r.patch_size * r.patch_size;
        let n_triplets = if config.train.batch == BatchKind::Patches { config.reg.planarity_triplets_per_step() } else { 0 };
        // The random-pose and triplet rays get the photometric rays' share of samples.
        let n_all = n + n_tv + 3 * n_triplets;
        let capacity = (config.train.max_samples as u64 * n_all as u64 / n.max(1) as u64).min(u32::MAX as u64) as u32;
        let random_background = config.train.random_background && scene.train_views().any(|v| v.alpha.is_some());
        let mut render_config: RenderConfig = *model.render_config();
        if random_background {
            render_config.background = Background::Random;
        }
        let random_background = random_background
            .then(|| GpuBuffer::zeros(gpu, "target alpha", n_all as usize).map(|a| (a, scene.background.unwrap_or([1.0; 3]))))
            .transpose()?;
        let reprojection = if config.reg.reprojection_on() && config.train.batch == BatchKind::Patches {
            Some(reprojection_term(gpu, scene, n, config.reg.reprojection_blur)?)
        } else {
            None
        };
        let mut mono_fits = Vec::new();
        let stereo = if config.priors.stereo_on() {
            let p = &config.priors;
            let settings = SweepSettings { planes: p.stereo_planes, window: p.stereo_window, consistency: p.stereo_consistency, fill: p.stereo_fill, uniqueness: p.stereo_uniqueness, horizontal: p.stereo_horizontal };
            let config_error = |message| TrainError::Config { source_name: "config".into(), message };
            if p.mono_depth_dir.is_some() {
                mono_depth::check_scene(scene).map_err(config_error)?;
            }
            let mut maps = match p.stereo_targets {
                StereoTargetSource::Sweep => {
                    // The fill reads the edge masks; a run whose regularizers do not read
                    // them gets them here.
                    let computed = match masks {
                        None if p.stereo_fill > 0 => Some(crate::edges::edge_masks(scene, &scene.split.train, &config.edges)?),
                        _ => None,
                    };
                    stereo::sweep(scene, settings, masks.or(computed.as_deref()))
                }
                StereoTargetSource::GroundTruth => stereo::ground_truth(scene),
            }
            .map_err(config_error)?;
            if let Some(dir) = &p.mono_depth_dir {
                mono_fits = mono_depth::merge(scene, &mut maps, dir, p.mono_depth_kind, p.mono_depth_confidence).map_err(config_error)?;
            }
            Some((StereoDepth::new(gpu, n)?, maps))
        } else {
            None
        };
        let mut renderer = Renderer::new(gpu, render_config)?;
        // The priors apply to every rendered ray of a batch, random-pose rays included.
        renderer.set_priors(config.priors.weights(n_all, scene.near, scene.far));
        Ok(Pipeline {
            n,
            n_tv,
            n_triplets,
            priors_on: config.priors.active(),
            random_background,
            renderer,
            bufs: BatchBuffers::new(gpu, n_all, capacity, config.sampler.visibility.train)?,
            targets: GpuBuffer::zeros(gpu, "targets", n_all as usize)?,
            d_rays: GpuBuffer::zeros(gpu, "d rays", n_all as usize)?,
            field_grads: FieldGrads::new(gpu, capacity)?,
            live: live_list(gpu, capacity)?,
            photometric: Photometric::new(gpu, n_all)?,
            drop_truncated: DropTruncated::new(gpu)?,
            edge_reg: EdgeReg::new(gpu, n / 4)?,
            depth_normal: DepthNormal::new(gpu, n / 4)?,
            depth_tv: DepthTv::new(gpu, n_tv)?,
            planarity: Planarity::new(gpu, n_triplets)?,
            reprojection,
            stereo,
            mono_fits,
        })
    }

    /// With the stereo priors: the fractions of the training views' pixels the sweep
    /// gave a confirmed depth and a filled one (`priors.stereo_fill`).
    pub fn stereo_coverage(&self) -> Option<(f64, f64)> {
        let (_, maps) = self.stereo.as_ref()?;
        let targets = maps.iter().flatten().flatten();
        let all = targets.clone().count().max(1) as f64;
        let confirmed = targets.clone().filter(|t| t[1] >= 1.0).count() as f64;
        let filled = targets.filter(|t| t[1] > 0.0 && t[1] < 1.0).count() as f64;
        Some((confirmed / all, filled / all))
    }

    /// Each training view's fit of its monocular depth map (empty without
    /// `priors.mono_depth_dir`).
    pub fn mono_fits(&self) -> &[MonoFit] {
        &self.mono_fits
    }

    /// The sweep's targets per scene view, when a stereo prior is on.
    pub fn stereo_targets(&self) -> Option<&StereoTargets> {
        self.stereo.as_ref().map(|(_, maps)| maps)
    }

    /// Random-pose rays a batch carries after its photometric rays (0: none).
    pub fn tv_rays(&self) -> u32 {
        self.n_tv
    }

    /// Planarity triplets a batch carries after its random-pose rays (0: none).
    pub fn triplets(&self) -> u32 {
        self.n_triplets
    }

    /// Rays a batch renders: photometric, random-pose and triplet rays.
    pub fn rays_per_batch(&self) -> u32 {
        self.n + self.n_tv + 3 * self.n_triplets
    }

    /// Samples a batch holds before rays are cut.
    pub fn sample_capacity(&self) -> u32 {
        self.bufs.batch.capacity
    }

    /// Checks that `batch` fits the pipeline: `train.rays_per_batch` rays and targets,
    /// and the random-pose rays the regnerf settings make (none when they make none).
    pub fn check_batch(&self, batch: &PixelBatch) -> Result<(), TrainError> {
        let error = |message: String| Err(TrainError::Config { source_name: "batch".into(), message });
        if batch.rays.len() != self.n as usize || batch.targets.len() != self.n as usize {
            return error(format!("{} rays given, train.rays_per_batch is {}", batch.rays.len(), self.n));
        }
        if self.n_tv > 0 && (batch.tv_rays.len() != self.n_tv as usize || batch.tv_z_scale.len() != self.n_tv as usize) {
            return error(format!("{} random-pose patch rays given, the regnerf settings make {}", batch.tv_rays.len(), self.n_tv));
        }
        let t = &batch.triplets;
        if self.n_triplets > 0 && (t.rays.len() != 3 * self.n_triplets as usize || t.pixel.len() != t.rays.len()) {
            return error(format!("{} planarity triplet rays given, reg.planarity_triplets makes {}", t.rays.len(), 3 * self.n_triplets));
        }
        Ok(())
    }

    /// Whether the edge-guided regularizers can read `batch`: a patch batch carrying the
    /// edge weights of every ray.
    pub fn has_patches(&self, config: &RunConfig, batch: &PixelBatch) -> bool {
        config.train.batch == BatchKind::Patches && batch.reg.len() == self.n as usize
    }

    /// Runs `batch` (checked by [`Pipeline::check_batch`]) forward through `model` and
    /// records every loss and the composite backward into `enc`, the step's encoder
    /// (the batch's uploads are queued before it); waits for nothing (the losses are
    /// read with the step's one readback, [`Pipeline::add_loss_reads`]). Touches no
    /// parameter and no field gradient (see the module doc). With profiling on,
    /// charges the sampler and the field forward to their stages.
    pub fn forward(
        &mut self,
        enc: &mut Encoder,
        model: &mut Model,
        scene: &Scene,
        batch: PixelBatch,
        plan: &StepPlan,
        profile: &mut Option<StageTimes>,
    ) -> Result<(), TrainError> {
        self.upload(enc.gpu(), scene, model, batch, plan);
        model.record_sample(enc, &self.bufs, super::model::MarchGrid::Training, Some(plan.jitter), plan.visibility, plan.march_step, None)?;
        end_recorded_stage(profile, enc, Stage::Sampler)?;
        model.field.record_forward_for_backward(enc, &self.bufs.batch, &self.bufs.field_out, plan.normals())?;
        end_recorded_stage(profile, enc, Stage::FieldForward)?;
        self.record_render_and_losses(enc, model, scene, plan)
    }

    /// Records the field's backward pass over the last [`Pipeline::forward`] into
    /// `enc`: its gradients zeroed, then this batch's added (second order through the
    /// normals when `L_n` or the orientation prior is on).
    pub fn backward(&self, enc: &mut Encoder, model: &mut Model, plan: &StepPlan) -> Result<(), TrainError> {
        model.field.record_zero_grads(enc);
        model.field.record_backward(enc, &self.bufs.batch, &self.field_grads, Some(&self.live.0), plan.normals())?;
        Ok(())
    }

    /// Grows the batch buffers when a batch's rays wanted `wanted` samples, more than
    /// the capacity ([`super::TrainConfig::grow_capacity`]): to 1.25x `wanted`, rounded
    /// up to whole 4096-sample blocks, at most what one storage binding of the device
    /// holds. The capacity never shrinks (one reallocation per new peak, not one per
    /// step). Returns the new capacity when it grew.
    pub fn grow_capacity(&mut self, gpu: &Gpu, wanted: u32) -> Result<Option<u32>, TrainError> {
        let capacity = self.bufs.batch.capacity;
        let limit = (gpu.limits().max_storage_buffer_binding_size / std::mem::size_of::<GpuSample>() as u64).min(u32::MAX as u64) as u32;
        if wanted <= capacity || capacity >= limit {
            return Ok(None);
        }
        let grown = (wanted as u64 * 5 / 4).next_multiple_of(4096).min(limit as u64) as u32;
        let n_all = self.bufs.batch.n_rays;
        self.bufs = BatchBuffers::new(gpu, n_all, grown, self.bufs.visibility.is_some())?;
        self.field_grads = FieldGrads::new(gpu, grown)?;
        self.live = live_list(gpu, grown)?;
        Ok(Some(grown))
    }

    /// The host side of a batch: the random-pose rays appended (zero photometric
    /// weight), every range annealed (RegNeRF), then rays, targets (and their alpha,
    /// with random backgrounds) and the edge and depth-TV weights uploaded.
    fn upload(&mut self, gpu: &Gpu, scene: &Scene, model: &Model, batch: PixelBatch, plan: &StepPlan) {
        let config = &model.config;
        if plan.reg.is_some() {
            self.edge_reg.pixel.write(gpu, &batch.reg);
        }
        if let Some((term, position, _)) = self.reprojection_at(plan) {
            term.source.write(gpu, &batch.views.iter().map(|&v| position[v as usize]).collect::<Vec<_>>());
        }
        let mut free_end = Vec::new();
        if let Some((term, maps)) = &self.stereo {
            let at = |(&v, &p): (&u32, &u32)| maps[v as usize].as_ref().map_or([0.0, 0.0], |m| m[p as usize]);
            let mut targets: Vec<[f32; 2]> = batch.views.iter().zip(&batch.pixels).map(at).collect();
            targets.resize(self.n as usize, [0.0; 2]);
            if config.priors.stereo_free_space > 0.0 {
                // Confirmed depths only: a filled one is a guess.
                let keep = 1.0 - config.priors.stereo_free_margin;
                free_end = targets.iter().map(|&[t, c]| if c >= 1.0 { keep * t } else { 0.0 }).collect();
            }
            term.targets.write(gpu, &targets);
        }
        if let Some((alpha, _)) = &self.random_background {
            let mut a: Vec<f32> = batch.alpha.iter().map(|a| a.unwrap_or(1.0)).collect();
            a.resize(alpha.len(), 1.0);
            alpha.write(gpu, &a);
        }
        let (mut rays, mut targets): (Vec<GpuRay>, Vec<[f32; 4]>) = (batch.rays, batch.targets);
        if self.n_tv > 0 {
            rays.extend_from_slice(&batch.tv_rays);
            self.depth_tv.z_scale.write(gpu, &batch.tv_z_scale);
        }
        if self.n_triplets > 0 {
            rays.extend_from_slice(&batch.triplets.rays);
            self.planarity.pixel.write(gpu, &batch.triplets.pixel);
        }
        // Zero photometric weight for every ray after the photometric ones.
        targets.resize(rays.len(), [0.0; 4]);
        if let Some(anneal) = config.regnerf.anneal_for(scene) {
            anneal.apply(&mut rays, plan.step);
        }
        self.bufs.rays.write(gpu, &rays);
        self.targets.write(gpu, &targets);
        if self.learned_background() || !free_end.is_empty() {
            model.write_ray_inputs(gpu, &rays, &free_end, &self.bufs.render_out.aux);
        }
    }

    /// Whether the training renderer composites the model's learned background (not
    /// random backgrounds).
    fn learned_background(&self) -> bool {
        self.renderer.config().background == Background::Learned
    }

    /// Records the drop of capacity-cut rays, composite forward, the losses into
    /// `d_rays`, composite backward into the per-sample field gradients.
    fn record_render_and_losses(&self, enc: &mut Encoder, model: &Model, scene: &Scene, plan: &StepPlan) -> Result<(), TrainError> {
        let (bufs, n, n_tv) = (&self.bufs, self.n, self.n_tv);
        let n_all = self.rays_per_batch();
        let gpu = enc.gpu();
        // Rays cut by the sample capacity render without their far samples: out of
        // every loss (their weight and their patch's edge weight to 0).
        if let Some(wanted) = model.wanted_counts() {
            let pixels = plan.reg.is_some().then_some(&self.edge_reg.pixel);
            self.drop_truncated.record(enc, &bufs.marched(plan.visibility.is_some()).ranges, wanted, &self.targets, pixels, n);
        }
        self.renderer.forward(enc, &bufs.batch, &bufs.field_out, &bufs.render_out, plan.step as u32)?;
        let rays_out = &bufs.render_out.rays;
        let recomposite = self.random_background.as_ref().map(|(alpha, loaded_over)| Recomposite { alpha, loaded_over: *loaded_over });
        let priors = &model.config.priors;
        let opacity = OpacityPriors {
            sparsity: priors.sparsity_at(plan.step),
            entropy: priors.opacity_entropy_at(plan.step),
            foreground: priors.foreground_opacity,
            foreground_tolerance: priors.foreground_tolerance,
        };
        self.photometric.record(enc, rays_out, &self.targets, &bufs.render_out.aux, recomposite.as_ref(), &self.d_rays, n_all, n as f32, plan.lambda_color, opacity);
        if let Some((term, _)) = self.stereo.as_ref().filter(|_| priors.stereo_depth > 0.0) {
            term.record(enc, rays_out, &self.targets, &self.d_rays, n, priors.stereo_depth, priors.stereo_delta);
        }
        if let Some(w) = &plan.reg {
            self.edge_reg.record(enc, rays_out, &self.d_rays, n / 4, w);
            if let Some(term) = w.depth_normal_term() {
                let (pixel, d_rays) = (&self.edge_reg.pixel, &self.d_rays);
                self.depth_normal.record(enc, rays_out, &bufs.rays, pixel, d_rays, n / 4, &term);
            }
        }
        if let Some(term) = self.planarity_term(plan) {
            self.planarity.record(enc, rays_out, &self.d_rays, n + n_tv, self.n_triplets, &term, scene.ndc.is_some());
        }
        if let Some((term, _, lambda)) = self.reprojection_at(plan) {
            let delta = model.config.reg.reprojection_delta;
            term.record(enc, rays_out, &bufs.rays, &self.targets, &self.d_rays, n, lambda, delta);
        }
        if let Some(lambda) = plan.tv {
            let r = &model.config.regnerf;
            let acc_weight = r.acc_weight_for(scene);
            self.depth_tv.record(enc, rays_out, &bufs.rays, &self.d_rays, n, n_tv, r.patch_size, lambda, acc_weight);
        }
        self.renderer.backward(enc, &bufs.batch, &bufs.field_out, &bufs.render_out, &self.d_rays, &self.field_grads, false)?;
        let (live, compaction) = &self.live;
        compaction.record(gpu, enc, &bufs.batch, &self.field_grads, plan.normals(), live)?;
        Ok(())
    }

    /// The planarity term's settings at `plan`'s step, `None` when it does not run (off,
    /// or the batch carries no triplets).
    fn planarity_term(&self, plan: &StepPlan) -> Option<PlanarityTerm> {
        plan.reg.and_then(|w| w.planarity_term()).filter(|_| self.n_triplets > 0)
    }

    /// The reprojection term, its views' training positions and its weight at `plan`'s
    /// step, `None` when it does not run.
    fn reprojection_at(&self, plan: &StepPlan) -> Option<(&Reprojection, &[u32], f32)> {
        let (term, position) = self.reprojection.as_ref()?;
        let lambda = plan.reg?.lambda_reprojection;
        (lambda > 0.0).then_some((term, position.as_slice(), lambda))
    }

    /// The per-ray (per-patch, per-triplet) loss buffers of the terms on at `plan`'s
    /// step and the ray aux when the priors are on: what the host sums into
    /// [`BatchLosses`] and the optimizer's guard checks for NaN / Inf (one list, so the
    /// two cannot drift apart).
    fn loss_terms(&self, plan: &StepPlan) -> LossTerms<'_> {
        let (n, quarter) = (self.n as usize, self.n as usize / 4);
        let dn_on = plan.reg.and_then(|w| w.depth_normal_term()).is_some();
        LossTerms {
            sq_error: (&self.photometric.sq_error, n),
            reg: plan.reg.is_some().then_some((&self.edge_reg.patch_loss, quarter)),
            depth_normal: dn_on.then_some((&self.depth_normal.patch_loss, quarter)),
            tv: plan.tv.is_some().then_some((&self.depth_tv.ray_loss, self.n_tv as usize)),
            planarity: self.planarity_term(plan).map(|_| (&self.planarity.triplet_loss, self.n_triplets as usize)),
            reprojection: self.reprojection_at(plan).map(|(t, _, _)| (&t.ray_loss, n)),
            aux: self.priors_on.then_some(&self.bufs.render_out.aux),
        }
    }

    /// The guard buffers of the last [`Pipeline::forward`] for
    /// [`crate::optim::GradNorm::record_guarded`]: a NaN / Inf in any loss the host
    /// reads makes Adam skip the step on the GPU.
    pub fn loss_guards(&self, plan: &StepPlan) -> Vec<Guard<'_>> {
        let t = self.loss_terms(plan);
        let terms = [Some(t.sq_error), t.depth_normal, t.tv, t.planarity, t.reprojection];
        let mut guards: Vec<Guard> = terms.into_iter().flatten().map(|(buffer, len)| Guard::of(buffer, len)).collect();
        guards.extend(t.reg.map(|(buffer, len)| Guard::of(buffer, len)));
        // RayAux holds floats, a sample count and padding: every word a finite float
        // or a small integer, as a guard requires.
        guards.extend(t.aux.map(|aux| Guard::of(aux, aux.len())));
        guards
    }

    /// Adds the last batch's losses and the sampler's counts to `reads` (the step's one
    /// readback); [`Pipeline::losses`] turns them into [`BatchLosses`]. `cut`: whether
    /// the sampler counted the rays' wanted samples (then the drop of cut rays ran).
    pub fn add_loss_reads<'a>(&'a self, reads: &mut ReadBatch<'a>, plan: &StepPlan, cut: bool) -> LossReads {
        let t = self.loss_terms(plan);
        let counts = reads.add(&self.bufs.batch.count, 2);
        let marched = reads.add(&self.bufs.marched(plan.visibility.is_some()).count, 1);
        let dropped = cut.then(|| reads.add(self.drop_truncated.dropped_count(), 1));
        let sq_error = reads.add(t.sq_error.0, t.sq_error.1);
        let reg = t.reg.map(|(buffer, len)| reads.add(buffer, len));
        let aux = t.aux.map(|aux| reads.add(aux, aux.len()));
        let background = self
            .learned_background()
            .then(|| (reads.add(&self.d_rays, self.n as usize), reads.add(&self.bufs.render_out.rays, self.n as usize)));
        let mut add = |term: Option<(&'a GpuBuffer<f32>, usize)>| term.map(|(buffer, len)| reads.add(buffer, len));
        LossReads {
            counts,
            marched,
            dropped,
            sq_error,
            reg,
            depth_normal: add(t.depth_normal),
            tv: add(t.tv),
            planarity: add(t.planarity),
            reprojection: add(t.reprojection),
            aux,
            background,
        }
    }

    /// With a learned background, what its step needs from the readback of
    /// [`Pipeline::add_loss_reads`]: the photometric rays' `dL/d rgb` and opacity.
    pub fn background_grads(&self, back: &ReadBack, slots: &LossReads) -> Option<(Vec<[f32; 3]>, Vec<f32>)> {
        let (d, out) = slots.background.as_ref()?;
        let d_rgb = back.get(d).iter().map(|g| g.rgb).collect();
        let opacity = back.get(out).iter().map(|o| o.opacity).collect();
        Some((d_rgb, opacity))
    }

    /// The losses of [`Pipeline::add_loss_reads`]'s slots in `back`.
    pub fn losses(&self, back: &ReadBack, slots: &LossReads) -> BatchLosses {
        let rays_dropped = slots.dropped.as_ref().map_or(0, |d| back.get(d)[0]);
        let counts = back.get(&slots.counts);
        let priors = *self.renderer.priors();
        let p = slots.aux.as_ref().map(|a| priors.losses(&back.get(a))).unwrap_or_default();
        let reg = slots.reg.as_ref().map(|r| EdgeReg::losses_of(&back.get(r))).unwrap_or_default();
        let sum = |slot: &Option<ReadSlot<f32>>| slot.as_ref().map_or(0.0, |s| sum_terms(&back.get(s)));
        BatchLosses {
            color: Photometric::mse_of(&back.get(&slots.sq_error), self.n.saturating_sub(rays_dropped).max(1) as f32),
            depth: reg.depth,
            normal: reg.normal,
            tv: sum(&slots.tv),
            distortion: p.distortion,
            occlusion: p.occlusion,
            orientation: p.orientation,
            depth_normal: sum(&slots.depth_normal),
            planarity: sum(&slots.planarity),
            reprojection: sum(&slots.reprojection),
            rays_dropped,
            samples: [counts[0], counts[1], back.get(&slots.marched)[0]],
            priors,
        }
    }
}

/// The loss buffers of one step ([`Pipeline::loss_terms`]): each with the elements
/// read, `None` when its term is off.
struct LossTerms<'a> {
    sq_error: (&'a GpuBuffer<f32>, usize),
    reg: Option<(&'a GpuBuffer<[f32; 2]>, usize)>,
    depth_normal: Option<(&'a GpuBuffer<f32>, usize)>,
    tv: Option<(&'a GpuBuffer<f32>, usize)>,
    planarity: Option<(&'a GpuBuffer<f32>, usize)>,
    reprojection: Option<(&'a GpuBuffer<f32>, usize)>,
    aux: Option<&'a GpuBuffer<RayAux>>,
}

/// Where a step's losses are in its readback ([`Pipeline::add_loss_reads`]).
pub struct LossReads {
    counts: ReadSlot<u32>,
    /// The march's written count (the same as `counts[0]` without the visibility pass).
    marched: ReadSlot<u32>,
    dropped: Option<ReadSlot<u32>>,
    sq_error: ReadSlot<f32>,
    reg: Option<ReadSlot<[f32; 2]>>,
    depth_normal: Option<ReadSlot<f32>>,
    tv: Option<ReadSlot<f32>>,
    planarity: Option<ReadSlot<f32>>,
    reprojection: Option<ReadSlot<f32>>,
    aux: Option<ReadSlot<RayAux>>,
    /// With a learned background: the photometric rays' `dL/d RayOutput` and outputs.
    background: Option<(ReadSlot<RayOutput>, ReadSlot<RayOutput>)>,
}

/// The reprojection term over batches of `n` photometric rays of `scene`, with the
/// position of each scene view in the training list (`u32::MAX` for views that are not
/// training views). A configuration error when the scene cannot be reprojected or its
/// training images exceed what one storage binding of the device holds.
fn reprojection_term(gpu: &Gpu, scene: &Scene, n: u32, blur: f32) -> Result<(Reprojection, Vec<u32>), TrainError> {
    let error = |message: String| TrainError::Config { source_name: "config".into(), message };
    check_reprojection_fits(scene, gpu.limits().max_storage_buffer_binding_size)?;
    let views = super::reprojection_views::reprojection_views(scene, blur).map_err(error)?;
    let mut position = vec![u32::MAX; scene.views.len()];
    for (i, &v) in scene.split.train.iter().enumerate() {
        position[v] = i as u32;
    }
    Ok((Reprojection::new(gpu, &views, n)?, position))
}

/// Refuses a scene whose training images, packed for the cross-view reprojection term
/// (which keeps them all on the GPU), exceed `binding_limit` bytes (one storage binding
/// of the device): from the image sizes alone, so `train` can say so before it spends
/// time on edge detection (the CLI calls it first; [`Pipeline::new`] again).
pub fn check_reprojection_fits(scene: &Scene, binding_limit: u64) -> Result<(), TrainError> {
    let sizes = scene.train_views().map(|v| (v.camera.width, v.camera.height));
    let bytes = crate::loss::reprojection::ReprojectionViews::packed_bytes(sizes);
    if bytes > binding_limit {
        return Err(TrainError::Config {
            source_name: "config".into(),
            message: format!(
                "the reprojection term keeps every training image on the GPU ({} MB), more than one storage binding of this device holds ({} MB); train on fewer or smaller views (--llff-factor N downsamples on load), or set reg.lambda_reprojection = 0",
                bytes >> 20,
                binding_limit >> 20
            ),
        });
    }
    Ok(())
}

/// The list of live samples and its compaction, for batches of `capacity` samples.
fn live_list(gpu: &Gpu, capacity: u32) -> Result<(LiveSamples, LiveCompaction), TrainError> {
    Ok((LiveSamples::new(gpu, capacity)?, LiveCompaction::new(gpu, capacity)?))
}

#[cfg(test)]
mod tests {
    use super::check_reprojection_fits;
    use crate::data::{LoadOptions, Scene};
    use crate::loss::reprojection::ReprojectionViews;

    #[test]
    fn a_scene_too_large_for_the_reprojection_term_is_refused_from_its_sizes() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/creases");
        // Cameras only: the check needs no pixels (it runs before edge detection).
        let scene = Scene::load(dir, &LoadOptions { views: Some(3), load_images: false, ..Default::default() }).unwrap();
        let bytes = ReprojectionViews::packed_bytes(scene.train_views().map(|v| (v.camera.width, v.camera.height)));
        assert!(bytes > 3 * 4 * 128 * 128, "{bytes}");
        check_reprojection_fits(&scene, bytes).unwrap();
        let err = check_reprojection_fits(&scene, bytes - 1).unwrap_err().to_string();
        assert!(err.contains("reg.lambda_reprojection = 0") && err.contains("fewer or smaller views"), "{err}");
    }
}
