//! Checkpoints: one safetensors file holding the field's parameters, the optimizer
//! state and, in its metadata, the format tag, step, backend and the run config.
//!
//! Layout (all tensors `F32`): `field.<name>` for every array of `Field::export`,
//! `adam.*` for every array of `Adam::export_state`, and `occupancy.density` (the
//! occupancy grid's EMA densities, `resolution^3` in x-fastest order; absent from
//! checkpoints of uniform-mode runs and of builds before it was added, whose grid is
//! then rebuilt from the field), and `background.*` (the learned background's maps and
//! Adam state, [`crate::render::background`], for runs that have one). Metadata keys: `format`
//! (`edgenerf-checkpoint`), `version` (`1`), `step`, `backend`, `config` (JSON of the
//! [`RunConfig`]).
//!
//! Invariant: a checkpoint file is replaced atomically ([`write_atomic`]: written beside
//! it, then renamed), so an interrupted write never destroys the last good checkpoint.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use crate::field::NamedArray;

use super::TrainError;
use super::config::RunConfig;
use super::output::write_atomic;

pub const FORMAT: &str = "edgenerf-checkpoint";
pub const VERSION: &str = "1";

/// A checkpoint's contents on the host.
pub struct Checkpoint {
    pub step: u64,
    pub config: RunConfig,
    pub field: Vec<NamedArray>,
    pub optimizer: Vec<(String, Vec<f32>)>,
    /// The occupancy grid's densities: restoring them makes a resumed or rendered run
    /// skip exactly the space training skipped (a grid rebuilt from the field by one
    /// query per cell differs, and the field was trained with the grid it had).
    pub occupancy: Option<Vec<f32>>,
    /// The learned background's maps and optimizer state (`background.*` tensors; empty
    /// for runs without one).
    pub background: Vec<(String, Vec<f32>)>,
}

/// Tensor name of [`Checkpoint::occupancy`].
const OCCUPANCY: &str = "occupancy.density";

fn corrupt(path: &Path, message: impl std::fmt::Display) -> TrainError {
    TrainError::Checkpoint { path: path.to_path_buf(), message: message.to_string() }
}

impl Checkpoint {
    /// Writes atomically to `path`.
    pub fn save(&self, path: &Path) -> Result<(), TrainError> {
        let mut bytes: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
        for a in &self.field {
            bytes.push((format!("field.{}", a.name), bytemuck::cast_slice(&a.data).to_vec(), a.shape.clone()));
        }
        for (name, data) in &self.optimizer {
            bytes.push((name.clone(), bytemuck::cast_slice(data).to_vec(), vec![data.len()]));
        }
        if let Some(d) = &self.occupancy {
            bytes.push((OCCUPANCY.to_string(), bytemuck::cast_slice(d).to_vec(), vec![d.len()]));
        }
        for (name, data) in &self.background {
            bytes.push((name.clone(), bytemuck::cast_slice(data).to_vec(), vec![data.len()]));
        }
        let views = bytes
            .iter()
            .map(|(n, b, s)| Ok((n.clone(), TensorView::new(Dtype::F32, s.clone(), b)?)))
            .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()
            .map_err(|e| corrupt(path, e))?;
        let meta = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("version".to_string(), VERSION.to_string()),
            ("step".to_string(), self.step.to_string()),
            ("backend".to_string(), serde_json::to_value(self.config.backend).unwrap().as_str().unwrap().to_string()),
            ("config".to_string(), serde_json::to_string(&self.config).expect("configs serialize")),
        ]);
        let data = safetensors::serialize(views, Some(meta)).map_err(|e| corrupt(path, e))?;
        write_atomic(path, &data)
    }

    /// Reads a checkpoint written by [`Checkpoint::save`].
    pub fn load(path: &Path) -> Result<Checkpoint, TrainError> {
        let data = std::fs::read(path).map_err(|e| TrainError::io(path, e))?;
        let (_, meta) = SafeTensors::read_metadata(&data).map_err(|e| corrupt(path, format!("not a safetensors file ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        if meta.get("format").map(String::as_str) != Some(FORMAT) {
            return Err(corrupt(path, "not an edgenerf checkpoint (metadata 'format' missing)"));
        }
        if meta.get("version").map(String::as_str) != Some(VERSION) {
            return Err(corrupt(path, format!("checkpoint version {:?}, this build reads {VERSION}", meta.get("version"))));
        }
        let step = meta.get("step").and_then(|s| s.parse().ok()).ok_or_else(|| corrupt(path, "bad 'step'"))?;
        let config: RunConfig = serde_json::from_str(meta.get("config").ok_or_else(|| corrupt(path, "no 'config'"))?)
            .map_err(|e| corrupt(path, format!("config: {e}")))?;
        let tensors = SafeTensors::deserialize(&data).map_err(|e| corrupt(path, e))?;
        let mut field = Vec::new();
        let mut optimizer = Vec::new();
        let mut occupancy = None;
        let mut background = Vec::new();
        for (name, view) in tensors.tensors() {
            if view.dtype() != Dtype::F32 {
                return Err(corrupt(path, format!("tensor {name} is {:?}, expected F32", view.dtype())));
            }
            let values: Vec<f32> = bytemuck::pod_collect_to_vec(view.data());
            if name == OCCUPANCY {
                occupancy = Some(values);
                continue;
            }
            if name.starts_with("background.") {
                background.push((name, values));
                continue;
            }
            match name.strip_prefix("field.") {
                Some(n) => field.push(NamedArray { name: n.to_string(), shape: view.shape().to_vec(), data: values }),
                None => optimizer.push((name, values)),
            }
        }
        Ok(Checkpoint { step, config, field, optimizer, occupancy, background })
    }
}
