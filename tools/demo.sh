#!/usr/bin/env bash
# The main job, run by `tools/run demo` after the build: train a committed synthetic
# scene, render its test views with depth and normals, print PSNR and the geometry
# error against the scene's ground truth. Outputs go to runs/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/edgenerf
scene=synthetic-scenes/small/${DEMO_SCENE:-smooth}
out=runs/demo
rm -rf "$out"
$bin info "$scene" --check-gpu
$bin train "$scene" --config tools/configs/demo.toml --out "$out" "$@"
echo
echo "renders (RGB, depth, normals, opacity) are in $out/test/; the run's config, log and checkpoint in $out/"
