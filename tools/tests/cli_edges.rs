//! `edgenerf edges` as a user runs it: masks and overlays of a committed synthetic
//! scene, the external-map path (its own masks read back as dark-edge maps), `--all`
//! with repeated view names, `--edges none`, and clear errors for a bad `--edges` dir.

use std::path::{Path, PathBuf};
mod common;

use common::{edgenerf, repo, text};


fn scene(name: &str) -> PathBuf {
    repo().join("synthetic-scenes/small").join(name)
}


/// Width and height from a PNG's IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[1..4], b"PNG", "{} is not a PNG", path.display());
    let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    (be(16), be(20))
}

#[test]
fn edges_writes_masks_and_overlays_and_reads_external_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("canny");
    let occlusion = scene("occlusion");
    let o = edgenerf(&["edges", occlusion.to_str().unwrap(), "--views", "3", "--out", out.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("canny on luma") && t.contains("mean edge fraction"), "{t}");
    assert_eq!(t.matches("edge fraction 0.").count(), 4, "three views and the mean:\n{t}");
    // The 3-view split of the 24 training frames: 0, 12, 23.
    for name in ["r_000", "r_012", "r_023"] {
        for f in [format!("{name}.png"), format!("{name}_overlay.png")] {
            assert_eq!(png_size(&out.join(&f)), (128, 96), "{f}; output:\n{t}");
        }
    }
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 6, "only the training views");

    // The masks are dark-edge maps: read back without dilation they give the same masks.
    let back = tmp.path().join("back");
    let o = edgenerf(&[
        "edges",
        occlusion.to_str().unwrap(),
        "--views",
        "3",
        "--out",
        back.to_str().unwrap(),
        "--edges",
        out.to_str().unwrap(),
        "--edge-polarity",
        "dark",
        "--tau-e",
        "128",
        "--no-dilate",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("external maps in"), "{}", text(&o));
    for name in ["r_000.png", "r_012.png", "r_023.png"] {
        assert_eq!(std::fs::read(back.join(name)).unwrap(), std::fs::read(out.join(name)).unwrap(), "{name}");
    }

    // `--edges none`: no edge pixels.
    let none = tmp.path().join("none");
    let o = edgenerf(&["edges", occlusion.to_str().unwrap(), "--views", "3", "--out", none.to_str().unwrap(), "--edges", "none"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("mean edge fraction 0.000"), "{}", text(&o));
}

#[test]
fn edges_all_names_repeated_test_views_apart() {
    let tmp = tempfile::tempdir().unwrap();
    let o = edgenerf(&["edges", scene("turntable").to_str().unwrap(), "--all", "--out", tmp.path().to_str().unwrap(), "--canny-sigma", "1.4"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("sigma 1.4 px"), "{t}");
    // 24 training and 8 test views; the test views' names repeat r_000..r_007.
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 2 * 32, "{t}");
    for f in ["r_000.png", "r_023_overlay.png", "test_r_000.png", "test_r_007_overlay.png"] {
        assert!(tmp.path().join(f).is_file(), "{f} missing:\n{t}");
    }
}

#[test]
fn a_bad_edges_dir_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let occlusion = scene("occlusion");
    let out = tmp.path().join("out");
    let o = edgenerf(&["edges", occlusion.to_str().unwrap(), "--views", "3", "--out", out.to_str().unwrap(), "--edges", "/no/such/edge/maps"]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("/no/such/edge/maps") && t.contains("not found"), "{t}");
    assert!(!t.contains("stack backtrace"), "{t}");

    // A directory without the view's map: names the expected file and what is there.
    let maps = tmp.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    std::fs::write(maps.join("notes.txt"), "not a map").unwrap();
    let o = edgenerf(&["edges", occlusion.to_str().unwrap(), "--views", "3", "--out", out.to_str().unwrap(), "--edges", maps.to_str().unwrap()]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("r_000.png") && t.contains("no PNG or JPEG files"), "{t}");
}
