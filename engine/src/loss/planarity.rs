//! The edge-guided planarity term `L_pl`: long-range smoothness of the rendered depth
//! inside non-edge regions, on triplets of pixels on a line. Owner of
//! `kernels/loss/planarity.wgsl` and its `f64` reference ([`reference`]).
//!
//! # Why
//! EdgeNeRF's `L_z` and `L_n` act on 2x2 patches: they smooth what two neighbouring
//! pixels see, but a surface that is wrong over tens of pixels is smooth at that scale
//! and pays nothing. With three views that is what a textureless region becomes: the
//! floor of `smooth` is rendered 0.15-0.3 scene units in front of the true floor in the
//! training views themselves (about 5 % of the depth; 0.03-0.07 with all 24 views),
//! pinned where shadows and object contacts give the photometric loss something to
//! match and lifted toward each camera in between; its normals lean toward the camera
//! that looks at it. Colour alone cannot move it: any height of a uniform grey surface
//! renders the same grey. A term that prefers planes over tens of pixels carries the
//! pinned depths across the region, and stops where the edge map says a region ends.
//! Measured (docs/journal.md, "Planarity: textureless floors in three views"): it flattens the
//! floor and lowers the object scenes' non-edge normal error by 2-4 degrees, but does
//! not lower the floor, and costs the deep forward-facing scenes, whose fog it
//! flattens into sheets, 0.4-3.7 dB: off by default.
//!
//! # The loss
//! A launch covers `T` triplets; triplet `k` is rays `offset + 3k .. offset + 3k + 2`,
//! the pixels `p0, p1 = p0 + s u, p2 = p0 + 2 s u` of one training view for a step `u`
//! along a row, column or diagonal and a spacing `s` up to `reg.planarity_max_stride`
//! pixels, every pixel of the segment `p0 .. p2` non-edge ([`crate::train::rays`]
//! draws them). Per ray the caller gives `(w, z_scale)`, `w` the triplet's weight (1;
//! 0 for a triplet the draw could not place) and `z_scale` as for `L_z`; the depth is
//! the depth given termination along the camera axis,
//! `z = z_scale depth / max(opacity, OPACITY_FLOOR)` ([`super::edge_reg`]).
//! ```text
//! world space:  r = z1 / z0 + z1 / z2 - 2      (= z1 (1/z0 - 2/z1 + 1/z2))
//! NDC (LLFF):   r = z0 - 2 z1 + z2
//! L_pl = 1/T sum_k w_k rho(r_k)
//! rho(r) = |r|                             (reg.planarity_scale = 0)
//! rho(r) = c r^2 / (r^2 + c^2)             (c = reg.planarity_scale > 0)
//! ```
//! The second `rho` (Geman-McClure, scaled by `c` so that its slope peaks at about
//! 0.65 near `r = c / sqrt 3`, as steep as the L1's 1 there) is quadratic below `c`
//! and bounded by `c` above it: a triplet that straddles a crease the edge map missed
//! (a wall meeting a table without an intensity edge) has a residual far above `c` and
//! pulls the two planes together with a slope that falls as `1 / r^3`, while the
//! gentle curvature of a lifted floor (residuals near `c`) is pulled as by the L1.
//! On a plane, inverse depth along the camera axis is an affine function of the pixel
//! coordinates (and so is the NDC parameter), so `r = 0` for any plane and any
//! spacing, whatever its slant: unlike `L_z` the term does not pull toward
//! fronto-parallel. Scaled by `z1` the world residual is a relative curvature, the same
//! at every distance. A triplet with a ray whose opacity is below `OPACITY_FLOOR`
//! (background, a hole: its depth given termination is an average over a trace of
//! weights) pays 0, as does one with a zero depth.
//!
//! With `reg.planarity_coherence = p > 0` each triplet's weight is scaled by the gate
//! `(mean_j c_j)^p`, `c_j = min(1, |n_j| / max(opacity_j, OPACITY_FLOOR))`, where
//! `n_j` is the ray's rendered (unnormalised) normal: near 1 where the ray's samples
//! agree on one surface, small in fog whose normals cancel, held constant in the
//! backward pass. It is `L_dn`'s coherence gate ([`super::depth_normal`]): the term
//! waits until a surface has formed (meant to spare fog; measured, it does not spare
//! `occlusion`'s).
//!
//! # Gradients (added to `dL/d RayOutput`)
//! With `g = w rho'(r) / T` (`rho' = sign(r)`, or `2 r c^3 / (r^2 + c^2)^2`): world
//! `dr/dz = (-z1/z0^2, 1/z0 + 1/z2, -z1/z2^2)`, NDC `(1, -2, 1)`; then as `L_z`'s given termination: `d depth = lambda g dr/dz z_scale /
//! o` and `d opacity = -lambda g dr/dz z / o`, `o = max(opacity, OPACITY_FLOOR)` (0
//! below the floor).
//!
//! Invariants: the kernel only *adds* to `d_rays` (the photometric loss writes first);
//! it reads the forward outputs of the same batch; the triplet rays are the contiguous
//! range `offset .. offset + 3 T` of the batch (after the photometric rays, with zero
//! photometric weight).

