//! Tests of the edge-guided regularizers: the kernel against the `f64` reference, the
//! reference against central differences, and the whole chain (hash-grid field with
//! analytic normals -> compositing -> L_z / L_n -> backward, second order through the
//! normals) against central differences of the CPU pipeline.

use glam::Vec3;

use super::reference::{PatchRay, Setting, losses, losses_given_means, patch_means};
use super::*;
use crate::field::grid::tests::{AABB, randomize, small_config};
use crate::rng::SplitMix64;
use crate::field::test_support::check_grid_grads_against_fd;
use crate::field::{Field, GridField};
use crate::gpu::test_gpu;
use crate::render::{Background, RenderConfig, RenderOutputs, Renderer, reference as render_ref};
use crate::layout::{FieldGrads, FieldOutputs, GpuSample, SampleBatch, SampleRange};

fn random_patch_rays(n_patches: usize, seed: u64) -> Vec<PatchRay> {
    let mut r = SplitMix64::new(seed);
    let mut rays: Vec<PatchRay> = (0..4 * n_patches)
        .map(|i| PatchRay {
            e: if (r.uniform(1.0) + 1.0) * 0.5 < 0.3 { 0.0 } else { 1.0 },
            z_scale: 0.8 + 0.1 * (r.uniform(1.0) + 1.0),
            depth: 2.0 + r.uniform(1.0) + 0.01 * i as f64,
            // Some rays below the opacity floor of the depth given termination.
            opacity: 0.05 + 0.45 * (r.uniform(1.0) + 1.0),
            normal: [r.uniform(1.0), r.uniform(1.0), r.uniform(1.0)],
        })
        .collect();
    // One patch entirely on edges (0/0 guard) and one entirely non-edge.
    for i in 0..4 {
        rays[4 + i].e = 0.0;
        rays[8 + i].e = 1.0;
    }
    rays
}

fn weights(variant: RegVariant, depth_target: DepthTarget, depth_estimate: DepthEstimate, tau_depth: f32) -> EdgeRegWeights {
    EdgeRegWeights { variant, lambda_depth: 0.7, lambda_normal: 1.3, tau_depth, tau_normal: 0.0, depth_target, depth_estimate, lambda_depth_normal: 0.0, depth_normal_residual: Default::default(), depth_normal_coherence: 0.0, lambda_planarity: 0.0, planarity_scale: 0.0, planarity_coherence: 0.0, lambda_reprojection: 0.0, reprojection_delta: 0.02 }
}

fn setting_of(w: &EdgeRegWeights) -> Setting {
    Setting {
        variant: w.variant,
        target: w.depth_target,
        estimate: w.depth_estimate,
        tau_depth: w.tau_depth as f64,
        tau_normal: w.tau_normal as f64,
    }
}

