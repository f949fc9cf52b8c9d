//! GPU tests of the render room against its CPU reference (`reference.rs`).
//!
//! Tolerances, stated once:
//! * forward: `|gpu - ref| <= 3e-5 * m` per component, `m` the sum of the absolute
//!   values of the terms summed into it (`sum_i w_i |x_i|`, plus `(1 - opacity) |bg|`
//!   for colour), floored at 1e-12 (so empty and fully transparent rays must be exact);
//!   per-sample weights `|gpu - ref| <= 3e-5 * max(w_ref, 1e-7)`.
//! * backward vs central differences of the `f64` reference (`h = 1e-6 max(1, |x|)`,
//!   accurate to ~1e-10): `dL/dc`, `dL/dn`: `<= 1e-5 |fd| + 1e-7`; `dL/dsigma`:
//!   `<= 1e-4 |fd| + 2e-6 dt S`, where `S = sum_j w_j |u_j| + |total|` bounds the
//!   cancellation in the suffix sum `total - prefix` (float precision of the ray's terms).
//! * Rays whose `K` differs between GPU (`f32`) and reference (`f64`) are allowed only when
//!   a transmittance at the cut lies within 1e-4 relative of the threshold.

#![allow(clippy::needless_range_loop)] // component loops over several arrays read best indexed

use super::reference::{self, RefRay, RefSample};
use super::*;
use crate::gpu::test_gpu;
use crate::rng::SplitMix64;
use crate::layout::{GpuSample, SampleRange};

/// A batch on the host, in the kernels' layout.
#[derive(Clone)]
struct HostBatch {
    ranges: Vec<SampleRange>,
    samples: Vec<GpuSample>,
    density: Vec<f32>,
    rgb: Vec<[f32; 4]>,
    normal: Vec<[f32; 4]>,
}

impl HostBatch {
    fn n_rays(&self) -> u32 {
        self.ranges.len() as u32
    }
    fn capacity(&self) -> u32 {
        self.density.len() as u32
    }
    fn ray(&self, r: usize) -> Vec<RefSample> {
        reference::gather(self.ranges[r], &self.samples, &self.density, &self.rgb, &self.normal)
    }
    /// Samples that belong to no range.
    fn in_range(&self) -> Vec<bool> {
        let mut v = vec![false; self.density.len()];
        for r in &self.ranges {
            for s in r.start..r.start + r.count {
                v[s as usize] = true;
            }
        }
        v
    }
}

/// Random rays: ~15% empty, up to `max_count` samples, random gaps between ranges
/// (filled with garbage the kernels must not touch), densities from transparent to
/// opaque, normals unit or zero, `w` components garbage.
fn random_batch(rng: &mut SplitMix64, n_rays: u32, max_count: u32) -> HostBatch {
    let mut b = HostBatch { ranges: vec![], samples: vec![], density: vec![], rgb: vec![], normal: vec![] };
    let garbage = |b: &mut HostBatch| {
        b.samples.push(GpuSample { pos: [9.0; 3], t: -7.0, dir: [9.0; 3], dt: 5.0 });
        b.density.push(1e3);
        b.rgb.push([5.0; 4]);
        b.normal.push([5.0; 4]);
    };
    for _ in 0..n_rays {
        for _ in 0..rng.below(3) {
            garbage(&mut b);
        }
        let count = if rng.unit_f32() < 0.15 { 0 } else { 1 + rng.below(max_count as u64) as u32 };
        b.ranges.push(SampleRange { start: b.density.len() as u32, count });
        // Per-ray density scale: some rays stay transparent, some terminate early.
        let scale = [0.3f32, 3.0, 30.0][rng.below(3) as usize];
        let mut t = rng.range_f32(0.1, 2.0);
        // From a generator of its own, so the rest of the batch is what it was before
        // rays had directions.
        let dir = {
            let mut d = SplitMix64::mixed(b.ranges.len() as u64);
            let v = [d.range_f32(-1.0, 1.0), d.range_f32(-1.0, 1.0), d.range_f32(0.2, 1.0)];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / l)
        };
        for _ in 0..count {
            let dt = rng.range_f32(0.002, 0.08);
            t += dt * 0.5;
            b.samples.push(GpuSample { pos: [rng.unit_f32(); 3], t, dir, dt });
            t += dt * 0.5 + if rng.unit_f32() < 0.3 { rng.range_f32(0.0, 0.1) } else { 0.0 };
            let u = rng.unit_f32();
            let sigma = if u < 0.25 { 0.0 } else if u < 0.9 { scale * rng.range_f32(0.0, 1.0) } else { scale * rng.range_f32(5.0, 50.0) };
            b.density.push(sigma);
            b.rgb.push([rng.unit_f32(), rng.unit_f32(), rng.unit_f32(), 7.0]);
            let n = if rng.unit_f32() < 0.1 {
                [0.0; 3]
            } else {
                let v = [rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0)];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
                v.map(|x| x / l)
            };
            b.normal.push([n[0], n[1], n[2], -3.0]);
        }
    }
    garbage(&mut b);
    b
}

struct Uploaded {
    batch: SampleBatch,
    field: FieldOutputs,
}

fn upload(gpu: &Gpu, h: &HostBatch) -> Uploaded {
    let batch = SampleBatch {
        ranges: GpuBuffer::from_slice(gpu, "ranges", &h.ranges).unwrap(),
        samples: GpuBuffer::from_slice(gpu, "samples", &h.samples).unwrap(),
        count: GpuBuffer::from_slice(gpu, "count", &[h.capacity(), h.capacity()]).unwrap(),
        n_rays: h.n_rays(),
        capacity: h.capacity(),
    };
    let field = FieldOutputs::new(gpu, h.density.len() as u32).unwrap();
    field.write(gpu, &h.density, &h.rgb, &h.normal);
    Uploaded { batch, field }
}

