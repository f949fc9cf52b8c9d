//! Users' own scenes (issue 18): nerfstudio `transforms.json`, COLMAP sparse models
//! (text and binary), distorted lenses and the image downsampling factor.
//!
//! * The committed `creases` scene, rewritten as a nerfstudio file and as COLMAP models,
//!   gives the Blender loader's rays for every pixel of every view to 1e-5.
//! * OPENCV (COLMAP) and OPENCV_FISHEYE (nerfstudio) cameras: known 3D points projected
//!   with the distortion models written here independently land on pixels whose loaded
//!   rays pass through the points.
//! * A forward-facing COLMAP capture is the LLFF scene of the same cameras and bounds.
//! * `box_scale` widens a world-space scene's box about its centre and moves `far` to its
//!   far corners; an NDC scene refuses it.
//! * Bad inputs: a missing `cameras.bin`, an unknown or unsupported camera model, a
//!   truncated binary file, an ambiguous folder.

mod common;

use std::path::Path;

use common::colmap::{Cam, Img, pose_of, write_binary, write_text};
use edgenerf::data::npy::write_npy_f64;
use edgenerf::data::{Lens, LoadOptions, Scene, SceneFormat};
use glam::{DMat4, DVec2, DVec3, Mat4, Vec3};
use serde_json::json;

fn creases() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("synthetic-scenes/small/creases")
}

fn headers_only() -> LoadOptions {
    LoadOptions { load_images: false, ..Default::default() }
}

/// Copies `train/` and `test/` pictures of creases into `dest` (no ground truth).
fn copy_images(dest: &Path) {
    for split in ["train", "test"] {
        std::fs::create_dir_all(dest.join(split)).unwrap();
        for e in std::fs::read_dir(creases().join(split)).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_str().unwrap().to_string();
            let stem = name.strip_prefix("r_").and_then(|s| s.strip_suffix(".png"));
            if stem.is_some_and(|s| s.chars().all(|c| c.is_ascii_digit())) {
                std::fs::copy(&p, dest.join(split).join(&name)).unwrap();
            }
        }
    }
}

/// Every pixel's ray of every view of `other` against the Blender scene's view of the
/// same image file (`split/name`), to `tol`.
fn assert_same_rays(blender: &Scene, other: &Scene, tol: f32) {
    assert_eq!(blender.views.len(), other.views.len());
    let key = |v: &edgenerf::data::View| {
        let p = &v.path;
        format!("{}/{}", p.parent().unwrap().file_name().unwrap().to_str().unwrap(), p.file_stem().unwrap().to_str().unwrap())
    };
    let mut worst = 0.0f32;
    for (bi, bv) in blender.views.iter().enumerate() {
        let oi = other.views.iter().position(|v| key(v) == key(bv)).unwrap_or_else(|| panic!("no view {}", key(bv)));
        assert_eq!(other.image_size(), blender.image_size());
        let (a, b) = (blender.image_rays(bi), other.image_rays(oi));
        for (ra, rb) in a.iter().zip(&b) {
            worst = worst.max((ra.origin - rb.origin).abs().max_element()).max((ra.dir - rb.dir).abs().max_element());
        }
    }
    assert!(worst < tol, "largest ray difference {worst}");
}

/// creases' cameras as COLMAP cameras and images (one PINHOLE camera, Blender's
/// intrinsics), names `train/r_000.png` ...
fn creases_colmap(blender: &Scene) -> (Vec<Cam>, Vec<Img>) {
    let c = blender.views[0].camera;
    let cams = vec![Cam {
        id: 3,
        model: "PINHOLE",
        model_id: 1,
        width: 128,
        height: 128,
        params: vec![c.fx.into(), c.fy.into(), c.cx.into(), c.cy.into()],
    }];
    let imgs = blender
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (q, t) = pose_of(v.camera.c2w.as_dmat4());
            let split = v.path.parent().unwrap().file_name().unwrap().to_str().unwrap();
            Img { id: 100 + i as u32, q, t, camera: 3, name: format!("{split}/{}.png", v.name) }
        })
        .collect();
    (cams, imgs)
}

/// The corners and centre of creases' box: the "sparse points" of the tests.
fn box_points() -> Vec<DVec3> {
    let (lo, hi) = (DVec3::new(-1.3, -1.3, -0.1), DVec3::new(1.3, 1.3, 1.0));
    let mut pts: Vec<DVec3> = (0..8)
        .map(|i| DVec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z }))
        .collect();
    pts.push((lo + hi) / 2.0);
    pts
}

