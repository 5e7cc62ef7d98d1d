#!/usr/bin/env bash
# The main job (README Quick start). Until the pipeline stages exist, it sets up
# the environment, simulates a stereo bag with one frame of each topology and
# prints what is in it. Output goes to out/demo/ (a bag and PNG folders).
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$repo/ros2_ws/setup.sh"
out="$repo/out/demo"
rm -rf "$out"
mkdir -p "$out"
"$repo/.venv/bin/suture-sim" --topology mixed --frames 5 --domain legacy --resolution 640x480 \
  --seed 1 --out "$out/bag" --png-dir "$out/png"
"$repo/.venv/bin/suture-bag-info" "$out/bag"
echo "demo: bag in $out/bag, stereo PNGs and masks in $out/png"
