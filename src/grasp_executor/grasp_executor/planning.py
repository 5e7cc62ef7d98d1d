# SPDX-License-Identifier: Apache-2.0
"""Motion plans: steps (move, jaw, dwell) and the grasp plan.

A grasp plan from a grasp pose in the robot base frame (x along the thread,
z the approach direction, see :mod:`suture_common.grasp`) is

    open jaw -> pre-grasp -> grasp -> close jaw -> lift

* the commanded tool orientation is the grasp orientation followed by the fixed
  ``tool_rotation`` (grasp frame -> tool frame; identity when the tool's z axis
  is its approach axis and its jaws close across the tool's x axis, as in the
  grasp frame);
* pre-grasp is ``approach_offset`` back along the approach axis (towards the
  camera, away from the tissue), with the grasp orientation, so the last
  motion is a straight approach;
* lift retreats ``lift_distance`` back along the same axis: the way the tool
  came in is known to be free;
* backends without a jaw (a UR with a touching tip) skip the jaw steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from grasp_executor.geometry import Pose, quaternion_multiply
from suture_common.parameters import described


@dataclass(frozen=True)
class Move:
    """Move the tool to ``pose`` (robot base frame). ``is_target`` moves are published as commanded."""

    name: str
    pose: Pose
    is_target: bool = False


@dataclass(frozen=True)
class Jaw:
    """Move the jaw to ``angle`` radians."""

    name: str
    angle: float


@dataclass(frozen=True)
class Dwell:
    """Wait ``seconds``; with ``keypoint`` set, then record the measured tool pose for that key point."""

    name: str
    seconds: float
    keypoint: int | None = None


Step = Move | Jaw | Dwell


@dataclass(frozen=True)
class Plan:
    """An ordered sequence of steps. ``target`` is the pose to show as the plan's goal."""

    kind: str
    target: Pose
    steps: tuple[Step, ...]
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(N, 3) key points in the base frame (key-point plans only)."""

    def moves(self) -> list[tuple[str, Pose]]:
        """``(name, pose)`` of every Move, in order."""
        return [(step.name, step.pose) for step in self.steps if isinstance(step, Move)]

    def jaws(self) -> list[tuple[str, float]]:
        """``(name, angle)`` of every Jaw step, in order."""
        return [(step.name, step.angle) for step in self.steps if isinstance(step, Jaw)]

    def first_pose(self) -> Pose:
        """The target of the first Move (every plan has one)."""
        return self.moves()[0][1]


@dataclass(frozen=True)
class GraspConfig:
    """Parameters of :func:`plan_grasp`; metres and radians."""

    approach_offset: float = field(
        default=0.01,
        metadata=described("pre-grasp distance back along the approach axis (m)", (0.0, 0.5)),
    )
    lift_distance: float = field(
        default=0.01,
        metadata=described(
            "lift distance back along the approach axis after closing the jaw (m)", (0.0, 0.5)
        ),
    )
    jaw_open: float = field(
        default=0.8,
        metadata=described("jaw angle before the grasp (rad)", (-math.pi, math.pi)),
    )
    jaw_close: float = field(
        default=-0.1,
        metadata=described("jaw angle of the grasp (rad; dVRK: negative squeezes)", (-math.pi, math.pi)),
    )
    tool_rotation: tuple[float, float, float, float] = field(
        default=(0.0, 0.0, 0.0, 1.0),
        metadata=described("fixed rotation [x, y, z, w] from the grasp frame to the commanded tool frame"),
    )

    def __post_init__(self) -> None:
        for name in ("approach_offset", "lift_distance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative distance in metres, got {value}")
        for name in ("jaw_open", "jaw_close"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be a finite angle in radians")
        rotation = np.asarray(self.tool_rotation, dtype=np.float64)
        norm = float(np.linalg.norm(rotation)) if rotation.shape == (4,) else float("nan")
        if not (np.isfinite(rotation).all() and abs(norm - 1.0) <= 1e-3):
            raise ValueError(f"tool_rotation must be a unit quaternion (x, y, z, w), got {rotation.tolist()}")
        object.__setattr__(self, "tool_rotation", tuple((rotation / norm).tolist()))


def plan_grasp(grasp: Pose, config: GraspConfig, has_jaw: bool = True) -> Plan:
    """The grasp plan (module docstring) for ``grasp``, a grasp pose in the robot base frame."""
    approach = grasp.axis(2)
    tool = Pose(grasp.position, quaternion_multiply(grasp.quaternion, config.tool_rotation), grasp.frame_id)
    steps: list[Step] = []
    if has_jaw:
        steps.append(Jaw("open_jaw", config.jaw_open))
    steps += [
        Move("pre_grasp", tool.translated(-config.approach_offset * approach)),
        Move("grasp", tool, is_target=True),
    ]
    if has_jaw:
        steps.append(Jaw("close_jaw", config.jaw_close))
    steps.append(Move("lift", tool.translated(-config.lift_distance * approach)))
    return Plan("grasp", tool, tuple(steps))
