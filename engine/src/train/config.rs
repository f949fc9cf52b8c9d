//! The run configuration: one typed struct per room, gathered in [`RunConfig`] and
//! written as `config.json` in every run directory.
//!
//! Invariants: every field has a default (`#[serde(default)]`), so a config file
//! names only what it changes; an unknown key is an error in every table, variants
//! included (typos do not pass silently); errors name the key at fault;
//! [`RunConfig::validate`] checks every range without touching the GPU or the scene;
//! [`RunConfig::set`] applies `a.b.c=value` overrides through the same serde
//! representation, so the CLI never redefines an option.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::data::{LoadOptions, Scene};
use crate::edges::EdgeConfig;
use crate::field::{GridConfig, MlpConfig};
use crate::loss::RegConfig;
use crate::optim::{LrSchedule, OptimConfig};
use crate::render::{PriorConfig, RenderConfig};
use crate::sampler::SamplerConfig;

use super::TrainError;
use super::regnerf::RegNerfConfig;

/// Which scene and how to load it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Scene directory (set by the CLI's positional argument).
    pub path: PathBuf,
    /// Training views `k` of the sparse-view split; `None`: all training views.
    pub views: Option<usize>,
    /// Background for RGBA images and for rendering; `None`: the scene's own
    /// (white for Blender-format scenes), black for scenes without one.
    pub background: Option<[f32; 3]>,
    /// Image downsampling factor (LLFF, COLMAP and nerfstudio scenes: `images_{N}`, or
    /// the full images downsampled on load; [`LoadOptions::llff_factor`]); `None`: the
    /// format's default (8 for LLFF, else 1), recorded by [`RunConfig::resolve_for`].
    pub llff_factor: Option<u32>,
    /// Scale of the scene box about its centre (world-space scenes; Instant-NGP's
    /// `aabb_scale`): above 1 the field reaches past the box the format gives, e.g. so
    /// that a backdrop behind a DTU object can lie where it is instead of as fog inside
    /// the object's box ([`LoadOptions::box_scale`]). The field's resolutions are per box:
    /// scale `field.finest_resolution` and `sampler.resolution` with it to keep them.
    pub box_scale: f32,
    /// Forward-facing (NDC) scenes: rays end at 1.1 times the capture's farthest bound
    /// instead of at infinity ([`LoadOptions::ndc_far_bound`]; `sparse-llff.toml` below
    /// 14 views). Leave off for a capture whose sky or distant backdrop lies beyond
    /// every point it reconstructed.
    pub ndc_far_bound: bool,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self { path: PathBuf::new(), views: None, background: None, llff_factor: None, box_scale: 1.0, ndc_far_bound: false }
    }
}

impl SceneConfig {
    /// How to load the scene this config names (split, background, LLFF factor).
    pub fn load_options(&self) -> LoadOptions {
        let mut opts = LoadOptions {
            views: self.views,
            llff_factor: self.llff_factor,
            box_scale: self.box_scale,
            ndc_far_bound: self.ndc_far_bound,
            ..Default::default()
        };
        if let Some(bg) = self.background {
            opts.background = bg;
        }
        opts
    }
}

/// Coarse-to-fine annealing of the encoding levels (a remedy for hash grids
/// overfitting few views): `start_levels` active at step 0, all active after `steps`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LevelAnneal {
    pub start_levels: u32,
    pub steps: u64,
}

impl Default for LevelAnneal {
    fn default() -> Self {
        Self { start_levels: 4, steps: 2000 }
    }
}

