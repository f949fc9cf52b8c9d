//! Checkpoints: one safetensors file holding the field's parameters, the optimizer
//! state and, in its metadata, the format tag, step, backend and the run config.
//!
//! Layout (all tensors `F32`): `field.<name>` for every array of `Field::export`,
//! `adam.*` for every array of `Adam::export_state`, and `occupancy.density` (the
//! occupancy grid's EMA densities, `resolution^3` in x-fastest order; absent from
//! checkpoints of uniform-mode runs and of builds before it was added, whose grid is
//! then rebuilt from the field), and `background.*` (the learned background's maps and
//! Adam state, [`crate::render::background`], for runs that have one). Metadata keys: `format`
//! (`edgenerf-checkpoint`), `version` (`2`), `step`, `backend`, `config` (JSON of the
//! [`RunConfig`]), and the integrity record: `tensors` (JSON: every tensor's name,
//! full shape and CRC-32 of its bytes) and `meta_crc32` (CRC-32 of `step`, `backend`
//! and `config`). Version `1` files (before the record) still load, unchecked.
//!
//! Invariants: a checkpoint file is replaced atomically ([`write_atomic`]: written
//! beside it, then renamed), so an interrupted write never destroys the last good
//! checkpoint. [`Checkpoint::load`] trusts nothing it cannot prove: every tensor must
//! match its record by name, full shape and checksum (a flipped weight, a reshaped
//! tensor or an edited config is refused, naming the file), and every value must be
//! finite.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use crate::field::NamedArray;

use super::TrainError;
use super::config::RunConfig;
use super::atomic_file::write_atomic;

pub const FORMAT: &str = "edgenerf-checkpoint";
pub const VERSION: &str = "2";
/// The version before the integrity record, read without checks.
const VERSION_UNCHECKED: &str = "1";

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
        let record: serde_json::Map<String, serde_json::Value> = bytes
            .iter()
            .map(|(n, b, s)| (n.clone(), serde_json::json!({ "shape": s, "crc32": tensor_crc(n, s, b) })))
            .collect();
        let step = self.step.to_string();
        let backend = serde_json::to_value(self.config.backend).unwrap().as_str().unwrap().to_string();
        let config = serde_json::to_string(&self.config).expect("configs serialize");
        let meta = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("version".to_string(), VERSION.to_string()),
            ("meta_crc32".to_string(), meta_crc(&step, &backend, &config).to_string()),
            ("tensors".to_string(), serde_json::Value::Object(record).to_string()),
            ("step".to_string(), step),
            ("backend".to_string(), backend),
            ("config".to_string(), config),
        ]);
        let data = safetensors::serialize(views, Some(meta)).map_err(|e| corrupt(path, e))?;
        write_atomic(path, &data)
    }

    /// Reads a checkpoint written by [`Checkpoint::save`], refusing one whose tensors or
    /// metadata do not match their integrity record or hold a non-finite value.
    pub fn load(path: &Path) -> Result<Checkpoint, TrainError> {
        let data = std::fs::read(path).map_err(|e| TrainError::io(path, e))?;
        let (_, meta) = SafeTensors::read_metadata(&data).map_err(|e| corrupt(path, format!("not a safetensors file ({e})")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        if meta.get("format").map(String::as_str) != Some(FORMAT) {
            return Err(corrupt(path, "not an edgenerf checkpoint (metadata 'format' missing)"));
        }
        let checked = match meta.get("version").map(String::as_str) {
            Some(VERSION) => true,
            Some(VERSION_UNCHECKED) => false,
            v => {
                return Err(corrupt(
                    path,
                    format!("checkpoint version {v:?}, this build reads {VERSION} and {VERSION_UNCHECKED}; use the build that wrote it"),
                ));
            }
        };
        let damaged = |what: String| {
            corrupt(
                path,
                format!(
                    "damaged: {what}; the file changed after it was saved (a disk or copy fault, or an edit), so it \
                     cannot be trusted. Restore it from a copy, or retrain"
                ),
            )
        };
        let get = |key: &str| meta.get(key).ok_or_else(|| damaged(format!("metadata '{key}' is missing")));
        let record: serde_json::Map<String, serde_json::Value> = if checked {
            let (step, backend, config) = (get("step")?, get("backend")?, get("config")?);
            let want: Option<u32> = get("meta_crc32")?.parse().ok();
            if want != Some(meta_crc(step, backend, config)) {
                return Err(damaged("its step, backend or config does not match the checksum saved with them".into()));
            }
            serde_json::from_str(get("tensors")?).map_err(|e| damaged(format!("metadata 'tensors' is not valid ({e})")))?
        } else {
            serde_json::Map::new()
        };
        let step = meta.get("step").and_then(|s| s.parse().ok()).ok_or_else(|| corrupt(path, "bad 'step'"))?;
        let config: RunConfig = serde_json::from_str(meta.get("config").ok_or_else(|| corrupt(path, "no 'config'"))?)
            .map_err(|e| corrupt(path, format!("config: {e}")))?;
        let tensors = SafeTensors::deserialize(&data).map_err(|e| corrupt(path, e))?;
        if checked {
            for name in record.keys() {
                if tensors.tensor(name).is_err() {
                    return Err(damaged(format!("tensor {name} is missing")));
                }
            }
        }
        let mut field = Vec::new();
        let mut optimizer = Vec::new();
        let mut occupancy = None;
        let mut background = Vec::new();
        for (name, view) in tensors.tensors() {
            if view.dtype() != Dtype::F32 {
                return Err(corrupt(path, format!("tensor {name} is {:?}, expected F32", view.dtype())));
            }
            if checked {
                let rec = record.get(&name).ok_or_else(|| damaged(format!("tensor {name} was not saved with it")))?;
                let shape: Option<Vec<usize>> = serde_json::from_value(rec["shape"].clone()).ok();
                if shape.as_deref() != Some(view.shape()) {
                    return Err(damaged(format!("tensor {name} has shape {:?}, saved as {}", view.shape(), rec["shape"])));
                }
                if rec["crc32"].as_u64() != Some(tensor_crc(&name, view.shape(), view.data()) as u64) {
                    return Err(damaged(format!("the values of tensor {name} do not match the checksum saved with them")));
                }
            }
            let values: Vec<f32> = bytemuck::pod_collect_to_vec(view.data());
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(corrupt(
                    path,
                    format!(
                        "tensor {name} holds a non-finite value ({} at index {i}): a diverged run or a damaged file; it \
                         cannot be rendered or resumed. Use an earlier checkpoint, or retrain",
                        values[i]
                    ),
                ));
            }
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

/// The CRC-32 of one tensor: its name, full shape and bytes (a renamed or reshaped
/// tensor fails it as a changed value does).
fn tensor_crc(name: &str, shape: &[usize], bytes: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(name.as_bytes());
    h.update(&[0]);
    for &d in shape {
        h.update(&(d as u64).to_le_bytes());
    }
    h.update(bytes);
    h.finalize()
}

/// The CRC-32 of the metadata a checkpoint is read with.
fn meta_crc(step: &str, backend: &str, config: &str) -> u32 {
    let mut h = crc32fast::Hasher::new();
    for part in [step, backend, config] {
        h.update(part.as_bytes());
        h.update(&[0]);
    }
    h.finalize()
}
