# SPDX-License-Identifier: Apache-2.0
"""Where the ordered sequence ends: the last, shorter piece to the thread's free end, and how
the search ended.

Termination.
    The search ends when no admissible node (not detected, O < τ_O, δ < τ_V)
    exists up to τ_O, nor a step out of a loop across the first pass
    (:mod:`suture_ordering.loops`), or at a junction without a smooth continuation
    (:mod:`suture_ordering.junctions`); the last, shorter piece to the free end is
    then appended, and the sequence ends half a thread width before the end of the
    mask (where the centreline of a rounded end ends).
"""

from __future__ import annotations

import math

import numpy as np

from suture_ordering.context import SearchContext
from suture_ordering.geometry import turn_angles
from suture_ordering.path import Branch, advance, predicted_heading, thread_width

#: The last piece to the free end turns by less than this (rad).
TAIL_MAX_TURN = math.pi / 3


def append_tail(context: SearchContext, branch: Branch) -> None:
    """End the sequence at the free end: the centreline's end lies half the thread's width
    before the end of the mask (a thread's end is rounded).

    The last piece, shorter than r_s, goes towards the farthest node nearer than r_s
    (turning less than 60 degrees, O = 0) as far as the mask reaches less half a width.
    If the last vertex already lies on the rounded end, the last step is shortened instead.
    """
    reader, scaled = context.reader, context.scaled
    vertex = branch.vertices[-1]
    consumed_flat = branch.consumed.reshape(-1)
    half = max(0.0, ((thread_width(branch) or 1.0) - 1.0) / 2.0)
    heading = predicted_heading(branch)
    for r in range(scaled.step_radius - 1, math.ceil(scaled.detect_radius), -1):
        nodes = reader.nodes(vertex, r, None)
        if nodes is None:
            continue
        delta = turn_angles(nodes.position - vertex, heading)
        ok = (consumed_flat[reader.flat(nodes.position)] == 0) & (delta < TAIL_MAX_TURN)
        ok &= reader.out_of_zone(vertex, nodes.position, r) == 0
        if not ok.any():
            continue
        j = np.flatnonzero(ok)[np.argmin(delta[ok])]
        unit = (nodes.position[j] - vertex) / r
        length = reader.extent(vertex, unit) - half
        if length >= 1.0:
            advance(context, branch, vertex + unit * length, float(nodes.width[j]))
            return
        break
    else:  # no node left on any circle: the end is nearer than that; go on straight to it
        if heading is not None:
            unit = heading / float(np.hypot(*heading))
            length = reader.extent(vertex, unit) - half
            if length >= 1.0:
                advance(context, branch, vertex + unit * length, thread_width(branch) or 1.0)
                return
    if not branch.segments or branch.segment_bridged[-1] or half <= 0:
        return
    last = branch.segments[-1]
    start = branch.vertices[-2]
    chord = branch.vertices[-1] - start
    length = float(np.hypot(*chord))
    unit = chord / max(length, 1e-9)
    shorten = half - reader.extent(branch.vertices[-1], unit)
    if 0 < shorten < length - 1.0:
        keep = np.hypot(*(last - start).T) <= length - shorten + 1e-9
        end = start + unit * (length - shorten)
        branch.segments[-1] = (
            np.vstack([last[keep], end]) if not np.allclose(last[keep][-1:], end) else last[keep]
        )
        branch.vertices[-1] = end


def end_status(context: SearchContext, vertex: np.ndarray) -> str:
    """'image_border' when the last vertex lies within r_s of the image's edge, else 'free_end'."""
    margin = context.scaled.step_radius
    height, width = context.reader.image_shape
    u, v = vertex
    if u < margin or v < margin or u > width - 1 - margin or v > height - 1 - margin:
        return "image_border"
    return "free_end"