struct Forward {
    out: RenderOutputs,
    rays: Vec<RayOutput>,
    aux: Vec<RayAux>,
    weights: Vec<f32>,
}

fn run_forward(gpu: &Gpu, renderer: &Renderer, up: &Uploaded, seed: u32) -> Forward {
    run_forward_with_free_ends(gpu, renderer, up, seed, &[])
}

/// The forward with the stereo free-space prior's ends of the first `free_end.len()`
/// rays written into aux first (as the trainer does).
fn run_forward_with_free_ends(gpu: &Gpu, renderer: &Renderer, up: &Uploaded, seed: u32, free_end: &[f32]) -> Forward {
    let out = RenderOutputs::new(gpu, up.batch.n_rays, Some(up.batch.capacity)).unwrap();
    if !free_end.is_empty() {
        let mut rows = vec![RayAux::default(); up.batch.n_rays as usize];
        for (row, &end) in rows.iter_mut().zip(free_end) {
            row.free_end = end;
        }
        out.aux.write(gpu, &rows);
    }
    // Sentinels: samples outside every range must keep them.
    out.weights.as_ref().unwrap().write(gpu, &vec![-1.0; up.batch.capacity as usize]);
    let mut enc = gpu.encoder();
    renderer.forward(&mut enc, &up.batch, &up.field, &out, seed).unwrap();
    enc.submit();
    let rays = out.rays.read(gpu).unwrap();
    let aux = out.aux.read(gpu).unwrap();
    let weights = out.weights.as_ref().unwrap().read(gpu).unwrap();
    Forward { out, rays, aux, weights }
}

struct Grads {
    density: Vec<f32>,
    rgb: Vec<[f32; 4]>,
    normal: Vec<[f32; 4]>,
}

fn run_backward(
    gpu: &Gpu,
    renderer: &Renderer,
    up: &Uploaded,
    fwd: &Forward,
    d_rays: &[RayOutput],
    init: &Grads,
    accumulate: bool,
) -> Grads {
    let grads = FieldOutputs::new(gpu, init.density.len() as u32).unwrap();
    grads.write(gpu, &init.density, &init.rgb, &init.normal);
    let d = GpuBuffer::from_slice(gpu, "d rays", d_rays).unwrap();
    let mut enc = gpu.encoder();
    renderer.backward(&mut enc, &up.batch, &up.field, &fwd.out, &d, &grads, accumulate).unwrap();
    enc.submit();
    let (density, rgb, normal) = grads.read(gpu).unwrap();
    Grads { density, rgb, normal }
}

fn sentinel_grads(n: usize) -> Grads {
    // rgb has no w of its own: FieldGrads packs d sigma there.
    Grads { density: vec![123.0; n], rgb: vec![[123.0, 123.0, 123.0, 0.0]; n], normal: vec![[123.0; 4]; n] }
}

fn backgrounds(cfg: &RenderConfig, seed: u32, n: u32) -> Vec<[f32; 3]> {
    (0..n).map(|r| background_of(&cfg.background, seed, r).expect("a background of the launch")).collect()
}

fn reference_of(h: &HostBatch, cfg: &RenderConfig, seed: u32) -> Vec<RefRay> {
    let bgs = backgrounds(cfg, seed, h.n_rays());
    reference::forward_batch(&h.ranges, &h.samples, &h.density, &h.rgb, &h.normal, &bgs, cfg.transmittance_threshold)
}

/// Whether a `K` mismatch between GPU and reference is explained by the transmittance
/// at the cut, `T_min(K_gpu, K_ref)` (compared with the threshold by one side and not the
/// other), lying within 1e-4 relative of the threshold.
fn near_threshold(r: &RefRay, threshold: f32, k_gpu: usize) -> bool {
    let t = r.transmittance[r.n_contrib.min(k_gpu)];
    threshold > 0.0 && (t / threshold as f64 - 1.0).abs() < 1e-4
}

/// Relative tolerance of the GPU forward against the f64 reference. Vulkan lets `exp`
/// be off by 3 + 2|x| ULP, and the transmittance multiplies one per sample: lavapipe's
/// worst is 7.8e-6, NVIDIA's (H200, driver 580) 1.34e-5 on one ray's colour.
const GPU_REL_TOL: f64 = 3e-5;

/// Compares GPU forward outputs with the reference; returns the rays checked.
fn check_forward(h: &HostBatch, cfg: &RenderConfig, seed: u32, fwd: &Forward) -> usize {
    let refs = reference_of(h, cfg, seed);
    let bgs = backgrounds(cfg, seed, h.n_rays());
    let in_range = h.in_range();
    let mut checked = 0;
    let mut skipped = 0;
    let mut worst = 0.0f64;
    for (r, want) in refs.iter().enumerate() {
        let got = &fwd.rays[r];
        let aux = &fwd.aux[r];
        assert_eq!(aux.background, bgs[r], "ray {r}: background");
        if aux.n_contrib as usize != want.n_contrib {
            assert!(
                near_threshold(want, cfg.transmittance_threshold, aux.n_contrib as usize),
                "ray {r}: GPU stopped after {} samples, reference after {} (T = {:?})",
                aux.n_contrib,
                want.n_contrib,
                want.transmittance
            );
            skipped += 1;
            continue;
        }
        let ray = h.ray(r);
        let mag = |f: &dyn Fn(&RefSample) -> f64| -> f64 {
            ray.iter().zip(&want.weights).map(|(s, w)| w * f(s).abs()).sum::<f64>()
        };
        let mut check = |what: &str, got: f32, want: f64, m: f64| {
            let err = (got as f64 - want).abs();
            let tol = GPU_REL_TOL * m.max(1e-12);
            worst = worst.max(err / m.max(1e-12));
            assert!(err <= tol, "ray {r} {what}: gpu {got} ref {want} (err {err:e}, tol {tol:e})");
        };
        for k in 0..3 {
            let m_rgb = mag(&|s| s.rgb[k]) + (1.0 - want.opacity).abs() * bgs[r][k].abs() as f64;
            check("rgb", got.rgb[k], want.rgb[k], m_rgb);
            check("normal", got.normal[k], want.normal[k], mag(&|s| s.normal[k]));
        }
        check("opacity", got.opacity, want.opacity, want.opacity);
        check("depth", got.depth, want.depth, mag(&|s| s.t));
        let start = h.ranges[r].start as usize;
        for (i, &w) in want.weights.iter().enumerate() {
            let g = fwd.weights[start + i] as f64;
            assert!((g - w).abs() <= GPU_REL_TOL * w.max(1e-7), "ray {r} sample {i}: weight gpu {g} ref {w}");
            if i >= want.n_contrib {
                assert_eq!(g, 0.0, "ray {r} sample {i}: weight past termination");
            }
        }
        checked += 1;
    }
    for (s, inside) in in_range.iter().enumerate() {
        if !inside {
            assert_eq!(fwd.weights[s], -1.0, "sample {s} outside every range was written");
        }
    }
    assert!(skipped * 100 <= refs.len(), "{skipped} of {} rays disagree on termination", refs.len());
    eprintln!("forward: {checked} rays checked, {skipped} at the threshold skipped, worst relative error {worst:e}");
    checked
}

