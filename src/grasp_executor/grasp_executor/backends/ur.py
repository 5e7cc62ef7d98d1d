# SPDX-License-Identifier: Apache-2.0
"""The ``ur`` backend: a Universal Robots arm through ``ur_rtde``.

Poses on the wire are ``[x, y, z, rx, ry, rz]``: metres and a rotation vector
in the controller's base frame (the frame the teach pendant shows, not ROS's
``base_link``), of the TCP configured on the controller. Set the TCP to the
touching tip or gripper centre on the pendant (the paper extended the tool by
a translation along z).

The connection seam is the pair of ur_rtde objects, ``RTDEControlInterface``
and ``RTDEReceiveInterface``, created by a ``connect`` callable
(:func:`rtde_connector` imports ur_rtde lazily, so this module imports without
it); tests pass fakes with the same methods. Motions are
``moveL(pose, speed, acceleration, asynchronous=True)`` followed by polling
``getActualTCPPose``/``getActualTCPSpeed``, so that a timeout, a lost
connection, a protective stop or an abort is noticed during the motion and
answered with ``stopL``. A move is done when the TCP is within
``position_tolerance`` of the target and at rest.

The UR has no jaw here (the paper's touching tip): ``has_jaw`` is false and
plans skip the jaw steps.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from grasp_executor.backends.base import (
    AbortedError,
    BackendError,
    ConnectionLostError,
    MotionTimeoutError,
    NotReadyError,
)
from grasp_executor.geometry import Pose, quaternion_to_rotvec, rotvec_to_quaternion

SAFETY_MODES = {
    1: "normal",
    2: "reduced",
    3: "protective stop",
    4: "recovery",
    5: "safeguard stop",
    6: "system emergency stop",
    7: "robot emergency stop",
    8: "violation",
    9: "fault",
    10: "validate joint id",
    11: "undefined safety mode",
    12: "automatic mode safeguard stop",
    13: "three-position enabling stop",
}
_RUNNING_SAFETY_MODES = (1, 2)
_AT_REST_LINEAR = 1e-3  # m/s
_AT_REST_ANGULAR = 1e-2  # rad/s


class RtdeControl(Protocol):
    """The methods of ``rtde_control.RTDEControlInterface`` this backend calls."""

    def moveL(self, pose: list[float], speed: float, acceleration: float, asynchronous: bool) -> bool: ...  # noqa: N802
    def stopL(self, a: float) -> None: ...  # noqa: N802
    def isConnected(self) -> bool: ...  # noqa: N802
    def disconnect(self) -> None: ...


class RtdeReceive(Protocol):
    """The methods of ``rtde_receive.RTDEReceiveInterface`` this backend calls."""

    def getActualTCPPose(self) -> list[float]: ...  # noqa: N802
    def getActualTCPSpeed(self) -> list[float]: ...  # noqa: N802
    def getSafetyMode(self) -> int: ...  # noqa: N802
    def isConnected(self) -> bool: ...  # noqa: N802
    def disconnect(self) -> None: ...


Connector = Callable[[], tuple[RtdeControl, RtdeReceive]]


def rtde_connector(host: str) -> Connector:
    """A ``connect`` callable that opens ur_rtde's control and receive interfaces to ``host``."""
    if not host:
        raise ValueError("the ur backend needs the controller's host name or IP address (parameter ur.host)")

    def connect() -> tuple[RtdeControl, RtdeReceive]:
        import rtde_control  # lazily: the module must import on machines without ur_rtde
        import rtde_receive

        receive = rtde_receive.RTDEReceiveInterface(host)
        control = rtde_control.RTDEControlInterface(host)
        return control, receive

    return connect


def pose_to_ur(pose: Pose) -> list[float]:
    """``[x, y, z, rx, ry, rz]`` of a pose (metres, rotation vector)."""
    return [*pose.position.tolist(), *quaternion_to_rotvec(pose.quaternion).tolist()]


