//! Tests of the MLP field on the GPU in use (lavapipe on CI): the tiled matrix kernels
//! against a CPU product, the whole forward pass against the `f64` reference, the
//! analytic normals against central differences of the density, and the backward pass
//! (with and without the second-order normal path) against central differences of
//! the reference loss over every parameter. Tiny networks keep each test at seconds.

#![allow(clippy::needless_range_loop)]

use glam::Vec3;

use super::gemm::{self, Dense, View};
use super::reference::MlpModel;
use super::*;
use crate::field::test_support::*;
use crate::gpu::{Gpu, test_gpu};
use crate::layout::{FieldOutputs, GpuSample, SampleBatch};

const AABB: [Vec3; 2] = [Vec3::new(-1.0, -0.5, -2.0), Vec3::new(1.5, 1.0, 0.5)];
const FOOTPRINT: Footprint = Footprint { radius0: 0.02, radius1: 0.2, point_var: 0.004 };

/// 3 layers of 16 with the skip at layer 2, colour 8, 3 position bands, 2 direction
/// bands, chunks of 64 samples.
fn tiny(encoding: PositionEncoding) -> MlpConfig {
    MlpConfig {
        depth: 3,
        width: 16,
        skip_layer: Some(2),
        color_width: 8,
        encoding,
        pos_min_deg: 0,
        pos_max_deg: 3,
        dir_max_deg: 2,
        chunk: 64,
        seed: 3,
        ..MlpConfig::default()
    }
}

/// Weights 1.5x Glorot and biases uniform in [-0.3, 0.3], so every ReLU and the
/// sigmoid/softplus heads see both regimes.
fn randomize(gpu: &Gpu, field: &mut MlpField, seed: u64) {
    let mut r = rng(seed);
    let mut arrays = field.export(gpu).unwrap();
    for a in &mut arrays {
        let bound = if a.shape.len() == 2 { (6.0 / (a.shape[0] + a.shape[1]) as f64).sqrt() * 1.5 } else { 0.3 };
        a.data.iter_mut().for_each(|v| *v = r.uniform(bound) as f32);
    }
    field.import(gpu, &arrays).unwrap();
}

struct Setup {
    gpu: Gpu,
    field: MlpField,
    batch: SampleBatch,
    samples: Vec<GpuSample>,
}

fn setup(cfg: &MlpConfig, n: usize, capacity: u32, seed: u64) -> Setup {
    let gpu = test_gpu(false);
    let mut field = MlpField::new(&gpu, cfg, AABB, FOOTPRINT).unwrap();
    randomize(&gpu, &mut field, seed);
    let mut samples = random_samples(AABB, n, seed + 1);
    // Varied frustums: t in [0.5, 3], dt in [0.005, 0.2].
    let mut r = rng(seed + 2);
    for s in &mut samples {
        s.t = 0.5 + 2.5 * unit(&mut r) as f32;
        s.dt = 0.005 + 0.195 * unit(&mut r) as f32;
    }
    let batch = SampleBatch::new(&gpu, 1, capacity).unwrap();
    batch.samples.write(&gpu, &samples);
    batch.count.write(&gpu, &[n as u32, n as u32]);
    Setup { gpu, field, batch, samples }
}

fn trace(m: &MlpModel, s: &GpuSample) -> reference::Trace {
    m.forward(s.pos.map(f64::from), s.dir.map(f64::from), s.t as f64, s.dt as f64)
}

fn loss(w: &LossWeights, m: &MlpModel, samples: &[GpuSample], normals: bool) -> f64 {
    samples
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let t = trace(m, s);
            w.weighted(i, t.sigma, t.rgb, if normals { t.normal } else { [0.0; 3] })
        })
        .sum()
}

// ---------------------------------------------------------------- matrix kernels

