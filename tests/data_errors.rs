//! Broken scenes give errors that name the offending path and say what is wrong.

use std::path::Path;

use edgenerf::data::npy::write_npy_f64;
use edgenerf::data::{DataError, LoadOptions, Scene};

fn write_png(path: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_pixel(w, h, image::Rgb([10, 20, 30]))
        .save(path)
        .unwrap();
}

/// A valid `n`-image LLFF scene of 8x6 images in `images_8` (LLFF rows, hwf 48x64 f=80).
fn llff_scene(root: &Path, n: usize) -> Vec<f64> {
    let mut rows = Vec::new();
    for i in 0..n {
        // [down, right, back] axes = identity; t; hwf column; near/far bounds.
        rows.extend_from_slice(&[1.0, 0.0, 0.0, i as f64 * 0.1, 48.0]);
        rows.extend_from_slice(&[0.0, 1.0, 0.0, 0.0, 64.0]);
        rows.extend_from_slice(&[0.0, 0.0, 1.0, 0.0, 80.0]);
        rows.extend_from_slice(&[2.0, 20.0]);
        write_png(&root.join(format!("images_8/img{i:02}.png")), 8, 6);
    }
    write_npy_f64(&root.join("poses_bounds.npy"), &[n, 17], &rows).unwrap();
    rows
}

fn load_err(root: &Path) -> (DataError, String) {
    let err = Scene::load(root, &LoadOptions::default()).expect_err("the scene is broken");
    let msg = err.to_string();
    eprintln!("{msg}");
    (err, msg)
}

fn has(msg: &str, path: &Path) -> bool {
    msg.contains(&path.display().to_string())
}

#[test]
fn valid_tiny_llff_scene_loads() {
    // The baseline the broken variants below start from.
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views.len(), 3);
    assert_eq!(
        (scene.views[0].camera.fx, scene.views[0].camera.fy),
        (10.0, 10.0)
    );
}

#[test]
fn missing_directory() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no_such_scene");
    let (err, msg) = load_err(&missing);
    assert!(matches!(err, DataError::NotFound { .. }));
    assert!(has(&msg, &missing) && msg.contains("not found"), "{msg}");
}

#[test]
fn unknown_layout_lists_the_known_ones() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("readme.txt"), "hello").unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::UnknownFormat { .. }));
    assert!(has(&msg, dir.path()), "{msg}");
    for layout in [
        "transforms_train.json",
        "poses_bounds.npy",
        "cameras_sphere.npz",
        "cameras.npz",
    ] {
        assert!(msg.contains(layout), "{msg}");
    }
}

#[test]
fn missing_image_for_a_pose() {
    // LLFF: 3 poses, 2 images.
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    std::fs::remove_file(dir.path().join("images_8/img02.png")).unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(
        matches!(
            err,
            DataError::CountMismatch {
                images: 2,
                cameras: 3,
                ..
            }
        ),
        "{err:?}"
    );
    assert!(has(&msg, &dir.path().join("images_8")), "{msg}");

    // Missing image folder for the requested factor.
    let (err, msg) = {
        let e = Scene::load(
            dir.path(),
            &LoadOptions {
                llff_factor: 4,
                ..Default::default()
            },
        )
        .unwrap_err();
        let m = e.to_string();
        (e, m)
    };
    assert!(matches!(err, DataError::NotFound { .. }));
    assert!(has(&msg, &dir.path().join("images_4")), "{msg}");

    // Blender: a frame whose file does not exist.
    let dir = tempfile::tempdir().unwrap();
    let eye = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 4.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let t = serde_json::json!({"camera_angle_x": 0.7, "frames": [{"file_path": "./train/r_7", "transform_matrix": eye}]});
    std::fs::write(dir.path().join("transforms_train.json"), t.to_string()).unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::MissingImage { .. }));
    assert!(
        has(&msg, &dir.path().join("train/r_7")) && msg.contains("frame 0"),
        "{msg}"
    );
}