/// The training loop's own settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Optimisation steps.
    pub iters: u64,
    /// Stop after the step that reaches this much training time (seconds), even
    /// before `iters` (equal-wall-time comparisons); the learning-rate schedule still
    /// follows `iters`. `None`: no limit.
    pub max_seconds: Option<f64>,
    /// Rays per step (a multiple of 4 with patch batches: `rays_per_batch / 4` patches).
    pub rays_per_batch: u32,
    /// How a step's rays are drawn: 2x2 patches of `images_per_step` training images
    /// (EdgeNeRF; what the edge-guided regularizers need), or single pixels uniform over
    /// all training images (Instant-NGP; the regularizers are then inactive).
    pub batch: BatchKind,
    /// Training images a patch batch is drawn from per step (the paper: 1).
    pub images_per_step: u32,
    /// Share of a patch batch's rays drawn as 2x2 patches (the paper: 1); the rest are
    /// single pixels uniform over all training views, which only the photometric loss
    /// reads. Regularizer terms are divided by the whole batch, so their weight in a
    /// step scales with this share. Below 1 with dense views: a patch shows the
    /// photometric loss only one distinct place per 4 rays (the demo: -1.5 dB at 400
    /// steps with every ray in patches).
    pub patch_share: f32,
    /// Pixel spacing of a patch's 2x2 rays (1: adjacent pixels, the paper). At `s > 1`
    /// a patch's rays are `(x, y), (x+s, y), (x, y+s), (x+s, y+s)`, so the edge-guided
    /// terms smooth depth and normals over a wider footprint (lower spatial
    /// frequencies); such a patch counts as non-edge only where no edge pixel lies
    /// anywhere in its `(s+1) x (s+1)` span (every ray then gets the span's weight).
    pub patch_stride: u32,
    /// Sample capacity of a step's batch at the start of the run (rays past it are
    /// cut: they render without their far samples and are dropped from the losses).
    pub max_samples: u32,
    /// Let the capacity follow what the batches want: after a step whose rays wanted
    /// more samples than the capacity, the batch buffers grow to 1.25x that count
    /// (up to the device's storage binding limit), so rays are cut only until the
    /// capacity has caught up. `false`: `max_samples` is a fixed cap.
    pub grow_capacity: bool,
    /// Seed of pixel selection, jitter and the occupancy grid's random cells.
    pub seed: u64,
    /// Write a checkpoint every this many steps (0: only at the end).
    pub checkpoint_every: u64,
    /// Coarse-to-fine level annealing; `None`: all levels from the start.
    pub level_anneal: Option<LevelAnneal>,
    /// For images with alpha: composite each training pixel over a random colour
    /// (the renderer uses the same colour), so transparency must be explained by
    /// opacity rather than by a colour that matches the background (Instant-NGP).
    /// Evaluation always uses the scene's background.
    pub random_background: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            iters: 5000,
            max_seconds: None,
            rays_per_batch: 4096,
            batch: BatchKind::Patches,
            images_per_step: 1,
            patch_share: 1.0,
            patch_stride: 1,
            max_samples: 1 << 18,
            grow_capacity: true,
            seed: 0,
            checkpoint_every: 1000,
            level_anneal: None,
            random_background: true,
        }
    }
}

impl TrainConfig {
    /// 2x2 patches of a patch batch: `patch_share` of `rays_per_batch`, at least one;
    /// the other rays are single pixels.
    pub fn patches_per_batch(&self) -> u32 {
        let patches = (self.patch_share as f64 * self.rays_per_batch as f64 / 4.0).round() as u32;
        patches.clamp(1, self.rays_per_batch / 4)
    }

    /// Range checks (the trainer relies on them); each message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if self.rays_per_batch == 0 || self.max_samples == 0 {
            return Err(format!(
                "train.rays_per_batch = {} and train.max_samples = {} must both be positive",
                self.rays_per_batch, self.max_samples
            ));
        }
        if self.batch == BatchKind::Patches && !self.rays_per_batch.is_multiple_of(4) {
            return Err(format!(
                "train.rays_per_batch = {} must be a multiple of 4 with patch batches (4 rays per 2x2 patch)",
                self.rays_per_batch
            ));
        }
        if !(1..=16).contains(&self.patch_stride) {
            return Err(format!("train.patch_stride = {} must be 1 to 16: the pixel spacing of a patch's 2x2 rays", self.patch_stride));
        }
        if !(self.patch_share > 0.0 && self.patch_share <= 1.0) {
            return Err(format!("train.patch_share = {} must be in (0, 1]: the share of a patch batch's rays drawn as 2x2 patches", self.patch_share));
        }
        if self.images_per_step == 0 {
            return Err("train.images_per_step = 0: a patch batch needs at least 1 image".into());
        }
        if let Some(s) = self.max_seconds
            && !(s.is_finite() && s > 0.0)
        {
            return Err(format!("train.max_seconds = {s} must be a positive number of seconds"));
        }
        if let Some(a) = &self.level_anneal
            && a.start_levels == 0
        {
            return Err("train.level_anneal.start_levels = 0: at least 1 level must be active from the start".into());
        }
        Ok(())
    }
}

/// How a training step draws its rays (see [`TrainConfig::batch`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BatchKind {
    #[default]
    Patches,
    Pixels,
}

/// Which field backend.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// Hash grid + tiny MLPs (Instant-NGP style; `field.*`).
    #[default]
    Grid,
    /// mip-NeRF / RegNeRF MLP (`mlp.*`).
    Mlp,
}

impl Backend {
    /// The name the CLI and config files use.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Grid => "grid",
            Backend::Mlp => "mlp",
        }
    }
}

impl std::str::FromStr for Backend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "grid" => Ok(Backend::Grid),
            "mlp" => Ok(Backend::Mlp),
            other => Err(format!("unknown backend {other:?} (expected grid or mlp)")),
        }
    }
}

