//! Adam on the GPU over named parameter groups. Owner of `kernels/optim/adam.wgsl`.
//!
//! # Update (per element, one dispatch per group per step)
//! With `t` the step counter after increment (the first step has `t = 1`), `lr` the
//! step's learning rate times the group's `lr_scale`, and the group's `beta1, beta2,
//! eps` (the group's overrides, else the [`AdamConfig`]'s):
//! ```text
//! g  = grad[i]                 if the group is sparse and g == 0: nothing changes
//! g  = clamp(g, -c, c) * s     c, s from the GradNorm stats (c = 0: no clamp; s = 1
//!                              without stats or once applied in place)
//! g += wd * w                  WeightDecay::L2 (before the moments; Instant-NGP / torch Adam)
//! m  = beta1 * m + (1 - beta1) * g
//! v  = beta2 * v + (1 - beta2) * g * g
//! w' = w - lr * (m / (1 - beta1^t)) / (sqrt(v / (1 - beta2^t)) + eps)
//! w' = w' - lr * wd * w        WeightDecay::Decoupled (AdamW, flax: on the old w)
//! ```
//! `eps` is added outside the square root (torch, optax, flax, tiny-cuda-nn). Bias
//! corrections are computed on the host in `f64` and passed as `f32`.
//!
//! # Invariants
//! * `m` and `v` are owned here, one pair per group, zero at creation and on
//!   [`Adam::reset`]; the step counter `t` counts [`Adam::record_step`] calls.
//! * With stats from a [`GradNorm`] and `skip_nonfinite`, a step whose gradients hold a
//!   NaN/Inf leaves parameters, `m` and `v` untouched on the GPU; the host counter `t`
//!   still advances (the trainer, which reads the flag, may [`Adam::set_step_count`]).
//!   Stats that count a non-finite word in their guard buffers (a batch's losses,
//!   [`GradNorm::record_guarded`]) skip the step the same way, whatever `skip_nonfinite`.
//! * Sparse groups (`skip_zero_grad`, for hash tables as in Instant-NGP) leave entries
//!   whose gradient is exactly zero untouched, `m` and `v` included; bias correction
//!   still uses the global `t`.

use serde::{Deserialize, Serialize};

use super::{GradNorm, OptimError};
use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, KernelSpec};

const SPEC: KernelSpec = KernelSpec {
    file: "optim/adam.wgsl",
    entry: "adam_step",
    bindings: &[
        Binding::Params,
        Binding::ReadWrite, // weights
        Binding::ReadOnly,  // grads
        Binding::ReadWrite, // m
        Binding::ReadWrite, // v
        Binding::ReadOnly,  // grad stats
    ],
};

const FLAG_SKIP_ZERO_GRAD: u32 = 1;
const FLAG_L2: u32 = 2;
const FLAG_DECOUPLED: u32 = 4;
const FLAG_SKIP_NONFINITE: u32 = 8;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AdamParams {
    n: u32,
    flags: u32,
    lr: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    bias1: f32,
    bias2: f32,
    weight_decay: f32,
    _pad: [u32; 3],
}

/// Weight decay of a group.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum WeightDecay {
    #[default]
    None,
    /// `g += factor * w` before the moments (L2 regularization; Instant-NGP applies
    /// 1e-6 to its MLP weights and none to the hash tables).
    L2 { factor: f32 },
    /// `w -= lr * factor * w` after the Adam update (AdamW).
    Decoupled { factor: f32 },
}

impl WeightDecay {
    fn flags_and_factor(self) -> (u32, f32) {
        match self {
            WeightDecay::None => (0, 0.0),
            WeightDecay::L2 { factor } => (FLAG_L2, factor),
            WeightDecay::Decoupled { factor } => (FLAG_DECOUPLED, factor),
        }
    }
}

/// Optimizer-wide Adam hyper-parameters; groups may override betas, eps and weight decay.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    pub weight_decay: WeightDecay,
    /// Skip the whole step on the GPU when the [`GradNorm`] stats passed to the step
    /// count a non-finite gradient (no effect without stats).
    pub skip_nonfinite: bool,
}

impl Default for AdamConfig {
    /// Instant-NGP's grid setting: betas (0.9, 0.99), eps 1e-15, no weight decay.
    fn default() -> Self {
        Self { beta1: 0.9, beta2: 0.99, eps: 1e-15, weight_decay: WeightDecay::None, skip_nonfinite: true }
    }
}

impl AdamConfig {
    /// mip-NeRF / RegNeRF (flax.optim.Adam defaults): betas (0.9, 0.999), eps 1e-8.
    pub fn mipnerf() -> Self {
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-8, ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), OptimError> {
        validate_hyper("adam", [self.beta1, self.beta2], self.eps, self.weight_decay)
    }
}

