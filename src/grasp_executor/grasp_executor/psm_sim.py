# SPDX-License-Identifier: Apache-2.0
"""A kinematic PSM, like the dVRK's kinematic simulation mode: the measured pose follows the goal.

Each ``move_cp`` goal starts a trajectory from the current pose: position on a
straight line, orientation by slerp, both on one quintic time scaling
s(t) = 10 t^3 - 15 t^4 + 6 t^5 (zero velocity and acceleration at both ends),
lasting so that the peak speeds are ``linear_speed`` (m/s) and
``angular_speed`` (rad/s). ``jaw/move_jp`` goals do the same for the jaw angle
at ``jaw_speed``. When a trajectory ends, :meth:`KinematicPsm.update` reports
``goal_reached`` true; a goal that replaces a running trajectory reports false
for the one it interrupts. There are no joint limits, dynamics or tracking
error: measured equals setpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from grasp_executor.geometry import Pose, rotation_angle, slerp

_PEAK_OVER_MEAN_SPEED = 1.875  # of the quintic time scaling


def _scaling(fraction: float) -> float:
    t = min(max(fraction, 0.0), 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t**2)


@dataclass(frozen=True)
class _Trajectory:
    start: Pose | float
    goal: Pose | float
    t0: float
    duration: float

    def fraction(self, now: float) -> float:
        return 1.0 if self.duration <= 0 else _scaling((now - self.t0) / self.duration)


class KinematicPsm:
    """The arm state and its two trajectories (tool pose, jaw); times in seconds on any monotonic clock."""

    def __init__(
        self,
        pose: Pose,
        jaw: float = 0.0,
        *,
        linear_speed: float = 0.05,
        angular_speed: float = 1.0,
        jaw_speed: float = 1.0,
    ) -> None:
        for name, value in (
            ("linear_speed", linear_speed),
            ("angular_speed", angular_speed),
            ("jaw_speed", jaw_speed),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value}")
        _check_pose(pose, "initial pose")
        self._pose = pose
        self._jaw = float(jaw)
        self._linear_speed = linear_speed
        self._angular_speed = angular_speed
        self._jaw_speed = jaw_speed
        self._cartesian: _Trajectory | None = None
        self._jaw_trajectory: _Trajectory | None = None

    @property
    def pose(self) -> Pose:
        return self._pose

    @property
    def jaw(self) -> float:
        return self._jaw

    @property
    def moving(self) -> bool:
        return self._cartesian is not None or self._jaw_trajectory is not None

    def move_cp(self, goal: Pose, now: float) -> list[bool]:
        """Start a trajectory to ``goal``; returns goal_reached events due now (false if interrupting)."""
        _check_pose(goal, "move_cp goal")
        events = self.update(now)
        if self._cartesian is not None:
            events.append(False)
        goal = Pose(goal.position, goal.quaternion / np.linalg.norm(goal.quaternion), self._pose.frame_id)
        distance = float(np.linalg.norm(goal.position - self._pose.position))
        angle = rotation_angle(self._pose.quaternion, goal.quaternion)
        duration = _PEAK_OVER_MEAN_SPEED * max(distance / self._linear_speed, angle / self._angular_speed)
        self._cartesian = _Trajectory(self._pose, goal, now, duration)
        return events

    def move_jaw(self, angle: float, now: float) -> list[bool]:
        """Start a jaw trajectory to ``angle`` radians; returns goal_reached events due now."""
        if not math.isfinite(angle):
            raise ValueError("jaw goal is NaN or inf")
        events = self.update(now)
        if self._jaw_trajectory is not None:
            events.append(False)
        duration = _PEAK_OVER_MEAN_SPEED * abs(angle - self._jaw) / self._jaw_speed
        self._jaw_trajectory = _Trajectory(self._jaw, float(angle), now, duration)
        return events

    def update(self, now: float) -> list[bool]:
        """Advance to ``now``; returns ``[True]`` for each trajectory that ended (goal_reached events)."""
        events: list[bool] = []
        if self._cartesian is not None:
            trajectory = self._cartesian
            s = trajectory.fraction(now)
            start, goal = trajectory.start, trajectory.goal
            position = start.position + s * (goal.position - start.position)
            self._pose = Pose(position, slerp(start.quaternion, goal.quaternion, s), start.frame_id)
            if s >= 1.0:
                self._pose = goal
                self._cartesian = None
                events.append(True)
        if self._jaw_trajectory is not None:
            trajectory = self._jaw_trajectory
            s = trajectory.fraction(now)
            self._jaw = trajectory.start + s * (trajectory.goal - trajectory.start)
            if s >= 1.0:
                self._jaw = trajectory.goal
                self._jaw_trajectory = None
                events.append(True)
        return events


def _check_pose(pose: Pose, what: str) -> None:
    if not pose.is_finite():
        raise ValueError(f"{what} contains NaN or inf")
    norm = float(np.linalg.norm(pose.quaternion))
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"{what} orientation is not a unit quaternion (norm {norm:.4g})")
