# SPDX-License-Identifier: Apache-2.0
"""One step of the ordering search: the admissible nodes around the current vertex, read circle
by circle from the nearest, among which the parameter sets elect the next vertex (Eq. 6).

Active, detected and far nodes.
    The RoI is the annulus ``r_s <= |A - V^t| <= Υ`` (``step_radius``,
    ``roi_radius``): nodes nearer than ``r_s`` lie between ``V^t`` and the next
    vertex and are covered by the chord to it. *Detected* nodes are those within
    ``detect_radius`` of the polyline traversed so far (kept as a raster). Since
    the distance term prefers the nearest ring, circles are read lazily, from
    ``r_s`` outward, and stop as soon as no farther node can have a lower cost
    for any parameter set (every node at radius ``r`` costs at least
    ``log(μ) + ε2 r``). Nodes on one circle are equidistant, so among them the
    turning angle decides exactly, however small ε3 is. When the RoI holds no
    admissible node, circles continue up to τ_O across a gap
    (:mod:`suture_ordering.bridging`); a junction on the nearest circle is decided
    across the whole junction (:mod:`suture_ordering.junctions`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.bridging import gap_exit
from suture_ordering.compiled import admissible_nodes
from suture_ordering.context import SearchContext
from suture_ordering.geometry import turn_angles
from suture_ordering.junctions import Stop, decided_across_junction, junction_step
from suture_ordering.nodes import Candidates, Nodes
from suture_ordering.path import Branch, predicted_heading, tangent_at_vertex, thread_width


def admissible(
    context: SearchContext,
    branch: Branch,
    nodes: Nodes,
    heading: np.ndarray | None,
    consumed_flat: np.ndarray,
) -> Candidates | None:
    """The admissible nodes among ``nodes``: not detected, δ < τ_V, O < τ_O (and bridge checks).

    δ is computed here; which nodes are undetected and turn less than τ_V, and their O, by
    :func:`suture_ordering.compiled.admissible_nodes`."""
    reader, params = context.reader, context.params
    vertex = branch.vertices[-1]
    position = nodes.position
    if heading is None:
        delta = np.zeros(len(position))
    else:  # |position - vertex| = r for nodes on the circle around the vertex
        cos = (position - vertex).dot(heading) / (nodes.radius * math.hypot(heading[0], heading[1]))
        delta = np.arccos(np.minimum(np.maximum(cos, -1.0, out=cos), 1.0, out=cos), out=cos)
    position, delta, widths, out, radius, bridge = admissible_nodes(
        position,
        delta,
        nodes.width,
        params.tau_v,
        consumed_flat,
        reader.zone_flat,
        reader.padded_width,
        reader.pad,
        float(vertex[0]),
        float(vertex[1]),
        nodes.radius,
    )
    if not len(position):
        return None
    continuation: list[np.ndarray | None] = [None] * len(position)
    if not np.count_nonzero(bridge):
        return Candidates(position, radius, out, delta, widths, continuation, bridge)
    keep = out < context.scaled.tau_o
    for j in np.flatnonzero(out > 0):  # bridged gaps: few, checked one by one
        if not keep[j] or delta[j] >= params.bridge_turn_max:
            keep[j] = False
            continue
        continuation[j] = gap_exit(
            context, position[j], position[j] - vertex, tangent_at_vertex(branch), branch.consumed
        )
        keep[j] = continuation[j] is not None
    if not keep.any():
        return None
    return Candidates(
        position[keep],
        radius[keep],
        out[keep],
        delta[keep],
        widths[keep],
        [continuation[j] for j in np.flatnonzero(keep)],
        out[keep] > 0,
    )


def farther_radii(
    context: SearchContext, branch: Branch, vertex: np.ndarray, heading: np.ndarray | None
) -> list[int]:
    """Radii in (r_s, max_reach] whose circles meet an undetected mask pixel ahead, ascending."""
    reader, scaled = context.reader, context.scaled
    reach = scaled.max_reach
    pad = reader.pad
    cu, cv = round(float(vertex[0])) + pad, round(float(vertex[1])) + pad
    window = (slice(cv - reach - 1, cv + reach + 2), slice(cu - reach - 1, cu + reach + 2))
    # The undetected mask pixels (both rasters 0/1), listed row by row as np.nonzero would.
    undetected = cv2.findNonZero(cv2.subtract(reader.mask[window], branch.consumed[window]))
    if undetected is None:
        return []
    cols, rows = undetected.reshape(-1, 2).T
    offset = np.column_stack((cols + (cu - reach - 1 - pad), rows + (cv - reach - 1 - pad))) - vertex
    distance = np.sqrt((offset * offset).sum(axis=1))
    near = (distance > scaled.step_radius) & (distance < reach + 1)
    if heading is not None:
        slack = math.asin(min(1.0, 1.0 / scaled.step_radius))
        near &= turn_angles(offset, heading) < context.params.tau_v + slack
    distance = distance[near]
    radii = np.unique(np.concatenate((np.floor(distance), np.ceil(distance))).astype(int))
    return [int(r) for r in radii if scaled.step_radius < r <= reach]


def next_candidates(context: SearchContext, branch: Branch) -> Candidates | Stop | None:
    """Admissible nodes of the current RoI (widened across a gap if it has none), or None;
    :data:`~suture_ordering.junctions.STOP` where a junction ahead turns only sharply onto
    another strand.

    Circles are read from r_s outward and only while a farther node could still cost less
    for some parameter set; beyond Υ only if the RoI held no admissible node.
    """
    reader, tuning = context.reader, context.tuning
    vertex = branch.vertices[-1]
    heading = predicted_heading(branch)
    consumed_flat = branch.consumed.reshape(-1)
    width = thread_width(branch)
    r_s = context.scaled.step_radius
    found: list[Candidates] = []
    best = None  # per parameter set, the least cost found so far
    nodes = reader.nodes(vertex, r_s, width)
    if nodes is not None:
        first = admissible(context, branch, nodes, heading, consumed_flat)
        if first is not None and heading is not None and decided_across_junction(context, first, width):
            junction = junction_step(context, branch, heading, consumed_flat)
            if junction is not None:
                return junction
        if first is not None:
            if tuning.zone_dominates:
                # Equidistant nodes inside the zone: every parameter set prefers the smallest
                # turn, and no farther node can do better if even the largest ε3 keeps that
                # cost below the cheapest node one pixel farther (no cost matrix needed).
                turns = (
                    np.where(first.bridge, np.inf, first.delta)
                    if np.count_nonzero(first.bridge)
                    else first.delta
                )
                smallest = int(turns.argmin())
                turn = float(turns[smallest])
                if turn < math.inf and math.exp(tuning.eps3_max * math.sin(turn / 2)) <= (r_s + 1) / r_s:
                    first.decided = smallest
                    return first
            found.append(first)
            best = tuning.cost(branch.rows, first).min(axis=1)
            if np.all(best <= tuning.least_cost_at(branch.rows, r_s + 1)):
                return first
    for r in farther_radii(context, branch, vertex, heading):
        if best is not None and (
            r > context.scaled.roi_radius or np.all(best <= tuning.least_cost_at(branch.rows, r))
        ):
            break
        nodes = reader.nodes(vertex, r, width)
        if nodes is None:
            continue
        more = admissible(context, branch, nodes, heading, consumed_flat)
        if more is None:
            continue
        found.append(more)
        least = tuning.cost(branch.rows, more).min(axis=1)
        best = least if best is None else np.minimum(best, least)
    return Candidates.concatenate(found) if found else None
