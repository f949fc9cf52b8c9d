//! The sampler room: which points along each ray the field is evaluated at.
//!
//! Owns the occupancy grid ([`OccupancyGrid`]), the BVH over its occupied bricks
//! ([`bricks`]), the per-ray occupied intervals ([`intervals`]), sample placement and
//! compaction ([`Sampler`]), the prefix sum that compacts ([`scan`]), and the drop of
//! the rays the batch capacity cut from the losses ([`truncated`]), and the list of the
//! samples that carry gradient for the field's backward ([`live`]), and the
//! visibility pass that keeps, of the marched samples, those a ray can still see
//! ([`visibility`]). Kernels live
//! under `kernels/sampler/`; each has exactly one owner here:
//!
//! | kernel | owner |
//! |---|---|
//! | `sampler/occupancy.wgsl` | [`occupancy`] (query points, scatter-max, EMA, mean, bitfield) |
//! | `sampler/intervals.wgsl` | [`intervals`] (BVH traversal per ray) |
//! | `sampler/scan.wgsl` | [`scan`] (exclusive prefix sum) |
//! | `sampler/march.wgsl` | [`march`] (count / write samples) |
//! | `sampler/truncated.wgsl` | [`truncated`] (zero the loss weights of cut rays) |
//! | `sampler/live.wgsl` | [`live`] (list the samples that carry gradient) |
//! | `sampler/visibility.wgsl` | [`visibility`] (keep the samples a ray can see) |
//! | `sampler/common.wgsl` | include only: grid geometry, slab test, PCG hash |
//!
//! # How the train loop drives it
//! ```text
//! once:       grid = OccupancyGrid::new(gpu, &cfg, aabb)?;  sampler = Sampler::new(&cfg, aabb)?;
//! each step:  if grid.should_update(step) {
//!                 let q = grid.query_points(gpu, step, seed)?;      // jittered points
//!                 field density at q.positions[..q.count] -> dens   // the caller's field
//!                 grid.update(gpu, &q.cells, &dens, q.count, q.decay)?; // EMA, bits, BVH
//!             }
//!             sampler.sample(gpu, March::Occupancy(&grid), &rays, &batch, Some(seed))?;
//! ```
//! The sampler never sees the field: the grid asks for densities at points and is
//! handed them back.
//!
//! # Choices
//! * **One cascade.** The grid covers the scene AABB only. Blender and DTU scenes are
//!   bounded; LLFF is sampled in NDC where the AABB is the cube `[-1, 1]^3` that already
//!   reaches infinity, so Instant-NGP's outer cascades have nothing to cover.
//! * **Update rule** (Instant-NGP / nerfacc): queried cells get
//!   `cell <- max(decay * cell, density)` (decay 0.95; several queries of one cell in
//!   one update use their maximum), a cell is occupied iff `cell > min(threshold / step, mean
//!   of all cells)` (threshold 0.01 on the opacity `sigma * step` of one marching step); during the first `warmup_steps` (256) every cell
//!   is queried, afterwards a quarter of the cells at random plus a quarter drawn from
//!   the occupied ones (all of them when fewer). Updates every `update_interval` (16)
//!   steps. Before the first update every cell counts as occupied. The densities are
//!   saved in checkpoints and restored on resume, so a rendered checkpoint skips
//!   exactly what training skipped (the field was fitted with that grid; a grid rebuilt
//!   from one query per cell differed enough to cost 1.7 dB on the dense `table` scene).
//! * **What it can skip.** Space whose density the field has driven below the
//!   threshold: empty space that training rays cross. It cannot skip space behind the
//!   first surface, where no ray's gradient ever lowers the untrained field's density
//!   (about 1, above the threshold at coarse steps); those samples carry weight ~0, and
//!   only a transmittance cut-off drops them: the visibility pass ([`visibility`], off
//!   by default; `sampler.visibility`), which pays for a density-only pass over every
//!   marched sample. Forward-facing scenes, whose rays end on the box's far wall, are
//!   mostly such space: there the grid saves 8-11 % of the test views' samples, on
//!   the object scenes 70-80 % (README, "Dense views: the engine's baseline"). The
//!   EMA time constant (`decay` per `update_interval` steps) should be short against
//!   the schedule: a cell whose density the field has lowered from `d_old` keeps
//!   counting as occupied for `log(d_threshold / d_old) / log(decay)` more updates
//!   (the short-schedule configs under `tools/configs/` use 0.9, as does the sparse
//!   presets' `[with_cameras_inside]`, where 0.95 left `room` marching fog the field
//!   had emptied for its first 350 of 800 steps; faster forgetting loses thin
//!   structures that one jittered query per cell misses, and at 0.8 a held-out room
//!   lost cells before its furniture formed).
//! * **Bricks of 8^3 cells** (`brick_size`): the BVH is built over the AABBs of bricks
//!   holding at least one occupied cell. 8^3 keeps the BVH small (at most 16^3 = 4096
//!   leaves at 128^3, built on the CPU in milliseconds whenever the bitfield changes)
//!   and the per-ray interval lists short, while the per-cell bit test during marching
//!   restores the full 128^3 resolution inside bricks. At most 32 bricks per axis.
//! * **Intervals**: every hit brick gives `[t_enter, t_exit]` clipped to
//!   `[t_min, t_max]`; they are sorted, merged where they overlap or touch (gap below
//!   `1e-5 * max(1, |t|)`), and while more than `max_intervals` (16) remain the
//!   smallest gap is closed. Closing gaps never loses samples: marching still tests
//!   every sample's cell bit.
//! * **Placement: Instant-NGP's constant step.** `dt = step / |dir|` with `step` a
//!   length in the field's space (default: AABB diagonal / 1024), on a per-ray grid of
//!   segments anchored at `t_min` (optionally shifted by a random fraction of `dt` per
//!   ray for training). A segment is kept if its midpoint is in an occupied interval
//!   and cell; empty cells are jumped over. Uniform mode keeps every segment of
//!   `[t_min, t_max]` on the same grid, so both modes place identical samples where
//!   space is occupied ("with vs without" comparisons differ only by skipped space).
//!   At most `max_samples_per_ray` per ray (the nearest ones).
//! * **Compaction**: count pass, exclusive scan over the rays (a real scan kernel, so
//!   offsets are deterministic), write pass. Samples of all rays are packed; empty rays
//!   get `count = 0` and cost nothing downstream. Past the batch capacity a ray keeps
//!   its first samples and later rays get none; `count[1]` tells how many were wanted.

