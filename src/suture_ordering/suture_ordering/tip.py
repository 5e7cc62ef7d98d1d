# SPDX-License-Identifier: Apache-2.0
"""Cut-tip localisation in the left view (from a hint or automatically) and in the right view.

The cut tip is a *free end* of the thread's centreline: an end point (one
8-neighbour) of the mask's skeleton (``skimage.morphology.skeletonize``). Only
a small window is skeletonised when a hint is given, so this costs well under a
millisecond.

* **With a hint** (the paper's manual indication, ``/suture/tip_hint``): the free
  end nearest to the hint within ``tip_radius`` px. No thread pixel within that
  radius: :class:`TipNotOnThreadError`, unless a thread end points at the hint from
  a little farther (:func:`tip_across_gap`: the segmenter lost the cut end; the
  caller bridges the stretch and flags it not seen); thread pixels but no free end (a closed
  ring, or a hint on the middle of a thread): :class:`NoFreeEndError`.
* **Without a hint** (automatic rule): the free end of the largest thread (the
  skeleton component with most pixels) that lies nearest to the image centre.
  The mask alone cannot tell the cut end from the other end; the rule assumes
  that the camera is centred on the cut, as it is when the surgeon has just cut
  the suture. Give a hint whenever one is available.
* **Right view** (rectified pair): the free end on the left tip's row (within
  ``row_tolerance`` px) whose disparity ``u_left - u_right`` lies in
  ``[camera.disparity(max_depth), camera.disparity(min_depth)]`` (17 to 52 px for
  the default 640 px camera and 50 to 150 mm), widened by the row tolerance; of
  several, the one on the nearest row. No thread on that band at all: the end that points
  back at the left tip shifted by the disparity of the row where it starts
  (:func:`right_tip_across_gap`).
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.morphology import skeletonize, thin

from suture_ordering.errors import NoFreeEndError, TipNotOnThreadError, TipOutsideImageError

_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], dtype=np.float32)


def free_ends(mask: np.ndarray) -> np.ndarray:
    """(K, 2) int (u, v) end points of the skeleton of ``mask`` ((H, W) uint8 0/1 or bool)."""
    return end_pixels(skeletonize(np.asarray(mask, dtype=bool)))


def thinned_free_ends(mask: np.ndarray) -> np.ndarray:
    """(K, 2) int (u, v) end points of ``mask`` ((H, W) uint8 0/1 or bool) thinned by
    :func:`skimage.morphology.thin`. :func:`free_ends`' skeleton (Zhang's thinning) can lose half
    of a thin diagonal thread from its end (36 px of a thread drawn four pixels a row whose end
    tapers); this thinning keeps the end, with more spurs on a wide or ragged mask."""
    return end_pixels(thin(np.asarray(mask, dtype=bool)))


def end_pixels(skeleton: np.ndarray) -> np.ndarray:
    """(K, 2) int (u, v) pixels of ``skeleton`` ((H, W) bool or 0/1) with one skeleton neighbour."""
    skeleton = skeleton.astype(np.uint8)
    count = cv2.filter2D(skeleton, cv2.CV_8U, _NEIGHBOURS, borderType=cv2.BORDER_CONSTANT)
    v, u = np.nonzero((skeleton == 1) & (count == 1))
    return np.column_stack([u, v])


def extend_to_end(
    mask: np.ndarray, end: np.ndarray, radius: float, axis: np.ndarray | None = None
) -> np.ndarray:
    """Move a skeleton end point to the end of the mask along the thread's direction.

    Thinning shortens a thread's end by up to its width (more on diagonal threads: 7 px on a
    3-px thread at 43 degrees). Only the mask pixels connected to ``end`` within ``radius``
    count (another thread may pass by). The thread leaves ``end`` along its skeleton: the outward
    axis points from the mean of the skeleton pixels within ``radius`` to ``end``. The returned
    end (float64 (u, v)) is the mask pixel that lies farthest out along that axis, within
    ``radius`` and at most 1.5 px from the axis, moved back by half the thread's width (the
    rounded end of a thread lies that far beyond its centreline's end). The width is the mask
    area between radius/2 and radius from ``end``, on the inner side, divided by radius/2. (The
    mask pixels alone cannot give the axis: when the skeleton is that short, they lie on both
    sides of ``end``.) ``axis``: the outward direction ((2,) float, (u, v)) when the caller
    knows it from a skeleton of its own; the window's skeleton gives none where thinning
    has eaten the end back by more than ``radius`` (a 2 px thread on the diagonal), since the
    thread then runs on past ``end`` on both sides.
    """
    if axis is None:
        found = _outward_axis(mask, end, radius)
        if found is None:
            return np.asarray(end, dtype=np.float64)
        axis, thread, u0, v0 = found
    else:
        own = _own_thread(mask, end, radius)
        axis = np.array(axis, dtype=np.float64)
        norm = float(np.hypot(*axis))
        if own is None or norm < 1e-6:
            return np.asarray(end, dtype=np.float64)
        thread, u0, v0 = own
        axis /= norm
    rows, cols = np.nonzero(thread)
    offset = np.column_stack((cols + u0 - end[0], rows + v0 - end[1]))
    distance = np.hypot(offset[:, 0], offset[:, 1])
    along = offset @ axis
    across = np.abs(offset[:, 0] * axis[1] - offset[:, 1] * axis[0])
    ok = (distance <= radius) & (across <= 1.5)
    if not ok.any() or along[ok].max() <= 0:
        return np.asarray(end, dtype=np.float64)
    best = np.flatnonzero(ok)[np.argmax(np.where(ok, along, -np.inf)[ok])]
    ring = (distance >= radius / 2) & (distance <= radius) & (along < 0)
    thread_width = int(ring.sum()) / (radius / 2)
    back = min(max(0.0, (thread_width - 1) / 2), float(along[best]) + 0.0)
    return np.asarray(end, dtype=np.float64) + offset[best] - back * axis


def _own_thread(mask: np.ndarray, end: np.ndarray, radius: float) -> tuple[np.ndarray, int, int] | None:
    """The mask pixels connected to ``end`` in the window of ``radius`` around it ((h, w) bool:
    not another thread passing through the window) and the window's (u0, v0); None off the mask."""
    r = int(np.ceil(radius))
    u0, v0 = max(0, int(end[0]) - r), max(0, int(end[1]) - r)
    window = np.asarray(mask[v0 : int(end[1]) + r + 1, u0 : int(end[0]) + r + 1], dtype=np.uint8)
    _, pieces = cv2.connectedComponents(window, connectivity=8)
    own = pieces[int(end[1]) - v0, int(end[0]) - u0]
    return None if own == 0 else (pieces == own, u0, v0)


