//! Random unobserved camera poses near the training cameras, for RegNeRF's depth
//! smoothness term (patches rendered from views no image constrains): a pool generated
//! once per run from the training cameras, and the 8x8 patch rays drawn from it each step.
//!
//! Follows RegNeRF's `_generate_random_poses` (google-research/regnerf,
//! `internal/datasets.py`), one generator per scene type ([`PoseKind`]):
//! * [`PoseKind::Llff`] (forward-facing, NDC): positions uniform in the box
//!   `mean + R_avg (r * (2u - 1))`, `r` the largest per-axis offset of the cameras from
//!   their mean in the average camera frame (RegNeRF: the 100th percentile of the
//!   recentred positions); every pose looks at the point at the focus depth on the
//!   average camera's axis, with the average up vector. Focus depth: RegNeRF's
//!   `1 / ((1 - 0.75) / close + 0.75 / inf)` with `close = 0.9 min_bound`
//!   ([`focus_depth`]); the scene keeps no bounds, so `min_bound = near / 0.75` (the
//!   rescaling makes it so) and the `inf = 5 max_bound` term is dropped (11 % on fern):
//!   `4 * 0.9 near / 0.75`. (The video spiral of `data::paths` re-reads the bounds.)
//! * [`PoseKind::Box`] (DTU): positions in the same box; each pose looks at the focus
//!   point (the point nearest to all training optical axes, RegNeRF's `focus_pt_fn`)
//!   jittered by a normal of sigma `0.125 s`, where `s` is the box's largest half-extent
//!   (RegNeRF's 0.125 is in DTU units, scaled so the largest camera coordinate is 1).
//! * [`PoseKind::Sphere`] (object-centric Blender scenes; RegNeRF's `renderpath` poses
//!   for NeRF-synthetic): positions uniform on the hemisphere of radius `mean camera
//!   distance` around the focus point, on the side of the cameras' mean up vector
//!   (RegNeRF: radius 4.03, `z >= 0`), looking at the focus point.
//!
//! Where we differ: the pool is spanned by the *training* cameras only (RegNeRF's
//! `camtoworlds_all` includes the test poses, which a sparse-view method should not
//! see); the sphere's radius, centre and up are measured from those cameras instead of
//! NeRF-synthetic's constants; Blender-format scenes whose training cameras face one
//! way (the forward `occlusion`/`table` layouts: every axis within 45 degrees of the mean
//! axis) use the box, the others the sphere. Intrinsics are the mean of the training
//! cameras' (RegNeRF: the mean `pix2cam`).
//!
//! Invariants: the pool is a pure function of the scene's training cameras, the kind,
//! the size and the seed; every pose is a rigid OpenGL-convention `c2w` (looking down
//! `-z`) whose optical axis points at the scene's focus point (up to the Box jitter).

use glam::{Mat3, Mat4, Vec3};

use crate::data::camera::{facing_one_way, focus_point};
use crate::data::paths::{average_pose, focus_depth, look_at};
use crate::data::{Camera, Scene};
use crate::layout::GpuRay;

use super::rays::to_gpu_ray;
use crate::rng::SplitMix64;

/// How random poses are placed (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseKind {
    Llff,
    Box,
    Sphere,
}

impl PoseKind {
    /// RegNeRF's generator for the scene's type (module doc).
    pub fn for_scene(scene: &Scene) -> PoseKind {
        if scene.ndc.is_some() {
            return PoseKind::Llff;
        }
        if scene.is_dtu() {
            return PoseKind::Box;
        }
        let cams: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
        if facing_one_way(&cams, 45.0) { PoseKind::Box } else { PoseKind::Sphere }
    }
}

