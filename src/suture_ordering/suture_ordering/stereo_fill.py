# SPDX-License-Identifier: Apache-2.0
"""Stereo help for the ordering: one view's sequence mended from the other view where its own search failed.

A predicted mask often loses a stretch of the thread (low contrast at a
crossing, a specular highlight). Each view's search decides alone whether to
bridge such a gap, and its guards rightly refuse many. When one view stops
there and the other goes on, the reconstruction pairs nothing beyond the stop,
and the thread comes out shorter than the grasp's reserved length: no grasp.
In a rectified pair the view that went on shows where the thread lies in the
stopped one: on the same rows, shifted by the disparity.
:func:`continue_from_other_view` walks the other view's sequence beyond the
point matching the stop, shifts it by the disparity measured where both views
still agree, and keeps the shifted points that this view's own mask confirms,
each moved to the centre of the mask run it lands on, so that the depth there
is measured, not copied. Points without mask support are not kept: the gap
stays a jump, which the reconstruction treats as a hidden stretch.

It adds no thread this view's mask does not show, stops once more than
``max_gap`` px of the other view's path in a row find no mask, and follows the
disparity as it changes along the thread (the thread rises over crossings).
A search that stops at a gap often ends in a short hook (its last steps bent by
the mask's ragged end): up to ``HOOK_SAMPLES`` end points may be given up to
find where the sequence leaves the other view's path (measuring the disparity
before them if the hook's rows bias it), and that path must run on the same way
(not back along a loop's other pass).
It does follow a gap the other view bridged: in most gaps of predicted masks
both views lose the thread at the same place and only one view's search
bridges it. Where the other view bridged to the wrong strand, the result follows
that strand too. A stretch the other view bridged counts towards ``max_gap``
only where this view's mask shows some of it (more than
``SHARED_GAP_MAX_SUPPORT``) or this view's gap begins well before it: an
instrument shaft hides 5-25 mm of thread in both views, often more than
``max_gap``, and the other view's bridge has passed the checks of a bridge
across an occluder (:mod:`suture_ordering.occluders`).

:func:`splice_skipped_stretch` mends the other way one view's search can go
wrong where the other's did not: at its own crossing a thread runs straight on
into its loop, and where the mask has a gap near the crossing a search can take
the other arm and skip the loop. Both sequences then end at the same place, one
much shorter; the loop is put back from the other view where this view's mask
shows it, and only a loop: a stretch most of whose points lie on thread passed already (the
other view went out along a strand and back, or round a loop twice) is not put back.

Shapes and units: sequences (N, 2) float64 (u, v) in pixels from the cut tip;
masks (H, W), nonzero = thread; disparity d = u_left - u_right > 0.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from suture_ordering.geometry import revisited
from suture_ordering.not_seen import flagged_runs

#: Longest step (px) of the guiding sequence that counts as following the thread (searches
#: sample the centreline about 1 px apart; a longer step jumps over an unseen stretch).
GUIDE_MAX_STEP_PX = 3.0
#: Samples at the end of a stopped sequence (or the start of one that skipped a loop) that
#: measure the disparity to the other view.
DISPARITY_SAMPLES = 80
#: How fast the carried disparity follows the snapped points (fraction per sample).
DISPARITY_FOLLOW = 0.2
#: A stretch put back may pass this share of its points over thread already passed (by this
#: view's sequence, or by the stretch itself farther along): a loop comes back only at its
#: crossing; more is the other view going out and back along a strand, or round a loop twice.
MAX_RETRACED = 0.5
#: Samples at the end of a stopped sequence that may be dropped to find where it leaves the other
#: view's path: a search that stops at a gap often ends in a short hook (its last steps bent by
#: the mask's ragged end), several px off that path.
HOOK_SAMPLES = 12
#: Largest share of a stretch the other view bridged that this view's mask may show for the gap
#: to count as one both views have (an occluder); more, and the other view bridged a faint
#: stretch that this view partly sees.
SHARED_GAP_MAX_SUPPORT = 0.1
#: This view's gap must begin at most this fraction of ``max_gap`` before the other view's
#: bridged stretch does for the two to be the same gap (a shaft's edge lies a few px apart in
#: the two views: it is nearer than the thread, so its disparity is larger).
SHARED_GAP_LEAD = 1.0 / 3.0


def arc_length(points: np.ndarray) -> np.ndarray:
    """(N,) cumulative length (px) along an (N, 2) polyline, 0 at its first point."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def row_disparities(
    points: np.ndarray,
    point_arc: np.ndarray,
    guide: np.ndarray,
    sign: float,
    d_range: tuple[float, float],
    min_angle: float,
) -> np.ndarray:
    """Disparity (px) of each of ``points`` to the ``guide`` polyline on its row; NaN where none.

    ``points`` (N, 2) lie at arc lengths ``point_arc`` (N,) from the tip. A row counts where
    the guide crosses it within ``d_range`` and at least ``min_angle`` (rad) steep; of several
    such crossings the one nearest in arc length is taken (both views' arc lengths from the
    tip differ by little more than the change of disparity).
    """
    guide_arc = arc_length(guide)[:-1]
    start, stop = guide[:-1], guide[1:]
    low, high = points[:, 1].min(), points[:, 1].max()
    near_rows = (np.maximum(start[:, 1], stop[:, 1]) >= low) & (np.minimum(start[:, 1], stop[:, 1]) <= high)
    start, stop, guide_arc = start[near_rows], stop[near_rows], guide_arc[near_rows]
    if not len(start):
        return np.full(len(points), np.nan)
    rise = stop[:, 1] - start[:, 1]
    length = np.linalg.norm(stop - start, axis=1)
    steep = np.abs(rise) >= np.sin(min_angle) * np.maximum(length, 1e-9)
    along = (points[:, 1:2] - start[:, 1]) / np.where(rise == 0, np.nan, rise)
    u_cross = start[:, 0] + along * (stop[:, 0] - start[:, 0])
    disparity = sign * (u_cross - points[:, 0:1])
    usable = (along >= 0) & (along <= 1) & steep & (disparity >= d_range[0]) & (disparity <= d_range[1])
    arc_gap = np.where(usable, np.abs(guide_arc - point_arc[:, None]), np.inf)
    nearest = np.argmin(arc_gap, axis=1)
    rows = np.arange(len(points))
    return np.where(usable[rows, nearest], disparity[rows, nearest], np.nan)