#[test]
fn field_mlp_gemm_kernels_match_cpu_products() {
    // Sizes that cross tile edges in every dimension; 4 streams.
    let gpu = test_gpu(false);
    let k = gemm::Kernels::new(&gpu).unwrap();
    let (rows, n_in, n_out, streams) = (4 * 37u32, 70u32, 67u32, 4u32);
    let layer = Dense { w_off: 5, n_in, n_out };
    let mut r = rng(1);
    let mut rand = |n: usize| (0..n).map(|_| r.uniform(1.0) as f32).collect::<Vec<f32>>();
    let params_h = rand(5 + layer.len());
    let x_h = rand(3 + (rows * (n_in + 2)) as usize);
    let gy_h = rand((rows * n_out) as usize);
    let params = GpuBuffer::from_slice(&gpu, "p", &params_h).unwrap();
    let x = GpuBuffer::from_slice(&gpu, "x", &x_h).unwrap();
    let gy = GpuBuffer::from_slice(&gpu, "gy", &gy_h).unwrap();
    let y = GpuBuffer::<f32>::zeros(&gpu, "y", (rows * n_out) as usize).unwrap();
    let gx = GpuBuffer::from_slice(&gpu, "gx", &vec![0.5f32; (rows * n_in) as usize]).unwrap();
    let partial = GpuBuffer::<f32>::zeros(&gpu, "partial", gemm::partial_len(layer, rows)).unwrap();
    let grads = GpuBuffer::from_slice(&gpu, "grads", &vec![0.25f32; params_h.len()]).unwrap();
    let xv = View::new(&x, 3, n_in + 2);
    let mut enc = gpu.encoder();
    gemm::linear_forward(&mut enc, &k, &params, layer, xv, View::new(&y, 0, n_out), rows, streams, true);
    gemm::linear_grad_input(&mut enc, &k, &params, layer, n_in, View::new(&gy, 0, n_out), View::new(&gx, 0, n_in), rows, Some((xv, streams)), true);
    gemm::linear_weight_grad(&mut enc, &k, layer, View::new(&gy, 0, n_out), xv, rows, streams, &partial, &grads);
    enc.submit();
    let (ni, no) = (n_in as usize, n_out as usize);
    let xa = |r: usize, i: usize| x_h[3 + r * (ni + 2) + i] as f64;
    let w = |o: usize, i: usize| params_h[5 + o * ni + i] as f64;
    let b = |o: usize| params_h[5 + no * ni + o] as f64;
    // forward: bias on primal rows, ReLU masked by the primal row.
    let mut want_y = vec![0.0; rows as usize * no];
    for r in 0..rows as usize {
        let p = r - r % 4;
        for o in 0..no {
            let z = |r: usize| (0..ni).map(|i| xa(r, i) * w(o, i)).sum::<f64>() + if r % 4 == 0 { b(o) } else { 0.0 };
            want_y[r * no + o] = if z(p) > 0.0 { z(r) } else { 0.0 };
        }
    }
    assert_close("forward", &to_f64(&y.read(&gpu).unwrap()), &want_y, 1e-5, 1e-5);
    // grad_input: accumulated onto 0.5, masked by x of the primal row.
    let mut want_gx = vec![0.0; rows as usize * ni];
    for r in 0..rows as usize {
        for i in 0..ni {
            let v = (0..no).map(|o| gy_h[r * no + o] as f64 * w(o, i)).sum::<f64>();
            want_gx[r * ni + i] = 0.5 + if xa(r - r % 4, i) > 0.0 { v } else { 0.0 };
        }
    }
    assert_close("grad_input", &to_f64(&gx.read(&gpu).unwrap()), &want_gx, 1e-5, 1e-5);
    // weight_grad: added onto 0.25; bias over primal rows; the 5 leading floats untouched.
    let mut want_g = vec![0.25; params_h.len()];
    for o in 0..no {
        for i in 0..ni {
            want_g[5 + o * ni + i] += (0..rows as usize).map(|r| gy_h[r * no + o] as f64 * xa(r, i)).sum::<f64>();
        }
        want_g[5 + no * ni + o] += (0..rows as usize).step_by(4).map(|r| gy_h[r * no + o] as f64).sum::<f64>();
    }
    assert_close("weight_grad", &to_f64(&grads.read(&gpu).unwrap()), &want_g, 1e-5, 1e-5);
}

// ---------------------------------------------------------------- layout, init, io

#[test]
fn field_mlp_layout_init_and_export_import() {
    let cfg = MlpConfig::default();
    let l = MlpLayout::new(&cfg).unwrap();
    // mip-NeRF: IPE 0..16 (96), skip at 4 (256 + 96), colour 128 over [256, 27].
    assert_eq!((l.pos_dim, l.dir_dim), (96, 27));
    assert_eq!(l.trunk.iter().map(|d| d.n_in).collect::<Vec<_>>(), [96, 256, 256, 256, 352, 256, 256, 256]);
    assert_eq!((l.color.n_in, l.color.n_out, l.rgb.n_in), (283, 128, 128));
    assert_eq!(l.len, l.layers().iter().map(|(_, d)| d.len()).sum::<usize>());
    assert!(MlpConfig { skip_layer: Some(0), ..cfg.clone() }.validate().is_err());
    assert!(MlpConfig { chunk: 100, ..cfg.clone() }.validate().is_err());

    let gpu = test_gpu(false);
    let cfg = tiny(PositionEncoding::Integrated);
    let mut f = MlpField::new(&gpu, &cfg, AABB, FOOTPRINT).unwrap();
    let a = f.export(&gpu).unwrap();
    let again = MlpField::new(&gpu, &cfg, AABB, FOOTPRINT).unwrap().export(&gpu).unwrap();
    assert_eq!(a, again, "deterministic initialisation");
    for arr in &a {
        if arr.name.ends_with(".bias") {
            assert!(arr.data.iter().all(|&v| v == 0.0), "{}: zero biases", arr.name);
        } else {
            let bound = (6.0 / (arr.shape[0] + arr.shape[1]) as f32).sqrt();
            assert!(arr.data.iter().all(|v| v.abs() <= bound) && arr.data.iter().any(|&v| v != 0.0), "{}", arr.name);
        }
    }
    randomize(&gpu, &mut f, 9);
    let b = f.export(&gpu).unwrap();
    let mut g = MlpField::new(&gpu, &cfg, AABB, FOOTPRINT).unwrap();
    g.import(&gpu, &b).unwrap();
    assert_eq!(g.export(&gpu).unwrap(), b);
    assert!(g.import(&gpu, &b[1..]).is_err(), "a missing array is an error");
    let mut short = b.clone();
    short[0].data.pop();
    assert!(g.import(&gpu, &short).is_err(), "a wrong length is an error");
    assert_eq!(f.params().len(), 1);
    assert_eq!(f.n_params(), f.layout().len);
}

