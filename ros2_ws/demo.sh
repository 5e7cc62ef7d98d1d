#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The main job (README Quick start): set up, replay the bundled bag through the real node graph
# (segmentation -> ordering -> reconstruction -> dry_run executor, each node its own process,
# ros2_ws/launch.sh), record the graph's outputs to MCAP, then print per frame the grasp point in
# the camera and robot frames with its error against the ground truth, and write the report:
#   out/demo/report/{summary.json, frames.json, overlays/, centreline_3d.png, outputs/ (MCAP)}
# Another bag (with the simulator's ground truth): bash ros2_ws/demo.sh path/to/bag
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bag=$(realpath "${1:-$repo/bags/sample}")
out="$repo/out/demo"
bash "$repo/ros2_ws/setup.sh"
rm -rf "$out"
mkdir -p "$out"
echo "demo: replaying $bag through the node graph (logs in $out/logs)"
bash "$repo/ros2_ws/launch.sh" --bag "$bag" --as-fast-as-graph --record "$out/report/outputs" \
  --report "$out/player.json" --memory "$out/memory.json" --log-dir "$out/logs"
"$repo/.venv/bin/suture-graph-report" --bag "$bag" --outputs "$out/report/outputs" \
  --player-report "$out/player.json" --memory "$out/memory.json" --out "$out/report"
echo "demo: report in $out/report (summary.json, frames.json, overlays/, centreline_3d.png, outputs/ MCAP)"