def _disparity_over(
    own: np.ndarray,
    part: slice,
    guide: np.ndarray,
    sign: float,
    d_range: tuple[float, float],
    min_angle: float,
    recent: int | None = None,
) -> float | None:
    """Median disparity (px) of ``own[part]`` to ``guide`` over its well-conditioned rows (the last
    ``recent`` of them if given), or None where fewer than 5 rows measure it."""
    measured = row_disparities(own[part], arc_length(own)[part], guide, sign, d_range, min_angle)
    measured = measured[np.isfinite(measured)]
    if measured.size < 5:
        return None
    return float(np.median(measured if recent is None else measured[-recent:]))


def snap_to_mask_runs(mask: np.ndarray, points: np.ndarray, radius: float, max_run: float) -> np.ndarray:
    """(N,) column of the mask run nearest each (u, v) of ``points`` on its row; NaN if none is
    within ``radius`` px.

    A short run (at most ``max_run`` px: the thread crosses the row) gives its centre; a longer
    one (the thread runs along the row) says nothing about the column, which is then ``u``
    clipped to the run.
    """
    height, width = mask.shape
    reach = int(np.ceil(radius + max_run)) + 1
    offsets = np.arange(-reach, reach + 1)
    rows = np.rint(points[:, 1]).astype(int)[:, None]
    cols = np.rint(points[:, 0]).astype(int)[:, None] + offsets
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    on = np.zeros(cols.shape, dtype=bool)
    on[inside] = mask[np.broadcast_to(rows, cols.shape)[inside], cols[inside]] > 0
    u = points[:, 0:1]
    distance = np.where(on, np.abs(cols - u), np.inf)
    nearest = np.argmin(distance, axis=1)
    found = distance[np.arange(len(points)), nearest] <= radius
    # Run around the nearest on-pixel: last off-pixel before it and first one after it.
    position = np.broadcast_to(np.arange(cols.shape[1]), cols.shape)
    last_off = np.maximum.accumulate(np.where(on, -1, position), axis=1)
    next_off = np.minimum.accumulate(np.where(on, cols.shape[1], position)[:, ::-1], axis=1)[:, ::-1]
    rows_index = np.arange(len(points))
    run_start = cols[rows_index, 0] + last_off[rows_index, nearest] + 1
    run_end = cols[rows_index, 0] + next_off[rows_index, nearest] - 1
    centre = np.where(
        run_end - run_start + 1 > max_run,
        np.clip(points[:, 0], run_start, run_end),
        0.5 * (run_start + run_end),
    )
    return np.where(found, centre, np.nan)