/// Uniform in `[0, 1)`.
fn unit(rng: &mut SplitMix64) -> f32 {
    (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32
}

/// Standard normal (Box-Muller).
fn normal(rng: &mut SplitMix64) -> f32 {
    let u1 = 1.0 - unit(rng);
    let u2 = unit(rng);
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// Half-extents of the box the training cameras span around their mean, in the frame
/// of the average pose.
fn camera_box(cameras: &[Camera], mean: Vec3, rot: Mat3) -> Vec3 {
    cameras.iter().fold(Vec3::ZERO, |r, c| r.max((rot.transpose() * (c.origin() - mean)).abs()))
}

/// Mean intrinsics of the training cameras, with pose `c2w`.
fn mean_camera(cameras: &[Camera], c2w: Mat4) -> Camera {
    let n = cameras.len() as f32;
    let avg = |f: fn(&Camera) -> f32| cameras.iter().map(f).sum::<f32>() / n;
    Camera { fx: avg(|c| c.fx), fy: avg(|c| c.fy), cx: avg(|c| c.cx), cy: avg(|c| c.cy), c2w, ..cameras[0] }
}

/// A pool of `n` random cameras of kind `kind` around the training cameras of `scene`
/// (a pure function of the arguments).
pub fn random_poses(scene: &Scene, kind: PoseKind, n: usize, seed: u64) -> Vec<Camera> {
    let cams: Vec<Camera> = scene.train_views().map(|v| v.camera).collect();
    assert!(!cams.is_empty(), "random poses need training cameras");
    let mut rng = SplitMix64::mixed(seed ^ 0x5245_474E_4552_4621);
    let (mean, rot, up) = average_pose(&cams);
    let r = camera_box(&cams, mean, rot);
    let in_box = |rng: &mut SplitMix64| mean + rot * (r * Vec3::new(2.0 * unit(rng) - 1.0, 2.0 * unit(rng) - 1.0, 2.0 * unit(rng) - 1.0));
    let focus = focus_point(&cams);
    (0..n)
        .map(|_| {
            let c2w = match kind {
                PoseKind::Llff => {
                    let near = scene.ndc.map_or(scene.near.max(1e-3), |p| p.near);
                    let target = mean + rot * Vec3::new(0.0, 0.0, -focus_depth(near / 0.75, f32::INFINITY));
                    look_at(in_box(&mut rng), target, up)
                }
                PoseKind::Box => {
                    let sigma = 0.125 * r.max_element();
                    let jitter = Vec3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)) * sigma;
                    look_at(in_box(&mut rng), focus + jitter, up)
                }
                PoseKind::Sphere => {
                    let radius = cams.iter().map(|c| c.origin().distance(focus)).sum::<f32>() / cams.len() as f32;
                    let mut d = Vec3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)).normalize_or(up);
                    if d.dot(up) < 0.0 {
                        d -= 2.0 * d.dot(up) * up;
                    }
                    look_at(focus + radius * d, focus, up)
                }
            };
            mean_camera(&cams, c2w)
        })
        .collect()
}

