//! The MLP field (mip-NeRF / RegNeRF backbone) behind the same [`Field`] interface as
//! the hash grid: position encoding, a ReLU trunk with a skip connection, a density
//! head, a view-dependent colour branch, analytic normals and the exact backward pass
//! including the second-order path through the normals.
//!
//! Owns `kernels/field/mlp_lib.wgsl` (shared parameters and helpers), `mlp_encode.wgsl`,
//! `mlp_heads.wgsl`, `mlp_heads_backward.wgsl` and, through [`gemm`], `mlp_gemm.wgsl`;
//! the `f64` CPU reference is [`reference`](mod@reference).
//!
//! # Network (defaults: mip-NeRF; [`MlpConfig`])
//! ```text
//! p    = (x - c) s                      c = AABB centre, s = 2 / longest AABB side
//! e    = [p (plain PE only), sin(2^k p), cos(2^k p)]_{k = min_deg .. max_deg-1}
//!        IPE: each band times exp(-4^k var_d / 2), var = the diagonal covariance of
//!        the sample's conical frustum (mip-NeRF's formulas with half-width dt/2 and
//!        radius r0 + r1 t, scaled by s^2); band k is zero past the active bands
//! h_0  = relu(W_0 e + b_0);  h_l = relu(W_l h_{l-1} + b_l), with [h_{l-1}, e] at the skip layer
//! raw  = w_sigma . h_{D-1} + b_sigma;   sigma = softplus(raw + density_bias)
//! bott = W_b h_{D-1} + b_b;   c1 = relu(W_c [bott, e_dir] + b_c);   rgb = sigmoid(W_rgb c1 + b_rgb)
//! e_dir = [d, sin(2^k d), cos(2^k d)]_{k < dir_max_deg},  d the unit direction
//! ```
//! The network is defined everywhere (no box test: the sampler only queries points
//! inside the scene box). Points of density queries (occupancy grid) use an isotropic
//! variance `point_var` (an occupancy cell's), as they have no frustum.
//!
//! # Analytic normals: forward-mode tangents as extra rows
//! With `normals`, every sample occupies 4 consecutive rows ("streams") of each
//! activation matrix: the primal row and the derivatives `dh/dp_e` for `e = x, y, z`.
//! The encoding writes `de/dp_e` (variance held fixed); a layer maps tangent rows by
//! `t' = relu'(z_primal) * (W t)` (no bias). As relu'' = 0 a.e., the tangent rows are
//! linear in the weights given the primal masks, so **the same matrix kernels** run the
//! 4R rows. The density head's tangent rows are `g = grad_p raw`, and
//! ```text
//! u = grad_x sigma = softplus'(raw') s g        n = -u / |u|   (0 if |u| <= eps)
//! ```
//!
//! # Backward (exact, including second order)
//! Heads: `d_o = dL/drgb rgb (1 - rgb)`; with `c = dL/dn`:
//! `du = -(I - n n^T) c / |u|`, `dg = softplus'(raw') s du`,
//! `draw = dL/dsigma softplus'(raw') + softplus''(raw') s <g, du>` (the last term is 0
//! analytically; computed anyway). `draw` seeds the primal row of the density head,
//! `dg` its 3 tangent rows. Then plain reverse mode over all rows, because the forward
//! map is linear in every row given the primal ReLU masks:
//! `G_z = G_h * relu'(z_primal)`, `G_x = G_z W`, `dW += sum_rows G_z (x) x`,
//! `db += sum_primal_rows G_z`. The colour branch runs on primal rows only and adds
//! its `G` into the primal rows of `h_{D-1}`. No gradient flows to positions or
//! directions.
//!
//! # Kernels and memory
//! Samples go in chunks of [`MlpConfig::chunk`]: encode (one thread per sample), one
//! tiled matrix product per layer ([`gemm`]: 64 x 64 output tiles per workgroup of
//! 8 x 8 threads, operands staged in workgroup memory, 8 x 8 outputs per thread in
//! registers), heads (one thread per sample). Measured with the ignored
//! `field_mlp_throughput` test; on lavapipe the 8 x 8 register block was 1.6-2.5x
//! faster than 4 x 4 (one measurement, 2 shared cores). Activations of every layer are
//! kept for the backward pass (about `4 (D + 4) W` floats per sample with normals),
//! allocated once for a chunk at construction. The sample count is read back once per
//! pass (the host loops over chunks).
//!
//! [`Field::backward`] recomputes the forward pass of each chunk, except for the last
//! chunk of the last [`Field::forward`] on the same batch with the same streams, whose
//! activations are still in place.
//!
//! # Invariants
//! * Parameters: one `f32` buffer, layer after layer (trunk 0..D, density, bottleneck,
//!   colour, rgb), each `W [out][in]` row-major followed by `b [out]`; gradients alike.
//! * Initialisation is deterministic for a seed: Glorot-uniform weights (as mip-NeRF's
//!   `glorot_uniform`), zero biases.