fn validate_hyper(what: &str, betas: [f32; 2], eps: f32, wd: WeightDecay) -> Result<(), OptimError> {
    for (name, b) in [("beta1", betas[0]), ("beta2", betas[1])] {
        if !(0.0..1.0).contains(&b) {
            return Err(OptimError::Config(format!("{what}: {name} = {b} must lie in [0, 1)")));
        }
    }
    if !(eps.is_finite() && eps >= 0.0) {
        return Err(OptimError::Config(format!("{what}: eps = {eps} must be finite and >= 0")));
    }
    if let WeightDecay::L2 { factor } | WeightDecay::Decoupled { factor } = wd
        && !(factor.is_finite() && factor >= 0.0)
    {
        return Err(OptimError::Config(format!("{what}: weight decay factor {factor} must be finite and >= 0")));
    }
    Ok(())
}

/// One parameter group as a field hands it to the optimizer: borrowed buffers plus
/// per-group settings. `params` and `grads` must have equal lengths, equal to the
/// length the optimizer was built for under this `name`.
///
/// Build with [`ParamGroup::new`] and the chainable setters, or as a literal.
pub struct ParamGroup<'a> {
    /// Unique name; the key of the group's state in checkpoints (e.g. `"grid.tables"`).
    pub name: &'a str,
    pub params: &'a GpuBuffer<f32>,
    pub grads: &'a GpuBuffer<f32>,
    /// Multiplier of the step's learning rate for this group.
    pub lr_scale: f32,
    /// Overrides [`AdamConfig::beta1`] / `beta2`.
    pub betas: Option<[f32; 2]>,
    /// Overrides [`AdamConfig::eps`].
    pub eps: Option<f32>,
    /// Overrides [`AdamConfig::weight_decay`].
    pub weight_decay: Option<WeightDecay>,
    /// Sparse update: elements whose gradient is exactly 0 are left untouched
    /// (parameters, `m`, `v`), as Instant-NGP does for hash-table entries.
    pub skip_zero_grad: bool,
}

impl<'a> ParamGroup<'a> {
    /// A group with `lr_scale` 1, no overrides, dense updates.
    pub fn new(name: &'a str, params: &'a GpuBuffer<f32>, grads: &'a GpuBuffer<f32>) -> Self {
        Self { name, params, grads, lr_scale: 1.0, betas: None, eps: None, weight_decay: None, skip_zero_grad: false }
    }
    pub fn lr_scale(mut self, lr_scale: f32) -> Self {
        self.lr_scale = lr_scale;
        self
    }
    pub fn betas(mut self, beta1: f32, beta2: f32) -> Self {
        self.betas = Some([beta1, beta2]);
        self
    }
    pub fn eps(mut self, eps: f32) -> Self {
        self.eps = Some(eps);
        self
    }
    pub fn weight_decay(mut self, weight_decay: WeightDecay) -> Self {
        self.weight_decay = Some(weight_decay);
        self
    }
    pub fn sparse(mut self, skip_zero_grad: bool) -> Self {
        self.skip_zero_grad = skip_zero_grad;
        self
    }
    /// The group's name and length, for [`Adam::new`].
    pub fn spec(&self) -> GroupSpec {
        GroupSpec { name: self.name.to_string(), len: self.params.len() }
    }
    /// The gradient buffers of `groups`, in order (for [`GradNorm::record`]).
    pub fn grads_of(groups: &[ParamGroup<'a>]) -> Vec<&'a GpuBuffer<f32>> {
        groups.iter().map(|g| g.grads).collect()
    }
}

/// Name and length of a group: what the optimizer allocates state for.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct GroupSpec {
    pub name: String,
    pub len: usize,
}

struct GroupState {
    spec: GroupSpec,
    m: GpuBuffer<f32>,
    v: GpuBuffer<f32>,
}

/// The optimizer's state as named `f32` arrays, for checkpoints: `"adam.step"` (two
/// elements `[hi, lo]` with `t = hi * 2^24 + lo`, both exact in `f32`, so `t` is
/// exact up to 2^48), then `"adam.<group>.m"` and `"adam.<group>.v"` per group in
/// construction order.
pub type AdamState = Vec<(String, Vec<f32>)>;

const STEP_KEY: &str = "adam.step";
const STEP_SPLIT: u64 = 1 << 24;

/// Adam over a fixed set of named groups. See the module doc for the update.
pub struct Adam {
    config: AdamConfig,
    groups: Vec<GroupState>,
    step: u64,
    /// Stats meaning "no clipping, all finite, nothing to skip" for steps without a GradNorm.
    unit_stats: GpuBuffer<f32>,
}

impl Adam {
    /// Allocates zeroed `m`, `v` for each group. Names must be unique.
    pub fn new(gpu: &Gpu, groups: &[GroupSpec], config: AdamConfig) -> Result<Self, OptimError> {
        config.validate()?;
        let mut states: Vec<GroupState> = Vec::with_capacity(groups.len());
        for spec in groups {
            if states.iter().any(|s| s.spec.name == spec.name) {
                return Err(OptimError::DuplicateGroup(spec.name.clone()));
            }
            // wgpu zero-initializes new buffers.
            let m = GpuBuffer::zeros(gpu, &format!("adam.{}.m", spec.name), spec.len)?;
            let v = GpuBuffer::zeros(gpu, &format!("adam.{}.v", spec.name), spec.len)?;
            states.push(GroupState { spec: spec.clone(), m, v });
        }
        let unit_stats = GpuBuffer::from_slice(gpu, "adam.unit_stats", &super::grad::unit_stats())?;
        Ok(Self { config, groups: states, step: 0, unit_stats })
    }