pub mod bricks;
pub mod occupancy;
pub mod intervals;
pub mod march;
pub mod scan;
pub mod truncated;
pub mod live;
pub mod visibility;

pub use occupancy::{OccupancyQuery, OccupancyUpdate, OccupancyGrid};
pub use march::{March, Sampler};
pub use scan::ExclusiveScan;
pub use truncated::DropTruncated;
pub use live::LiveCompaction;
pub use visibility::{Visibility, VisibilityPass};

use serde::{Deserialize, Serialize};

use crate::gpu::GpuError;

/// Most bricks along one axis: a ray crosses at most `3 * 32 - 2` bricks, which the
/// interval kernel collects in a fixed per-thread array.
pub const MAX_BRICKS_PER_AXIS: u32 = 32;
/// Upper bound of [`SamplerConfig::max_intervals`] (the interval kernel's array).
pub const MAX_INTERVALS_LIMIT: u32 = 96;

/// Errors of the sampler room.
#[derive(Debug, thiserror::Error)]
pub enum SamplerError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("invalid sampler configuration: {0}")]
    Config(String),
    #[error("the brick BVH is {depth} levels deep; the GPU traversal stack holds {limit}")]
    BvhTooDeep { depth: u32, limit: u32 },
}

/// How samples are placed (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SamplerMode {
    /// Occupancy grid + brick BVH: skip empty space.
    #[default]
    Occupancy,
    /// Constant step across `[t_min, t_max]`, no grid.
    Uniform,
}