def ur_to_pose(values: Sequence[float], frame_id: str) -> Pose:
    """A Pose from ``[x, y, z, rx, ry, rz]`` as ``getActualTCPPose`` returns it."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (6,):
        raise ValueError(f"a UR pose has 6 values [x, y, z, rx, ry, rz], got {array.shape}")
    return Pose(array[:3], rotvec_to_quaternion(array[3:]), frame_id)


class UrBackend:
    """moveL with speed and acceleration limits; stopL on abort. Connects on the first run."""

    name = "ur"
    has_jaw = False

    def __init__(
        self,
        connect: Connector,
        *,
        frame_id: str = "base",
        speed: float = 0.05,
        acceleration: float = 0.2,
        stop_deceleration: float = 2.0,
        position_tolerance: float = 0.002,
        poll_s: float = 0.01,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        for name, value in (
            ("ur.speed", speed),
            ("ur.acceleration", acceleration),
            ("ur.stop_deceleration", stop_deceleration),
            ("position_tolerance", position_tolerance),
            ("poll_s", poll_s),
        ):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")
        self._connect = connect
        self._frame_id = frame_id
        self._speed = speed
        self._acceleration = acceleration
        self._stop_deceleration = stop_deceleration
        self._tolerance = position_tolerance
        self._poll_s = poll_s
        self._clock = clock
        self._sleep = sleep
        self._control: RtdeControl | None = None
        self._receive: RtdeReceive | None = None

    def prepare(self, first_target: Pose) -> None:
        if self._control is None or not self._connected():
            self._disconnect()
            try:
                self._control, self._receive = self._connect()
            except Exception as exc:  # ur_rtde raises RuntimeError; any failure means no robot
                raise NotReadyError(f"cannot connect to the UR controller: {exc}") from exc
        try:
            mode = int(self._receive.getSafetyMode())
        except Exception as exc:
            raise NotReadyError(f"cannot read the UR safety mode: {exc}") from exc
        if mode not in _RUNNING_SAFETY_MODES:
            raise NotReadyError(
                f"UR safety mode is {SAFETY_MODES.get(mode, mode)}; clear it on the teach pendant"
            )

    def measured_pose(self) -> Pose | None:
        if self._receive is None:
            return None
        try:
            return ur_to_pose(self._receive.getActualTCPPose(), self._frame_id)
        except Exception:  # no pose is the answer when the connection is gone
            return None

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        control, receive = self._require_connection("before moveL")
        pose = pose_to_ur(target)
        try:
            accepted = control.moveL(pose, self._speed, self._acceleration, True)
        except RuntimeError as exc:
            raise ConnectionLostError(f"connection lost sending moveL: {exc}") from exc
        if not accepted:
            raise BackendError(
                "the UR controller rejected moveL (robot in remote control, RTDE script running?)"
            )
        deadline = self._clock() + timeout_s
        while True:
            if cancel.is_set():
                raise AbortedError("aborted during moveL")
            self._require_connection("during moveL")
            try:
                mode = int(receive.getSafetyMode())
                actual = np.asarray(receive.getActualTCPPose(), dtype=np.float64)
                velocity = np.asarray(receive.getActualTCPSpeed(), dtype=np.float64)
            except RuntimeError as exc:
                raise ConnectionLostError(f"connection lost during moveL: {exc}") from exc
            if mode not in _RUNNING_SAFETY_MODES:
                raise BackendError(f"UR entered {SAFETY_MODES.get(mode, mode)} during moveL")
            distance = float(np.linalg.norm(actual[:3] - target.position))
            at_rest = (
                np.linalg.norm(velocity[:3]) < _AT_REST_LINEAR
                and np.linalg.norm(velocity[3:]) < _AT_REST_ANGULAR
            )
            if distance <= self._tolerance and at_rest:
                return
            if self._clock() >= deadline:
                raise MotionTimeoutError(
                    f"motion timeout: moveL not finished within {timeout_s:.1f} s "
                    f"(TCP still {distance * 1000:.1f} mm from the target)"
                )
            self._sleep(self._poll_s)

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        raise BackendError("the ur backend has no jaw (touching tip); plans for it skip jaw steps")

    def stop(self) -> str:
        if self._control is None:
            return "not connected; nothing to stop"
        try:
            self._control.stopL(self._stop_deceleration)
            return f"sent stopL ({self._stop_deceleration:.1f} m/s^2)"
        except Exception as exc:  # stop must never raise: it runs while handling another fault
            return f"stopL could not be sent: {exc}"

    def close(self) -> None:
        self._disconnect()

    def _connected(self) -> bool:
        try:
            return bool(self._control.isConnected() and self._receive.isConnected())
        except Exception:
            return False

    def _require_connection(self, when: str) -> tuple[RtdeControl, RtdeReceive]:
        if self._control is None or self._receive is None:
            raise ConnectionLostError(f"not connected to the UR controller {when}")
        if not self._connected():
            raise ConnectionLostError(f"connection to the UR controller lost {when}")
        return self._control, self._receive

    def _disconnect(self) -> None:
        for interface in (self._control, self._receive):
            if interface is not None:
                with contextlib.suppress(Exception):  # already gone
                    interface.disconnect()
        self._control = self._receive = None