#[test]
fn colmap_text_and_binary_give_the_blender_rays() {
    let blender = Scene::load(creases(), &headers_only()).unwrap();
    let (cams, imgs) = creases_colmap(&blender);
    let points = box_points();
    let mut aabbs = Vec::new();
    for binary in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        copy_images(&dir.path().join("images"));
        let model = dir.path().join(if binary { "sparse/0" } else { "sparse" });
        if binary {
            write_binary(&model, &cams, &imgs, &points);
        } else {
            write_text(&model, &cams, &imgs, &points);
        }
        let scene = Scene::load(dir.path(), &headers_only()).unwrap();
        assert_eq!(scene.format, SceneFormat::Colmap);
        assert!(scene.ndc.is_none(), "an orbit is object-centric");
        assert_same_rays(&blender, &scene, 1e-5);
        // RGBA pictures: composited over the load background, which the scene records.
        assert_eq!(scene.background, Some([1.0; 3]));
        // Views sorted by name (colliding stems named by their folder), split as LLFF
        // (every 8th a test view).
        assert_eq!((scene.views[0].name.as_str(), scene.views[8].name.as_str()), ("test_r_000", "train_r_000"));
        assert_eq!(scene.split.test, vec![0, 8, 16, 24]);
        // Bounds from the points: the box holds every point, near is in front of all.
        let [lo, hi] = scene.aabb;
        assert!(points.iter().all(|p| p.as_vec3().cmpge(lo).all() && p.as_vec3().cmple(hi).all()), "{lo} {hi}");
        assert!((hi - lo - Vec3::new(2.6, 2.6, 1.1)).max_element() < 0.3, "{lo} {hi}");
        let closest = scene.views.iter().flat_map(|v| points.iter().map(move |p| v.camera.origin().distance(p.as_vec3()))).fold(f32::MAX, f32::min);
        assert!(scene.near > 0.0 && scene.near < closest && scene.far > closest, "{} {}", scene.near, scene.far);
        aabbs.push((scene.near, scene.far, scene.aabb));
    }
    assert_eq!(aabbs[0], aabbs[1], "text and binary models give the same bounds");
}

/// nerfstudio's transforms.json of creases: intrinsics at the top level for training
/// frames and per frame for test frames, the frames shuffled, ns-process-data's
/// applied_transform (which must not move the poses).
fn creases_transforms(blender: &Scene, extra: serde_json::Value) -> serde_json::Value {
    let c = blender.views[0].camera;
    let mut frames: Vec<serde_json::Value> = blender
        .views
        .iter()
        .map(|v| {
            let split = v.path.parent().unwrap().file_name().unwrap().to_str().unwrap();
            let m = v.camera.c2w.transpose().to_cols_array_2d();
            let mut f = json!({"file_path": format!("./{split}/{}.png", v.name), "transform_matrix": m});
            if split == "test" {
                for (k, val) in [("fl_x", c.fx), ("fl_y", c.fy), ("cx", c.cx), ("cy", c.cy)] {
                    f[k] = json!(val);
                }
            }
            f
        })
        .collect();
    frames.reverse();
    let mut t = json!({"camera_model": "OPENCV", "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy, "w": 128, "h": 128,
                       "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames,
                       "applied_transform": [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]});
    for (k, v) in extra.as_object().unwrap() {
        t[k] = v.clone();
    }
    t
}