/// Configuration of the sampler room.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SamplerConfig {
    pub mode: SamplerMode,
    /// Occupancy cells per axis.
    pub resolution: u32,
    /// EMA decay of a queried cell.
    pub decay: f32,
    /// EMA decay of the updates during the warm-up, when every cell is queried
    /// (`None`, the default: `decay`). A short memory there drops the untrained field's
    /// density from space the field has emptied at once instead of carrying it for
    /// `log(threshold / density) / log(decay)` more updates (see the module doc): it
    /// trades quality for speed. Measured at 0 (each warm-up update replaces the cells)
    /// on `sparse-small.toml`'s val views, 3 views, seed 0 (docs/performance.md):
    /// field samples per ray over the run 30-50 % fewer on `creases`, `occlusion`,
    /// `room` and the held-out `den`, PSNR -0.12, -0.75, -0.32 and -0.43 dB: cells
    /// emptied before the structures that would fill them formed.
    pub warmup_decay: Option<f32>,
    /// Jittered points per cell in the warm-up's updates (every cell queried; the cell
    /// keeps the largest density found). 1 (the default): one point a cell, nerfacc's
    /// rule. A structure thinner than a cell is found by one random point only now and
    /// then, so a short `warmup_decay` can empty its cell before it forms; several
    /// points find it at each update. Costs `n^3 * (k - 1)` more density queries per
    /// warm-up update. At most [`MAX_WARMUP_POINTS_PER_CELL`], and at most
    /// [`MAX_WARMUP_QUERY_POINTS`] points an update.
    pub warmup_points_per_cell: u32,
    /// Occupancy threshold on the opacity of one marching step, `sigma * step`
    /// (nerfacc's `occ_thre`): a cell is occupied iff its density exceeds
    /// `min(threshold / step, mean density)` ([`SamplerConfig::density_threshold`]).
    /// Measuring it per step makes it independent of the scene's units.
    pub threshold: f32,
    /// Steps between grid updates ([`OccupancyGrid::should_update`]).
    pub update_interval: u32,
    /// Steps during which updates query every cell.
    pub warmup_steps: u32,
    /// Cells per brick edge (the BVH's primitives).
    pub brick_size: u32,
    /// Marching step as a length in the field's space; 0: AABB diagonal / 1024.
    pub step_size: f32,
    /// When `step_size` is 0 the step is the AABB diagonal divided by this
    /// (Instant-NGP: 1024); lower it for low-resolution images.
    pub steps_per_diagonal: f32,
    /// Samples kept per ray (the nearest).
    pub max_samples_per_ray: u32,
    /// Rendering (evaluation, `render`, the viewer; not training) marches each ray in
    /// segments, the first of this many samples, each next twice as long (or the rest
    /// of every ray at once after a segment that turned few rays opaque), the field
    /// shading one segment before the next is marched from where it stopped; a ray
    /// stops once its transmittance falls under the renderer's threshold, so the
    /// samples behind an opaque surface are never shaded. The image is the one pass's
    /// up to that threshold. 0 (the default): one pass over every marched sample.
    /// Ignored where `visibility.render` renders through the visibility pass. It pays
    /// where rays turn opaque (objects: `sparse-small.toml` sets 16), and costs a
    /// round trip a segment where they do not (fog, a painted box, forward-facing
    /// scenes; docs/performance.md, "Rendering in segments").
    pub render_segment: u32,
    /// Rendering (evaluation, `render`, the viewer; not training) marches a finer grid
    /// of this many cells per axis instead of the training grid: built from the trained
    /// field once before the first render (the density at [`RENDER_GRID_POINTS`]
    /// jittered points of each cell, the cell occupied when the largest exceeds
    /// [`RENDER_GRID_THRESHOLD_SCALE`] times the training grid's threshold), only inside
    /// the training grid's occupied cells, so it never marches space training skipped.
    /// Fewer samples land in the empty parts of a coarse cell, and none where the
    /// field's density fell since the training grid's decaying maximum last saw it; what
    /// the finer grid empties had only faint density where it was probed, so images
    /// change only where such faint density lay.
    /// 0 (the default): render with the training grid. Otherwise a multiple of
    /// `resolution`, at most [`MAX_RENDER_RESOLUTION`]. Measured (docs/performance.md,
    /// "A finer grid for rendering").
    pub render_resolution: u32,
    /// A coarse start: while `train.level_anneal` has only the coarse levels of a grid
    /// field switched on, training marches at `cell / anneal_samples_per_cell`, `cell`
    /// being the finest active level's cell edge (along the box's shortest axis), when
    /// that is longer than the configured step (the encoded features vary linearly
    /// within such a cell; the MLP and the density's activation still bend the field
    /// there); the step returns to the configured one as the finer levels switch on.
    /// Rendering always marches at the configured step. 0: off, as in every preset:
    /// at 1 the first 256 steps of `room` march 32 samples per ray instead of 78 at the
    /// same val PSNR, but `occlusion` loses 0.7 dB (0.5 at 2) and DTU 0.3 dB
    /// (docs/guide/configuration.md).
    pub anneal_samples_per_cell: f32,
    /// Occupied intervals kept per ray.
    pub max_intervals: u32,
    /// Only cells some training camera sees can be occupied (world-space scenes;
    /// [`OccupancyGrid::restrict_to_seen`]): Instant-NGP's treatment of never-seen space.
    /// Off by default: on scenes with content everywhere (walls) a test ray through
    /// never-seen space then renders the background instead of the untrained field's
    /// grey fog, which measured -0.3 dB on `occlusion` (3 views), +0.05 dB on `room`,
    /// +0.02 dB on `creases` (README, "Sparse-view priors").
    pub seen_cells_only: bool,
    /// With `seen_cells_only`: how many training cameras must image a cell for it to
    /// count as seen (1: any camera, Instant-NGP's rule). Above 1, space that only one
    /// camera sees, where nothing but that one photograph constrains the density (fog
    /// in front of a camera that explains its image and veils the object from every
    /// other view), is never marched. Uses the cameras only, never masks. Measured
    /// (docs/results/real-captures.md): `room`, 3 views, 2: half the field samples per
    /// ray, +0.16 dB, SSIM -0.03; DTU, 9 views (no space there only one camera sees),
    /// 2: -0.11 dB, 4: -0.92 dB.
    pub seen_views: u32,
    /// The visibility pass ([`visibility`]): the field's density at every marched
    /// sample, then only the samples a ray can still see reach the full forward.
    pub visibility: VisibilityConfig,
}

