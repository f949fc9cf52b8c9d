#!/usr/bin/env python3
"""Regenerates tests/fixtures/metrics/: image pairs with scikit-image's SSIM and PSNR.

The Rust SSIM/PSNR (engine/src/metrics/image.rs) must match scikit-image's
`structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1, channel_axis=-1)` and
`peak_signal_noise_ratio(a, b, data_range=1)`; tests/metrics_image.rs checks the values
written here to 1e-4 (SSIM) and 1e-4 dB (PSNR).

Usage (from anywhere; nothing is installed inside the repository):

    python3 tools/metrics-fixtures/make_fixtures.py

It creates (first run only) a virtual environment under
~/.cache/edgenerf/metrics-venv (override with EDGENERF_METRICS_VENV) holding numpy and
scikit-image from PyPI, re-runs itself inside it, and writes

* tests/fixtures/metrics/pairs.npz: float32 arrays, H=32 x W=40 (x 3 for RGB):
  `<pair>_a`, `<pair>_b` for every pair, and `mask` (H x W, 0/1) for the masked pair;
* tests/fixtures/metrics/values.json: per pair, skimage's `ssim` and `psnr` on the
  float32 arrays promoted to float64 (exactly what the Rust test reads), the
  library versions, and for the masked pair `masked_psnr` (MSE over mask pixels and
  channels) and `masked_ssim` (SSIM of `img * mask + (1 - mask)` composites).

Everything is deterministic (fixed seeds, a crop of a committed synthetic render).
"""

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "tests" / "fixtures" / "metrics"
VENV = Path(os.environ.get("EDGENERF_METRICS_VENV", Path.home() / ".cache" / "edgenerf" / "metrics-venv"))
RENDER = REPO / "synthetic-scenes" / "small" / "creases" / "train" / "r_000.png"
MASK = REPO / "synthetic-scenes" / "small" / "creases" / "train" / "r_000_mask.png"
# The crop of the 128x128 render used as the natural image: rows, columns.
CROP = (slice(44, 76), slice(44, 84))


def ensure_venv():
    """Re-executes this script inside the metrics venv, creating it if needed."""
    py = VENV / "bin" / "python"
    if Path(sys.prefix).resolve() == VENV.resolve():
        return
    if not py.exists():
        print(f"creating {VENV} (numpy, scikit-image from PyPI)", file=sys.stderr)
        venv.create(VENV, with_pip=True)
        subprocess.check_call([str(py), "-m", "pip", "install", "-q", "numpy", "scikit-image"])
    os.execv(str(py), [str(py), __file__, *sys.argv[1:]])


def main():
    import numpy as np
    import scipy
    import skimage
    from PIL import Image
    from scipy import ndimage
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    def f32(x):
        return np.clip(x, 0.0, 1.0).astype(np.float32)

    rgba = np.asarray(Image.open(RENDER), dtype=np.float64) / 255.0
    render = rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])  # over white, as the loader
    render = f32(render[CROP])
    mask = (np.asarray(Image.open(MASK), dtype=np.float64)[CROP] > 127).astype(np.float32)

    rng = np.random.default_rng(20240611)
    h, w, _ = render.shape
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w]).reshape(2, 1, 1)
    pattern = f32(np.stack([0.5 + 0.4 * np.sin(7 * xx + 3 * yy), yy, 0.5 + 0.3 * np.cos(11 * xx * yy)], -1)
                  + rng.uniform(-0.1, 0.1, (h, w, 3)))

    pairs = {
        "noise": (render, f32(render + rng.normal(0.0, 0.05, render.shape))),
        "blur": (render, f32(ndimage.gaussian_filter(render.astype(np.float64), (1.0, 1.0, 0.0)))),
        "shift": (render, np.roll(render, (2, 1), axis=(0, 1))),
        "perturbed": (render, f32(1.03 * render ** 1.15 + 0.02 + rng.normal(0.0, 0.01, render.shape))),
        "pattern": (pattern, f32(pattern + rng.uniform(-0.2, 0.2, pattern.shape))),
    }

    def ssim(a, b):
        return float(structural_similarity(a.astype(np.float64), b.astype(np.float64), gaussian_weights=True,
                                           sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1))

    def psnr(a, b):
        return float(peak_signal_noise_ratio(a.astype(np.float64), b.astype(np.float64), data_range=1.0))

    values = {}
    arrays = {"mask": mask}
    for name, (a, b) in pairs.items():
        assert a.dtype == np.float32 and b.dtype == np.float32 and a.shape == (32, 40, 3)
        arrays[f"{name}_a"], arrays[f"{name}_b"] = a, b
        values[name] = {"ssim": ssim(a, b), "psnr": psnr(a, b)}

    # DTU-style masked metrics on the noise pair.
    a, b = (x.astype(np.float64) for x in pairs["noise"])
    m = mask.astype(np.float64)[..., None]
    mse = float(((a - b) ** 2 * m).sum() / (m.sum() * 3))
    values["noise"]["masked_psnr"] = float(10 * np.log10(1.0 / mse))
    values["noise"]["masked_ssim"] = ssim(a * m + (1 - m), b * m + (1 - m))

    OUT.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT / "pairs.npz", **arrays)
    doc = {
        "generator": "tools/metrics-fixtures/make_fixtures.py",
        "versions": {"numpy": np.__version__, "scipy": scipy.__version__, "scikit-image": skimage.__version__},
        "ssim_call": "structural_similarity(a, b, gaussian_weights=True, sigma=1.5, "
                     "use_sample_covariance=False, data_range=1, channel_axis=-1)",
        "psnr_call": "peak_signal_noise_ratio(a, b, data_range=1)",
        "pairs": values,
    }
    (OUT / "values.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(values, indent=2))


if __name__ == "__main__":
    ensure_venv()
    main()
