# SPDX-License-Identifier: Apache-2.0
"""Grasp plans and key-point plans: geometry of pre-grasp, lift, tool rotation and point spacing."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from grasp_executor.geometry import Pose, quaternion_multiply, rotation_angle, rotvec_to_quaternion
from grasp_executor.keypoints import (
    KeypointConfig,
    KeypointRecord,
    append_keypoint_csv,
    evenly_spaced_points,
    plan_keypoints,
)
from grasp_executor.planning import Dwell, GraspConfig, Jaw, Move, plan_grasp

# a grasp pose in the base frame whose approach axis (z) points along -z of the base
DOWN = rotvec_to_quaternion([math.pi, 0.0, 0.0])
GRASP = Pose([0.41, -0.02, 0.05], quaternion_multiply(DOWN, rotvec_to_quaternion([0.0, 0.0, 0.3])), "base")


def test_grasp_plan_steps_and_geometry():
    config = GraspConfig(approach_offset=0.012, lift_distance=0.02, jaw_open=0.7, jaw_close=-0.05)
    plan = plan_grasp(GRASP, config, has_jaw=True)
    assert [type(step) for step in plan.steps] == [Jaw, Move, Move, Jaw, Move]
    assert [step.name for step in plan.steps] == ["open_jaw", "pre_grasp", "grasp", "close_jaw", "lift"]
    assert plan.jaws() == [("open_jaw", 0.7), ("close_jaw", -0.05)]
    moves = dict(plan.moves())
    approach = GRASP.axis(2)
    np.testing.assert_allclose(approach, [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(moves["grasp"].position, GRASP.position)
    np.testing.assert_allclose(
        moves["pre_grasp"].position, GRASP.position + np.array([0.0, 0.0, 0.012]), atol=1e-12
    )
    np.testing.assert_allclose(
        moves["lift"].position, GRASP.position + np.array([0.0, 0.0, 0.02]), atol=1e-12
    )
    for pose in moves.values():
        assert pose.frame_id == "base"
        assert rotation_angle(pose.quaternion, GRASP.quaternion) < 1e-12
    assert plan.target == moves["grasp"]
    assert plan.first_pose() == moves["pre_grasp"]
    assert [step.name for step in plan.steps if isinstance(step, Move) and step.is_target] == ["grasp"]


def test_grasp_plan_without_jaw_skips_jaw_steps():
    plan = plan_grasp(GRASP, GraspConfig(), has_jaw=False)
    assert [step.name for step in plan.steps] == ["pre_grasp", "grasp", "lift"]


def test_tool_rotation_changes_orientation_not_the_approach():
    quarter_turn = tuple(rotvec_to_quaternion([0.0, 0.0, math.pi / 2]))
    plan = plan_grasp(GRASP, GraspConfig(approach_offset=0.01, tool_rotation=quarter_turn))
    grasp = dict(plan.moves())["grasp"]
    # the tool's x axis is the grasp frame's y axis; z (approach) is unchanged
    np.testing.assert_allclose(grasp.axis(0), GRASP.axis(1), atol=1e-12)
    np.testing.assert_allclose(grasp.axis(2), GRASP.axis(2), atol=1e-12)
    np.testing.assert_allclose(
        dict(plan.moves())["pre_grasp"].position, GRASP.position + np.array([0.0, 0.0, 0.01]), atol=1e-12
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"approach_offset": -0.01}, "approach_offset"),
        ({"lift_distance": math.nan}, "lift_distance"),
        ({"jaw_close": math.inf}, "jaw_close"),
        ({"tool_rotation": (0.0, 0.0, 0.0, 0.0)}, "unit quaternion"),
    ],
)
def test_grasp_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GraspConfig(**kwargs)


def test_evenly_spaced_points_by_arc_length():
    # an L-shaped path: 30 mm along x, then 30 mm along y, with a repeated vertex
    path = np.array([[0.0, 0.0, 0.1], [0.03, 0.0, 0.1], [0.03, 0.0, 0.1], [0.03, 0.03, 0.1]])
    points = evenly_spaced_points(path, 4)
    np.testing.assert_allclose(
        points, [[0.0, 0.0, 0.1], [0.02, 0.0, 0.1], [0.03, 0.01, 0.1], [0.03, 0.03, 0.1]], atol=1e-12
    )
    np.testing.assert_allclose(evenly_spaced_points(path, 1), [[0.0, 0.0, 0.1]])
    assert evenly_spaced_points(path, 10).shape == (10, 3)


@pytest.mark.parametrize(
    ("path", "count", "match"),
    [
        (np.zeros((1, 3)), 3, "at least 2 points"),
        (np.zeros((3, 3)), 3, "zero length"),
        (np.array([[0, 0, 0], [np.nan, 0, 0]]), 3, "NaN"),
        (np.array([[0, 0, 0], [1, 0, 0]]), 0, "at least 1"),
    ],
)
def test_evenly_spaced_points_errors(path, count, match):
    with pytest.raises(ValueError, match=match):
        evenly_spaced_points(path, count)


def test_keypoint_plan():
    points = np.array([[0.40, 0.0, 0.05], [0.42, 0.0, 0.05]])
    plan = plan_keypoints(points, DOWN, "base", approach_offset=0.01, dwell=0.5)
    assert [step.name for step in plan.steps] == [
        "key point 1/2 approach",
        "key point 1/2 touch",
        "key point 1/2 dwell",
        "key point 1/2 retreat",
        "key point 2/2 approach",
        "key point 2/2 touch",
        "key point 2/2 dwell",
        "key point 2/2 retreat",
    ]
    moves = plan.moves()
    np.testing.assert_allclose(
        moves[0][1].position, [0.40, 0.0, 0.06], atol=1e-12
    )  # above: approach along -z
    np.testing.assert_allclose(moves[1][1].position, points[0])
    np.testing.assert_allclose(moves[2][1].position, [0.40, 0.0, 0.06], atol=1e-12)
    dwells = [step for step in plan.steps if isinstance(step, Dwell)]
    assert [(d.seconds, d.keypoint) for d in dwells] == [(0.5, 0), (0.5, 1)]
    np.testing.assert_allclose(plan.keypoints, points)
    assert plan.first_pose() == moves[0][1]


def test_keypoint_config_validation():
    assert KeypointConfig(count=4.0).count == 4
    with pytest.raises(ValueError, match="positive integer"):
        KeypointConfig(count=2.5)
    with pytest.raises(ValueError, match="dwell"):
        KeypointConfig(dwell=-1.0)
    with pytest.raises(ValueError, match="unit quaternion"):
        KeypointConfig(orientation=(0.0, 0.0, 0.0, 0.0))


def test_keypoint_csv(tmp_path):
    measured = Pose([0.4005, 0.0, 0.05], DOWN, "base")
    records = [
        KeypointRecord(0, 2, np.array([0.40, 0.0, 0.05]), np.array([0.0, 0.01, 0.45]), measured),
        KeypointRecord(1, 2, np.array([0.42, 0.0, 0.05]), np.array([0.0, -0.01, 0.45]), None),
    ]
    assert records[0].deviation == pytest.approx(0.0005)
    assert "deviation 0.50 mm" in records[0].describe()
    assert "no measured pose" in records[1].describe()
    path = tmp_path / "keypoints.csv"
    for record in records:
        append_keypoint_csv(path, record)
    rows = list(csv.DictReader(path.open()))
    assert [row["index"] for row in rows] == ["1", "2"]
    assert float(rows[0]["measured_x"]) == pytest.approx(0.4005)
    assert float(rows[0]["deviation_mm"]) == pytest.approx(0.5)
    assert float(rows[1]["camera_y"]) == pytest.approx(-0.01)
    assert rows[1]["deviation_mm"] == "nan" and rows[1]["frame_id"] == ""
