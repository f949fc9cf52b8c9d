//! Novel-view camera paths for videos, from a scene's training cameras: NeRF/LLFF's
//! forward-facing spiral ([`spiral`]), an orbit around an object-centric scene
//! ([`orbit`]) and a smooth loop through the training poses ([`interpolate`]); and the
//! pose helpers they share with RegNeRF's random poses (`train::random_poses`):
//! [`look_at`] and [`average_pose`] (with the cameras' [`focus_point`] from `camera`).
//!
//! * **Spiral** (NeRF's `render_path_spiral`, RegNeRF's `generate_spiral_path`): around
//!   the average pose (mean centre, summed back and up axes), offsets
//!   `r * (cos t, -sin t, -sin(t / 2))` in its frame over 2 turns, `r` per axis the 90th
//!   percentile of the cameras' absolute offsets from their mean in that frame; every
//!   pose looks at the point `focus depth` ahead of the average pose on its axis, with the
//!   cameras' mean up vector. Focus depth: NeRF's `1 / (0.25 / (0.9 near) + 0.75 / (5 far))`
//!   ([`focus_depth`]) from the scene's depth bounds (LLFF: `poses_bounds.npy` in the
//!   loader's rescaled units; forward-facing COLMAP / nerfstudio captures: the closest
//!   bound only, as RegNeRF's random poses do); world scenes use the depth of the cameras' focus point
//!   along the average axis instead, since their near / far are loose ray ranges.
//! * **Orbit**: a circle around a centre (the training cameras' [`focus_point`] when it
//!   lies in the scene box, else the box centre) about the cameras' mean up vector, at
//!   their mean distance and mean elevation, starting at the first training camera's
//!   azimuth. Forward-facing (NDC) scenes are refused: nothing behind their cameras exists.
//! * **Interpolate**: a closed loop through the training poses in split order; positions on
//!   a uniform Catmull-Rom spline (through every key, continuous tangent), rotations by
//!   quaternion slerp. Key `j` is frame `round(j * frames / k)` exactly.
//!
//! Where we differ from NeRF: every path uses the *training* cameras only (a sparse-view
//! method must not see the test poses), as [`average_pose`] and the spiral's radii do.
//!
//! Invariants: every function is pure (cameras, bounds and frame count in, poses out); a
//! path of `n` frames has exactly `n` rigid OpenGL camera-to-world poses (rotation
//! orthonormal, determinant +1, looking down `-z`) and is a closed loop: frame `n` would
//! be frame 0 again, so a looping video has no jump. Path cameras share the first training
//! view's intrinsics.

use std::f32::consts::TAU;
use std::path::PathBuf;

use glam::{Mat3, Mat4, Quat, Vec3};

use super::camera::focus_point;
use super::{Camera, DataError, Scene, SceneFormat, quantile};

/// Turns of NeRF's spiral.
pub const SPIRAL_ROTATIONS: f32 = 2.0;
/// Oscillations of the spiral along the viewing axis per turn.
pub const SPIRAL_ZRATE: f32 = 0.5;
/// The percentile of the cameras' offsets that sets the spiral's radii.
pub const SPIRAL_PERCENTILE: f64 = 0.9;
/// NeRF's focus depth: the near bound pulled in, the far bound pushed out, and the
/// weight of the far bound in disparity space.
const NEAR_STRETCH: f32 = 0.9;
const FAR_STRETCH: f32 = 5.0;
const FOCUS_DISTANCE: f32 = 0.75;

/// Which camera path to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathKind {
    Spiral,
    Orbit,
    Interpolate,
}

impl PathKind {
    pub const ALL: [PathKind; 3] = [PathKind::Spiral, PathKind::Orbit, PathKind::Interpolate];

    pub fn name(self) -> &'static str {
        match self {
            PathKind::Spiral => "spiral",
            PathKind::Orbit => "orbit",
            PathKind::Interpolate => "interpolate",
        }
    }
}

impl std::str::FromStr for PathKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        PathKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| format!("unknown camera path {s:?} (spiral, orbit or interpolate)"))
    }
}

