//! Learning-rate schedules (host side, serde-configurable, deterministic: computed in
//! `f64` from the step alone).
//!
//! # Step convention
//! `lr(step)` takes the step being taken counted from 1, i.e. Adam's `t` after the
//! increment (`Adam::step_count() + 1` before the call), which is how mip-NeRF and
//! RegNeRF call their schedule (`for step in range(1, max_steps + 1)`). `lr(0)` is
//! defined too (the very start of the warm-up).
//!
//! # Formulas
//! * [`LrSchedule::Constant`]: the constant `lr`.
//! * [`LrSchedule::Ngp`] (Instant-NGP / nerfacc style): `lr * warmup(step) * decay(step)`
//!   with the linear warm-up of torch's `LinearLR`,
//!   `warmup(s) = f + (1 - f) * min(s, W) / W` (`f` = `warmup_start_factor`, `W` =
//!   `warmup_steps`; 1 when `W` = 0), and [`LrDecay`]:
//!   - `None`: 1;
//!   - `Exponential { start, interval, base }`: `base^k` with `k = 0` before `start`,
//!     else `k = floor((step - start) / interval) + 1` (the rate is multiplied by
//!     `base` at steps `start, start + interval, ...`; Instant-NGP's NeRF config uses
//!     20000, 10000, 0.33);
//!   - `Steps { milestones, gamma }`: `gamma^(number of milestones <= step)` (torch's
//!     `MultiStepLR`; nerfacc uses `[T/2, 3T/4, 9T/10]`, 0.33).
//! * [`LrSchedule::LogLinear`] (mip-NeRF's `learning_rate_decay`, used by RegNeRF and
//!   EdgeNeRF):
//!   ```text
//!   delay = mult + (1 - mult) * sin(pi/2 * clamp(step / delay_steps, 0, 1))  (1 if delay_steps = 0)
//!   t     = clamp(step / max_steps, 0, 1)
//!   lr    = delay * exp(ln(lr_init) * (1 - t) + ln(lr_final) * t)
//!   ```
//!   RegNeRF: `lr_init` 2e-3, `lr_final` 2e-5, `lr_delay_steps` 512, `lr_delay_mult` 0.01.

use serde::{Deserialize, Serialize};

use super::OptimError;

fn one() -> f32 {
    1.0
}

/// Step decay of [`LrSchedule::Ngp`] (see the module doc).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LrDecay {
    #[default]
    None,
    Exponential {
        start: u64,
        interval: u64,
        base: f32,
        /// The run length `start` and `interval` are written for: a run of other
        /// `train.iters` has both scaled by `iters / for_iters`
        /// ([`LrDecay::scale_to_iters`]), so a preset's decay keeps its shape over a
        /// longer run instead of ending it at a learning rate near zero. `None`: steps
        /// as written.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        for_iters: Option<u64>,
    },
    Steps { milestones: Vec<u64>, gamma: f32 },
}

/// A learning-rate schedule (see the module doc for formulas and the step convention).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LrSchedule {
    Constant {
        lr: f32,
    },
    Ngp {
        lr: f32,
        #[serde(default)]
        warmup_steps: u64,
        #[serde(default = "one")]
        warmup_start_factor: f32,
        #[serde(default)]
        decay: LrDecay,
    },
    LogLinear {
        lr_init: f32,
        lr_final: f32,
        max_steps: u64,
        #[serde(default)]
        lr_delay_steps: u64,
        #[serde(default = "one")]
        lr_delay_mult: f32,
    },
}

impl LrDecay {
    /// An [`LrDecay::Exponential`] written for `for_iters` steps, rescaled to a run of
    /// `iters` (start and interval times `iters / for_iters`, rounded, the interval at
    /// least 1; `for_iters` becomes `iters`, so the call is idempotent). Other decays
    /// are left alone.
    pub fn scale_to_iters(&mut self, iters: u64) {
        if let LrDecay::Exponential { start, interval, for_iters: Some(written), .. } = self
            && *written != iters
            && *written > 0
        {
            let f = iters as f64 / *written as f64;
            *start = (*start as f64 * f).round() as u64;
            *interval = ((*interval as f64 * f).round() as u64).max(1);
            *written = iters;
        }
    }
}

impl Default for LrSchedule {
    /// [`LrSchedule::instant_ngp`].
    fn default() -> Self {
        Self::instant_ngp()
    }
}

