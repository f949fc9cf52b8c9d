//! A trained (or training) model: field + occupancy grid + sampler + renderer, built
//! fresh ([`Model::new`]) or from a checkpoint without any optimizer state
//! ([`Model::from_checkpoint`]), and rendering of arbitrary rays and whole views with it.
//! Training batches run through the same model in [`super::pipeline`].
//!
//! Invariants: the model never changes parameters (the [`Trainer`](super::Trainer)
//! does); the occupancy grid is refreshed only through [`Model::update_occupancy`], from the
//! field's own densities, or restored from a checkpoint; the finer grid renders may
//! march (`sampler.render_resolution`) is built from the field as it is at the render
//! and dropped whenever the field or the training grid changes; rendering for images
//! uses no jitter (deterministic output).

use crate::data::{Camera, Scene};
use crate::field::{Field, Footprint, GridField, MlpField};
use crate::gpu::{Encoder, Gpu, GpuBuffer};
use crate::render::{Background, LearnedBackground, RenderConfig, RenderOutputs, Renderer};
use crate::sampler::{OccupancyUpdate, March, OccupancyGrid, Sampler, SamplerMode, Visibility, VisibilityPass};
use crate::layout::{FieldOutputs, GpuRay, GpuSample, RayOutput, SampleBatch, SampleRange};

use super::TrainError;
use super::checkpoint::Checkpoint;
use super::config::{Backend, RunConfig};

/// Rays rendered per chunk when rendering images.
const RENDER_CHUNK: u32 = 4096;

/// Points per GPU launch of [`Model::densities`] and [`Model::colors_at`].
const POINT_CHUNK: usize = 1 << 18;

/// A rendered view: per pixel, row-major.
#[derive(Clone, Debug)]
pub struct RenderedView {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
    pub opacity: Vec<f32>,
    /// Expected ray distance `sum w_i t_i` (NDC parameter for forward-facing scenes).
    pub depth: Vec<f32>,
    /// Expected depth along the camera axis, `depth * z_scale` (world scenes only;
    /// equal to `depth` in NDC, whose parameter is already along the axis).
    pub z_depth: Vec<f32>,
    /// `sum w_i n_i` (not renormalised).
    pub normal: Vec<[f32; 3]>,
    /// Field samples evaluated.
    pub samples: u64,
}

impl RenderedView {
    /// Expected ray distance given that the ray terminates, `depth / opacity` (the
    /// scene's far distance where the opacity is below 1e-3): what depth maps show and
    /// what is compared with ground truth, unbiased by partial opacity.
    pub fn terminated_depth(&self, far: f32) -> Vec<f32> {
        self.depth.iter().zip(&self.opacity).map(|(&d, &a)| if a > 1e-3 { d / a } else { far }).collect()
    }

    /// Normals renormalised to unit length (zero where the rendered normal vanishes).
    pub fn unit_normals(&self) -> Vec<[f32; 3]> {
        self.normal
            .iter()
            .map(|n| {
                let v = glam::Vec3::from(*n);
                let l = v.length();
                if l > 1e-6 { (v / l).to_array() } else { [0.0; 3] }
            })
            .collect()
    }
}

/// Per-batch GPU buffers of one batch size.
pub(super) struct BatchBuffers {
    pub rays: GpuBuffer<GpuRay>,
    /// The samples the field and renderer run on: the march's, or those the
    /// visibility pass kept of them.
    pub batch: SampleBatch,
    pub field_out: FieldOutputs,
    pub render_out: RenderOutputs,
    /// With the visibility pass: the marched samples and the pass (their densities go
    /// into `field_out`, which the forward of the kept samples then overwrites).
    pub visibility: Option<VisibilityBuffers>,
}

/// What the visibility pass needs beside a batch ([`crate::sampler::visibility`]).
pub(super) struct VisibilityBuffers {
    pub marched: SampleBatch,
    pub pass: VisibilityPass,
}

impl BatchBuffers {
    /// Buffers for `n_rays` rays and `capacity` samples, with those of the visibility
    /// pass when `visibility`.
    pub fn new(gpu: &Gpu, n_rays: u32, capacity: u32, visibility: bool) -> Result<Self, TrainError> {
        let visibility = if visibility {
            Some(VisibilityBuffers {
                marched: SampleBatch::new(gpu, n_rays, capacity)?,
                pass: VisibilityPass::new(gpu, n_rays)?,
            })
        } else {
            None
        };
        Ok(Self {
            rays: GpuBuffer::zeros(gpu, "rays", n_rays as usize)?,
            batch: SampleBatch::new(gpu, n_rays, capacity)?,
            field_out: FieldOutputs::new(gpu, capacity)?,
            render_out: RenderOutputs::new(gpu, n_rays, None)?,
            visibility,
        })
    }

