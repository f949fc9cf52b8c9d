#!/usr/bin/env python3
"""Consistency checks of rendered synthetic scenes (NumPy only, no Mitsuba needed).

    python3 gtcheck.py synthetic-scenes/small/*      # check committed scenes
    python3 gtcheck.py --compare A B                 # drift: compare two renders

Checks on one scene (`check_scene`):
* files and fields: every frame's image, depth, normal and mask exist, sizes agree;
* mask == (depth > 0); normals unit length on hits, zero on misses, facing the camera;
  depth inside [near, far]; every hit point inside the aabb (1e-3 slack);
* reprojection: every view's depth is back-projected to world points and projected
  into its two nearest views; where the neighbour sees a continuous surface at the
  projected point (2x2 neighbourhood all hits, spread < 2 %) and the point is not
  behind that surface by more than 0.5 % (occluded in the neighbour), the bilinearly
  interpolated neighbour depth must match the point's distance to the neighbour's
  centre: >= 95 % of such pixels within 0.5 % relative, median below 1e-4 (clean
  renders: 1e-5 to 4e-5; a principal point off by half a pixel gives 2e-4 on
  object-centric scenes).
  Points seen in front of the neighbour's surface (free-space violations) must be
  < 2 %. This validates cameras, intrinsics, the pixel-centre convention and the
  depth convention together;
* normals from depth: on flat regions (3x3 neighbourhood of equal GT normals, within
  0.5 deg, and no depth kink), the normal of the back-projected point grid must match
  the GT normal: median angle < 0.1 deg, 95th percentile < 0.5 deg at 128 px (scaled
  with the width above that; clean renders: ~0.03 / ~0.1 deg, a half-pixel principal
  point error: > 0.12 deg median, which the near-parallel forward layouts need to see);
* transparent scenes: alpha agrees with the mask (alpha >= 0.5 <=> hit) on >= 98 %.

Drift (`compare_scenes`, used by `render.py --check`): same cameras (1e-6), masks
differ on <= 0.1 % of pixels, depth within 1e-4 relative and normals within 0.1 deg
on >= 99.9 % of pixels hit in both, RGB(A) PSNR >= 40 dB per image and mean absolute
difference <= 1/255 (path-tracing noise at the small preset is about 46 dB against a
converged image, so an independent seed would still pass; in practice the re-render is
bit-identical).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gtio  # noqa: E402


@dataclass
class Result:
    scene: str
    name: str
    ok: bool
    detail: str

    def line(self) -> str:
        return f"{'ok  ' if self.ok else 'FAIL'} {self.scene:10s} {self.name:24s} {self.detail}"


@dataclass
class View:
    name: str
    c2w: np.ndarray
    rgb: np.ndarray  # uint8 (H, W, 3 or 4)
    depth: np.ndarray
    normal: np.ndarray
    mask: np.ndarray  # uint8


@dataclass
class Loaded:
    root: Path
    meta: dict
    views: list[View]

    @property
    def intr(self):
        m = self.meta
        return m["fl_x"], m["fl_y"], m["cx"], m["cy"], m["w"], m["h"]


def load_scene(root: Path, images: bool = True) -> Loaded:
    root = Path(root)
    views, meta = [], None
    for split in ("train", "test"):
        doc = json.loads((root / f"transforms_{split}.json").read_text())
        meta = meta or doc
        for f in doc["frames"]:
            rgb = gtio.read_png(root / f["file_path"]) if images else np.zeros((0, 0, 3), np.uint8)
            n = gtio.read_exr(root / f["normal_path"])
            views.append(View(
                name=f["file_path"],
                c2w=np.array(f["transform_matrix"], float),
                rgb=rgb,
                depth=gtio.read_exr(root / f["depth_path"])["Y"],
                normal=np.stack([n["R"], n["G"], n["B"]], -1),
                mask=gtio.read_png(root / f["mask_path"])[..., 0],
            ))
    return Loaded(root, meta, views)


def pixel_dirs(c2w, fx, fy, cx, cy, w, h):
    U, V = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dc = np.stack([(U - cx) / fx, -(V - cy) / fy, -np.ones_like(U)], -1)
    dc /= np.linalg.norm(dc, axis=-1, keepdims=True)
    return dc @ c2w[:3, :3].T


def world_points(v: View, intr) -> np.ndarray:
    d = pixel_dirs(v.c2w, *intr)
    return v.c2w[:3, 3] + d * v.depth[..., None].astype(np.float64)


def project(c2w, pts, fx, fy, cx, cy):
    """World points -> (u, v) pixel coordinates (pixel centres at +0.5), camera-space
    depth along -z, and the distance to the camera centre."""
    R, o = c2w[:3, :3], c2w[:3, 3]
    pc = (pts - o) @ R  # world -> camera (R orthonormal)
    z = -pc[..., 2]
    u = cx + fx * pc[..., 0] / z
    v = cy - fy * pc[..., 1] / z
    return u, v, z, np.linalg.norm(pts - o, axis=-1)


def reprojection(a: View, b: View, intr):
    """Compares a's depth, seen from b, with b's depth. Returns relative errors on
    continuous-surface pixels and the number of free-space violations / tested."""
    fx, fy, cx, cy, w, h = intr
    P = world_points(a, intr)[a.depth > 0]
    u, v, z, dist = project(b.c2w, P, fx, fy, cx, cy)
    # bilinear cell of pixel centres
    x0 = np.floor(u - 0.5).astype(int)
    y0 = np.floor(v - 0.5).astype(int)
    inside = (z > 1e-6) & (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    x0, y0, fxr, fyr, dist = x0[inside], y0[inside], (u - 0.5 - np.floor(u - 0.5))[inside], \
        (v - 0.5 - np.floor(v - 0.5))[inside], dist[inside]
    D = b.depth.astype(np.float64)
    c00, c10, c01, c11 = D[y0, x0], D[y0, x0 + 1], D[y0 + 1, x0], D[y0 + 1, x0 + 1]
    corners = np.stack([c00, c10, c01, c11], -1)
    allhit = (corners > 0).all(-1)
    spread = (corners.max(-1) - corners.min(-1)) / np.maximum(corners.min(-1), 1e-9)
    cont = allhit & (spread < 0.02)
    interp = (c00 * (1 - fxr) * (1 - fyr) + c10 * fxr * (1 - fyr) + c01 * (1 - fxr) * fyr + c11 * fxr * fyr)
    rel = (interp - dist) / dist
    # points clearly behind the surface b sees are occluded in b: not comparable
    tested = cont & (rel > -5e-3)
    # a's point lying clearly in front of what b sees: b would have seen it
    nearest = np.where(allhit, corners.min(-1), np.where(corners.max(-1) > 0, corners.max(-1), np.inf))
    violation = (dist < nearest * (1 - 0.02)) & (corners > 0).any(-1)
    return rel[tested], int(violation.sum()), int(inside.sum())


def depth_normals(v: View, intr) -> tuple[np.ndarray, np.ndarray]:
    """Normals of the back-projected point grid (central differences), toward the
    camera, and the flat-region mask on which they are comparable with GT normals."""
    P = world_points(v, intr)
    n = np.zeros_like(P)
    du = P[1:-1, 2:] - P[1:-1, :-2]
    dv = P[2:, 1:-1] - P[:-2, 1:-1]
    c = np.cross(du, dv)
    c /= np.maximum(np.linalg.norm(c, axis=-1, keepdims=True), 1e-12)
    d = pixel_dirs(v.c2w, *intr)[1:-1, 1:-1]
    c[np.sum(c * d, -1) > 0] *= -1
    n[1:-1, 1:-1] = c
    # flat region: 3x3 all hits, GT normals equal (0.5 deg), depth second differences small
    hit = v.depth > 0
    N = v.normal.astype(np.float64)
    flat = np.zeros(hit.shape, bool)
    ok = hit[1:-1, 1:-1].copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            sl = (slice(1 + dy, v.depth.shape[0] - 1 + dy), slice(1 + dx, v.depth.shape[1] - 1 + dx))
            ok &= hit[sl]
            ok &= angle_deg(N[sl], N[1:-1, 1:-1]) < 0.5
    t = v.depth.astype(np.float64)
    ku = np.abs(t[1:-1, 2:] + t[1:-1, :-2] - 2 * t[1:-1, 1:-1])
    kv = np.abs(t[2:, 1:-1] + t[:-2, 1:-1] - 2 * t[1:-1, 1:-1])
    ok &= (ku < 0.01 * t[1:-1, 1:-1]) & (kv < 0.01 * t[1:-1, 1:-1])
    flat[1:-1, 1:-1] = ok
    return n, flat


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors (last axis) in degrees, robust near 0 (atan2 of |a x b| and
    a.b) and independent of their lengths (the stored normals are unit to ~3e-5)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, -1)))


def _nearest_views(views: list[View], k: int) -> list[list[int]]:
    C = np.array([v.c2w[:3, 3] for v in views])
    D = np.linalg.norm(C[:, None] - C[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    return [list(np.argsort(D[i])[:k]) for i in range(len(views))]


def check_scene(root: Path) -> list[Result]:
    root = Path(root)
    sc = load_scene(root)
    name = sc.meta.get("scene", root.name)
    intr = sc.intr
    fx, fy, cx, cy, w, h = intr
    out: list[Result] = []

    def add(test, ok, detail):
        out.append(Result(name, test, bool(ok), detail))

    # ---- per-pixel invariants
    bad_size = [v.name for v in sc.views if v.depth.shape != (h, w) or v.rgb.shape[:2] != (h, w)
                or v.mask.shape != (h, w) or v.normal.shape != (h, w, 3)]
    add("sizes", not bad_size, f"{len(sc.views)} views of {w}x{h}" + (f"; wrong: {bad_size[:3]}" if bad_size else ""))
    mask_bad = sum(int(np.sum((v.mask == 255) != (v.depth > 0)) + np.sum((v.mask != 0) & (v.mask != 255)))
                   for v in sc.views)
    add("mask == depth>0", mask_bad == 0, f"{mask_bad} mismatching pixels")
    unit_err, zero_bad, facing_bad, hits = 0.0, 0, 0, 0
    for v in sc.views:
        hit = v.depth > 0
        nl = np.linalg.norm(v.normal, axis=-1)
        if hit.any():
            unit_err = max(unit_err, float(np.abs(nl[hit] - 1).max()))
        zero_bad += int(np.sum(nl[~hit] != 0))
        d = pixel_dirs(v.c2w, *intr)
        facing_bad += int(np.sum(np.sum(v.normal * d, -1)[hit] > 2e-4))  # 2^-12 rounding
        hits += int(hit.sum())
    add("normals unit/zero", unit_err < 5e-4 and zero_bad == 0, f"max | |n|-1 | = {unit_err:.1e}, {zero_bad} non-zero misses")
    add("normals face camera", facing_bad == 0, f"{facing_bad} of {hits} hit pixels face away")
    dmin = min(float(v.depth[v.depth > 0].min()) for v in sc.views if (v.depth > 0).any())
    dmax = max(float(v.depth.max()) for v in sc.views)
    near, far = sc.meta["near"], sc.meta["far"]
    add("depth in [near,far]", near <= dmin and dmax <= far, f"depth [{dmin:.3f}, {dmax:.3f}], near/far [{near}, {far}]")
    lo, hi = np.array(sc.meta["aabb"][0]) - 1e-3, np.array(sc.meta["aabb"][1]) + 1e-3
    outside = sum(int(np.sum(np.any((P < lo) | (P > hi), -1)))
                  for v in sc.views for P in [world_points(v, intr)[v.depth > 0]])
    add("hits inside aabb", outside == 0, f"{outside} hit points outside {sc.meta['aabb']}")

    # ---- reprojection between nearby views
    rels, viol, tested = [], 0, 0
    for i, nb in enumerate(_nearest_views(sc.views, 2)):
        for j in nb:
            r, vi, te = reprojection(sc.views[i], sc.views[j], intr)
            rels.append(r)
            viol += vi
            tested += te
    rel = np.abs(np.concatenate(rels))
    frac = float(np.mean(rel < 5e-3)) if rel.size else 0.0
    med = float(np.median(rel)) if rel.size else 1.0
    vfrac = viol / max(tested, 1)
    add("reprojection", rel.size > 1000 and frac >= 0.95 and med < 1e-4 and vfrac < 0.02,
        f"{rel.size} co-visible px: {100 * frac:.2f}% within 0.5%, median {med:.1e}, "
        f"free-space violations {100 * vfrac:.2f}%")

    # ---- normals derived from depth on flat regions
    angs = []
    for v in sc.views:
        n, flat = depth_normals(v, intr)
        angs.append(angle_deg(n[flat], v.normal[flat]))
    ang = np.concatenate(angs)
    if ang.size:
        med, p95 = float(np.median(ang)), float(np.percentile(ang, 95))
        # the stored depth's precision (1.5e-5 relative) limits depth-derived normals to
        # ~0.03 deg median at 128 px; the pixel baseline shrinks with the resolution
        scale = max(1.0, w / 128)
        add("normals vs depth", ang.size > 1000 and med < 0.1 * scale and p95 < 0.5 * scale,
            f"{ang.size} flat px: median {med:.3f} deg, 95th pct {p95:.3f} deg")
    else:
        add("normals vs depth", False, "no flat pixels found")

    # ---- alpha vs mask
    if sc.meta.get("background") == "transparent":
        agree = np.mean(np.concatenate([((v.rgb[..., 3] >= 128) == (v.mask == 255)).ravel() for v in sc.views]))
        add("alpha vs mask", agree >= 0.98, f"{100 * agree:.2f}% agree")
    return out


def compare_scenes(a_root: Path, b_root: Path) -> list[Result]:
    a, b = load_scene(a_root), load_scene(b_root)
    name = a.meta.get("scene", Path(a_root).name)
    out: list[Result] = []

    def add(test, ok, detail):
        out.append(Result(name, "drift: " + test, bool(ok), detail))

    same = len(a.views) == len(b.views) and all(x.name == y.name for x, y in zip(a.views, b.views))
    cam = same and all(np.abs(x.c2w - y.c2w).max() < 1e-6 for x, y in zip(a.views, b.views)) and \
        all(abs(a.meta[k] - b.meta[k]) < 1e-6 for k in ("fl_x", "fl_y", "cx", "cy", "w", "h", "near", "far"))
    add("cameras", cam, f"{len(a.views)} vs {len(b.views)} views")
    if not cam:
        return out
    px = sum(v.depth.size for v in a.views)
    mdiff = sum(int(np.sum(x.mask != y.mask)) for x, y in zip(a.views, b.views))
    add("mask", mdiff <= 1e-3 * px, f"{mdiff} of {px} pixels differ")
    drel, nang, both = [], [], 0
    for x, y in zip(a.views, b.views):
        m = (x.depth > 0) & (y.depth > 0)
        both += int(m.sum())
        drel.append(np.abs(x.depth[m] - y.depth[m]) / y.depth[m])
        nang.append(angle_deg(x.normal[m], y.normal[m]))
    drel, nang = np.concatenate(drel), np.concatenate(nang)
    add("depth", np.mean(drel <= 1e-4) >= 0.999, f"max rel diff {drel.max():.1e}, "
        f"{100 * np.mean(drel <= 1e-4):.3f}% within 1e-4")
    add("normals", np.mean(nang <= 0.1) >= 0.999, f"max {nang.max():.3f} deg, {100 * np.mean(nang <= 0.1):.3f}% within 0.1 deg")
    worst_psnr, worst_mad = np.inf, 0.0
    for x, y in zip(a.views, b.views):
        if x.rgb.shape != y.rgb.shape:
            worst_psnr = -np.inf
            break
        d = x.rgb.astype(np.float64) / 255 - y.rgb.astype(np.float64) / 255
        mse = float(np.mean(d * d))
        worst_psnr = min(worst_psnr, 10 * np.log10(1 / mse) if mse > 0 else np.inf)
        worst_mad = max(worst_mad, float(np.mean(np.abs(d))))
    add("rgb", worst_psnr >= 40 and worst_mad <= 1 / 255,
        f"worst PSNR {worst_psnr:.1f} dB, worst mean abs diff {worst_mad * 255:.3f}/255")
    ma, mb = Path(a_root) / "gt_mesh.ply", Path(b_root) / "gt_mesh.ply"
    if not (ma.is_file() and mb.is_file()):
        add("gt mesh", False, f"gt_mesh.ply missing in {ma.parent if not ma.is_file() else mb.parent}")
    else:
        same_mesh = ma.read_bytes() == mb.read_bytes()
        add("gt mesh", same_mesh, f"{ma.stat().st_size} vs {mb.stat().st_size} bytes, " + ("identical" if same_mesh else "differ"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Consistency checks of rendered synthetic scenes.")
    ap.add_argument("scenes", nargs="*", help="scene folders (containing transforms_train.json)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="drift-compare two renders of one scene")
    args = ap.parse_args(argv)
    results: list[Result] = []
    if args.compare:
        results += compare_scenes(Path(args.compare[0]), Path(args.compare[1]))
    for s in args.scenes:
        results += check_scene(Path(s))
    for r in results:
        print(r.line())
    npass = sum(r.ok for r in results)
    print(f"gtcheck: {npass} passed, {len(results) - npass} failed")
    return 0 if results and npass == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
