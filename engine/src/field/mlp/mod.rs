//! The MLP field (mip-NeRF / RegNeRF backbone), behind the same [`Field`](super::Field)
//! interface as the hash grid. Work in progress: the configuration only.

pub mod config;

pub use config::{MlpConfig, PositionEncoding};
