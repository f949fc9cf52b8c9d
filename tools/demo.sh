#!/usr/bin/env bash
# The main job, run by `tools/run demo` after the build: describes a committed
# synthetic scene and the GPU. (Training, rendering and evaluation join here as the
# engine grows.)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/edgenerf
scene=synthetic-scenes/small/creases
$bin info "$scene" --views 3 --check-gpu
