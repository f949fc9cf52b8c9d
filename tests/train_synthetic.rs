//! End-to-end training on a committed synthetic scene (lavapipe): test PSNR rises well
//! above the untrained model's, with the hash grid and with the MLP backend,
//! checkpoints round-trip and resume, a non-finite
//! loss stops training without touching the parameters, and the edge-guided
//! regularizers lower what they penalize on 3-view patch batches, as do RegNeRF's depth TV
//! and the edge-guided planarity term.

use std::path::PathBuf;

use edgenerf::data::{LoadOptions, Scene};
use edgenerf::gpu::test_gpu;
use edgenerf::train::{Checkpoint, RunConfig, TrainError, Trainer, evaluate};

fn scene_dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("synthetic-scenes/small").join(name)
}

/// What every engine test's configuration shares: a coarse occupancy grid and
/// marching step for the 128x128 scenes, single pixels, no regularizers (see the
/// edge-guided tests below).
const ENGINE_TEST_SETTINGS: [&str; 5] =
    ["sampler.resolution=32", "sampler.step_size=0.02", "train.batch=pixels", "reg.depth=false", "reg.normal=false"];

/// `base` with [`ENGINE_TEST_SETTINGS`], then `settings`, on committed scene `scene`.
fn configured(mut base: RunConfig, scene: &str, iters: u64, settings: &[&str]) -> RunConfig {
    base.scene.path = scene_dir(scene);
    for s in ENGINE_TEST_SETTINGS.iter().chain(settings) {
        base.set(s).unwrap();
    }
    base.train.iters = iters;
    base
}

/// A configuration small enough for a few seconds per dozen steps on 2 CPU cores.
fn tiny_config(scene: &str, iters: u64) -> RunConfig {
    let grid = [
        "field.n_levels=6",
        "field.log2_hashmap_size=14",
        "field.finest_resolution=256",
        "field.hidden_width=32",
        "train.rays_per_batch=1024",
        "train.max_samples=65536",
        "optim.schedule.warmup_steps=10",
    ];
    configured(RunConfig::default(), scene, iters, &grid)
}

/// Compares named parameter arrays regardless of order, reporting the first difference.
fn assert_same_params(a: &[edgenerf::field::NamedArray], b: &[edgenerf::field::NamedArray], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: array count");
    for x in a {
        let y = b.iter().find(|y| y.name == x.name).unwrap_or_else(|| panic!("{what}: {} missing", x.name));
        assert_eq!(x.shape, y.shape, "{what}: shape of {}", x.name);
        if let Some(i) = (0..x.data.len()).find(|&i| x.data[i].to_bits() != y.data[i].to_bits()) {
            panic!("{what}: {}[{i}] = {} vs {}", x.name, x.data[i], y.data[i]);
        }
    }
}

fn load(config: &RunConfig) -> Scene {
    // Test on a subset of test views to keep evaluation short.
    let mut scene = Scene::load(&config.scene.path, &LoadOptions::default()).unwrap();
    scene.split.test.truncate(2);
    scene
}

#[test]
fn training_raises_test_psnr_well_above_untrained() {
    let config = tiny_config("smooth", 150);
    let gpu = test_gpu(false);
    let mut trainer = Trainer::new(gpu, load(&config), config).unwrap();
    let (before, _) = trainer.evaluate().unwrap();
    let mut last = None;
    for _ in 0..trainer.config().train.iters {
        last = Some(trainer.step().unwrap());
    }
    let stats = last.unwrap();
    let (after, renders) = trainer.evaluate().unwrap();
    // Geometry is compared with the ground truth of the synthetic scene.
    let depth_err = after.mean_depth_abs_error.expect("smooth has GT depth");
    let normal_err = after.mean_normal_angle_deg.expect("smooth has GT normals");
    eprintln!("mean depth error {depth_err:.3}, mean normal angle {normal_err:.1} deg");
    assert!(depth_err < before.mean_depth_abs_error.unwrap(), "depth improves with training");
    eprintln!(
        "untrained {:.2} dB -> trained {:.2} dB after {} steps ({:.1} samples/ray, last batch PSNR {:.2})",
        before.mean_psnr, after.mean_psnr, stats.step + 1, stats.samples_per_ray, stats.psnr
    );
    assert!(after.mean_psnr > before.mean_psnr + 6.0, "{:.2} -> {:.2}", before.mean_psnr, after.mean_psnr);
    assert!(after.mean_psnr > 18.0, "trained PSNR {:.2}", after.mean_psnr);
    // The occupancy grid has started skipping space: fewer samples than the uniform
    // march along the (AABB-clipped) rays would take.
    assert!(stats.samples_per_ray > 0.0);
    let r = &renders[0].1;
    assert!(r.opacity.iter().all(|a| (0.0..=1.0 + 1e-4).contains(a)));
    assert!(r.depth.iter().all(|d| d.is_finite()));
}

