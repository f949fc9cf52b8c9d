//! Unit tests of the edge room: binarization, dilation, sources, errors and the cache.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

use super::*;
use crate::data::{Camera, ImageRgb, SceneFormat, Split, View};

/// A `w x h` RGB image: white square `[x0, x1) x [y0, y1)` on black.
fn square_image(w: u32, h: u32, (x0, x1, y0, y1): (u32, u32, u32, u32)) -> ImageRgb {
    let mut img = ImageRgb::new(w, h);
    for y in y0..y1 {
        for x in x0..x1 {
            img.set(x, y, [1.0; 3]);
        }
    }
    img
}

/// A scene under `root` whose views are `(relative image path, image)`; the first is
/// the only training view.
fn scene(root: &Path, images: Vec<(&str, ImageRgb)>) -> Scene {
    let views: Vec<View> = images
        .into_iter()
        .map(|(rel, image)| {
            let path = root.join(rel);
            View {
                name: path.file_stem().unwrap().to_string_lossy().into_owned(),
                path,
                camera: Camera::from_fov_x(image.width, image.height, 1.0, Mat4::IDENTITY),
                image,
                mask: None,
                alpha: None,
                depth: None,
                normal: None,
                train_mask: None,
            }
        })
        .collect();
    let n = views.len();
    Scene {
        root: root.to_path_buf(),
        format: SceneFormat::Blender,
        views,
        split: Split { train: vec![0], test: (1..n).collect() },
        near: 1.0,
        far: 2.0,
        ndc: None,
        aabb: [Vec3::splat(-1.0), Vec3::splat(1.0)],
        background: None,
    }
}

fn edge_count(m: &EdgeMask) -> usize {
    m.non_edge.iter().filter(|&&v| v == 0).count()
}

fn external(dir: &Path, polarity: Polarity, dilate: bool) -> EdgeConfig {
    EdgeConfig { source: EdgeSource::External, dir: Some(dir.to_path_buf()), polarity, dilate, ..Default::default() }
}

fn save_grey(path: &Path, w: u32, h: u32, f: impl Fn(u32, u32) -> u8) {
    image::GrayImage::from_fn(w, h, |x, y| image::Luma([f(x, y)])).save(path).unwrap();
}

#[test]
fn binarization_follows_polarity_and_tau_e() {
    let e = [0.0, 124.0, 124.9, 125.0, 126.0, 255.0];
    let dark = binarize(6, 1, &e, Polarity::DarkEdges, 125.0);
    assert_eq!(dark.non_edge, [0, 0, 0, 1, 1, 1], "dark edges: non-edge where E >= tau_e");
    let bright = binarize(6, 1, &e, Polarity::BrightEdges, 125.0);
    assert_eq!(bright.non_edge, [1, 1, 1, 0, 0, 0], "bright edges: edge where E >= tau_e");
    let high = binarize(6, 1, &e, Polarity::DarkEdges, 200.0);
    assert_eq!(high.non_edge, [0, 0, 0, 0, 0, 1]);
    assert_eq!((dark.at(0, 0), dark.at(5, 0)), (0.0, 1.0));
    assert!((dark.edge_fraction() - 0.5).abs() < 1e-6);
}

#[test]
fn dilation_widens_edges_by_one_pixel_each_side() {
    // A vertical edge line at x = 3 of a 7x5 mask becomes x = 2..=4.
    let mut m = EdgeMask::all_non_edge(7, 5);
    for y in 0..5 {
        m.non_edge[y * 7 + 3] = 0;
    }
    let d = m.dilate_edges();
    for y in 0..5 {
        let row: Vec<u8> = d.non_edge[y * 7..(y + 1) * 7].to_vec();
        assert_eq!(row, [1, 1, 0, 0, 0, 1, 1], "row {y}");
    }
    // A single pixel becomes a 3x3 block; a corner pixel a 2x2 block (outside counts
    // as non-edge, so the border does not turn into an edge).
    let mut m = EdgeMask::all_non_edge(7, 5);
    m.non_edge[2 * 7 + 3] = 0;
    m.non_edge[0] = 0;
    let d = m.dilate_edges();
    assert_eq!(edge_count(&d), 9 + 4);
    for (x, y) in [(2, 1), (4, 3), (3, 2), (0, 0), (1, 1)] {
        assert!(d.is_edge(x, y), "({x}, {y})");
    }
    assert!(!d.is_edge(5, 2) && !d.is_edge(2, 0) && !d.is_edge(6, 4));
}

