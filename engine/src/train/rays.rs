//! Rays for training and rendering: scene pixels to [`GpuRay`]s, and the random pixel
//! batches of a training step.
//!
//! Two kinds of batches: single pixels uniform over all training views
//! ([`random_pixels`]), and 2x2 patches of a few views with their edge masks
//! ([`random_patches`], what the edge-guided regularizers read), optionally followed by
//! single pixels that only the photometric loss sees (edge weight 0).
//!
//! Invariants: a ray's `[t_min, t_max]` is the scene's near/far range clipped to the
//! scene AABB (world-space scenes) or `[0, 1]` (NDC scenes); a ray that misses the
//! AABB gets `t_min == t_max` and therefore no samples. Pixel selection is a pure
//! function of the seed and step (deterministic runs, exact resumes). A view with a
//! training mask ([`crate::data::View::train_mask`]) only gives pixels (whole patches)
//! inside it: a draw outside is redrawn, up to [`MASK_DRAWS`] times.

use glam::Vec3;

use crate::data::{Ray, Scene};
use crate::edges::EdgeMask;
use crate::rng::SplitMix64;
use crate::layout::GpuRay;

/// `[t_enter, t_exit]` of a ray (`t >= 0`) against an AABB, if it hits: the kernels'
/// slab test ([`GpuRay::box_range`]).
pub fn ray_aabb(origin: Vec3, dir: Vec3, aabb: [Vec3; 2]) -> Option<(f32, f32)> {
    let line = GpuRay { origin: origin.into(), dir: dir.into(), ..GpuRay::default() };
    let [enter, exit] = line.box_range(aabb[0].into(), aabb[1].into());
    (exit >= enter.max(0.0)).then_some((enter.max(0.0), exit))
}

/// The kernel-side ray of a scene ray (world or NDC, as [`Scene::ray`] gives it).
pub fn to_gpu_ray(scene: &Scene, ray: &Ray) -> GpuRay {
    let (t_min, t_max) = if scene.ndc.is_some() {
        (scene.near, scene.far)
    } else {
        match ray_aabb(ray.origin, ray.dir, scene.aabb) {
            Some((enter, exit)) => {
                let (lo, hi) = (enter.max(scene.near), exit.min(scene.far));
                if hi > lo { (lo, hi) } else { (lo, lo) }
            }
            None => (scene.near, scene.near),
        }
    };
    GpuRay { origin: ray.origin.to_array(), t_min, dir: ray.dir.to_array(), t_max }
}

/// A step's training rays and their targets.
#[derive(Clone, Default)]
pub struct PixelBatch {
    pub rays: Vec<GpuRay>,
    /// Target colour and weight (1).
    pub targets: Vec<[f32; 4]>,
    /// The pixel's alpha where its image has one.
    pub alpha: Vec<Option<f32>>,
    /// Per ray `(e, z_scale)` for the edge-guided regularizers (patch batches only):
    /// `e` = 1 on non-edge pixels; `z_scale` turns the rendered ray parameter into the
    /// regularized depth ([`Ray::z_scale`]: along the camera axis in world space, 1 in NDC).
    pub reg: Vec<[f32; 2]>,
    /// RegNeRF's depth TV patches from random poses (rays and their `z_scale`), trained
    /// after the photometric rays; empty: the trainer draws them for the step.
    pub tv_rays: Vec<GpuRay>,
    pub tv_z_scale: Vec<f32>,
}

impl PixelBatch {
    /// Appends the ray of pixel `(x, y)` of `view`; returns the ray's `z_scale`.
    fn push(&mut self, scene: &Scene, view: usize, x: u32, y: u32) -> f32 {
        let ray = scene.ray(view, x, y);
        self.rays.push(to_gpu_ray(scene, &ray));
        let px = scene.views[view].image.get(x, y);
        self.targets.push([px[0], px[1], px[2], 1.0]);
        let w = scene.views[view].camera.width;
        self.alpha.push(scene.views[view].alpha.as_ref().map(|a| a[(y * w + x) as usize]));
        ray.z_scale
    }
}

