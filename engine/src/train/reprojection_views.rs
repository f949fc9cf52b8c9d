//! The training views of a scene as the cross-view reprojection term reads them
//! ([`crate::loss::reprojection`]): each training view's pinhole camera and image,
//! optionally blurred, packed in the order of `scene.split.train`, with the scene's NDC
//! map when its rays are NDC rays.
//!
//! Invariants: only training views are packed (never a test view); the packed index of
//! a view is its position in `scene.split.train`, which is what the term's per-ray
//! source index means; a scene the term cannot project is an error that says what to
//! change, never a silently wrong term.

use crate::data::Scene;
use crate::edges::gaussian_blur;
use crate::loss::reprojection::{NdcMap, ReprojectionViews, ViewToPack};

/// Packs the training views of `scene`, each channel blurred by a Gaussian of `blur`
/// pixels (0: none). Errors (a message saying what to change) for distorted lenses,
/// views of fewer than 2x2 pixels and scenes loaded without images.
pub fn reprojection_views(scene: &Scene, blur: f32) -> Result<ReprojectionViews, String> {
    let mut blurred = Vec::new();
    for view in scene.train_views() {
        if !view.camera.lens.is_pinhole() {
            return Err(format!(
                "the reprojection term projects through pinhole cameras, and view {} has a distorted lens; undistort the images or set reg.lambda_reprojection = 0",
                view.name
            ));
        }
        let (w, h) = (view.image.width as usize, view.image.height as usize);
        if w < 2 || h < 2 || view.image.data.len() != w * h * 3 {
            return Err(format!("the reprojection term reads the training images, and view {} has none of at least 2x2 pixels", view.name));
        }
        let planes: Vec<Vec<f32>> =
            (0..3).map(|c| gaussian_blur(&view.image.data.iter().skip(c).step_by(3).copied().collect::<Vec<_>>(), w, h, blur)).collect();
        blurred.push((0..w * h).flat_map(|i| [planes[0][i], planes[1][i], planes[2][i]]).collect::<Vec<f32>>());
    }
    let views: Vec<ViewToPack<'_>> = scene
        .train_views()
        .zip(&blurred)
        .map(|(view, rgb)| {
            let (c, w2c) = (&view.camera, view.camera.w2c());
            ViewToPack {
                w2c: [0, 1, 2].map(|r| w2c.row(r).to_array()),
                fx: c.fx,
                fy: c.fy,
                cx: c.cx,
                cy: c.cy,
                width: view.image.width,
                height: view.image.height,
                rgb,
            }
        })
        .collect();
    let ndc = scene.ndc.map(|n| NdcMap { near: n.near, scale: [-n.width / (2.0 * n.focal_x), -n.height / (2.0 * n.focal_y)] });
    Ok(ReprojectionViews::pack(&views, ndc))
}

#[cfg(test)]
mod tests;
