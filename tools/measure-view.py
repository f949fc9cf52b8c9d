#!/usr/bin/env python3
"""Times `edgenerf view` as the page uses it (docs/guide/viewer.md): the time from
starting the viewer to its first frame (coarse, as the page asks first) and its first
full-resolution frame, then frames per second while
orbiting, one request at a time like the page (each frame 3 degrees further around the
orbit's up axis), at the coarse resolution (the page's: about 4096 pixels, at most 1/2
of the size) and the full resolution.

    tools/measure-view.py RUN [--bin target/release/edgenerf] [--coarse 40] [--full 12]

Standard library only. Prints one line per figure and a JSON summary.
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
import urllib.request


def get(url):
    with urllib.request.urlopen(url, timeout=600) as r:
        return r.status, dict(r.headers), r.read()


def rot(v, k, a):
    """v rotated by angle a about the unit axis k (Rodrigues)."""
    c, s = math.cos(a), math.sin(a)
    kv = sum(x * y for x, y in zip(k, v))
    cr = [k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]]
    return [v[i] * c + cr[i] * s + k[i] * kv * (1 - c) for i in range(3)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--bin", default="target/release/edgenerf")
    ap.add_argument("--coarse", type=int, default=40, help="frames timed at the coarse resolution")
    ap.add_argument("--full", type=int, default=12, help="frames timed at full resolution")
    a = ap.parse_args()
    env = dict(os.environ, XDG_RUNTIME_DIR=os.environ.get("XDG_RUNTIME_DIR", "/tmp"))
    t0 = time.monotonic()
    p = subprocess.Popen([a.bin, "view", a.run, "--port", "0"], stdout=subprocess.PIPE, text=True, env=env)
    try:
        line = p.stdout.readline()
        t_ready = time.monotonic() - t0
        base = "http://" + line.split("http://")[1].split("/")[0]
        info = json.loads(get(base + "/api/info")[2])
        v0 = info["default_view"]
        coarse = round(min(0.5, math.sqrt(4096 / (info["width"] * info["height"]))), 3)
        # As the page starts: a coarse frame, then the full one.
        get(f"{base}/api/frame?view={v0}&scale={coarse}")
        t_coarse = time.monotonic() - t0
        _, h, _ = get(f"{base}/api/frame?view={v0}")
        t_first = time.monotonic() - t0
        print(f"viewer up in {t_ready:.2f} s; first (coarse) frame at {t_coarse:.2f} s; first full frame "
              f"({info['width']}x{info['height']}) at {t_first:.2f} s (render {h.get('X-Render-Ms')} ms)")
        m = info["views"][v0]["c2w"]
        r, u, b, pos = [m[0], m[4], m[8]], [m[1], m[5], m[9]], [m[2], m[6], m[10]], [m[3], m[7], m[11]]
        fwd = [-x for x in b]
        t = sum((f - q) * d for f, q, d in zip(info["focus"], pos, fwd))
        t = t if t > 1e-3 else 1.0
        target = [q + d * t for q, d in zip(pos, fwd)]
        up = info["up"]
        out = {"ready_s": t_ready, "first_coarse_frame_s": t_coarse, "first_full_frame_s": t_first, "width": info["width"], "height": info["height"]}
        for name, scale, n in [("coarse", coarse, a.coarse), ("full", 1.0, a.full)]:
            off = [q - c for q, c in zip(pos, target)]
            rr, uu, bb = r, u, b
            ms, start = [], time.monotonic()
            for i in range(n):
                ang = math.radians(3.0)
                off, rr, uu, bb = rot(off, up, ang), rot(rr, up, ang), rot(uu, up, ang), rot(bb, up, ang)
                p_ = [c + o for c, o in zip(target, off)]
                c2w = [rr[0], uu[0], bb[0], p_[0], rr[1], uu[1], bb[1], p_[1], rr[2], uu[2], bb[2], p_[2], 0, 0, 0, 1]
                q = ",".join(f"{x:.7g}" for x in c2w)
                st, h, _ = get(f"{base}/api/frame?view={v0}&scale={scale}&client=measure&c2w={q}")
                assert st == 200, st
                ms.append(float(h["X-Render-Ms"]))
            el = time.monotonic() - start
            fps = n / el
            size = f"{round(info['width'] * scale)}x{round(info['height'] * scale)}"
            print(f"{name} ({size}): {n} frames in {el:.2f} s = {fps:.2f} frames/s (render median {statistics.median(ms):.0f} ms)")
            out[name] = {"size": size, "frames": n, "fps": fps, "render_ms_median": statistics.median(ms)}
        print(json.dumps(out))
    finally:
        p.terminate()
        p.wait()


if __name__ == "__main__":
    sys.exit(main())
