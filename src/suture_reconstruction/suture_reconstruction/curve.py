# SPDX-License-Identifier: Apache-2.0
"""A smooth, arc-length parametrised 3D curve through the optimised vertices, and the grasp pose on it.

The vertices of the shortest path (:mod:`suture_reconstruction.shape_graph`)
are resampled by chord length, smoothed with a discrete cubic smoothing spline
(the Whittaker smoother of :mod:`suture_reconstruction.smoothing`, whose
penalty lam = (h / step)^4 makes it act like a kernel of half-width about h,
the smoothing length) and interpolated by a C2 cubic spline; that curve is
sampled densely, which gives the thread's length and points and tangents at any
arc length from the cut tip.

The smoother cuts a bend tighter than its smoothing length: a hairpin or hook at the
cut end (bend radius 0.3-2 mm, its arms side by side) loses arc under the 1 mm smoothing
length, and every point beyond it, the grasp point too, moves along the thread by as much.
The arc length is therefore measured along a second version of the curve whose image-plane
directions (x/z, y/z) are smoothed over a much shorter length, ``arc_smoothing`` (0.2 mm by
default, about what one pixel spans across the viewing ray at the working distance), and whose
depth keeps the 1 mm smoothing: the depth, from disparity, carries a ripple along the viewing
rays that would make the thread too long, while a hook's arms lie side by side in the image.
The 1 mm curve gives the thread's shape and tangents. ``ArcLengthCurve.arc`` is that arc
length along the thread, and the published path is spaced by the smoothed samples' own arc.

Units: metres at the interface; millimetres inside the fit (for conditioning).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from suture_common.grasp import (
    DegenerateGraspFrameError,
    grasp_rotation,
    point_at_arc_length,
    rotation_to_quaternion,
)
from suture_reconstruction.errors import ReconstructionError, ThreadTooShortError
from suture_reconstruction.smoothing import whittaker

_MM = 1000.0
_DENSE_STEP_MM = 0.05


@dataclass(frozen=True)
class ArcLengthCurve:
    """A 3D curve sampled densely by arc length from the cut tip.

    ``samples`` (S, 3) metres, ``arc`` (S,) metres from the first sample (0 to ``length``),
    increasing: each sample's arc length along the thread (module docstring).
    """

    samples: np.ndarray
    arc: np.ndarray

    @property
    def length(self) -> float:
        """Arc length of the curve (m)."""
        return float(self.arc[-1])

    def at(self, arc_length: np.ndarray | float) -> np.ndarray:
        """Points (..., 3) at ``arc_length`` metres from the tip (clamped to the curve)."""
        s = np.asarray(arc_length, dtype=np.float64)
        return np.stack([np.interp(s, self.arc, self.samples[:, k]) for k in range(3)], axis=-1)

    def resample(self, step: float) -> np.ndarray:
        """(P, 3) points every ``step`` metres along the samples from the tip (apart by
        ``step`` in space, also where ``arc`` kept a bend's arc); the last one is the curve's end."""
        own = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.samples, axis=0), axis=1))])
        s = np.arange(0.0, own[-1], step)
        if own[-1] - s[-1] > 1e-9:
            s = np.append(s, own[-1])
        return np.stack([np.interp(s, own, self.samples[:, k]) for k in range(3)], axis=-1)


def fit_curve(
    vertices: np.ndarray, smoothing: float, arc_smoothing: float = 2e-4, step: float = 2.5e-4
) -> ArcLengthCurve:
    """Smooth arc-length curve through (n, 3) ordered vertices (m); smoothing length ``smoothing`` (m).

    The vertices are resampled every ``step`` m of chord length, smoothed with the
    Whittaker smoother (lam = (smoothing / step)^4, a discrete cubic smoothing
    spline), interpolated by a C2 cubic spline (``scipy.interpolate.make_interp_spline``)
    and sampled every 0.05 mm. The samples' ``arc`` is measured along the same curve with its
    image-plane directions (x/z, y/z) smoothed only over ``arc_smoothing`` (m; at most
    ``smoothing``), which keeps the arc of bends tighter than ``smoothing``; the depth z keeps
    the full smoothing. ``vertices`` are in a camera's frame (z > 0 along its optical axis).
    ``smoothing`` = 0 keeps the (resampled) polyline.
    """
    mm = np.asarray(vertices, dtype=np.float64) * _MM
    seg = np.linalg.norm(np.diff(mm, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    mm = mm[keep]
    chord = np.concatenate([[0.0], np.cumsum(seg[seg > 1e-9])])
    step_mm = step * _MM
    count = max(2, int(np.ceil(chord[-1] / step_mm)) + 1)
    s = np.linspace(0.0, chord[-1], count)
    resampled = np.column_stack([np.interp(s, chord, mm[:, k]) for k in range(3)])
    dense_s = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / _DENSE_STEP_MM)) + 1))

    def smoothed(points: np.ndarray, length_mm: float) -> np.ndarray:
        if length_mm > 0 and count >= 5:
            return whittaker(points, np.ones(count), (length_mm / (s[1] - s[0])) ** 4)
        return points

    def densified(points: np.ndarray) -> np.ndarray:
        return make_interp_spline(s, points, k=3)(dense_s) if count >= 4 else points

    shaped = smoothed(resampled, smoothing * _MM)
    dense = densified(shaped)
    # The depth's noise (along the viewing rays) keeps the long smoothing; the image-plane
    # directions, measured to a fraction of a pixel, keep their tight bends.
    depth = shaped[:, 2:]
    rays = smoothed(resampled[:, :2] / resampled[:, 2:], min(arc_smoothing, smoothing) * _MM)
    measured = densified(np.column_stack([rays * depth, depth]))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(measured, axis=0), axis=1))])
    return ArcLengthCurve(dense / _MM, arc / _MM)


@dataclass(frozen=True)
class GraspPose:
    """Grasp pose on the curve: ``position`` (3,) m, ``quaternion`` (4,) x y z w, ``tangent`` (3,) unit."""

    position: np.ndarray
    quaternion: np.ndarray
    tangent: np.ndarray


def grasp_pose(curve: ArcLengthCurve, arc_length: float) -> GraspPose:
    """The grasp pose ``arc_length`` metres from the cut tip (along ``curve.arc``), in the frame
    of :mod:`suture_common.grasp`; the tangent is that of the curve's segment there.

    Raises ThreadTooShortError when the curve is shorter than ``arc_length`` and
    ReconstructionError when the thread points along the viewing ray there.
    """
    if curve.length < arc_length:
        raise ThreadTooShortError(
            f"reconstructed thread is {curve.length * 1000:.1f} mm long, shorter than the reserved "
            f"{arc_length * 1000:.1f} mm from the cut tip: no grasp point (lower grasp_arc_length or "
            "check that the whole thread is in view)"
        )
    position, tangent = point_at_arc_length(curve.samples, arc_length, curve.arc)
    try:
        rotation = grasp_rotation(position, tangent)
    except DegenerateGraspFrameError as exc:
        raise ReconstructionError(f"no grasp frame at {arc_length * 1000:.1f} mm: {exc}") from None
    return GraspPose(position, rotation_to_quaternion(rotation), tangent)
