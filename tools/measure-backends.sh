#!/usr/bin/env bash
# Grid vs MLP on one scene and machine, in one invocation: each backend trains for the
# same wall time (train.max_seconds), then its test views are evaluated. Prints steps,
# steps/s, field samples/s and test PSNR/SSIM per backend.
#
#   tools/measure-backends.sh [SCENE] [SECONDS] [VIEWS]
#
# Backends: the grid (tools/configs/sparse-small.toml), the small MLP and the
# full-size mip-NeRF MLP (tools/configs/sparse-small-mlp.toml, the latter with
# `mlp.*` set to 8 x 256). Regularizers are off so only the field differs. Runs go
# to runs/backends/<scene>-<backend>; a finished run is reused. NO_EVAL="mlp-full"
# (the default) skips the test-view evaluation of the listed backends (the full MLP
# renders ~1.4k samples/s on lavapipe: 8 test views would take over an hour); their
# PSNR column is then the mean training-batch PSNR of the last 10 steps, marked "(train)".
set -euo pipefail
cd "$(dirname "$0")/.."
scene="${1:-synthetic-scenes/small/creases}"
seconds="${2:-300}"
views="${3:-3}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
name="$(basename "$scene")"
no_eval="${NO_EVAL-mlp-full}"
full=(--set mlp.depth=8 --set mlp.width=256 --set mlp.skip_layer=4 --set mlp.color_width=128 --set mlp.pos_max_deg=16)
run() {
    local label="$1"; shift
    local out="runs/backends/$name-$label"
    local eval=()
    case " $no_eval " in *" $label "*) eval=(--no-eval) ;; esac
    if [ ! -f "$out/test/metrics.json" ] && [ ! -f "$out/done" ]; then
        rm -rf "$out"; mkdir -p runs/backends
        "$bin" train "$scene" --views "$views" --out "$out" --no-depth-reg --no-normal-reg "${eval[@]}" \
            --iters 2000 --max-seconds "$seconds" "$@" 2> >(tee "$out.stderr" >&2)
        touch "$out/done"
    fi
}
run grid --config tools/configs/sparse-small.toml
run mlp-small --config tools/configs/sparse-small-mlp.toml
run mlp-full --config tools/configs/sparse-small-mlp.toml "${full[@]}"
adapter="$(sed -n 's/^training .* on \(.*\); [0-9]* parameters;.*/\1/p' "runs/backends/$name-grid.stderr" | head -1)"
echo "scene $name, $views views, ${seconds} s of training each, adapter: $adapter"
printf '| backend | parameters | steps | steps/s | samples/s | test PSNR | SSIM |\n|---|---|---|---|---|---|---|\n'
for label in grid mlp-small mlp-full; do
    out="runs/backends/$name-$label"
    python3 - "$out" "$label" <<'PY'
import csv, json, re, sys
out, label = sys.argv[1], sys.argv[2]
rows = list(csv.DictReader(open(f"{out}/log.csv")))
import os
m = json.load(open(f"{out}/test/metrics.json")) if os.path.exists(f"{out}/test/metrics.json") else None
t = float(rows[-1]["elapsed_s"])
samples = sum(float(r["samples"]) for r in rows)
found = re.search(r"; (\d+) parameters;", open(f"{out}.stderr", errors="replace").read())
params = f"{int(found.group(1)):,}" if found else "?"
if m:
    psnr, ssim = f"{m['mean_psnr']:.2f}", f"{m['mean_ssim']:.3f}"
else:
    last = rows[-10:]
    psnr, ssim = f"{sum(float(r['psnr']) for r in last) / len(last):.2f} (train)", "-"
print(f"| {label} | {params} | {len(rows)} | {len(rows) / t:.3f} | {samples / t:,.0f} | {psnr} | {ssim} |")
PY
done
