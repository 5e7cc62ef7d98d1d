# SPDX-License-Identifier: Apache-2.0
"""Hand-eye transform T_base_camera: the documented worked example, YAML forms and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from grasp_executor.geometry import Pose
from grasp_executor.handeye import FrameMismatchError, HandEye, HandEyeError, load_hand_eye
from suture_common.grasp import grasp_rotation, rotation_to_quaternion

CONFIG = Path(__file__).resolve().parents[1] / "config"

# docs/executor.md, "Hand-eye transform": a camera 0.5 m above the table at x = 0.4 m,
# looking straight down, image "up" pointing away from the robot (+x of the base).
EXAMPLE_TRANSLATION = [0.4, 0.0, 0.5]
EXAMPLE_QUATERNION = [math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0]


def example() -> HandEye:
    return HandEye(EXAMPLE_TRANSLATION, EXAMPLE_QUATERNION, "left_camera_optical_frame", "base")


def test_worked_example_from_the_docs():
    hand_eye = example()
    # the columns of R are the camera axes in the base frame: x right = -y_base,
    # y down (in the image) = -x_base, z forward (optical axis) = -z_base
    np.testing.assert_allclose(hand_eye.rotation, [[0, -1, 0], [-1, 0, 0], [0, 0, -1]], atol=1e-12)
    p_camera = np.array([0.02, -0.01, 0.45])
    np.testing.assert_allclose(hand_eye.transform_points(p_camera), [0.41, -0.02, 0.05], atol=1e-12)
    np.testing.assert_allclose(hand_eye.matrix @ [*p_camera, 1.0], [0.41, -0.02, 0.05, 1.0], atol=1e-12)
    # the grasp frame's approach axis (the viewing ray) points down in the base frame
    grasp = Pose(
        p_camera, rotation_to_quaternion(grasp_rotation(p_camera, [1.0, 0.0, 0.0])), hand_eye.camera_frame
    )
    base = hand_eye.transform_pose(grasp)
    assert base.frame_id == "base"
    np.testing.assert_allclose(base.position, [0.41, -0.02, 0.05], atol=1e-12)
    np.testing.assert_allclose(base.axis(2), hand_eye.rotation @ grasp.axis(2), atol=1e-12)
    assert base.axis(2)[2] < -0.99
    np.testing.assert_allclose(base.axis(0), [0.0, -1.0, 0.0], atol=1e-12)  # camera x (right) = -y_base


def test_example_yaml_file_is_the_worked_example():
    hand_eye = load_hand_eye(CONFIG / "hand_eye_example.yaml")
    np.testing.assert_allclose(hand_eye.matrix, example().matrix, atol=1e-9)
    assert hand_eye.camera_frame == "left_camera_optical_frame"
    assert hand_eye.base_frame == "base"


def test_matrix_form_and_nesting(tmp_path):
    matrix = example().matrix
    path = tmp_path / "matrix.yaml"
    rows = ", ".join("[" + ", ".join(f"{v:.17g}" for v in row) + "]" for row in matrix)
    path.write_text(f"hand_eye:\n  base_frame: PSM1_base\n  matrix: [{rows}]\n")
    hand_eye = load_hand_eye(path, camera_frame="cam")
    np.testing.assert_allclose(hand_eye.matrix, matrix, atol=1e-12)
    assert (hand_eye.camera_frame, hand_eye.base_frame) == ("cam", "PSM1_base")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("translation: [0, 0, 0]\n", "missing quaternion"),
        ("translation: [0, 0]\nquaternion: [0, 0, 0, 1]\n", "translation needs 3 values"),
        ("translation: [0, 0, 0]\nquaternion: [0, 0, 0, 2]\n", "norm 2"),
        ("translation: [0, .nan, 0]\nquaternion: [0, 0, 0, 1]\n", "NaN"),
        ("translation: [a, b, c]\nquaternion: [0, 0, 0, 1]\n", "must be numbers"),
        ("matrix: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n", "proper rotation"),
        ("matrix: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]\n", "last row"),
        ("- 1\n- 2\n", "must hold a mapping"),
        ("translation: [0, 0, 0\n", "not valid YAML"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, match):
    path = tmp_path / "hand_eye.yaml"
    path.write_text(text)
    with pytest.raises(HandEyeError, match=match) as info:
        load_hand_eye(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(HandEyeError, match="cannot read hand-eye file"):
        load_hand_eye(tmp_path / "nope.yaml")


def test_pose_in_another_frame_is_rejected():
    with pytest.raises(FrameMismatchError, match="'right_camera_optical_frame'.*publish it in"):
        example().transform_pose(Pose([0, 0, 1], [0, 0, 0, 1], "right_camera_optical_frame"))


def test_parameters_are_validated():
    with pytest.raises(HandEyeError, match="unit quaternion"):
        HandEye([0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(HandEyeError, match="non-empty"):
        HandEye([0, 0, 0], [0, 0, 0, 1], "", "base")
    # a quaternion off by rounding is renormalised
    assert np.linalg.norm(HandEye([0, 0, 0], [0, 0, 0, 1.0005]).quaternion) == pytest.approx(1.0)
