#!/usr/bin/env python3
"""Renders the synthetic ground-truth scenes with Mitsuba 3 (variant scalar_rgb).

    render.py [--preset small|full] [--scene NAME ...] [--out DIR] [--progress-lines]
    render.py --check DIR [--scene NAME ...]     # drift check against committed renders
    render.py --list

Per scene it writes a NeRF-synthetic style folder (see README.md for every field):

    transforms_train.json, transforms_test.json
    train/r_000.png          RGB (RGBA with alpha = coverage for transparent scenes)
    train/r_000_depth.exr    float32 channel "Y": ray distance from the camera centre, 0 = miss
    train/r_000_normal.exr   float32 "R","G","B": world-space unit normal toward the camera, 0 = miss
    train/r_000_mask.png     8-bit gray: 255 where the pixel-centre ray hits a surface
    test/...                 the same for the test views

RGB: `path` integrator, multi-jittered sampler, box pixel filter (each pixel is the
average over its own square footprint), fixed per-view seeds. Depth / normals / mask:
`aov` integrator with one sample per pixel exactly at the pixel centre (stratified
sampler without jitter, box filter), so the ground truth is the value at
(x + 0.5, y + 0.5). Mitsuba measures `dd.y` from the near-clip point, not from the
camera centre; the offset (near_clip / cos(angle to the optical axis)) is added back.
Every view is cross-checked against rays we cast ourselves from the NeRF camera.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import gtcheck  # noqa: E402
import gtio  # noqa: E402
import scenes as scene_defs  # noqa: E402
from geometry import icosphere, merge_surfaces, write_ply  # noqa: E402

MITSUBA_VERSION = "3.9.1"
VARIANT = "scalar_rgb"
NEAR_CLIP = 0.01  # Mitsuba sensor near clip; its depth offset is corrected exactly
SEED_BASE = 1000
# EXR compression of the float32 depth / normal channels. PXR24 (zlib over byte planes
# of horizontal differences) keeps the top 24 bits of each float32: 16 significant bits,
# relative error <= 2^-16 (1.5e-5), far below a pixel footprint; it makes the files
# about half the size of lossless ZIP. OpenEXR, Mitsuba and the Rust `exr` crate read it.
EXR_COMPRESSION = "pxr24"
# Normal components are additionally rounded to multiples of 2^-12 (error <= 1.2e-4 per
# component, < 0.01 deg), which PXR24 then stores exactly; saves ~20 % on curved scenes.
NORMAL_STEP = 2.0**-12

# Presets: resolution of square (object / turntable) and 4:3 (forward) scenes, RGB
# samples per pixel, number of train / test views.
PRESETS = {
    "small": dict(square=(128, 128), wide=(128, 96), spp=144, train=24, test=8, max_depth=4),
    "full": dict(square=(512, 512), wide=(512, 384), spp=256, train=64, test=16, max_depth=5),
}
DEFAULT_OUT = {"small": HERE / "small", "full": HERE / "out-full"}
CHECK_DEFAULT_SCENES = ["creases"]


# --------------------------------------------------------------------------- mitsuba


def _mi():
    import mitsuba as mi

    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    return mi


def nerf_to_mitsuba(c2w: np.ndarray) -> np.ndarray:
    """NeRF/OpenGL camera-to-world (camera looks down -z, +x right, +y up) to the
    `to_world` of Mitsuba's perspective sensor (looks down +z, +x is image-left)."""
    return np.asarray(c2w, float) @ np.diag([-1.0, 1.0, -1.0, 1.0])


def _srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _material(mi, shape: scene_defs.Shape) -> dict:
    if shape.texture is not None:
        # Mitsuba maps v = 0 to the first row of the bitmap; our textures have row 0 at
        # the top (v = 1), so flip them.
        tex = np.ascontiguousarray(np.flipud(shape.texture), np.float32)
        refl = {"type": "bitmap", "bitmap": mi.Bitmap(tex),
                "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat"}
    else:
        refl = {"type": "rgb", "value": list(shape.color)}
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": refl}}