/// Everything a run depends on.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    pub backend: Backend,
    pub scene: SceneConfig,
    /// The hash-grid field (backend `grid`).
    pub field: GridConfig,
    /// The MLP field (backend `mlp`).
    pub mlp: MlpConfig,
    pub sampler: SamplerConfig,
    pub render: RenderConfig,
    pub optim: OptimConfig,
    pub train: TrainConfig,
    /// Edge maps of the training images (the regularizers' masks).
    pub edges: EdgeConfig,
    /// The edge-guided depth and normal regularizers.
    pub reg: RegConfig,
    /// RegNeRF's depth smoothness on random poses and sample-space annealing.
    pub regnerf: RegNerfConfig,
    /// Sparse-view priors on each ray's weights: mip-NeRF 360's distortion loss and
    /// FreeNeRF's occlusion regularization ([`crate::render::priors`]).
    pub priors: PriorConfig,
    /// Settings for runs with more training views (`[[with_views]]` tables of a preset):
    /// each one whose `min_views` the run reaches is applied, in order, by
    /// [`RunConfig::apply_with_views`] before the command line's options; empty in a
    /// config that ran (`config.json`, checkpoints), which holds the values applied.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub with_views: Vec<WithViews>,
    /// Settings for inside-out captures (`[with_cameras_inside]` of a preset): applied by
    /// [`RunConfig::apply_with_cameras_inside`] where every training camera stands inside
    /// the scene box (a room seen from within), before the command line's options; absent
    /// in a config that ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub with_cameras_inside: Option<WithCamerasInside>,
}

/// Assignments (as `--set key=value`) for runs with at least `min_views` training
/// views: a preset chosen for 3 views holds what more views want, e.g. a colour that
/// follows the view direction once enough views pin it down.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WithViews {
    pub min_views: usize,
    pub set: Vec<String>,
}

/// Assignments (as `--set key=value`) for inside-out captures, whose training cameras
/// all stand inside the scene box ([`crate::data::Scene::cameras_inside_box`]): there the
/// box holds everything the photos show, so its faces are what lies behind everything
/// (a room's walls and floor).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WithCamerasInside {
    pub set: Vec<String>,
}

impl RunConfig {
    /// The defaults of a backend: the grid's are [`RunConfig::default`]; the MLP's
    /// optimizer is RegNeRF's ([`OptimConfig::regnerf`]: Adam 0.9/0.999/1e-8, lr 2e-3
    /// -> 2e-5 log-linear over the run's `train.iters` (see [`RunConfig::resolve`]),
    /// 512 warm-up steps, clipping).
    pub fn defaults_for(backend: Backend) -> RunConfig {
        let mut c = RunConfig { backend, ..RunConfig::default() };
        if backend == Backend::Mlp {
            c.optim = OptimConfig::regnerf(FOLLOW_ITERS);
        }
        c
    }

