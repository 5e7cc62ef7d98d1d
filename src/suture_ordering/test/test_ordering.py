# SPDX-License-Identifier: Apache-2.0
"""Behaviour of the ordering core on synthetic masks drawn with cv2 and on the sample bag.

Every scene states the thread's true centreline; a result is checked against it:
starts at the cut tip, stays on the centreline, advances along it, reaches its end.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import median_filter
from scipy.spatial import cKDTree

from suture_common import messages, topics
from suture_common.bag_io import read_messages
from suture_common.camera import StereoCamera
from suture_ordering import (
    EmptyMaskError,
    InvalidInputError,
    NoFreeEndError,
    OrderingParams,
    TipNotOnThreadError,
    TipOutsideImageError,
    order_sequence,
    order_stereo,
)
from suture_ordering.cleaning import fill_holes_remove_specks
from suture_ordering.core import _tip_arcs
from suture_ordering.hooks import _smoothed
from suture_ordering.stereo_fill import continue_from_other_view, splice_skipped_stretch
from suture_ordering.tip import free_ends, right_tip_across_gap, tip_across_gap, tip_from_hint

W, H = 640, 480
SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"


def line(a: tuple[float, float], b: tuple[float, float]) -> np.ndarray:
    """(N, 2) points ~0.5 px apart from a to b."""
    n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) * 2))
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.asarray(a, float) + t * (np.asarray(b, float) - np.asarray(a, float))


def draw(curves: list[np.ndarray], width: int = 3, shape: tuple[int, int] = (H, W)) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    for curve in curves:
        cv2.polylines(mask, [np.rint(curve).astype(np.int32)], False, 255, width)
    return mask


def check_follows(
    points: np.ndarray, truth: np.ndarray, tolerance: float = 2.5, coverage: float = 0.95
) -> None:
    """``points`` start at truth[0], stay within ``tolerance`` px of ``truth``, advance along it
    and reach ``coverage`` of its length.

    Each point is mapped to the first truth sample within ``tolerance`` that is not behind the
    previous point's sample by more than 10 samples (so the two passes of a loop's crossing are
    told apart)."""
    assert np.hypot(*(points[0] - truth[0])) <= 4.0, f"starts at {points[0]}, tip is {truth[0]}"
    tree = cKDTree(truth)
    previous = 0
    for point in points:
        near = np.sort(tree.query_ball_point(point, tolerance))
        ahead = near[near >= previous - 10]
        assert ahead.size, f"{point} is off the thread (or goes backwards) after truth sample {previous}"
        previous = max(previous, int(ahead[0]))
    assert previous >= coverage * (len(truth) - 1), "stops short of the thread's end"


# --------------------------------------------------------------------------- single threads


def test_straight_thread_is_ordered_from_the_hinted_tip():
    truth = line((100, 100), (500, 300))
    result = order_sequence(draw([truth]), np.array([103.0, 98.0]))
    check_follows(result.points, truth, tolerance=1.5)
    assert result.status == "free_end" and result.tip_source == "hint"
    assert np.all(np.diff(result.points, axis=0).__abs__().max(axis=1) <= 1.01)  # ~1 px apart


def test_the_other_end_as_hint_gives_the_reverse_order():
    truth = line((100, 100), (500, 300))
    result = order_sequence(draw([truth]), np.array([500.0, 300.0]))
    check_follows(result.points, truth[::-1], tolerance=1.5)


def test_holes_inside_the_mask_and_specks_beside_it_change_nothing():
    truth = line((80, 400), (560, 120))
    mask = draw([truth], width=9)
    rng = np.random.default_rng(4)
    for point in truth[rng.choice(len(truth), 25, replace=False)]:
        cv2.circle(mask, tuple(int(x) for x in point + rng.uniform(-1, 1, 2)), 1, 0, -1)  # 3x3 holes
    for _ in range(30):  # isolated specks of 1-2 px
        u, v = rng.integers(20, 620), rng.integers(20, 460)
        if cKDTree(truth).query([u, v])[0] > 12:
            mask[v : v + 2, u : u + 2] = 255
    assert (mask[np.rint(truth[:, 1]).astype(int), np.rint(truth[:, 0]).astype(int)] == 0).any()
    result = order_sequence(mask, truth[0])
    check_follows(result.points, truth, tolerance=2.0)


def test_a_small_loops_eye_is_kept_open_and_a_slit_or_a_dropout_in_a_thick_stroke_filled():
    mask = np.zeros((40, 200), np.uint8)
    cv2.circle(mask, (20, 20), 3, 1, 1)  # a loop of 1-px thread round an eye 3 px across
    mask[10:17, 60:72] = 1
    mask[13, 62:70] = 0  # merged arms with a 1-px slit between them
    mask[10:19, 130:190] = 1
    mask[13:16, 150:153] = 0  # a 3x3 dropout inside a 9 px stroke
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    holes = [cv2.contourArea(c) for c, h in zip(contours, hierarchy[0], strict=True) if h[3] >= 0]
    assert len(holes) == 3 and max(holes) <= OrderingParams().max_hole_area_px
    kept = mask.copy()
    fill_holes_remove_specks(kept, 20.0, min_eye_width=2)
    assert kept[20, 20] == 0 and (kept[13, 62:70] == 1).all() and (kept[13:16, 150:153] == 1).all()
    filled = mask.copy()
    fill_holes_remove_specks(filled, 20.0, min_eye_width=0)
    assert filled[20, 20] == 1
    with pytest.raises(ValueError, match="min_eye_width_px"):
        OrderingParams(min_eye_width_px=-1.0)


def test_a_16_px_gap_is_bridged_and_flagged():
    truth = line((60, 240), (580, 260))
    mask = draw([truth])
    cv2.rectangle(mask, (312, 200), (327, 300), 0, -1)  # 16 columns erased
    result = order_sequence(mask, truth[0])
    check_follows(result.points, truth, tolerance=2.0)
    assert result.bridges == 1 and result.bridged.sum() >= 10
    assert np.all(np.abs(result.points[result.bridged, 0] - 320) < 12)
    visible = result.visible
    assert np.max(np.hypot(*np.diff(visible, axis=0).T)) >= 16  # one jump across the gap


def test_a_gap_longer_than_tau_o_ends_the_sequence_unless_it_continues_across_an_occluder():
    truth = line((60, 240), (580, 240))
    mask = draw([truth])
    cv2.rectangle(mask, (300, 200), (379, 280), 0, -1)  # 80 px > tau_O = 2.6 * 24 px
    result = order_sequence(mask, truth[0], OrderingParams(occluder_reach_px=0.0))
    assert result.bridges == 0 and result.status == "free_end"
    assert 290 <= result.points[-1, 0] < 300
    # With the occluder bridging (the default) the thread beyond, straight on, is reached.
    result = order_sequence(mask, truth[0])
    assert result.bridges == 1 and result.points[-1, 0] > 575
    assert np.all(np.abs(result.points[result.bridged, 1] - 240) < 1.0)


def test_a_closed_ring_has_no_free_end():
    angle = np.linspace(0, 2 * np.pi, 1000)
    ring = np.column_stack([320 + 90 * np.cos(angle), 240 + 90 * np.sin(angle)])
    with pytest.raises(NoFreeEndError, match="closed ring"):
        order_sequence(draw([ring]), np.array([410.0, 240.0]))


def test_tip_at_the_image_border():
    truth = line((0, 200), (400, 330))
    result = order_sequence(draw([truth]), np.array([1.0, 201.0]))
    check_follows(result.points, truth, tolerance=2.5)  # cv2 draws a round cap cut by the border
    assert result.points[0, 0] <= 1.5


def test_thread_leaving_the_image_ends_at_the_border():
    truth = line((200, 200), (639, 330))
    result = order_sequence(draw([truth]), truth[0])
    check_follows(result.points, truth, tolerance=1.5)
    assert result.status == "image_border"


@pytest.mark.parametrize("hint", [(-20.0, 100.0), (700.0, 100.0), (100.0, 480.0), (np.nan, 10.0)])
def test_tip_hint_outside_the_image_is_refused(hint):
    with pytest.raises(TipOutsideImageError, match="outside|NaN"):
        order_sequence(draw([line((100, 100), (500, 300))]), np.array(hint))


def test_tip_hint_far_from_any_thread():
    with pytest.raises(TipNotOnThreadError, match="no thread pixel within 12 px"):
        order_sequence(draw([line((100, 100), (500, 300))]), np.array([300.0, 400.0]))


def test_bad_masks_raise_specific_errors():
    with pytest.raises(EmptyMaskError, match="empty"):
        order_sequence(np.zeros((H, W), np.uint8), np.array([10.0, 10.0]))
    with pytest.raises(EmptyMaskError, match="specks"):
        speck = np.zeros((H, W), np.uint8)
        speck[10:12, 10:12] = 255
        order_sequence(speck, np.array([10.0, 10.0]))
    with pytest.raises(InvalidInputError, match="uint8"):
        order_sequence(np.ones((H, W), np.float32), np.array([10.0, 10.0]))
    with pytest.raises(InvalidInputError, match="2D"):
        order_sequence(np.ones((H, W, 3), np.uint8), np.array([10.0, 10.0]))


def test_automatic_tip_takes_the_free_end_nearest_the_image_centre():
    truth = line((300, 230), (600, 420))
    result = order_sequence(draw([truth]), None)
    assert result.tip_source == "automatic"
    check_follows(result.points, truth, tolerance=1.5)


def test_a_sharp_hairpin_ends_the_search_tau_v():
    """Turning by more than tau_V = 120 degrees is not admissible: a fold ends the sequence."""
    first = line((100, 240), (400, 240))
    back = line((400, 240), (400 - 300 * math.cos(math.radians(25)), 240 - 300 * math.sin(math.radians(25))))
    result = order_sequence(draw([first, back]), first[0])
    assert result.points[:, 0].max() <= 405 and result.points[-1, 0] >= 390
    assert result.points[:, 1].min() >= 230  # did not follow the fold back


# --------------------------------------------------------------------------- crossings


def test_shallow_12_degree_crossing_continues_on_the_same_thread():
    truth = line((60, 240), (580, 240))
    a = math.radians(12)
    other = line(
        (320 - 220 * math.cos(a), 240 - 220 * math.sin(a)), (320 + 220 * math.cos(a), 240 + 220 * math.sin(a))
    )
    result = order_sequence(draw([truth, other]), truth[0])
    check_follows(result.points, truth, tolerance=2.0)


def test_right_angle_crossing_with_a_curved_thread():
    s = np.linspace(0, 1, 1500)
    truth = np.column_stack([60 + 500 * s, 360 - 260 * s + 120 * np.sin(np.pi * s)])
    other = line((330, 60), (330, 460))
    result = order_sequence(draw([truth, other]), truth[0])
    check_follows(result.points, truth, tolerance=2.0)


def test_two_threads_touching_side_by_side_for_a_stretch():
    truth = line((60, 240), (580, 240))
    # The other thread joins from below, runs alongside touching it for 160 px, and leaves.
    other = np.vstack(
        [line((100, 330), (220, 243)), line((220, 243), (380, 243)), line((380, 243), (540, 330))]
    )
    result = order_sequence(draw([truth, other]), truth[0])
    check_follows(result.points, truth, tolerance=2.0)
    # The same from above.
    other = np.vstack(
        [line((100, 150), (220, 237)), line((220, 237), (380, 237)), line((380, 237), (540, 150))]
    )
    check_follows(order_sequence(draw([truth, other]), truth[0]).points, truth, tolerance=2.0)


def test_a_loop_is_traversed_through_its_own_crossing():
    t = np.linspace(-1.1 * np.pi, 1.1 * np.pi, 3000)  # a prolate cycloid: one loop
    truth = np.column_stack([320 + 45 * t - 70 * np.sin(t), 240 - 70 * np.cos(t)])
    result = order_sequence(draw([truth]), truth[0])
    check_follows(result.points, truth, tolerance=2.5)
    assert result.length_px >= 0.95 * float(np.hypot(*np.diff(truth, axis=0).T).sum())


# --------------------------------------------------------------------------- stereo


def _shifted(mask: np.ndarray, disparity: int) -> np.ndarray:
    right = np.zeros_like(mask)
    right[:, : W - disparity] = mask[:, disparity:]
    return right


def test_order_stereo_finds_the_right_tip_on_the_same_row():
    camera = StereoCamera.default(W, H)  # disparity 17..52 px for 50..150 mm
    s = np.linspace(0, 1, 1200)
    truth = np.column_stack([150 + 380 * s, 120 + 250 * s + 60 * np.sin(3 * s)])
    left = draw([truth])
    result = order_stereo(left, _shifted(left, 30), truth[0] + 1.5, camera)
    check_follows(result.left, truth, tolerance=1.5)
    check_follows(result.right, truth - [30, 0], tolerance=1.5)
    assert result.right_result.tip_source == "epipolar"
    assert abs(result.left_result.tip[1] - result.right_result.tip[1]) <= 1.0


def test_order_stereo_finds_a_right_tip_the_segmenter_shortened():
    # A steep thread whose faint tip the segmenter missed in the right view only (4 rows): its free
    # end there lies 4-5 rows below the left tip's row (fresh sets: 8 of 400 frames were lost so).
    camera = StereoCamera.default(W, H)
    truth = line((300, 100), (330, 400))
    left = draw([truth])
    right = _shifted(draw([truth[truth[:, 1] >= 104.5]]), 30)
    result = order_stereo(left, right, truth[0], camera)
    assert 3.5 <= result.right_result.tip[1] - result.left_result.tip[1] <= 6.0
    check_follows(result.right, truth[truth[:, 1] >= 104.5] - [30, 0], tolerance=1.5)
    with pytest.raises(NoFreeEndError, match="right view"):  # the tolerance is what finds it
        order_stereo(left, right, truth[0], camera, OrderingParams(row_tolerance_px=3.0))


def test_order_stereo_rejects_a_right_tip_outside_the_disparity_range():
    camera = StereoCamera.default(W, H)
    left = draw([line((300, 100), (500, 300))])
    with pytest.raises(TipNotOnThreadError, match="right view"):
        order_stereo(left, _shifted(left, 90), np.array([300.0, 100.0]), camera)  # 90 px > 52 px


def test_order_stereo_rejects_masks_of_the_wrong_size():
    camera = StereoCamera.default(W, H)
    left = draw([line((300, 100), (500, 300))])
    with pytest.raises(InvalidInputError, match=r"expected \(H, W\) = \(480, 640\)"):
        order_stereo(left, left[:, :600], np.array([300.0, 100.0]), camera)


def _faint_stretch_scene():
    """A thread whose masks lose a 92 px stretch in both views (the faint part the segmenter's
    probability left between its two thresholds), and low masks that keep it."""
    s = np.linspace(0, 1, 1500)
    truth = np.column_stack([150 + 380 * s, 120 + 250 * s + 60 * np.sin(3 * s)])
    low_left = draw([truth])
    masks = [draw([truth[:600], truth[900:]]), None]
    masks[1] = _shifted(masks[0], 30)
    return masks, (low_left, _shifted(low_left, 30)), truth


def test_low_masks_carry_the_sequences_across_a_faint_stretch():
    camera = StereoCamera.default(W, H)
    (left, right), low, truth = _faint_stretch_scene()
    # The search alone (not bridging it as an occluder) stops at the faint stretch.
    params = OrderingParams(occluder_reach_px=0.0)
    alone = order_stereo(left, right, truth[0] + 1.0, camera, params)
    assert not alone.low_masks_used and alone.left_result.length_px < 250  # of ~480 px: stops there
    result = order_stereo(left, right, truth[0] + 1.0, camera, params, low_masks=low)
    assert result.low_masks_used
    check_follows(result.left, truth, tolerance=1.5)
    check_follows(result.right, truth - [30, 0], tolerance=1.5)


def test_low_masks_that_reach_no_farther_leave_the_masks_sequences():
    # Low masks one pixel wider all along (the faint rim of a thread): same length, masks kept.
    camera = StereoCamera.default(W, H)
    s = np.linspace(0, 1, 1200)
    truth = np.column_stack([150 + 380 * s, 120 + 250 * s + 60 * np.sin(3 * s)])
    left = draw([truth])
    wider = cv2.dilate(left, np.ones((3, 3), np.uint8))
    alone = order_stereo(left, _shifted(left, 30), truth[0] + 1.5, camera)
    result = order_stereo(
        left, _shifted(left, 30), truth[0] + 1.5, camera, low_masks=(wider, _shifted(wider, 30))
    )
    assert not result.low_masks_used
    assert np.array_equal(result.left, alone.left) and np.array_equal(result.right, alone.right)


def test_low_masks_give_the_sequences_when_the_masks_miss_the_cut_tip():
    # The masks lost the faint cut end (30 px): no thread near the hint; the low masks keep it.
    camera = StereoCamera.default(W, H)
    (_, _), (low_left, low_right), truth = _faint_stretch_scene()
    left, right = low_left.copy(), low_right.copy()
    left[:, :185], right[:, :155] = 0, 0
    with pytest.raises(TipNotOnThreadError):
        order_stereo(left, right, truth[0], camera)
    result = order_stereo(left, right, truth[0], camera, low_masks=(low_left, low_right))
    assert result.low_masks_used
    check_follows(result.left, truth, tolerance=1.5)
    with pytest.raises(TipNotOnThreadError):  # low masks without the tip either: the masks' error
        order_stereo(left, right, truth[0], camera, low_masks=(left, right))
    with pytest.raises(InvalidInputError, match="left low view"):
        order_stereo(low_left, low_right, truth[0], camera, low_masks=(low_left[:, :600], low_right))


def _gap_in_right_view(gap_rows: tuple[int, int], disparity_after: float = 30.0):
    """A steep thread seen by both views, the right mask missing rows ``gap_rows`` of it; the
    disparity is 30 px before the gap and ``disparity_after`` beyond it (the thread rises)."""
    truth_left = line((250, 60), (330, 430))
    disparity = np.where(truth_left[:, 1] < gap_rows[0], 30.0, disparity_after)
    truth_right = truth_left - np.column_stack([disparity, np.zeros(len(disparity))])
    right_visible = (truth_right[:, 1] < gap_rows[0]) | (truth_right[:, 1] > gap_rows[1])
    before, after = truth_right[truth_right[:, 1] < gap_rows[0]], truth_right[truth_right[:, 1] > gap_rows[1]]
    return draw([truth_left]), draw([before, after]), truth_left, truth_right, right_visible


def test_a_gap_in_one_view_only_is_crossed_along_the_other_view():
    # 75 rows missing in the right mask: longer than its search bridges (tau_O = 62 px; not as an
    # occluder here), so alone it stops there and the thread is too short to grasp.
    camera = StereoCamera.default(W, H)
    left, right, truth_left, truth_right, right_visible = _gap_in_right_view((200, 275), 31.5)
    params = OrderingParams(stereo_fill_max_gap_px=0, occluder_reach_px=0.0)
    alone = order_stereo(left, right, truth_left[0], camera, params)
    assert alone.right[-1, 1] < 202 and alone.filled == (0, 0)
    assert alone.right_result.status == "free_end"

    params = OrderingParams(stereo_fill_max_gap_px=100, occluder_reach_px=0.0)
    result = order_stereo(left, right, truth_left[0], camera, params)
    check_follows(result.left, truth_left, tolerance=1.5)
    assert result.filled[0] == 0 and result.filled[1] > 100
    assert result.right[-1, 1] > 420  # on to the end
    filled = result.right[-result.filled[1] :]
    assert not np.any((filled[:, 1] > 203) & (filled[:, 1] < 272)), "a point made up inside the gap"
    # Each filled point is the right mask's own centre on its row: the disparity beyond the gap
    # (31.5 px, not the 30 px before it) is measured there, not copied from before the gap.
    true_u = np.interp(filled[:, 1], truth_right[right_visible, 1], truth_right[right_visible, 0])
    assert np.max(np.abs(filled[:, 0] - true_u)) <= 0.75


def test_a_stop_that_ends_in_a_hook_is_continued_from_before_the_hook():
    # The right mask's thread ends at the gap in an 8 px hook (a ragged mask end), so its search
    # ends 6 px off the path the left view shows; the hook is given up, the rest continued.
    camera = StereoCamera.default(W, H)
    left, _, truth_left, truth_right, right_visible = _gap_in_right_view((200, 275), 31.5)
    before, after = truth_right[truth_right[:, 1] < 200], truth_right[truth_right[:, 1] > 275]
    hook = line(tuple(before[-1]), (before[-1][0] + 8, before[-1][1] + 2))
    right = draw([before, hook, after])
    params = OrderingParams(stereo_fill_max_gap_px=100)
    result = order_stereo(left, right, truth_left[0], camera, params)
    assert result.right_result.visible[-1, 0] - before[-1][0] > 5  # the search ended on the hook
    assert result.filled[1] > 100 and result.right[-1, 1] > 420
    true_u = np.interp(result.right[:, 1], truth_right[right_visible, 1], truth_right[right_visible, 0])
    # at most the hook's root is kept (2.1 px off the thread); its tip lies 8 px off
    assert np.max(np.abs(result.right[:, 0] - true_u)) <= 2.5


def test_the_other_view_is_followed_only_across_gaps_up_to_the_limit():
    camera = StereoCamera.default(W, H)
    left, right, truth_left, _, _ = _gap_in_right_view((200, 275))
    params = OrderingParams(occluder_reach_px=0.0)  # the search alone stops at the gap
    result = order_stereo(left, right, truth_left[0], camera, params)  # default limit: 60 px
    assert result.filled == (0, 0) and result.right[-1, 1] < 202


def test_a_gap_the_other_view_bridged_is_followed_however_wide_it_is():
    # A shaft hides rows 200-290 in both views; the left view's search bridged it (its points
    # there flagged not seen), the right view's stopped. The right mask's gap, 90 px, is wider
    # than the fill's limit, which counts only the left view's seen thread.
    truth_left = line((250, 60), (330, 430))
    hidden = (truth_left[:, 1] > 200) & (truth_left[:, 1] < 290)
    truth_right = truth_left - [30.0, 0.0]
    right = draw([truth_right[truth_right[:, 1] <= 200], truth_right[truth_right[:, 1] >= 290]])
    own = truth_right[truth_right[:, 1] <= 199]
    args = (own, right, truth_left, 1.0, (5.0, 200.0))
    unflagged, added = continue_from_other_view(*args, max_gap=60.0)
    assert added == 0 and len(unflagged) == len(own)
    sequence, added = continue_from_other_view(*args, max_gap=60.0, guide_not_seen=hidden)
    assert added > 100 and sequence[-1, 1] > 420
    beyond = sequence[len(own) :]
    assert not np.any((beyond[:, 1] > 203) & (beyond[:, 1] < 287)), "a point made up under the shaft"
    true_u = np.interp(beyond[:, 1], truth_right[:, 1], truth_right[:, 0])
    assert np.max(np.abs(beyond[:, 0] - true_u)) <= 1.0  # the centres of the right mask's runs


def test_the_other_view_adds_nothing_this_views_mask_does_not_show():
    # The right view's thread really ends at row 200 (nothing below it in the right mask).
    camera = StereoCamera.default(W, H)
    truth_left = line((250, 60), (330, 430))
    right = draw([truth_left[truth_left[:, 1] < 200] - [30, 0]])
    result = order_stereo(draw([truth_left]), right, truth_left[0], camera)
    assert result.filled == (0, 0) and result.right[-1, 1] < 202


def _loop_thread() -> tuple[np.ndarray, np.ndarray]:
    """A thread crossing itself (a nodal cubic: the crossing at t = -1 and t = 1), ~1 px apart,
    and whether each point lies on the loop between the two passes."""
    t = np.linspace(-1.6, 1.6, 20000)
    curve = np.column_stack([320 + 100 * (t**2 - 1), 240 + 60 * (t**3 - t)])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(curve, axis=0).T))])
    keep = np.searchsorted(arc, np.arange(0.0, arc[-1], 1.0))
    return curve[keep], np.abs(t[keep]) < 1.0


def test_a_loop_one_view_cut_across_is_put_back_from_the_other_view():
    camera = StereoCamera.default(W, H)
    truth, on_loop = _loop_thread()
    shortcut = truth[~on_loop]  # the left search went straight from the first pass to the second
    left_mask = draw([truth])
    d_range = (camera.disparity(0.15), camera.disparity(0.05))
    spliced, added = splice_skipped_stretch(shortcut, left_mask, truth - [30, 0], -1.0, d_range)
    assert added >= 0.9 * on_loop.sum()
    check_follows(spliced, truth, tolerance=1.0, coverage=0.99)

    # The loop the other view went round is not in this view's mask: nothing is put back.
    unchanged, added = splice_skipped_stretch(shortcut, draw([shortcut]), truth - [30, 0], -1.0, d_range)
    assert added == 0 and unchanged is shortcut


def test_a_stretch_the_other_view_walked_out_and_back_is_not_put_back():
    """The other view's sequence went out along a crossing strand to its free end and back (the
    mask lost the strand beyond the crossing); this view crossed straight. Every point of that
    stretch lies on thread it passes twice: no loop of ours, nothing to put back."""
    camera = StereoCamera.default(W, H)
    thread, strand = line((100, 150), (500, 350))[::2], line((300, 250), (345, 185))[::2]
    crossing = int(np.argmin(np.hypot(*(thread - strand[0]).T)))
    out_and_back = np.vstack([thread[:crossing], strand, strand[::-1], thread[crossing:]])
    d_range = (camera.disparity(0.15), camera.disparity(0.05))
    mask = draw([thread, strand])
    kept, added = splice_skipped_stretch(thread, mask, out_and_back - [30, 0], -1.0, d_range)
    assert added == 0 and kept is thread


def test_params_scale_with_the_image_width():
    truth = line((200, 200), (1000, 700))
    mask = draw([truth], width=5, shape=(1024, 1280))
    result = order_sequence(mask, truth[0])
    check_follows(result.points, truth, tolerance=2.0)
    assert result.steps < 0.7 * len(
        order_sequence(mask, truth[0], OrderingParams(reference_width_px=None)).points
    )


def test_sample_bag_frames_are_ordered_like_the_ground_truth():
    """Every frame of bags/sample (2 per topology, 640x480) with ground-truth masks."""
    wanted = (
        topics.GT_LEFT_MASK,
        topics.GT_RIGHT_MASK,
        topics.GT_LEFT_SEQUENCE,
        topics.GT_RIGHT_SEQUENCE,
        topics.TIP_HINT,
        topics.LEFT_CAMERA_INFO,
        topics.RIGHT_CAMERA_INFO,
    )
    frames: dict[int, dict] = {}
    for record in read_messages(SAMPLE_BAG, wanted):
        frames.setdefault(record.timestamp_ns, {})[record.topic] = record.message
    assert len(frames) >= 10
    for frame in frames.values():
        camera = StereoCamera.from_camera_info(
            frame[topics.LEFT_CAMERA_INFO], frame[topics.RIGHT_CAMERA_INFO]
        )
        result = order_stereo(
            messages.image_to_array(frame[topics.GT_LEFT_MASK]),
            messages.image_to_array(frame[topics.GT_RIGHT_MASK]),
            messages.point_to_array(frame[topics.TIP_HINT])[:2],
            camera,
        )
        for points, truth_topic in (
            (result.left, topics.GT_LEFT_SEQUENCE),
            (result.right, topics.GT_RIGHT_SEQUENCE),
        ):
            truth = messages.polygon_to_array(frame[truth_topic])[:, :2]
            distance, index = cKDTree(truth).query(points)
            assert np.hypot(*(points[0] - truth[0])) <= 5.0
            assert np.percentile(distance, 99) <= 3.0
            assert index.max() >= 0.9 * len(truth)


def test_noise_masks_are_refused_at_once_instead_of_ordered_for_minutes():
    """A speckle or all-white mask is not a thread: refused in milliseconds, with the reason."""
    camera = StereoCamera.default(640, 480)
    speckle = (np.random.default_rng(0).random((480, 640)) < 0.5).astype(np.uint8) * 255
    for mask in (speckle, np.full((480, 640), 255, np.uint8)):
        with pytest.raises(InvalidInputError, match="max_mask_fraction"):
            order_stereo(mask, mask, None, camera)


# --------------------------------------------------------------------------- predicted masks


def test_a_predicted_mask_is_followed_straight_across_a_crossing():
    """A segmenter's mask of a simulated frame (fresh set seed 707, frame 48): the last step
    before the crossing is pulled towards the other strand, and the tangent of that step alone
    made every arm look like a sharp turn, so the sequence ended at the crossing (194 of the
    thread's 410 points); the tangent of the path over the last Υ crosses it."""
    stored = np.load(Path(__file__).parent / "data" / "predicted_crossing.npz")
    mask = np.unpackbits(stored["mask"])[: int(np.prod(stored["shape"]))].reshape(stored["shape"])
    result = order_sequence(mask, stored["hint"])
    check_follows(result.points, stored["truth"].astype(float), tolerance=2.5)


def test_a_predicted_mask_is_followed_out_of_a_loop_across_its_own_first_pass():
    """A segmenter's mask of a simulated frame (fresh set seed 7003, frame 222): the thread comes
    back round its loop to a crossing where the way out leaves along the first pass's track, so
    the nearer nodes ahead were all detected and the chord to the first free one cut the curve
    outside the zone; the sequence ended at the crossing (201 of the thread's 274 px) and the
    frame had no grasp point. The step across the thread's own path takes it to the end."""
    stored = np.load(Path(__file__).parent / "data" / "predicted_loop_exit.npz")
    mask = np.unpackbits(stored["mask"])[: int(np.prod(stored["shape"]))].reshape(stored["shape"])
    result = order_sequence(mask, stored["hint"])
    check_follows(result.points, stored["truth"].astype(float), tolerance=2.5)
    assert result.status == "free_end"


def test_a_predicted_mask_is_followed_round_a_small_loop_entered_tangentially():
    """A segmenter's mask of a simulated frame (fresh set seed 7002, frame 102): the loop (about
    20 px across) leaves the thread at a shallow angle and runs merged with the way out past the
    nearest circle, whose one node ahead (a 36 degree turn) was the way out's; the sequence cut the
    loop (390 of the thread's 513 px) and the grasp point was 20 mm off. A step turning that
    sharply is decided across the junction, which enters the loop first."""
    stored = np.load(Path(__file__).parent / "data" / "predicted_small_loop.npz")
    mask = np.unpackbits(stored["mask"])[: int(np.prod(stored["shape"]))].reshape(stored["shape"])
    result = order_sequence(mask, stored["hint"])
    check_follows(result.points, stored["truth"].astype(float), tolerance=2.5)


# --------------------------------------------------------------------------- hooks at the cut tip


def curve_from_curvature(
    start: tuple[float, float], heading: float, pieces: list[tuple[float, float]]
) -> np.ndarray:
    """(N, 2) points 0.5 px apart from ``start`` along ``pieces`` of (length px, curvature 1/px)."""
    step = 0.5
    kappa = np.concatenate([np.full(round(length / step), k) for length, k in pieces])
    angle = heading + np.concatenate([[0.0], np.cumsum(kappa * step)])
    offsets = np.cumsum(np.column_stack([np.cos(angle), np.sin(angle)]) * step, axis=0)
    return np.vstack([start, np.asarray(start) + offsets[:-1]])


def hairpin() -> np.ndarray:
    """Tip at (300, 240); its arm runs left 60 px to a bend of radius 1.5 px and comes back
    1.5 px beside it (the arms merge into one stroke), passes the tip and goes on 260 px."""
    arm = line((300, 240), (240, 240))
    angle = np.linspace(-math.pi / 2, -3 * math.pi / 2, 12)
    bend = np.column_stack([240 + 1.5 * np.cos(angle), 241.5 + 1.5 * np.sin(angle)])
    return np.vstack([arm, bend, line((240, 243), (560, 243))])


def test_a_thin_diagonal_threads_end_eaten_back_by_thinning_is_found():
    """A thread 3 px wide at 45 degrees (four pixels a row, as the simulator draws a thin
    straight thread) whose cut end tapers to three and two pixels: thinning eats its skeleton back
    36 px from the end, out of the hint's reach (12 px). Where the skeleton has no end near the
    hint, the ends of the other thinning (skimage's thin, which keeps that end) are read, and the
    tip is found at the cut end, not refused with NoFreeEndError."""
    mask = np.zeros((80, 80), dtype=np.uint8)
    for row in range(10, 60):
        mask[row, row - 6 : row - 2] = 1
    mask[60, 54:57] = 1
    mask[61, 55:57] = 1
    cut_end = np.array([55.5, 61.0])
    assert np.hypot(*(free_ends(mask) - cut_end).T).min() > 12.0
    tip = tip_from_hint(mask, cut_end + np.array([1.0, 0.5]), 12.0)
    assert np.hypot(*(tip - cut_end)) < 2.0


def test_hairpin_with_merged_arms_is_ordered_from_the_tip_inside_the_stroke():
    truth = hairpin()
    mask = draw([truth], width=2)
    hint = truth[0] + (1.0, 1.0)
    with pytest.raises(NoFreeEndError):  # the tip is no free end of the mask
        tip_from_hint(mask > 0, hint, 12.0)
    result = order_sequence(mask, hint)
    check_follows(result.points, truth, tolerance=3.0)  # the merged stroke's centre: 1.5 px off
    assert result.points[:, 0].min() < 245  # to the bend (its apex at 238.5) before coming back
    assert result.points[-1, 0] > 550


def test_low_masks_that_keep_a_hairpins_bend_the_masks_lost_give_the_sequences():
    # The masks paint the hairpin's merged arms but lose its last 12 px and the bend (a faint
    # bend whose probability stayed between the thresholds); the low masks keep them. The whole
    # threads differ by under 10 %, but near the tip the low masks' sequences hold ~24 px more.
    camera = StereoCamera.default(W, H)
    truth = hairpin()
    low = draw([truth], width=2)
    masks = low.copy()
    masks[:, :252] = 0
    hint = truth[0] + (1.0, 1.0)
    lost = order_stereo(
        masks,
        _shifted(masks, 30),
        hint,
        camera,
        OrderingParams(low_mask_tip_gain_px=0.0),
        low_masks=(low, _shifted(low, 30)),
    )
    assert not lost.low_masks_used and lost.left[:, 0].min() > 248  # turned back where the mask ends
    result = order_stereo(masks, _shifted(masks, 30), hint, camera, low_masks=(low, _shifted(low, 30)))
    assert result.low_masks_used
    check_follows(result.left, truth, tolerance=3.0)
    check_follows(result.right, truth - [30, 0], tolerance=3.0)
    assert result.left[:, 0].min() < 245 and result.right[:, 0].min() < 215  # round the bend


def test_tip_arcs_count_thread_off_the_masks_sequence_not_a_second_lap_over_it():
    sequence = line((0, 0), (100, 0))  # leaves the 48 px window at u = 48
    lap = np.vstack([line((0, 0), (30, 0)), line((30, 0), (10, 0)), line((10, 0), (100, 0))])
    longer, unexplained = _tip_arcs(sequence, lap, 48.0, 2.0)
    assert longer == pytest.approx(40.0, abs=1.0) and unexplained == 0.0  # the same pixels again
    bend = np.vstack(
        [
            line((0, 0), (20, 0)),
            line((20, 0), (20, 10)),
            line((20, 10), (24, 10)),
            line((24, 10), (24, 0)),
            line((24, 0), (100, 0)),
        ]
    )
    longer, unexplained = _tip_arcs(sequence, bend, 48.0, 2.0)
    assert longer == pytest.approx(20.0, abs=1.0) and 16.0 < unexplained < 22.0  # the detour off it
    assert _tip_arcs(sequence, line((0, 5), (100, 5)), 48.0, 2.0) is None  # never passes u = 48, v = 0
    assert _tip_arcs(line((0, 0), (40, 0)), sequence, 48.0, 2.0) is None  # stays in the window


@pytest.mark.parametrize("width", [2, 3])
def test_small_closed_loop_at_the_tip_is_gone_round_then_left_across_the_tip_arm(width):
    """Tip arm 25 px, a loop of radius 8 px turning by 230 degrees, then straight across the
    tip arm 8 px from the tip and on, slanting out of the hook's window (drawn 3 px wide, its
    skeleton stops short of the window's edge by more than its width)."""
    radius, beta = 8.0, math.radians(50)
    to_line = radius * (1 + math.cos(beta)) / math.sin(beta)
    arm = 8.0 + radius * math.sin(beta) + math.cos(beta) * to_line
    truth = curve_from_curvature(
        (300.0, 240.0), math.pi, [(arm, 0.0), ((math.pi + beta) * radius, 1 / radius), (260.0, 0.0)]
    )
    result = order_sequence(draw([truth], width=width), truth[0])
    check_follows(result.points, truth)
    # Round the loop first: the sequence reaches the loop's far side before the long thread.
    far_side = int(np.argmin(result.points[:, 0]))
    assert result.points[far_side, 0] < 300 - arm - radius + 2
    assert np.hypot(*(result.points[-1] - truth[-1])) < 4


def teardrop(
    side: float, gap: float = 2.5, heading: float = math.pi + 0.3, start: tuple[float, float] = (300.0, 240.0)
) -> np.ndarray:
    """Tip at ``start``; its arm runs 20 px along ``heading``, bends outward (radius 12 px),
    round a bend of radius 6 px and back so that the returning arm lies ``gap`` px beside the
    tip arm (drawn 2 px wide, the arms merge into one stroke ending in a loop), and on 220 px.
    ``side``: +1 or -1, which way it curls."""
    bend, counter = 6.0, 12.0
    alpha = math.acos((gap / 2 + counter) / (bend + counter))
    pieces = [(20.0, 0.0), (counter * alpha, -1 / counter), ((math.pi + 2 * alpha) * bend, 1 / bend)]
    pieces += [(counter * alpha, -1 / counter), (220.0, 0.0)]
    return curve_from_curvature(start, heading, [(length, side * k) for length, k in pieces])


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_loop_at_the_end_of_merged_arms_is_entered_on_the_tip_arms_side(side):
    # The skeleton runs one line down the merged arms into a loop, the same both ways round;
    # the thread leaving the stroke lies on the returning arm's side.
    truth = teardrop(side)
    result = order_sequence(draw([truth], width=2), truth[0])
    check_follows(result.points, truth, tolerance=3.0)


@pytest.mark.parametrize("side", [1.0, -1.0])
@pytest.mark.parametrize("heading", [0.0, 0.52, 1.05, 2.09, 2.62, 5.76])
def test_loop_at_the_end_of_arms_1_5_px_apart_is_gone_round_the_way_the_thread_leaves(heading, side):
    # Arms 1.5 px apart drawn 2 px wide: the stroke is a pixel wider than the thread leaving it.
    # Near the stroke the leaving thread's skeleton still bends over from the stroke's centre,
    # and a skeleton a pixel wide runs up to a pixel aside: the leaving line is fitted to the
    # thread's mask pixels farther out.
    truth = teardrop(side, gap=1.5, heading=heading, start=(300.3, 240.6))
    result = order_sequence(draw([truth], width=2), truth[0])
    check_follows(result.points, truth, tolerance=3.0)


@pytest.mark.parametrize("heading", [0.0, 1.2])
def test_merged_arms_at_1280_are_walked_on_each_arm_not_down_the_strokes_centre(heading):
    # 1280 x 1024: a hairpin drawn 5 px wide whose arms lie 7 px apart merge into a stroke
    # whose centre (the skeleton) lies 3.5 px from either arm.
    gap, cos, sin = 7.0, math.cos(heading), math.sin(heading)
    angle = np.linspace(-math.pi / 2, -3 * math.pi / 2, 24)
    bend = np.column_stack([520 + gap / 2 * np.cos(angle), 500 + gap / 2 + gap / 2 * np.sin(angle)])
    truth = np.vstack([line((600, 500), (520, 500)), bend, line((520, 500 + gap), (1100, 500 + gap))])
    truth = (truth - (600, 500)) @ np.array([[cos, sin], [-sin, cos]]) + (600, 500)
    result = order_sequence(draw([truth], width=5, shape=(1024, 1280)), truth[0])
    off, _ = cKDTree(truth).query(result.points[:150])  # along the merged arms and back
    assert np.percentile(off, 90) < 1.5
    assert np.hypot(*(result.points[-1] - truth[-1])) < 4


def test_tip_at_the_crossing_of_a_small_loop_leaving_the_window_slanting_is_ordered():
    """A simulated hooked thread (640 x 480, true mask): its tip lies where the thread crosses
    its tip arm, so no end of the skeleton is near it (the other thinning keeps a stub at the tip,
    where the search starts and then walks the hook); the thread leaves the hook's window
    slanting, where the skeleton of the window's mask stops short of the window's edge by more
    than the spur length. The walk leaves the window there."""
    stored = np.load(Path(__file__).parent / "data" / "hooked_ring_at_tip.npz")
    mask = np.unpackbits(stored["mask"])[: int(np.prod(stored["shape"]))].reshape(stored["shape"])
    assert np.hypot(*(free_ends(mask) - stored["hint"]).T).min() > 12.0
    result = order_sequence(mask, stored["hint"])
    check_follows(result.points, stored["truth"].astype(float), tolerance=2.5)


def test_right_views_tip_inside_a_hook_is_found_from_the_left_tip():
    truth = hairpin()
    left = draw([truth], width=2)
    right = np.roll(left, -26, axis=1)
    ordering = order_stereo(left, right, truth[0] + (1.0, -1.0), StereoCamera.default(640, 480))
    check_follows(ordering.left, truth, tolerance=3.0)
    check_follows(ordering.right, truth - (26.0, 0.0), tolerance=3.0)


def test_another_strand_near_the_right_tip_is_not_read_as_a_hook():
    """A simulator frame (crossed, 640x480) whose second strand passes ~60 px from the cut tip,
    nearer to it in the right view than in the left: the left view sees no hook, so the right
    view, the same thread, follows its free end along the target rather than walking onto the
    other strand (which took the grasp 35 mm away)."""
    check_stored_stereo_frame("crossing_near_the_right_tip.npz")


def test_right_view_goes_round_a_hooks_loop_the_way_the_left_view_does():
    """A simulator frame (hooked, 640x480, true masks): the tip arm and the returning arm lie
    on top of each other in a stroke 2 px wide that ends in a loop, the tip inside the stroke.
    The right view's skeleton is the same both ways round the loop and its least-turning walk
    went round against the thread (the grasp came out 34 mm off); the right view's walk now
    follows the left view's, shifted by the tip's disparity."""
    check_stored_stereo_frame("hooked_loop_merged_arms_stereo.npz")


def test_loop_at_the_end_of_long_merged_arms_is_gone_round_the_way_a_bending_thread_leaves():
    """A simulator frame (hooked, 640x480, true masks): merged arms 35 px long end in a loop,
    and the thread leaving them bends gently. Its line, extended along the whole stroke, strays
    by about as much as the arms lie apart (the whole stroke's side: 0.04 px, which tells
    nothing); measured within a chord of where the thread leaves, it is the returning arm's."""
    check_stored_stereo_frame("hooked_long_merged_arms_bending_away.npz")


def test_right_view_goes_round_a_loop_a_tenth_of_its_walk_the_way_the_left_view_does():
    """A simulator frame (hooked, 1280x1024, true masks): a loop at the end of merged arms, a
    tenth of the hook's walk, whose two ways round turn alike (0.85 and 0.90 rad in the right
    view). The left view's guide tells them apart only along the loop: the walks are compared
    with it by their largest distance, not by a percentile that leaves the loop out."""
    check_stored_stereo_frame("hooked_right_loop_a_tenth_of_the_walk_1280.npz")


def test_small_loop_at_the_end_of_merged_arms_has_its_arms_compared_before_its_half():
    """A simulator frame (hooked, 1280x1024, true masks): merged arms about 70 px long end in a
    loop of 20 px of skeleton, shorter than two chords. Its arms, compared half a chord to a
    chord from either end, were each sampled past the loop's half, on the other arm's side, and
    the walk went round against the thread; they are compared within a quarter of the loop.
    (The sequences stop about 60 px before the far end, within the evaluator's 90 %.)"""
    check_stored_stereo_frame("hooked_small_loop_after_merged_arms_1280.npz", coverage=0.9)


@pytest.mark.parametrize(
    "name",
    [
        "hooked_hairpin_merged_arms_split_by_leaving_thread.npz",
        "hooked_loop_merged_arms_split_by_leaving_thread.npz",
    ],
)
def test_merged_arms_are_moved_apart_to_the_side_the_leaving_threads_mask_gives(name):
    """Simulator frames (hooked, 640x480, true masks): merged arms from the tip down to a
    hairpin's bend, and down to a loop. The side the thread leaves the stroke by, read on the
    skeleton near the stroke, was under half a pixel (-0.35, -0.48) in the left view, so the walk
    stayed on the stroke's centre, the tip arm's outer pixels lay off it and the ordering refused
    (UnexplainedTipError); in the hairpin's right view it had the wrong sign. Read on the leaving
    thread's own mask pixels, as the way round a loop is, it is 1.7-1.9 px, and both views walk
    each arm."""
    check_stored_stereo_frame(name)


def test_a_walks_turn_at_a_hairpins_bend_stays_where_the_walk_turned():
    # Down one arm to the bend and back along the other, 4 px apart: averaged across the U-turn,
    # the bend is pulled 1.7 px in; cut there and each side smoothed as its own end, it stays.
    down = np.column_stack([np.arange(0.0, 30.0), np.zeros(30)])
    back = np.column_stack([np.arange(29.0, -1.0, -1.0), np.full(30, 4.0)])
    path = np.vstack([down, [[30.0, 2.0]], back])
    averaged, kept = _smoothed(path, keep_start=False), _smoothed(path, keep_start=False, turns=[30])
    assert averaged[:, 0].max() < 28.5
    np.testing.assert_allclose(kept[30], path[30])
    assert kept.shape == path.shape
    np.testing.assert_allclose(kept[5:25], averaged[5:25])  # away from the bend: the same
    np.testing.assert_allclose(kept[36:56], averaged[36:56])


def test_a_hairpins_bend_is_on_the_sequence_so_the_tip_check_explains_it():
    """A simulator frame (hooked, 640x480, true masks): a hairpin 15 px long, arms 4 px apart. The
    walk turned at the bend's end, but the smoothing averaged across the U-turn and pulled the
    left view's bend 2.5 px in; 11 px of the bend's rim lay off the sequence and the ordering
    refused (UnexplainedTipError)."""
    check_stored_stereo_frame("hooked_hairpin_bend_kept_through_the_smoothing.npz")


def test_arms_touching_beside_the_tip_are_one_place_of_the_hooks_walk():
    """A simulator frame (hooked, 640x480, true masks): a hairpin whose arms lie a pixel apart
    and touch diagonally next to the cut tip, so that thinning leaves a cycle 2 px long between
    the tip and a junction. The walk had to pass that little branch too and went up the
    returning arm, round the bend and down the tip arm (ordered backwards); it is now optional,
    and its two ends count as one place where the walk comes back to."""
    check_stored_stereo_frame("hooked_arms_touching_near_the_tip.npz")


def test_a_crossing_strand_that_ends_in_the_hooks_window_is_not_walked():
    """Predicted masks (M-oST int8) of a simulator frame (crossed, 640x480): a thin thread
    crosses a thicker one 56 px of arc from its cut tip, inside the hook's window, and the mask
    loses the thicker thread 63 px from the tip. The search crossed straight, but the thicker
    thread's unvisited pixels made the hook's walk take over; its arm to that end had to be
    walked out and back, and the walk then left along the thicker thread (a grasp 25.6 mm off).
    At the crossing's four arms that arm runs on straight into one as wide as itself that leaves
    the window, as our thread does into the fourth: another strand's arm, which the walk need
    not pass."""
    ordering, stored = order_stored_frame("predicted_crossing_in_the_hook_window.npz")
    for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"])):
        check_follows(sequence[:150, :2], truth.astype(float), tolerance=3.5, coverage=0.0)


def test_a_crossing_strand_whose_far_arm_the_mask_lost_is_not_walked():
    """Predicted masks (M-oST int8) of a simulator frame (crossed, 640x480): 50 px of arc from the
    cut tip our thread crosses a straight strand, and the right view's mask lost that strand's
    far arm, so the crossing has three arms and the near arm, to the strand's free end 53 px
    away, had to be walked out and back like a hairpin's merged arms. The left view then took
    that stretch from the right one as a loop it had passed by (a grasp 20.6 mm off). Our thread
    runs straight through the junction and the arm is no wider than it: another strand's arm,
    which the walk need not pass."""
    check_stored_stereo_frame("predicted_crossing_strand_lost_beyond_the_crossing.npz")


def test_a_thread_the_mask_lost_beside_the_strand_it_crosses_is_walked_on_beyond_it():
    """Predicted masks (the on-site default, int8) of an on-site simulator frame (crossed,
    640x480): 100 px from the cut tip the left view's mask lost our thread for 8 px just past
    the strand it crosses at about 70 degrees. The junction's every arm turned sharply onto that
    strand, and the step out of a loop took it (a 70 degree arc over 11 px), so the sequence
    was cut at the crossing and the 3D stage refused a thread 22 mm long. The search now looks
    beyond the strand and bridges the gap. (The mask also lost the cut tip's last 8 px: the
    sequences are followed from the true sample nearest their start.)"""
    ordering, stored = order_stored_frame("predicted_crossing_lower_strand_lost_beside_the_upper.npz")
    for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"])):
        truth = truth.astype(float)
        start = int(np.argmin(np.hypot(*(truth - sequence[0, :2]).T)))
        check_follows(sequence[:, :2], truth[start:], tolerance=3.0)


def test_a_tip_arm_that_thinning_ate_back_is_walked_from_the_masks_end():
    """A simulator frame (hooked, 640x480, true masks): the tip arm is drawn 2 px wide on the
    diagonal and its skeleton stops 12 px short of the cut tip; the walk through the hook
    started there, and the tip check refused the frame (the arm's last pixels lay off the
    sequence). The walk now starts at the mask's end along its own branch."""
    check_stored_stereo_frame("hooked_tip_arm_thinned_back.npz", coverage=0.9)


def test_a_tip_inside_merged_arms_is_walked_from_its_arms_end():
    """A simulator frame (hooked, 640x480, true masks): the tip arm and the returning arm merge
    into one stroke and the tip arm ends 4 px past the stroke skeleton's pixel nearest the
    hint; the walk started at that pixel and the tip check refused the frame. The start now
    moves back along the walk onto the tip arm's end, no farther than the hint."""
    check_stored_stereo_frame("hooked_tip_inside_merged_arms_short_of_the_arms_end.npz", coverage=0.9)


def test_the_walks_start_is_not_moved_onto_the_returning_arm_beside_the_tip():
    """A simulator frame (hooked, 640x480, true masks): the returning arm passes a pixel beside
    the tip's end; moved out along the tip arm, the start must stop where the tip arm's mask
    does, not run on along the other arm (14 px from the tip)."""
    check_stored_stereo_frame("hooked_tip_beside_the_returning_arm.npz")


def test_the_search_after_a_hook_walk_follows_a_thin_threads_centre_not_its_edge():
    """A simulator frame (hooked, 640x480, true masks; seed 20262007, frame 62): a thread 2-3 px
    wide leaves a loop at its tip. The walk through the loop handed the search a width of 1 px,
    so every cross-section after it looked like merged threads and the search stepped along one
    edge, the upper in one view and the lower in the other: 0.7 px off the centreline on
    average, and on a stretch at 14 degrees to the rows the grasp came out 17.9 mm off. The
    search now takes the width of the cross-section where the walk leaves."""
    ordering, stored = order_stored_frame("hooked_thin_thread_leaving_the_walk.npz")
    for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"])):
        sequence = np.asarray(sequence)[:, :2]
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(sequence, axis=0).T))])
        beyond_the_loop = sequence[arc > 100]
        assert arc[-1] > 400
        off = _distance_to_polyline(beyond_the_loop, truth.astype(float))
        assert off.mean() < 0.35 and off.max() < 1.0, (off.mean(), off.max())


