# SPDX-License-Identifier: Apache-2.0
"""Two ``suture-eval`` runs over the same bags, compared frame by frame (``suture-eval-compare``).

A change to a stage or a model moves the headline figure by a few frames while many more frames
change outcome both ways; a 400-frame set's ``within_5mm`` alone cannot tell a gain from that
churn. :func:`compare_records` pairs the per-frame records of two runs (``suture-eval --report
DIR`` writes them to ``DIR/frames.json``) and counts the frames gained (a miss in the base run, a
success in the new one) and lost, overall and by topology, with each changed frame's outcome in
both runs, and the grasps more than 10 mm off in each, listing the frames missed in both runs that
came under or went over 10 mm (a refusal instead of a wrong grasp is such a change). A frame's
``success`` is the evaluator's (``suture_bench.evaluate``): a grasp within 5 mm of a true grasp
point that is not hidden, or a hidden one refused as not seen.

    suture-eval-compare out/base_report out/new_report [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from suture_bench.evaluate import WRONG_GRASP

#: The evaluator's wrong grasp (``grasp.beyond_10mm``) in the per-frame records' millimetres.
WRONG_GRASP_MM = 1000 * WRONG_GRASP


class CompareError(ValueError):
    """The two runs cannot be compared (a missing or unreadable report, other bags, old records)."""


@dataclass
class Comparison:
    """Frame-by-frame difference of two runs: ``by_topology`` (base successes, new successes,
    frames scored), grasps more than :data:`WRONG_GRASP_MM` off in each, and ``gained``/``lost``:
    (index, topology, base outcome, new outcome) of the frames whose success changed;
    ``wrong_gone``/``wrong_new``: the same of the frames missed in both runs that were more than
    :data:`WRONG_GRASP_MM` off in the base run only / in the new run only."""

    by_topology: dict[str, tuple[int, int, int]] = field(default_factory=dict)
    base_wrong: int = 0
    new_wrong: int = 0
    gained: list[tuple[int, str, str, str]] = field(default_factory=list)
    lost: list[tuple[int, str, str, str]] = field(default_factory=list)
    wrong_gone: list[tuple[int, str, str, str]] = field(default_factory=list)
    wrong_new: list[tuple[int, str, str, str]] = field(default_factory=list)

    @property
    def base_successes(self) -> int:
        return sum(base for base, _, _ in self.by_topology.values())

    @property
    def new_successes(self) -> int:
        return sum(new for _, new, _ in self.by_topology.values())

    @property
    def frames(self) -> int:
        return sum(total for _, _, total in self.by_topology.values())

    def as_dict(self) -> dict[str, Any]:
        def rows(changes: list[tuple[int, str, str, str]]) -> list[dict[str, Any]]:
            keys = ("index", "topology", "base", "new")
            return [dict(zip(keys, change, strict=True)) for change in changes]

        return {
            "frames": self.frames,
            "within_5mm": {
                "base": self.base_successes / self.frames,
                "new": self.new_successes / self.frames,
            },
            "beyond_10mm": {"base": self.base_wrong, "new": self.new_wrong},
            "by_topology": {
                name: {"frames": total, "base_successes": base, "new_successes": new}
                for name, (base, new, total) in self.by_topology.items()
            },
            "gained": rows(self.gained),
            "lost": rows(self.lost),
            "wrong_gone": rows(self.wrong_gone),
            "wrong_new": rows(self.wrong_new),
        }


def load_records(report: str | Path) -> list[dict[str, Any]]:
    """The per-frame records of a ``suture-eval --report`` folder (or its ``frames.json``)."""
    path = Path(report)
    if path.is_dir():
        path = path / "frames.json"
    try:
        records = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise CompareError(f"cannot read {path}: {error}; give a suture-eval --report folder") from error
    if not isinstance(records, list):
        raise CompareError(f"{path} is not a list of per-frame records")
    return records


def outcome(record: dict[str, Any]) -> str:
    """A frame's result in a few words: the grasp error, the refusal, or why it was not scored."""
    if record.get("not_run"):
        return f"not run: {record['not_run']}"
    hidden = " (true grasp point hidden)" if record.get("grasp_hidden") else ""
    if record.get("grasp_produced"):
        error = record.get("grasp_error_mm")
        return ("grasp, not scored" if error is None else f"grasp {error:.1f} mm") + hidden
    return f"refused: {record.get('failure', 'no reason recorded')}{hidden}"


