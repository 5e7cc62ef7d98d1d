# SPDX-License-Identifier: Apache-2.0
"""Stretches of the thread not seen in a view: the sequences' not-seen flag, and depth across them.

The ordering stage publishes (N, 3) sequences whose third column is the *not-seen flag*: 1.0
for a pixel it interpolated across a gap in the mask (under an instrument shaft lying across
the thread), 0.0 for a pixel seen in the mask; (N, 2) sequences are seen throughout
(docs/interfaces.md). A not-seen pixel is a guess of where the thread runs in the image, not an
observation: it is never matched between the views. Its depth comes from the seen thread on
either side: the regularised disparity interpolates across the stretch (a cubic smoothing
spline, :func:`suture_reconstruction.pairing.regularise_disparity`), and the pixel, a smooth
(Hermite) curve along the thread's direction at both ends, is triangulated with it. The 3D
thread across the gap is therefore a smooth curve that meets the seen thread in position and
direction at both ends, and its arc length, not the chord's, goes into the arc length to the
grasp point. Path points that lie there are flagged (``Reconstruction.path_not_seen``,
:mod:`suture_reconstruction.uncertainty`) and a grasp on them is refused, unless the view's image
shows the thread along the stretch (the mask lost a faint stretch, no instrument hides it:
:mod:`suture_reconstruction.image_evidence`).
"""

from __future__ import annotations

import numpy as np

from suture_common.camera import StereoCamera
from suture_reconstruction.errors import InvalidSequenceError
from suture_reconstruction.pairing import Disparity
from suture_reconstruction.sequences import Resampled, resample, smooth_sequence
from suture_reconstruction.triangulation import Triangulated


def not_seen_flags(sequence: np.ndarray, name: str) -> np.ndarray:
    """(N,) bool: True where the (N, 3) ``sequence``'s third column is above 0.5 (not seen);
    all False for an (N, 2) one. The sequence's shape has been checked
    (:func:`suture_reconstruction.sequences.as_sequence`).

    Raises InvalidSequenceError for a NaN or infinite flag.
    """
    array = np.asarray(sequence, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        return np.zeros(len(array), dtype=bool)
    flag = array[:, 2]
    if not np.all(np.isfinite(flag)):
        raise InvalidSequenceError(
            f"{name} sequence has a NaN or infinite not-seen flag (z); z must be 1.0 (not seen) or 0.0 (seen)"
        )
    return flag > 0.5


def observed_samples(
    sequence: np.ndarray, not_seen: np.ndarray, window: int, max_jump_px: float
) -> tuple[Resampled, np.ndarray]:
    """The (N, 2) ``sequence`` smoothed lightly and resampled every 1 px (jumps longer than
    ``max_jump_px`` not observed, :func:`suture_reconstruction.sequences.resample`), with the
    samples on or next to a not-seen point not observed either; and (K,) bool, the samples
    that lie on a not-seen stretch."""
    smoothed = smooth_sequence(sequence, window)
    if not not_seen.any():
        resampled = resample(smoothed, 1.0, max_jump_px)
        return resampled, np.zeros(len(resampled.arc), dtype=bool)
    with_flag = resample(np.column_stack([smoothed, not_seen.astype(np.float64)]), 1.0, max_jump_px)
    hidden = with_flag.points[:, 2] > 0.0
    observed = with_flag.observed & ~hidden
    return Resampled(with_flag.points[:, :2], with_flag.arc, observed), hidden


def with_not_seen(
    camera: StereoCamera,
    left: Resampled,
    hidden: np.ndarray,
    disparity: Disparity,
    d_range: tuple[float, float],
    seen: Triangulated,
) -> Triangulated:
    """``seen`` together with the left samples of not-seen stretches (``hidden``) triangulated
    at the disparity interpolated across them, in sequence order.

    Samples between two seen vertices are added with a supported disparity within ``d_range``.
    A not-seen stretch at the cut tip (an end the segmenter lost, bridged from the tip hint)
    has no depth in front of it: its samples take the first seen vertex's disparity. One at the
    far end is left out.
    """
    if seen.index.size == 0:
        return seen
    with np.errstate(invalid="ignore"):
        usable = (
            hidden & disparity.supported & (disparity.value >= d_range[0]) & (disparity.value <= d_range[1])
        )
    index = np.flatnonzero(usable)
    index = index[(index > seen.index[0]) & (index < seen.index[-1])]
    d = disparity.value[index]
    if hidden[0]:
        leading = np.flatnonzero(hidden[: seen.index[0]])
        index = np.concatenate([leading, index])
        d = np.concatenate([np.full(leading.size, seen.disparity[0]), d])
    if index.size == 0:
        return seen
    uv = left.points[index]
    points = camera.triangulate(uv, uv[:, 0] - d)
    order = np.argsort(np.concatenate([seen.index, index]), kind="stable")
    return Triangulated(
        index=np.concatenate([seen.index, index])[order],
        left_uv=np.vstack([seen.left_uv, uv])[order],
        disparity=np.concatenate([seen.disparity, d])[order],
        points=np.vstack([seen.points, points])[order],
        unsupported=seen.unsupported,
    )