#[test]
fn forward_matches_reference_for_every_background() {
    let gpu = test_gpu(false);
    let mut rng = SplitMix64::new(1);
    let h = random_batch(&mut rng, 2000, 64);
    let up = upload(&gpu, &h);
    let configs = [
        RenderConfig::default(),
        RenderConfig { background: Background::Color { rgb: [0.25, 1.0, 0.5] }, transmittance_threshold: 1e-4, ..Default::default() },
        RenderConfig { background: Background::Random, transmittance_threshold: 1e-4, ..Default::default() },
        RenderConfig { background: Background::Color { rgb: [1.0; 3] }, transmittance_threshold: 0.0, ..Default::default() },
        RenderConfig { background: Background::Black, transmittance_threshold: 1e-2, ..Default::default() },
    ];
    for cfg in configs {
        let renderer = Renderer::new(&gpu, cfg).unwrap();
        let t0 = std::time::Instant::now();
        let fwd = run_forward(&gpu, &renderer, &up, 77);
        eprintln!("{cfg:?}: forward of {} rays, {} samples in {:?}", h.n_rays(), h.capacity(), t0.elapsed());
        let checked = check_forward(&h, &cfg, 77, &fwd);
        assert!(checked > 1900);
        // Early termination must actually happen in this data set (threshold > 0).
        let refs = reference_of(&h, &cfg, 77);
        let cut = refs.iter().zip(&h.ranges).filter(|(r, range)| r.n_contrib < range.count as usize).count();
        if cfg.transmittance_threshold > 0.0 {
            assert!(cut > 100, "only {cut} rays terminate early");
        } else {
            assert_eq!(cut, 0);
        }
    }
}

#[test]
fn learned_background_is_read_per_ray_from_aux() {
    // Background::Learned composites the colour the caller wrote into each ray's aux,
    // and keeps it there: the backward reads a ray's background from aux whatever the
    // mode, so the finite-difference tests of the colour backgrounds cover its
    // gradients once the forward matches the reference and aux holds the caller's colour.
    let gpu = test_gpu(false);
    let mut rng = SplitMix64::new(21);
    let h = random_batch(&mut rng, 300, 32);
    let up = upload(&gpu, &h);
    let bgs: Vec<[f32; 3]> = (0..h.n_rays()).map(|_| [rng.range_f32(0.0, 1.0), rng.range_f32(0.0, 1.0), rng.range_f32(0.0, 1.0)]).collect();
    let cfg = RenderConfig { background: Background::Learned, ..Default::default() };
    let renderer = Renderer::new(&gpu, cfg).unwrap();
    let out = RenderOutputs::new(&gpu, up.batch.n_rays, Some(up.batch.capacity)).unwrap();
    out.aux.write(&gpu, &bgs.iter().map(|&background| RayAux { background, ..Default::default() }).collect::<Vec<_>>());
    let mut enc = gpu.encoder();
    renderer.forward(&mut enc, &up.batch, &up.field, &out, 3).unwrap();
    enc.submit();
    let (rays, aux) = (out.rays.read(&gpu).unwrap(), out.aux.read(&gpu).unwrap());
    let refs = reference::forward_batch(&h.ranges, &h.samples, &h.density, &h.rgb, &h.normal, &bgs, cfg.transmittance_threshold);
    let mut checked = 0;
    for (r, ((gpu_ray, a), reference)) in rays.iter().zip(&aux).zip(&refs).enumerate() {
        assert_eq!(a.background, bgs[r], "ray {r}: the forward keeps the caller's background");
        if a.n_contrib as usize != reference.n_contrib {
            continue;
        }
        for c in 0..3 {
            let want = reference.rgb[c];
            assert!((gpu_ray.rgb[c] as f64 - want).abs() <= 1e-5 + GPU_REL_TOL * want.abs(), "ray {r}: {} vs {want}", gpu_ray.rgb[c]);
        }
        checked += 1;
    }
    assert!(checked > 280, "{checked} rays checked");
    // Some rays show their background: the test would not notice a black one.
    assert!(refs.iter().filter(|r| r.opacity < 0.5).count() > 20);
}