def _distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """(N,) distance (px) of each point to the polyline (M, 2) (its segments, not only its vertices)."""
    start, chord = polyline[:-1], np.diff(polyline, axis=0)
    squared = np.maximum((chord**2).sum(axis=1), 1e-12)
    along = ((points[:, None, :] - start[None]) * chord[None]).sum(axis=2) / squared
    nearest = start[None] + np.clip(along, 0.0, 1.0)[..., None] * chord[None]
    return np.hypot(*(points[:, None, :] - nearest).transpose(2, 0, 1)).min(axis=1)


def test_right_views_tip_in_a_hook_takes_the_disparity_of_the_tips_own_neighbourhood():
    """A simulator frame (hooked, 1280x1024, true masks): the thread runs at 45 degrees, and the
    hook window's best shift traded 8 rows for 9 columns, so the right view's walk started on
    the returning arm 13 px from its tip (the grasp came out 39 mm off). The shift is now
    refined along the row on the tip's own neighbourhood."""
    check_stored_stereo_frame("hooked_right_tip_1280.npz")


def test_arms_touching_where_the_search_steps_across_are_walked_along_the_skeleton():
    """A simulator frame (hooked, 640x480, true masks): the hook's returning arm passes the cut
    tip touching it, without merging into one stroke, so the window's skeleton is one line
    from the tip along the thread. The search from the tip's free end stepped across onto the
    returning arm where they touch and came back to where it had passed (ordered backwards);
    the walk along the skeleton, which passes no place twice, is now taken."""
    check_stored_stereo_frame("hooked_arms_touching_search_steps_across.npz", coverage=0.9)


