//! Scene bounds of captures that do not state them (COLMAP models, nerfstudio's
//! `transforms.json`): whether rays go to NDC, near / far and the box the field covers.
//!
//! The rule, applied by [`finish_capture`] to the cameras (all views) and the sparse 3D
//! points (COLMAP's `points3D`, in the cameras' world frame) of a capture:
//!
//! * **Forward-facing** when every camera's optical axis lies within
//!   [`FORWARD_FACING_MAX_DEG`] of the mean axis (an LLFF-style sweep; LLFF's scenes stay
//!   within about 15 degrees). Handled exactly as an LLFF scene: each view's depth range
//!   is the 0.1 and 99.9 percentiles of the z-depths of the points it sees (what LLFF's
//!   `imgs2poses` writes to `poses_bounds.npy`), the poses are rescaled so the closest
//!   bound sits at 1 / 0.75 and recentred on their average ([`super::llff`]), and rays go
//!   to NDC (near 0). Without points the file's `near` key is the closest bound; without
//!   either it is an error. Rays end at infinity (NDC 1), or with
//!   [`super::LoadOptions::ndc_far_bound`] at 1.1 times the farthest content
//!   ([`super::llff::ndc_far`]): the largest per-view far bound (the 99.9-percentile
//!   z-depth, as `imgs2poses` writes it), else the file's `far` key, else still at
//!   infinity.
//! * **Object-centric** otherwise: world rays in the capture's own frame and units (no
//!   rescaling, so a COLMAP or nerfstudio export of a scene gives the rays the scene's
//!   other formats give). With points: near = 0.9 x the smallest per-view 0.1-percentile
//!   z-depth, far = 1.1 x the largest per-view 99.9-percentile distance, and the box is
//!   the 0.5-99.5 percentile box of the points (per axis), padded by 5 % of its size on
//!   each side. Without points: the box is a cube centred on the point nearest to all
//!   optical axes ([`super::camera::focus_point`]) of half side `h`, what the cameras
//!   frame there (the median over the cameras of `distance x tan(half field of view)`,
//!   narrower axis: [`framed_half_size`]), near = `0.05 r` and far = `r + sqrt(3) h`
//!   with `r` the mean camera distance from the focus. (A box reaching the cameras, as
//!   nerfstudio's, let a capture without alpha fill it with fog that looks like the
//!   backdrop from every training view: docs/results/real-captures.md.) Explicit
//!   `near` / `far` / `aabb` keys (nerfstudio files) win.
//!
//! Invariants: `0 <= near < far`, finite; `aabb` min < max; a forward-facing scene's
//! ground-truth depth (nerfstudio `depth_file_path`) is rescaled with its poses.

use std::path::Path;

use glam::{DMat4, Vec3};

use super::camera::{facing_one_way, focus_point};
use super::llff::{ndc_scene, normalize_forward_facing};
use super::{Camera, DataError, Scene, SceneFormat, Split, View};

/// Largest angle (degrees) between a camera's axis and the mean axis of a capture
/// treated as forward-facing.
pub const FORWARD_FACING_MAX_DEG: f32 = 30.0;
/// Points used for the bounds at most (a regular subsample of larger models).
const MAX_POINTS: usize = 20_000;

/// A capture as a loader read it: views with world cameras, the split, optional sparse
/// points (same world frame) and the bounds the file states, if any.
pub(super) struct Capture {
    pub views: Vec<View>,
    pub split: Split,
    pub points: Vec<Vec3>,
    /// The file's own `near` and `far`, each optional.
    pub near_far: [Option<f32>; 2],
    pub aabb: Option<[Vec3; 2]>,
    pub background: Option<[f32; 3]>,
}

/// NumPy's `percentile` (linear interpolation) of sorted values, `q` in `[0, 100]`.
fn percentile(sorted: &[f32], q: f64) -> f32 {
    let pos = q / 100.0 * (sorted.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, (pos - pos.floor()) as f32);
    let next = sorted[(i + 1).min(sorted.len() - 1)];
    sorted[i] + (next - sorted[i]) * frac
}

fn sorted(mut v: Vec<f32>) -> Vec<f32> {
    v.sort_by(f32::total_cmp);
    v
}