    /// [`Adam::new`] with the names and lengths of `groups`.
    pub fn for_groups(gpu: &Gpu, groups: &[ParamGroup], config: AdamConfig) -> Result<Self, OptimError> {
        let specs: Vec<_> = groups.iter().map(ParamGroup::spec).collect();
        Self::new(gpu, &specs, config)
    }

    pub fn config(&self) -> &AdamConfig {
        &self.config
    }

    /// The groups the optimizer was built for, in order.
    pub fn groups(&self) -> impl Iterator<Item = &GroupSpec> {
        self.groups.iter().map(|g| &g.spec)
    }

    /// Steps taken so far (`t` of the last step; 0 before the first).
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// Sets the step counter (e.g. back by one after a step skipped for NaN gradients).
    pub fn set_step_count(&mut self, step: u64) {
        self.step = step;
    }

    /// The `(m, v)` buffers of a group.
    pub fn moments(&self, name: &str) -> Option<(&GpuBuffer<f32>, &GpuBuffer<f32>)> {
        self.groups.iter().find(|g| g.spec.name == name).map(|g| (&g.m, &g.v))
    }

    fn group_index(&self, name: &str) -> Result<usize, OptimError> {
        self.groups.iter().position(|g| g.spec.name == name).ok_or_else(|| {
            let known = self.groups.iter().map(|g| format!("{:?}", g.spec.name)).collect::<Vec<_>>().join(", ");
            OptimError::UnknownGroup(name.to_string(), known)
        })
    }

    /// Records one Adam step over `groups` (any subset of the optimizer's groups, each
    /// at most once, in any order) into `enc`, with learning rate `lr` (times each
    /// group's `lr_scale`). With `grad_stats`, the gradients are clipped as the stats
    /// say and the step is skipped on the GPU if they count a non-finite gradient
    /// (see the module doc); the stats must have been recorded before this call, in
    /// this encoder or an earlier submission. Increments the step counter.
    pub fn record_step(
        &mut self,
        gpu: &Gpu,
        enc: &mut Encoder,
        groups: &[ParamGroup],
        lr: f32,
        grad_stats: Option<&GradNorm>,
    ) -> Result<(), OptimError> {
        if !lr.is_finite() {
            return Err(OptimError::Config(format!("learning rate {lr} is not finite")));
        }
        let mut indices = Vec::with_capacity(groups.len());
        for g in groups {
            let idx = self.group_index(g.name)?;
            if indices.contains(&idx) {
                return Err(OptimError::DuplicateGroup(g.name.to_string()));
            }
            let expected = self.groups[idx].spec.len;
            if g.params.len() != g.grads.len() {
                return Err(OptimError::GradLength {
                    name: g.name.to_string(),
                    params: g.params.len(),
                    grads: g.grads.len(),
                });
            }
            if g.params.len() != expected {
                return Err(OptimError::GroupSize { name: g.name.to_string(), expected, got: g.params.len() });
            }
            let betas = g.betas.unwrap_or([self.config.beta1, self.config.beta2]);
            let eps = g.eps.unwrap_or(self.config.eps);
            let wd = g.weight_decay.unwrap_or(self.config.weight_decay);
            validate_hyper(&format!("group {:?}", g.name), betas, eps, wd)?;
            indices.push(idx);
        }
        let kernel = gpu.kernel(&SPEC)?;
        self.step += 1;
        let t = self.step as f64;
        let stats = grad_stats.map(|s| &s.stats().buffer).unwrap_or(&self.unit_stats.buffer);
        for (g, &idx) in groups.iter().zip(&indices) {
            let [beta1, beta2] = g.betas.unwrap_or([self.config.beta1, self.config.beta2]);
            let (wd_flag, weight_decay) = g.weight_decay.unwrap_or(self.config.weight_decay).flags_and_factor();
            let mut flags = wd_flag;
            if g.skip_zero_grad {
                flags |= FLAG_SKIP_ZERO_GRAD;
            }
            if self.config.skip_nonfinite {
                flags |= FLAG_SKIP_NONFINITE;
            }
            let params = AdamParams {
                n: g.params.len() as u32,
                flags,
                lr: lr * g.lr_scale,
                beta1,
                beta2,
                eps: g.eps.unwrap_or(self.config.eps),
                bias1: (1.0 - (beta1 as f64).powf(t)) as f32,
                bias2: (1.0 - (beta2 as f64).powf(t)) as f32,
                weight_decay,
                _pad: [0; 3],
            };
            let state = &self.groups[idx];
            let params_buf = enc.params(&params);
            enc.dispatch_threads(
                &kernel,
                &[&params_buf, &g.params.buffer, &g.grads.buffer, &state.m.buffer, &state.v.buffer, stats],
                params.n,
            );
        }
        Ok(())
    }