/// Why a camera path cannot be built for a scene.
#[derive(Debug, thiserror::Error)]
pub enum PathError {
    #[error("{root} has no training views to build a camera path from")]
    NoTrainingViews { root: PathBuf },
    #[error("a {kind} path through {views} training views needs at least {views} frames (one per view), not {frames}")]
    TooFewFrames { kind: &'static str, views: usize, frames: usize },
    #[error("a camera path needs at least 1 frame")]
    NoFrames,
    #[error(
        "an orbit circles an object-centric scene, but {root} is forward-facing (LLFF, NDC rays): \
         nothing behind its cameras was ever seen; use the spiral or interpolate path"
    )]
    ForwardFacing { root: PathBuf },
    #[error(transparent)]
    Data(#[from] DataError),
}

/// An OpenGL `c2w` at `position` whose `-z` axis points at `target`, `+y` towards `up`.
pub fn look_at(position: Vec3, target: Vec3, up: Vec3) -> Mat4 {
    let z = (position - target).normalize();
    let mut x = up.cross(z);
    if x.length() < 1e-6 {
        // Looking along `up`: any perpendicular will do.
        x = z.any_orthonormal_vector().cross(z);
    }
    let x = x.normalize();
    let y = z.cross(x);
    Mat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), position.extend(1.0))
}

/// Mean position, rotation of the average pose (NeRF's `poses_avg`: mean back axis and
/// mean up), and the unit mean up vector.
pub fn average_pose(cameras: &[Camera]) -> (Vec3, Mat3, Vec3) {
    let n = cameras.len().max(1) as f32;
    let mean = cameras.iter().map(|c| c.origin()).sum::<Vec3>() / n;
    let back = cameras.iter().map(|c| -c.forward()).sum::<Vec3>() / n;
    let up = (cameras.iter().map(|c| c.c2w.y_axis.truncate()).sum::<Vec3>() / n).normalize();
    let rot = Mat3::from_mat4(look_at(mean, mean - back, up));
    (mean, rot, up)
}

/// NeRF's focus depth for depth bounds `near..far` (world units; `far` may be
/// infinite): `1 / ((1 - 0.75) / (0.9 near) + 0.75 / (5 far))`, a weighted mean in
/// disparity of a pulled-in near and a pushed-out far bound.
pub fn focus_depth(near: f32, far: f32) -> f32 {
    1.0 / ((1.0 - FOCUS_DISTANCE) / (NEAR_STRETCH * near) + FOCUS_DISTANCE / (FAR_STRETCH * far))
}

/// The spiral's radii: per axis of the frame `rot` (centred on `centre`), the
/// [`SPIRAL_PERCENTILE`] of the cameras' absolute offsets.
pub fn spiral_radii(cameras: &[Camera], centre: Vec3, rot: Mat3) -> Vec3 {
    let offsets: Vec<Vec3> = cameras.iter().map(|c| (rot.transpose() * (c.origin() - centre)).abs()).collect();
    let percentile = |axis: usize| {
        let mut v: Vec<f64> = offsets.iter().map(|o| o[axis] as f64).collect();
        quantile(&mut v, SPIRAL_PERCENTILE).unwrap_or(0.0) as f32
    };
    Vec3::new(percentile(0), percentile(1), percentile(2))
}

/// NeRF's spiral of `frames` poses around the cameras' [`average_pose`], looking at the
/// point `focus_depth` ahead of it (module doc).
pub fn spiral(cameras: &[Camera], focus_depth: f32, frames: usize) -> Vec<Mat4> {
    let (centre, rot, up) = average_pose(cameras);
    let radii = spiral_radii(cameras, centre, rot);
    let target = centre + rot * Vec3::new(0.0, 0.0, -focus_depth);
    (0..frames)
        .map(|i| {
            let t = TAU * SPIRAL_ROTATIONS * i as f32 / frames as f32;
            let offset = radii * Vec3::new(t.cos(), -t.sin(), -(t * SPIRAL_ZRATE).sin());
            look_at(centre + rot * offset, target, up)
        })
        .collect()
}

