# SPDX-License-Identifier: Apache-2.0
"""rclpy implementation of :class:`grasp_executor.backends.dvrk.CrtkTransport` (node side).

Topics under the arm namespace (default ``/PSM1``): publishes ``move_cp``
(PoseStamped) and ``jaw/move_jp`` (JointState) from the executor node, and
subscribes ``measured_cp`` (PoseStamped, sensor-data QoS so that reliable and
best-effort publishers both match) and ``goal_reached`` (Bool, reliable).

The subscriptions live on a small helper node, ``<node>_crtk_feedback``, spun
by its own SingleThreadedExecutor in a background thread: the feedback keeps
arriving while the executor node's service callback blocks in a run, and the
100 Hz ``measured_cp`` stream stays off the node's MultiThreadedExecutor,
whose dispatch busy-waits in rclpy 7.1 (ros2/rclpy#1452) and would take a CPU
core at that rate. Remappings given on the command line apply to both nodes.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Header

from grasp_executor.geometry import Pose
from suture_common.messages import MessageConversionError, pose_message, pose_to_arrays
from suture_common.ros import RELIABLE_QOS, SENSOR_DATA_QOS, to_rclpy

_KEPT_EVENTS = 64
_ACK_TIMEOUT_S = 1.0


class CrtkRosTransport:
    """CRTK topics of one arm; thread-safe, waits with a condition variable."""

    def __init__(self, node: Node, namespace: str = "/PSM1") -> None:
        namespace = "/" + namespace.strip("/")
        self.namespace = namespace
        self._node = node
        self._condition = threading.Condition()
        self._measured: tuple[Pose, float] | None = None
        self._events: deque[tuple[int, bool]] = deque(maxlen=_KEPT_EVENTS)
        self._count = 0
        self._goal = node.create_publisher(PoseStamped, f"{namespace}/move_cp", RELIABLE_QOS)
        self._jaw = node.create_publisher(JointState, f"{namespace}/jaw/move_jp", RELIABLE_QOS)
        self._feedback = rclpy.create_node(
            f"{node.get_name()}_crtk_feedback",
            context=node.context,
            namespace=node.get_namespace(),
            start_parameter_services=False,
        )
        feedback = self._feedback
        feedback.create_subscription(
            PoseStamped, f"{namespace}/measured_cp", self._on_measured, SENSOR_DATA_QOS
        )
        feedback.create_subscription(Bool, f"{namespace}/goal_reached", self._on_goal_reached, RELIABLE_QOS)
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(feedback)
        self._thread = threading.Thread(target=self._spin, name="crtk_feedback", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        with contextlib.suppress(ExternalShutdownException):  # ROS shut down: the thread just ends
            self._executor.spin()

    def close(self) -> None:
        """Deliver what was sent, stop the feedback thread and destroy the helper node.

        A hold sent while the node shuts down (Ctrl-C during a motion) must reach the arm before
        the process exits: the reliable publishers wait up to ``_ACK_TIMEOUT_S`` for the arm's
        acknowledgement (without it the goal was now and then lost with the exiting process).
        """
        for publisher in (self._goal, self._jaw):
            with contextlib.suppress(Exception):  # closing must not raise: ROS may be gone already
                publisher.wait_for_all_acked(Duration(seconds=_ACK_TIMEOUT_S))
        self._executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        self._feedback.destroy_node()

    def send_goal(self, pose: Pose) -> None:
        stamp = self._node.get_clock().now().nanoseconds
        self._goal.publish(to_rclpy(pose_message(pose.position, pose.quaternion, stamp, pose.frame_id)))

    def send_jaw(self, angle: float) -> None:
        header = Header(stamp=self._node.get_clock().now().to_msg())
        self._jaw.publish(JointState(header=header, position=[float(angle)]))

    def measured(self) -> tuple[Pose, float] | None:
        with self._condition:
            if self._measured is None:
                return None
            pose, received = self._measured
        return pose, time.monotonic() - received

    def goal_reached_count(self) -> int:
        with self._condition:
            return self._count

    def wait_goal_reached(self, after: int, timeout_s: float) -> bool | None:
        with self._condition:
            self._condition.wait_for(lambda: self._count > after, timeout=max(0.0, timeout_s))
            for number, value in self._events:
                if number == after + 1:
                    return value
            return None

    def _on_measured(self, msg: PoseStamped) -> None:
        try:
            position, quaternion = pose_to_arrays(msg)
        except MessageConversionError as exc:
            self._node.get_logger().warning(
                f"dropped {self.namespace}/measured_cp: {exc}", throttle_duration_sec=5.0
            )
            return
        pose = Pose(position, quaternion, msg.header.frame_id)
        with self._condition:
            self._measured = (pose, time.monotonic())
            self._condition.notify_all()

    def _on_goal_reached(self, msg: Bool) -> None:
        with self._condition:
            self._count += 1
            self._events.append((self._count, bool(msg.data)))
            self._condition.notify_all()
