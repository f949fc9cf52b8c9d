//! Tests of the hash-grid field on the GPU in use (lavapipe on CI) against the `f64`
//! CPU reference, and of the reference against central finite differences.
//!
//! Small configurations throughout (5 levels mixing dense and hashed indexing, an
//! encoding width that needs padding, default MLP widths) so each test runs in seconds.

#![allow(clippy::needless_range_loop)]

use glam::Vec3;

use super::reference::{GridModel, Trace};
use super::*;
use crate::field::Field;
use crate::field::test_support::*;
use crate::gpu::{test_gpu, Gpu};
use crate::layout::{FieldOutputs, GpuSample, SampleBatch};

pub(crate) const AABB: [Vec3; 2] = [Vec3::new(-1.0, -0.5, -2.0), Vec3::new(1.5, 1.0, 0.5)];

/// 5 levels (2 dense, 3 hashed), in_dim 10 padded to 12; a density bias, so that
/// every reference and finite-difference test covers it.
pub(crate) fn small_config() -> GridConfig {
    GridConfig {
        density_bias: -0.5,
        n_levels: 5,
        log2_hashmap_size: 11,
        base_resolution: 4,
        finest_resolution: 96.0,
        seed: 7,
        ..GridConfig::default()
    }
}

/// Replaces the field's parameters with values large enough to exercise every
/// nonlinearity (features uniform in [-1, 1], Xavier-like MLP weights).
pub(crate) fn randomize(gpu: &Gpu, field: &mut GridField, seed: u64) {
    let mut r = rng(seed);
    let mut arrays = field.export(gpu).unwrap();
    for a in &mut arrays {
        let bound = if a.name == TABLE_NAME { 1.0 } else { (6.0 / (a.shape[0] + a.shape[1]) as f64).sqrt() * 1.5 };
        a.data.iter_mut().for_each(|v| *v = r.uniform(bound) as f32);
    }
    field.import(gpu, &arrays).unwrap();
}

struct Setup {
    gpu: Gpu,
    field: GridField,
    batch: SampleBatch,
    samples: Vec<GpuSample>,
}

fn setup(cfg: &GridConfig, n: usize, capacity: u32, seed: u64, disable_float_atomics: bool) -> Setup {
    let gpu = test_gpu(disable_float_atomics);
    let mut field = GridField::new(&gpu, cfg, AABB).unwrap();
    randomize(&gpu, &mut field, seed);
    let samples = random_samples(AABB, n, seed + 1);
    let batch = SampleBatch::new(&gpu, 1, capacity).unwrap();
    batch.samples.write(&gpu, &samples);
    batch.count.write(&gpu, &[n as u32, n as u32]);
    Setup { gpu, field, batch, samples }
}

fn pos(s: &GpuSample) -> [f64; 3] {
    s.pos.map(f64::from)
}
fn dir(s: &GpuSample) -> [f64; 3] {
    s.dir.map(f64::from)
}

/// The grid's losses and reference gradients for [`LossWeights`].
trait GridLoss {
    fn loss_of(&self, i: usize, t: &Trace) -> f64;
    fn loss(&self, m: &GridModel, samples: &[GpuSample]) -> f64;
    fn cpu_grads(&self, m: &GridModel, samples: &[GpuSample], normal_grads: bool) -> reference::Grads;
}

impl GridLoss for LossWeights {
    fn loss_of(&self, i: usize, t: &Trace) -> f64 {
        self.weighted(i, t.sigma, t.rgb, t.normal)
    }

    fn loss(&self, m: &GridModel, samples: &[GpuSample]) -> f64 {
        samples.iter().enumerate().map(|(i, s)| self.loss_of(i, &m.forward(pos(s), dir(s)))).sum()
    }

    fn cpu_grads(&self, m: &GridModel, samples: &[GpuSample], normal_grads: bool) -> reference::Grads {
        let mut g = m.zero_grads();
        for (i, s) in samples.iter().enumerate() {
            let b = [0, 1, 2].map(|d| self.b[i][d] as f64);
            let c = [0, 1, 2].map(|d| self.c[i][d] as f64);
            m.backward(pos(s), dir(s), self.a[i] as f64, b, c, normal_grads, &mut g);
        }
        g
    }
}

fn scratch_rows(s: &Setup, r: usize) -> (Vec<[f32; 4]>, usize) {
    let scratch = s.field.scratch.as_ref().unwrap();
    let dim = scratch_dims4(&s.field.layout)[r] as usize;
    let all = scratch.buffer.read(&s.gpu).unwrap();
    let off = scratch.offsets[r] as usize;
    (all[off..off + dim * scratch.chunk as usize].to_vec(), dim)
}

fn scratch_vec(rows: &(Vec<[f32; 4]>, usize), i: usize) -> Vec<f64> {
    rows.0[i * rows.1..(i + 1) * rows.1].iter().flatten().map(|&v| v as f64).collect()
}

// ---------------------------------------------------------------- layout, init

#[test]
fn field_grid_layout_follows_instant_ngp() {
    let cfg = GridConfig::default();
    assert!((cfg.per_level_scale() - 1.3819).abs() < 1e-3, "b = {}", cfg.per_level_scale());
    let lay = GridLayout::new(&cfg).unwrap();
    assert_eq!(lay.levels.len(), 16);
    assert_eq!(lay.levels[0].scale, 15.0);
    assert!((lay.levels[15].scale - 2047.0).abs() < 0.1);
    let t = 1u32 << 19;
    let mut offset = 0;
    for l in &lay.levels {
        assert_eq!(l.offset, offset);
        let r = (l.scale + 0.5).floor() as u64 + 2;
        if r * r * r <= t as u64 {
            assert_eq!((l.dense_res as u64, l.size as u64), (r, r * r * r));
        } else {
            assert_eq!((l.dense_res, l.size), (0, t));
        }
        offset += l.size;
    }
    assert!(lay.levels[0].dense_res > 0 && lay.levels[15].dense_res == 0);
    assert_eq!((lay.in_dim, lay.in_pad, lay.width), (32, 32, 64));
    // Table + MLP of the defaults fit lavapipe's 128 MiB bindings; so does the scratch.
    assert!(lay.table_entries * 8 < 128 << 20);
    assert_eq!(lay.scratch_floats_per_sample(), 500);
    let small = GridLayout::new(&small_config()).unwrap();
    let kinds: Vec<bool> = small.levels.iter().map(|l| l.dense_res > 0).collect();
    assert_eq!(kinds, [true, true, false, false, false]);
    assert_eq!((small.in_dim, small.in_pad), (10, 12));
    let largest = GridLayout::new(&GridConfig { n_levels: MAX_LEVELS, hidden_width: MAX_WIDTH, ..cfg.clone() }).unwrap();
    assert_eq!(largest.mlp_len, 4 * 2880, "every matrix of the largest configuration, in whole vec4 units");
    assert!(GridLayout::new(&GridConfig { hidden_width: 30, ..cfg.clone() }).is_err());
    assert!(GridLayout::new(&GridConfig { features_per_level: 4, ..cfg.clone() }).is_err());
    assert!(GridLayout::new(&GridConfig { n_levels: 33, ..cfg }).is_err());
}

