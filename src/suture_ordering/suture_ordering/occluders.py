# SPDX-License-Identifier: Apache-2.0
"""Continuing across an occluder: a gap in the mask wider than τ_O (an instrument shaft lying
across the thread) where the thread goes on beyond with a consistent direction and curvature.

Where the search finds nothing more (no admissible node up to τ_O, no way out of a loop), the
thread's end is extrapolated: its direction t0 and curvature κ are fitted over the last
``FIT_STEPS`` x r_s px of the path, or over all of a shorter one (the direction alone, straight
on, over less than half that, but at least ``MIN_FIT_STEPS`` x r_s). The undetected mask beyond,
up to ``occluder_reach_px``, is searched in a cone around the arcs that continue the end:
between the straight line and the arc of curvature κ (whose chord of length d turns by κ d / 2
from the tangent; a bend may straighten under the occluder), widened by ``bridge_bend_max`` on
either side. Each piece of mask met there (a connected component clear of the path traversed,
nearest first) is entered at its point nearest to the end, moved to the middle of its
cross-section, and taken only if it passes the checks of a bridged gap
(:func:`suture_ordering.bridging.gap_exit`): the thread must *start* there facing the gap, turn
by less than ``bridge_turn_max`` from the chord, and leave it so that the turns into and out of
the chord differ by less than ``occluder_bend_max`` (one and two steps beyond; wider than
``bridge_bend_max``, since a thread hidden over tens of px may bend one way and then the other).
Such an S (a difference of ``bridge_bend_max`` or more) is taken only where its first half is
the bend the end already had: the chord within ``S_BEND_SLACK`` of the predicted arcs. Pieces
within τ_O / 2 of the end are the search's own business (gaps it bridges or refused), except
where the search stopped at a junction because every arm there turns sharply onto another strand
(:data:`suture_ordering.junctions.STOP`): it never looked past that strand, and a segmenter often
loses the lower strand for a few pixels beside the upper one, so there pieces farther than r_s
are tried too. A strand crossing the way fails these checks, and so does one that starts
beside the line of a thread ending straight; the search then ends as before: stopping is safer
than a bridge onto another strand. The bridged stretch is a cubic Hermite curve along both
tangents, flagged as not seen (:func:`suture_ordering.path.advance`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import cv2
import numpy as np

from suture_ordering.bridging import gap_exit
from suture_ordering.context import SearchContext
from suture_ordering.geometry import signed_angle
from suture_ordering.nodes import Candidates
from suture_ordering.params import OrderingParams
from suture_ordering.path import Branch, thread_width

#: The end's direction and curvature are fitted over this many step radii of the path.
FIT_STEPS = 6
#: Less thread than this many step radii before the gap is not extrapolated.
MIN_FIT_STEPS = 1.5
#: Largest curvature (1/px, at 640 px width) the extrapolation follows: a fit over a few tens of
#: px on a pixel-traced centreline cannot tell tighter bends from noise.
MAX_CURVATURE = 1.0 / 60.0
#: An S-shaped connection's chord may deviate this much (rad) from the arcs the end predicts.
S_BEND_SLACK = math.radians(5.0)
#: Pieces of mask beyond the gap tried, nearest first.
MAX_PIECES = 4


def end_direction(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Unit tangent and signed curvature (1/px) at the last of ``points`` (k, 2), from a
    quadratic in arc length fitted to them; None for fewer than 5 points or no length."""
    if len(points) < 5:
        return None
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))))
    if arc[-1] <= 0:
        return None
    s = arc - arc[-1]
    coefficients = np.polyfit(s, points, 2)  # (3, 2): a s^2 + b s + c per coordinate
    first, second = coefficients[1], 2 * coefficients[0]
    speed = float(np.hypot(*first))
    if speed <= 0:
        return None
    curvature = (first[0] * second[1] - first[1] * second[0]) / speed**3
    return first / speed, float(curvature)