/// When the visibility pass runs and what it keeps ([`visibility`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VisibilityConfig {
    /// Run the pass in training steps from `start_step` on.
    pub train: bool,
    /// Run the pass when rendering (evaluation, `render`, `export`, the viewer).
    pub render: bool,
    /// A ray's walk stops at the first sample whose transmittance is below this
    /// (nerfacc's `early_stop_eps`). The renderer's `transmittance_threshold` (1e-4)
    /// makes the pass exact when `min_alpha` is 0.
    pub min_transmittance: f32,
    /// Samples whose opacity `1 - exp(-sigma dt)` is below this are dropped (nerfacc's
    /// `alpha_thre`); 0 keeps them.
    pub min_alpha: f32,
    /// The most opacity a ray may lose to `min_alpha`: walking front to back, a faint
    /// sample is dropped only while the dropped samples' opacity together,
    /// `1 - exp(-sum sigma dt)`, stays at most this; past it the ray keeps its faint
    /// samples. It bounds what the floor changes in a ray's colour. 1 (the default):
    /// no bound, nerfacc's `alpha_thre`; on fog, where every sample is faint, a bound
    /// keeps most of them.
    pub max_dropped_opacity: f32,
    /// First training step with the pass.
    pub start_step: u32,
    /// First training step at which `min_alpha` applies (before it, 0). An untrained
    /// field can be faint everywhere (density about 1 against a short step): dropping
    /// every sample from the start would leave it no gradient to grow from.
    pub min_alpha_start_step: u32,
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        Self { train: false, render: false, min_transmittance: 1e-4, min_alpha: 0.0, max_dropped_opacity: 1.0, start_step: 0, min_alpha_start_step: 256 }
    }
}

impl VisibilityConfig {
    /// The rule the pass applies when rendering.
    pub fn rule(&self) -> Visibility {
        Visibility { min_transmittance: self.min_transmittance, min_alpha: self.min_alpha, max_dropped_opacity: self.max_dropped_opacity }
    }

    /// The rule the pass applies at training step `step`, `None` when the step runs
    /// without it.
    pub fn training_rule_at(&self, step: u64) -> Option<Visibility> {
        let min_alpha = if step >= self.min_alpha_start_step as u64 { self.min_alpha } else { 0.0 };
        (self.train && step >= self.start_step as u64).then_some(Visibility { min_alpha, ..self.rule() })
    }
}