#[test]
fn field_grid_init_is_deterministic_and_in_range() {
    let cfg = small_config();
    let lay = GridLayout::new(&cfg).unwrap();
    let (t1, m1) = initial_params(&cfg, &lay);
    let (t2, m2) = initial_params(&cfg, &lay);
    assert_eq!((&t1, &m1), (&t2, &m2));
    let (t3, _) = initial_params(&GridConfig { seed: 8, ..cfg.clone() }, &lay);
    assert_ne!(t1, t3);
    assert!(t1.iter().all(|v| v.abs() <= 1e-4) && t1.iter().any(|v| v.abs() > 5e-5));
    // Padding of W1 (columns 10, 11) and row 3 of C3 are zero.
    for j in 0..lay.width {
        assert_eq!(&m1[lay.w1 + j * lay.in_pad + 10..lay.w1 + j * lay.in_pad + 12], &[0.0, 0.0]);
    }
    assert!(m1[lay.c3 + 3 * lay.width..].iter().all(|&v| v == 0.0));
    let bound = (6.0f32 / (64.0 + 64.0)).sqrt();
    assert!(m1[lay.c2..lay.c3].iter().all(|v| v.abs() <= bound));
    let cfg_json = serde_json::to_string(&cfg).unwrap();
    assert_eq!(serde_json::from_str::<GridConfig>(&cfg_json).unwrap(), cfg);
    assert_eq!(serde_json::from_str::<GridConfig>("{}").unwrap(), GridConfig::default());
}

// ---------------------------------------------------------------- encoding

#[test]
fn field_grid_encoding_reference_matches_finite_differences() {
    let gpu = test_gpu(false);
    let mut field = GridField::new(&gpu, &small_config(), AABB).unwrap();
    randomize(&gpu, &mut field, 3);
    let m = field.reference(&gpu).unwrap();
    let mut table = m.table.clone();
    let samples = random_samples(AABB, 24, 5);
    let eps = 1e-7;
    for s in samples.iter().filter(|s| m.to_unit(pos(s)).1) {
        let x = pos(s);
        let enc = m.encode(x);
        // de/dx against central differences.
        for d in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[d] += eps;
            xm[d] -= eps;
            let (ep, em) = (m.encode(xp).e, m.encode(xm).e);
            for k in 0..m.layout.in_dim {
                let fd = (ep[k] - em[k]) / (2.0 * eps);
                let an = enc.jac[k][d];
                assert!((fd - an).abs() <= 1e-5 * (1.0 + an.abs()), "de{k}/dx{d}: fd {fd} analytic {an}");
            }
        }
        // de/dF: e is linear in the features with the corner weights as coefficients.
        for (l, cs) in enc.corners.iter().enumerate() {
            let c = cs[(l * 3 + 1) % 8];
            for k in 0..2 {
                let idx = 2 * c.entry + k;
                let fd = central_diff(&mut table, idx, 1e-3, |t| {
                    let mm = GridModel { table: t.to_vec(), ..m.clone() };
                    mm.encode(x).e[2 * l + k]
                });
                let an: f64 = cs.iter().filter(|o| o.entry == c.entry).map(|o| o.w).sum();
                assert!((fd - an).abs() < 1e-9, "de/dF level {l}: fd {fd} analytic {an}");
            }
        }
    }
}

#[test]
fn field_grid_gpu_encoding_and_mlps_match_reference() {
    forward_matches_reference(&small_config());
}

/// A lower spherical-harmonics band: the GPU's colour input zeroes the same terms as the
/// reference's, and with band 0 the colour no longer depends on the view direction.
#[test]
fn field_grid_sh_degree_limits_the_view_dependence() {
    for sh_degree in [0, 1, 2] {
        forward_matches_reference(&GridConfig { sh_degree, ..small_config() });
    }
    let cfg = GridConfig { sh_degree: 0, ..small_config() };
    let s = setup(&cfg, 8, 128, 11, false);
    let m = s.field.reference(&s.gpu).unwrap();
    let x = pos(&s.samples[0]);
    let a = m.forward(x, [0.0, 0.0, 1.0]).rgb;
    let b = m.forward(x, [0.6, -0.8, 0.0]).rgb;
    assert_eq!(a, b, "band 0: a view-independent colour");
    let full = GridModel { sh_degree: 3, ..m };
    assert_ne!(full.forward(x, [0.0, 0.0, 1.0]).rgb, full.forward(x, [0.6, -0.8, 0.0]).rgb);
    assert!(GridConfig { sh_degree: 4, ..small_config() }.validate().is_err());
    end_to_end(&GridConfig { sh_degree: 1, ..small_config() }, false, 32, 4);
}

fn forward_matches_reference(cfg: &GridConfig) {
    let n = 96;
    let mut s = setup(cfg, n, 128, 11, false);
    let m = s.field.reference(&s.gpu).unwrap();
    let out = FieldOutputs::new(&s.gpu, 128).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    // Negligible output gradients (all-zero ones skip the sample): the backward writes
    // its per-sample forward values.
    let tiny = LossWeights { a: vec![1e-30; n], b: vec![[0.0; 4]; n], c: vec![[0.0; 4]; n] };
    s.field.backward(&s.gpu, &s.batch, &tiny.upload(&s.gpu, 128), None, true).unwrap();
    let (density, rgb, _) = out.read(&s.gpu).unwrap();
    let e_rows = scratch_rows(&s, region::E);
    let a1_rows = scratch_rows(&s, region::A1);
    let xc_rows = scratch_rows(&s, region::XC);
    let ac2_rows = scratch_rows(&s, region::AC2);
    for (i, smp) in s.samples.iter().enumerate() {
        let t = m.forward(pos(smp), dir(smp));
        // Encoding (GPU) == reference, padding zero.
        // (f32 positions at the finest level: errors ~ resolution x 1e-7)
        assert_close(&format!("e[{i}]"), &scratch_vec(&e_rows, i), &t.enc.e, 1e-4, 1e-4);
        // Density MLP on the GPU's own encoding == reference.
        let (a1, h) = m.density_mlp(&scratch_vec(&e_rows, i));
        assert_close(&format!("a1[{i}]"), &scratch_vec(&a1_rows, i), &a1, 1e-5, 1e-5);
        let xc = scratch_vec(&xc_rows, i);
        assert_close(&format!("h[{i}]"), &xc[..16], &h, 1e-5, 1e-5);
        assert_close(&format!("xc[{i}]"), &xc, &t.xc, 1e-4, 1e-4);
        // Colour MLP on the GPU's own input == reference.
        let (_, ac2, o) = m.color_mlp(&xc);
        assert_close(&format!("ac2[{i}]"), &scratch_vec(&ac2_rows, i), &ac2, 1e-5, 1e-5);
        let want_rgb = o.map(|v| 1.0 / (1.0 + (-v).exp()));
        assert_close(&format!("rgb[{i}]"), &to_f64(&rgb[i][..3]), &want_rgb, 1e-5, 1e-5);
        assert_close(&format!("sigma[{i}]"), &[density[i] as f64], &[t.sigma], 1e-4, 1e-4);
        assert_eq!(t.enc.inside, t.sigma > 0.0);
    }
    // Samples past count are untouched.
    assert!(density[n..].iter().all(|&v| v == 0.0));
}

