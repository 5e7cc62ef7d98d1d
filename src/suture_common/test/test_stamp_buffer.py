# SPDX-License-Identifier: Apache-2.0
"""Stamp-keyed pairing of the left and right sequences."""

from __future__ import annotations

import pytest

from suture_common.stamp_buffer import StampedPairs, StampPairBuffer


def test_pairs_by_exact_stamp_in_either_order():
    buffer: StampPairBuffer[str] = StampPairBuffer()
    assert buffer.add("left", 10, "L10") is None
    assert buffer.add("right", 11, "R11") is None
    assert buffer.add("right", 10, "R10") == ("L10", "R10")
    assert buffer.add("left", 11, "L11") == ("L11", "R11")
    assert buffer.pending("left") == [] and buffer.pending("right") == []


def test_capacity_drops_the_earliest_and_a_repeat_replaces():
    buffer: StampPairBuffer[int] = StampPairBuffer(capacity=2)
    for stamp in (1, 2, 3):
        buffer.add("left", stamp, stamp)
    assert buffer.pending("left") == [2, 3] and buffer.dropped == 1
    buffer.add("left", 3, 33)
    assert buffer.add("right", 3, 0) == (33, 0)
    assert buffer.add("right", 1, 0) is None  # its partner was dropped


def test_bad_arguments():
    with pytest.raises(ValueError):
        StampPairBuffer(0)
    with pytest.raises(ValueError):
        StampPairBuffer().add("middle", 1, None)


def test_stamped_pairs_keep_the_newest_complete_pairs_until_taken():
    pairs: StampedPairs[str] = StampedPairs(capacity=2)
    assert pairs.add("left", 1, "L1") is None and len(pairs) == 0 and pairs.take(1) is None
    for stamp in (1, 2, 3):
        pairs.add("right" if stamp == 1 else "left", stamp, f"x{stamp}")
        if stamp > 1:
            assert pairs.add("right", stamp, f"R{stamp}") == (f"x{stamp}", f"R{stamp}")
    assert len(pairs) == 2 and pairs.take(1) is None  # the earliest complete pair was dropped
    assert pairs.take(3) == ("x3", "R3") and pairs.take(3) is None and len(pairs) == 1
    with pytest.raises(ValueError):
        StampedPairs(capacity=0)
