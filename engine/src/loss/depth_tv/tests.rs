//! Tests of the depth TV regularizer: the kernel against the `f64` reference, the
//! reference against central differences, and the whole chain (hash-grid field ->
//! compositing -> depth TV -> backward into the parameters) against central
//! differences of the CPU pipeline.

use glam::Vec3;

use super::reference::{TvRay, loss, weights};
use super::*;
use crate::field::grid::tests::{AABB, randomize, small_config};
use crate::rng::SplitMix64;
use crate::field::test_support::check_grid_grads_against_fd;
use crate::field::{Field, GridField};
use crate::gpu::test_gpu;
use crate::render::{Background, RenderConfig, RenderOutputs, Renderer, reference as render_ref};
use crate::layout::{FieldGrads, FieldOutputs, GpuSample, SampleBatch, SampleRange};

/// Random patch rays; a few with the clamp active (low and high), one transparent.
fn random_rays(n: usize, seed: u64) -> Vec<TvRay> {
    let mut r = SplitMix64::new(seed);
    let mut rays: Vec<TvRay> = (0..n)
        .map(|_| {
            let opacity = 0.3 + 0.35 * (r.uniform(1.0) + 1.0);
            TvRay { depth: opacity * (2.5 + 0.4 * r.uniform(1.0)), opacity, z_scale: 0.8 + 0.1 * r.uniform(1.0), t_min: 2.0, t_max: 3.5 }
        })
        .collect();
    rays[3].depth = rays[3].opacity * 1.5;
    rays[10].depth = rays[10].opacity * 4.0;
    rays[20].opacity = 0.0;
    rays[20].depth = 0.0;
    rays
}

fn gpu_rays(rays: &[TvRay], pad: usize) -> (Vec<RayOutput>, Vec<GpuRay>) {
    let mut outs = vec![RayOutput::default(); pad];
    let mut ins = vec![GpuRay::default(); pad];
    for r in rays {
        outs.push(RayOutput { depth: r.depth as f32, opacity: r.opacity as f32, ..Default::default() });
        ins.push(GpuRay { t_min: r.t_min as f32, t_max: r.t_max as f32, ..Default::default() });
    }
    (outs, ins)
}

#[test]
fn depth_tv_kernel_matches_reference() {
    let gpu = test_gpu(false);
    for (ps, n_patches, acc_weight) in [(8usize, 3usize, 0.0f32), (8, 2, 1.0), (4, 5, 0.5)] {
        let n = ps * ps * n_patches;
        let rays = random_rays(n, ps as u64 + n_patches as u64);
        let offset = 7usize;
        let (outs, ins) = gpu_rays(&rays, offset);
        let tv = DepthTv::new(&gpu, n as u32).unwrap();
        tv.z_scale.write(&gpu, &rays.iter().map(|r| r.z_scale as f32).collect::<Vec<_>>());
        let outs_buf = GpuBuffer::from_slice(&gpu, "outs", &outs).unwrap();
        let ins_buf = GpuBuffer::from_slice(&gpu, "rays", &ins).unwrap();
        // Pre-filled gradients: the kernel adds, and leaves the rays before `offset` alone.
        let prior: Vec<RayOutput> = (0..offset + n).map(|i| RayOutput { rgb: [0.5; 3], depth: 0.25, opacity: 0.01 * i as f32, ..Default::default() }).collect();
        let d = GpuBuffer::from_slice(&gpu, "d", &prior).unwrap();
        let lambda = 0.7f32;
        let mut enc = gpu.encoder();
        tv.record(&mut enc, &outs_buf, &ins_buf, &d, offset as u32, n as u32, ps as u32, lambda, acc_weight);
        enc.submit();
        let got = tv.loss(&gpu, n as u32).unwrap() as f64;
        let (want, grads) = loss(&rays, ps, &weights(&rays, acc_weight as f64));
        assert!((got - want).abs() <= 1e-5 * want.max(1e-3), "ps {ps}: loss {got} vs {want}");
        let d = d.read(&gpu).unwrap();
        let what = format!("ps {ps}");
        crate::loss::test_support::assert_added_depth_opacity_grads(&d, &prior, offset, &grads, lambda as f64, (1e-5, 1.0), &what);
        assert_eq!((grads[3], grads[10]), ((0.0, 0.0), (0.0, 0.0)), "clamped rays get no gradient");
    }
}

#[test]
fn depth_tv_reference_matches_finite_differences() {
    let ps = 8;
    let rays = random_rays(2 * ps * ps, 5);
    for acc_weight in [0.0, 1.0] {
        // The weights are constants of the backward pass (stop-gradient): hold them.
        let w = weights(&rays, acc_weight);
        let (_, grads) = loss(&rays, ps, &w);
        let h = 1e-6;
        for k in 0..rays.len() {
            if k == 20 {
                continue; // transparent: the loss is not differentiable in its opacity at 0
            }
            for which in 0..2 {
                let bump = |s: f64| {
                    let mut p = rays.clone();
                    if which == 0 { p[k].depth += s } else { p[k].opacity += s }
                    loss(&p, ps, &w).0
                };
                let fd = (bump(h) - bump(-h)) / (2.0 * h);
                let got = if which == 0 { grads[k].0 } else { grads[k].1 };
                assert!((fd - got).abs() < 1e-6 * fd.abs().max(1.0), "acc {acc_weight} ray {k} {which}: fd {fd} vs {got}");
            }
        }
    }
    // Linear in z: a constant patch has no loss; a ramp along x gives (ps-1)^2 terms of slope^2.
    let flat: Vec<TvRay> = (0..ps * ps).map(|k| TvRay { depth: 2.0 + 0.1 * (k % ps) as f64, opacity: 1.0, z_scale: 1.0, t_min: 0.0, t_max: 10.0 }).collect();
    let (l, _) = loss(&flat, ps, &weights(&flat, 0.0));
    assert!((l - 0.01).abs() < 1e-12, "{l}");
}

