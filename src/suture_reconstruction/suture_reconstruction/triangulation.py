# SPDX-License-Identifier: Apache-2.0
"""3D points of the thread: triangulation of the left samples with a supported disparity, and
their resampling into the evenly spaced vertices that Algorithm 1 takes.

Points are in the left camera optical frame, metres, (K, 3) float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from suture_common.camera import StereoCamera
from suture_reconstruction.errors import NoStereoOverlapError
from suture_reconstruction.pairing import Disparity
from suture_reconstruction.sequences import Resampled


@dataclass(frozen=True)
class Triangulated:
    """``index`` (K,) the left samples with a vertex; ``left_uv`` (K, 2) their pixels;
    ``disparity`` (K,) px; ``points`` (K, 3) m; ``unsupported``: observed left samples
    without a vertex (no supported disparity within the limits)."""

    index: np.ndarray
    left_uv: np.ndarray
    disparity: np.ndarray
    points: np.ndarray
    unsupported: int


def triangulate_supported(
    camera: StereoCamera,
    left: Resampled,
    disparity: Disparity,
    d_range: tuple[float, float],
    min_points: int,
) -> Triangulated:
    """Triangulate every observed left sample whose disparity is supported and within ``d_range``
    (px, min and max).

    Raises NoStereoOverlapError when fewer than ``min_points`` remain.
    """
    with np.errstate(invalid="ignore"):
        valid = (
            left.observed
            & disparity.supported
            & (disparity.value >= d_range[0])
            & (disparity.value <= d_range[1])
        )
    unsupported = int((left.observed & ~valid).sum())
    index = np.flatnonzero(valid)
    if index.size < min_points:
        raise NoStereoOverlapError(
            f"only {index.size} left samples have a disparity within the limits after regularisation"
        )
    left_uv = left.points[index]
    d = disparity.value[index]
    points = camera.triangulate(left_uv, left_uv[:, 0] - d)
    return Triangulated(index, left_uv, d, points, unsupported)


def resample_runs(points: np.ndarray, index: np.ndarray, step: float) -> np.ndarray:
    """Resample (K, 3) ``points`` every ``step`` m within each run of consecutive ``index`` values.

    A break in ``index`` (samples without a vertex between) is a gap that is not
    filled: Algorithm 1 bridges it by growing tau_L. A run's last point is kept.
    """
    breaks = np.flatnonzero(np.diff(index) > 1) + 1
    runs = np.split(np.arange(len(points)), breaks)
    out = []
    for run in runs:
        chain = points[run]
        seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        s = np.arange(0.0, arc[-1], step) if arc[-1] > 0 else np.zeros(1)
        if arc[-1] - s[-1] > 0.25 * step:
            s = np.append(s, arc[-1])
        else:
            s[-1] = arc[-1] if s.size > 1 else s[-1]
        out.append(np.column_stack([np.interp(s, arc, chain[:, k]) for k in range(3)]))
    return np.concatenate(out)