impl Default for SamplerConfig {
    fn default() -> Self {
        Self {
            mode: SamplerMode::Occupancy,
            resolution: 128,
            decay: 0.95,
            warmup_decay: None,
            warmup_points_per_cell: 1,
            threshold: 0.01,
            update_interval: 16,
            warmup_steps: 256,
            brick_size: 8,
            step_size: 0.0,
            steps_per_diagonal: DEFAULT_STEPS_PER_DIAGONAL,
            max_samples_per_ray: 1024,
            render_segment: 0,
            render_resolution: 0,
            anneal_samples_per_cell: 0.0,
            max_intervals: 16,
            seen_cells_only: false,
            seen_views: 1,
            visibility: VisibilityConfig::default(),
        }
    }
}

/// Largest [`SamplerConfig::render_resolution`]: a 128^3 grid's query (one point a cell
/// at a time) is 32 MiB of positions, within every adapter's storage binding limit.
pub const MAX_RENDER_RESOLUTION: u32 = 128;

/// Largest [`SamplerConfig::warmup_points_per_cell`].
pub const MAX_WARMUP_POINTS_PER_CELL: u32 = 16;

/// Most points of one warm-up update with [`SamplerConfig::warmup_points_per_cell`] above
/// 1: 2^23 positions are 128 MiB, wgpu's default storage binding limit (4 points a cell
/// at 128^3, 16 at 64^3).
pub const MAX_WARMUP_QUERY_POINTS: u64 = 1 << 23;

/// Jittered points per cell at which [`SamplerConfig::render_resolution`]'s grid
/// probes the field (each its own draw; the cell keeps the largest density).
pub const RENDER_GRID_POINTS: u32 = 2;

/// The threshold of [`SamplerConfig::render_resolution`]'s grid, as a fraction of the
/// training grid's (`threshold`): a finer cell is occupied once the density probed in it
/// exceeds a quarter of what keeps a training cell. Chosen on the val views of 3-view
/// `sparse-small.toml` runs (seed 0, 2026-12-07; docs/performance.md, "A finer grid for
/// rendering"): at 1 `table` lost 0.06 dB and `occlusion` 0.03 against the training
/// grid, at 0.25 they gained 0.15 / 0.07 and no scene lost more than 0.01.
pub const RENDER_GRID_THRESHOLD_SCALE: f32 = 0.25;

/// Default of [`SamplerConfig::steps_per_diagonal`] (Instant-NGP).
pub const DEFAULT_STEPS_PER_DIAGONAL: f32 = 1024.0;

impl SamplerConfig {
    /// Checks the ranges the kernels rely on.
    pub fn validate(&self) -> Result<(), SamplerError> {
        let fail = |m: String| Err(SamplerError::Config(m));
        if self.resolution == 0 || self.resolution > 1024 {
            return fail(format!("resolution {} not in 1..=1024", self.resolution));
        }
        if self.brick_size == 0 {
            return fail("brick_size must be at least 1".into());
        }
        // The training grid and the finer grid of renders are both bricked.
        let bricks_fit = |name: &str, r: u32| {
            if r.div_ceil(self.brick_size) > MAX_BRICKS_PER_AXIS {
                return fail(format!("{name} {r} / brick_size {} gives more than {MAX_BRICKS_PER_AXIS} bricks per axis", self.brick_size));
            }
            Ok(())
        };
        bricks_fit("resolution", self.resolution)?;
        if !(0.0..=1.0).contains(&self.decay) {
            return fail(format!("decay {} not in [0, 1]", self.decay));
        }
        if let Some(d) = self.warmup_decay.filter(|d| !(0.0..=1.0).contains(d)) {
            return fail(format!("warmup_decay {d} not in [0, 1]"));
        }
        let k = self.warmup_points_per_cell;
        if !(1..=MAX_WARMUP_POINTS_PER_CELL).contains(&k) {
            return fail(format!("warmup_points_per_cell {k} not in [1, {MAX_WARMUP_POINTS_PER_CELL}]"));
        }
        let points = k as u64 * (self.resolution as u64).pow(3);
        if k > 1 && points > MAX_WARMUP_QUERY_POINTS {
            return fail(format!(
                "warmup_points_per_cell {k} at resolution {} queries {points} points an update, over {MAX_WARMUP_QUERY_POINTS}: lower one of them",
                self.resolution
            ));
        }
        if !(self.threshold >= 0.0 && self.threshold.is_finite()) {
            return fail(format!("threshold {} must be finite and >= 0", self.threshold));
        }
        if self.update_interval == 0 {
            return fail("update_interval must be at least 1".into());
        }
        if !(self.step_size >= 0.0 && self.step_size.is_finite()) {
            return fail(format!("step_size {} must be finite and >= 0", self.step_size));
        }
        if !(self.steps_per_diagonal >= 1.0 && self.steps_per_diagonal.is_finite()) {
            return fail(format!("steps_per_diagonal {} must be finite and >= 1", self.steps_per_diagonal));
        }
        if !(self.anneal_samples_per_cell >= 0.0 && self.anneal_samples_per_cell.is_finite()) {
            return fail(format!("anneal_samples_per_cell {} must be finite and >= 0 (0: off)", self.anneal_samples_per_cell));
        }
        let r = self.render_resolution;
        if r != 0 && (r < self.resolution || !r.is_multiple_of(self.resolution) || r > MAX_RENDER_RESOLUTION) {
            return fail(format!(
                "render_resolution {r} must be 0 (render with the training grid) or a multiple of resolution ({}) \
                 of at most {MAX_RENDER_RESOLUTION}",
                self.resolution
            ));
        }
        bricks_fit("render_resolution", r)?;
        if self.max_samples_per_ray == 0 {
            return fail("max_samples_per_ray must be at least 1".into());
        }
        if self.seen_views == 0 {
            return fail("seen_views must be at least 1".into());
        }
        if self.seen_views > 1 && !self.seen_cells_only {
            return fail(format!("seen_views = {} applies to seen cells only: set sampler.seen_cells_only = true", self.seen_views));
        }
        if let Err(e) = self.visibility.rule().validate() {
            return fail(e);
        }
        if self.max_intervals == 0 || self.max_intervals > MAX_INTERVALS_LIMIT {
            return fail(format!("max_intervals {} not in 1..={MAX_INTERVALS_LIMIT}", self.max_intervals));
        }
        Ok(())
    }