// ---------------------------------------------------------------- MLP gradients

#[test]
fn field_grid_mlp_gradients_match_finite_differences() {
    // Colour-only and density-only losses isolate each MLP (first-order path).
    let n = 40;
    for (wa, wb, name) in [(0.0, 1.0, "rgb"), (1.0, 0.0, "density")] {
        let mut s = setup(&small_config(), n, 64, 21, false);
        let m = s.field.reference(&s.gpu).unwrap();
        let w = LossWeights::random(n, 22, wa, wb, 0.0);
        s.field.zero_grads(&s.gpu);
        s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 64), None, false).unwrap();
        let gpu_mlp = to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap());
        let cpu = w.cpu_grads(&m, &s.samples, false);
        assert_close(&format!("{name}: mlp grads GPU vs CPU"), &gpu_mlp, &cpu.mlp, 2e-4, 2e-3);
        // Reference analytic gradient vs finite differences for a spread of weights of
        // every matrix.
        let mut mlp = m.mlp.clone();
        let mut r = rng(23);
        for (mat, off, rows, cols, stride) in m.layout.matrices() {
            for _ in 0..6 {
                let idx = off + (r.next_u64() as usize % rows) * stride + r.next_u64() as usize % cols;
                let fd = central_diff(&mut mlp, idx, 1e-6, |p| {
                    w.loss(&GridModel { mlp: p.to_vec(), ..m.clone() }, &s.samples)
                });
                let scale = cpu.mlp.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                assert!(
                    (fd - cpu.mlp[idx]).abs() <= 1e-6 * scale + 1e-5 * fd.abs(),
                    "{name}: {mat}[{idx}]: fd {fd} analytic {} (GPU {})",
                    cpu.mlp[idx],
                    gpu_mlp[idx]
                );
            }
        }
        // Input gradient of the colour MLP (dL/dh, stored by the backward) vs finite
        // differences of the reference colour MLP.
        if name == "rgb" {
            let dh_rows = scratch_rows(&s, region::DH);
            let xc_rows = scratch_rows(&s, region::XC);
            for i in [0usize, 7, 13] {
                let mut xc = scratch_vec(&xc_rows, i);
                let got = scratch_vec(&dh_rows, i);
                for k in 0..16 {
                    let fd = central_diff(&mut xc, k, 1e-6, |x| {
                        let (_, _, o) = m.color_mlp(x);
                        (0..3).map(|c| w.b[i][c] as f64 / (1.0 + (-o[c]).exp())).sum()
                    });
                    assert!((fd - got[k]).abs() <= 1e-4 * (1.0 + fd.abs()), "dL/dh[{i}][{k}]: fd {fd} GPU {}", got[k]);
                }
            }
        }
    }
}

// ---------------------------------------------------------------- normals

#[test]
fn field_grid_normals_match_finite_differences_and_gpu() {
    let n = 96;
    let mut s = setup(&small_config(), n, 128, 31, false);
    let m = s.field.reference(&s.gpu).unwrap();
    let out = FieldOutputs::new(&s.gpu, 128).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let normals = out.normal.read(&s.gpu).unwrap();
    let eps = 1e-7;
    let mut checked = 0;
    for (i, smp) in s.samples.iter().enumerate() {
        let x = pos(smp);
        let t = m.forward(x, dir(smp));
        // GPU normals == reference analytic normals (unit or zero).
        assert_close(&format!("normal[{i}]"), &to_f64(&normals[i][..3]), &t.normal, 1e-4, 1e-4);
        if !t.enc.inside {
            assert_eq!(t.normal, [0.0; 3]);
            continue;
        }
        let len: f64 = t.normal.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((len - 1.0).abs() < 1e-12);
        // Reference analytic gradient vs central differences of the density.
        let grad: [f64; 3] = std::array::from_fn(|d| {
            let (mut xp, mut xm) = (x, x);
            xp[d] += eps;
            xm[d] -= eps;
            (m.density(xp) - m.density(xm)) / (2.0 * eps)
        });
        for d in 0..3 {
            assert!((grad[d] - t.u[d]).abs() <= 1e-5 * (1.0 + t.u[d].abs()), "grad sigma[{i}]: fd {grad:?} analytic {:?}", t.u);
        }
        let gl = grad.iter().map(|v| v * v).sum::<f64>().sqrt();
        for d in 0..3 {
            assert!((-grad[d] / gl - t.normal[d]).abs() < 1e-5);
        }
        checked += 1;
    }
    assert!(checked > n / 2);
}

// ---------------------------------------------------------------- end to end

