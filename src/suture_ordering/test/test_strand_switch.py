# SPDX-License-Identifier: Apache-2.0
"""A sequence that leaves its thread at a crossing for the other strand
(suture_ordering.strand_switch): found where the mask shows our thread going on straight and the
other strand's far arm, and cut there by the ordering; a thread's own bends and loops are not."""

from __future__ import annotations

import math

import cv2
import numpy as np

from suture_common.camera import StereoCamera
from suture_ordering import OrderingParams, order_stereo
from suture_ordering.strand_switch import strand_switch_index

W, H = 640, 480
RADIUS = 24  # Υ at 640 px
TURN = math.radians(30.0)
START = 3 * RADIUS  # the hook window


def _line(start: tuple[float, float], end: tuple[float, float]) -> np.ndarray:
    """1 px samples from ``start`` to ``end``."""
    length = math.hypot(end[0] - start[0], end[1] - start[1])
    s = np.linspace(0.0, 1.0, round(length) + 1)[:, None]
    return np.asarray(start) + s * (np.asarray(end) - np.asarray(start))


def _draw(*polylines: np.ndarray, width: int = 3) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    for line in polylines:
        cv2.polylines(mask, [np.rint(line).astype(np.int32)], False, 255, width)
    return mask


def _crossing(angle_deg: float, lost: tuple[int, int] | None = (300, 330)) -> np.ndarray:
    """Our thread along row 240 from its cut tip at u = 100 to u = 560, crossed at (300, 240)
    by a straight strand at ``angle_deg`` to it; ``lost``: the columns of our thread the mask
    lost just past the crossing (None: our thread ends at the crossing)."""
    ours = _line((100, 240), (560, 240)) if lost is not None else _line((100, 240), (300, 240))
    t = math.radians(angle_deg)
    other = _line(
        (300 - 200 * math.cos(t), 240 - 200 * math.sin(t)), (300 + 200 * math.cos(t), 240 + 200 * math.sin(t))
    )
    mask = _draw(ours, other)
    if lost is not None:
        mask[235:246, lost[0] : lost[1]] = 0
        mask = mask | _draw(other)  # the other strand stays whole
    return mask


def _onto_the_other_strand(tip_u: float) -> np.ndarray:
    """A sequence along row 240 from ``tip_u`` to the crossing at (300, 240), then 150 px up the
    45 degree strand of :func:`_crossing`."""
    t = math.radians(-45.0)
    on = _line((300, 240), (300 + 150 * math.cos(t), 240 + 150 * math.sin(t)))
    return np.vstack([_line((tip_u, 240), (300, 240)), on[1:]])


def test_a_turn_onto_the_crossing_strand_is_found_at_the_crossing() -> None:
    mask = _crossing(-45.0)
    switched = _onto_the_other_strand(100)
    index = strand_switch_index(mask, switched, RADIUS, TURN, START)
    assert index is not None
    assert abs(switched[index, 0] - 300) <= RADIUS / 2 and abs(switched[index, 1] - 240) <= RADIUS / 2


def test_no_switch_without_our_thread_beyond_the_crossing() -> None:
    """A thread that ends on the other strand leaves no mask straight on: nothing to tell a turn
    from the end of the thread, so nothing is cut."""
    mask = _crossing(-45.0, lost=None)
    along = _onto_the_other_strand(100)
    assert strand_switch_index(mask, along, RADIUS, TURN, START) is None


def test_a_bend_and_a_loop_of_the_thread_itself_are_not_switches() -> None:
    s = np.linspace(0.0, 1.0, 700)
    bend = np.column_stack([100 + 300 * s, 240 - 120 * np.clip((s - 0.5) * 3, 0, 1) ** 2])  # turns ~70 deg
    assert strand_switch_index(_draw(bend), bend, RADIUS, TURN, START) is None
    phi = np.linspace(0.0, 1.0, 1500)
    loop = np.column_stack(
        [100 + 400 * phi - 60 * np.sin(2 * np.pi * phi * 2), 240 - 60 * (1 - np.cos(2 * np.pi * phi * 2))]
    )
    assert strand_switch_index(_draw(loop), loop, RADIUS, TURN, START) is None


def _looped(radius: float, advance: float) -> np.ndarray:
    """A thread along row 240 for 150 px, then one loop of ``radius`` px (a trochoid advancing
    ``advance`` px per turn) and on: 1 px samples."""
    t = np.linspace(-np.pi, 3 * np.pi, 2000)
    u, v = 200 + advance * t / (2 * np.pi) - radius * np.sin(t), 240 - radius * (1 - np.cos(t))
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(u), np.diff(v)))))
    steps = np.arange(0.0, arc[-1])
    curve = np.column_stack([np.interp(steps, arc, u), np.interp(steps, arc, v)])
    lead = np.column_stack([np.arange(curve[0, 0] - 150, curve[0, 0]), np.full(150, curve[0, 1])])
    return np.vstack([lead, curve])


def test_a_thick_threads_own_loop_is_not_a_switch() -> None:
    """A thread 8 px wide through a loop about one RoI radius across: the mask's edge lies 4 px
    from the sequence, so the loop's own passes ahead of and behind a turn are mask beside it;
    measured against the thread's width they are the thread itself."""
    for radius in (18.0, 26.0, 36.0):
        loop = _looped(radius, 100.0)
        assert strand_switch_index(_draw(loop, width=8), loop, RADIUS, TURN, START) is None


def test_a_thick_thread_that_took_the_other_strand_is_still_found() -> None:
    ours = _line((100, 240), (560, 240))
    other = _line((300 - 141.4, 240 + 141.4), (300 + 141.4, 240 - 141.4))
    mask = _draw(ours, width=8)
    mask[230:251, 308:338] = 0
    mask |= _draw(other, width=8)
    index = strand_switch_index(mask, _onto_the_other_strand(100), RADIUS, TURN, START)
    assert index is not None and abs(index - 200) <= RADIUS / 2


def test_nothing_is_checked_inside_the_hook_window() -> None:
    mask = _crossing(-45.0)
    switched = _onto_the_other_strand(240)
    assert strand_switch_index(mask, switched, RADIUS, TURN, START) is None  # the turn is 60 px from the tip
    assert strand_switch_index(mask, switched, RADIUS, TURN, 0.0) is not None


def test_the_ordering_cuts_a_sequence_that_took_the_other_strand() -> None:
    """Our thread's mask lost 30 px just past a 45 degree crossing: the search takes the other
    strand; the ordering cuts both views' sequences at the crossing (off: they run on along
    the other strand to its end)."""
    camera = StereoCamera.default(W, H)
    left = _crossing(-45.0)
    right = np.roll(left, -26, axis=1)
    tip = np.array([100.0, 240.0])
    off = order_stereo(left, right, tip, camera, params=OrderingParams(strand_switch_turn=math.pi))
    assert off.left[-1, 1] < 150  # up the other strand
    assert off.cut == (0, 0)
    cut = order_stereo(left, right, tip, camera)
    assert np.abs(cut.left[-1] - (300, 240)).max() <= RADIUS / 2
    assert np.abs(cut.right[-1] - (274, 240)).max() <= RADIUS / 2
    assert cut.cut[0] > 100 and cut.cut[1] > 100
    assert np.all(np.abs(cut.left[:, 1] - 240) <= 2)  # all of it on our thread
    assert len(cut.left_sequence) <= len(cut.left) + 1