def test_views_whose_own_walks_go_round_a_hooks_loop_different_ways_take_both_views_evidence():
    """A simulator frame (hooked, 640x480, true masks): a thread 1 px wide whose tip arm crosses
    the returning arm 5 px from the cut tip, the two junctions of the crossing 2 px apart. The
    left view's walk went round the loop beyond the crossing against the thread (the side of
    the merged stroke, within a pixel's noise, outweighed the turn), and the right view, guided
    by it, followed, while its own walk went the other way (both ordered backwards). Where the
    views' own walks disagree, the walk whose score summed over both views is least is taken,
    in both views."""
    check_stored_stereo_frame("hooked_views_disagree_round_the_loop.npz", coverage=0.9)


def test_a_tip_a_step_from_its_loops_crossing_is_walked_round_the_loop_the_way_it_points():
    """A simulator frame (hooked, 640x480, true masks): the cut end runs 6 px into the crossing
    of a small loop at the tip, where the loop's two sides and the thread leave. The search's
    first step has no heading, so it took the side of the loop that leaves the crossing
    nearest to the tip, against the thread's way round (the sequence went backwards). The mask
    branching within one step of the tip now has the walk through the hook compared, and the
    least-turning walk goes on the way the cut end points."""
    check_stored_stereo_frame("hooked_tip_a_step_from_its_loops_crossing.npz")


