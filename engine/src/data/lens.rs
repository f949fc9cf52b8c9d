//! Lens distortion: the camera models of COLMAP and nerfstudio beyond the pinhole.
//!
//! Owns [`Lens`], the map between camera-frame directions and *normalised distorted
//! image coordinates* `(xd, yd) = ((px - cx) / fx, (py - cy) / fy)` in both directions.
//! Everything here works in the OpenCV camera frame (`+x` right, `+y` down, `+z`
//! forward), where COLMAP and OpenCV define the models; [`super::Camera`] converts to
//! and from the project's OpenGL frame.
//!
//! Models (coefficients exactly as COLMAP's `cameras.txt` and nerfstudio's
//! `transforms.json` store them):
//! * [`Lens::Pinhole`]: `(xd, yd) = (X / Z, Y / Z)`.
//! * [`Lens::OpenCv`] (COLMAP `SIMPLE_RADIAL`, `RADIAL`, `OPENCV`; nerfstudio
//!   `OPENCV` / `PERSPECTIVE`): with `(u, v) = (X / Z, Y / Z)` and `r2 = u^2 + v^2`,
//!   `xd = u d + 2 p1 u v + p2 (r2 + 2 u^2)`, `yd = v d + 2 p2 u v + p1 (r2 + 2 v^2)`,
//!   `d = 1 + k1 r2 + k2 r2^2 + k3 r2^3 + k4 r2^4` (COLMAP's models have `k3 = k4 = 0`;
//!   nerfstudio passes `k3`, `k4` through the same polynomial).
//! * [`Lens::Fisheye`] (COLMAP / nerfstudio `OPENCV_FISHEYE`, OpenCV's fisheye model):
//!   `theta` = angle between the direction and the optical axis,
//!   `theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`, and
//!   `(xd, yd) = theta_d (X, Y) / sqrt(X^2 + Y^2)`.
//!
//! Invariants: [`Lens::unproject`] inverts [`Lens::project`] wherever the model is
//! monotonic in the radius (Newton's method in `f64`, as COLMAP's and nerfstudio's
//! iterative undistortion, to `1e-12` or 50 iterations); the pinhole path involves no
//! iteration. Coefficients are finite ([`Lens::check`]).

use glam::{DVec2, DVec3};

/// A camera's lens model (see the module doc); intrinsics stay in [`super::Camera`].
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Lens {
    /// No distortion.
    #[default]
    Pinhole,
    /// Radial `k1..k4` (in `r^2 .. r^8`) and tangential `p1`, `p2` distortion.
    OpenCv { k: [f32; 4], p: [f32; 2] },
    /// OpenCV's fisheye model, `k1..k4` on the angle from the axis.
    Fisheye { k: [f32; 4] },
}

const NEWTON_ITERS: usize = 50;
const NEWTON_TOL: f64 = 1e-12;

fn radial(k: &[f32; 4], s: f64) -> f64 {
    let [k1, k2, k3, k4] = k.map(f64::from);
    1.0 + s * (k1 + s * (k2 + s * (k3 + s * k4)))
}

/// Derivative of [`radial`] with respect to `s`.
fn radial_ds(k: &[f32; 4], s: f64) -> f64 {
    let [k1, k2, k3, k4] = k.map(f64::from);
    k1 + s * (2.0 * k2 + s * (3.0 * k3 + s * 4.0 * k4))
}

impl Lens {
    /// A perspective lens, [`Lens::Pinhole`] when every coefficient is zero.
    pub fn opencv(k: [f32; 4], p: [f32; 2]) -> Lens {
        if k.iter().chain(&p).all(|&c| c == 0.0) { Lens::Pinhole } else { Lens::OpenCv { k, p } }
    }

    /// Whether this is the plain pinhole.
    pub fn is_pinhole(&self) -> bool {
        matches!(self, Lens::Pinhole)
    }