/// A circle of `frames` poses around `centre` looking at it (module doc): about the
/// cameras' mean up vector, at their mean distance from `centre` and mean elevation,
/// from the first camera's azimuth.
pub fn orbit(cameras: &[Camera], centre: Vec3, frames: usize) -> Vec<Mat4> {
    let (_, _, up) = average_pose(cameras);
    let n = cameras.len().max(1) as f32;
    let (mut radius, mut elevation) = (0.0, 0.0);
    for c in cameras {
        let d = c.origin() - centre;
        let height = d.dot(up);
        radius += d.length() / n;
        elevation += height.atan2((d - height * up).length()) / n;
    }
    let d0 = cameras.first().map_or(Vec3::ZERO, |c| c.origin() - centre);
    let a = (d0 - d0.dot(up) * up).try_normalize().unwrap_or_else(|| up.any_orthonormal_vector());
    let b = up.cross(a);
    (0..frames)
        .map(|i| {
            let phi = TAU * i as f32 / frames as f32;
            let dir = elevation.cos() * (phi.cos() * a + phi.sin() * b) + elevation.sin() * up;
            look_at(centre + radius * dir, centre, up)
        })
        .collect()
}

/// The closed loop through `poses` at parameter `s` (module doc): key `j` at `s = j`,
/// `s` taken modulo `poses.len()`. Continuous in `s`.
pub fn interpolate_at(poses: &[Mat4], s: f32) -> Mat4 {
    let k = poses.len();
    assert!(k > 0, "interpolation needs at least one pose");
    let s = s.rem_euclid(k as f32);
    let j = (s.floor() as usize).min(k - 1);
    let t = s - j as f32;
    let pose = |i: isize| poses[i.rem_euclid(k as isize) as usize];
    let p = |i: isize| pose(i).w_axis.truncate();
    let j = j as isize;
    let (p0, p1, p2, p3) = (p(j - 1), p(j), p(j + 1), p(j + 2));
    // Uniform Catmull-Rom: through p1 at t = 0 and p2 at t = 1, tangents (p2 - p0) / 2.
    let position = 0.5
        * (2.0 * p1
            + (p2 - p0) * t
            + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * (t * t)
            + (3.0 * p1 - p0 - 3.0 * p2 + p3) * (t * t * t));
    let q = |i: isize| Quat::from_mat3(&Mat3::from_mat4(pose(i))).normalize();
    let rotation = q(j).slerp(q(j + 1), t).normalize();
    Mat4::from_rotation_translation(rotation, position)
}

/// `frames` poses along the closed loop through `poses` ([`interpolate_at`]); key `j`
/// is frame `round(j * frames / k)`, and the frames between two keys are evenly spaced
/// in the spline's parameter. Needs `frames >= poses.len()` to hit every key.
pub fn interpolate(poses: &[Mat4], frames: usize) -> Vec<Mat4> {
    let k = poses.len();
    let key = |j: usize| (j * frames + k / 2) / k;
    let mut out = Vec::with_capacity(frames);
    for j in 0..k {
        let (start, end) = (key(j), key(j + 1));
        for f in start..end {
            out.push(interpolate_at(poses, j as f32 + (f - start) as f32 / (end - start) as f32));
        }
    }
    out
}

/// The depth the spiral of `scene` focuses at (module doc): NeRF's [`focus_depth`] of
/// the LLFF bounds (of the closest bound alone for other forward-facing captures, whose
/// bounds the scene does not keep), or for world scenes the depth of the cameras' focus point along
/// their average axis (NeRF's formula on the scene's near / far when that point is not
/// in front of them).
pub fn spiral_focus_depth(scene: &Scene, cameras: &[Camera]) -> Result<f32, PathError> {
    if scene.format == SceneFormat::Llff {
        let [near, far] = super::llff::world_bounds(&scene.root)?;
        return Ok(focus_depth(near, far));
    }
    if let Some(ndc) = scene.ndc {
        // A forward-facing COLMAP / nerfstudio capture: its bounds are not kept, but the
        // closest one sits at `1 / BD_FACTOR` after the rescaling; the far term drops.
        return Ok(focus_depth(ndc.near / super::llff::BD_FACTOR as f32, f32::INFINITY));
    }
    let (centre, rot, _) = average_pose(cameras);
    let depth = (focus_point(cameras) - centre).dot(-rot.z_axis);
    Ok(if depth > 1e-3 { depth } else { focus_depth(scene.near.max(1e-3), scene.far) })
}

