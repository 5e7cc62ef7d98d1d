#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The project's test command (README Quick start; CI runs exactly this).
# Sets up the environment if needed, then: ruff lint and format check,
# import-linter contracts (docs/interfaces.md one-way dependencies), and pytest.
# Extra arguments go to pytest, e.g. `bash ros2_ws/test.sh -k bag -x`.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
# CI installs the Blender extra too and requires it, so the Cycles renderer's test renders a
# frame on every run instead of being skipped (see src/suture_sim/test/conftest.py).
bash "$repo/ros2_ws/setup.sh" --with-blender
export SUTURE_REQUIRE_BLENDER=1
cd "$repo"
venv="$repo/.venv/bin"
echo "== ruff"
"$venv/ruff" check .
"$venv/ruff" format --check .
echo "== import contracts"
"$venv/lint-imports"
echo "== pytest"
"$venv/python" -m pytest "$@"
