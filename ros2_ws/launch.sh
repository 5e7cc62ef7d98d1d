#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Start the node graph of docs/interfaces.md with one parameter file, optionally replay a bag
# through it and record its outputs; stop everything cleanly on Ctrl-C, on SIGTERM, or when the
# replay ends.
#
#   bash ros2_ws/launch.sh                                  # the four nodes, until Ctrl-C
#   bash ros2_ws/launch.sh --bag bags/sample --as-fast-as-graph --record out/run/outputs
#   bash ros2_ws/launch.sh --dry-run                        # print settings and commands only
#
# Discovery stays on this host: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless you set the
# variable yourself (SUBNET, SYSTEM_DEFAULT, OFF). Hosts named in ROS_STATIC_PEERS are still
# reached with LOCALHOST; docs/security.md shows how to put a node on another host (--without).
# With ROS_SECURITY_ENABLE=true each node runs in the SROS2 enclave /suture/<name>.
#
# Nodes: segmentation_node, ordering_node, reconstruction_node, executor_node (+ player_node with
# --bag, recorder_node with --record), each started as `ros2 run PKG EXE --ros-args --params-file
# FILE` when the ros2 tool is on PATH, otherwise as the installed console script (.venv/bin/EXE
# from ros2_ws/setup.sh, or lib/PKG/EXE of a sourced colcon install). Job control is on, so each
# node runs in its own process group (Ctrl-C reaches this script only, which then sends every
# node one SIGINT: a second one would skip a node's clean-up, e.g. the recorder finalising its
# bag) and does not start with SIGINT ignored, as background jobs of a plain script would.
# Each node logs to LOG_DIR/NAME.log; a node that exits early is reported and the others go on.
set -euo pipefail
set -m

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
params="$repo/ros2_ws/params/pipeline.yaml"
bag="" rate="" record="" report="" loops="" graph_paced=false memory_file="" dry_run=false
log_dir="$repo/out/launch/$(date +%Y%m%d-%H%M%S)"
ros_args=() without=()

usage() {
  cat <<EOF
usage: bash ros2_ws/launch.sh [options] [-- ROS_ARGS...]
  --params FILE        parameter YAML for every node (default ros2_ws/params/pipeline.yaml)
  --bag BAG            replay this bag's input topics (player_node); the graph stops after it
  --rate R             replay at the recorded timing x R (default 1.0)
  --as-fast-as-graph   send each frame once the previous frame's grasp pose arrived
  --loops N            replay the bag N times (stamps shifted per loop)
  --record DIR         record the pipeline's outputs to this new MCAP bag (recorder_node)
  --report FILE        the player's per-frame latency report (JSON)
  --memory FILE        each node's peak resident memory at the end (JSON, MiB)
  --log-dir DIR        node logs (default out/launch/<date-time>)
  --without NODE       do not start NODE here (e.g. segmentation_node on another host); repeatable
  --dry-run            print the network settings and each node's command, start nothing
  ROS_ARGS             extra --ros-args for every node, e.g. -- -p use_sim_time:=false
EOF
}

while [ $# -gt 0 ]; do
  case "$1" in
    --params) params=$(realpath "$2"); shift 2 ;;
    --bag) bag=$(realpath "$2"); shift 2 ;;
    --rate) rate=$2; shift 2 ;;
    --as-fast-as-graph) graph_paced=true; shift ;;
    --loops) loops=$2; shift 2 ;;
    --record) record=$(realpath -m "$2"); shift 2 ;;
    --report) report=$(realpath -m "$2"); shift 2 ;;
    --memory) memory_file=$(realpath -m "$2"); shift 2 ;;
    --log-dir) log_dir=$(realpath -m "$2"); shift 2 ;;
    --without) without+=("$2"); shift 2 ;;
    --dry-run) dry_run=true; shift ;;
    -h|--help) usage; exit 0 ;;
    --) shift; ros_args=("$@"); break ;;
    *) echo "launch: unknown option $1" >&2; usage >&2; exit 2 ;;
  esac
