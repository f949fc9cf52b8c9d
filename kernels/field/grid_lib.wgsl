// Hash-grid field: shared bindings 0..2 and the per-sample math (owner:
// engine/src/field/grid/mod.rs, which documents the math; CPU mirror in
// engine/src/field/grid/reference.rs). Included by grid_density.wgsl,
// grid_forward.wgsl and grid_backward.wgsl, which declare their own bindings from 3 on.
//
// Layouts (all set by the host, see GridLayout):
// * table: per level l, `levels[l].size` entries of 2 features starting at entry
//   `levels[l].offset`; entry e holds features (2e, 2e+1) of the f32 parameter buffer.
// * weights: a uniform copy of the f32 MLP parameters (the host copies them before
//   each pass).
//   vec4 units, row-major [out][in],
//   row stride = in/4:
//   P.w1 [width][in_pad] at w1, P.w2 [16][width] at w2, P.c1 [width][32] at c1,
//   P.c2 [width][width] at c2, P.c3 [4][width] at c3 (row 3 is padding, always 0).
// * Per-thread vectors live in `Vec64` (64 floats); only the first n/4 entries are used.
//
// The vector code (encode, both MLPs, the normal's g and J^T g, the backward products,
// the scatter and the scratch stores) is generated per configuration and appended to
// each kernel when its pipeline is built (engine/src/field/grid/codegen.rs): there
// every width, level count and weight offset is a constant, so per-sample arrays are
// only ever indexed by constants. Code here and in the kernels must keep that rule.

//#include "common/dispatch.wgsl"
//#include "common/layout.wgsl"

const MAX_LEVELS: u32 = 32u;
const ACT_TRUNC_EXP: u32 = 0u;
const ACT_SOFTPLUS: u32 = 1u;
const FLAG_NORMALS: u32 = 1u;
// Backward: `count` is a LiveSamples list (engine/src/layout.rs): count[0] the number
// of live samples, count[LIVE_HEADER + k] the index of the k-th; thread t of a chunk runs entry
// chunk_start + t.
const FLAG_LIVE: u32 = 2u;

alias Vec64 = array<vec4<f32>, 16>;
alias Jac64 = array<vec3<f32>, 64>;

struct Level {
    // First entry of the level in the table.
    offset: u32,
    // Entries of the level: res^3 (dense) or T (hashed, a power of two).
    size: u32,
    // Vertices per axis for dense indexing, 0 for hashed levels.
    res: u32,
    // pos = p * scale + 0.5, p in [0,1]^3.
    scale: f32,
}

struct GridParams {
    aabb_min: vec3<f32>,
    n_levels: u32,
    inv_extent: vec3<f32>,
    active_levels: u32,
    in4: u32,
    width4: u32,
    activation: u32,
    flags: u32,
    w1: u32,
    w2: u32,
    c1: u32,
    c2: u32,
    c3: u32,
    n: u32,
    chunk_start: u32,
    chunk_len: u32,
    normal_eps: f32,
    // Added to the density MLP's output before the activation (GridConfig::density_bias).
    density_bias: f32,
    // Spherical-harmonics terms of the view direction the colour MLP reads, (l + 1)^2
    // for the highest band l (GridConfig::sh_degree); the later terms are zero.
    sh_terms: u32,
    _pad: u32,
    // Backward scratch: vec4 offset of each of the 11 per-sample regions.
    scratch: array<vec4<u32>, 3>,
    levels: array<Level, MAX_LEVELS>,
    // beta_l of the analytic normal (GridConfig::normal_level_weights), level 4i+j at [i][j].
    normal_weights: array<vec4<f32>, 8>,
}

@group(0) @binding(0) var<storage, read> P_buffer: GridParams;
// The parameters, copied to private memory (`P = P_buffer;`) as the first statement of
// every entry point: outside any branch, lavapipe reads storage at a uniform address
// once and broadcasts it; inside one it reads lane by lane. Every later read of P is a
// private read.
var<private> P: GridParams;