    /// The marching step for a scene box: `step_size`, or the diagonal / `steps_per_diagonal`.
    pub fn step_for(&self, aabb: [glam::Vec3; 2]) -> f32 {
        if self.step_size > 0.0 { self.step_size } else { (aabb[1] - aabb[0]).length() / self.steps_per_diagonal }
    }

    /// The EMA decay of the grid update at training step `step`.
    pub fn decay_at(&self, step: u32) -> f32 {
        if step < self.warmup_steps { self.warmup_decay.unwrap_or(self.decay) } else { self.decay }
    }

    /// The density threshold for a scene box: `threshold / step` (see [`SamplerConfig::threshold`]).
    pub fn density_threshold(&self, aabb: [glam::Vec3; 2]) -> f32 {
        self.threshold / self.step_for(aabb)
    }
}

/// Workgroup grid for `groups` workgroups of a kernel that folds its grid into x and y
/// (`wid.x + wid.y * nwg.x`), for kernels with their own workgroup size.
pub(crate) fn fold_groups(gpu: &crate::gpu::Gpu, groups: u32) -> [u32; 3] {
    let max = gpu.limits().max_compute_workgroups_per_dimension;
    if groups <= max {
        [groups, 1, 1]
    } else {
        let y = groups.div_ceil(max);
        [groups.div_ceil(y), y, 1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampler_config_defaults_validate_and_roundtrip() {
        let c = SamplerConfig::default();
        c.validate().unwrap();
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(serde_json::from_str::<SamplerConfig>(&json).unwrap(), c);
        // Missing fields take their defaults.
        let partial: SamplerConfig = serde_json::from_str(r#"{"mode":"uniform","resolution":64}"#).unwrap();
        assert_eq!(partial.mode, SamplerMode::Uniform);
        assert_eq!(partial.brick_size, 8);
        let bad = SamplerConfig { resolution: 512, ..Default::default() };
        assert!(matches!(bad.validate(), Err(SamplerError::Config(_))));
        // The render grid: 0, or a multiple of the training grid's resolution up to 128.
        for (r, ok) in [(0, true), (64, true), (128, true), (32, true), (48, false), (16, false), (256, false)] {
            let cfg = SamplerConfig { resolution: 32, render_resolution: r, ..Default::default() };
            assert_eq!(cfg.validate().is_ok(), ok, "render_resolution {r}");
        }
        let aabb = [glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0)];
        assert!((c.step_for(aabb) - 12f32.sqrt() / 1024.0).abs() < 1e-7);
    }
}
