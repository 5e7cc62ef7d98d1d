# SPDX-License-Identifier: Apache-2.0
"""Whether the sequences explain the thread at the cut tip.

A cut suture often curls into a small hook or loop at its tip. Where the segmenter loses part of
the loop (a faint, tight bend) the search can start at the tip and run straight on along the
thread, skipping the loop: the sequence then misses the loop's arc, and since the grasp point is
placed a fixed arc length from the tip, the grasp lands that much too far along the thread
(5-15 mm on simulated hooks). Both views usually skip the same loop, so the stereo pair shows no
disagreement. What does show it is thread near the tip that the sequence does not pass through.

:func:`unexplained_tip_pixels` counts, in one view, the pixels of a mask (the low mask where there
is one: the loop's faint pixels are more often there) within ``radius`` px of the sequence's first
point that lie farther from the sequence than the thread's own half width plus 1 px (at least
:data:`EXPLAINED_PX`), whether or not they connect to it
there (the segmenter often keeps the loop's far side as a separate fragment). Another thread
passing that close to the tip counts too: the ordering then refuses, the safe side.
:func:`check_tip_explained` raises :class:`~suture_ordering.errors.UnexplainedTipError`
when either view has more than ``max_pixels``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.errors import UnexplainedTipError

#: A mask pixel within this distance (px) of the sequence's polyline is always explained by it.
EXPLAINED_PX = 2.5


def unexplained_tip_pixels(mask: np.ndarray, sequence: np.ndarray, radius: float) -> int:
    """Pixels of ``mask`` (H, W; nonzero: thread) within ``radius`` px of ``sequence[0]``
    ((N, 2) float (u, v), the ordered centreline from the tip) farther from the sequence's
    polyline than the thread's own pixels lie (:func:`_explained_distance`)."""
    sequence = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    if len(sequence) == 0:
        return 0
    height, width = mask.shape
    tip = sequence[0]
    r = math.ceil(radius) + 1
    u0, v0 = max(0, round(float(tip[0])) - r), max(0, round(float(tip[1])) - r)
    u1, v1 = min(width, round(float(tip[0])) + r + 1), min(height, round(float(tip[1])) + r + 1)
    if u1 <= u0 or v1 <= v0:
        return 0
    window = (np.asarray(mask[v0:v1, u0:u1]) > 0).astype(np.uint8)
    rows, cols = np.mgrid[v0:v1, u0:u1]
    near = np.hypot(cols - tip[0], rows - tip[1]) <= radius
    if not (window & near).any():
        return 0
    local = np.rint(sequence - [u0, v0]).astype(np.int32)
    drawn = np.zeros_like(window)
    cv2.polylines(drawn, [local.reshape(-1, 1, 2)], False, 1, 1)
    if not drawn.any():
        return 0
    explained = _explained_distance(window, local)
    far = cv2.distanceTransform((1 - drawn).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) > explained
    return int(np.count_nonzero((window > 0) & near & far))


def _explained_distance(window: np.ndarray, local: np.ndarray) -> float:
    """Distance (px) from the sequence within which the thread's own pixels lie: half its width in
    the ``window`` (uint8 0/1; the median distance transform at the sequence's ``local`` (N, 2) int
    pixels in it) plus 1 px, at least :data:`EXPLAINED_PX`."""
    height, width = window.shape
    inside = (local[:, 0] >= 0) & (local[:, 0] < width) & (local[:, 1] >= 0) & (local[:, 1] < height)
    if not inside.any():
        return EXPLAINED_PX
    depth = cv2.distanceTransform(window, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    depth = depth[local[inside, 1], local[inside, 0]]
    return max(EXPLAINED_PX, float(np.median(depth)) + 1.0)


def check_tip_explained(
    masks: tuple[np.ndarray, np.ndarray],
    sequences: tuple[np.ndarray, np.ndarray],
    radius: float,
    max_pixels: float,
) -> None:
    """Raise :class:`UnexplainedTipError` when, in either view, more than ``max_pixels`` of the
    mask near the tip (:func:`unexplained_tip_pixels` within ``radius`` px) lie off the sequence.
    ``masks``: (left, right) (H, W); ``sequences``: (left, right) (N, 2) from the cut tip."""
    for view, mask, sequence in zip(("left", "right"), masks, sequences, strict=True):
        unexplained = unexplained_tip_pixels(mask, sequence, radius)
        if unexplained > max_pixels:
            raise UnexplainedTipError(
                f"{unexplained} px of thread within {radius:.0f} px of the cut tip lie off the ordered "
                f"sequence (more than tip_unexplained_max_px, {max_pixels:.0f} px at this image size): "
                "the search skipped a hook or loop at the tip, and the grasp point would lie that arc too "
                "far along the thread; check the masks near the tip",
                view,
            )