done
[ -f "$params" ] || { echo "launch: no parameter file $params" >&2; exit 2; }
for skipped in ${without[@]+"${without[@]}"}; do
  case "$skipped" in
    segmentation_node|ordering_node|reconstruction_node|executor_node) ;;
    *) echo "launch: --without $skipped: not one of segmentation_node, ordering_node," \
         "reconstruction_node, executor_node" >&2; exit 2 ;;
  esac
done
[ -z "$bag" ] || [ -e "$bag" ] || { echo "launch: no bag at $bag" >&2; exit 2; }
[ -z "$record" ] || [ ! -e "$record" ] || { echo "launch: $record exists; choose a new --record" >&2; exit 2; }
$dry_run || mkdir -p "$log_dir"
# Large frames over shared memory (see the file's comment); a profile of your own wins.
export FASTRTPS_DEFAULT_PROFILES_FILE=${FASTRTPS_DEFAULT_PROFILES_FILE:-$repo/ros2_ws/params/fastdds.xml}
# Nobody else on the network sees or commands the graph unless you open it (docs/security.md):
# a range you set yourself wins; static peers you name are reached at LOCALHOST too.
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
echo "launch: ROS_AUTOMATIC_DISCOVERY_RANGE=$ROS_AUTOMATIC_DISCOVERY_RANGE" \
  "ROS_STATIC_PEERS=${ROS_STATIC_PEERS:-} ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-0}"

# How a node executable is found: `ros2 run`, the set-up's .venv, or a sourced colcon install.
executable() {  # PKG EXE -> the command words, one per line
  local pkg=$1 exe=$2 prefix
  if command -v ros2 >/dev/null 2>&1; then
    printf '%s\n' ros2 run "$pkg" "$exe"; return
  fi
  if [ -x "$repo/.venv/bin/$exe" ]; then
    printf '%s\n' "$repo/.venv/bin/$exe"; return
  fi
  local IFS=:
  for prefix in ${AMENT_PREFIX_PATH:-}; do
    if [ -x "$prefix/lib/$pkg/$exe" ]; then printf '%s\n' "$prefix/lib/$pkg/$exe"; return; fi
  done
  echo "launch: cannot find $pkg $exe: run 'bash ros2_ws/setup.sh' or source a colcon install" >&2
  return 1
}

