#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The project's test command (README Quick start; CI runs exactly this).
# Sets up the environment if needed, then: ruff lint and format check,
# import-linter contracts (docs/interfaces.md one-way dependencies), and pytest.
# Extra arguments go to pytest, e.g. `bash ros2_ws/test.sh -k bag -x`.
set -euo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$repo/ros2_ws/setup.sh"
cd "$repo"
venv="$repo/.venv/bin"
echo "== ruff"
"$venv/ruff" check .
"$venv/ruff" format --check .
echo "== import contracts"
"$venv/lint-imports"
echo "== pytest"
"$venv/python" -m pytest "$@"
