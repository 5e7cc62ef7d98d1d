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

Where the hook at the tip is so tight that the mask cleaning filled its holes (the slit a pixel
wide between merged arms, the eye of a loop too small to keep open: ``max_hole_area``,
``min_eye_width``), the walk through the hook goes down the filled stroke's middle and back, or
into the filled eye and back, and the arms' outer pixels, or the loop's rim, lie a little farther
from it than one thread's half width. Those pixels are explained where the sequence passes
twice, before it first leaves the tip's neighbourhood (:func:`_doubled`), and where the filling
widened the stroke at the sequence's point: within 1 px more than that point's distance to the
filled mask's edge (the discs about a medial axis that rebuild its shape; :func:`_covered`). A
loop or hook the search skipped is not: the sequence does not come back to it, and a thread
beside the sequence that it passes once is not either.
:func:`check_tip_explained` raises :class:`~suture_ordering.errors.UnexplainedTipError`
when either view has more than ``max_pixels``.

The segmenter can lose a hairpin's merged arms, the stroke twice the thread's width between the
cut tip and the hairpin's loop, and keep the loop: the mask then ends at the tip, and the loop lies
apart, farther on in line with the thread than the check's radius. :func:`thread_beyond_tip_pixels`
counts the mask's pixels off the sequence from the radius out to :data:`BEYOND_REACH` radii, within
:data:`BEYOND_HALF_ANGLE_DEG` of the way the thread leaves the tip; :func:`check_tip_explained`
refuses more than ``max_pixels`` of them too. A thread passing to the side of the tip at that
distance does not count; one crossing the line beyond the tip does, the safe side.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.cleaning import fill_holes_remove_specks
from suture_ordering.errors import UnexplainedTipError

#: A mask pixel within this distance (px) of the sequence's polyline is always explained by it.
EXPLAINED_PX = 2.5
#: Beyond the tip, pixels off the sequence count within this angle (deg) of the thread's way out
#: of the tip, from the check's radius out to :data:`BEYOND_REACH` radii.
BEYOND_HALF_ANGLE_DEG = 25.0
#: How far beyond the tip (in check radii) a piece of the thread in line with the tip counts.
BEYOND_REACH = 2.0
#: Holes are filled, and the sequence's passes found, this much (px) beyond the radius: a hole or
#: a walk's bend just past it counts as in the search's whole mask.
COVER_MARGIN = 8


def unexplained_tip_pixels(
    mask: np.ndarray,
    sequence: np.ndarray,
    radius: float,
    max_hole_area: float = 0.0,
    min_eye_width: int = 0,
) -> int:
    """Pixels of ``mask`` (H, W; nonzero: thread) within ``radius`` px of ``sequence[0]``
    ((N, 2) float (u, v), the ordered centreline from the tip) farther from the sequence's
    polyline than the thread's own pixels lie (:func:`_explained_distance`) and not within the
    reach of the filled stroke the sequence passes twice (:func:`_covered`; ``max_hole_area``:
    px², the largest hole the search's mask cleaning fills; 0: none; ``min_eye_width``: px, the
    width of a square of background that keeps a hole open, as in the cleaning)."""
    sequence = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    pixels = _off_sequence(mask, sequence, radius)
    return _not_covered(mask, sequence, pixels, radius, max_hole_area, min_eye_width)


def _not_covered(
    mask: np.ndarray,
    sequence: np.ndarray,
    pixels: np.ndarray,
    radius: float,
    max_hole_area: float,
    min_eye_width: int = 0,
) -> int:
    """How many of ``pixels`` ((K, 2) int (u, v), from :func:`_off_sequence`) lie beyond the reach
    of the filled stroke the sequence passes twice (all of them with ``max_hole_area`` 0)."""
    if max_hole_area <= 0 or len(pixels) == 0:
        return len(pixels)
    covered = _covered(mask, sequence, pixels, radius + COVER_MARGIN, max_hole_area, min_eye_width)
    return int(np.count_nonzero(~covered))


def _off_sequence(mask: np.ndarray, sequence: np.ndarray, radius: float) -> np.ndarray:
    """(K, 2) int (u, v): the pixels of ``mask`` within ``radius`` px of ``sequence[0]`` ((N, 2)
    float64) farther from the sequence's polyline than the thread's own pixels lie."""
    none = np.zeros((0, 2), dtype=np.int64)
    if len(sequence) == 0:
        return none
    tip = sequence[0]
    window, u0, v0 = _window(mask, tip, radius)
    if window.size == 0:
        return none
    rows, cols = np.mgrid[v0 : v0 + window.shape[0], u0 : u0 + window.shape[1]]
    near = np.hypot(cols - tip[0], rows - tip[1]) <= radius
    if not (window & near).any():
        return none
    far = _far_from_sequence(window, sequence - [u0, v0])
    if far is None:
        return none
    rows, cols = np.nonzero((window > 0) & near & far)
    return np.column_stack((cols + u0, rows + v0)).astype(np.int64)


