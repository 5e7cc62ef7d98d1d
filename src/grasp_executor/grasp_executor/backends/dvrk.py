# SPDX-License-Identifier: Apache-2.0
"""The ``dvrk`` backend: a dVRK PSM through its CRTK topics, behind a transport seam.

The backend logic (what to send, what to wait for, when to give up) is here and
ROS-free; the topics themselves are a :class:`CrtkTransport`, implemented with
rclpy in :mod:`grasp_executor.crtk_ros` and by a fake in the tests. Under the
arm namespace (default ``/PSM1``):

* ``move_cp`` (geometry_msgs/PoseStamped): Cartesian goals, in the frame of
  ``measured_cp`` (docs/interfaces.md, Robots);
* ``jaw/move_jp`` (sensor_msgs/JointState): one jaw position in radians;
* ``measured_cp`` (geometry_msgs/PoseStamped): the measured tool pose; its
  stream is the connection's heartbeat: no message for ``measured_timeout``
  seconds is a lost connection;
* ``goal_reached`` (std_msgs/Bool): true when a ``move_cp``/``jaw/move_jp``
  trajectory ends at its goal, false when it ends elsewhere.

A Cartesian move is done when ``goal_reached`` is true *and* ``measured_cp``
is within ``position_tolerance`` of the goal (within ``settle_s`` after
``goal_reached``). Stopping sends a ``move_cp`` goal at the last measured pose,
which ends any running trajectory where the arm is.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from grasp_executor.backends.base import (
    AbortedError,
    BackendError,
    ConnectionLostError,
    MotionTimeoutError,
    NotReadyError,
)
from grasp_executor.geometry import Pose


class CrtkTransport(Protocol):
    """The four CRTK exchanges the backend needs; thread-safe."""

    namespace: str

    def send_goal(self, pose: Pose) -> None:
        """Publish ``pose`` on ``move_cp``."""
        ...

    def send_jaw(self, angle: float) -> None:
        """Publish ``angle`` (radians) on ``jaw/move_jp``."""
        ...

    def measured(self) -> tuple[Pose, float] | None:
        """The latest ``measured_cp`` and its age in seconds, or None before the first one."""
        ...

    def goal_reached_count(self) -> int:
        """How many ``goal_reached`` messages have arrived so far."""
        ...

    def wait_goal_reached(self, after: int, timeout_s: float) -> bool | None:
        """The value of ``goal_reached`` message number ``after + 1`` (counting from 1).

        Returns at once if it has arrived, else waits up to ``timeout_s``;
        None if it has not arrived by then.
        """
        ...

    def close(self) -> None:
        """Release the topics (node shutdown)."""
        ...


class DvrkBackend:
    """A PSM over CRTK: move_cp goals, jaw/move_jp, measured_cp and goal_reached feedback."""

    name = "dvrk"
    has_jaw = True

    def __init__(
        self,
        transport: CrtkTransport,
        *,
        measured_timeout: float = 0.5,
        position_tolerance: float = 0.002,
        settle_s: float = 0.5,
        poll_s: float = 0.02,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not (measured_timeout > 0 and position_tolerance > 0 and settle_s >= 0 and poll_s > 0):
            raise ValueError(
                "measured_timeout, position_tolerance and poll_s must be positive, settle_s >= 0"
            )
        self._transport = transport
        self._measured_timeout = measured_timeout
        self._tolerance = position_tolerance
        self._settle_s = settle_s
        self._poll_s = poll_s
        self._clock = clock
        self._sleep = sleep

    @property
    def _topic(self) -> str:
        return f"{self._transport.namespace.rstrip('/')}/measured_cp"

    def prepare(self, first_target: Pose) -> None:
        measured = self._transport.measured()
        if measured is None:
            raise NotReadyError(
                f"no message on {self._topic} yet: is the dVRK console running, the arm powered and homed?"
            )
        if measured[1] > self._measured_timeout:
            raise NotReadyError(
                f"{self._topic} is {measured[1]:.2f} s old (max {self._measured_timeout:.2f} s): "
                "the dVRK stopped publishing"
            )

    def measured_pose(self) -> Pose | None:
        measured = self._transport.measured()
        return None if measured is None else measured[0]

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        self._check_connection("before move_cp")
        count = self._transport.goal_reached_count()
        self._transport.send_goal(target)
        deadline = self._clock() + timeout_s
        what = "move_cp goal"
        self._wait_goal_reached(count, deadline, timeout_s, cancel, what)
        settle_deadline = min(deadline, self._clock() + self._settle_s)
        while True:
            distance = float(np.linalg.norm(self._transport.measured()[0].position - target.position))
            if distance <= self._tolerance:
                return
            if self._clock() >= settle_deadline:
                raise BackendError(
                    f"goal_reached, but {self._topic} is {distance * 1000:.1f} mm from the {what} "
                    f"(tolerance {self._tolerance * 1000:.1f} mm)"
                )
            self._check_cancel(cancel, what)
            self._check_connection(f"while settling at the {what}")
            self._sleep(self._poll_s)

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        self._check_connection("before jaw/move_jp")
        count = self._transport.goal_reached_count()
        self._transport.send_jaw(angle)
        self._wait_goal_reached(count, self._clock() + timeout_s, timeout_s, cancel, "jaw goal")

    def stop(self) -> str:
        try:
            measured = self._transport.measured()
            if measured is None:
                return "no measured_cp to hold; nothing sent"
            self._transport.send_goal(measured[0])
            return f"sent move_cp to the last measured pose (hold) on {self._transport.namespace}"
        except Exception as exc:  # stop must never raise: it runs while handling another fault
            return f"stop could not be sent: {exc}"

    def close(self) -> None:
        self._transport.close()

    def _wait_goal_reached(
        self, count: int, deadline: float, timeout_s: float, cancel: threading.Event, what: str
    ) -> None:
        while True:
            self._check_cancel(cancel, what)
            self._check_connection(f"while moving to the {what}")
            remaining = deadline - self._clock()
            if remaining <= 0:
                raise MotionTimeoutError(
                    f"motion timeout: {what} not reached within {timeout_s:.1f} s "
                    f"(no goal_reached on {self._transport.namespace})"
                )
            reached = self._transport.wait_goal_reached(count, min(self._poll_s, remaining))
            if reached is None:
                continue
            if not reached:
                raise BackendError(
                    f"the dVRK reported goal_reached false for the {what} (unreachable goal or interrupted)"
                )
            return

    def _check_cancel(self, cancel: threading.Event, what: str) -> None:
        if cancel.is_set():
            raise AbortedError(f"aborted while moving to the {what}")

    def _check_connection(self, when: str) -> None:
        measured = self._transport.measured()
        if measured is None:
            raise ConnectionLostError(f"connection lost {when}: no message on {self._topic}")
        if measured[1] > self._measured_timeout:
            raise ConnectionLostError(
                f"connection lost {when}: no message on {self._topic} for {measured[1]:.2f} s "
                f"(max {self._measured_timeout:.2f} s)"
            )