pub mod config;
pub mod gemm;
pub mod reference;
#[cfg(test)]
mod tests;

use std::cell::Cell;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

pub use config::{MlpConfig, PositionEncoding};
use gemm::{Dense, Kernels, View};

use super::{Field, FieldError, NamedArray, ParamGroup};
use crate::gpu::{Binding, Encoder, Gpu, GpuBuffer, GpuError, KernelSpec};
use crate::layout::{FieldGrads, FieldOutputs, GpuSample, LiveSamples, SampleBatch};

/// Name of the parameter group.
pub const PARAMS_NAME: &str = "mlp.params";

/// The pixel footprint the integrated encoding needs: a sample at ray parameter `t`
/// has frustum radius `radius0 + radius1 t` (world scenes: `radius1 = 2 / (sqrt(12)
/// focal)`, as mip-NeRF; NDC: a constant `radius0`), and density queries use the
/// isotropic variance `point_var`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub radius0: f32,
    pub radius1: f32,
    pub point_var: f32,
}

/// Where every layer lives in the parameter buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct MlpLayout {
    pub trunk: Vec<Dense>,
    pub density: Dense,
    pub bottleneck: Dense,
    pub color: Dense,
    pub rgb: Dense,
    pub pos_dim: u32,
    pub dir_dim: u32,
    pub width: u32,
    pub skip: Option<u32>,
    pub len: usize,
}

impl MlpLayout {
    pub fn new(cfg: &MlpConfig) -> Result<Self, FieldError> {
        cfg.validate()?;
        let (w, e, ed) = (cfg.width, cfg.pos_dim(), cfg.dir_dim());
        let mut off = 0u32;
        let mut dense = |n_in: u32, n_out: u32| {
            let d = Dense { w_off: off, n_in, n_out };
            off += n_out * (n_in + 1);
            d
        };
        let trunk = (0..cfg.depth)
            .map(|l| {
                let n_in = if l == 0 {
                    e
                } else if cfg.skip_layer == Some(l) {
                    w + e
                } else {
                    w
                };
                dense(n_in, w)
            })
            .collect();
        let density = dense(w, 1);
        let bottleneck = dense(w, w);
        let color = dense(w + ed, cfg.color_width);
        let rgb = dense(cfg.color_width, 3);
        Ok(Self {
            trunk,
            density,
            bottleneck,
            color,
            rgb,
            pos_dim: e,
            dir_dim: ed,
            width: w,
            skip: cfg.skip_layer,
            len: off as usize,
        })
    }

    /// Every layer with its export name.
    pub fn layers(&self) -> Vec<(String, Dense)> {
        let mut v: Vec<(String, Dense)> =
            self.trunk.iter().enumerate().map(|(l, d)| (format!("mlp.trunk.{l}"), *d)).collect();
        v.push(("mlp.density".into(), self.density));
        v.push(("mlp.bottleneck".into(), self.bottleneck));
        v.push(("mlp.color".into(), self.color));
        v.push(("mlp.rgb".into(), self.rgb));
        v
    }
}

/// Initial parameters (Glorot-uniform weights, zero biases) for a seed.
pub fn initial_params(cfg: &MlpConfig, layout: &MlpLayout) -> Vec<f32> {
    let mut rng = crate::rng::SplitMix64::new(cfg.seed ^ 0x6d6c_7000);
    let mut p = vec![0.0f32; layout.len];
    for (_, d) in layout.layers() {
        let bound = (6.0 / (d.n_in + d.n_out) as f64).sqrt();
        for v in &mut p[d.w_off as usize..d.bias_off() as usize] {
            *v = rng.uniform(bound) as f32;
        }
    }
    p
}