names=() pids=()
start() {  # NAME PKG EXE [extra ros args...]
  local name=$1 pkg=$2 exe=$3; shift 3
  local command skipped
  for skipped in ${without[@]+"${without[@]}"}; do
    if [ "$skipped" = "$name" ]; then echo "launch: not starting $name here (--without)"; return; fi
  done
  mapfile -t command < <(executable "$pkg" "$exe")
  [ ${#command[@]} -gt 0 ] || exit 1
  # SROS2: each node in its own enclave of ros2_ws/security/policy.xml (docs/security.md).
  [ "${ROS_SECURITY_ENABLE:-}" != true ] || set -- --enclave "/suture/$name" "$@"
  if $dry_run; then
    printf 'launch: would start %s:' "$name"
    printf ' %q' "${command[@]}" --ros-args --params-file "$params" "$@" ${ros_args[@]+"${ros_args[@]}"}
    echo
    return
  fi
  "${command[@]}" --ros-args --params-file "$params" "$@" ${ros_args[@]+"${ros_args[@]}"} \
    >"$log_dir/$name.log" 2>&1 &
  names+=("$name"); pids+=($!)
  echo "launch: started $name (pid $!, log $log_dir/$name.log)"
}

alive() { kill -0 "$1" 2>/dev/null; }
poll() {  # TRIES CMD...: run CMD every 0.2 s until it succeeds (status 0) or TRIES runs failed
  local tries=$1; shift
  for _ in $(seq "$tries"); do "$@" 2>/dev/null && return 0; sleep 0.2; done
  return 1
}
every_node_logged() {  # every running node has written its first log line
  local i
  for i in "${!pids[@]}"; do
    if alive "${pids[$i]}" && [ ! -s "$log_dir/${names[$i]}.log" ]; then return 1; fi
  done
}

peak_memory() {  # write and print each node's VmHWM (peak resident set), MiB
  local i kib json="{" sep=""
  echo "launch: peak resident memory per node (VmHWM):"
  for i in "${!pids[@]}"; do
    alive "${pids[$i]}" || continue
    kib=$(awk '/^VmHWM:/ {print $2}' "/proc/${pids[$i]}/status" 2>/dev/null || true)
    [ -n "$kib" ] || continue
    printf '  %-22s %7.1f MiB\n' "${names[$i]}" "$(awk "BEGIN {print $kib / 1024}")"
    json+="$sep\"${names[$i]}\": $(awk "BEGIN {printf \"%.1f\", $kib / 1024}")"; sep=", "
  done
  [ -z "$memory_file" ] || echo "$json}" > "$memory_file"
}

stopped=false
stop_all() {  # SIGINT once to every node (recorder last, so it keeps the final outputs)
  $stopped && return; stopped=true
  trap '' INT TERM
  [ -z "$memory_file" ] || peak_memory
  local i deadline pass
  for pass in nodes recorder; do
    local group=()
    for i in "${!pids[@]}"; do
      if [ "$pass" = recorder ] && [ "${names[$i]}" != recorder ]; then continue; fi
      if [ "$pass" = nodes ] && [ "${names[$i]}" = recorder ]; then continue; fi
      group+=("$i")
      alive "${pids[$i]}" && kill -INT "${pids[$i]}" 2>/dev/null || true
    done
    deadline=$((SECONDS + 10))
    for i in ${group[@]+"${group[@]}"}; do
      while alive "${pids[$i]}" && [ $SECONDS -lt $deadline ]; do sleep 0.1; done
      if alive "${pids[$i]}"; then
        echo "launch: ${names[$i]} did not stop on SIGINT within 10 s; SIGTERM" >&2
        kill -TERM "${pids[$i]}" 2>/dev/null || true; sleep 2
        alive "${pids[$i]}" && kill -KILL "${pids[$i]}" 2>/dev/null || true
      fi
    done
  done
  echo "launch: stopped (logs in $log_dir)"
}
if ! $dry_run; then
  trap 'stop_all; exit 130' INT
  trap 'stop_all; exit 143' TERM
  trap 'stop_all' EXIT
fi

[ -z "$record" ] || start recorder suture_replay recorder_node -p "output:=$record"
start segmentation_node suture_segmentation segmentation_node
start ordering_node suture_ordering ordering_node
start reconstruction_node suture_reconstruction reconstruction_node
start executor_node grasp_executor executor_node

player_pid=""
if [ -n "$bag" ]; then
  # Before the first frame: every node constructed (its first log line; the recorder and the
  # executor's target pose must hear frame 0 too) and the recorder matched a publisher on every
  # topic (what is written before is not recorded); 30 s and 15 s at most.
  if ! $dry_run; then
    poll 150 every_node_logged || true
    [ -z "$record" ] || poll 75 grep -q "every recorded topic has a publisher" "$log_dir/recorder.log" || true
  fi
  player_args=(-p "bag:=$bag" -p "wait_for_output:=$graph_paced")
  [ -z "$rate" ] || player_args+=(-p "rate:=$rate")
  [ -z "$loops" ] || player_args+=(-p "loops:=$loops")
  [ -z "$report" ] || player_args+=(-p "report:=$report")
  start player suture_replay player_node "${player_args[@]}"
  $dry_run || player_pid=${pids[-1]}
fi
$dry_run && exit 0

# Watch: report nodes that exit early; with a replay, stop when the player is done.
reported=()
status=0
while true; do
  if [ -n "$player_pid" ] && ! alive "$player_pid"; then
    wait "$player_pid" || status=$?
    [ "$status" -eq 0 ] || echo "launch: player exited with status $status (log $log_dir/player.log)" >&2
    tail -n 1 "$log_dir/player.log" | sed 's/^/launch: player: /'
    break
  fi
  for i in "${!pids[@]}"; do
    if [ "${pids[$i]}" != "$player_pid" ] && ! alive "${pids[$i]}" && [ -z "${reported[$i]:-}" ]; then
      reported[$i]=1
      echo "launch: ${names[$i]} exited; last lines of $log_dir/${names[$i]}.log:" >&2
      tail -n 5 "$log_dir/${names[$i]}.log" | sed 's/^/    /' >&2
    fi
  done
  sleep 0.2
done
stop_all
exit "$status"