/// The visibility pass with `min_alpha = 0` and the renderer's own termination
/// threshold keeps exactly the samples the renderer composites, so a run with it
/// trains as one without it (the same losses, to float noise) on fewer field samples;
/// its renders match too. A threshold of 0.3 makes rays terminate within a few dozen
/// steps; with `min_alpha` the pass also drops faint samples.
#[test]
fn the_exact_visibility_pass_trains_as_without_it_on_fewer_samples() {
    let run = |settings: &[&str]| {
        let mut config = tiny_config("smooth", 40);
        for s in ["render.transmittance_threshold=0.3", "sampler.visibility.min_transmittance=0.3"].iter().chain(settings) {
            config.set(s).unwrap();
        }
        let mut trainer = Trainer::new(test_gpu(false), load(&config), config).unwrap();
        let stats: Vec<_> = (0..40).map(|_| trainer.step().unwrap()).collect();
        let (eval, _) = trainer.evaluate().unwrap();
        (stats, eval)
    };
    let off = ["sampler.visibility.train=false", "sampler.visibility.render=false"];
    let (plain, plain_eval) = run(&off);
    let (exact, exact_eval) = run(&["sampler.visibility.train=true", "sampler.visibility.render=true"]);
    for (a, b) in plain.iter().zip(&exact) {
        assert_eq!(a.marched_samples_per_ray, a.samples_per_ray, "without the pass the field runs on every marched sample");
        // Float-atomic gradient sums land in another order each run, so the
        // trajectories drift apart slowly; a step that dropped a visible sample or kept
        // a batch's cut rays would differ at once.
        let close = (a.loss - b.loss).abs() <= 2e-3 * a.loss.abs() + 1e-6;
        assert!(close || a.step > 10, "step {}: loss {} without the pass, {} with it", a.step, a.loss, b.loss);
        assert!(b.samples_per_ray <= b.marched_samples_per_ray);
    }
    let last = exact.last().unwrap();
    assert!(
        last.samples_per_ray < 0.9 * last.marched_samples_per_ray,
        "the pass dropped samples past termination: {} of {} per ray",
        last.samples_per_ray,
        last.marched_samples_per_ray
    );
    assert!((plain_eval.mean_psnr - exact_eval.mean_psnr).abs() < 0.1, "{} vs {}", plain_eval.mean_psnr, exact_eval.mean_psnr);
    assert!(exact_eval.mean_samples_per_ray < plain_eval.mean_samples_per_ray);
    // Faint samples dropped too: fewer still.
    let (faint, _) = run(&["sampler.visibility.train=true", "sampler.visibility.min_alpha=0.01", "sampler.visibility.min_alpha_start_step=10"]);
    assert!(faint.last().unwrap().samples_per_ray < last.samples_per_ray, "min_alpha drops faint samples");
}

#[test]
fn the_coarse_start_marches_coarser_until_the_fine_levels_switch_on() {
    // Levels 1-2 of 6 at step 0, all 6 from step 8: while only the coarse levels are
    // on, a step marches one sample per cell of the finest active level (0.041 along
    // `smooth`'s shortest axis, 1.1 / 26.9: about 2x the configured 0.02), then the
    // configured step again.
    let run = |per_cell: &str| {
        let mut config = tiny_config("smooth", 14);
        for s in ["train.level_anneal.start_levels=2", "train.level_anneal.steps=8", per_cell] {
            config.set(s).unwrap();
        }
        let mut trainer = Trainer::new(test_gpu(false), load(&config), config).unwrap();
        (0..14).map(|_| trainer.step().unwrap()).collect::<Vec<_>>()
    };
    let fine = run("sampler.anneal_samples_per_cell=0");
    let coarse = run("sampler.anneal_samples_per_cell=1");
    // Step 0 marches the same untrained grid in both runs.
    let (a, b) = (fine[0].samples_per_ray, coarse[0].samples_per_ray);
    assert!(b < 0.5 * a && b > 0.0, "step 0: {b} samples per ray coarse, {a} at the configured step");
    let last = (fine.last().unwrap().samples_per_ray, coarse.last().unwrap().samples_per_ray);
    // No grid update between steps 1 and 15: the same grid, rays and jitter.
    assert!((last.1 - last.0).abs() <= 1e-3 * last.0, "every level on: the configured step again ({} against {})", last.1, last.0);
    assert!(coarse.iter().all(|s| s.loss.is_finite()));
}

/// PSNR of test view `view` rendered at `size x size` against its image area-averaged
/// to that size: the test PSNR at a fraction of the pixels, cheap enough to take before
/// and after training a slow backend on a CPU.
fn downscaled_test_psnr(trainer: &mut Trainer, view: usize, size: u32) -> f64 {
    let v = &trainer.scene.views[view];
    let cam = v.camera.resized(size, size);
    let target = edgenerf::data::resample::resize_area(&v.image.data, 3, (v.image.width, v.image.height), (size, size));
    let gpu = trainer.gpu.clone();
    let r = trainer.model.render_camera(&gpu, &trainer.scene, &cam).unwrap();
    let se: f64 = r.rgb.iter().flatten().zip(&target).map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2)).sum();
    -10.0 * (se / target.len() as f64).log10()
}

