# SPDX-License-Identifier: Apache-2.0
"""The ordering across an occluder (suture_ordering.occluders): a wide instrument shaft lying
across the thread is bridged, the bridged points flagged and on the hidden centreline; a thread
that ends where another strand goes on is not joined to it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from suture_common.camera import StereoCamera
from suture_ordering import order_sequence, order_stereo
from suture_ordering.not_seen import flagged_sequence, seen_in_low_mask
from suture_ordering.occluders import _path_back, end_direction
from suture_ordering.path import Branch

W, H = 640, 480
#: At 110 mm from the default 640 px camera (fx 520 px) 20 mm of thread is about 95 px.
SHAFT_PX = 95


def _curve() -> np.ndarray:
    """A gently curved thread ~480 px long, 1 px samples, from its cut tip at the left."""
    s = np.linspace(0.0, 1.0, 2000)
    return np.column_stack([90 + 460 * s, 300 - 140 * s + 50 * np.sin(2.5 * s)])


def _draw(centreline: np.ndarray, width: int = 3) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    cv2.polylines(mask, [np.rint(centreline).astype(np.int32)], False, 255, width)
    return mask


def _shaft(mask: np.ndarray, centreline: np.ndarray, at: float, across_px: float) -> np.ndarray:
    """``mask`` with a straight shaft, hiding ``across_px`` of the centreline's arc, laid across it
    at arc fraction ``at`` (perpendicular to the thread there, wider than the image)."""
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(centreline, axis=0).T))])
    i = int(np.searchsorted(arc, at * arc[-1]))
    tangent = centreline[i + 5] - centreline[i - 5]
    tangent /= np.hypot(*tangent)
    normal = np.array([-tangent[1], tangent[0]])
    half = across_px / 2
    corners = [
        centreline[i] + a * tangent * half + b * normal * 1000
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    hidden = mask.copy()
    cv2.fillConvexPoly(hidden, np.rint(corners).astype(np.int32), 0)
    return hidden


def test_a_wide_shaft_is_bridged_with_the_bridged_points_flagged_on_the_hidden_centreline():
    truth = _curve()
    mask = _shaft(_draw(truth), truth, 0.45, SHAFT_PX)
    result = order_sequence(mask, truth[0])
    assert result.bridges == 1
    bridged = result.points[result.bridged]
    # The whole hidden stretch is bridged (about SHAFT_PX points) and the sequence goes on to the end.
    assert SHAFT_PX - 10 <= len(bridged) <= SHAFT_PX + 25
    assert np.hypot(*(result.points[-1] - truth[-1])) < 4.0
    # Bridged points lie within a few px of the hidden true centreline (the last seen points at
    # the shaft's oblique edge are up to 2 px off it already); those seen on it.
    distance, _ = cKDTree(truth).query(result.points)
    assert distance[result.bridged].max() < 3.5
    assert np.median(distance[result.bridged]) < 2.5
    assert distance[~result.bridged].max() < 2.5
    hidden = mask[np.rint(bridged[:, 1]).astype(int), np.rint(bridged[:, 0]).astype(int)] == 0
    assert hidden.mean() > 0.9


def test_the_stereo_ordering_publishes_the_bridged_stretch_flagged_in_both_views():
    camera = StereoCamera.default(W, H)
    truth = _curve()
    left = _shaft(_draw(truth), truth, 0.45, SHAFT_PX)
    right = np.zeros_like(left)
    right[:, :-25] = left[:, 25:]
    ordering = order_stereo(left, right, truth[0], camera)
    for sequence, visible, shift in (
        (ordering.left_sequence, ordering.left, 0),
        (ordering.right_sequence, ordering.right, 25),
    ):
        assert sequence.shape[1] == 3 and set(np.unique(sequence[:, 2])) == {0.0, 1.0}
        seen = sequence[sequence[:, 2] == 0, :2]
        # the visible points, plus the bridge's ends that still lie on the mask, as seen
        kept = (seen[:, None] == visible[None]).all(axis=2).any(axis=0)
        assert kept.all() and len(seen) - len(visible) < 12
        mask = left if shift == 0 else right
        flagged = sequence[sequence[:, 2] == 1, :2]
        assert SHAFT_PX - 10 < len(flagged) < 1.5 * SHAFT_PX  # the thread crosses the shaft obliquely
        u, v = np.rint(flagged).astype(int).T
        assert not mask[v, u].any()  # not seen: off the mask
        distance, _ = cKDTree(truth - [shift, 0]).query(flagged)
        assert distance.max() < 3.5


def test_a_bridged_stretch_that_the_low_mask_covers_is_published_as_seen_and_one_under_a_shaft_is_not():
    # The masks lose 40 px of the thread in both views (faint there); the low masks keep it.
    camera = StereoCamera.default(W, H)
    truth = _curve()

    def pair(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return mask, np.roll(mask, -25, axis=1)

    masks = pair(_shaft(_draw(truth), truth, 0.45, 40))
    alone = order_stereo(*masks, truth[0], camera)
    assert all(
        25 < (sequence[:, 2] == 1).sum() < 70 for sequence in (alone.left_sequence, alone.right_sequence)
    )
    faint = order_stereo(*masks, truth[0], camera, low_masks=pair(_draw(truth)))
    assert not faint.low_masks_used  # the masks' own sequences, their bridge now seen
    np.testing.assert_array_equal(faint.left_sequence[:, :2], alone.left_sequence[:, :2])
    assert not faint.left_sequence[:, 2].any() and not faint.right_sequence[:, 2].any()
    # Low masks that lose the stretch too (a shaft hides it) leave it flagged.
    hidden = order_stereo(*masks, truth[0], camera, low_masks=masks)
    np.testing.assert_array_equal(hidden.left_sequence, alone.left_sequence)
    np.testing.assert_array_equal(hidden.right_sequence, alone.right_sequence)


def test_seen_in_low_mask_keeps_flagged_the_part_of_a_stretch_off_the_low_mask():
    sequence = np.column_stack([np.arange(20.0), np.full(20, 10.0), np.zeros(20)])
    sequence[5:15, 2] = 1.0
    low = np.zeros((H, W), np.uint8)
    low[10, :9] = 255  # u 0-8: the points up to u 9 lie within 1 px of it
    flags = seen_in_low_mask(sequence, low)[:, 2]
    np.testing.assert_array_equal(np.flatnonzero(flags), np.arange(10, 15))
    np.testing.assert_array_equal(sequence[5:15, 2], 1.0)  # the input is left as it was


@pytest.mark.parametrize("angle_deg", [60.0, 75.0, 90.0])
@pytest.mark.parametrize("lost_to", [315, 327])
def test_a_thread_the_mask_lost_just_past_a_crossing_is_bridged_across_the_other_strand(angle_deg, lost_to):
    """Our thread along row 240 from u = 100, crossed at u = 300 by a straight strand; the mask lost
    our thread from the crossing to ``lost_to`` (a segmenter often loses the lower strand there).
    The search neither turns onto the other strand nor stops on it: it bridges the gap."""
    ours = np.column_stack([np.arange(100.0, 561.0), np.full(461, 240.0)])
    t = np.radians(angle_deg)
    other = np.array([300.0, 240.0]) + np.linspace(-200, 200, 401)[:, None] * [np.cos(t), -np.sin(t)]
    mask = _draw(ours)
    mask[235:246, 300:lost_to] = 0
    mask |= _draw(other)
    result = order_sequence(mask, ours[0])
    assert result.points[-1, 0] > 555
    assert np.abs(result.points[:, 1] - 240).max() < 2.5  # never on the other strand
    assert result.bridges <= 1  # a gap within the junction's circle is crossed in its one step
    bridged_u = result.points[result.bridged, 0]
    assert np.all((bridged_u > 280) & (bridged_u < lost_to + 2))


def test_a_thread_ending_where_another_strand_crosses_its_way_is_not_joined_to_it():
    truth = _curve()[:900]  # ends at its real free end
    end = truth[-1]
    direction = (truth[-1] - truth[-20]) / np.hypot(*(truth[-1] - truth[-20]))
    normal = np.array([-direction[1], direction[0]])
    beyond = end + 90 * direction
    crossing = np.linspace(beyond - 150 * normal, beyond + 150 * normal, 400)
    mask = _draw(truth) | _draw(crossing)
    result = order_sequence(mask, truth[0])
    assert result.bridges == 0
    assert np.hypot(*(result.points[-1] - end)) < 4.0


def test_a_thread_ending_where_another_strand_starts_at_an_angle_is_not_joined_to_it():
    truth = _curve()[:900]
    end = truth[-1]
    direction = (truth[-1] - truth[-20]) / np.hypot(*(truth[-1] - truth[-20]))
    normal = np.array([-direction[1], direction[0]])
    start = end + 90 * direction
    # Another strand starting beyond the gap, facing it, but leaving 60 degrees off the way.
    away = np.cos(np.radians(60)) * direction + np.sin(np.radians(60)) * normal
    other = start + np.arange(0, 200)[:, None] * away
    result = order_sequence(_draw(truth) | _draw(other), truth[0])
    assert result.bridges == 0
    assert np.hypot(*(result.points[-1] - end)) < 4.0


def test_a_thread_ending_where_another_strand_starts_beside_its_line_is_not_joined_to_it():
    truth = _curve()[:900]
    end = truth[-1]
    direction = (truth[-1] - truth[-20]) / np.hypot(*(truth[-1] - truth[-20]))
    normal = np.array([-direction[1], direction[0]])
    for side in (1, -1):
        # Parallel to the thread's end, 90 px on and 30 px beside its line: joining it would take
        # an S-bend that the thread's end does not announce.
        start = end + 90 * direction + side * 30 * normal
        other = start + np.arange(0, 200)[:, None] * direction
        result = order_sequence(_draw(truth) | _draw(other), truth[0])
        assert result.bridges == 0
        assert np.hypot(*(result.points[-1] - end)) < 4.0


def test_a_straight_continuation_beyond_the_reach_is_not_bridged():
    truth = _curve()
    mask = _shaft(_draw(truth), truth, 0.45, 200)  # 200 px hidden: beyond occluder_reach_px
    result = order_sequence(mask, truth[0])
    assert result.bridges == 0 and not result.bridged.any()


def test_flagged_sequence_puts_the_bridged_stretch_back_between_its_ends():
    points = np.column_stack([np.arange(10.0), np.zeros(10)])
    bridged = np.zeros(10, bool)
    bridged[4:7] = True
    visible = points[~bridged]
    flagged = flagged_sequence(visible, points, bridged)
    np.testing.assert_array_equal(flagged[:, :2], points)
    np.testing.assert_array_equal(flagged[:, 2], bridged.astype(float))
    # A stretch whose ends no longer follow each other (replaced by the other view) stays out.
    spliced = np.vstack([visible[:4], [[3.5, 1.0]], visible[4:]])
    assert flagged_sequence(spliced, points, bridged)[:, 2].sum() == 0


def test_end_direction_measures_the_tangent_and_curvature_of_an_arc():
    radius = 80.0
    angle = np.linspace(0, 0.6, 60)
    arc = np.column_stack([radius * np.sin(angle), radius * (1 - np.cos(angle))])
    tangent, curvature = end_direction(arc)
    np.testing.assert_allclose(tangent, [np.cos(0.6), np.sin(0.6)], atol=0.01)
    assert abs(curvature * radius - 1) < 0.15


@pytest.mark.parametrize("spacing", [1.0, 0.3, 2.5])
def test_the_fitted_tail_is_the_whole_paths_end(spacing):
    rng = np.random.default_rng(7)
    start = np.array([100.0, 100.0])
    segments = [
        start + np.cumsum(rng.uniform(0.5, 1.5, (k, 2)) * spacing, axis=0) for k in (5, 9, 3, 12, 7, 8)
    ]
    branch = Branch(
        rows=np.arange(1), consumed=np.zeros((4, 4), np.uint8), vertices=[start], segments=segments
    )
    path = np.vstack([start, *segments])
    full = np.cumsum(np.hypot(*np.diff(path[::-1], axis=0).T))
    for length in (3.0, 20.0, 1e6):
        tail, arc_back = _path_back(branch, length)
        assert np.array_equal(tail, path[-len(tail) :])
        assert np.array_equal(arc_back, full[: len(arc_back)])
        assert arc_back[-1] >= length or len(tail) == len(path)