@pytest.mark.parametrize(
    ("name", "narrow"),
    [
        ("hooked_small_loop_crossed_at_the_tip.npz", True),
        ("hooked_loop_crossing_thinned_to_two_junctions.npz", False),
        ("hooked_small_loop_behind_a_thinned_crossing.npz", True),
    ],
)
def test_a_loop_crossed_at_the_tip_is_gone_round_the_way_the_tip_arm_enters_it(name, narrow):
    """Simulator frames (hooked, 640x480, true masks), each a loop closed by a crossing near the
    cut tip, gone round against the thread in both views (ordered backwards):

    - small_loop_crossed_at_the_tip: a loop of 15 px, 5 px across, 10 px from the tip. The
      turn at each pass of the crossing was measured over one step (8 px) of the loop, past its
      half, where both ways round point the same way: at a loop entered and left through a
      crossing, the turn is measured within a third of the loop.
    - loop_crossing_thinned_to_two_junctions: a loop of 58 px whose crossing, at 35 degrees,
      thins to two junctions 8 px apart. The thread passes each junction with a turn of 15-30
      degrees, one way and then the other, and summed over four such turns the way across the
      crossing turned more than the way round against the thread: passes closer than two steps
      are one place, the turn measured across it.
    - small_loop_behind_a_thinned_crossing: a loop of 15 px behind a crossing thinned to two
      junctions 3 px apart: one place, whose turn is measured within a third of the loop.

    A ``narrow`` loop lies within the 3 px tolerance of ``check_follows`` all round, so each of
    the first 80 points is matched to its nearest true sample too (a median over 5 points: at the
    crossing the nearest sample may lie on the other pass), and these must never fall back."""
    ordering, stored = order_stored_frame(name)
    for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"])):
        check_follows(sequence, truth.astype(float), tolerance=3.0)
        if narrow:
            nearest = median_filter(cKDTree(truth).query(sequence[:80])[1], 5, mode="nearest")
            assert (np.maximum.accumulate(nearest) - nearest).max() <= 2, nearest