    /// [`Adam::record_step`] in its own submission (does not wait).
    pub fn step(
        &mut self,
        gpu: &Gpu,
        groups: &[ParamGroup],
        lr: f32,
        grad_stats: Option<&GradNorm>,
    ) -> Result<(), OptimError> {
        let mut enc = gpu.encoder();
        self.record_step(gpu, &mut enc, groups, lr, grad_stats)?;
        enc.submit();
        Ok(())
    }

    /// Zeroes `m`, `v` and the step counter.
    pub fn reset(&mut self, gpu: &Gpu) {
        for g in &self.groups {
            g.m.clear(gpu);
            g.v.clear(gpu);
        }
        self.step = 0;
    }

    /// Reads the state back (waits for submitted work). See [`AdamState`] for names.
    pub fn export_state(&self, gpu: &Gpu) -> Result<AdamState, OptimError> {
        if self.step >= STEP_SPLIT * STEP_SPLIT {
            return Err(OptimError::State(format!("step {} too large to store", self.step)));
        }
        let mut out = vec![(
            STEP_KEY.to_string(),
            vec![(self.step / STEP_SPLIT) as f32, (self.step % STEP_SPLIT) as f32],
        )];
        for g in &self.groups {
            out.push((format!("adam.{}.m", g.spec.name), g.m.read(gpu)?));
            out.push((format!("adam.{}.v", g.spec.name), g.v.read(gpu)?));
        }
        Ok(out)
    }

    /// Restores a state written by [`Adam::export_state`] for the same groups. Every
    /// array must be present with its exact length; arrays whose names do not start
    /// with `"adam."` are ignored (a checkpoint may hold other rooms' arrays), unknown
    /// `"adam."` arrays are an error. Nothing changes on error.
    pub fn import_state(&mut self, gpu: &Gpu, state: &[(String, Vec<f32>)]) -> Result<(), OptimError> {
        let find = |name: &str| -> Result<&Vec<f32>, OptimError> {
            let mut hits = state.iter().filter(|(n, _)| n == name);
            let first = hits.next().ok_or_else(|| OptimError::State(format!("array {name:?} missing")))?;
            if hits.next().is_some() {
                return Err(OptimError::State(format!("array {name:?} appears twice")));
            }
            Ok(&first.1)
        };
        let step = find(STEP_KEY)?;
        let step = match step.as_slice() {
            [hi, lo] if *hi >= 0.0 && *lo >= 0.0 && hi.fract() == 0.0 && lo.fract() == 0.0 && (*lo as u64) < STEP_SPLIT => {
                *hi as u64 * STEP_SPLIT + *lo as u64
            }
            other => return Err(OptimError::State(format!("{STEP_KEY:?} must be [hi, lo] integers, got {other:?}"))),
        };
        let mut expected = vec![STEP_KEY.to_string()];
        let mut arrays = Vec::with_capacity(self.groups.len());
        for g in &self.groups {
            let mut pair = Vec::with_capacity(2);
            for which in ["m", "v"] {
                let name = format!("adam.{}.{which}", g.spec.name);
                let data = find(&name)?;
                if data.len() != g.spec.len {
                    return Err(OptimError::State(format!(
                        "array {name:?} has {} elements, the group has {}",
                        data.len(),
                        g.spec.len
                    )));
                }
                pair.push(data);
                expected.push(name);
            }
            arrays.push(pair);
        }
        if let Some((name, _)) = state.iter().find(|(n, _)| n.starts_with("adam.") && !expected.contains(n)) {
            return Err(OptimError::State(format!("array {name:?} belongs to no group of this optimizer")));
        }
        for (g, pair) in self.groups.iter().zip(arrays) {
            g.m.write(gpu, pair[0]);
            g.v.write(gpu, pair[1]);
        }
        self.step = step;
        Ok(())
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(AdamParams, "optim/adam.wgsl", "AdamParams", [n, flags, lr, beta1, beta2, eps, bias1, bias2, weight_decay]);
    }
}
