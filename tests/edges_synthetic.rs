//! Edge masks against geometric ground truth: on the committed Mitsuba scenes
//! (`synthetic-scenes/small/`), the default Canny masks must cover the ground-truth
//! depth discontinuities (occlusion boundaries), so that the edge-guided losses do not
//! smooth across them, while leaving most of each image non-edge.
//!
//! GT depth discontinuity: two 4-neighbouring pixels where one hits a surface and the
//! other does not, or whose ray distances differ by more than 5 % (both pixels count).
//! A discontinuity pixel is covered when an edge pixel of the (dilated) mask lies
//! within 1 px of it (8-neighbourhood), i.e. within 2 px of the thin Canny edge.

use std::path::PathBuf;

use edgenerf::data::{LoadOptions, Scene, View};
use edgenerf::edges::{EdgeConfig, EdgeMask, edge_masks};

fn load(name: &str) -> Scene {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("synthetic-scenes/small").join(name);
    Scene::load(&dir, &LoadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
}

/// GT depth-discontinuity pixels of `v`, row-major.
fn depth_discontinuities(v: &View) -> Vec<bool> {
    let (w, h) = (v.camera.width as usize, v.camera.height as usize);
    let d = v.depth.as_deref().expect("GT depth");
    let jump = |a: f32, b: f32| (a > 0.0) != (b > 0.0) || (a > 0.0 && (a - b).abs() > 0.05 * a.min(b));
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for j in [(x + 1 < w).then(|| i + 1), (y + 1 < h).then(|| i + w)].into_iter().flatten() {
                if jump(d[i], d[j]) {
                    out[i] = true;
                    out[j] = true;
                }
            }
        }
    }
    out
}

/// GT normal creases of `v`: two 4-neighbouring pixels that both hit a surface whose
/// normals differ by more than 30 degrees, and whose depths do not jump.
fn normal_creases(v: &View) -> Vec<bool> {
    let (w, h) = (v.camera.width as usize, v.camera.height as usize);
    let d = v.depth.as_deref().expect("GT depth");
    let n = v.normal.as_deref().expect("GT normals");
    let cos30 = 30f32.to_radians().cos();
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for j in [(x + 1 < w).then(|| i + 1), (y + 1 < h).then(|| i + w)].into_iter().flatten() {
                let dot = n[i][0] * n[j][0] + n[i][1] * n[j][1] + n[i][2] * n[j][2];
                if d[i] > 0.0 && d[j] > 0.0 && (d[i] - d[j]).abs() <= 0.05 * d[i].min(d[j]) && dot < cos30 {
                    out[i] = true;
                    out[j] = true;
                }
            }
        }
    }
    out
}

/// Fraction of `gt` pixels with an edge pixel of `mask` within 1 px (8-neighbourhood).
fn coverage(mask: &EdgeMask, gt: &[bool]) -> f32 {
    let near = mask.dilate_edges();
    let n = gt.iter().filter(|&&g| g).count();
    let hit = gt.iter().zip(&near.non_edge).filter(|&(&g, &ne)| g && ne == 0).count();
    hit as f32 / n.max(1) as f32
}

/// Mean coverage of `gt(view)` and mean edge fraction over the training views of `scene`.
fn score_with(scene: &Scene, cfg: &EdgeConfig, gt: fn(&View) -> Vec<bool>) -> (f32, f32) {
    let views = scene.split.train.clone();
    let masks = edge_masks(scene, &views, cfg).unwrap();
    let n = views.len() as f32;
    let cov = views.iter().zip(&masks).map(|(&v, m)| coverage(m, &gt(&scene.views[v]))).sum::<f32>() / n;
    let frac = masks.iter().map(|m| m.edge_fraction()).sum::<f32>() / n;
    (cov, frac)
}

fn score(scene: &Scene, cfg: &EdgeConfig) -> (f32, f32) {
    score_with(scene, cfg, depth_discontinuities)
}

#[test]
fn default_canny_masks_cover_depth_discontinuities() {
    // (scene, minimum coverage, maximum edge fraction), a few points under the values
    // measured with the defaults (coverage / edge fraction over the 24 training views:
    // occlusion 0.90 / 0.25, thin 0.95 / 0.32, table 0.91 / 0.18, turntable 0.92 / 0.14).
    for (name, min_cov, max_frac) in [("occlusion", 0.87, 0.3), ("thin", 0.92, 0.37), ("table", 0.88, 0.22), ("turntable", 0.89, 0.18)] {
        let scene = load(name);
        let (cov, frac) = score(&scene, &EdgeConfig::default());
        eprintln!("{name}: coverage {cov:.3}, edge fraction {frac:.3}");
        assert!(cov >= min_cov, "{name}: only {:.1}% of GT depth-discontinuity pixels lie within 1 px of a mask edge", 100.0 * cov);
        assert!(frac <= max_frac, "{name}: {:.1}% of pixels are edge; thresholds too low", 100.0 * frac);
    }
}

#[test]
fn default_canny_masks_cover_creases_and_stay_off_smooth_interiors() {
    // Normal creases of the polyhedra show as shading edges.
    let creases = load("creases");
    let (cov, _) = score_with(&creases, &EdgeConfig::default(), normal_creases);
    eprintln!("creases: normal-crease coverage {cov:.3}");
    assert!(cov >= 0.8, "only {:.1}% of GT normal-crease pixels lie within 1 px of a mask edge", 100.0 * cov);
    // Soft shading of smooth objects is not an edge: most pixels stay non-edge.
    let smooth = load("smooth");
    let (cov, frac) = score(&smooth, &EdgeConfig::default());
    eprintln!("smooth: coverage {cov:.3}, edge fraction {frac:.3}");
    assert!(frac <= 0.22 && cov >= 0.88, "smooth: coverage {cov:.3}, edge fraction {frac:.3}");
}

/// Prints coverage and edge fraction over a grid of Canny settings (tuning aid):
/// `cargo test --test edges_synthetic -- --ignored --nocapture`.
#[test]
#[ignore]
fn sweep_canny_settings() {
    let scenes: Vec<(&str, Scene)> = ["occlusion", "creases", "texture", "thin", "smooth", "table", "turntable"].into_iter().map(|n| (n, load(n))).collect();
    for sigma in [1.4f32, 2.0, 2.5] {
        for (low, high) in [(0.05f32, 0.1f32), (0.05, 0.15), (0.1, 0.2)] {
            let mut cfg = EdgeConfig::default();
            cfg.canny.sigma = sigma;
            cfg.canny.low = low;
            cfg.canny.high = high;
            let row: Vec<String> = scenes
                .iter()
                .map(|(n, s)| {
                    let (c, f) = score(s, &cfg);
                    let crease = if *n == "creases" { format!(" crease {:.2}", score_with(s, &cfg, normal_creases).0) } else { String::new() };
                    format!("{n} {c:.2}/{f:.2}{crease}")
                })
                .collect();
            println!("sigma {sigma} low {low} high {high}: {}", row.join("  "));
        }
    }
}