use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::RayOutput;

use super::depth_estimate::OPACITY_FLOOR;

const SPEC: KernelSpec = KernelSpec {
    file: "loss/planarity.wgsl",
    entry: "planarity",
    bindings: &[Binding::Params, Binding::ReadOnly, Binding::ReadOnly, Binding::ReadWrite, Binding::ReadWrite],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_triplets: u32,
    offset: u32,
    ndc: u32,
    _pad0: u32,
    lambda: f32,
    opacity_floor: f32,
    scale: f32,
    coherence_power: f32,
}

/// One launch's settings of `L_pl` (the trainer applies the schedule to `lambda`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanarityTerm {
    pub lambda: f32,
    /// `c` of the robust `rho` (0: L1).
    pub scale: f32,
    /// The coherence gate's exponent `p` (0: no gate).
    pub coherence_power: f32,
}

/// The planarity kernel, its per-ray inputs and per-triplet losses.
pub struct Planarity {
    kernel: std::sync::Arc<crate::gpu::Kernel>,
    /// Per triplet ray `(w, z_scale)`, written by the caller.
    pub pixel: GpuBuffer<[f32; 2]>,
    /// Per triplet: its term of the last launch (normalized, lambda not included).
    pub triplet_loss: GpuBuffer<f32>,
}

impl Planarity {
    pub fn new(gpu: &Gpu, max_triplets: u32) -> Result<Self, GpuError> {
        let n = max_triplets.max(1) as usize;
        Ok(Self {
            kernel: gpu.kernel(&SPEC)?,
            pixel: GpuBuffer::zeros(gpu, "planarity pixels", 3 * n)?,
            triplet_loss: GpuBuffer::zeros(gpu, "planarity triplet losses", n)?,
        })
    }

    /// Records the loss of the `n_triplets` triplets in `outs[offset .. offset + 3
    /// n_triplets]` (with [`Planarity::pixel`] filled), adding `term.lambda` times its
    /// gradient into `d_rays`. `ndc`: the rays are in NDC (the residual of the module
    /// doc's second line).
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        enc: &mut Encoder,
        outs: &GpuBuffer<RayOutput>,
        d_rays: &GpuBuffer<RayOutput>,
        offset: u32,
        n_triplets: u32,
        term: &PlanarityTerm,
        ndc: bool,
    ) {
        let end = (offset + 3 * n_triplets) as usize;
        assert!(outs.len() >= end && d_rays.len() >= end, "planarity: the batch holds {} rays, the triplets end at {end}", outs.len());
        assert!(self.triplet_loss.len() >= n_triplets as usize, "planarity buffers for {} triplets", self.triplet_loss.len());
        let params = enc.params(&Params {
            n_triplets,
            offset,
            ndc: ndc as u32,
            _pad0: 0,
            lambda: term.lambda,
            opacity_floor: OPACITY_FLOOR,
            scale: term.scale,
            coherence_power: term.coherence_power,
        });
        enc.dispatch_threads(
            &self.kernel,
            &[&params, &outs.buffer, &self.pixel.buffer, &d_rays.buffer, &self.triplet_loss.buffer],
            n_triplets,
        );
    }

    /// The loss of the last launch over `n_triplets` (waits for the GPU).
    pub fn loss(&self, gpu: &Gpu, n_triplets: u32) -> Result<f32, GpuError> {
        super::sum_of_terms(gpu, &self.triplet_loss, n_triplets)
    }
}