def _path_back(branch: Branch, length: float) -> tuple[np.ndarray, np.ndarray]:
    """The path's last points ((M, 2), a tail of the traversed path, or all of it) and the arc
    length back from its end to each earlier point ((M - 1,), cumulative): a tail whose arc
    reaches ``length`` (only that much is fitted), else the whole path."""
    taken = 0
    for first in range(len(branch.segments) - 1, -1, -1):
        taken += len(branch.segments[first])
        if taken > length + 1:  # then the arc back may reach ``length``: check it
            tail = np.vstack(branch.segments[first:])
            arc_back = np.cumsum(np.hypot(*np.diff(tail[::-1], axis=0).T))
            if arc_back[-1] >= length:
                return tail, arc_back
            break  # points closer than 1 px: the whole path
    path = np.vstack([branch.vertices[0], *branch.segments])
    return path, np.cumsum(np.hypot(*np.diff(path[::-1], axis=0).T))


def across_occluder(context: SearchContext, branch: Branch, on_strand: bool) -> Candidates | None:
    """The step across a wide gap beyond the end of the search (see the module docstring): the
    one candidate, or None (the thread ends here). With a candidate, ``branch``'s track is set
    to the fitted end tangent, along which the bridge's Hermite curve leaves (the last chords'
    turn measures it less well). ``on_strand``: the search stopped at a junction that turns only
    sharply onto another strand, so pieces nearer than τ_O / 2 are tried too."""
    params, scaled = context.params, context.scaled
    reach = params.occluder_reach_px * scaled.scale
    if reach <= scaled.tau_o or not branch.segments:
        return None
    fit_length = FIT_STEPS * scaled.step_radius
    path, arc_back = _path_back(branch, fit_length)
    count = int(np.searchsorted(arc_back, fit_length)) + 1
    if arc_back[-1] < MIN_FIT_STEPS * scaled.step_radius:
        return None  # too little thread seen to extrapolate
    fitted = end_direction(path[-count - 1 :])
    if fitted is None:
        return None
    tangent, curvature = fitted
    if arc_back[-1] < fit_length / 2:  # too short to measure a curvature: straight on
        curvature = 0.0
    curvature = float(np.clip(curvature, -MAX_CURVATURE / scaled.scale, MAX_CURVATURE / scaled.scale))
    end = branch.vertices[-1]
    width = thread_width(branch) or 1.0

    def in_cone(offset: np.ndarray) -> np.ndarray:
        """Which (k, 2) offsets from the end lie in the cone (between the straight and the
        constant-curvature extrapolation, widened by bridge_bend_max) within the reach."""
        distance = np.hypot(offset[:, 0], offset[:, 1])
        bearing = np.arctan2(tangent[0] * offset[:, 1] - tangent[1] * offset[:, 0], offset @ tangent)
        curved = np.arcsin(np.clip(curvature * distance / 2, -1.0, 1.0))
        inside = (distance > scaled.step_radius) & (distance <= reach)
        inside &= bearing > np.minimum(curved, 0.0) - params.bridge_bend_max
        return inside & (bearing < np.maximum(curved, 0.0) + params.bridge_bend_max)

    free = _free_mask_near(context, branch, end, reach, width, in_cone)
    if free is None:
        return None
    labels, origin = free
    # The thread may bend either way under the occluder (an S between its two ends).
    across = dataclasses.replace(
        context, params=dataclasses.replace(params, bridge_bend_max=params.occluder_bend_max)
    )
    rows, cols = np.nonzero(labels)
    offset = np.column_stack((cols + origin[0], rows + origin[1])) - end
    distance = np.hypot(offset[:, 0], offset[:, 1])
    ahead = in_cone(offset)
    if not ahead.any():
        return None
    label = labels[rows[ahead], cols[ahead]]
    order = np.argsort(distance[ahead], kind="stable")
    _, first = np.unique(label[order], return_index=True)
    for k in np.sort(first)[:MAX_PIECES]:
        nearest = np.flatnonzero(ahead)[order[k]]
        piece = labels[rows, cols] == labels[rows[nearest], cols[nearest]]
        entry = offset[nearest] + end
        near_entry = piece & (np.hypot(*(offset + end - entry).T) <= max(2.0, width))
        point = (offset[near_entry] + end).mean(axis=0)
        chord = point - end
        length = float(np.hypot(*chord))
        if length <= (scaled.step_radius if on_strand else scaled.tau_o / 2):
            continue  # within the search's own reach: its own end, or a gap it refused
        continuation = gap_exit(across, point, chord, tangent, branch.consumed)
        if continuation is None or not _bends_as_predicted(tangent, curvature, chord, continuation, params):
            continue
        branch.track, branch.turn = tangent * scaled.step_radius, 0.0
        return Candidates(
            point[None, :],
            np.array([length]),
            np.array([int(length)]),
            np.array([abs(signed_angle(tangent, chord))]),
            np.array([width]),
            [continuation],
            np.array([True]),
            decided=0,
        )
    return None


