# SPDX-License-Identifier: Apache-2.0
"""The arc-length curve, its length, and the grasp pose on it."""

from __future__ import annotations

import numpy as np
import pytest

from suture_common.grasp import grasp_rotation, rotation_to_quaternion
from suture_reconstruction.curve import fit_curve, grasp_pose
from suture_reconstruction.errors import ReconstructionError, ThreadTooShortError


def test_length_and_arc_length_parametrisation_of_an_arc():
    radius = 0.02
    angle = np.linspace(0, np.pi, 600)
    arc = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.full_like(angle, 0.1)])
    curve = fit_curve(arc, smoothing=0.001)
    assert curve.length == pytest.approx(np.pi * radius, rel=2e-3)
    path = curve.resample(0.0005)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.allclose(steps[:-1], 0.0005, rtol=1e-2)
    assert np.abs(np.linalg.norm(path[:, :2], axis=1) - radius).max() < 1e-4
    np.testing.assert_allclose(curve.at(0.0), arc[0], atol=5e-5)


def test_grasp_pose_on_a_straight_thread():
    line = np.column_stack([np.linspace(0, 0.08, 200), np.zeros(200), np.full(200, 0.1)])
    pose = grasp_pose(fit_curve(line, 0.001), 0.05)
    np.testing.assert_allclose(pose.position, [0.05, 0.0, 0.1], atol=1e-6)
    expected = rotation_to_quaternion(grasp_rotation(pose.position, [1.0, 0.0, 0.0]))
    np.testing.assert_allclose(pose.quaternion, expected, atol=1e-6)


def test_thread_shorter_than_the_reserve_and_degenerate_frame():
    line = np.column_stack([np.linspace(0, 0.03, 50), np.zeros(50), np.full(50, 0.1)])
    with pytest.raises(ThreadTooShortError, match=r"30\.0 mm long, shorter than the reserved 50\.0 mm"):
        grasp_pose(fit_curve(line, 0.001), 0.05)
    along_ray = np.column_stack([np.zeros(50), np.zeros(50), np.linspace(0.06, 0.12, 50)])
    with pytest.raises(ReconstructionError, match="viewing ray"):
        grasp_pose(fit_curve(along_ray, 0.001), 0.05)


def test_a_hairpin_tighter_than_the_smoothing_keeps_its_arc_length():
    # A cut end bent into a hairpin of radius 0.4 mm (arms 0.8 mm apart) after a 5 mm tip arm:
    # the 1 mm smoothing cuts the bend, and the points beyond it must not move along the thread.
    radius, step = 0.0004, 1e-5
    arm = np.column_stack([np.arange(0.0, 0.005, step), np.zeros(500)])
    angle = np.arange(0.0, np.pi, step / radius)
    bend = np.column_stack([0.005 + radius * np.sin(angle), radius - radius * np.cos(angle)])
    back = np.column_stack([np.arange(0.005, -0.045, -step), np.full(5000, 2 * radius)])
    planar = np.vstack([arm, bend, back])
    thread = np.column_stack([planar, np.full(len(planar), 0.1)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(thread, axis=0), axis=1))])
    curve = fit_curve(thread[::10], smoothing=0.001)
    assert curve.length == pytest.approx(arc[-1], abs=3e-4)
    for at in (0.02, 0.04):
        true = thread[np.searchsorted(arc, at)]
        assert np.linalg.norm(curve.at(at) - true) < 3e-4
        assert np.linalg.norm(grasp_pose(curve, at).position - true) < 3e-4