#[test]
fn nerfstudio_gives_the_blender_rays_and_its_split() {
    let blender = Scene::load(creases(), &headers_only()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    copy_images(dir.path());
    let t = creases_transforms(&blender, json!({"near": 2.4, "far": 6.0, "aabb": [[-1.3, -1.3, -0.1], [1.3, 1.3, 1.0]]}));
    std::fs::write(dir.path().join("transforms.json"), t.to_string()).unwrap();
    let scene = Scene::load(dir.path(), &headers_only()).unwrap();
    assert_eq!(scene.format, SceneFormat::Nerfstudio);
    assert_same_rays(&blender, &scene, 1e-5);
    // The file's bounds win.
    assert_eq!((scene.near, scene.far), (blender.near, blender.far));
    assert_eq!(scene.aabb, blender.aabb);
    // Sorted by file_path (test/ before train/); nerfstudio's 0.9 fraction split of 32:
    // 29 training frames at np.linspace(0, 31, 29, dtype=int), which skips 10, 20 and 30.
    assert_eq!(scene.views[0].name, "test_r_000");
    assert_eq!(scene.split.train.len(), 29);
    assert_eq!(scene.split.test, vec![10, 20, 30]);
    // k views: spread over the training frames.
    let k3 = Scene::load(dir.path(), &LoadOptions { views: Some(3), ..headers_only() }).unwrap();
    assert_eq!(k3.split.train.len(), 3);
    assert_eq!(k3.split.test, scene.split.test);
    // An explicit split.
    let t = creases_transforms(&blender, json!({"train_filenames": ["train/r_001.png", "./train/r_005.png"], "test_filenames": ["test/r_002.png"]}));
    std::fs::write(dir.path().join("transforms.json"), t.to_string()).unwrap();
    let s = Scene::load(dir.path(), &headers_only()).unwrap();
    let names = |ids: &[usize]| ids.iter().map(|&i| s.views[i].path.strip_prefix(dir.path()).unwrap().to_str().unwrap().to_string()).collect::<Vec<_>>();
    assert_eq!(names(&s.split.train), vec!["train/r_001.png", "train/r_005.png"]);
    assert_eq!(names(&s.split.test), vec!["test/r_002.png"]);
}

/// The COLMAP model ns-process-data leaves in colmap/sparse/0 is in COLMAP's world;
/// applied_transform brings its points into the file's frame: the bounds equal those of
/// the COLMAP scene whose points are already in that frame.
#[test]
fn nerfstudio_points_go_through_applied_transform() {
    let blender = Scene::load(creases(), &headers_only()).unwrap();
    let (cams, imgs) = creases_colmap(&blender);
    let points = box_points();
    let colmap = colmap_scene_of(&cams, &imgs, &points);

    let ns = tempfile::tempdir().unwrap();
    copy_images(ns.path());
    std::fs::write(ns.path().join("transforms.json"), creases_transforms(&blender, json!({})).to_string()).unwrap();
    // COLMAP world = A^-1 (file world), A = [[1,0,0],[0,0,1],[0,-1,0]]: (x, y, z) -> (x, -z, y).
    let original: Vec<DVec3> = points.iter().map(|p| DVec3::new(p.x, -p.z, p.y)).collect();
    write_binary(&ns.path().join("colmap/sparse/0"), &cams, &imgs, &original);
    let scene = Scene::load(ns.path(), &headers_only()).unwrap();
    assert!(same_bounds(&scene, &colmap), "{} {} {:?} vs {} {} {:?}", scene.near, scene.far, scene.aabb, colmap.near, colmap.far, colmap.aabb);
}

/// The COLMAP text model of creases' cameras with `points`, loaded (headers only).
fn colmap_scene_of(cams: &[Cam], imgs: &[Img], points: &[DVec3]) -> Scene {
    let dir = tempfile::tempdir().unwrap();
    copy_images(&dir.path().join("images"));
    write_text(&dir.path().join("sparse/0"), cams, imgs, points);
    Scene::load(dir.path(), &headers_only()).unwrap()
}

/// Whether two scenes have the same near, far and box, to 1e-4.
fn same_bounds(a: &Scene, b: &Scene) -> bool {
    (a.near - b.near).abs() < 1e-4
        && (a.far - b.far).abs() < 1e-4
        && (a.aabb[0] - b.aabb[0]).abs().max_element() < 1e-4
        && (a.aabb[1] - b.aabb[1]).abs().max_element() < 1e-4
}

/// `ply_file_path` (ns-process-data's `sparse_pc.ply`, ASCII with 8-bit colours, in the
/// file's frame) bounds the scene as the COLMAP model of the same points does, and wins
/// over a `colmap/sparse/0` beside it; a binary little-endian cloud reads the same; a
/// missing or empty cloud is an error that names the key.
#[test]
fn nerfstudio_reads_the_point_cloud_of_ply_file_path() {
    let blender = Scene::load(creases(), &headers_only()).unwrap();
    let (cams, imgs) = creases_colmap(&blender);
    let points = box_points();
    let colmap = colmap_scene_of(&cams, &imgs, &points);

    let ns = tempfile::tempdir().unwrap();
    copy_images(ns.path());
    let t = creases_transforms(&blender, json!({"ply_file_path": "sparse_pc.ply"}));
    std::fs::write(ns.path().join("transforms.json"), t.to_string()).unwrap();
    // As nerfstudio's create_ply_from_colmap writes it.
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uint8 red\nproperty uint8 green\nproperty uint8 blue\nend_header\n",
        points.len()
    );
    for p in &points {
        ply += &format!("{:8} {:8} {:8} 120 30 200\n", p.x, p.y, p.z);
    }
    std::fs::write(ns.path().join("sparse_pc.ply"), &ply).unwrap();
    // A COLMAP model beside it whose points lie elsewhere: the cloud wins.
    let elsewhere: Vec<DVec3> = points.iter().map(|p| *p * 3.0).collect();
    write_binary(&ns.path().join("colmap/sparse/0"), &cams, &imgs, &elsewhere);
    let scene = Scene::load(ns.path(), &headers_only()).unwrap();
    assert!(same_bounds(&scene, &colmap), "{} {} {:?} vs {} {} {:?}", scene.near, scene.far, scene.aabb, colmap.near, colmap.far, colmap.aabb);
    // Without the key the COLMAP model's (different) points bound it.
    let t = creases_transforms(&blender, json!({}));
    std::fs::write(ns.path().join("transforms.json"), t.to_string()).unwrap();
    assert!(!same_bounds(&Scene::load(ns.path(), &headers_only()).unwrap(), &colmap));

    // Binary little-endian, in a subfolder, as other exporters write it.
    let cloud = edgenerf::mesh::TriMesh { positions: points.iter().map(|p| p.as_vec3()).collect(), ..Default::default() };
    std::fs::create_dir_all(ns.path().join("pc")).unwrap();
    std::fs::write(ns.path().join("pc/points.ply"), edgenerf::mesh::ply::points_to_ply(&cloud).unwrap()).unwrap();
    let t = creases_transforms(&blender, json!({"ply_file_path": "pc/points.ply"}));
    std::fs::write(ns.path().join("transforms.json"), t.to_string()).unwrap();
    assert!(same_bounds(&Scene::load(ns.path(), &headers_only()).unwrap(), &colmap));

    // A key whose file is missing, or a cloud without vertices: errors that say what to do.
    let t = creases_transforms(&blender, json!({"ply_file_path": "missing.ply"}));
    std::fs::write(ns.path().join("transforms.json"), t.to_string()).unwrap();
    let e = Scene::load(ns.path(), &headers_only()).expect_err("a missing point cloud is an error").to_string();
    assert!(e.contains("ply_file_path") && e.contains("missing.ply") && e.contains("remove the key"), "{e}");
    std::fs::write(ns.path().join("empty.ply"), "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n").unwrap();
    let t = creases_transforms(&blender, json!({"ply_file_path": "empty.ply"}));
    std::fs::write(ns.path().join("transforms.json"), t.to_string()).unwrap();
    let e = Scene::load(ns.path(), &headers_only()).expect_err("an empty point cloud is an error").to_string();
    assert!(e.contains("no vertices"), "{e}");
}

