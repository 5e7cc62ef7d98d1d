# SPDX-License-Identifier: Apache-2.0
"""Junctions ahead of the search (crossings, the thread's own loops, touching threads): when a
step is decided across the whole junction, and which arm the thread leaves through.

When the nodes on the first circle show several branches, or a cross-section
wider than a thread, or every one of them turns by more than
``sharp_step_turn`` (a small loop entered tangentially runs merged with the
way out past that circle, and its one node there is the way out's), the
search decides across the whole junction instead of on the biased near
nodes, with the arms on the circle of radius Υ (:func:`junction_step`): a loop
the thread forms here is entered first (two arms connected outside the
junction), a crossing is crossed straight (the arm opposite ours in angular
order), otherwise the arm that continues the thread like one arc wins; the
step is a Hermite curve to that arm. If every arm bends sharply, the thread
ends there (it ends on another strand, or the mask lost it beyond that strand, which
:mod:`suture_ordering.occluders` then looks for): :data:`STOP`. Our tangent there is the
last steps' track unless the path over the last Υ (the circle through the
points Υ and Υ/2 back and the vertex) points more than 5° elsewhere: on a
segmenter's mask the step into a junction is often pulled towards the other
strand (:func:`junction_tangent`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.context import SearchContext
from suture_ordering.geometry import bend, hermite, rotate, signed_angle, turn_angles
from suture_ordering.nodes import MAX_OUTSIDE_ZONE, Candidates
from suture_ordering.path import Branch, entry_point, tangent_at_vertex


class Stop:
    """Marker: the search ends at this junction."""


STOP = Stop()
#: (1, 5, 1) fractions of a chord where :func:`junction_step` checks that it leads across.
_CHORD_SAMPLES = np.linspace(0.25, 0.75, 5)[None, :, None]
#: A path tangent this far from the track replaces it at a junction (:func:`junction_tangent`).
PULLED_TURN = math.radians(5.0)


def at_junction(context: SearchContext, nodes: Candidates, width: float | None) -> bool:
    """Several branches ahead (nodes farther apart than a thread width), or a merged
    cross-section (wider than ``wide_arc_factor`` thread widths): a crossing or touching
    threads."""
    if width is None:
        return False
    if np.count_nonzero(nodes.width > context.params.wide_arc_factor * width):
        return True
    if len(nodes.width) < 2:
        return False
    position = nodes.position
    return float((position.max(axis=0) - position.min(axis=0)).max()) > max(2.0, width)


def decided_across_junction(context: SearchContext, nodes: Candidates, width: float | None) -> bool:
    """Whether the step is decided across the whole junction (:func:`junction_step`): a
    junction on the nearest circle (:func:`at_junction`), or every near node turning by more
    than ``sharp_step_turn`` (a strand that leaves ours at a shallow angle may still run
    merged with it there, and the near node be that strand's)."""
    return at_junction(context, nodes, width) or min(nodes.delta.tolist()) > context.params.sharp_step_turn


def junction_tangent(branch: Branch, radius: float) -> np.ndarray | None:
    """Our thread's tangent at a junction's vertex, from the path over the last ``radius`` px.

    The step that reached the junction is often pulled towards the other strand (the merged
    cross-section's nodes are biased): when the tangent of the circle through the path points
    ``radius`` and ``radius / 2`` back and the vertex differs from the last steps' track by
    more than :data:`PULLED_TURN`, it replaces the track.
    """
    track = tangent_at_vertex(branch)
    far, mid = entry_point(branch, radius), entry_point(branch, radius / 2)
    if far is None or mid is None or track is None:
        return track
    chord = branch.vertices[-1] - mid
    path = rotate(chord, signed_angle(mid - far, chord) / 2)
    return path if abs(signed_angle(track, path)) > PULLED_TURN else track


def opposite_arm(vertex: np.ndarray, tangent: np.ndarray, points: np.ndarray) -> int:
    """Index (into the three ``points``) of the arm opposite ours in angular order around V."""
    back = -tangent / float(np.hypot(*tangent))
    arms = np.vstack([back, points - vertex])
    order = list(np.argsort(np.arctan2(arms[:, 1], arms[:, 0])))
    return int(order[(order.index(0) + 2) % 4]) - 1


def loop_entry(
    context: SearchContext,
    vertex: np.ndarray,
    tangent: np.ndarray,
    points: np.ndarray,
    tangents: list[np.ndarray | None],
    ahead: np.ndarray,
) -> int | None:
    """Index of the arm that enters a loop the thread forms at this junction, or None.

    Two arms (separate cross-sections of the circle of radius Υ) that are connected
    through the mask outside the junction (the disc of radius Υ - 2 around V cut out) are
    the two ends of a loop: at its own crossing, a thread must go round its loop
    before it can leave through the remaining arm. With three arms (two strands crossing)
    the loop is entered straight across, through the arm opposite ours in angular order;
    otherwise, of the loop arms ahead, the one continuing the thread more smoothly
    (smaller bend) is taken.
    """
    if len(points) < 3:
        return None
    pad = context.reader.pad
    scratch = context.reader.mask.copy()
    centre = (round(float(vertex[0])) + pad, round(float(vertex[1])) + pad)
    cv2.circle(scratch, centre, context.scaled.roi_radius - 2, 0, thickness=cv2.FILLED)
    seeds: list[tuple[int, int] | None] = []
    for point in points:
        u, v = (round(float(x)) + pad for x in point)
        window = scratch[v - 1 : v + 2, u - 1 : u + 2]
        on = np.argwhere(window == 1)
        seeds.append(None if on.size == 0 else (u - 1 + int(on[0, 1]), v - 1 + int(on[0, 0])))
    label = 2
    groups: dict[int, list[int]] = {}
    for k, seed in enumerate(seeds):
        if seed is None:
            continue
        value = int(scratch[seed[1], seed[0]])
        if value == 1:
            cv2.floodFill(scratch, None, seed, label, flags=8)
            value, label = label, label + 1
        groups.setdefault(value, []).append(k)
    loops = [arms for arms in groups.values() if len(arms) == 2]
    if len(loops) != 1:
        return None
    entries = [k for k in loops[0] if ahead[k]]
    if len(points) == 3:  # a crossing of two strands: the loop is entered straight across
        opposite = opposite_arm(vertex, tangent, points)
        entries = [k for k in entries if k == opposite]
    if not entries:
        return None
    bends = [
        np.inf if tangents[k] is None else bend(vertex, tangent, points[k], tangents[k]) for k in entries
    ]
    return entries[int(np.argmin(bends))]


def crossing_exit(
    context: SearchContext, vertex: np.ndarray, tangent: np.ndarray, points: np.ndarray, ahead: np.ndarray
) -> int | None:
    """Index of the arm that crosses the other strand, if the junction is a crossing.

    Four arms around V (ours coming in, three on the circle): if our thread crosses the
    other strand, it leaves through the arm opposite ours in angular order (one arm on each
    side). That pairing implies two strands, both passing within r_s of V, meeting at the
    angle between their chords; when it is at least ``min_crossing_angle`` the junction is
    taken to be a crossing. A smaller angle means two threads touching without crossing (or
    no clear evidence): None.
    """
    scaled = context.scaled
    back = vertex - tangent * (scaled.roi_radius / float(np.hypot(*tangent)))
    opposite = opposite_arm(vertex, tangent, points)
    if not ahead[opposite]:
        return None
    i, j = (m for m in range(3) if m != opposite)
    ours = points[opposite] - back
    other = points[j] - points[i]
    # Both strands must pass near V (the junction lies between the arms).
    for start, chord in ((back, ours), (points[i], other)):
        offset = vertex - start
        if abs(chord[0] * offset[1] - chord[1] * offset[0]) / float(np.hypot(*chord)) > scaled.step_radius:
            return None
    cos = abs(float(ours @ other)) / (float(np.hypot(*ours)) * float(np.hypot(*other)) + 1e-12)
    if math.acos(min(1.0, cos)) < context.params.min_crossing_angle:
        return None
    return opposite


def junction_step(
    context: SearchContext, branch: Branch, heading: np.ndarray, consumed_flat: np.ndarray
) -> Candidates | Stop | None:
    """One step across a junction ahead (a crossing, a loop's crossing, touching threads).

    Inside the junction the cross-sections merge and near nodes are biased, so it is
    crossed in one step to a node N on the circle of radius Υ around the vertex V, where
    the branches are apart again. A branch that leaves through N with outward tangent t_N
    continues a strand that passed through M (tangent t_M, pointing in) smoothly when the
    chord M N bends like one arc: ``bend(M, N) = |α1 - α2|``, α1 the turn from t_M to the
    chord and α2 the turn from the chord to t_N (curvature does not matter; joining two
    different strands costs about their crossing angle). For our thread M = V with the
    track's tangent.

    With exactly three undetected branches on the circle (two strands, four arms) a
    crossing is recognised first (:func:`crossing_exit`): our thread leaves through the
    opposite arm. If the arms do not form a clear crossing (threads touching), the choice
    of our branch k also decides how the other strand passes, so the hypothesis with the
    smallest ``bend(V, N_k) + bend(N_i, N_j)`` wins. Otherwise the branch with the smallest
    ``bend(V, N_k)`` wins if it is below ``bridge_bend_max`` and smaller than the next by
    ``junction_tie`` (else the near nodes decide: in a band of two threads side by side
    the search keeps to its side). Only arms that can be reached through the mask count
    (at most 10 % of the Hermite step outside the zone). The step is drawn as a cubic
    Hermite curve matching both tangents. If every branch ahead bends by at least
    ``junction_bend_max`` the thread ends at this junction (it ends on another strand, or a
    short stub remains): :data:`STOP`. None when the evidence is missing (the search then
    decides on the near nodes as usual).
    """
    reader, params = context.reader, context.params
    vertex = branch.vertices[-1]
    radius = context.scaled.roi_radius
    far = reader.nodes(vertex, radius, None)  # one node per arm: merged arms stay one
    if far is None:
        return None
    free = np.flatnonzero(consumed_flat[reader.flat(far.position)] == 0)
    points = far.position[free]
    ahead = turn_angles(points - vertex, heading) < params.tau_v
    # A branch whose chord runs mostly over the traversed path leads back, not across.
    along = vertex + _CHORD_SAMPLES * (points - vertex)[:, None, :]
    ahead &= (consumed_flat[reader.flat(along)] != 0).sum(axis=1) <= 2
    if int(ahead.sum()) < 2:
        return None  # one branch ahead after all: the near nodes follow it
    tangent = junction_tangent(branch, radius)
    if tangent is None:
        return None
    tangents = [reader.tangent(p, p - vertex, consumed_flat) for p in points]
    ours = [
        bend(vertex, tangent, p, t) if t is not None and ok else np.inf
        for p, t, ok in zip(points, tangents, ahead, strict=True)
    ]
    # The step to a branch is a Hermite curve; it must run through the thread, not across the
    # background to some other strand (at most 10 % of it outside the zone).
    for k in np.flatnonzero(ahead):
        end_tangent = tangents[k] if tangents[k] is not None else (points[k] - vertex) / radius
        curve = hermite(vertex, points[k], tangent / float(np.hypot(*tangent)) * radius, end_tangent * radius)
        ahead[k] = (reader.zone_flat[reader.flat(curve)] == 0).mean() <= MAX_OUTSIDE_ZONE
    choice = loop_entry(context, vertex, tangent, points, tangents, ahead)
    if choice is None and len(points) == 3:
        choice = crossing_exit(context, vertex, tangent, points, ahead)
    if choice is None and len(points) == 3 and all(t is not None for t in tangents):
        totals = []
        for k in range(3):
            i, j = (m for m in range(3) if m != k)
            other = min(
                bend(points[i], -tangents[i], points[j], tangents[j]),  # type: ignore[operator]
                bend(points[j], -tangents[j], points[i], tangents[i]),  # type: ignore[operator]
            )
            totals.append(ours[k] + other)
        if np.isfinite(min(totals)):
            choice = int(np.argmin(totals))
    if choice is None and ours and min(ours) < params.bridge_bend_max:
        ranked = sorted(ours)
        if len(ranked) > 1 and ranked[1] - ranked[0] < params.junction_tie:
            return None  # two branches continue about equally well: decide on the near nodes
        choice = int(np.argmin(ours))
    if choice is None:
        measured = [b for b, t, ok in zip(ours, tangents, ahead, strict=True) if ok and t is not None]
        if measured and len(measured) == int(ahead.sum()) and min(measured) >= params.junction_bend_max:
            return STOP  # only sharp turns onto other strands: the thread ends here
        return None
    point = points[choice]
    return Candidates.smooth_step(
        point,
        radius,
        turn_angles((point - vertex)[None, :], heading),
        np.array([float(far.width[free[choice]])]),
        tangents[choice],
    )