#[test]
fn random_background_differs_per_seed_and_ray() {
    let gpu = test_gpu(false);
    let cfg = RenderConfig { background: Background::Random, ..Default::default() };
    let renderer = Renderer::new(&gpu, cfg).unwrap();
    let h = HostBatch {
        ranges: vec![SampleRange::default(); 4096],
        samples: vec![GpuSample::default()],
        density: vec![0.0],
        rgb: vec![[0.0; 4]],
        normal: vec![[0.0; 4]],
    };
    let up = upload(&gpu, &h);
    let a = run_forward(&gpu, &renderer, &up, 1);
    let b = run_forward(&gpu, &renderer, &up, 2);
    let mut mean = [0.0f64; 3];
    for r in 0..4096 {
        // Empty rays show exactly their background, which is the host's hash.
        assert_eq!(a.rays[r].rgb, random_background(1, r as u32));
        assert_eq!(a.aux[r].background, a.rays[r].rgb);
        assert_ne!(a.rays[r].rgb, b.rays[r].rgb);
        for k in 0..3 {
            let v = a.rays[r].rgb[k];
            assert!((0.0..1.0).contains(&v));
            mean[k] += v as f64 / 4096.0;
        }
    }
    assert_ne!(a.rays[0].rgb, a.rays[1].rgb);
    for m in mean {
        assert!((m - 0.5).abs() < 0.02, "mean background {m}");
    }
}

#[test]
fn background_shows_only_through_transparency() {
    let gpu = test_gpu(false);
    let bg = [0.25, 0.5, 1.0];
    let cfg = RenderConfig { background: Background::Color { rgb: bg }, ..Default::default() };
    let renderer = Renderer::new(&gpu, cfg).unwrap();
    let sample = |t: f32| GpuSample { pos: [0.0; 3], t, dir: [0.0, 0.0, 1.0], dt: 0.01 };
    let c = [0.1, 0.7, 0.3, 0.0];
    let n = [0.0, 0.6, 0.8, 0.0];
    // Ray 0: one opaque sample then more (alpha = 1 exactly). Ray 1: empty.
    // Ray 2: zero density everywhere. Ray 3: half transparent.
    let h = HostBatch {
        ranges: vec![
            SampleRange { start: 0, count: 3 },
            SampleRange { start: 3, count: 0 },
            SampleRange { start: 3, count: 2 },
            SampleRange { start: 5, count: 1 },
        ],
        samples: vec![sample(1.0), sample(1.1), sample(1.2), sample(2.0), sample(2.1), sample(3.0)],
        density: vec![1e30, 5.0, 5.0, 0.0, 0.0, std::f32::consts::LN_2 / 0.01],
        rgb: vec![c; 6],
        normal: vec![n; 6],
    };
    let up = upload(&gpu, &h);
    let fwd = run_forward(&gpu, &renderer, &up, 0);
    // Opaque: exactly the sample's colour, no background.
    assert_eq!(fwd.rays[0], RayOutput { rgb: [c[0], c[1], c[2]], opacity: 1.0, normal: [n[0], n[1], n[2]], depth: 1.0 });
    assert_eq!(fwd.aux[0].n_contrib, 1);
    assert_eq!(&fwd.weights[0..3], &[1.0, 0.0, 0.0]);
    // Empty and transparent rays: exactly the background, nothing else.
    for r in [1, 2] {
        assert_eq!(fwd.rays[r], RayOutput { rgb: bg, opacity: 0.0, normal: [0.0; 3], depth: 0.0 }, "ray {r}");
    }
    assert_eq!(fwd.aux[1].n_contrib, 0);
    assert_eq!(fwd.aux[2].n_contrib, 2);
    // Half transparent: an even mix.
    let half = &fwd.rays[3];
    assert!((half.opacity - 0.5).abs() < 1e-6);
    for k in 0..3 {
        assert!((half.rgb[k] - 0.5 * (c[k] + bg[k])).abs() < 1e-6);
        assert!((half.normal[k] - 0.5 * n[k]).abs() < 1e-6);
    }
    assert!((half.depth - 1.5).abs() < 1e-6);
    // Black background: the same rays composite onto zero.
    let black = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let fb = run_forward(&gpu, &black, &up, 0);
    assert_eq!(fb.rays[1].rgb, [0.0; 3]);
    assert!((fb.rays[3].rgb[1] - 0.5 * c[1]).abs() < 1e-6);
    // Renormalised normal helper.
    let u = unit_normal(half);
    assert!((u[1] - 0.6).abs() < 1e-6 && (u[2] - 0.8).abs() < 1e-6);
    assert_eq!(unit_normal(&fwd.rays[1]), [0.0; 3]);
    // Backward through the opaque and empty rays: the background gets no gradient
    // path through ray 0, and only sample 0 of ray 0 gets colour gradient.
    let g = RayOutput { rgb: [1.0, -2.0, 0.5], opacity: 0.3, normal: [0.1, 0.2, 0.3], depth: -1.0 };
    let grads = run_backward(&gpu, &renderer, &up, &fwd, &[g; 4], &sentinel_grads(6), false);
    assert_eq!(grads.rgb[0], [1.0, -2.0, 0.5, 0.0]);
    assert_eq!(grads.normal[0], [0.1, 0.2, 0.3, 0.0]);
    for s in 1..3 {
        assert_eq!((grads.density[s], grads.rgb[s], grads.normal[s]), (0.0, [0.0; 4], [0.0; 4]), "sample {s}");
    }
}

