//! DTU scans, in the IDR layout (`cameras_sphere.npz`) and the pixelNeRF/RegNeRF layout
//! (`cameras.npz`); both share this code.
//!
//! * Cameras: `world_mat_i` (the 3x4 or 4x4 projection `K [R | t]` of view `i`, every `i`
//!   in `0..n` present) and the optional `scale_mat_i` (maps the normalised frame to
//!   DTU's world; for every view or for none, a missing one is an error naming it). The projection
//!   of the normalised frame is `P = world_mat @ scale_mat`; its left 3x3 is split by an
//!   RQ decomposition into `K` (upper triangular, positive diagonal, `K[2][2] = 1`) and a
//!   rotation `R`, and the camera centre is `-M^-1 p4` (as `cv2.decomposeProjectionMatrix`
//!   in IDR's `load_K_Rt_from_P`). The OpenCV camera (x right, y down, z forward) is
//!   turned into our OpenGL frame by flipping its `y` and `z` axes. World frame = the
//!   normalised frame (no extra world flip), where the object lies in the unit sphere.
//! * Resolution: DTU's `K` refers to the full-resolution images (1600x1200) even when
//!   the shipped images are smaller. The downsampling factor is
//!   `round(2 cx / width)` (the principal point is near the centre of the full image),
//!   required to agree with `round(2 cy / height)`; `fx, fy, cx, cy` are divided by it
//!   (as RegNeRF: no half-pixel shift).
//! * Images: `image/*.{png,jpg}` sorted by name (or, without `image/`, the `rect_*`
//!   files of the scan folder, lighting 3 `*_3_r5000*` when present); view `i` is the
//!   `i`-th image and uses `world_mat_i`. Masks: `mask/*` sorted by name, matched by
//!   position (IDR names them `000.png` while images are `000000.png`), values in
//!   `[0, 1]` in [`View::mask`].
//! * Near/far: pixelNeRF layout: RegNeRF's `0.5 / 3.5`. IDR layout (unit-sphere
//!   normalisation, object within radius 1): `near = max(min_i |C_i| - 1, 0.1 min_i |C_i|)`
//!   and `far = max_i |C_i| + 1` from the camera-centre distances `|C_i|` to the origin.
//!   `aabb` is `[-1, 1]^3` for both.
//! * Split: [`dtu_split`] (pixelNeRF ids; view id = image index).

use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DVec3, DVec4, Vec3};

use super::image_io::{SizeGuard, file_stem, list_images, read_view_image, read_view_mask};
use super::npy::{NpyArray, Npz};
use super::split::dtu_split;
use super::{Camera, DataError, LoadOptions, Scene, SceneFormat, View};

/// RegNeRF's DTU near/far after pixelNeRF's normalisation.
const PIXELNERF_NEAR_FAR: (f32, f32) = (0.5, 3.5);

/// A decomposed projection matrix `P = K [R | -R C]` (OpenCV camera frame).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Decomposed {
    /// Intrinsics, upper triangular, positive diagonal, `k[2][2] = 1` (`K.col(c).row(r)`).
    pub k: DMat3,
    /// World-to-camera rotation (proper: `det = +1`).
    pub r: DMat3,
    /// Camera centre in world coordinates.
    pub center: DVec3,
}

/// Splits the 3x4 projection `p` (rows) into intrinsics, rotation and centre by an RQ
/// decomposition of its left 3x3 block (Gram-Schmidt from the last row up). The overall
/// sign of `p` is fixed so that `det(M) > 0`, which makes `R` a proper rotation and
/// points in front of the camera have positive depth. `None` if `p` is degenerate.
pub(crate) fn decompose_projection(p: [[f64; 4]; 3]) -> Option<Decomposed> {
    let row = |r: usize| DVec3::new(p[r][0], p[r][1], p[r][2]);
    let (mut m1, mut m2, mut m3) = (row(0), row(1), row(2));
    let mut p4 = DVec3::new(p[0][3], p[1][3], p[2][3]);
    let det = DMat3::from_cols(m1, m2, m3).determinant();
    if !det.is_finite() || det.abs() < 1e-300 {
        return None;
    }
    if det < 0.0 {
        (m1, m2, m3, p4) = (-m1, -m2, -m3, -p4);
    }
    let k33 = m3.length();
    let r3 = m3 / k33;
    let k23 = m2.dot(r3);
    let v2 = m2 - k23 * r3;
    let k22 = v2.length();
    let r2 = v2 / k22;
    let (k13, k12) = (m1.dot(r3), m1.dot(r2));
    let v1 = m1 - k12 * r2 - k13 * r3;
    let k11 = v1.length();
    let r1 = v1 / k11;
    // glam matrices are column-major: build the transposes of the row layouts.
    let k = DMat3::from_cols(
        DVec3::new(k11, 0.0, 0.0),
        DVec3::new(k12, k22, 0.0),
        DVec3::new(k13, k23, k33),
    ) / k33;
    let r = DMat3::from_cols(r1, r2, r3).transpose();
    let m = DMat3::from_cols(m1, m2, m3).transpose();
    let center = -(m.inverse() * p4);
    let ok = k.is_finite() && r.is_finite() && center.is_finite() && k11 > 0.0 && k22 > 0.0;
    ok.then_some(Decomposed { k, r, center })
}