/// The centre an orbit of `scene` circles: the cameras' [`focus_point`] when it lies in
/// the scene box, else the box centre.
pub fn orbit_centre(scene: &Scene, cameras: &[Camera]) -> Vec3 {
    let focus = focus_point(cameras);
    let [lo, hi] = scene.aabb;
    if (focus.cmpge(lo) & focus.cmple(hi)).all() { focus } else { 0.5 * (lo + hi) }
}

/// The `frames` cameras of path `kind` through `scene` (module doc), built from its
/// training cameras, with the first training view's intrinsics.
pub fn camera_path(scene: &Scene, kind: PathKind, frames: usize) -> Result<Vec<Camera>, PathError> {
    let cams: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
    let first = *cams.first().ok_or_else(|| PathError::NoTrainingViews { root: scene.root.clone() })?;
    if frames == 0 {
        return Err(PathError::NoFrames);
    }
    let poses = match kind {
        PathKind::Spiral => spiral(&cams, spiral_focus_depth(scene, &cams)?, frames),
        PathKind::Orbit => {
            if scene.ndc.is_some() {
                return Err(PathError::ForwardFacing { root: scene.root.clone() });
            }
            orbit(&cams, orbit_centre(scene, &cams), frames)
        }
        PathKind::Interpolate => {
            if frames < cams.len() {
                return Err(PathError::TooFewFrames { kind: kind.name(), views: cams.len(), frames });
            }
            interpolate(&cams.iter().map(|c| c.c2w).collect::<Vec<_>>(), frames)
        }
    };
    Ok(poses.into_iter().map(|c2w| Camera { c2w, ..first }).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::LoadOptions;

    const EPS: f32 = 1e-4;

    fn camera(c2w: Mat4) -> Camera {
        Camera { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0, c2w, lens: Default::default() }
    }

    /// Rigid, OpenGL: orthonormal rotation with determinant +1, bottom row `0 0 0 1`.
    fn assert_rigid(m: &Mat4) {
        crate::data::camera::check_rigid(m).unwrap();
        let r = Mat3::from_mat4(*m);
        assert!((r.transpose() * r).abs_diff_eq(Mat3::IDENTITY, 1e-5), "{r}");
        assert!((r.determinant() - 1.0).abs() < 1e-5);
    }

    /// The optical axis of `m` passes through `target` (and looks towards it).
    fn assert_looks_at(m: &Mat4, target: Vec3) {
        let cam = camera(*m);
        let to = (target - cam.origin()).normalize();
        assert!(cam.forward().dot(to) > 1.0 - 1e-6, "axis {} vs direction to target {to}", cam.forward());
    }

    fn creases() -> Scene {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/creases");
        Scene::load(dir, &LoadOptions { views: Some(3), load_images: false, ..Default::default() }).unwrap()
    }

    #[test]
    fn look_at_and_focus_point() {
        let m = look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y);
        assert!((m.z_axis.truncate() - Vec3::Z).length() < 1e-6 && (m.y_axis.truncate() - Vec3::Y).length() < 1e-6);
        let cam = |p: Vec3| camera(look_at(p, Vec3::new(1.0, 2.0, 3.0), Vec3::Z));
        let f = focus_point(&[cam(Vec3::new(5.0, 0.0, 3.0)), cam(Vec3::new(0.0, 6.0, 4.0)), cam(Vec3::new(-3.0, -2.0, 6.0))]);
        assert!((f - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-3, "{f}");
        // Looking straight along `up` still gives a rigid pose.
        let m = look_at(Vec3::new(0.0, 5.0, 0.0), Vec3::ZERO, Vec3::Y);
        assert_rigid(&m);
        assert_looks_at(&m, Vec3::ZERO);
    }

    #[test]
    fn focus_depth_is_nerfs_weighted_disparity() {
        // fern: bounds 16.985 .. 80.002 in poses_bounds.npy, rescaled so the near one is 1 / 0.75.
        let far = 80.002_097_f32 / 16.985_296 / 0.75;
        assert!((focus_depth(1.0 / 0.75, far) - 4.306_293).abs() < 1e-4, "{}", focus_depth(1.0 / 0.75, far));
        // An infinite far bound leaves the near term: 0.9 near / 0.25.
        assert!((focus_depth(2.0, f32::INFINITY) - 7.2).abs() < 1e-5);
    }

    /// Five cameras facing `-z` (identity rotation) around `centre` with known offsets.
    fn forward_rig(centre: Vec3) -> Vec<Camera> {
        let x = [-4.0, -1.0, 0.0, 2.0, 3.0];
        let y = [-0.5, 0.5, 0.0, -1.0, 1.0];
        let z = [0.1, -0.1, 0.2, -0.2, 0.0];
        (0..5).map(|i| camera(Mat4::from_translation(centre + Vec3::new(x[i], y[i], z[i])))).collect()
    }

    #[test]
    fn spiral_radii_are_percentiles_of_the_camera_offsets() {
        let centre = Vec3::new(0.5, -1.0, 2.0);
        let cams = forward_rig(centre);
        let (mean, rot, up) = average_pose(&cams);
        assert!((mean - centre).length() < 1e-6 && rot.abs_diff_eq(Mat3::IDENTITY, 1e-6) && (up - Vec3::Y).length() < 1e-6);
        // |x| = 0 1 2 3 4 -> numpy.percentile(.., 90) = 3.6; |y| = 0 .5 .5 1 1 -> 1; |z| -> 0.2.
        let r = spiral_radii(&cams, mean, rot);
        assert!((r - Vec3::new(3.6, 1.0, 0.2)).length() < 1e-5, "{r}");
    }

    #[test]
    fn spiral_circles_the_average_pose_looking_at_the_focus() {
        let centre = Vec3::new(0.5, -1.0, 2.0);
        let cams = forward_rig(centre);
        let target = centre - 5.0 * Vec3::Z;
        let path = spiral(&cams, 5.0, 16);
        assert_eq!(path.len(), 16);
        for m in &path {
            assert_rigid(m);
            assert_looks_at(m, target);
        }
        // t = 0: offset (rx, 0, 0); t = pi / 2 (frame 16 / 8): (0, -ry, -sin(pi / 4) rz).
        let pos = |i: usize| path[i].w_axis.truncate();
        assert!((pos(0) - (centre + Vec3::new(3.6, 0.0, 0.0))).length() < EPS, "{}", pos(0));
        let expected = centre + Vec3::new(0.0, -1.0, -(std::f32::consts::FRAC_PI_4).sin() * 0.2);
        assert!((pos(2) - expected).length() < EPS, "{}", pos(2));
        // Two turns: one turn apart, the same point across the axis, the z oscillation opposite.
        let (a, b) = (pos(4) - centre, pos(12) - centre);
        assert!((a - Vec3::new(-3.6, 0.0, -0.2)).length() < EPS && (b - Vec3::new(-3.6, 0.0, 0.2)).length() < EPS, "{a} {b}");
        // A closed loop: the sampling does not depend on the frame count, and the step from
        // the last frame back to the first is one ordinary step.
        let fine = spiral(&cams, 5.0, 32);
        assert!(path.iter().enumerate().all(|(i, m)| m.abs_diff_eq(fine[2 * i], 1e-5)));
        let steps: Vec<f32> = (0..16).map(|i| pos(i).distance(pos((i + 1) % 16))).collect();
        let max = steps.iter().cloned().fold(0.0, f32::max);
        assert!(steps[15] > 0.0 && steps[15] <= max + 1e-6, "{steps:?}");
    }

    /// Three cameras at distance 4 and elevation 30 degrees around `centre`, evenly spread
    /// in azimuth from 10 degrees (so their mean up vector is `+z`).
    fn ring(centre: Vec3) -> Vec<Camera> {
        let e = 30f32.to_radians();
        [10f32, 130.0, 250.0]
            .iter()
            .map(|az| {
                let az = az.to_radians();
                let p = centre + 4.0 * Vec3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin());
                camera(look_at(p, centre, Vec3::Z))
            })
            .collect()
    }

    #[test]
    fn orbit_keeps_the_cameras_distance_and_elevation() {
        let centre = Vec3::new(1.0, 2.0, 3.0);
        let cams = ring(centre);
        assert!((focus_point(&cams) - centre).length() < 1e-4);
        let path = orbit(&cams, centre, 24);
        assert_eq!(path.len(), 24);
        for (i, m) in path.iter().enumerate() {
            assert_rigid(m);
            assert_looks_at(m, centre);
            let d = m.w_axis.truncate() - centre;
            assert!((d.length() - 4.0).abs() < EPS, "radius {}", d.length());
            assert!((d.z / 4.0 - 0.5).abs() < EPS, "elevation sin {}", d.z / 4.0);
            // Up stays up: the camera's x axis is horizontal.
            assert!(m.x_axis.z.abs() < 1e-5);
            // 15 degrees of azimuth per frame, from the first camera's 10 degrees.
            let az = d.y.atan2(d.x).to_degrees();
            let want = 10.0 + 15.0 * i as f32;
            let diff = (az - want).rem_euclid(360.0);
            assert!(diff < 1e-2 || diff > 360.0 - 1e-2, "frame {i}: azimuth {az} vs {want}");
        }
        assert!(path[0].abs_diff_eq(cams[0].c2w, 1e-4), "starts at the first camera");
    }

    /// Four poses looking at different points from different places.
    fn key_poses() -> Vec<Mat4> {
        [
            (Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO),
            (Vec3::new(3.0, 1.0, 3.0), Vec3::new(0.2, 0.0, 0.0)),
            (Vec3::new(4.0, -1.0, 0.0), Vec3::new(0.0, 0.3, -0.1)),
            (Vec3::new(1.0, 2.0, -3.5), Vec3::ZERO),
        ]
        .iter()
        .map(|&(p, t)| look_at(p, t, Vec3::Y))
        .collect()
    }

    #[test]
    fn interpolation_passes_through_the_keys_and_is_continuous() {
        let keys = key_poses();
        for (frames, at) in [(12, [0, 3, 6, 9]), (10, [0, 3, 5, 8])] {
            let path = interpolate(&keys, frames);
            assert_eq!(path.len(), frames);
            for (j, &f) in at.iter().enumerate() {
                assert!(path[f].abs_diff_eq(keys[j], 1e-5), "{frames} frames: frame {f} is key {j}\n{}\n{}", path[f], keys[j]);
            }
            path.iter().for_each(assert_rigid);
        }
        // Continuous across every key (and around the loop), in position and rotation.
        for j in 0..4 {
            for s in [j as f32 - 1e-3, j as f32 + 1e-3] {
                let (a, b) = (interpolate_at(&keys, s), keys[j]);
                assert!(a.w_axis.truncate().distance(b.w_axis.truncate()) < 0.02, "position jump at key {j}");
                let qa = Quat::from_mat4(&a);
                assert!(qa.angle_between(Quat::from_mat4(&b)) < 0.01, "rotation jump at key {j}");
            }
        }
        // Dense sampling: no step is far longer than the mean (no jumps, no stalls).
        let path = interpolate(&keys, 400);
        let steps: Vec<f32> = (0..400).map(|i| path[i].w_axis.distance(path[(i + 1) % 400].w_axis)).collect();
        let mean = steps.iter().sum::<f32>() / 400.0;
        assert!(steps.iter().all(|&s| s < 2.5 * mean && s > 0.0), "mean {mean}, max {}", steps.iter().cloned().fold(0.0, f32::max));
        let turn = (0..400).map(|i| Quat::from_mat4(&path[i]).angle_between(Quat::from_mat4(&path[(i + 1) % 400]))).fold(0.0, f32::max);
        assert!(turn < 3f32.to_radians(), "largest turn between frames {} deg", turn.to_degrees());
    }

    #[test]
    fn scene_paths_use_the_training_cameras() {
        let scene = creases();
        let cams: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
        let first = cams[0];
        for kind in PathKind::ALL {
            let path = camera_path(&scene, kind, 9).unwrap();
            assert_eq!(path.len(), 9, "{kind:?}");
            for c in &path {
                assert_eq!((c.width, c.height, c.fx, c.fy, c.cx, c.cy), (first.width, first.height, first.fx, first.fy, first.cx, first.cy));
                assert_rigid(&c.c2w);
                assert!(c.check().is_ok());
            }
            assert_eq!(kind.name().parse::<PathKind>().unwrap(), kind);
        }
        // The orbit circles the focus of the cameras (inside the box) at their mean distance.
        let centre = orbit_centre(&scene, &cams);
        assert!((centre - focus_point(&cams)).length() < 1e-6);
        let mean_dist = cams.iter().map(|c| c.origin().distance(centre)).sum::<f32>() / 3.0;
        for c in camera_path(&scene, PathKind::Orbit, 8).unwrap() {
            assert_looks_at(&c.c2w, centre);
            assert!((c.origin().distance(centre) - mean_dist).abs() < 1e-3);
        }
        // The spiral looks at the focus point's depth on the average axis.
        let (mean, rot, _) = average_pose(&cams);
        let depth = spiral_focus_depth(&scene, &cams).unwrap();
        let target = mean + rot * Vec3::new(0.0, 0.0, -depth);
        assert!(depth > 0.0 && (target - focus_point(&cams)).length() < 0.5 * depth, "depth {depth}");
        camera_path(&scene, PathKind::Spiral, 8).unwrap().iter().for_each(|c| assert_looks_at(&c.c2w, target));
        // Interpolation hits the training poses.
        let path = camera_path(&scene, PathKind::Interpolate, 6).unwrap();
        for (j, f) in [0, 2, 4].into_iter().enumerate() {
            assert!(path[f].c2w.abs_diff_eq(cams[j].c2w, 1e-4), "frame {f} vs training view {j}");
        }
        // Bad requests.
        assert!(matches!(camera_path(&scene, PathKind::Interpolate, 2), Err(PathError::TooFewFrames { views: 3, frames: 2, .. })));
        assert!(matches!(camera_path(&scene, PathKind::Spiral, 0), Err(PathError::NoFrames)));
        let mut ndc = scene.clone();
        ndc.ndc = Some(crate::data::NdcParams { focal_x: 60.0, focal_y: 60.0, width: 64.0, height: 48.0, near: 1.0 });
        let e = camera_path(&ndc, PathKind::Orbit, 8).unwrap_err();
        assert!(e.to_string().contains("spiral or interpolate"), "{e}");
        // A forward-facing capture that is not LLFF keeps no bounds: the closest one alone.
        assert!((spiral_focus_depth(&ndc, &cams).unwrap() - 4.8).abs() < 1e-5);
        let mut empty = scene.clone();
        empty.split.train.clear();
        assert!(matches!(camera_path(&empty, PathKind::Spiral, 8), Err(PathError::NoTrainingViews { .. })));
        assert!("circle".parse::<PathKind>().unwrap_err().contains("spiral, orbit or interpolate"));
    }

    #[test]
    fn llff_spiral_on_fern_when_available() {
        let Some(dir) = crate::data::real_scene_dir("llff/fern") else { return };
        let scene = Scene::load(dir, &LoadOptions { views: Some(3), load_images: false, ..Default::default() }).unwrap();
        let [near, far] = crate::data::llff::world_bounds(&scene.root).unwrap();
        assert!((near - 1.0 / 0.75).abs() < 1e-5 && (far - 6.2803).abs() < 1e-3, "{near} {far}");
        let cams: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
        assert!((spiral_focus_depth(&scene, &cams).unwrap() - 4.3063).abs() < 1e-3);
        let ndc = scene.ndc.unwrap();
        for c in camera_path(&scene, PathKind::Spiral, 12).unwrap() {
            // Every pixel's NDC ray is finite (the cameras look down -z, past the near plane).
            for (px, py) in [(0.5, 0.5), (c.cx, c.cy), (c.width as f32 - 0.5, c.height as f32 - 0.5)] {
                let r = ndc.ray_to_ndc(c.pixel_ray(px, py));
                assert!(r.origin.is_finite() && r.dir.is_finite(), "{r:?}");
            }
        }
    }
}