/// `f64` CPU reference of the loss and its gradients (tests; the kernel in plain Rust).
pub mod reference {
    use super::OPACITY_FLOOR;

    /// One triplet ray as the loss sees it.
    #[derive(Clone, Copy, Debug, Default)]
    pub struct PlanarityRay {
        pub depth: f64,
        pub opacity: f64,
        pub z_scale: f64,
        /// The triplet's weight (the same on its three rays).
        pub w: f64,
        /// The length of the rendered normal (the coherence gate's input).
        pub normal_len: f64,
    }

    fn opacity_floored(r: &PlanarityRay) -> f64 {
        r.opacity.max(OPACITY_FLOOR as f64)
    }

    fn z(r: &PlanarityRay) -> f64 {
        r.z_scale * r.depth / opacity_floored(r)
    }

    /// The residual of a triplet and `dr/dz` of its three rays.
    pub fn residual(z: [f64; 3], ndc: bool) -> (f64, [f64; 3]) {
        let [z0, z1, z2] = z;
        if ndc {
            (z0 - 2.0 * z1 + z2, [1.0, -2.0, 1.0])
        } else if z0 > 0.0 && z1 > 0.0 && z2 > 0.0 {
            (z1 / z0 + z1 / z2 - 2.0, [-z1 / (z0 * z0), 1.0 / z0 + 1.0 / z2, -z1 / (z2 * z2)])
        } else {
            (0.0, [0.0; 3])
        }
    }

    /// `rho(r)` and `rho'(r)` with scale `c` (0: L1).
    pub fn rho(r: f64, c: f64) -> (f64, f64) {
        if c > 0.0 {
            let q = r * r + c * c;
            (c * r * r / q, 2.0 * r * c * c * c / (q * q))
        } else {
            (r.abs(), r.signum())
        }
    }

    /// The coherence gate of a triplet with exponent `p` (1 when `p = 0`).
    pub fn gate(t: &[PlanarityRay], p: f64) -> f64 {
        if p <= 0.0 {
            return 1.0;
        }
        let mean = t.iter().map(|r| (r.normal_len / opacity_floored(r)).min(1.0)).sum::<f64>() / t.len() as f64;
        mean.powf(p)
    }

    /// The loss of `rays` (whole triplets) with robust scale `c` (0: L1) and coherence
    /// exponent `p` (0: no gate; the gate held constant), and per ray `(dL/d depth,
    /// dL/d opacity)`.
    pub fn loss(rays: &[PlanarityRay], c: f64, p: f64, ndc: bool) -> (f64, Vec<(f64, f64)>) {
        assert_eq!(rays.len() % 3, 0, "whole triplets");
        let norm = 1.0 / (rays.len() / 3) as f64;
        let mut total = 0.0;
        let mut grads = vec![(0.0, 0.0); rays.len()];
        for (k, t) in rays.chunks(3).enumerate() {
            let (r, dr) = residual([z(&t[0]), z(&t[1]), z(&t[2])], ndc);
            let opaque = t.iter().all(|ray| ray.opacity >= OPACITY_FLOOR as f64);
            let w = if opaque { t[0].w * gate(t, p) } else { 0.0 };
            let (value, slope) = rho(r, c);
            total += w * value * norm;
            if w == 0.0 || r == 0.0 {
                continue;
            }
            let g = norm * w * slope;
            for (j, ray) in t.iter().enumerate() {
                let dz = g * dr[j];
                let o = opacity_floored(ray);
                let d_opacity = if ray.opacity > OPACITY_FLOOR as f64 { -dz * z(ray) / o } else { 0.0 };
                grads[3 * k + j] = (dz * ray.z_scale / o, d_opacity);
            }
        }
        (total, grads)
    }
}