// ---------------------------------------------------------------- forward

fn forward_matches_reference(encoding: PositionEncoding) {
    // 150 samples: 3 chunks of 64, the last one partial.
    let (n, cap) = (150, 160);
    let mut s = setup(&tiny(encoding), n, cap, 11);
    let m = s.field.reference(&s.gpu).unwrap();
    let out = FieldOutputs::new(&s.gpu, cap).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let (d, rgb, nrm) = out.read(&s.gpu).unwrap();
    let mut gpu_v = Vec::new();
    let mut cpu_v = Vec::new();
    for (i, smp) in s.samples.iter().enumerate() {
        let t = trace(&m, smp);
        gpu_v.extend([d[i] as f64, rgb[i][0] as f64, rgb[i][1] as f64, rgb[i][2] as f64]);
        cpu_v.extend([t.sigma, t.rgb[0], t.rgb[1], t.rgb[2]]);
        assert_close(&format!("normal[{i}]"), &to_f64(&nrm[i][..3]), &t.normal, 1e-4, 1e-4);
    }
    assert_close("sigma and rgb", &gpu_v, &cpu_v, 1e-5, 1e-4);
    assert!(d[n..].iter().all(|&v| v == 0.0), "samples past count untouched");
    // Without normals: the same density and colour, normals untouched.
    let out2 = FieldOutputs::new(&s.gpu, cap).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out2, false).unwrap();
    assert_eq!(out2.read(&s.gpu).unwrap().0, d);
    assert!(out2.normal.read(&s.gpu).unwrap().iter().all(|v| *v == [0.0; 4]));
}

#[test]
fn field_mlp_forward_matches_reference_ipe() {
    forward_matches_reference(PositionEncoding::Integrated);
}

#[test]
fn field_mlp_forward_matches_reference_plain_pe() {
    forward_matches_reference(PositionEncoding::Plain);
}

#[test]
fn field_mlp_normals_match_finite_differences_of_density() {
    let s = setup(&tiny(PositionEncoding::Integrated), 40, 64, 21);
    let m = s.field.reference(&s.gpu).unwrap();
    for smp in &s.samples {
        let pos = smp.pos.map(f64::from);
        let var = m.frustum_var(smp.t as f64, smp.dt as f64, smp.dir.map(f64::from));
        let (_, grad, _) = m.density_with_var(pos, var);
        let mut p = pos;
        let fd: Vec<f64> = (0..3).map(|d| central_diff(&mut p, d, 1e-6, |q| m.density_with_var([q[0], q[1], q[2]], var).0)).collect();
        assert_close("grad_x sigma", &grad, &fd, 1e-6, 1e-5);
        let len = grad.iter().map(|v| v * v).sum::<f64>().sqrt();
        let t = trace(&m, smp);
        assert_close("normal", &t.normal, &grad.map(|v| -v / len), 1e-12, 1e-9);
    }
}

#[test]
fn field_mlp_density_queries_match_reference() {
    let s = setup(&tiny(PositionEncoding::Integrated), 100, 128, 31);
    let m = s.field.reference(&s.gpu).unwrap();
    let want: Vec<f64> = s.samples.iter().map(|p| m.density_at(p.pos.map(f64::from))).collect();
    assert_close("density queries", &to_f64(&query_densities(&s.gpu, &s.field, &s.samples)), &want, 1e-5, 1e-4);
}