/// `dL/dx` by central differences of the `f64` reference, for one ray; the loss is
/// `<g, output> + c_d D + c_o O + c_r R + c_f F` with the priors' `(c_d, c_o,
/// occlusion_end, c_r, c_f, free_end)` (`F`: `O` over the ray's free-space range).
fn fd(ray: &[RefSample], bg: [f64; 3], th: f64, g: &RayOutput, pri: [f64; 6], i: usize, set: &dyn Fn(&mut RefSample, f64), x: f64) -> Option<f64> {
    let h = 1e-6 * x.abs().max(1.0);
    let eval = |v: f64| {
        let mut ray = ray.to_vec();
        set(&mut ray[i], v);
        let r = reference::composite(&ray, bg, th);
        let (d, o, ori) = reference::ray_priors(&ray, &r, pri[2]);
        let free = reference::ray_priors(&ray, &r, pri[5]).1;
        (r.dot(g) + pri[0] * d + pri[1] * o + pri[3] * ori + pri[4] * free, r.n_contrib)
    };
    let (lp, kp) = eval(x + h);
    let (lm, km) = eval(x - h);
    // A step across the termination threshold is a discontinuity: skip.
    (kp == km).then(|| (lp - lm) / (2.0 * h))
}

fn check_backward_fd(cfg: RenderConfig, seed: u64) {
    check_backward_fd_with(cfg, RayPriors::default(), &[], seed);
}

/// `free_end`: the stereo free-space prior's end per ray (missing: 0, no range).
fn check_backward_fd_with(cfg: RenderConfig, priors: RayPriors, free_end: &[f32], seed: u64) {
    let gpu = test_gpu(false);
    let mut rng = SplitMix64::new(seed);
    let h = random_batch(&mut rng, 300, 48);
    let up = upload(&gpu, &h);
    let mut renderer = Renderer::new(&gpu, cfg).unwrap();
    renderer.set_priors(priors);
    let c = priors.coefficients();
    let fwd = run_forward_with_free_ends(&gpu, &renderer, &up, 5, free_end);
    let d_rays: Vec<RayOutput> = (0..h.n_rays())
        .map(|_| RayOutput {
            rgb: [rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0)],
            opacity: rng.range_f32(-1.0, 1.0),
            normal: [rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0)],
            depth: rng.range_f32(-1.0, 1.0),
        })
        .collect();
    let t0 = std::time::Instant::now();
    let grads = run_backward(&gpu, &renderer, &up, &fwd, &d_rays, &sentinel_grads(h.density.len()), false);
    eprintln!("backward of {} rays, {} samples in {:?}", h.n_rays(), h.capacity(), t0.elapsed());
    let refs = reference_of(&h, &cfg, 5);
    let bgs = backgrounds(&cfg, 5, h.n_rays());
    let th = cfg.transmittance_threshold as f64;
    let (mut n_sigma, mut n_skipped, mut worst_sigma) = (0, 0, 0.0f64);
    for (r, want) in refs.iter().enumerate() {
        if fwd.aux[r].n_contrib as usize != want.n_contrib {
            n_skipped += 1;
            continue;
        }
        let ray = h.ray(r);
        let bg = bgs[r].map(|v| v as f64);
        let g = &d_rays[r];
        let end = free_end.get(r).copied().unwrap_or(0.0);
        assert_eq!(fwd.aux[r].free_end, end, "ray {r}: the forward keeps the free-space end");
        let pri = [c.distortion as f64, c.occlusion as f64, priors.occlusion_end as f64, c.orientation as f64, c.free_space as f64, end as f64];
        let gv = |a: [f32; 3]| a.map(|v| v as f64);
        let (grgb, gn) = (gv(g.rgb), gv(g.normal));
        // The scale of the suffix-sum cancellation.
        let u: Vec<f64> = ray
            .iter()
            .map(|s| {
                (0..3).map(|k| grgb[k] * (s.rgb[k] - bg[k]) + gn[k] * s.normal[k]).sum::<f64>()
                    + g.opacity as f64
                    + g.depth as f64 * s.t
            })
            .collect();
        // The size of the distortion's share of u_i as the kernel sums it: prefix and
        // suffix sums of w t (suffixes from `depth`), so its rounding is relative to
        // t_max opacity, not to the (smaller) differences m_i - m_j.
        let (d, o, ori) = reference::ray_priors(&ray, want, pri[2]);
        let t_max = ray.last().map_or(0.0, |l| l.t + l.dt);
        let u_dist = pri[0] * 4.0 * want.opacity * t_max;
        let total: f64 = u.iter().zip(&want.weights).map(|(u, w)| u * w).sum::<f64>() + 2.0 * pri[0] * d + pri[3] * ori;
        let scale = u.iter().zip(&want.weights).map(|(u, w)| (u.abs() + u_dist) * w).sum::<f64>() + total.abs();
        let (aux_d, aux_o, aux_r) = (fwd.aux[r].distortion as f64, fwd.aux[r].occlusion as f64, fwd.aux[r].orientation as f64);
        assert!((aux_d - d).abs() <= 1e-5 * d + 1e-7, "ray {r}: distortion gpu {aux_d} ref {d}");
        assert!((aux_o - o).abs() <= 1e-5 * o + 1e-7, "ray {r}: occlusion gpu {aux_o} ref {o}");
        assert!((aux_r - ori).abs() <= 1e-5 * ori + 1e-7, "ray {r}: orientation gpu {aux_r} ref {ori}");
        let start = h.ranges[r].start as usize;
        for (i, s) in ray.iter().enumerate() {
            let idx = start + i;
            let (gd, gc, gnn) = (grads.density[idx] as f64, grads.rgb[idx], grads.normal[idx]);
            assert_eq!((gc[3], gnn[3]), (0.0, 0.0), "ray {r} sample {i}: w components");
            if let Some(want_s) = fd(&ray, bg, th, g, pri, i, &|s, v| s.sigma = v, s.sigma) {
                let tol = 1e-4 * want_s.abs() + 2e-6 * s.dt * scale;
                worst_sigma = worst_sigma.max((gd - want_s).abs() / (1e-4 * want_s.abs() + 1e-6 * s.dt * scale).max(1e-30));
                assert!(
                    (gd - want_s).abs() <= tol,
                    "ray {r} sample {i}: dL/dsigma gpu {gd} fd {want_s} (tol {tol:e}, sigma {}, K {})",
                    s.sigma,
                    want.n_contrib
                );
                n_sigma += 1;
            }
            for k in 0..3 {
                let fc = fd(&ray, bg, th, g, pri, i, &|s, v| s.rgb[k] = v, s.rgb[k]).unwrap();
                let fnn = fd(&ray, bg, th, g, pri, i, &|s, v| s.normal[k] = v, s.normal[k]).unwrap();
                assert!((gc[k] as f64 - fc).abs() <= 1e-5 * fc.abs() + 1e-7, "ray {r} sample {i}: dL/dc{k} {} vs {fc}", gc[k]);
                assert!((gnn[k] as f64 - fnn).abs() <= 1e-5 * fnn.abs() + 1e-7, "ray {r} sample {i}: dL/dn{k} {} vs {fnn}", gnn[k]);
            }
            if i >= want.n_contrib {
                assert_eq!((gd, gc, gnn), (0.0, [0.0; 4], [0.0; 4]), "ray {r} sample {i}: past termination");
            }
        }
    }
    for (s, inside) in h.in_range().iter().enumerate() {
        if !inside {
            assert_eq!((grads.density[s], grads.rgb[s], grads.normal[s]), (123.0, [123.0, 123.0, 123.0, 0.0], [123.0; 4]), "gap sample {s} written");
        }
    }
    assert!(n_skipped <= 3, "{n_skipped} rays disagree on termination");
    assert!(n_sigma > 4000, "only {n_sigma} sigma gradients checked");
    eprintln!("{cfg:?}: {n_sigma} dL/dsigma checked, worst error / (1e-4 |fd| + 1e-6 dt S) = {worst_sigma:.3}");
}

