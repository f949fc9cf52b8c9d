//! Cameras (pinhole intrinsics plus an optional lens distortion, [`Lens`]), world-space
//! rays, and NeRF's NDC mapping for forward-facing scenes.
//!
//! Conventions are those of the parent module ([`crate::data`]): OpenGL camera frame
//! (look down `-z`, `+y` up), pixel origin at the top-left image corner with `y` down,
//! pixel centres at `+0.5` (COLMAP's and nerfstudio's convention too, so their `cx`, `cy`
//! are used as they are). [`Camera::c2w`] is a `glam::Mat4` whose upper 3x3 is a
//! rotation (orthonormal up to the rounding of the source data) and whose last column is
//! the camera centre; it is never scaled, so world units are the scene's units.
//!
//! Loaders enforce this with [`Camera::check`] (positive finite focal lengths, a rigid
//! `c2w` with bottom row `0 0 0 1`), refusing the camera file otherwise.
//!
//! Distorted cameras generate distorted rays: the ray of pixel `p` is the direction that
//! [`Camera::lens`] projects to `p` (no image is resampled). [`Camera::resized`] keeps the
//! lens: its coefficients act on normalised coordinates, independent of resolution.
//!
//! Invariants: [`Camera::pixel_ray`] returns a unit direction and `z_scale` in `(0, 1]`
//! (`<= 0` only for fisheye rays past 90 degrees from the axis);
//! [`Camera::project`] is its inverse (a point at distance `t` along the ray of pixel `p`
//! projects back to `p` with z-depth `t * z_scale`), the lens included.

use glam::{DVec2, DVec3, Mat4, Vec2, Vec3, Vec4Swizzles};

pub use super::lens::Lens;

/// A ray. World-space rays have a unit `dir` and `t` is the distance from the origin;
/// NDC rays (see [`NdcParams::ray_to_ndc`]) keep NeRF's non-unit direction so that
/// `t` in `[0, 1]` spans the near plane to infinity.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ray {
    pub origin: Vec3,
    pub dir: Vec3,
    /// World rays: cosine between `dir` and the camera's optical axis, so that the
    /// z-depth of the point at `t` is `t * z_scale`. NDC rays: `1` (`t` is the NDC depth).
    pub z_scale: f32,
}

impl Ray {
    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Largest deviation of `R^T R` from the identity [`Camera::check`] accepts in a pose's
/// rotation (poses are often stored with 6-7 significant digits).
pub const RIGID_TOLERANCE: f32 = 1e-3;

/// A camera: pinhole intrinsics (principal point and focal lengths in pixels) and a
/// lens model ([`Lens::Pinhole`] for none).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// Camera-to-world transform (OpenGL camera frame), rigid.
    pub c2w: Mat4,
    /// Lens distortion applied to the normalised coordinates `((px - cx) / fx, (py - cy) / fy)`.
    #[serde(default)]
    pub lens: Lens,
}

impl Camera {
    /// A camera with the principal point at the image centre and a horizontal field of
    /// view of `angle_x` radians (NeRF-synthetic's `camera_angle_x`; square pixels).
    pub fn from_fov_x(width: u32, height: u32, angle_x: f32, c2w: Mat4) -> Camera {
        let f = 0.5 * width as f32 / (0.5 * angle_x).tan();
        Camera {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            c2w,
            lens: Lens::Pinhole,
        }
    }

