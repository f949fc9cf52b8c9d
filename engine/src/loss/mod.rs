//! The loss room: per-ray losses and their gradients with respect to the rendered
//! [`RayOutput`](crate::layout::RayOutput)s.
//!
//! Owns the photometric loss ([`photometric`]) and the edge-guided depth/normal
//! regularizers of EdgeNeRF ([`edge_reg`]), the edge-guided depth-normal consistency on
//! the same patches ([`depth_normal`]) and RegNeRF's depth total variation on patches
//! from random poses ([`depth_tv`]). Invariant: a loss *writes* or *adds*
//! `dL/d RayOutput` per ray into one shared gradient buffer, never touching sampler,
//! field or renderer state; the photometric loss writes (it runs first), the others add.

pub mod depth_normal;
pub mod depth_tv;
pub mod edge_reg;
pub mod photometric;

pub use depth_normal::DepthNormal;
pub use depth_tv::DepthTv;
pub use edge_reg::{EdgeReg, EdgeRegLosses, EdgeRegWeights, RegConfig, RegVariant};
pub use photometric::Photometric;