@group(0) @binding(1) var<storage, read> table: array<vec2<f32>>;
// All MLP weights of the largest configuration (width 64, 32 levels): 2880 vec4.
const MAX_WEIGHTS4: u32 = 2880u;
// A uniform-buffer copy of the MLP parameters: every thread reads the same weight at the
// same time (a broadcast from the constant cache on NVIDIA; on lavapipe the field is
// 1.5-1.7x faster than with storage reads). Weights never steer control flow, so
// lavapipe does not recompile for their values (see gpu/kernel.rs, "Uniform buffers").
@group(0) @binding(2) var<uniform> weights: array<vec4<f32>, MAX_WEIGHTS4>;
// The per-sample kernels read most weights from a workgroup copy, `wsh`, declared and
// filled by the generated `load_shared_weights` (engine/src/field/grid/codegen.rs).

// A position mapped to the unit cube of the AABB; outside points are clamped for the
// encoding and get zero density (and a zero normal).
struct UnitPoint {
    p: vec3<f32>,
    inside: bool,
}

fn to_unit(x: vec3<f32>) -> UnitPoint {
    let q = (x - P.aabb_min) * P.inv_extent;
    let inside = all(q >= vec3<f32>(0.0)) && all(q <= vec3<f32>(1.0));
    return UnitPoint(clamp(q, vec3<f32>(0.0), vec3<f32>(1.0)), inside);
}

// Table entry of integer vertex `c` of level `l`.
fn corner_entry(l: u32, c: vec3<u32>) -> u32 {
    let lv = P.levels[l];
    var idx: u32;
    if (lv.res != 0u) {
        let cc = min(c, vec3<u32>(lv.res - 1u));
        idx = cc.x + lv.res * (cc.y + lv.res * cc.z);
    } else {
        idx = (c.x ^ (c.y * 2654435761u) ^ (c.z * 805459861u)) & (lv.size - 1u);
    }
    return lv.offset + idx;
}

// Trilinear weight of corner `bits` for fractional position f, and its gradient w.r.t. f.
struct CornerWeight {
    w: f32,
    dw: vec3<f32>,
}

fn corner_weight(f: vec3<f32>, bits: vec3<u32>) -> CornerWeight {
    let bf = vec3<f32>(bits);
    let wv = select(vec3<f32>(1.0) - f, f, bits == vec3<u32>(1u));
    let sg = bf * 2.0 - vec3<f32>(1.0);
    return CornerWeight(wv.x * wv.y * wv.z, vec3<f32>(sg.x * wv.y * wv.z, wv.x * sg.y * wv.z, wv.x * wv.y * sg.z));
}

fn corner_bits(c: u32) -> vec3<u32> {
    return vec3<u32>(c & 1u, (c >> 1u) & 1u, (c >> 2u) & 1u);
}

fn level_active(l: u32) -> bool {
    return l < P.active_levels;
}

// beta_l: the weight of level l in the analytic normal's gradient.
fn normal_weight(l: u32) -> f32 {
    return P.normal_weights[l >> 2u][l & 3u];
}

// One level's share of the encoding: its 2 features and, when `want_jac`, the normal
// path's Jacobian rows beta_l de/dx (world units; beta_l = 1 for every level gives the
// exact density gradient; zero without `want_jac`). The generated `encode`
// (engine/src/field/grid/codegen.rs) calls it for every active level with `l` a constant.
struct LevelEncoding {
    val: vec2<f32>,
    jac0: vec3<f32>,
    jac1: vec3<f32>,
}

