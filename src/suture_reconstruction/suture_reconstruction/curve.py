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
cut end (bend radius 0.3-2 mm, its arms side by side) lost about 2 mm of arc under the
1 mm smoothing length, and every point beyond it, the grasp point too, moved along the
thread by as much. At such bends the arc length is taken from the vertex polyline
instead (:func:`_bends_kept`); ``ArcLengthCurve.arc`` is that arc length along the
thread, and the published path is spaced by the smoothed samples' own arc.

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
#: Grid steps (of 0.25 mm) over which the arc the smoothing cut off at a bend is measured.
_BEND_WINDOW = 5
#: A bend whose smoothed radius is within this many smoothing lengths was cut by the smoother.
_BEND_RADIUS = 2.0


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


def fit_curve(vertices: np.ndarray, smoothing: float, step: float = 2.5e-4) -> ArcLengthCurve:
    """Smooth arc-length curve through (n, 3) ordered vertices (m); smoothing length ``smoothing`` (m).

    The vertices are resampled every ``step`` m of chord length, smoothed with the
    Whittaker smoother (lam = (smoothing / step)^4, a discrete cubic smoothing
    spline), interpolated by a C2 cubic spline (``scipy.interpolate.make_interp_spline``)
    and sampled every 0.05 mm; the samples' ``arc`` is their own arc length, with the arc
    that the smoothing cut off at tight bends kept (:func:`_bends_kept`). ``smoothing`` = 0
    keeps the (resampled) polyline.
    """
    mm = np.asarray(vertices, dtype=np.float64) * _MM
    seg = np.linalg.norm(np.diff(mm, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    mm = mm[keep]
    chord = np.concatenate([[0.0], np.cumsum(seg[seg > 1e-9])])
    step_mm = step * _MM
    count = max(2, int(np.ceil(chord[-1] / step_mm)) + 1)
    s = np.linspace(0.0, chord[-1], count)
    points = np.column_stack([np.interp(s, chord, mm[:, k]) for k in range(3)])
    if smoothing > 0 and count >= 5:
        points = whittaker(points, np.ones(count), (smoothing * _MM / (s[1] - s[0])) ** 4)
    if count >= 4:
        dense_s = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / _DENSE_STEP_MM)) + 1))
        dense = make_interp_spline(s, points, k=3)(dense_s)
    else:
        dense = points
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    if smoothing > 0 and count >= 5:
        arc = _bends_kept(arc, dense_s, s, points, smoothing * _MM)
    return ArcLengthCurve(dense / _MM, arc / _MM)


def _bends_kept(
    arc: np.ndarray, chord: np.ndarray, grid: np.ndarray, smoothed: np.ndarray, smoothing: float
) -> np.ndarray:
    """The smoothed curve's ``arc`` (S,) mm with the arc that the smoothing cut off at tight
    bends put back. ``chord`` (S,): the samples' arc along the vertex polyline; ``grid`` (K,)
    mm: its resampling grid, ``smoothed`` (K, 3) mm the smoothed points there; ``smoothing``
    the smoothing length (mm).

    Over windows of :data:`_BEND_WINDOW` grid steps the polyline's arc exceeds the smoothed
    one by a ratio that its noise keeps about the same along the thread (the median ratio),
    and that a bend tighter than the smoothing length raises locally. Where the smoothed
    curve still bends with a radius within :data:`_BEND_RADIUS` smoothing lengths (over about
    1 mm either side), each step's smoothed arc grows by the local ratio over the median (it
    never shrinks); elsewhere it stays: the staircase of a sequence traced on a mask raises
    the ratio along straight stretches too, and there it is noise."""
    smooth = np.interp(grid, chord, arc)
    own, polyline = np.diff(smooth), np.diff(grid)
    window = np.ones(_BEND_WINDOW)
    ratio = np.convolve(polyline, window, "same") / np.maximum(np.convolve(own, window, "same"), 1e-12)
    gain = np.maximum(1.0, ratio / max(float(np.median(ratio)), 1e-12))
    chords = np.diff(smoothed, axis=0)
    half = _BEND_WINDOW // 2 + 1
    before, after = chords[: len(chords) - half], chords[half:]
    cos = np.einsum("ij,ij->i", before, after) / np.maximum(
        np.linalg.norm(before, axis=1) * np.linalg.norm(after, axis=1), 1e-12
    )
    turn = np.zeros(len(chords))
    turn[half // 2 : half // 2 + len(cos)] = np.arccos(np.clip(cos, -1.0, 1.0))
    radius = (half * np.diff(grid).mean()) / np.maximum(turn, 1e-12)
    gain = np.where(radius < _BEND_RADIUS * smoothing, gain, 1.0)
    kept = np.concatenate([[0.0], np.cumsum(own * gain)])
    return np.interp(chord, grid, kept)


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