    /// The batch the march wrote when the visibility pass `ran` (its ranges are what
    /// the capacity cut is told from), else the batch itself.
    pub fn marched(&self, ran: bool) -> &SampleBatch {
        match &self.visibility {
            Some(v) if ran => &v.marched,
            _ => &self.batch,
        }
    }
}

/// Field, occupancy grid, sampler and renderer of one run.
pub struct Model {
    pub config: RunConfig,
    pub field: Box<dyn Field>,
    pub occupancy: OccupancyGrid,
    sampler: Sampler,
    renderer: Renderer,
    /// The learned background of captures without alpha (`Background::Learned`):
    /// trained by the [`super::Trainer`], read by every render.
    pub background: Option<LearnedBackground>,
    occupancy_densities: Option<GpuBuffer<f32>>,
    render_buffers: Option<BatchBuffers>,
    /// The finer grid renders march (`sampler.render_resolution`), built from the field
    /// at the first render after the field or the training grid last changed
    /// ([`Model::forget_render_grid`]); `None` until then, or without the option.
    render_grid: Option<OccupancyGrid>,
}

/// Which occupancy grid a march goes through: training's, or the finer one of renders
/// (`sampler.render_resolution`; the training grid where there is none).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum MarchGrid {
    Training,
    Render,
}

/// The pixel footprint of the scene's training cameras, for the MLP's integrated
/// encoding (mip-NeRF: a pixel is a disk of radius `2 / sqrt(12)` pixel widths):
/// world scenes have cones of radius `t * 2 / (sqrt(12) fx)` (`fx` averaged over the
/// training views); NDC maps every pixel to a cylinder of width `2 / W`. Density
/// queries use the variance of a uniform distribution over an occupancy cell.
pub fn footprint(scene: &Scene, sampler: &crate::sampler::SamplerConfig) -> Footprint {
    let k = 2.0 / 12f32.sqrt();
    let cams: Vec<_> = scene.split.train.iter().map(|&v| &scene.views[v].camera).collect();
    let mean = |f: &dyn Fn(&crate::data::Camera) -> f32| cams.iter().map(|c| f(c)).sum::<f32>() / cams.len().max(1) as f32;
    let (radius0, radius1) = match scene.ndc {
        Some(_) => (k * mean(&|c| 2.0 / c.width as f32), 0.0),
        None => (0.0, k * mean(&|c| 1.0 / c.fx)),
    };
    let cell = (scene.aabb[1] - scene.aabb[0]).max_element() / sampler.resolution.max(1) as f32;
    Footprint { radius0, radius1, point_var: cell * cell / 12.0 }
}

/// The test of whether a box `lo..hi` (world space) appears in at least `min_views`
/// training images: a camera images it when its corners are not all behind the camera
/// and the bounding rectangle of their projections overlaps the image (conservative: a
/// box straddling the camera plane counts as seen). The cameras' world-to-camera
/// matrices are computed once, here, for the millions of cells the test then visits.
/// NDC scenes need no such test: their box is the reference frustum.
pub fn seen_by_training_cameras(scene: &Scene, min_views: u32) -> impl Fn(glam::Vec3, glam::Vec3) -> bool + Sync + '_ {
    let cameras: Vec<_> = scene.train_views().map(|v| (&v.camera, v.camera.w2c())).collect();
    move |lo, hi| {
        let imaged = cameras.iter().filter(|(cam, w2c)| {
            let (mut min, mut max) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
            let mut behind = 0;
            for k in 0..8 {
                let corner = glam::Vec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                );
                match cam.project_with(w2c, corner) {
                    Some((px, _)) => {
                        min = min.min(px);
                        max = max.max(px);
                    }
                    None => behind += 1,
                }
            }
            match behind {
                8 => false,
                0 => max.x >= 0.0 && max.y >= 0.0 && min.x < cam.width as f32 && min.y < cam.height as f32,
                _ => true,
            }
        });
        imaged.count() >= min_views as usize
    }
}

/// The background a run renders over: the configured colour, else the scene's, else
/// `render.background`, whose default [`Background::Auto`] is a learned background for
/// world-space scenes whose training images have no alpha (photographs: what lies
/// beyond the box needs a colour other than fog) and black for the others (NDC rays
/// end at infinity).
pub fn background_of(config: &RunConfig, scene: &Scene) -> Background {
    match config.scene.background.or(scene.background) {
        Some(rgb) => Background::Color { rgb },
        None => match config.render.background {
            Background::Auto if scene.ndc.is_none() && scene.train_views().all(|v| v.alpha.is_none()) => Background::Learned,
            Background::Auto => Background::Black,
            other => other,
        },
    }
}

