//! End-to-end training on a committed synthetic scene (lavapipe): test PSNR rises well
//! above the untrained model's, checkpoints round-trip and resume, and a non-finite
//! loss stops training without touching the parameters.

use std::path::PathBuf;

use edgenerf::data::{LoadOptions, Scene};
use edgenerf::gpu::test_gpu;
use edgenerf::train::{Checkpoint, RunConfig, TrainError, Trainer, evaluate};

fn scene_dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("synthetic-scenes/small").join(name)
}

/// A configuration small enough for a few seconds per dozen steps on 2 CPU cores.
fn tiny_config(scene: &str, iters: u64) -> RunConfig {
    let mut c = RunConfig::default();
    c.scene.path = scene_dir(scene);
    for s in [
        "field.n_levels=6",
        "field.log2_hashmap_size=14",
        "field.finest_resolution=256",
        "field.hidden_width=32",
        "sampler.resolution=32",
        "sampler.step_size=0.02",
        "train.rays_per_batch=1024",
        "train.max_samples=65536",
        "optim.schedule.warmup_steps=10",
    ] {
        c.set(s).unwrap();
    }
    c.train.iters = iters;
    c
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

    let mut resumed = Trainer::resume(gpu.clone(), scene, loaded).unwrap();
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

#[test]
fn non_finite_loss_stops_training_without_updating_parameters() {
    let config = tiny_config("creases", 2);
    let gpu = test_gpu(false);
    let mut scene = load(&config);
    for &v in &scene.split.train.clone() {
        scene.views[v].image.data.fill(f32::NAN);
    }
    let mut trainer = Trainer::new(gpu.clone(), scene, config).unwrap();
    let before = trainer.model.field.export(&gpu).unwrap();
    match trainer.step() {
        Err(TrainError::NonFinite { step: 0, what }) => assert!(what.contains("loss"), "{what}"),
        other => panic!("expected a non-finite error, got {other:?}", other = other.map(|s| s.loss)),
    }
    assert_same_params(&trainer.model.field.export(&gpu).unwrap(), &before, "no parameter changed");
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
