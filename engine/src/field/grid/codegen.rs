//! WGSL generated per grid configuration: the per-sample vector code of the hash-grid
//! kernels with every width, level count and weight offset a compile-time constant.
//!
//! Owns the text appended to `grid_density.wgsl`, `grid_forward.wgsl` and
//! `grid_backward.wgsl` when their pipelines are built ([`Gpu::specialized_kernel`]):
//! the workgroup's copy of the weights (`load_shared_weights`, the kernels' first
//! call), the encoding (levels unrolled), the MLP products (rows and columns unrolled,
//! weights read at constant indices from that copy, `wsh`, or past it from the uniform
//! block; the copy's size is the layout's [`WorkgroupWeights4`] for the kernel), the
//! analytic normal's `g` and `J^T g`, the backward products, the hash-feature scatter
//! (levels unrolled) and the scratch stores. The hand-written
//! kernels call these functions by name and keep the control flow, and call every
//! function holding a product outside their branches (see the grid module's
//! "Weights in workgroup memory" for why); `grid_lib.wgsl` keeps the per-level and
//! per-corner math.
//!
//! Why generate: with widths read from the parameters, every loop bound and every
//! index into a per-sample array (`Vec64`, `Jac64`) is a run-time value, so a compiler
//! must keep those arrays in memory and index them per thread (local memory on a GPU;
//! per-lane gathers and scatters on lavapipe, where each invocation is a SIMD lane),
//! and each weight read is a gather at a computed address. Here every array index is a
//! constant, so the arrays become registers, and every weight index is a constant, so
//! a weight read is one broadcast load from the constant block. (Pipeline `override`
//! constants were tried first: lavapipe then unrolled every loop, the level loop's
//! corner loops included, and ran slower; here only the vector code is unrolled and
//! the 8-corner loops stay loops.)
//!
//! Invariants: the generated functions compute exactly what the generic WGSL they
//! replaced computed, in the same summation order (the finite-difference and
//! reference tests of `tests.rs` run every configuration they use through them);
//! the text is a pure function of [`GridLayout`], so a configuration builds one
//! pipeline per kernel (the cache key of [`Gpu::specialized_kernel`]).
//!
//! [`Gpu::specialized_kernel`]: crate::gpu::Gpu::specialized_kernel

use std::fmt::Write;

use super::{GridLayout, DENSITY_OUT, KEPT_REGION, SH_TERMS};
#[cfg(doc)]
use super::WorkgroupWeights4;

/// Which kernel the text is for: each gets the functions it calls (the backward's refer
/// to its own bindings).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum GridKernel {
    Density,
    /// Density at a batch's samples (the sampler's visibility pass): Density's code.
    SampleDensity,
    Forward,
    Backward,
    /// The forward of a training step: also keeps each sample's encoding and normal
    /// Jacobian in the scratch buffer's kept region for the backward.
    ForwardKeep,
    /// The backward reading the kept encoding instead of gathering it from the table.
    BackwardKept,
}

impl GridKernel {
    pub(super) const COUNT: usize = 6;
}

/// The dimensions the generated code is specialized for (vec4 units).
struct Dims {
    in4: u32,
    w4: u32,
    levels: u32,
    w1: u32,
    w2: u32,
    c1: u32,
    c2: u32,
    c3: u32,
    /// Where the generated code reads each weight vec4 (set by [`source`] for its kernel).
    weights: WeightReads,
}

impl Dims {
    fn of(layout: &GridLayout) -> Self {
        Self {
            in4: (layout.in_pad / 4) as u32,
            w4: (layout.width / 4) as u32,
            levels: layout.levels.len() as u32,
            w1: (layout.w1 / 4) as u32,
            w2: (layout.w2 / 4) as u32,
            c1: (layout.c1 / 4) as u32,
            c2: (layout.c2 / 4) as u32,
            c3: (layout.c3 / 4) as u32,
            weights: WeightReads { shared4: 0 },
        }
    }
}