    /// The model's name as COLMAP spells it (`PINHOLE`, `OPENCV`, `OPENCV_FISHEYE`).
    pub fn name(&self) -> &'static str {
        match self {
            Lens::Pinhole => "PINHOLE",
            Lens::OpenCv { .. } => "OPENCV",
            Lens::Fisheye { .. } => "OPENCV_FISHEYE",
        }
    }

    /// Why the coefficients are unusable, if they are: all must be finite.
    pub fn check(&self) -> Result<(), String> {
        let finite = match self {
            Lens::Pinhole => true,
            Lens::OpenCv { k, p } => k.iter().chain(p).all(|c| c.is_finite()),
            Lens::Fisheye { k } => k.iter().all(|c| c.is_finite()),
        };
        if finite { Ok(()) } else { Err(format!("lens distortion coefficients {self:?} are not finite")) }
    }

    /// Normalised distorted image coordinates of the camera-frame direction `d` (OpenCV
    /// frame); `None` for directions at or behind the camera plane (`d.z <= 0`).
    pub fn project(&self, d: DVec3) -> Option<DVec2> {
        if d.z <= 0.0 || !d.is_finite() {
            return None;
        }
        let (u, v) = (d.x / d.z, d.y / d.z);
        Some(match self {
            Lens::Pinhole => DVec2::new(u, v),
            Lens::OpenCv { k, p } => distort_opencv(k, p, DVec2::new(u, v)),
            Lens::Fisheye { k } => {
                let r = (u * u + v * v).sqrt();
                if r < 1e-15 {
                    DVec2::new(u, v)
                } else {
                    let theta = r.atan();
                    DVec2::new(u, v) * (theta * radial(k, theta * theta) / r)
                }
            }
        })
    }

    /// The camera-frame direction (OpenCV frame, not normalised, `z >= 0` except for
    /// fisheye angles past 90 degrees) whose projection is `xd`.
    pub fn unproject(&self, xd: DVec2) -> DVec3 {
        match self {
            Lens::Pinhole => xd.extend(1.0),
            Lens::OpenCv { k, p } => undistort_opencv(k, p, xd).extend(1.0),
            Lens::Fisheye { k } => {
                let theta_d = xd.length();
                if theta_d < 1e-15 {
                    return xd.extend(1.0);
                }
                // Solve theta * radial(theta^2) = theta_d for theta in [0, pi).
                let mut theta = theta_d;
                for _ in 0..NEWTON_ITERS {
                    let s = theta * theta;
                    let f = theta * radial(k, s) - theta_d;
                    let df = radial(k, s) + 2.0 * s * radial_ds(k, s);
                    if df.abs() < 1e-15 {
                        break;
                    }
                    let step = f / df;
                    theta = (theta - step).clamp(0.0, std::f64::consts::PI - 1e-9);
                    if step.abs() < NEWTON_TOL {
                        break;
                    }
                }
                let dir = xd / theta_d * theta.sin();
                DVec3::new(dir.x, dir.y, theta.cos())
            }
        }
    }
}

/// OpenCV's radial-tangential model on undistorted normalised coordinates.
fn distort_opencv(k: &[f32; 4], p: &[f32; 2], q: DVec2) -> DVec2 {
    let [p1, p2] = p.map(f64::from);
    let (u, v) = (q.x, q.y);
    let r2 = u * u + v * v;
    let d = radial(k, r2);
    DVec2::new(
        u * d + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u),
        v * d + 2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v),
    )
}

/// Inverts [`distort_opencv`] by Newton's method with the analytic Jacobian, starting
/// from the distorted point (as nerfstudio's `radial_and_tangential_undistort`).
fn undistort_opencv(k: &[f32; 4], p: &[f32; 2], xd: DVec2) -> DVec2 {
    let [p1, p2] = p.map(f64::from);
    let mut q = xd;
    for _ in 0..NEWTON_ITERS {
        let (u, v) = (q.x, q.y);
        let r2 = u * u + v * v;
        let d = radial(k, r2);
        let dd = radial_ds(k, r2); // d(d)/d(r2)
        let res = distort_opencv(k, p, q) - xd;
        // Jacobian of distort_opencv.
        let a = d + 2.0 * u * u * dd + 2.0 * p1 * v + 6.0 * p2 * u;
        let b = 2.0 * u * v * dd + 2.0 * p1 * u + 2.0 * p2 * v;
        let c = 2.0 * u * v * dd + 2.0 * p2 * v + 2.0 * p1 * u;
        let e = d + 2.0 * v * v * dd + 2.0 * p2 * u + 6.0 * p1 * v;
        let det = a * e - b * c;
        if det.abs() < 1e-15 || !det.is_finite() {
            break;
        }
        let step = DVec2::new((e * res.x - b * res.y) / det, (a * res.y - c * res.x) / det);
        q -= step;
        if step.length() < NEWTON_TOL {
            break;
        }
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unproject_inverts_project() {
        let lenses = [
            Lens::Pinhole,
            Lens::OpenCv { k: [-0.12, 0.03, 0.0, 0.0], p: [0.001, -0.0015] },
            Lens::OpenCv { k: [0.08, -0.01, 0.002, 0.0], p: [0.0, 0.0] },
            Lens::Fisheye { k: [0.05, -0.01, 0.003, -0.0005] },
        ];
        for lens in lenses {
            for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.45), (0.05, 0.6)] {
                let d = DVec3::new(x, y, 1.0);
                let xd = lens.project(d).unwrap();
                let back = lens.unproject(xd);
                let err = (back / back.z - d).length();
                assert!(err < 1e-10, "{lens:?} at ({x}, {y}): {err}");
            }
        }
        // The fisheye sees past 90 degrees: theta = 100 deg comes back.
        let lens = Lens::Fisheye { k: [0.0; 4] };
        let theta = 100f64.to_radians();
        let d = lens.unproject(DVec2::new(theta, 0.0));
        assert!((d.z - theta.cos()).abs() < 1e-12 && d.z < 0.0);
        // Barrel distortion pulls a point toward the centre.
        let barrel = Lens::OpenCv { k: [-0.2, 0.0, 0.0, 0.0], p: [0.0; 2] };
        assert!(barrel.project(DVec3::new(0.5, 0.0, 1.0)).unwrap().x < 0.5);
        assert!(Lens::opencv([0.0; 4], [0.0; 2]).is_pinhole());
        assert!(Lens::Fisheye { k: [f32::NAN, 0.0, 0.0, 0.0] }.check().is_err());
    }
}