/// The rays (the field's ray space) and colours of the pixels in a frame around
/// each training image, `max(1, min(w, h) / 50)` pixels wide, at most about 20 000 in
/// all (a regular subsample): what a learned background is fitted to before training
/// (in object-centric captures the frame mostly shows what lies behind the object).
pub fn frame_pixels(scene: &Scene) -> (Vec<GpuRay>, Vec<[f32; 3]>) {
    let mut picked = Vec::new();
    for &v in &scene.split.train {
        let view = &scene.views[v];
        let (w, h) = (view.camera.width as usize, view.camera.height as usize);
        if view.image.data.len() < 3 * w * h {
            continue;
        }
        let band = (w.min(h) / 50).max(1);
        for y in 0..h {
            for x in 0..w {
                if x < band || y < band || x + band >= w || y + band >= h {
                    picked.push((v, x, y));
                }
            }
        }
    }
    let stride = picked.len().div_ceil(20_000).max(1);
    let (mut rays, mut colors) = (Vec::new(), Vec::new());
    for &(v, x, y) in picked.iter().step_by(stride) {
        let view = &scene.views[v];
        let cam = &view.camera;
        let ray = cam.pixel_ray(x as f32 + 0.5, y as f32 + 0.5);
        let ray = scene.ndc.as_ref().map_or(ray, |ndc| ndc.ray_to_ndc(ray));
        rays.push(super::rays::to_gpu_ray(scene, &ray));
        let i = 3 * (y * cam.width as usize + x);
        colors.push([view.image.data[i], view.image.data[i + 1], view.image.data[i + 2]]);
    }
    (rays, colors)
}

impl Model {
    /// A freshly initialised model for `scene` with `config` as given (a run's config
    /// is first [`RunConfig::resolve_for`] the scene).
    pub fn new(gpu: &Gpu, scene: &Scene, config: RunConfig) -> Result<Model, TrainError> {
        let field: Box<dyn Field> = match config.backend {
            Backend::Grid => Box::new(GridField::new(gpu, &config.field, scene.aabb)?),
            Backend::Mlp => Box::new(MlpField::new(gpu, &config.mlp, scene.aabb, footprint(scene, &config.sampler))?),
        };
        let mut occupancy = OccupancyGrid::new(gpu, &config.sampler, scene.aabb)?;
        if config.sampler.seen_cells_only && scene.ndc.is_none() {
            let (need, have) = (config.sampler.seen_views, scene.split.train.len());
            if need as usize > have {
                return Err(TrainError::Config {
                    source_name: "sampler.seen_views".into(),
                    message: format!(
                        "sampler.seen_views = {need}: a cell must be seen by more training cameras than the run has ({have}); \
                         set it to at most {have}"
                    ),
                });
            }
            occupancy.restrict_to_seen(gpu, seen_by_training_cameras(scene, need))?;
        }
        let sampler = Sampler::new(&config.sampler, scene.aabb)?;
        let mut render_config = config.render;
        render_config.background = background_of(&config, scene);
        let background = (render_config.background == Background::Learned).then(|| LearnedBackground::new(config.render.learned_background, scene.aabb));
        let renderer = Renderer::new(gpu, render_config)?;
        Ok(Model {
            config,
            field,
            occupancy,
            sampler,
            renderer,
            background,
            occupancy_densities: None,
            render_buffers: None,
            render_grid: None,
        })
    }

    /// The model of a checkpoint, ready to render, without optimizer state: its config
    /// [`RunConfig::resolve_for`] `scene`, its field's parameters with the encoding
    /// levels its last step used (coarse-to-fine runs), and its occupancy grid's
    /// densities (so renders skip exactly the space training skipped), or, for a
    /// checkpoint without them (uniform sampling, older files), a grid rebuilt from the
    /// restored field. It renders as the trained model did at the end of its run.
    pub fn from_checkpoint(gpu: &Gpu, scene: &Scene, ckpt: &Checkpoint) -> Result<Model, TrainError> {
        let mut config = ckpt.config.clone();
        config.resolve_for(scene)?;
        let mut model = Model::new(gpu, scene, config)?;
        check_field_arrays(&model.field.export(gpu)?, &ckpt.field)?;
        model.field.import(gpu, &ckpt.field)?;
        if let Some(bg) = &mut model.background {
            bg.import(&ckpt.background).map_err(|message| TrainError::Config { source_name: "checkpoint".into(), message })?;
        }
        match &ckpt.occupancy {
            Some(density) if model.config.sampler.mode == SamplerMode::Occupancy => {
                model.occupancy.restore_density(gpu, density)?;
            }
            _ => {
                model.update_occupancy(gpu, ckpt.step, model.occupancy_seed(ckpt.step), true)?;
            }
        }
        // The levels the last trained step used, as the trained model had them (after
        // any grid rebuild, which queries every level as it always has).
        model.set_levels_for_step(ckpt.step.saturating_sub(1));
        Ok(model)
    }