/// Where generated code reads weight vec4 `k` (the grid module's "Weights in workgroup
/// memory"): the workgroup copy `wsh` for `k < shared4`, else the uniform block.
#[derive(Clone, Copy)]
struct WeightReads {
    shared4: u32,
}

impl WeightReads {
    fn at(self, k: u32) -> String {
        if k < self.shared4 {
            format!("wsh[{k}u]")
        } else {
            format!("weights[{k}u]")
        }
    }
}

/// The generated WGSL for `kernel` of a field with `layout`.
pub(super) fn source(layout: &GridLayout, kernel: GridKernel) -> String {
    let mut d = Dims::of(layout);
    let copy = layout.workgroup_weights4;
    d.weights.shared4 = match kernel {
        // Density queries read only W1 and W2's first row, the block's prefix up to
        // W2's second row (`density_hidden`, `density_h0`).
        GridKernel::Density | GridKernel::SampleDensity => copy.forward.min(d.w2 + d.w4),
        GridKernel::Forward | GridKernel::ForwardKeep => copy.forward,
        GridKernel::Backward | GridKernel::BackwardKept => copy.backward,
    };
    let mut s = format!(
        "\n// ---- generated by engine/src/field/grid/codegen.rs: in4 {}, width4 {}, {} levels\n",
        d.in4, d.w4, d.levels
    );
    shared_weights(&mut s, &d);
    encode(&mut s, &d);
    density_hidden(&mut s, &d);
    match kernel {
        GridKernel::Density | GridKernel::SampleDensity => density_h0(&mut s, &d),
        _ => {
            density_mlp(&mut s, &d);
            color_mlp(&mut s, &d);
            density_dir(&mut s, &d);
            jac_t_vec(&mut s, &d);
        }
    }
    match kernel {
        GridKernel::Density | GridKernel::SampleDensity => {}
        GridKernel::Forward | GridKernel::ForwardKeep => keep_encoding(&mut s, &d, kernel == GridKernel::ForwardKeep),
        GridKernel::Backward | GridKernel::BackwardKept => {
            backward_encoding(&mut s, &d, kernel == GridKernel::BackwardKept);
            color_backward(&mut s, &d);
            normal_dg(&mut s, &d);
            density_backward(&mut s, &d);
            scatter_table_grads(&mut s, &d);
            store_rows(&mut s, &d);
        }
    }
    s
}

/// The workgroup copy of weight vec4s `0 .. shared4` and `load_shared_weights`, which
/// every per-sample kernel calls first (the grid module's "Weights in workgroup memory");
/// without a copy (`shared4` 0) the function does nothing.
fn shared_weights(s: &mut String, d: &Dims) {
    if d.weights.shared4 == 0 {
        s.push_str("fn load_shared_weights(li: u32) {}\n");
        return;
    }
    writeln!(
        s,
        "// The first {n} weight vec4 in workgroup memory, read by the products outside any branch.\n\
         var<workgroup> wsh: array<vec4<f32>, {n}>;\n\
         // Every invocation of the workgroup calls this first, outside any branch (`li`: its local index).\n\
         fn load_shared_weights(li: u32) {{\n    \
         for (var k = li; k < {n}u; k += WG_SIZE) {{\n        wsh[k] = weights[k];\n    }}\n    \
         workgroupBarrier();\n}}",
        n = d.weights.shared4
    )
    .unwrap();
}

/// vec4s of one sample's kept row: the encoding `e` (in4), then the normal path's
/// Jacobian rows packed three floats each (`6 L` floats).
pub(super) fn kept_dims4(layout: &GridLayout) -> u32 {
    let d = Dims::of(layout);
    d.in4 + kept_jac4(&d)
}

fn kept_jac4(d: &Dims) -> u32 {
    (6 * d.levels).div_ceil(4)
}

/// Float `k` of the Jacobian rows packed three to a row: `(*jac)[k / 3]`, component `k % 3`.
fn jac_comp(k: u32) -> String {
    format!("(*jac)[{}].{}", k / 3, ["x", "y", "z"][(k % 3) as usize])
}

