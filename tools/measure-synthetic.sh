#!/usr/bin/env bash
# Dense-view training on the committed synthetic scenes: per scene, test PSNR, steps,
# training wall time, field samples/s, and the empty-space skipping: field samples per
# ray with the occupancy grid + BVH sampler vs uniform marching (the same segments,
# none skipped), both over the test views of the trained model, and the PSNR of the
# uniform render (skipping must not change the image), plus the samples per ray the
# last half of training wanted (before the batch capacity cut), and the mean depth and
# normal errors against ground truth.
#   tools/measure-synthetic.sh [CONFIG] [SCENE...]    (release build; results in runs/measure/)
set -euo pipefail
cd "$(dirname "$0")/.."
config=${1:-tools/configs/demo.toml}; shift || true
scenes=("$@"); [ ${#scenes[@]} -gt 0 ] || scenes=(smooth creases occlusion texture thin table turntable)
mkdir -p runs/measure
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
printf '| scene | test PSNR | steps | train s | samples/s | spr train | spr occ | spr uniform | PSNR uniform | depth err | normal deg |\n|---|---|---|---|---|---|---|---|---|---|---|\n'
for s in "${scenes[@]}"; do
    out=runs/measure/$s
    rm -rf "$out" "$out-uniform"
    $bin train "synthetic-scenes/small/$s" --config "$config" --out "$out" >"$out.log" 2>&1 || { echo "$s failed: see $out.log"; continue; }
    $bin render "$out" --sampler uniform --out "$out-uniform" >"$out-uniform.log" 2>&1 || { echo "$s: uniform render failed: see $out-uniform.log"; continue; }
    python3 - "$out" "$out-uniform" "$s" <<'PY'
import csv, json, sys
out, uni, scene = sys.argv[1:4]
rows = list(csv.DictReader(open(f"{out}/log.csv")))
m = json.load(open(f"{out}/test/metrics.json"))
u = json.load(open(f"{uni}/metrics.json"))
t = float(rows[-1]["elapsed_s"]); samples = sum(int(r["samples"]) for r in rows)
late = rows[len(rows) // 2:]
# Wanted per ray in training: kept plus cut by the capacity, over the batch's rays.
wanted = sum((int(r["samples"]) + int(r["samples_truncated"])) / int(r["samples"]) * float(r["samples_per_ray"]) for r in late) / len(late)
f = lambda x: "-" if x is None else f"{x:.3f}"
print(f"| {scene} | {m['mean_psnr']:.2f} | {len(rows)} | {t:.0f} | {samples / t:,.0f} | {wanted:.1f} | {m['mean_samples_per_ray']:.1f} | {u['mean_samples_per_ray']:.1f} | {u['mean_psnr']:.2f} | {f(m['mean_depth_abs_error'])} | {f(m['mean_normal_angle_deg'])} |")
PY
done