    /// Coarse-to-fine (`train.level_anneal`): activates the field's encoding levels of
    /// step `step`, from `start_levels` up to all of them over `steps` steps; does
    /// nothing without the option or for a field without levels.
    pub fn set_levels_for_step(&mut self, step: u64) {
        let levels = self.field.encoding_levels();
        if let Some(a) = &self.config.train.level_anneal
            && levels > 0
        {
            let frac = if a.steps == 0 { 1.0 } else { (step as f64 / a.steps as f64).min(1.0) };
            let start = a.start_levels.min(levels) as f64;
            let active = (start + frac * (levels as f64 - start)).floor() as u32;
            self.field.set_active_levels(active.max(1));
            self.forget_render_grid();
        }
    }

    /// The marching step of a training step with the field's levels as they are now:
    /// the finest active level's cell over `sampler.anneal_samples_per_cell` when that
    /// is longer than the configured step, else `None` (the configured step).
    pub fn training_march_step(&self) -> Option<f32> {
        let per_cell = self.config.sampler.anneal_samples_per_cell;
        if per_cell <= 0.0 {
            return None;
        }
        let coarse = self.field.finest_active_cell()? / per_cell;
        (coarse > self.sampler.step_size()).then_some(coarse)
    }

    /// The seed of the occupancy grid's random cells at `step`.
    pub fn occupancy_seed(&self, step: u64) -> u32 {
        (self.config.train.seed as u32).wrapping_mul(0x9E37_79B9) ^ (step as u32)
    }

    /// The renderer's settings (the background resolved for the scene).
    pub fn render_config(&self) -> &RenderConfig {
        self.renderer.config()
    }

    /// Fraction of the occupancy grid's cells marked occupied.
    pub fn occupied_fraction(&self) -> f32 {
        self.occupancy.occupied_cells() as f32 / self.config.sampler.resolution.pow(3) as f32
    }

    /// Per-ray sample counts of the last sampled batch before the capacity cap
    /// ([`Sampler::wanted_counts`]); `None` before the first batch.
    pub(super) fn wanted_counts(&self) -> Option<&GpuBuffer<u32>> {
        self.sampler.wanted_counts()
    }

    /// Refreshes the occupancy grid from the field if `step` is an update step (or
    /// `force`). Returns what the update did. A forced update (resume, rendering a
    /// checkpoint: the grid starts empty) refreshes every cell, as the warm-up does;
    /// past the warm-up a regular update visits only a quarter of the cells plus the
    /// occupied ones, which would leave most of an empty grid empty.
    pub fn update_occupancy(&mut self, gpu: &Gpu, step: u64, seed: u32, force: bool) -> Result<Option<OccupancyUpdate>, TrainError> {
        if self.config.sampler.mode == SamplerMode::Uniform || !(force || self.occupancy.should_update(step as u32)) {
            return Ok(None);
        }
        self.forget_render_grid();
        let query_step = if force { 0 } else { step as u32 };
        // The query, the densities and the update in one submission, one wait.
        let mut enc = gpu.encoder();
        let query = self.occupancy.record_query_points(&mut enc, query_step, seed)?;
        if self.occupancy_densities.as_ref().is_none_or(|b| b.len() < query.count as usize) {
            self.occupancy_densities = Some(GpuBuffer::zeros(gpu, "grid densities", query.positions.len())?);
        }
        let densities = self.occupancy_densities.as_ref().unwrap();
        self.field.record_density(&mut enc, &query.positions, query.count, densities)?;
        self.occupancy.record_update(&mut enc, &query.cells, densities, query.count, query.decay)?;
        Ok(Some(self.occupancy.finish_update(enc)?))
    }