/// Reads array `name` of shape `4x4` (or `3x4`, completed with `[0, 0, 0, 1]`).
fn matrix4(npz: &Npz, name: &str, a: &NpyArray) -> Result<DMat4, DataError> {
    let rows = a.shape.first().copied().unwrap_or(0);
    if !(a.shape.len() == 2 && a.shape[1] == 4 && (rows == 3 || rows == 4)) {
        a.expect_shape(npz.path(), name, &[Some(4), Some(4)])?;
    }
    check_finite(npz.path(), name, a)?;
    let r = |i: usize| {
        if i < rows {
            DVec4::from_slice(&a.data[i * 4..i * 4 + 4])
        } else {
            DVec4::new(0.0, 0.0, 0.0, 1.0)
        }
    };
    Ok(DMat4::from_cols(r(0), r(1), r(2), r(3)).transpose())
}

fn check_finite(path: &Path, name: &str, a: &NpyArray) -> Result<(), DataError> {
    if a.data.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(DataError::NonFinite {
            path: path.to_path_buf(),
            what: format!("{name} contains NaN or infinite values"),
        })
    }
}

/// The OpenGL camera of view `i` at full resolution (intrinsics not yet scaled).
fn full_res_camera(npz: &Npz, i: usize) -> Result<(Decomposed, glam::Mat4), DataError> {
    let world_name = format!("world_mat_{i}");
    let world = matrix4(npz, &world_name, npz.require(&world_name)?)?;
    let scale_name = format!("scale_mat_{i}");
    let scale = match npz.get(&scale_name) {
        Some(a) => matrix4(npz, &scale_name, a)?,
        None => DMat4::IDENTITY,
    };
    let p = world * scale;
    let rows = [0, 1, 2].map(|r| p.row(r).to_array());
    let d = decompose_projection(rows).ok_or_else(|| DataError::NonFinite {
        path: npz.path().to_path_buf(),
        what: format!("{world_name} @ scale_mat_{i} is not a valid projection matrix (singular)"),
    })?;
    // Camera-to-world in OpenCV axes is [R^T | C]; flip the camera's y and z for OpenGL.
    let rt = d.r.transpose();
    let c2w = DMat4::from_cols(
        rt.x_axis.extend(0.0),
        (-rt.y_axis).extend(0.0),
        (-rt.z_axis).extend(0.0),
        d.center.extend(1.0),
    );
    Ok((d, c2w.as_mat4()))
}

/// Image files of a scan: `image/`, or the `rect_*` files of the scan folder.
fn scan_images(root: &Path) -> Result<(PathBuf, Vec<PathBuf>), DataError> {
    let dir = root.join("image");
    if dir.is_dir() {
        let files = list_images(&dir, "DTU image folder")?;
        return Ok((dir, files));
    }
    let rect: Vec<PathBuf> = list_images(root, "DTU scan folder")?
        .into_iter()
        .filter(|p| file_stem(p).starts_with("rect_"))
        .collect();
    if rect.is_empty() {
        return Err(DataError::NotFound {
            path: dir,
            what: "DTU image folder (image/ or rect_* files)",
        });
    }
    let lit: Vec<PathBuf> = rect
        .iter()
        .filter(|p| file_stem(p).contains("_3_r5000"))
        .cloned()
        .collect();
    Ok((root.to_path_buf(), if lit.is_empty() { rect } else { lit }))
}

/// Ids `i` of the arrays `{prefix}{i}`, sorted.
fn ids(npz: &Npz, prefix: &str) -> Vec<usize> {
    let mut ids: Vec<usize> = npz
        .names()
        .filter_map(|n| n.strip_prefix(prefix).and_then(|i| i.parse::<usize>().ok()))
        .collect();
    ids.sort_unstable();
    ids
}