/// The depths of the points one view sees.
#[derive(Clone, Copy)]
struct ViewRange {
    /// 0.1-percentile z-depth (LLFF's near bound).
    z_near: f32,
    /// 99.9-percentile z-depth (LLFF's far bound).
    z_far: f32,
    /// 99.9-percentile distance from the camera.
    distance_far: f32,
}

/// Per view, the depths of the points that project into its frame; `None` for a view
/// that sees none.
fn view_ranges(cameras: &[Camera], points: &[Vec3]) -> Vec<Option<ViewRange>> {
    let stride = points.len().div_ceil(MAX_POINTS).max(1);
    cameras
        .iter()
        .map(|cam| {
            let w2c = cam.w2c();
            let (mut z, mut dist) = (Vec::new(), Vec::new());
            for p in points.iter().step_by(stride) {
                if let Some((px, depth)) = cam.project_with(&w2c, *p)
                    && cam.in_frame(px)
                {
                    z.push(depth);
                    dist.push(p.distance(cam.origin()));
                }
            }
            (!z.is_empty()).then(|| {
                let z = sorted(z);
                ViewRange { z_near: percentile(&z, 0.1), z_far: percentile(&z, 99.9), distance_far: percentile(&sorted(dist), 99.9) }
            })
        })
        .collect()
}

/// Half the side of the box of an object-centric capture without points: what the
/// cameras frame around their common focus `centre`. Each camera frames, at the
/// focus, a half-width of `distance * tan(half field of view)` along its narrower image
/// axis; the median over the cameras is taken (a close-up or a wide shot does not
/// decide alone), so the object a capture photographs from all around fits, and what
/// lies beyond it (a backdrop, a room) is left to the learned background rather than
/// to fog inside a box that reaches the cameras.
fn framed_half_size(cameras: &[Camera], centre: Vec3) -> f32 {
    let half = sorted(
        cameras
            .iter()
            .map(|c| {
                let tan = (c.width as f32 / (2.0 * c.fx)).min(c.height as f32 / (2.0 * c.fy));
                c.origin().distance(centre) * tan
            })
            .collect(),
    );
    percentile(&half, 50.0)
}

/// The 0.5-99.5 percentile box of `points`, padded by 5 % of its size per side.
fn point_box(points: &[Vec3]) -> [Vec3; 2] {
    let axis = |a: usize| sorted(points.iter().map(|p| p[a]).collect());
    let (x, y, z) = (axis(0), axis(1), axis(2));
    let lo = Vec3::new(percentile(&x, 0.5), percentile(&y, 0.5), percentile(&z, 0.5));
    let hi = Vec3::new(percentile(&x, 99.5), percentile(&y, 99.5), percentile(&z, 99.5));
    let pad = ((hi - lo) * 0.05).max(Vec3::splat(1e-3 * (hi - lo).max_element().max(1e-6)));
    [lo - pad, hi + pad]
}

/// View names are file stems; when two collide (`train/r_000.png`, `test/r_000.png`),
/// every view is named by its path under the folder all images share, without
/// extension, `/` as `_` (`train_r_000`), so renders and edge maps do not overwrite
/// each other.
fn unique_names(root: &Path, views: &mut [View]) {
    let mut seen = std::collections::HashSet::new();
    if views.iter().all(|v| seen.insert(v.name.clone())) {
        return;
    }
    let mut common = views[0].path.parent().unwrap_or(root).to_path_buf();
    while !views.iter().all(|v| v.path.starts_with(&common)) && common.pop() {}
    for v in views {
        let rel = v.path.strip_prefix(&common).unwrap_or(&v.path).with_extension("");
        v.name = rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("_");
    }
}

