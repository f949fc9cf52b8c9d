//! Blender / NeRF-synthetic loader on tiny scenes generated in a temporary directory:
//! alpha compositing, intrinsics, ground-truth maps, split and defaults.

use std::path::Path;

use edgenerf::data::{LoadOptions, Scene, SceneFormat, save_depth_exr, save_normal_exr};
use glam::Vec3;
use serde_json::{Value, json};

const W: u32 = 8;
const H: u32 = 6;

/// RGBA test picture: pixel (0, 0) transparent red, (1, 0) opaque, (2, 0) half covered,
/// the rest opaque grey whose value encodes the frame index.
fn write_rgba(path: &Path, frame: u8) {
    let mut img =
        image::RgbaImage::from_pixel(W, H, image::Rgba([frame * 40, frame * 40, frame * 40, 255]));
    img.put_pixel(0, 0, image::Rgba([255, 0, 0, 0]));
    img.put_pixel(1, 0, image::Rgba([51, 102, 204, 255]));
    img.put_pixel(2, 0, image::Rgba([255, 255, 255, 102]));
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    img.save(path).unwrap();
}

fn pose(tx: f32, ty: f32, tz: f32) -> Value {
    // A camera rotated 90 degrees about y (looking down world -x) at (tx, ty, tz); rows.
    json!([
        [0.0, 0.0, 1.0, tx],
        [0.0, 1.0, 0.0, ty],
        [-1.0, 0.0, 0.0, tz],
        [0.0, 0.0, 0.0, 1.0]
    ])
}

fn depth_of(frame: usize) -> Vec<f32> {
    (0..W * H)
        .map(|i| {
            if i == 0 {
                0.0
            } else {
                2.0 + frame as f32 + i as f32 * 0.01
            }
        })
        .collect()
}

fn normal_of(frame: usize) -> Vec<[f32; 3]> {
    (0..W * H)
        .map(|i| {
            if i == 0 {
                [0.0; 3]
            } else {
                [frame as f32 * 0.1, 0.6, 0.8]
            }
        })
        .collect()
}

/// Three training frames (paths with and without extension and `./`) and one test frame.
fn nerf_synthetic_scene(root: &Path) {
    write_rgba(&root.join("train/r_0.png"), 0);
    write_rgba(&root.join("train/r_1.png"), 1);
    write_rgba(&root.join("train/r_2.png"), 2);
    write_rgba(&root.join("test/r_0.png"), 3);
    let train = json!({
        "camera_angle_x": 0.6911112070083618,
        "frames": [
            {"file_path": "./train/r_0", "transform_matrix": pose(4.0, 0.0, 0.0)},
            {"file_path": "train/r_1.png", "transform_matrix": pose(4.0, 1.0, 0.0)},
            {"file_path": "./train/r_2", "transform_matrix": pose(4.0, 2.0, 0.5)},
        ]
    });
    let test = json!({
        "camera_angle_x": 0.6911112070083618,
        "frames": [{"file_path": "./test/r_0", "transform_matrix": pose(4.0, -1.0, 0.0)}]
    });
    std::fs::write(root.join("transforms_train.json"), train.to_string()).unwrap();
    std::fs::write(root.join("transforms_test.json"), test.to_string()).unwrap();
    // Ignored while a test split exists.
    std::fs::write(
        root.join("transforms_val.json"),
        r#"{"camera_angle_x": 0.5, "frames": []}"#,
    )
    .unwrap();
}