// ---------------------------------------------------------------- kernels

/// Mirror of `MlpParams` in `mlp_lib.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Default, Pod, Zeroable)]
struct Params {
    center: [f32; 3],
    scale: f32,
    n: u32,
    streams: u32,
    flags: u32,
    pos_min_deg: u32,
    pos_bands: u32,
    active_bands: u32,
    dir_deg: u32,
    pos_dim: u32,
    enc_off: u32,
    enc_stride: u32,
    dir_off: u32,
    dir_stride: u32,
    density_bias: f32,
    normal_eps: f32,
    radius0: f32,
    radius1: f32,
    point_var: f32,
    chunk_start: u32,
    _pad: [u32; 2],
}

const FLAG_IPE: u32 = 1;
const FLAG_NORMALS: u32 = 2;
const FLAG_COLOR: u32 = 4;

use Binding::{ReadOnly as R, ReadWrite as RW, Params as U};

const ENCODE_SAMPLES: KernelSpec =
    KernelSpec { file: "field/mlp_encode.wgsl", entry: "encode_samples", bindings: &[U, R, RW, RW] };
const ENCODE_POINTS: KernelSpec =
    KernelSpec { file: "field/mlp_encode.wgsl", entry: "encode_points", bindings: &[U, R, RW, RW] };
const HEADS: KernelSpec =
    KernelSpec { file: "field/mlp_heads.wgsl", entry: "heads_forward", bindings: &[U, R, R, RW, RW] };
const HEADS_DENSITY: KernelSpec =
    KernelSpec { file: "field/mlp_heads.wgsl", entry: "heads_density", bindings: &[U, R, R, RW] };
const HEADS_BACKWARD: KernelSpec = KernelSpec {
    file: "field/mlp_heads_backward.wgsl",
    entry: "heads_backward",
    bindings: &[U, R, R, R, R, RW, RW],
};

/// Activation and gradient buffers of one chunk (`chunk` samples, up to 4 streams).
struct Work {
    chunk: u32,
    /// `[h_{skip-1}, e]` rows (or just `e` at column `W` without a skip layer).
    cat: GpuBuffer<f32>,
    /// Trunk outputs (the one that lives in `cat` is a 1-float placeholder).
    h: Vec<GpuBuffer<f32>>,
    sig: GpuBuffer<f32>,
    /// `[bott, e_dir]` rows (primal only).
    cin: GpuBuffer<f32>,
    c1: GpuBuffer<f32>,
    rgb: GpuBuffer<f32>,
    g_sig: GpuBuffer<f32>,
    g_rgb: GpuBuffer<f32>,
    g_c1: GpuBuffer<f32>,
    g_bott: GpuBuffer<f32>,
    g: [GpuBuffer<f32>; 2],
    partial: GpuBuffer<f32>,
}

/// What a chunk's forward pass reads.
#[derive(Clone, Copy)]
enum Input<'a> {
    Samples(&'a GpuBuffer<GpuSample>),
    Points(&'a GpuBuffer<[f32; 4]>),
}

/// Identifies the activations left in [`Work`] by the last chunk forward.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct CacheKey {
    batch: usize,
    start: u32,
    len: u32,
    streams: u32,
}

/// The MLP field. See the module doc.
pub struct MlpField {
    config: MlpConfig,
    layout: MlpLayout,
    aabb: [Vec3; 2],
    footprint: Footprint,
    active_bands: u32,
    params: GpuBuffer<f32>,
    grads: GpuBuffer<f32>,
    work: Work,
    kernels: Kernels,
    cached: Cell<Option<CacheKey>>,
}