#[test]
fn source_none_gives_all_ones() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(dir.path(), vec![("a.png", square_image(16, 12, (4, 10, 3, 8)))]);
    let cfg = EdgeConfig { source: EdgeSource::None, ..Default::default() };
    let masks = edge_masks(&s, &[0], &cfg).unwrap();
    assert_eq!(masks, [EdgeMask::all_non_edge(16, 12)]);
    assert!(masks[0].non_edge.iter().all(|&v| v == 1));
    assert_eq!(masks[0].edge_fraction(), 0.0);
}

#[test]
fn canny_source_marks_the_square_boundary_and_dilates_it() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(dir.path(), vec![("a.png", square_image(40, 48, (10, 30, 6, 42)))]);
    let thin = edge_mask(&s, 0, &EdgeConfig { dilate: false, ..Default::default() }).unwrap();
    let wide = edge_mask(&s, 0, &EdgeConfig::default()).unwrap();
    assert_eq!(wide, thin.dilate_edges());
    let xs = |m: &EdgeMask, y: u32| (0..40).filter(|&x| m.is_edge(x, y)).collect::<Vec<u32>>();
    for y in 10..38u32 {
        let t = xs(&thin, y);
        assert_eq!(t.len(), 2, "row {y}: one pixel on each side, {t:?}");
        assert!((9..=10).contains(&t[0]) && (29..=30).contains(&t[1]), "row {y}: {t:?}");
    }
    // Away from the corners the thin edge is straight, and the dilated one three pixels wide.
    for y in 16..32u32 {
        let t = xs(&thin, y);
        assert_eq!(xs(&wide, y), [t[0] - 1, t[0], t[0] + 1, t[1] - 1, t[1], t[1] + 1], "row {y}");
    }
    // The flat inside and outside stay non-edge.
    assert!(!wide.is_edge(20, 16) && !wide.is_edge(2, 2));
}

#[test]
fn external_maps_of_any_depth_and_polarity() {
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    let img = ImageRgb::new(8, 6);
    // Views a (8-bit grey, dark edge at x = 2), b (16-bit grey, bright edge at x = 5),
    // c (RGB, dark edge at y = 1), test/d (looked up by its path mirrored under the dir).
    let s = scene(dir.path(), vec![("a.png", img.clone()), ("b.png", img.clone()), ("c.png", img.clone()), ("test/d.png", img)]);
    save_grey(&maps.join("a.png"), 8, 6, |x, _| if x == 2 { 30 } else { 250 });
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(8, 6, |x, _| image::Luma([if x == 5 { 60000 } else { 1000 }])).save(maps.join("b.png")).unwrap();
    image::RgbImage::from_fn(8, 6, |_, y| if y == 1 { image::Rgb([125, 0, 0]) } else { image::Rgb([125, 125, 125]) }).save(maps.join("c.png")).unwrap();
    std::fs::create_dir(maps.join("test")).unwrap();
    save_grey(&maps.join("test/d.png"), 8, 6, |x, y| if (x, y) == (7, 5) { 0 } else { 255 });

    let dark = edge_masks(&s, &[0, 2, 3], &external(&maps, Polarity::DarkEdges, false)).unwrap();
    assert!((0..6).all(|y| (0..8).all(|x| dark[0].is_edge(x, y) == (x == 2))), "{:?}", dark[0]);
    // Grey level 125 exactly (RGB 125,125,125) is non-edge at tau_e = 125; the red row is edge.
    assert!((0..6).all(|y| (0..8).all(|x| dark[1].is_edge(x, y) == (y == 1))), "{:?}", dark[1]);
    assert_eq!(edge_count(&dark[2]), 1);
    let bright = edge_mask(&s, 1, &external(&maps, Polarity::BrightEdges, false)).unwrap();
    assert!((0..6).all(|y| (0..8).all(|x| bright.is_edge(x, y) == (x == 5))), "{bright:?}");
    // Read with the wrong polarity, almost everything is edge.
    let wrong = edge_mask(&s, 1, &external(&maps, Polarity::DarkEdges, false)).unwrap();
    assert!(wrong.edge_fraction() > 0.8);
    // Dilation applies to external maps as well.
    let wide = edge_mask(&s, 0, &external(&maps, Polarity::DarkEdges, true)).unwrap();
    assert!((0..6).all(|y| (0..8).all(|x| wide.is_edge(x, y) == (1..=3).contains(&x))));
}