/// Number of cameras: `world_mat_0..n` must all be present, and `scale_mat_0..n` all
/// or none (a view without its `scale_mat` would be read in DTU's unnormalised frame,
/// hundreds of units away: its far bound jumped from 3.97 to 618).
fn camera_count(npz: &Npz) -> Result<usize, DataError> {
    let world = ids(npz, "world_mat_");
    let n = world.last().map_or(0, |&last| last + 1);
    let missing = |have: &[usize]| (0..n).find(|i| have.binary_search(i).is_err());
    if let Some(i) = missing(&world) {
        return Err(DataError::Npy {
            path: npz.path().to_path_buf(),
            message: format!(
                "the archive has no world_mat_{i}, but has world_mat_ up to {}: every view 0..{n} needs its \
                 projection matrix (a damaged or hand-edited archive; regenerate it)",
                n - 1
            ),
        });
    }
    if n == 0 {
        return Err(DataError::Npy {
            path: npz.path().to_path_buf(),
            message: "the archive holds no world_mat_<i> arrays (the cameras of a DTU scan)".into(),
        });
    }
    let scale = ids(npz, "scale_mat_");
    if !scale.is_empty()
        && let Some(i) = missing(&scale)
    {
        return Err(DataError::Npy {
            path: npz.path().to_path_buf(),
            message: format!(
                "the archive has no scale_mat_{i}, but has scale_mat_ for other views: each view needs its \
                 normalisation (or none has one); regenerate the archive"
            ),
        });
    }
    Ok(n)
}

pub(super) fn load(
    root: &Path,
    format: SceneFormat,
    opts: &LoadOptions,
) -> Result<Scene, DataError> {
    let npz_name = if format == SceneFormat::DtuIdr {
        "cameras_sphere.npz"
    } else {
        "cameras.npz"
    };
    let npz = Npz::read(&root.join(npz_name))?;
    let (image_dir, images) = scan_images(root)?;
    let n = camera_count(&npz)?;
    if images.len() != n {
        return Err(DataError::CountMismatch {
            path: image_dir,
            images: images.len(),
            cameras: n,
        });
    }
    let mask_dir = root.join("mask");
    let masks = if opts.load_images && mask_dir.is_dir() {
        let masks = list_images(&mask_dir, "DTU mask folder")?;
        if masks.len() != n {
            return Err(DataError::invalid(
                &mask_dir,
                format!(
                    "{} masks for {n} images; provide one mask per image (matched in name order) or remove the folder",
                    masks.len()
                ),
            ));
        }
        Some(masks)
    } else {
        None
    };

    let mut guard = SizeGuard::default();
    let mut views = Vec::with_capacity(n);
    for (i, path) in images.iter().enumerate() {
        let (d, c2w) = full_res_camera(&npz, i)?;
        let img = read_view_image(path, opts.load_images, [0.0; 3], &mut guard)?;
        let (w, h) = (img.info.width, img.info.height);
        let (cx, cy) = (d.k.z_axis.x, d.k.z_axis.y);
        let factor = (2.0 * cx / w as f64).round();
        if factor < 1.0 || factor != (2.0 * cy / h as f64).round() {
            return Err(DataError::invalid(
                path,
                format!(
                    "cannot relate the {w}x{h} image to the intrinsics of {npz_name} (principal point \
                     {cx:.1}, {cy:.1}): expected the image to be the full-resolution one downsampled by \
                     an integer factor"
                ),
            ));
        }
        let camera = Camera {
            width: w,
            height: h,
            fx: (d.k.x_axis.x / factor) as f32,
            fy: (d.k.y_axis.y / factor) as f32,
            cx: (cx / factor) as f32,
            cy: (cy / factor) as f32,
            c2w,
            lens: Default::default(),
        };
        if let Err(m) = camera.check() {
            return Err(DataError::NonFinite {
                path: npz.path().to_path_buf(),
                what: format!("camera {i} (world_mat_{i}): {m}"),
            });
        }
        let mask = match &masks {
            Some(masks) => Some(read_view_mask(&masks[i], path, (w, h))?),
            None => None,
        };
        views.push(View {
            name: file_stem(path),
            path: path.clone(),
            camera,
            image: img.image,
            mask,
            alpha: img.alpha,
            depth: None,
            normal: None,
            train_mask: None,
        });
    }

    let (near, far) = match format {
        SceneFormat::DtuIdr => unit_sphere_near_far(views.iter().map(|v| v.camera.origin())),
        _ => PIXELNERF_NEAR_FAR,
    };
    let split = dtu_split(n, opts.views).map_err(|m| DataError::invalid(root, m))?;
    Ok(Scene {
        root: root.to_path_buf(),
        format,
        views,
        split,
        near,
        far,
        ndc: None,
        aabb: [Vec3::splat(-1.0), Vec3::splat(1.0)],
        background: None,
    })
}

