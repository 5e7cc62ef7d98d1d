# SPDX-License-Identifier: Apache-2.0
"""Plane geometry of the ordering search: angles between directions, rotations, the bend of a
connection and the cubic Hermite curve of a smooth step.

Directions are (2,) or (k, 2) float arrays (u, v) in pixels; angles are radians. The (2,)
functions compute on Python floats (the same IEEE double arithmetic as numpy's, without the
cost of numpy scalars): the search calls them at every step.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

#: cv2 drawing with 1/16 px precision (``shift`` of cv2.line / cv2.polylines).
LINE_SHIFT = 4


def signed_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) that turns direction ``a`` into ``b``, in (-pi, pi]."""
    ax, ay = float(a[0]), float(a[1])
    bx, by = float(b[0]), float(b[1])
    return math.atan2(ax * by - ay * bx, ax * bx + ay * by)


def rotate(v: np.ndarray, angle: float) -> np.ndarray:
    """(2,) ``v`` turned by ``angle`` (rad)."""
    c, s = math.cos(angle), math.sin(angle)
    x, y = float(v[0]), float(v[1])
    return np.array([c * x - s * y, s * x + c * y])


def turn_angles(direction: np.ndarray, heading: np.ndarray | None) -> np.ndarray:
    """δ (rad) between each row of ``direction`` (k, 2) and ``heading`` (2,); 0 without heading."""
    if heading is None:
        return np.zeros(len(direction))
    norm = np.sqrt((direction * direction).sum(axis=1) * float(heading @ heading))
    cos = direction.dot(heading) / np.maximum(norm, 1e-12)
    return np.arccos(np.minimum(np.maximum(cos, -1.0), 1.0))


def bend(start: np.ndarray, t_start: np.ndarray, end: np.ndarray, t_end: np.ndarray) -> float:
    """|α1 - α2| of the chord start -> end: α1 from ``t_start`` to the chord, α2 from the chord
    to ``t_end`` (0 for any circular arc; large for a corner)."""
    chord = end - start
    return abs(signed_angle(t_start, chord) - signed_angle(chord, t_end))


def hermite(start: np.ndarray, end: np.ndarray, tangent0: np.ndarray, tangent1: np.ndarray) -> np.ndarray:
    """Points (excluding ``start``) ~1 px apart on the cubic Hermite curve start -> end."""
    n = max(2, math.ceil(1.2 * float(np.hypot(*(end - start)))))
    t = (np.arange(1, n + 1) / n)[:, None]
    t2, t3 = t * t, t * t * t
    return (
        (2 * t3 - 3 * t2 + 1) * start
        + (t3 - 2 * t2 + t) * tangent0
        + (-2 * t3 + 3 * t2) * end
        + (t3 - t2) * tangent1
    )


def fixed_point(point: np.ndarray | tuple[float, float]) -> tuple[int, int]:
    """(2,) ``point`` (an array or two floats) in cv2's fixed-point coordinates (:data:`LINE_SHIFT`
    fractional bits)."""
    scale = 1 << LINE_SHIFT  # a power of two: the products are exact; round() is round-half-even
    return round(float(point[0]) * scale), round(float(point[1]) * scale)


def revisited(points: np.ndarray, radius: float, min_arc: float) -> np.ndarray:
    """(N,) bool: which of the ordered ``points`` ((N, 2) px) lie nearer than ``radius`` px to
    another of them more than ``min_arc`` px of arc away along them (the sequence comes back
    there, or is come back to)."""
    points = np.asarray(points, dtype=np.float64)
    found = np.zeros(len(points), dtype=bool)
    if len(points) < 2:
        return found
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    # Only the pairs of points close together (a k-d tree's, with a little slack) are measured.
    i, j = cKDTree(points).query_pairs(radius * (1 + 1e-6) + 1e-6, output_type="ndarray").T
    near = (np.abs(along[i] - along[j]) > min_arc) & (np.hypot(*(points[i] - points[j]).T) < radius)
    found[i[near]] = True
    found[j[near]] = True
    return found