#[test]
fn field_mlp_band_annealing_masks_high_frequencies() {
    let mut s = setup(&tiny(PositionEncoding::Plain), 50, 64, 51);
    assert_eq!(s.field.encoding_levels(), 3);
    let all = s.field.reference(&s.gpu).unwrap();
    s.field.set_active_levels(1);
    let m = s.field.reference(&s.gpu).unwrap();
    assert_eq!(m.active_bands, 1);
    let (e, _) = m.encode([0.3, -0.2, 0.1], [0.0; 3]);
    assert!(e[3 + 3..3 + 9].iter().all(|&v| v == 0.0) && e[3 + 9 + 3..].iter().all(|&v| v == 0.0));
    let out = FieldOutputs::new(&s.gpu, 64).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, true).unwrap();
    let d = out.read(&s.gpu).unwrap().0;
    let want: Vec<f64> = s.samples.iter().map(|p| trace(&m, p).sigma).collect();
    let unmasked: Vec<f64> = s.samples.iter().map(|p| trace(&all, p).sigma).collect();
    assert_close("annealed density", &to_f64(&d[..50]), &want, 1e-5, 1e-4);
    assert!(want.iter().zip(&unmasked).any(|(a, b)| (a - b).abs() > 1e-3), "masking changes the field");
}

// ---------------------------------------------------------------- backward

/// GPU gradients of `L = sum a sigma + <b, rgb> (+ <c, n>)` against central differences
/// of the reference loss over every parameter.
fn gradients_match_finite_differences(encoding: PositionEncoding, normals: bool) {
    let (n, cap) = (90, 96); // 2 chunks
    let mut s = setup(&tiny(encoding), n, cap, 61);
    let m = s.field.reference(&s.gpu).unwrap();
    let w = LossWeights::random(n, 62, 1.0, 1.0, 1.0);
    let g_out = w.upload(&s.gpu, cap);
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &g_out, None, normals).unwrap();
    let gpu = to_f64(&s.field.grads.read(&s.gpu).unwrap());
    let mut params = m.params.clone();
    let fd: Vec<f64> = (0..params.len())
        .map(|i| central_diff(&mut params, i, 1e-6, |p| loss(&w, &MlpModel { params: p.to_vec(), ..m.clone() }, &s.samples, normals)))
        .collect();
    assert_close(&format!("{encoding:?} gradients (normals {normals})"), &gpu, &fd, 2e-4, 2e-3);
    if normals {
        // The second-order path matters: the first-order gradients differ.
        s.field.zero_grads(&s.gpu);
        s.field.backward(&s.gpu, &s.batch, &g_out, None, false).unwrap();
        let first = to_f64(&s.field.grads.read(&s.gpu).unwrap());
        let diff = first.iter().zip(&gpu).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(diff > 1e-3 * gpu.iter().fold(0.0f64, |a, v| a.max(v.abs())), "normal path has no effect");
    }
    // After a forward pass on the same batch the backward reuses its last chunk: same result.
    let out = FieldOutputs::new(&s.gpu, cap).unwrap();
    s.field.forward(&s.gpu, &s.batch, &out, normals).unwrap();
    s.field.zero_grads(&s.gpu);
    s.field.backward(&s.gpu, &s.batch, &g_out, None, normals).unwrap();
    assert_close("backward after forward", &to_f64(&s.field.grads.read(&s.gpu).unwrap()), &gpu, 1e-6, 1e-5);
}

#[test]
fn field_mlp_gradients_with_normals_match_finite_differences_ipe() {
    gradients_match_finite_differences(PositionEncoding::Integrated, true);
}

#[test]
fn field_mlp_gradients_with_normals_match_finite_differences_plain_pe() {
    gradients_match_finite_differences(PositionEncoding::Plain, true);
}

#[test]
fn field_mlp_first_order_gradients_match_finite_differences() {
    gradients_match_finite_differences(PositionEncoding::Integrated, false);
}

/// Throughput of the small and the full-size (mip-NeRF) network; run with
/// `cargo test --release -p edgenerf-engine --lib field_mlp_throughput -- --ignored --nocapture`.
#[test]
#[ignore]
fn field_mlp_throughput() {
    let gpu = test_gpu(false);
    let n = std::env::var("EDGENERF_THROUGHPUT_SAMPLES").ok().and_then(|v| v.parse().ok()).unwrap_or(1 << 14);
    // EDGENERF_THROUGHPUT_SMALL_ONLY=1: skip the full-size network.
    let full = std::env::var_os("EDGENERF_THROUGHPUT_SMALL_ONLY").is_none();
    for cfg in [MlpConfig::small()].into_iter().chain(full.then(MlpConfig::default)) {
        let mut field = MlpField::new(&gpu, &cfg, AABB, FOOTPRINT).unwrap();
        eprintln!("mlp {} x {} (skip {:?}, colour {})", cfg.depth, cfg.width, cfg.skip_layer, cfg.color_width);
        measure_throughput(&gpu, &mut field, AABB, n);
    }
}