/// The MLP backend (a small mip-NeRF network with RegNeRF's optimizer at a constant
/// learning rate) trains end to end through the same sampler, renderer and trainer as
/// the grid: test PSNR rises well above the untrained network's. The project compares
/// the two backends, so neither may silently stop learning. (The test 65b4a10 removed,
/// made cheaper: 60 steps instead of 100 at a learning rate that does not decay, and
/// the test view scored at 32x32 instead of 128x128, whose two renders through the MLP
/// took most of its time on 2 CPU cores.)
#[test]
fn mlp_backend_raises_test_psnr_above_untrained() {
    use edgenerf::train::Backend;
    const ITERS: u64 = 60;
    let mlp = [
        "mlp.depth=3",
        "mlp.width=32",
        "mlp.skip_layer=2",
        "mlp.color_width=16",
        "mlp.pos_max_deg=8",
        "train.rays_per_batch=256",
        "train.max_samples=16384",
        "optim.schedule.lr_init=0.005",
        "optim.schedule.lr_final=0.005",
        "optim.schedule.lr_delay_steps=10",
    ];
    let config = configured(RunConfig::defaults_for(Backend::Mlp), "smooth", ITERS, &mlp);
    let scene = load(&config);
    let view = scene.split.test[0];
    let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
    assert_eq!(trainer.model.field.kind(), "mlp");
    let before = downscaled_test_psnr(&mut trainer, view, 32);
    let stats = (0..ITERS).map(|_| trainer.step().unwrap()).last().unwrap();
    let after = downscaled_test_psnr(&mut trainer, view, 32);
    eprintln!("mlp: untrained {before:.2} dB -> trained {after:.2} dB after {ITERS} steps ({:.1} samples/ray)", stats.samples_per_ray);
    // Measured on lavapipe: 15.43 -> 20.20 dB (40 steps: 17.95; with the learning rate
    // decaying over the 60 steps: 17.00).
    assert!(after > before + 2.5, "{before:.2} -> {after:.2}");
}

#[test]
fn checkpoints_round_trip_and_resume_exactly() {
    let config = tiny_config("creases", 6);
    let gpu = test_gpu(false);
    let scene = load(&config);
    let mut trainer = Trainer::new(gpu.clone(), scene.clone(), config).unwrap();
    for _ in 0..3 {
        trainer.step().unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.safetensors");
    trainer.checkpoint().unwrap().save(&path).unwrap();
    let loaded = Checkpoint::load(&path).unwrap();
    assert_eq!(loaded.step, 3);
    assert_eq!(&loaded.config, trainer.config());
    let original = trainer.model.field.export(&gpu).unwrap();
    assert_same_params(&loaded.field, &original, "parameters survive the file bit for bit");

    let mut resumed = Trainer::resume(gpu.clone(), scene, loaded, None).unwrap();
    assert_eq!(resumed.step_count(), 3);
    assert_same_params(&resumed.model.field.export(&gpu).unwrap(), &original, "resumed parameters");
    let a = trainer.step().unwrap();
    let b = resumed.step().unwrap();
    assert_eq!(a.step, b.step);
    assert!((a.loss - b.loss).abs() <= 1e-3 * a.loss.abs().max(1e-6), "{} vs {}", a.loss, b.loss);

    // A file that is not a checkpoint is refused with its path.
    std::fs::write(dir.path().join("junk.safetensors"), b"not a checkpoint").unwrap();
    let err = Checkpoint::load(&dir.path().join("junk.safetensors")).err().unwrap().to_string();
    assert!(err.contains("junk.safetensors"), "{err}");
}

/// A non-finite loss stops training with the parameters and the optimizer (moments and
/// step counter) exactly as before the step, although the step runs its backward and
/// Adam before the host reads the loss: the loss guards Adam on the GPU, with Adam's own
/// skip of non-finite gradients on or off.
#[test]
fn non_finite_loss_stops_training_without_updating_parameters() {
    for skip_nonfinite in [true, false] {
        let mut config = tiny_config("creases", 3);
        config.optim.adam.skip_nonfinite = skip_nonfinite;
        let gpu = test_gpu(false);
        let scene = load(&config);
        let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
        trainer.step().unwrap();
        for &v in &trainer.scene.split.train.clone() {
            trainer.scene.views[v].image.data.fill(f32::NAN);
        }
        let before = trainer.checkpoint().unwrap();
        match trainer.step() {
            Err(TrainError::NonFinite { step: 1, what }) => assert!(what.contains("loss"), "{what}"),
            other => panic!("expected a non-finite error, got {other:?}", other = other.map(|s| s.loss)),
        }
        let after = trainer.checkpoint().unwrap();
        assert_same_params(&after.field, &before.field, "no parameter changed");
        assert_eq!(after.optimizer.len(), before.optimizer.len());
        for ((name, a), (_, b)) in after.optimizer.iter().zip(&before.optimizer) {
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "skip_nonfinite {skip_nonfinite}: {name} changed");
        }
    }
}

