//! Cross-view photometric consistency of the rendered depth: each training ray's depth,
//! reprojected into the other training views, must land where those views show the
//! ray's colour. Owner of `kernels/loss/reprojection.wgsl`, the GPU copy of the training
//! images and cameras it reads ([`ReprojectionViews`]) and its `f64` reference
//! ([`reference`]).
//!
//! The edge-guided terms shape a surface (flat, smooth, consistent with its normals)
//! but do not say *where* it is: a floor lifted above its true height is as smooth as
//! the true one. Three views do say where, wherever the colour varies (shadows, object
//! boundaries, texture): this is the multi-view photometric constraint of MVS and of
//! self-supervised depth (Monodepth2's per-pixel minimum over views), applied to the
//! radiance field's rendered depth.
//!
//! # The loss
//! For photometric ray `k` of view `s` with drop weight `w_k` (`target.w`, 0 for rays the
//! sample capacity cut), rendered `depth` and `opacity`:
//! ```text
//! t   = clamp(depth / max(opacity, eps), t_min, t_max)      x = origin + t dir
//! E_j = 1/3 sum_c rho(I_j(pi_j(x))_c - I_s(pi_s(x))_c)        rho(r) = sqrt(r^2 + delta^2) - delta
//! L   = 1/n sum_k m_k min_{j != s, x inside j} E_j            m_k = w_k opacity_k  (constant)
//! ```
//! `pi_j` is view `j`'s pinhole projection (`Camera::project` of `crate::data`); `I_j` its image,
//! optionally blurred by a Gaussian of `reg.reprojection_blur` pixels, sampled
//! bilinearly between pixel centres, and `x` counts as inside when its whole 2x2
//! footprint lies in the image and it is in front of the camera. `I_s(pi_s(x))` is the
//! ray's own pixel in the same (blurred) image: the same colour as its target without
//! blur (to 8 bits), and a constant of `t` (every point of the ray projects there). The minimum over
//! views is Monodepth2's answer to occlusion: a view that sees an occluder at `x` costs
//! nothing while another sees the surface. A ray that lands inside no other view has no
//! term. The Charbonnier `rho` is L1 away from 0 and smooth at it (`delta`, colour units).
//! `m_k` holds the term off transparent rays (no depth to speak of) and is not
//! differentiated: the term moves depth, never opacity for its own sake.
//!
//! # Gradients (added to `dL/d RayOutput`)
//! With `q = R_j x + T_j` (camera frame, looking down `-z`, `z = -q_z`) and `dq = R_j
//! dx/dt` (`dx/dt = dir` in world space):
//! ```text
//! du/dt = fx (dq_x / z + q_x dq_z / z^2)      dv/dt = -fy (dq_y / z + q_y dq_z / z^2)
//! dE/dt = 1/3 sum_c rho'(r_c) (dI_c/du du/dt + dI_c/dv dv/dt)       (the best view j)
//! d depth   += lambda / n m_k dE/dt / A          A = max(opacity, eps)
//! d opacity -= lambda / n m_k dE/dt t / A        (only where opacity > eps)
//! ```
//! where the clamp is inactive, else nothing (as [`super::depth_tv`]). The image
//! derivative is that of the bilinear interpolant, so the term sees about a pixel of
//! disparity around the current depth, or about the blur's width with a blur: a wider
//! blur reaches farther at the price of detail.
//!
//! Invariants: the kernel only *adds* to `d_rays` (the photometric loss writes first);
//! it reads rays `0 .. n` of the batch (the photometric rays), each with its source
//! view's position in the scene's training list; only training
//! images are on the GPU (never a test view; `crate::train::reprojection_views` packs
//! them and refuses distorted lenses: the cameras are pinhole). NDC rays
//! (forward-facing LLFF scenes) work too: their point at `t` is mapped back to world
//! space (`NdcParams::ndc_to_world` of `crate::data`, differentiated along `t`) before
//! it is projected.

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::{GpuRay, RayOutput};

const SPEC: KernelSpec = KernelSpec {
    file: "loss/reprojection.wgsl",
    entry: "reprojection",
    bindings: &[
        Binding::Params,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadOnly,
        Binding::ReadWrite,
        Binding::ReadWrite,
    ],
};

/// `eps` of the division by the opacity and of the camera-plane test.
pub const OPACITY_EPS: f32 = f32::EPSILON;

/// Words of a view's header in the packed array (`HEADER` in the kernel).
pub const HEADER: usize = 20;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_rays: u32,
    n_views: u32,
    ndc: u32,
    _pad0: u32,
    lambda: f32,
    delta: f32,
    eps: f32,
    ndc_near: f32,
    ndc_scale: [f32; 2],
    _pad1: [f32; 2],
}