/// L = sum_i a_i sigma_i + <b_i, rgb_i> + <c_i, n_i>: GPU backward (second order
/// through the normals) vs the reference backward for every parameter, and the
/// reference vs central differences of the reference forward on a random subset.
fn end_to_end(cfg: &GridConfig, disable_float_atomics: bool, n: usize, fd_checks: usize) {
    let mut s = setup(cfg, n, 128, 41, disable_float_atomics);
    let m = s.field.reference(&s.gpu).unwrap();
    let w = LossWeights::random(n, 42, 1.0, 1.0, 1.0);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 128), None, true).unwrap();
    let gpu_table = to_f64(&s.field.table_grad.read(&s.gpu).unwrap());
    let gpu_mlp = to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap());
    let cpu = w.cpu_grads(&m, &s.samples, true);
    assert_close("table grads GPU vs CPU", &gpu_table, &cpu.table, 3e-4, 3e-3);
    assert_close("mlp grads GPU vs CPU", &gpu_mlp, &cpu.mlp, 3e-4, 3e-3);
    // The normal path matters: without it the gradients differ.
    let first_order = w.cpu_grads(&m, &s.samples, false);
    let diff = cpu.table.iter().zip(&first_order.table).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(diff > 1e-2 * cpu.table.iter().fold(0.0f64, |a, v| a.max(v.abs())), "normal path has no effect");
    let w1_diff = (0..m.layout.in_dim).map(|k| (cpu.mlp[m.layout.w1 + k] - first_order.mlp[m.layout.w1 + k]).abs());
    assert!(w1_diff.fold(0.0, f64::max) > 0.0);

    // Finite differences: touched table entries and weights of every matrix.
    let mut r = rng(43);
    let touched: Vec<usize> = (0..cpu.table.len()).filter(|&i| cpu.table[i] != 0.0).collect();
    assert!(!touched.is_empty());
    let tscale = cpu.table.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mut table = m.table.clone();
    for _ in 0..fd_checks {
        let idx = touched[r.next_u64() as usize % touched.len()];
        let fd = central_diff(&mut table, idx, 1e-6, |t| w.loss(&GridModel { table: t.to_vec(), ..m.clone() }, &s.samples));
        assert!(
            (fd - cpu.table[idx]).abs() <= 1e-6 * tscale + 1e-5 * fd.abs(),
            "table[{idx}]: fd {fd} analytic {} GPU {}",
            cpu.table[idx],
            gpu_table[idx]
        );
    }
    let mscale = cpu.mlp.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mut mlp = m.mlp.clone();
    for (mat, off, rows, cols, stride) in m.layout.matrices() {
        // Row 0 of W2 carries the normal path's dW2 term: always include it.
        let mut idxs: Vec<usize> = (0..fd_checks / 4 + 1)
            .map(|_| off + (r.next_u64() as usize % rows) * stride + r.next_u64() as usize % cols)
            .collect();
        if mat == "grid.density_mlp.1" {
            idxs.push(off + r.next_u64() as usize % cols);
        }
        for idx in idxs {
            let fd = central_diff(&mut mlp, idx, 1e-6, |p| w.loss(&GridModel { mlp: p.to_vec(), ..m.clone() }, &s.samples));
            assert!(
                (fd - cpu.mlp[idx]).abs() <= 1e-6 * mscale + 1e-5 * fd.abs(),
                "{mat}[{idx}]: fd {fd} analytic {} GPU {}",
                cpu.mlp[idx],
                gpu_mlp[idx]
            );
        }
    }
}

#[test]
fn field_grid_end_to_end_gradients_with_normals() {
    end_to_end(&small_config(), false, 64, 24);
}

#[test]
fn field_grid_end_to_end_gradients_compare_exchange_atomics() {
    end_to_end(&small_config(), true, 48, 4);
}

/// Level weights of the band-limited normal covering 1, a fraction, 0 and a weight
/// above 1, on dense and hashed levels.
fn band_limited_config() -> GridConfig {
    GridConfig { normal_level_weights: vec![1.0, 1.3, 0.6, 0.2, 0.0], ..small_config() }
}

#[test]
fn field_grid_end_to_end_gradients_with_band_limited_normals() {
    end_to_end(&band_limited_config(), false, 64, 24);
}

/// Band-limited normals: the GPU equals the reference; the reference's `u` equals
/// central differences of the level-shifted density (each level read at
/// `x + beta_l dx`); density and colour are those of the unweighted field, the normals
/// are not.
#[test]
fn field_grid_band_limited_normals_match_finite_differences_and_gpu() {
    let n = 96;
    let cfg = band_limited_config();
    let mut s = setup(&cfg, n, 128, 33, false);
    let m = s.field.reference(&s.gpu).unwrap();
    assert_eq!(m.normal_weights, vec![1.0, 1.3f32 as f64, 0.6f32 as f64, 0.2f32 as f64, 0.0]);
    let exact = GridModel { normal_weights: vec![1.0; 5], ..m.clone() };
    let out = FieldOutputs::new(&s.gpu, 128).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let normals = out.normal.read(&s.gpu).unwrap();
    let rgbd = out.rgb_density.read(&s.gpu).unwrap();
    let eps = 1e-7;
    let (mut checked, mut differ) = (0, 0);
    for (i, smp) in s.samples.iter().enumerate() {
        let x = pos(smp);
        let t = m.forward(x, dir(smp));
        let te = exact.forward(x, dir(smp));
        assert_close(&format!("normal[{i}]"), &to_f64(&normals[i][..3]), &t.normal, 1e-4, 1e-4);
        assert_eq!((t.sigma, t.rgb), (te.sigma, te.rgb), "density and colour keep every level");
        assert_close(&format!("rgb sigma[{i}]"), &to_f64(&rgbd[i]), &[te.rgb[0], te.rgb[1], te.rgb[2], te.sigma], 1e-4, 1e-4);
        if !t.enc.inside {
            assert_eq!(t.normal, [0.0; 3]);
            continue;
        }
        let grad: [f64; 3] = std::array::from_fn(|d| {
            let (mut dp, mut dm) = ([0.0; 3], [0.0; 3]);
            dp[d] = eps;
            dm[d] = -eps;
            (m.density_level_shifted(x, dp) - m.density_level_shifted(x, dm)) / (2.0 * eps)
        });
        for d in 0..3 {
            assert!((grad[d] - t.u[d]).abs() <= 1e-5 * (1.0 + t.u[d].abs()), "u[{i}]: fd {grad:?} analytic {:?}", t.u);
        }
        let angle = (0..3).map(|d| t.normal[d] * te.normal[d]).sum::<f64>().clamp(-1.0, 1.0).acos();
        differ += (angle > 1e-3) as usize;
        checked += 1;
    }
    assert!(checked > n / 2);
    assert!(differ > checked / 2, "the weights change most normals ({differ} of {checked})");
}

#[test]
fn field_grid_normal_level_weights_are_validated() {
    let cfg = small_config();
    assert_eq!(cfg.normal_weights(), vec![1.0; 5]);
    assert!(GridConfig { normal_level_weights: vec![1.0; 5], ..cfg.clone() }.validate().is_ok());
    // Resolutions 4, 8.85, 19.6, 43.4, 96: a cap keeps the levels at or below it.
    assert_eq!(GridConfig { normal_max_resolution: 20.0, ..cfg.clone() }.normal_weights(), vec![1., 1., 1., 0., 0.]);
    assert_eq!(GridConfig { normal_max_resolution: 96.0, ..cfg.clone() }.normal_weights(), vec![1.0; 5]);
    assert_eq!(GridConfig { normal_max_resolution: 4.0, ..cfg.clone() }.normal_weights(), vec![1., 0., 0., 0., 0.]);
    let both = GridConfig { normal_max_resolution: 4.0, normal_level_weights: vec![0.5; 5], ..cfg.clone() };
    assert_eq!(both.normal_weights(), vec![0.5; 5], "the explicit weights win");
    for cap in [3.0, -1.0, f32::INFINITY, f32::NAN] {
        assert!(GridConfig { normal_max_resolution: cap, ..cfg.clone() }.validate().is_err(), "{cap}");
    }
    for bad in [vec![1.0; 4], vec![1.0, 1.0, 1.0, 1.0, -0.1], vec![0.0; 5], vec![1.0, 1.0, f32::NAN, 1.0, 1.0]] {
        assert!(GridConfig { normal_level_weights: bad.clone(), ..cfg.clone() }.validate().is_err(), "{bad:?}");
    }
}

