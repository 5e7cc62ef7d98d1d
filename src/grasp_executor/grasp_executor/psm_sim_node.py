# SPDX-License-Identifier: Apache-2.0
"""psm_sim_node: a kinematic dVRK PSM on CRTK topics, for tests and demos (no dVRK needed).

Under ``namespace`` (default ``/PSM1``) it subscribes ``move_cp`` (PoseStamped)
and ``jaw/move_jp`` (JointState, first position in radians) and publishes, at
``rate`` Hz, ``measured_cp`` (PoseStamped in ``frame_id``) and
``jaw/measured_js`` (JointState), plus ``goal_reached`` (Bool) when a
trajectory ends. The motion model is :class:`grasp_executor.psm_sim.KinematicPsm`.
A goal that is NaN, not a unit quaternion, or in another non-empty frame than
``frame_id`` is dropped with a log line.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Header

from grasp_executor.geometry import Pose
from grasp_executor.psm_sim import KinematicPsm
from suture_common.messages import pose_message, pose_to_arrays
from suture_common.parameters import ParameterSpec, spec_table
from suture_common.ros import RELIABLE_QOS, declare_parameters, run_node, to_rclpy

PARAMETERS: dict[str, ParameterSpec] = spec_table(
    ParameterSpec(name, default, description, value_range, dynamic_typing=not isinstance(default, str))
    for name, default, description, value_range in (
        ("namespace", "/PSM1", "CRTK namespace of the simulated arm", None),
        ("frame_id", "base", "frame of measured_cp and of the goals accepted", None),
        ("rate", 100.0, "rate of measured_cp and jaw/measured_js (Hz; > 0)", (0.0, 10_000.0)),
        ("linear_speed", 0.05, "tool speed along a trajectory (m/s)", (0.0, 10.0)),
        ("angular_speed", 1.0, "tool rotation speed along a trajectory (rad/s)", (0.0, 100.0)),
        ("jaw_speed", 1.0, "jaw speed (rad/s)", (0.0, 100.0)),
        ("initial_position", [0.0, 0.0, 0.1], "tool position [x, y, z] at start (m)", None),
        ("initial_orientation", [0.0, 0.0, 0.0, 1.0], "tool orientation [x, y, z, w] at start", None),
        ("initial_jaw", 0.0, "jaw angle at start (rad)", (-math.pi, math.pi)),
    )
)
"""Parameters: metres, radians, seconds, Hz; orientation as quaternion x y z w."""


class PsmSimNode(Node):
    """Publishes the simulated arm's state and follows CRTK goals."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("psm_sim", **kwargs)
        values = declare_parameters(self, PARAMETERS.values())
        value = values.__getitem__
        namespace = "/" + str(value("namespace")).strip("/")
        self._frame_id = str(value("frame_id"))
        start = Pose(value("initial_position"), value("initial_orientation"), self._frame_id)
        self.psm = KinematicPsm(
            start,
            float(value("initial_jaw")),
            linear_speed=float(value("linear_speed")),
            angular_speed=float(value("angular_speed")),
            jaw_speed=float(value("jaw_speed")),
        )
        rate = float(value("rate"))
        if not rate > 0:
            raise ValueError(f"parameter rate must be positive, got {rate}")
        self._measured = self.create_publisher(PoseStamped, f"{namespace}/measured_cp", RELIABLE_QOS)
        self._jaw_measured = self.create_publisher(JointState, f"{namespace}/jaw/measured_js", RELIABLE_QOS)
        self._goal_reached = self.create_publisher(Bool, f"{namespace}/goal_reached", RELIABLE_QOS)
        self.create_subscription(PoseStamped, f"{namespace}/move_cp", self._on_move_cp, RELIABLE_QOS)
        self.create_subscription(JointState, f"{namespace}/jaw/move_jp", self._on_jaw, RELIABLE_QOS)
        self.create_timer(1.0 / rate, self._tick)
        self.get_logger().info(f"kinematic PSM on {namespace}, {rate:.0f} Hz, frame {self._frame_id!r}")

    def _on_move_cp(self, msg: PoseStamped) -> None:
        try:
            frame = msg.header.frame_id
            if frame and frame != self._frame_id:
                raise ValueError(f"goal frame {frame!r} is not the arm's frame {self._frame_id!r}")
            position, quaternion = pose_to_arrays(msg)
            events = self.psm.move_cp(Pose(position, quaternion, self._frame_id), time.monotonic())
        except ValueError as exc:
            self.get_logger().warning(f"dropped move_cp: {exc}", throttle_duration_sec=5.0)
            return
        self._publish_events(events)

    def _on_jaw(self, msg: JointState) -> None:
        try:
            if len(msg.position) < 1:
                raise ValueError("jaw/move_jp has no position")
            events = self.psm.move_jaw(float(msg.position[0]), time.monotonic())
        except ValueError as exc:
            self.get_logger().warning(f"dropped jaw/move_jp: {exc}", throttle_duration_sec=5.0)
            return
        self._publish_events(events)

    def _tick(self) -> None:
        events = self.psm.update(time.monotonic())
        now = self.get_clock().now()
        pose = self.psm.pose
        message = pose_message(pose.position, pose.quaternion, now.nanoseconds, self._frame_id)
        self._measured.publish(to_rclpy(message))
        header = Header(stamp=now.to_msg(), frame_id=self._frame_id)
        self._jaw_measured.publish(JointState(header=header, name=["jaw"], position=[self.psm.jaw]))
        self._publish_events(events)  # after measured_cp, so a client sees the final pose first

    def _publish_events(self, events: list[bool]) -> None:
        for reached in events:
            self._goal_reached.publish(Bool(data=reached))


def main(args: list[str] | None = None) -> int:
    """``ros2 run grasp_executor psm_sim_node``: spin until Ctrl-C."""
    return run_node(PsmSimNode, "psm_sim_node", args)


if __name__ == "__main__":
    sys.exit(main())
