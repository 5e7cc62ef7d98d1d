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


def hairpin(radius: float, tip_arm: float, step: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """A cut end bent into a hairpin of ``radius`` (arms 2 * radius apart) after a ``tip_arm``
    (m), then 45 mm back past the tip, at 0.11 m depth: (N, 3) points every 10 um and their arc."""
    arm = np.column_stack([np.arange(0.0, tip_arm, step), np.zeros(round(tip_arm / step))])
    angle = np.arange(0.0, np.pi, step / radius)
    bend = np.column_stack([tip_arm + radius * np.sin(angle), radius - radius * np.cos(angle)])
    back_x = np.arange(tip_arm, -0.045, -step)
    back = np.column_stack([back_x, np.full(len(back_x), 2 * radius)])
    planar = np.vstack([arm, bend, back])
    thread = np.column_stack([planar, np.full(len(planar), 0.11)])
    return thread, np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(thread, axis=0), axis=1))])


@pytest.mark.parametrize(("radius", "tip_arm"), [(0.0001, 0.002), (0.0002, 0.002), (0.0004, 0.005)])
def test_a_hairpin_tighter_than_the_smoothing_keeps_its_arc_length(radius, tip_arm):
    # The 1 mm smoothing cuts the bend (1.0-1.4 mm of arc at radii 0.1-0.2 mm after a 2 mm
    # arm); the points beyond it must not move along the thread.
    thread, arc = hairpin(radius, tip_arm)
    curve = fit_curve(thread[::10], smoothing=0.001)
    assert curve.length == pytest.approx(arc[-1], abs=3e-4)
    for at in (0.02, 0.04):
        true = thread[np.searchsorted(arc, at)]
        assert np.linalg.norm(curve.at(at) - true) < 3e-4
        assert np.linalg.norm(grasp_pose(curve, at).position - true) < 3e-4


def test_a_ripple_in_depth_does_not_lengthen_the_thread():
    # Disparity noise is a ripple along the viewing rays (here 0.2 mm over 2 mm of thread):
    # the arc is measured with the depth smoothed as the curve, not as the tight bends.
    x = np.arange(0.0, 0.08, 1e-4)
    rippled = np.column_stack([x, np.zeros_like(x), 0.11 + 2e-4 * np.sin(2 * np.pi * x / 0.002)])
    curve = fit_curve(rippled, smoothing=0.001)
    assert curve.length == pytest.approx(0.08, rel=2e-3)
    fully_smoothed = fit_curve(rippled, smoothing=0.001, arc_smoothing=0.001)
    assert fully_smoothed.length == pytest.approx(curve.length, rel=1e-3)