    /// Reads a `.toml` or `.json` config file over the defaults of its backend (the
    /// file's `backend`, else `backend`, else the grid). `backend`, when given, wins
    /// over the file's.
    pub fn from_file_for(path: &Path, backend: Option<Backend>) -> Result<RunConfig, TrainError> {
        let bad = |message: String| TrainError::Config { source_name: path.display().to_string(), message };
        let is_toml = match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => true,
            Some("json") => false,
            _ => return Err(bad("config files are TOML (.toml) or JSON (.json) only; name the file after its format".into())),
        };
        let text = std::fs::read_to_string(path).map_err(|e| TrainError::io(path, e))?;
        RunConfig::from_text_for(&text, is_toml, &path.display().to_string(), backend)
    }

    /// [`RunConfig::from_file_for`] on a config's text (`is_toml`, else JSON); errors
    /// name `source_name`.
    pub fn from_text_for(
        text: &str,
        is_toml: bool,
        source_name: &str,
        backend: Option<Backend>,
    ) -> Result<RunConfig, TrainError> {
        let bad = |message: String| TrainError::Config { source_name: source_name.to_string(), message };
        let mut file: serde_json::Value = if is_toml {
            toml::from_str(text).map_err(|e| bad(e.to_string()))?
        } else {
            serde_json::from_str(text).map_err(|e| bad(e.to_string()))?
        };
        if let (Some(b), Some(obj)) = (backend, file.as_object_mut()) {
            obj.insert("backend".into(), serde_json::to_value(b).expect("backends serialize"));
        }
        let backend = match file.get("backend") {
            Some(b) => serde_json::from_value(b.clone()).map_err(|e| bad(format!("backend: {e}")))?,
            None => Backend::Grid,
        };
        let mut merged = serde_json::to_value(RunConfig::defaults_for(backend)).expect("configs serialize");
        merge_json(&mut merged, file);
        from_value_with_path(merged).map_err(bad)
    }

    /// [`RunConfig::from_file_for`] with the file's own backend.
    pub fn from_file(path: &Path) -> Result<RunConfig, TrainError> {
        RunConfig::from_file_for(path, None)
    }

    /// Fills in what depends on other settings: a log-linear schedule with
    /// `max_steps = 0` decays over `train.iters`; an exponential decay written for
    /// `for_iters` steps is stretched to `train.iters` ([`crate::optim::LrDecay::scale_to_iters`]).
    /// Idempotent; the trainer calls it.
    pub fn resolve(&mut self) {
        if let LrSchedule::LogLinear { max_steps, .. } = &mut self.optim.schedule
            && *max_steps == FOLLOW_ITERS
        {
            *max_steps = self.train.iters.max(1);
        }
        if let LrSchedule::Ngp { decay, .. } = &mut self.optim.schedule {
            decay.scale_to_iters(self.train.iters.max(1));
        }
    }

    /// The config a run on `scene` uses: [`RunConfig::resolve`]d, the options that
    /// default by scene type (lambda3, RegNeRF's) set to their values on `scene` so that
    /// `config.json` and checkpoints say what ran rather than `null`, and checked
    /// ([`RunConfig::validate`], [`RunConfig::check_paths`], training views present).
    /// Idempotent; every model, trained or loaded from a checkpoint, is built from it.
    pub fn resolve_for(&mut self, scene: &Scene) -> Result<(), TrainError> {
        self.resolve();
        self.scene.llff_factor = Some(self.scene.llff_factor.unwrap_or(scene.format.default_downscale()));
        // The scene decides lambda3's default (0.001 on DTU).
        self.reg.lambda_normal = Some(self.reg.lambda_normal_for(scene.is_dtu()));
        self.regnerf.resolve_for(scene);
        self.optim.validate()?;
        let config_error = |message: String| TrainError::Config { source_name: "config".into(), message };
        // Every range, reg / regnerf / priors and the batch sizes included.
        self.validate().map_err(config_error)?;
        self.check_paths().map_err(config_error)?;
        if scene.split.train.is_empty() {
            return Err(TrainError::Config { source_name: "scene".into(), message: "no training views".into() });
        }
        Ok(())
    }

    /// Applies an override `dotted.key=value`; `value` is parsed as JSON (numbers,
    /// booleans, arrays, `null`), falling back to a plain string.
    pub fn set(&mut self, assignment: &str) -> Result<(), TrainError> {
        let bad = |message: String| TrainError::Config { source_name: format!("--set {assignment}"), message };
        let (key, value) = assignment.split_once('=').ok_or_else(|| bad("expected key=value".into()))?;
        let value: serde_json::Value =
            serde_json::from_str(value).unwrap_or_else(|_| serde_json::Value::String(value.to_string()));
        let mut root = serde_json::to_value(&*self).map_err(|e| bad(e.to_string()))?;
        let mut node = &mut root;
        // Inside an optional table that was unset, every key is new, and so is an unset
        // optional key (absent from the serialized config, as `decay.for_iters`):
        // serde's `deny_unknown_fields` and the round trip judge them when the result
        // is deserialized.
        let mut fresh = false;
        let mut absent = false;
        let parts: Vec<&str> = key.split('.').collect();
        for (i, part) in parts.iter().enumerate() {
            let obj = node.as_object_mut().ok_or_else(|| bad(format!("{} is not a table", parts[..i].join("."))))?;
            if i + 1 == parts.len() {
                absent = !obj.contains_key(*part);
                obj.insert(part.to_string(), value.clone());
                break;
            }
            if fresh {
                obj.entry(part.to_string()).or_insert_with(|| serde_json::Value::Object(Default::default()));
            }
            let next = obj.get_mut(*part).ok_or_else(|| bad(format!("unknown key {key:?}")))?;
            if next.is_null() {
                *next = serde_json::Value::Object(Default::default());
                fresh = true;
            }
            node = next;
        }
        *self = from_value_with_path(root).map_err(|e| match absent && e.contains("unknown") {
            true => bad(format!("unknown key {key:?} ({e})")),
            false => bad(e),
        })?;
        Ok(())
    }

    /// Applies, in order, the `[[with_views]]` tables whose `min_views` a run of `views`
    /// training views reaches, then empties the list (a config that ran holds values, not
    /// rules). Returns the assignments applied, for the log. An assignment that names no
    /// key or a wrong type is an error naming `source` (the config file) and the table.
    pub fn apply_with_views(&mut self, views: usize, source: &str) -> Result<Vec<String>, TrainError> {
        self.check_with_views().map_err(|message| TrainError::Config { source_name: source.into(), message })?;
        let tables = std::mem::take(&mut self.with_views);
        let mut applied = Vec::new();
        for table in tables.iter().filter(|t| views >= t.min_views) {
            self.apply_assignments(&table.set, &format!("{source}, [[with_views]] min_views = {}", table.min_views))?;
            applied.extend(table.set.iter().cloned());
        }
        Ok(applied)
    }

    /// Applies `[with_cameras_inside]` where `inside` (the scene's training cameras all
    /// stand inside its box), then removes the table. Returns the assignments applied.
    pub fn apply_with_cameras_inside(&mut self, inside: bool, source: &str) -> Result<Vec<String>, TrainError> {
        self.check_with_views().map_err(|message| TrainError::Config { source_name: source.into(), message })?;
        let Some(table) = self.with_cameras_inside.take() else { return Ok(Vec::new()) };
        if !inside {
            return Ok(Vec::new());
        }
        self.apply_assignments(&table.set, &format!("{source}, [with_cameras_inside]"))?;
        Ok(table.set)
    }

    /// A preset table's assignments, each as `--set` would; an error names `table`
    /// (the file and the table).
    fn apply_assignments(&mut self, set: &[String], table: &str) -> Result<(), TrainError> {
        for assignment in set {
            self.set(assignment).map_err(|e| TrainError::Config { source_name: table.into(), message: e.to_string() })?;
        }
        Ok(())
    }

    /// A `[[with_views]]` table that could never apply (`min_views` under 2) or sets
    /// nothing, or a `[with_cameras_inside]` that sets nothing, is an error, whether the
    /// tables are validated or applied first.
    fn check_with_views(&self) -> Result<(), String> {
        match self.with_views.iter().find(|t| t.min_views < 2 || t.set.is_empty()) {
            Some(t) => Err(format!(
                "[[with_views]] min_views = {}: needs min_views of at least 2 and at least one assignment in set",
                t.min_views
            )),
            None if self.with_cameras_inside.as_ref().is_some_and(|t| t.set.is_empty()) => {
                Err("[with_cameras_inside]: needs at least one assignment in set".into())
            }
            None => Ok(()),
        }
    }

    /// Checks every value's range, section by section, without touching the GPU or the
    /// scene (the CLI calls it on the config it built, before any work; the trainer
    /// again). Call [`RunConfig::resolve`] first. The message names the key, or at
    /// least its section.
    pub fn validate(&self) -> Result<(), String> {
        self.train.validate()?;
        self.check_with_views()?;
        if let Some(bg) = self.scene.background
            && !bg.iter().all(|c| (0.0..=1.0).contains(c))
        {
            return Err(format!("scene.background = {bg:?}: each channel must lie in [0, 1]"));
        }
        if let Some(f) = self.scene.llff_factor
            && !(1..=64).contains(&f)
        {
            return Err(format!("scene.llff_factor = {f} must lie in 1..=64"));
        }
        if !(self.scene.box_scale.is_finite() && (0.1..=16.0).contains(&self.scene.box_scale)) {
            return Err(format!("scene.box_scale = {}: must lie in [0.1, 16]", self.scene.box_scale));
        }
        self.edges.validate().map_err(|e| format!("edges: {e}"))?;
        self.reg.validate()?;
        if self.reg.planarity_on() && self.train.batch != BatchKind::Patches {
            return Err(format!(
                "reg.lambda_planarity = {}: the planarity term reads the edge masks of patch batches; set train.batch = \"patches\" or the weight to 0",
                self.reg.lambda_planarity
            ));
        }
        if self.reg.reprojection_on() && self.train.batch != BatchKind::Patches {
            return Err(format!(
                "reg.lambda_reprojection = {}: the reprojection term runs on patch batches with the edge-guided terms; set train.batch = \"patches\" or the weight to 0",
                self.reg.lambda_reprojection
            ));
        }
        self.regnerf.validate()?;
        self.priors.validate()?;
        self.sampler.validate().map_err(|e| format!("sampler: {e}"))?;
        match self.backend {
            Backend::Grid => self.field.validate().map_err(|e| format!("field: {e}"))?,
            Backend::Mlp => self.mlp.validate().map_err(|e| format!("mlp: {e}"))?,
        }
        self.optim.validate().map_err(|e| format!("optim: {e}"))?;
        let t = self.render.transmittance_threshold;
        if !(t.is_finite() && (0.0..1.0).contains(&t)) {
            return Err(format!("render.transmittance_threshold = {t} must be finite and in [0, 1)"));
        }
        if let crate::render::Background::Color { rgb } = self.render.background
            && !rgb.iter().all(|c| (0.0..=1.0).contains(c))
        {
            return Err(format!("render.background.rgb = {rgb:?}: each channel must lie in [0, 1]"));
        }
        self.render.learned_background.validate()?;
        Ok(())
    }

    /// Paths the config records must be UTF-8: `config.json` and checkpoints hold them
    /// as JSON text ([`RunConfig::to_json`] panics otherwise). The message says which.
    pub fn check_paths(&self) -> Result<(), String> {
        let paths = [
            ("scene.path", Some(&self.scene.path)),
            ("edges.dir", self.edges.dir.as_ref()),
            ("priors.mono_depth_dir", self.priors.mono_depth_dir.as_ref()),
        ];
        for (key, path) in paths {
            if let Some(p) = path.filter(|p| p.to_str().is_none()) {
                return Err(format!(
                    "{key} = {} is not valid UTF-8; the run records it as text (config.json, the checkpoint): \
                     rename it or reach it through a UTF-8 path (e.g. a symbolic link)",
                    p.display()
                ));
            }
        }
        Ok(())
    }

    /// The config as pretty JSON (what `config.json` holds). Call
    /// [`RunConfig::check_paths`] first on configs built from user input.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("configs serialize")
    }

    /// A short stable hash of the config (benchmark rows, checkpoint metadata).
    pub fn hash(&self) -> String {
        // FNV-1a over the canonical JSON.
        let mut h: u64 = 0xcbf29ce484222325;
        for b in serde_json::to_string(self).expect("configs serialize").bytes() {
            h = (h ^ b as u64).wrapping_mul(0x100000001b3);
        }
        format!("{h:016x}")
    }
}

