//! A COLMAP sparse model written by hand (text and binary), from OpenGL cameras, for
//! the loader tests: the file layouts of COLMAP's `read_write_model.py`, written
//! independently of the engine's reader.

use std::path::Path;

use glam::{DMat3, DMat4, DQuat, DVec3};

/// One camera: COLMAP model name, its numeric id, size and parameters.
pub struct Cam {
    pub id: u32,
    pub model: &'static str,
    pub model_id: i32,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

/// One registered image: world-to-camera `(qw, qx, qy, qz)`, `t`, camera id and name.
pub struct Img {
    pub id: u32,
    pub q: [f64; 4],
    pub t: [f64; 3],
    pub camera: u32,
    pub name: String,
}

/// COLMAP's pose of an OpenGL camera-to-world matrix: `R = (c2w's rotation with y and z
/// negated)^T`, `t = -R C`.
pub fn pose_of(c2w: DMat4) -> ([f64; 4], [f64; 3]) {
    let rot = DMat3::from_cols(c2w.x_axis.truncate(), -c2w.y_axis.truncate(), -c2w.z_axis.truncate());
    let r = rot.transpose();
    let t = -(r * c2w.w_axis.truncate());
    let q = DQuat::from_mat3(&r);
    ([q.w, q.x, q.y, q.z], t.to_array())
}

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `dir`.
pub fn write_text(dir: &Path, cams: &[Cam], imgs: &[Img], points: &[DVec3]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut c = String::from("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for cam in cams {
        let p: Vec<String> = cam.params.iter().map(|v| format!("{v:?}")).collect();
        c += &format!("{} {} {} {} {}\n", cam.id, cam.model, cam.width, cam.height, p.join(" "));
    }
    std::fs::write(dir.join("cameras.txt"), c).unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n");
    for (k, im) in imgs.iter().enumerate() {
        let [qw, qx, qy, qz] = im.q;
        let [tx, ty, tz] = im.t;
        s += &format!("{} {qw:?} {qx:?} {qy:?} {qz:?} {tx:?} {ty:?} {tz:?} {} {}\n", im.id, im.camera, im.name);
        // Every other image with an empty point list, as COLMAP writes unmatched images.
        s += if k % 2 == 0 { "10.5 20.5 1 11.0 3.0 -1\n" } else { "\n" };
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let mut p = String::from("# 3D point list with one line of data per point:\n");
    for (i, x) in points.iter().enumerate() {
        p += &format!("{} {:?} {:?} {:?} 128 128 128 0.5 1 0\n", i + 1, x.x, x.y, x.z);
    }
    std::fs::write(dir.join("points3D.txt"), p).unwrap();
}

/// The binary model files' bytes: `(cameras.bin, images.bin, points3D.bin)`.
pub fn binary_bytes(cams: &[Cam], imgs: &[Img], points: &[DVec3]) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let mut c = (cams.len() as u64).to_le_bytes().to_vec();
    for cam in cams {
        c.extend((cam.id as i32).to_le_bytes());
        c.extend(cam.model_id.to_le_bytes());
        c.extend(cam.width.to_le_bytes());
        c.extend(cam.height.to_le_bytes());
        cam.params.iter().for_each(|v| c.extend(v.to_le_bytes()));
    }
    let mut s = (imgs.len() as u64).to_le_bytes().to_vec();
    for im in imgs {
        s.extend((im.id as i32).to_le_bytes());
        im.q.iter().chain(&im.t).for_each(|v| s.extend(v.to_le_bytes()));
        s.extend((im.camera as i32).to_le_bytes());
        s.extend(im.name.as_bytes());
        s.push(0);
        s.extend(1u64.to_le_bytes());
        s.extend(10.5f64.to_le_bytes());
        s.extend(20.5f64.to_le_bytes());
        s.extend(1i64.to_le_bytes());
    }
    let mut p = (points.len() as u64).to_le_bytes().to_vec();
    for (i, x) in points.iter().enumerate() {
        p.extend((i as u64 + 1).to_le_bytes());
        x.to_array().iter().for_each(|v| p.extend(v.to_le_bytes()));
        p.extend([128u8, 128, 128]);
        p.extend(0.5f64.to_le_bytes());
        p.extend(1u64.to_le_bytes());
        p.extend(1i32.to_le_bytes());
        p.extend(0i32.to_le_bytes());
    }
    (c, s, p)
}

/// Writes `cameras.bin`, `images.bin` and `points3D.bin` into `dir`.
pub fn write_binary(dir: &Path, cams: &[Cam], imgs: &[Img], points: &[DVec3]) {
    std::fs::create_dir_all(dir).unwrap();
    let (c, s, p) = binary_bytes(cams, imgs, points);
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    std::fs::write(dir.join("images.bin"), s).unwrap();
    std::fs::write(dir.join("points3D.bin"), p).unwrap();
}