#[test]
fn nerf_synthetic_layout() {
    let dir = tempfile::tempdir().unwrap();
    nerf_synthetic_scene(dir.path());
    let bg = [0.25, 0.5, 0.75];
    let scene = Scene::load(
        dir.path(),
        &LoadOptions {
            background: bg,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(scene.format, SceneFormat::Blender);
    assert_eq!(scene.views.len(), 4);
    assert_eq!(scene.split.train, vec![0, 1, 2]);
    assert_eq!(scene.split.test, vec![3]);
    assert_eq!(
        scene
            .views
            .iter()
            .map(|v| v.name.as_str())
            .collect::<Vec<_>>(),
        ["r_0", "r_1", "r_2", "r_0"]
    );
    assert!(scene.views[3].path.ends_with("test/r_0.png"));
    assert_eq!((scene.near, scene.far), (2.0, 6.0));
    assert_eq!(scene.aabb, [Vec3::splat(-1.5), Vec3::splat(1.5)]);
    assert_eq!(scene.background, Some(bg));
    assert!(scene.ndc.is_none());

    // Compositing over the background.
    let img = &scene.views[1].image;
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(close(img.get(0, 0), bg), "{:?}", img.get(0, 0));
    assert!(close(img.get(1, 0), [0.2, 0.4, 0.8]), "{:?}", img.get(1, 0));
    let a = 102.0 / 255.0;
    assert!(
        close(img.get(2, 0), bg.map(|b| a + b * (1.0 - a))),
        "{:?}",
        img.get(2, 0)
    );
    assert!(close(img.get(5, 5), [40.0 / 255.0; 3]));
    // The alpha channel is the view's mask when the frame has no mask_path.
    let mask = scene.views[1].mask.as_ref().unwrap();
    assert_eq!((mask[0], mask[1], mask[2]), (0.0, 1.0, a));

    // Intrinsics from camera_angle_x, poses from the row-major transform_matrix.
    let c = &scene.views[2].camera;
    let f = 0.5 * W as f32 / (0.5f32 * 0.6911112).tan();
    assert!((c.fx - f).abs() < 1e-3 && (c.fy - f).abs() < 1e-3);
    assert_eq!((c.cx, c.cy, c.width, c.height), (4.0, 3.0, W, H));
    assert_eq!(c.origin(), Vec3::new(4.0, 2.0, 0.5));
    assert!((c.forward() - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6);
    let centre = scene.ray(2, W / 2, H / 2);
    assert!(centre.dir.dot(-Vec3::X) > 0.99);

    // A sparse split keeps round(linspace(0, 2, 2)) = frames 0 and 2, then the test frame.
    let sparse = Scene::load(
        dir.path(),
        &LoadOptions {
            views: Some(2),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(
        sparse
            .views
            .iter()
            .map(|v| v.camera.origin().y)
            .collect::<Vec<_>>(),
        [0.0, 2.0, -1.0]
    );
    assert_eq!(
        (sparse.split.train.clone(), sparse.split.test.clone()),
        (vec![0, 1], vec![2])
    );
    // With the unused views (the val split), the left-out frame 1 follows the test frame.
    let with_val = Scene::load(dir.path(), &LoadOptions { views: Some(2), unused_views: true, ..Default::default() }).unwrap();
    assert_eq!(with_val.views.iter().map(|v| v.camera.origin().y).collect::<Vec<_>>(), [0.0, 2.0, -1.0, 1.0]);
    assert_eq!((&with_val.split, with_val.split.unused(with_val.views.len())), (&sparse.split, vec![3]));
    let all = Scene::load(dir.path(), &LoadOptions { unused_views: true, ..Default::default() }).unwrap();
    assert!(all.split.unused(all.views.len()).is_empty());
    assert!(
        Scene::load(
            dir.path(),
            &LoadOptions {
                views: Some(4),
                ..Default::default()
            }
        )
        .is_err()
    );

    // Cameras only.
    let info = Scene::load(
        dir.path(),
        &LoadOptions {
            load_images: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        info.views
            .iter()
            .all(|v| v.image.is_empty() && v.mask.is_none())
    );
    assert_eq!(info.image_size(), (W, H));
    assert_eq!(info.views[2].camera, *c);
}

#[test]
fn synthetic_scene_with_ground_truth_and_full_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let mut frames = Vec::new();
    for i in 0..2 {
        write_rgba(&root.join(format!("rgb/{i:03}.png")), i as u8);
        save_depth_exr(root.join(format!("depth_{i}.exr")), W, H, &depth_of(i)).unwrap();
        save_normal_exr(root.join(format!("normal_{i}.exr")), W, H, &normal_of(i)).unwrap();
        let mask =
            image::GrayImage::from_fn(W, H, |x, _| image::Luma([if x < 4 { 255 } else { 0 }]));
        mask.save(root.join(format!("mask_{i}.png"))).unwrap();
        frames.push(json!({
            "file_path": format!("./rgb/{i:03}.png"),
            "transform_matrix": pose(3.0, i as f32, 0.0),
            "depth_path": format!("depth_{i}.exr"),
            "normal_path": format!("./normal_{i}.exr"),
            "mask_path": format!("mask_{i}.png"),
        }));
    }
    // Intrinsics given for a 2x larger render: scaled to the loaded 8x6 images.
    let transforms = json!({
        "fl_x": 20.0, "fl_y": 22.0, "cx": 7.0, "cy": 5.0, "w": 16, "h": 12,
        "near": 0.5, "far": 4.5, "aabb": [[-1.0, -0.5, -0.25], [1.0, 0.5, 0.25]],
        "frames": frames,
    });
    std::fs::write(root.join("transforms_train.json"), transforms.to_string()).unwrap();

    let scene = Scene::load(
        root,
        &LoadOptions {
            background: [0.0; 3],
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(scene.split.train, vec![0, 1]);
    assert!(scene.split.test.is_empty());
    assert_eq!((scene.near, scene.far), (0.5, 4.5));
    assert_eq!(
        scene.aabb,
        [Vec3::new(-1.0, -0.5, -0.25), Vec3::new(1.0, 0.5, 0.25)]
    );
    let c = &scene.views[0].camera;
    assert_eq!((c.fx, c.fy, c.cx, c.cy), (10.0, 11.0, 3.5, 2.5));
    for (i, v) in scene.views.iter().enumerate() {
        assert_eq!(v.depth.as_deref(), Some(depth_of(i).as_slice()));
        assert_eq!(v.normal.as_deref(), Some(normal_of(i).as_slice()));
        let mask = v.mask.as_ref().unwrap();
        assert_eq!(mask.len(), (W * H) as usize);
        assert!(
            (0..W * H).all(|p| mask[p as usize] == if p % W < 4 { 1.0 } else { 0.0 }),
            "mask_path wins over alpha"
        );
    }
    // Ground truth is skipped when only cameras are read.
    let info = Scene::load(
        root,
        &LoadOptions {
            load_images: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        info.views
            .iter()
            .all(|v| v.depth.is_none() && v.normal.is_none())
    );
}