def _outward_axis(
    mask: np.ndarray, end: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, int, int] | None:
    """The unit direction in which the thread leaves the skeleton end ``end`` (from the mean of
    its skeleton pixels within ``radius`` to ``end``), and :func:`_own_thread`'s pixels and
    window corner; None off the mask or on a dot."""
    own = _own_thread(mask, end, radius)
    if own is None:
        return None
    thread, u0, v0 = own
    rows, cols = np.nonzero(skeletonize(thread))
    inward = np.column_stack((cols + u0 - end[0], rows + v0 - end[1]))
    inward = inward[np.hypot(inward[:, 0], inward[:, 1]) <= radius]
    axis = -inward.mean(axis=0) if len(inward) else np.zeros(2)
    norm = float(np.hypot(*axis))
    if norm < 1e-6:
        return None
    return axis / norm, thread, u0, v0


def tip_across_gap(
    mask: np.ndarray, hint: np.ndarray, radius: float, max_gap: float, max_angle: float
) -> np.ndarray | None:
    """The thread end that points at ``hint`` across a gap in the mask, or None.

    For a cut tip the segmenter lost (a faint or dark stretch at the end of the thread): the
    free end of ``mask`` within ``max_gap`` px of ``hint`` whose thread leaves it towards the
    hint (the angle between its outward direction, :func:`extend_to_end`, and the way to the
    hint at most ``max_angle`` rad), the nearest of several. Returns (2,) float64 (u, v), the end
    moved out to the end of the mask. ``radius``: as in :func:`extend_to_end`.
    """
    height, width = mask.shape
    u, v = float(hint[0]), float(hint[1])
    margin = int(np.ceil(max_gap + radius)) + 8
    u0, v0 = max(0, int(u) - margin), max(0, int(v) - margin)
    ends = free_ends(mask[v0 : min(height, int(v) + margin + 1), u0 : min(width, int(u) + margin + 1)])
    ends = ends + np.array([u0, v0])
    best, best_distance = None, np.inf
    for skeleton_end in ends:  # skeleton ends near the hint: a handful
        end = extend_to_end(mask, skeleton_end, radius)
        way = np.array([u, v]) - end
        distance = float(np.hypot(*way))
        if distance > max_gap or distance >= best_distance or distance < 1e-6:
            continue
        found = _outward_axis(mask, skeleton_end, radius)
        if found is not None and float(np.dot(found[0], way / distance)) >= np.cos(max_angle):
            best, best_distance = end, distance
    return best


