# SPDX-License-Identifier: Apache-2.0
"""suture-order-bench prints the median per view by topology and, with --baseline, times two
versions of the ordering side by side on the same frames and counts the sequences that differ."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SAMPLE = Path(__file__).resolve().parents[3] / "bags" / "sample"


def _bench(*args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "suture_bench.ordering_bench", str(SAMPLE), "--limit", "3", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=300)


def test_side_by_side_with_the_same_code_finds_no_difference():
    done = _bench("--baseline", sys.executable, "--rounds", "2")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    straight = next(line for line in lines if line.split()[:2] == ["640x480", "straight"])
    assert float(straight.split()[-1]) > 0  # the topology's median ms per view
    assert any(line.startswith("640x480: median") and "ms per view" in line for line in lines)
    side = lines[lines.index(next(line for line in lines if line.startswith("side by side"))) :]
    assert "fastest of 2 round(s)" in side[0]
    overall = next(line for line in side if line.split()[:2] == ["640x480", "all"]).split()
    assert int(overall[2]) > 0 and float(overall[3]) > 0 and float(overall[4]) > 0
    assert any(line.startswith("CPU ms per view") for line in side)
    assert side[-1].startswith("sequences: 0 of ") and "differ from the baseline" in side[-1]


def test_a_missing_baseline_is_one_line_on_stderr(tmp_path):
    done = _bench("--baseline", str(tmp_path))
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1 and "no interpreter there" in done.stderr