    /// The same camera for an image resized to `width x height`: intrinsics scale with
    /// the size ratio per axis (pixel-corner origin, so no half-pixel shift).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            c2w: self.c2w,
            lens: self.lens,
        }
    }

    /// Camera centre in world space.
    pub fn origin(&self) -> Vec3 {
        self.c2w.w_axis.xyz()
    }

    /// Unit optical axis (the camera's `-z`) in world space.
    pub fn forward(&self) -> Vec3 {
        (-self.c2w.z_axis.xyz()).normalize()
    }

    /// World-to-camera transform (the inverse of `c2w`).
    pub fn w2c(&self) -> Mat4 {
        self.c2w.inverse()
    }

    /// Whether all intrinsics and the pose are finite.
    pub fn is_finite(&self) -> bool {
        [self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite())
            && self.c2w.is_finite()
    }

    /// Why this camera cannot produce rays, if it cannot: focal lengths must be finite
    /// and positive, the principal point finite, and `c2w` a rigid transform (its
    /// rotation orthonormal to [`RIGID_TOLERANCE`] with determinant +1, bottom row
    /// `0 0 0 1`). Loaders call it on every camera they read, so a zero or negative
    /// focal length, a scaled or zero rotation, a reflection or a projective bottom row
    /// is an error naming the file instead of a scene trained on nonsense.
    pub fn check(&self) -> Result<(), String> {
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx > 0.0 && self.fy > 0.0) {
            return Err(format!("focal length fx {} / fy {} (pixels) must be finite and positive", self.fx, self.fy));
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return Err(format!("principal point ({}, {}) is not finite", self.cx, self.cy));
        }
        self.lens.check()?;
        check_rigid(&self.c2w)
    }

    /// Camera-space direction (OpenGL frame, not normalised; `z = -1` for a pinhole)
    /// through image point `(px, py)`.
    fn camera_dir(&self, px: f32, py: f32) -> Vec3 {
        if self.lens.is_pinhole() {
            return Vec3::new((px - self.cx) / self.fx, -(py - self.cy) / self.fy, -1.0);
        }
        let xd = DVec2::new(
            (f64::from(px) - f64::from(self.cx)) / f64::from(self.fx),
            (f64::from(py) - f64::from(self.cy)) / f64::from(self.fy),
        );
        let d = self.lens.unproject(xd);
        // OpenCV (x right, y down, z forward) to OpenGL (x right, y up, z backward).
        Vec3::new(d.x as f32, -d.y as f32, -d.z as f32)
    }

    /// The world-space ray through image point `(px, py)` (continuous pixel coordinates:
    /// pass `x + 0.5, y + 0.5` for the centre of pixel `(x, y)`).
    pub fn pixel_ray(&self, px: f32, py: f32) -> Ray {
        let d = self
            .c2w
            .transform_vector3(self.camera_dir(px, py))
            .normalize();
        Ray {
            origin: self.origin(),
            dir: d,
            z_scale: d.dot(self.forward()),
        }
    }

    /// Rays through the centres of all pixels, row-major.
    pub fn pixel_rays(&self) -> Vec<Ray> {
        let mut rays = Vec::with_capacity(self.width as usize * self.height as usize);
        for y in 0..self.height {
            for x in 0..self.width {
                rays.push(self.pixel_ray(x as f32 + 0.5, y as f32 + 0.5));
            }
        }
        rays
    }

    /// Projects a world point into the image: continuous pixel coordinates and z-depth
    /// (distance along the optical axis). `None` for points at or behind the camera
    /// plane. The pixel may lie outside the image; see [`Camera::in_frame`].
    pub fn project(&self, p: Vec3) -> Option<(Vec2, f32)> {
        self.project_with(&self.w2c(), p)
    }

    /// [`Camera::project`] with a precomputed [`Camera::w2c`] (for many points).
    pub fn project_with(&self, w2c: &Mat4, p: Vec3) -> Option<(Vec2, f32)> {
        let q = w2c.transform_point3(p);
        let z = -q.z;
        if z <= 0.0 || !z.is_finite() {
            return None;
        }
        if self.lens.is_pinhole() {
            return Some((Vec2::new(self.cx + self.fx * q.x / z, self.cy - self.fy * q.y / z), z));
        }
        let xd = self.lens.project(DVec3::new(q.x.into(), (-q.y).into(), z.into()))?;
        Some((
            Vec2::new(self.cx + self.fx * xd.x as f32, self.cy + self.fy * xd.y as f32),
            z,
        ))
    }

    /// Whether continuous pixel coordinates lie inside the image.
    pub fn in_frame(&self, px: Vec2) -> bool {
        px.x >= 0.0 && px.y >= 0.0 && px.x < self.width as f32 && px.y < self.height as f32
    }
}

/// The point nearest (least squares) to all cameras' optical axes (RegNeRF's
/// `focus_pt_fn`); the mean camera position when the axes are (nearly) parallel.
pub fn focus_point(cameras: &[Camera]) -> Vec3 {
    let (mut a, mut b) = (glam::DMat3::ZERO, glam::DVec3::ZERO);
    for c in cameras {
        let d = c.forward().as_dvec3();
        let m = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * c.origin().as_dvec3();
    }
    let mean = cameras.iter().map(|c| c.origin()).sum::<Vec3>() / cameras.len().max(1) as f32;
    if a.determinant().abs() < 1e-9 { mean } else { (a.inverse() * b).as_vec3() }
}

/// Whether every camera's optical axis lies within `max_deg` degrees of the cameras'
/// mean axis (a capture facing one way rather than around an object).
pub fn facing_one_way(cameras: &[Camera], max_deg: f32) -> bool {
    let mean = cameras.iter().map(|c| c.forward()).sum::<Vec3>().normalize_or_zero();
    cameras.iter().all(|c| c.forward().dot(mean) >= max_deg.to_radians().cos())
}