#[cfg(test)]
mod tests {
    use super::reference::{PlanarityRay, gate, loss, residual, rho};
    use super::*;
    use crate::gpu::test_gpu;
    use crate::rng::SplitMix64;

    /// Random triplets around depth 3; triplet 1 has a ray below the opacity floor,
    /// triplet 2 a zero weight, triplet 3 a transparent ray (zero depth and opacity).
    fn random_rays(n_triplets: usize, seed: u64) -> Vec<PlanarityRay> {
        let mut r = SplitMix64::new(seed);
        let mut rays: Vec<PlanarityRay> = (0..3 * n_triplets)
            .map(|_| {
                let opacity = 0.5 + 0.25 * (r.uniform(1.0) + 1.0);
                let normal_len = opacity * (0.6 + 0.3 * (r.uniform(1.0) + 1.0));
                PlanarityRay { depth: opacity * (3.0 + 0.5 * r.uniform(1.0)), opacity, z_scale: 0.8 + 0.1 * r.uniform(1.0), w: 1.0, normal_len }
            })
            .collect();
        rays[4].opacity = 0.05;
        rays[4].depth = 0.05 * 2.9;
        for j in 6..9 {
            rays[j].w = 0.0;
        }
        rays[10].opacity = 0.0;
        rays[10].depth = 0.0;
        rays
    }

    #[test]
    fn planarity_kernel_matches_reference() {
        let gpu = test_gpu(false);
        for (n_triplets, ndc, c, p) in [(40usize, false, 0.0f32, 0.0f32), (17, true, 0.0, 2.0), (33, false, 0.02, 0.0), (9, true, 0.005, 1.5), (21, false, 0.0, 2.0)] {
            let rays = random_rays(n_triplets, n_triplets as u64);
            let offset = 5usize;
            let mut outs = vec![RayOutput::default(); offset];
            // The rendered normal: a direction of the given length.
            let dir = glam::Vec3::new(0.36, -0.48, 0.8);
            outs.extend(rays.iter().map(|r| RayOutput {
                depth: r.depth as f32,
                opacity: r.opacity as f32,
                normal: (dir * r.normal_len as f32).to_array(),
                ..Default::default()
            }));
            let pl = Planarity::new(&gpu, n_triplets as u32).unwrap();
            pl.pixel.write(&gpu, &rays.iter().map(|r| [r.w as f32, r.z_scale as f32]).collect::<Vec<_>>());
            let outs_buf = GpuBuffer::from_slice(&gpu, "outs", &outs).unwrap();
            // Pre-filled gradients: the kernel adds, and leaves the rays before `offset` alone.
            let prior: Vec<RayOutput> = (0..offset + rays.len())
                .map(|i| RayOutput { rgb: [0.5; 3], depth: 0.25, opacity: 0.01 * i as f32, normal: [0.1, 0.2, 0.3] })
                .collect();
            let d = GpuBuffer::from_slice(&gpu, "d", &prior).unwrap();
            let lambda = 0.7f32;
            let mut enc = gpu.encoder();
            let term = PlanarityTerm { lambda, scale: c, coherence_power: p };
            pl.record(&mut enc, &outs_buf, &d, offset as u32, n_triplets as u32, &term, ndc);
            enc.submit();
            let got = pl.loss(&gpu, n_triplets as u32).unwrap() as f64;
            // The robust slope is proportional to r near 0, and r is a difference of
            // terms near 1 (about 1e-7 absolute in f32): a looser relative tolerance.
            let tol = if c > 0.0 { 3e-4 } else { 1e-5 };
            let (want, grads) = loss(&rays, c as f64, p as f64, ndc);
            assert!(want > 0.0);
            assert!((got - want).abs() <= tol * want, "ndc {ndc} c {c}: loss {got} vs {want}");
            let d = d.read(&gpu).unwrap();
            let what = format!("ndc {ndc} c {c} p {p}");
            crate::loss::test_support::assert_added_depth_opacity_grads(&d, &prior, offset, &grads, lambda as f64, (tol, 0.0), &what);
            assert!(grads[6..9].iter().all(|g| *g == (0.0, 0.0)), "a zero-weight triplet gets no gradient");
            assert!(grads[3..6].iter().all(|g| *g == (0.0, 0.0)), "a ray below the opacity floor: its triplet pays nothing");
        }
    }

