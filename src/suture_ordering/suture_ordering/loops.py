# SPDX-License-Identifier: Apache-2.0
"""Leaving a loop across the thread's own first pass, where the usual step finds nothing.

Back round a loop at its own crossing, the way out may share the first
pass's track for a few pixels (strands meeting at a shallow angle): every
nearer node ahead is detected and the chord to the first free one cuts the
curve outside the zone, like a gap that the bridge checks refuse
(:mod:`suture_ordering.bridging`). Before the search ends, a free node ahead
within ``bridge_turn_max`` is taken when the smooth step to it (Hermite,
bending less than ``bridge_bend_max``) stays in the zone and crosses the
traversed path (:func:`across_own_path`). Where the search stopped at a junction whose every
arm turns sharply onto another strand (:data:`suture_ordering.junctions.STOP`), the step must
also leave in about our direction (its end tangent within ``bridge_turn_max`` of ours): the
Hermite curve bends evenly onto a strand crossing ours at 70 degrees within 11 px, and the
drawn end of our own path round the vertex counts as the pass it crosses.

The search ends (and this is tried) once per search, mostly at the thread's free end, where
nothing lies ahead: one raster test of the window (:func:`radii_ahead`) settles that before
any circle is read, and which circles may hold a way on.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_ordering.context import SearchContext
from suture_ordering.geometry import bend, hermite, turn_angles
from suture_ordering.nodes import MAX_OUTSIDE_ZONE, Candidates
from suture_ordering.path import Branch, predicted_heading, tangent_at_vertex


def across_own_path(context: SearchContext, branch: Branch, on_strand: bool) -> Candidates | None:
    """The step out of a loop across the thread's own earlier pass, where the search found
    nothing: the candidate, or None (the thread ends here).

    Coming round a loop back to its crossing, the nearer nodes ahead lie on the path traversed
    before (detected), and where the strands meet at a shallow angle the way out shares the
    first pass's track for a while: the first free node of the exit lies beyond the RoI's
    nearest circles, and the chord to it, cutting the curve, leaves the zone by a few pixels, so
    that it is taken for a gap and refused. Here a free node ahead (turning less than
    ``bridge_turn_max``) is taken when the smooth step to it (a Hermite curve along both
    tangents, bending less than ``bridge_bend_max``) runs within the zone (at most 10 %
    outside) and over the traversed path (crossing it), nearest first. ``on_strand``: the search
    stopped at a junction that turns only sharply onto another strand; the step must then keep
    our direction too (module docstring).
    """
    reader, params = context.reader, context.params
    heading = predicted_heading(branch)
    tangent = tangent_at_vertex(branch)
    if heading is None or tangent is None:
        return None
    vertex = branch.vertices[-1]
    consumed_flat = branch.consumed.reshape(-1)
    unit = tangent / float(np.hypot(*tangent))
    for r in radii_ahead(context, branch, vertex, heading):
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
            if on_strand and turn_angles(onward[None, :], unit)[0] >= params.bridge_turn_max:
                continue  # onto the strand whose every arm the junction found turning sharply
            curve = reader.flat(hermite(vertex, point, unit * r, onward * r))
            outside = (reader.zone_flat[curve] == 0).mean()
            if outside > MAX_OUTSIDE_ZONE or (consumed_flat[curve] != 0).sum() < 2:
                continue
            return Candidates.smooth_step(point, r, delta[j : j + 1], nodes.width[j : j + 1], onward)
    return None


#: A node's pixel (its rounded position) lies within this many pixels (Chebyshev) of a mask
#: pixel: 0.5 from the node, which lies within one sample spacing (<= 1 px) of a circle sample
#: above 0.5; 0.5 from that sample to its rounded position, and 1 from there to the sample's
#: bilinear neighbour on the mask.
NODE_TO_MASK_PX = 3


def radii_ahead(context: SearchContext, branch: Branch, vertex: np.ndarray, heading: np.ndarray) -> list[int]:
    """The circles r_s < r <= Υ, ascending, that may hold a free node ahead for
    :func:`across_own_path`: those a node's pixel (its rounded position, < 1 px from the circle)
    can round from, for the undetected pixels within :data:`NODE_TO_MASK_PX` of the mask that
    turn from ``heading`` less than ``bridge_turn_max`` (plus what rounding to a pixel can
    turn). A circle left out holds no such node; one listed may."""
    reader, scaled = context.reader, context.scaled
    every = list(range(scaled.step_radius + 1, scaled.roi_radius + 1))
    reach = scaled.roi_radius + 1
    margin = reach + NODE_TO_MASK_PX
    cu, cv = round(float(vertex[0])) + reader.pad, round(float(vertex[1])) + reader.pad
    if min(cu, cv) < margin or cu + margin >= reader.padded_width or cv + margin >= reader.padded_height:
        return every  # beyond the padding: let the circles decide
    size = 2 * NODE_TO_MASK_PX + 1
    near_mask = cv2.dilate(
        reader.mask[cv - margin : cv + margin + 1, cu - margin : cu + margin + 1],
        np.ones((size, size), np.uint8),
    )[NODE_TO_MASK_PX:-NODE_TO_MASK_PX, NODE_TO_MASK_PX:-NODE_TO_MASK_PX]
    window = (slice(cv - reach, cv + reach + 1), slice(cu - reach, cu + reach + 1))
    rows, cols = np.nonzero(near_mask > branch.consumed[window])
    if rows.size == 0:
        return []
    offset = np.column_stack((cols + (cu - reach - reader.pad), rows + (cv - reach - reader.pad))) - vertex
    distance = np.sqrt((offset * offset).sum(axis=1))
    # A pixel lies at most sqrt(2) / 2 px (< 1) from the node it rounds: from circle floor(d) or ceil(d).
    near = (distance >= scaled.step_radius) & (distance <= scaled.roi_radius + 1)
    if not near.any():
        return []
    slack = math.asin(min(1.0, 1.0 / scaled.step_radius))
    ahead = turn_angles(offset[near], heading) < context.params.bridge_turn_max + slack
    distance = distance[near][ahead]
    radii = np.unique(np.concatenate((np.floor(distance), np.ceil(distance))).astype(int))
    return [int(r) for r in radii if scaled.step_radius < r <= scaled.roi_radius]