/// The forward's `keep_encoding`: with `keep`, the `kept` binding (the backward's
/// scratch buffer) and the stores of sample `i`'s row at region `R_KEPT` (the
/// Jacobian only when the forward computes normals); without it a no-op.
fn keep_encoding(s: &mut String, d: &Dims, keep: bool) {
    if !keep {
        s.push_str("fn keep_encoding(i: u32, valid: bool, e: ptr<function, Vec64>, jac: ptr<function, Jac64>) {}\n");
        return;
    }
    s.push_str(concat!(
        "// The backward's scratch buffer: sample i's encoding and packed Jacobian at\n",
        "// P.scratch slot KEPT_REGION + i * row (engine/src/field/grid/mod.rs).\n",
        "@group(0) @binding(7) var<storage, read_write> kept: array<vec4<f32>>;\n",
        "fn keep_encoding(i: u32, valid: bool, e: ptr<function, Vec64>, jac: ptr<function, Jac64>) {\n",
        "    if (!valid) {\n",
        "        return;\n",
        "    }\n",
    ));
    writeln!(s, "    let b = P.scratch[{}][{}] + i * {}u;", KEPT_REGION / 4, KEPT_REGION % 4, d.in4 + kept_jac4(d)).unwrap();
    for k4 in 0..d.in4 {
        writeln!(s, "    kept[b + {k4}u] = (*e)[{k4}];").unwrap();
    }
    s.push_str("    if ((P.flags & FLAG_NORMALS) == 0u) {\n        return;\n    }\n");
    for j4 in 0..kept_jac4(d) {
        let c: Vec<String> = (4 * j4..4 * j4 + 4)
            .map(|k| if k < 6 * d.levels { jac_comp(k) } else { "0.0".to_string() })
            .collect();
        writeln!(s, "    kept[b + {}u] = vec4<f32>({});", d.in4 + j4, c.join(", ")).unwrap();
    }
    s.push_str("}\n");
}

/// The backward's `backward_encoding`: the encoding recomputed from the table, or with
/// `kept` sample `i`'s row of region `R_KEPT` as the forward left it (the Jacobian
/// read only when the normal path runs, zero otherwise, as `encode` leaves it).
fn backward_encoding(s: &mut String, d: &Dims, kept: bool) {
    s.push_str(concat!(
        "// e and the normal path's Jacobian of sample i at unit position p.\n",
        "fn backward_encoding(i: u32, p: vec3<f32>, want_jac: bool, e: ptr<function, Vec64>, jac: ptr<function, Jac64>) {\n",
    ));
    if !kept {
        s.push_str("    encode(p, want_jac, e, jac);\n}\n");
        return;
    }
    writeln!(s, "    let b = region(R_KEPT) + i * {}u;", d.in4 + kept_jac4(d)).unwrap();
    for k4 in 0..d.in4 {
        writeln!(s, "    (*e)[{k4}] = scratch[b + {k4}u];").unwrap();
    }
    s.push_str("    if (!want_jac) {\n");
    for r in 0..2 * d.levels {
        writeln!(s, "        (*jac)[{r}] = vec3<f32>(0.0);").unwrap();
    }
    s.push_str("        return;\n    }\n");
    for j4 in 0..kept_jac4(d) {
        writeln!(s, "    let j{j4} = scratch[b + {}u];", d.in4 + j4).unwrap();
    }
    for k in 0..6 * d.levels {
        writeln!(s, "    {} = j{}.{};", jac_comp(k), k / 4, ["x", "y", "z", "w"][(k % 4) as usize]).unwrap();
    }
    s.push_str("}\n");
}

/// Component `k % 4` of vec4 `k / 4` of array pointer `v`.
fn comp(v: &str, k: u32) -> String {
    format!("(*{v})[{}][{}]", k / 4, k % 4)
}

