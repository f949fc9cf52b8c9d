//! Rays for training and rendering: scene pixels to [`GpuRay`]s, and the random pixel
//! batches of a training step.
//!
//! Two kinds of batches: single pixels uniform over all training views
//! ([`random_pixels`]), and 2x2 patches of a few views with their edge masks
//! ([`random_patches`], what the edge-guided regularizers read), optionally followed by
//! single pixels that only the photometric loss sees (edge weight 0). Beside either, the
//! triplets of pixels on a line inside non-edge regions that the planarity term reads
//! ([`random_triplets`]).
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
    /// The index into `Scene::views` of each ray's view.
    pub views: Vec<u32>,
    /// Each ray's pixel in its view, `y * width + x`.
    pub pixels: Vec<u32>,
    /// Per ray `(e, z_scale)` for the edge-guided regularizers (patch batches only):
    /// `e` = 1 on non-edge pixels; `z_scale` turns the rendered ray parameter into the
    /// regularized depth ([`Ray::z_scale`]: along the camera axis in world space, 1 in NDC).
    pub reg: Vec<[f32; 2]>,
    /// RegNeRF's depth TV patches from random poses (rays and their `z_scale`), trained
    /// after the photometric rays; empty: the trainer draws them for the step.
    pub tv_rays: Vec<GpuRay>,
    pub tv_z_scale: Vec<f32>,
    /// The planarity term's triplets, trained after the random-pose rays; empty: the
    /// trainer draws them for the step.
    pub triplets: Triplets,
}

/// Triplets of pixels on a line for the planarity term ([`crate::loss::planarity`]):
/// rays `3k .. 3k + 2` are triplet `k`.
#[derive(Clone, Default)]
pub struct Triplets {
    pub rays: Vec<GpuRay>,
    /// Per ray `(w, z_scale)`: the triplet's weight (1; 0 where no triplet could be
    /// placed) and the ray's `z_scale` ([`Ray::z_scale`]).
    pub pixel: Vec<[f32; 2]>,
}

impl Triplets {
    pub fn len(&self) -> usize {
        self.rays.len() / 3
    }

    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }
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
        self.views.push(view as u32);
        self.pixels.push(y * w + x);
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

/// How [`random_patches`] lays out a step's patches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PatchShape {
    /// Distinct training views the patches are dealt to (the paper: 1).
    pub images_per_step: u32,
    /// Pixel spacing of a patch's rays (`train.patch_stride`; 1: adjacent pixels).
    pub stride: u32,
}

/// Draws `n_patches` random 2x2 patches for `step` (EdgeNeRF's batches): from
/// `shape.images_per_step` distinct training views chosen at random (the paper: one),
/// patches dealt to them in turn, top-left corners uniform over the image. Rays
/// `4m .. 4m+3` are patch `m` in the order `(x, y), (x+s, y), (x, y+s), (x+s, y+s)`
/// with `s = shape.stride` (1: adjacent pixels). Each ray carries its pixel's edge
/// weight at `s = 1`; at `s > 1` every ray of a patch carries the minimum over the
/// patch's `(s+1) x (s+1)` span, so an edge between the four pixels makes it an edge
/// patch. `masks[i]` is the edge mask of `scene.split.train[i]`. After the patches come
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
    shape: PatchShape,
    seed: u64,
    step: u64,
) -> PixelBatch {
    let mut rng = step_rng(seed, step);
    let train = &scene.split.train;
    assert_eq!(masks.len(), train.len(), "one edge mask per training view");
    // A partial Fisher-Yates shuffle picks the step's distinct views.
    let mut order: Vec<usize> = (0..train.len()).collect();
    let k = (shape.images_per_step.max(1) as usize).min(train.len());
    for i in 0..k {
        let j = i + rng.below((train.len() - i) as u64) as usize;
        order.swap(i, j);
    }
    let (w, h) = scene.image_size();
    let s = shape.stride.max(1);
    let mut batch = PixelBatch::default();
    for m in 0..n_patches as usize {
        let i = order[m % k];
        let view = train[i];
        let (mut x0, mut y0) = (0, 0);
        for _ in 0..MASK_DRAWS {
            x0 = rng.below(w.saturating_sub(s).max(1) as u64) as u32;
            y0 = rng.below(h.saturating_sub(s).max(1) as u64) as u32;
            let inside = |dx: u32, dy: u32| drawable(scene, view, (x0 + dx).min(w - 1), (y0 + dy).min(h - 1));
            if inside(0, 0) && inside(s, 0) && inside(0, s) && inside(s, s) {
                break;
            }
        }
        // At stride 1 the span is the patch itself, whose pixels keep their own weight.
        let span = (s > 1).then(|| {
            let (x1, y1) = ((x0 + s).min(w - 1), (y0 + s).min(h - 1));
            (y0..=y1).flat_map(|y| (x0..=x1).map(move |x| (x, y))).map(|(x, y)| masks[i].at(x, y)).fold(1.0f32, f32::min)
        });
        for (dx, dy) in [(0, 0), (s, 0), (0, s), (s, s)] {
            let (x, y) = ((x0 + dx).min(w - 1), (y0 + dy).min(h - 1));
            let z_scale = batch.push(scene, view, x, y);
            batch.reg.push([span.unwrap_or_else(|| masks[i].at(x, y)), z_scale]);
        }
    }
    draw_pixels(scene, n_pixels, &mut rng, &mut batch, true);
    batch
}