def build_mitsuba_scene(spec: scene_defs.SceneSpec, shapes: list[scene_defs.Shape], tmp: Path, rgb_integrator: dict):
    mi = _mi()
    T = mi.ScalarTransform4f
    d: dict = {"type": "scene", "integrator": rgb_integrator}
    d["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(spec.sky)}}
    sun = np.asarray(spec.sun_dir, float)
    d["sun"] = {"type": "directional", "direction": list(sun / np.linalg.norm(sun)),
                "irradiance": {"type": "rgb", "value": [spec.sun_irradiance * c for c in (1.0, 0.96, 0.9)]}}
    for i, s in enumerate(shapes):
        if s.sphere is not None:
            c, r = s.sphere
            sd = {"type": "sphere", "to_world": T().translate(list(c)).scale(r)}
        else:
            path = tmp / f"{i:02d}_{s.name}.ply"
            write_ply(path, s.mesh)
            sd = {"type": "ply", "filename": str(path), "face_normals": s.mesh.N is None}
        sd["bsdf"] = _material(mi, s)
        d[f"{i:02d}_{s.name}"] = sd
    return mi.load_dict(d)


def gt_mesh(shapes: list[scene_defs.Shape]):
    """Every shape of the scene as one world-space triangle mesh (analytic spheres as
    icospheres): the ground truth of mesh metrics (`gt_mesh.ply`)."""
    return merge_surfaces([icosphere(s.sphere[0], s.sphere[1]) if s.sphere is not None else s.mesh for s in shapes])


def check_inside_aabb(spec: scene_defs.SceneSpec, shapes: list[scene_defs.Shape]) -> None:
    lo, hi = np.array(spec.aabb[0]), np.array(spec.aabb[1])
    for s in shapes:
        if s.sphere is not None:
            c, r = np.array(s.sphere[0]), s.sphere[1]
            a, b = c - r, c + r
        else:
            a, b = s.mesh.bounds()
        if np.any(a < lo - 1e-6) or np.any(b > hi + 1e-6):
            raise SystemExit(f"{spec.name}: shape {s.name} [{a}, {b}] leaves the scene aabb {spec.aabb}")


def _sensor(mi, c2w, w, h, fov_x, sampler: dict, pixel_format: str):
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "perspective", "fov": fov_x, "fov_axis": "x", "near_clip": NEAR_CLIP, "far_clip": 1.0e4,
        "to_world": T(nerf_to_mitsuba(c2w).tolist()),
        "sampler": sampler,
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": pixel_format, "component_format": "float32"},
    })


def camera_rays(c2w: np.ndarray, w: int, h: int, fx: float, fy: float, cx: float, cy: float):
    """World-space unit directions through every pixel centre, and 1/cos to the axis."""
    u = np.arange(w) + 0.5
    v = np.arange(h) + 0.5
    U, V = np.meshgrid(u, v)
    dc = np.stack([(U - cx) / fx, -(V - cy) / fy, -np.ones_like(U)], -1)
    norm = np.linalg.norm(dc, axis=-1)
    dw = (dc / norm[..., None]) @ np.asarray(c2w)[:3, :3].T
    return dw, norm


def render_view(mi, scene, c2w, spec, preset, seed, intr):
    w, h = intr["w"], intr["h"]
    # ---- ground truth: one ray per pixel, exactly through the pixel centre
    aov = mi.load_dict({"type": "aov", "aovs": "dd.y:depth,nn:sh_normal"})
    s_aov = _sensor(mi, c2w, w, h, spec.fov_x, {"type": "stratified", "sample_count": 1, "jitter": False}, "rgb")
    a = np.array(mi.render(scene, sensor=s_aov, integrator=aov, spp=1, seed=0), dtype=np.float32)
    if a.shape != (h, w, 4):
        raise RuntimeError(f"unexpected AOV output shape {a.shape}")
    dirs, inv_cos = camera_rays(c2w, w, h, intr["fl_x"], intr["fl_y"], intr["cx"], intr["cy"])
    hit = a[..., 0] > 0
    depth = np.where(hit, a[..., 0].astype(np.float64) + NEAR_CLIP * inv_cos, 0.0).astype(np.float32)
    n = a[..., 1:4].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    flip = np.sum(n * dirs, axis=-1) > 0
    n[flip] *= -1
    n[~hit] = 0
    normal = (np.round(n / NORMAL_STEP) * NORMAL_STEP).astype(np.float32)
    mask = np.where(hit, 255, 0).astype(np.uint8)
    # ---- RGB: path tracing, box filter over the pixel footprint
    rgb_sampler = {"type": "multijitter", "sample_count": preset["spp"], "seed": seed}
    s_rgb = _sensor(mi, c2w, w, h, spec.fov_x, rgb_sampler, "rgba")
    img = np.array(mi.render(scene, sensor=s_rgb, spp=preset["spp"], seed=seed), dtype=np.float64)
    alpha = np.clip(img[..., 3], 0.0, 1.0)
    if spec.background == "transparent":
        straight = np.where(alpha[..., None] > 1e-6, img[..., :3] / np.maximum(alpha[..., None], 1e-6), 0.0)
        rgba = np.concatenate([_srgb(straight), alpha[..., None]], -1)
        rgb8 = np.round(rgba * 255).astype(np.uint8)
    else:
        rgb8 = np.round(_srgb(img[..., :3]) * 255).astype(np.uint8)
    _self_check(mi, scene, c2w, depth, dirs, seed)
    return rgb8, depth, normal, mask


