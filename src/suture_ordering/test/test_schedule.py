# SPDX-License-Identifier: Apache-2.0
"""ordering_node's timing (MaskPairSchedule) driven by a fake clock: pairing, low-mask waits, holds."""

from __future__ import annotations

import pytest

from suture_ordering.schedule import MaskPairSchedule, ReadyPair


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def schedule(capacity: int = 10, wait_s: float = 0.1) -> tuple[MaskPairSchedule[str], FakeClock]:
    clock = FakeClock()
    return MaskPairSchedule(capacity, wait_s, clock), clock


def masks(s: MaskPairSchedule[str], stamp: int) -> list[ReadyPair[str]]:
    assert s.add_mask("left", stamp, f"L{stamp}") == []
    return s.add_mask("right", stamp, f"R{stamp}")


def low_masks(s: MaskPairSchedule[str], stamp: int) -> list[ReadyPair[str]]:
    assert s.add_low_mask("right", stamp, f"r{stamp}") == []
    return s.add_low_mask("left", stamp, f"l{stamp}")


def test_without_low_masks_every_pair_is_ready_at_once():
    s, _ = schedule()
    assert masks(s, 1) == [ReadyPair(1, "L1", "R1", None)]
    assert s.waiting == 0 and s.next_deadline is None and s.without_low_masks == 0


def test_low_masks_published_first_come_with_their_masks():
    s, _ = schedule()
    assert low_masks(s, 1) == []  # kept for the masks of stamp 1
    assert s.low_masks_seen
    assert masks(s, 1) == [ReadyPair(1, "L1", "R1", ("l1", "r1"))]


def test_once_low_masks_were_seen_a_pair_waits_for_them_until_its_deadline():
    s, clock = schedule(wait_s=0.1)
    low_masks(s, 1)
    masks(s, 1)
    assert masks(s, 2) == []  # its low masks are late
    assert s.waiting == 1 and s.next_deadline == pytest.approx(100.1)
    clock.now = 100.05
    assert s.overdue() == []
    assert low_masks(s, 2) == [ReadyPair(2, "L2", "R2", ("l2", "r2"))]  # they came in time
    assert s.waiting == 0 and s.without_low_masks == 0
    assert masks(s, 3) == []
    clock.now = 100.16
    assert s.overdue() == [ReadyPair(3, "L3", "R3", None)]
    assert s.without_low_masks == 1 and s.next_deadline is None
    assert low_masks(s, 3) == []  # too late: nobody waits for them any more


def test_the_next_complete_pair_ends_the_wait_of_the_older_ones():
    s, clock = schedule(wait_s=10.0)
    low_masks(s, 1)
    masks(s, 1)
    assert masks(s, 2) == [] and masks(s, 3) == [ReadyPair(2, "L2", "R2", None)]
    assert s.waiting == 1  # stamp 3 waits in turn
    assert low_masks(s, 4) == []
    assert masks(s, 4) == [ReadyPair(3, "L3", "R3", None), ReadyPair(4, "L4", "R4", ("l4", "r4"))]
    assert s.without_low_masks == 2
    clock.now += 100.0
    assert s.overdue() == []


def test_a_zero_wait_is_overdue_at_once():
    s, _ = schedule(wait_s=0.0)
    low_masks(s, 1)
    masks(s, 1)
    assert masks(s, 2) == []
    assert s.overdue() == [ReadyPair(2, "L2", "R2", None)]


def test_held_pairs_come_back_oldest_first_the_newest_capacity():
    s, _ = schedule(capacity=2)
    for stamp in (1, 2, 3):
        for pair in masks(s, stamp):
            s.hold(pair)
    assert s.held == 2
    assert [pair.stamp_ns for pair in s.release_held()] == [2, 3]
    assert s.held == 0 and s.release_held() == []


def test_unmatched_masks_are_bounded_by_the_capacity():
    s, _ = schedule(capacity=2)
    for stamp in (1, 2, 3):
        assert s.add_mask("left", stamp, f"L{stamp}") == []
    assert s.masks.pending("left") == [2, 3] and s.masks.dropped == 1
    assert s.add_mask("right", 1, "R1") == []  # its partner was dropped


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="low_mask_wait"):
        MaskPairSchedule(10, -0.1)
    with pytest.raises(ValueError, match="capacity"):
        MaskPairSchedule(0, 0.1)


def test_seconds_to_deadline_follow_the_oldest_waiting_pair():
    s, clock = schedule(wait_s=0.1)
    assert s.seconds_to_deadline() is None
    low_masks(s, 1)
    masks(s, 1)
    masks(s, 2)
    clock.now += 0.04
    assert s.seconds_to_deadline() == pytest.approx(0.06)
    assert s.add_mask("left", 3, "L3") == []  # an incomplete pair does not move the deadline
    assert s.seconds_to_deadline() == pytest.approx(0.06)
    clock.now += 1.0
    assert s.seconds_to_deadline() == 0.0
