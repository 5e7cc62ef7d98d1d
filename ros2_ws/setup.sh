#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# One idempotent set-up: creates .venv at the repository root with the pinned
# dependencies (requirements.txt + constraints.txt) and installs every package
# under src/ into it (editable, so a `git pull` needs no reinstall).
# A second run with nothing to do checks one fingerprint and returns in about
# a second. Set SUTURE_PYTHON to choose the interpreter (default: python3).
#
# --with-blender also installs the optional Blender extra (requirements-blender.txt:
# bpy and OpenEXR, ~375 MB) for `suture-sim --renderer cycles`; it has its own
# fingerprint, so a second run is as fast, and a later run without the option keeps it.
set -euo pipefail

with_blender=0
for option in "$@"; do
  case "$option" in
    --with-blender) with_blender=1 ;;
    *) echo "setup: unknown option $option (known: --with-blender)" >&2; exit 2 ;;
  esac
done

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
venv="$repo/.venv"
python=${SUTURE_PYTHON:-python3}
stamp="$venv/.suture-setup-fingerprint"

# Everything that changes what gets installed goes into the fingerprint.
fingerprint=$(
  cd "$repo"
  { "$python" -c 'import sys; print(sys.version)'
    cat ros2_ws/requirements.txt ros2_ws/constraints.txt
    cat src/*/setup.py src/*/setup.cfg src/*/package.xml
    ls -d src/*/
  } | sha256sum | cut -d' ' -f1
)

# The Blender extra, installed into an up-to-date environment.
install_blender() {
  local blender_stamp="$venv/.suture-setup-blender-fingerprint" blender_fingerprint
  blender_fingerprint=$(cat "$stamp" "$repo/ros2_ws/requirements-blender.txt" | sha256sum | cut -d' ' -f1)
  if [ -f "$blender_stamp" ] && [ "$(cat "$blender_stamp")" = "$blender_fingerprint" ]; then
    echo "setup: the Blender extra is up to date"
    return
  fi
  echo "setup: installing the Blender extra (bpy, ~375 MB)"
  # --no-deps: see requirements-blender.txt (bpy declares numpy<2; the project pins numpy 2).
  "$venv/bin/python" -m pip --disable-pip-version-check install --quiet --no-deps \
    -r "$repo/ros2_ws/requirements-blender.txt" 2>&1 | grep -v "^WARNING: Location" || true
  "$venv/bin/python" -c 'import OpenEXR; from suture_sim.cycles import import_bpy; import_bpy()' \
    || { echo "setup: the Blender extra is incomplete, see the pip output above" >&2; exit 1; }
  echo "$blender_fingerprint" > "$blender_stamp"
  echo "setup: the Blender extra is installed"
}

if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$fingerprint" ]; then
  echo "setup: $venv is up to date"
  [ "$with_blender" = 0 ] || install_blender
  exit 0
fi

if ! "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "setup: the ROS 2 Jazzy wheels need Python 3.11; $python is $("$python" --version 2>&1)" >&2
  echo "setup: set SUTURE_PYTHON=/path/to/python3.11" >&2
  exit 1
fi

echo "setup: creating the environment in $venv (first run takes a few minutes)"
# pip's own error for a full disk is easy to miss in its output: say it first.
need_mb=$(( with_blender ? 3500 : 2500 ))
for place in "$repo" "${TMPDIR:-/tmp}"; do
  free_mb=$(df -Pm "$place" 2>/dev/null | awk 'NR == 2 {print $4}')
  if [ -n "$free_mb" ] && [ "$free_mb" -lt "$need_mb" ]; then
    echo "setup: warning: $free_mb MB free on the disk of $place; the installation needs about" \
      "$need_mb MB there (pip then fails with 'No space left on device')" >&2
  fi
done
[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
pip=("$venv/bin/python" -m pip --disable-pip-version-check)
"${pip[@]}" install --quiet --upgrade "pip>=24" 2>&1 | grep -v "^WARNING: Location" || true
"${pip[@]}" install --quiet -r "$repo/ros2_ws/requirements.txt" -c "$repo/ros2_ws/constraints.txt" \
  2>&1 | grep -v "^WARNING: Location" || true
packages=()
for package in "$repo"/src/*/; do packages+=(-e "$package"); done
PYTHONWARNINGS=ignore "${pip[@]}" install --quiet --no-deps --no-build-isolation "${packages[@]}" \
  2>&1 | grep -v "^WARNING: Location" || true
# The greps above hide the local-index noise but would hide a failure too:
# check that the environment is complete before recording success.
"$venv/bin/python" -c 'import rclpy, torch, cv2, rosbags, mcap, scipy, suture_common, suture_sim' \
  || { echo "setup: the environment is incomplete, see the pip output above" >&2; exit 1; }
echo "$fingerprint" > "$stamp"
echo "setup: done"
[ "$with_blender" = 0 ] || install_blender
