# SPDX-License-Identifier: Apache-2.0
"""The grasp frame convention, shared by the simulator's ground truth and the reconstruction stage.

A grasp pose at a point on the thread has:

* x axis: the unit tangent of the thread, pointing away from the cut tip;
* z axis: the approach direction, the viewing ray from the left optical centre
  through the point (away from the camera, towards the tissue), with its
  component along the tangent removed;
* y axis: z cross x, completing a right-handed frame.

All in the left camera optical frame, metres.
"""

from __future__ import annotations

import numpy as np


class DegenerateGraspFrameError(ValueError):
    """The tangent is zero or parallel to the viewing ray, so no approach axis exists."""


def grasp_rotation(point: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix whose columns are the grasp x, y, z axes (see module docstring).

    ``point`` and ``tangent`` are (3,) arrays in the left optical frame.
    """
    point = np.asarray(point, dtype=np.float64)
    tangent = np.asarray(tangent, dtype=np.float64)
    tangent_norm = np.linalg.norm(tangent)
    ray_norm = np.linalg.norm(point)
    if not (np.isfinite(tangent_norm) and tangent_norm > 0 and ray_norm > 0):
        raise DegenerateGraspFrameError(
            "grasp frame needs a non-zero tangent and a point off the camera centre"
        )
    x_axis = tangent / tangent_norm
    ray = point / ray_norm
    approach = ray - np.dot(ray, x_axis) * x_axis
    approach_norm = np.linalg.norm(approach)
    if approach_norm < 1e-6:
        raise DegenerateGraspFrameError("the thread points straight along the viewing ray at the grasp point")
    z_axis = approach / approach_norm
    y_axis = np.cross(z_axis, x_axis)
    return np.column_stack([x_axis, y_axis, z_axis])


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w), w >= 0, of a 3x3 rotation matrix (ROS order)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def quaternion_to_rotation(quaternion: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of a quaternion (x, y, z, w); it need not be normalised."""
    x, y, z, w = np.asarray(quaternion, dtype=np.float64) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def point_at_arc_length(
    polyline: np.ndarray, arc_length: float, arc: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Point (3,) and unit tangent (3,) at ``arc_length`` metres along an (N, 3) polyline.

    ``arc`` (N,), increasing from 0: the vertices' arc lengths when they are not the polyline's
    own (a curve whose arc keeps what its sampling cut off); the point is interpolated on it.
    Raises ValueError when the polyline is shorter than ``arc_length``.
    """
    polyline = np.asarray(polyline, dtype=np.float64)
    steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    own = arc is None
    cumulative = np.concatenate([[0.0], np.cumsum(steps)]) if own else np.asarray(arc, dtype=np.float64)
    if arc_length < 0 or arc_length > cumulative[-1]:
        raise ValueError(
            f"thread is {cumulative[-1] * 1000:.1f} mm long, shorter than the reserved "
            f"{arc_length * 1000:.1f} mm"
        )
    index = int(np.clip(np.searchsorted(cumulative, arc_length, side="right") - 1, 0, len(steps) - 1))
    while steps[index] == 0 and index > 0:
        index -= 1
    span = steps[index] if own else cumulative[index + 1] - cumulative[index]
    fraction = (arc_length - cumulative[index]) / span if span > 0 else 1.0
    point = polyline[index] + fraction * (polyline[index + 1] - polyline[index])
    tangent = (polyline[index + 1] - polyline[index]) / steps[index]
    return point, tangent