/// Why `c2w` is not a rigid camera-to-world transform, if it is not: finite, rotation
/// orthonormal to [`RIGID_TOLERANCE`] with determinant +1, bottom row `0 0 0 1`.
pub fn check_rigid(c2w: &Mat4) -> Result<(), String> {
    if !c2w.is_finite() {
        return Err("the camera-to-world matrix contains NaN or infinite values".into());
    }
    let bottom = c2w.row(3);
    if (bottom - glam::Vec4::W).abs().max_element() > 1e-5 {
        return Err(format!(
            "the camera-to-world matrix's bottom row is [{} {} {} {}], expected [0 0 0 1]",
            bottom.x, bottom.y, bottom.z, bottom.w
        ));
    }
    let r = glam::Mat3::from_mat4(*c2w);
    let gram = r.transpose() * r;
    let off = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (gram.col(j)[i] - if i == j { 1.0 } else { 0.0 }).abs())
        .fold(0.0f32, f32::max);
    if off > RIGID_TOLERANCE {
        return Err(format!(
            "the rotation part of the camera-to-world matrix is not orthonormal (R^T R differs from the \
             identity by {off:.3}); it must be a rotation, without scale or shear"
        ));
    }
    if r.determinant() < 0.0 {
        return Err("the rotation part of the camera-to-world matrix is a reflection (determinant -1)".into());
    }
    Ok(())
}

/// NeRF's normalised device coordinates for forward-facing scenes (`ndc_rays`): world
/// space with the cameras looking down `-z` maps to the cube `[-1, 1]^3`, the plane
/// `z = -near` to NDC `z = -1` and infinity to NDC `z = 1`. One shared pinhole
/// (`focal_*`, `width`, `height` in pixels of the loaded images) defines the frustum.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NdcParams {
    pub focal_x: f32,
    pub focal_y: f32,
    pub width: f32,
    pub height: f32,
    /// World distance of the near plane along `-z` (1.0 for LLFF after rescaling).
    pub near: f32,
}

impl NdcParams {
    /// Maps a world-space ray to NDC exactly as NeRF's `ndc_rays`: the origin is first
    /// moved along the ray to the plane `z = -near`, then both origin and direction are
    /// projected. The result has NDC origin `z = -1`, direction `z = 2 near / near = 2`
    /// (so NDC `z = 2t - 1`), and `t` in `[0, 1]` covers the near plane to infinity.
    /// The direction is *not* unit length; `z_scale` is `1`. Rays with `dir.z >= 0`
    /// (pointing away from the scene) give non-finite values.
    pub fn ray_to_ndc(&self, ray: Ray) -> Ray {
        let (o, d) = (ray.origin, ray.dir);
        let t = -(self.near + o.z) / d.z;
        let o = o + d * t;
        let ax = -2.0 * self.focal_x / self.width;
        let ay = -2.0 * self.focal_y / self.height;
        let origin = Vec3::new(ax * o.x / o.z, ay * o.y / o.z, 1.0 + 2.0 * self.near / o.z);
        let dir = Vec3::new(
            ax * (d.x / d.z - o.x / o.z),
            ay * (d.y / d.z - o.y / o.z),
            -2.0 * self.near / o.z,
        );
        Ray {
            origin,
            dir,
            z_scale: 1.0,
        }
    }

    /// Maps a world point (in front of the near plane, `z < 0`) to NDC.
    pub fn point_to_ndc(&self, p: Vec3) -> Vec3 {
        Vec3::new(
            -2.0 * self.focal_x / self.width * p.x / p.z,
            -2.0 * self.focal_y / self.height * p.y / p.z,
            1.0 + 2.0 * self.near / p.z,
        )
    }

    /// Maps an NDC point back to world space (inverse of [`NdcParams::point_to_ndc`];
    /// NDC `z -> 1` is infinitely far, and `z >= 1` gives non-finite values).
    pub fn ndc_to_world(&self, q: Vec3) -> Vec3 {
        let z = 2.0 * self.near / (q.z - 1.0);
        Vec3::new(-q.x * z * self.width / (2.0 * self.focal_x), -q.y * z * self.height / (2.0 * self.focal_y), z)
    }