// ------------------------------------------------------------------ distorted lenses

/// An OpenGL camera-to-world at `eye` looking at `target` (`-z` toward it, `+y` up-ish).
fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> DMat4 {
    let z = (eye - target).normalize();
    let x = up.cross(z).normalize();
    let y = z.cross(x);
    DMat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), eye.extend(1.0))
}

/// Four cameras around the origin (an orbit: object-centric, world frame kept).
fn orbit() -> Vec<DMat4> {
    (0..4)
        .map(|i| {
            let a = i as f64 * std::f64::consts::FRAC_PI_2 + 0.3;
            let eye = DVec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.8);
            look_at(eye, DVec3::new(0.1, -0.1, 0.0), DVec3::Z)
        })
        .collect()
}

fn write_png(path: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([x as u8, y as u8, 9])).save(path).unwrap();
}

/// Reference OpenCV projection (radial k1, k2 and tangential p1, p2) of a world point
/// for an OpenGL c2w, written from OpenCV's documentation.
fn project_opencv(c2w: DMat4, k: [f64; 4], p: [f64; 2], f: [f64; 4], x: DVec3) -> DVec2 {
    let q = c2w.inverse().transform_point3(x);
    let (xc, yc, zc) = (q.x, -q.y, -q.z);
    let (u, v) = (xc / zc, yc / zc);
    let r2 = u * u + v * v;
    let radial = 1.0 + k[0] * r2 + k[1] * r2 * r2 + k[2] * r2.powi(3) + k[3] * r2.powi(4);
    let ud = u * radial + 2.0 * p[0] * u * v + p[1] * (r2 + 2.0 * u * u);
    let vd = v * radial + p[0] * (r2 + 2.0 * v * v) + 2.0 * p[1] * u * v;
    DVec2::new(f[0] * ud + f[2], f[1] * vd + f[3])
}

/// Reference OpenCV fisheye projection (k1..k4 on the angle from the axis).
fn project_fisheye(c2w: DMat4, k: [f64; 4], f: [f64; 4], x: DVec3) -> DVec2 {
    let q = c2w.inverse().transform_point3(x);
    let (xc, yc, zc) = (q.x, -q.y, -q.z);
    let r = (xc * xc + yc * yc).sqrt();
    let theta = r.atan2(zc);
    let t2 = theta * theta;
    let theta_d = theta * (1.0 + k[0] * t2 + k[1] * t2 * t2 + k[2] * t2.powi(3) + k[3] * t2.powi(4));
    DVec2::new(f[0] * theta_d * xc / r + f[2], f[1] * theta_d * yc / r + f[3])
}

/// Points spread in front of the cameras; for each view and point projecting into the
/// frame, the loaded ray of that pixel passes within `tol` of the point. Returns how
/// many (view, point) pairs were checked.
fn check_rays_through_points(scene: &Scene, poses: &[DMat4], project: &dyn Fn(DMat4, DVec3) -> DVec2, tol: f32) -> usize {
    let mut checked = 0;
    for (i, v) in scene.views.iter().enumerate() {
        let pose = poses[v.name[1..].parse::<usize>().unwrap()];
        assert!((v.camera.c2w.as_dmat4() - pose).to_cols_array().iter().all(|d| d.abs() < 1e-5), "view {i} keeps its pose");
        for a in 0..7 {
            for b in 0..7 {
                let x = DVec3::new(-0.9 + 0.3 * a as f64, -0.9 + 0.3 * b as f64, 0.15 * (a as f64 - b as f64));
                let px = project(pose, x);
                if !v.camera.in_frame(px.as_vec2()) {
                    continue;
                }
                let ray = scene.ray(i, 0, 0);
                assert_eq!(ray.origin, v.camera.origin());
                let ray = v.camera.pixel_ray(px.x as f32, px.y as f32);
                let to = x.as_vec3() - ray.origin;
                let miss = (to - ray.dir * to.dot(ray.dir)).length();
                assert!(miss < tol, "view {i}, point {x}: pixel {px} ray misses by {miss}");
                // And the camera projects the point back to the pixel.
                let (back, _) = v.camera.project(x.as_vec3()).unwrap();
                assert!((back.as_dvec2() - px).length() < 1e-3, "{back} vs {px}");
                checked += 1;
            }
        }
    }
    checked
}

