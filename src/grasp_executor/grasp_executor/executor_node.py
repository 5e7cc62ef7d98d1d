# SPDX-License-Identifier: Apache-2.0
"""executor_node: grasp poses in, robot motion out, through :class:`grasp_executor.executor.GraspExecutor`.

Subscribes ``/suture/grasp_pose`` (PoseStamped) and ``/suture/path`` (Path) in
the camera frame; publishes ``/grasp_executor/target_pose`` (the commanded
grasp pose in the robot base frame, with the stamp of the grasp pose it came
from) and ``/grasp_executor/state`` (String: idle, planned, executing, done,
refused: <reason>, fault: <reason>). Services (std_srvs/Trigger):
``/grasp_executor/execute`` runs the grasp of the latest valid grasp pose,
``/grasp_executor/visit_keypoints`` runs key-point mode on the latest path,
``/grasp_executor/abort`` stops a running motion. The responses carry the
final state text. Setting the parameter ``armed`` at run time arms or disarms
(disarming aborts a running motion); every other parameter is read at start-up.

Parameters, with defaults, units, descriptions and ranges, are in :data:`PARAMETERS`
(``ros2 param describe``, ``docs/nodes.md``); ``config/executor.yaml`` and ``docs/executor.md``
explain them. The node only converts
messages and parameters; every decision is in the ROS-free core.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from grasp_executor.backends.base import Backend
from grasp_executor.backends.dry_run import DryRunBackend
from grasp_executor.backends.dvrk import DvrkBackend
from grasp_executor.backends.ur import UrBackend, rtde_connector
from grasp_executor.crtk_ros import CrtkRosTransport
from grasp_executor.executor import IDLE, GraspExecutor, Listeners
from grasp_executor.geometry import Pose
from grasp_executor.handeye import HandEye, load_hand_eye
from grasp_executor.keypoints import KeypointConfig, KeypointRecord, append_keypoint_csv
from grasp_executor.planning import GraspConfig
from grasp_executor.safety import SafetyGate, SafetyLimits
from suture_common import topics
from suture_common.messages import ns_from_stamp, path_to_array, pose_message, pose_to_arrays
from suture_common.parameters import ParameterSpec, Range, field_parameter, spec_table
from suture_common.ros import (
    RELIABLE_QOS,
    ThreadPoolExecutor,
    ThrottledWarnings,
    declare_parameters,
    run_node,
    to_rclpy,
)
from suture_common.topics import GRASP_POSE, LEFT_FRAME, PATH

NODE_NAME = "grasp_executor"
TARGET_POSE = topics.TARGET_POSE
STATE = topics.EXECUTOR_STATE
EXECUTE = "/grasp_executor/execute"
VISIT_KEYPOINTS = "/grasp_executor/visit_keypoints"
ABORT = "/grasp_executor/abort"

BACKENDS = ("dry_run", "dvrk", "ur")


def _spec(name: str, default: Any, description: str, value_range: Range | None = None) -> ParameterSpec:
    """Numbers and lists of numbers may be given as integers or doubles (the node converts them)."""
    return ParameterSpec(name, default, description, value_range, dynamic_typing=_numeric(default))


def _core(cls: type, field_name: str, name: str, default: Any = dataclasses.MISSING) -> ParameterSpec:
    """A parameter that is a field of the core's configuration (description and range beside it)."""
    spec = field_parameter(cls, field_name, name, default)
    return dataclasses.replace(spec, dynamic_typing=_numeric(spec.default))


def _numeric(default: Any) -> bool:
    return not isinstance(default, (str, bool))