/// A training step is one submission to the GPU, on pixel batches and on 3-view patch
/// batches with the edge-guided terms and the priors on. Steps read back one step late
/// (`step_pipelined`, as `train_run` takes them) are the steps of `step`: the same
/// figures (step 0 bit for bit; later ones up to the order of float atomic adds), and
/// a non-finite loss is reported one call late with parameters and optimizer as they
/// were, both steps it hit skipped. Step 0 updates the occupancy grid (every 16 steps),
/// which is one submission of its own, read back before the step.
#[test]
fn pipelined_steps_submit_once_and_match_plain_steps() {
    let patches = ["train.batch=patches", "reg.depth=true", "reg.normal=true", "scene.views=3", "reg.start_step=0"];
    let every_term = [&patches[..], &["reg.warmup_steps=0", "priors.distortion=0.01", "priors.occlusion=0.01"]].concat();
    for settings in [&[][..], &every_term[..]] {
        let mut config = tiny_config("creases", 6);
        for s in settings {
            config.set(s).unwrap();
        }
        let views = config.scene.views;
        let scene = Scene::load(&config.scene.path, &LoadOptions { views, ..Default::default() }).unwrap();
        let mut plain = Trainer::new(test_gpu(false), scene.clone(), config.clone()).unwrap();
        let expected: Vec<_> = (0..6).map(|_| plain.step().unwrap()).collect();

        // A context of its own: the submission counter is shared by a context's clones,
        // and other tests run in parallel on the shared test GPU.
        let gpu = edgenerf::gpu::Gpu::new(&edgenerf::gpu::GpuOptions::default()).unwrap();
        let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
        let mut got = Vec::new();
        for i in 0..6 {
            let before = gpu.submissions();
            got.extend(trainer.step_pipelined(i == 5).unwrap());
            // Step 0 also updates the occupancy grid: its query, densities and update
            // are one more submission (waited for: the BVH is rebuilt on the host).
            let wanted = if i == 0 { 2 } else { 1 };
            assert_eq!(gpu.submissions() - before, wanted, "{settings:?}: submissions in step {i}");
            assert_eq!(got.len(), if i == 5 { 6 } else { i }, "{settings:?}: steps read back after call {i}");
        }
        assert_eq!(expected[0].loss.to_bits(), got[0].loss.to_bits(), "{settings:?}: step 0");
        for (e, g) in expected.iter().zip(&got) {
            assert_eq!(e.step, g.step);
            let close = |a: f32, b: f32, rel: f32| (a - b).abs() <= rel * a.abs().max(1e-6);
            // The gradient norm sums squares of gradients whose float-atomic adds land in
            // another order each run, and with the second-order normal terms on that
            // drifts faster than the loss: 1.24e-3 apart at step 5 in one CI run of this
            // test. Consecutive steps differ by 5-10 % (pixel batches: 0.0098, 0.0092,
            // 0.0084, 0.0079, 0.0087, 0.0082) and by 20 % or more with every term, so a
            // step taken with another step's parameters or batch still fails.
            assert!(
                close(e.loss, g.loss, 1e-3) && close(e.grad_norm, g.grad_norm, 1e-2),
                "{settings:?}: step {} {e:?} vs {g:?}",
                e.step
            );
        }

        for &v in &trainer.scene.split.train.clone() {
            trainer.scene.views[v].image.data.fill(f32::NAN);
        }
        let before = trainer.checkpoint().unwrap();
        assert!(trainer.step_pipelined(false).unwrap().is_empty(), "step 6 is in flight");
        match trainer.step_pipelined(false) {
            Err(TrainError::NonFinite { step: 6, what }) => assert!(what.contains("loss"), "{what}"),
            other => panic!("expected step 6 to fail, got {other:?}"),
        }
        assert!(matches!(trainer.finish_pending(), Err(TrainError::NonFinite { step: 7, .. })), "step 7 fails too");
        let after = trainer.checkpoint().unwrap();
        assert_same_params(&after.field, &before.field, "no parameter changed");
        for ((name, a), (_, b)) in after.optimizer.iter().zip(&before.optimizer) {
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "{settings:?}: {name} changed");
        }
    }
}

/// A run that stops early (an observer's stop request, a time limit) with a step in
/// flight finishes that step too: the log has a row for every step the checkpoint
/// holds, in order, and the summary names the step it ended at. A finished run's last
/// checkpoint holds `train.iters` steps and the log as many rows.
#[test]
fn a_run_that_stops_early_logs_every_step_its_checkpoint_holds() {
    struct StopAfter(u64);
    impl edgenerf::train::RunObserver for StopAfter {
        fn step(&mut self, _: &Trainer, stats: &edgenerf::train::StepStats, _: f64) {
            self.0 = self.0.saturating_sub(1);
            assert!(stats.loss.is_finite());
        }
        fn stop_requested(&mut self) -> bool {
            self.0 == 0
        }
    }
    let cases: [(&str, Option<f64>, u64, edgenerf::train::RunEnd); 3] = [
        ("stop request", None, 2, edgenerf::train::RunEnd::Stopped),
        ("time limit", Some(1e-6), u64::MAX, edgenerf::train::RunEnd::TimeLimit),
        ("finished", None, u64::MAX, edgenerf::train::RunEnd::Finished),
    ];
    for (what, max_seconds, stop_after, end) in cases {
        let mut config = tiny_config("thin", 5);
        config.train.max_seconds = max_seconds;
        config.train.checkpoint_every = 2;
        let scene = load(&config);
        let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let summary = edgenerf::train::train_run(&mut trainer, dir.path(), &mut StopAfter(stop_after)).unwrap();
        assert_eq!(summary.end, end, "{what}");
        let log = std::fs::read_to_string(dir.path().join("log.csv")).unwrap();
        let steps: Vec<u64> = log.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect();
        let saved = Checkpoint::load(&summary.checkpoint).unwrap();
        assert_eq!(saved.step, summary.last_step, "{what}");
        assert_eq!(steps, (0..saved.step).collect::<Vec<_>>(), "{what}: log rows against the checkpoint's {} steps", saved.step);
        if end == edgenerf::train::RunEnd::Finished {
            assert_eq!(saved.step, 5);
        } else {
            assert!(saved.step < 5, "{what}: stopped early at {}", saved.step);
        }
    }
}

