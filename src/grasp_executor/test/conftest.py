# SPDX-License-Identifier: Apache-2.0
"""Fakes shared by the grasp_executor tests: a fake clock, robot seams that record every call.

Test modules are imported with ``--import-mode=importlib``, so they cannot
import this file; the fakes reach them through the fixtures at the bottom.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import pytest

from grasp_executor.backends.base import AbortedError
from grasp_executor.geometry import Pose, quaternion_to_rotvec


class FakeClock:
    """Monotonic seconds that advance only when something sleeps or waits."""

    def __init__(self, start: float = 1000.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(0.0, seconds)


class FakeCrtk:
    """A CRTK transport (see grasp_executor.backends.dvrk.CrtkTransport) over a scripted arm.

    ``mode``: 'reach' (goals are reached after ``duration`` s and goal_reached true
    is sent), 'never' (no goal_reached), 'false' (goal_reached false), 'drift'
    (goal_reached true but the arm stops ``drift`` m short). ``lose_after_waits``
    stops the measured_cp stream after that many waits (a lost connection).
    """

    namespace = "/PSM1"

    def __init__(
        self, clock: FakeClock, pose: Pose | None, mode: str = "reach", duration: float = 0.1
    ) -> None:
        self.clock = clock
        self.pose = pose
        self.mode = mode
        self.duration = duration
        self.drift = 0.005
        self.jaw = 0.0
        self.goals: list[Pose] = []
        self.jaw_goals: list[float] = []
        self.measured_at = clock.now
        self.alive = True
        self.lose_after_waits: int | None = None
        self.waits = 0
        self._count = 0
        self._events: list[bool] = []
        self._pending: tuple[str, object, float] | None = None

    def send_goal(self, pose: Pose) -> None:
        self.goals.append(pose)
        self._pending = ("cp", pose, self.clock.now + self.duration)

    def send_jaw(self, angle: float) -> None:
        self.jaw_goals.append(angle)
        self._pending = ("jaw", angle, self.clock.now + self.duration)

    def measured(self) -> tuple[Pose, float] | None:
        if self.pose is None:
            return None
        return self.pose, self.clock.now - self.measured_at

    def goal_reached_count(self) -> int:
        return self._count

    def close(self) -> None:
        self.closed = True

    def wait_goal_reached(self, after: int, timeout_s: float) -> bool | None:
        self.waits += 1
        if self.lose_after_waits is not None and self.waits > self.lose_after_waits:
            self.alive = False
        if self._count <= after and self._pending is not None and self.mode != "never":
            kind, goal, due = self._pending
            if due <= self.clock.now + timeout_s:
                self.clock.now = max(self.clock.now, due)
                self._finish(kind, goal)
                return self._result(after)
        self.clock.sleep(timeout_s)
        if self.alive:
            self.measured_at = self.clock.now
        return self._result(after)

    def _finish(self, kind: str, goal: object) -> None:
        self._pending = None
        if kind == "cp":
            assert isinstance(goal, Pose)
            if self.mode == "drift":
                goal = goal.translated([self.drift, 0.0, 0.0])
            if self.mode != "false":
                self.pose = goal
        else:
            self.jaw = float(goal)
        if self.alive:
            self.measured_at = self.clock.now
        self._count += 1
        self._events.append(self.mode != "false")

    def _result(self, after: int) -> bool | None:
        return self._events[after] if self._count > after else None


@dataclass
class FakeUr:
    """The state behind fake RTDEControlInterface/RTDEReceiveInterface objects.

    The TCP moves toward the last moveL target at the commanded speed as the fake
    clock advances; ``stuck`` keeps it still, ``disconnect_at`` (clock time) drops
    the connection (isConnected false, reads raise RuntimeError), ``safety_mode``
    is what getSafetyMode returns.
    """

    clock: FakeClock
    tcp: np.ndarray
    stuck: bool = False
    disconnect_at: float | None = None
    safety_mode: int = 1
    accept: bool = True
    move_calls: list[tuple[list[float], float, float, bool]] = field(default_factory=list)
    stop_calls: list[float] = field(default_factory=list)
    connects: int = 0
    _target: np.ndarray | None = None
    _speed: float = 0.0
    _last: float = 0.0
    _moving: bool = False

    def connected(self) -> bool:
        return self.disconnect_at is None or self.clock.now < self.disconnect_at

    def advance(self) -> None:
        dt = self.clock.now - self._last
        self._last = self.clock.now
        self._moving = False
        if self._target is None or self.stuck:
            return
        delta = self._target[:3] - self.tcp[:3]
        distance = float(np.linalg.norm(delta))
        step = self._speed * dt
        if distance <= step:
            self.tcp = self._target.copy()
        else:
            self.tcp = np.concatenate([self.tcp[:3] + delta / distance * step, self._target[3:]])
            self._moving = True

    def connect(self) -> tuple[FakeRtdeControl, FakeRtdeReceive]:
        self.connects += 1
        if not self.connected():
            raise RuntimeError("fake: cannot connect")
        self._last = self.clock.now
        return FakeRtdeControl(self), FakeRtdeReceive(self)


class FakeRtdeControl:
    """The RTDEControlInterface methods the backend uses."""

    def __init__(self, ur: FakeUr) -> None:
        self.ur = ur

    def moveL(self, pose: list[float], speed: float, acceleration: float, asynchronous: bool) -> bool:  # noqa: N802
        if not self.ur.connected():
            raise RuntimeError("fake: RTDE control connection lost")
        self.ur.move_calls.append((list(pose), speed, acceleration, asynchronous))
        if not self.ur.accept:
            return False
        self.ur.advance()
        self.ur._target = np.asarray(pose, dtype=np.float64)
        self.ur._speed = speed
        return True

    def stopL(self, a: float) -> None:  # noqa: N802
        self.ur.stop_calls.append(a)
        if not self.ur.connected():
            raise RuntimeError("fake: RTDE control connection lost")
        self.ur._target = None

    def isConnected(self) -> bool:  # noqa: N802
        return self.ur.connected()

    def disconnect(self) -> None:
        pass


class FakeRtdeReceive:
    """The RTDEReceiveInterface methods the backend uses."""

    def __init__(self, ur: FakeUr) -> None:
        self.ur = ur

    def _read(self) -> None:
        if not self.ur.connected():
            raise RuntimeError("fake: RTDE receive connection lost")
        self.ur.advance()

    def getActualTCPPose(self) -> list[float]:  # noqa: N802
        self._read()
        return self.ur.tcp.tolist()

    def getActualTCPSpeed(self) -> list[float]:  # noqa: N802
        self._read()
        return [self.ur._speed if self.ur._moving else 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]

    def getSafetyMode(self) -> int:  # noqa: N802
        self._read()
        return self.ur.safety_mode

    def isConnected(self) -> bool:  # noqa: N802
        return self.ur.connected()

    def disconnect(self) -> None:
        pass


class RecordingBackend:
    """A perfect virtual robot that records every command with the measured pose at that moment.

    After each move the measured pose is the target plus ``tracking_error`` (a
    (3,) offset), so the measured pose differs from the plan as on a real robot.
    """

    name = "recording"

    def __init__(
        self, start: Pose | None, has_jaw: bool = True, tracking_error: np.ndarray | None = None
    ) -> None:
        self.pose = start
        self.has_jaw = has_jaw
        self.tracking_error = np.zeros(3) if tracking_error is None else np.asarray(tracking_error)
        self.moves: list[tuple[Pose, Pose | None]] = []
        self.jaws: list[float] = []
        self.stops = 0
        self.prepared: list[Pose] = []

    def prepare(self, first_target: Pose) -> None:
        self.prepared.append(first_target)

    def measured_pose(self) -> Pose | None:
        return self.pose

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        if cancel.is_set():
            raise AbortedError("cancelled")
        self.moves.append((target, self.pose))
        self.pose = target.translated(self.tracking_error)

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        self.jaws.append(angle)

    def stop(self) -> str:
        self.stops += 1
        return "recording: stopped"

    def close(self) -> None:
        pass


def ur_pose(pose: Pose) -> np.ndarray:
    """[x, y, z, rx, ry, rz] of a pose (for setting a fake UR's TCP)."""
    return np.concatenate([pose.position, quaternion_to_rotvec(pose.quaternion)])


@pytest.fixture
def fake_clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def fakes():
    """The fake classes, for tests that build their own."""

    @dataclass
    class Fakes:
        Clock = FakeClock
        Crtk = FakeCrtk
        Ur = FakeUr
        Recording = RecordingBackend
        ur_pose = staticmethod(ur_pose)

    return Fakes