def test_a_hooks_loop_is_gone_round_once():
    """A simulator frame (hard set, hooked, 640x480; the low masks of a retrained M-oST): the cut
    end enters a loop of about 75 px 6 px from the tip, through a crossing whose two junctions
    lie 3 px apart. The walk through the hook could pass the loop twice: the way round once
    that the thread turns was set apart by the side rule, the other way turned more than twice
    round, so the walk coiled round the loop twice in both views and the grasp landed one loop's
    arc (12 mm) short. A thread does not coil twice over the same pixels: a loop is passed once."""
    ordering, stored = order_stored_frame("predicted_hook_loop_gone_round_once.npz")
    for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"])):
        ordered, true = (np.linalg.norm(np.diff(line, axis=0), axis=1).sum() for line in (sequence, truth))
        assert abs(ordered - true) < 10.0, (ordered, true)  # a second time round would add ~75 px


def test_the_right_views_hook_walk_starts_at_the_left_tips_match():
    """A simulator frame (hooked, 640x480, true masks): the cut tip lies inside a stroke of merged
    arms, so each view's walk starts at the skeleton's pixel nearest its hint and is moved out
    along the arm; the left view's start lies 3.8 px from its true tip. The right view's walk
    starts at the left tip's match, which was smoothed once already: its own smoothing must not
    pull that start inward a second time (5.1 px from the true tip, past the ordering's tolerance
    of 5 px)."""
    ordering, stored = order_stored_frame("hooked_right_tip_inside_merged_arms.npz")
    views = ((ordering.left, stored["truth_left"]), (ordering.right, stored["truth_right"]))
    left_off, right_off = (float(np.hypot(*(sequence[0] - truth[0]))) for sequence, truth in views)
    assert right_off < min(5.0, left_off + 0.5), (left_off, right_off)


