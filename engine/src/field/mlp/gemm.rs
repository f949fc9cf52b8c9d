//! Thin wrapper of `kernels/field/mlp_gemm.wgsl`: the tiled matrix products of a dense
//! layer, forward and backward, over row-major activation matrices in GPU buffers.
//!
//! A layer `y = act(W x + b)` with `W: [out][in]` and `b: [out]` stored contiguously in
//! the parameter buffer (`b` right after `W`) is applied to `rows` rows at once:
//! * [`linear_forward`]: `Y = act(X W^T + b)` (bias on primal rows only, ReLU of a
//!   tangent row masked by its primal row; `streams` rows per sample);
//! * [`linear_grad_input`]: `G_X (+)= (G_Y W) * relu'(mask)` on the first `n` input
//!   columns;
//! * [`linear_weight_grad`]: `dW += G_Y^T X`, `db += sum over primal rows of G_Y`,
//!   split over the rows into partial sums (deterministic, no atomics) and reduced
//!   into the gradient buffer.
//!
//! Invariants: every view is in bounds for the rows it is used with (asserted);
//! `streams` is 1 or 4, and with 4 streams the rows of a sample are consecutive and
//! the first row is the primal one.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Binding, Encoder, GpuBuffer, Kernel, KernelSpec};

use Binding::{ReadOnly as R, ReadWrite as RW, Params as U};

const BINDINGS: &[Binding] = &[U, R, R, R, RW];
pub(super) const FORWARD: KernelSpec = KernelSpec { file: "field/mlp_gemm.wgsl", entry: "forward", bindings: BINDINGS };
pub(super) const GRAD_INPUT: KernelSpec =
    KernelSpec { file: "field/mlp_gemm.wgsl", entry: "grad_input", bindings: BINDINGS };
pub(super) const WEIGHT_GRAD: KernelSpec =
    KernelSpec { file: "field/mlp_gemm.wgsl", entry: "weight_grad", bindings: BINDINGS };
pub(super) const REDUCE: KernelSpec = KernelSpec { file: "field/mlp_gemm.wgsl", entry: "reduce", bindings: BINDINGS };

/// Output tile edge of the kernels.
const TILE: u32 = 64;
/// Largest number of row splits of a weight gradient.
pub const MAX_SPLITS: u32 = 64;
/// Fewest rows per split.
const MIN_SPLIT_ROWS: u32 = 256;

const FLAG_BIAS: u32 = 1;
const FLAG_RELU: u32 = 2;
const FLAG_ACCUMULATE: u32 = 4;
const FLAG_MASK: u32 = 8;
const FLAG_BIAS_COL: u32 = 16;

/// Mirror of `Gemm` in `mlp_gemm.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Default, Pod, Zeroable)]
struct Params {
    m: u32,
    n: u32,
    k: u32,
    flags: u32,
    a_off: u32,
    a_sm: u32,
    a_sk: u32,
    streams: u32,
    b_off: u32,
    b_sk: u32,
    b_sn: u32,
    bias_off: u32,
    c_off: u32,
    c_sm: u32,
    k_chunk: u32,
    bias_col: u32,
    mask_off: u32,
    mask_sm: u32,
    mask_streams: u32,
    splits: u32,
}

/// A row-major matrix inside a buffer: element `(r, c)` at `off + r * stride + c`.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub buf: &'a GpuBuffer<f32>,
    pub off: u32,
    pub stride: u32,
}

impl<'a> View<'a> {
    pub fn new(buf: &'a GpuBuffer<f32>, off: u32, stride: u32) -> Self {
        Self { buf, off, stride }
    }

    /// Every `step`-th row of this view (the primal rows of a multi-stream matrix).
    pub fn every(self, step: u32) -> Self {
        Self { stride: self.stride * step, ..self }
    }

    fn check(&self, rows: u32, cols: u32, what: &str) {
        if rows == 0 || cols == 0 {
            return;
        }
        let last = self.off as u64 + (rows as u64 - 1) * self.stride as u64 + cols as u64;
        assert!(last <= self.buf.len() as u64, "{what}: view of {rows}x{cols} past its buffer ({} floats)", self.buf.len());
    }
}

/// A dense layer's place in the parameter buffer: `W` at `w_off`, `b` at `w_off + out * in`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dense {
    pub w_off: u32,
    pub n_in: u32,
    pub n_out: u32,
}

impl Dense {
    pub fn bias_off(&self) -> u32 {
        self.w_off + self.n_out * self.n_in
    }
    pub fn len(&self) -> usize {
        (self.n_out * (self.n_in + 1)) as usize
    }
}

/// The four pipelines.
pub struct Kernels {
    pub forward: std::sync::Arc<Kernel>,
    pub grad_input: std::sync::Arc<Kernel>,
    pub weight_grad: std::sync::Arc<Kernel>,
    pub reduce: std::sync::Arc<Kernel>,
}

impl Kernels {
    pub fn new(gpu: &crate::gpu::Gpu) -> Result<Self, crate::gpu::GpuError> {
        Ok(Self {
            forward: gpu.kernel(&FORWARD)?,
            grad_input: gpu.kernel(&GRAD_INPUT)?,
            weight_grad: gpu.kernel(&WEIGHT_GRAD)?,
            reduce: gpu.kernel(&REDUCE)?,
        })
    }
}

fn groups(m: u32, n: u32, z: u32) -> [u32; 3] {
    [n.div_ceil(TILE), m.div_ceil(TILE), z]
}