/// `dense_normal_levels`: the levels of the normal's band become dense where they
/// would be hashed, the others keep Instant-NGP's layout; a band whose dense levels
/// would not fit is a configuration error.
#[test]
fn field_grid_dense_normal_levels_store_the_normal_band_densely() {
    // small_config: resolutions 4, 8.85, 19.6, 43.4, 96, T = 2^11; levels 0-1 dense.
    let cfg = GridConfig { normal_max_resolution: 20.0, dense_normal_levels: true, ..small_config() };
    let lay = GridLayout::new(&cfg).unwrap();
    let kinds: Vec<bool> = lay.levels.iter().map(|l| l.dense_res > 0).collect();
    assert_eq!(kinds, [true, true, true, false, false]);
    let r = (lay.levels[2].scale + 0.5).floor() as u32 + 2;
    assert_eq!((lay.levels[2].dense_res, lay.levels[2].size), (r, r * r * r));
    assert!(r * r * r > 1 << 11, "level 2 is hashed without the switch");
    let mut offset = 0;
    for l in &lay.levels {
        assert_eq!(l.offset, offset);
        offset += l.size;
    }
    assert_eq!(lay.table_entries, offset as usize);
    // The sparse preset's band (4 levels at 2^16): level 3 (54^3 vertices) becomes dense.
    let sparse = GridConfig {
        n_levels: 8,
        log2_hashmap_size: 16,
        finest_resolution: 256.0,
        hidden_width: 32,
        normal_level_weights: vec![1., 1., 1., 1., 0., 0., 0., 0.],
        dense_normal_levels: true,
        ..GridConfig::default()
    };
    let sizes: Vec<u32> = GridLayout::new(&sparse).unwrap().levels.iter().map(|l| l.size).collect();
    assert_eq!(sizes[3], 54 * 54 * 54);
    assert!(sizes[4..].iter().all(|&s| s == 1 << 16));
    // Every level in the normal at the defaults (finest 2048): far too large dense.
    let err = GridConfig { dense_normal_levels: true, ..GridConfig::default() }.validate().unwrap_err();
    assert!(err.to_string().contains("dense_normal_levels"), "{err}");
}

/// The kernels read a level made dense by the switch like any dense level: forward,
/// backward and normals equal the reference and finite differences.
#[test]
fn field_grid_end_to_end_gradients_with_dense_normal_levels() {
    end_to_end(&GridConfig { normal_max_resolution: 20.0, dense_normal_levels: true, ..small_config() }, false, 48, 8);
}

// ---------------------------------------------------------------- options

#[test]
fn field_grid_level_annealing_masks_levels() {
    let n = 48;
    let mut s = setup(&small_config(), n, 64, 51, false);
    s.field.set_active_levels(2);
    assert_eq!((s.field.active_levels(), s.field.encoding_levels()), (2, 5));
    let m = s.field.reference(&s.gpu).unwrap();
    assert_eq!(m.active_levels, 2);
    let out = FieldOutputs::new(&s.gpu, 64).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let w = LossWeights::random(n, 52, 1.0, 1.0, 1.0);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 64), None, true).unwrap();
    let e_rows = scratch_rows(&s, region::E);
    for i in 0..n {
        let e = scratch_vec(&e_rows, i);
        assert!(e[4..].iter().all(|&v| v == 0.0), "inactive levels must encode to 0");
    }
    let gpu_table = to_f64(&s.field.table_grad.read(&s.gpu).unwrap());
    let first_inactive = 2 * m.layout.levels[2].offset as usize;
    assert!(gpu_table[first_inactive..].iter().all(|&v| v == 0.0), "inactive levels get no gradient");
    assert!(gpu_table[..first_inactive].iter().any(|&v| v != 0.0));
    let cpu = w.cpu_grads(&m, &s.samples, true);
    assert_close("annealed table grads", &gpu_table, &cpu.table, 3e-4, 3e-3);
    let normals = out.normal.read(&s.gpu).unwrap();
    for (i, smp) in s.samples.iter().enumerate() {
        let t = m.forward(pos(smp), dir(smp));
        assert_close("annealed normal", &to_f64(&normals[i][..3]), &t.normal, 1e-4, 1e-4);
    }
    // The finest active level's cell along the box's shortest axis (the coarse
    // start's marching step is a fraction of it).
    let cfg = small_config();
    let ext = (s.field.aabb()[1] - s.field.aabb()[0]).min_element();
    let cell_of = |l: i32| ext / (cfg.base_resolution as f64 * cfg.per_level_scale().powi(l) - 1.0) as f32;
    let cell = s.field.finest_active_cell().unwrap();
    assert!((cell - cell_of(1)).abs() < 1e-5 * cell, "{cell} against {}", cell_of(1));
    // All levels again: level 4 contributes.
    s.field.set_active_levels(99);
    assert_eq!(s.field.active_levels(), 5);
    let fine = s.field.finest_active_cell().unwrap();
    assert!((fine - cell_of(4)).abs() < 1e-5 * fine && fine < 0.2 * cell);
}

#[test]
fn field_grid_density_queries_match_forward_and_softplus() {
    for act in [DensityActivation::TruncExp, DensityActivation::Softplus] {
        let cfg = GridConfig { density_activation: act, ..small_config() };
        let n = 70;
        let mut s = setup(&cfg, n, 128, 61, false);
        let out = FieldOutputs::new(&s.gpu, 128).unwrap();
        s.field.forward(&s.gpu, &s.batch, &out, false).unwrap();
        let (q, f) = (query_densities(&s.gpu, &s.field, &s.samples), out.read(&s.gpu).unwrap().0);
        let m = s.field.reference(&s.gpu).unwrap();
        for i in 0..n {
            assert_eq!(q[i], f[i], "{act:?}: query vs forward density at {i}");
            let want = m.density(pos(&s.samples[i]));
            assert!((q[i] as f64 - want).abs() <= 1e-5 * (1.0 + want), "{act:?}: {} vs {want}", q[i]);
        }
        // No normals requested: the normal buffer is untouched.
        assert!(out.normal.read(&s.gpu).unwrap().iter().all(|v| *v == [0.0; 4]));
        // The visibility pass's densities at a batch's samples: the forward's, written
        // only below count[0] (the rest keeps its sentinel).
        let dens = FieldOutputs::new(&s.gpu, 128).unwrap();
        dens.rgb_density.write(&s.gpu, &[[-1.0; 4]; 128]);
        let mut enc = s.gpu.encoder();
        s.field.record_sample_density(&mut enc, &s.batch, &dens).unwrap();
        enc.submit();
        let got = dens.rgb_density.read(&s.gpu).unwrap();
        for i in 0..n {
            assert_eq!(got[i][3], f[i], "{act:?}: sample density vs forward density at {i}");
        }
        assert!(got[n..].iter().all(|v| *v == [-1.0; 4]), "{act:?}: samples past the count are not written");
        // Softplus end to end through the reference (first and second order).
        if act == DensityActivation::Softplus {
            let m = s.field.reference(&s.gpu).unwrap();
            let w = LossWeights::random(n, 62, 1.0, 0.5, 1.0);
            s.field.zero_grads(&s.gpu);
            s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 128), None, true).unwrap();
            let cpu = w.cpu_grads(&m, &s.samples, true);
            let gpu_mlp = to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap());
            assert_close("softplus mlp grads", &gpu_mlp, &cpu.mlp, 3e-4, 3e-3);
            let mut mlp = m.mlp.clone();
            let idx = m.layout.w2 + 3;
            let fd = central_diff(&mut mlp, idx, 1e-6, |p| w.loss(&GridModel { mlp: p.to_vec(), ..m.clone() }, &s.samples));
            assert!((fd - cpu.mlp[idx]).abs() < 1e-6 * (1.0 + fd.abs()), "softplus W2[0,3]: fd {fd} vs {}", cpu.mlp[idx]);
        }
    }
}

