#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# One idempotent set-up: creates .venv at the repository root with the pinned
# dependencies (requirements.txt + constraints.txt) and installs every package
# under src/ into it (editable, so a `git pull` needs no reinstall).
# A second run with nothing to do checks one fingerprint and returns in about
# a second. Set SUTURE_PYTHON to choose the interpreter (default: python3).
set -euo pipefail

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

if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$fingerprint" ]; then
  echo "setup: $venv is up to date"
  exit 0
fi

if ! "$python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "setup: the ROS 2 Jazzy wheels need Python 3.11; $python is $("$python" --version 2>&1)" >&2
  echo "setup: set SUTURE_PYTHON=/path/to/python3.11" >&2
  exit 1
fi

echo "setup: creating the environment in $venv (first run takes a few minutes)"
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