#[test]
fn opencv_camera_rays_pass_through_projected_points() {
    let (w, h) = (64u32, 48u32);
    let (f, k, p) = ([52.0, 50.0, 31.5, 24.5], [-0.18, 0.04, 0.0, 0.0], [0.0015, -0.002]);
    let poses = orbit();
    let dir = tempfile::tempdir().unwrap();
    let cams = vec![Cam { id: 1, model: "OPENCV", model_id: 4, width: w as u64, height: h as u64, params: vec![f[0], f[1], f[2], f[3], k[0], k[1], p[0], p[1]] }];
    let imgs: Vec<Img> = poses
        .iter()
        .enumerate()
        .map(|(i, &c2w)| {
            write_png(&dir.path().join(format!("images/v{i}.png")), w, h);
            let (q, t) = pose_of(c2w);
            Img { id: i as u32 + 1, q, t, camera: 1, name: format!("v{i}.png") }
        })
        .collect();
    write_text(&dir.path().join("sparse/0"), &cams, &imgs, &[DVec3::ZERO, DVec3::ONE, -DVec3::ONE]);
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views[0].camera.lens, Lens::OpenCv { k: [-0.18, 0.04, 0.0, 0.0], p: [0.0015, -0.002] });
    let n = check_rays_through_points(&scene, &poses, &|c2w, x| project_opencv(c2w, k, p, f, x), 2e-5);
    assert!(n > 40, "{n} points checked");
    // A pinhole reading of the same pixels would miss: distortion is not dropped.
    let cam = scene.views[0].camera;
    let corner = edgenerf::data::Camera { lens: Lens::Pinhole, ..cam }.pixel_ray(2.0, 2.0).dir;
    assert!((corner - cam.pixel_ray(2.0, 2.0).dir).length() > 1e-2);
}

#[test]
fn fisheye_camera_rays_pass_through_projected_points() {
    let (w, h) = (64u32, 48u32);
    let (f, k) = ([24.0, 24.5, 32.0, 23.5], [0.05, -0.02, 0.004, -0.001]);
    let poses = orbit();
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<serde_json::Value> = poses
        .iter()
        .enumerate()
        .map(|(i, c2w)| {
            write_png(&dir.path().join(format!("images/v{i}.png")), w, h);
            json!({"file_path": format!("images/v{i}.png"), "transform_matrix": c2w.transpose().to_cols_array_2d()})
        })
        .collect();
    let t = json!({"camera_model": "OPENCV_FISHEYE", "fl_x": f[0], "fl_y": f[1], "cx": f[2], "cy": f[3], "w": w, "h": h,
                   "k1": k[0], "k2": k[1], "k3": k[2], "k4": k[3], "frames": frames});
    std::fs::write(dir.path().join("transforms.json"), t.to_string()).unwrap();
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views[0].camera.lens, Lens::Fisheye { k: [0.05, -0.02, 0.004, -0.001] });
    // Without points or keys: a cube around the cameras' focus reaching the cameras.
    assert!(scene.ndc.is_none() && scene.aabb[0].x < -2.5 && scene.aabb[1].x > 2.5, "{:?}", scene.aabb);
    let n = check_rays_through_points(&scene, &poses, &|c2w, x| project_fisheye(c2w, k, f, x), 2e-5);
    assert!(n > 40, "{n} points checked");
}

// ------------------------------------------------------------ forward-facing captures