@pytest.mark.parametrize("name", ["hooked_diagonal_tail_into_loop.npz", "hooked_diagonal_tail_hairpin.npz"])
def test_a_hooks_thin_diagonal_tail_is_walked_from_its_end(name):
    """Simulator frames (hooked, 640x480, true masks): the cut end is a straight tail 2 px wide
    at 45 degrees into a loop (into_loop) or a hairpin (hairpin). In the right view Zhang's
    skeleton loses the whole tail, 17 px, up to the loop's crossing; a walk through the hook from
    that skeleton starts at the crossing (into_loop) or 6 px from the tip and stops after 106 of
    513 px (hairpin). Each view must start at its cut tip and follow its thread."""
    check_stored_stereo_frame(name)


def test_a_thin_diagonal_thread_cut_by_the_hook_window_leaves_it():
    """A simulator frame (hooked, 640x480, true masks): a hairpin at the cut tip whose arms touch
    its thread, which leaves as a 2 px line at 45 degrees. Zhang's skeleton of the hook's window
    eats that line back from the window's edge by 10 px, so in the right view its branch ends
    inside the window. A free end whose thread runs on ahead to the window's rim is the rim's:
    the walk leaves the window there, and both views follow their threads."""
    check_stored_stereo_frame("hooked_diagonal_thread_cut_by_window.npz")


