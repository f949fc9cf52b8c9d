//! edgenerf: sparse-view neural radiance fields with edge-guided depth and normal
//! regularization, on a hash-grid engine that runs in WGSL compute shaders through
//! wgpu/Vulkan (an NVIDIA GPU, or Mesa lavapipe on the CPU).
//!
//! The crate is divided into rooms, its top-level modules; `docs/ARCHITECTURE.md` in the
//! repository describes what each owns, the data flow of a training step, and which
//! room may use which (checked by `tests/room_rules.rs`):
//! * [`gpu`]: the wgpu/Vulkan context: adapter selection, buffers, kernels and dispatch;
//! * [`rng`]: the deterministic generators (SplitMix64 on the host, the kernels' PCG
//!   hash and its host mirror);
//! * [`data`]: scenes, cameras and rays, dataset formats (Blender, LLFF, DTU) and splits;
//! * [`edges`]: edge masks of the training images (Canny, external maps, dilation);
//! * [`layout`]: the ray, sample and per-ray output layouts shared by the GPU rooms;
//! * [`field`]: the `Field` trait and its hash-grid and MLP backends, with analytic
//!   normals and the exact backward pass;
//! * [`sampler`]: the occupancy grid, its BVH and sample placement along rays;
//! * [`render`]: volume rendering forward and backward, and the sparse-view priors;
//! * [`loss`]: photometric, edge-guided depth/normal and RegNeRF depth-TV losses;
//! * [`optim`]: Adam, gradient norm and clipping on the GPU, learning-rate schedules;
//! * [`train`]: configuration, the model, the training step, checkpoints, evaluation;
//! * [`mesh`]: triangle meshes on the CPU: PLY, marching tetrahedra, surface sampling,
//!   nearest points, Chamfer distance and F-score;
//! * [`metrics`]: image and geometry metrics (PSNR, SSIM, LPIPS, depth/normal errors,
//!   depth boundary error, mesh Chamfer / F-score against a ground-truth mesh);
//! * [`viz`]: depth, normal and opacity images for people.

pub mod data;
pub mod edges;
pub mod field;
pub mod gpu;
pub mod loss;
pub mod mesh;
pub mod metrics;
pub mod optim;
pub mod render;
pub mod rng;
pub mod layout;
pub mod train;
pub mod viz;
pub mod sampler;
