#!/usr/bin/env bash
# Trains a few steps of a 3-view run (edge-guided terms on from step 0) on lavapipe and
# on SwiftShader under the Khronos validation layer, and compares the per-step losses:
# the stand-in for the GPUs we cannot run here (other limits, other execution order).
#   tools/check-other-vulkan.sh [STEPS]      (release build; runs/other-vulkan/)
# Needs SwiftShader (Debian's chromium-common: /usr/lib/chromium/vk_swiftshader_icd.json)
# and vulkan-validationlayers; says what is missing otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-6}
swiftshader=${SWIFTSHADER_ICD:-/usr/lib/chromium/vk_swiftshader_icd.json}
[ -f "$swiftshader" ] || { echo "SwiftShader not found at $swiftshader: apt-get install chromium-common (or set SWIFTSHADER_ICD)"; exit 1; }
ls /usr/share/vulkan/explicit_layer.d/*khronos_validation* >/dev/null 2>&1 \
    || { echo "the Khronos validation layer is missing: apt-get install vulkan-validationlayers"; exit 1; }
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
cargo build --release -q -p edgenerf-tools
bin=target/release/edgenerf
out=runs/other-vulkan
rm -rf "$out"; mkdir -p "$out/layer"
# The layer reads its settings from this directory: every error, warning and
# performance message goes to validation.txt.
cat >"$out/layer/vk_layer_settings.txt" <<SETTINGS
khronos_validation.debug_action = VK_DBG_LAYER_ACTION_LOG_MSG
khronos_validation.report_flags = error,warn,perf
khronos_validation.log_filename = $PWD/$out/layer/validation.txt
SETTINGS
args=(train synthetic-scenes/small/creases --views 3 --config tools/configs/sparse-small.toml --iters "$steps"
      --set reg.start_step=0 --set reg.warmup_steps=0 --set sampler.steps_per_diagonal=64)
$bin "${args[@]}" --out "$out/lavapipe" >"$out/lavapipe.log" 2>&1 || { echo "lavapipe run failed: see $out/lavapipe.log"; exit 1; }
VK_ICD_FILENAMES="$swiftshader" VK_INSTANCE_LAYERS=VK_LAYER_KHRONOS_validation VK_LAYER_SETTINGS_PATH="$PWD/$out/layer" \
    $bin "${args[@]}" --out "$out/swiftshader" >"$out/swiftshader.log" 2>&1 || { echo "SwiftShader run failed: see $out/swiftshader.log"; exit 1; }
grep -h "^training\|^test PSNR" "$out/lavapipe.log" "$out/swiftshader.log"
python3 - "$out" <<'PY'
import csv, sys
out = sys.argv[1]
a, b = (list(csv.DictReader(open(f"{out}/{n}/log.csv"))) for n in ("lavapipe", "swiftshader"))
worst = 0.0
for ra, rb in zip(a, b):
    for k in ("loss", "loss_color", "loss_depth", "loss_normal"):
        x, y = float(ra[k]), float(rb[k])
        worst = max(worst, abs(x - y) / max(abs(x), 1e-12))
print(f"{len(a)} steps: largest relative loss difference lavapipe vs SwiftShader {worst:.2e}")
sys.exit(0 if len(a) == len(b) and worst < 1e-3 else 1)
PY
n=$(grep -c . "$out/layer/validation.txt" 2>/dev/null || true)
echo "validation layer messages: ${n:-0} (in $out/layer/validation.txt)"
[ "${n:-0}" = 0 ]