    /// World depth `-z` of the point at NDC ray parameter `t` (inverse of NDC
    /// `z = 2t - 1 = 1 + 2 near / z`): `near / (1 - t)`.
    pub fn ndc_t_to_world_depth(&self, t: f32) -> f32 {
        self.near / (1.0 - t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec3};

    fn test_camera() -> Camera {
        let rot = Quat::from_euler(glam::EulerRot::YXZ, 0.4, -0.3, 0.1);
        let c2w = Mat4::from_rotation_translation(rot, Vec3::new(0.5, -1.0, 3.0));
        Camera {
            width: 64,
            height: 48,
            fx: 70.0,
            fy: 72.0,
            cx: 31.0,
            cy: 25.0,
            c2w,
            lens: Lens::Pinhole,
        }
    }

    #[test]
    fn pixel_ray_and_project_round_trip() {
        let cam = test_camera();
        for &(px, py) in &[(0.5, 0.5), (31.0, 25.0), (63.5, 47.5), (10.25, 40.75)] {
            let ray = cam.pixel_ray(px, py);
            assert!((ray.dir.length() - 1.0).abs() < 1e-5);
            assert!(ray.z_scale > 0.0 && ray.z_scale <= 1.0 + 1e-6);
            let t = 2.7;
            let (p, z) = cam.project(ray.at(t)).unwrap();
            assert!((p - Vec2::new(px, py)).length() < 1e-3, "{p} vs {px},{py}");
            assert!((z - t * ray.z_scale).abs() < 1e-4);
        }
        // The principal point looks straight down the optical axis.
        let axis = cam.pixel_ray(31.0, 25.0);
        assert!((axis.dir - cam.forward()).length() < 1e-6 && (axis.z_scale - 1.0).abs() < 1e-6);
        // Points behind the camera do not project.
        assert!(cam.project(cam.origin() - cam.forward()).is_none());
    }

    #[test]
    fn opengl_frame_orientation() {
        // Identity pose: a pixel right of / above the centre looks to +x / +y, forward is -z.
        let cam = Camera {
            c2w: Mat4::IDENTITY,
            ..test_camera()
        };
        let r = cam.pixel_ray(60.0, 25.0);
        assert!(r.dir.x > 0.0 && r.dir.z < 0.0);
        let u = cam.pixel_ray(31.0, 2.0);
        assert!(u.dir.y > 0.0);
        let f = Camera::from_fov_x(800, 600, std::f32::consts::FRAC_PI_2, Mat4::IDENTITY);
        assert!((f.fx - 400.0).abs() < 1e-3 && f.cx == 400.0 && f.cy == 300.0);
        let h = f.resized(400, 300);
        assert!((h.fx - 200.0).abs() < 1e-3 && h.cy == 150.0);
    }

    #[test]
    fn ndc_of_known_rays() {
        let ndc = NdcParams {
            focal_x: 100.0,
            focal_y: 100.0,
            width: 200.0,
            height: 100.0,
            near: 1.0,
        };
        // The optical axis ray from the origin: NDC origin (0, 0, -1), direction (0, 0, 2).
        let r = ndc.ray_to_ndc(Ray {
            origin: Vec3::ZERO,
            dir: -Vec3::Z,
            z_scale: 1.0,
        });
        assert!((r.origin - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        assert!((r.dir - Vec3::new(0.0, 0.0, 2.0)).length() < 1e-6);
        // A ray through a corner-ish direction (x/z = -1 means the right image border
        // when 2f/W = 1): NDC x goes to 1 at t = 1 (infinity).
        let dir = Vec3::new(1.0, 0.5, -1.0).normalize();
        let r = ndc.ray_to_ndc(Ray {
            origin: Vec3::new(0.2, -0.1, 0.5),
            dir,
            z_scale: 1.0,
        });
        assert!((r.origin.z + 1.0).abs() < 1e-6 && (r.dir.z - 2.0).abs() < 1e-6);
        let far = r.at(1.0);
        // At infinity the NDC xy of a ray is its direction's projection: -(2f/W) dx/dz.
        assert!(
            (far.x - 1.0).abs() < 1e-5 && (far.y - 1.0).abs() < 1e-5 && (far.z - 1.0).abs() < 1e-5,
            "{far}"
        );
        // Intermediate points agree with the point mapping (NDC is a projective map).
        let world = Ray {
            origin: Vec3::new(0.2, -0.1, 0.5),
            dir,
            z_scale: 1.0,
        }
        .at(4.0);
        let p = ndc.point_to_ndc(world);
        let t = (p.z + 1.0) / 2.0;
        assert!((r.at(t) - p).length() < 1e-4, "{} vs {p}", r.at(t));
        assert!((ndc.ndc_t_to_world_depth(t) + world.z).abs() < 1e-3);
        assert!((ndc.ndc_to_world(p) - world).length() < 1e-4, "{} vs {world}", ndc.ndc_to_world(p));
    }
}
