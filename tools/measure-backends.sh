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
# to runs/backends/<scene>-<backend>; a finished run (test/metrics.json) is reused.
set -euo pipefail
cd "$(dirname "$0")/.."
scene="${1:-synthetic-scenes/small/creases}"
seconds="${2:-300}"
views="${3:-3}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
name="$(basename "$scene")"
full=(--set mlp.depth=8 --set mlp.width=256 --set mlp.skip_layer=4 --set mlp.color_width=128 --set mlp.pos_max_deg=16)
run() {
    local label="$1"; shift
    local out="runs/backends/$name-$label"
    if [ ! -f "$out/test/metrics.json" ]; then
        rm -rf "$out"; mkdir -p runs/backends
        "$bin" train "$scene" --views "$views" --out "$out" --no-depth-reg --no-normal-reg \
            --iters 2000 --max-seconds "$seconds" "$@" 2> >(tee "$out.stderr" >&2)
    fi
}
run grid --config tools/configs/sparse-small.toml
run mlp-small --config tools/configs/sparse-small-mlp.toml
run mlp-full --config tools/configs/sparse-small-mlp.toml "${full[@]}"
echo "scene $name, $views views, ${seconds} s of training each, adapter: $("$bin" info "$scene" --check-gpu 2>/dev/null | grep -i adapter | head -1 | sed 's/.*: //')"
printf '| backend | parameters | steps | steps/s | samples/s | test PSNR | SSIM |\n|---|---|---|---|---|---|---|\n'
for label in grid mlp-small mlp-full; do
    out="runs/backends/$name-$label"
    python3 - "$out" "$label" <<'PY'
import csv, json, re, sys
out, label = sys.argv[1], sys.argv[2]
rows = list(csv.DictReader(open(f"{out}/log.csv")))
m = json.load(open(f"{out}/test/metrics.json"))
t = float(rows[-1]["elapsed_s"])
samples = sum(float(r["samples"]) for r in rows)
found = re.search(r"; (\d+) parameters;", open(f"{out}.stderr", errors="replace").read())
params = f"{int(found.group(1)):,}" if found else "?"
print(f"| {label} | {params} | {len(rows)} | {len(rows) / t:.2f} | {samples / t:,.0f} | {m['mean_psnr']:.2f} | {m['mean_ssim']:.3f} |")
PY
done
