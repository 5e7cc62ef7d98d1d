# SPDX-License-Identifier: Apache-2.0
"""When ordering_node orders a mask pair: pairing, the wait for low masks, the hold for camera_info.

ROS-free and driven by a clock given to it (``time.monotonic`` in the node, a fake one in tests).
:class:`MaskPairSchedule` takes the masks and low masks of both views as they arrive and
returns the :class:`ReadyPair` objects to order now, oldest first:

* masks and low masks are paired by exact stamp (:mod:`suture_common.stamp_buffer`);
* until the first complete low-mask pair, a complete mask pair is ready at once, without low
  masks (a segmenter that publishes none);
* after it, a mask pair whose low masks have not arrived waits for them up to ``low_mask_wait_s``
  (:attr:`MaskPairSchedule.next_deadline`; the node calls :meth:`~MaskPairSchedule.overdue` then),
  or until the next mask pair is complete, and is then ready without them (counted in
  :attr:`~MaskPairSchedule.without_low_masks`);
* a ready pair the node cannot order yet (no camera_info) is handed back with
  :meth:`~MaskPairSchedule.hold`; the newest ``capacity`` held pairs come back from
  :meth:`~MaskPairSchedule.release_held`.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from suture_common.stamp_buffer import StampedPairs, StampPairBuffer

T = TypeVar("T")


@dataclass(frozen=True)
class ReadyPair(Generic[T]):
    """A mask pair to order, with its low masks when they came in time."""

    stamp_ns: int
    left: T
    right: T
    low: tuple[T, T] | None = None


class MaskPairSchedule(Generic[T]):
    """The timing of ordering_node (module docstring); items are the nodes' mask messages."""

    def __init__(
        self,
        capacity: int,
        low_mask_wait_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not low_mask_wait_s >= 0:
            raise ValueError(f"low_mask_wait must be >= 0 s, got {low_mask_wait_s}")
        self.low_mask_wait_s = float(low_mask_wait_s)
        self._clock = clock
        self.masks: StampPairBuffer[T] = StampPairBuffer(capacity)  # ValueError below 1
        """Unmatched masks, per side."""
        self._low_masks: StampedPairs[T] = StampedPairs(capacity)
        self._awaiting_low: OrderedDict[int, tuple[T, T, float]] = OrderedDict()
        self._held: deque[ReadyPair[T]] = deque(maxlen=capacity)
        self.low_masks_seen = False
        """Whether a complete low-mask pair has arrived."""
        self.without_low_masks = 0
        """Mask pairs made ready without their low masks after low masks had been seen."""

    @property
    def capacity(self) -> int:
        return self.masks.capacity

    @property
    def waiting(self) -> int:
        """Mask pairs waiting for their low masks."""
        return len(self._awaiting_low)

    @property
    def next_deadline(self) -> float | None:
        """Clock time at which the oldest waiting pair is due, or None when none waits."""
        for _, _, deadline in self._awaiting_low.values():
            return deadline
        return None

    def seconds_to_deadline(self) -> float | None:
        """Seconds until :attr:`next_deadline` (0 when it passed), or None when no pair waits."""
        deadline = self.next_deadline
        return None if deadline is None else max(0.0, deadline - self._clock())

    def add_mask(self, side: str, stamp_ns: int, mask: T) -> list[ReadyPair[T]]:
        """Take one mask; the pairs ready now (those that waited, then this one's, if complete)."""
        paired = self.masks.add(side, stamp_ns, mask)
        if paired is None:
            return []
        ready = self._release_waiting(everything=True)  # a newer pair is complete: they waited enough
        low = self._low_masks.take(stamp_ns)
        if low is not None or not self.low_masks_seen:
            ready.append(ReadyPair(stamp_ns, *paired, low))
        else:
            self._awaiting_low[stamp_ns] = (*paired, self._clock() + self.low_mask_wait_s)
        return ready

    def add_low_mask(self, side: str, stamp_ns: int, low_mask: T) -> list[ReadyPair[T]]:
        """Take one low mask; the mask pair it completes, if that pair waits for it."""
        if self._low_masks.add(side, stamp_ns, low_mask) is None:
            return []
        self.low_masks_seen = True
        waiting = self._awaiting_low.pop(stamp_ns, None)
        if waiting is None:
            return []  # kept for the masks of its stamp
        left, right, _ = waiting
        return [ReadyPair(stamp_ns, left, right, self._low_masks.take(stamp_ns))]

    def overdue(self) -> list[ReadyPair[T]]:
        """The waiting pairs whose wait is over, without their low masks."""
        return self._release_waiting(everything=False)

    def _release_waiting(self, everything: bool) -> list[ReadyPair[T]]:
        now = self._clock()
        ready: list[ReadyPair[T]] = []
        while self._awaiting_low:
            stamp_ns, (left, right, deadline) = next(iter(self._awaiting_low.items()))
            if not everything and deadline > now:
                break
            del self._awaiting_low[stamp_ns]
            self.without_low_masks += 1
            ready.append(ReadyPair(stamp_ns, left, right, None))
        return ready

    def hold(self, pair: ReadyPair[T]) -> None:
        """Keep a ready pair the node cannot order yet; beyond ``capacity`` the oldest is dropped."""
        self._held.append(pair)

    @property
    def held(self) -> int:
        return len(self._held)

    def release_held(self) -> list[ReadyPair[T]]:
        """The held pairs, oldest first, no longer held."""
        pairs = list(self._held)
        self._held.clear()
        return pairs
