//! Broken scenes give errors that name the offending path and say what is wrong.

mod common;

use std::path::Path;

use edgenerf::data::npy::write_npy_f64;
use edgenerf::data::{DataError, Lens, LoadOptions, Scene};

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
                llff_factor: Some(4),
                ..Default::default()
            },
        )
        .unwrap_err();
        let m = e.to_string();
        (e, m)
    };
    assert!(matches!(err, DataError::Invalid { .. }), "{err:?}");
    assert!(has(&msg, &dir.path().join("images_4")) && msg.contains("images_8 (--llff-factor 8)"), "{msg}");

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

/// A valid blender scene of `n` 8x6 frames (identity-rotation cameras at z = 4) with
/// `top` merged into the file's top level and `frame0` into its first frame.
fn blender_scene(root: &Path, n: usize, top: serde_json::Value, frame0: serde_json::Value) {
    let eye = serde_json::json!([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
    let mut frames = Vec::new();
    for i in 0..n {
        write_png(&root.join(format!("r_{i}.png")), 8, 6);
        frames.push(serde_json::json!({"file_path": format!("r_{i}"), "transform_matrix": eye}));
    }
    for (k, v) in frame0.as_object().unwrap() {
        frames[0][k] = v.clone();
    }
    let mut t = serde_json::json!({"camera_angle_x": 0.7, "frames": frames});
    for (k, v) in top.as_object().unwrap() {
        t[k] = v.clone();
    }
    std::fs::write(root.join("transforms_train.json"), t.to_string()).unwrap();
}

fn blender_err(top: serde_json::Value, frame0: serde_json::Value) -> String {
    let dir = tempfile::tempdir().unwrap();
    blender_scene(dir.path(), 2, top, frame0);
    let (_, msg) = load_err(dir.path());
    assert!(has(&msg, &dir.path().join("transforms_train.json")), "{msg}");
    msg
}

/// Cameras that cannot form rays were loaded and trained on: a zero or negative focal
/// length, a zero, scaled or mirrored rotation, a bottom row of 0 0 0 0.
#[test]
fn degenerate_cameras_are_refused() {
    for (top, want) in [
        (serde_json::json!({"fl_x": 0.0}), "focal length"),
        (serde_json::json!({"fl_x": -50.0, "fl_y": -50.0}), "focal length"),
        (serde_json::json!({"camera_angle_x": -1.0}), "camera_angle_x"),
        (serde_json::json!({"camera_angle_x": 3.5}), "camera_angle_x"),
        (serde_json::json!({"fl_x": 50.0, "w": 0.0}), "must be positive"),
    ] {
        let msg = blender_err(top.clone(), serde_json::json!({}));
        assert!(msg.contains(want) && msg.contains("frame 0"), "{top}: {msg}");
    }
    let zero = serde_json::json!([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
    let scaled = serde_json::json!([[2.0, 0.0, 0.0, 0.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 2.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
    let mirrored = serde_json::json!([[-1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]);
    let bottom = serde_json::json!([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 0.0]]);
    for (m, want) in [(zero, "not orthonormal"), (scaled, "not orthonormal"), (mirrored, "reflection"), (bottom, "bottom row")] {
        let msg = blender_err(serde_json::json!({}), serde_json::json!({"transform_matrix": m}));
        assert!(msg.contains(want) && msg.contains("frame 0"), "{msg}");
    }
}

/// nerfstudio keys that change the rays are honoured (per-frame intrinsics, the OPENCV
/// and OPENCV_FISHEYE lenses) or refused (other lens models); they were dropped without
/// a word.
#[test]
fn nerfstudio_camera_keys_are_honoured_or_refused() {
    for (top, want) in [
        (serde_json::json!({"camera_model": "EQUIRECTANGULAR"}), "camera_model \"EQUIRECTANGULAR\" is not supported"),
        (serde_json::json!({"camera_model": "FISHEYE624"}), "FISHEYE624"),
        (serde_json::json!({"camera_model": "OPENCV_FISHEYE", "p1": 0.002}), "no tangential terms"),
        (serde_json::json!({"is_fisheye": true}), "is_fisheye"),
        (serde_json::json!({"camera_model": "OPENCV", "k1": 1e39}), "not finite"),
    ] {
        let msg = blender_err(top.clone(), serde_json::json!({}));
        assert!(msg.contains(want) && msg.contains("frame 0"), "{top}: {msg}");
    }
    // Distortion, at the top level or on one frame, becomes the camera's lens.
    let dir = tempfile::tempdir().unwrap();
    blender_scene(dir.path(), 2, serde_json::json!({"camera_model": "OPENCV", "fl_x": 40.0, "k1": 0.1, "p2": 0.002}), serde_json::json!({"k2": 0.05}));
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views[0].camera.lens, Lens::OpenCv { k: [0.1, 0.05, 0.0, 0.0], p: [0.0, 0.002] });
    assert_eq!(scene.views[1].camera.lens, Lens::OpenCv { k: [0.1, 0.0, 0.0, 0.0], p: [0.0, 0.002] });
    let dir = tempfile::tempdir().unwrap();
    blender_scene(dir.path(), 1, serde_json::json!({"camera_model": "OPENCV_FISHEYE", "fl_x": 40.0, "k1": 0.1, "k4": -0.01}), serde_json::json!({}));
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views[0].camera.lens, Lens::Fisheye { k: [0.1, 0.0, 0.0, -0.01] });

    // Pinhole models and zero distortion load; per-frame intrinsics win over the top level.
    let dir = tempfile::tempdir().unwrap();
    blender_scene(
        dir.path(),
        2,
        serde_json::json!({"camera_model": "OPENCV", "fl_x": 40.0, "fl_y": 41.0, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6,
                           "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}),
        serde_json::json!({"fl_x": 20.0, "cx": 3.5, "w": 16, "h": 12}),
    );
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    let (c0, c1) = (scene.views[0].camera, scene.views[1].camera);
    // Frame 0: fl_x 20 for a 16x12 image (fl_y follows its own fl_x), scaled to 8x6.
    assert_eq!((c0.fx, c0.fy, c0.cx, c0.cy), (10.0, 10.0, 1.75, 1.5), "{c0:?}");
    assert_eq!((c1.fx, c1.fy, c1.cx, c1.cy), (40.0, 41.0, 4.0, 3.0), "{c1:?}");
}

/// `n` cameras of a pixelNeRF-layout DTU scan with 8x6 images: world_mat_i (K [R | t]
/// looking at the origin) and an identity scale_mat_i.
fn dtu_scan(root: &Path, n: usize) -> Vec<(String, Vec<f64>)> {
    for i in 0..n {
        write_png(&root.join(format!("image/{i:06}.png")), 8, 6);
    }
    common::dtu_camera_matrices(n, 8, 6, 1.0)
}

fn write_cameras(root: &Path, arrays: &[(String, Vec<f64>)]) {
    let views: Vec<(&str, &[usize], &[f64])> =
        arrays.iter().map(|(n, d)| (n.as_str(), &[4usize, 4][..], d.as_slice())).collect();
    edgenerf::data::npy::write_npz_f64(&root.join("cameras.npz"), &views).unwrap();
}

/// A DTU archive missing one view's scale_mat was read in DTU's unnormalised frame (far
/// bound 3.97 -> 618); one missing world_mat was reported as an image/camera count.
#[test]
fn dtu_archive_missing_a_views_matrix_names_it() {
    let dir = tempfile::tempdir().unwrap();
    // 49 views: the DTU protocol's split needs ids up to 48.
    let arrays = dtu_scan(dir.path(), 49);
    write_cameras(dir.path(), &arrays);
    assert_eq!(Scene::load(dir.path(), &LoadOptions::default()).unwrap().views.len(), 49);
    let npz = dir.path().join("cameras.npz");

    let without = |name: &str| arrays.iter().filter(|(n, _)| n != name).cloned().collect::<Vec<_>>();
    write_cameras(dir.path(), &without("scale_mat_2"));
    let (err, msg) = load_err(dir.path());
    assert!(matches!(err, DataError::Npy { .. }), "{err:?}");
    assert!(has(&msg, &npz) && msg.contains("no scale_mat_2"), "{msg}");

    write_cameras(dir.path(), &without("world_mat_1"));
    let (_, msg) = load_err(dir.path());
    assert!(has(&msg, &npz) && msg.contains("no world_mat_1"), "{msg}");

    // A singular projection.
    let mut bad = arrays.clone();
    bad[2].1 = vec![0.0; 16];
    write_cameras(dir.path(), &bad);
    let (_, msg) = load_err(dir.path());
    assert!(has(&msg, &npz) && msg.contains("world_mat_1"), "{msg}");
}

/// LLFF without images_8: the error lists the image folders the scene has and the
/// --llff-factor that reads each (it cited an internal API); the factor is honoured.
#[test]
fn llff_without_the_default_image_folder_says_which_factor_to_pass() {
    let dir = tempfile::tempdir().unwrap();
    llff_scene(dir.path(), 3);
    std::fs::rename(dir.path().join("images_8"), dir.path().join("images_4")).unwrap();
    let (_, msg) = load_err(dir.path());
    assert!(
        has(&msg, &dir.path().join("images_8")) && msg.contains("images_4 (--llff-factor 4)") && !msg.contains("LoadOptions"),
        "{msg}"
    );
    let scene = Scene::load(dir.path(), &LoadOptions { llff_factor: Some(4), ..Default::default() }).unwrap();
    assert_eq!(scene.views.len(), 3);
    // A pose whose rotation is scaled names its row.
    let mut rows = llff_scene(dir.path(), 3);
    rows[17] = 3.0;
    write_npy_f64(&dir.path().join("poses_bounds.npy"), &[3, 17], &rows).unwrap();
    let (_, msg) = load_err(dir.path());
    assert!(msg.contains("row 1") && msg.contains("orthonormal"), "{msg}");
}
