# SPDX-License-Identifier: Apache-2.0
"""The check that the ordered sequences explain the thread at the cut tip."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_ordering import OrderingParams, UnexplainedTipError, order_stereo
from suture_ordering.tip_check import check_tip_explained, thread_beyond_tip_pixels, unexplained_tip_pixels

W, H = 640, 480


def _line(a: tuple[float, float], b: tuple[float, float]) -> np.ndarray:
    t = np.linspace(0.0, 1.0, max(2, int(np.hypot(b[0] - a[0], b[1] - a[1]))))[:, None]
    return np.asarray(a, float) + t * (np.asarray(b, float) - np.asarray(a, float))


def _draw(curves: list[np.ndarray], width: int = 3) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    for curve in curves:
        cv2.polylines(mask, [np.rint(curve).astype(np.int32)], False, 255, width)
    return mask


def _loop_fragment(centre: tuple[float, float], radius: float, start: float, stop: float) -> np.ndarray:
    """An arc of a circle: the far side of a small loop at the tip that the segmenter kept apart."""
    angle = np.linspace(start, stop, 40)
    return np.column_stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle)])


def test_a_plain_thread_is_explained_by_its_own_sequence():
    thread = _line((150, 120), (520, 330))
    assert unexplained_tip_pixels(_draw([thread]), thread, 16.0) == 0


def test_a_loop_at_the_tip_that_the_sequence_skips_is_not_explained():
    thread = _line((150, 120), (520, 330))
    loop = _loop_fragment((139.0, 124.0), 6.0, 0.5 * np.pi, 1.5 * np.pi)  # behind the tip, apart
    mask = _draw([thread, loop], width=1)
    assert unexplained_tip_pixels(mask, thread, 16.0) > 5
    # The search's hole filling does not explain it: the sequence does not come back to it.
    assert unexplained_tip_pixels(mask, thread, 16.0, max_hole_area=20.0) > 5
    with pytest.raises(UnexplainedTipError, match="right view: .* px of thread within 16 px of the cut tip"):
        check_tip_explained((_draw([thread], width=1), mask), (thread, thread), 16.0, 5.0)
    # Farther from the tip than the radius, the same fragment does not count.
    far = _loop_fragment((300.0, 250.0), 6.0, 0.5 * np.pi, 1.5 * np.pi)
    assert unexplained_tip_pixels(_draw([thread, far], width=1), thread, 16.0) == 0


def test_a_hooks_loop_cut_off_in_line_beyond_the_tip_is_thread_beyond_it():
    # The mask lost a hairpin's merged arms: the tip is the mask's end, and the hairpin's loop
    # lies apart, 20-30 px on in line with the thread, beyond the 16 px of the check near the tip.
    thread = _line((150, 120), (520, 330))
    outward = (thread[0] - thread[10]) / np.hypot(*(thread[0] - thread[10]))
    centre = thread[0] + 25.0 * outward
    loop = _loop_fragment(tuple(centre), 5.0, 0.0, 2.0 * np.pi)
    mask = _draw([thread, loop], width=2)
    assert unexplained_tip_pixels(mask, thread, 16.0) == 0
    assert thread_beyond_tip_pixels(mask, thread, 16.0) > 5
    with pytest.raises(UnexplainedTipError, match="left view: .* px of thread lie beyond the cut tip"):
        check_tip_explained((mask, _draw([thread], width=2)), (thread, thread), 16.0, 5.0)
    # The same loop to the side of the tip, or 40 px on, is not in line with it within reach.
    aside = thread[0] + 25.0 * np.array([-outward[1], outward[0]])
    farther = thread[0] + 40.0 * outward
    for elsewhere in (aside, farther):
        other = _draw([thread, _loop_fragment(tuple(elsewhere), 5.0, 0.0, 2.0 * np.pi)], width=2)
        assert thread_beyond_tip_pixels(other, thread, 16.0) == 0
    assert thread_beyond_tip_pixels(_draw([thread], width=2), thread, 16.0) == 0


def _shifted(mask: np.ndarray, disparity: int) -> np.ndarray:
    right = np.zeros_like(mask)
    right[:, : W - disparity] = mask[:, disparity:]
    return right


def test_order_stereo_refuses_a_tip_whose_loop_it_skipped():
    camera = StereoCamera.default(W, H)
    thread = _line((150, 120), (520, 330))
    left = _draw([thread, _loop_fragment((139.0, 124.0), 6.0, 0.5 * np.pi, 1.5 * np.pi)])
    with pytest.raises(UnexplainedTipError, match="left view"):
        order_stereo(left, _shifted(left, 30), thread[0], camera)
    ordering = order_stereo(
        left, _shifted(left, 30), thread[0], camera, OrderingParams(tip_unexplained_radius_px=0.0)
    )
    assert np.hypot(*(ordering.left[0] - thread[0])) <= 3.0
    with pytest.raises(ValueError, match="tip_unexplained_max_px"):
        OrderingParams(tip_unexplained_max_px=-1.0)


def test_merged_arms_the_sequence_runs_down_once_stay_unexplained_where_the_cleaning_filled_the_slit():
    """A hairpin at the tip whose arms (3 px wide) touch every 4 px across a 1-px slit, which the
    cleaning fills: a search that started at the bend and ran down the filled stroke's middle,
    once, skipped the tip arm. Passed once, the filled stroke does not explain its arms."""
    mask = np.zeros((H, W), np.uint8)
    mask[117:120, 148:521] = 255  # the thread
    mask[121:124, 148:167] = 255  # the tip arm folded back beside it
    mask[117:124, 148:151] = 255  # the bend
    mask[120, 150:167:4] = 255  # the arms touch: holes of 3 px
    merged = np.column_stack([np.arange(150.0, 167.0), np.full(17, 120.0)])  # the stroke's middle
    sequence = np.vstack([merged, np.column_stack([np.arange(168.0, 521.0), np.full(353, 118.0)])])
    assert unexplained_tip_pixels(mask, sequence, 16.0, max_hole_area=20.0) > 5
    # Down the stroke and back (a walk round the bend), the same stroke is the thread it passes.
    down_and_back = np.vstack([sequence[16::-1], sequence[1:]])
    assert unexplained_tip_pixels(mask, down_and_back, 16.0, max_hole_area=20.0) <= 5


def test_a_loops_eye_is_gone_round_and_where_filled_the_walk_into_it_runs_on_its_arms():
    """A simulator frame (hooked, 640x480, true masks; set seed 9701, frame 17): the cut end
    curls into a loop whose eye (14 px², 3 px across) sits beside merged arms with a 1-px slit.
    Kept open (``min_eye_width_px``, the default), the eye is gone round: the right view's arc
    from the tip to the thread past the loop comes within 8 px of the truth's. Filled with the
    slit (``min_eye_width_px`` 0), the right view's walk goes down the filled stroke into the eye
    and back; moved from the stroke's centre onto each arm (the side the leaving thread's mask
    gives), it passes the loop's rim, explains it, and comes within 10 px of the true arc. Down
    the stroke's centre it was 12 px short and left 6 px of the rim unexplained."""
    stored = np.load(Path(__file__).parent / "data" / "hooked_loop_eye_filled_right.npz")
    height, width = (int(n) for n in stored["shape"])
    left, right = (
        np.unpackbits(stored[view])[: height * width].reshape(height, width) for view in ("left", "right")
    )
    camera = StereoCamera.default(width, height)
    truth_right = stored["truth_right"].astype(float)
    past_the_loop = truth_right[150]
    true_arc = _arc_to(truth_right, past_the_loop)
    filled = order_stereo(left, right, stored["hint"], camera, OrderingParams(min_eye_width_px=0.0))
    kept = order_stereo(left, right, stored["hint"], camera)
    assert unexplained_tip_pixels(right, filled.right, 16.0) <= 5
    assert unexplained_tip_pixels(right, kept.right, 16.0) <= 5
    assert _arc_to(filled.right, past_the_loop) > true_arc - 10.0
    assert _arc_to(kept.right, past_the_loop) > true_arc - 8.0
    for ordering in (filled, kept):
        for sequence, truth in ((ordering.left, stored["truth_left"]), (ordering.right, truth_right)):
            gap = np.hypot(*(sequence[:, None, :] - truth[None, :, :].astype(float)).transpose(2, 0, 1))
            assert np.percentile(gap.min(axis=1), 95) <= 3.0


def _arc_to(sequence: np.ndarray, point: np.ndarray) -> float:
    """Arc length (px) of ``sequence`` ((N, 2)) from its start to its point nearest ``point``."""
    nearest = int(np.argmin(np.hypot(*(sequence - point).T)))
    return float(np.hypot(*np.diff(sequence[: nearest + 1], axis=0).T).sum())
