//! The metrics room on the committed Mitsuba scenes (`synthetic-scenes/small/`): the
//! ground truth measured against itself is perfect, and the ground-truth edge map is a
//! plausible one.
//!
//! For every scene and every test view, through `edgenerf::data::Scene::load`:
//! * `evaluate_geometry` of the GT depth and normals against themselves gives AbsRel,
//!   RMSE and RMSE-log 0, delta < 1.25 = 1, mean and median angle 0, 100 % under
//!   11.25 deg, in all three regions (all, edge, non-edge), and a depth boundary error
//!   of 0 / 0 with edges present;
//! * the GT edge map is non-empty and a small fraction of the image: under 30 % of all
//!   pixels of all scenes with its 2 px dilation (28.5 % with the default parameters:
//!   16 % for `texture` to 38-39 % for `occlusion`, `thin` and `room`); in every single
//!   view under 35 % before the dilation and 60 % after it (the worst: a `thin` view of
//!   rods and fences, 28 % and 49 %, and a `room` view, 22 % and 50.5 %);
//! * the error maps of a perturbed prediction have the image's size.
//!
//! `EDGENERF_METRICS_MAPS=DIR` also writes, per scene, the edge overlay and error maps of
//! a perturbed prediction of the first test view to `DIR` (for looking at them).

use std::path::PathBuf;

use edgenerf::data::{ImageRgb, LoadOptions, Scene};
use edgenerf::metrics::boundary::{dbe_edges, normalize_depth};
use edgenerf::metrics::geometry::{EdgeMapParams, GeometryInputs, GeometryParams};
use edgenerf::metrics::maps::{depth_error_map, edge_overlay, normal_error_map};
use edgenerf::metrics::{evaluate_geometry, gt_edge_map};

const SCENES: [&str; 8] = ["occlusion", "creases", "texture", "thin", "smooth", "table", "turntable", "room"];

