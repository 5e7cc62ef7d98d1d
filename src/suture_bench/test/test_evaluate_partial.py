# SPDX-License-Identifier: Apache-2.0
"""suture-eval on bags that carry less than the simulator's: true masks only, sequences with
z = 0, damaged files, no frames at all; and ``--report``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from suture_bench.evaluate import Scoreboard, StageOutputs, evaluate
from suture_bench.frames import EvaluationError, read_frames
from suture_common import messages, topics
from suture_common.bag_io import BagWriter, read_raw
from suture_common.camera import StereoCamera
from suture_sim.output import write_frame
from suture_sim.scene import SimConfig, generate_frame

SAMPLE = Path(__file__).resolve().parents[3] / "bags" / "sample"
THREE_D_TRUTH = {topics.GT_PATH, topics.GT_GRASP_POSE, topics.GT_LEFT_SEQUENCE, topics.GT_RIGHT_SEQUENCE}


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory) -> Path:
    """Three small legacy-domain simulator frames (320x240)."""
    path = tmp_path_factory.mktemp("sim") / "bag"
    config = SimConfig(topology="mixed", camera=StereoCamera.default(320, 240), seed=2201)
    with BagWriter(path) as writer:
        for index in range(3):
            write_frame(writer, generate_frame(config, index))
    return path


def copy_bag(source: Path, target: Path, drop=frozenset(), flatten_sequences: bool = False) -> Path:
    """A copy of ``source`` without the ``drop`` topics; sequences with z = 0 when asked."""
    with BagWriter(target) as writer:
        for topic, msgtype, stamp, data in read_raw(source):
            if topic in drop:
                continue
            if flatten_sequences and topic in (topics.GT_LEFT_SEQUENCE, topics.GT_RIGHT_SEQUENCE):
                message = messages.TYPESTORE.deserialize_cdr(data, msgtype)
                points = messages.polygon_to_array(message)
                points[:, 2] = 0.0
                frame_id = message.header.frame_id
                writer.write(topic, messages.polygon_message(points, stamp, frame_id), stamp)
                continue
            writer.write_raw(topic, msgtype, data, stamp)
    return target


def test_a_bag_with_true_masks_only_reports_what_it_can(sim_bag, tmp_path):
    bag = copy_bag(sim_bag, tmp_path / "masks_only", drop=THREE_D_TRUTH)
    summary = evaluate([bag], masks="predicted", sequences="predicted", seg_weights="m_ost")
    assert summary["frames"] == 3
    segmentation = summary["segmentation"]
    assert segmentation["iou"] > 0.4 and segmentation["centreline_recall"] > 0.5
    assert 0 < segmentation["cldice"] <= 1
    grasp = summary["grasp"]
    assert grasp["produced"] + sum(grasp["refused"].values()) == 3 and grasp["produced"] >= 1
    assert grasp["median_error_mm"] is None and summary["reconstruction"]["mean_error_mm"] is None
    consistency = summary["self_consistency"]
    assert consistency["frames"] == grasp["produced"] and consistency["reprojection_mean_px"] < 2.0
    assert summary["ordering"]["success_rate"] is None
    assert summary["unscored"]["ordering: the bag has no true sequence"] == 3
    assert any("no true 3D path" in note for note in summary["notes"])


def test_sequences_without_a_visibility_flag_are_scored_from_the_true_masks(sim_bag, tmp_path):
    flat = copy_bag(sim_bag, tmp_path / "flat", flatten_sequences=True)
    frames = list(read_frames(flat, images=False, complete=False))
    assert {frame.visibility for frame in frames} == {"mask"}
    # the true order scores a success, the reverse order does not
    board = Scoreboard()
    for frame in frames:
        truth = frame.true_left_sequence[:, :2]
        board.add(frame, StageOutputs(sequences=(truth, frame.true_right_sequence[:, :2])))
        board.add(frame, StageOutputs(sequences=(truth[::-1], frame.true_right_sequence[::-1, :2])))
    assert [r["ordering_success"] for r in board.tally.per_frame] == [True, False] * 3
    assert [r["ordering_right_success"] for r in board.tally.per_frame] == [True, False] * 3
    # the ordering stage scores on the flattened bag as on the simulator's own flags
    flagged = evaluate([sim_bag], masks="ground_truth", sequences="predicted", use_images=False)
    scored = evaluate([flat], masks="ground_truth", sequences="predicted", use_images=False)
    assert scored["ordering"]["success_rate"] == flagged["ordering"]["success_rate"] > 0
    assert any("visibility from the true masks" in note for note in scored["notes"])


def test_each_view_is_scored_against_its_own_truth(sim_bag):
    frames = list(read_frames(sim_bag, images=False, complete=False))
    board = Scoreboard()
    for frame in frames:
        left, right = frame.true_left_sequence[:, :2], frame.true_right_sequence[:, :2]
        board.add(frame, StageOutputs(sequences=(left, right[::-1])))  # right view reversed
        board.add(frame, StageOutputs(sequences=(left, left)))  # the left sequence sent as the right
        board.add(frame, StageOutputs(sequences=None))  # the ordering gave none
    records = board.tally.per_frame
    assert [r["ordering_success"] for r in records] == [True, True, False] * 3
    assert [r["ordering_right_success"] for r in records] == [False] * 9
    assert "from the true cut tip" in records[0]["ordering_right"]
    assert records[2]["ordering_right"] == "no sequence"
    ordering = board.summary("ground_truth", "predicted")["ordering"]
    assert ordering["success_rate"] == pytest.approx(2 / 3)
    assert ordering["right_view"]["success_rate"] == 0.0
    assert set(ordering["right_view"]["by_topology"]) == set(ordering["by_topology"])


def test_a_mask_cache_gives_the_same_figures_and_refuses_other_masks(sim_bag, tmp_path):
    cache = tmp_path / "masks.npz"
    fresh = evaluate([sim_bag], seg_weights="m_ost_int8", use_images=False, mask_cache=cache)
    assert cache.exists() and fresh["latency_ms"]["segmentation"] is not None
    again = evaluate([sim_bag], seg_weights="m_ost_int8", use_images=False, mask_cache=cache)
    assert again["segmentation"] == fresh["segmentation"]
    assert again["grasp"] == fresh["grasp"] and again["ordering"] == fresh["ordering"]
    assert again["latency_ms"]["segmentation"] is None
    assert any("mask cache" in note for note in again["notes"])
    with pytest.raises(EvaluationError, match="was made with"):
        evaluate([sim_bag], seg_weights="m_ost_int8", flip_average=False, mask_cache=cache)
    with pytest.raises(EvaluationError, match="was made with"):
        evaluate([sim_bag], seg_weights="m_ost", mask_cache=cache)
    with pytest.raises(EvaluationError, match="has no masks of frame"):
        evaluate([SAMPLE], seg_weights="m_ost_int8", mask_cache=cache)
    cache.write_bytes(b"not a cache")
    with pytest.raises(EvaluationError, match="cannot be read"):
        evaluate([sim_bag], seg_weights="m_ost_int8", mask_cache=cache)


def test_the_report_of_a_cut_sample_bag_covers_the_frames_before_the_cut(tmp_path):
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / "metadata.yaml").write_text((SAMPLE / "metadata.yaml").read_text())
    data = (SAMPLE / "sample.mcap").read_bytes()
    (cut / "sample.mcap").write_bytes(data[: len(data) // 2])
    report = tmp_path / "report"
    summary = evaluate([cut], masks="ground_truth", sequences="predicted", report=report)
    frames = summary["frames"]
    assert 0 < frames < 10
    (damaged,) = summary["damaged"]
    assert damaged["lost"] == 10 - frames and "cut short" in damaged["error"]
    assert any(f"{10 - frames} lost" in note for note in summary["notes"])
    records = json.loads((report / "frames.json").read_text())
    assert len(records) == frames == len(list((report / "frames").glob("*.json")))
    assert all("grasp_produced" in record for record in records)
    assert len(list((report / "overlays").glob("*.png"))) == frames
    assert (report / "centreline_3d.png").stat().st_size > 10_000
    written = json.loads((report / "summary.json").read_text())
    assert written["frames"] == frames and "per_frame" not in written


def test_a_bag_without_camera_info_says_why_it_has_no_frames(sim_bag, tmp_path):
    bag = copy_bag(sim_bag, tmp_path / "no_info", drop={topics.LEFT_CAMERA_INFO, topics.RIGHT_CAMERA_INFO})
    summary = evaluate([bag], masks="ground_truth", sequences="predicted")
    assert summary["frames"] == 0
    assert sum(summary["skipped"].values()) == 3
    assert any("no stereo frame" in note and "camera_info" in note for note in summary["notes"])


def test_a_bag_without_any_ground_truth_still_reports_grasps_and_consistency(sim_bag, tmp_path):
    bag = copy_bag(sim_bag, tmp_path / "bare", drop={*topics.GROUND_TRUTH_TOPICS, topics.TIP_HINT})
    summary = evaluate([bag], masks="predicted", sequences="predicted", seg_weights="m_ost")
    assert summary["frames"] == 3
    assert summary["segmentation"]["iou"] is None and summary["segmentation"]["cldice"] is None
    assert summary["unscored"]["segmentation: the bag has no true masks"] == 3
    grasp = summary["grasp"]
    assert grasp["produced"] + sum(grasp["refused"].values()) == 3
    assert summary["self_consistency"]["frames"] == grasp["produced"]
    assert summary["latency_ms"]["segmentation"] > 0


def test_grasps_more_than_10_mm_off_are_counted(tmp_path):
    """The sample bag with one true grasp point moved 20 mm: that grasp is counted as a wrong one."""
    moved = tmp_path / "moved"
    first = None
    with BagWriter(moved) as writer:
        for topic, msgtype, stamp, data in read_raw(SAMPLE):
            if topic == topics.GT_GRASP_POSE and first is None:
                first = stamp
                message = messages.TYPESTORE.deserialize_cdr(data, msgtype)
                position, quaternion = messages.pose_to_arrays(message)
                shifted = messages.pose_message(
                    position + np.array([0.02, 0.0, 0.0]), quaternion, stamp, message.header.frame_id
                )
                writer.write(topic, shifted, stamp)
                continue
            writer.write_raw(topic, msgtype, data, stamp)
    summary = evaluate([moved], masks="ground_truth", sequences="ground_truth")
    assert summary["grasp"]["beyond_10mm"] == 1
    assert summary["grasp"]["max_error_mm"] > 10.0
    assert evaluate([SAMPLE], masks="ground_truth", sequences="ground_truth")["grasp"]["beyond_10mm"] == 0


def test_an_empty_mask_leaves_self_consistency_finite_and_says_so():
    """A frame whose mask is empty cannot be measured: counted, not an infinite run-wide mean."""
    frame = next(iter(read_frames(SAMPLE, images=False, complete=False)))
    board = Scoreboard(ordering_ran=False)
    empty = np.zeros_like(frame.true_left_mask)
    outputs = StageOutputs(masks=(empty, empty), path=frame.true_path, grasp=frame.true_grasp)
    board.add(frame, outputs)
    summary = board.summary("predicted", "ground_truth")
    assert summary["self_consistency"]["frames"] == 0
    assert summary["self_consistency"]["reprojection_mean_px"] is None
    assert summary["unscored"] == {"self-consistency: an empty mask or a path outside a view": 1}
    json.dumps(summary, allow_nan=False)


def test_a_hidden_true_grasp_point_is_a_success_when_refused_as_not_seen_and_a_miss_when_grasped():
    """The contract's rule for a true grasp point hidden in a view, both ways, and the counts."""
    from suture_bench.evaluate import NOT_SEEN_REFUSAL, true_grasp_hidden

    frame = next(iter(read_frames(SAMPLE, images=False, complete=False)))
    assert true_grasp_hidden(frame) is False
    samples = frame.camera.triangulate(frame.true_left_sequence[:, :2], frame.true_right_sequence[:, 0])
    row = int(np.argmin(np.linalg.norm(samples - frame.true_grasp, axis=1)))
    frame.true_right_sequence = frame.true_right_sequence.copy()
    frame.true_right_sequence[row - 20 : row + 20, 2] = 0.0  # under an instrument in the right view
    assert true_grasp_hidden(frame) is True

    refused = Scoreboard(ordering_ran=False)
    refused.add(frame, StageOutputs(failure=NOT_SEEN_REFUSAL))
    summary = refused.summary("ground_truth", "ground_truth")
    assert summary["grasp"]["within_5mm"] == 1.0
    assert summary["grasp"]["hidden"] == {
        "hidden": 1,
        "refused_not_seen": 1,
        "grasped": 0,
        "refused_otherwise": 0,
    }

    grasped = Scoreboard(ordering_ran=False)  # exactly on the true point, but it cannot be seen
    grasped.add(frame, StageOutputs(path=frame.true_path, grasp=frame.true_grasp))
    summary = grasped.summary("ground_truth", "ground_truth")
    assert summary["grasp"]["within_5mm"] == 0.0
    assert summary["grasp"]["hidden"]["grasped"] == 1

    other = Scoreboard(ordering_ran=False)  # refused, but not for that reason: a miss
    other.add(frame, StageOutputs(failure="reconstruction: UncertainGraspError"))
    summary = other.summary("ground_truth", "ground_truth")
    assert summary["grasp"]["within_5mm"] == 0.0
    assert summary["grasp"]["hidden"]["refused_otherwise"] == 1
