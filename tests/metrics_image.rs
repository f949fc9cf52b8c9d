//! PSNR and SSIM against scikit-image, on the pairs in `tests/fixtures/metrics/`
//! (written by `tools/metrics-fixtures/make_fixtures.py`, which documents how to
//! regenerate them): SSIM must match `structural_similarity(..., gaussian_weights=True,
//! sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1)` to 1e-4 and
//! PSNR `peak_signal_noise_ratio(..., data_range=1)` to 1e-4 dB, plain and with the DTU
//! mask protocol.

use std::path::PathBuf;

use edgenerf::data::npy::{NpyArray, Npz};
use edgenerf::metrics::{image_metrics, masked_image_metrics};

const TOL: f64 = 1e-4;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests").join("fixtures").join("metrics")
}

fn f32s(a: &NpyArray) -> Vec<f32> {
    a.data.iter().map(|&v| v as f32).collect()
}

#[test]
fn psnr_and_ssim_match_scikit_image() {
    let npz = Npz::read(&fixtures().join("pairs.npz")).unwrap();
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("values.json")).unwrap()).unwrap();
    let pairs = doc["pairs"].as_object().unwrap();
    assert!(pairs.len() >= 5, "expected at least 5 fixture pairs");
    let mut worst = (0.0f64, 0.0f64);
    let mut checked = 0;
    for (name, want) in pairs {
        let a = npz.require(&format!("{name}_a")).unwrap();
        let b = npz.require(&format!("{name}_b")).unwrap();
        assert_eq!(a.shape, [32, 40, 3], "{name}");
        let (h, w) = (a.shape[0] as u32, a.shape[1] as u32);
        let (a, b) = (f32s(a), f32s(b));
        let got = image_metrics(w, h, &a, &b).unwrap();
        let (ssim, psnr) = (want["ssim"].as_f64().unwrap(), want["psnr"].as_f64().unwrap());
        eprintln!("{name:10} SSIM {:.6} (skimage {ssim:.6})  PSNR {:.5} dB (skimage {psnr:.5})", got.ssim, got.psnr);
        assert!((got.ssim - ssim).abs() < TOL, "{name}: SSIM {} vs skimage {ssim}", got.ssim);
        assert!((got.psnr - psnr).abs() < TOL, "{name}: PSNR {} vs skimage {psnr}", got.psnr);
        worst = (worst.0.max((got.ssim - ssim).abs()), worst.1.max((got.psnr - psnr).abs()));
        checked += 1;
        if let (Some(mp), Some(ms)) = (want.get("masked_psnr"), want.get("masked_ssim")) {
            let mask = f32s(npz.require("mask").unwrap());
            let got = masked_image_metrics(w, h, &a, &b, &mask).unwrap();
            let (mp, ms) = (mp.as_f64().unwrap(), ms.as_f64().unwrap());
            eprintln!("{name:10} masked SSIM {:.6} (skimage {ms:.6})  PSNR {:.5} dB (numpy {mp:.5})", got.ssim, got.psnr);
            assert!((got.ssim - ms).abs() < TOL, "{name}: masked SSIM {} vs {ms}", got.ssim);
            assert!((got.psnr - mp).abs() < TOL, "{name}: masked PSNR {} vs {mp}", got.psnr);
            worst = (worst.0.max((got.ssim - ms).abs()), worst.1.max((got.psnr - mp).abs()));
            checked += 1;
        }
    }
    eprintln!("{checked} comparisons; max deviation: SSIM {:.2e}, PSNR {:.2e} dB", worst.0, worst.1);
}
