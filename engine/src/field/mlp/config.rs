//! Configuration of the MLP field (see the [`mlp`](super) module doc for the network).
//!
//! Defaults are mip-NeRF's / RegNeRF's backbone: 8 layers of 256 with the encoding
//! concatenated again before layer 4, a 256-wide bottleneck, one view-dependent layer
//! of 128, integrated positional encoding of degrees 0..16 for positions and a plain
//! encoding of degrees 0..4 (with the identity) for directions.

use serde::{Deserialize, Serialize};

use crate::field::FieldError;

/// How positions are encoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PositionEncoding {
    /// mip-NeRF's integrated positional encoding: each frequency band attenuated by
    /// the Gaussian of the sample's conical frustum, `exp(-4^k var / 2)`.
    #[default]
    Integrated,
    /// NeRF's positional encoding `[p, sin(2^k p), cos(2^k p)]`.
    Plain,
}

/// Largest supported hidden width (workgroup tiles handle any width; this bounds memory).
pub const MAX_MLP_WIDTH: u32 = 1024;
/// Largest number of frequency bands of either encoding.
pub const MAX_DEGREE: u32 = 24;

/// Configuration of the MLP field. Defaults: mip-NeRF / RegNeRF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MlpConfig {
    /// Layers of the trunk (`D`, mip-NeRF 8).
    pub depth: u32,
    /// Width of the trunk and of the bottleneck (`W`, mip-NeRF 256).
    pub width: u32,
    /// The position encoding is concatenated to the input of this trunk layer
    /// (mip-NeRF: 4, i.e. after the 4th layer); `None`: no skip connection.
    pub skip_layer: Option<u32>,
    /// Width of the view-dependent layer (mip-NeRF 128).
    pub color_width: u32,
    pub encoding: PositionEncoding,
    /// Frequency bands `2^k` of the position encoding, `k in [min_deg, max_deg)`
    /// (mip-NeRF IPE 0..16; NeRF's plain PE 0..10).
    pub pos_min_deg: u32,
    pub pos_max_deg: u32,
    /// Frequency bands of the direction encoding (0..4, with the identity).
    pub dir_max_deg: u32,
    /// `sigma = softplus(raw + density_bias)` (mip-NeRF: -1).
    pub density_bias: f32,
    /// Normals are zero where `|grad_x sigma| <= normal_eps`.
    pub normal_eps: f32,
    /// Samples per GPU chunk (bounds the activation memory: about
    /// `4 * 4 (D + 4) W` bytes per sample with normals).
    pub chunk: u32,
    /// Seed of the deterministic initialisation (Glorot-uniform weights, zero biases).
    pub seed: u64,
    /// Learning-rate multiplier of the MLP's parameter group.
    pub lr_scale: f32,
}

impl Default for MlpConfig {
    fn default() -> Self {
        Self {
            depth: 8,
            width: 256,
            skip_layer: Some(4),
            color_width: 128,
            encoding: PositionEncoding::Integrated,
            pos_min_deg: 0,
            pos_max_deg: 16,
            dir_max_deg: 4,
            density_bias: -1.0,
            normal_eps: 1e-10,
            chunk: 4096,
            seed: 0,
            lr_scale: 1.0,
        }
    }
}

impl MlpConfig {
    /// A small network for tests and quick comparisons (4 x 64, skip at 2, colour 32).
    pub fn small() -> Self {
        Self { depth: 4, width: 64, skip_layer: Some(2), color_width: 32, ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), FieldError> {
        let err = |m: String| Err(FieldError::Config(m));
        if !(1..=32).contains(&self.depth) {
            return err(format!("mlp.depth = {} must lie in 1..=32", self.depth));
        }
        if !(1..=MAX_MLP_WIDTH).contains(&self.width) || !(1..=MAX_MLP_WIDTH).contains(&self.color_width) {
            return err(format!(
                "mlp.width = {} and mlp.color_width = {} must lie in 1..={MAX_MLP_WIDTH}",
                self.width, self.color_width
            ));
        }
        if let Some(s) = self.skip_layer
            && !(1..self.depth).contains(&s)
        {
            return err(format!("mlp.skip_layer = {s} must lie in 1..{} (a layer after the first)", self.depth));
        }
        if self.pos_min_deg >= self.pos_max_deg || self.pos_max_deg > MAX_DEGREE || self.dir_max_deg > MAX_DEGREE {
            return err(format!(
                "mlp encoding degrees: need pos_min_deg < pos_max_deg <= {MAX_DEGREE} and dir_max_deg <= {MAX_DEGREE} \
                 (got {}..{}, {})",
                self.pos_min_deg, self.pos_max_deg, self.dir_max_deg
            ));
        }
        if !(self.density_bias.is_finite() && self.normal_eps >= 0.0) {
            return err("mlp.density_bias must be finite and mlp.normal_eps >= 0".into());
        }
        if self.chunk < 64 || !self.chunk.is_multiple_of(64) {
            return err(format!("mlp.chunk = {} must be a positive multiple of 64", self.chunk));
        }
        if !(self.lr_scale.is_finite() && self.lr_scale > 0.0) {
            return err(format!("mlp.lr_scale = {} must be finite and > 0", self.lr_scale));
        }
        Ok(())
    }

    /// Frequency bands of the position encoding.
    pub fn pos_bands(&self) -> u32 {
        self.pos_max_deg - self.pos_min_deg
    }

    /// Width of the position encoding: `6` per band (sin and cos of 3 axes), plus the
    /// identity (3) for the plain encoding.
    pub fn pos_dim(&self) -> u32 {
        6 * self.pos_bands() + if self.encoding == PositionEncoding::Plain { 3 } else { 0 }
    }

    /// Width of the direction encoding: the identity and `6` per band.
    pub fn dir_dim(&self) -> u32 {
        3 + 6 * self.dir_max_deg
    }
}
