# SPDX-License-Identifier: Apache-2.0
"""suture-eval-compare: two runs' frames paired, the frames gained and lost, refusals named."""

from __future__ import annotations

import copy
import json
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

    (tmp_path / "new.json").write_text(json.dumps(new))
    assert main([str(out), str(tmp_path / "new.json"), "--json", str(tmp_path / "cmp.json")]) == 0
    printed = capsys.readouterr().out
    assert "(gained 0, lost 2)" in printed and "more than 10 mm off 0 -> 1" in printed
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
