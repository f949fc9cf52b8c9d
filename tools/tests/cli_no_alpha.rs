//! Photographs have no alpha. The committed `turntable` scene (an object on a
//! transparent background) rewritten as a nerfstudio capture the way `ns-process-data`
//! gives photos of it: images composited on white, RGB only, no masks, no scene box or
//! depth range in `transforms.json`. Trained with the default command (`--views K`, the
//! preset the format gets), it must measure within 1 dB of the RGBA original under the
//! same command: whatever lies behind the object is explained by the learned background,
//! not by fog in front of it (README, "Real captures").
//!
//! `EDGENERF_NO_ALPHA_ITERS` sets the steps (default 200), `EDGENERF_NO_ALPHA_KEEP` a
//! folder where the nerfstudio copy is written and kept (to train it by hand).

mod common;

use std::path::Path;

use common::{edgenerf, repo, text};

/// Writes `src` (a Blender-format scene with RGBA images) to `dst` as a nerfstudio
/// capture: `images/{train,test}_NNN.png` composited on white, `transforms.json` with
/// the intrinsics, poses and split, and nothing else.
fn nerfstudio_on_white(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst.join("images")).unwrap();
    let mut frames = Vec::new();
    let mut lists = [Vec::new(), Vec::new()];
    let mut intrinsics = serde_json::Map::new();
    for (k, split) in ["train", "test"].iter().enumerate() {
        let t: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(src.join(format!("transforms_{split}.json"))).unwrap()).unwrap();
        for key in ["fl_x", "fl_y", "cx", "cy", "w", "h"] {
            intrinsics.insert(key.into(), t[key].clone());
        }
        for (i, f) in t["frames"].as_array().unwrap().iter().enumerate() {
            let rgba = image::open(src.join(f["file_path"].as_str().unwrap())).unwrap().to_rgba8();
            let rgb = image::RgbImage::from_fn(rgba.width(), rgba.height(), |x, y| {
                let p = rgba.get_pixel(x, y).0;
                let a = p[3] as f32 / 255.0;
                image::Rgb([0, 1, 2].map(|c| (p[c] as f32 * a + 255.0 * (1.0 - a)).round() as u8))
            });
            let name = format!("images/{split}_{i:03}.png");
            rgb.save(dst.join(&name)).unwrap();
            frames.push(serde_json::json!({ "file_path": name, "transform_matrix": f["transform_matrix"] }));
            lists[k].push(name);
        }
    }
    let mut t = intrinsics;
    t.insert("camera_model".into(), "OPENCV".into());
    t.insert("frames".into(), frames.into());
    t.insert("train_filenames".into(), lists[0].clone().into());
    t.insert("test_filenames".into(), lists[1].clone().into());
    std::fs::write(dst.join("transforms.json"), serde_json::to_string_pretty(&t).unwrap()).unwrap();
}

/// The mean test PSNR a `train` run printed.
fn test_psnr(out: &str) -> f64 {
    let line = out.lines().find(|l| l.starts_with("test PSNR")).unwrap_or_else(|| panic!("no test PSNR in:\n{out}"));
    line.split_whitespace().nth(2).unwrap().parse().unwrap()
}

#[test]
fn a_capture_composited_on_white_trains_like_its_rgba_original() {
    let iters = std::env::var("EDGENERF_NO_ALPHA_ITERS").unwrap_or_else(|_| "200".into());
    let tmp = tempfile::tempdir().unwrap();
    let original = repo().join("synthetic-scenes/small/turntable");
    let copy = match std::env::var_os("EDGENERF_NO_ALPHA_KEEP") {
        Some(dir) => std::path::PathBuf::from(dir),
        None => tmp.path().join("turntable-ns"),
    };
    nerfstudio_on_white(&original, &copy);
    let mut psnr = Vec::new();
    for (scene, run) in [(&original, "rgba"), (&copy, "white")] {
        let out = tmp.path().join(run);
        let o = edgenerf(&["train", scene.to_str().unwrap(), "--views", "8", "--iters", &iters, "--out", out.to_str().unwrap()]);
        let t = text(&o);
        assert!(o.status.success(), "{run}: {t}");
        psnr.push(test_psnr(&t));
        if run == "white" {
            assert!(t.contains("learned background"), "the capture without alpha should train a learned background:\n{t}");
        }
    }
    eprintln!("turntable, 8 views, {iters} steps: RGBA {:.2} dB, nerfstudio on white {:.2} dB", psnr[0], psnr[1]);
    assert!(psnr[1] >= psnr[0] - 1.0, "on white {:.2} dB, RGBA original {:.2} dB: more than 1 dB apart", psnr[1], psnr[0]);
}
