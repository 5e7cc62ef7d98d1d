# SPDX-License-Identifier: Apache-2.0
"""The backend interface and the faults a backend reports.

A backend moves one robot. Its calls block until the motion ends, so a caller
knows where the robot is; each wait ends with a fault instead of hanging:

* :class:`MotionTimeoutError`: the motion did not finish within ``timeout_s``;
* :class:`ConnectionLostError`: the robot stopped answering (no feedback, socket down);
* :class:`AbortedError`: ``cancel`` was set (an abort request, a disarm);
* :class:`BackendError`: anything else the robot reported (goal not reached,
  command rejected, protective stop).

After any of them the caller must call :meth:`Backend.stop`. :class:`NotReadyError`
comes from :meth:`Backend.prepare` only, before anything moved.

Backends do not check targets: the safety gate does, in front of them
(:class:`grasp_executor.safety.GuardedBackend`).
"""

from __future__ import annotations

import threading
from typing import Protocol, runtime_checkable

from grasp_executor.geometry import Pose


class BackendError(RuntimeError):
    """A motion failed; the robot may have moved part of the way. The text names the cause."""


class MotionTimeoutError(BackendError):
    """A motion did not finish within its timeout."""


class ConnectionLostError(BackendError):
    """The robot's feedback or connection stopped during a run."""


class AbortedError(BackendError):
    """The run was cancelled (abort request or disarm) while a motion was under way."""


class NotReadyError(RuntimeError):
    """The backend cannot start a run (no connection, no feedback yet); nothing moved."""


@runtime_checkable
class Backend(Protocol):
    """What the executor needs from a robot. Poses are in the robot base frame, SI units."""

    name: str
    """Short name for messages: 'dry_run', 'dvrk', 'ur'."""

    has_jaw: bool
    """Whether :meth:`move_jaw` drives a gripper (plans skip jaw steps otherwise)."""

    def prepare(self, first_target: Pose) -> None:
        """Get ready for a run whose first motion goes to ``first_target``; NotReadyError if impossible."""
        ...

    def measured_pose(self) -> Pose | None:
        """The latest measured tool pose, or None when the robot has reported none."""
        ...

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        """Move the tool to ``target``; return when it is there, raise a BackendError subclass if not."""
        ...

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        """Move the jaw to ``angle`` radians and return when done; raise a BackendError subclass otherwise."""
        ...

    def stop(self) -> str:
        """Tell the robot to stop now. Never raises; returns what was done, for the fault message."""
        ...

    def close(self) -> None:
        """Release the connection (node shutdown)."""
        ...