impl LrSchedule {
    /// lr 1e-2, 100-step warm-up from 0.01x, x0.33 every 10k steps from step 20k.
    pub fn instant_ngp() -> Self {
        LrSchedule::Ngp {
            lr: 1e-2,
            warmup_steps: 100,
            warmup_start_factor: 0.01,
            decay: LrDecay::Exponential { start: 20_000, interval: 10_000, base: 0.33, for_iters: None },
        }
    }

    /// RegNeRF / EdgeNeRF: 2e-3 -> 2e-5 log-linear over `max_steps` (LLFF 69768, DTU
    /// 43945 for 3 views), 512-step warm-up from 0.01x.
    pub fn regnerf(max_steps: u64) -> Self {
        LrSchedule::LogLinear { lr_init: 2e-3, lr_final: 2e-5, max_steps, lr_delay_steps: 512, lr_delay_mult: 0.01 }
    }

    /// The learning rate of step `step` (1-based; see the module doc).
    pub fn lr(&self, step: u64) -> f32 {
        let s = step as f64;
        let lr = match self {
            LrSchedule::Constant { lr } => *lr as f64,
            LrSchedule::Ngp { lr, warmup_steps, warmup_start_factor, decay } => {
                let warm = if *warmup_steps == 0 {
                    1.0
                } else {
                    let f = *warmup_start_factor as f64;
                    f + (1.0 - f) * (step.min(*warmup_steps) as f64 / *warmup_steps as f64)
                };
                let k = match decay {
                    LrDecay::None => 1.0,
                    LrDecay::Exponential { start, interval, base, .. } => {
                        if step < *start {
                            1.0
                        } else {
                            let k = (step - start) / (*interval).max(1) + 1;
                            (*base as f64).powi(k.min(i32::MAX as u64) as i32)
                        }
                    }
                    LrDecay::Steps { milestones, gamma } => {
                        let k = milestones.iter().filter(|&&m| m <= step).count();
                        (*gamma as f64).powi(k as i32)
                    }
                };
                *lr as f64 * warm * k
            }
            LrSchedule::LogLinear { lr_init, lr_final, max_steps, lr_delay_steps, lr_delay_mult } => {
                let delay = if *lr_delay_steps > 0 {
                    let m = *lr_delay_mult as f64;
                    m + (1.0 - m) * (0.5 * std::f64::consts::PI * (s / *lr_delay_steps as f64).clamp(0.0, 1.0)).sin()
                } else {
                    1.0
                };
                let t = (s / (*max_steps).max(1) as f64).clamp(0.0, 1.0);
                delay * ((*lr_init as f64).ln() * (1.0 - t) + (*lr_final as f64).ln() * t).exp()
            }
        };
        lr as f32
    }

    /// Checks the parameters; the message names the offending one.
    pub fn validate(&self) -> Result<(), OptimError> {
        let positive = |name: &str, x: f32| {
            if x.is_finite() && x > 0.0 {
                Ok(())
            } else {
                Err(OptimError::Config(format!("schedule: {name} = {x} must be finite and > 0")))
            }
        };
        let nonneg = |name: &str, x: f32| {
            if x.is_finite() && x >= 0.0 {
                Ok(())
            } else {
                Err(OptimError::Config(format!("schedule: {name} = {x} must be finite and >= 0")))
            }
        };
        match self {
            LrSchedule::Constant { lr } => nonneg("lr", *lr),
            LrSchedule::Ngp { lr, warmup_start_factor, decay, .. } => {
                nonneg("lr", *lr)?;
                nonneg("warmup_start_factor", *warmup_start_factor)?;
                match decay {
                    LrDecay::None => Ok(()),
                    LrDecay::Exponential { interval, base, .. } => {
                        if *interval == 0 {
                            return Err(OptimError::Config("schedule: decay interval must be > 0".into()));
                        }
                        nonneg("decay base", *base)
                    }
                    LrDecay::Steps { gamma, .. } => nonneg("decay gamma", *gamma),
                }
            }
            LrSchedule::LogLinear { lr_init, lr_final, max_steps, lr_delay_mult, .. } => {
                positive("lr_init", *lr_init)?;
                positive("lr_final", *lr_final)?;
                nonneg("lr_delay_mult", *lr_delay_mult)?;
                if *max_steps == 0 {
                    return Err(OptimError::Config("schedule: max_steps must be > 0".into()));
                }
                Ok(())
            }
        }
    }
}
