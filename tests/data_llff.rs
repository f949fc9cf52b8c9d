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
    let Some(scene) = load_fern(&LoadOptions {
        views: Some(3),
        ..Default::default()
    }) else {
        return;
    };
    assert_eq!(scene.format, SceneFormat::Llff);
    assert_eq!(scene.views.len(), 20);
    assert_eq!(scene.image_size(), (504, 378));
    assert_eq!(scene.split.train, vec![1, 10, 19]);
    assert_eq!(scene.split.test, vec![0, 8, 16]);
    assert_eq!((scene.near, scene.far), (0.0, 1.0));
    // With the far bound, rays end at 1.1 times the farthest bound, rescaled as the
    // poses are (the nearest bound at 1 / 0.75), as an NDC ray parameter `1 - near / depth`.
    let bounds = edgenerf::data::npy::read_npy(&scene.root.join("poses_bounds.npy")).unwrap();
    let rows = (0..bounds.shape[0]).map(|i| bounds.row(i));
    let (near, far) = rows.fold((f64::INFINITY, 0.0f64), |(n, f), r| (n.min(r[15]), f.max(r[16])));
    let far_t = 1.0 - 1.0 / (1.1 * far / (near * 0.75));
    let bounded = load_fern(&LoadOptions { load_images: false, ndc_far_bound: true, ..Default::default() }).unwrap();
    assert_eq!(bounded.near, 0.0);
    assert!((f64::from(bounded.far) - far_t).abs() < 1e-6 && bounded.far < 0.9, "far {} against {far_t}", bounded.far);
    assert_eq!(scene.aabb, [Vec3::new(-1.5, -1.5, -1.0), Vec3::new(1.5, 1.5, 1.0)]);
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
        assert!(
            (c.fx - 3260.526 / 8.0).abs() < 0.05 && (c.fy - c.fx).abs() < 1e-3,
            "fx {}",
            c.fx
        );
        assert_eq!((c.cx, c.cy), (252.0, 189.0));
    }
    assert!(
        scene.views[0].image.data.iter().any(|&x| x > 0.2),
        "image is not blank"
    );

    // All non-test images train when no view count is given.
    let dense = load_fern(&LoadOptions::default()).unwrap();
    assert_eq!(dense.split.train.len(), 17);
    assert!(dense.split.train.iter().all(|i| i % 8 != 0));
}

#[test]
fn fern_poses_are_recentred() {
    let Some(scene) = load_fern(&LoadOptions {
        load_images: false,
        ..Default::default()
    }) else {
        return;
    };
    assert!(
        scene
            .views
            .iter()
            .all(|v| v.image.is_empty() && v.camera.width == 504)
    );
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
    assert!(
        mean_fwd.normalize().dot(-Vec3::Z) > 0.999,
        "mean forward {mean_fwd}"
    );
    // The bd_factor rescale puts the closest content at depth 1/0.75: the cameras sit well
    // behind the NDC near plane z = -1.
    assert!(scene.views.iter().all(|v| v.camera.origin().z.abs() < 0.5));
}

#[test]
fn fern_ndc_rays() {
    let Some(scene) = load_fern(&LoadOptions {
        load_images: false,
        ..Default::default()
    }) else {
        return;
    };
    let (w, h) = scene.image_size();
    let within = |p: Vec3, xy: f32| p.x.abs() <= xy && p.y.abs() <= xy && p.z.abs() <= 1.0 + 1e-5;
    for view in 0..scene.views.len() {
        let rays = scene.image_rays(view);
        assert_eq!(rays.len(), (w * h) as usize);
        for (i, ray) in rays.iter().enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            assert_eq!(*ray, scene.ray(view, x, y));
            // NDC: origin on the near plane z = -1, direction z = 2, far point at z = 1.
            assert!((ray.origin.z + 1.0).abs() < 1e-4 && (ray.dir.z - 2.0).abs() < 1e-4);
            let central = (w / 4..3 * w / 4).contains(&x) && (h / 4..3 * h / 4).contains(&y);
            for t in [0.0, 0.5, 1.0] {
                let p = ray.at(t);
                // The central half of every image maps inside the NDC cube. Border pixels
                // of fern's views (rotated up to ~9 degrees from the mean axis) leave it
                // sideways by up to ~45% at infinity, as in NeRF; z always stays in range.
                assert!(
                    within(p, if central { 1.0 + 1e-5 } else { 1.5 }),
                    "view {view} pixel ({x}, {y}) t {t}: {p}"
                );
            }
        }
    }

    // Centre rays of neighbouring views are roughly parallel (forward-facing capture).
    for i in 1..scene.views.len() {
        let a = scene.views[i - 1]
            .camera
            .pixel_ray(w as f32 / 2.0, h as f32 / 2.0);
        let b = scene.views[i]
            .camera
            .pixel_ray(w as f32 / 2.0, h as f32 / 2.0);
        assert!(
            a.dir.dot(b.dir) > 0.98,
            "views {} and {i}: {} vs {}",
            i - 1,
            a.dir,
            b.dir
        );
        let (na, nb) = (scene.ray(i - 1, w / 2, h / 2), scene.ray(i, w / 2, h / 2));
        assert!(na.dir.normalize().dot(nb.dir.normalize()) > 0.98);
    }
}

#[test]
fn fern_matches_nerf_reference_values() {
    // Reference values from NeRF's `load_llff_data(factor=8, recenter=True, bd_factor=.75)`
    // and `ndc_rays(H, W, focal, 1.0, ...)` (NumPy, pixel centres at +0.5).
    let Some(scene) = load_fern(&LoadOptions {
        load_images: false,
        ..Default::default()
    }) else {
        return;
    };
    let c2w = scene.views[10].camera.c2w;
    let expected = [
        [0.98857, -0.0051, -0.1507, -0.3944],
        [0.00423, 0.99997, -0.00606, -0.04749],
        [0.15073, 0.00535, 0.98856, 0.03857],
    ];
    for (r, row) in expected.iter().enumerate() {
        for (c, &v) in row.iter().enumerate() {
            assert!(
                (c2w.col(c)[r] - v).abs() < 2e-5,
                "c2w[{r}][{c}] = {} vs {v}",
                c2w.col(c)[r]
            );
        }
    }
    assert!((scene.views[10].camera.fx - 407.5658).abs() < 1e-3);
    let ray = scene.ray(10, 100, 50);
    assert!(
        ray.origin
            .abs_diff_eq(Vec3::new(-0.98983, 0.63705, -1.0), 2e-5),
        "{}",
        ray.origin
    );
    assert!(
        ray.dir.abs_diff_eq(Vec3::new(0.65094, 0.07495, 2.0), 2e-5),
        "{}",
        ray.dir
    );
}