/// NeRF's NDC map as the term inverts it (`NdcParams::ndc_to_world` in `crate::data`):
/// the near plane and the per-axis scale `-size / (2 focal)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NdcMap {
    pub near: f32,
    pub scale: [f32; 2],
}

/// One training view to pack: its world-to-camera rows `[R | T]`, pinhole intrinsics
/// (pixels) and its RGB pixels (row-major, `width * height * 3` floats in `[0, 1]`).
pub struct ViewToPack<'a> {
    pub w2c: [[f32; 4]; 3],
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
    pub rgb: &'a [f32],
}

/// The training views as the kernel reads them: one `u32` array of per-view headers
/// (world-to-camera rows, intrinsics, size, pixel offset) followed by every view's
/// pixels as RGBA8 (layout in `kernels/loss/reprojection.wgsl`). Built by
/// `crate::train::reprojection_views` from a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct ReprojectionViews {
    pub words: Vec<u32>,
    pub n_views: u32,
    /// The NDC map when the rays are NDC rays (the term maps their points back to world
    /// space).
    pub ndc: Option<NdcMap>,
}

impl ReprojectionViews {
    /// Packs `views` (in the order of the training list the rays' source indices refer
    /// to). Panics on a view smaller than 2x2 pixels or whose pixels do not match its
    /// size (the caller checks what users can get wrong).
    pub fn pack(views: &[ViewToPack<'_>], ndc: Option<NdcMap>) -> ReprojectionViews {
        let mut words = vec![0u32; HEADER * views.len()];
        for (i, v) in views.iter().enumerate() {
            assert!(v.width >= 2 && v.height >= 2 && v.rgb.len() == (v.width * v.height * 3) as usize, "a view of at least 2x2 pixels");
            let offset = u32::try_from(words.len()).expect("the training images fit 2^32 pixels");
            let h = &mut words[i * HEADER..(i + 1) * HEADER];
            for (row, r) in v.w2c.iter().enumerate() {
                for (col, x) in r.iter().enumerate() {
                    h[4 * row + col] = x.to_bits();
                }
            }
            for (k, x) in [v.fx, v.fy, v.cx, v.cy].into_iter().enumerate() {
                h[12 + k] = x.to_bits();
            }
            h[16] = v.width;
            h[17] = v.height;
            h[18] = offset;
            words.extend(v.rgb.chunks_exact(3).map(|p| pack_rgba8([p[0], p[1], p[2]])));
        }
        ReprojectionViews { words, n_views: views.len() as u32, ndc }
    }

    /// Bytes the packed views take on the GPU.
    pub fn bytes(&self) -> u64 {
        4 * self.words.len() as u64
    }

    /// Bytes [`ReprojectionViews::pack`] makes of views of these `(width, height)`
    /// sizes, known before any image is read or blurred.
    pub fn packed_bytes(sizes: impl Iterator<Item = (u32, u32)>) -> u64 {
        sizes.map(|(w, h)| 4 * (HEADER as u64 + w as u64 * h as u64)).sum()
    }
}

/// The near plane and scale of NDC's inverse map; zeros without NDC.
fn ndc_map(ndc: Option<NdcMap>) -> (f32, [f32; 2]) {
    ndc.map_or((0.0, [0.0; 2]), |n| (n.near, n.scale))
}

/// `unpack4x8unorm`'s inverse: channels in `[0, 1]` rounded to 8 bits, alpha 1.
fn pack_rgba8(rgb: [f32; 3]) -> u32 {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u32;
    q(rgb[0]) | (q(rgb[1]) << 8) | (q(rgb[2]) << 16) | (255 << 24)
}

/// The reprojection kernel, the packed training views, the per-ray source views and the
/// per-ray loss terms.
pub struct Reprojection {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    views: GpuBuffer<u32>,
    n_views: u32,
    ndc: Option<NdcMap>,
    /// Per photometric ray: its view's position in the training list, written by the caller.
    pub source: GpuBuffer<u32>,
    /// Per photometric ray: its term (normalized, lambda not included).
    pub ray_loss: GpuBuffer<f32>,
}

impl Reprojection {
    /// The term over batches of up to `max_rays` photometric rays, reading `views`.
    pub fn new(gpu: &Gpu, views: &ReprojectionViews, max_rays: u32) -> Result<Self, GpuError> {
        let n = max_rays.max(1) as usize;
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            views: GpuBuffer::from_slice(gpu, "reprojection views", &views.words)?,
            n_views: views.n_views,
            ndc: views.ndc,
            source: GpuBuffer::zeros(gpu, "reprojection source views", n)?,
            ray_loss: GpuBuffer::zeros(gpu, "reprojection ray losses", n)?,
        })
    }

    /// Records the term over rays `0 .. n_rays` (`outs` rendered from `rays`, `targets`
    /// their colours and drop weights, [`Reprojection::source`] filled), adding
    /// `lambda` times its gradient into `d_rays`. `delta`: the Charbonnier scale.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        enc: &mut Encoder,
        outs: &GpuBuffer<RayOutput>,
        rays: &GpuBuffer<GpuRay>,
        targets: &GpuBuffer<[f32; 4]>,
        d_rays: &GpuBuffer<RayOutput>,
        n_rays: u32,
        lambda: f32,
        delta: f32,
    ) {
        let n = n_rays as usize;
        assert!(outs.len() >= n && rays.len() >= n && targets.len() >= n && d_rays.len() >= n);
        assert!(self.source.len() >= n, "reprojection buffers for {} rays", self.source.len());
        let (ndc_near, ndc_scale) = ndc_map(self.ndc);
        let params = enc.params(&Params {
            n_rays,
            n_views: self.n_views,
            ndc: self.ndc.is_some() as u32,
            _pad0: 0,
            lambda,
            delta,
            eps: OPACITY_EPS,
            ndc_near,
            ndc_scale,
            _pad1: [0.0; 2],
        });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &outs.buffer, &rays.buffer, &targets.buffer, &self.source.buffer, &self.views.buffer, &d_rays.buffer, &self.ray_loss.buffer],
            n_rays,
        );
    }

    /// The loss of the last launch over `n_rays` (waits for the GPU).
    pub fn loss(&self, gpu: &Gpu, n_rays: u32) -> Result<f32, GpuError> {
        super::sum_of_terms(gpu, &self.ray_loss, n_rays)
    }
}

