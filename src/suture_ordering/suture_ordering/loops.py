# SPDX-License-Identifier: Apache-2.0
"""Leaving a loop across the thread's own first pass, where the usual step finds nothing.

Back round a loop at its own crossing, the way out may share the first
pass's track for a few pixels (strands meeting at a shallow angle): every
nearer node ahead is detected and the chord to the first free one cuts the
curve outside the zone, like a gap that the bridge checks refuse
(:mod:`suture_ordering.bridging`). Before the search ends, a free node ahead
within ``bridge_turn_max`` is taken when the smooth step to it (Hermite,
bending less than ``bridge_bend_max``) stays in the zone and crosses the
traversed path (:func:`across_own_path`).
"""

from __future__ import annotations

import numpy as np

from suture_ordering.context import SearchContext
from suture_ordering.geometry import bend, hermite, turn_angles
from suture_ordering.nodes import MAX_OUTSIDE_ZONE, Candidates
from suture_ordering.path import Branch, predicted_heading, tangent_at_vertex


def across_own_path(context: SearchContext, branch: Branch) -> Candidates | None:
    """The step out of a loop across the thread's own earlier pass, where the search found
    nothing: the candidate, or None (the thread ends here).

    Coming round a loop back to its crossing, the nearer nodes ahead lie on the path traversed
    before (detected), and where the strands meet at a shallow angle the way out shares the
    first pass's track for a while: the first free node of the exit lies beyond the RoI's
    nearest circles, and the chord to it, cutting the curve, leaves the zone by a few pixels, so
    that it is taken for a gap and refused. Here a free node ahead (turning less than
    ``bridge_turn_max``) is taken when the smooth step to it (a Hermite curve along both
    tangents, bending less than ``bridge_bend_max``) runs within the zone (at most 10 %
    outside) and over the traversed path (crossing it), nearest first.
    """
    reader, params, scaled = context.reader, context.params, context.scaled
    heading = predicted_heading(branch)
    tangent = tangent_at_vertex(branch)
    if heading is None or tangent is None:
        return None
    vertex = branch.vertices[-1]
    consumed_flat = branch.consumed.reshape(-1)
    unit = tangent / float(np.hypot(*tangent))
    for r in range(scaled.step_radius + 1, scaled.roi_radius + 1):
        nodes = reader.nodes(vertex, r, None)
        if nodes is None:
            continue
        delta = turn_angles(nodes.position - vertex, heading)
        free = consumed_flat[reader.flat(nodes.position)] == 0
        for j in np.flatnonzero(free & (delta < params.bridge_turn_max)):
            point = nodes.position[j]
            onward = reader.tangent(point, point - vertex, consumed_flat)
            if onward is None or bend(vertex, unit, point, onward) >= params.bridge_bend_max:
                continue
            curve = reader.flat(hermite(vertex, point, unit * r, onward * r))
            outside = (reader.zone_flat[curve] == 0).mean()
            if outside > MAX_OUTSIDE_ZONE or (consumed_flat[curve] != 0).sum() < 2:
                continue
            return Candidates.smooth_step(point, r, delta[j : j + 1], nodes.width[j : j + 1], onward)
    return None
