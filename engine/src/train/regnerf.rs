//! RegNeRF's geometry regularization as trainer options (the baseline "RegNeRF without
//! appearance regularization"): the depth smoothness term on patches from random poses
//! ([`crate::loss::depth_tv`], poses from [`super::random_poses`]) and sample-space
//! annealing. Owns their configuration (`[regnerf]`) and schedules.
//!
//! Settings follow RegNeRF's configs (google-research/regnerf, `configs/{llff,dtu}3.gin`
//! and `internal/configs.py`):
//! * depth TV: `depth_tvnorm_decay = True`, weight `400 -> 0.1` linearly over the first
//!   512 steps (`compute_tvnorm_weight`), then constant; 8x8 patches; a pool of 10000
//!   random poses; `depth_tvnorm_mask_weight` 1 on DTU (0 elsewhere: see
//!   [`crate::loss::depth_tv`]). RegNeRF's photometric loss sums the three channels where
//!   ours averages them, so the same balance needs its weights divided by 3: our
//!   defaults are `400 / 3` and `0.1 / 3`.
//! * sample-space annealing (`anneal_nearfar`): over `n` steps the ray's range widens
//!   linearly from `[mid + p (near - mid), mid + p (far - mid)]`, `mid = near + m (far -
//!   near)`, to `[near, far]`; LLFF `n = 512, p = 1e-4, m = 1` (NDC: from infinity
//!   inwards), DTU `n = 256, p = 0.5, m = 0.5`. RegNeRF anneals the scene's global
//!   near/far; we anneal each ray's own range (near/far clipped to the scene box, what
//!   our sampler marches), which is the same for NDC scenes and keeps the annealed range
//!   on the object in box-bounded scenes. Non-NDC scenes take the DTU values.
//!   RegNeRF anneals the random-pose rays as well (it maps every ray in the batch); so do we.
//!
//! Invariants: everything here is a pure function of the config, the scene type and the
//! step (deterministic, exact resumes); with the defaults (`depth_tv = false`,
//! `anneal = false`) a run is unchanged.

use serde::{Deserialize, Serialize};

use crate::data::Scene;
use crate::layout::GpuRay;

use super::random_poses::PoseKind;

/// Largest `regnerf.patch_size` accepted.
pub const MAX_PATCH_SIZE: u32 = 64;
/// Most depth-TV rays per step (`patches_per_step * patch_size^2`).
pub const MAX_TV_RAYS: u32 = 1 << 20;
/// Largest random-pose pool.
pub const MAX_POSES: usize = 1_000_000;

/// RegNeRF's options (`[regnerf]` in a run config).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegNerfConfig {
    /// Depth smoothness (total variation) on patches from random poses.
    pub depth_tv: bool,
    /// The TV weight after the decay (ours: RegNeRF's 0.1 / 3, see the module doc).
    pub tv_weight: f32,
    /// The TV weight at step 1, decaying linearly to `tv_weight` over `tv_decay_steps`
    /// (RegNeRF's 400 / 3); `None`: no decay, `tv_weight` throughout.
    pub tv_weight_start: Option<f32>,
    pub tv_decay_steps: u64,
    /// Patch side (RegNeRF: 8).
    pub patch_size: u32,
    /// Patches per step; `None`: as many rays as the photometric batch
    /// (`train.rays_per_batch / patch_size^2`, at least 1).
    pub patches_per_step: Option<u32>,
    /// Random poses in the pool (RegNeRF: 10000).
    pub n_poses: usize,
    /// How poses are placed; `None`: by scene type ([`PoseKind::for_scene`]).
    pub poses: Option<PoseKind>,
    /// RegNeRF's `depth_tvnorm_mask_weight` (terms weighted by the constant opacity
    /// times this; 0: unweighted); `None`: 1 on DTU, 0 elsewhere.
    pub tv_acc_weight: Option<f32>,
    /// Sample-space annealing of the training rays' ranges.
    pub anneal: bool,
    /// Annealing steps, start fraction and midpoint (module doc); `None`: RegNeRF's
    /// values for the scene type.
    pub anneal_steps: Option<u64>,
    pub anneal_start: Option<f32>,
    pub anneal_mid: Option<f32>,
}

impl Default for RegNerfConfig {
    fn default() -> Self {
        Self {
            depth_tv: false,
            tv_weight: 0.1 / 3.0,
            tv_weight_start: Some(400.0 / 3.0),
            tv_decay_steps: 512,
            patch_size: 8,
            patches_per_step: None,
            n_poses: 10_000,
            poses: None,
            tv_acc_weight: None,
            anneal: false,
            anneal_steps: None,
            anneal_start: None,
            anneal_mid: None,
        }
    }
}