/// Rays of `n_patches` square patches of side `patch_size`, each from a random camera of
/// `pool` at a random position inside its image (RegNeRF's `subsample_patches` with
/// `all_images` batching), row-major within a patch, in the field's space (NDC for
/// forward-facing scenes), with their `z_scale`. A pure function of `seed` and `step`.
pub fn patch_rays(scene: &Scene, pool: &[Camera], n_patches: u32, patch_size: u32, seed: u64, step: u64) -> (Vec<GpuRay>, Vec<f32>) {
    let mut rng = SplitMix64::mixed(seed.wrapping_mul(0x9FB2_1C65_1E98_DF25) ^ step.rotate_left(29) ^ 0x7456);
    let n = (n_patches * patch_size * patch_size) as usize;
    let (mut rays, mut z_scales) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n_patches {
        let cam = &pool[rng.below(pool.len() as u64) as usize];
        let x0 = rng.below((cam.width.saturating_sub(patch_size) + 1) as u64) as u32;
        let y0 = rng.below((cam.height.saturating_sub(patch_size) + 1) as u64) as u32;
        for dy in 0..patch_size {
            for dx in 0..patch_size {
                let ray = cam.pixel_ray((x0 + dx) as f32 + 0.5, (y0 + dy) as f32 + 0.5);
                let ray = scene.ndc.map_or(ray, |p| p.ray_to_ndc(ray));
                rays.push(to_gpu_ray(scene, &ray));
                z_scales.push(ray.z_scale);
            }
        }
    }
    (rays, z_scales)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::LoadOptions;
    use crate::train::rays::ray_aabb;

    fn scene(name: &str) -> Scene {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small").join(name);
        Scene::load(dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap()
    }

    /// Poses look at `target` (within `max_deg`), sit near the training cameras, their
    /// optical axes cross the scene box, and most patch rays hit it.
    fn check(scene: &Scene, kind: PoseKind, target: Vec3, max_deg: f32, near_cameras: impl Fn(&Camera) -> bool) {
        let pool = random_poses(scene, kind, 200, 7);
        assert_eq!(pool.len(), 200);
        let again = random_poses(scene, kind, 200, 7);
        assert!(pool.iter().zip(&again).all(|(a, b)| a == b), "deterministic for the seed");
        assert_ne!(random_poses(scene, kind, 5, 8)[0], pool[0], "the seed matters");
        for c in &pool {
            assert!(c.is_finite());
            let rot = Mat3::from_mat4(c.c2w);
            assert!((rot.transpose() * rot - Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-4), "rigid");
            assert!(near_cameras(c), "pose at {} is not near the training cameras", c.origin());
            let axis = c.pixel_ray(c.cx, c.cy);
            let hits = match scene.ndc {
                // NDC: the axis from the near plane to infinity stays inside the NDC box.
                Some(p) => {
                    let r = p.ray_to_ndc(axis);
                    [0.0, 0.5, 0.99].iter().all(|&t| {
                        let q = r.at(t);
                        (q.cmpge(scene.aabb[0] - 1e-3) & q.cmple(scene.aabb[1] + 1e-3)).all()
                    })
                }
                None => ray_aabb(axis.origin, axis.dir, scene.aabb).is_some(),
            };
            assert!(hits, "optical axis from {} misses the scene box", c.origin());
            let to_target = (target - c.origin()).normalize();
            assert!(axis.dir.dot(to_target) > max_deg.to_radians().cos(), "looks at the scene");
        }
        let (rays, z) = patch_rays(scene, &pool, 32, 8, 3, 11);
        assert_eq!((rays.len(), z.len()), (32 * 64, 32 * 64));
        // Patches anywhere in the frame: some see past the scene box (as in RegNeRF).
        let hits = rays.iter().filter(|r| r.t_max > r.t_min).count();
        assert!(hits * 3 >= rays.len() * 2, "{hits} of {} patch rays hit the scene box", rays.len());
        assert_eq!(patch_rays(scene, &pool, 4, 8, 3, 11).0[5].origin, rays[5].origin, "pure function of seed and step");
    }

    fn train_cameras(s: &Scene) -> Vec<Camera> {
        s.train_views().map(|v| v.camera).collect()
    }

    /// Inside the box the training cameras span (with `slack` times its size around it).
    fn in_camera_box(cams: &[Camera], slack: f32) -> impl Fn(&Camera) -> bool {
        let (lo, hi) = cams.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), c| (lo.min(c.origin()), hi.max(c.origin())));
        let half = (hi - lo).max_element() * (0.5 + slack) + 1e-3;
        move |c| (c.origin() - (lo + hi) / 2.0).abs().max_element() <= half
    }

    #[test]
    fn sphere_poses_around_an_object_centric_scene() {
        let s = scene("creases");
        assert_eq!(PoseKind::for_scene(&s), PoseKind::Sphere);
        let cams = train_cameras(&s);
        let focus = focus_point(&cams);
        let dists: Vec<f32> = cams.iter().map(|c| c.origin().distance(focus)).collect();
        let (lo, hi) = (dists.iter().cloned().fold(f32::MAX, f32::min), dists.iter().cloned().fold(0.0, f32::max));
        let (_, _, up) = average_pose(&cams);
        check(&s, PoseKind::Sphere, focus, 1.0, |c| {
            let d = c.origin().distance(focus);
            d >= 0.99 * lo && d <= 1.01 * hi && (c.origin() - focus).dot(up) >= -1e-4
        });
    }

    #[test]
    fn box_poses_for_forward_facing_world_scenes() {
        let s = scene("occlusion");
        assert_eq!(PoseKind::for_scene(&s), PoseKind::Box);
        let cams = train_cameras(&s);
        check(&s, PoseKind::Box, focus_point(&cams), 25.0, in_camera_box(&cams, 0.5));
    }

    #[test]
    fn llff_poses_on_fern_when_available() {
        let Some(dir) = crate::data::real_scene_dir("llff/fern") else { return };
        let s = Scene::load(dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
        assert_eq!(PoseKind::for_scene(&s), PoseKind::Llff);
        let cams = train_cameras(&s);
        let (mean, rot, _) = average_pose(&cams);
        let target = mean + rot * Vec3::new(0.0, 0.0, -4.0 * 0.9 * s.ndc.unwrap().near / 0.75);
        check(&s, PoseKind::Llff, target, 1.0, in_camera_box(&cams, 0.5));
    }

    #[test]
    fn normal_draws_are_standard_normal() {
        let mut rng = SplitMix64::mixed(1);
        let xs: Vec<f32> = (0..4000).map(|_| normal(&mut rng)).collect();
        let mean = xs.iter().sum::<f32>() / 4000.0;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / 4000.0;
        assert!(mean.abs() < 0.06 && (var - 1.0).abs() < 0.08, "{mean} {var}");
    }
}
