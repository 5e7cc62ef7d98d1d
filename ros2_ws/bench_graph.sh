#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Latency benchmark of the whole node graph (image publication -> grasp pose received), on the
# real middleware, with the nodes as separate processes (ros2_ws/launch.sh):
#   1. frame by frame (--as-fast-as-graph): each frame sent when the previous grasp pose arrived,
#      so the latency has no queueing in it;
#   2. streaming at the bag's recorded rate x RATE (default 1.0; the bundled bag is 10 frames/s):
#      the graph drops what it cannot keep up with; frames per second sustained = grasp poses
#      received per second, with the latency under that load.
# Then the nodes' peak resident memory (VmHWM). Results go to OUT (default out/bench_graph).
#
#   bash ros2_ws/bench_graph.sh [--bag BAG] [--loops N] [--rate R] [--out DIR] [-- ROS_ARGS...]
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bag="$repo/bags/sample" loops=5 rate=1.0 out="$repo/out/bench_graph" extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --bag) bag=$2; shift 2 ;;
    --loops) loops=$2; shift 2 ;;
    --rate) rate=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --) shift; extra=(-- "$@"); break ;;
    *) echo "bench_graph: unknown option $1" >&2; exit 2 ;;
  esac
done
bash "$repo/ros2_ws/setup.sh" >/dev/null
rm -rf "$out"
mkdir -p "$out"
launch=(bash "$repo/ros2_ws/launch.sh" --bag "$bag" --loops "$loops")

echo "bench_graph: 1/2 frame by frame"
"${launch[@]}" --as-fast-as-graph --report "$out/frame_by_frame.json" --memory "$out/memory.json" \
  --log-dir "$out/logs_frame_by_frame" ${extra[@]+"${extra[@]}"} >"$out/frame_by_frame.log"
echo "bench_graph: 2/2 streaming at ${rate} x the recorded rate"
"${launch[@]}" --rate "$rate" --report "$out/streaming.json" \
  --log-dir "$out/logs_streaming" ${extra[@]+"${extra[@]}"} >"$out/streaming.log"

"$repo/.venv/bin/python" - "$out" <<'EOF'
import json, os, sys
out = sys.argv[1]
load = lambda name: json.load(open(os.path.join(out, name)))
cpu = f"{os.cpu_count()} CPU cores"
print(f"\nnode graph latency, image publication -> grasp pose received ({cpu}):")
print(f"{'mode':34s} {'frames':>6s} {'poses':>6s} {'median ms':>9s} {'p95 ms':>7s} {'fps':>6s}")
for name, label in (("frame_by_frame.json", "frame by frame (no queueing)"),
                    ("streaming.json", "streaming at the recorded rate")):
    r = load(name)
    lat = r.get("latency_ms") or {}
    fmt = lambda v, d=1: "n/a" if v is None else f"{v:.{d}f}"
    print(f"{label:34s} {r['frames']:>6d} {r['outputs']:>6d} {fmt(lat.get('median')):>9s} "
          f"{fmt(lat.get('p95')):>7s} {fmt(r.get('fps'), 2):>6s}")
print("\npeak resident memory per node (MiB):")
for node, mib in load("memory.json").items():
    print(f"  {node:22s} {mib:7.1f}")
EOF
echo "bench_graph: reports in $out"