def _far_from_sequence(window: np.ndarray, local: np.ndarray) -> np.ndarray | None:
    """(h, w) bool: the pixels of ``window`` (uint8 0/1) farther from the sequence's polyline
    (``local``: (N, 2) float (u, v) in the window's coordinates) than the thread's own pixels lie
    (:func:`_explained_distance`); None when the polyline misses the window."""
    cells = np.rint(local).astype(np.int32)
    drawn = np.zeros_like(window)
    cv2.polylines(drawn, [cells.reshape(-1, 1, 2)], False, 1, 1)
    if not drawn.any():
        return None
    distance = cv2.distanceTransform((1 - drawn).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return distance > _explained_distance(window, cells)


def _window(mask: np.ndarray, tip: np.ndarray, radius: float) -> tuple[np.ndarray, int, int]:
    """The square of ``mask`` (H, W) about ``tip`` ((2,) float (u, v)) that holds the disc of
    ``radius`` px, clipped to the image, as uint8 0/1, and its top-left corner (u0, v0)."""
    height, width = mask.shape
    r = math.ceil(radius) + 1
    u0, v0 = max(0, round(float(tip[0])) - r), max(0, round(float(tip[1])) - r)
    u1, v1 = min(width, round(float(tip[0])) + r + 1), min(height, round(float(tip[1])) + r + 1)
    window = (np.asarray(mask[v0 : max(v1, v0), u0 : max(u1, u0)]) > 0).astype(np.uint8)
    return window, u0, v0


def _covered(
    mask: np.ndarray,
    sequence: np.ndarray,
    pixels: np.ndarray,
    radius: float,
    max_hole_area: float,
    min_eye_width: int = 0,
) -> np.ndarray:
    """Which ``pixels`` ((K, 2) int (u, v) of ``mask`` (H, W)) lie within 1 px more than the
    filled mask's depth (the distance to its edge) of a point of ``sequence`` ((N, 2) float
    (u, v) from the tip) that the sequence passes twice (:func:`_doubled`) and where filling
    deepened the mask. (K,) bool. The filled mask is ``mask`` within ``radius`` px of the tip
    with its holes of at most ``max_hole_area`` px² filled but the eyes ``min_eye_width`` px wide,
    as the search's cleaning fills them;
    only the sequence's points from the tip until it first leaves ``radius`` count."""
    tip = sequence[0]
    window, u0, v0 = _window(mask, tip, radius)
    filled = window.copy()
    fill_holes_remove_specks(filled, max_hole_area, min_eye_width=min_eye_width)
    beyond = np.flatnonzero(np.hypot(*(sequence - tip).T) > radius + 1.0)
    points = _dense(sequence[: beyond[0] + 1] if len(beyond) else sequence) - [u0, v0]
    cells = np.rint(points).astype(np.int64)
    rows, cols = window.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < cols) & (cells[:, 1] >= 0) & (cells[:, 1] < rows)
    inside &= np.hypot(*(points - (tip - [u0, v0])).T) <= radius
    first = len(points) if inside.all() else int(np.argmin(inside))  # where it first leaves
    points, cells = points[:first], cells[:first]
    if len(points) == 0:
        return np.zeros(len(pixels), dtype=bool)
    depth = cv2.distanceTransform(filled, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[cells[:, 1], cells[:, 0]]
    own = cv2.distanceTransform(window, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[cells[:, 1], cells[:, 0]]
    reach = depth + 1.0
    chosen = _doubled(points, reach) & (depth > own)
    if not chosen.any():
        return np.zeros(len(pixels), dtype=bool)
    points, reach = points[chosen], reach[chosen]
    offsets = pixels - [u0, v0]
    gap = np.hypot(offsets[:, None, 0] - points[None, :, 0], offsets[:, None, 1] - points[None, :, 1])
    return (gap <= reach[None, :]).any(axis=1)


def _doubled(points: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Which ``points`` ((N, 2) float, along the sequence, at most 1 px apart) lie on a stretch
    that the sequence passes twice: from a point to a later one within both points' ``reach``
    ((N,) px) of it, after more than twice the larger reach of arc in between (down a stroke
    and back, or into a small loop's filled eye and back). (N,) bool."""
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    apart = np.hypot(points[:, None, 0] - points[None, :, 0], points[:, None, 1] - points[None, :, 1])
    later = arc[None, :] - arc[:, None] > 2.0 * np.maximum(reach[:, None], reach[None, :])
    partner = later & (apart <= np.minimum(reach[:, None], reach[None, :]))
    last = np.where(partner.any(axis=1), len(points) - 1 - np.argmax(partner[:, ::-1], axis=1), -1)
    return np.maximum.accumulate(last) >= np.arange(len(points))


def _dense(points: np.ndarray) -> np.ndarray:
    """The polyline ``points`` ((N, 2) float) with points put in, at most 1 px apart."""
    if len(points) < 2:
        return points
    lengths = np.hypot(*np.diff(points, axis=0).T)
    counts = np.maximum(1, np.ceil(lengths)).astype(np.int64)
    index = np.repeat(np.arange(len(points) - 1), counts)
    within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    dense = points[index] + (within / counts[index])[:, None] * (points[index + 1] - points[index])
    return np.vstack([dense, points[-1:]])


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


def thread_beyond_tip_pixels(mask: np.ndarray, sequence: np.ndarray, radius: float) -> int:
    """Pixels of ``mask`` (H, W; nonzero: thread) in line with the thread beyond its cut tip: from
    ``radius`` to :data:`BEYOND_REACH` times ``radius`` px from ``sequence[0]`` ((N, 2) float (u, v)
    from the tip), within :data:`BEYOND_HALF_ANGLE_DEG` of the way the sequence leaves the tip
    backwards (from its point ``radius`` / 2 px of arc in, through the tip), and farther from the
    sequence's polyline than the thread's own pixels lie."""
    sequence = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    if len(sequence) < 2 or radius <= 0:
        return 0
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(sequence, axis=0).T))])
    tip = sequence[0]
    outward = tip - sequence[min(int(np.searchsorted(arc, radius / 2)), len(sequence) - 1)]
    length = float(np.hypot(*outward))
    if length == 0:
        return 0
    reach = BEYOND_REACH * radius
    window, u0, v0 = _window(mask, tip, reach)
    if window.size == 0:
        return 0
    rows, cols = np.mgrid[v0 : v0 + window.shape[0], u0 : u0 + window.shape[1]]
    offset_u, offset_v = cols - tip[0], rows - tip[1]
    distance = np.hypot(offset_u, offset_v)
    along = (offset_u * outward[0] + offset_v * outward[1]) / length
    in_line = along >= distance * math.cos(math.radians(BEYOND_HALF_ANGLE_DEG))
    candidates = (window > 0) & in_line & (distance > radius) & (distance <= reach)
    if not candidates.any():
        return 0
    far = _far_from_sequence(window, sequence - [u0, v0])
    return 0 if far is None else int(np.count_nonzero(candidates & far))


