//! LLFF loader on the real fern scene: RegNeRF split, NeRF pose processing, NDC rays.

mod common;

use edgenerf::data::{LoadOptions, Scene, SceneFormat};
use glam::Vec3;

fn load_fern(opts: &LoadOptions) -> Option<Scene> {
    let dir = common::scene_dir("llff/fern")?;
    Some(Scene::load(&dir, opts).expect("fern loads"))
}

#[test]
fn fern_split_sizes_and_intrinsics() {
    let Some(scene) = load_fern(&LoadOptions { views: Some(3), ..Default::default() }) else { return };
    assert_eq!(scene.format, SceneFormat::Llff);
    assert_eq!(scene.views.len(), 20);
    assert_eq!(scene.image_size(), (504, 378));
    assert_eq!(scene.split.train, vec![1, 10, 19]);
    assert_eq!(scene.split.test, vec![0, 8, 16]);
    assert_eq!((scene.near, scene.far), (0.0, 1.0));
    assert_eq!(scene.aabb, [Vec3::splat(-1.0), Vec3::splat(1.0)]);
    assert!(scene.background.is_none());
    let ndc = scene.ndc.expect("LLFF scenes carry NDC parameters");
    assert_eq!((ndc.width, ndc.height, ndc.near), (504.0, 378.0, 1.0));

    // Images sorted by name, one per pose, pixels loaded in [0, 1].
    for (i, v) in scene.views.iter().enumerate() {
        assert_eq!(v.name, format!("image{i:03}"));
        assert_eq!(v.image.data.len(), 504 * 378 * 3);
        assert!(v.image.data.iter().all(|&x| (0.0..=1.0).contains(&x)));
        // fern's hwf focal is 3260.53 px at 4032x3024; images_8 is 8x smaller.
        let c = &v.camera;
        assert!((c.fx - 3260.526 / 8.0).abs() < 0.05 && (c.fy - c.fx).abs() < 1e-3, "fx {}", c.fx);
        assert_eq!((c.cx, c.cy), (252.0, 189.0));
    }
    assert!(scene.views[0].image.data.iter().any(|&x| x > 0.2), "image is not blank");

    // All non-test images train when no view count is given.
    let dense = load_fern(&LoadOptions::default()).unwrap();
    assert_eq!(dense.split.train.len(), 17);
    assert!(dense.split.train.iter().all(|i| i % 8 != 0));
}

#[test]
fn fern_poses_are_recentred() {
    let Some(scene) = load_fern(&LoadOptions { load_images: false, ..Default::default() }) else { return };
    assert!(scene.views.iter().all(|v| v.image.is_empty() && v.camera.width == 504));
    let n = scene.views.len() as f32;
    let mut mean_pos = Vec3::ZERO;
    let mut mean_fwd = Vec3::ZERO;
    for v in &scene.views {
        let c = &v.camera;
        assert!(c.is_finite());
        // Rotations stay orthonormal.
        let r = glam::Mat3::from_mat4(c.c2w);
        assert!((r.transpose() * r).abs_diff_eq(glam::Mat3::IDENTITY, 1e-4));
        assert!((r.determinant() - 1.0).abs() < 1e-4);
        mean_pos += c.origin() / n;
        mean_fwd += c.forward() / n;
    }
    assert!(mean_pos.length() < 1e-4, "mean camera position {mean_pos}");
    assert!(mean_fwd.normalize().dot(-Vec3::Z) > 0.999, "mean forward {mean_fwd}");
    // The bd_factor rescale puts the closest content at depth 1/0.75: the cameras sit well
    // behind the NDC near plane z = -1.
    assert!(scene.views.iter().all(|v| v.camera.origin().z.abs() < 0.5));
}

#[test]
fn fern_ndc_rays() {
    let Some(scene) = load_fern(&LoadOptions { load_images: false, ..Default::default() }) else { return };
    let (w, h) = scene.image_size();
    let inside = |p: Vec3| p.abs().max_element() <= 1.0 + 1e-4;
    let (mut total, mut outside) = (0usize, 0usize);
    for view in 0..scene.views.len() {
        let rays = scene.image_rays(view);
        assert_eq!(rays.len(), (w * h) as usize);
        for (i, ray) in rays.iter().enumerate() {
            assert_eq!(*ray, scene.ray(view, i as u32 % w, i as u32 / w));
            // NDC: origin on the near plane z = -1, direction z = 2, far point at z = 1.
            assert!((ray.origin.z + 1.0).abs() < 1e-4 && (ray.dir.z - 2.0).abs() < 1e-4);
            for t in [0.0, 0.5, 1.0] {
                total += 1;
                outside += usize::from(!inside(ray.at(t)));
            }
        }
    }
    // Cameras are nearly fronto-parallel, so only slivers at the image borders of the
    // outermost views leave the cube.
    let frac = outside as f64 / total as f64;
    assert!(frac < 0.02, "{outside} of {total} NDC samples outside the cube");

    // Centre rays of neighbouring views are roughly parallel (forward-facing capture).
    for i in 1..scene.views.len() {
        let a = scene.views[i - 1].camera.pixel_ray(w as f32 / 2.0, h as f32 / 2.0);
        let b = scene.views[i].camera.pixel_ray(w as f32 / 2.0, h as f32 / 2.0);
        assert!(a.dir.dot(b.dir) > 0.98, "views {} and {i}: {} vs {}", i - 1, a.dir, b.dir);
        let (na, nb) = (scene.ray(i - 1, w / 2, h / 2), scene.ray(i, w / 2, h / 2));
        assert!(na.dir.normalize().dot(nb.dir.normalize()) > 0.98);
    }
}
