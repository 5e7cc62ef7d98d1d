# SPDX-License-Identifier: Apache-2.0
"""Cut-tip localisation in the left view (from a hint or automatically) and in the right view.

The cut tip is a *free end* of the thread's centreline: an end point (one
8-neighbour) of the mask's skeleton (``skimage.morphology.skeletonize``). Only
a small window is skeletonised when a hint is given, so this costs well under a
millisecond.

* **With a hint** (the paper's manual indication, ``/suture/tip_hint``): the free
  end nearest to the hint within ``tip_radius`` px. No thread pixel within that
  radius: :class:`TipNotOnThreadError`; thread pixels but no free end (a closed
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
  several, the one on the nearest row.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.morphology import skeletonize

from suture_ordering.errors import NoFreeEndError, TipNotOnThreadError, TipOutsideImageError

_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], dtype=np.float32)


def free_ends(mask: np.ndarray) -> np.ndarray:
    """(K, 2) int (u, v) end points of the skeleton of ``mask`` ((H, W) uint8 0/1 or bool)."""
    skeleton = skeletonize(np.asarray(mask, dtype=bool)).astype(np.uint8)
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
    r = int(np.ceil(radius))
    u0, v0 = max(0, int(end[0]) - r), max(0, int(end[1]) - r)
    window = np.asarray(mask[v0 : int(end[1]) + r + 1, u0 : int(end[0]) + r + 1], dtype=np.uint8)
    _, pieces = cv2.connectedComponents(window, connectivity=8)
    own = pieces[int(end[1]) - v0, int(end[0]) - u0]
    if own == 0:  # not on the mask
        return np.asarray(end, dtype=np.float64)
    thread = pieces == own  # not another thread passing through the window
    if axis is None:
        rows, cols = np.nonzero(skeletonize(thread))
        inward = np.column_stack((cols + u0 - end[0], rows + v0 - end[1]))
        inward = inward[np.hypot(inward[:, 0], inward[:, 1]) <= radius]
        axis = -inward.mean(axis=0) if len(inward) else np.zeros(2)
    axis = np.array(axis, dtype=np.float64)
    norm = float(np.hypot(*axis))
    if norm < 1e-6:
        return np.asarray(end, dtype=np.float64)
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
    """The free end of ``mask`` nearest to ``hint`` within ``radius`` px, as (2,) float64 (u, v)."""
    height, width = mask.shape
    u, v = check_hint(hint, width, height, view)
    margin = int(np.ceil(radius)) + 8  # skeleton context beyond the search radius
    u0, u1 = max(0, int(u) - margin), min(width, int(u) + margin + 1)
    v0, v1 = max(0, int(v) - margin), min(height, int(v) + margin + 1)
    window = mask[v0:v1, u0:u1]
    ends = free_ends(window) + np.array([u0, v0])
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
    ``radius`` as in :func:`extend_to_end`.
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
    ends = free_ends(mask[v0:v1, u0:u1]) + np.array([u0, v0])
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
