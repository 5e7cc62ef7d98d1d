# SPDX-License-Identifier: Apache-2.0
"""Every safety check of the executor, in one place: :class:`SafetyGate` and :class:`GuardedBackend`.

Checks (each refusal raises :class:`RefusedError` whose ``reason`` a person can act on):

* armed: motion only while the ``armed`` parameter is true;
* age: the grasp pose (or path) stamp is at most ``max_age`` seconds from now,
  in either direction (a stamp from the future means unsynchronised clocks);
* finite: no NaN or infinity in a target, a jaw angle or the measured pose;
* frame: a target is in the frame of the measured pose (when both name one);
* workspace: every target position lies inside the axis-aligned box
  ``workspace_min`` .. ``workspace_max`` (base frame, bounds included);
* step: every target position is at most ``max_step`` metres from the tool's
  measured position at the moment it is commanded;
* jaw: jaw angles lie within ``jaw_min`` .. ``jaw_max``.

A plan is checked as a whole before its first motion (:meth:`SafetyGate.check_plan`:
each target against the box and against the previous target), and every single
command is checked again against the live measured pose as it is sent
(:class:`GuardedBackend`, the only way the executor reaches a backend).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from grasp_executor.backends.base import Backend
from grasp_executor.geometry import Pose
from suture_common.parameters import described

_AXES = "xyz"


class RefusedError(Exception):
    """A safety check failed; nothing was commanded. ``reason`` says which check and by how much."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class SafetyLimits:
    """Limits of :class:`SafetyGate`; SI units, positions in the robot base frame."""

    workspace_min: tuple[float, float, float] = field(
        metadata=described(
            "lower corner [x, y, z] of the box every commanded position must lie in (m, base frame)"
        )
    )
    workspace_max: tuple[float, float, float] = field(
        metadata=described(
            "upper corner [x, y, z] of the box every commanded position must lie in (m, base frame)"
        )
    )
    max_step: float = field(
        default=0.05,
        metadata=described(
            "largest distance from the measured tool position to any commanded position (m; > 0)", (0.0, 2.0)
        ),
    )
    max_age: float = field(
        default=1.0,
        metadata=described(
            "largest age of the grasp pose (or path) at execute, either way (s; > 0)", (0.0, 3600.0)
        ),
    )
    jaw_min: float = field(
        default=-0.35,
        metadata=described("smallest jaw angle commanded; below it is refused (rad)", (-math.pi, math.pi)),
    )
    jaw_max: float = field(
        default=1.4,
        metadata=described("largest jaw angle commanded; above it is refused (rad)", (-math.pi, math.pi)),
    )

    def __post_init__(self) -> None:
        low = np.asarray(self.workspace_min, dtype=np.float64)
        high = np.asarray(self.workspace_max, dtype=np.float64)
        if low.shape != (3,) or high.shape != (3,):
            raise ValueError("workspace_min and workspace_max need 3 values each (x, y, z in metres)")
        if not (np.isfinite(low).all() and np.isfinite(high).all()) or (low >= high).any():
            raise ValueError(
                f"workspace box must be finite with min < max on every axis, got min {low.tolist()} "
                f"max {high.tolist()}"
            )
        for name in ("max_step", "max_age"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")
        if not (math.isfinite(self.jaw_min) and math.isfinite(self.jaw_max) and self.jaw_min < self.jaw_max):
            raise ValueError(
                f"jaw limits must be finite with jaw_min < jaw_max, got {self.jaw_min}, {self.jaw_max}"
            )
        object.__setattr__(self, "workspace_min", tuple(low.tolist()))
        object.__setattr__(self, "workspace_max", tuple(high.tolist()))


class SafetyGate:
    """Decides whether a command may be sent. Thread-safe; arming is the only mutable state."""

    def __init__(self, limits: SafetyLimits, armed: bool = False) -> None:
        self.limits = limits
        self._low = np.asarray(limits.workspace_min)
        self._high = np.asarray(limits.workspace_max)
        self._armed = threading.Event()
        if armed:
            self._armed.set()

    @property
    def armed(self) -> bool:
        return self._armed.is_set()

    def set_armed(self, armed: bool) -> None:
        if armed:
            self._armed.set()
        else:
            self._armed.clear()

    # ------------------------------------------------------------------ single checks

    def check_armed(self) -> None:
        if not self.armed:
            raise RefusedError("not armed: set the parameter armed to true to allow motion")

    def check_age(self, age_s: float, what: str = "grasp pose") -> None:
        """``what`` was stamped ``age_s`` seconds ago; at most ``max_age`` either way (future: clock skew)."""
        max_age = self.limits.max_age
        if not math.isfinite(age_s):
            raise RefusedError(f"{what} has an invalid stamp")
        if age_s > max_age:
            raise RefusedError(f"{what} is {age_s:.1f} s old (max {max_age:.1f} s)")
        if age_s < -max_age:
            raise RefusedError(
                f"{what} is stamped {-age_s:.1f} s in the future (max {max_age:.1f} s); "
                "synchronise the clocks of the camera and executor machines"
            )

    def check_finite(self, pose: Pose, what: str) -> None:
        if not np.isfinite(pose.position).all():
            raise RefusedError(f"{what} position contains NaN or inf")
        if not np.isfinite(pose.quaternion).all():
            raise RefusedError(f"{what} orientation contains NaN or inf")
        norm = float(np.linalg.norm(pose.quaternion))
        if abs(norm - 1.0) > 1e-3:
            raise RefusedError(f"{what} orientation is not a unit quaternion (norm {norm:.4g})")

    def check_workspace(self, pose: Pose, what: str) -> None:
        """``pose.position`` lies in the workspace box; the refusal names the worst axis and distance."""
        position = pose.position
        if np.all((position >= self._low) & (position <= self._high)):  # fails closed: NaN is never inside
            return
        if not np.isfinite(position).all():
            raise RefusedError(f"{what} position contains NaN or inf")
        outside = np.maximum(self._low - position, 0.0) + np.maximum(position - self._high, 0.0)
        order = np.argsort(-outside)
        worst = int(order[0])
        reason = (
            f"{what} {outside[worst] * 1000:.1f} mm outside workspace box on {_AXES[worst]} "
            f"({_AXES[worst]} = {position[worst]:.4f} m, "
            f"box {self._low[worst]:.4f} .. {self._high[worst]:.4f} m)"
        )
        others = [f"{outside[i] * 1000:.1f} mm on {_AXES[i]}" for i in order[1:] if outside[i] > 0]
        if others:
            reason += "; also " + ", ".join(others)
        raise RefusedError(reason)

    def check_step(self, target: Pose, measured: Pose, what: str) -> None:
        distance = float(np.linalg.norm(target.position - measured.position))
        if not distance <= self.limits.max_step:  # fails closed: a NaN distance is refused
            raise RefusedError(
                f"{what} is {distance * 1000:.1f} mm from the measured tool position "
                f"(max step {self.limits.max_step * 1000:.1f} mm); move the robot closer first"
            )

    def check_frame(self, target: Pose, measured: Pose, what: str) -> None:
        if target.frame_id and measured.frame_id and target.frame_id != measured.frame_id:
            raise RefusedError(
                f"{what} is in frame {target.frame_id!r} but the robot measures in {measured.frame_id!r}; "
                "set base_frame (and the hand-eye transform) for this robot"
            )

    def check_jaw(self, angle: float, what: str = "jaw") -> None:
        low, high = self.limits.jaw_min, self.limits.jaw_max
        if not math.isfinite(angle):
            raise RefusedError(f"{what} angle is NaN or inf")
        if not low <= angle <= high:
            raise RefusedError(f"{what} angle {angle:.3f} rad outside jaw limits {low:.3f} .. {high:.3f} rad")

    def check_measured(self, measured: Pose | None, source: str) -> Pose:
        if measured is None:
            raise RefusedError(f"no measured tool pose from the {source} backend; is the robot connected?")
        self.check_finite(measured, "measured tool pose")
        return measured

    # ------------------------------------------------------------------ composite checks

    def check_move(self, target: Pose, measured: Pose | None, what: str, source: str = "robot") -> None:
        """All checks for one Cartesian command, against the measured pose at the moment it is sent."""
        self.check_armed()
        self._check_target(target, self.check_measured(measured, source), what)

    def check_plan(
        self,
        moves: Sequence[tuple[str, Pose]],
        jaws: Sequence[tuple[str, float]],
        measured: Pose | None,
        source: str = "robot",
    ) -> None:
        """Check a whole plan before its first motion: each ``(name, target)`` in order, and jaw angles.

        Each target must pass the single-command checks with the previous target
        (the measured pose for the first) standing in for the measured pose.
        """
        self.check_armed()
        previous = self.check_measured(measured, source)
        for name, angle in jaws:
            self.check_jaw(angle, name)
        for name, target in moves:
            self._check_target(target, previous, name)
            previous = target

    def _check_target(self, target: Pose, reference: Pose, what: str) -> None:
        self.check_finite(target, what)
        self.check_frame(target, reference, what)
        self.check_workspace(target, what)
        self.check_step(target, reference, what)


class GuardedBackend:
    """A backend behind the gate: each command is checked, with the live measured pose, before it is sent.

    The executor holds only this object, so no command can bypass the gate.
    """

    def __init__(self, backend: Backend, gate: SafetyGate) -> None:
        self._backend = backend
        self.gate = gate

    @property
    def name(self) -> str:
        return self._backend.name

    @property
    def has_jaw(self) -> bool:
        return self._backend.has_jaw

    def prepare(self, first_target: Pose) -> None:
        self.gate.check_armed()
        self._backend.prepare(first_target)

    def measured_pose(self) -> Pose | None:
        return self._backend.measured_pose()

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event, what: str = "target") -> None:
        self.gate.check_move(target, self._backend.measured_pose(), what, self._backend.name)
        self._backend.move_to(target, timeout_s, cancel)

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event, what: str = "jaw") -> None:
        self.gate.check_armed()
        self.gate.check_jaw(angle, what)
        self._backend.move_jaw(angle, timeout_s, cancel)

    def stop(self) -> str:
        return self._backend.stop()

    def close(self) -> None:
        self._backend.close()