fn load(name: &str) -> Scene {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("synthetic-scenes").join("small").join(name);
    Scene::load(&dir, &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
}

#[test]
fn ground_truth_against_itself_is_perfect() {
    for name in SCENES {
        let scene = load(name);
        let (w, h) = scene.image_size();
        for view in scene.test_views() {
            let at = format!("{name}/{}", view.name);
            let (depth, normal) = (view.depth.as_deref().unwrap(), view.normal.as_deref().unwrap());
            let inputs = GeometryInputs {
                width: w,
                height: h,
                gt_depth: Some(depth),
                gt_normal: Some(normal),
                depth: Some(depth),
                normal: Some(normal),
            };
            let m = evaluate_geometry(&inputs, &GeometryParams::default()).unwrap();
            let d = m.depth.unwrap();
            let n = m.normal.unwrap();
            for (region, e) in [("all", d.all), ("edge", d.edge), ("non-edge", d.non_edge)] {
                let e = e.unwrap_or_else(|| panic!("{at}: no {region} depth pixels"));
                assert_eq!((e.abs_rel, e.rmse, e.rmse_log), (0.0, 0.0, 0.0), "{at} {region}");
                assert_eq!((e.delta_1, e.delta_2, e.delta_3), (1.0, 1.0, 1.0), "{at} {region}");
            }
            for (region, e) in [("all", n.all), ("edge", n.edge), ("non-edge", n.non_edge)] {
                let e = e.unwrap_or_else(|| panic!("{at}: no {region} normal pixels"));
                assert_eq!((e.mean_deg, e.median_deg), (0.0, 0.0), "{at} {region}");
                assert_eq!((e.under_11_25, e.under_22_5, e.under_30), (1.0, 1.0, 1.0), "{at} {region}");
            }
            let b = m.boundary.unwrap();
            assert!(b.gt_edge_pixels > 0, "{at}: no DBE edges in the GT depth");
            assert_eq!((b.accuracy, b.completeness), (0.0, 0.0), "{at}");
            assert_eq!(b.est_edge_pixels, b.gt_edge_pixels, "{at}");
        }
    }
}

#[test]
fn ground_truth_edge_map_is_a_small_nonempty_fraction() {
    let (mut all_edges, mut all_pixels) = (0usize, 0usize);
    for name in SCENES {
        let scene = load(name);
        let (w, h) = scene.image_size();
        let (mut dilated, mut thin, mut total) = (0usize, 0usize, 0usize);
        for view in scene.test_views() {
            let (depth, normal) = (view.depth.as_deref(), view.normal.as_deref());
            let at = format!("{name}/{}", view.name);
            let e = gt_edge_map(w, h, depth, normal, &EdgeMapParams::default()).unwrap();
            let raw = gt_edge_map(w, h, depth, normal, &EdgeMapParams { dilate_px: 0.0, ..Default::default() }).unwrap();
            let (n, r) = (e.iter().filter(|&&b| b).count(), raw.iter().filter(|&&b| b).count());
            assert!(r > 0 && n > r, "{at}: {r} edge pixels, {n} dilated");
            assert!(raw.iter().zip(&e).all(|(&r, &e)| !r || e), "{at}: dilation lost a pixel");
            assert!((n as f64) < 0.60 * e.len() as f64, "{at}: {n} of {} pixels are edges", e.len());
            assert!((r as f64) < 0.35 * e.len() as f64, "{at}: {r} of {} pixels are edges before dilation", e.len());
            (dilated, thin, total) = (dilated + n, thin + r, total + e.len());
        }
        eprintln!(
            "{name:10} GT edges: {:5.2} % of pixels, {:5.2} % before the 2 px dilation",
            100.0 * dilated as f64 / total as f64,
            100.0 * thin as f64 / total as f64
        );
        (all_edges, all_pixels) = (all_edges + dilated, all_pixels + total);
    }
    let fraction = all_edges as f64 / all_pixels as f64;
    eprintln!("all scenes: {:5.2} % of pixels are GT edges", 100.0 * fraction);
    assert!(fraction < 0.30, "{:.1} % of all pixels are GT edges", 100.0 * fraction);
}

#[test]
fn error_maps_of_a_perturbed_prediction() {
    let out = std::env::var_os("EDGENERF_METRICS_MAPS").map(PathBuf::from);
    for name in SCENES {
        let scene = load(name);
        let (w, h) = scene.image_size();
        let view = scene.test_views().next().unwrap();
        let (depth, normal) = (view.depth.as_deref().unwrap(), view.normal.as_deref().unwrap());
        // A prediction that is 2 % too far on the left half and tilted by 20 deg on the
        // right half, with the background at the far distance.
        let pred_depth: Vec<f32> = depth
            .iter()
            .enumerate()
            .map(|(i, &d)| if d <= 0.0 { scene.far } else if (i as u32 % w) < w / 2 { d * 1.02 } else { d })
            .collect();
        let (s, c) = 20f32.to_radians().sin_cos();
        let pred_normal: Vec<[f32; 3]> = normal
            .iter()
            .enumerate()
            .map(|(i, n)| if (i as u32 % w) < w / 2 { *n } else { [c * n[0] - s * n[1], s * n[0] + c * n[1], n[2]] })
            .collect();
        let (depth_map, scale) = depth_error_map(w, h, depth, &pred_depth, None).unwrap();
        assert!(scale > 0.0);
        let normal_map = normal_error_map(w, h, normal, &pred_normal).unwrap();
        let (e_gt, e_est) = dbe_edges(w, h, depth, &pred_depth, &Default::default()).unwrap();
        let overlay = edge_overlay(w, h, &normalize_depth(depth, depth).unwrap(), &e_gt, &e_est).unwrap();
        let geo_edges = gt_edge_map(w, h, Some(depth), Some(normal), &EdgeMapParams::default()).unwrap();
        let geo = edge_overlay(w, h, &normalize_depth(depth, depth).unwrap(), &geo_edges, &vec![false; geo_edges.len()]).unwrap();
        for img in [&depth_map, &normal_map, &overlay, &geo] {
            assert_eq!((img.width, img.height, img.data.len()), (w, h, (3 * w * h) as usize));
        }
        if let Some(dir) = &out {
            std::fs::create_dir_all(dir).unwrap();
            let save = |img: &ImageRgb, what: &str| img.save_png(dir.join(format!("{name}_{what}.png"))).unwrap();
            save(&depth_map, "depth_error");
            save(&normal_map, "normal_error");
            save(&overlay, "dbe_edges");
            save(&geo, "gt_edges");
        }
    }
}
