//! Tests of the reprojection term ([`crate::loss::reprojection`]) on the views this
//! module packs from the committed `creases` scene (3 training views,
//! rendered by Mitsuba with ground-truth depth): the packed cameras against
//! [`crate::data::Camera::project`], the kernel against the `f64` reference, the reference against
//! central differences, and the physics: ground-truth depth reprojects onto matching
//! colours, and the gradient at a wrong depth points back toward the truth.

use super::*;
use crate::data::{Lens, LoadOptions};
use crate::gpu::{GpuBuffer, test_gpu};
use crate::layout::{GpuRay, RayOutput};
use crate::loss::reprojection::reference::{ReprojRay, colour_at, loss, ray_point, view_term};
use crate::loss::reprojection::{HEADER, Reprojection};
use crate::rng::SplitMix64;
use crate::train::rays::to_gpu_ray;

fn three_view_creases() -> Scene {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../synthetic-scenes/small/creases");
    Scene::load(&dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap()
}

/// `n` rays of random pixels of the training views that hit a surface, at their
/// ground-truth depth scaled by `1 + scale * U(-1, 1)`, with opacity in `[0.3, 1]`.
fn rays_at_depth(scene: &Scene, n: usize, scale: f64, seed: u64) -> Vec<ReprojRay> {
    let mut rng = SplitMix64::new(seed);
    let (w, h) = scene.image_size();
    let mut rays = Vec::new();
    while rays.len() < n {
        let source = rng.below(scene.split.train.len() as u64) as usize;
        let view = scene.split.train[source];
        let (x, y) = (rng.below(w as u64) as u32, rng.below(h as u64) as u32);
        let gt = scene.views[view].depth.as_ref().unwrap()[(y * w + x) as usize] as f64;
        if gt <= 0.0 {
            continue;
        }
        let r = to_gpu_ray(scene, &scene.ray(view, x, y));
        let opacity = 0.3 + 0.35 * (rng.uniform(1.0) + 1.0);
        rays.push(ReprojRay {
            origin: r.origin.map(f64::from),
            dir: r.dir.map(f64::from),
            t_min: r.t_min as f64,
            t_max: r.t_max as f64,
            depth: opacity * gt * (1.0 + scale * rng.uniform(1.0)),
            opacity,
            weight: 1.0,
            source: source as u32,
        });
    }
    rays
}

#[test]
fn packed_views_project_as_the_cameras_do() {
    let scene = three_view_creases();
    let views = reprojection_views(&scene, 0.0).unwrap();
    // The size known before packing (what train checks against the device) is the packed one.
    let sizes = scene.train_views().map(|v| (v.camera.width, v.camera.height));
    assert_eq!(crate::loss::reprojection::ReprojectionViews::packed_bytes(sizes), views.bytes());
    assert_eq!(views.n_views, 3);
    let (w, h) = scene.image_size();
    assert_eq!(views.words.len(), 3 * HEADER + 3 * (w * h) as usize);
    let mut rng = SplitMix64::new(3);
    for (i, view) in scene.train_views().enumerate() {
        // The pixels are the image's, 8 bits each.
        let p = views.words[views.words[i * HEADER + 18] as usize + (5 * w + 7) as usize];
        let want = view.image.get(7, 5);
        for (c, s) in [0, 8, 16].into_iter().enumerate() {
            assert!((((p >> s) & 255) as f32 / 255.0 - want[c]).abs() <= 0.5 / 255.0 + 1e-6);
        }
        // A point on the ray of a pixel projects onto it: its colour is the pixel's.
        let v = scene.split.train[i];
        for (px, py) in [(7u32, 5u32), (64, 64), (100, 31), (w - 2, h - 2)] {
            let x = scene.ray(v, px, py).at(2.5).to_array().map(f64::from);
            let (got, want) = (colour_at(&views, i, x), view.image.get(px, py));
            assert!((0..3).all(|c| (got[c] - want[c] as f64).abs() <= 0.5 / 255.0 + 1e-4), "view {i} pixel ({px}, {py}): {got:?} vs {want:?}");
        }
        for _ in 0..50 {
            let x = glam::Vec3::new(rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), rng.range_f32(-0.2, 0.8));
            let Some((px, _)) = view.camera.project(x) else { continue };
            // A point along a unit direction: the term's pixel is the camera's.
            let inside = px.x >= 0.5 && px.y >= 0.5 && px.x < w as f32 - 0.5 && px.y < h as f32 - 0.5;
            let term = view_term(&views, i, x.to_array().map(f64::from), [1.0, 0.0, 0.0], [0.0; 3], 0.01);
            assert_eq!(term.is_some(), inside, "view {i} point {x}: pixel {px}");
        }
    }
}

