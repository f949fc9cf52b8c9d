//! edgenerf: sparse-view neural radiance fields with edge-guided depth and normal
//! regularization, on a hash-grid engine that runs in WGSL compute shaders through
//! wgpu/Vulkan (an NVIDIA GPU, or Mesa lavapipe on the CPU).
//!
//! Rooms (see `ARCHITECTURE.md` in the repository's docs):
//! * [`gpu`]: adapter selection, buffers, kernels and dispatch;
//! * [`data`]: scenes, cameras, dataset formats and splits;
//! * [`edges`]: edge masks of the training images (Canny, external maps, dilation).

pub mod data;
pub mod edges;
pub mod field;
pub mod gpu;
pub mod loss;
pub mod metrics;
pub mod optim;
pub mod render;
pub mod samples;
pub mod train;
pub mod viz;
pub mod sampler;