def continue_from_other_view(
    own: np.ndarray,
    own_mask: np.ndarray,
    guide: np.ndarray,
    sign: float,
    d_range: tuple[float, float],
    *,
    snap_radius: float = 2.0,
    max_run: float = 6.0,
    max_gap: float = 60.0,
    min_resume: int = 10,
    min_angle: float = np.radians(10.0),
    guide_not_seen: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """``own`` continued along ``guide``, the other view's sequence, and the number of points added.

    Parameters
    ----------
    own : (N, 2) float64
        This view's visible sequence from the cut tip (its search stopped).
    own_mask : (H, W) uint8 or bool
        This view's mask, nonzero = thread.
    guide : (M, 2) float64
        The other view's ordered points from the cut tip, about 1 px apart, gaps it bridged
        included.
    sign : float
        +1 if this view is the right one (u_own = u_guide - d), -1 if it is the left one.
    d_range : (2,) float
        Disparity limits (px) of the working depth range.
    snap_radius, max_run : float
        A shifted point is kept where a mask run of its row lies within ``snap_radius`` px
        (see :func:`snap_to_mask_runs` for ``max_run``).
    max_gap : float
        The walk ends after this many px of guide in a row without mask support, not counting
        a gap both views have (see ``guide_not_seen``).
    min_resume : int
        Supported points found after a gap count only as a run of at least this many.
    min_angle : float
        Rows crossing the guide flatter than this (rad) do not measure the disparity.
    guide_not_seen : (M,) bool, optional
        The guide's points that its view bridged across a gap (an occluder it crossed). Such a
        stretch does not count towards ``max_gap`` where this view's mask shows at most
        ``SHARED_GAP_MAX_SUPPORT`` of it and this view's gap began at most ``SHARED_GAP_LEAD``
        x ``max_gap`` px before it: both views lose the thread at the same occluder, which may
        be wider than ``max_gap``, and the other view's checks of the bridge stand for this one.

    Returns
    -------
    sequence : (N', 2) float64
        ``own`` (without its end hook, up to ``HOOK_SAMPLES`` points that leave the guide by
        more than ``snap_radius`` + 1 px, where a continuation was found) followed by the
        continuation; ``own`` itself when there is none. A jump separates the two where this
        view's mask has its gap.
    added : int
        Points of the continuation.
    """
    if len(own) < min_resume or len(guide) < min_resume:
        return own, 0
    # The disparity from this view's last rows; where that finds no way on, from the rows
    # before its last HOOK_SAMPLES points (an end hook's own rows bias it).
    hooked = max(min_resume, len(own) - HOOK_SAMPLES)
    for stop in dict.fromkeys((len(own), hooked)):  # one pass when own is too short for a hook
        tail = slice(max(0, stop - DISPARITY_SAMPLES), stop)
        disparity = _disparity_over(own, tail, guide, sign, d_range, min_angle, recent=15)
        if disparity is None:
            continue
        shift = np.array([sign * disparity, 0.0])
        for end in range(len(own), hooked - 1, -1):  # own's last point on the shifted guide
            distance = np.linalg.norm(guide - (own[end - 1] + shift), axis=1)
            matched = int(np.argmin(distance))
            if distance[matched] <= snap_radius + 1.0 and _same_way(own, end, guide, matched):
                break
        else:
            continue
        not_seen = np.zeros(len(guide), dtype=bool) if guide_not_seen is None else guide_not_seen
        kept = _follow(
            own_mask,
            guide[matched:],
            not_seen[matched:],
            sign,
            disparity,
            snap_radius,
            max_run,
            max_gap,
            min_resume,
        )
        if len(kept) >= min_resume:
            return np.vstack([own[:end], kept]), len(kept)
    return own, 0


def _same_way(own: np.ndarray, end: int, guide: np.ndarray, matched: int, reach: int = 8) -> bool:
    """Whether ``own`` arriving at ``own[end - 1]`` and ``guide`` leaving ``guide[matched]`` run the
    same way (within 60 deg): where the guide passes a place twice (a loop), the pass running
    back towards the tip is not a way on."""
    arriving = own[end - 1] - own[max(0, end - 1 - reach)]
    leaving = guide[min(len(guide) - 1, matched + reach)] - guide[matched]
    norms = np.linalg.norm(arriving) * np.linalg.norm(leaving)
    return bool(norms > 0 and arriving @ leaving >= 0.5 * norms)


def _follow(
    own_mask: np.ndarray,
    guide: np.ndarray,
    guide_not_seen: np.ndarray,
    sign: float,
    disparity: float,
    snap_radius: float,
    max_run: float,
    max_gap: float,
    min_resume: int,
) -> np.ndarray:
    """(K, 2) points of ``own_mask`` along ``guide[1:]`` shifted by the (followed) disparity;
    parameters as in :func:`continue_from_other_view`."""
    steps = np.linalg.norm(np.diff(guide, axis=0), axis=1)
    followed = np.flatnonzero(steps > GUIDE_MAX_STEP_PX)
    ahead = guide[1 : 1 + (followed[0] if followed.size else len(steps))]
    if len(ahead) < min_resume:
        return np.empty((0, 2))
    shift = np.array([sign * disparity, 0.0])
    snapped = snap_to_mask_runs(own_mask, ahead - shift, snap_radius + 2.0, max_run)
    walked = np.cumsum(steps[: len(ahead)])
    # Where a shared gap (a stretch the guide bridged, this view's mask missing there too)
    # begins, for each of its points (inf elsewhere).
    shared_from = np.full(len(ahead), np.inf)
    supported = np.abs(snapped - ahead[:, 0] + shift[0]) <= snap_radius
    for start, stop in flagged_runs(guide_not_seen[1 : 1 + len(ahead)]):
        if supported[start:stop].mean() <= SHARED_GAP_MAX_SUPPORT:
            shared_from[start:stop] = walked[start]

    kept: list[tuple[float, float]] = []
    run: list[tuple[float, float]] = []
    gap_start = None
    exempt = 0.0  # px of the current gap that lie in a shared gap it ran into
    for k in range(len(ahead)):  # one pass along the guide, following the disparity
        column = ahead[k, 0] - sign * disparity
        if np.isnan(snapped[k]) or abs(snapped[k] - column) > snap_radius:
            if gap_start is None:
                gap_start, exempt = walked[k], 0.0
                if len(run) >= min_resume or not kept:
                    kept.extend(run)
                run = []
            elif shared_from[k] - gap_start <= SHARED_GAP_LEAD * max_gap:
                exempt += steps[k]
            if walked[k] - gap_start - exempt > max_gap:
                break
            continue
        gap_start = None
        run.append((float(snapped[k]), float(ahead[k, 1])))
        disparity += DISPARITY_FOLLOW * (sign * (ahead[k, 0] - snapped[k]) - disparity)
    if len(run) >= min_resume:
        kept.extend(run)
    return np.array(kept).reshape(-1, 2)


def splice_skipped_stretch(
    own: np.ndarray,
    own_mask: np.ndarray,
    guide: np.ndarray,
    sign: float,
    d_range: tuple[float, float],
    *,
    max_ratio: float = 0.85,
    window: int = 12,
    max_distance: float = 3.0,
    min_skip: int = 40,
    min_support: float = 0.6,
    snap_radius: float = 2.0,
    max_run: float = 6.0,
    min_angle: float = np.radians(10.0),
) -> tuple[np.ndarray, int]:
    """``own`` with the stretch of ``guide`` it skipped put back, and the number of points put back.

    At its own crossing a thread runs straight on into its loop; where the segmenter left a
    gap near the crossing, one view's search can take the other arm and skip the loop, while
    the other view goes round it. Both sequences then end at the same place, one much shorter.
    ``own`` (N, 2), at most ``max_ratio`` of the ``guide``'s (M, 2) length, is walked from the
    tip against the guide shifted by the disparity (measured on the first rows, then followed):
    each point must match a guide point within ``max_distance`` px among the next ``window``;
    where none does but one at least ``min_skip`` samples further on does, ``own`` skipped the
    guide's stretch in between. It is put back, snapped to this view's mask like
    :func:`continue_from_other_view` does, only if at least ``min_support`` of it lies on the
    mask (the loop is there, the search only missed it) and at most :data:`MAX_RETRACED` of it
    passes thread passed already (:func:`_retraced_share`, within ``snap_radius``); otherwise
    ``own`` is returned as it is.
    ``sign``, ``d_range``, ``snap_radius``, ``max_run``, ``min_angle`` as there.
    """
    if len(own) < 20 or len(guide) < 20 or arc_length(own)[-1] > max_ratio * arc_length(guide)[-1]:
        return own, 0
    disparity = _disparity_over(own, slice(0, DISPARITY_SAMPLES), guide, sign, d_range, min_angle)
    if disparity is None:
        return own, 0
    matched = 0
    for i in range(len(own)):  # one pass along the shorter sequence (it is rare: see max_ratio)
        target = own[i] + np.array([sign * disparity, 0.0])
        near = guide[matched : matched + window]
        distance = np.linalg.norm(near - target, axis=1)
        nearest = int(np.argmin(distance))
        if distance[nearest] <= max_distance:
            matched += nearest
            if abs(guide[matched, 1] - own[i, 1]) < 0.5:  # same row: the disparity is measured here
                disparity += DISPARITY_FOLLOW * (sign * (guide[matched, 0] - own[i, 0]) - disparity)
            continue
        distance = np.linalg.norm(guide[matched:] - target, axis=1)
        found = int(np.argmin(distance))
        if distance[found] > max_distance:
            return own, 0
        if found < min_skip:
            matched += found
            continue
        shift = np.array([sign * disparity, 0.0])
        stretch = guide[matched + 1 : matched + found]
        snapped = snap_to_mask_runs(own_mask, stretch - shift, snap_radius, max_run)
        on_mask = np.isfinite(snapped)
        if on_mask.mean() < min_support:
            return own, 0
        inserted = np.column_stack([snapped[on_mask], stretch[on_mask, 1]])
        # Near the crossing both passes match, so the loss of track comes a few points late or
        # early: the stretch replaces the points between those nearest its two ends.
        before = max(0, i - window)
        first = before + int(np.argmin(np.linalg.norm(own[before : i + 1] - inserted[0], axis=1)))
        last = i + int(np.argmin(np.linalg.norm(own[i : i + window] - inserted[-1], axis=1)))
        kept = np.vstack([own[:first], own[last + 1 :]])
        if _retraced_share(inserted, kept, snap_radius) > MAX_RETRACED:
            return own, 0
        return np.vstack([own[:first], inserted, own[last + 1 :]]), len(inserted)
    return own, 0


def _retraced_share(stretch: np.ndarray, kept: np.ndarray, radius: float) -> float:
    """The share of ``stretch``'s points ((K, 2) px) within ``radius`` px of a point of ``kept``
    ((M, 2)) or of a point of the stretch more than ``4 * radius`` px of its arc away."""
    if len(stretch) == 0:
        return 0.0
    passed = revisited(stretch, radius, 4 * radius)
    if len(kept):
        distance, _ = cKDTree(kept).query(stretch, distance_upper_bound=radius)
        passed |= np.isfinite(distance)
    return float(passed.mean())