fn step_rng(seed: u64, step: u64) -> SplitMix64 {
    SplitMix64::mixed(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ step)
}

/// Draws of a pixel (or patch corner) before one inside the view's training mask is
/// given up on and the last draw kept: a mask that leaves almost nothing still trains.
const MASK_DRAWS: u32 = 64;

/// Whether pixel `(x, y)` of `view` may be drawn ([`crate::data::View::train_mask`]).
fn drawable(scene: &Scene, view: usize, x: u32, y: u32) -> bool {
    let v = &scene.views[view];
    v.train_mask.as_ref().is_none_or(|m| m[(y * v.camera.width + x) as usize] > 0.5)
}

/// Draws `n` training pixels for `step`, uniform over the pixels of all training views
/// (a pure function of `seed` and `step`).
pub fn random_pixels(scene: &Scene, n: u32, seed: u64, step: u64) -> PixelBatch {
    let mut batch = PixelBatch::default();
    draw_pixels(scene, n, &mut step_rng(seed, step), &mut batch, false);
    batch
}

/// Appends `n` pixels uniform over the pixels of all training views, drawn from `rng`;
/// with `reg`, each with edge weight 0 (`(0, z_scale)`: no regularizer reads it).
fn draw_pixels(scene: &Scene, n: u32, rng: &mut SplitMix64, batch: &mut PixelBatch, reg: bool) {
    let train = &scene.split.train;
    let (w, h) = scene.image_size();
    for _ in 0..n {
        let view = train[rng.below(train.len() as u64) as usize];
        let (mut x, mut y) = (0, 0);
        for _ in 0..MASK_DRAWS {
            x = rng.below(w as u64) as u32;
            y = rng.below(h as u64) as u32;
            if drawable(scene, view, x, y) {
                break;
            }
        }
        let z_scale = batch.push(scene, view, x, y);
        if reg {
            batch.reg.push([0.0, z_scale]);
        }
    }
}