/// `y[r] = act(W x[r] + b)` for `rows` rows (`x` has `layer.n_in` columns).
#[allow(clippy::too_many_arguments)]
pub fn linear_forward(
    enc: &mut Encoder,
    k: &Kernels,
    params: &GpuBuffer<f32>,
    layer: Dense,
    x: View,
    y: View,
    rows: u32,
    streams: u32,
    relu: bool,
) {
    x.check(rows, layer.n_in, "linear_forward x");
    y.check(rows, layer.n_out, "linear_forward y");
    let p = Params {
        m: rows,
        n: layer.n_out,
        k: layer.n_in,
        flags: FLAG_BIAS | if relu { FLAG_RELU } else { 0 },
        a_off: x.off,
        a_sm: x.stride,
        a_sk: 1,
        streams,
        b_off: layer.w_off,
        b_sk: 1,
        b_sn: layer.n_in,
        bias_off: layer.bias_off(),
        c_off: y.off,
        c_sm: y.stride,
        mask_streams: 1,
        ..Default::default()
    };
    let u = enc.params(&p);
    enc.dispatch(&k.forward, &[&u, &x.buf.buffer, &params.buffer, &x.buf.buffer, &y.buf.buffer], groups(rows, p.n, 1));
}

/// `gx[r, :n] (+)= (gy[r] W)[:n] * [mask(primal row of r) > 0]` for `rows` rows.
#[allow(clippy::too_many_arguments)]
pub fn linear_grad_input(
    enc: &mut Encoder,
    k: &Kernels,
    params: &GpuBuffer<f32>,
    layer: Dense,
    n: u32,
    gy: View,
    gx: View,
    rows: u32,
    mask: Option<(View, u32)>,
    accumulate: bool,
) {
    assert!(n <= layer.n_in);
    gy.check(rows, layer.n_out, "linear_grad_input gy");
    gx.check(rows, n, "linear_grad_input gx");
    let mut p = Params {
        m: rows,
        n,
        k: layer.n_out,
        flags: if accumulate { FLAG_ACCUMULATE } else { 0 },
        a_off: gy.off,
        a_sm: gy.stride,
        a_sk: 1,
        streams: 1,
        b_off: layer.w_off,
        b_sk: layer.n_in,
        b_sn: 1,
        c_off: gx.off,
        c_sm: gx.stride,
        mask_streams: 1,
        ..Default::default()
    };
    let mask_buf = match mask {
        Some((m, s)) => {
            m.check(rows, n, "linear_grad_input mask");
            p.flags |= FLAG_MASK;
            p.mask_off = m.off;
            p.mask_sm = m.stride;
            p.mask_streams = s;
            m.buf
        }
        None => gy.buf,
    };
    let u = enc.params(&p);
    enc.dispatch(
        &k.grad_input,
        &[&u, &gy.buf.buffer, &params.buffer, &mask_buf.buffer, &gx.buf.buffer],
        groups(rows, n, 1),
    );
}

/// Rows per split and the split count for a reduction over `rows` rows.
fn splits_for(rows: u32) -> (u32, u32) {
    let per = rows.div_ceil(MAX_SPLITS).max(MIN_SPLIT_ROWS).next_multiple_of(16);
    (per, rows.div_ceil(per).max(1))
}

/// Floats of the partial-sum buffer a weight gradient of `layer` over `rows` rows needs.
pub fn partial_len(layer: Dense, rows: u32) -> usize {
    splits_for(rows).1 as usize * layer.len()
}

/// `dW += gy^T x`, `db += sum of gy over primal rows`, over `rows` rows.
#[allow(clippy::too_many_arguments)]
pub fn linear_weight_grad(
    enc: &mut Encoder,
    k: &Kernels,
    layer: Dense,
    gy: View,
    x: View,
    rows: u32,
    streams: u32,
    partial: &GpuBuffer<f32>,
    grads: &GpuBuffer<f32>,
) {
    gy.check(rows, layer.n_out, "linear_weight_grad gy");
    x.check(rows, layer.n_in, "linear_weight_grad x");
    let (per, splits) = splits_for(rows);
    assert!(partial.len() >= splits as usize * layer.len(), "linear_weight_grad: partial buffer too small");
    let n = layer.n_in + 1;
    let p = Params {
        m: layer.n_out,
        n,
        k: rows,
        flags: FLAG_BIAS_COL,
        a_off: gy.off,
        a_sm: 1,
        a_sk: gy.stride,
        streams,
        b_off: x.off,
        b_sk: x.stride,
        b_sn: 1,
        c_off: 0,
        c_sm: n,
        k_chunk: per,
        bias_col: layer.n_in,
        mask_streams: 1,
        splits,
        ..Default::default()
    };
    let u = enc.params(&p);
    enc.dispatch(
        &k.weight_grad,
        &[&u, &gy.buf.buffer, &x.buf.buffer, &x.buf.buffer, &partial.buffer],
        groups(layer.n_out, n, splits),
    );
    let r = Params { c_off: layer.w_off, ..p };
    let u = enc.params(&r);
    enc.dispatch_threads(&k.reduce, &[&u, &partial.buffer, &partial.buffer, &partial.buffer, &grads.buffer], layer.n_out * n);
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(Params, "field/mlp_gemm.wgsl", "Gemm", [m, n, k, flags, a_off, a_sm, a_sk, streams, b_off, b_sk, b_sn, bias_off, c_off, c_sm, k_chunk, bias_col, mask_off, mask_sm, mask_streams, splits]);
    }
}