PARAMETERS: dict[str, ParameterSpec] = spec_table(
    (
        _spec("backend", "dry_run", "robot interface: dry_run (moves nothing), dvrk or ur"),
        _spec(
            "armed",
            False,
            "motion is refused unless true; may change at run time; false aborts a running motion",
        ),
        _spec("camera_frame", LEFT_FRAME, "frame the grasp poses and paths must be in"),
        _spec("base_frame", "base", "robot base frame of the commands (dVRK: the frame of measured_cp)"),
        _spec(
            "hand_eye.file",
            "",
            "hand-eye YAML file; when set it replaces hand_eye.translation and hand_eye.quaternion",
        ),
        _spec("hand_eye.translation", [0.0, 0.0, 0.0], "T_base_camera translation [x, y, z] (m)"),
        _spec("hand_eye.quaternion", [0.0, 0.0, 0.0, 1.0], "T_base_camera rotation [x, y, z, w]"),
        _core(GraspConfig, "tool_rotation", "tool_rotation"),
        _core(SafetyLimits, "workspace_min", "workspace.min", [-0.15, -0.15, 0.0]),
        _core(SafetyLimits, "workspace_max", "workspace.max", [0.15, 0.15, 0.3]),
        _core(SafetyLimits, "max_step", "max_step"),
        _core(SafetyLimits, "max_age", "max_age"),
        _core(GraspConfig, "approach_offset", "approach_offset"),
        _core(GraspConfig, "lift_distance", "lift_distance"),
        _core(GraspConfig, "jaw_open", "jaw.open"),
        _core(GraspConfig, "jaw_close", "jaw.close"),
        _core(SafetyLimits, "jaw_min", "jaw.min"),
        _core(SafetyLimits, "jaw_max", "jaw.max"),
        _spec(
            "motion_timeout",
            10.0,
            "longest time of one motion; then the robot is told to stop (s)",
            (0.0, 3600.0),
        ),
        _spec(
            "position_tolerance",
            0.002,
            "a move is done when the measured position is this close to the goal (m)",
            (0.0, 0.1),
        ),
        _spec("dvrk.namespace", "/PSM1", "CRTK namespace of the dVRK arm"),
        _spec(
            "dvrk.measured_timeout", 0.5, "no measured_cp for this long is a lost connection (s)", (0.0, 60.0)
        ),
        _spec("ur.host", "", "UR controller IP address or host name (required for backend ur)"),
        _spec("ur.speed", 0.05, "moveL tool speed (m/s)", (0.0, 3.0)),
        _spec("ur.acceleration", 0.2, "moveL tool acceleration (m/s²)", (0.0, 20.0)),
        _spec("ur.stop_deceleration", 2.0, "stopL deceleration on abort (m/s²)", (0.0, 20.0)),
        _core(KeypointConfig, "count", "keypoints.count"),
        _core(KeypointConfig, "approach_offset", "keypoints.approach_offset"),
        _core(KeypointConfig, "dwell", "keypoints.dwell"),
        _core(KeypointConfig, "orientation_from_robot", "keypoints.orientation_from_robot"),
        _core(KeypointConfig, "orientation", "keypoints.orientation"),
        _spec(
            "keypoints.log_file",
            "",
            "CSV file to append the commanded and measured key points to (empty: log only)",
        ),
    )
)
"""Every parameter (SI units: metres, radians, seconds; quaternions x y z w); those of the core's
configuration take their description and range from its dataclass fields."""

DEFAULTS: dict[str, Any] = {name: spec.default for name, spec in PARAMETERS.items()}
"""Every parameter and its default."""

_RUNTIME_PARAMETERS = ("armed",)

WARNING_PERIOD_S = 5.0
"""Seconds between two warnings about the same problem on the same topic."""


class ConfigError(ValueError):
    """A parameter value is unusable; the node does not start."""


