# SPDX-License-Identifier: Apache-2.0
"""``suture-graph-report``: score and show what the node graph published for a replayed bag.

The demo replays a simulator bag through the running nodes and records their
outputs (``ros2_ws/launch.sh --bag BAG --record OUTPUTS``). This command joins the
recorded outputs with the bag's ground truth by header stamp, scores them with the
same :class:`suture_bench.evaluate.Scoreboard` as ``suture-eval`` (one truth for both),
prints per frame the grasp point in the camera and robot frames and its error, and
writes the report folder of :mod:`suture_bench.report` (the same as ``suture-eval
--report``): ``summary.json`` (the evaluation summary of the graph's outputs, plus "graph":
the player's latency figures and the nodes' peak memory when given), ``frames.json`` and
``frames/`` (per frame also the grasp in camera and robot frames), ``overlays/`` and
``centreline_3d.png``.

Per-stage latencies come from the recorder's receive times (``ros2 bag record``'s log
time) relative to the player's publication time of the frame, so they include transport.

Example::

    suture-graph-report --bag bags/sample --outputs out/demo/report/outputs \\
        --player-report out/demo/player.json --out out/demo/report

Exit status 0 on success, 1 with one line on standard error when an input cannot be read.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from suture_bench.cli import render_table
from suture_bench.evaluate import Scoreboard, StageOutputs
from suture_bench.frames import EvaluationError, Frame, read_frames
from suture_bench.report import ReportWriter
from suture_common import messages, topics
from suture_common.bag_io import read_messages

TARGET_POSE = topics.TARGET_POSE
OUTPUT_TOPICS = (
    topics.LEFT_MASK,
    topics.RIGHT_MASK,
    topics.LEFT_SEQUENCE,
    topics.RIGHT_SEQUENCE,
    topics.PATH,
    topics.GRASP_POSE,
    TARGET_POSE,
)


@dataclass
class Received:
    """The graph's outputs of one stamp: rosbags messages and receive times (ns) by topic."""

    messages: dict[str, Any] = field(default_factory=dict)
    received_ns: dict[str, int] = field(default_factory=dict)

    def first_ns(self, *names: str) -> int | None:
        """The latest receive time of the given topics (None if any is missing)."""
        if not all(name in self.received_ns for name in names):
            return None
        return max(self.received_ns[name] for name in names)


def read_outputs(bag: str | Path) -> dict[int, Received]:
    """The recorded pipeline outputs of ``bag`` by header stamp (ns); the first message per topic wins."""
    outputs: dict[int, Received] = defaultdict(Received)
    for record in read_messages(bag, OUTPUT_TOPICS):
        stamp = messages.ns_from_stamp(record.message.header.stamp)
        entry = outputs[stamp]
        if record.topic not in entry.messages:
            entry.messages[record.topic] = record.message
            entry.received_ns[record.topic] = record.timestamp_ns
    return dict(outputs)


def stage_outputs(frame: Frame, got: Received | None, published_ns: int | None) -> StageOutputs:
    """What the graph published for ``frame`` as :class:`StageOutputs` (missing masks = empty masks)."""
    got = got or Received()
    result = StageOutputs()
    found = got.messages
    if topics.LEFT_MASK in found and topics.RIGHT_MASK in found:
        result.masks = (
            messages.image_to_array(found[topics.LEFT_MASK], expect="mono8"),
            messages.image_to_array(found[topics.RIGHT_MASK], expect="mono8"),
        )
    else:
        result.masks = (np.zeros_like(frame.true_left_mask), np.zeros_like(frame.true_right_mask))
        result.failure = "segmentation: no masks published"
    if topics.LEFT_SEQUENCE in found and topics.RIGHT_SEQUENCE in found:
        # Scored like StereoOrdering.left/right: the points seen in the mask (z = 0).
        left, right = (
            messages.polygon_to_array(found[t]) for t in (topics.LEFT_SEQUENCE, topics.RIGHT_SEQUENCE)
        )
        result.sequences = (left[left[:, 2] == 0.0, :2], right[right[:, 2] == 0.0, :2])
    elif result.failure is None:
        result.failure = "ordering: no sequences published"
    if topics.GRASP_POSE in found and topics.PATH in found:
        result.path = messages.path_to_array(found[topics.PATH])
        result.grasp = messages.pose_to_arrays(found[topics.GRASP_POSE])[0]
    elif result.failure is None:
        result.failure = "reconstruction: no grasp pose published"
    if published_ns is not None:
        marks = [
            ("segmentation", published_ns, got.first_ns(topics.LEFT_MASK, topics.RIGHT_MASK)),
            (
                "ordering",
                got.first_ns(topics.LEFT_MASK, topics.RIGHT_MASK),
                got.first_ns(topics.LEFT_SEQUENCE),
            ),
            ("reconstruction", got.first_ns(topics.LEFT_SEQUENCE), got.first_ns(topics.GRASP_POSE)),
            ("total", published_ns, got.first_ns(topics.GRASP_POSE)),
        ]
        for stage, start, end in marks:
            if start is not None and end is not None:
                result.latency_ms[stage] = (end - start) / 1e6
    return result