def order_stored_frame(name: str) -> tuple:
    """The ordering of a stored stereo frame (test/data/NAME: packed masks of ``shape``, hint,
    true sequences) with the simulator's default camera of that size, and the stored arrays."""
    stored = np.load(Path(__file__).parent / "data" / name)
    height, width = (int(n) for n in stored["shape"])
    size = height * width
    left, right = (np.unpackbits(stored[view])[:size].reshape(height, width) for view in ("left", "right"))
    return order_stereo(left, right, stored["hint"], StereoCamera.default(width, height)), stored


def check_stored_stereo_frame(name: str, coverage: float = 0.95) -> None:
    """Order a stored stereo frame (test/data/NAME: packed masks of ``shape``, hint, true
    sequences; the simulator's default camera of that size) and check that both views follow
    their true sequences within 3 px, over ``coverage`` of their length."""
    ordering, stored = order_stored_frame(name)
    check_follows(ordering.left, stored["truth_left"].astype(float), tolerance=3.0, coverage=coverage)
    check_follows(ordering.right, stored["truth_right"].astype(float), tolerance=3.0, coverage=coverage)


# --------------------------------------------------------------------------- a cut end the masks lost
# The search starts at the thread end that points at the tip hint (suture_ordering.tip.tip_across_gap,
# right_tip_across_gap), and the stretch from the tip to it is published flagged not seen.
DISPARITY = 30


