# SPDX-License-Identifier: Apache-2.0
"""The circles :func:`across_own_path` reads: :func:`radii_ahead` leaves out only circles that hold
no free node ahead, and none at a thread's free end."""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from suture_ordering import OrderingParams
from suture_ordering.core import _prepare
from suture_ordering.geometry import LINE_SHIFT, fixed_point, turn_angles
from suture_ordering.loops import radii_ahead
from suture_ordering.path import Branch

H, W = 480, 640


def _context_and_branch(mask: np.ndarray, path: np.ndarray):
    context = _prepare(mask, OrderingParams(), None).searcher.context
    pad = context.reader.pad
    consumed = np.zeros(context.reader.mask.shape, dtype=np.uint8)
    for a, b in itertools.pairwise(path):
        start, end = fixed_point(a + pad), fixed_point(b + pad)
        cv2.line(consumed, start, end, 1, context.thickness, cv2.LINE_8, LINE_SHIFT)
    branch = Branch(rows=np.arange(1), consumed=consumed, vertices=list(path))
    return context, branch


def _radii_with_a_free_node_ahead(context, branch, vertex, heading) -> list[int]:
    """Every circle r_s < r <= Υ, read in full, that holds a free node turning less than bridge_turn_max."""
    reader, scaled = context.reader, context.scaled
    consumed_flat = branch.consumed.reshape(-1)
    radii = []
    for r in range(scaled.step_radius + 1, scaled.roi_radius + 1):
        nodes = reader.nodes(vertex, r, None)
        if nodes is None:
            continue
        free = consumed_flat[reader.flat(nodes.position)] == 0
        if (free & (turn_angles(nodes.position - vertex, heading) < context.params.bridge_turn_max)).any():
            radii.append(r)
    return radii


def test_nothing_ahead_at_a_free_end_reads_no_circle():
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (40, 120), (200, 120), 1, 4)
    path = np.array([[45.0, 120.0], [120.0, 120.0], [199.0, 120.0]])
    context, branch = _context_and_branch(mask, path)
    assert radii_ahead(context, branch, path[-1], np.array([1.0, 0.0])) == []


def test_a_strand_ahead_beyond_the_end_keeps_its_circles():
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (40, 120), (150, 120), 1, 4)
    cv2.line(mask, (165, 100), (165, 140), 1, 4)  # another strand 15 px ahead
    path = np.array([[45.0, 120.0], [100.0, 120.0], [148.0, 120.0]])
    context, branch = _context_and_branch(mask, path)
    heading = np.array([1.0, 0.0])
    full = _radii_with_a_free_node_ahead(context, branch, path[-1], heading)
    assert full  # the strand's nodes lie ahead on the circles around r = 17
    assert set(full) <= set(radii_ahead(context, branch, path[-1], heading))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    angle=st.floats(0.0, 2 * math.pi),
    width=st.integers(2, 7),
)
def test_circles_left_out_hold_no_free_node_ahead(seed, angle, width):
    rng = np.random.default_rng(seed)
    mask = np.zeros((H, W), np.uint8)
    for _ in range(4):  # random strands round the vertex
        a, b = rng.uniform((100, 60), (220, 180), size=(2, 2)).astype(int)
        cv2.line(mask, tuple(int(x) for x in a), tuple(int(x) for x in b), 1, width)
    vertex = np.array([160.0, 120.0]) + rng.uniform(-2, 2, 2)
    cv2.circle(mask, (160, 120), 3, 1, -1)
    heading = np.array([math.cos(angle), math.sin(angle)])
    path = np.array([vertex - 30 * heading, vertex - 12 * heading, vertex])
    context, branch = _context_and_branch(mask, path)
    listed = radii_ahead(context, branch, vertex, heading)
    assert listed == sorted(set(listed))
    assert set(_radii_with_a_free_node_ahead(context, branch, vertex, heading)) <= set(listed)
