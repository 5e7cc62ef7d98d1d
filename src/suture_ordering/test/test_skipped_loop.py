# SPDX-License-Identifier: Apache-2.0
"""A sequence that passes by a loop the mask shows (suture_ordering.skipped_loop): found where a
ring or a detour of the mask joins the sequence, or where a ring the mask broke on both sides of
its crossing comes near it, and the sequence cut there by the ordering; a crossing strand, thread
beside the sequence that is no longer than it, and a strand that leaves the image are not."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_ordering import OrderingParams, StereoOrdering, order_stereo
from suture_ordering.skipped_loop import skipped_loop_index

W, H = 640, 480


def _draw(*polylines: np.ndarray | list[tuple[float, float]], width: int = 3) -> np.ndarray:
    """A (H, W) mask of the polylines (vertex lists), ``width`` px wide."""
    mask = np.zeros((H, W), np.uint8)
    cv2.polylines(mask, [np.rint(np.asarray(line)).astype(np.int32) for line in polylines], False, 255, width)
    return mask


def _ring(centre: tuple[float, float], radius: float, start_deg: float, sweep_deg: float) -> np.ndarray:
    angles = np.radians(start_deg + np.linspace(0.0, sweep_deg, round(abs(sweep_deg) * radius / 40) + 2))
    return np.column_stack([centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)])


STRAIGHT = np.column_stack([np.arange(100.0, 561.0), np.full(461, 240.0)])  # 1 px apart


def test_a_ring_beside_the_sequence_is_found_where_it_joins() -> None:
    """A loop of 20 px radius hanging below row 240 at u = 300, broken where it meets the thread
    (the segmenter lost it there): the sequence along the row passes it by."""
    ring = _ring((300, 262), 20, -70, 320)  # a gap of 40 degrees at its top, on the thread
    index = skipped_loop_index(_draw(STRAIGHT, ring), STRAIGHT)
    assert index is not None and abs(STRAIGHT[index, 0] - 300) <= 20  # within the ring's radius
    assert skipped_loop_index(_draw(STRAIGHT), STRAIGHT) is None


def test_a_detour_much_longer_than_the_sequence_beside_it_is_found() -> None:
    """Mask leaving the row at u = 280 and coming back at u = 320 over a 60 px deep bulge."""
    detour = [(280, 244), (280, 300), (320, 300), (320, 244)]
    index = skipped_loop_index(_draw(STRAIGHT, detour), STRAIGHT)
    assert index is not None and abs(STRAIGHT[index, 0] - 280) <= 12
    shallow = [(280, 244), (300, 250), (320, 244)]  # no longer than its chord
    assert skipped_loop_index(_draw(STRAIGHT, shallow), STRAIGHT) is None


def test_a_ring_the_mask_broke_on_both_sides_of_its_crossing_is_found() -> None:
    """A loop of 25 px radius below row 240 whose mask stops 5 px short of the thread at both
    ends (the segmenter lost it where it crosses the thread): found near u = 300. Another
    thread running 6 px beside the sequence, and an arc of one that comes near it at one end
    only, are not loops."""
    ring = _ring((300, 268), 25, -52, 284)  # ends at 38 degrees either side of the top
    index = skipped_loop_index(_draw(STRAIGHT, ring), STRAIGHT)
    assert index is not None and abs(STRAIGHT[index, 0] - 300) <= 25
    beside = [(200, 249), (400, 249)]
    assert skipped_loop_index(_draw(STRAIGHT, beside), STRAIGHT) is None
    hook = _ring((300, 268), 25, -52, 200)  # one end near the thread, the other 40 px from it
    assert skipped_loop_index(_draw(STRAIGHT, hook), STRAIGHT) is None
    far = _ring((300, 290), 25, -52, 284)  # the same ring 22 px lower: its ends are far from the thread
    assert skipped_loop_index(_draw(STRAIGHT, far), STRAIGHT) is None


@pytest.mark.parametrize("gap_px", [6, 9])
def test_a_ring_whose_mask_stops_short_of_the_thread_reaches_from_its_own_end(gap_px: int) -> None:
    """A loop of 28 px radius whose mask (2 px wide, 300 of its 360 degrees) starts ``gap_px``
    below the thread and ends 14 px farther off: it is 2.3 times as long as it reaches from its
    own end near the thread, but less than 2.2 times as long as it reaches from the thread, whose
    gap the mask lost. Found where it comes near, at u = 300."""
    ring = _ring((300, 240 + gap_px + 28), 28, -90, 300)
    index = skipped_loop_index(_draw(STRAIGHT, ring, width=2), STRAIGHT)
    assert index is not None and abs(STRAIGHT[index, 0] - 300) <= 10


def test_a_nearly_closed_ring_apart_from_the_sequence_is_found_where_it_opens() -> None:
    """A loop of 30 px radius 16 px below the thread whose mask lost 50 degrees at its top (its
    crossing): its ends lie 19 px from the thread, too far to count as near it, but they are 25 px
    apart and it is 160 px long. Found at u = 300. The same ring opening away from the thread, an
    arc of 200 degrees, and the ring 13 px lower (its ends 32 px from the thread) are not loops."""
    closed = _ring((300, 240 + 16 + 30), 30, -65, 310)
    index = skipped_loop_index(_draw(STRAIGHT, closed, width=2), STRAIGHT)
    assert index is not None and abs(STRAIGHT[index, 0] - 300) <= 10
    away = _ring((300, 240 + 16 + 30), 30, 115, 310)
    assert skipped_loop_index(_draw(STRAIGHT, away, width=2), STRAIGHT) is None
    arc = _ring((300, 240 + 16 + 30), 30, -10, 200)
    assert skipped_loop_index(_draw(STRAIGHT, arc, width=2), STRAIGHT) is None
    lower = _ring((300, 240 + 29 + 30), 30, -65, 310)
    assert skipped_loop_index(_draw(STRAIGHT, lower, width=2), STRAIGHT) is None


def test_crossing_strands_and_strands_leaving_the_image_are_not_loops() -> None:
    crossing = [(200, 60), (400, 420)]  # an X with another thread
    assert skipped_loop_index(_draw(STRAIGHT, crossing), STRAIGHT) is None
    touching = [(300, 243), (300, 479)]  # a strand that joins at a T and leaves the image
    assert skipped_loop_index(_draw(STRAIGHT, touching), STRAIGHT) is None
    wide = _draw(STRAIGHT, width=7)  # a thick thread: its rim lies in the corridor
    assert skipped_loop_index(wide, STRAIGHT) is None
    assert skipped_loop_index(np.full((H, W), 255, np.uint8), STRAIGHT) is None  # a mask with no background


def _ordered_without_and_with_the_cut(stored_frame: str) -> tuple[StereoOrdering, StereoOrdering, np.ndarray]:
    """A stored frame's orderings with ``skipped_loop_cut`` off and on, and its true left
    centreline (N, 2) float (u, v). The file holds both views' masks and low masks (packed
    bits), their ``shape``, the tip ``hint`` and ``truth_left``."""
    stored = np.load(Path(__file__).parent / "data" / stored_frame)
    height, width = (int(n) for n in stored["shape"])
    masks = [
        np.unpackbits(stored[view])[: height * width].reshape(height, width) * 255
        for view in ("left", "right", "left_low", "right_low")
    ]
    arguments = (masks[0], masks[1], stored["hint"], StereoCamera.default(width, height))
    off = order_stereo(*arguments, params=OrderingParams(skipped_loop_cut=False), low_masks=tuple(masks[2:]))
    cut = order_stereo(*arguments, low_masks=tuple(masks[2:]))
    return off, cut, stored["truth_left"][:, :2].astype(float)


@pytest.mark.parametrize(
    ("stored_frame", "loop_at_px"),
    [("predicted_loop_passed_by.npz", 110), ("predicted_loop_detached_at_its_crossing.npz", 245)],
)
def test_the_ordering_cuts_a_sequence_that_passed_a_loop_by(stored_frame: str, loop_at_px: float) -> None:
    """A segmenter's masks of simulated frames (M-oST int8), whose sequences in both views went
    straight on past a loop. ``predicted_loop_passed_by``: fresh mixed set of seed 20261964,
    frame 482; the mask broke a pale loop 45 px across next to its crossing, the low mask kept
    the rest of it, and the grasp, 50 mm of arc from the tip, lay 32 mm too far along the thread
    (24.8 mm off). ``predicted_loop_detached_at_its_crossing``: fresh mixed set of seed 20262018,
    frame 467; a loop 100 px across meets the thread at a small angle, the masks lose it on both
    sides of the crossing, and the grasp was 19.7 mm off. Cut where the loop meets the sequence,
    before the loop (``loop_at_px`` of true arc from the tip): the 3D stage finds the thread too
    short."""
    off, cut, truth = _ordered_without_and_with_the_cut(stored_frame)
    assert off.cut == (0, 0) and min(cut.cut) > 100
    true_arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth, axis=0).T))])
    distance = np.hypot(*(truth - cut.left[-1]).T)
    assert distance.min() < 3 and true_arc[np.argmin(distance)] < loop_at_px  # on our thread, before the loop
    assert np.hypot(*(off.left[-1] - truth[-1])).min() < 5  # without the cut: on past it to the end
    assert len(off.left) - len(cut.left) == cut.cut[0]


def test_a_loop_beside_a_stretch_the_sequence_bridged_is_found_at_the_bridge() -> None:
    """The mask lost the thread for 120 px (u = 260 to 380) and most of the loop it makes there, a
    pale loop on a highlight: what is left of the loop, two arcs 11 px and more from the row, lies
    beside the stretch the ordering bridged. The bridge skipped the loop's arc, so the sequence is
    cut where the bridge starts. The same arcs beside a stretch the mask showed (not bridged) are
    left to the ring and detour shapes, which they are not; and a strand of another thread that
    stops short of the gap, reaching far from it, is not a loop."""
    bridged = (STRAIGHT[:, 0] >= 260) & (STRAIGHT[:, 0] <= 380)
    seen_part = [STRAIGHT[STRAIGHT[:, 0] < 260], STRAIGHT[STRAIGHT[:, 0] > 380]]
    arcs = [_ring((320, 275), 24, 10, 120), _ring((320, 275), 24, 170, 100)]
    mask = _draw(*seen_part, *arcs)
    index = skipped_loop_index(mask, STRAIGHT, not_seen=bridged)
    assert index is not None and STRAIGHT[index, 0] == 260
    assert skipped_loop_index(mask, STRAIGHT) is None
    strand = [(320, 60), (320, 226)]
    assert skipped_loop_index(_draw(*seen_part, strand), STRAIGHT, not_seen=bridged) is None


def test_a_stored_frame_whose_bridge_went_past_a_pale_loop_is_cut_where_the_bridge_starts() -> None:
    """A simulator frame (self_intersected, 640x480, predicted masks of ``m_ost_int8`` and their
    low masks): a pale loop on a highlight, which the segmenter lost with the thread either side of
    its crossing. In the right view the ordering bridged 150 px straight past what is left of the
    loop, and the grasp point, 50 mm of arc from the cut tip, landed 24 mm off (the loop's arc was
    missing). The right sequence is now cut where that bridge starts, before the loop: what is
    kept lies on the thread, and the 3D stage refuses the thread as too short."""
    stored = np.load(Path(__file__).parent / "data" / "predicted_pale_loop_skipped_by_a_bridge.npz")
    height, width = (int(n) for n in stored["shape"])
    views = [
        np.unpackbits(stored[name])[: height * width].reshape(height, width)
        for name in ("left", "right", "low_left", "low_right")
    ]
    camera = StereoCamera.default(width, height)
    ordering = order_stereo(views[0], views[1], stored["hint"], camera, low_masks=(views[2], views[3]))
    assert ordering.cut[1] > 100
    truth = stored["truth_right"].astype(float)
    distance = np.hypot(*(ordering.right[:, None, :2] - truth[None]).transpose(2, 0, 1)).min(axis=1)
    assert distance.max() < 3.0
    nearest_end = int(np.argmin(np.hypot(*(truth - ordering.right[-1, :2]).T)))
    assert nearest_end < 0.2 * len(truth)  # the loop lies farther on


def test_thread_beside_the_sequence_and_a_hook_that_joins_it_are_not_loops() -> None:
    """Mask running 4 px beside the thread for 80 px (a blurred edge) has both ends at the
    corridor, but joins a stretch of the sequence longer than it reaches away; an arc of 200
    degrees joined at one end has its other end 48 px from the thread. Neither comes back to
    where it left."""
    assert skipped_loop_index(_draw(STRAIGHT, [(250, 244), (330, 244)]), STRAIGHT) is None
    assert skipped_loop_index(_draw(STRAIGHT, _ring((300, 267), 24, -90, 200)), STRAIGHT) is None


@pytest.mark.parametrize(
    ("stored_frame", "loop_at_px"),
    [
        ("predicted_onsite_loop_one_end_near.npz", 194),
        ("predicted_onsite_loop_at_a_small_angle.npz", 140),
        ("predicted_onsite_nearly_closed_loop_apart.npz", 143),
    ],
)
def test_an_on_site_loop_the_sequence_went_past_is_cut_where_it_starts(
    stored_frame: str, loop_at_px: float
) -> None:
    """On-site simulator frames (self_intersected, 640x480, masks of the default on-site model and
    their low masks) whose sequences went straight past a loop; the grasps landed 21.6 and 23.4 mm
    off. ``predicted_onsite_loop_one_end_near``: a bright loop 85 px across whose crossing the
    segmenter lost; one end of its mask 2 px from the corridor, the other 14 px, so not a ring
    broken at its crossing (which needs both ends near): a piece that comes near the corridor at
    one place is now tested as a joined ring is. ``predicted_onsite_loop_at_a_small_angle``: a loop
    42 px across that leaves the thread at a small angle; the corridor takes the arc beside the
    sequence, and what is left, joined at one place, is 2.1 times as long as it reaches (a ring
    needs 2.2): its skeleton's ends both lie at the corridor, it leaves the thread and comes back.
    ``predicted_onsite_nearly_closed_loop_apart``: a bright loop 65 px across whose mask the
    segmenter broke on both sides of its crossing, 11-17 px from the sequence (28.6 mm off): apart
    from the corridor, a nearly closed ring that opens towards it. Both views are cut where the
    loop starts (``loop_at_px`` of true arc from the tip)."""
    off, cut, truth = _ordered_without_and_with_the_cut(stored_frame)
    assert off.cut == (0, 0) and min(cut.cut) > 100
    distance = np.hypot(*(cut.left[:, None, :] - truth[None]).transpose(2, 0, 1)).min(axis=1)
    assert distance.max() < 3.0  # what is kept lies on the thread
    kept_arc = float(np.hypot(*np.diff(cut.left, axis=0).T).sum())
    assert abs(kept_arc - loop_at_px) < 20