def _thread() -> np.ndarray:
    s = np.linspace(0, 1, 1500)
    return np.column_stack([150 + 380 * s, 120 + 250 * s + 60 * np.sin(3 * s)])


def _without_cut_end(mask: np.ndarray, up_to_column: int) -> np.ndarray:
    lost = mask.copy()
    lost[:, :up_to_column] = 0
    return lost


def _seen_from(sequence: np.ndarray) -> int:
    seen = np.flatnonzero(sequence[:, 2] == 0)
    assert seen.size and np.all(sequence[: seen[0], 2] == 1) and np.all(sequence[seen[0] :, 2] == 0)
    return int(seen[0])


def test_a_cut_end_both_masks_lost_is_bridged_from_the_hint_and_flagged_not_seen():
    truth = _thread()
    full = draw([truth])
    left = _without_cut_end(full, 180)  # ~35 px of thread from the tip
    right = _without_cut_end(_shifted(full, DISPARITY), 180 - DISPARITY)
    with pytest.raises(TipNotOnThreadError):
        order_stereo(left, right, truth[0], StereoCamera.default(W, H), OrderingParams(tip_gap_max_px=0.0))
    result = order_stereo(left, right, truth[0], StereoCamera.default(W, H))
    for sequence, shift in ((result.left_sequence, 0), (result.right_sequence, DISPARITY)):
        start = _seen_from(sequence)
        np.testing.assert_allclose(sequence[0, :2], truth[0] - [shift, 0], atol=1.5)
        assert 25 <= start <= 45  # the lost stretch, about 1 px apart
        seen = sequence[start:, :2] + [shift, 0]
        first = int(np.argmin(np.hypot(*(truth - seen[0]).T)))
        assert 175 <= truth[first, 0] <= 186  # where the masks start
        check_follows(seen, truth[first:])
    assert result.left_result.bridges == 1 and result.left_result.bridged[0]


def test_a_thread_end_that_does_not_point_at_the_hint_is_not_taken():
    straight = line((200, 200), (450, 200))  # its free end at u = 200 points to smaller u
    mask = draw([straight])
    beside = np.array([205.0, 170.0])  # 30 px off the end, across the thread's way
    with pytest.raises(TipNotOnThreadError):
        order_stereo(mask, _shifted(mask, DISPARITY), beside, StereoCamera.default(W, H))
    assert tip_across_gap(mask, beside, 12.0, 48.0, 0.5) is None
    ahead = np.array([170.0, 200.0])  # 30 px on along the thread's way
    np.testing.assert_allclose(tip_across_gap(mask, ahead, 12.0, 48.0, 0.5), [200.0, 200.0], atol=1.5)
    too_far = np.array([140.0, 200.0])
    assert tip_across_gap(mask, too_far, 12.0, 48.0, 0.5) is None


def test_a_cut_end_only_the_right_mask_lost_starts_that_view_at_the_shifted_tip():
    truth = _thread()
    left = draw([truth])
    right = _without_cut_end(_shifted(left, DISPARITY), 150)  # ~30 px of the right thread
    result = order_stereo(left, right, truth[0], StereoCamera.default(W, H))
    assert not result.left_sequence[:, 2].any()
    start = _seen_from(result.right_sequence)
    assert 20 <= start <= 40
    # The tip shifted as the thread's first seen row is: a pixel's disparity error or two.
    np.testing.assert_allclose(result.right_sequence[0, :2], truth[0] - [DISPARITY, 0], atol=5.0)
    found = right_tip_across_gap(right, truth, (17.0, 52.0), 12.0, 48.0, 0.5)
    assert found is not None
    np.testing.assert_allclose(found[1], truth[0] - [DISPARITY, 0], atol=5.0)
