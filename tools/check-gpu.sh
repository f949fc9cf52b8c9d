#!/usr/bin/env bash
# The checks of a machine with a real GPU in one run, for a release binary built
# elsewhere (the "On an H100" figures of docs/journal.md came from these steps):
#   tools/check-gpu.sh [BINARY] [OUT]        (defaults: target/release/edgenerf, runs/check-gpu)
# 1. the adapter and the GPU self-test (`edgenerf info --check-gpu`);
# 2. `edgenerf speed` on the demo and sparse-small presets (OUT/speed/speed.json);
# 3. the demo and the 3-view sparse-small preset trained with evaluation (PSNR, time);
# 4. a 20-step 3-view run with every term and prior on from step 0 under the Khronos
#    validation layer with synchronization validation, when the layer is installed:
#    OUT/validation.txt must stay empty, and OUT/every-term/log.csv is the run's
#    per-step losses, to compare with the same command on lavapipe (docs/guide/testing.md).
# 5. with LIB_TESTS=<the engine's library test binary> (built with `cargo test --release
#    -p edgenerf-engine --lib --no-run`; it must see the repository at the path it was
#    built at, e.g. `ln -s $PWD /work/main`): that binary LIB_TEST_RUNS times (default
#    3) at 16 test threads, NVIDIA's shader cache emptied before each run, where a
#    shared device used to be lost (docs/journal.md, "On an H100"); OUT/lib-tests-N.log.
# Run from anywhere; paths are the repository's. Without a Vulkan loader on the machine,
# unpack Debian's libvulkan1 and glvnd's libraries first (docs/journal.md, "On an H100").
set -uo pipefail
cd "$(dirname "$0")/.."
BIN="${1:-target/release/edgenerf}"
OUT="${2:-runs/check-gpu}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
[ -x "$BIN" ] || { echo "no executable $BIN: build it with cargo build --release -p edgenerf-tools, or pass its path" >&2; exit 2; }
mkdir -p "$OUT"
status=0
step() { echo "== $*"; }
fail() { echo "FAILED: $*"; status=1; }

step "adapter and self-test"
"$BIN" info synthetic-scenes/small/smooth --check-gpu || fail "self-test"

step "speed (demo, sparse-small)"
"$BIN" speed --warmup 50 --steps 200 --out "$OUT/speed" || fail "speed"

step "training with evaluation"
"$BIN" train synthetic-scenes/small/smooth --config tools/configs/demo.toml --out "$OUT/demo" --overwrite 2>&1 \
  | grep -E "^trained|^test PSNR|^geometry" || fail "demo training"
"$BIN" train synthetic-scenes/small/creases --views 3 --config tools/configs/sparse-small.toml --out "$OUT/sparse-small" --overwrite 2>&1 \
  | grep -E "^trained|^test PSNR|^geometry" || fail "sparse-small training"

step "every term from step 0 under the validation layer (synchronization validation)"
layer_json=$(ls /usr/share/vulkan/explicit_layer.d/*khronos_validation*.json 2>/dev/null | head -1)
if [ -z "$layer_json" ]; then
  echo "skipped: the Khronos validation layer is not installed (Debian: vulkan-validationlayers)"
else
  settings="$OUT/layer"
  mkdir -p "$settings"
  report="$(cd "$OUT" && pwd)/validation.txt"
  rm -f "$report"
  printf '%s\n' "khronos_validation.debug_action = VK_DBG_LAYER_ACTION_LOG_MSG" \
    "khronos_validation.report_flags = error,warn,perf" \
    "khronos_validation.enables = VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT" \
    "khronos_validation.log_filename = $report" > "$settings/vk_layer_settings.txt"
  VK_INSTANCE_LAYERS=VK_LAYER_KHRONOS_validation VK_LAYER_SETTINGS_PATH="$settings" \
    "$BIN" train synthetic-scenes/small/creases --views 3 --config tools/configs/sparse-small.toml \
    --out "$OUT/every-term" --overwrite --iters 20 --no-eval \
    --set reg.start_step=0 --set reg.warmup_steps=0 --set priors.distortion=0.01 --set priors.occlusion=0.01 \
    2>&1 | grep -E "^trained|error" || fail "the run under the validation layer"
  messages=$(cat "$report" 2>/dev/null | wc -l)
  echo "validation layer: $messages lines in $report"
  [ "$messages" -eq 0 ] || fail "the validation layer logged messages"
fi
if [ -n "${LIB_TESTS:-}" ]; then
  step "the library tests at 16 threads, ${LIB_TEST_RUNS:-3} runs, each with an empty shader cache"
  for i in $(seq 1 "${LIB_TEST_RUNS:-3}"); do
    rm -rf "$HOME/.cache/nvidia" "$HOME/.nv"
    log="$OUT/lib-tests-$i.log"
    timeout 300 "$LIB_TESTS" --test-threads 16 > "$log" 2>&1
    rc=$?
    echo "run $i: exit $rc, $(grep -c -i 'device.*lost' "$log") lost-device lines, $(grep 'test result' "$log")"
    [ $rc -eq 0 ] || fail "library tests, run $i ($log)"
  done
fi
[ $status -eq 0 ] && echo "all checks passed" || echo "some checks failed (above)"
exit $status