/// The annealing schedule in effect for a scene (see [`RegNerfConfig::anneal_for`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Anneal {
    pub steps: u64,
    pub start: f32,
    pub mid: f32,
}

impl Anneal {
    /// The annealed `[near, far]` of a range `[near, far]` at `step` (0-based; RegNeRF's
    /// `anneal_nearfar` with `it = step + 1`, its loop starting at 1).
    pub fn range(&self, near: f32, far: f32, step: u64) -> (f32, f32) {
        let mid = near + self.mid * (far - near);
        let (near0, far0) = (mid + self.start * (near - mid), mid + self.start * (far - mid));
        let w = if self.steps == 0 { 1.0 } else { ((step + 1) as f64 / self.steps as f64).min(1.0) as f32 };
        (near0 + w * (near - near0), far0 + w * (far - far0))
    }

    /// Applies [`Anneal::range`] to each ray's own `[t_min, t_max]`.
    pub fn apply(&self, rays: &mut [GpuRay], step: u64) {
        for r in rays {
            let (a, b) = self.range(r.t_min, r.t_max, step);
            (r.t_min, r.t_max) = (a, b.max(a));
        }
    }
}

impl RegNerfConfig {
    /// The TV weight at `step` (0-based; RegNeRF's `compute_tvnorm_weight` at `step + 1`),
    /// `None` when the term is off.
    pub fn tv_weight_at(&self, step: u64) -> Option<f32> {
        if !self.depth_tv {
            return None;
        }
        let w = match self.tv_weight_start {
            Some(start) => {
                let f = ((step + 1) as f64 / self.tv_decay_steps.max(1) as f64).clamp(0.0, 1.0) as f32;
                start * (1.0 - f) + f * self.tv_weight
            }
            None => self.tv_weight,
        };
        (w > 0.0).then_some(w)
    }

    /// Patches a step renders (0 when the term is off).
    pub fn patches(&self, rays_per_batch: u32) -> u32 {
        if !self.depth_tv {
            return 0;
        }
        self.patches_per_step.unwrap_or((rays_per_batch / (self.patch_size * self.patch_size)).max(1))
    }

    /// `depth_tvnorm_mask_weight` in effect.
    pub fn acc_weight_for(&self, scene: &Scene) -> f32 {
        self.tv_acc_weight.unwrap_or(if scene.is_dtu() { 1.0 } else { 0.0 })
    }

    /// The pose generator in effect.
    pub fn pose_kind_for(&self, scene: &Scene) -> PoseKind {
        self.poses.unwrap_or_else(|| PoseKind::for_scene(scene))
    }

    /// The annealing schedule in effect, `None` when off.
    pub fn anneal_for(&self, scene: &Scene) -> Option<Anneal> {
        self.anneal.then(|| self.anneal_schedule_for(scene))
    }

    /// The annealing schedule on `scene` whether or not annealing is on: the given
    /// values, RegNeRF's for the scene type otherwise.
    fn anneal_schedule_for(&self, scene: &Scene) -> Anneal {
        let (steps, start, mid) = if scene.ndc.is_some() { (512, 1e-4, 1.0) } else { (256, 0.5, 0.5) };
        Anneal {
            steps: self.anneal_steps.unwrap_or(steps),
            start: self.anneal_start.unwrap_or(start),
            mid: self.anneal_mid.unwrap_or(mid),
        }
    }

    /// Fills in the options that default by scene type (`poses`, `tv_acc_weight`,
    /// `anneal_*`) with their values on `scene`, so that `config.json` and checkpoints
    /// record what a run used rather than `null`. Idempotent; the trainer calls it.
    pub fn resolve_for(&mut self, scene: &Scene) {
        self.poses = Some(self.pose_kind_for(scene));
        self.tv_acc_weight = Some(self.acc_weight_for(scene));
        let a = self.anneal_schedule_for(scene);
        (self.anneal_steps, self.anneal_start, self.anneal_mid) = (Some(a.steps), Some(a.start), Some(a.mid));
    }