impl MlpField {
    /// A field over the box `aabb` (world or NDC units) with the deterministic
    /// initialisation of `config.seed`.
    pub fn new(gpu: &Gpu, config: &MlpConfig, aabb: [Vec3; 2], footprint: Footprint) -> Result<Self, FieldError> {
        let layout = MlpLayout::new(config)?;
        if !(aabb[0].is_finite() && aabb[1].is_finite() && aabb[0].cmplt(aabb[1]).all()) {
            return Err(FieldError::Config(format!("aabb {aabb:?} must be finite with min < max")));
        }
        let params = initial_params(config, &layout);
        let work = Self::allocate(gpu, config, &layout)?;
        Ok(Self {
            config: config.clone(),
            aabb,
            footprint,
            active_bands: config.pos_bands(),
            params: GpuBuffer::from_slice(gpu, "mlp params", &params)?,
            grads: GpuBuffer::zeros(gpu, "mlp grads", params.len())?,
            work,
            kernels: Kernels::new(gpu)?,
            cached: Cell::new(None),
            layout,
        })
    }

    fn allocate(gpu: &Gpu, cfg: &MlpConfig, l: &MlpLayout) -> Result<Work, GpuError> {
        let n = cfg.chunk as usize;
        let rows = 4 * n;
        let (w, e, ed, cw) = (l.width as usize, l.pos_dim as usize, l.dir_dim as usize, cfg.color_width as usize);
        let z = |label: &str, len: usize| GpuBuffer::<f32>::zeros(gpu, label, len.max(1));
        let h = (0..cfg.depth)
            .map(|i| z("mlp h", if l.skip == Some(i + 1) { 1 } else { rows * w }))
            .collect::<Result<Vec<_>, _>>()?;
        let partial = l.layers().iter().map(|(_, d)| gemm::partial_len(*d, rows as u32)).max().unwrap_or(1);
        Ok(Work {
            chunk: cfg.chunk,
            cat: z("mlp cat", rows * (w + e))?,
            h,
            sig: z("mlp sigma rows", rows)?,
            cin: z("mlp colour input", n * (w + ed))?,
            c1: z("mlp colour hidden", n * cw)?,
            rgb: z("mlp rgb", n * 3)?,
            g_sig: z("mlp d sigma rows", rows)?,
            g_rgb: z("mlp d rgb", n * 3)?,
            g_c1: z("mlp d colour hidden", n * cw)?,
            g_bott: z("mlp d bottleneck", n * w)?,
            g: [z("mlp d h (a)", rows * w)?, z("mlp d h (b)", rows * w)?],
            partial: z("mlp weight-gradient partials", partial)?,
        })
    }

    pub fn config(&self) -> &MlpConfig {
        &self.config
    }
    pub fn layout(&self) -> &MlpLayout {
        &self.layout
    }
    /// The parameter and gradient buffers.
    pub fn buffers(&self) -> (&GpuBuffer<f32>, &GpuBuffer<f32>) {
        (&self.params, &self.grads)
    }

    /// Centre and isotropic scale of the normalisation `p = (x - c) s`.
    pub fn normalization(&self) -> (Vec3, f32) {
        let ext = self.aabb[1] - self.aabb[0];
        (0.5 * (self.aabb[0] + self.aabb[1]), 2.0 / ext.max_element())
    }

    /// The CPU reference holding a copy of the current parameters (f64).
    pub fn reference(&self, gpu: &Gpu) -> Result<reference::MlpModel, GpuError> {
        let (c, s) = self.normalization();
        Ok(reference::MlpModel {
            config: self.config.clone(),
            layout: self.layout.clone(),
            center: c.to_array().map(f64::from),
            scale: s as f64,
            footprint: self.footprint,
            active_bands: self.active_bands,
            params: self.params.read(gpu)?.into_iter().map(f64::from).collect(),
        })
    }