/// A forward-facing COLMAP capture loads as the LLFF scene of the same cameras with the
/// bounds LLFF's imgs2poses would write (0.1 / 99.9 percentiles of the points' z-depths).
#[test]
fn forward_facing_colmap_is_the_llff_scene() {
    let (w, h, fl) = (32u32, 24u32, 30.0f64);
    let dir = tempfile::tempdir().unwrap();
    let llff = tempfile::tempdir().unwrap();
    // Five cameras sliding along x, looking down -z with small turns.
    let poses: Vec<DMat4> = (0..5)
        .map(|i| {
            let eye = DVec3::new(-0.4 + 0.2 * i as f64, 0.05 * i as f64, 0.0);
            look_at(eye, DVec3::new(0.0, 0.0, -6.0), DVec3::Y)
        })
        .collect();
    let points: Vec<DVec3> = (0..40).map(|i| DVec3::new(-1.0 + 0.05 * i as f64, 0.6 - 0.03 * i as f64, -3.0 - 0.1 * i as f64)).collect();
    let cams = vec![Cam { id: 1, model: "SIMPLE_PINHOLE", model_id: 0, width: w as u64, height: h as u64, params: vec![fl, 16.0, 12.0] }];
    let mut imgs = Vec::new();
    let mut rows = Vec::new();
    for (i, &c2w) in poses.iter().enumerate() {
        write_png(&dir.path().join(format!("images/img{i}.png")), w, h);
        write_png(&llff.path().join(format!("images/img{i}.png")), w, h);
        let (q, t) = pose_of(c2w);
        imgs.push(Img { id: i as u32 + 1, q, t, camera: 1, name: format!("img{i}.png") });
        // The depths of the points this camera sees (all in frame, checked below).
        let w2c = c2w.inverse();
        let mut z: Vec<f64> = points
            .iter()
            .map(|p| {
                let q = w2c.transform_point3(*p);
                let px = DVec2::new(16.0 + fl * q.x / -q.z, 12.0 - fl * q.y / -q.z);
                assert!(px.x >= 0.0 && px.x < w as f64 && px.y >= 0.0 && px.y < h as f64, "point out of frame");
                -q.z
            })
            .collect();
        z.sort_by(f64::total_cmp);
        let pct = |q: f64| {
            let pos = q / 100.0 * (z.len() - 1) as f64;
            let j = pos.floor() as usize;
            z[j] + (z[(j + 1).min(z.len() - 1)] - z[j]) * (pos - j as f64)
        };
        // poses_bounds row: [R | t | hwf] in LLFF's [down, right, back] axes, then near, far.
        let (x, y, zc, c) = (c2w.x_axis.truncate(), c2w.y_axis.truncate(), c2w.z_axis.truncate(), c2w.w_axis.truncate());
        let cols = [-y, x, zc, c];
        for r in 0..3 {
            for col in cols {
                rows.push(col[r]);
            }
            rows.push([h as f64, w as f64, fl][r]);
        }
        rows.extend([pct(0.1), pct(99.9)]);
    }
    write_binary(&dir.path().join("sparse/0"), &cams, &imgs, &points);
    write_npy_f64(&llff.path().join("poses_bounds.npy"), &[5, 17], &rows).unwrap();
    let opts = LoadOptions { llff_factor: Some(1), ..headers_only() };
    let a = Scene::load(llff.path(), &opts).unwrap();
    let b = Scene::load(dir.path(), &headers_only()).unwrap();
    assert_eq!(b.format, SceneFormat::Colmap);
    assert_eq!((b.near, b.far, b.aabb, b.ndc), (a.near, a.far, a.aabb, a.ndc));
    assert_eq!(b.far, 1.0);
    // With the far bound, both end at 1.1 times the farthest far bound, as an NDC ray
    // parameter: the COLMAP model's from its points as imgs2poses would write it.
    let bounded = LoadOptions { ndc_far_bound: true, ..headers_only() };
    let a = Scene::load(llff.path(), &LoadOptions { llff_factor: Some(1), ..bounded.clone() }).unwrap();
    let b = Scene::load(dir.path(), &bounded).unwrap();
    let bound = |col: usize| rows.chunks(17).map(move |r| r[col]);
    let (near, far) = (bound(15).fold(f64::INFINITY, f64::min), bound(16).fold(0.0, f64::max));
    let far_t = 1.0 - 1.0 / (1.1 * far / (near * 0.75));
    assert!((f64::from(b.far) - far_t).abs() < 1e-5 && b.far < 1.0, "far {} against {far_t}", b.far);
    assert_eq!(a.far, b.far);
    assert_eq!(a.split, b.split);
    for v in 0..5 {
        for (ra, rb) in a.image_rays(v).iter().zip(&b.image_rays(v)) {
            assert!((ra.origin - rb.origin).abs().max_element() < 1e-4 && (ra.dir - rb.dir).abs().max_element() < 1e-4, "{ra:?} {rb:?}");
        }
    }
}

// ------------------------------------------------------------------ box scale

/// `box_scale` scales the box about its centre and moves `far` out until every camera
/// reaches the far corner of the larger box; cameras and rays are unchanged. An NDC
/// scene (forward-facing LLFF) refuses any scale but 1 with a message naming the key.
#[test]
fn box_scale_widens_the_box_and_far_reaches_it() {
    let plain = Scene::load(creases(), &headers_only()).unwrap();
    let wide = Scene::load(creases(), &LoadOptions { box_scale: 2.5, ..headers_only() }).unwrap();
    let [lo, hi] = plain.aabb;
    let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
    for (got, want) in wide.aabb.iter().zip([centre - 2.5 * half, centre + 2.5 * half]) {
        assert!((*got - want).abs().max_element() < 1e-5, "{:?} vs {want}", wide.aabb);
    }
    assert_eq!(wide.near, plain.near);
    let far_corner = |o: Vec3| {
        let pick = |axis: usize| if (o[axis] - wide.aabb[0][axis]).abs() > (o[axis] - wide.aabb[1][axis]).abs() { wide.aabb[0][axis] } else { wide.aabb[1][axis] };
        o.distance(Vec3::new(pick(0), pick(1), pick(2)))
    };
    let reach = wide.views.iter().map(|v| far_corner(v.camera.origin())).fold(0.0f32, f32::max);
    assert!(wide.far >= reach - 1e-4 && wide.far >= plain.far, "far {} (plain {}), farthest corner {reach}", wide.far, plain.far);
    assert!(reach > plain.far, "the test needs a box that reaches past the plain far ({reach} vs {})", plain.far);
    for v in 0..plain.views.len() {
        assert_eq!(plain.image_rays(v), wide.image_rays(v));
    }
    // A scale below 1 narrows the box and keeps far.
    let narrow = Scene::load(creases(), &LoadOptions { box_scale: 0.5, ..headers_only() }).unwrap();
    assert!(((narrow.aabb[1] - narrow.aabb[0]) - (hi - lo) * 0.5).abs().max_element() < 1e-5);
    assert_eq!(narrow.far, plain.far);

    let llff = tempfile::tempdir().unwrap();
    let mut rows = Vec::new();
    for i in 0..3 {
        rows.extend_from_slice(&[1.0, 0.0, 0.0, i as f64 * 0.1, 6.0, 0.0, 1.0, 0.0, 0.0, 8.0, 0.0, 0.0, 1.0, 0.0, 10.0, 2.0, 20.0]);
        write_png(&llff.path().join(format!("images/img{i}.png")), 8, 6);
    }
    write_npy_f64(&llff.path().join("poses_bounds.npy"), &[3, 17], &rows).unwrap();
    let opts = LoadOptions { llff_factor: Some(1), ..headers_only() };
    assert!(Scene::load(llff.path(), &opts).unwrap().ndc.is_some());
    let err = Scene::load(llff.path(), &LoadOptions { box_scale: 2.0, ..opts }).expect_err("NDC refuses a box scale").to_string();
    assert!(err.contains("box_scale") && err.contains("NDC"), "{err}");
}