#[test]
fn backward_matches_finite_differences_black() {
    check_backward_fd(RenderConfig::default(), 11);
}

#[test]
fn backward_matches_finite_differences_colour_background() {
    check_backward_fd(RenderConfig { background: Background::Color { rgb: [0.9, 0.1, 0.6] }, transmittance_threshold: 1e-4, ..Default::default() }, 12);
}

#[test]
fn backward_with_priors_matches_finite_differences() {
    // Weights large enough that the priors dominate some samples' gradients; the
    // occlusion range covers the first half of the rays' t (0.1 .. ~4).
    let priors = RayPriors {
        lambda_distortion: 1.0,
        lambda_occlusion: 1.0,
        distortion_scale: 0.7,
        occlusion_scale: 0.3,
        occlusion_end: 1.2,
        lambda_orientation: 1.0,
        orientation_scale: 0.5,
        ..Default::default()
    };
    check_backward_fd_with(RenderConfig { background: Background::Color { rgb: [0.2, 0.4, 0.6] }, transmittance_threshold: 1e-4, ..Default::default() }, priors, &[], 14);
    check_backward_fd_with(RenderConfig { background: Background::Random, transmittance_threshold: 1e-4, ..Default::default() }, priors, &[], 15);
}

#[test]
fn backward_with_the_stereo_free_space_matches_finite_differences() {
    // The free-space prior alone and beside the occlusion prior, with ends per ray: none
    // (0), inside the rays' t (0.1 .. ~4) and past every sample; the rays after the
    // listed ends get none.
    let free_end: Vec<f32> = (0..250).map(|r| [0.0, 0.7, 1.9, 3.1, 100.0][r % 5]).collect();
    let alone = RayPriors { lambda_free_space: 1.0, free_space_scale: 0.4, ..Default::default() };
    let cfg = RenderConfig { background: Background::Color { rgb: [0.2, 0.4, 0.6] }, transmittance_threshold: 1e-4, ..Default::default() };
    check_backward_fd_with(cfg, alone, &free_end, 31);
    let both = RayPriors { lambda_occlusion: 1.0, occlusion_scale: 0.3, occlusion_end: 1.2, ..alone };
    check_backward_fd_with(cfg, both, &free_end, 32);
}

#[test]
fn the_free_space_prior_pushes_out_only_the_density_in_front_of_its_end() {
    // With every other gradient zero, dL/dsigma_i is c_f dt_i before the ray's end and
    // 0 from it on: the prior carves the space in front of the stereo depth and leaves
    // the surface behind it alone.
    let gpu = test_gpu(false);
    let h = random_batch(&mut SplitMix64::new(33), 120, 24);
    let up = upload(&gpu, &h);
    let mut renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let c_f = 0.25f32;
    renderer.set_priors(RayPriors { lambda_free_space: 1.0, free_space_scale: c_f, ..Default::default() });
    let free_end: Vec<f32> = (0..h.n_rays()).map(|r| if r % 2 == 0 { 1.5 } else { 0.0 }).collect();
    let fwd = run_forward_with_free_ends(&gpu, &renderer, &up, 0, &free_end);
    let zero = vec![RayOutput { rgb: [0.0; 3], opacity: 0.0, normal: [0.0; 3], depth: 0.0 }; h.n_rays() as usize];
    let grads = run_backward(&gpu, &renderer, &up, &fwd, &zero, &sentinel_grads(h.density.len()), false);
    let (mut inside, mut outside) = (0, 0);
    for r in 0..h.n_rays() as usize {
        let start = h.ranges[r].start as usize;
        for (i, s) in h.ray(r).iter().enumerate().take(fwd.aux[r].n_contrib as usize) {
            let got = grads.density[start + i];
            if (s.t as f32) < free_end[r] {
                assert!((got - c_f * s.dt as f32).abs() <= 1e-6, "ray {r} sample {i}: {got} vs {}", c_f * s.dt as f32);
                inside += 1;
            } else {
                assert_eq!(got, 0.0, "ray {r} sample {i} at t {} (end {})", s.t, free_end[r]);
                outside += 1;
            }
        }
    }
    assert!(inside > 200 && outside > 200, "{inside} samples in front of their ends, {outside} behind");
}