/// `max_steps` of a log-linear schedule that follows `train.iters` ([`RunConfig::resolve`]).
pub const FOLLOW_ITERS: u64 = 0;

/// A config from JSON, the error naming the key at fault (`train.iters: invalid type:
/// string "many", expected u64`) rather than only the type.
///
/// Unknown keys are errors in every table: most tables deny them through serde, and a
/// key serde would still drop (beside the `kind` of a variant without fields, such as
/// `render.background = {kind = "black", rgb = ...}`) is found by comparing the input
/// with the config serialized back, which holds every key a config has.
fn from_value_with_path(value: serde_json::Value) -> Result<RunConfig, String> {
    let config: RunConfig = serde_path_to_error::deserialize(&value).map_err(|e| {
        let path = e.path().to_string();
        if path == "." { e.into_inner().to_string() } else { format!("{path}: {}", e.into_inner()) }
    })?;
    let back = serde_json::to_value(&config).expect("configs serialize");
    match first_unknown_key(&value, &back, "") {
        Some(message) => Err(message),
        None => Ok(config),
    }
}

/// The first key of `input` that `known` (the same config serialized back) lacks.
fn first_unknown_key(input: &serde_json::Value, known: &serde_json::Value, path: &str) -> Option<String> {
    let (serde_json::Value::Object(input), serde_json::Value::Object(known)) = (input, known) else { return None };
    for (k, v) in input {
        let at = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
        match known.get(k) {
            None => {
                let keys: Vec<&str> = known.keys().map(String::as_str).collect();
                let table = if path.is_empty() { "the config" } else { path };
                return Some(format!("{at}: unknown key {k:?} ({table} has {})", keys.join(", ")));
            }
            Some(kv) => {
                if let Some(m) = first_unknown_key(v, kv, &at) {
                    return Some(m);
                }
            }
        }
    }
    None
}