#[test]
fn wrong_npy_shape() {
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    let npy = dir.path().join("poses_bounds.npy");
    write_npy_f64(&npy, &[3, 15], &[0.5; 45]).unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::Npy { .. }));
    assert!(
        has(&msg, &npy) && msg.contains("(3, 15)") && msg.contains("(N, 17)"),
        "{msg}"
    );

    // Not a .npy file at all.
    std::fs::write(&npy, b"garbage").unwrap();
    let (_, msg) = load_err(dir.path());
    assert!(has(&msg, &npy) && msg.contains("magic"), "{msg}");
}

#[test]
fn mismatched_image_sizes_name_both_files() {
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    let odd = dir.path().join("images_8/img01.png");
    write_png(&odd, 9, 6);
    let (err, msg) = load_err(dir.path());
    assert!(
        matches!(
            err,
            DataError::SizeMismatch {
                got: (9, 6),
                expected: (8, 6),
                ..
            }
        ),
        "{err:?}"
    );
    assert!(
        has(&msg, &odd) && has(&msg, &dir.path().join("images_8/img00.png")),
        "{msg}"
    );
}

#[test]
fn nan_pose() {
    let dir = tempfile::tempdir().unwrap();
    let mut rows = llff_scene(dir.path(), 3);
    rows[17 + 3] = f64::NAN;
    let npy = dir.path().join("poses_bounds.npy");
    write_npy_f64(&npy, &[3, 17], &rows).unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::NonFinite { .. }));
    assert!(has(&msg, &npy) && msg.contains("row 1"), "{msg}");
}

#[test]
fn bad_json() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("transforms_train.json");
    std::fs::write(&json, "{\"camera_angle_x\": 0.7, \"frames\": [").unwrap();
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::Json { .. }));
    assert!(has(&msg, &json), "{msg}");

    // Valid JSON with the wrong structure (no transform_matrix).
    std::fs::write(
        &json,
        r#"{"camera_angle_x": 0.7, "frames": [{"file_path": "a"}]}"#,
    )
    .unwrap();
    let (_, msg) = load_err(dir.path());
    assert!(
        has(&msg, &json) && msg.contains("transform_matrix"),
        "{msg}"
    );
}

#[test]
fn mask_and_ground_truth_size_mismatch() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    write_png(&root.join("r_0.png"), 8, 6);
    image::GrayImage::new(4, 3)
        .save(root.join("mask.png"))
        .unwrap();
    let eye = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 4.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let t = serde_json::json!({"camera_angle_x": 0.7, "frames": [
        {"file_path": "r_0", "transform_matrix": eye, "mask_path": "mask.png"}]});
    std::fs::write(root.join("transforms_train.json"), t.to_string()).unwrap();
    let (err, msg) = load_err(root);
    assert!(matches!(err, DataError::SizeMismatch { .. }));
    assert!(
        has(&msg, &root.join("mask.png")) && has(&msg, &root.join("r_0.png")),
        "{msg}"
    );

    // A depth map of the wrong size, and a missing normal map.
    edgenerf::data::save_depth_exr(root.join("d.exr"), 8, 5, &[1.0; 40]).unwrap();
    let t = serde_json::json!({"camera_angle_x": 0.7, "frames": [
        {"file_path": "r_0", "transform_matrix": eye, "depth_path": "d.exr"}]});
    std::fs::write(root.join("transforms_train.json"), t.to_string()).unwrap();
    let (_, msg) = load_err(root);
    assert!(
        has(&msg, &root.join("d.exr")) && msg.contains("8x5"),
        "{msg}"
    );
    let t = serde_json::json!({"camera_angle_x": 0.7, "frames": [
        {"file_path": "r_0", "transform_matrix": eye, "normal_path": "n.exr"}]});
    std::fs::write(root.join("transforms_train.json"), t.to_string()).unwrap();
    let (_, msg) = load_err(root);
    assert!(has(&msg, &root.join("n.exr")), "{msg}");
}

#[test]
fn too_many_views_requested() {
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    let err = Scene::load(
        dir.path(),
        &LoadOptions {
            views: Some(5),
            ..Default::default()
        },
    )
    .unwrap_err();
    let msg = err.to_string();
    assert!(
        has(&msg, dir.path()) && msg.contains("5 training views"),
        "{msg}"
    );
}