#[test]
fn edge_reg_kernel_matches_reference() {
    let gpu = test_gpu(false);
    let n_patches = 37usize;
    let rays = random_patch_rays(n_patches, 3);
    use DepthEstimate::{Expected, GivenTermination};
    use DepthTarget::{Mean, Plane};
    let cases = [
        (RegVariant::Paper, Mean, Expected, 1e-4f32),
        (RegVariant::Official, Mean, Expected, 1e-4),
        (RegVariant::Paper, Mean, Expected, 0.3),
        (RegVariant::Paper, Plane, Expected, 1e-4),
        (RegVariant::Official, Plane, Expected, 0.3),
        (RegVariant::Paper, Mean, GivenTermination, 1e-4),
        (RegVariant::Official, Mean, GivenTermination, 1e-4),
        (RegVariant::Paper, Plane, GivenTermination, 1e-4),
    ];
    for (variant, target, estimate, tau) in cases {
        let w = weights(variant, target, estimate, tau);
        let reg = EdgeReg::new(&gpu, n_patches as u32).unwrap();
        reg.pixel.write(&gpu, &rays.iter().map(|r| [r.e as f32, r.z_scale as f32]).collect::<Vec<_>>());
        let outs: Vec<RayOutput> = rays
            .iter()
            .map(|r| RayOutput {
                depth: r.depth as f32,
                opacity: r.opacity as f32,
                normal: r.normal.map(|v| v as f32),
                ..Default::default()
            })
            .collect();
        let rays_buf = GpuBuffer::from_slice(&gpu, "rays", &outs).unwrap();
        // Pre-filled gradients: the kernel adds.
        let prior: Vec<RayOutput> =
            (0..rays.len()).map(|i| RayOutput { rgb: [0.5; 3], depth: 0.25, normal: [i as f32 * 0.01, 0.0, -1.0], opacity: 0.125 }).collect();
        let d = GpuBuffer::from_slice(&gpu, "d", &prior).unwrap();
        let mut enc = gpu.encoder();
        reg.record(&mut enc, &rays_buf, &d, n_patches as u32, &w);
        enc.submit();
        let got = reg.losses(&gpu, n_patches as u32).unwrap();
        let ((lz, ln), grads) = losses(&rays, &setting_of(&w));
        let case = format!("{variant:?} {target:?} {estimate:?} tau {tau}");
        assert!((got.depth as f64 - lz).abs() <= 1e-5 * lz.abs().max(1e-3), "{case}: L_z {} vs {lz}", got.depth);
        assert!((got.normal as f64 - ln).abs() <= 1e-5 * ln.abs().max(1e-3), "{case}: L_n {} vs {ln}", got.normal);
        let d = d.read(&gpu).unwrap();
        for (i, (g, p)) in grads.iter().zip(&prior).enumerate() {
            let want_z = p.depth as f64 + w.lambda_depth as f64 * g.depth;
            assert!((d[i].depth as f64 - want_z).abs() < 1e-5, "{case} ray {i}: d depth {} vs {want_z}", d[i].depth);
            let want_o = p.opacity as f64 + w.lambda_depth as f64 * g.opacity;
            assert!((d[i].opacity as f64 - want_o).abs() < 1e-5, "{case} ray {i}: d opacity {} vs {want_o}", d[i].opacity);
            for c in 0..3 {
                let want = p.normal[c] as f64 + w.lambda_normal as f64 * g.normal[c];
                assert!((d[i].normal[c] as f64 - want).abs() < 1e-5, "{case} ray {i} d normal[{c}]");
            }
            assert_eq!(d[i].rgb, p.rgb, "colour gradients untouched");
        }
        // The all-edge patch has no loss and no gradient.
        assert!((4..8).all(|i| d[i].depth == prior[i].depth && d[i].opacity == prior[i].opacity));
        // The expected depth leaves opacity alone; given termination reaches it.
        let opacity_touched = d.iter().zip(&prior).any(|(a, b)| a.opacity != b.opacity);
        assert_eq!(opacity_touched, estimate == GivenTermination, "{case}");
    }
}

#[test]
fn edge_reg_reference_matches_finite_differences() {
    let rays = random_patch_rays(9, 11);
    let variants = [RegVariant::Paper, RegVariant::Official];
    let targets = [DepthTarget::Mean, DepthTarget::Plane];
    let estimates = [DepthEstimate::Expected, DepthEstimate::GivenTermination];
    for variant in variants {
        for target in targets {
            for estimate in estimates {
                let setting = Setting { variant, target, estimate, tau_depth: 1e-4, tau_normal: 0.0 };
                check_reference_against_finite_differences(&rays, &setting);
            }
        }
    }
    // Stop-gradient changes the answer (the paper variant's mean terms matter).
    let official = Setting { variant: RegVariant::Official, target: DepthTarget::Mean, estimate: DepthEstimate::Expected, tau_depth: 1e-4, tau_normal: 0.0 };
    let (_, a) = losses(&rays, &official);
    let (_, b) = losses(&rays, &Setting { variant: RegVariant::Paper, ..official });
    assert!(a.iter().zip(&b).any(|(a, b)| (a.depth - b.depth).abs() > 1e-3));
}