#[test]
fn packed_views_blur_each_channel() {
    let scene = three_view_creases();
    let (sharp, blurred) = (reprojection_views(&scene, 0.0).unwrap(), reprojection_views(&scene, 2.0).unwrap());
    assert_eq!(sharp.words[..3 * HEADER], blurred.words[..3 * HEADER], "same headers");
    let (w, h) = scene.image_size();
    let view = scene.train_views().nth(1).unwrap();
    let offset = blurred.words[HEADER + 18] as usize;
    for c in 0..3 {
        let plane: Vec<f32> = view.image.data.iter().skip(c).step_by(3).copied().collect();
        let want = crate::edges::gaussian_blur(&plane, w as usize, h as usize, 2.0);
        for i in [0, 777, 5000, (w * h - 1) as usize] {
            let got = ((blurred.words[offset + i] >> (8 * c)) & 255) as f32 / 255.0;
            assert!((got - want[i]).abs() <= 0.5 / 255.0 + 1e-6, "channel {c} pixel {i}: {got} vs {}", want[i]);
        }
    }
    let changed = (offset..offset + (w * h) as usize).filter(|&i| sharp.words[i] != blurred.words[i]).count();
    assert!(changed > (w * h / 4) as usize, "the blur changes the images ({changed} pixels)");
}

#[test]
fn packing_refuses_what_it_cannot_project() {
    let scene = three_view_creases();
    let mut distorted = scene.clone();
    let v = distorted.split.train[1];
    distorted.views[v].camera.lens = Lens::OpenCv { k: [0.1, 0.0, 0.0, 0.0], p: [0.0; 2] };
    let err = reprojection_views(&distorted, 0.0).unwrap_err();
    assert!(err.contains("distorted lens") && err.contains(&distorted.views[v].name), "{err}");
    let mut no_images = scene;
    no_images.views[v].image.data.clear();
    assert!(reprojection_views(&no_images, 0.0).unwrap_err().contains("training images"));
}

#[test]
fn reprojection_kernel_matches_reference() {
    let scene = three_view_creases();
    let views = reprojection_views(&scene, 0.0).unwrap();
    let mut rays = rays_at_depth(&scene, 512, 0.08, 11);
    // Clamped low and high, transparent, and dropped rays.
    rays[3].depth = rays[3].opacity * (rays[3].t_min - 0.1);
    rays[10].depth = rays[10].opacity * (rays[10].t_max + 0.1);
    rays[20].opacity = 0.0;
    rays[20].depth = 0.0;
    rays[21].weight = 0.0;
    let delta = 0.02;
    let (_, grads) = loss(&views, &rays, delta);
    let with_gradient = grads.iter().filter(|g| g.0 != 0.0).count();
    eprintln!("{with_gradient} of {} rays with a gradient", rays.len());
    assert!(with_gradient > 200, "{with_gradient} rays with a gradient: most should land on colour changes");
    assert_eq!((grads[3], grads[10], grads[20], grads[21]), ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)));

    assert_kernel_matches_reference(&views, &rays, delta, "creases");
}