/// Near/far that enclose the unit sphere from every camera centre.
fn unit_sphere_near_far(centers: impl Iterator<Item = Vec3>) -> (f32, f32) {
    let (lo, hi) = centers
        .map(Vec3::length)
        .fold((f32::INFINITY, 0.0f32), |(lo, hi), d| {
            (lo.min(d), hi.max(d))
        });
    ((lo - 1.0).max(0.1 * lo), hi + 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rq_recovers_k_r_t() {
        let k = DMat3::from_cols(
            DVec3::new(2890.0, 0.0, 0.0),
            DVec3::new(1.5, 2880.0, 0.0),
            DVec3::new(823.2, 619.1, 1.0),
        );
        let r = DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.4);
        let center = DVec3::new(0.4, -1.2, 2.5);
        let t = -(r * center);
        for scale in [3.7, -0.02] {
            // P = s K [R | t], rows.
            let kr = k * r;
            let kt = k * t;
            let p = [0, 1, 2].map(|i| {
                let row = kr.row(i);
                [row.x * scale, row.y * scale, row.z * scale, kt[i] * scale]
            });
            let d = decompose_projection(p).unwrap();
            assert!((d.k - k).abs_diff_eq(DMat3::ZERO, 1e-6), "{:?}", d.k);
            assert!(d.r.abs_diff_eq(r, 1e-9), "{:?} vs {r:?}", d.r);
            assert!(d.center.abs_diff_eq(center, 1e-9));
        }
        assert!(decompose_projection([[0.0; 4]; 3]).is_none());
    }

    #[test]
    fn opencv_to_opengl_projection_agrees() {
        // A point projected by P (OpenCV) and by our camera (OpenGL) lands on the same pixel.
        let r = DMat3::from_euler(glam::EulerRot::XYZ, -0.2, 0.5, 0.1);
        let center = DVec3::new(0.3, 0.2, -2.8);
        let k = DMat3::from_cols(
            DVec3::new(300.0, 0.0, 0.0),
            DVec3::new(0.0, 310.0, 0.0),
            DVec3::new(200.0, 150.0, 1.0),
        );
        let (kr, kt) = (k * r, k * -(r * center));
        let p = [0, 1, 2].map(|i| {
            let row = kr.row(i);
            [row.x, row.y, row.z, kt[i]]
        });
        let mut npz_like = DMat4::IDENTITY;
        for (i, row) in p.iter().enumerate() {
            npz_like.x_axis[i] = row[0];
            npz_like.y_axis[i] = row[1];
            npz_like.z_axis[i] = row[2];
            npz_like.w_axis[i] = row[3];
        }
        let d = decompose_projection(p).unwrap();
        let rt = d.r.transpose();
        let c2w = DMat4::from_cols(
            rt.x_axis.extend(0.0),
            (-rt.y_axis).extend(0.0),
            (-rt.z_axis).extend(0.0),
            d.center.extend(1.0),
        );
        let cam = Camera {
            width: 400,
            height: 300,
            fx: 300.0,
            fy: 310.0,
            cx: 200.0,
            cy: 150.0,
            c2w: c2w.as_mat4(),
            lens: Default::default(),
        };
        let x = DVec3::new(0.1, -0.3, 0.2);
        let q = npz_like * x.extend(1.0);
        let (px, z) = cam.project(x.as_vec3()).unwrap();
        assert!((px.x as f64 - q.x / q.z).abs() < 1e-3 && (px.y as f64 - q.y / q.z).abs() < 1e-3);
        assert!((z as f64 - q.z).abs() < 1e-4);
    }

    /// A synthetic pixelNeRF-layout scan: 30 cameras on an arc looking at the origin,
    /// full-resolution intrinsics for 32x24 images shipped at 8x6, and a world frame
    /// that `scale_mat` maps back to the normalised one.
    #[test]
    fn loads_a_synthetic_scan() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        std::fs::create_dir_all(root.join("image")).unwrap();
        std::fs::create_dir_all(root.join("mask")).unwrap();
        let k = DMat4::from_cols(
            DVec4::new(40.0, 0.0, 0.0, 0.0),
            DVec4::new(0.0, 41.0, 0.0, 0.0),
            DVec4::new(16.4, 11.6, 1.0, 0.0),
            DVec4::W,
        );
        let scale = DMat4::from_cols(
            DVec4::new(2.0, 0.0, 0.0, 0.0),
            DVec4::new(0.0, 2.0, 0.0, 0.0),
            DVec4::new(0.0, 0.0, 2.0, 0.0),
            DVec4::new(0.5, -0.3, 1.0, 1.0),
        );
        let n = 30;
        let centers: Vec<DVec3> = (0..n)
            .map(|i| {
                let a = i as f64 * std::f64::consts::PI / n as f64;
                DVec3::new(2.5 * a.cos(), 1.0, 2.5 * a.sin())
            })
            .collect();
        let mut mats = Vec::new();
        for (i, c) in centers.iter().enumerate() {
            let f = (-*c).normalize();
            let r = f.cross(DVec3::Y).normalize();
            let d = f.cross(r);
            let w2c = DMat4::from_cols(r.extend(0.0), d.extend(0.0), f.extend(0.0), DVec4::W)
                .transpose()
                * DMat4::from_translation(-*c);
            let world = k * w2c * scale.inverse();
            let rows = |m: DMat4| {
                (0..4)
                    .flat_map(|r| m.row(r).to_array())
                    .collect::<Vec<f64>>()
            };
            mats.push((format!("world_mat_{i}"), rows(world)));
            mats.push((format!("scale_mat_{i}"), rows(scale)));
            image::RgbImage::new(8, 6)
                .save(root.join(format!("image/{i:06}.png")))
                .unwrap();
            image::GrayImage::from_pixel(8, 6, image::Luma([255]))
                .save(root.join(format!("mask/{i:03}.png")))
                .unwrap();
        }
        let arrays: Vec<(&str, &[usize], &[f64])> = mats
            .iter()
            .map(|(name, data)| (name.as_str(), &[4usize, 4][..], data.as_slice()))
            .collect();
        crate::data::npy::write_npz_f64(&root.join("cameras.npz"), &arrays).unwrap();

        let opts = LoadOptions {
            views: Some(3),
            ..Default::default()
        };
        let scene = Scene::load(root, &opts).unwrap();
        assert_eq!(scene.format, SceneFormat::DtuPixelNerf);
        assert_eq!((scene.near, scene.far), PIXELNERF_NEAR_FAR);
        assert_eq!(scene.split.train, vec![25, 22, 28]);
        // Ids below 30: 6 of the 9 train ids and 11 of the 15 excluded ones.
        assert_eq!(scene.split.test.len(), 30 - 6 - 11);
        for (v, c) in scene.views.iter().zip(&centers) {
            let cam = &v.camera;
            assert!((cam.fx - 10.0).abs() < 1e-4 && (cam.fy - 10.25).abs() < 1e-4);
            assert!((cam.cx - 4.1).abs() < 1e-4 && (cam.cy - 2.9).abs() < 1e-4);
            assert!(
                cam.origin().abs_diff_eq(c.as_vec3(), 1e-5),
                "{} vs {c}",
                cam.origin()
            );
            // Each camera looks at the origin: it projects to the principal point.
            let (p, z) = cam.project(Vec3::ZERO).unwrap();
            assert!(
                (p - glam::Vec2::new(4.1, 2.9)).length() < 1e-4
                    && (z as f64 - c.length()).abs() < 1e-4
            );
            // World up (+y) appears up in the image (smaller pixel y).
            let (up, _) = cam.project(Vec3::Y * 0.1).unwrap();
            assert!(up.y < p.y);
            assert_eq!(v.mask.as_ref().map(Vec::len), Some(48));
        }

        // A missing camera for an existing image.
        image::RgbImage::new(8, 6)
            .save(root.join("image/000030.png"))
            .unwrap();
        let msg = Scene::load(root, &opts).unwrap_err().to_string();
        assert!(
            msg.contains("31 images for 30 cameras") && msg.contains("image"),
            "{msg}"
        );
    }

    #[test]
    fn rect_files_prefer_lighting_3() {
        let dir = tempfile::tempdir().unwrap();
        for view in 1..=2 {
            for light in 0..7 {
                image::RgbImage::new(4, 3)
                    .save(dir.path().join(format!("rect_{view:03}_{light}_r5000.png")))
                    .unwrap();
            }
        }
        let (folder, files) = scan_images(dir.path()).unwrap();
        assert_eq!(folder, dir.path());
        let names: Vec<String> = files.iter().map(|p| file_stem(p)).collect();
        assert_eq!(names, ["rect_001_3_r5000", "rect_002_3_r5000"]);
    }
}
