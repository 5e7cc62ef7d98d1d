# SPDX-License-Identifier: Apache-2.0
"""suture-graph-report scores recorded outputs exactly as suture-eval scores the core functions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from suture_bench.evaluate import evaluate
from suture_bench.frames import read_frames
from suture_bench.graph_report import TARGET_POSE, main, write_report
from suture_common import messages, topics
from suture_common.bag_io import BagWriter
from suture_ordering.core import order_stereo
from suture_reconstruction.core import reconstruct

SAMPLE = Path(__file__).resolve().parents[3] / "bags" / "sample"
FRAME = topics.LEFT_FRAME


def _record_outputs(path: Path, skip: set[int]) -> list[int]:
    """Write what the graph would publish from the true masks (frames in ``skip``: nothing)."""
    stamps = []
    with BagWriter(path) as bag:
        for index, frame in enumerate(read_frames(SAMPLE, images=True)):
            stamps.append(frame.stamp_ns)
            if index in skip:
                continue
            stamp, clock = frame.stamp_ns, 2_000_000_000_000_000_000 + index * 10**8
            masks = (frame.true_left_mask, frame.true_right_mask)
            for topic, mask in zip((topics.LEFT_MASK, topics.RIGHT_MASK), masks, strict=True):
                bag.write(
                    topic, messages.image_message(mask.astype(np.uint8) * 255, "mono8", stamp, FRAME), clock
                )
            ordering = order_stereo(masks[0], masks[1], frame.tip_hint, frame.camera)
            # As ordering_node publishes them: z = 1 on points bridged across a gap in the mask.
            left, right = ordering.left_sequence, ordering.right_sequence
            bag.write(topics.LEFT_SEQUENCE, messages.polygon_message(left, stamp, FRAME), clock + 10**6)
            bag.write(topics.RIGHT_SEQUENCE, messages.polygon_message(right, stamp, FRAME), clock + 10**6)
            images = (frame.left_image, frame.right_image)  # as reconstruction_node gets them
            result = reconstruct(left, right, frame.camera, images=images)
            bag.write(topics.PATH, messages.path_message(result.path, stamp, FRAME), clock + 2 * 10**6)
            pose = messages.pose_message(result.grasp_position, np.array([0, 0, 0, 1.0]), stamp, FRAME)
            bag.write(topics.GRASP_POSE, pose, clock + 3 * 10**6)
            shifted = result.grasp_position + np.array([1, 2, 3])
            robot = messages.pose_message(shifted, np.array([0, 0, 0, 1.0]), stamp, "base")
            bag.write(TARGET_POSE, robot, clock + 4 * 10**6)
    return stamps


def test_the_report_scores_recorded_outputs_like_suture_eval(tmp_path, capsys):
    stamps = _record_outputs(tmp_path / "outputs", skip={9})
    player = {
        "frames": 10,
        "per_frame": [{"stamp_ns": s, "published_s": 2e9 + i * 0.1 - 0.05} for i, s in enumerate(stamps)],
    }
    summary = write_report(SAMPLE, tmp_path / "outputs", tmp_path / "report", player_report=player)
    reference = evaluate([SAMPLE], masks="ground_truth", sequences="predicted")

    rows = json.loads((tmp_path / "report" / "frames.json").read_text())
    assert len(rows) == 10 and rows[9]["grasp_camera_m"] is None
    assert rows[9]["failure"] == "segmentation: no masks published"
    for row, expected in zip(rows[:9], reference["per_frame"][:9], strict=True):
        assert abs(row["grasp_error_mm"] - expected["grasp_error_mm"]) < 0.05
        assert np.allclose(np.subtract(row["grasp_robot_m"], row["grasp_camera_m"]), [1, 2, 3])
        # receive times minus publication: 50 ms to the masks, +1 ms sequences, +2 ms grasp pose
        assert (
            abs(row["latency_ms"]["segmentation"] - 50) < 1e-3 and abs(row["latency_ms"]["total"] - 53) < 1e-3
        )
    assert summary["segmentation"]["iou"] < 1.0  # the skipped frame's masks count as missed
    assert summary["grasp"]["within_5mm"] <= 0.9  # and the frame without a grasp point as a miss
    assert summary["graph"]["frames_with_grasp_pose"] == 9
    assert len(list((tmp_path / "report" / "overlays").glob("*.png"))) == 10
    assert (tmp_path / "report" / "centreline_3d.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert printed.count("grasp camera") == 10 and "robot (not published)" in printed


def test_the_command_fails_with_one_line_on_a_missing_bag(tmp_path, capsys):
    assert (
        main(["--bag", str(tmp_path / "nope"), "--outputs", str(tmp_path), "--out", str(tmp_path / "r")]) == 1
    )
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "suture-graph-report" in error[0]