/// `y[r] = sum_c W[r][c] x[c]` for `4 rows4` rows, as statements writing `(*y)[r4]`,
/// optionally through a ReLU. W at vec4 offset `off`, row stride `cols4`.
fn mat_vec(s: &mut String, w: WeightReads, off: u32, rows4: u32, cols4: u32, x: &str, y: &str, relu: bool) {
    for r4 in 0..rows4 {
        let row = |k: u32| {
            let b = off + (4 * r4 + k) * cols4;
            (0..cols4).map(|c4| format!("dot({}, (*{x})[{c4}])", w.at(b + c4))).collect::<Vec<_>>().join(" + ")
        };
        let v = format!("vec4<f32>({}, {}, {}, {})", row(0), row(1), row(2), row(3));
        if relu {
            writeln!(s, "    (*{y})[{r4}] = max({v}, vec4<f32>(0.0));").unwrap();
        } else {
            writeln!(s, "    (*{y})[{r4}] = {v};").unwrap();
        }
    }
}

/// `y[c] = sum_r W[r][c] d[r]` (same W layout as [`mat_vec`]), as statements writing
/// `(*y)[c4]` for `c4 < cols4`; with `mask`, each result through `select(0, y, mask > 0)`.
fn mat_t_vec(s: &mut String, w: WeightReads, off: u32, rows4: u32, cols4: u32, d: &str, y: &str, mask: Option<&str>) {
    for c4 in 0..cols4 {
        let terms = (0..rows4)
            .map(|r4| {
                let b = off + 4 * r4 * cols4 + c4;
                format!(
                    "({} * (*{d})[{r4}].x + {} * (*{d})[{r4}].y + {} * (*{d})[{r4}].z + {} * (*{d})[{r4}].w)",
                    w.at(b),
                    w.at(b + cols4),
                    w.at(b + 2 * cols4),
                    w.at(b + 3 * cols4)
                )
            })
            .collect::<Vec<_>>()
            .join(" + ");
        match mask {
            Some(m) => writeln!(s, "    (*{y})[{c4}] = select(vec4<f32>(0.0), {terms}, (*{m})[{c4}] > vec4<f32>(0.0));")
                .unwrap(),
            None => writeln!(s, "    (*{y})[{c4}] = {terms};").unwrap(),
        }
    }
}

fn encode(s: &mut String, d: &Dims) {
    s.push_str(
        "// e (2 features per level, zero for inactive levels and the padding) and, when\n\
         // `want_jac`, the normal path's Jacobian beta_l de/dx (grid_lib.wgsl, encode_level).\n\
         fn encode(p: vec3<f32>, want_jac: bool, e: ptr<function, Vec64>, jac: ptr<function, Jac64>) {\n",
    );
    for k4 in 0..d.in4 {
        writeln!(s, "    (*e)[{k4}] = vec4<f32>(0.0);").unwrap();
    }
    for l in 0..d.levels {
        writeln!(
            s,
            "    if (level_active({l}u)) {{\n        let r = encode_level({l}u, p, want_jac);\n        \
             {} = r.val.x;\n        {} = r.val.y;\n        \
             (*jac)[{}] = r.jac0;\n        (*jac)[{}] = r.jac1;\n    }} else {{\n        \
             (*jac)[{}] = vec3<f32>(0.0);\n        (*jac)[{}] = vec3<f32>(0.0);\n    }}",
            comp("e", 2 * l),
            comp("e", 2 * l + 1),
            2 * l,
            2 * l + 1,
            2 * l,
            2 * l + 1
        )
        .unwrap();
    }
    s.push_str("}\n");
}

fn density_hidden(s: &mut String, d: &Dims) {
    s.push_str("// a1 = relu(W1 e).\nfn density_hidden(e: ptr<function, Vec64>, a1: ptr<function, Vec64>) {\n");
    mat_vec(s, d.weights, d.w1, d.w4, d.in4, "e", "a1", true);
    s.push_str("}\n");
}