#[test]
fn mask_pngs_round_trip_and_read_back_as_dark_edge_maps() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(dir.path(), vec![("a.png", square_image(24, 20, (6, 18, 5, 15)))]);
    let mask = edge_mask(&s, 0, &EdgeConfig::default()).unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    mask.save_png(&maps.join("a.png")).unwrap();
    assert_eq!(EdgeMask::load_png(&maps.join("a.png")).unwrap(), mask);
    let back = edge_mask(&s, 0, &external(&maps, Polarity::DarkEdges, false)).unwrap();
    assert_eq!(back, mask, "a mask PNG is a dark-edge external map");
}

#[test]
fn missing_unreadable_and_wrong_size_maps_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(dir.path(), vec![("image007.png", ImageRgb::new(8, 6)), ("image008.png", ImageRgb::new(8, 6))]);
    let maps = dir.path().join("maps");

    let msg = edge_masks(&s, &[0], &external(&maps, Polarity::DarkEdges, true)).unwrap_err().to_string();
    assert!(msg.contains("not found") && msg.contains("maps"), "{msg}");

    std::fs::create_dir(&maps).unwrap();
    let msg = edge_masks(&s, &[0], &external(&maps, Polarity::DarkEdges, true)).unwrap_err().to_string();
    assert!(msg.contains("image007.png") && msg.contains(&maps.display().to_string()) && msg.contains("no PNG or JPEG files"), "{msg}");
    save_grey(&maps.join("other.png"), 8, 6, |_, _| 255);
    let err = edge_masks(&s, &[0], &external(&maps, Polarity::DarkEdges, true)).unwrap_err();
    assert!(matches!(err, EdgeError::MissingMap { .. }), "{err:?}");
    assert!(err.to_string().contains("1 image file (other.png)"), "{err}");

    save_grey(&maps.join("image007.png"), 10, 6, |_, _| 255);
    let msg = edge_masks(&s, &[0], &external(&maps, Polarity::DarkEdges, true)).unwrap_err().to_string();
    assert!(msg.contains("image007.png") && msg.contains("10x6") && msg.contains("8x6"), "{msg}");

    std::fs::write(maps.join("image008.jpg"), b"not a jpeg").unwrap();
    let err = edge_masks(&s, &[1], &external(&maps, Polarity::DarkEdges, true)).unwrap_err();
    assert!(matches!(err, EdgeError::Image { .. }) && err.to_string().contains("image008.jpg"), "{err}");

    let no_dir = EdgeConfig { source: EdgeSource::External, ..Default::default() };
    assert!(matches!(edge_masks(&s, &[0], &no_dir), Err(EdgeError::NoDir)));
    assert!(edge_masks(&s, &[0], &no_dir).unwrap_err().to_string().contains("--edges DIR"));
}