    /// The input of trunk layer `l`: the encoding, the previous output, or (skip
    /// layer) `[h_{l-1}, e]` in `cat`.
    fn trunk_input(&self, l: u32) -> View<'_> {
        let (w, e) = (self.layout.width, self.layout.pos_dim);
        if l == 0 {
            View::new(&self.work.cat, w, w + e)
        } else {
            self.h_view(l - 1)
        }
    }

    /// Where the output of trunk layer `l` lives (inside `cat` before the skip layer).
    fn h_view(&self, l: u32) -> View<'_> {
        let (w, e) = (self.layout.width, self.layout.pos_dim);
        if self.layout.skip == Some(l + 1) {
            View::new(&self.work.cat, 0, w + e)
        } else {
            View::new(&self.work.h[l as usize], 0, w)
        }
    }

    fn uniform(&self, n: u32, start: u32, streams: u32, flags: u32) -> Params {
        let (c, s) = self.normalization();
        let l = &self.layout;
        let ipe = self.config.encoding == PositionEncoding::Integrated;
        Params {
            center: c.to_array(),
            scale: s,
            n,
            streams,
            flags: flags | if ipe { FLAG_IPE } else { 0 },
            pos_min_deg: self.config.pos_min_deg,
            pos_bands: self.config.pos_bands(),
            active_bands: self.active_bands,
            dir_deg: self.config.dir_max_deg,
            pos_dim: l.pos_dim,
            enc_off: l.width,
            enc_stride: l.width + l.pos_dim,
            dir_off: l.width,
            dir_stride: l.width + l.dir_dim,
            density_bias: self.config.density_bias,
            normal_eps: self.config.normal_eps,
            radius0: self.footprint.radius0,
            radius1: self.footprint.radius1,
            point_var: self.footprint.point_var,
            chunk_start: start,
            _pad: [0; 2],
        }
    }

    /// Encoding, trunk and density head of one chunk, and (with `color`) the colour
    /// branch; leaves every activation in `work`.
    fn chunk_forward(&self, gpu: &Gpu, enc: &mut Encoder, input: Input, start: u32, n: u32, streams: u32, color: bool)
    -> Result<(), GpuError> {
        let l = &self.layout;
        let k = &self.kernels;
        let rows = n * streams;
        let flags = if color { FLAG_COLOR } else { 0 };
        let u = enc.params(&self.uniform(n, start, streams, flags));
        let (spec, data) = match input {
            Input::Samples(s) => (&ENCODE_SAMPLES, &s.buffer),
            Input::Points(p) => (&ENCODE_POINTS, &p.buffer),
        };
        enc.dispatch_threads(&*gpu.kernel(spec)?, &[&u, data, &self.work.cat.buffer, &self.work.cin.buffer], n);
        for (i, layer) in l.trunk.iter().enumerate() {
            let i = i as u32;
            gemm::linear_forward(enc, k, &self.params, *layer, self.trunk_input(i), self.h_view(i), rows, streams, true);
        }
        let last = self.h_view(l.trunk.len() as u32 - 1);
        gemm::linear_forward(enc, k, &self.params, l.density, last, View::new(&self.work.sig, 0, 1), rows, streams, false);
        if color {
            let cin_stride = l.width + l.dir_dim;
            let cin = View::new(&self.work.cin, 0, cin_stride);
            gemm::linear_forward(enc, k, &self.params, l.bottleneck, last.every(streams), cin, n, 1, false);
            let c1 = View::new(&self.work.c1, 0, self.config.color_width);
            gemm::linear_forward(enc, k, &self.params, l.color, cin, c1, n, 1, true);
            gemm::linear_forward(enc, k, &self.params, l.rgb, c1, View::new(&self.work.rgb, 0, 3), n, 1, false);
        }
        Ok(())
    }

    /// Backward of one chunk whose activations are in `work`, adding into `grads`.
    fn chunk_backward(&self, gpu: &Gpu, enc: &mut Encoder, grads: &FieldGrads, start: u32, n: u32, streams: u32)
    -> Result<(), GpuError> {
        let l = &self.layout;
        let k = &self.kernels;
        let wk = &self.work;
        let rows = n * streams;
        let w = l.width;
        let cw = self.config.color_width;
        let flags = FLAG_COLOR | if streams == 4 { FLAG_NORMALS } else { 0 };
        let u = enc.params(&self.uniform(n, start, streams, flags));
        enc.dispatch_threads(
            &*gpu.kernel(&HEADS_BACKWARD)?,
            &[
                &u,
                &wk.sig.buffer,
                &wk.rgb.buffer,
                &grads.rgb_density.buffer,
                &grads.normal.buffer,
                &wk.g_sig.buffer,
                &wk.g_rgb.buffer,
            ],
            n,
        );
        let (p, g) = (&self.params, &self.grads);
        // Colour branch (primal rows).
        let c1 = View::new(&wk.c1, 0, cw);
        let g_rgb = View::new(&wk.g_rgb, 0, 3);
        let g_c1 = View::new(&wk.g_c1, 0, cw);
        gemm::linear_weight_grad(enc, k, l.rgb, g_rgb, c1, n, 1, &wk.partial, g);
        gemm::linear_grad_input(enc, k, p, l.rgb, cw, g_rgb, g_c1, n, Some((c1, 1)), false);
        let cin = View::new(&wk.cin, 0, w + l.dir_dim);
        let g_bott = View::new(&wk.g_bott, 0, w);
        gemm::linear_weight_grad(enc, k, l.color, g_c1, cin, n, 1, &wk.partial, g);
        gemm::linear_grad_input(enc, k, p, l.color, w, g_c1, g_bott, n, None, false);
        let last = self.h_view(l.trunk.len() as u32 - 1);
        gemm::linear_weight_grad(enc, k, l.bottleneck, g_bott, last.every(streams), n, 1, &wk.partial, g);
        // Density head (all rows), then G of the last trunk output from both heads.
        let g_sig = View::new(&wk.g_sig, 0, 1);
        gemm::linear_weight_grad(enc, k, l.density, g_sig, last, rows, streams, &wk.partial, g);
        let mut cur = 0usize;
        let g_last = View::new(&wk.g[cur], 0, w);
        gemm::linear_grad_input(enc, k, p, l.density, w, g_sig, g_last, rows, Some((last, streams)), false);
        gemm::linear_grad_input(enc, k, p, l.bottleneck, w, g_bott, g_last.every(streams), n, Some((last.every(streams), 1)), true);
        // Trunk, last layer first.
        for i in (0..l.trunk.len() as u32).rev() {
            let layer = l.trunk[i as usize];
            let gz = View::new(&wk.g[cur], 0, w);
            gemm::linear_weight_grad(enc, k, layer, gz, self.trunk_input(i), rows, streams, &wk.partial, g);
            if i > 0 {
                let prev = self.h_view(i - 1);
                let gx = View::new(&wk.g[1 - cur], 0, w);
                gemm::linear_grad_input(enc, k, p, layer, w, gz, gx, rows, Some((prev, streams)), false);
                cur = 1 - cur;
            }
        }
        Ok(())
    }

    fn chunks(&self, count: u32) -> impl DoubleEndedIterator<Item = (u32, u32)> + '_ {
        let chunk = self.work.chunk;
        (0..count.div_ceil(chunk)).map(move |c| (c * chunk, chunk.min(count - c * chunk)))
    }

    /// The batch's sample count, read on the host: what `enc` recorded (the sampler)
    /// is submitted first, so this backend waits here, unlike the grid.
    fn batch_count(enc: &mut Encoder, batch: &SampleBatch) -> Result<u32, GpuError> {
        enc.flush();
        Ok(batch.count.read(enc.gpu())?[0].min(batch.capacity))
    }
}

