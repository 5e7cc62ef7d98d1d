# SPDX-License-Identifier: Apache-2.0
"""The ``dry_run`` backend: logs every command and moves nothing.

It keeps a virtual tool that is wherever it was last commanded. There is no
robot to measure, so at the start of each run (:meth:`DryRunBackend.prepare`)
the virtual tool is placed at the run's first target: a dry run checks the
workspace box, the age, NaN and every step *within* the plan, but not the
first step from a real robot's pose, which only a robot backend can measure.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from grasp_executor.backends.base import AbortedError
from grasp_executor.geometry import Pose


class DryRunBackend:
    """Plans and logs; never moves anything. ``log`` receives one line per command."""

    name = "dry_run"
    has_jaw = True

    def __init__(self, log: Callable[[str], None] = print) -> None:
        self._log = log
        self._pose: Pose | None = None
        self.jaw: float | None = None

    def prepare(self, first_target: Pose) -> None:
        self._pose = first_target

    def measured_pose(self) -> Pose | None:
        return self._pose

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        if cancel.is_set():
            raise AbortedError("dry run aborted")
        position = ", ".join(f"{v:.4f}" for v in target.position)
        quaternion = ", ".join(f"{v:.4f}" for v in target.quaternion)
        self._log(f"dry_run: move_to ({position}) m, quaternion ({quaternion}) in {target.frame_id!r}")
        self._pose = target

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        if cancel.is_set():
            raise AbortedError("dry run aborted")
        self._log(f"dry_run: jaw to {angle:.3f} rad")
        self.jaw = angle

    def stop(self) -> str:
        self._log("dry_run: stop")
        return "dry run: nothing to stop"

    def close(self) -> None:
        pass