fn density_mlp(s: &mut String, d: &Dims) {
    s.push_str(
        "// Density MLP: a1 = relu(W1 e), h = W2 a1 (16 outputs, h[0].x is the pre-activation density).\n\
         fn density_mlp(e: ptr<function, Vec64>, a1: ptr<function, Vec64>, h: ptr<function, Vec64>) {\n    \
         density_hidden(e, a1);\n",
    );
    mat_vec(s, d.weights, d.w2, DENSITY_OUT / 4, d.w4, "a1", "h", false);
    s.push_str("}\n");
}

fn density_h0(s: &mut String, d: &Dims) {
    let terms =
        (0..d.w4).map(|j4| format!("dot({}, (*a1)[{j4}])", d.weights.at(d.w2 + j4))).collect::<Vec<_>>().join(" + ");
    writeln!(
        s,
        "// Pre-activation density only: W2 row 0 dotted with a1.\n\
         fn density_h0(a1: ptr<function, Vec64>) -> f32 {{\n    return {terms};\n}}"
    )
    .unwrap();
}

fn color_mlp(s: &mut String, d: &Dims) {
    let cin4 = (DENSITY_OUT + SH_TERMS) / 4;
    s.push_str(
        "// Colour MLP on xc = [h (16), sh (16)]: ac1 = relu(C1 xc), ac2 = relu(C2 ac1); returns\n\
         // the pre-sigmoid output (w = 0).\n\
         fn color_mlp(xc: ptr<function, Vec64>, ac1: ptr<function, Vec64>, ac2: ptr<function, Vec64>) -> vec4<f32> {\n",
    );
    mat_vec(s, d.weights, d.c1, d.w4, cin4, "xc", "ac1", true);
    mat_vec(s, d.weights, d.c2, d.w4, d.w4, "ac1", "ac2", true);
    let row = |k: u32| {
        (0..d.w4)
            .map(|j4| format!("dot({}, (*ac2)[{j4}])", d.weights.at(d.c3 + k * d.w4 + j4)))
            .collect::<Vec<_>>()
            .join(" + ")
    };
    writeln!(s, "    return vec4<f32>({}, {}, {}, 0.0);\n}}", row(0), row(1), row(2)).unwrap();
}

fn density_dir(s: &mut String, d: &Dims) {
    s.push_str("// g = dh0/de = W1^T (relu'(z1) * W2[0, :]).\nfn density_dir(a1: ptr<function, Vec64>, g: ptr<function, Vec64>) {\n    var q: Vec64;\n");
    for j4 in 0..d.w4 {
        writeln!(s, "    q[{j4}] = select(vec4<f32>(0.0), {}, (*a1)[{j4}] > vec4<f32>(0.0));", d.weights.at(d.w2 + j4))
            .unwrap();
    }
    s.push_str("    let qp = &q;\n");
    mat_t_vec(s, d.weights, d.w1, d.w4, d.in4, "qp", "g", None);
    s.push_str("}\n");
}

fn jac_t_vec(s: &mut String, d: &Dims) {
    let terms = (0..d.levels)
        .map(|l| format!("{} * (*jac)[{}] + {} * (*jac)[{}]", comp("g", 2 * l), 2 * l, comp("g", 2 * l + 1), 2 * l + 1))
        .collect::<Vec<_>>()
        .join(" + ");
    writeln!(
        s,
        "// v = J^T g = sum_k g_k de_k/dx.\n\
         fn jac_t_vec(g: ptr<function, Vec64>, jac: ptr<function, Jac64>) -> vec3<f32> {{\n    return {terms};\n}}"
    )
    .unwrap();
}