// --------------------------------------------------------- downsampling on load

/// Without images_N the full images are downsampled by area on load; intrinsics follow.
#[test]
fn missing_images_n_folder_is_downsampled_on_load() {
    let dir = tempfile::tempdir().unwrap();
    let mut rows = Vec::new();
    for i in 0..3 {
        rows.extend_from_slice(&[1.0, 0.0, 0.0, i as f64 * 0.1, 12.0, 0.0, 1.0, 0.0, 0.0, 16.0, 0.0, 0.0, 1.0, 0.0, 40.0, 2.0, 20.0]);
        let p = dir.path().join(format!("images/img{i}.png"));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        image::RgbImage::from_fn(16, 12, |x, y| image::Rgb([(x * 10) as u8, (y * 20) as u8, 200])).save(&p).unwrap();
    }
    write_npy_f64(&dir.path().join("poses_bounds.npy"), &[3, 17], &rows).unwrap();
    let s = Scene::load(dir.path(), &LoadOptions { llff_factor: Some(4), ..Default::default() }).unwrap();
    assert_eq!(s.image_size(), (4, 3));
    let c = s.views[0].camera;
    assert_eq!((c.fx, c.cx, c.cy), (10.0, 2.0, 1.5));
    // Pixel (1, 2) averages x 4..8, y 8..12: red mean 55, green mean 190.
    let px = s.views[0].image.get(1, 2);
    assert!((px[0] - 55.0 / 255.0).abs() < 1e-5 && (px[1] - 190.0 / 255.0).abs() < 1e-5, "{px:?}");
}

// ----------------------------------------------------------------------- bad inputs

fn load_err(dir: &Path) -> String {
    Scene::load(dir, &headers_only()).map(|_| ()).unwrap_err().to_string()
}