/// 8 samples per ray through the field's box for one 4x4 patch looking along +z.
fn patch_samples(ps: usize) -> (Vec<SampleRange>, Vec<GpuSample>, Vec<GpuRay>) {
    let per_ray = 8u32;
    let (mut ranges, mut samples, mut rays) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..ps * ps {
        let (i, j) = ((k / ps) as f32, (k % ps) as f32);
        let origin = Vec3::new(0.1 + 0.05 * j, 0.3 + 0.05 * i, -1.2);
        let dir = Vec3::new(0.03 * j, -0.02 * i, 1.0).normalize();
        ranges.push(SampleRange { start: k as u32 * per_ray, count: per_ray });
        for s in 0..per_ray {
            let t = 0.1 + 0.15 * s as f32;
            samples.push(GpuSample { pos: (origin + t * dir).to_array(), t, dir: dir.to_array(), dt: 0.15 });
        }
        rays.push(GpuRay { origin: origin.to_array(), t_min: 0.025, dir: dir.to_array(), t_max: 1.225 });
    }
    (ranges, samples, rays)
}

#[test]
fn depth_tv_end_to_end_matches_finite_differences() {
    let gpu = test_gpu(false);
    let mut field = GridField::new(&gpu, &small_config(), AABB).unwrap();
    randomize(&gpu, &mut field, 5);
    let ps = 4usize;
    let n_rays = ps * ps;
    let (ranges, samples, in_rays) = patch_samples(ps);
    let capacity = samples.len() as u32;
    let batch = SampleBatch::new(&gpu, n_rays as u32, capacity).unwrap();
    batch.ranges.write(&gpu, &ranges);
    batch.samples.write(&gpu, &samples);
    batch.count.write(&gpu, &[capacity, capacity]);
    let z_scale: Vec<f32> = (0..n_rays).map(|k| 0.9 + 0.005 * k as f32).collect();

    // GPU: field forward (through the trait), composite, TV, backward to the parameters.
    let field_dyn: &mut dyn Field = &mut field;
    let out = FieldOutputs::new(&gpu, capacity).unwrap();
    field_dyn.forward(&gpu, &batch, &out, false).unwrap();
    let renderer = Renderer::new(&gpu, RenderConfig { background: Background::Black, transmittance_threshold: 0.0, ..Default::default() }).unwrap();
    let render_out = RenderOutputs::new(&gpu, n_rays as u32, None).unwrap();
    let tv = DepthTv::new(&gpu, n_rays as u32).unwrap();
    tv.z_scale.write(&gpu, &z_scale);
    let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &in_rays).unwrap();
    let d_rays = GpuBuffer::<RayOutput>::zeros(&gpu, "d rays", n_rays).unwrap();
    let grads = FieldGrads::new(&gpu, capacity).unwrap();
    let mut enc = gpu.encoder();
    renderer.forward(&mut enc, &batch, &out, &render_out, 0).unwrap();
    tv.record(&mut enc, &render_out.rays, &rays_buf, &d_rays, 0, n_rays as u32, ps as u32, 1.0, 0.0);
    renderer.backward(&mut enc, &batch, &out, &render_out, &d_rays, &grads, false).unwrap();
    enc.submit();
    let gpu_loss = tv.loss(&gpu, n_rays as u32).unwrap() as f64;
    field_dyn.zero_grads(&gpu);
    field_dyn.backward(&gpu, &batch, &grads, None, false).unwrap();
    let [(_, table_grad), (_, mlp_grad)] = field.buffers();
    let (table_grad, mlp_grad) = (table_grad.read(&gpu).unwrap(), mlp_grad.read(&gpu).unwrap());

    // CPU: the same chain in f64.
    let model = field.reference(&gpu).unwrap();
    let loss_of = |m: &crate::field::grid::reference::GridModel| -> f64 {
        let rays: Vec<TvRay> = ranges
            .iter()
            .enumerate()
            .map(|(k, range)| {
                let ref_samples: Vec<render_ref::RefSample> = (range.start..range.start + range.count)
                    .map(|s| {
                        let smp = &samples[s as usize];
                        let t = m.forward(smp.pos.map(|v| v as f64), smp.dir.map(|v| v as f64));
                        render_ref::RefSample { sigma: t.sigma, rgb: t.rgb, normal: t.normal, t: smp.t as f64, dt: smp.dt as f64, dir: smp.dir.map(|v| v as f64) }
                    })
                    .collect();
                let ray = render_ref::composite(&ref_samples, [0.0; 3], 0.0);
                TvRay { depth: ray.depth, opacity: ray.opacity, z_scale: z_scale[k] as f64, t_min: in_rays[k].t_min as f64, t_max: in_rays[k].t_max as f64 }
            })
            .collect();
        loss(&rays, ps, &weights(&rays, 0.0)).0
    };
    let l = loss_of(&model);
    assert!(l > 1e-4, "the test patch must be uneven: {l}");
    assert!((gpu_loss - l).abs() < 1e-3 * l, "GPU {gpu_loss} vs CPU {l}");
    check_grid_grads_against_fd("depth TV", &model, &table_grad, &mlp_grad, 23, loss_of);
}