fn check_reference_against_finite_differences(rays: &[PatchRay], setting: &Setting) {
    // The official variant's means are constants of the backward pass: hold them.
    let frozen = patch_means(rays, setting.estimate);
    let total = |rays: &[PatchRay]| {
        let means = if setting.variant == RegVariant::Official { frozen.clone() } else { patch_means(rays, setting.estimate) };
        let ((lz, ln), _) = losses_given_means(rays, &means, setting);
        lz + 2.0 * ln
    };
    let (_, grads) = losses(rays, setting);
    let h = 1e-6;
    let fd = |i: usize, perturb: &dyn Fn(&mut PatchRay, f64)| {
        let (mut p, mut m) = (rays.to_vec(), rays.to_vec());
        perturb(&mut p[i], h);
        perturb(&mut m[i], -h);
        (total(&p) - total(&m)) / (2.0 * h)
    };
    for (i, g) in grads.iter().enumerate() {
        let d = fd(i, &|r, h| r.depth += h);
        assert!((d - g.depth).abs() < 1e-6, "{setting:?} ray {i} depth: fd {d} vs {}", g.depth);
        // Rays within h of the opacity floor would straddle its kink: none are.
        let o = fd(i, &|r, h| r.opacity += h);
        assert!((o - g.opacity).abs() < 1e-6, "{setting:?} ray {i} opacity: fd {o} vs {}", g.opacity);
        for c in 0..3 {
            let n = fd(i, &|r, h| r.normal[c] += h);
            assert!((n - 2.0 * g.normal[c]).abs() < 1e-6, "{setting:?} ray {i} normal {c}: fd {n} vs {}", 2.0 * g.normal[c]);
        }
    }
}

/// Rays of 8 samples each through the field's box, 4 per patch.
fn patch_samples(n_patches: usize, seed: u64) -> (Vec<SampleRange>, Vec<GpuSample>) {
    let mut r = SplitMix64::new(seed);
    let per_ray = 8u32;
    let mut ranges = Vec::new();
    let mut samples = Vec::new();
    for p in 0..n_patches {
        let base = Vec3::new(0.3 * r.uniform(1.0) as f32, 0.25 + 0.2 * r.uniform(1.0) as f32, -1.2);
        let dir0 = Vec3::new(0.2 * r.uniform(1.0) as f32, 0.1 * r.uniform(1.0) as f32, 1.0).normalize();
        for i in 0..4 {
            let offset = Vec3::new(0.02 * (i % 2) as f32, 0.02 * (i / 2) as f32, 0.0);
            let dir = (dir0 + 0.5 * offset).normalize();
            ranges.push(SampleRange { start: ((4 * p + i) as u32) * per_ray, count: per_ray });
            for k in 0..per_ray {
                let t = 0.1 + 0.15 * k as f32;
                samples.push(GpuSample { pos: (base + offset + t * dir).to_array(), t, dir: dir.to_array(), dt: 0.15 });
            }
        }
    }
    (ranges, samples)
}