impl Field for MlpField {
    fn kind(&self) -> &'static str {
        "mlp"
    }

    fn record_density(&self, enc: &mut Encoder, points: &GpuBuffer<[f32; 4]>, count: u32, out: &GpuBuffer<f32>)
    -> Result<(), GpuError> {
        assert!(points.len() >= count as usize && out.len() >= count as usize, "density: buffers shorter than count");
        self.cached.set(None);
        let gpu = enc.gpu();
        let heads = gpu.kernel(&HEADS_DENSITY)?;
        for (start, n) in self.chunks(count) {
            self.chunk_forward(gpu, enc, Input::Points(points), start, n, 1, false)?;
            let u = enc.params(&self.uniform(n, start, 1, 0));
            let wk = &self.work;
            enc.dispatch_threads(
                &heads,
                &[&u, &wk.sig.buffer, &wk.rgb.buffer, &out.buffer],
                n,
            );
        }
        Ok(())
    }

    fn record_forward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError> {
        let cap = batch.capacity;
        out.assert_capacity(cap, "forward: FieldOutputs");
        let count = Self::batch_count(enc, batch)?;
        let gpu = enc.gpu();
        let streams = if normals { 4 } else { 1 };
        let heads = gpu.kernel(&HEADS)?;
        self.cached.set(None);
        for (start, n) in self.chunks(count) {
            self.chunk_forward(gpu, enc, Input::Samples(&batch.samples), start, n, streams, true)?;
            let flags = FLAG_COLOR | if normals { FLAG_NORMALS } else { 0 };
            let u = enc.params(&self.uniform(n, start, streams, flags));
            let wk = &self.work;
            enc.dispatch_threads(
                &heads,
                &[&u, &wk.sig.buffer, &wk.rgb.buffer, &out.rgb_density.buffer, &out.normal.buffer],
                n,
            );
            self.cached.set(Some(CacheKey { batch: batch as *const _ as usize, start, len: n, streams }));
        }
        Ok(())
    }

    /// Runs every sample: the list of live samples is not used (the MLP's chunked
    /// matrix kernels take contiguous samples; zero-gradient ones add exact zeros).
    fn record_backward(
        &mut self,
        enc: &mut Encoder,
        batch: &SampleBatch,
        grads: &FieldGrads,
        _live: Option<&LiveSamples>,
        normal_grads: bool,
    ) -> Result<(), GpuError> {
        let cap = batch.capacity;
        grads.assert_capacity(cap, "backward: FieldGrads");
        let count = Self::batch_count(enc, batch)?;
        let gpu = enc.gpu();
        let streams = if normal_grads { 4 } else { 1 };
        // Last chunk first: its activations may still be in place.
        for (start, n) in self.chunks(count).rev() {
            let key = CacheKey { batch: batch as *const _ as usize, start, len: n, streams };
            if self.cached.get() != Some(key) {
                self.chunk_forward(gpu, enc, Input::Samples(&batch.samples), start, n, streams, true)?;
                self.cached.set(Some(key));
            }
            self.chunk_backward(gpu, enc, grads, start, n, streams)?;
        }
        Ok(())
    }

    fn params(&self) -> Vec<ParamGroup<'_>> {
        vec![ParamGroup::new(PARAMS_NAME, &self.params, &self.grads).lr_scale(self.config.lr_scale)]
    }

    fn record_zero_grads(&self, enc: &mut Encoder) {
        enc.clear(&self.grads.buffer);
    }

    fn export(&self, gpu: &Gpu) -> Result<Vec<NamedArray>, GpuError> {
        let p = self.params.read(gpu)?;
        let mut out = Vec::new();
        for (name, d) in self.layout.layers() {
            let (w0, b0, b1) = (d.w_off as usize, d.bias_off() as usize, d.w_off as usize + d.len());
            out.push(NamedArray {
                name: format!("{name}.weight"),
                shape: vec![d.n_out as usize, d.n_in as usize],
                data: p[w0..b0].to_vec(),
            });
            out.push(NamedArray { name: format!("{name}.bias"), shape: vec![d.n_out as usize], data: p[b0..b1].to_vec() });
        }
        Ok(out)
    }

    fn import(&mut self, gpu: &Gpu, arrays: &[NamedArray]) -> Result<(), FieldError> {
        let mut p = vec![0.0f32; self.layout.len];
        for (name, d) in self.layout.layers() {
            for (suffix, off, len) in [
                ("weight", d.w_off as usize, (d.n_out * d.n_in) as usize),
                ("bias", d.bias_off() as usize, d.n_out as usize),
            ] {
                let full = format!("{name}.{suffix}");
                let a = arrays
                    .iter()
                    .find(|a| a.name == full)
                    .ok_or_else(|| FieldError::Import(format!("array {full:?} is missing")))?;
                if a.data.len() != len {
                    return Err(FieldError::Import(format!("array {full:?} has {} values, expected {len}", a.data.len())));
                }
                p[off..off + len].copy_from_slice(&a.data);
            }
        }
        self.params.write(gpu, &p);
        self.cached.set(None);
        Ok(())
    }

    fn encoding_levels(&self) -> u32 {
        self.config.pos_bands()
    }

    fn set_active_levels(&mut self, n: u32) {
        self.active_bands = n.min(self.config.pos_bands());
        self.cached.set(None);
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "field/mlp_lib.wgsl", "MlpParams", [center, scale, n, streams, flags, pos_min_deg, pos_bands, active_bands, dir_deg, pos_dim, enc_off, enc_stride, dir_off, dir_stride, density_bias, normal_eps, radius0, radius1, point_var, chunk_start]);
    }
}