fn color_backward(s: &mut String, d: &Dims) {
    s.push_str(
        "// Colour MLP backward from d_o = dL/do: dc2 = C3^T d_o * relu'(ac2), dc1 = C2^T dc2 * relu'(ac1),\n\
         // dh = C1^T dc1 (all 8 vec4 of dL/dxc; the first 4 are dL/dh).\n\
         fn color_backward(dout: vec4<f32>, ac1: ptr<function, Vec64>, ac2: ptr<function, Vec64>,\n\
         \x20   dc1: ptr<function, Vec64>, dc2: ptr<function, Vec64>, dh: ptr<function, Vec64>) {\n",
    );
    for j4 in 0..d.w4 {
        writeln!(
            s,
            "    (*dc2)[{j4}] = select(vec4<f32>(0.0), {} * dout.x + {} * dout.y + {} * dout.z, (*ac2)[{j4}] > vec4<f32>(0.0));",
            d.weights.at(d.c3 + j4),
            d.weights.at(d.c3 + d.w4 + j4),
            d.weights.at(d.c3 + 2 * d.w4 + j4)
        )
        .unwrap();
    }
    mat_t_vec(s, d.weights, d.c2, d.w4, d.w4, "dc2", "dc1", Some("ac1"));
    mat_t_vec(s, d.weights, d.c1, d.w4, (DENSITY_OUT + SH_TERMS) / 4, "dc1", "dh", None);
    s.push_str("}\n");
}

fn normal_dg(s: &mut String, d: &Dims) {
    s.push_str("// dL/dg = J dv.\nfn normal_dg(jac: ptr<function, Jac64>, dv: vec3<f32>, dg: ptr<function, Vec64>) {\n");
    for l in 0..d.levels {
        writeln!(s, "    {} = dot((*jac)[{}], dv);", comp("dg", 2 * l), 2 * l).unwrap();
        writeln!(s, "    {} = dot((*jac)[{}], dv);", comp("dg", 2 * l + 1), 2 * l + 1).unwrap();
    }
    s.push_str("}\n");
}

fn density_backward(s: &mut String, d: &Dims) {
    s.push_str(
        "// Density MLP backward: d1 = W2^T dh * relu'(a1), de = W1^T d1.\n\
         fn density_backward(dh: ptr<function, Vec64>, a1: ptr<function, Vec64>, d1: ptr<function, Vec64>,\n\
         \x20   de: ptr<function, Vec64>) {\n",
    );
    mat_t_vec(s, d.weights, d.w2, DENSITY_OUT / 4, d.w4, "dh", "d1", Some("a1"));
    mat_t_vec(s, d.weights, d.w1, d.w4, d.in4, "d1", "de", None);
    s.push_str("}\n");
}

fn scatter_table_grads(s: &mut String, d: &Dims) {
    s.push_str(
        "// Hash-feature gradients of every active level (grid_backward.wgsl, scatter_level).\n\
         fn scatter_table_grads(p: vec3<f32>, de: ptr<function, Vec64>, g: ptr<function, Vec64>, dv: vec3<f32>) {\n",
    );
    for l in 0..d.levels {
        writeln!(
            s,
            "    if (level_active({l}u)) {{\n        scatter_level({l}u, p, vec2<f32>({}, {}), vec2<f32>({}, {}), dv);\n    }}",
            comp("de", 2 * l),
            comp("de", 2 * l + 1),
            comp("g", 2 * l),
            comp("g", 2 * l + 1)
        )
        .unwrap();
    }
    s.push_str("}\n");
}