fn encode_level(l: u32, p: vec3<f32>, want_jac: bool) -> LevelEncoding {
    let scale = P.levels[l].scale;
    let pos = p * scale + vec3<f32>(0.5);
    let fl = floor(pos);
    let f = pos - fl;
    let c0 = vec3<u32>(fl);
    var val = vec2<f32>(0.0);
    var gx = vec2<f32>(0.0);
    var gy = vec2<f32>(0.0);
    var gz = vec2<f32>(0.0);
    for (var c = 0u; c < 8u; c++) {
        let bits = corner_bits(c);
        let cw = corner_weight(f, bits);
        let feat = table[corner_entry(l, c0 + bits)];
        val += cw.w * feat;
        gx += cw.dw.x * feat;
        gy += cw.dw.y * feat;
        gz += cw.dw.z * feat;
    }
    var r = LevelEncoding(val, vec3<f32>(0.0), vec3<f32>(0.0));
    if (want_jac) {
        let sc = scale * normal_weight(l) * P.inv_extent;
        r.jac0 = vec3<f32>(gx.x, gy.x, gz.x) * sc;
        r.jac1 = vec3<f32>(gx.y, gy.y, gz.y) * sc;
    }
    return r;
}

// sigma = act(h0 + density_bias); the derivatives below are d/dh0 of the same.
fn density_act(h0_raw: f32) -> f32 {
    let h0 = h0_raw + P.density_bias;
    if (P.activation == ACT_SOFTPLUS) {
        return max(h0, 0.0) + log(1.0 + exp(-abs(h0)));
    }
    return exp(min(h0, 80.0));
}

// d sigma / d h0 (trunc_exp: exp with the argument clamped to [-15, 15], Instant-NGP).
fn density_act_d1(h0_raw: f32) -> f32 {
    let h0 = h0_raw + P.density_bias;
    if (P.activation == ACT_SOFTPLUS) {
        return 1.0 / (1.0 + exp(-h0));
    }
    return exp(clamp(h0, -15.0, 15.0));
}

fn density_act_d2(h0_raw: f32) -> f32 {
    let h0 = h0_raw + P.density_bias;
    if (P.activation == ACT_SOFTPLUS) {
        let s = 1.0 / (1.0 + exp(-h0));
        return s * (1.0 - s);
    }
    return exp(clamp(h0, -15.0, 15.0));
}

// Real spherical harmonics of degree 4 (16 coefficients, tiny-cuda-nn constants) of the
// unit direction d, written to x[4..8]; the terms from P.sh_terms on are zero.
fn sh_encode(dir: vec3<f32>, x: ptr<function, Vec64>) {
    let len = length(dir);
    var d = vec3<f32>(0.0, 0.0, 1.0);
    if (len > 0.0) {
        d = dir / len;
    }
    let xx = d.x * d.x;
    let yy = d.y * d.y;
    let zz = d.z * d.z;
    (*x)[4] = vec4<f32>(0.28209479177387814, -0.48860251190291987 * d.y, 0.48860251190291987 * d.z,
        -0.48860251190291987 * d.x);
    (*x)[5] = vec4<f32>(1.0925484305920792 * d.x * d.y, -1.0925484305920792 * d.y * d.z,
        0.94617469575755997 * zz - 0.31539156525251999, -1.0925484305920792 * d.x * d.z);
    (*x)[6] = vec4<f32>(0.54627421529603959 * (xx - yy), 0.59004358992664352 * d.y * (yy - 3.0 * xx),
        2.8906114426405538 * d.x * d.y * d.z, 0.45704579946446572 * d.y * (1.0 - 5.0 * zz));
    (*x)[7] = vec4<f32>(0.3731763325901154 * d.z * (5.0 * zz - 3.0), 0.45704579946446572 * d.x * (1.0 - 5.0 * zz),
        1.4453057213202769 * d.z * (xx - yy), 0.59004358992664352 * d.x * (3.0 * yy - xx));
    let first = vec4<u32>(0u, 1u, 2u, 3u);
    for (var k = 0u; k < 4u; k++) {
        (*x)[4u + k] = select(vec4<f32>(0.0), (*x)[4u + k], first + 4u * k < vec4<u32>(P.sh_terms));
    }
}

fn sigmoid3(o: vec4<f32>) -> vec3<f32> {
    return vec3<f32>(1.0) / (vec3<f32>(1.0) + exp(-o.xyz));
}
