//! The camera matrices of a small DTU-layout scan, shared by the integration tests of
//! the root suite (through `common`) and of the CLI (`tools/tests/cli_protocol.rs`
//! includes this file by path: the two are different test crates).

/// The `world_mat_i` / `scale_mat_i` pairs of a DTU-layout scan of `n` views of
/// `width` x `height` pixels (row-major 4x4): cameras on an arc looking at the origin,
/// focal length `1.25 width`, principal point at the image centre, every `scale_mat` a
/// uniform `scale`.
pub fn dtu_camera_matrices(n: usize, width: u32, height: u32, scale: f64) -> Vec<(String, Vec<f64>)> {
    use glam::{DMat4, DVec3, DVec4};
    let (w, h) = (width as f64, height as f64);
    let k = DMat4::from_cols(
        DVec4::new(1.25 * w, 0.0, 0.0, 0.0),
        DVec4::new(0.0, 1.25 * w, 0.0, 0.0),
        DVec4::new(w / 2.0, h / 2.0, 1.0, 0.0),
        DVec4::W,
    );
    let rows = |m: DMat4| (0..4).flat_map(|r| m.row(r).to_array()).collect::<Vec<f64>>();
    let mut arrays = Vec::new();
    for i in 0..n {
        let a = i as f64 * 0.05;
        let c = DVec3::new(2.5 * a.cos(), 1.0, 2.5 * a.sin());
        let f = (-c).normalize();
        let r = f.cross(DVec3::Y).normalize();
        let d = f.cross(r);
        let w2c = DMat4::from_cols(r.extend(0.0), d.extend(0.0), f.extend(0.0), DVec4::W).transpose() * DMat4::from_translation(-c);
        arrays.push((format!("world_mat_{i}"), rows(k * w2c)));
        arrays.push((format!("scale_mat_{i}"), rows(DMat4::from_scale(DVec3::splat(scale)))));
    }
    arrays
}