#[test]
fn evaluation_renders_every_test_view() {
    let config = tiny_config("thin", 1);
    let gpu = test_gpu(false);
    let scene = load(&config);
    let n_test = scene.split.test.len();
    let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
    let (eval, renders) = evaluate(&gpu, &mut trainer.model, &trainer.scene).unwrap();
    assert_eq!(eval.per_view.len(), n_test);
    assert_eq!(renders.len(), n_test);
    let (w, h) = trainer.scene.image_size();
    assert_eq!(renders[0].1.rgb.len(), (w * h) as usize);
}

/// Rendering in segments (`sampler.render_segment`) gives the one-pass image on fewer
/// samples: a field made opaque by its density's bias (4: about 9 samples to opacity)
/// stops its rays in the first segment; at a bias of 3 (about 23) the first segment
/// turns no ray opaque, so the rest of every ray goes in one more segment, restarted
/// where the first stopped. Both renders of a test view agree up to the renderer's
/// threshold either way.
#[test]
fn segmented_rendering_matches_one_pass_on_fewer_samples() {
    let gpu = test_gpu(false);
    let render = |bias: f32, segment: u32| {
        let mut config = tiny_config("creases", 1);
        config.set(&format!("field.density_bias={bias}")).unwrap();
        config.set(&format!("sampler.render_segment={segment}")).unwrap();
        let scene = load(&config);
        let view = scene.split.test[0];
        let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
        trainer.model.render_view(&gpu, &trainer.scene, view).unwrap()
    };
    for bias in [4.0, 3.0] {
        let (one, seg) = (render(bias, 0), render(bias, 16));
        eprintln!("bias {bias}: one pass {} samples, in segments {}", one.samples, seg.samples);
        assert!(one.opacity.iter().filter(|&&a| a > 0.999).count() * 2 > one.opacity.len(), "the test needs opaque rays");
        if bias == 4.0 {
            assert!(seg.samples * 2 < one.samples, "segments shade {} samples, one pass {}", seg.samples, one.samples);
        } else {
            assert!(seg.samples <= one.samples && seg.samples * 10 > one.samples * 9, "{} vs {}", seg.samples, one.samples);
        }
        let far = one.depth.iter().cloned().fold(0.0f32, f32::max).max(1.0);
        let close = |a: f32, b: f32, tol: f32| (a - b).abs() <= tol;
        let mut normal_diff = Vec::with_capacity(one.normal.len());
        for i in 0..one.rgb.len() {
            let ok = (0..3).all(|c| close(one.rgb[i][c], seg.rgb[i][c], 1e-3))
                && close(one.opacity[i], seg.opacity[i], 1e-3)
                && close(one.depth[i], seg.depth[i], 1e-3 * far);
            assert!(ok, "bias {bias}, pixel {i}: one pass {:?} {} {}, segments {:?} {} {}", one.rgb[i], one.opacity[i], one.depth[i], seg.rgb[i], seg.opacity[i], seg.depth[i]);
            normal_diff.push((0..3).map(|c| (one.normal[i][c] - seg.normal[i][c]).abs()).fold(0.0f32, f32::max));
        }
        // A segment restarts at its predecessor's last sample's far end, which rounds
        // within an ulp of where one pass's grid puts it; the density is continuous
        // there, but its gradient (the normal) jumps across the hash grid's cell faces,
        // so a sample that lands on one may flip its normal.
        normal_diff.sort_by(f32::total_cmp);
        let (p99, max) = (normal_diff[normal_diff.len() * 99 / 100], *normal_diff.last().unwrap());
        eprintln!("bias {bias}: normal difference 99th percentile {p99:.2e}, largest {max:.2e}");
        assert!(p99 < 1e-3 && max < 0.05, "bias {bias}, normals: 99th percentile {p99}, largest {max}");
    }
}