/// Draws `n_patches` random 2x2 patches for `step` (EdgeNeRF's batches): from
/// `images_per_step` distinct training views chosen at random (the paper: one), patches
/// dealt to them in turn, top-left corners uniform over the image. Rays
/// `4m .. 4m+3` are patch `m` in the order `(x, y), (x+1, y), (x, y+1), (x+1, y+1)`.
/// `masks[i]` is the edge mask of `scene.split.train[i]`. After the patches come
/// `n_pixels` single pixels uniform over all training views with edge weight 0 (`0`:
/// none), so that a batch can carry fewer patches than rays (`train.patch_share`): every
/// group of 4 of them is an all-edge "patch" to the regularizers, which adds nothing,
/// while the photometric loss sees more distinct pixels. A pure function of `seed` and
/// `step`.
pub fn random_patches(
    scene: &Scene,
    masks: &[EdgeMask],
    n_patches: u32,
    n_pixels: u32,
    images_per_step: u32,
    seed: u64,
    step: u64,
) -> PixelBatch {
    let mut rng = step_rng(seed, step);
    let train = &scene.split.train;
    assert_eq!(masks.len(), train.len(), "one edge mask per training view");
    // A partial Fisher-Yates shuffle picks the step's distinct views.
    let mut order: Vec<usize> = (0..train.len()).collect();
    let k = (images_per_step.max(1) as usize).min(train.len());
    for i in 0..k {
        let j = i + rng.below((train.len() - i) as u64) as usize;
        order.swap(i, j);
    }
    let (w, h) = scene.image_size();
    let mut batch = PixelBatch::default();
    for m in 0..n_patches as usize {
        let i = order[m % k];
        let view = train[i];
        let (mut x0, mut y0) = (0, 0);
        for _ in 0..MASK_DRAWS {
            x0 = rng.below((w - 1).max(1) as u64) as u32;
            y0 = rng.below((h - 1).max(1) as u64) as u32;
            let inside = |dx: u32, dy: u32| drawable(scene, view, (x0 + dx).min(w - 1), (y0 + dy).min(h - 1));
            if inside(0, 0) && inside(1, 0) && inside(0, 1) && inside(1, 1) {
                break;
            }
        }
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (x, y) = ((x0 + dx).min(w - 1), (y0 + dy).min(h - 1));
            let z_scale = batch.push(scene, view, x, y);
            batch.reg.push([masks[i].at(x, y), z_scale]);
        }
    }
    draw_pixels(scene, n_pixels, &mut rng, &mut batch, true);
    batch
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_test_hits_and_misses() {
        let aabb = [Vec3::splat(-1.0), Vec3::splat(1.0)];
        let (a, b) = ray_aabb(Vec3::new(0.0, 0.0, -3.0), Vec3::Z, aabb).unwrap();
        assert!((a - 2.0).abs() < 1e-6 && (b - 4.0).abs() < 1e-6);
        assert!(ray_aabb(Vec3::new(0.0, 3.0, -3.0), Vec3::Z, aabb).is_none());
        let (a, _) = ray_aabb(Vec3::ZERO, Vec3::X, aabb).unwrap();
        assert_eq!(a, 0.0, "origin inside: starts at 0");
    }

    #[test]
    fn batches_draw_only_pixels_inside_the_training_mask() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/creases");
        let opts = crate::data::LoadOptions { views: Some(3), ..Default::default() };
        let mut scene = Scene::load(&dir, &opts).unwrap();
        let (w, h) = scene.image_size();
        // Training may only use the left third of each view.
        let allowed = |x: u32| x < w / 3;
        for &v in &scene.split.train.clone() {
            let mask = (0..w * h).map(|i| if allowed(i % w) { 1.0 } else { 0.0 }).collect();
            scene.views[v].train_mask = Some(mask);
        }
        let ray_pixel = |scene: &Scene, r: &GpuRay| {
            // The pixel a ray came from: its target colour identifies it only loosely, so
            // match the ray against every training pixel's ray.
            for &v in &scene.split.train {
                for y in 0..h {
                    for x in 0..w {
                        let q = to_gpu_ray(scene, &scene.ray(v, x, y));
                        if q.origin == r.origin && q.dir == r.dir {
                            return x;
                        }
                    }
                }
            }
            panic!("ray of no training pixel");
        };
        let pixels = random_pixels(&scene, 40, 7, 3);
        assert!(pixels.rays.iter().all(|r| allowed(ray_pixel(&scene, r))), "single pixels");
        let masks: Vec<EdgeMask> = scene.split.train.iter().map(|_| EdgeMask::all_non_edge(w, h)).collect();
        let patches = random_patches(&scene, &masks, 10, 6, 1, 7, 3);
        assert!(patches.rays.iter().all(|r| allowed(ray_pixel(&scene, r))), "whole patches and the pixels after them");
        // The pixels after the patches carry edge weight 0 (no regularizer reads them).
        assert_eq!(patches.rays.len(), 46);
        assert!(patches.reg[..40].iter().all(|r| r[0] == 1.0) && patches.reg[40..].iter().all(|r| r[0] == 0.0 && r[1] > 0.0));
        // Without the mask the same draws reach the rest of the image.
        for &v in &scene.split.train.clone() {
            scene.views[v].train_mask = None;
        }
        let free = random_pixels(&scene, 40, 7, 3);
        assert!(free.rays.iter().any(|r| !allowed(ray_pixel(&scene, r))));
    }

    #[test]
    fn rng_is_deterministic_and_roughly_uniform() {
        let mut a = SplitMix64::mixed(5);
        let mut b = SplitMix64::mixed(5);
        let xs: Vec<u64> = (0..1000).map(|_| a.below(10)).collect();
        let ys: Vec<u64> = (0..1000).map(|_| b.below(10)).collect();
        assert_eq!(xs, ys);
        for k in 0..10 {
            let c = xs.iter().filter(|&&x| x == k).count();
            assert!((60..140).contains(&c), "bucket {k}: {c}");
        }
    }
}