#[test]
fn priors_off_leave_the_gradients_unchanged() {
    // Zero lambdas with a live occlusion range: the backward is the plain one, bit for bit.
    let gpu = test_gpu(false);
    let h = random_batch(&mut SplitMix64::new(16), 200, 32);
    let up = upload(&gpu, &h);
    let plain = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let mut off = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    off.set_priors(RayPriors { occlusion_end: 1.0, distortion_scale: 1.0, occlusion_scale: 1.0, orientation_scale: 1.0, ..Default::default() });
    let d_rays: Vec<RayOutput> = (0..h.n_rays()).map(|r| RayOutput { rgb: [0.3, -0.2, 0.1], opacity: 0.05 * (r % 3) as f32, normal: [0.1; 3], depth: -0.2 }).collect();
    let a = run_backward(&gpu, &plain, &up, &run_forward(&gpu, &plain, &up, 0), &d_rays, &sentinel_grads(h.density.len()), false);
    let fwd_off = run_forward(&gpu, &off, &up, 0);
    let b = run_backward(&gpu, &off, &up, &fwd_off, &d_rays, &sentinel_grads(h.density.len()), false);
    assert_eq!((a.density, a.rgb, a.normal), (b.density, b.rgb, b.normal));
    assert!(fwd_off.aux.iter().any(|x| x.occlusion > 0.0), "the forward still measures O");
    assert!(fwd_off.aux.iter().any(|x| x.orientation > 0.0), "the forward still measures R");
}

#[test]
fn backward_matches_finite_differences_random_background_no_termination() {
    check_backward_fd(RenderConfig { background: Background::Random, transmittance_threshold: 0.0, ..Default::default() }, 13);
}

#[test]
fn backward_accumulates_when_asked() {
    let gpu = test_gpu(false);
    let mut rng = SplitMix64::new(21);
    let h = random_batch(&mut rng, 200, 32);
    let up = upload(&gpu, &h);
    let renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let fwd = run_forward(&gpu, &renderer, &up, 0);
    let d_rays: Vec<RayOutput> =
        (0..h.n_rays()).map(|_| RayOutput { rgb: [rng.unit_f32(); 3], opacity: 0.5, normal: [0.3; 3], depth: -0.2 }).collect();
    let n = h.density.len();
    let fresh = run_backward(&gpu, &renderer, &up, &fwd, &d_rays, &sentinel_grads(n), false);
    let init = Grads {
        density: (0..n).map(|_| rng.range_f32(-1.0, 1.0)).collect(),
        rgb: (0..n).map(|_| [rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), rng.range_f32(-1.0, 1.0), 0.0]).collect(),
        normal: (0..n).map(|_| [rng.range_f32(-1.0, 1.0); 4]).collect(),
    };
    let acc = run_backward(&gpu, &renderer, &up, &fwd, &d_rays, &init, true);
    let inside = h.in_range();
    for s in 0..n {
        if inside[s] {
            assert_eq!(acc.density[s], init.density[s] + fresh.density[s], "sample {s}");
            for k in 0..4 {
                assert_eq!(acc.rgb[s][k], init.rgb[s][k] + fresh.rgb[s][k]);
                assert_eq!(acc.normal[s][k], init.normal[s][k] + fresh.normal[s][k]);
            }
        } else {
            assert_eq!((acc.density[s], acc.rgb[s], acc.normal[s]), (init.density[s], init.rgb[s], init.normal[s]));
        }
    }
}

#[test]
fn early_termination_is_the_same_forward_and_backward() {
    let gpu = test_gpu(false);
    let renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    // 8 samples, dt = 0.1; sample 3 has tau = 12, so T_4 < 1e-4 and K = 4.
    let sigma = [0.5f32, 1.0, 2.0, 120.0, 1.0, 3.0, 0.5, 200.0];
    let mk = |density: &[f32]| HostBatch {
        ranges: vec![SampleRange { start: 0, count: 8 }],
        samples: (0..8).map(|i| GpuSample { pos: [0.0; 3], t: 1.0 + 0.1 * i as f32, dir: [0.0, 0.0, 1.0], dt: 0.1 }).collect(),
        density: density.to_vec(),
        rgb: (0..8).map(|i| [0.1 * i as f32, 0.5, 1.0 - 0.1 * i as f32, 0.0]).collect(),
        normal: vec![[0.0, 0.0, 1.0, 0.0]; 8],
    };
    let h = mk(&sigma);
    let up = upload(&gpu, &h);
    let fwd = run_forward(&gpu, &renderer, &up, 0);
    let want = reference::composite(&h.ray(0), [0.0; 3], 1e-4);
    assert_eq!(want.n_contrib, 4);
    assert_eq!(fwd.aux[0].n_contrib, 4);
    assert!(fwd.weights[..4].iter().all(|&w| w > 0.0));
    assert_eq!(&fwd.weights[4..], &[0.0; 4]);
    // The host weights helper agrees.
    let hw = reference::sample_weights(&h.ranges, &h.samples, &h.density, 1e-4);
    for (a, b) in hw.iter().zip(&fwd.weights) {
        assert!((a - b).abs() <= 1e-6 * a.max(1e-6));
    }
    // Samples past K change nothing in the forward pass, bit for bit.
    let mut other = sigma;
    other[4..].copy_from_slice(&[50.0, 0.0, 9.0, 1.0]);
    let fwd2 = run_forward(&gpu, &renderer, &upload(&gpu, &mk(&other)), 0);
    assert_eq!(fwd.rays, fwd2.rays);
    // ... and get exactly zero gradient, while the K contributing samples get some.
    let g = RayOutput { rgb: [1.0, 1.0, 1.0], opacity: 1.0, normal: [1.0; 3], depth: 1.0 };
    let grads = run_backward(&gpu, &renderer, &up, &fwd, &[g], &sentinel_grads(8), false);
    for i in 0..8 {
        let zero = grads.density[i] == 0.0 && grads.rgb[i] == [0.0; 4] && grads.normal[i] == [0.0; 4];
        assert_eq!(zero, i >= 4, "sample {i}: {:?} {:?}", grads.density[i], grads.rgb[i]);
    }
    // Consistent with the truncated reference: dL/dsigma of sample 5 is 0 there too.
    let fd5 = fd(&h.ray(0), [0.0; 3], 1e-4, &g, [0.0, 0.0, f64::MIN, 0.0, 0.0, 0.0], 5, &|s, v| s.sigma = v, 3.0).unwrap();
    assert_eq!(fd5, 0.0);
}

