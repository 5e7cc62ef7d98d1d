# SPDX-License-Identifier: Apache-2.0
"""SIGINT and SIGTERM as a flag: how every node executable stops through its clean-up.

Python's default SIGINT handler raises ``KeyboardInterrupt`` wherever the main thread happens
to be, and rclpy's own handler shuts the ROS context down from another thread while the
executor may be building its wait set; either way a Ctrl-C at an unlucky moment ends a node with
a traceback, an unwritten report or an arm that was not told to hold. With :class:`StopSignals`
both signals only set :attr:`StopSignals.received`; the node's loop polls it and leaves through
its normal clean-up (:func:`suture_common.ros.run_node`). ROS-free, main thread only.
"""

from __future__ import annotations

import signal
from collections.abc import Collection
from types import FrameType
from typing import Any


class StopSignals:
    """SIGINT and SIGTERM set :attr:`received` instead of raising or killing the process.

    Use as a context manager. Both handlers are installed explicitly, because a process started
    in the background by a shell script inherits SIGINT ignored. Further signals while the
    process is already stopping change nothing: the clean-up runs to its end (SIGKILL remains
    the way to force an exit). On exit the previous handlers come back, unless a signal was
    received: then both signals stay ignored, so a second Ctrl-C while the interpreter shuts
    down cannot raise ``KeyboardInterrupt`` there.
    """

    SIGNALS: Collection[signal.Signals] = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        """The first signal received (its number), or None."""
        self._previous: dict[signal.Signals, Any] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.received is None:
            self.received = signum

    def __enter__(self) -> StopSignals:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler if self.received is None else signal.SIG_IGN)
        self._previous.clear()
