#!/usr/bin/env bash
# Dense-view training on the committed synthetic scenes: per scene, test PSNR, steps,
# wall time, samples/s, and mean samples per ray with the occupancy grid + BVH
# sampler vs uniform marching over the same kind of batches.
#   tools/measure-synthetic.sh [CONFIG] [SCENE...]    (release build; results in runs/measure/)
set -euo pipefail
cd "$(dirname "$0")/.."
config=${1:-tools/configs/demo.toml}; shift || true
scenes=("$@"); [ ${#scenes[@]} -gt 0 ] || scenes=(occlusion creases texture thin smooth table turntable)
mkdir -p runs/measure
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
printf '%-10s %8s %6s %8s %10s %10s %12s %8s %8s\n' scene psnr steps train_s samples/s spr_occ spr_uniform depth_err normal_deg
for s in "${scenes[@]}"; do
    out=runs/measure/$s
    rm -rf "$out" "$out-uniform"
    $bin train "synthetic-scenes/small/$s" --config "$config" --out "$out" >"$out.log" 2>&1 || { echo "$s failed: see $out.log"; continue; }
    # Uniform marching (no occupancy grid, no BVH): a few steps of the same batches.
    $bin train "synthetic-scenes/small/$s" --config "$config" --out "$out-uniform" --iters 5 --no-eval \
        --set sampler.mode='"uniform"' >/dev/null 2>&1
    python3 - "$out" "$out-uniform" "$s" <<'PY'
import csv, json, sys
out, uni, scene = sys.argv[1:4]
rows = list(csv.DictReader(open(f"{out}/log.csv")))
urows = list(csv.DictReader(open(f"{uni}/log.csv")))
m = json.load(open(f"{out}/test/metrics.json"))
t = float(rows[-1]["elapsed_s"]); samples = sum(int(r["samples"]) for r in rows)
late = rows[len(rows) // 2:]
spr = sum(float(r["samples_per_ray"]) for r in late) / len(late)
spr_u = sum(float(r["samples_per_ray"]) for r in urows) / len(urows)
f = lambda x: "-" if x is None else f"{x:.3f}"
print(f"{scene:<10} {m['mean_psnr']:8.2f} {len(rows):6d} {t:8.1f} {samples / t:10.0f} {spr:10.1f} {spr_u:12.1f} {f(m['mean_depth_abs_error']):>8} {f(m['mean_normal_angle_deg']):>8}")
PY
done