/// Overwrites `base` with every key of `over`, recursing into tables (a config file
/// over defaults: keys the file does not name keep the default).
fn merge_json(base: &mut serde_json::Value, over: serde_json::Value) {
    match (base, over) {
        (serde_json::Value::Object(b), serde_json::Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    // A tagged enum (`kind = ...`) switching variant is replaced whole.
                    Some(slot) if slot.is_object() && v.is_object() && !(v.get("kind").is_some() && slot.get("kind") != v.get("kind")) => merge_json(slot, v),
                    _ => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_reach_nested_keys_and_reject_typos() {
        let mut c = RunConfig::default();
        c.set("train.iters=123").unwrap();
        c.set("field.n_levels=8").unwrap();
        c.set("scene.views=3").unwrap();
        assert_eq!((c.train.iters, c.field.n_levels, c.scene.views), (123, 8, Some(3)));
        c.set("train.level_anneal.steps=50").unwrap();
        assert_eq!(c.train.level_anneal, Some(LevelAnneal { steps: 50, ..Default::default() }));
        let mut d = RunConfig::default();
        assert!(d.set("train.level_anneal.stpes=50").is_err(), "typos inside a fresh table are caught too");
        assert!(c.set("train.itres=1").unwrap_err().to_string().contains("unknown key \"train.itres\""));
        // An unset optional key is not in the serialized config, and can still be set.
        c.set("optim.schedule.decay={\"kind\": \"exponential\", \"start\": 500, \"interval\": 100, \"base\": 0.7}").unwrap();
        c.set("optim.schedule.decay.for_iters=2000").unwrap();
        match c.optim.schedule {
            LrSchedule::Ngp { decay: crate::optim::LrDecay::Exponential { start: 500, for_iters, .. }, .. } => {
                assert_eq!(for_iters, Some(2000))
            }
            ref other => panic!("{other:?}"),
        }
        assert!(c.set("optim.schedule.decay.for_itres=2000").unwrap_err().to_string().contains("unknown key"));
        assert!(c.set("train.iters=-1").is_err());
        assert!(c.set("noequals").is_err());
    }

    #[test]
    fn mlp_backend_defaults_to_regnerf_optimizer_following_iters() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "backend = \"mlp\"\n[train]\niters = 300\n[mlp]\nwidth = 64\n").unwrap();
        let mut c = RunConfig::from_file(&path).unwrap();
        assert_eq!((c.backend, c.mlp.width, c.mlp.depth), (Backend::Mlp, 64, 8));
        c.resolve();
        assert_eq!(c.optim, OptimConfig::regnerf(300));
        // A file that sets the schedule keeps it; the CLI's backend wins over the file's.
        std::fs::write(&path, "[optim.schedule]\nkind = \"constant\"\nlr = 0.01\n").unwrap();
        let c = RunConfig::from_file_for(&path, Some(Backend::Mlp)).unwrap();
        assert_eq!((c.backend, &c.optim.schedule), (Backend::Mlp, &LrSchedule::Constant { lr: 0.01 }));
        assert_eq!(c.optim.adam, OptimConfig::regnerf(1).adam);
        std::fs::write(&path, "[train]\nbogus = 1\n").unwrap();
        assert!(RunConfig::from_file(&path).is_err(), "unknown keys are still errors after the merge");
    }

    #[test]
    fn config_errors_name_the_key_and_the_format() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.toml");
        std::fs::write(&path, "[train]\niters = \"many\"\n").unwrap();
        let e = RunConfig::from_file(&path).unwrap_err().to_string();
        assert!(e.contains("train.iters") && e.contains("invalid type"), "{e}");
        let yaml = dir.path().join("c.yaml");
        std::fs::write(&yaml, "train:\n  iters: 3\n").unwrap();
        let e = RunConfig::from_file(&yaml).unwrap_err().to_string();
        assert!(e.contains("TOML (.toml) or JSON (.json) only"), "{e}");
        let e = RunConfig::default().set("reg.lambda_depth=\"x\"").unwrap_err().to_string();
        assert!(e.contains("reg.lambda_depth"), "{e}");
    }

    /// Every table of a config, each section and each nested table (tagged variants
    /// included), refuses a key it does not know: a typo never passes silently (the
    /// sampler's, the field's, the optimizer's and the renderer's tables accepted any).
    #[test]
    fn an_unknown_key_in_any_table_is_an_error_naming_it() {
        fn tables(v: &serde_json::Value, path: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
            if let serde_json::Value::Object(map) = v {
                out.push(path.clone());
                for (k, child) in map {
                    path.push(k.clone());
                    tables(child, path, out);
                    path.pop();
                }
            }
        }
        let mut configs = vec![RunConfig::defaults_for(Backend::Grid), RunConfig::defaults_for(Backend::Mlp)];
        // Optional tables and other variants, so that their keys are probed too.
        let mut c = RunConfig::default();
        c.train.level_anneal = Some(LevelAnneal::default());
        c.set("render.background={\"kind\": \"color\", \"rgb\": [1, 1, 1]}").unwrap();
        c.set("optim.adam.weight_decay={\"kind\": \"l2\", \"factor\": 0.1}").unwrap();
        configs.push(c);
        let (mut probed, mut accepted) = (0, Vec::new());
        for config in configs {
            let base = serde_json::to_value(&config).unwrap();
            let mut paths = Vec::new();
            tables(&base, &mut Vec::new(), &mut paths);
            for path in paths {
                let mut v = base.clone();
                let mut node = &mut v;
                for k in &path {
                    node = node.get_mut(k).unwrap();
                }
                node.as_object_mut().unwrap().insert("no_such_key".into(), 1.into());
                match from_value_with_path(v) {
                    Err(e) if e.contains("no_such_key") => {}
                    Err(e) => accepted.push(format!("{}: {e}", path.join("."))),
                    Ok(_) => accepted.push(path.join(".")),
                }
                probed += 1;
            }
        }
        assert!(accepted.is_empty(), "tables that took an unknown key without naming it: {accepted:?}");
        assert!(probed >= 30, "only {probed} tables probed");
    }

    /// Out-of-range values are errors naming their key, whether or not the run would
    /// read them (`--tau-e 300` passed on runs without edge masks; a patch size of
    /// 100000 overflowed the ray count; `images_per_step = 0`, a background of 2 and
    /// `level_anneal.start_levels = 0` trained).
    #[test]
    fn validate_names_the_key_out_of_range() {
        assert_eq!(RunConfig::default().validate(), Ok(()));
        let mut mlp = RunConfig::defaults_for(Backend::Mlp);
        mlp.resolve();
        assert_eq!(mlp.validate(), Ok(()));
        for (set, key) in [
            ("train.rays_per_batch=0", "train.rays_per_batch"),
            ("train.images_per_step=0", "train.images_per_step"),
            ("train.patch_share=0", "train.patch_share"),
            ("train.patch_share=1.5", "train.patch_share"),
            ("train.patch_stride=0", "train.patch_stride"),
            ("train.max_seconds=-1", "train.max_seconds"),
            ("train.level_anneal.start_levels=0", "train.level_anneal.start_levels"),
            ("scene.background=[2,0,0]", "scene.background"),
            ("scene.llff_factor=0", "scene.llff_factor"),
            ("scene.box_scale=0", "scene.box_scale"),
            ("scene.box_scale=100", "scene.box_scale"),
            ("sampler.seen_views=0", "seen_views"),
            ("sampler.seen_views=2", "seen_cells_only"),
            ("render.learned_background.shell_radius=0.5", "shell_radius"),
            ("render.transmittance_threshold=2", "render.transmittance_threshold"),
            ("reg.lambda_depth=-1", "reg.lambda_depth"),
            ("reg.tau_normal=-0.5", "reg.tau_normal"),
            ("reg.lambda_planarity=-1", "reg.lambda_planarity"),
            ("reg.planarity_triplets=100000000", "reg.planarity_triplets"),
            ("reg.lambda_reprojection=-1", "reg.lambda_reprojection"),
            ("reg.reprojection_delta=0", "reg.reprojection_delta"),
            ("regnerf.patch_size=100000", "regnerf.patch_size"),
            ("regnerf.n_poses=0", "regnerf.n_poses"),
            ("edges.tau_e=300", "tau_e"),
            ("sampler.resolution=0", "sampler"),
            ("field.n_levels=0", "n_levels"),
            ("priors.occlusion=-1", "priors.occlusion"),
            ("priors.orientation=-0.1", "priors.orientation"),
        ] {
            let mut c = RunConfig::default();
            c.set(set).unwrap();
            let e = c.validate().expect_err(set);
            assert!(e.contains(key), "{set}: {e}");
        }
    }

    #[test]
    fn json_round_trip_and_partial_files() {
        let c = RunConfig::default();
        let back: RunConfig = serde_json::from_str(&c.to_json()).unwrap();
        assert_eq!(back, c);
        let partial: RunConfig = toml::from_str("[train]\niters = 7\n").unwrap();
        assert_eq!(partial.train.iters, 7);
        assert_eq!(partial.field, GridConfig::default());
        assert!(toml::from_str::<RunConfig>("[train]\nbogus = 1\n").is_err());
    }

    /// `[[with_views]]` tables apply, in order, only where the run has `min_views`
    /// training views, then leave the config (a config that ran holds values, not
    /// rules); a wrong assignment names its table; a table that could never apply or
    /// sets nothing is refused.
    #[test]
    fn with_views_apply_from_their_view_count() {
        let text = "[train]\niters = 800\n\n[[with_views]]\nmin_views = 6\nset = [\"field.sh_degree=1\", \"train.iters=2400\"]\n\n[[with_views]]\nmin_views = 9\nset = [\"field.sh_degree=2\"]\n";
        let preset = RunConfig::from_text_for(text, true, "preset.toml", None).unwrap();
        assert_eq!(preset.with_views.len(), 2);
        for (views, applied, sh_degree, iters) in [(3, 0, 3, 800), (6, 2, 1, 2400), (8, 2, 1, 2400), (9, 3, 2, 2400), (49, 3, 2, 2400)] {
            let mut c = preset.clone();
            assert_eq!(c.apply_with_views(views, "preset.toml").unwrap().len(), applied, "{views} views");
            assert_eq!((c.field.sh_degree, c.train.iters), (sh_degree, iters), "{views} views");
            assert!(c.with_views.is_empty(), "{views} views: the tables stay in the config");
            assert!(!c.to_json().contains("with_views"), "{views} views: config.json names with_views");
        }

        let bad = RunConfig::from_text_for("[[with_views]]\nmin_views = 4\nset = [\"field.no_such=1\"]\n", true, "p", None).unwrap();
        let e = bad.clone().apply_with_views(5, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml") && e.contains("min_views = 4") && e.contains("field.no_such"), "{e}");
        assert!(bad.clone().apply_with_views(3, "my.toml").unwrap().is_empty(), "a table under its view count is not read");

        for text in ["[[with_views]]\nmin_views = 1\nset = [\"train.iters=5\"]\n", "[[with_views]]\nmin_views = 5\nset = []\n"] {
            let c = RunConfig::from_text_for(text, true, "p", None).unwrap();
            let e = c.validate().unwrap_err();
            assert!(e.contains("[[with_views]]"), "{text}: {e}");
            let e = c.clone().apply_with_views(9, "my.toml").unwrap_err().to_string();
            assert!(e.contains("my.toml") && e.contains("[[with_views]]"), "applied before validation, {text}: {e}");
        }
    }

    /// `[with_cameras_inside]` applies only to an inside-out capture, is gone from the
    /// config after (either way), names its file in errors and must set something.
    #[test]
    fn with_cameras_inside_applies_only_where_the_cameras_are_inside() {
        let text = "[train]\niters = 800\n\n[with_cameras_inside]\nset = [\"priors.sparsity=0.01\", \"train.iters=900\"]\n";
        let preset = RunConfig::from_text_for(text, true, "preset.toml", None).unwrap();
        for (inside, sparsity, iters) in [(false, 0.0, 800), (true, 0.01, 900)] {
            let mut c = preset.clone();
            let applied = c.apply_with_cameras_inside(inside, "preset.toml").unwrap();
            assert_eq!(applied.len(), if inside { 2 } else { 0 });
            assert_eq!((c.priors.sparsity, c.train.iters), (sparsity, iters), "inside: {inside}");
            assert!(c.with_cameras_inside.is_none() && !c.to_json().contains("with_cameras_inside"), "inside: {inside}");
        }
        let bad = RunConfig::from_text_for("[with_cameras_inside]\nset = [\"field.no_such=1\"]\n", true, "p", None).unwrap();
        let e = bad.clone().apply_with_cameras_inside(true, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml") && e.contains("[with_cameras_inside]") && e.contains("field.no_such"), "{e}");
        let empty = RunConfig::from_text_for("[with_cameras_inside]\nset = []\n", true, "p", None).unwrap();
        assert!(empty.validate().unwrap_err().contains("[with_cameras_inside]"));
        assert!(empty.clone().apply_with_cameras_inside(false, "my.toml").is_err(), "checked whether it applies or not");
    }
}