    #[test]
    fn planarity_reference_matches_finite_differences() {
        for (ndc, c, p) in [(false, 0.0, 0.0), (true, 0.0, 2.0), (false, 0.03, 1.0), (true, 0.01, 0.0)] {
            let rays = random_rays(12, 3);
            let (_, grads) = loss(&rays, c, p, ndc);
            let h = 1e-6;
            for k in 0..rays.len() {
                if (3..6).contains(&k) || (9..12).contains(&k) {
                    continue; // triplets with a ray below the opacity floor pay 0 (a step there)
                }
                for which in 0..2 {
                    let bump = |s: f64| {
                        let mut q = rays.clone();
                        if which == 0 {
                            q[k].depth += s;
                        } else {
                            // The gate is a constant of the backward pass: hold it by
                            // keeping the ray's normal length over opacity as it was.
                            q[k].normal_len *= (q[k].opacity + s) / q[k].opacity;
                            q[k].opacity += s;
                        }
                        loss(&q, c, p, ndc).0
                    };
                    let fd = (bump(h) - bump(-h)) / (2.0 * h);
                    let got = if which == 0 { grads[k].0 } else { grads[k].1 };
                    assert!((fd - got).abs() < 1e-6 * fd.abs().max(1.0), "ndc {ndc} c {c} ray {k} {which}: fd {fd} vs {got}");
                }
            }
        }
        // The gate: 1 without an exponent, the mean coherence to the power otherwise,
        // coherence capped at 1.
        let mut t = random_rays(12, 1)[..3].to_vec();
        for (r, f) in t.iter_mut().zip([0.5, 0.8, 1.4]) {
            r.normal_len = f * r.opacity;
        }
        assert_eq!(gate(&t, 0.0), 1.0);
        let mean: f64 = (0.5 + 0.8 + 1.0) / 3.0;
        assert!((gate(&t, 2.0) - mean * mean).abs() < 1e-12, "{}", gate(&t, 2.0));
        // The robust rho: L1-like slope near c, bounded by c, its slope falling far past it.
        let c = 0.02;
        assert!((rho(c / 3f64.sqrt(), c).1 - 0.6495).abs() < 1e-3);
        assert!(rho(1.0, c).0 < c && rho(1.0, c).1 < 1e-4 && rho(-1.0, c).1 > -1e-4);
        assert_eq!(rho(-0.3, 0.0), (0.3, -1.0));
    }

    #[test]
    fn any_plane_has_zero_residual_whatever_its_slant_and_spacing() {
        // A camera at the origin looking along +z with focal 100 px; the plane
        // n . X = d with a strong slant. The z of pixel (u, v) on the plane.
        let (n, d) = (glam::DVec3::new(0.3, -0.8, 0.52).normalize(), 2.5);
        let z_at = |u: f64, v: f64| {
            let ray = glam::DVec3::new(u / 100.0, v / 100.0, 1.0);
            d / n.dot(ray)
        };
        for (u0, v0, du, dv, s) in [(3.0, -7.0, 1.0, 0.0, 1.0), (-20.0, 10.0, 0.0, 1.0, 16.0), (5.0, 5.0, 1.0, -1.0, 9.0)] {
            let z = [z_at(u0, v0), z_at(u0 + s * du, v0 + s * dv), z_at(u0 + 2.0 * s * du, v0 + 2.0 * s * dv)];
            let (r, _) = residual(z, false);
            assert!(r.abs() < 1e-12, "plane residual {r}");
        }
        // A bump is not a plane: the middle pixel closer than the plane by 5 %.
        let z = [z_at(0.0, 0.0), 0.95 * z_at(8.0, 0.0), z_at(16.0, 0.0)];
        assert!(residual(z, false).0 < -0.05 * 1.9);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "loss/planarity.wgsl", "Params", [n_triplets, offset, ndc, lambda, opacity_floor, scale, coherence_power]);
    }
}