def right_tip_across_gap(
    mask: np.ndarray,
    left_points: np.ndarray,
    disparity_range: tuple[float, float],
    radius: float,
    max_gap: float,
    max_angle: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the right mask lost the cut end that the left view sees: (the right thread's end,
    the right cut tip), each (2,) float64 (u, v), or None.

    The end is a free end of ``mask`` on the row of a point of ``left_points`` ((N, 2) the left
    sequence from its cut tip) that lies less than ``max_gap`` px of arc from the tip, at a
    disparity in ``disparity_range``; the right cut tip is the left one shifted as that point
    is. The thread must leave the end towards that tip (within ``max_angle`` rad), at most
    ``max_gap`` px away. A row that the left stretch crosses more than once, or along which it
    runs (disparities more than 4 px apart on it), does not tell the point: no end there.
    """
    left = np.asarray(left_points, dtype=np.float64)
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(left, axis=0).T))))
    near = left[arc < max_gap]
    d_min, d_max = disparity_range
    height, width = mask.shape
    margin = int(np.ceil(radius)) + 8
    u0 = max(0, int(near[:, 0].min() - d_max) - margin)
    u1 = min(width, int(near[:, 0].max() - d_min) + margin + 1)
    v0, v1 = max(0, int(near[:, 1].min()) - margin), min(height, int(near[:, 1].max()) + margin + 1)
    if u1 <= u0 or v1 <= v0:
        return None
    best, best_distance = None, np.inf
    for skeleton_end in free_ends(mask[v0:v1, u0:u1]) + np.array([u0, v0]):  # a handful
        end = extend_to_end(mask, skeleton_end, radius)
        on_row = np.flatnonzero(np.abs(near[:, 1] - end[1]) <= 1.0)
        disparity = near[on_row, 0] - end[0]
        if on_row.size == 0 or np.ptp(disparity) > 4.0 or not d_min <= disparity.mean() <= d_max:
            continue
        tip = left[0] + (end - near[on_row[np.argmin(np.abs(near[on_row, 1] - end[1]))]])
        way = tip - end
        distance = float(np.hypot(*way))
        if distance > max_gap or distance >= best_distance or distance < 1e-6:
            continue
        found = _outward_axis(mask, skeleton_end, radius)
        if found is not None and float(np.dot(found[0], way / distance)) >= np.cos(max_angle):
            best, best_distance = (end, tip), distance
    return best


def check_hint(hint: np.ndarray, width: int, height: int, view: str | None = None) -> np.ndarray:
    """``hint`` as a finite (2,) float64 (u, v) inside the image, else TipOutsideImageError."""
    point = np.asarray(hint, dtype=np.float64).reshape(-1)
    if point.shape != (2,):
        raise TipOutsideImageError(f"tip hint must be a (2,) pixel (u, v), got shape {np.shape(hint)}", view)
    if not np.all(np.isfinite(point)):
        raise TipOutsideImageError(f"tip hint {point.tolist()} is NaN or infinite", view)
    u, v = point
    if not (-0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5):
        raise TipOutsideImageError(
            f"tip hint ({u:.1f}, {v:.1f}) lies outside the {width}x{height} image; "
            "give the cut tip's pixel in the left image (x = column, y = row)",
            view,
        )
    return point


def tip_from_hint(mask: np.ndarray, hint: np.ndarray, radius: float, view: str | None = None) -> np.ndarray:
    """The free end of ``mask`` nearest to ``hint`` within ``radius`` px, as (2,) float64 (u, v),
    moved out to the mask's end (:func:`extend_to_end`). Where the skeleton has no end that near,
    the ends of the mask thinned otherwise (:func:`thinned_free_ends`: a thin diagonal thread's
    end that the skeleton lost)."""
    height, width = mask.shape
    u, v = check_hint(hint, width, height, view)
    margin = int(np.ceil(radius)) + 8  # skeleton context beyond the search radius
    u0, u1 = max(0, int(u) - margin), min(width, int(u) + margin + 1)
    v0, v1 = max(0, int(v) - margin), min(height, int(v) + margin + 1)
    window = mask[v0:v1, u0:u1]
    for find in (free_ends, thinned_free_ends):
        ends = find(window) + np.array([u0, v0])
        distance = np.hypot(ends[:, 0] - u, ends[:, 1] - v)
        near = distance <= radius
        if near.any():
            return extend_to_end(mask, ends[near][np.argmin(distance[near])], radius)
    rows, cols = np.nonzero(window)
    if rows.size == 0 or np.min(np.hypot(cols + u0 - u, rows + v0 - v)) > radius:
        raise TipNotOnThreadError(
            f"no thread pixel within {radius:.0f} px of the tip hint ({u:.1f}, {v:.1f}); "
            "the hint must point at the cut tip of a segmented thread",
            view,
        )
    raise NoFreeEndError(
        f"the thread near the tip hint ({u:.1f}, {v:.1f}) has no free end within {radius:.0f} px: "
        "it is a closed ring there, or the hint is not at the cut end; move the hint onto the cut tip",
        view,
    )


def automatic_tip(mask: np.ndarray, radius: float, view: str | None = None) -> np.ndarray:
    """The free end of the largest skeleton component nearest to the image centre ((2,) float64).

    ``radius``: how far the end may be moved out to the mask's end (:func:`extend_to_end`)."""
    skeleton = skeletonize(mask.astype(bool)).astype(np.uint8)
    count = cv2.filter2D(skeleton, cv2.CV_8U, _NEIGHBOURS, borderType=cv2.BORDER_CONSTANT)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(skeleton, connectivity=8)
    v, u = np.nonzero((skeleton == 1) & (count == 1))
    if u.size == 0:
        raise NoFreeEndError(
            "no thread in the mask has a free end (closed rings only); give a tip hint", view
        )
    sizes = stats[labels[v, u], cv2.CC_STAT_AREA]
    keep = sizes == sizes.max()
    u, v = u[keep], v[keep]
    height, width = mask.shape
    best = np.argmin(np.hypot(u - (width - 1) / 2, v - (height - 1) / 2))
    return extend_to_end(mask, np.array([u[best], v[best]], dtype=np.float64), radius)


def right_tip(
    mask: np.ndarray,
    left_tip: np.ndarray,
    disparity_range: tuple[float, float],
    row_tolerance: float,
    radius: float,
    view: str = "right",
) -> np.ndarray:
    """The free end of the right ``mask`` matching ``left_tip`` under rectified geometry ((2,) float64).

    ``disparity_range`` = (d_min, d_max) px; the end must satisfy
    ``|v_r - v_l| <= row_tolerance`` and ``d_min - row_tolerance <= u_l - u_r <= d_max + row_tolerance``;
    ``radius`` as in :func:`extend_to_end`. Where the skeleton has no such end, the ends of the
    mask thinned otherwise (:func:`thinned_free_ends`), as :func:`tip_from_hint` reads them.
    """
    height, width = mask.shape
    u, v = float(left_tip[0]), float(left_tip[1])
    d_min, d_max = disparity_range
    tol = row_tolerance
    reach = tol + radius  # skeleton ends lie up to ``radius`` inside the mask's end
    margin = 8
    u0 = max(0, int(np.floor(u - d_max - reach)) - margin)
    u1 = min(width, int(np.ceil(u - d_min + reach)) + margin + 1)
    v0 = max(0, int(np.floor(v - reach)) - margin)
    v1 = min(height, int(np.ceil(v + reach)) + margin + 1)
    band = f"rows {v - tol:.0f}..{v + tol:.0f}, disparity {d_min:.0f}..{d_max:.0f} px"
    if u1 <= u0 or v1 <= v0:
        raise TipNotOnThreadError(f"the epipolar band of the left tip ({band}) lies outside the image", view)
    for find in (free_ends, thinned_free_ends):
        ends = find(mask[v0:v1, u0:u1]) + np.array([u0, v0])
        near = (
            (np.abs(ends[:, 1] - v) <= reach)
            & (u - ends[:, 0] >= d_min - reach)
            & (u - ends[:, 0] <= d_max + reach)
        )
        ends = np.array([extend_to_end(mask, e, radius) for e in ends[near]]).reshape(-1, 2)
        dv = np.abs(ends[:, 1] - v)
        disparity = u - ends[:, 0]
        ok = (dv <= tol) & (disparity >= d_min - tol) & (disparity <= d_max + tol)
        if ok.any():
            candidates = ends[ok]
            return candidates[np.argmin(dv[ok] + 1e-3 * np.abs(disparity[ok] - (d_min + d_max) / 2))]
    on_band = mask[
        max(0, int(v - tol)) : int(v + tol) + 1,
        max(0, int(u - d_max - tol)) : max(0, int(u - d_min + tol) + 1),
    ]
    if not on_band.any():
        raise TipNotOnThreadError(
            f"no thread pixel on the left tip's epipolar band ({band}): the tip is hidden in this view "
            "or the pair is not rectified",
            view,
        )
    raise NoFreeEndError(
        f"no free end of a thread on the left tip's epipolar band ({band}): the cut tip is hidden or "
        "touches another thread in this view",
        view,
    )