/// The finer grid of renders (`sampler.render_resolution`): on a briefly trained
/// `creases` (training grid 32^3) a test view rendered through a 128^3 grid built from
/// the field marches fewer samples for nearly the same image (it drops only space whose
/// probed density is under the training grid's threshold), leaves the training grid as
/// it was, and is dropped by the next training step (the field it was built from changed).
#[test]
fn render_grid_marches_fewer_samples_for_nearly_the_same_image() {
    let gpu = test_gpu(false);
    let mut config = tiny_config("creases", 64);
    config.set("sampler.resolution=32").unwrap();
    let scene = load(&config);
    let view = scene.split.test[0];
    let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
    for _ in 0..64 {
        trainer.step().unwrap();
    }
    let training_grid = trainer.model.occupied_fraction();
    let coarse = trainer.model.render_view(&gpu, &trainer.scene, view).unwrap();
    assert_eq!(trainer.model.render_grid_occupied_fraction(), None, "no render grid without the option");
    trainer.model.config.sampler.render_resolution = 128;
    let fine = trainer.model.render_view(&gpu, &trainer.scene, view).unwrap();
    let render_grid = trainer.model.render_grid_occupied_fraction().expect("built by the render");
    let mse = coarse.rgb.iter().zip(&fine.rgb).map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f32>() / 3.0).sum::<f32>()
        / coarse.rgb.len() as f32;
    let psnr = -10.0 * mse.max(1e-12).log10();
    let opacity_diff = coarse.opacity.iter().zip(&fine.opacity).map(|(a, b)| (a - b).abs()).sum::<f32>() / coarse.opacity.len() as f32;
    eprintln!(
        "training grid {training_grid:.3} occupied, render grid {render_grid:.3}; samples {} -> {}; renders agree to {psnr:.1} dB, opacity {opacity_diff:.4}",
        coarse.samples, fine.samples
    );
    assert!(render_grid < training_grid, "the finer grid is emptier: {render_grid} vs {training_grid}");
    assert!(fine.samples * 10 < coarse.samples * 9, "{} samples through the finer grid, {} through training's", fine.samples, coarse.samples);
    assert!(psnr > 32.0 && opacity_diff < 0.02, "the renders differ: {psnr} dB, opacity {opacity_diff}");
    assert_eq!(trainer.model.occupied_fraction(), training_grid, "the training grid is untouched");
    trainer.step().unwrap();
    assert_eq!(trainer.model.render_grid_occupied_fraction(), None, "a training step drops the render grid");
}