/// The kernel's loss and added gradients against the reference's on `rays`.
fn assert_kernel_matches_reference(views: &ReprojectionViews, rays: &[ReprojRay], delta: f64, what: &str) {
    let gpu = test_gpu(false);
    let (want, grads) = loss(views, rays, delta);
    let outs: Vec<RayOutput> = rays.iter().map(|r| RayOutput { depth: r.depth as f32, opacity: r.opacity as f32, ..Default::default() }).collect();
    let ins: Vec<GpuRay> = rays
        .iter()
        .map(|r| GpuRay { origin: r.origin.map(|v| v as f32), t_min: r.t_min as f32, dir: r.dir.map(|v| v as f32), t_max: r.t_max as f32 })
        .collect();
    // The kernel reads only the drop weight of the targets (the colour comes from the views).
    let targets: Vec<[f32; 4]> = rays.iter().map(|r| [0.3, 0.6, 0.9, r.weight as f32]).collect();
    let term = Reprojection::new(&gpu, views, rays.len() as u32).unwrap();
    term.source.write(&gpu, &rays.iter().map(|r| r.source).collect::<Vec<_>>());
    let prior: Vec<RayOutput> = (0..rays.len()).map(|i| RayOutput { rgb: [0.5; 3], depth: 0.25, opacity: 0.01 * i as f32, ..Default::default() }).collect();
    let d = GpuBuffer::from_slice(&gpu, "d", &prior).unwrap();
    let (outs, ins, targets) = (
        GpuBuffer::from_slice(&gpu, "outs", &outs).unwrap(),
        GpuBuffer::from_slice(&gpu, "rays", &ins).unwrap(),
        GpuBuffer::from_slice(&gpu, "targets", &targets).unwrap(),
    );
    let lambda = 0.7f32;
    let mut enc = gpu.encoder();
    term.record(&mut enc, &outs, &ins, &targets, &d, rays.len() as u32, lambda, delta as f32);
    enc.submit();
    let got = term.loss(&gpu, rays.len() as u32).unwrap() as f64;
    assert!((got - want).abs() <= 1e-4 * want, "{what}: loss {got} vs {want}");
    let d = d.read(&gpu).unwrap();
    // f32 projections land within ~1e-5 pixel of the f64 ones; the bilinear derivative
    // is continuous in between pixel centres, so the gradients agree to ~1e-4.
    crate::loss::test_support::assert_added_depth_opacity_grads(&d, &prior, 0, &grads, lambda as f64, (2e-3, 0.0), what);
}

#[test]
fn reprojection_reference_matches_finite_differences() {
    let scene = three_view_creases();
    let views = reprojection_views(&scene, 0.0).unwrap();
    assert_reference_matches_finite_differences(&views, &rays_at_depth(&scene, 64, 0.08, 5), "creases");
}

/// The reference's gradients against central differences of its loss, away from the
/// kinks (bilinear cell boundaries, changes of best view); at least 120 of the 128.
fn assert_reference_matches_finite_differences(views: &ReprojectionViews, rays: &[ReprojRay], what: &str) {
    let delta = 0.02;
    let (_, grads) = loss(views, rays, delta);
    let h = 1e-7;
    let mut checked = 0;
    for k in 0..rays.len() {
        for which in 0..2 {
            let bump = |s: f64| {
                let mut p = rays.to_vec();
                if which == 0 {
                    p[k].depth += s;
                } else {
                    // The weight m = weight * opacity is a constant of the backward pass
                    // (stop-gradient): hold it.
                    p[k].opacity += s;
                    p[k].weight = rays[k].weight * rays[k].opacity / p[k].opacity;
                }
                loss(views, &p, delta).0
            };
            let (fwd, bwd) = ((bump(h) - bump(0.0)) / h, (bump(0.0) - bump(-h)) / h);
            // A bilinear cell boundary or a change of best view inside the step: no derivative.
            if (fwd - bwd).abs() > 1e-3 * fwd.abs().max(bwd.abs()).max(1e-6) {
                continue;
            }
            let fd = 0.5 * (fwd + bwd);
            let got = if which == 0 { grads[k].0 } else { grads[k].1 };
            assert!((fd - got).abs() < 1e-4 * fd.abs().max(1e-4), "{what} ray {k} {which}: fd {fd} vs {got}");
            checked += 1;
        }
    }
    assert!(checked >= 120 && rays.len() == 64, "{what}: only {checked} of 128 derivatives away from a kink");
}

