#!/usr/bin/env bash
# Trains a few steps of a 3-view run (edge-guided terms and priors on from step 0) on
# lavapipe and on SwiftShader under the Khronos validation layer (synchronization
# validation on), and compares the per-step losses: the stand-in for the GPUs we cannot
# run here (other limits, other execution order). The logic is the test
# tools/tests/other_vulkan.rs (CI runs it); this runs it in a release build.
#   tools/check-other-vulkan.sh
# Needs SwiftShader (Debian's chromium-common: /usr/lib/chromium/vk_swiftshader_icd.json,
# or SWIFTSHADER_ICD) and vulkan-validationlayers.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
EDGENERF_REQUIRE_OTHER_VULKAN=1 exec cargo test --release -p edgenerf-tools --test other_vulkan -- --nocapture