#[test]
fn bad_colmap_and_nerfstudio_inputs_are_clear_errors() {
    let blender = Scene::load(creases(), &headers_only()).unwrap();
    let (mut cams, imgs) = creases_colmap(&blender);
    let points = box_points();
    let dir = tempfile::tempdir().unwrap();
    copy_images(&dir.path().join("images"));
    let model = dir.path().join("sparse/0");

    // Missing cameras.bin (images and points present).
    write_binary(&model, &cams, &imgs, &points);
    std::fs::remove_file(model.join("cameras.bin")).unwrap();
    let msg = load_err(dir.path());
    assert!(msg.contains("cameras.bin or cameras.txt") && msg.contains("sparse"), "{msg}");

    // A truncated images.bin.
    write_binary(&model, &cams, &imgs, &points);
    let bytes = std::fs::read(model.join("images.bin")).unwrap();
    std::fs::write(model.join("images.bin"), &bytes[..bytes.len() / 2]).unwrap();
    let msg = load_err(dir.path());
    assert!(msg.contains("images.bin") && msg.contains("truncated"), "{msg}");

    // A missing points3D (model files must come together).
    write_binary(&model, &cams, &imgs, &points);
    std::fs::remove_file(model.join("points3D.bin")).unwrap();
    let msg = load_err(dir.path());
    assert!(msg.contains("points3D.bin") && msg.contains("not found"), "{msg}");
    std::fs::remove_dir_all(&model).unwrap();

    // An unknown model name (text) and an unknown model id (binary).
    let text = dir.path().join("sparse");
    write_text(&text, &cams, &imgs, &points);
    let c = std::fs::read_to_string(text.join("cameras.txt")).unwrap().replace("PINHOLE", "PINHOL");
    std::fs::write(text.join("cameras.txt"), c).unwrap();
    let msg = load_err(dir.path());
    assert!(msg.contains("cameras.txt") && msg.contains("unknown camera model \"PINHOL\""), "{msg}");
    std::fs::remove_dir_all(&text).unwrap();
    cams[0].model_id = 42;
    write_binary(&model, &cams, &imgs, &points);
    let msg = load_err(dir.path());
    assert!(msg.contains("cameras.bin") && msg.contains("unknown camera model id 42"), "{msg}");

    // A model COLMAP knows that the ray generator does not.
    cams[0] = Cam { id: 3, model: "FULL_OPENCV", model_id: 6, width: 128, height: 128, params: vec![170.0, 170.0, 64.0, 64.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] };
    write_binary(&model, &cams, &imgs, &points);
    let msg = load_err(dir.path());
    assert!(msg.contains("FULL_OPENCV is not supported") && msg.contains("image_undistorter"), "{msg}");

    // A missing image.
    cams[0] = Cam { id: 3, model: "SIMPLE_RADIAL", model_id: 2, width: 128, height: 128, params: vec![170.0, 64.0, 64.0, 0.01] };
    write_binary(&model, &cams, &imgs, &points);
    std::fs::remove_file(dir.path().join("images/train/r_003.png")).unwrap();
    let msg = load_err(dir.path());
    assert!(msg.contains("r_003.png") && msg.contains("missing image"), "{msg}");

    // nerfstudio beside a Blender layout: ambiguous.
    let both = tempfile::tempdir().unwrap();
    std::fs::write(both.path().join("transforms.json"), "{}").unwrap();
    std::fs::write(both.path().join("transforms_train.json"), "{}").unwrap();
    let msg = load_err(both.path());
    assert!(msg.contains("ambiguous"), "{msg}");

    // A forward-facing nerfstudio capture with nothing to bound its depth.
    let ff = tempfile::tempdir().unwrap();
    write_png(&ff.path().join("a.png"), 8, 6);
    let pose = Mat4::IDENTITY.to_cols_array_2d();
    let t = json!({"fl_x": 8.0, "frames": [{"file_path": "a.png", "transform_matrix": pose}, {"file_path": "a.png", "transform_matrix": pose}]});
    std::fs::write(ff.path().join("transforms.json"), t.to_string()).unwrap();
    let msg = load_err(ff.path());
    assert!(msg.contains("forward-facing") && msg.contains("\"near\""), "{msg}");
    // The near key is enough: an NDC scene, its rays to infinity.
    let t = json!({"fl_x": 8.0, "near": 0.5, "frames": [{"file_path": "a.png", "transform_matrix": pose}]});
    std::fs::write(ff.path().join("transforms.json"), t.to_string()).unwrap();
    let scene = Scene::load(ff.path(), &headers_only()).unwrap();
    assert!(scene.ndc.is_some() && scene.far == 1.0, "{}", scene.far);
    let bounded = LoadOptions { ndc_far_bound: true, ..headers_only() };
    assert_eq!(Scene::load(ff.path(), &bounded).unwrap().far, 1.0, "no far bound to end at");
    // With a far key and the far bound they end at 1.1 times it: 4 rescaled by 1 / (0.5 * 0.75).
    let t = json!({"fl_x": 8.0, "near": 0.5, "far": 4.0, "frames": [{"file_path": "a.png", "transform_matrix": pose}]});
    std::fs::write(ff.path().join("transforms.json"), t.to_string()).unwrap();
    let far_t = 1.0 - 1.0 / (1.1 * 4.0 / (0.5 * 0.75));
    assert!((Scene::load(ff.path(), &bounded).unwrap().far - far_t).abs() < 1e-6);
    assert_eq!(Scene::load(ff.path(), &headers_only()).unwrap().far, 1.0);
    // mask_path on some frames only.
    let t = json!({"fl_x": 8.0, "near": 0.5, "frames": [{"file_path": "a.png", "transform_matrix": pose, "mask_path": "a.png"},
                                                         {"file_path": "a.png", "transform_matrix": pose}]});
    std::fs::write(ff.path().join("transforms.json"), t.to_string()).unwrap();
    let msg = load_err(ff.path());
    assert!(msg.contains("mask_path is given for 1 of 2 frames"), "{msg}");
}

/// nerfstudio depth (16-bit PNG, millimetres, z-depth) becomes the view's ray distance;
/// masks load as the view's mask.
#[test]
fn nerfstudio_depth_and_masks() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("images/a.png"), 8, 6);
    std::fs::create_dir_all(dir.path().join("depths")).unwrap();
    image::ImageBuffer::<image::Luma<u16>, _>::from_fn(8, 6, |_, _| image::Luma([2000u16])).save(dir.path().join("depths/a.png")).unwrap();
    image::GrayImage::from_fn(8, 6, |x, _| image::Luma([if x < 4 { 0 } else { 255 }])).save(dir.path().join("mask.png")).unwrap();
    let pose = Mat4::IDENTITY.to_cols_array_2d();
    let t = json!({"fl_x": 8.0, "fl_y": 8.0, "cx": 4.0, "cy": 3.0, "near": 0.5,
                   "frames": [{"file_path": "images/a.png", "transform_matrix": pose, "depth_file_path": "depths/a.png", "mask_path": "mask.png"}]});
    std::fs::write(dir.path().join("transforms.json"), t.to_string()).unwrap();
    let s = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    let v = &s.views[0];
    let mask = v.mask.as_ref().unwrap();
    assert_eq!((mask[0], mask[7]), (0.0, 1.0));
    // Forward-facing: depth rescaled with the poses (sc = 1 / (0.5 * 0.75)); each
    // pixel's ray is longer than the z-depth 2 m by 1 / cos of its angle to the axis.
    let depth = v.depth.as_ref().unwrap();
    let sc = 1.0 / (0.5 * 0.75);
    for (x, y) in [(0u32, 0u32), (4, 3), (7, 5)] {
        let (dx, dy) = ((x as f32 + 0.5 - 4.0) / 8.0, (y as f32 + 0.5 - 3.0) / 8.0);
        let want = 2.0 * sc * (1.0 + dx * dx + dy * dy).sqrt();
        let got = depth[(y * 8 + x) as usize];
        assert!((got - want).abs() < 1e-4, "pixel ({x}, {y}): {got} vs {want}");
    }
}