/// `n` rays of random pixels of fern's 3 training views (NDC rays) at random NDC depths
/// in `[0.3, 0.95]`, `None` without the data.
fn fern_rays(n: usize, seed: u64) -> Option<(Scene, Vec<ReprojRay>)> {
    let dir = crate::data::real_scene_dir("llff/fern")?;
    let scene = Scene::load(&dir, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
    assert!(scene.ndc.is_some());
    let mut rng = SplitMix64::new(seed);
    let (w, h) = scene.image_size();
    let rays = (0..n)
        .map(|_| {
            let source = rng.below(3) as usize;
            let (x, y) = (rng.below(w as u64) as u32, rng.below(h as u64) as u32);
            let r = to_gpu_ray(&scene, &scene.ray(scene.split.train[source], x, y));
            let opacity = 0.5 + 0.25 * (rng.uniform(1.0) + 1.0);
            ReprojRay {
                origin: r.origin.map(f64::from),
                dir: r.dir.map(f64::from),
                t_min: r.t_min as f64,
                t_max: r.t_max as f64,
                depth: opacity * (0.625 + 0.325 * rng.uniform(1.0)),
                opacity,
                weight: 1.0,
                source: source as u32,
            }
        })
        .collect();
    Some((scene, rays))
}

#[test]
fn ndc_rays_reproject_through_world_space() {
    let Some((scene, rays)) = fern_rays(64, 3) else { return };
    let views = reprojection_views(&scene, 0.0).unwrap();
    let ndc = scene.ndc.unwrap();
    for r in &rays {
        let t = r.depth / r.opacity;
        let (x, dx) = ray_point(&views, r, t);
        // NeRF's inverse map of the NDC point, and its derivative along t.
        let p = glam::DVec3::from(r.origin) + t * glam::DVec3::from(r.dir);
        let want = ndc.ndc_to_world(p.as_vec3()).as_dvec3();
        assert!((glam::DVec3::from(x) - want).length() < 1e-4 * want.length(), "{x:?} vs {want}");
        let h = 1e-6;
        let fd = (glam::DVec3::from(ray_point(&views, r, t + h).0) - glam::DVec3::from(ray_point(&views, r, t - h).0)) / (2.0 * h);
        assert!((glam::DVec3::from(dx) - fd).length() < 1e-5 * fd.length(), "{dx:?} vs {fd}");
        // The point lies on the ray of its pixel: its own view sees it at that pixel.
        let c = &scene.views[scene.split.train[r.source as usize]].camera;
        let (px, _) = c.project(x.map(|v| v as f32).into()).unwrap();
        let back = to_gpu_ray(&scene, &scene.ray(scene.split.train[r.source as usize], px.x as u32, px.y as u32));
        assert!((glam::Vec3::from(back.dir) - glam::Vec3::from(r.dir.map(|v| v as f32))).length() < 1e-3, "pixel {px}");
    }
    let (_, grads) = loss(&views, &rays, 0.02);
    assert!(grads.iter().filter(|g| g.0 != 0.0).count() > 32, "fern's rays land in the other views");
    assert_reference_matches_finite_differences(&views, &rays, "fern (NDC)");
    let (_, rays) = fern_rays(512, 4).unwrap();
    assert_kernel_matches_reference(&views, &rays, 0.02, "fern (NDC)");
}

#[test]
fn ground_truth_depth_reprojects_onto_matching_colours() {
    let scene = three_view_creases();
    let views = reprojection_views(&scene, 0.0).unwrap();
    let delta = 0.02;
    let at_truth = rays_at_depth(&scene, 2000, 0.0, 7);
    let (l_true, _) = loss(&views, &at_truth, delta);
    for off in [0.9, 1.1] {
        let moved: Vec<ReprojRay> = at_truth.iter().map(|r| ReprojRay { depth: r.depth * off, ..*r }).collect();
        let (l, _) = loss(&views, &moved, delta);
        assert!(l > 1.5 * l_true, "depth x{off}: loss {l} vs {l_true} at the truth");
    }
    // Off the truth by 1-3 % of the depth (one to a few pixels of disparity), unblurred
    // and blurred by 2 pixels: the loss is higher, and its gradient points back toward
    // the truth on most rays whose colour changes there and in sum (a per-ray majority
    // only: rendering noise and shading differences between views move each ray's
    // minimum by a fraction of a pixel).
    for (blur, scale) in [(0.0, 0.01), (2.0, 0.03)] {
        let views = reprojection_views(&scene, blur).unwrap();
        let (l_true, _) = loss(&views, &at_truth, delta);
        let mut rng = SplitMix64::new(9);
        let near: Vec<ReprojRay> = at_truth.iter().map(|r| ReprojRay { depth: r.depth * (1.0 + scale * rng.uniform(1.0)), ..*r }).collect();
        let (l_near, grads) = loss(&views, &near, delta);
        let (mut toward, mut away, mut descent) = (0, 0, 0.0);
        for ((r, t), g) in near.iter().zip(&at_truth).zip(&grads) {
            descent += g.0 * (r.depth - t.depth);
            if g.0.abs() < 1e-6 {
                continue;
            }
            // Descent moves depth by -g: toward the truth when g has the sign of the error.
            if (g.0 > 0.0) == (r.depth > t.depth) { toward += 1 } else { away += 1 }
        }
        let what = format!("blur {blur}, {scale} of the depth: {toward} rays pulled toward the true depth, {away} away, loss {l_near} vs {l_true}");
        assert!(l_near > l_true && descent > 0.0 && toward > 500 && 2 * toward > 3 * away, "{what}");
    }
}