def check_tip_explained(
    masks: tuple[np.ndarray, np.ndarray],
    sequences: tuple[np.ndarray, np.ndarray],
    radius: float,
    max_pixels: float,
    max_hole_area: float = 0.0,
    min_eye_width: int = 0,
) -> None:
    """Raise :class:`UnexplainedTipError` when, in either view, more than ``max_pixels`` of the
    mask near the tip (:func:`unexplained_tip_pixels` within ``radius`` px), or in line beyond it
    (:func:`thread_beyond_tip_pixels`), lie off the sequence.
    ``masks``: (left, right) (H, W); ``sequences``: (left, right) (N, 2) from the cut tip;
    ``max_hole_area``: px², the largest hole the ordering's mask cleaning fills; ``min_eye_width``:
    px, the square of background that keeps such a hole open there."""
    for view, mask, sequence in zip(("left", "right"), masks, sequences, strict=True):
        sequence = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
        pixels = _off_sequence(mask, sequence, radius)
        unexplained = len(pixels)
        if unexplained > max_pixels:  # fewer, never more: worked out only where it decides
            unexplained = _not_covered(mask, sequence, pixels, radius, max_hole_area, min_eye_width)
        if unexplained > max_pixels:
            raise UnexplainedTipError(
                f"{unexplained} px of thread within {radius:.0f} px of the cut tip lie off the ordered "
                f"sequence (more than tip_unexplained_max_px, {max_pixels:.0f} px at this image size): "
                "the search skipped a hook or loop at the tip, and the grasp point would lie that arc too "
                "far along the thread; check the masks near the tip",
                view,
            )
        beyond = thread_beyond_tip_pixels(mask, sequence, radius)
        if beyond > max_pixels:
            raise UnexplainedTipError(
                f"{beyond} px of thread lie beyond the cut tip in line with it, {radius:.0f}-"
                f"{BEYOND_REACH * radius:.0f} px away and off the ordered sequence (more than "
                f"tip_unexplained_max_px, {max_pixels:.0f} px at this image size): the mask lost the "
                "thread between the tip and the rest of a hook, and the grasp point would lie that arc "
                "too far along the thread; check the masks near the tip",
                view,
            )
