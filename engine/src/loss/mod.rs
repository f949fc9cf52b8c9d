//! The loss room: per-ray losses and their gradients with respect to the rendered
//! [`RayOutput`](crate::samples::RayOutput)s.
//!
//! Owns the photometric loss ([`photometric`]); the edge-guided depth/normal
//! regularizers and RegNeRF's depth TV join here. Invariant: a loss *writes* or *adds*
//! `dL/d RayOutput` per ray into one shared gradient buffer, never touching sampler,
//! field or renderer state; the photometric loss writes (it runs first), the others add.

pub mod photometric;

pub use photometric::Photometric;
