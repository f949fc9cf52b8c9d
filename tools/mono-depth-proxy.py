#!/usr/bin/env python3
"""Monocular-depth stand-ins made from a synthetic scene's ground truth, to measure what
a monocular depth prior of a given quality buys (`priors.mono_depth_dir`) where no
monocular network can run. Not a prior: the maps come from the true depth.

    tools/mono-depth-proxy.py SCENE OUT [--error 0.04] [--blur 1.0] [--seed 0]

For every frame of SCENE/transforms_train.json (a Blender-format scene with
`*_depth.exr`, channel Y = ray distance, as synthetic-scenes/ renders them) it writes
OUT/<image stem>.npy: relative disparity as MiDaS and Depth Anything write it,
`s / z' + b` with a random scale `s` and shift `b` per image, where `z'` is the true
z-depth times `exp(error * n)`, `n` a smooth random field (Gaussian-filtered white
noise, sigma 12 pixels, scaled to unit standard deviation): errors that vary slowly
over the image, as a network's do. The disparity is then blurred by a Gaussian of
`blur` pixels (soft depth edges). `--error 0 --blur 0`: the exact disparity up to the
affine map. Needs numpy and OpenEXR (pip install numpy OpenEXR).
"""
import argparse
import json
import math
import os
import sys

import numpy as np


def gaussian(image, sigma):
    """Separable Gaussian filter with reflected borders (numpy only)."""
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    out = image
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        padded = np.pad(out, pad, mode="reflect")
        out = np.apply_along_axis(lambda v: np.convolve(v, k, mode="valid"), axis, padded)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--error", type=float, default=0.04, help="std of the smooth log-depth error (0.04: about 4 %%)")
    ap.add_argument("--blur", type=float, default=1.0, help="Gaussian blur of the disparity, in pixels")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    try:
        import OpenEXR
        import Imath
    except ImportError:
        sys.exit("mono-depth-proxy: needs OpenEXR (pip install OpenEXR numpy)")
    meta_path = os.path.join(a.scene, "transforms_train.json")
    if not os.path.isfile(meta_path):
        sys.exit(f"mono-depth-proxy: {meta_path} not found (a Blender-format synthetic scene is needed)")
    if os.path.exists(a.out) and os.listdir(a.out):
        sys.exit(f"mono-depth-proxy: {a.out} exists and is not empty; choose a new folder")
    os.makedirs(a.out, exist_ok=True)
    meta = json.load(open(meta_path))
    rng = np.random.default_rng(a.seed)
    for frame in meta["frames"]:
        base = os.path.splitext(os.path.join(a.scene, frame["file_path"]))[0]
        exr_path = frame.get("depth_path")
        exr_path = os.path.join(a.scene, exr_path) if exr_path else base + "_depth.exr"
        if not os.path.isfile(exr_path):
            sys.exit(f"mono-depth-proxy: {exr_path} not found: the scene has no ground-truth depth")
        exr = OpenEXR.InputFile(exr_path)
        dw = exr.header()["dataWindow"]
        w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
        t = np.frombuffer(exr.channel("Y", Imath.PixelType(Imath.PixelType.FLOAT)), dtype=np.float32).reshape(h, w).astype(np.float64)
        fx = 0.5 * w / math.tan(0.5 * meta["camera_angle_x"])
        xs, ys = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
        z = t / np.sqrt(1 + (xs / fx) ** 2 + (ys / fx) ** 2)
        z[~(t > 0)] = np.nan
        if a.error > 0:
            n = gaussian(rng.standard_normal((h, w)), 12.0)
            z = z * np.exp(a.error * n / n.std())
        disparity = 1.0 / z
        if a.blur > 0:
            ok = np.isfinite(disparity)
            num = gaussian(np.where(ok, disparity, 0.0), a.blur)
            den = gaussian(ok.astype(np.float64), a.blur)
            disparity = np.where(ok, num / np.maximum(den, 1e-9), np.nan)
        s, b = rng.uniform(0.5, 5.0), rng.uniform(-0.2, 0.5)
        stem = os.path.splitext(os.path.basename(frame["file_path"]))[0]
        np.save(os.path.join(a.out, stem + ".npy"), (s * disparity + b).astype(np.float32))
    print(f"mono-depth-proxy: wrote {len(meta['frames'])} maps to {a.out}")


if __name__ == "__main__":
    main()
