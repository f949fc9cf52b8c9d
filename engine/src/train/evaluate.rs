//! The evaluation of a model on a scene's views: each rendered view scored against its
//! image under the scene's protocol ([`crate::metrics::protocol`]: DTU masked, or full
//! image) and, where the scene has them, against its ground-truth depth and normals.
//!
//! Every evaluation goes through [`evaluate_view`]: the end-of-run evaluation of a
//! training run ([`evaluate`]), `edgenerf render` and `edgenerf eval`, so the same
//! checkpoint gets the same figures from each.
//!
//! Where the view and the training views have ground-truth depth (world-space scenes),
//! PSNR is also split by how many training views see each pixel's surface
//! ([`crate::metrics::covisibility`]).
//!
//! Invariants: image figures follow [`Protocol::of_view`]; the rendered depth compared
//! with ground truth is [`RenderedView::terminated_depth`], the normals the
//! renormalised rendered ones; depth is compared only in world-space scenes.

use crate::data::Scene;
use crate::gpu::Gpu;
use crate::metrics::geometry::{DepthErrors, GeometryInputs, GeometryMetrics, GeometryParams, NormalErrors, Regions, evaluate_geometry};
use crate::metrics::image::ImageMetrics;
use crate::metrics::protocol::{Protocol, score_view};
use crate::metrics::MetricsError;
use crate::metrics::covisibility::{Covisibility, CovisibilityParams, DepthView, MAX_TRAINING_VIEWS, covisibility};

use super::TrainError;
use super::model::{Model, RenderedView};

/// Test-view evaluation: per view, and means over views (geometry means over the views
/// that have ground truth; see [`crate::metrics`] for the definitions).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Evaluation {
    pub per_view: Vec<ViewEvaluation>,
    /// Mean of the per-view PSNRs (the convention of NeRF papers), and of the SSIMs.
    pub mean_psnr: f32,
    pub mean_ssim: f32,
    /// Field samples per pixel ray of the test renders (the sampler's cost at render time).
    pub mean_samples_per_ray: f32,
    /// Mean absolute depth error (world units) over all GT pixels, outside and inside
    /// the GT edge band (within `dilate_px` of a GT depth/normal discontinuity).
    pub mean_depth_abs_error: Option<f32>,
    pub mean_depth_abs_error_non_edge: Option<f32>,
    pub mean_depth_abs_error_edge: Option<f32>,
    pub mean_depth_abs_rel: Option<f32>,
    /// Mean normal angle (degrees), likewise split.
    pub mean_normal_angle_deg: Option<f32>,
    pub mean_normal_angle_deg_non_edge: Option<f32>,
    pub mean_normal_angle_deg_edge: Option<f32>,
    /// iBims-1 depth boundary error (pixels): accuracy and completeness.
    pub mean_dbe_accuracy: Option<f32>,
    pub mean_dbe_completeness: Option<f32>,
}

/// One rendered test view against its image and, where the scene has them, its
/// ground-truth depth and normals.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewEvaluation {
    pub view: usize,
    /// PSNR (dB) and SSIM under `protocol`.
    pub psnr: f32,
    pub ssim: f32,
    /// Which pixels `psnr` and `ssim` count ([`Protocol::of_view`]).
    pub protocol: Protocol,
    /// The unmasked figures, where `protocol` is masked (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_image: Option<ImageMetrics>,
    /// Field samples per pixel ray of this render.
    pub samples_per_ray: f32,
    /// Geometry against ground truth (scenes with GT depth or normals; depth only for
    /// world-space scenes). The rendered depth is [`RenderedView::terminated_depth`]
    /// (expected ray distance given termination), the normals the renormalised
    /// rendered ones.
    pub geometry: Option<GeometryMetrics>,
    /// PSNR over the pixels whose ground-truth surface no training view, one, or two or
    /// more see (world-space scenes whose views all have ground-truth depth, with at
    /// most [`MAX_TRAINING_VIEWS`] training views; absent otherwise). Full-image pixels,
    /// whatever `protocol` is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub covisibility: Option<Covisibility>,
}

fn mean_of(values: impl Iterator<Item = Option<f64>>) -> Option<f32> {
    let v: Vec<f64> = values.flatten().collect();
    (!v.is_empty()).then(|| (v.iter().sum::<f64>() / v.len() as f64) as f32)
}

