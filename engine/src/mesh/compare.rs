//! How far apart two surfaces are: the Chamfer distance, and precision, recall and
//! F-score at a distance threshold (Knapitsch et al., Tanks and Temples, 2017), from
//! uniform samples of each mesh and exact point-to-triangle distances to the other.
//!
//! * accuracy: mean distance from the predicted surface's samples to the reference
//!   mesh; completeness: mean distance from the reference's samples to the predicted
//!   mesh; Chamfer: their mean (DTU's convention, in scene units);
//! * precision: the fraction of predicted samples within `tau` of the reference;
//!   recall: the fraction of reference samples within `tau` of the prediction;
//!   F-score: their harmonic mean (0 when both are 0).

use glam::Vec3;
use serde::Serialize;

use super::{TriMesh, TriangleBvh, sample_surface};

/// The figures of [`compare_meshes`] (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SurfaceDistances {
    pub chamfer: f64,
    pub accuracy: f64,
    pub completeness: f64,
    pub precision: f64,
    pub recall: f64,
    pub fscore: f64,
    /// The F-score's threshold `tau` (scene units).
    pub threshold: f64,
    /// Samples counted on each surface (after the region filter).
    pub pred_samples: usize,
    pub gt_samples: usize,
}

/// The figures from the two directions' distances (`pred_to_gt`: from predicted
/// samples to the reference mesh; `gt_to_pred`: the reverse) at threshold `tau`.
/// An empty side makes its mean infinite and its fraction 0.
pub fn chamfer_fscore(pred_to_gt: &[f32], gt_to_pred: &[f32], tau: f64) -> SurfaceDistances {
    let mean = |d: &[f32]| if d.is_empty() { f64::INFINITY } else { d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64 };
    let within = |d: &[f32]| if d.is_empty() { 0.0 } else { d.iter().filter(|&&x| (x as f64) < tau).count() as f64 / d.len() as f64 };
    let (accuracy, completeness) = (mean(pred_to_gt), mean(gt_to_pred));
    let (precision, recall) = (within(pred_to_gt), within(gt_to_pred));
    let fscore = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
    SurfaceDistances {
        chamfer: 0.5 * (accuracy + completeness),
        accuracy,
        completeness,
        precision,
        recall,
        fscore,
        threshold: tau,
        pred_samples: pred_to_gt.len(),
        gt_samples: gt_to_pred.len(),
    }
}

/// Samples `samples` points on each mesh (seeds `seed` and `seed + 1`), keeps the
/// predicted ones where `keep_pred` holds and the reference ones where `keep_gt` holds
/// (the region that counts), and scores them with [`chamfer_fscore`] at `tau`.
pub fn compare_meshes(
    pred: &TriMesh,
    gt: &TriMesh,
    samples: usize,
    seed: u64,
    tau: f64,
    keep_pred: impl Fn(Vec3) -> bool + Sync,
    keep_gt: impl Fn(Vec3) -> bool + Sync,
) -> SurfaceDistances {
    let pred_pts: Vec<Vec3> = sample_surface(pred, samples, seed).into_iter().filter(|&p| keep_pred(p)).collect();
    let gt_pts: Vec<Vec3> = sample_surface(gt, samples, seed.wrapping_add(1)).into_iter().filter(|&p| keep_gt(p)).collect();
    let to_gt = TriangleBvh::new(gt).distances(&pred_pts);
    let to_pred = TriangleBvh::new(pred).distances(&gt_pts);
    chamfer_fscore(&to_gt, &to_pred, tau)
}
