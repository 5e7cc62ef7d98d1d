# SPDX-License-Identifier: Apache-2.0
"""Image sequences of the thread: validation, light smoothing and arc-length resampling.

A sequence is an ordered centreline from the cut tip in one rectified view, as
the ordering stage publishes it: an (N, 2) float array of pixels (u, v) =
(column, row), about 1 px apart. (N, 3) arrays, as read from a PolygonStamped,
are accepted and their third column ignored.

All lengths in this module are in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from suture_reconstruction.errors import InvalidSequenceError, TooFewPointsError
from suture_reconstruction.smoothing import savgol


def as_sequence(sequence: np.ndarray, name: str, min_points: int) -> np.ndarray:
    """The (N, 2) float64 pixels of ``sequence`` ((N, 2) or (N, 3) array-like).

    Raises InvalidSequenceError for a wrong shape or NaN/inf values and
    TooFewPointsError when N < ``min_points``.
    """
    try:
        array = np.asarray(sequence, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidSequenceError(f"{name} sequence is not numeric: {exc}") from None
    if array.ndim == 1 and array.size == 0:
        array = array.reshape(0, 2)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise InvalidSequenceError(f"{name} sequence must have shape (N, 2) pixels (u, v), got {array.shape}")
    array = array[:, :2]
    bad = ~np.isfinite(array)
    if bad.any():
        row = int(np.argwhere(bad)[0, 0])
        raise InvalidSequenceError(
            f"{name} sequence contains NaN or inf ({int(bad.any(axis=1).sum())} points, first at row {row}); "
            "the ordering stage must publish finite pixels"
        )
    if len(array) < min_points:
        raise TooFewPointsError(
            f"{name} sequence has {len(array)} points; "
            f"at least {min_points} are needed to reconstruct a thread"
        )
    return array


#: Image margin (fraction of the width/height) within which sequence points must lie.
IMAGE_MARGIN = 0.1
#: Longest plausible sequence, in image half-perimeters (W + H): a 150 mm thread at the nearest
#: working depth spans about 3 (W + H)/2; scattered points or garbage are far longer and would
#: cost minutes in the shape graph (its work grows faster than linearly with the length).
MAX_LENGTH_HALF_PERIMETERS = 4.0


def check_plausible(sequence: np.ndarray, width: int, height: int, name: str) -> None:
    """Raise InvalidSequenceError unless the (N, 2) ``sequence`` could be a thread in a WxH image.

    Every point must lie within the image (plus :data:`IMAGE_MARGIN`), and the polyline may be at
    most :data:`MAX_LENGTH_HALF_PERIMETERS` x (W + H) pixels long.
    """
    margin_u, margin_v = IMAGE_MARGIN * width, IMAGE_MARGIN * height
    outside = (
        (sequence[:, 0] < -margin_u)
        | (sequence[:, 0] > width + margin_u)
        | (sequence[:, 1] < -margin_v)
        | (sequence[:, 1] > height + margin_v)
    )
    if outside.any():
        raise InvalidSequenceError(
            f"{name} sequence has {int(outside.sum())} points outside the {width}x{height} image "
            f"(first {sequence[np.argmax(outside)].round(1).tolist()}); pixels must be u, v in the image"
        )
    length = float(np.hypot(*np.diff(sequence, axis=0).T).sum())
    limit = MAX_LENGTH_HALF_PERIMETERS * (width + height)
    if length > limit:
        raise InvalidSequenceError(
            f"{name} sequence is {length:.0f} px long, more than {limit:.0f} px "
            f"({MAX_LENGTH_HALF_PERIMETERS:g} x (W + H)): not an ordered thread centreline"
        )


def smooth_sequence(points: np.ndarray, window: int) -> np.ndarray:
    """Savitzky-Golay smoothing (quadratic, ``window`` samples) of an (N, 2) sequence along its index.

    The ends are fitted with one-sided polynomials, so the cut tip is
    not pulled inwards. Windows shorter than 5 samples, or sequences shorter than
    the window, are returned unchanged (as a copy).
    """
    window = int(window) | 1  # odd
    if window < 5 or len(points) < window:
        return np.array(points, dtype=np.float64, copy=True)
    return savgol(points, window, 2)


@dataclass(frozen=True)
class Resampled:
    """A polyline resampled at uniform arc length.

    ``points`` (K, D) lie every ``step`` along the input polyline (the last one at
    its end); ``arc`` (K,) is their arc length from the first point; ``observed``
    (K,) is False for samples that fall inside a jump of the input (a step longer
    than the ``max_step`` given), which is a straight-line guess, not an observation.
    """

    points: np.ndarray
    arc: np.ndarray
    observed: np.ndarray


def resample(points: np.ndarray, step: float, max_step: float = np.inf) -> Resampled:
    """Resample an (N, D) polyline every ``step`` of arc length (see :class:`Resampled`)."""
    points = np.asarray(points, dtype=np.float64)
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(seg)])
    total = cumulative[-1]
    arc = np.arange(0.0, total, step) if total > 0 else np.zeros(1)
    if total - arc[-1] > 1e-6 * step:
        arc = np.append(arc, total)
    columns = [np.interp(arc, cumulative, points[:, k]) for k in range(points.shape[1])]
    resampled = np.column_stack(columns)
    observed = np.ones(arc.size, dtype=bool)
    jumps = np.flatnonzero(seg > max_step)
    for j in jumps:  # few: only where the ordering stage jumped over a gap
        observed &= ~((arc > cumulative[j] + 0.5 * step) & (arc < cumulative[j + 1] - 0.5 * step))
    return Resampled(resampled, arc, observed)


def segment_lengths(points: np.ndarray) -> np.ndarray:
    """(N - 1,) lengths of the segments of an (N, D) polyline."""
    return np.linalg.norm(np.diff(points, axis=0), axis=1)


def roughness(points: np.ndarray, window: int, order: int) -> float:
    """Robust standard deviation (px) of an (N, 2) sequence across itself, about its own local fit.

    The residual of each sample from a Savitzky-Golay fit (``window`` samples,
    polynomial ``order``), measured along the sequence's normal, and its spread
    as 1.4826 x the median absolute value. A polynomial of order 4 over 31 px
    follows the image of a smooth thread (even a tight loop) to a few thousandths
    of a px, so what remains is the centreline's own noise: about zero for exact
    (simulated) sequences, some hundredths of a px for a centreline traced on a
    pixel mask, whose pixel quantisation leaves a saw-tooth across the thread.
    0 for sequences too short to fit.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < order + 3:
        return 0.0
    fit = savgol(points, window, order)
    tangent = savgol(points, window, 2, deriv=1)
    norm = np.hypot(tangent[:, 0], tangent[:, 1])
    ok = norm > 0
    across = (points[ok, 0] - fit[ok, 0]) * -tangent[ok, 1] + (points[ok, 1] - fit[ok, 1]) * tangent[ok, 0]
    if across.size == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(across / norm[ok])))


def row_alignment(points: np.ndarray, window: int) -> np.ndarray:
    """(N,) sin^2 of the angle between the sequence's tangent and the image rows.

    The tangent is a Savitzky-Golay derivative over ``window`` samples, wide enough
    that pixel noise does not make a thread that runs along the rows look steep.
    A crossing of a row at angle a has a column error of (row error) / tan(a), so
    sin^2(a) is the weight of the pair it gives.
    """
    if len(points) < 3:
        return np.ones(len(points))
    derivative = savgol(points, window, 2, deriv=1)
    du, dv = derivative[:, 0], derivative[:, 1]
    norm2 = du * du + dv * dv
    return np.where(norm2 > 0, dv * dv / np.maximum(norm2, 1e-300), 0.0)
