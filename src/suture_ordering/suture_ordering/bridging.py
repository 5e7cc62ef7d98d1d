# SPDX-License-Identifier: Apache-2.0
"""Gaps in the mask: when a step whose chord leaves the zone (O > 0) may bridge the gap.

τ_O and gaps.
    Inside the RoI O <= |A - V| <= Υ < τ_O, so τ_O only binds when the RoI holds
    no admissible node: then the circles continue beyond Υ up to τ_O (the
    farthest a node with O < τ_O can lie), which bridges gaps of up to τ_O px
    (62 px at 640 px width, e.g. an instrument lying across the thread). A node
    whose chord leaves the zone (O > 0: a bridged gap) must also turn by less
    than ``bridge_turn_max``, the thread must *start* there facing the gap, and
    continue beyond it so that the connection bends like one arc (turns into and
    out of the chord differing by less than ``bridge_bend_max``, measured one and
    two steps beyond); otherwise it is not admissible (a thread that ends near
    another one is not joined to it). Bridged stretches are filled with a cubic
    Hermite curve matching the thread's direction at both ends and flagged
    (:func:`suture_ordering.path.advance`).
"""

from __future__ import annotations

import numpy as np

from suture_ordering.context import SearchContext
from suture_ordering.geometry import signed_angle, turn_angles


def gap_exit(
    context: SearchContext,
    point: np.ndarray,
    chord: np.ndarray,
    heading: np.ndarray | None,
    consumed: np.ndarray,
) -> np.ndarray | None:
    """Unit direction in which the thread leaves a gap at ``point``, or None when the bridge
    ``chord`` is not a smooth continuation.

    With α1 the turn from ``heading`` to the chord and α2 the turn from the chord to the
    thread beyond the gap, a bridge needs |α2| < bridge_turn_max and |α1 - α2| <
    bridge_bend_max: the connection must bend like one smooth arc, not like a corner. The
    thread beyond must also *start* at ``point``, facing the gap (no mask within
    bridge_turn_max of the way back along the chord): a gap ends where the thread emerges,
    not on the side of another thread. ``consumed``: the branch's raster of the path
    traversed so far (nodes on it do not count).
    """
    reader, params = context.reader, context.params
    r = context.scaled.step_radius
    nodes = reader.nodes(point, r, None)
    if nodes is None:
        return None
    ahead = nodes.position - point
    if np.any(turn_angles(ahead, -chord) < params.bridge_turn_max):
        return None
    alpha1 = 0.0 if heading is None else signed_angle(heading, chord)
    alpha2 = np.arctan2(chord[0] * ahead[:, 1] - chord[1] * ahead[:, 0], ahead @ chord)
    bend = np.abs(alpha1 - alpha2)
    ok = (np.abs(alpha2) < params.bridge_turn_max) & (bend < params.bridge_bend_max)
    ok &= consumed.reshape(-1)[reader.flat(nodes.position)] == 0
    if not ok.any():
        return None
    ok &= reader.out_of_zone(point, nodes.position, r) == 0
    if not ok.any():
        return None
    j = int(np.flatnonzero(ok)[np.argmin(bend[ok])])
    # Measure the thread's direction one step farther on too (a rounded or frayed end biases
    # the first chord) and require both to continue the arc.
    farther = reader.nodes(nodes.position[j], r, None)
    if farther is not None:
        onward = farther.position - nodes.position[j]
        turn = turn_angles(onward, ahead[j])
        if turn.min() < params.bridge_turn_max:
            direction = onward[int(np.argmin(turn))]
            beyond = signed_angle(chord, direction)
            if abs(beyond) >= params.bridge_turn_max or abs(alpha1 - beyond) >= params.bridge_bend_max:
                return None
    return ahead[j] / float(np.hypot(*ahead[j]))
