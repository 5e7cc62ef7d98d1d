# SPDX-License-Identifier: Apache-2.0
"""Where a sequence passed by a loop that the mask shows.

A thread that loops crosses itself. Where the segmenter breaks the loop next to its crossing (a
faint stretch of a pale thread), the search arrives at the crossing, finds the thread straight on
(the loop's way out) and goes on: the sequence passes the loop by. The grasp point is placed a
fixed arc from the cut tip, so a grasp beyond the loop lands the loop's arc too far along the
thread (25-32 mm on the simulated loops looked at); both views usually break the same loop, so the stereo pair
does not tell.

What tells is the loop itself, in the mask the ordering read (its low mask, where there is one):
thread off the sequence's corridor (farther than the thread's half width plus
:data:`CORRIDOR_MARGIN_PX` from it) that joins the corridor and is much longer than the part of
the sequence it stands beside. Two shapes count:

- a *detour*: mask joined to the corridor at two places along the sequence, at least
  :data:`DETOUR_RATIO` times as long as the sequence's arc between them plus
  :data:`DETOUR_EXTRA_PX`;
- a *ring*: mask joined at one place and not cut by the image border, either at least
  :data:`RING_LENGTH_RATIO` times as long as it reaches away from the sequence (and at least
  :data:`RING_MIN_LENGTH_PX`; another strand that crosses the thread leaves it in a line: as
  long as it reaches), or leaving the thread and coming back to the same place: its skeleton at
  least :data:`RING_MIN_LENGTH_PX` long with all its ends within :data:`DETACHED_GAP_WIDTHS`
  thread widths of the corridor, beside a stretch of sequence (where it joins and where its ends
  lie) shorter than its reach (a loop that leaves the thread at a small angle, the arc beside
  the sequence inside the corridor; a hook or a strand ends away from the thread, thread beside
  the sequence lies along a longer stretch than it reaches, and another strand crossing twice
  comes back far along).

A loop the mask broke on both sides of its crossing does not join the corridor. Such a piece
counts as joined where its two ends come within :data:`DETACHED_GAP_WIDTHS` thread widths of the
corridor, when nothing else of it does (another thread running beside the sequence comes near it
all along, not at two ends), and is then a ring or a detour as above; its reach is measured from
its own ends near the corridor (the gap to the sequence is what the mask lost). Where the loop's
other end stops farther off (the mask lost more of it on that side), the piece comes near at one
place only and counts as a ring from there, unless the stretch of sequence it comes near is
longer than the piece reaches away from it (thread beside the sequence that then turns away).
Where the mask lost more round the crossing, both ends farther off than that, the piece counts
as a ring when it is nearly closed: its skeleton's two ends no farther apart than
:data:`CLOSED_CHORD_RATIO` of its length and both within :data:`CLOSED_GAP_PX` of the corridor
(another thread's arc is open; a ring of something else lies farther off).

Where the segmenter lost the thread round the loop as well (a pale loop on a highlight), the
ordering bridges the gap straight across and what is left of the loop lies beside the bridge, too
far from the corridor to count as joined. A piece apart from the corridor counts, whatever its
shape, where it is as long as a ring must be (:data:`RING_MIN_LENGTH_PX`; an instrument's edge
that the segmenter took for thread leaves shorter slivers), every pixel of it lies nearest to one
stretch the sequence bridged (its not-seen samples) and no farther from it than half that
stretch's length: thread the bridge went past. The sequence is then cut where that bridge starts.

A piece's length is its area over the thread's width. :func:`skipped_loop_index` gives the
sequence's index where the first such piece joins it; ``order_stereo`` cuts the view's sequence
there (``StereoOrdering.cut``), so that the 3D stage refuses a grasp beyond it as on a thread too
short, and keeps a grasp before it. Loops the segmenter lost whole leave nothing to see.

Units: pixels (u, v); the lengths below are at 640 px image width and scale with it.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree
from skimage.morphology import skeletonize

from suture_ordering.geometry import LINE_SHIFT
from suture_ordering.not_seen import flagged_runs
from suture_ordering.tip import end_pixels

#: Mask pixels farther than the thread's half width plus this (px) from the sequence are off it.
CORRIDOR_MARGIN_PX = 1.5
#: Where a piece's joins to the corridor lie more than this many thread widths (plus 4 px) of
#: sequence apart, it joins it at two places.
JOIN_GAP_WIDTHS = 1.5
#: The thread is taken to be at least this wide (px).
MIN_WIDTH_PX = 2.0
#: Pieces of mask off the corridor smaller than this (px² at 640 px width) are left alone.
MIN_AREA_PX = 30.0
#: A detour counts when it is at least this many times longer than the sequence beside it ...
DETOUR_RATIO = 2.0
#: ... plus this many px.
DETOUR_EXTRA_PX = 12.0
#: A ring counts when it is at least this long (px) ...
RING_MIN_LENGTH_PX = 32.0
#: ... and at least this many times as long as it reaches away from where it joins the sequence.
RING_LENGTH_RATIO = 2.2
#: A ring that does not join the corridor counts when both its ends come this many thread widths
#: near it (a crossing's gap in the mask: the other strand's width and a little more).
DETACHED_GAP_WIDTHS = 2.5
#: A ring apart from the corridor, its ends farther off, counts when its two ends are no farther
#: apart than this share of its length (a nearly closed ring: the mask lost its crossing) ...
CLOSED_CHORD_RATIO = 0.3
#: ... and both lie within this (px) of the corridor (what a segmenter loses round a crossing).
CLOSED_GAP_PX = 20.0


def skipped_loop_index(
    mask: np.ndarray, sequence: np.ndarray, scale: float = 1.0, not_seen: np.ndarray | None = None
) -> int | None:
    """Index into ``sequence`` where it first passes by a loop or detour of ``mask``, or None.

    ``mask``: (H, W) the mask the sequence was ordered on, nonzero = thread; ``sequence``:
    (N, 2) float (u, v) from the cut tip, about 1 px apart; ``scale``: image width / 640;
    ``not_seen``: (N,) bool, the samples the ordering bridged (None: all seen).
    """
    points = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    thread = (np.asarray(mask) > 0).astype(np.uint8)
    if len(points) < 10:
        return None
    min_area = MIN_AREA_PX * scale**2
    # The corridor of the narrowest thread leaves the most mask off it: too little there, none.
    if np.count_nonzero(thread & (1 - _corridor(thread.shape, points, MIN_WIDTH_PX, scale))) < min_area:
        return None
    width = thread_width_along(thread, points)
    if width is None:  # no background around the sequence: no thread to tell a loop in
        return None
    corridor = _corridor(thread.shape, points, width, scale)
    off = thread & (1 - corridor)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(off, connectivity=8)
    large = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_area) + 1
    if large.size == 0:
        return None
    touching = cv2.dilate(corridor, np.ones((3, 3), np.uint8)) > 0
    away: np.ndarray | None = None  # each pixel's distance from the corridor (px), once a piece needs it
    near_px = DETACHED_GAP_WIDTHS * width
    bridges = [] if not_seen is None else flagged_runs(not_seen)
    bridge_of = np.full(len(points), -1)  # each sample's bridged run, -1 where seen
    for number, (start, stop) in enumerate(bridges):
        bridge_of[start:stop] = number
    tree = cKDTree(points)
    height, image_width = thread.shape
    first: int | None = None
    for label in large.tolist():
        left, top, box_width, box_height, area = stats[label]
        box = (slice(top, top + box_height), slice(left, left + box_width))
        piece = labels[box] == label
        rows, cols = np.nonzero(piece & touching[box])
        detached = rows.size == 0
        end_count = 0  # of a detached piece: its parts near the corridor
        length = area / width
        if detached and bridges and length >= RING_MIN_LENGTH_PX * scale:
            at = _beside_bridge(piece, left, top, tree, bridges, bridge_of)
            if at is not None:
                first = at if first is None else min(first, at)
                continue
        if detached:
            if away is None:
                away = cv2.distanceTransform(1 - corridor, cv2.DIST_L2, 3)
            ends = (piece & (away[box] <= near_px)).astype(np.uint8)
            end_count = cv2.connectedComponents(ends, connectivity=8)[0] - 1
            if end_count == 0 and length >= RING_MIN_LENGTH_PX * scale:
                at = _closed_ring(
                    piece, (left, top), away[box], tree, RING_MIN_LENGTH_PX * scale, CLOSED_GAP_PX * scale
                )
                if at is not None:
                    first = at if first is None else min(first, at)
                continue
            if end_count not in (1, 2):
                continue
            rows, cols = np.nonzero(ends)
        _, joined = tree.query(np.column_stack((cols + left, rows + top)).astype(np.float64))
        joined = np.sort(joined)
        # points about 1 px apart: index differences are px of sequence (a jump counts as one)
        clusters = np.split(joined, np.flatnonzero(np.diff(joined) > JOIN_GAP_WIDTHS * width + 4 * scale) + 1)
        one_end_near = detached and end_count == 1
        if one_end_near and len(clusters) >= 2:
            continue
        if len(clusters) >= 2:
            beside = clusters[-1][0] - clusters[0][-1]
            if length < DETOUR_RATIO * beside + DETOUR_EXTRA_PX * scale:
                continue
        else:
            at_border = (
                left <= 1 or top <= 1 or left + box_width >= image_width - 1 or top + box_height >= height - 1
            )
            origin = np.column_stack((cols + left, rows + top)) if detached else points[clusters[0]]
            piece_rows, piece_cols = np.nonzero(piece)
            pixels = np.column_stack((piece_cols + left, piece_rows + top)).astype(np.float64)
            reach = float(cKDTree(origin).query(pixels)[0].max())
            beside = joined[-1] - joined[0] > reach  # near a longer stretch than it reaches away
            if at_border or (one_end_near and beside):
                continue
            if length < max(RING_MIN_LENGTH_PX * scale, RING_LENGTH_RATIO * reach):
                if away is None:
                    away = cv2.distanceTransform(1 - corridor, cv2.DIST_L2, 3)
                if not _comes_back(
                    piece, (left, top), away[box] <= near_px, tree, joined, reach, RING_MIN_LENGTH_PX * scale
                ):
                    continue
        index = int(clusters[0][0])
        first = index if first is None else min(first, index)
    return first


def _closed_ring(
    piece: np.ndarray, corner: tuple[int, int], away: np.ndarray, tree: cKDTree, min_length: float, gap: float
) -> int | None:
    """Where a nearly closed ring apart from the corridor opens towards the sequence: the index
    nearest the middle of its opening, when ``piece`` (bool box whose first pixel is ``corner``)
    has a skeleton at least ``min_length`` px long with two ends no farther apart than
    :data:`CLOSED_CHORD_RATIO` of its length, both within ``gap`` px of the corridor (``away``,
    each pixel's distance from it, the same box); else None."""
    if away[piece].min() > gap:  # its ends cannot be nearer; skips the skeleton of far threads
        return None
    skeleton = skeletonize(piece)
    length = np.count_nonzero(skeleton)
    if length < min_length:
        return None
    ends = end_pixels(skeleton)  # (u, v) in the box
    if len(ends) != 2:
        return None
    chord = float(np.hypot(*(ends[0] - ends[1])))
    if chord > CLOSED_CHORD_RATIO * length or away[ends[:, 1], ends[:, 0]].max() > gap:
        return None
    return int(tree.query(ends.mean(axis=0) + corner)[1])


def _comes_back(
    piece: np.ndarray,
    corner: tuple[int, int],
    near: np.ndarray,
    tree: cKDTree,
    joined: np.ndarray,
    reach: float,
    min_length: float,
) -> bool:
    """Whether ``piece`` (bool box whose first pixel is ``corner``, (u, v)) leaves the thread and
    comes back to where it left: its skeleton is at least ``min_length`` px long, every end of it
    lies on ``near`` (bool box), and the stretch of the sequence (``tree`` over its points) from
    the ``joined`` indices to those nearest its ends is no longer than the piece's ``reach``
    (px) away from it; a closed ring has no ends."""
    skeleton = skeletonize(piece)
    if np.count_nonzero(skeleton) < min_length:
        return False
    ends = end_pixels(skeleton)  # (u, v) in the box
    if not near[ends[:, 1], ends[:, 0]].all():
        return False
    _, nearest = tree.query((ends + corner).astype(np.float64))
    indices = np.concatenate((joined, np.atleast_1d(nearest)))
    return bool(indices.max() - indices.min() <= reach)


def _beside_bridge(
    piece: np.ndarray,
    left: int,
    top: int,
    tree: cKDTree,
    bridges: list[tuple[int, int]],
    bridge_of: np.ndarray,
) -> int | None:
    """Where a piece of mask apart from the corridor lies beside a stretch the sequence bridged:
    the start of that bridged run when every pixel of ``piece`` (a bool box at column ``left``,
    row ``top``) is nearest to a sample of it (``tree`` over the sequence's points; ``bridges``:
    the (start, stop) runs of not-seen samples, ``bridge_of`` (N,) each sample's run, -1 where
    seen) and no farther from it than half the run's length; else None."""
    rows, cols = np.nonzero(piece)
    distance, nearest = tree.query(np.column_stack((cols + left, rows + top)).astype(np.float64))
    runs = bridge_of[nearest]
    if runs.min() < 0 or runs.min() != runs.max():
        return None
    start, stop = bridges[int(runs[0])]
    if distance.max() > 0.5 * (stop - start):
        return None
    return start


def _corridor(shape: tuple[int, int], points: np.ndarray, width: float, scale: float) -> np.ndarray:
    """(H, W) uint8 1 within the corridor of ``points`` for a thread ``width`` px wide."""
    corridor = np.zeros(shape, dtype=np.uint8)
    thickness = max(1, int(width + 2 * CORRIDOR_MARGIN_PX * scale))
    polyline = np.rint(points * (1 << LINE_SHIFT)).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(corridor, [polyline], False, 1, thickness, cv2.LINE_8, LINE_SHIFT)
    return corridor


def thread_width_along(thread: np.ndarray, points: np.ndarray) -> float | None:
    """The thread's width (px): twice the median distance to the background at the sequence's
    points (the 3x3 distance transform), at least :data:`MIN_WIDTH_PX`; None where the mask
    has no background."""
    height, width = thread.shape
    cells = np.rint(points).astype(int)
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < width) & (cells[:, 1] >= 0) & (cells[:, 1] < height)
    if not inside.any():
        return MIN_WIDTH_PX
    if thread.all():
        return None
    depth = cv2.distanceTransform(thread, cv2.DIST_L2, 3)
    return max(MIN_WIDTH_PX, 2.0 * float(np.median(depth[cells[inside, 1], cells[inside, 0]])))