/// What [`random_triplets`] draws: `n` triplets of spacing up to `max_stride` pixels,
/// on segments whose colour varies by at most `color_range` per channel (0: any).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TripletDraw {
    pub n: u32,
    pub max_stride: u32,
    pub color_range: f32,
}

/// The directions of a triplet: rows, columns and both diagonals, either way.
const TRIPLET_DIRECTIONS: [(i32, i32); 8] = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)];

/// Mixed into the seed of the triplet draws, so that switching the planarity term on
/// leaves the step's photometric batch as it was.
const TRIPLET_SALT: u64 = 0x7121_91E7_5EED_0001;

/// Draws `n` triplets for `step`: each from a training view chosen at random, pixels
/// `p0, p0 + s u, p0 + 2 s u` for a direction `u` along a row, column or diagonal
/// ([`TRIPLET_DIRECTIONS`]) and a spacing `s` uniform in `1..=max_stride`, accepted
/// when every pixel of the segment from `p0` to `p0 + 2 s u` lies inside the image, is
/// non-edge (`masks[i]`, the edge mask of `scene.split.train[i]`), inside the view's
/// training mask and, where the image has alpha, foreground (alpha at least 0.5).
/// Up to [`MASK_DRAWS`] draws per triplet; a triplet that finds none is the last draw's
/// first pixel three times with weight 0. Long segments cross edges more often, so
/// the accepted spacings lean short in busy images. With `color_range > 0` a segment
/// is also rejected when any channel of the image varies along it by more than that
/// (max - min): the term then acts only where the colour is flat, i.e. where the
/// photometric loss says nothing about depth, and not on shaded curved surfaces.
/// A pure function of `seed` and `step`, independent of the other draws of the step.
pub fn random_triplets(scene: &Scene, masks: &[EdgeMask], draw: TripletDraw, seed: u64, step: u64) -> Triplets {
    let TripletDraw { n, max_stride, color_range } = draw;
    let mut rng = step_rng(seed ^ TRIPLET_SALT, step);
    let train = &scene.split.train;
    assert_eq!(masks.len(), train.len(), "one edge mask per training view");
    let (w, h) = scene.image_size();
    let max_stride = max_stride.max(1);
    let mut out = Triplets::default();
    for _ in 0..n {
        let i = rng.below(train.len() as u64) as usize;
        let view = train[i];
        let alpha = scene.views[view].alpha.as_deref();
        let usable = |x: u32, y: u32| {
            !masks[i].is_edge(x, y) && drawable(scene, view, x, y) && alpha.is_none_or(|a| a[(y * w + x) as usize] >= 0.5)
        };
        let mut found = None;
        let mut last = (0, 0);
        for _ in 0..MASK_DRAWS {
            let (x0, y0) = (rng.below(w as u64) as i64, rng.below(h as u64) as i64);
            let (dx, dy) = TRIPLET_DIRECTIONS[rng.below(TRIPLET_DIRECTIONS.len() as u64) as usize];
            let stride = 1 + rng.below(max_stride as u64) as i64;
            last = (x0 as u32, y0 as u32);
            let (x2, y2) = (x0 + 2 * stride * dx as i64, y0 + 2 * stride * dy as i64);
            if !(0..w as i64).contains(&x2) || !(0..h as i64).contains(&y2) {
                continue;
            }
            let on_segment = |k: i64| ((x0 + k * dx as i64) as u32, (y0 + k * dy as i64) as u32);
            let flat = || {
                let image = &scene.views[view].image;
                let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                for k in 0..=2 * stride {
                    let (x, y) = on_segment(k);
                    let c = image.get(x, y);
                    for ch in 0..3 {
                        lo[ch] = lo[ch].min(c[ch]);
                        hi[ch] = hi[ch].max(c[ch]);
                    }
                }
                (0..3).all(|ch| hi[ch] - lo[ch] <= color_range)
            };
            if (0..=2 * stride).all(|k| {
                let (x, y) = on_segment(k);
                usable(x, y)
            }) && (color_range <= 0.0 || flat())
            {
                found = Some([on_segment(0), on_segment(stride), on_segment(2 * stride)]);
                break;
            }
        }
        let (pixels, weight) = match found {
            Some(p) => (p, 1.0),
            None => ([last; 3], 0.0),
        };
        for (x, y) in pixels {
            let ray = scene.ray(view, x, y);
            out.rays.push(to_gpu_ray(scene, &ray));
            out.pixel.push([weight, ray.z_scale]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed `creases` scene with its 3 training views.
    fn three_view_creases() -> Scene {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/creases");
        Scene::load(&dir, &crate::data::LoadOptions { views: Some(3), ..Default::default() }).unwrap()
    }

    /// The pixel of `view` whose ray is `r`, if any.
    fn pixel_in_view(scene: &Scene, r: &GpuRay, view: usize) -> Option<(u32, u32)> {
        let (w, h) = scene.image_size();
        let (o, d) = (glam::Vec3::from(r.origin), glam::Vec3::from(r.dir));
        (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).find(|&(x, y)| {
            let q = to_gpu_ray(scene, &scene.ray(view, x, y));
            glam::Vec3::from(q.origin) == o && glam::Vec3::from(q.dir) == d
        })
    }

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
        let mut scene = three_view_creases();
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
        let shape = PatchShape { images_per_step: 1, stride: 1 };
        let patches = random_patches(&scene, &masks, 10, 6, shape, 7, 3);
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
    fn strided_patches_span_their_stride_and_take_the_edge_weight_of_the_span() {
        let scene = three_view_creases();
        let (w, h) = scene.image_size();
        // Edge columns at every x divisible by 10 in every view: a patch straddling one
        // at stride 4 mostly has none of its four pixels on it.
        let mut mask = EdgeMask::all_non_edge(w, h);
        for y in 0..h {
            for x in (0..w).step_by(10) {
                mask.non_edge[(y * w + x) as usize] = 0;
            }
        }
        let masks = vec![mask; scene.split.train.len()];
        let stride = 4;
        let b = random_patches(&scene, &masks, 400, 0, PatchShape { images_per_step: 3, stride }, 11, 5);
        let pixel = |r: &GpuRay, view: usize| pixel_in_view(&scene, r, view);
        let (mut straddling, mut clear, mut pixels_on_edges) = (0, 0, 0);
        for (m, patch) in b.rays.chunks(4).enumerate().take(40) {
            let view = scene.split.train.iter().copied().find(|&v| pixel(&patch[0], v).is_some()).expect("a training view");
            let p: Vec<(u32, u32)> = patch.iter().map(|r| pixel(r, view).expect("same view")).collect();
            let (x0, y0) = p[0];
            assert_eq!(p, vec![(x0, y0), (x0 + stride, y0), (x0, y0 + stride), (x0 + stride, y0 + stride)]);
            let e = &b.reg[4 * m..4 * m + 4];
            assert!(e.iter().all(|r| r[0] == e[0][0]), "one weight per strided patch");
            if (x0..=x0 + stride).any(|x| x % 10 == 0) {
                assert_eq!(e[0][0], 0.0, "an edge column in the span makes an edge patch");
                straddling += 1;
                pixels_on_edges += usize::from(x0 % 10 == 0 || (x0 + stride) % 10 == 0);
            } else {
                assert_eq!(e[0][0], 1.0);
                clear += 1;
            }
        }
        assert!(straddling > pixels_on_edges && clear > 0, "{straddling} straddling ({pixels_on_edges} with a pixel on the edge), {clear} clear");
    }

    #[test]
    fn triplets_lie_on_a_line_inside_one_non_edge_region() {
        let scene = three_view_creases();
        let (w, h) = scene.image_size();
        // Edge rows at every y divisible by 12: a triplet may not straddle one.
        let mut mask = EdgeMask::all_non_edge(w, h);
        for y in (0..h).step_by(12) {
            for x in 0..w {
                mask.non_edge[(y * w + x) as usize] = 0;
            }
        }
        let masks = vec![mask; scene.split.train.len()];
        let max_stride = 5;
        let t = random_triplets(&scene, &masks, TripletDraw { n: 300, max_stride, color_range: 0.0 }, 3, 9);
        assert_eq!((t.len(), t.pixel.len()), (300, 900));
        let pixel = |r: &GpuRay| scene.split.train.iter().find_map(|&view| pixel_in_view(&scene, r, view));
        let (mut placed, mut vertical, mut long) = (0, 0, 0);
        for (k, rays) in t.rays.chunks(3).enumerate().take(60) {
            let e = &t.pixel[3 * k..3 * k + 3];
            assert!(e.iter().all(|p| p[0] == e[0][0] && p[1] > 0.0), "one weight per triplet, z_scale set");
            if e[0][0] == 0.0 {
                continue;
            }
            placed += 1;
            let p: Vec<(i64, i64)> = rays.iter().map(|r| pixel(r).map(|(x, y)| (x as i64, y as i64)).expect("a training pixel")).collect();
            let (dx, dy) = (p[1].0 - p[0].0, p[1].1 - p[0].1);
            assert_eq!((p[2].0 - p[1].0, p[2].1 - p[1].1), (dx, dy), "equally spaced on a line: {p:?}");
            let s = dx.abs().max(dy.abs());
            assert!((1..=max_stride as i64).contains(&s) && (dx.abs() == s || dx == 0) && (dy.abs() == s || dy == 0), "{p:?}");
            let (y0, y2) = (p[0].1.min(p[2].1), p[0].1.max(p[2].1));
            assert!(!(y0..=y2).any(|y| y % 12 == 0), "the segment crosses no edge row: {p:?}");
            vertical += usize::from(dy != 0);
            long += usize::from(s >= 3);
        }
        assert!(placed > 50 && vertical > 10 && long > 10, "{placed} placed, {vertical} not horizontal, {long} spaced 3 or more");
        // A pure function of seed and step.
        let again = random_triplets(&scene, &masks, TripletDraw { n: 300, max_stride, color_range: 0.0 }, 3, 9);
        assert_eq!(again.pixel, t.pixel);
        // Where every pixel is an edge, nothing is placed.
        let edges: Vec<EdgeMask> = masks.iter().map(|m| EdgeMask { non_edge: vec![0; m.non_edge.len()], ..m.clone() }).collect();
        assert!(random_triplets(&scene, &edges, TripletDraw { n: 20, max_stride: 4, color_range: 0.0 }, 3, 9).pixel.iter().all(|p| p[0] == 0.0));
    }

    #[test]
    fn triplets_with_a_colour_range_lie_where_the_colour_is_flat() {
        let scene = three_view_creases();
        let (w, h) = scene.image_size();
        let masks = vec![EdgeMask::all_non_edge(w, h); scene.split.train.len()];
        let range = 0.03;
        let draw = TripletDraw { n: 200, max_stride: 8, color_range: range };
        let t = random_triplets(&scene, &masks, draw, 5, 2);
        let (mut placed, mut spread) = (0, 0.0f32);
        for (k, rays) in t.rays.chunks(3).enumerate() {
            if t.pixel[3 * k][0] == 0.0 {
                continue;
            }
            placed += 1;
            let (view, p) = scene.split.train.iter().find_map(|&v| {
                let p: Option<Vec<(u32, u32)>> = rays.iter().map(|r| pixel_in_view(&scene, r, v)).collect();
                p.map(|p| (v, p))
            }).expect("training pixels of one view");
            let (dx, dy) = ((p[1].0 as i64 - p[0].0 as i64).signum(), (p[1].1 as i64 - p[0].1 as i64).signum());
            let steps = (p[2].0 as i64 - p[0].0 as i64).abs().max((p[2].1 as i64 - p[0].1 as i64).abs());
            let colours: Vec<[f32; 3]> = (0..=steps)
                .map(|k| scene.views[view].image.get((p[0].0 as i64 + k * dx) as u32, (p[0].1 as i64 + k * dy) as u32))
                .collect();
            for ch in 0..3 {
                let (lo, hi) = colours.iter().fold((f32::MAX, f32::MIN), |(lo, hi), c| (lo.min(c[ch]), hi.max(c[ch])));
                assert!(hi - lo <= range, "triplet {k}: channel {ch} spans {lo}..{hi} along {p:?}");
                spread = spread.max(hi - lo);
            }
        }
        // The floor and the flat faces are there to find; without the range the same
        // draws land on shaded and textured pixels too.
        assert!(placed > 100 && spread > 0.0, "{placed} placed");
        let any = random_triplets(&scene, &masks, TripletDraw { color_range: 0.0, ..draw }, 5, 2);
        assert_ne!(any.pixel, t.pixel);
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