fn store_rows(s: &mut String, d: &Dims) {
    // (region constant, array, vec4s per row), in region order (grid_backward.wgsl).
    let rows: [(&str, &str, u32); 10] = [
        ("R_E", "e", d.in4),
        ("R_D1", "d1", d.w4),
        ("R_A1", "a1", d.w4),
        ("R_DH", "dh", DENSITY_OUT / 4),
        ("R_DG", "dg", d.in4),
        ("R_XC", "xc", (DENSITY_OUT + SH_TERMS) / 4),
        ("R_DC1", "dc1", d.w4),
        ("R_AC1", "ac1", d.w4),
        ("R_DC2", "dc2", d.w4),
        ("R_AC2", "ac2", d.w4),
    ];
    s.push_str("// Every per-sample row of the weight-gradient reduction, for sample `local` of the chunk.\nfn store_rows(local: u32");
    for (_, v, _) in rows {
        write!(s, ", {v}: ptr<function, Vec64>").unwrap();
    }
    s.push_str(", dout: vec4<f32>) {\n");
    for (r, v, n) in rows {
        writeln!(s, "    {{\n        let b = region({r}) + local * {n}u;").unwrap();
        for j in 0..n {
            writeln!(s, "        scratch[b + {j}u] = (*{v})[{j}];").unwrap();
        }
        s.push_str("    }\n");
    }
    s.push_str("    scratch[region(R_DO) + local] = dout;\n}\n");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::grid::GridConfig;

    #[test]
    fn every_array_index_and_weight_index_is_a_constant() {
        let cfg = GridConfig { n_levels: 5, hidden_width: 12, ..GridConfig::default() };
        let layout = GridLayout::new(&cfg).unwrap();
        assert_eq!(layout.mlp_len / 4, 228);
        for kernel in [GridKernel::Density, GridKernel::SampleDensity, GridKernel::Forward, GridKernel::Backward, GridKernel::ForwardKeep, GridKernel::BackwardKept] {
            let full = source(&layout, kernel);
            // Apart from the workgroup's copy of the weights (one loop, run before any
            // sample's work), no loops in the generated text, and every index into the
            // weights or their workgroup copy is a literal.
            let copy_start = full.find("fn load_shared_weights").unwrap();
            let copy_end = copy_start + full[copy_start..].find("\n}\n").unwrap();
            let src = format!("{}{}", &full[..copy_start], &full[copy_end..]);
            assert!(!src.contains("for ("), "{kernel:?}: generated code has a loop");
            for array in ["weights[", "wsh["] {
                for (i, _) in src.match_indices(array) {
                    let idx = &src[i + array.len()..];
                    let lit = &idx[..idx.find(']').unwrap()];
                    assert!(lit.ends_with('u') && lit[..lit.len() - 1].parse::<u32>().is_ok(), "{kernel:?}: {array}{lit}]");
                }
            }
            // Width 12 at 5 levels is 228 weight vec4, all in workgroup memory; density
            // queries copy only W1 and W2's first row (12 x 12 and 12 floats: 39 vec4).
            let copied = if matches!(kernel, GridKernel::Density | GridKernel::SampleDensity) { 39 } else { 228 };
            assert!(src.contains(&format!("var<workgroup> wsh: array<vec4<f32>, {copied}>")), "{kernel:?}");
        }
        // Instant-NGP's width 64 (2880 weight vec4): the first 1024 in workgroup memory,
        // the rest read from the uniform block.
        let wide = source(&GridLayout::new(&GridConfig::default()).unwrap(), GridKernel::Forward);
        assert!(wide.contains("var<workgroup> wsh: array<vec4<f32>, 1024>"));
        assert!(wide.contains("wsh[1023u]") && !wide.contains("wsh[1024u]") && wide.contains("weights[1024u]"));
        // With a larger forward copy (a CPU adapter, `forward_copy4`): the forward kernels
        // split there, the backward still at 1024, density queries copy their prefix.
        let cpu = GridLayout::new(&GridConfig::default()).unwrap().with_forward_copy4(2048);
        for kernel in [GridKernel::Forward, GridKernel::ForwardKeep] {
            let src = source(&cpu, kernel);
            assert!(src.contains("array<vec4<f32>, 2048>") && src.contains("wsh[2047u]") && src.contains("weights[2048u]"));
        }
        for kernel in [GridKernel::Backward, GridKernel::BackwardKept] {
            assert!(source(&cpu, kernel).contains("var<workgroup> wsh: array<vec4<f32>, 1024>"));
        }
        // W1 (64 x 32) and W2's first row (64): 528 vec4.
        assert!(source(&cpu, GridKernel::Density).contains("var<workgroup> wsh: array<vec4<f32>, 528>"));
        // Switched off: no workgroup memory, every weight from the uniform block.
        let off = GridLayout::new(&GridConfig { workgroup_weights: false, ..cfg }).unwrap();
        let plain = source(&off, GridKernel::Backward);
        assert!(!plain.contains("wsh") && !plain.contains("workgroupBarrier") && plain.contains("weights[0u]"));
    }
}
