#!/usr/bin/env bash
# The main job end to end on the bundled data: a synthetic photo of the
# procedural soda can under the bundled courtyard map, the estimate of the
# probe's pose and the lighting from it, and the estimate scored against the
# truth. Runs from any directory; writes demo/ at the repository's root
# (re-runs replace it). Needs the Rust toolchain only.
set -euo pipefail
cd "$(dirname "$0")/.."

cargo build --release -p alp
alp=./target/release/alp

"$alp" synth --probe can --env assets/envmaps/courtyard.exr --out demo/scene --seed 3
"$alp" estimate --image demo/scene/image.exr --mask demo/scene/mask.png \
    --camera demo/scene/camera.json --probe can --out demo/estimate
"$alp" eval --scene demo/scene --env demo/estimate/env.exr --pose demo/estimate/pose.json

root=$(pwd)
echo
echo "The scene (photo, mask, camera, true pose and map): $root/demo/scene/"
echo "The estimate: $root/demo/estimate/"
echo "  env.exr         the environment map"
echo "  pose.json       the probe's pose"
echo "  confidence.exr  how well the probe sees each direction of the map"
echo "  rerender.exr    the photo re-rendered with the estimate"
echo "  preview.png     photo | re-render | env map"
echo "  report.json     every phase's pose, losses, time and memory"
echo "The scores (angular errors and pose errors) are the JSON line above."