/// The scene of a capture under the module doc's rule; `source` (the camera file) is
/// named in errors.
pub(super) fn finish_capture(root: &Path, format: SceneFormat, source: &Path, capture: Capture) -> Result<Scene, DataError> {
    let Capture { mut views, split, points, near_far, aabb, background } = capture;
    unique_names(root, &mut views);
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera).collect();
    let ranges = view_ranges(&cameras, &points);
    let seen: Vec<ViewRange> = ranges.iter().flatten().copied().collect();

    if facing_one_way(&cameras, FORWARD_FACING_MAX_DEG) {
        let min_near = match (seen.iter().map(|r| r.z_near).reduce(f32::min), near_far[0]) {
            (Some(z), _) => z,
            (None, Some(near)) => near,
            (None, None) => {
                return Err(DataError::invalid(
                    source,
                    format!(
                        "the cameras face one way (a forward-facing capture, every axis within {FORWARD_FACING_MAX_DEG} deg of \
                         their mean), which is trained in NDC and needs the depth of the closest content, but there are no 3D \
                         points in front of the cameras; keep the COLMAP model's points3D (nerfstudio: colmap/sparse/0 beside \
                         transforms.json) or add a top-level \"near\" key (closest scene depth, in the poses' units)"
                    ),
                ));
            }
        };
        if !(min_near.is_finite() && min_near > 0.0) {
            return Err(DataError::invalid(source, format!("the closest scene depth {min_near} must be positive and finite")));
        }
        let far_depth = seen.iter().map(|r| r.z_far).reduce(f32::max).or(near_far[1]);
        let c2w: Vec<DMat4> = cameras.iter().map(|c| c.c2w.as_dmat4()).collect();
        let (poses, sc) = normalize_forward_facing(&c2w, f64::from(min_near));
        for (view, pose) in views.iter_mut().zip(&poses) {
            view.camera.c2w = pose.as_mat4();
            view.camera.check().map_err(|m| DataError::NonFinite {
                path: source.to_path_buf(),
                what: format!("view {} after rescaling by {sc} (closest depth {min_near}) and recentring: {m}", view.name),
            })?;
            if let Some(depth) = view.depth.as_mut() {
                depth.iter_mut().for_each(|d| *d *= sc as f32);
            }
        }
        return Ok(ndc_scene(root, format, views, split, far_depth.map(|d| f64::from(d) * sc)));
    }

    let (near, far, aabb) = if seen.is_empty() {
        let centre = focus_point(&cameras);
        let r = cameras.iter().map(|c| c.origin().distance(centre)).sum::<f32>() / cameras.len().max(1) as f32;
        let h = framed_half_size(&cameras, centre);
        let near = near_far[0].unwrap_or(0.05 * r);
        let far = near_far[1].unwrap_or(r + 3f32.sqrt() * h);
        (near, far, aabb.unwrap_or([centre - Vec3::splat(h), centre + Vec3::splat(h)]))
    } else {
        let near = near_far[0].unwrap_or(0.9 * seen.iter().map(|r| r.z_near).fold(f32::INFINITY, f32::min));
        let far = near_far[1].unwrap_or(1.1 * seen.iter().map(|r| r.distance_far).fold(0.0, f32::max));
        (near, far, aabb.unwrap_or_else(|| point_box(&points)))
    };
    if !(near.is_finite() && far.is_finite() && 0.0 <= near && near < far) {
        return Err(DataError::invalid(source, format!("near {near} / far {far}: need 0 <= near < far (check the poses and points)")));
    }
    if !(aabb[0].is_finite() && aabb[1].is_finite() && aabb[0].cmplt(aabb[1]).all()) {
        return Err(DataError::invalid(
            source,
            format!("scene box {:?} .. {:?}: need finite min < max (check the poses and points)", aabb[0], aabb[1]),
        ));
    }
    Ok(Scene { root: root.to_path_buf(), format, views, split, near, far, ndc: None, aabb, background })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_match_numpy() {
        let v: Vec<f32> = (0..11).map(|i| i as f32).collect();
        // np.percentile(np.arange(11), [0.1, 50, 99.9]) = [0.01, 5, 9.99]
        assert!((percentile(&v, 0.1) - 0.01).abs() < 1e-6);
        assert_eq!(percentile(&v, 50.0), 5.0);
        assert!((percentile(&v, 99.9) - 9.99).abs() < 1e-5);
        assert_eq!(percentile(&[3.0], 99.9), 3.0);
        // Two points: percentiles 0.005 / 0.995, padded by 5 % of 0.99.
        let b = point_box(&[Vec3::ZERO, Vec3::ONE]);
        assert!((b[0] - Vec3::splat(0.005 - 0.0495)).abs().max_element() < 1e-5, "{b:?}");
        assert!((b[1] - Vec3::splat(0.995 + 0.0495)).abs().max_element() < 1e-5, "{b:?}");
    }
}