#[test]
fn field_grid_backward_skips_samples_without_gradient_exactly() {
    // Runs of samples with all-zero output gradients (as past a ray's early
    // termination) return early; the gradients must equal the reference's, and the
    // rows they leave in scratch must not carry a previous chunk's values (NaN here).
    let n = 200;
    let cfg = GridConfig { backward_chunk: 64, hidden_width: 16, ..small_config() };
    let mut s = setup(&cfg, n, 256, 73, false);
    let mut w = LossWeights::random(n, 74, 1.0, 1.0, 1.0);
    for i in (0..n).filter(|i| (i / 13) % 2 == 1 || i % 7 == 0) {
        (w.a[i], w.b[i], w.c[i]) = (0.0, [0.0; 4], [0.0; 4]);
    }
    // Normal gradient alone, and density gradient alone, still count as gradient.
    (w.a[26], w.b[26]) = (0.0, [0.0; 4]);
    (w.b[27], w.c[27]) = ([0.0; 4], [0.0; 4]);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 256), None, true).unwrap();
    let scratch = s.field.scratch.as_ref().unwrap();
    scratch.buffer.write(&s.gpu, &vec![[f32::NAN; 4]; scratch.buffer.len()]);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &w.upload(&s.gpu, 256), None, true).unwrap();
    let m = s.field.reference(&s.gpu).unwrap();
    let cpu = w.cpu_grads(&m, &s.samples, true);
    assert_close("table grads with skipped samples", &to_f64(&s.field.table_grad.read(&s.gpu).unwrap()), &cpu.table, 3e-4, 3e-3);
    assert_close("mlp grads with skipped samples", &to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap()), &cpu.mlp, 3e-4, 3e-3);

    // The same through the list of the samples that carry gradient (the sampler's live
    // compaction writes it in training): only those run, in chunks of the list.
    let grads = w.upload(&s.gpu, 256);
    let listed: Vec<u32> =
        (0..n).filter(|&i| w.a[i] != 0.0 || w.b[i] != [0.0; 4] || w.c[i] != [0.0; 4]).map(|i| i as u32).collect();
    assert!(listed.len() > 64 && listed.len() < n - 64, "several chunks, some of them empty");
    let live = LiveSamples::new(&s.gpu, 256).unwrap();
    // Stale entries past the list's end point at samples with gradient: they must not run.
    let mut stale = listed.clone();
    stale.resize(256, 3);
    live.write(&s.gpu, &stale);
    live.write(&s.gpu, &listed);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &grads, Some(&live), true).unwrap();
    assert_close("table grads of the live list", &to_f64(&s.field.table_grad.read(&s.gpu).unwrap()), &cpu.table, 3e-4, 3e-3);
    assert_close("mlp grads of the live list", &to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap()), &cpu.mlp, 3e-4, 3e-3);
}

/// The training step's path: `forward_for_backward` keeps each sample's encoding and
/// normal Jacobian, and the backward that follows reads them instead of gathering the
/// table (in chunks, and over a live list with some samples skipped). The gradients
/// equal the reference's; the kept rows are what the backward reads (zeroing them
/// changes its result); a kept encoding without the Jacobian, of another batch or at
/// other levels is not used, and one is used only once.
fn backward_from_the_kept_encoding(cfg: GridConfig) {
    let n = 200;
    let cfg = GridConfig { backward_chunk: 64, ..cfg };
    let mut s = setup(&cfg, n, 256, 77, false);
    let mut w = LossWeights::random(n, 78, 1.0, 1.0, 1.0);
    for i in (0..n).filter(|i| i % 5 == 1) {
        (w.a[i], w.b[i], w.c[i]) = (0.0, [0.0; 4], [0.0; 4]);
    }
    let grads = w.upload(&s.gpu, 256);
    let m = s.field.reference(&s.gpu).unwrap();
    let cpu = w.cpu_grads(&m, &s.samples, true);
    let out = FieldOutputs::new(&s.gpu, 256).unwrap();
    let table_grad = |s: &Setup| to_f64(&s.field.table_grad.read(&s.gpu).unwrap());
    let mlp_grad = |s: &Setup| to_f64(&s.field.mlp_grad.read(&s.gpu).unwrap());
    let check = |s: &Setup, what: &str| {
        assert_close(&format!("table grads, {what}"), &table_grad(s), &cpu.table, 3e-4, 3e-3);
        assert_close(&format!("mlp grads, {what}"), &mlp_grad(s), &cpu.mlp, 3e-4, 3e-3);
    };

    s.field.forward_for_backward(&s.gpu, &s.batch, &out, true).unwrap();
    assert!(s.field.kept.is_some(), "the training forward keeps the encoding");
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
    assert!(s.field.kept.is_none(), "used once");
    check(&s, "kept encoding");

    let listed: Vec<u32> =
        (0..n).filter(|&i| w.a[i] != 0.0 || w.b[i] != [0.0; 4] || w.c[i] != [0.0; 4]).map(|i| i as u32).collect();
    let live = LiveSamples::new(&s.gpu, 256).unwrap();
    live.write(&s.gpu, &listed);
    s.field.forward_for_backward(&s.gpu, &s.batch, &out, true).unwrap();
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &grads, Some(&live), true).unwrap();
    check(&s, "kept encoding, live list");

    // The backward reads the kept rows: zeroed, the gradients change.
    s.field.forward_for_backward(&s.gpu, &s.batch, &out, true).unwrap();
    let scratch = s.field.scratch.as_ref().unwrap();
    let mut rows = scratch.buffer.read(&s.gpu).unwrap();
    let kept = scratch.kept_offset as usize..rows.len();
    assert_eq!(kept.len(), codegen::kept_dims4(&s.field.layout) as usize * 256);
    rows[kept].iter_mut().for_each(|r| *r = [0.0; 4]);
    scratch.buffer.write(&s.gpu, &rows);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
    let zeroed = mlp_grad(&s);
    let diff = zeroed.iter().zip(&cpu.mlp).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(diff > 1e-3 * cpu.mlp.iter().fold(0.0f64, |a, v| a.max(v.abs())), "the kept rows were not read");

    // Not used: kept without the Jacobian for a backward through the normals, after a
    // level change, for another batch; nor a second time.
    let other = SampleBatch::new(&s.gpu, 1, 256).unwrap();
    other.samples.write(&s.gpu, &s.samples);
    other.count.write(&s.gpu, &[n as u32, n as u32]);
    type Prepare<'a> = &'a dyn Fn(&mut Setup);
    let cases: [(&str, Prepare); 4] = [
        ("kept without normals", &|s| s.field.forward_for_backward(&s.gpu, &s.batch, &out, false).unwrap()),
        ("kept at other levels", &|s| {
            s.field.set_active_levels(2);
            s.field.forward_for_backward(&s.gpu, &s.batch, &out, true).unwrap();
            s.field.set_active_levels(cfg.n_levels);
        }),
        ("kept for another batch", &|s| s.field.forward_for_backward(&s.gpu, &other, &out, true).unwrap()),
        ("kept and used before", &|s| {
            s.field.forward_for_backward(&s.gpu, &s.batch, &out, true).unwrap();
            s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
        }),
    ];
    for (what, prepare) in cases {
        // Poison the kept region: a backward that read it would not match.
        prepare(&mut s);
        let scratch = s.field.scratch.as_ref().unwrap();
        let mut rows = scratch.buffer.read(&s.gpu).unwrap();
        let kept = scratch.kept_offset as usize..rows.len();
        rows[kept].iter_mut().for_each(|r| *r = [f32::NAN; 4]);
        scratch.buffer.write(&s.gpu, &rows);
        s.field.zero_grads(&s.gpu);
        s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
        check(&s, what);
    }
}