/// A 3-view patch run on `creases`: `lambda1 = lambda_color`, `lambda2 = lambda3 =
/// lambda`. Returns the `(L_z, L_n)` of each of `iters` steps, all on one fixed batch
/// when `fixed` (else the trainer's own random batches).
fn regularized_run(lambda_color: f32, lambda: [f32; 2], edges: &str, iters: u64, fixed: bool) -> Vec<(f32, f32)> {
    let mut config = tiny_config("creases", iters);
    for s in ["train.batch=patches", "reg.depth=true", "reg.normal=true", "scene.views=3", "optim.schedule.warmup_steps=1"] {
        config.set(s).unwrap();
    }
    config.set(&format!("edges.source={edges}")).unwrap();
    config.reg.lambda_depth = lambda[0];
    config.reg.lambda_normal = Some(lambda[1]);
    config.reg.lambda_color = lambda_color;
    let scene = Scene::load(&config.scene.path, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
    let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
    let first = trainer.draw_batch().unwrap();
    assert_eq!(first.reg.len(), first.rays.len(), "patch batches carry (e, z_scale) per ray");
    (0..iters)
        .map(|_| {
            let batch = if fixed { first.clone() } else { trainer.draw_batch().unwrap() };
            let s = trainer.step_on(batch).unwrap();
            assert!(s.loss_depth.is_finite() && s.loss_normal.is_finite() && s.loss_color.is_finite());
            let want = lambda_color * s.loss_color + lambda[0] * s.loss_depth + lambda[1] * s.loss_normal;
            assert!((s.loss - want).abs() <= 1e-4 * s.loss.max(1e-3));
            (s.loss_depth, s.loss_normal)
        })
        .collect()
}

#[test]
fn edge_regularizers_lower_their_losses_on_three_views() {
    let depth = regularized_run(0.0, [1.0, 1e-6], "canny", 25, true);
    let normal = regularized_run(0.0, [1e-6, 1.0], "canny", 25, true);
    let monitor = regularized_run(1.0, [1e-6, 1e-6], "canny", 25, true);
    let tail = |v: &[(f32, f32)]| {
        let t = &v[v.len() - 5..];
        (t.iter().map(|x| x.0).sum::<f32>() / 5.0, t.iter().map(|x| x.1).sum::<f32>() / 5.0)
    };
    let (start, mon) = (monitor[0], tail(&monitor));
    let end = (tail(&depth).0, tail(&normal).1);
    eprintln!("L_z {:.4} -> {:.4} (monitor {:.4}), L_n {:.4} -> {:.4} (monitor {:.4})", start.0, end.0, mon.0, start.1, end.1, mon.1);
    assert!(start.0 > 0.0 && start.1 > 0.0, "the losses are measured");
    assert!(end.0 < 0.4 * start.0 && end.0 < 0.5 * mon.0, "L_z does not descend");
    assert!(end.1 < 0.8 * start.1 && end.1 < 0.5 * mon.1, "L_n does not descend");
    // The masks matter: without edges (global smoothing) the same batch sees a larger
    // L_z, since edge pixels (the largest depth differences) are no longer excluded.
    let global = regularized_run(1.0, [1e-6; 2], "none", 1, false);
    let guided = regularized_run(1.0, [1e-6; 2], "canny", 1, false);
    assert!(global[0].0 > guided[0].0, "edge pixels are excluded from L_z: {guided:?} vs {global:?}");
}

#[test]
fn a_resumed_model_renders_like_the_trained_one() {
    // The checkpoint carries the occupancy grid, so a resumed model skips exactly the
    // cells training skipped: the same samples and the same image. A checkpoint without
    // it (older builds) gets the grid rebuilt from the field, every cell re-queried
    // (past the warm-up, regular updates refresh only part of the grid).
    let mut config = tiny_config("smooth", 12);
    config.set("sampler.warmup_steps=2").unwrap();
    // Twelve steps leave the field's density near its initial 1 almost everywhere: a
    // threshold of density 1 (0.02 opacity per 0.02 step) splits the grid roughly in two.
    config.set("sampler.decay=0.5").unwrap();
    config.set("sampler.update_interval=2").unwrap();
    config.set("sampler.threshold=0.02").unwrap();
    let gpu = test_gpu(false);
    let mut scene = load(&config);
    scene.split.test.truncate(1);
    let mut trainer = Trainer::new(gpu.clone(), scene.clone(), config).unwrap();
    for _ in 0..12 {
        trainer.step().unwrap();
    }
    let (trained, _) = trainer.evaluate().unwrap();
    let ckpt = trainer.checkpoint().unwrap();
    let saved = ckpt.occupancy.clone().expect("an updated grid is saved");
    assert_eq!(saved.len(), 32usize.pow(3));
    assert!(trainer.model.occupancy.occupied_cells() < saved.len() as u32, "the test needs a grid that skips something");

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.safetensors");
    ckpt.save(&path).unwrap();
    let mut resumed = Trainer::resume(gpu.clone(), scene.clone(), Checkpoint::load(&path).unwrap(), None).unwrap();
    assert_eq!(resumed.model.occupancy.occupancy_bits(), trainer.model.occupancy.occupancy_bits(), "restored bitfield");
    let (again, _) = resumed.evaluate().unwrap();
    eprintln!("trained {:.3} dB at {:.2} samples/ray, resumed {:.3} dB at {:.2}", trained.mean_psnr, trained.mean_samples_per_ray, again.mean_psnr, again.mean_samples_per_ray);
    assert_eq!(again.mean_samples_per_ray, trained.mean_samples_per_ray);
    assert!((trained.mean_psnr - again.mean_psnr).abs() < 1e-3, "{} vs {}", trained.mean_psnr, again.mean_psnr);

    let mut older = Checkpoint::load(&path).unwrap();
    older.occupancy = None;
    let mut rebuilt = Trainer::resume(gpu, scene, older, None).unwrap();
    let (again, _) = rebuilt.evaluate().unwrap();
    eprintln!("rebuilt grid: {:.3} dB, occupied {} (trained {})", again.mean_psnr, rebuilt.model.occupancy.occupied_cells(), trainer.model.occupancy.occupied_cells());
    assert!((trained.mean_psnr - again.mean_psnr).abs() < 0.2, "{} vs {}", trained.mean_psnr, again.mean_psnr);
}

/// RegNeRF's depth TV alone (`lambda_color` on the photometric term, a constant TV
/// weight `tv`), every step on one fixed batch (photometric and random-pose patches):
/// the TV of those patches re-rendered after the first and the last of `iters` steps
/// (the `f64` reference on the model's renders), and the logged per-step TV.
fn depth_tv_run(lambda_color: f32, tv: f32, iters: u64) -> (f64, f64, Vec<f32>) {
    use edgenerf::loss::depth_tv::reference::{TvRay, loss, weights};
    let mut config = tiny_config("creases", iters);
    for s in ["train.batch=patches", "scene.views=3", "optim.schedule.warmup_steps=1", "regnerf.depth_tv=true", "regnerf.patches_per_step=16"] {
        config.set(s).unwrap();
    }
    config.regnerf.tv_weight_start = None;
    config.regnerf.tv_weight = tv;
    config.reg.lambda_color = lambda_color;
    let scene = Scene::load(&config.scene.path, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
    let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
    let gpu = trainer.gpu.clone();
    let first = trainer.draw_batch().unwrap();
    assert_eq!((first.tv_rays.len(), first.tv_z_scale.len()), (16 * 64, 16 * 64), "the batch carries its random-pose patches");
    let (patches, z_scale) = (first.tv_rays.clone(), first.tv_z_scale.clone());
    let patch_tv = |t: &mut Trainer| {
        let (outs, _) = t.model.render_rays(&gpu, &patches, false).unwrap();
        let rays: Vec<TvRay> = outs
            .iter()
            .zip(&patches)
            .zip(&z_scale)
            .map(|((o, r), &z)| TvRay { depth: o.depth as f64, opacity: o.opacity as f64, z_scale: z as f64, t_min: r.t_min as f64, t_max: r.t_max as f64 })
            .collect();
        loss(&rays, 8, &weights(&rays, 0.0)).0
    };
    let mut logged = Vec::new();
    let mut start = 0.0;
    for i in 0..iters {
        let s = trainer.step_on(first.clone()).unwrap();
        assert!(s.loss_tv.is_finite() && s.lambda_tv == tv);
        assert!((s.loss - (lambda_color * s.loss_color + tv * s.loss_tv)).abs() <= 1e-4 * s.loss.max(1e-3));
        logged.push(s.loss_tv);
        if i == 0 {
            start = patch_tv(&mut trainer);
        }
    }
    (start, patch_tv(&mut trainer), logged)
}

#[test]
fn depth_tv_alone_lowers_it_on_a_fixed_batch() {
    let (start, end, logged) = depth_tv_run(0.0, 1.0, 25);
    let (m_start, m_end, _) = depth_tv_run(1.0, 1e-6, 25);
    eprintln!("depth TV {start:.5} -> {end:.5} (photometric only: {m_start:.5} -> {m_end:.5}); logged {logged:?}");
    assert!(start > 0.0 && logged[0] > 0.0, "the term is measured");
    // The patches' TV is mostly the object's silhouette, which 25 small steps only
    // soften: a steady few per cent, against a slight rise without the term.
    assert!(end < 0.96 * start, "the depth TV does not descend");
    assert!(end < 0.96 * m_end, "the descent comes from the TV term");
    assert!(logged[logged.len() - 1] < 0.96 * logged[0], "the logged term falls too");
    let falls = logged.windows(2).filter(|w| w[1] <= w[0]).count();
    assert!(falls >= 20, "the logged term falls steadily: {falls} of 24 steps");
}

/// The edge-guided planarity term alone (`lambda_color` on the photometric term,
/// `lambda` on `L_pl`, no other regularizer), every step on one fixed batch of
/// 3-view patches and triplets: the logged `L_pl` of each of `iters` steps.
fn planarity_run(lambda_color: f32, lambda: f32, iters: u64) -> Vec<f32> {
    let mut config = tiny_config("creases", iters);
    for s in ["train.batch=patches", "scene.views=3", "optim.schedule.warmup_steps=1", "reg.depth=true", "reg.lambda_depth=0", "reg.planarity_triplets=128"] {
        config.set(s).unwrap();
    }
    config.reg.lambda_planarity = lambda;
    config.reg.lambda_color = lambda_color;
    let scene = Scene::load(&config.scene.path, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
    let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
    let first = trainer.draw_batch().unwrap();
    assert_eq!((first.triplets.len(), first.triplets.pixel.len()), (128, 384), "the batch carries its triplets");
    assert!(first.triplets.pixel.iter().filter(|p| p[0] == 1.0).count() > 300, "most triplets are placed");
    (0..iters)
        .map(|_| {
            let s = trainer.step_on(first.clone()).unwrap();
            assert!(s.loss_planarity.is_finite() && s.lambda_planarity == lambda);
            assert!((s.loss - (lambda_color * s.loss_color + lambda * s.loss_planarity)).abs() <= 1e-4 * s.loss.max(1e-3));
            s.loss_planarity
        })
        .collect()
}

#[test]
fn planarity_alone_lowers_it_on_a_fixed_batch() {
    let alone = planarity_run(0.0, 1.0, 25);
    let monitor = planarity_run(1.0, 1e-6, 25);
    let tail = |v: &[f32]| v[v.len() - 5..].iter().sum::<f32>() / 5.0;
    eprintln!("L_pl {:.5} -> {:.5} (photometric only: {:.5} -> {:.5})", alone[0], tail(&alone), monitor[0], tail(&monitor));
    assert!(alone[0] > 0.0, "the term is measured");
    assert!(tail(&alone) < 0.7 * alone[0], "L_pl does not descend: {alone:?}");
    assert!(tail(&alone) < 0.7 * tail(&monitor), "the descent comes from the term: {monitor:?}");
}

/// The cross-view reprojection term alone (`lambda_color` on the photometric term,
/// `lambda` on `L_rp`), every step on one fixed batch of 3-view patches: the logged
/// `L_rp` of each of `iters` steps.
fn reprojection_run(lambda_color: f32, lambda: f32, iters: u64) -> Vec<f32> {
    let mut config = tiny_config("creases", iters);
    for s in ["train.batch=patches", "scene.views=3", "optim.schedule.warmup_steps=1", "reg.depth=true", "reg.lambda_depth=0"] {
        config.set(s).unwrap();
    }
    config.reg.lambda_reprojection = lambda;
    config.reg.lambda_color = lambda_color;
    let scene = Scene::load(&config.scene.path, &LoadOptions { views: Some(3), ..Default::default() }).unwrap();
    let mut trainer = Trainer::new(test_gpu(false), scene, config).unwrap();
    let first = trainer.draw_batch().unwrap();
    (0..iters)
        .map(|_| {
            let s = trainer.step_on(first.clone()).unwrap();
            assert!(s.loss_reprojection.is_finite() && s.lambda_reprojection == lambda);
            assert!((s.loss - (lambda_color * s.loss_color + lambda * s.loss_reprojection)).abs() <= 1e-4 * s.loss.max(1e-3));
            s.loss_reprojection
        })
        .collect()
}

#[test]
fn reprojection_alone_lowers_it_on_a_fixed_batch() {
    let alone = reprojection_run(0.0, 1.0, 25);
    let monitor = reprojection_run(1.0, 1e-6, 25);
    let tail = |v: &[f32]| v[v.len() - 5..].iter().sum::<f32>() / 5.0;
    eprintln!("L_rp {:.5} -> {:.5} (photometric only: {:.5} -> {:.5})", alone[0], tail(&alone), monitor[0], tail(&monitor));
    assert!(alone[0] > 0.0, "the term is measured");
    assert!(tail(&alone) < 0.8 * alone[0], "L_rp does not descend: {alone:?}");
    assert!(tail(&alone) < 0.8 * tail(&monitor), "the descent comes from the term: {monitor:?}");
}
