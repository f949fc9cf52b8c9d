//! Mesh-level geometry: a predicted surface (an exported mesh) against the scene's
//! ground-truth mesh (synthetic scenes' `gt_mesh.ply`), as the Chamfer distance and
//! the F-score with its precision and recall ([`crate::mesh::compare`]), from
//! `samples` uniform, area-weighted, seeded samples of each mesh and exact
//! point-to-triangle distances to the other.
//!
//! Which surface counts: what the scene's cameras see, judged with the ground-truth
//! depth of every view (train and test):
//! * a ground-truth sample counts when some view sees it: it projects into the view's
//!   frame and its distance from the camera matches the GT depth of its pixel within
//!   [`visibility_tolerance`] (hidden faces, the undersides of objects on a floor, are
//!   not counted against the prediction);
//! * a predicted sample counts when it lies inside the scene box and some view could
//!   see it: it projects into the frame and is not behind the GT surface of its pixel
//!   by more than the tolerance (or the pixel has no GT surface). Predicted surface in
//!   free space (floaters) counts; surface hidden behind the ground truth in every view
//!   (the inside of a solid) cannot be judged and does not.
//!
//! The default threshold is 1 % of the scene box's diagonal (0.038 on the committed
//! `creases`, about 1.4 pixel footprints at its cameras' distance of 4 units).

use glam::Vec3;
use serde::Serialize;

use super::MetricsError;
use crate::data::Scene;
use crate::mesh::{SurfaceDistances, TriMesh, compare::compare_meshes};

/// Settings of [`mesh_metrics`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeshMetricParams {
    /// Samples drawn on each mesh (before the visibility filter).
    pub samples: usize,
    pub seed: u64,
    /// F-score threshold as a fraction of the scene box's diagonal.
    pub threshold_rel: f64,
}

impl Default for MeshMetricParams {
    fn default() -> Self {
        MeshMetricParams { samples: 100_000, seed: 0, threshold_rel: 0.01 }
    }
}

/// The figures of [`mesh_metrics`] and the parameters they were computed with.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshMetrics {
    #[serde(flatten)]
    pub distances: SurfaceDistances,
    pub params: MeshMetricParams,
}

/// How far a point's distance from a camera may differ from the GT depth of its pixel
/// and still count as that pixel's surface: three pixel footprints at depth `d`
/// (`3 d / fx`, the change of depth across a pixel on a surface seen at 70 degrees)
/// plus 0.1 % of `d`.
pub fn visibility_tolerance(d: f32, fx: f32) -> f32 {
    3.0 * d / fx + 1e-3 * d
}

/// `(gt_visible, pred_visible)`: the region tests of the module doc for `scene`.
fn region(scene: &Scene) -> impl Fn(Vec3, bool) -> bool + Sync + '_ {
    let views: Vec<_> = scene.views.iter().filter_map(|v| Some((&v.camera, v.camera.w2c(), v.depth.as_deref()?))).collect();
    let [lo, hi] = scene.aabb;
    move |p: Vec3, predicted: bool| {
        if predicted && (p.cmplt(lo).any() || p.cmpgt(hi).any()) {
            return false;
        }
        views.iter().any(|(cam, w2c, depth)| {
            let Some((px, _)) = cam.project_with(w2c, p) else { return false };
            if !cam.in_frame(px) {
                return false;
            }
            let gt = depth[px.y as usize * cam.width as usize + px.x as usize];
            let d = p.distance(cam.origin());
            let tol = visibility_tolerance(gt.max(d), cam.fx);
            if super::valid_depth(gt) {
                if predicted { d <= gt + tol } else { (d - gt).abs() <= tol }
            } else {
                predicted
            }
        })
    }
}

/// The mesh figures of `pred` against `gt` over the part of `scene` its cameras see
/// (see the module doc). Needs a world-space scene with GT depth.
pub fn mesh_metrics(pred: &TriMesh, gt: &TriMesh, scene: &Scene, params: &MeshMetricParams) -> Result<MeshMetrics, MetricsError> {
    if scene.ndc.is_some() || scene.views.iter().all(|v| v.depth.is_none()) {
        return Err(MetricsError::Empty { what: "the ground-truth depth that decides which surface the cameras see" });
    }
    if gt.triangles.is_empty() {
        return Err(MetricsError::Empty { what: "the ground-truth mesh" });
    }
    let seen = region(scene);
    let tau = params.threshold_rel * (scene.aabb[1] - scene.aabb[0]).length() as f64;
    let distances = compare_meshes(pred, gt, params.samples, params.seed, tau, |p| seen(p, true), |p| seen(p, false));
    Ok(MeshMetrics { distances, params: *params })
}