def _published_ns(player_report: dict | None) -> dict[int, int]:
    if not player_report:
        return {}
    return {
        int(entry["stamp_ns"]): round(entry["published_s"] * 1e9)
        for entry in player_report.get("per_frame", [])
        if entry.get("published_s") is not None
    }


def _vector_mm(vector: np.ndarray | None) -> str:
    if vector is None:
        return "(not published)"
    return "(" + ", ".join(f"{1000 * float(x):+8.1f}" for x in vector) + ") mm"


def write_report(
    bag: str | Path,
    outputs_bag: str | Path,
    out: str | Path,
    player_report: dict | None = None,
    memory: dict | None = None,
    max_overlays: int = 20,
    echo: bool = True,
) -> dict:
    """Score the recorded outputs against the bag's ground truth and write the report folder.

    Returns the summary written to ``OUT/summary.json``.
    """
    writer = ReportWriter(out, max_overlays)
    recorded = read_outputs(outputs_bag)
    published = _published_ns(player_report)
    scoreboard = Scoreboard(ordering_ran=True)
    rows: list[dict[str, Any]] = []
    for index, frame in enumerate(read_frames(Path(bag), images=True)):
        got = recorded.get(frame.stamp_ns)
        outputs = stage_outputs(frame, got, published.get(frame.stamp_ns))
        record = scoreboard.add(frame, outputs)
        error = record.get("grasp_error_mm")
        robot = None
        if got is not None and TARGET_POSE in got.messages:
            robot = messages.pose_to_arrays(got.messages[TARGET_POSE])[0]
        row = {
            **record,
            "grasp_camera_m": None if outputs.grasp is None else np.asarray(outputs.grasp).tolist(),
            "grasp_robot_m": None if robot is None else robot.tolist(),
            "grasp_error_mm": error,
            "failure": outputs.failure,
        }
        rows.append(row)
        writer.add(frame, outputs, row)
        if echo:
            shown = "n/a" if error is None else f"{error:5.2f} mm"
            print(
                f"frame {index:3d} {frame.topology:16s} grasp camera {_vector_mm(outputs.grasp)}  "
                f"robot {_vector_mm(robot)}  error {shown}"
                + (f"  [{outputs.failure}]" if outputs.failure else "")
            )
    if not rows:
        raise EvaluationError(f"{bag}: no frames with ground truth to report on")
    summary = scoreboard.summary("predicted", "predicted")
    summary.pop("per_frame")
    summary["graph"] = {
        "player": {k: v for k, v in (player_report or {}).items() if k != "per_frame"},
        "peak_memory_mib": memory or {},
        "frames_with_grasp_pose": sum(row["grasp_camera_m"] is not None for row in rows),
    }
    writer.finish(summary)
    return summary


def _load_json(path: str | None) -> dict | None:
    if not path:
        return None
    with open(path) as stream:
        return json.load(stream)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="suture-graph-report", description=__doc__.split("\n\n")[0])
    parser.add_argument("--bag", required=True, help="the replayed bag, with ground truth")
    parser.add_argument("--outputs", required=True, help="the recorded outputs of the node graph")
    parser.add_argument("--out", required=True, help="report folder to write")
    parser.add_argument("--player-report", help="the player's JSON report (latency per frame)")
    parser.add_argument("--memory", help="peak memory per node (JSON from ros2_ws/launch.sh --memory)")
    parser.add_argument("--max-overlays", type=int, default=20, help="overlay pictures written (default 20)")
    args = parser.parse_args(argv)
    try:
        summary = write_report(
            args.bag,
            args.outputs,
            args.out,
            player_report=_load_json(args.player_report),
            memory=_load_json(args.memory),
            max_overlays=args.max_overlays,
        )
    except (EvaluationError, OSError, ValueError) as error:
        print(f"suture-graph-report: error: {error}", file=sys.stderr)
        return 1
    print()
    print(render_table(summary, title="node graph"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