#[test]
fn field_grid_backward_from_the_kept_encoding() {
    backward_from_the_kept_encoding(small_config());
}

#[test]
fn field_grid_backward_from_the_kept_encoding_with_band_limited_normals() {
    backward_from_the_kept_encoding(GridConfig { dense_normal_levels: true, ..band_limited_config() });
}

#[test]
fn field_grid_weights_from_the_uniform_block_match_the_workgroup_copy() {
    // `workgroup_weights` off reads every weight from the uniform block: the same
    // outputs bit for bit (same values, same order of operations) and gradients that
    // match the CPU reference.
    let n = 96;
    // Width 16 (as the chunk test below) keeps the extra pipelines quick to compile.
    let cfg = GridConfig { hidden_width: 16, ..small_config() };
    let mut on = setup(&cfg, n, 128, 41, false);
    let mut off = setup(&GridConfig { workgroup_weights: false, ..cfg }, n, 128, 41, false);
    let (copy_on, copy_off) = (on.field.layout().workgroup_weights4, off.field.layout().workgroup_weights4);
    assert!(copy_on.forward > 0 && copy_on.backward > 0, "{copy_on:?}");
    assert_eq!(copy_off, WorkgroupWeights4 { forward: 0, backward: 0 });
    let outputs = |s: &mut Setup| {
        let out = FieldOutputs::new(&s.gpu, 128).unwrap();
        s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
        out.read(&s.gpu).unwrap()
    };
    assert_eq!(outputs(&mut on), outputs(&mut off));
    let w = LossWeights::random(n, 42, 1.0, 1.0, 1.0);
    off.field.zero_grads(&off.gpu);
    off.field.backward(&off.gpu, &off.batch, &w.upload(&off.gpu, 128), None, true).unwrap();
    let cpu = w.cpu_grads(&off.field.reference(&off.gpu).unwrap(), &off.samples, true);
    assert_close("table", &to_f64(&off.field.table_grad.read(&off.gpu).unwrap()), &cpu.table, 3e-4, 3e-3);
    assert_close("mlp", &to_f64(&off.field.mlp_grad.read(&off.gpu).unwrap()), &cpu.mlp, 3e-4, 3e-3);
}

#[test]
fn field_grid_wider_forward_copy_matches_reference() {
    // A width-64 field at 8 levels has 2112 weight vec4, more than the 16 KB copy. On a
    // CPU adapter with 32 KB of workgroup memory (lavapipe) the forward kernels copy
    // 2048 of them and read the rest from the uniform block, the backward copies 1024
    // (`forward_copy4`). The forward and density queries match the CPU reference, so
    // every weight is read from where it is (a weight read from the wrong place, or
    // from an uncopied slot, would be off by far more than rounding).
    let n = 96;
    let cfg = GridConfig { hidden_width: 64, n_levels: 8, ..small_config() };
    let mut s = setup(&cfg, n, 128, 43, false);
    let layout = s.field.layout();
    assert_eq!(layout.mlp_len / 4, 2112);
    let copy = layout.workgroup_weights4;
    assert_eq!(copy, WorkgroupWeights4 { forward: forward_copy4(&s.gpu), backward: SHARED_WEIGHTS4 });
    if s.gpu.adapter().is_cpu() && s.gpu.limits().max_compute_workgroup_storage_size >= 32 << 10 {
        assert_eq!(copy.forward, SHARED_WEIGHTS4_CPU_FORWARD);
    }
    let out = FieldOutputs::new(&s.gpu, 128).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let (density, rgb, _) = out.read(&s.gpu).unwrap();
    let queried = query_densities(&s.gpu, &s.field, &s.samples);
    let m = s.field.reference(&s.gpu).unwrap();
    for (i, smp) in s.samples.iter().enumerate() {
        let t = m.forward(pos(smp), dir(smp));
        assert_close(&format!("rgb[{i}]"), &to_f64(&rgb[i][..3]), &t.rgb, 1e-4, 1e-4);
        assert_close(&format!("sigma[{i}]"), &[density[i] as f64], &[t.sigma], 1e-4, 1e-4);
        assert_close(&format!("queried sigma[{i}]"), &[queried[i] as f64], &[t.sigma], 1e-4, 1e-4);
    }
    assert!(density.iter().any(|&d| d > 0.0), "no sample inside the box: the comparison says little");
}