def _bends_as_predicted(
    tangent: np.ndarray, curvature: float, chord: np.ndarray, continuation: np.ndarray, params: OrderingParams
) -> bool:
    """Whether a connection that bends like an S (turns into and out of the chord differing by
    ``bridge_bend_max`` or more) starts as the end's curvature predicts: its chord lies within
    ``S_BEND_SLACK`` of the arcs between straight on and constant curvature. A thread ending
    straight where another strand starts beside its line would need an S that its end does not
    announce."""
    into = signed_angle(tangent, chord)
    if abs(into - signed_angle(chord, continuation)) < params.bridge_bend_max:
        return True
    curved = math.asin(max(-1.0, min(1.0, curvature * float(np.hypot(*chord)) / 2)))
    return min(curved, 0.0) - S_BEND_SLACK <= into <= max(curved, 0.0) + S_BEND_SLACK


def _free_mask_near(
    context: SearchContext,
    branch: Branch,
    end: np.ndarray,
    reach: float,
    width: float,
    in_cone: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray] | None:
    """Connected pieces (int32 labels, 0 = none) of the mask within ``reach`` of ``end`` that lie
    clear of the path traversed so far (by a thread width), and the (u, v) of the window's first
    pixel; None when no undetected mask pixel lies ``in_cone`` (offsets from ``end``)."""
    reader = context.reader
    pad = reader.pad
    height, width_px = reader.mask.shape
    cu, cv = round(float(end[0])) + pad, round(float(end[1])) + pad
    r = math.ceil(reach) + 1
    u0, u1 = max(0, cu - r), min(width_px, cu + r + 1)
    v0, v1 = max(0, cv - r), min(height, cv + r + 1)
    consumed = branch.consumed[v0:v1, u0:u1]
    mask = reader.mask[v0:v1, u0:u1]
    origin = np.array([u0 - pad, v0 - pad], dtype=np.float64)
    # The undetected mask pixels (both rasters 0/1), listed row by row as np.nonzero would.
    undetected = cv2.findNonZero(cv2.subtract(mask, consumed))
    if undetected is None:
        return None
    cols, rows = undetected.reshape(-1, 2).T
    ahead = in_cone(np.column_stack((cols, rows)) + origin - end)
    if not ahead.any():
        return None  # the usual end of a thread: nothing ahead (no need to label the window)
    # Only the box round the pixels ahead is labelled (with room for the clearance).
    clearance = max(3, math.ceil(width))
    margin = 2 * clearance + 1
    r0, r1 = max(0, rows[ahead].min() - margin), rows[ahead].max() + margin + 1
    c0, c1 = max(0, cols[ahead].min() - margin), cols[ahead].max() + margin + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * clearance + 1, 2 * clearance + 1))
    near_path = cv2.dilate(consumed[r0:r1, c0:c1], kernel) > 0
    free = ((mask[r0:r1, c0:c1] > 0) & ~near_path).astype(np.uint8)
    count, labels = cv2.connectedComponents(free, connectivity=8)
    if count <= 1:
        return None
    return labels, origin + np.array([c0, r0], dtype=np.float64)
