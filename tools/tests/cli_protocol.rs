//! One evaluation protocol: on a DTU-layout scan with object masks, the end-of-run
//! evaluation of `train`, `render --split test` and `eval` of the saved checkpoint give
//! identical PSNR and SSIM, under the DTU masked protocol.

use std::path::Path;


mod common;
#[path = "../../tests/common/dtu_arc.rs"]
mod dtu_arc;

use common::{edgenerf, repo, text};

/// Views of the scan: the 3-view DTU split trains on views 25, 22 and 28; 12 of the
/// ids below 29 are test views.
const VIEWS: usize = 29;
const W: u32 = 32;
const H: u32 = 24;

/// A pixelNeRF-layout DTU scan (`cameras.npz`, `image/`, `mask/`) of `VIEWS` cameras on
/// an arc looking at the origin, each image a smooth colour pattern that varies with the
/// view, each mask the central part of the frame (so masked and full-image figures differ).
fn write_dtu_scan(root: &Path) {
    std::fs::create_dir_all(root.join("image")).unwrap();
    std::fs::create_dir_all(root.join("mask")).unwrap();
    let mats = dtu_arc::dtu_camera_matrices(VIEWS, W, H, 1.0);
    for i in 0..VIEWS {
        let image = image::RgbImage::from_fn(W, H, |x, y| {
            let v = |s: f64| (127.0 + 120.0 * (s + i as f64 * 0.3).sin()) as u8;
            image::Rgb([v(x as f64 * 0.4), v(y as f64 * 0.5 + 1.0), v((x + y) as f64 * 0.2 + 2.0)])
        });
        image.save(root.join(format!("image/{i:06}.png"))).unwrap();
        let inside = |x: u32, y: u32| (6..26).contains(&x) && (5..19).contains(&y);
        let mask = image::GrayImage::from_fn(W, H, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }]));
        mask.save(root.join(format!("mask/{i:03}.png"))).unwrap();
    }
    let arrays: Vec<(&str, &[usize], &[f64])> = mats.iter().map(|(n, d)| (n.as_str(), &[4usize, 4][..], d.as_slice())).collect();
    edgenerf::data::npy::write_npz_f64(&root.join("cameras.npz"), &arrays).unwrap();
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// A figure as the `f32` both evaluations computed (train's `metrics.json` holds `f32`,
/// `eval`'s the same value widened to `f64`).
fn figure(v: &serde_json::Value, key: &str) -> f32 {
    v[key].as_f64().unwrap_or_else(|| panic!("no {key} in {v}")) as f32
}

#[test]
fn train_render_and_eval_score_a_dtu_checkpoint_identically() {
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan");
    write_dtu_scan(&scan);
    let run = dir.path().join("run");
    // The sparse preset: patch batches with the edge-guided terms and coarse-to-fine
    // levels, stopped early in the level schedule (the checkpoint's model must render
    // with the levels the trained one had).
    let config = repo().join("tools/configs/sparse-small.toml");
    let o = edgenerf(&[
        "train",
        scan.to_str().unwrap(),
        "--views",
        "3",
        "--config",
        config.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--iters",
        "6",
        "--set",
        "train.rays_per_batch=256",
        "--set",
        "sampler.steps_per_diagonal=48",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let trained = json(&run.join("test/metrics.json"));
    let per_view = trained["per_view"].as_array().unwrap();
    assert_eq!(per_view.len(), 12, "the test views of the 3-view DTU split");

    let rendered = dir.path().join("render");
    let o = edgenerf(&["render", run.to_str().unwrap(), "--split", "test", "--out", rendered.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let rendered = json(&rendered.join("metrics.json"));

    let o = edgenerf(&["eval", run.to_str().unwrap(), "--lpips", "none"]);
    assert!(o.status.success(), "{}", text(&o));
    let evaluated = json(&run.join("eval/metrics.json"));
    assert_eq!(evaluated["protocol"], "dtu-masked");
    let views = evaluated["views"].as_array().unwrap();
    assert_eq!(views.len(), per_view.len());

    for ((t, r), e) in per_view.iter().zip(rendered["per_view"].as_array().unwrap()).zip(views) {
        assert_eq!(t["view"], e["view"]);
        assert_eq!(t["protocol"], "dtu-masked", "{t}");
        assert_eq!(e["protocol"], "dtu-masked", "{e}");
        for key in ["psnr", "ssim"] {
            assert_eq!(figure(t, key), figure(e, key), "{key} of view {}: train {t}\neval {e}", t["view"]);
            assert_eq!(figure(t, key), figure(r, key), "{key} of view {}: train {t}\nrender {r}", t["view"]);
        }
        // The unmasked figures are kept, and they are not the masked ones.
        let full = &t["full_image"];
        assert_eq!(full, &e["full_image"], "view {}", t["view"]);
        assert_ne!(full["psnr"].as_f64().unwrap() as f32, figure(t, "psnr"), "view {}", t["view"]);
    }
    assert_eq!(figure(&trained, "mean_psnr"), evaluated["metrics"]["psnr"].as_f64().unwrap() as f32);
    assert_eq!(figure(&trained, "mean_ssim"), evaluated["metrics"]["ssim"].as_f64().unwrap() as f32);
}