fn end_to_end(variant: RegVariant, depth_target: DepthTarget, depth_estimate: DepthEstimate) {
    let gpu = test_gpu(false);
    let cfg = small_config();
    let mut field = GridField::new(&gpu, &cfg, AABB).unwrap();
    randomize(&gpu, &mut field, 5);
    let n_patches = 4usize;
    let n_rays = 4 * n_patches;
    let (ranges, samples) = patch_samples(n_patches, 9);
    let capacity = samples.len() as u32;
    let batch = SampleBatch::new(&gpu, n_rays as u32, capacity).unwrap();
    batch.ranges.write(&gpu, &ranges);
    batch.samples.write(&gpu, &samples);
    batch.count.write(&gpu, &[capacity, capacity]);
    let pixel: Vec<[f32; 2]> = (0..n_rays).map(|i| [if i % 7 == 3 { 0.0 } else { 1.0 }, 0.9 + 0.01 * i as f32]).collect();
    let w = EdgeRegWeights { variant, lambda_depth: 1.0, lambda_normal: 1.0, tau_depth: 1e-4, tau_normal: 0.0, depth_target, depth_estimate, lambda_depth_normal: 0.0, depth_normal_residual: Default::default(), depth_normal_coherence: 0.0, lambda_planarity: 0.0, planarity_scale: 0.0, planarity_coherence: 0.0, lambda_reprojection: 0.0, reprojection_delta: 0.02 };
    let setting = setting_of(&w);

    // GPU: forward with normals, composite, losses, backward to the parameters.
    let out = FieldOutputs::new(&gpu, capacity).unwrap();
    field.forward(&gpu, &batch, &out, true).unwrap();
    let renderer = Renderer::new(&gpu, RenderConfig { background: Background::Black, transmittance_threshold: 0.0, ..Default::default() }).unwrap();
    let render_out = RenderOutputs::new(&gpu, n_rays as u32, None).unwrap();
    let reg = EdgeReg::new(&gpu, n_patches as u32).unwrap();
    reg.pixel.write(&gpu, &pixel);
    let d_rays = GpuBuffer::<RayOutput>::zeros(&gpu, "d rays", n_rays).unwrap();
    let grads = FieldGrads::new(&gpu, capacity).unwrap();
    let mut enc = gpu.encoder();
    renderer.forward(&mut enc, &batch, &out, &render_out, 0).unwrap();
    reg.record(&mut enc, &render_out.rays, &d_rays, n_patches as u32, &w);
    renderer.backward(&mut enc, &batch, &out, &render_out, &d_rays, &grads, false).unwrap();
    enc.submit();
    let gpu_loss = reg.losses(&gpu, n_patches as u32).unwrap();
    field.zero_grads(&gpu);
    field.backward(&gpu, &batch, &grads, None, true).unwrap();
    let [(_, table_grad), (_, mlp_grad)] = field.buffers();
    let (table_grad, mlp_grad) = (table_grad.read(&gpu).unwrap(), mlp_grad.read(&gpu).unwrap());

    // CPU: the same chain in f64.
    let model = field.reference(&gpu).unwrap();
    // The official variant's means are held at their unperturbed values (stop-gradient).
    let patch_rays_of = |m: &crate::field::grid::reference::GridModel| -> Vec<PatchRay> {
        let mut rays = Vec::new();
        for (r, range) in ranges.iter().enumerate() {
            let ref_samples: Vec<render_ref::RefSample> = (range.start..range.start + range.count)
                .map(|s| {
                    let smp = &samples[s as usize];
                    let t = m.forward(smp.pos.map(|v| v as f64), smp.dir.map(|v| v as f64));
                    render_ref::RefSample { sigma: t.sigma, rgb: t.rgb, normal: t.normal, t: smp.t as f64, dt: smp.dt as f64, dir: smp.dir.map(|v| v as f64) }
                })
                .collect();
            let ray = render_ref::composite(&ref_samples, [0.0; 3], 0.0);
            rays.push(PatchRay { e: pixel[r][0] as f64, z_scale: pixel[r][1] as f64, depth: ray.depth, opacity: ray.opacity, normal: ray.normal });
        }
        rays
    };
    let frozen = patch_means(&patch_rays_of(&model), depth_estimate);
    let loss_of = |m: &crate::field::grid::reference::GridModel| -> (f64, f64) {
        let rays = patch_rays_of(m);
        let means = if variant == RegVariant::Official { frozen.clone() } else { patch_means(&rays, depth_estimate) };
        losses_given_means(&rays, &means, &setting).0
    };
    let (lz, ln) = loss_of(&model);
    assert!(lz > 1e-3 && ln > 1e-3, "the test scene must exercise both losses: {lz} {ln}");
    assert!((gpu_loss.depth as f64 - lz).abs() < 1e-3 * lz && (gpu_loss.normal as f64 - ln).abs() < 1e-3 * ln);

    let total = |m: &crate::field::grid::reference::GridModel| {
        let (a, b) = loss_of(m);
        a + b
    };
    check_grid_grads_against_fd(&format!("{variant:?}"), &model, &table_grad, &mlp_grad, 17, total);
}

#[test]
fn edge_reg_end_to_end_paper_matches_finite_differences() {
    end_to_end(RegVariant::Paper, DepthTarget::Mean, DepthEstimate::Expected);
}

#[test]
fn edge_reg_end_to_end_plane_matches_finite_differences() {
    end_to_end(RegVariant::Paper, DepthTarget::Plane, DepthEstimate::Expected);
}

#[test]
fn edge_reg_end_to_end_official_matches_finite_differences() {
    end_to_end(RegVariant::Official, DepthTarget::Mean, DepthEstimate::Expected);
}