def _self_check(mi, scene, c2w, depth, dirs, seed, n=96):
    """Casts rays ourselves from the NeRF camera through random pixel centres and
    compares their hit distance with the AOV depth: validates the sensor conversion,
    the pixel-centre sampling and the near-clip correction on every view."""
    rng = np.random.default_rng(seed)
    h, w = depth.shape
    ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
    o = mi.Point3f(*[float(v) for v in np.asarray(c2w)[:3, 3]])
    bad = 0
    for y, x in zip(ys, xs):
        d = dirs[y, x]
        si = scene.ray_intersect(mi.Ray3f(o, mi.Vector3f(float(d[0]), float(d[1]), float(d[2]))))
        t = float(si.t) if si.is_valid() else 0.0
        ref = float(depth[y, x])
        if (t > 0) != (ref > 0) or (t > 0 and abs(t - ref) > 1e-4 * t + 1e-5):
            bad += 1
    if bad > max(1, n // 50):
        raise RuntimeError(f"AOV depth disagrees with our own camera rays on {bad}/{n} pixels: "
                           "camera convention or pixel-centre sampling is broken")


# --------------------------------------------------------------------------- output


def intrinsics(spec, preset) -> dict:
    w, h = preset["square"] if spec.aspect == 1.0 else preset["wide"]
    fx = 0.5 * w / math.tan(0.5 * math.radians(spec.fov_x))
    return dict(w=w, h=h, fl_x=fx, fl_y=fx, cx=w / 2, cy=h / 2, camera_angle_x=math.radians(spec.fov_x))


def _transforms(spec, preset_name, preset, intr, split, c2ws) -> dict:
    frames = []
    for i, c2w in enumerate(c2ws):
        stem = f"{split}/r_{i:03d}"
        frames.append({
            "file_path": f"{stem}.png",
            "depth_path": f"{stem}_depth.exr",
            "normal_path": f"{stem}_normal.exr",
            "mask_path": f"{stem}_mask.png",
            "transform_matrix": [[float(v) for v in row] for row in np.asarray(c2w)],
        })
    return {
        "camera_angle_x": intr["camera_angle_x"],
        "fl_x": intr["fl_x"], "fl_y": intr["fl_y"], "cx": intr["cx"], "cy": intr["cy"],
        "w": intr["w"], "h": intr["h"],
        "near": spec.near, "far": spec.far,
        "aabb": [list(spec.aabb[0]), list(spec.aabb[1])],
        "scene": spec.name,
        "scene_description": spec.description,
        "layout": spec.layout,
        "background": spec.background,
        "conventions": {
            "camera": "OpenGL/NeRF c2w: camera looks down -z, +x right, +y up; world +z up",
            "pixel_centres": "pixel (x, y) has its centre at (x + 0.5, y + 0.5); ground truth is sampled there",
            "depth": "ray distance from the camera centre in world units (not z-depth); 0 = no surface",
            "normal": "world-space unit shading normal, flipped to face the camera; (0,0,0) = no surface",
            "mask": "255 where the pixel-centre ray hits a surface, else 0",
            "rgb": ("8-bit sRGB, pixel-footprint (box filter) average; RGBA with straight alpha = coverage"
                    if spec.background == "transparent" else "8-bit sRGB, pixel-footprint (box filter) average"),
        },
        "renderer": {
            "mitsuba": MITSUBA_VERSION, "variant": VARIANT, "preset": preset_name,
            "integrator": "path", "max_depth": preset["max_depth"], "spp": preset["spp"],
            "sampler": "multijitter", "rfilter": "box", "seed_base": SEED_BASE,
        },
        "frames": frames,
    }


def render_scene(name, preset_name, preset, out_root: Path, progress, state) -> dict:
    spec = scene_defs.SCENES[name]
    mi = _mi()
    shapes = spec.build()
    check_inside_aabb(spec, shapes)
    intr = intrinsics(spec, preset)
    train, test = spec.cameras(preset["train"], preset["test"])
    final = out_root / name
    work = out_root / f".{name}.partial"
    if work.exists():
        shutil.rmtree(work)
    (work / "train").mkdir(parents=True)
    (work / "test").mkdir()
    write_ply(work / "gt_mesh.ply", gt_mesh(shapes), compact=True)
    stats = {"depth_min": math.inf, "depth_max": 0.0}
    t0 = time.time()
    with tempfile.TemporaryDirectory(prefix=f"edgenerf-{name}-") as tmp:
        integ = {"type": "path", "max_depth": preset["max_depth"], "hide_emitters": spec.background == "transparent"}
        scene = build_mitsuba_scene(spec, shapes, Path(tmp), integ)
        for split, c2ws in (("train", train), ("test", test)):
            for i, c2w in enumerate(c2ws):
                seed = SEED_BASE + (0 if split == "train" else 500) + i
                rgb8, depth, normal, mask = render_view(mi, scene, c2w, spec, preset, seed, intr)
                stem = work / split / f"r_{i:03d}"
                gtio.write_png(f"{stem}.png", rgb8)
                gtio.write_exr(f"{stem}_depth.exr", {"Y": depth}, EXR_COMPRESSION)
                gtio.write_exr(f"{stem}_normal.exr", {"R": normal[..., 0], "G": normal[..., 1], "B": normal[..., 2]},
                               EXR_COMPRESSION)
                gtio.write_png(f"{stem}_mask.png", mask)
                hit = depth > 0
                if hit.any():
                    stats["depth_min"] = min(stats["depth_min"], float(depth[hit].min()))
                    stats["depth_max"] = max(stats["depth_max"], float(depth[hit].max()))
                state["done"] += 1
                progress(state["done"], state["total"], f"{name} {split}/r_{i:03d}")
    if not (spec.near <= stats["depth_min"] and stats["depth_max"] <= spec.far):
        raise SystemExit(f"{name}: depths [{stats['depth_min']:.3f}, {stats['depth_max']:.3f}] leave "
                         f"near/far [{spec.near}, {spec.far}]")
    for split, c2ws in (("train", train), ("test", test)):
        doc = _transforms(spec, preset_name, preset, intr, split, c2ws)
        (work / f"transforms_{split}.json").write_text(json.dumps(doc, indent=1) + "\n")
    if final.exists():
        shutil.rmtree(final)
    work.rename(final)
    stats["seconds"] = time.time() - t0
    return stats


# --------------------------------------------------------------------------- CLI


def _progress_printer(machine: bool):
    tty = sys.stderr.isatty()
    t0 = time.time()

    def progress(done: int, total: int, msg: str) -> None:
        if machine:
            print(f"progress {done} {total} {msg}", flush=True)
            return
        el = time.time() - t0
        eta = el / done * (total - done) if done else 0.0
        line = f"[{done:4d}/{total}] {msg:<28s} {el:6.1f}s elapsed, ~{eta:5.1f}s left"
        if tty:
            sys.stderr.write("\r" + line + ("\n" if done == total else ""))
            sys.stderr.flush()
        else:
            print(line, file=sys.stderr, flush=True)

    return progress


def _set_threads(n: int | None) -> None:
    import drjit as dr

    _mi()
    dr.set_thread_count(n or os.cpu_count() or 2)


def cmd_render(args) -> int:
    preset = dict(PRESETS[args.preset])
    for k in ("spp", "train", "test"):
        if getattr(args, k) is not None:
            preset[k] = getattr(args, k)
    out = Path(args.out) if args.out else DEFAULT_OUT[args.preset]
    out.mkdir(parents=True, exist_ok=True)
    names = args.scene or list(scene_defs.SCENES)
    _set_threads(args.threads)
    state = {"done": 0, "total": sum(preset["train"] + preset["test"] for _ in names)}
    progress = _progress_printer(args.progress_lines)
    t0 = time.time()
    for name in names:
        st = render_scene(name, args.preset, preset, out, progress, state)
        msg = (f"{name}: {preset['train']}+{preset['test']} views in {st['seconds']:.1f}s, "
               f"depth [{st['depth_min']:.2f}, {st['depth_max']:.2f}] -> {out / name}")
        print(f"info {msg}" if args.progress_lines else msg, flush=True)
    print(("info " if args.progress_lines else "") + f"rendered {len(names)} scene(s) in {time.time() - t0:.1f}s",
          flush=True)
    return 0


def cmd_gt_mesh(args) -> int:
    """Writes only gt_mesh.ply into already rendered scene folders (no Mitsuba)."""
    out = Path(args.out) if args.out else DEFAULT_OUT[args.preset]
    for name in args.scene or list(scene_defs.SCENES):
        folder = out / name
        if not (folder / "transforms_train.json").is_file():
            raise SystemExit(f"{folder} holds no rendered scene (no transforms_train.json); render it first")
        shapes = scene_defs.SCENES[name].build()
        check_inside_aabb(scene_defs.SCENES[name], shapes)
        tmp = folder / "gt_mesh.ply.partial"
        write_ply(tmp, gt_mesh(shapes), compact=True)
        tmp.rename(folder / "gt_mesh.ply")
        print(f"{name}: wrote {folder / 'gt_mesh.ply'} ({(folder / 'gt_mesh.ply').stat().st_size} bytes)", flush=True)
    return 0


def cmd_check(args) -> int:
    committed = Path(args.check)
    names = args.scene or CHECK_DEFAULT_SCENES
    _set_threads(args.threads)
    ok = True
    results = []
    with tempfile.TemporaryDirectory(prefix="edgenerf-check-") as tmp:
        for name in names:
            meta = json.loads((committed / name / "transforms_train.json").read_text())
            r = meta["renderer"]
            preset = dict(PRESETS[r["preset"]])
            n_test = len(json.loads((committed / name / "transforms_test.json").read_text())["frames"])
            preset.update(spp=r["spp"], max_depth=r["max_depth"], train=len(meta["frames"]), test=n_test)
            state = {"done": 0, "total": preset["train"] + preset["test"]}
            t0 = time.time()
            render_scene(name, r["preset"], preset, Path(tmp), _progress_printer(args.progress_lines), state)
            print(f"{name}: re-rendered {state['total']} views in {time.time() - t0:.1f}s", flush=True)
            results += gtcheck.compare_scenes(committed / name, Path(tmp) / name)
            results += gtcheck.check_scene(Path(tmp) / name)
    # consistency of every committed scene (NumPy only, a few seconds each)
    for d in sorted(p for p in committed.iterdir() if (p / "transforms_train.json").is_file()):
        results += gtcheck.check_scene(d)
    for r in results:
        print(r.line())
        ok &= r.ok
    npass = sum(r.ok for r in results)
    print(f"drift check: {npass} passed, {len(results) - npass} failed")
    return 0 if ok else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", choices=sorted(PRESETS), default="small")
    ap.add_argument("--scene", nargs="+", action="extend", choices=sorted(scene_defs.SCENES), metavar="NAME",
                    help=f"scenes to render (default: all): {', '.join(scene_defs.SCENES)}")
    ap.add_argument("--out", help="output root (default: synthetic-scenes/small or synthetic-scenes/out-full)")
    ap.add_argument("--progress-lines", action="store_true",
                    help="print machine-readable 'progress <done> <total> <message>' lines on stdout")
    ap.add_argument("--threads", type=int, help="render threads (default: all cores)")
    ap.add_argument("--spp", type=int, help="override the preset's RGB samples per pixel")
    ap.add_argument("--train", type=int, help="override the preset's number of training views")
    ap.add_argument("--test", type=int, help="override the preset's number of test views")
    ap.add_argument("--check", metavar="DIR",
                    help="drift check: re-render --scene (default: creases) into a temp dir, compare with "
                         "DIR/<scene>, and run the consistency checks on it and on every scene in DIR; "
                         "exit 1 on any failure")
    ap.add_argument("--list", action="store_true", help="list the scenes and exit")
    ap.add_argument("--gt-mesh-only", action="store_true",
                    help="write only each scene's gt_mesh.ply into its existing folder under --out (no rendering)")
    args = ap.parse_args(argv)
    if args.list:
        for s in scene_defs.SCENES.values():
            print(f"{s.name:10s} {s.layout:9s} {s.description}")
        return 0
    if args.check:
        return cmd_check(args)
    if args.gt_mesh_only:
        return cmd_gt_mesh(args)
    return cmd_render(args)


if __name__ == "__main__":
    sys.exit(main())
