"""What player_node and recorder_node share: the main loop.

The main loop takes SIGINT/SIGTERM as a flag, spins, finishes and cleans up.

rclpy's own signal handlers are off (they would shut the context down before the node could
write its report or finalise its bag); :class:`suture_replay.replay.StopSignals` turns both
signals into a flag that the loop checks every 0.1 s.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TypeVar

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from suture_replay.replay import StopSignals

N = TypeVar("N", bound=Node)


def run_until_stopped(
    make_node: Callable[[], N],
    executable: str,
    args: list[str] | None,
    finished: Callable[[N], bool],
    finish: Callable[[N], None],
    finish_error: Callable[[N, OSError], str],
) -> int:
    """Build the node, spin until a signal or ``finished(node)``, then ``finish(node)``; the exit status.

    A ValueError while building the node (a bad parameter) and an OSError from ``finish`` (a file
    that cannot be written; ``finish_error`` words it) are one line on standard error and status 1.
    """
    with StopSignals() as stop:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        try:
            try:
                node = make_node()
            except ValueError as exc:
                print(f"{executable}: {exc}", file=sys.stderr)
                return 1
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            try:
                try:
                    while stop.received is None and not finished(node):
                        executor.spin_once(timeout_sec=0.1)
                except ExternalShutdownException:
                    pass
                finish(node)
            except OSError as exc:
                print(f"{executable}: {finish_error(node, exc)}", file=sys.stderr)
                return 1
            finally:
                executor.shutdown()
                node.destroy_node()
            return 0
        finally:
            rclpy.try_shutdown()