#[test]
fn config_validation_and_serde() {
    let bad = EdgeConfig { canny: CannyParams { sigma: 1.0, low: 0.3, high: 0.2 }, ..Default::default() };
    assert!(bad.validate().unwrap_err().to_string().contains("low 0.3 / high 0.2"));
    let bad = EdgeConfig { tau_e: f32::NAN, ..Default::default() };
    assert!(bad.validate().is_err());
    // Outside the grey levels, and a blur whose kernel would grow without bound (this
    // hung `edgenerf edges --canny-sigma 1e9`).
    for tau_e in [300.0, -1.0] {
        assert!(EdgeConfig { tau_e, ..Default::default() }.validate().unwrap_err().to_string().contains("0..=255"));
    }
    let huge = EdgeConfig { canny: CannyParams { sigma: 1e9, ..Default::default() }, ..Default::default() };
    assert!(huge.validate().unwrap_err().to_string().contains("canny.sigma is 1000000000"));
    EdgeConfig { tau_e: 255.0, canny: CannyParams { sigma: MAX_CANNY_SIGMA, ..Default::default() }, ..Default::default() }.validate().unwrap();
    EdgeConfig::default().validate().unwrap();

    let cfg: EdgeConfig = serde_json::from_str(r#"{"source": "external", "dir": "maps", "polarity": "bright_edges", "canny": {"sigma": 2.0}}"#).unwrap();
    assert_eq!(cfg.source, EdgeSource::External);
    assert_eq!(cfg.polarity, Polarity::BrightEdges);
    assert_eq!(cfg.dir.as_deref(), Some(Path::new("maps")));
    assert_eq!(cfg.canny, CannyParams { sigma: 2.0, ..Default::default() });
    assert_eq!(cfg.tau_e, 125.0);
    assert!(serde_json::from_str::<EdgeConfig>(r#"{"tau": 3}"#).is_err(), "unknown keys are errors");
    assert!(serde_json::from_str::<EdgeConfig>(r#"{"source": "dexined"}"#).is_err());
}

#[test]
fn repeated_view_names_get_their_folder_as_a_prefix() {
    let dir = tempfile::tempdir().unwrap();
    let img = ImageRgb::new(4, 4);
    let s = scene(dir.path(), vec![("train/r_000.png", img.clone()), ("train/r_001.png", img.clone()), ("test/r_000.png", img)]);
    let stems: Vec<String> = (0..3).map(|v| mask_stem(&s, v)).collect();
    assert_eq!(stems, ["r_000", "r_001", "test_r_000"]);
}

fn write_stamp_tamper(dir: &Path, file: &str) {
    // Overwrite a cached mask with one that has no edges.
    let m = EdgeMask::load_png(&dir.join(file)).unwrap();
    EdgeMask::all_non_edge(m.width, m.height).save_png(&dir.join(file)).unwrap();
}

#[test]
fn the_cache_is_reused_when_the_stamp_matches_and_recomputed_otherwise() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = scene(dir.path(), vec![("a.png", square_image(24, 20, (6, 18, 5, 15))), ("b.png", square_image(24, 20, (2, 9, 3, 17)))]);
    let cache: PathBuf = dir.path().join("run/edges");
    let cfg = EdgeConfig::default();
    let fresh = edge_masks_cached(&s, &[0, 1], &cfg, &cache).unwrap();
    assert_eq!(fresh, edge_masks(&s, &[0, 1], &cfg).unwrap());
    for f in ["a.png", "b.png", "stamp.json"] {
        assert!(cache.join(f).is_file(), "{f}");
    }
    let stamp = std::fs::read_to_string(cache.join("stamp.json")).unwrap();
    assert!(stamp.contains("\"a\"") && stamp.contains("\"sigma\""), "{stamp}");

    // Same inputs: the (tampered) files are what comes back, so they were reused.
    write_stamp_tamper(&cache, "a.png");
    let reused = edge_masks_cached(&s, &[0, 1], &cfg, &cache).unwrap();
    assert_eq!(reused[0].edge_fraction(), 0.0);
    assert_eq!(reused[1], fresh[1]);

    // Another config: recomputed and rewritten.
    let cfg2 = EdgeConfig { dilate: false, ..Default::default() };
    let other = edge_masks_cached(&s, &[0, 1], &cfg2, &cache).unwrap();
    assert_eq!(other, edge_masks(&s, &[0, 1], &cfg2).unwrap());
    assert_eq!(EdgeMask::load_png(&cache.join("a.png")).unwrap(), other[0]);

    // Other pixels (same names): recomputed.
    write_stamp_tamper(&cache, "a.png");
    s.views[0].image = square_image(24, 20, (3, 12, 2, 10));
    let moved = edge_masks_cached(&s, &[0, 1], &cfg2, &cache).unwrap();
    assert_eq!(moved[0], edge_mask(&s, 0, &cfg2).unwrap());
    assert!(moved[0].edge_fraction() > 0.0);

    // A damaged stamp or a missing mask file: recomputed.
    std::fs::write(cache.join("stamp.json"), "{").unwrap();
    assert_eq!(edge_masks_cached(&s, &[0, 1], &cfg2, &cache).unwrap(), moved);
    std::fs::remove_file(cache.join("b.png")).unwrap();
    assert_eq!(edge_masks_cached(&s, &[0, 1], &cfg2, &cache).unwrap(), moved);
    assert!(cache.join("b.png").is_file());
}