/// `f64` CPU reference of the loss and its gradients (tests; the kernel in plain Rust,
/// reading the same packed views).
pub mod reference {
    use super::{HEADER, OPACITY_EPS, ReprojectionViews, ndc_map};

    /// One photometric ray as the term sees it.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct ReprojRay {
        pub origin: [f64; 3],
        pub dir: [f64; 3],
        pub t_min: f64,
        pub t_max: f64,
        pub depth: f64,
        pub opacity: f64,
        /// The drop weight (`target.w`).
        pub weight: f64,
        /// Position of the ray's view in the training list.
        pub source: u32,
    }

    fn f(views: &ReprojectionViews, v: usize, i: usize) -> f64 {
        f32::from_bits(views.words[v * HEADER + i]) as f64
    }

    fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }

    /// View `v`'s camera-frame point `q`, its rate `dq` along `dir`, and the continuous
    /// pixel coordinates of `x`.
    fn project(views: &ReprojectionViews, v: usize, x: [f64; 3], dir: [f64; 3]) -> ([f64; 3], [f64; 3], [f64; 2]) {
        let row = |r: usize| [f(views, v, 4 * r), f(views, v, 4 * r + 1), f(views, v, 4 * r + 2)];
        let q = [0, 1, 2].map(|r| dot(row(r), x) + f(views, v, 4 * r + 3));
        let dq = [0, 1, 2].map(|r| dot(row(r), dir));
        let z = -q[2];
        (q, dq, [f(views, v, 14) + f(views, v, 12) * q[0] / z, f(views, v, 15) - f(views, v, 13) * q[1] / z])
    }

    /// The bilinear interpolant of view `v` at `uv` (clamped to the pixel centres) per
    /// channel: `(value, d/du, d/dv)`.
    fn bilinear(views: &ReprojectionViews, v: usize, uv: [f64; 2]) -> [[f64; 3]; 3] {
        let base = v * HEADER;
        let (width, height, offset) = (views.words[base + 16] as usize, views.words[base + 17] as usize, views.words[base + 18] as usize);
        let (px, py) = ((uv[0] - 0.5).clamp(0.0, (width - 1) as f64), (uv[1] - 0.5).clamp(0.0, (height - 1) as f64));
        let (x0, y0) = ((px as usize).min(width - 2), (py as usize).min(height - 2));
        let (a, b) = (px - x0 as f64, py - y0 as f64);
        let c = |dx: usize, dy: usize| {
            let p = views.words[offset + (y0 + dy) * width + x0 + dx];
            [0, 8, 16].map(|s| ((p >> s) & 255) as f64 / 255.0)
        };
        let (c00, c10, c01, c11) = (c(0, 0), c(1, 0), c(0, 1), c(1, 1));
        let mut out = [[0.0; 3]; 3];
        for ch in 0..3 {
            out[ch] = [
                (1.0 - a) * (1.0 - b) * c00[ch] + a * (1.0 - b) * c10[ch] + (1.0 - a) * b * c01[ch] + a * b * c11[ch],
                (1.0 - b) * (c10[ch] - c00[ch]) + b * (c11[ch] - c01[ch]),
                (1.0 - a) * (c01[ch] - c00[ch]) + a * (c11[ch] - c10[ch]),
            ];
        }
        out
    }

    /// The colour of view `v` where `x` projects (the ray's own colour when `v` is its view).
    pub fn colour_at(views: &ReprojectionViews, v: usize, x: [f64; 3]) -> [f64; 3] {
        bilinear(views, v, project(views, v, x, [0.0; 3]).2).map(|c| c[0])
    }

    /// `(E_v, dE_v/dt)` of view `v` at `x` moving along `dir` against the colour `own`,
    /// `None` when `x` is not inside it.
    pub fn view_term(views: &ReprojectionViews, v: usize, x: [f64; 3], dir: [f64; 3], own: [f64; 3], delta: f64) -> Option<(f64, f64)> {
        let (q, dq, uv) = project(views, v, x, dir);
        let (width, height) = (views.words[v * HEADER + 16] as f64, views.words[v * HEADER + 17] as f64);
        let (z, px, py) = (-q[2], uv[0] - 0.5, uv[1] - 0.5);
        if !(z > OPACITY_EPS as f64 && px >= 0.0 && py >= 0.0 && px < width - 1.0 && py < height - 1.0) {
            return None;
        }
        let du_dt = f(views, v, 12) * (dq[0] / z + q[0] * dq[2] / (z * z));
        let dv_dt = -f(views, v, 13) * (dq[1] / z + q[1] * dq[2] / (z * z));
        let (mut err, mut d_err) = (0.0, 0.0);
        for (ch, [value, d_du, d_dv]) in bilinear(views, v, uv).into_iter().enumerate() {
            let r = value - own[ch];
            let root = (r * r + delta * delta).sqrt();
            err += (root - delta) / 3.0;
            d_err += r / root * (d_du * du_dt + d_dv * dv_dt) / 3.0;
        }
        Some((err, d_err))
    }

    /// The world point at parameter `t` of `r` and its rate along `t` (NDC rays mapped
    /// back to world space).
    pub fn ray_point(views: &ReprojectionViews, r: &ReprojRay, t: f64) -> ([f64; 3], [f64; 3]) {
        let p = [0, 1, 2].map(|i| r.origin[i] + t * r.dir[i]);
        if views.ndc.is_none() {
            return (p, r.dir);
        }
        let (near, [sx, sy]) = ndc_map(views.ndc);
        let (near, sx, sy) = (near as f64, sx as f64, sy as f64);
        let z = 2.0 * near / (p[2] - 1.0);
        let dz = -z / (p[2] - 1.0) * r.dir[2];
        ([sx * p[0] * z, sy * p[1] * z, z], [sx * (r.dir[0] * z + p[0] * dz), sy * (r.dir[1] * z + p[1] * dz), dz])
    }

    /// The loss of `rays` and per ray `(dL/d depth, dL/d opacity)` (lambda not included).
    pub fn loss(views: &ReprojectionViews, rays: &[ReprojRay], delta: f64) -> (f64, Vec<(f64, f64)>) {
        let (n, eps) = (rays.len() as f64, OPACITY_EPS as f64);
        let mut total = 0.0;
        let grads = rays
            .iter()
            .map(|r| {
                let m = r.weight * r.opacity;
                let a = r.opacity.max(eps);
                let t_raw = r.depth / a;
                let t = t_raw.clamp(r.t_min, r.t_max);
                let (x, dx) = ray_point(views, r, t);
                if !(m > 0.0 && r.source < views.n_views) {
                    return (0.0, 0.0);
                }
                let own = colour_at(views, r.source as usize, x);
                let best = (0..views.n_views as usize)
                    .filter(|&v| v != r.source as usize)
                    .filter_map(|v| view_term(views, v, x, dx, own, delta))
                    .fold(None, |best: Option<(f64, f64)>, e| if best.is_none_or(|b| e.0 < b.0) { Some(e) } else { best });
                let Some((err, d_err)) = best else { return (0.0, 0.0) };
                total += m * err / n;
                if t_raw <= r.t_min || t_raw >= r.t_max {
                    return (0.0, 0.0);
                }
                let g = m * d_err / n;
                (g / a, if r.opacity > eps { -g * t_raw / a } else { 0.0 })
            })
            .collect();
        (total, grads)
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/reprojection.wgsl", "Params", [n_rays, n_views, ndc, lambda, delta, eps, ndc_near, ndc_scale]);
        if let Err(e) = crate::gpu::kernel::tests::check_wgsl_u32_const("loss/reprojection.wgsl", "HEADER", HEADER as u32) {
            panic!("{e}");
        }
    }
}
