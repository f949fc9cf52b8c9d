//! Which depth of a ray the edge-guided terms regularize: owner of [`DepthEstimate`]
//! (`reg.depth_estimate`) and [`OPACITY_FLOOR`], the opacity below which the depth
//! given termination stops dividing by the ray's opacity.
//!
//! Shared by `L_z`/`L_n` ([`super::edge_reg`]), `L_dn` ([`super::depth_normal`]) and
//! `L_pl` ([`super::planarity`]), which each pass the floor to their kernel as a
//! parameter. It sits below all three so that none of them imports another for it:
//! `edge_reg` (which turns `reg.*` into the settings of the other two terms) imports
//! `depth_normal` and `planarity`, and those two import only this module.

/// Which depth of a ray `L_z` regularizes (see [`super::edge_reg`]'s module doc), and
/// where `L_dn` takes the point a ray ends at ([`super::depth_normal`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthEstimate {
    /// `sum_i w_i t_i`, the paper's integral (not divided by opacity): the loss can
    /// lower it by changing a ray's opacity as well as where the ray terminates.
    #[default]
    Expected,
    /// Depth given termination, `sum_i w_i t_i / opacity` (the authors' code): only
    /// where the ray ends counts. Opacity is floored at [`OPACITY_FLOOR`].
    GivenTermination,
}

/// Below this opacity a ray is mostly background and its depth given termination an
/// average over a trace of weights: the estimate divides by this floor instead, and
/// the gradient into opacity is zero there (the authors clip the distance to the
/// ray's range instead, with a gradient that grows as `1 / opacity`).
pub const OPACITY_FLOOR: f32 = 0.1;