    /// Samples `bufs.rays[..n]` into `bufs.batch` and runs the field forward.
    /// Renders with the visibility pass when `sampler.visibility.render`.
    pub(super) fn sample_and_shade(
        &mut self,
        gpu: &Gpu,
        bufs: &BatchBuffers,
        jitter_seed: Option<u32>,
        normals: bool,
    ) -> Result<(), TrainError> {
        let visible = self.config.sampler.visibility.render.then(|| self.config.sampler.visibility.rule());
        gpu.submit_recorded(|enc| self.record_sample(enc, bufs, MarchGrid::Render, jitter_seed, visible, None, None))?;
        self.field.forward(gpu, &bufs.batch, &bufs.field_out, normals)?;
        Ok(())
    }

    /// Samples `bufs.rays[..n]` into `bufs.batch`, recorded into `enc` (the caller
    /// submits). With a `visible` rule (and `bufs` made for it) the march writes
    /// `bufs.visibility`'s batch, the field's densities there decide which samples a
    /// ray can see, and only those go into `bufs.batch`. `step`: march at this step
    /// instead of the configured one ([`Model::training_march_step`]); `max_per_ray`:
    /// keep at most this many samples a ray instead of `sampler.max_samples_per_ray`
    /// (the segments of [`Model::render_rays`]); `grid`: the grid marched.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_sample(
        &mut self,
        enc: &mut Encoder,
        bufs: &BatchBuffers,
        grid: MarchGrid,
        jitter_seed: Option<u32>,
        visible: Option<Visibility>,
        step: Option<f32>,
        max_per_ray: Option<u32>,
    ) -> Result<(), TrainError> {
        let step = step.unwrap_or(self.sampler.step_size());
        // Spelled out (not a `&self` helper) so the grid and the sampler borrow apart.
        let march = match self.config.sampler.mode {
            SamplerMode::Occupancy => March::Occupancy(match (grid, &self.render_grid) {
                (MarchGrid::Render, Some(fine)) => fine,
                _ => &self.occupancy,
            }),
            SamplerMode::Uniform => March::Uniform,
        };
        match (&bufs.visibility, visible) {
            (Some(v), Some(rule)) => {
                self.sampler.record_sample_with_step(enc, march, &bufs.rays, &v.marched, jitter_seed, step, max_per_ray)?;
                // The marched samples' densities in `field_out`: the pass reads them
                // before the forward of the kept samples overwrites the buffer.
                self.field.record_sample_density(enc, &v.marched, &bufs.field_out)?;
                v.pass.record(enc, &v.marched, &bufs.field_out, &bufs.batch, rule)?;
            }
            _ => self.sampler.record_sample_with_step(enc, march, &bufs.rays, &bufs.batch, jitter_seed, step, max_per_ray)?,
        }
        Ok(())
    }

    /// Renders arbitrary rays (no jitter), `normals` on request. Returns the per-ray
    /// outputs and the number of samples evaluated.
    pub fn render_rays(&mut self, gpu: &Gpu, rays: &[GpuRay], normals: bool) -> Result<(Vec<RayOutput>, u64), TrainError> {
        let capacity = RENDER_CHUNK * self.config.sampler.max_samples_per_ray.min(1024);
        let capacity = capacity.min((gpu.limits().max_storage_buffer_binding_size / 32) as u32);
        if self.render_buffers.is_none() {
            self.render_buffers = Some(BatchBuffers::new(gpu, RENDER_CHUNK, capacity, self.config.sampler.visibility.render)?);
        }
        self.ensure_render_grid(gpu)?;
        let bufs = self.render_buffers.take().unwrap();
        let result = (|| {
            let mut out = Vec::with_capacity(rays.len());
            let mut samples = 0u64;
            for chunk in rays.chunks(RENDER_CHUNK as usize) {
                let mut padded = chunk.to_vec();
                padded.resize(RENDER_CHUNK as usize, GpuRay::default());
                let learned = self.write_ray_inputs(gpu, &padded, &[], &bufs.render_out.aux);
                if self.renders_in_segments() {
                    let (rendered, n) = self.render_segments(gpu, &bufs, &padded, learned, normals)?;
                    out.extend_from_slice(&rendered[..chunk.len()]);
                    samples += n;
                    continue;
                }
                bufs.rays.write(gpu, &padded);
                self.sample_and_shade(gpu, &bufs, None, normals)?;
                let mut enc = gpu.encoder();
                self.renderer.forward(&mut enc, &bufs.batch, &bufs.field_out, &bufs.render_out, 0)?;
                enc.submit();
                out.extend_from_slice(&bufs.render_out.rays.read(gpu)?[..chunk.len()]);
                samples += bufs.batch.count.read(gpu)?[0] as u64;
            }
            Ok((out, samples))
        })();
        self.render_buffers = Some(bufs);
        result
    }

    /// Builds the finer grid of renders (`sampler.render_resolution`, see
    /// [`OccupancyGrid::refined`]) from the field as it is now, unless built at that
    /// resolution since the field or the training grid last changed; without the option
    /// (or a grid) drops any.
    fn ensure_render_grid(&mut self, gpu: &Gpu) -> Result<(), TrainError> {
        let sampler = &self.config.sampler;
        let resolution = sampler.render_resolution;
        if resolution == 0 || sampler.mode != SamplerMode::Occupancy {
            self.render_grid = None;
            return Ok(());
        }
        if self.render_grid.as_ref().is_some_and(|g| g.resolution() == resolution) {
            return Ok(());
        }
        let seed = (self.config.train.seed as u32).wrapping_mul(0x85EB_CA6B) ^ 0x5245_4E44;
        let field = &self.field;
        let fine = self.occupancy.refined(gpu, resolution, seed, |enc, points, count, out| {
            field.record_density(enc, points, count, out).map_err(TrainError::from)
        })?;
        self.render_grid = Some(fine);
        Ok(())
    }

    /// Drops the finer grid of renders, to be rebuilt at the next render: the
    /// [`super::Trainer`] calls it after each step, [`Model::update_occupancy`] and
    /// [`Model::set_levels_for_step`] themselves.
    pub(super) fn forget_render_grid(&mut self) {
        self.render_grid = None;
    }

    /// Fraction of the render grid's cells marked occupied (`None` until a render has
    /// built it, or without `sampler.render_resolution`).
    pub fn render_grid_occupied_fraction(&self) -> Option<f32> {
        self.render_grid.as_ref().map(|g| g.occupied_cells() as f32 / g.resolution().pow(3) as f32)
    }

    /// Whether [`Model::render_rays`] renders in segments (`sampler.render_segment`;
    /// not through the visibility pass).
    fn renders_in_segments(&self) -> bool {
        let sampler = &self.config.sampler;
        sampler.render_segment > 0 && !sampler.visibility.render
    }

    /// One chunk of rays (their renderer inputs already in `bufs`; `learned`: the
    /// learned background's colours behind them, where there is one) rendered in
    /// segments ([`super::render_segments`]): the outputs and the samples shaded.
    fn render_segments(
        &mut self,
        gpu: &Gpu,
        bufs: &BatchBuffers,
        rays: &[GpuRay],
        learned: Option<Vec<[f32; 3]>>,
        normals: bool,
    ) -> Result<(Vec<RayOutput>, u64), TrainError> {
        use super::render_segments::{FEW_OPAQUE, SegmentedRays};
        let sampler = &self.config.sampler;
        let max = sampler.max_samples_per_ray.min(bufs.batch.capacity / bufs.batch.n_rays).max(1);
        let mut cap = sampler.render_segment.min(max);
        // The background each ray is composited over (the renderer's, launch seed 0).
        let background = learned.unwrap_or_else(|| {
            (0..rays.len() as u32).map(|r| crate::render::background_of(&self.renderer.config().background, 0, r).unwrap_or([0.0; 3])).collect()
        });
        let mut segments = SegmentedRays::new(rays, background, self.renderer.config().transmittance_threshold);
        let mut samples = 0u64;
        while segments.any_active() && cap > 0 {
            bufs.rays.write(gpu, segments.rays());
            gpu.submit_recorded(|enc| self.record_sample(enc, bufs, MarchGrid::Render, None, None, None, Some(cap)))?;
            self.field.forward(gpu, &bufs.batch, &bufs.field_out, normals)?;
            let mut enc = gpu.encoder();
            self.renderer.forward(&mut enc, &bufs.batch, &bufs.field_out, &bufs.render_out, 0)?;
            let mut read = crate::gpu::ReadBatch::new();
            let count = read.add(&bufs.batch.count, 1);
            let outs = read.add(&bufs.render_out.rays, rays.len());
            let ranges = read.add(&bufs.batch.ranges, rays.len());
            let back = read.read_after(enc)?;
            let n = back.get(&count)[0];
            let marched = if n > 0 { bufs.batch.samples.read_prefix(gpu, n as usize)? } else { Vec::new() };
            let (opaque, of) = segments.add(&back.get(&outs), &back.get(&ranges), &marched, cap);
            samples += n as u64;
            let left = max - segments.used().min(max);
            cap = if opaque * FEW_OPAQUE < of { left } else { (2 * cap).min(left) };
        }
        Ok((segments.finish(), samples))
    }

    /// Writes the renderer's per-ray inputs into `aux`: with a learned background each
    /// ray's background colour (what the renderer composites behind it), and the
    /// stereo free-space prior's end of the first `free_end.len()` rays; nothing when
    /// there is neither. Returns the learned background's colours it wrote, if any.
    pub(super) fn write_ray_inputs(&self, gpu: &Gpu, rays: &[GpuRay], free_end: &[f32], aux: &GpuBuffer<crate::layout::RayAux>) -> Option<Vec<[f32; 3]>> {
        if self.background.is_none() && free_end.is_empty() {
            return None;
        }
        let mut rows = vec![crate::layout::RayAux::default(); rays.len()];
        let learned = self.background.as_ref().map(|bg| bg.colors(&bg.ray_dirs(rays)));
        for (row, &background) in rows.iter_mut().zip(learned.iter().flatten()) {
            row.background = background;
        }
        for (row, &end) in rows.iter_mut().zip(free_end) {
            row.free_end = end;
        }
        aux.write(gpu, &rows);
        learned
    }

    /// Post-activation densities of the field at `points` (field space: world, or NDC
    /// for forward-facing scenes), queried on the GPU in chunks of `POINT_CHUNK`;
    /// `progress(done, total)` after each chunk.
    pub fn densities(&self, gpu: &Gpu, points: &[glam::Vec3], progress: &mut dyn FnMut(usize, usize)) -> Result<Vec<f32>, TrainError> {
        let chunk = POINT_CHUNK.min(points.len().max(1));
        let pos = GpuBuffer::<[f32; 4]>::zeros(gpu, "density query points", chunk)?;
        let out = GpuBuffer::<f32>::zeros(gpu, "density query values", chunk)?;
        let mut values = Vec::with_capacity(points.len());
        for part in points.chunks(chunk) {
            pos.write(gpu, &part.iter().map(|p| [p.x, p.y, p.z, 0.0]).collect::<Vec<_>>());
            self.field.density(gpu, &pos, part.len() as u32, &out)?;
            values.extend_from_slice(&out.read(gpu)?[..part.len()]);
            progress(values.len(), points.len());
        }
        Ok(values)
    }

    /// The field's colour at each of `points` seen along the unit direction `dirs[i]`
    /// (field space), through the field's own forward pass over a batch of one-sample
    /// rays, in chunks of `POINT_CHUNK`.
    pub fn colors_at(&mut self, gpu: &Gpu, points: &[glam::Vec3], dirs: &[glam::Vec3]) -> Result<Vec<[f32; 3]>, TrainError> {
        assert_eq!(points.len(), dirs.len(), "colors_at: one direction per point");
        let chunk = POINT_CHUNK.min(points.len().max(1));
        let batch = SampleBatch::new(gpu, chunk as u32, chunk as u32)?;
        let out = FieldOutputs::new(gpu, chunk as u32)?;
        let mut colors = Vec::with_capacity(points.len());
        for (part, dir) in points.chunks(chunk).zip(dirs.chunks(chunk)) {
            let n = part.len();
            let samples: Vec<GpuSample> =
                part.iter().zip(dir).map(|(p, d)| GpuSample { pos: p.to_array(), t: 0.0, dir: d.to_array(), dt: 0.0 }).collect();
            let ranges: Vec<SampleRange> = (0..n as u32).map(|i| SampleRange { start: i, count: 1 }).collect();
            batch.samples.write(gpu, &samples);
            batch.ranges.write(gpu, &ranges);
            batch.count.write(gpu, &[n as u32, n as u32]);
            self.field.forward(gpu, &batch, &out, false)?;
            colors.extend(out.rgb_density.read(gpu)?[..n].iter().map(|v| [v[0], v[1], v[2]]));
        }
        Ok(colors)
    }

    /// Renders view `view` of `scene` with depth and normals.
    pub fn render_view(&mut self, gpu: &Gpu, scene: &Scene, view: usize) -> Result<RenderedView, TrainError> {
        self.render_camera(gpu, scene, &scene.views[view].camera)
    }

    /// Renders what `cam` (any pose and intrinsics, e.g. a camera path's) sees of
    /// `scene`, with depth and normals, through the scene's ray space (NDC for
    /// forward-facing scenes) as training does.
    pub fn render_camera(&mut self, gpu: &Gpu, scene: &Scene, cam: &Camera) -> Result<RenderedView, TrainError> {
        let rays = scene.camera_rays(cam);
        let gpu_rays: Vec<GpuRay> = rays.iter().map(|r| super::rays::to_gpu_ray(scene, r)).collect();
        let (outs, samples) = self.render_rays(gpu, &gpu_rays, true)?;
        let ndc = scene.ndc.is_some();
        Ok(RenderedView {
            width: cam.width,
            height: cam.height,
            rgb: outs.iter().map(|o| o.rgb).collect(),
            opacity: outs.iter().map(|o| o.opacity).collect(),
            depth: outs.iter().map(|o| o.depth).collect(),
            z_depth: outs.iter().zip(&rays).map(|(o, r)| if ndc { o.depth } else { o.depth * r.z_scale }).collect(),
            normal: outs.iter().map(|o| o.normal).collect(),
            samples,
        })
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::seen_by_training_cameras;
    use crate::data::{LoadOptions, Scene};

    /// `room`'s cameras stand inside its box (an inside-out capture); the forward and
    /// object scenes' stand outside theirs.
    #[test]
    fn inside_out_captures_are_those_whose_cameras_stand_in_the_box() {
        for (name, inside) in [("room", true), ("table", false), ("occlusion", false), ("turntable", false)] {
            let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small").join(name);
            let scene = Scene::load(dir, &LoadOptions { views: Some(3), load_images: false, ..Default::default() }).unwrap();
            assert_eq!(scene.cameras_inside_box(), inside, "{name}");
        }
    }

    #[test]
    fn seen_cells_are_those_a_training_camera_images() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/occlusion");
        let scene = Scene::load(dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
        let seen = seen_by_training_cameras(&scene, 1);
        let cell = |c: Vec3| (c - Vec3::splat(0.05), c + Vec3::splat(0.05));
        // The point every camera looks at, and a point just in front of a camera.
        let cam = &scene.train_views().next().unwrap().camera;
        for p in [Vec3::new(0.0, 1.5, 0.95), cam.origin() + 0.5 * cam.forward()] {
            let (lo, hi) = cell(p);
            assert!(seen(lo, hi), "{p} is in view");
        }
        // Behind every camera (they all face +y), and far to the side of the frustums.
        for p in [Vec3::new(0.0, -4.0, 1.2), Vec3::new(30.0, 1.5, 1.0)] {
            let (lo, hi) = cell(p);
            assert!(!seen(lo, hi), "{p} is out of view");
        }
        // A box straddling a camera's plane counts as seen (conservative).
        let o = cam.origin();
        assert!(seen(o - Vec3::splat(0.2), o + Vec3::splat(0.2)));
    }

    /// `min_views` counts the cameras: the point all three training cameras look at is
    /// seen by all three, a point just in front of one camera by that one alone.
    #[test]
    fn seen_views_count_the_training_cameras_that_image_a_cell() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/occlusion");
        let scene = Scene::load(dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
        let cell = |c: Vec3| (c - Vec3::splat(0.02), c + Vec3::splat(0.02));
        let count = |p: Vec3| {
            let (lo, hi) = cell(p);
            (1..=4).filter(|&k| seen_by_training_cameras(&scene, k)(lo, hi)).count()
        };
        assert_eq!(count(Vec3::new(0.0, 1.5, 0.95)), 3, "the common target");
        for view in scene.train_views() {
            let cam = &view.camera;
            let p = cam.origin() + 0.2 * cam.forward();
            assert_eq!(count(p), 1, "just in front of {}", view.name);
        }
    }
}

/// A checkpoint's field arrays against those of a field of its config (`expected`):
/// the same names with the same full shapes (the field's import compares lengths only,
/// so a `[32, 32]` array saved as `[16, 64]` loaded scrambled).
fn check_field_arrays(expected: &[crate::field::NamedArray], got: &[crate::field::NamedArray]) -> Result<(), TrainError> {
    use crate::field::FieldError;
    for e in expected {
        match got.iter().find(|a| a.name == e.name) {
            None => return Err(FieldError::Import(format!("array {:?} is missing from the checkpoint", e.name)).into()),
            Some(a) if a.shape != e.shape => {
                return Err(FieldError::Import(format!(
                    "array {:?} has shape {:?}, but this field's config makes it {:?}",
                    e.name, a.shape, e.shape
                ))
                .into());
            }
            Some(_) => {}
        }
    }
    if let Some(a) = got.iter().find(|a| !expected.iter().any(|e| e.name == a.name)) {
        return Err(FieldError::Import(format!("array {:?} is not a parameter of this field's config", a.name)).into());
    }
    Ok(())
}