    pub fn validate(&self) -> Result<(), String> {
        let ok = |v: f32| v.is_finite() && v >= 0.0;
        let unit = |v: Option<f32>| v.is_none_or(|v| (0.0..=1.0).contains(&v));
        if !(ok(self.tv_weight) && self.tv_weight_start.is_none_or(ok) && self.tv_acc_weight.is_none_or(ok)) {
            return Err("regnerf: weights must be finite and >= 0".into());
        }
        // Bounded above too: the rays of a step (patches x patch_size^2) and the pose
        // pool are allocated (patch_size 100000 overflowed the ray count).
        if !(2..=MAX_PATCH_SIZE).contains(&self.patch_size) {
            return Err(format!("regnerf.patch_size = {} must lie in 2..={MAX_PATCH_SIZE} (RegNeRF: 8)", self.patch_size));
        }
        if let Some(p) = self.patches_per_step
            && !(1..=MAX_TV_RAYS / (self.patch_size * self.patch_size)).contains(&p)
        {
            return Err(format!(
                "regnerf.patches_per_step = {p} must lie in 1..={} (at most {MAX_TV_RAYS} rays of {}x{} patches)",
                MAX_TV_RAYS / (self.patch_size * self.patch_size),
                self.patch_size,
                self.patch_size
            ));
        }
        if !(1..=MAX_POSES).contains(&self.n_poses) {
            return Err(format!("regnerf.n_poses = {} must lie in 1..={MAX_POSES} (RegNeRF: 10000)", self.n_poses));
        }
        if !(unit(self.anneal_start) && unit(self.anneal_mid)) {
            return Err("regnerf: anneal_start and anneal_mid must lie in [0, 1]".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anneal_starts_at_the_midpoint_and_reaches_the_full_range() {
        let a = Anneal { steps: 256, start: 0.5, mid: 0.5 };
        // DTU: near 0.5, far 3.5 -> mid 2, start [1.25, 2.75] (RegNeRF at it = 0).
        let (n0, f0) = Anneal { steps: 256, ..a }.range(0.5, 3.5, u64::MAX - 1);
        assert_eq!((n0, f0), (0.5, 3.5), "full range at the end");
        let at = |s| a.range(0.5, 3.5, s);
        let (n, f) = at(0);
        let w = 1.0 / 256.0;
        assert!((n - (1.25 - w * 0.75)).abs() < 1e-6 && (f - (2.75 + w * 0.75)).abs() < 1e-6, "{n} {f}");
        assert_eq!(at(255), (0.5, 3.5), "full range from step 255 (it = 256)");
        let mut prev = at(0);
        for s in 1..300 {
            let cur = at(s);
            assert!(cur.0 <= prev.0 && cur.1 >= prev.1, "widens monotonically");
            assert!(((cur.0 + cur.1) / 2.0 - 2.0).abs() < 1e-6, "centred on the midpoint");
            prev = cur;
        }
        // LLFF: NDC [0, 1] with mid 1 starts at [1 - 1e-4, 1] (next to infinity).
        let l = Anneal { steps: 512, start: 1e-4, mid: 1.0 };
        let (n, f) = l.range(0.0, 1.0, 0);
        assert!(n > 0.99 && f == 1.0, "{n}");
        assert_eq!(l.range(0.0, 1.0, 511), (0.0, 1.0));
        // Per ray, and empty rays stay empty.
        let mut rays = [GpuRay { t_min: 2.0, t_max: 4.0, ..Default::default() }, GpuRay { t_min: 3.0, t_max: 3.0, ..Default::default() }];
        a.apply(&mut rays, 0);
        assert!(rays[0].t_min > 2.4 && rays[0].t_max < 3.6 && rays[1].t_min == rays[1].t_max);
    }

    #[test]
    fn tv_weight_decays_like_regnerf_and_defaults_are_off() {
        let off = RegNerfConfig::default();
        assert!(off.tv_weight_at(0).is_none() && off.patches(1024) == 0 && !off.anneal);
        let c = RegNerfConfig { depth_tv: true, ..Default::default() };
        let w = |s| c.tv_weight_at(s).unwrap() * 3.0;
        assert!((w(0) - (400.0 * (1.0 - 1.0 / 512.0) + 0.1 / 512.0)).abs() < 1e-3);
        assert!((w(255) - (400.0 * 0.5 + 0.05)).abs() < 1e-3);
        assert!((w(511) - 0.1).abs() < 1e-6 && (w(10_000) - 0.1).abs() < 1e-6);
        assert_eq!(c.patches(4096), 64, "as many rays as the photometric batch");
        assert_eq!(RegNerfConfig { patches_per_step: Some(3), ..c.clone() }.patches(4096), 3);
        let flat = RegNerfConfig { tv_weight_start: None, tv_weight: 0.5, ..c.clone() };
        assert_eq!(flat.tv_weight_at(0), Some(0.5));
        assert!(RegNerfConfig { patch_size: 1, ..c.clone() }.validate().is_err());
        assert!(RegNerfConfig { anneal_mid: Some(1.5), ..c.clone() }.validate().is_err());
        assert!(RegNerfConfig { tv_weight: f32::NAN, ..c }.validate().is_err());
    }
}