def compare_records(base: Sequence[dict[str, Any]], new: Sequence[dict[str, Any]]) -> Comparison:
    """Compare two runs' per-frame records, paired by position (the same bags in the same order).

    Frames that neither run could score (no true 3D path) are left out. Raises
    :class:`CompareError` when the runs differ in frame count, in a frame's stamp or topology, in
    which frames they scored, or when they scored none (reports of a ``suture-eval`` older than
    the records' ``success``)."""
    if len(base) != len(new):
        raise CompareError(f"the runs have {len(base)} and {len(new)} frames: run both over the same bags")
    comparison = Comparison()
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0])
    for index, (old_record, new_record) in enumerate(zip(base, new, strict=True)):
        same = all(old_record.get(key) == new_record.get(key) for key in ("stamp_ns", "topology"))
        if not same:
            raise CompareError(f"frame {index} differs in stamp or topology: run both over the same bags")
        scored = ("success" in old_record, "success" in new_record)
        if scored != (True, True):
            if scored == (False, False):  # no 3D truth to score it against, in either run
                continue
            raise CompareError(f"frame {index} is scored in one run only: run both with this suture-eval")
        topology = str(new_record.get("topology"))
        successes = (bool(old_record["success"]), bool(new_record["success"]))
        counts[topology][0] += successes[0]
        counts[topology][1] += successes[1]
        counts[topology][2] += 1
        wrong = (_wrong(old_record), _wrong(new_record))
        comparison.base_wrong += wrong[0]
        comparison.new_wrong += wrong[1]
        if successes[0] != successes[1]:
            listed = comparison.gained if successes[1] else comparison.lost
        elif wrong[0] != wrong[1]:
            listed = comparison.wrong_new if wrong[1] else comparison.wrong_gone
        else:
            continue
        listed.append((index, topology, outcome(old_record), outcome(new_record)))
    comparison.by_topology = {name: (base, new, total) for name, (base, new, total) in sorted(counts.items())}
    if comparison.frames == 0:
        raise CompareError("no frame is scored in the reports (true 3D path and grasp point, and 'success')")
    return comparison


def _wrong(record: dict[str, Any]) -> bool:
    error = record.get("grasp_error_mm")
    return bool(record.get("grasp_produced")) and error is not None and error > WRONG_GRASP_MM


def format_comparison(comparison: Comparison) -> str:
    """The comparison as the lines ``suture-eval-compare`` prints."""
    total = comparison.frames
    lines = [
        f"{total} frames; within 5 mm {100 * comparison.base_successes / total:.1f} % -> "
        f"{100 * comparison.new_successes / total:.1f} % (gained {len(comparison.gained)}, "
        f"lost {len(comparison.lost)}); grasps more than {WRONG_GRASP_MM:.0f} mm off "
        f"{comparison.base_wrong} -> {comparison.new_wrong}",
    ]
    for name, (base, new, frames) in comparison.by_topology.items():
        lines.append(f"  {name:<18} {base:>5} -> {new:<5} of {frames}")
    limit = f"{WRONG_GRASP_MM:.0f} mm"
    sections = (
        ("gained", comparison.gained),
        ("lost", comparison.lost),
        (f"missed in both, no longer more than {limit} off", comparison.wrong_gone),
        (f"missed in both, now more than {limit} off", comparison.wrong_new),
    )
    for title, changes in sections:
        if changes:
            lines.append(f"{title}:")
            lines += [f"  {index:>5} {topology:<16} {old} -> {new}" for index, topology, old, new in changes]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="suture-eval-compare",
        description="Compare two suture-eval --report runs over the same bags frame by frame: frames "
        "gained and lost within 5 mm, by topology, and grasps more than 10 mm off.",
    )
    parser.add_argument("base", help="the base run's --report folder (or its frames.json)")
    parser.add_argument("new", help="the new run's --report folder (or its frames.json)")
    parser.add_argument("--json", metavar="FILE", help="also write the comparison here")
    args = parser.parse_args(argv)
    try:
        comparison = compare_records(load_records(args.base), load_records(args.new))
    except CompareError as error:
        print(f"suture-eval-compare: {error}", file=sys.stderr)
        return 1
    try:
        print(format_comparison(comparison), flush=True)
    except BrokenPipeError:  # the reader went away (e.g. piped into head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    if args.json:
        Path(args.json).write_text(json.dumps(comparison.as_dict(), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