#[test]
fn field_grid_backward_chunks_and_accumulation() {
    // A 64-sample chunk over 200 samples (capacity 256, count 200) must give the same
    // gradients as one chunk; two backward calls add up.
    let n = 200;
    let cfg = GridConfig { backward_chunk: 64, hidden_width: 16, ..small_config() };
    let mut s = setup(&cfg, n, 256, 71, false);
    let w = LossWeights::random(n, 72, 1.0, 1.0, 1.0);
    let grads = w.upload(&s.gpu, 256);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
    assert_eq!(s.field.scratch.as_ref().unwrap().chunk, 64);
    let chunked = (s.field.table_grad.read(&s.gpu).unwrap(), s.field.mlp_grad.read(&s.gpu).unwrap());
    let m = s.field.reference(&s.gpu).unwrap();
    let cpu = w.cpu_grads(&m, &s.samples, true);
    assert_close("chunked table", &to_f64(&chunked.0), &cpu.table, 3e-4, 3e-3);
    assert_close("chunked mlp", &to_f64(&chunked.1), &cpu.mlp, 3e-4, 3e-3);
    s.field.backward(&s.gpu, &s.batch, &grads, None, true).unwrap();
    let twice = s.field.mlp_grad.read(&s.gpu).unwrap();
    let doubled: Vec<f64> = cpu.mlp.iter().map(|v| 2.0 * v).collect();
    assert_close("accumulated mlp", &to_f64(&twice), &doubled, 3e-4, 3e-3);
    s.field.zero_grads(&s.gpu);
    assert!(s.field.mlp_grad.read(&s.gpu).unwrap().iter().all(|&v| v == 0.0));

    // The weight-gradient kernel's sample groups: 7 samples a thread (groups that do
    // not divide the chunk, a short last one) and one sample a thread give the same
    // weight gradients; the table's are not computed there.
    for spt in [7, 1] {
        let cfg = GridConfig { outer_samples_per_thread: spt, ..cfg.clone() };
        let mut g = setup(&cfg, n, 256, 71, false);
        g.field.zero_grads(&g.gpu);
        g.field.backward(&g.gpu, &g.batch, &w.upload(&g.gpu, 256), None, true).unwrap();
        let what = format!("mlp, {spt} samples a thread");
        assert_close(&what, &to_f64(&g.field.mlp_grad.read(&g.gpu).unwrap()), &cpu.mlp, 3e-4, 3e-3);
    }
}

#[test]
fn field_grid_export_import_roundtrip_and_param_groups() {
    let gpu = test_gpu(false);
    let cfg = small_config();
    let mut field = GridField::new(&gpu, &cfg, AABB).unwrap();
    let arrays = field.export(&gpu).unwrap();
    let names: Vec<&str> = arrays.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(
        names,
        [TABLE_NAME, "grid.density_mlp.0", "grid.density_mlp.1", "grid.color_mlp.0", "grid.color_mlp.1", "grid.color_mlp.2"]
    );
    assert_eq!(arrays[1].shape, vec![64, 10]);
    assert_eq!(arrays[5].shape, vec![3, 64]);
    let mut changed = arrays.clone();
    changed.iter_mut().for_each(|a| a.data.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32 * 1e-3));
    field.import(&gpu, &changed).unwrap();
    assert_eq!(field.export(&gpu).unwrap(), changed);
    // Padding stays zero in the GPU layout.
    let mlp = field.mlp.read(&gpu).unwrap();
    let lay = field.layout().clone();
    assert!((0..lay.width).all(|j| mlp[lay.w1 + j * lay.in_pad + 10] == 0.0));
    assert!(mlp[lay.c3 + 3 * lay.width..].iter().all(|&v| v == 0.0));
    // Errors: a missing array, a wrong length.
    assert!(matches!(field.import(&gpu, &changed[1..]), Err(FieldError::Import(_))));
    let mut short = changed.clone();
    short[2].data.pop();
    assert!(matches!(field.import(&gpu, &short), Err(FieldError::Import(_))));
    // Parameter groups for the optimizer.
    let groups = field.params();
    assert_eq!(groups.len(), 2);
    assert_eq!((groups[0].name, groups[0].params.len(), groups[0].eps), (TABLE_NAME, lay.table_entries * 2, Some(1e-15)));
    assert!(groups[0].skip_zero_grad && !groups[1].skip_zero_grad);
    assert_eq!((groups[1].name, groups[1].params.len()), (MLP_NAME, lay.mlp_len));
    assert!(groups.iter().all(|g| g.grads.len() == g.params.len()));
    assert_eq!(field.n_params(), lay.table_entries * 2 + lay.mlp_len);
    let as_dyn: &dyn Field = &field;
    assert_eq!((as_dyn.kind(), as_dyn.encoding_levels()), ("grid", 5));
    assert!(GridField::new(&gpu, &cfg, [Vec3::ONE, Vec3::ZERO]).is_err());
}

// ---------------------------------------------------------------- throughput

/// Forward / backward samples per second at the default configuration (2^16
/// samples). Run with `cargo test -p edgenerf-engine --release field_grid_throughput -- --ignored --nocapture`.
#[test]
#[ignore]
fn field_grid_throughput() {
    let gpu = test_gpu(false);
    let mut field = GridField::new(&gpu, &GridConfig::default(), AABB).unwrap();
    measure_throughput(&gpu, &mut field, AABB, 1 << 16);
}

/// The same at the field of `tools/configs/sparse-small.toml` and `demo.toml` (8 levels,
/// 2^16 entries, finest resolution 256, width 32). Run with
/// `cargo test -p edgenerf-engine --release field_grid_throughput_small -- --ignored --nocapture`.
#[test]
#[ignore]
fn field_grid_throughput_small() {
    let gpu = test_gpu(false);
    let cfg = GridConfig {
        n_levels: 8,
        log2_hashmap_size: 16,
        finest_resolution: 256.0,
        hidden_width: 32,
        ..GridConfig::default()
    };
    let mut field = GridField::new(&gpu, &cfg, AABB).unwrap();
    measure_throughput(&gpu, &mut field, AABB, 1 << 16);
}

/// Every generated kernel variant the presets use (the `[field]` table of each
/// `tools/configs/*.toml`, and the default config) validates with naga on both
/// float-atomic paths and stays within the portability rules of `gpu::kernel`.
#[test]
fn generated_kernels_of_every_preset_validate() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/configs");
    let mut configs = vec![("default".to_string(), GridConfig::default())];
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let value: toml::Value = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
            let field = value.get("field").cloned().unwrap_or(toml::Value::Table(Default::default()));
            let cfg: GridConfig = field.try_into().unwrap_or_else(|e| panic!("{}: [field]: {e}", path.display()));
            configs.push((path.display().to_string(), cfg));
        }
    }
    assert!(configs.len() >= 5, "the presets were not found in {}", dir.display());
    let kernels = [
        (&DENSITY, codegen::GridKernel::Density),
        (&SAMPLE_DENSITY, codegen::GridKernel::SampleDensity),
        (&FORWARD, codegen::GridKernel::Forward),
        (&BACKWARD, codegen::GridKernel::Backward),
        (&FORWARD_KEEP, codegen::GridKernel::ForwardKeep),
        (&BACKWARD, codegen::GridKernel::BackwardKept),
    ];
    let mut problems = Vec::new();
    for (name, cfg) in &configs {
        let layout = GridLayout::new(cfg).unwrap();
        for (spec, which) in kernels {
            for p in crate::gpu::kernel::tests::portability_problems(spec.file, &codegen::source(&layout, which)) {
                problems.push(format!("{name}: {p}"));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n\n"));
}
