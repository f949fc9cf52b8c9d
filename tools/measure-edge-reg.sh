#!/usr/bin/env bash
# EdgeNeRF's regularizers on 3-view training, same steps per variant:
#   edge   : edge-guided L_z + L_n (Canny edges), the method
#   none   : no regularizer (same patch batches)
#   global : the same regularizers without an edge mask (--edges none), the global
#            smoothing the paper argues against
#   official (only when asked, VARIANTS="... official"): edge-guided, the authors'
#            code variant (stop-gradient means, unhinged L_n averaged, lambda3 0.01)
#   regnerf  (only when asked): RegNeRF without appearance regularization: no
#            edge-guided terms, depth TV on 8x8 patches from random poses and
#            sample-space annealing (RegNeRF's weights and schedules)
#   regnerf_short (only when asked): the same with RegNeRF's TV decay and annealing
#            shortened in proportion to the run (DTU: 512 and 256 of 43945 steps, i.e.
#            5 and 2 of our 400)
# Per scene and variant: test PSNR / SSIM, mean depth error overall, in non-edge
# regions and within the GT edge band (2 px of a GT depth/normal discontinuity), the
# iBims-1 depth boundary error, mean normal angle, and training time.
#   tools/measure-edge-reg.sh [CONFIG] [SCENE_DIR...]   (release build; runs/edge-reg/)
# VARIANTS="none edge" runs a subset; finished runs are kept and not redone.
# SCENE_DIR defaults to every committed synthetic scene; pass ../shared/data/llff/fern
# for LLFF (no ground-truth geometry there: PSNR/SSIM only).
set -euo pipefail
cd "$(dirname "$0")/.."
config=${1:-tools/configs/sparse-small.toml}; shift || true
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(synthetic-scenes/small/{smooth,creases,occlusion,texture,thin,table,turntable})
views=${VIEWS:-3}
read -r -a variants <<<"${VARIANTS:-none edge global}"   # a subset, e.g. VARIANTS="none edge" 
mkdir -p runs/edge-reg
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
declare -A flags=([edge]="" [none]="--no-depth-reg --no-normal-reg" [global]="--edges none" [official]="--reg-variant official"
    [regnerf]="--no-depth-reg --no-normal-reg --regnerf-depth-tv --anneal-sample-space"
    [regnerf_short]="--no-depth-reg --no-normal-reg --regnerf-depth-tv --anneal-sample-space --set regnerf.tv_decay_steps=5 --set regnerf.anneal_steps=2")
for dir in "${scenes[@]}"; do
    s=$(basename "$dir")
    for v in "${variants[@]}"; do
        out=runs/edge-reg/$s-$v
        if [ -f "$out/test/metrics.json" ]; then continue; fi
        rm -rf "$out"
        # shellcheck disable=SC2086
        $bin train "$dir" --views "$views" --config "$config" --out "$out" ${flags[$v]} >"$out.log" 2>&1 \
            || { echo "$s $v failed: see $out.log"; continue; }
    done
done
python3 - "${scenes[@]}" <<'PY'
import csv, json, os, sys
f = lambda x, d=3: "-" if x is None else f"{x:.{d}f}"
print(f"{'scene':<10} {'variant':<13} {'psnr':>6} {'ssim':>6} {'depth':>7} {'d_nonedge':>9} {'d_edge2px':>9} {'dbe_acc':>7} {'dbe_comp':>8} {'normal':>7} {'train_s':>7}")
for d in sys.argv[1:]:
    s = os.path.basename(d.rstrip("/"))
    for v in ["none", "edge", "global", "official", "regnerf", "regnerf_short"]:
        if not os.path.isdir(f"runs/edge-reg/{s}-{v}"):
            continue
        out = f"runs/edge-reg/{s}-{v}"
        try:
            m = json.load(open(f"{out}/test/metrics.json"))
            rows = list(csv.DictReader(open(f"{out}/log.csv")))
        except (OSError, KeyError, IndexError):
            print(f"{s:<10} {v:<13} (missing: see {out}.log)")
            continue
        t = float(rows[-1]["elapsed_s"])
        print(f"{s:<10} {v:<13} {m['mean_psnr']:6.2f} {m['mean_ssim']:6.3f} {f(m['mean_depth_abs_error']):>7} "
              f"{f(m['mean_depth_abs_error_non_edge']):>9} {f(m['mean_depth_abs_error_edge']):>9} "
              f"{f(m['mean_dbe_accuracy'], 2):>7} {f(m['mean_dbe_completeness'], 2):>8} {f(m['mean_normal_angle_deg'], 1):>7} {t:7.0f}")
PY
