# SPDX-License-Identifier: Apache-2.0
"""Pairing of left and right inputs by exact ``header.stamp`` (docs/interfaces.md), without rclpy.

The one stamp synchroniser of the project (what message_filters gives on a full install);
every node that joins a stereo pair uses it.

:class:`StampPairBuffer` keeps the latest unmatched items of each side keyed by
their stamp (integer nanoseconds). When the item of the other side with the same
stamp arrives, the pair is returned and removed. Each side keeps at most
``capacity`` unmatched stamps; the earliest received are dropped first (and counted), so a
side whose partner never arrives cannot grow the buffer.

:class:`StampedPairs` keeps the completed pairs too, the newest ``capacity``, until they are
taken by stamp: for an input that a node looks up when another input of the same stamp is
complete (reconstruction_node's images, ordering_node's low masks).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Generic, TypeVar

T = TypeVar("T")

SIDES = ("left", "right")


class StampPairBuffer(Generic[T]):
    """Stamp-keyed pairing of two input streams ('left' and 'right')."""

    def __init__(self, capacity: int = 30) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self.capacity = capacity
        self._pending: dict[str, OrderedDict[int, T]] = {side: OrderedDict() for side in SIDES}
        self.dropped = 0
        """Unmatched items discarded because a side exceeded ``capacity``."""

    def add(self, side: str, stamp_ns: int, item: T) -> tuple[T, T] | None:
        """Add ``item`` of ``side`` at ``stamp_ns``; return (left, right) when its partner is waiting.

        A second item of the same side and stamp replaces the first.
        """
        if side not in SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        other = "right" if side == "left" else "left"
        partner = self._pending[other].pop(stamp_ns, None)
        if partner is not None:
            return (item, partner) if side == "left" else (partner, item)
        pending = self._pending[side]
        pending.pop(stamp_ns, None)
        pending[stamp_ns] = item
        while len(pending) > self.capacity:
            pending.popitem(last=False)
            self.dropped += 1
        return None

    def pending(self, side: str) -> list[int]:
        """Stamps of ``side`` still waiting for a partner, oldest first."""
        return list(self._pending[side])

    def clear(self) -> None:
        for pending in self._pending.values():
            pending.clear()


class StampedPairs(Generic[T]):
    """Completed (left, right) pairs by stamp, the newest ``capacity``, taken by stamp."""

    def __init__(self, capacity: int = 30) -> None:
        self._pairer: StampPairBuffer[T] = StampPairBuffer(capacity)  # ValueError below 1
        self.capacity = capacity
        self._pairs: OrderedDict[int, tuple[T, T]] = OrderedDict()

    def add(self, side: str, stamp_ns: int, item: T) -> tuple[T, T] | None:
        """Add ``item`` of ``side``; when it completes its stamp's pair, keep the pair (dropping the
        earliest beyond ``capacity``) and return it."""
        pair = self._pairer.add(side, stamp_ns, item)
        if pair is not None:
            self._pairs.pop(stamp_ns, None)
            self._pairs[stamp_ns] = pair
            while len(self._pairs) > self.capacity:
                self._pairs.popitem(last=False)
        return pair

    def take(self, stamp_ns: int) -> tuple[T, T] | None:
        """The pair of ``stamp_ns``, removed, or None if there is none (not complete, or dropped)."""
        return self._pairs.pop(stamp_ns, None)

    def __len__(self) -> int:
        return len(self._pairs)