#[test]
fn edge_reg_end_to_end_given_termination_matches_finite_differences() {
    end_to_end(RegVariant::Paper, DepthTarget::Mean, DepthEstimate::GivenTermination);
}

#[test]
fn plane_target_is_zero_on_any_plane_and_mean_target_is_not() {
    // Depths affine in the pixel coordinates (a slanted plane) over an all non-edge patch.
    let rays: Vec<PatchRay> = (0..4)
        .map(|i| PatchRay { e: 1.0, z_scale: 1.0, depth: 2.0 + 0.03 * (i % 2) as f64 - 0.05 * (i / 2) as f64, opacity: 1.0, normal: [0.0; 3] })
        .collect();
    let plane_setting = Setting { variant: RegVariant::Paper, target: DepthTarget::Plane, estimate: DepthEstimate::Expected, tau_depth: 1e-4, tau_normal: 0.0 };
    let ((plane, _), grads) = losses(&rays, &plane_setting);
    assert!(plane == 0.0 && grads.iter().all(|g| g.depth == 0.0), "plane: {plane}");
    let ((mean, _), _) = losses(&rays, &Setting { target: DepthTarget::Mean, ..plane_setting });
    assert!(mean > 0.05, "the paper's target pulls the plane fronto-parallel: {mean}");
    // One edge pixel: three points always lie on a plane, so nothing to pull.
    let mut edge = rays.clone();
    edge[0].depth += 1.0;
    edge[1].e = 0.0;
    assert_eq!(losses(&edge, &plane_setting).0.0, 0.0);
}

#[test]
fn reg_config_defaults_schedule_and_variants() {
    let c = RegConfig::default();
    assert_eq!((c.lambda_depth, c.tau_depth, c.tau_normal, c.lambda_color), (0.1, 1e-4, 0.0, 1.0));
    assert_eq!(c.lambda_normal_for(false), 0.1, "paper, LLFF / synthetic");
    assert_eq!(c.lambda_normal_for(true), 0.001, "paper, DTU");
    let official = RegConfig { variant: RegVariant::Official, ..c.clone() };
    assert_eq!((official.lambda_normal_for(false), official.lambda_normal_for(true)), (0.01, 0.01));
    assert_eq!(RegConfig { lambda_normal: Some(0.5), ..c.clone() }.lambda_normal_for(true), 0.5, "explicit wins");

    // Off before start_step, then a linear ramp over warmup_steps.
    let ramp = RegConfig { start_step: 10, warmup_steps: 4, ..c.clone() };
    assert!(ramp.weights_at(9, false).is_none());
    let w: Vec<f32> = (10..16).map(|s| ramp.weights_at(s, false).unwrap().lambda_depth).collect();
    let want = [0.025, 0.05, 0.075, 0.1, 0.1, 0.1];
    assert!(w.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{w:?}");
    // Switches.
    let depth_only = RegConfig { normal: false, ..c.clone() };
    assert_eq!(depth_only.weights_at(0, false).unwrap().lambda_normal, 0.0);
    let off = RegConfig { normal: false, depth: false, ..c.clone() };
    assert!(off.weights_at(0, false).is_none() && !off.any(false));
    // L_dn is a normal regularizer: on with L_n, off with it.
    let dn = RegConfig { depth: false, lambda_depth_normal: 0.01, ..c.clone() };
    assert_eq!(dn.weights_at(0, false).unwrap().lambda_depth_normal, 0.01);
    let dn_off = RegConfig { normal: false, ..dn.clone() };
    assert!(dn_off.weights_at(0, false).is_none() && !dn_off.any(false), "--no-depth-reg --no-normal-reg: no regularizer");
    let dn_only = RegConfig { lambda_normal: Some(0.0), ..dn };
    assert_eq!(dn_only.weights_at(0, false).map(|w| (w.lambda_normal, w.lambda_depth_normal)), Some((0.0, 0.01)));
    assert!(RegConfig { lambda_depth: -1.0, ..c.clone() }.validate().is_err());
    assert!(RegConfig { tau_normal: f32::NAN, ..c }.validate().is_err());
}
