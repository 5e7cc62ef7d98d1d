# SPDX-License-Identifier: Apache-2.0
"""The ROS-free executor: latest inputs, the state machine, and runs of plans through the safety gate.

States (docs/interfaces.md, ``/grasp_executor/state``)::

    idle --grasp pose--> planned --execute--> executing --> done
                                     |                 \\--> fault: <reason>   (robot told to stop)
                                     \\--> refused: <reason>                   (nothing moved)

* :meth:`GraspExecutor.on_grasp_pose` takes each valid camera-frame grasp pose,
  maps it to the base frame with the hand-eye transform and plans the grasp
  (state ``planned``, the commanded grasp pose goes to the ``target`` listener).
  While a run is executing, new poses are stored but the run is not changed.
* :meth:`GraspExecutor.execute` runs the plan of the latest valid grasp pose;
  :meth:`GraspExecutor.visit_keypoints` runs key-point mode on the latest path.
  Both block until the run ends and return an :class:`Outcome` whose message
  is the final state (``done``, ``refused: ...``, ``fault: ...``).
* A run is refused unless armed, the input is at most ``max_age`` old, and
  the whole plan passes :meth:`SafetyGate.check_plan` against the measured
  pose; every command is checked again as it is sent (:class:`GuardedBackend`).
* Any backend fault (timeout, lost connection, abort, robot error) and any
  refusal after motion began ends the run with :meth:`Backend.stop`.
* :meth:`GraspExecutor.abort` and disarming (:meth:`GraspExecutor.set_armed`)
  cancel a running motion from another thread.

Only one run at a time; a second request while busy is refused.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from grasp_executor.backends.base import AbortedError, Backend, BackendError, NotReadyError
from grasp_executor.geometry import Pose
from grasp_executor.handeye import FrameMismatchError, HandEye
from grasp_executor.keypoints import KeypointConfig, KeypointRecord, evenly_spaced_points, plan_keypoints
from grasp_executor.planning import Dwell, GraspConfig, Jaw, Move, Plan, plan_grasp
from grasp_executor.safety import GuardedBackend, RefusedError, SafetyGate

IDLE = "idle"
PLANNED = "planned"
EXECUTING = "executing"
DONE = "done"


class InvalidInputError(ValueError):
    """A grasp pose or path cannot be used (NaN, wrong frame, too short); the text says why.

    ``reason`` names the problem in one word ("not_finite", "frame", "too_short"): a node
    throttles its warnings per reason, so a new problem is reported at once.
    """

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Outcome:
    """The result of a run or request: ``message`` starts with done, refused: or fault:."""

    success: bool
    message: str


def _ignore(*_: object) -> None:
    pass


@dataclass
class Listeners:
    """Callbacks through which the executor reports; a node publishes and logs them."""

    state: Callable[[str], None] = _ignore
    """Every state change, and every refusal or fault (also when the state text repeats)."""
    target: Callable[[Pose, int], None] = _ignore
    """The commanded grasp pose in the base frame and the stamp (ns) of the input it came from:
    when planned, and as each target move is sent."""
    keypoint: Callable[[KeypointRecord], None] = _ignore
    """Each visited key point, after its dwell."""
    info: Callable[[str], None] = _ignore
    """Progress lines for the log."""


@dataclass
class _Input:
    stamp_ns: int
    plan: Plan | None = None
    points_camera: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


class GraspExecutor:
    """Executes grasp and key-point plans on one backend, behind one safety gate."""

    def __init__(
        self,
        backend: Backend,
        gate: SafetyGate,
        hand_eye: HandEye,
        grasp: GraspConfig | None = None,
        keypoints: KeypointConfig | None = None,
        *,
        motion_timeout: float = 10.0,
        clock: Callable[[], int] = time.time_ns,
        listeners: Listeners | None = None,
    ) -> None:
        if not motion_timeout > 0:
            raise ValueError(f"motion_timeout must be positive, got {motion_timeout}")
        self._robot = GuardedBackend(backend, gate)
        self.gate = gate
        self.hand_eye = hand_eye
        self.grasp_config = grasp or GraspConfig()
        self.keypoint_config = keypoints or KeypointConfig()
        self.motion_timeout = motion_timeout
        self._clock = clock
        self._listeners = listeners or Listeners()
        self._lock = threading.RLock()
        self._cancel = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._abort_reason = ""
        self._busy = False
        self._moving = False
        self._state = IDLE
        self._grasp: _Input | None = None
        self._path: _Input | None = None

    @property
    def state(self) -> str:
        with self._lock:
            return self._state

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._busy

    @property
    def backend_name(self) -> str:
        return self._robot.name

    @property
    def has_path(self) -> bool:
        """Whether a valid suture path has arrived (key-point mode can run)."""
        with self._lock:
            return self._path is not None

    def measured_pose(self) -> Pose | None:
        """The backend's latest measured tool pose (None before the robot reported one)."""
        return self._robot.measured_pose()

    # ------------------------------------------------------------------ inputs

    def on_grasp_pose(self, pose: Pose, stamp_ns: int) -> Plan:
        """Plan the grasp of a camera-frame grasp pose stamped ``stamp_ns``; InvalidInputError if unusable."""
        if not pose.is_finite():
            raise InvalidInputError("grasp pose contains NaN or inf", "not_finite")
        try:
            base = self.hand_eye.transform_pose(pose)
        except ValueError as exc:  # a wrong frame, or a quaternion with no rotation
            reason = "frame" if isinstance(exc, FrameMismatchError) else "rotation"
            raise InvalidInputError(str(exc), reason) from None
        plan = plan_grasp(base, self.grasp_config, self._robot.has_jaw)
        with self._lock:
            self._grasp = _Input(stamp_ns, plan=plan)
            if not self._busy:
                self._set_state(PLANNED, report_repeat=False)
        self._listeners.target(plan.target, stamp_ns)
        return plan

    def on_path(self, points: np.ndarray, frame_id: str, stamp_ns: int) -> None:
        """Store a camera-frame suture path (M, 3) for key-point mode; InvalidInputError if unusable."""
        points = np.asarray(points, dtype=np.float64)
        try:
            self.hand_eye.check_frame(frame_id, "suture path")
        except ValueError as exc:
            raise InvalidInputError(str(exc), "frame") from None
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
            raise InvalidInputError(f"suture path needs at least 2 points, got {len(points)}", "too_short")
        if not np.isfinite(points).all():
            raise InvalidInputError("suture path contains NaN or inf", "not_finite")
        with self._lock:
            self._path = _Input(stamp_ns, points_camera=points.copy())

    # ------------------------------------------------------------------ requests

    def execute(self) -> Outcome:
        """Run the grasp plan of the latest valid grasp pose; blocks until it ends."""
        return self._guarded_run(self._grasp_run)

    def visit_keypoints(self, count: int | None = None) -> Outcome:
        """Run key-point mode on the latest path (``count`` points, default from the config); blocks."""
        return self._guarded_run(lambda: self._keypoint_run(count or self.keypoint_config.count))

    def abort(self, reason: str = "aborted on request") -> Outcome:
        """Cancel the running motion (the run then stops the robot and reports a fault)."""
        with self._lock:
            if not self._busy:
                return Outcome(False, "nothing to abort: no run is executing")
            self._abort_reason = reason
            self._cancel.set()
        return Outcome(True, f"{reason}: stopping the robot")

    def set_armed(self, armed: bool) -> None:
        """Arm or disarm; disarming cancels a running motion."""
        self.gate.set_armed(armed)
        if not armed:
            self.abort("disarmed")

    def close(self, timeout_s: float = 5.0) -> None:
        """Cancel any run, give it up to ``timeout_s`` to stop the robot, and release the backend."""
        self.abort("executor shutting down")
        self._idle.wait(timeout_s)
        self._robot.close()

    # ------------------------------------------------------------------ runs

    def _guarded_run(self, body: Callable[[], str]) -> Outcome:
        with self._lock:
            if self._busy:
                return Outcome(False, "refused: busy: a run is executing; wait for it or call abort")
            self._busy = True
            self._idle.clear()
            self._cancel.clear()
            self._abort_reason = "aborted on request"
            self._moving = False
        try:
            outcome = self._run(body)
            self._set_state(DONE if outcome.success else outcome.message)
            return outcome
        finally:
            with self._lock:
                self._busy = False
            self._idle.set()

    def _run(self, body: Callable[[], str]) -> Outcome:
        """Run ``body``; map every way it can end to an Outcome, stopping the robot where it moved."""
        try:
            detail = body()
            return Outcome(True, f"{DONE}: {detail}" if detail else DONE)
        except (RefusedError, NotReadyError) as exc:
            message = f"refused: {exc}"
            if self._moving:
                message += f"; {self._robot.stop()}"
        except AbortedError as exc:
            message = f"fault: {self._abort_reason}: {exc}; {self._robot.stop()}"
        except BackendError as exc:
            message = f"fault: {exc}; {self._robot.stop()}"
        except Exception as exc:  # a bug must still stop the robot and leave the node serving
            message = f"fault: unexpected {type(exc).__name__}: {exc}; {self._robot.stop()}"
        return Outcome(False, message)

    def _grasp_run(self) -> str:
        self.gate.check_armed()
        with self._lock:
            grasp = self._grasp
        if grasp is None or grasp.plan is None:
            raise RefusedError("no valid grasp pose received yet")
        self.gate.check_age(self._age_s(grasp.stamp_ns), "grasp pose")
        self._robot.prepare(grasp.plan.first_pose())
        self._run_plan(grasp.plan, grasp.stamp_ns)
        return ""

    def _keypoint_run(self, count: int) -> str:
        self.gate.check_armed()
        config = self.keypoint_config
        with self._lock:
            path = self._path
        if path is None:
            raise RefusedError("no valid suture path received yet")
        self.gate.check_age(self._age_s(path.stamp_ns), "suture path")
        try:
            camera_points = evenly_spaced_points(path.points_camera, count)
        except ValueError as exc:
            raise RefusedError(f"suture path unusable: {exc}") from None
        points = self.hand_eye.transform_points(camera_points)
        frame = self.hand_eye.base_frame

        def plan_with(orientation: np.ndarray) -> Plan:
            return plan_keypoints(points, orientation, frame, config.approach_offset, config.dwell)

        plan = plan_with(np.asarray(config.orientation))
        self._robot.prepare(plan.first_pose())
        if config.orientation_from_robot:
            measured = self.gate.check_measured(self._robot.measured_pose(), self._robot.name)
            plan = plan_with(measured.quaternion)
        records = self._run_plan(plan, path.stamp_ns, camera_points)
        deviations = np.array([record.deviation for record in records])
        return f"visited {len(records)} key points, max deviation {np.nanmax(deviations) * 1000:.2f} mm"

    def _run_plan(
        self, plan: Plan, stamp_ns: int, camera_points: np.ndarray | None = None
    ) -> list[KeypointRecord]:
        self.gate.check_plan(plan.moves(), plan.jaws(), self._robot.measured_pose(), self._robot.name)
        self._set_state(EXECUTING)
        self._moving = True
        records: list[KeypointRecord] = []
        timeout = self.motion_timeout
        for step in plan.steps:
            self._listeners.info(f"{plan.kind}: {step.name}")
            if isinstance(step, Move):
                if step.is_target:
                    self._listeners.target(step.pose, stamp_ns)
                self._robot.move_to(step.pose, timeout, self._cancel, step.name)
            elif isinstance(step, Jaw):
                self._robot.move_jaw(step.angle, timeout, self._cancel, step.name)
            elif isinstance(step, Dwell):
                if self._cancel.wait(step.seconds):
                    raise AbortedError(f"aborted during {step.name}")
                if step.keypoint is not None:
                    record = KeypointRecord(
                        index=step.keypoint,
                        count=len(plan.keypoints),
                        commanded=plan.keypoints[step.keypoint],
                        commanded_camera=(
                            camera_points[step.keypoint] if camera_points is not None else np.full(3, np.nan)
                        ),
                        measured=self._robot.measured_pose(),
                    )
                    records.append(record)
                    self._listeners.keypoint(record)
        return records

    def _age_s(self, stamp_ns: int) -> float:
        return (self._clock() - stamp_ns) * 1e-9

    def _set_state(self, state: str, report_repeat: bool = True) -> None:
        with self._lock:
            if state == self._state and not report_repeat:
                return
            self._state = state
            self._listeners.state(state)