#[test]
fn undersized_buffers_are_errors() {
    let gpu = test_gpu(false);
    let renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let mut rng = SplitMix64::new(3);
    let h = random_batch(&mut rng, 10, 8);
    let up = upload(&gpu, &h);
    let small = RenderOutputs::new(&gpu, 5, None).unwrap();
    let mut enc = gpu.encoder();
    let err = renderer.forward(&mut enc, &up.batch, &up.field, &small, 0).unwrap_err();
    assert!(matches!(err, RenderError::BufferTooSmall { what: "ray outputs", len: 5, needed: 10 }), "{err}");
    let few_weights = RenderOutputs::new(&gpu, 10, Some(3)).unwrap();
    assert!(renderer.forward(&mut enc, &up.batch, &up.field, &few_weights, 0).is_err());
    assert!(matches!(
        Renderer::new(&gpu, RenderConfig { transmittance_threshold: f32::NAN, ..Default::default() }),
        Err(RenderError::BadThreshold(_))
    ));
}

#[test]
fn config_round_trips_through_json() {
    let cfg = RenderConfig { background: Background::Color { rgb: [1.0, 0.5, 0.0] }, transmittance_threshold: 1e-3, ..Default::default() };
    let s = serde_json::to_string(&cfg).unwrap();
    assert_eq!(serde_json::from_str::<RenderConfig>(&s).unwrap(), cfg);
    let r: RenderConfig = serde_json::from_str(r#"{"background":{"kind":"random"}}"#).unwrap();
    assert_eq!(r, RenderConfig { background: Background::Random, transmittance_threshold: 1e-4, ..Default::default() });
}

/// Throughput on the device in use (run with `--ignored --nocapture`).
#[test]
#[ignore]
fn render_throughput() {
    let gpu = test_gpu(false);
    let renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let mut rng = SplitMix64::new(99);
    let h = random_batch(&mut rng, 4096, 256);
    let up = upload(&gpu, &h);
    let out = RenderOutputs::new(&gpu, up.batch.n_rays, None).unwrap();
    let grads = FieldOutputs::new(&gpu, up.batch.capacity).unwrap();
    let d = GpuBuffer::from_slice(&gpu, "d", &vec![RayOutput { rgb: [1.0; 3], opacity: 1.0, normal: [1.0; 3], depth: 1.0 }; 4096]).unwrap();
    for pass in 0..2 {
        let t0 = std::time::Instant::now();
        let mut enc = gpu.encoder();
        renderer.forward(&mut enc, &up.batch, &up.field, &out, 0).unwrap();
        enc.submit();
        gpu.wait().unwrap();
        let t1 = std::time::Instant::now();
        let mut enc = gpu.encoder();
        renderer.backward(&mut enc, &up.batch, &up.field, &out, &d, &grads, false).unwrap();
        enc.submit();
        gpu.wait().unwrap();
        eprintln!(
            "pass {pass}: {} rays, {} samples on {}: forward {:?}, backward {:?}",
            h.n_rays(),
            h.capacity(),
            gpu.adapter().name,
            t1 - t0,
            t1.elapsed()
        );
    }
}

#[test]
fn weights_of_nearly_transparent_samples_are_accurate() {
    // One sample per ray, tau from 1e-7 to 0.3: w = alpha = 1 - exp(-tau), where the
    // naive form would lose up to all digits to cancellation at small tau.
    let gpu = test_gpu(false);
    let renderer = Renderer::new(&gpu, RenderConfig::default()).unwrap();
    let n = 2000u32;
    let taus: Vec<f32> = (0..n).map(|i| 1e-7f32 * (3e6f32).powf(i as f32 / (n - 1) as f32)).collect();
    let h = HostBatch {
        ranges: (0..n).map(|i| SampleRange { start: i, count: 1 }).collect(),
        samples: (0..n).map(|_| GpuSample { pos: [0.0; 3], t: 1.0, dir: [0.0, 0.0, 1.0], dt: 1.0 }).collect(),
        density: taus.clone(),
        rgb: vec![[1.0; 4]; n as usize],
        normal: vec![[0.0; 4]; n as usize],
    };
    let fwd = run_forward(&gpu, &renderer, &upload(&gpu, &h), 0);
    let mut worst = 0.0f64;
    for (i, &tau) in taus.iter().enumerate() {
        let want = -(-(tau as f64)).exp_m1();
        let rel = (fwd.weights[i] as f64 - want).abs() / want;
        // Series branch (tau < 0.1): a few ulps; direct branch: ulp(1) / alpha.
        let tol = if tau < 0.1 { 3e-7 } else { 3e-6 };
        assert!(rel <= tol, "tau {tau}: weight {} vs {want} (relative error {rel:e})", fwd.weights[i]);
        assert_eq!(fwd.rays[i].opacity, fwd.weights[i]);
        worst = worst.max(rel);
    }
    eprintln!("worst relative weight error over tau in [1e-7, 0.3]: {worst:e}");
}