/// Compares a rendered view with the image (under the view's protocol) and ground truth
/// of `scene.views[v]`.
pub fn evaluate_view(scene: &Scene, v: usize, r: &RenderedView) -> Result<ViewEvaluation, MetricsError> {
    let view = &scene.views[v];
    let image = score_view(scene, v, r.rgb.as_flattened())?;
    let gt_depth = view.depth.as_deref().filter(|_| scene.ndc.is_none());
    let gt_normal = view.normal.as_deref();
    let geometry = if gt_depth.is_some() || gt_normal.is_some() {
        let depth = r.terminated_depth(scene.far);
        let normal = r.unit_normals();
        Some(evaluate_geometry(
            &GeometryInputs {
                width: r.width,
                height: r.height,
                gt_depth,
                gt_normal,
                depth: gt_depth.map(|_| depth.as_slice()),
                normal: gt_normal.map(|_| normal.as_slice()),
            },
            &GeometryParams::default(),
        )?)
    } else {
        None
    };
    let samples_per_ray = r.samples as f32 / (r.width * r.height).max(1) as f32;
    let covisibility = covisibility_of(scene, v, r.rgb.as_flattened())?;
    Ok(ViewEvaluation {
        view: v,
        psnr: image.psnr as f32,
        ssim: image.ssim as f32,
        protocol: image.protocol,
        full_image: image.full_image,
        samples_per_ray,
        geometry,
        covisibility,
    })
}

/// [`ViewEvaluation::covisibility`] of `rgb`, the render of view `v`: `None` in NDC,
/// without training views or with more than [`MAX_TRAINING_VIEWS`], or where this view
/// or a training view lacks ground-truth depth.
fn covisibility_of(scene: &Scene, v: usize, rgb: &[f32]) -> Result<Option<Covisibility>, MetricsError> {
    let depth_view = |i: usize| scene.views[i].depth.as_deref().map(|depth| DepthView { camera: &scene.views[i].camera, depth });
    let train: Option<Vec<DepthView>> = scene.split.train.iter().filter(|&&i| i != v).map(|&i| depth_view(i)).collect();
    match (depth_view(v), train) {
        (Some(view), Some(train)) if scene.ndc.is_none() && !train.is_empty() && train.len() <= MAX_TRAINING_VIEWS => {
            Ok(Some(covisibility(rgb, &scene.views[v].image.data, view, &train, &CovisibilityParams::default())?))
        }
        _ => Ok(None),
    }
}

impl Evaluation {
    /// Means over `per_view`.
    pub fn new(per_view: Vec<ViewEvaluation>) -> Evaluation {
        let geo = || per_view.iter().filter_map(|e| e.geometry.as_ref());
        let depth = |f: fn(&Regions<DepthErrors>) -> Option<f64>| mean_of(geo().map(|g| g.depth.as_ref().and_then(f)));
        let normal = |f: fn(&Regions<NormalErrors>) -> Option<f64>| mean_of(geo().map(|g| g.normal.as_ref().and_then(f)));
        Evaluation {
            mean_psnr: mean_of(per_view.iter().map(|e| Some(e.psnr as f64))).unwrap_or(0.0),
            mean_ssim: mean_of(per_view.iter().map(|e| Some(e.ssim as f64))).unwrap_or(0.0),
            mean_samples_per_ray: mean_of(per_view.iter().map(|e| Some(e.samples_per_ray as f64))).unwrap_or(0.0),
            mean_depth_abs_error: depth(|d| d.all.map(|e| e.abs)),
            mean_depth_abs_error_non_edge: depth(|d| d.non_edge.map(|e| e.abs)),
            mean_depth_abs_error_edge: depth(|d| d.edge.map(|e| e.abs)),
            mean_depth_abs_rel: depth(|d| d.all.map(|e| e.abs_rel)),
            mean_normal_angle_deg: normal(|n| n.all.map(|e| e.mean_deg)),
            mean_normal_angle_deg_non_edge: normal(|n| n.non_edge.map(|e| e.mean_deg)),
            mean_normal_angle_deg_edge: normal(|n| n.edge.map(|e| e.mean_deg)),
            mean_dbe_accuracy: mean_of(geo().map(|g| g.boundary.as_ref().map(|b| b.accuracy))),
            mean_dbe_completeness: mean_of(geo().map(|g| g.boundary.as_ref().map(|b| b.completeness))),
            per_view,
        }
    }
}

/// Renders the test views of `scene` with `model` and measures each against its image
/// and ground truth.
pub fn evaluate(gpu: &Gpu, model: &mut Model, scene: &Scene) -> Result<(Evaluation, Vec<(usize, RenderedView)>), TrainError> {
    let mut per_view = Vec::new();
    let mut renders = Vec::new();
    for &v in &scene.split.test {
        let r = model.render_view(gpu, scene, v)?;
        per_view.push(evaluate_view(scene, v, &r)?);
        renders.push((v, r));
    }
    Ok((Evaluation::new(per_view), renders))
}
