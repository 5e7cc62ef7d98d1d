# SPDX-License-Identifier: Apache-2.0
"""suture-eval-compare: two runs' frames paired, the frames gained and lost, refusals named, the
frames that came under or went over 10 mm off while missed in both; its output into a closed pipe."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from suture_bench.compare import CompareError, compare_records, load_records, main
from suture_bench.evaluate import evaluate

SAMPLE = Path(__file__).resolve().parents[3] / "bags" / "sample"


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("compare") / "base"
    summary = evaluate([SAMPLE], masks="ground_truth", sequences="ground_truth", report=out, max_overlays=0)
    return out, summary


def test_each_record_says_whether_the_frame_counts_within_5mm(report: tuple[Path, dict]) -> None:
    out, summary = report
    records = load_records(out)
    assert len(records) == summary["frames"] == 10
    successes = [record["success"] for record in records]
    assert sum(successes) == round(summary["grasp"]["within_5mm"] * len(records))
    for record in records:
        assert record["success"] == (record["grasp_produced"] and record["grasp_error_mm"] <= 5.0)


def test_frames_gained_and_lost_are_listed_with_both_outcomes(report: tuple[Path, dict], tmp_path, capsys):
    out, _ = report
    base = load_records(out)
    assert compare_records(base, base).gained == [] and compare_records(base, base).lost == []
    new = copy.deepcopy(base)
    lost = next(i for i, record in enumerate(new) if record["success"])
    new[lost].update(success=False, grasp_produced=False, failure="reconstruction: UncertainGraspError")
    del new[lost]["grasp_error_mm"]
    wrong = next(i for i, record in enumerate(new) if record["success"] and i != lost)
    new[wrong].update(success=False, grasp_error_mm=12.5)
    comparison = compare_records(base, new)
    assert comparison.base_successes == sum(r["success"] for r in base)
    assert comparison.new_successes == comparison.base_successes - 2
    assert (comparison.base_wrong, comparison.new_wrong) == (0, 1)
    assert [change[0] for change in comparison.lost] == sorted([lost, wrong]) and not comparison.gained
    by_index = {change[0]: change for change in comparison.lost}
    assert by_index[lost][3] == "refused: reconstruction: UncertainGraspError"
    assert by_index[wrong][3] == "grasp 12.5 mm" and by_index[wrong][2].startswith("grasp ")
    topology = base[lost]["topology"]
    assert comparison.by_topology[topology][0] > comparison.by_topology[topology][1]
    assert not comparison.wrong_gone and not comparison.wrong_new  # those two are lost, listed there

    refused = copy.deepcopy(new)  # the wrong grasp refused instead: missed in both, no longer wrong
    refused[wrong].update(grasp_produced=False, failure="reconstruction: ThreadTooShortError")
    del refused[wrong]["grasp_error_mm"]
    refusal = compare_records(new, refused)
    assert not refusal.gained and not refusal.lost and (refusal.base_wrong, refusal.new_wrong) == (1, 0)
    refusal_outcomes = ("grasp 12.5 mm", "refused: reconstruction: ThreadTooShortError")
    assert refusal.wrong_gone == [(wrong, new[wrong]["topology"], *refusal_outcomes)]
    back = compare_records(refused, new)
    assert back.wrong_new == [(wrong, new[wrong]["topology"], *reversed(refusal_outcomes))]
    assert not back.wrong_gone

    (tmp_path / "new.json").write_text(json.dumps(new))
    assert main([str(out), str(tmp_path / "new.json"), "--json", str(tmp_path / "cmp.json")]) == 0
    printed = capsys.readouterr().out
    assert "(gained 0, lost 2)" in printed and "more than 10 mm off 0 -> 1" in printed
    (tmp_path / "refused.json").write_text(json.dumps(refused))
    assert main([str(tmp_path / "new.json"), str(tmp_path / "refused.json")]) == 0
    printed = capsys.readouterr().out
    assert f"missed in both, no longer more than 10 mm off:\n  {wrong:>5}" in printed
    assert json.loads((tmp_path / "cmp.json").read_text())["lost"][0]["index"] == min(lost, wrong)


def test_runs_over_other_frames_are_refused_with_one_line(report: tuple[Path, dict], tmp_path, capsys):
    out, _ = report
    base = load_records(out)
    with pytest.raises(CompareError, match="10 and 9 frames"):
        compare_records(base, base[:9])
    shifted = copy.deepcopy(base)
    shifted[3]["stamp_ns"] += 1
    with pytest.raises(CompareError, match="frame 3 differs"):
        compare_records(base, shifted)
    old = [{k: v for k, v in record.items() if k != "success"} for record in base]
    with pytest.raises(CompareError, match="no frame is scored"):
        compare_records(old, old)
    assert main([str(out), str(tmp_path / "missing")]) == 1
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "cannot read" in error[0]


def test_output_into_a_closed_pipe_ends_quietly(report: tuple[Path, dict]) -> None:
    """``suture-eval-compare A B | head``: the reader goes away before the lines are written."""
    out, _ = report
    read_end, write_end = os.pipe()
    os.close(read_end)
    command = [sys.executable, "-m", "suture_bench.compare", str(out), str(out)]
    ended = subprocess.run(command, stdout=write_end, stderr=subprocess.PIPE, timeout=120, check=False)
    os.close(write_end)
    assert ended.returncode == 0 and b"Traceback" not in ended.stderr, ended.stderr.decode()
