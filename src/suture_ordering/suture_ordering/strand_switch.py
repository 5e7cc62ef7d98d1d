# SPDX-License-Identifier: Apache-2.0
"""Where a sequence leaves its thread at a crossing for the other strand.

Two threads cross in an X. Where the segmenter loses a few pixels of our thread just past the
crossing (a faint stretch, a line of tissue texture beside it), the mask shows our arm coming in
and the other strand passing through, and the search, finding no mask straight on, takes the
other strand: it turns at the crossing by about the crossing's angle, and everything after is
another thread. If that happens before the grasp point, the grasp lands on the other thread;
both views usually lose the same stretch, so the stereo pair does not tell.

What does tell is the X itself. Where the sequence turns by more than ``strand_switch_turn``
over one RoI radius Υ on either side (the turn measured between the chords Υ back and Υ on),
look for mask off the sequence in two places: straight on along the way it came, Υ to 1.5 Υ
away within :data:`AHEAD_HALF_ANGLE_DEG` (our thread beyond the stretch the mask lost), and
behind the way it leaves, Υ / 2 to Υ away within :data:`BEHIND_HALF_ANGLE_DEG` (the other
strand's arm on the far side of the crossing). Both present: the sequence arrived on one strand
and left on the other, and :func:`strand_switch_index` gives the point where it turned. A thread's
own bends do not show this: a loop's other pass lies on the sequence itself, and a curve has no
strand passing through it. "Off the sequence" is measured against the thread's width: on a
thread several pixels wide the mask's edge lies that far from the sequence, and the edge of a
loop's own pass would otherwise read as a strand beside it. The check starts past the hook
window (``HOOK_WINDOW`` RoI radii of the sequence), where a hook's arms turn sharply beside each
other.

Units: pixels (u, v); the radius and angles come from the ordering's scaled parameters.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.skipped_loop import thread_width_along

#: Mask straight on counts within this angle (deg) of the way the sequence came.
AHEAD_HALF_ANGLE_DEG = 15.0
#: The other strand's far arm counts within this angle (deg) of the reverse of the way out.
BEHIND_HALF_ANGLE_DEG = 20.0
#: Mask pixels farther than this (px at 640 px width) from the sequence are off it ...
OFF_SEQUENCE_PX = 3.0
#: ... and farther than half the thread's width plus this (px), since a thread's own edge lies
#: half its width from the sequence and the sequence may sit a pixel off the thread's middle.
OFF_EDGE_PX = 1.5
#: The thread's width is measured over the rays' box widened by this much (px).
WIDTH_MARGIN_PX = 12
#: Distances (in RoI radii) at which mask straight on, and the far arm behind, are looked for.
AHEAD_REACH = np.array([1.0, 1.25, 1.5])
BEHIND_REACH = np.array([0.5, 0.75, 1.0])
#: The rays are sampled every this many degrees.
RAY_STEP_DEG = 3.0


def strand_switch_index(
    mask: np.ndarray, sequence: np.ndarray, radius: int, min_turn: float, start: float, scale: float = 1.0
) -> int | None:
    """Index into ``sequence`` where it turns off its thread onto a crossing strand, or None.

    ``mask``: (H, W) the mask the sequence was ordered on, nonzero = thread; ``sequence``:
    (N, 2) float (u, v) from the cut tip, about 1 px apart; ``radius``: Υ (px), the chords'
    length on either side of a point; ``min_turn``: rad, the least turn checked; ``start``: px of
    arc from the tip before which nothing is checked; ``scale``: image width / 640.
    """
    points = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    if radius < 2 or min_turn >= math.pi or len(points) < 2 * radius + 1:
        return None
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))))
    first = max(radius, int(np.searchsorted(arc, start)))
    index = np.arange(first, len(points) - radius)
    if not len(index):
        return None
    came = points[index] - points[index - radius]
    leaves = points[index + radius] - points[index]
    turn = np.abs(
        np.arctan2(came[:, 0] * leaves[:, 1] - came[:, 1] * leaves[:, 0], (came * leaves).sum(axis=1))
    )
    turning = np.flatnonzero(turn >= min_turn)
    if not len(turning):
        return None
    origins = points[index[turning]]
    ahead = _ray_pixels(origins, came[turning], radius * AHEAD_REACH, AHEAD_HALF_ANGLE_DEG)
    behind = _ray_pixels(origins, -leaves[turning], radius * BEHIND_REACH, BEHIND_HALF_ANGLE_DEG)
    rays = np.vstack((ahead.reshape(-1, 2), behind.reshape(-1, 2)))
    clearance = max(OFF_SEQUENCE_PX * scale, 0.5 * _width_round(mask, points, rays) + OFF_EDGE_PX)
    off_sequence, corner = _off_sequence(mask, points, clearance, rays)
    both = np.flatnonzero(_any_on(off_sequence, corner, ahead) & _any_on(off_sequence, corner, behind))
    return int(index[turning[both[0]]]) if len(both) else None


def _ray_pixels(
    origins: np.ndarray, directions: np.ndarray, distances: np.ndarray, half_angle_deg: float
) -> np.ndarray:
    """(K, D * A, 2) int (u, v): the pixels of rays from each of ``origins`` (K, 2) within
    ``half_angle_deg`` of its direction (K, 2), every :data:`RAY_STEP_DEG`, at ``distances`` (D,) px."""
    headings = np.array([math.atan2(float(v), float(u)) for u, v in directions])
    angles = headings[:, None] + np.radians(np.arange(-half_angle_deg, half_angle_deg + 1e-9, RAY_STEP_DEG))
    u = np.round(origins[:, 0, None, None] + distances[None, :, None] * np.cos(angles)[:, None, :])
    v = np.round(origins[:, 1, None, None] + distances[None, :, None] * np.sin(angles)[:, None, :])
    return np.stack((u, v), axis=-1).astype(int).reshape(len(origins), -1, 2)


def _width_round(mask: np.ndarray, points: np.ndarray, pixels: np.ndarray) -> float:
    """The thread's width (px) along the stretch of ``points`` (N, 2) inside the box round
    ``pixels`` (M, 2) int (u, v), widened by :data:`WIDTH_MARGIN_PX` so that the thread's own
    background lies inside it; 0 where the box holds none of the sequence or no background."""
    height, width = mask.shape
    u0, v0 = (int(max(0, pixels[:, k].min() - WIDTH_MARGIN_PX)) for k in (0, 1))
    u1 = int(min(width, pixels[:, 0].max() + WIDTH_MARGIN_PX + 1))
    v1 = int(min(height, pixels[:, 1].max() + WIDTH_MARGIN_PX + 1))
    if u0 >= u1 or v0 >= v1:
        return 0.0
    thread = (np.asarray(mask)[v0:v1, u0:u1] > 0).astype(np.uint8)
    return thread_width_along(thread, points - (u0, v0)) or 0.0


def _off_sequence(
    mask: np.ndarray, points: np.ndarray, clearance: float, pixels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Mask pixels farther than ``clearance`` px from the polyline ``points``, as (h, w) bool over
    the box round ``pixels`` (..., 2) int (u, v) clipped to the image, and that box's first (u, v).
    The distances are measured over the box widened by the clearance and two pixels: a point of the
    polyline outside it lies farther than the clearance from every one of ``pixels``."""
    height, width = mask.shape
    margin = math.ceil(clearance) + 2
    flat = pixels.reshape(-1, 2)
    u0, v0 = (int(max(0, flat[:, k].min() - margin)) for k in (0, 1))
    u1 = int(min(width, flat[:, 0].max() + margin + 1))
    v1 = int(min(height, flat[:, 1].max() + margin + 1))
    if u0 >= u1 or v0 >= v1:
        return np.zeros((0, 0), dtype=bool), np.array([u0, v0])
    not_on = np.ones((height, width), dtype=np.uint8)
    cv2.polylines(not_on, [np.round(points).astype(np.int32)], False, 0, 1)
    distance = cv2.distanceTransform(not_on[v0:v1, u0:u1], cv2.DIST_L2, 3)
    return (np.asarray(mask)[v0:v1, u0:u1] > 0) & (distance > clearance), np.array([u0, v0])


def _any_on(off_sequence: np.ndarray, corner: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(K,) whether any of each row of ``pixels`` (K, S, 2) int (u, v) falls on ``off_sequence``
    (a box whose first pixel is ``corner``); pixels outside it count as off the mask."""
    u, v = pixels[..., 0] - corner[0], pixels[..., 1] - corner[1]
    height, width = off_sequence.shape
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    hit = np.zeros(u.shape, dtype=bool)
    hit[inside] = off_sequence[v[inside], u[inside]]
    return hit.any(axis=1)
