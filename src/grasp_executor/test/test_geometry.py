# SPDX-License-Identifier: Apache-2.0
"""Quaternion <-> rotation vector (the UR wire format), quaternion product and slerp, against scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from grasp_executor.backends.ur import pose_to_ur, ur_to_pose
from grasp_executor.geometry import (
    Pose,
    quaternion_multiply,
    quaternion_to_rotvec,
    rotation_angle,
    rotvec_to_quaternion,
    slerp,
)

unit = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1)


def test_known_rotation_vectors():
    # 90 degrees about z
    q = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    np.testing.assert_allclose(quaternion_to_rotvec(q), [0.0, 0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(rotvec_to_quaternion([0.0, 0.0, math.pi / 2]), q, atol=1e-12)
    # identity, both ways
    np.testing.assert_allclose(quaternion_to_rotvec([0.0, 0.0, 0.0, 1.0]), np.zeros(3), atol=0)
    np.testing.assert_allclose(rotvec_to_quaternion(np.zeros(3)), [0.0, 0.0, 0.0, 1.0], atol=0)
    # 180 degrees about x: the tool pointing down, as a UR TCP above a table
    np.testing.assert_allclose(quaternion_to_rotvec([1.0, 0.0, 0.0, 0.0]), [math.pi, 0.0, 0.0], atol=1e-12)


def test_q_and_minus_q_give_the_same_rotation_vector():
    q = np.array([0.1, -0.7, 0.3, -0.6])
    np.testing.assert_allclose(quaternion_to_rotvec(q), quaternion_to_rotvec(-q), atol=1e-12)
    assert np.linalg.norm(quaternion_to_rotvec(q)) <= math.pi + 1e-12


def test_small_angles_are_accurate():
    for angle in (1e-3, 1e-7, 1e-10, 0.0):
        rotvec = np.array([angle, -2 * angle, 0.5 * angle])
        expected = Rotation.from_rotvec(rotvec).as_quat()
        np.testing.assert_allclose(rotvec_to_quaternion(rotvec), expected, atol=1e-15)
        np.testing.assert_allclose(quaternion_to_rotvec(expected), rotvec, atol=1e-15, rtol=1e-9)


def test_batches_match_single_values():
    rng = np.random.default_rng(5)
    qs = rng.normal(size=(50, 4))
    batch = quaternion_to_rotvec(qs)
    assert batch.shape == (50, 3)
    np.testing.assert_allclose(batch[17], quaternion_to_rotvec(qs[17]), atol=1e-15)
    np.testing.assert_allclose(rotvec_to_quaternion(batch)[3], rotvec_to_quaternion(batch[3]), atol=1e-15)


def test_invalid_values_raise():
    with pytest.raises(ValueError, match="zero, NaN"):
        quaternion_to_rotvec([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="zero, NaN"):
        quaternion_to_rotvec([np.nan, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="NaN"):
        rotvec_to_quaternion([np.inf, 0.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        quaternion_to_rotvec([0.0, 0.0, 1.0])


@settings(max_examples=200, deadline=None)
@given(quaternions)
def test_rotation_vector_matches_scipy_and_round_trips(q):
    q = np.asarray(q)
    rotvec = quaternion_to_rotvec(q)
    expected = Rotation.from_quat(q).as_rotvec()
    # equal, or (at exactly pi) the same rotation with the opposite axis
    same = Rotation.from_rotvec(rotvec) * Rotation.from_rotvec(expected).inv()
    assert same.magnitude() < 1e-9
    back = rotvec_to_quaternion(rotvec)
    assert rotation_angle(back, q / np.linalg.norm(q)) < 1e-7
    assert back[3] >= 0


@settings(max_examples=200, deadline=None)
@given(quaternions, quaternions)
def test_quaternion_multiply_matches_scipy(a, b):
    a = np.asarray(a) / np.linalg.norm(a)
    b = np.asarray(b) / np.linalg.norm(b)
    expected = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()
    assert rotation_angle(quaternion_multiply(a, b), expected) < 1e-7


def test_slerp_ends_and_midpoint():
    a = np.array([0.0, 0.0, 0.0, 1.0])
    b = rotvec_to_quaternion([0.0, 0.0, 1.2])
    np.testing.assert_allclose(slerp(a, b, 0.0), a, atol=1e-12)
    assert rotation_angle(slerp(a, b, 1.0), b) < 1e-9
    np.testing.assert_allclose(quaternion_to_rotvec(slerp(a, b, 0.5)), [0.0, 0.0, 0.6], atol=1e-12)
    # the shorter way round when the quaternions have opposite signs
    np.testing.assert_allclose(quaternion_to_rotvec(slerp(a, -b, 0.25)), [0.0, 0.0, 0.3], atol=1e-12)


def test_ur_pose_round_trip():
    pose = Pose([0.4, -0.1, 0.2], rotvec_to_quaternion([2.0, -1.0, 0.5]), "base")
    values = pose_to_ur(pose)
    assert len(values) == 6
    np.testing.assert_allclose(values[3:], [2.0, -1.0, 0.5], atol=1e-12)
    back = ur_to_pose(values, "base")
    np.testing.assert_allclose(back.position, pose.position)
    assert rotation_angle(back.quaternion, pose.quaternion) < 1e-12
    with pytest.raises(ValueError, match="6 values"):
        ur_to_pose([0.0] * 5, "base")


def test_pose_is_an_immutable_value():
    pose = Pose([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0], "base")
    with pytest.raises(ValueError):
        pose.position[0] = 5.0
    assert pose == Pose(np.array([1.0, 2.0, 3.0]), (0, 0, 0, 1), "base")
    assert pose != Pose([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0], "other")
    assert not Pose([np.nan, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).is_finite()
    np.testing.assert_allclose(pose.translated([0.0, 0.0, -1.0]).position, [1.0, 2.0, 2.0])
    with pytest.raises(ValueError, match="3 position and 4 quaternion"):
        Pose([1.0, 2.0], [0.0, 0.0, 0.0, 1.0])
