#!/usr/bin/env bash
# Training-time cost of each edge-guided regularizer, as the paper's table 8: the same
# steps on the same scene and machine, without regularizers, with L_z only and with
# L_n only, back to back in one invocation; prints seconds per step and the ratios.
#   tools/measure-reg-cost.sh [SCENE_DIR] [CONFIG] [STEPS]   (release build; runs/reg-cost/)
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-synthetic-scenes/small/creases}
config=${2:-tools/configs/sparse-small.toml}
steps=${3:-100}
mkdir -p runs/reg-cost
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
declare -A flags=([none]="--no-depth-reg --no-normal-reg" [depth]="--no-normal-reg" [normal]="--no-depth-reg" [both]="")
for v in none depth normal both; do
    out=runs/reg-cost/$v
    rm -rf "$out"
    # shellcheck disable=SC2086
    $bin train "$scene" --views 3 --config "$config" --iters "$steps" --no-eval --out "$out" ${flags[$v]} \
        --set train.checkpoint_every=0 --set reg.start_step=0 --set reg.warmup_steps=0 >"$out.log" 2>&1 || { echo "$v failed: see $out.log"; exit 1; }
done
python3 - "$($bin info "$scene" 2>/dev/null | grep -i adapter | head -1)" <<'PY'
import csv, sys
def per_step(v):
    rows = list(csv.DictReader(open(f"runs/reg-cost/{v}/log.csv")))
    # Skip the first 10 steps (pipeline compilation, occupancy warm-up).
    t = [float(r["elapsed_s"]) for r in rows]
    spr = sum(float(r["samples_per_ray"]) for r in rows[10:]) / len(rows[10:])
    return (t[-1] - t[9]) / (len(t) - 10), spr
base, _ = per_step("none")
print(sys.argv[1].strip())
print(f"{'variant':<8} {'s/step':>8} {'ratio':>6} {'samples/ray':>11}")
for v in ["none", "depth", "normal", "both"]:
    s, spr = per_step(v)
    print(f"{v:<8} {s:8.3f} {s / base:6.3f} {spr:11.1f}")
PY