class ExecutorNode(Node):
    """Thin adapter between ROS and :class:`GraspExecutor`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            declare_parameters(self, PARAMETERS.values())
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self._state_pub = self.create_publisher(String, STATE, RELIABLE_QOS)
        self._target_pub = self.create_publisher(PoseStamped, TARGET_POSE, RELIABLE_QOS)
        self._keypoint_log = str(self._value("keypoints.log_file"))
        self._warnings = ThrottledWarnings(self.get_logger(), WARNING_PERIOD_S)
        self.dropped: dict[str, int] = self._warnings.counts
        """Inputs dropped, by "topic reason"."""
        try:
            self.core = self._build_core()
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.create_subscription(PoseStamped, GRASP_POSE, self._on_grasp_pose, RELIABLE_QOS)
        self.create_subscription(Path, PATH, self._on_path, RELIABLE_QOS)
        runs = MutuallyExclusiveCallbackGroup()
        self.create_service(Trigger, EXECUTE, self._on_execute, callback_group=runs)
        self.create_service(Trigger, VISIT_KEYPOINTS, self._on_visit_keypoints, callback_group=runs)
        self.create_service(Trigger, ABORT, self._on_abort, callback_group=MutuallyExclusiveCallbackGroup())
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._publish_state(IDLE)
        armed = "ARMED" if self.core.gate.armed else "not armed"
        self.get_logger().info(
            f"{self.core.backend_name} backend, {armed}; hand-eye {self.core.hand_eye.camera_frame} -> "
            f"{self.core.hand_eye.base_frame}; call {EXECUTE} to grasp"
        )

    # ------------------------------------------------------------------ configuration

    def _build_core(self) -> GraspExecutor:
        camera_frame = str(self._value("camera_frame"))
        base_frame = str(self._value("base_frame"))
        hand_eye_file = str(self._value("hand_eye.file"))
        if hand_eye_file:
            hand_eye = load_hand_eye(hand_eye_file, camera_frame, base_frame)
            self.get_logger().info(
                f"hand-eye transform from {hand_eye_file} (hand_eye.translation/quaternion ignored)"
            )
        else:
            hand_eye = HandEye(
                self._floats("hand_eye.translation", 3),
                self._floats("hand_eye.quaternion", 4),
                camera_frame,
                base_frame,
            )
        limits = SafetyLimits(
            workspace_min=tuple(self._floats("workspace.min", 3)),
            workspace_max=tuple(self._floats("workspace.max", 3)),
            max_step=self._float("max_step"),
            max_age=self._float("max_age"),
            jaw_min=self._float("jaw.min"),
            jaw_max=self._float("jaw.max"),
        )
        gate = SafetyGate(limits, armed=bool(self._value("armed")))
        grasp = GraspConfig(
            approach_offset=self._float("approach_offset"),
            lift_distance=self._float("lift_distance"),
            jaw_open=self._float("jaw.open"),
            jaw_close=self._float("jaw.close"),
            tool_rotation=tuple(self._floats("tool_rotation", 4)),
        )
        keypoints = KeypointConfig(
            count=self._float("keypoints.count"),
            approach_offset=self._float("keypoints.approach_offset"),
            dwell=self._float("keypoints.dwell"),
            orientation_from_robot=bool(self._value("keypoints.orientation_from_robot")),
            orientation=tuple(self._floats("keypoints.orientation", 4)),
        )
        listeners = Listeners(
            state=self._publish_state,
            target=self._publish_target,
            keypoint=self._report_keypoint,
            info=self.get_logger().info,
        )
        motion_timeout = self._float("motion_timeout")
        backend = self._make_backend(hand_eye.base_frame)
        try:
            return GraspExecutor(
                backend,
                gate,
                hand_eye,
                grasp,
                keypoints,
                motion_timeout=motion_timeout,
                clock=lambda: self.get_clock().now().nanoseconds,
                listeners=listeners,
            )
        except ValueError:
            backend.close()
            raise

    def _make_backend(self, base_frame: str) -> Backend:
        kind = str(self._value("backend"))
        tolerance = self._float("position_tolerance")
        if kind == "dry_run":
            return DryRunBackend(log=self.get_logger().info)
        if kind == "dvrk":
            transport = CrtkRosTransport(self, str(self._value("dvrk.namespace")))
            return DvrkBackend(
                transport, measured_timeout=self._float("dvrk.measured_timeout"), position_tolerance=tolerance
            )
        if kind == "ur":
            return UrBackend(
                rtde_connector(str(self._value("ur.host"))),
                frame_id=base_frame,
                speed=self._float("ur.speed"),
                acceleration=self._float("ur.acceleration"),
                stop_deceleration=self._float("ur.stop_deceleration"),
                position_tolerance=tolerance,
            )
        raise ConfigError(f"parameter backend is {kind!r}; use one of {', '.join(BACKENDS)}")

    def _value(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _float(self, name: str) -> float:
        value = self._value(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"parameter {name} must be a number, got {value!r}")
        return float(value)

    def _floats(self, name: str, size: int) -> np.ndarray:
        value = self._value(name)
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != size:
            raise ConfigError(f"parameter {name} must be a list of {size} numbers, got {value!r}")
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
            raise ConfigError(f"parameter {name} must be a list of {size} numbers, got {value!r}")
        return np.asarray(value, dtype=np.float64)

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == "armed" and parameter.type_ != Parameter.Type.BOOL:
                return SetParametersResult(successful=False, reason="armed must be true or false")
            if parameter.name in DEFAULTS and parameter.name not in _RUNTIME_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f"{parameter.name} is read at start-up; restart the node to change it",
                )
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == "armed":
                self.core.set_armed(bool(parameter.value))
                if parameter.value:
                    self.get_logger().warning("ARMED: the robot moves on the next execute request")
                else:
                    self.get_logger().info("disarmed")

    # ------------------------------------------------------------------ inputs

    def _on_grasp_pose(self, msg: PoseStamped) -> None:
        try:
            position, quaternion = pose_to_arrays(msg)
            pose = Pose(position, quaternion, msg.header.frame_id)
            self.core.on_grasp_pose(pose, ns_from_stamp(msg.header.stamp))
        except ValueError as exc:
            self._drop(GRASP_POSE, exc)

    def _on_path(self, msg: Path) -> None:
        try:
            self.core.on_path(path_to_array(msg), msg.header.frame_id, ns_from_stamp(msg.header.stamp))
        except ValueError as exc:
            self._drop(PATH, exc)

    def _drop(self, topic: str, exc: ValueError) -> None:
        """One warning per topic and problem every WARNING_PERIOD_S (InvalidInputError.reason, or
        the conversion error's type)."""
        reason = getattr(exc, "reason", type(exc).__name__)
        self._warnings.warn(f"{topic} {reason}", f"dropped {topic}: {exc}")

    # ------------------------------------------------------------------ services

    def _on_execute(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        outcome = self.core.execute()
        response.success, response.message = outcome.success, outcome.message
        return response

    def _on_visit_keypoints(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        outcome = self.core.visit_keypoints()
        response.success, response.message = outcome.success, outcome.message
        return response

    def _on_abort(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        outcome = self.core.abort()
        response.success, response.message = outcome.success, outcome.message
        return response

    # ------------------------------------------------------------------ outputs

    def _publish_state(self, state: str) -> None:
        self._state_pub.publish(String(data=state))
        if state.startswith(("refused", "fault")):
            self.get_logger().warning(f"state: {state}")
        else:
            self.get_logger().info(f"state: {state}")

    def _publish_target(self, pose: Pose, stamp_ns: int) -> None:
        message = pose_message(pose.position, pose.quaternion, stamp_ns, pose.frame_id)
        self._target_pub.publish(to_rclpy(message))

    def _report_keypoint(self, record: KeypointRecord) -> None:
        self.get_logger().info(record.describe())
        if self._keypoint_log:
            try:
                append_keypoint_csv(self._keypoint_log, record)
            except OSError as exc:
                self.get_logger().warning(
                    f"cannot write {self._keypoint_log}: {exc.strerror or exc}", throttle_duration_sec=5.0
                )

    def close(self) -> None:
        """Cancel a running motion and release the robot connection."""
        self.core.close()


def main(args: list[str] | None = None) -> int:
    """``ros2 run grasp_executor executor_node``: spin until Ctrl-C (SIGINT) or SIGTERM.

    The signal ends the spin loop while ROS is still up: the node aborts a running motion, the
    backend tells the robot to stop (a dVRK through its topics), and only then does ROS shut
    down (:func:`suture_common.ros.run_node`). Callbacks run on four threads, so a service call
    that waits for a motion does not block the feedback that ends it.
    """
    return run_node(
        ExecutorNode,
        "executor_node",
        args,
        make_executor=lambda: ThreadPoolExecutor(num_threads=4),
        finish=ExecutorNode.close,
    )


if __name__ == "__main__":
    sys.exit(main())
