#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Drive executor_node once, end to end, with a grasp pose placed just below the robot's current tool.

For the URSim recipe (docker-compose.yml next to this file); not run by CI. It
stands in for the perception pipeline: it reads the tool pose from the
controller (ur_rtde receive interface, read-only) or takes ``--tcp``, places a
grasp pose ``--depth`` metres further along the tool's approach (z) axis with
the tool's orientation, maps it into the camera frame with the inverse of the
hand-eye transform, publishes it on /suture/grasp_pose at 10 Hz with fresh
stamps, optionally arms the executor, calls /grasp_executor/execute (or, with
``--keypoints``, publishes a 40 mm path through that point along the tool's x
axis and calls /grasp_executor/visit_keypoints) and prints the response.

Everything that moves the robot goes through executor_node and its safety
checks; ``--power-on`` only powers the simulated arm on and releases its brakes
through the dashboard server.

    python3 /ursim/ursim_demo.py --host ursim --power-on --arm
    python3 /ursim/ursim_demo.py --tcp 0.4 -0.1 0.3 3.1416 0 0 --arm   # without a controller
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from grasp_executor.backends.ur import ur_to_pose
from grasp_executor.geometry import quaternion_multiply
from grasp_executor.handeye import load_hand_eye
from suture_common.messages import path_message, pose_message
from suture_common.ros import RELIABLE_QOS, to_rclpy

HAND_EYE = "/ws/install/grasp_executor/share/grasp_executor/config/hand_eye_example.yaml"
TIMEOUT_S = 60.0


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--host", help="UR controller to read the tool pose from (e.g. ursim)")
    source.add_argument("--tcp", type=float, nargs=6, metavar="V", help="tool pose x y z rx ry rz instead")
    parser.add_argument("--hand-eye", default=HAND_EYE, help="hand-eye YAML, as given to the executor")
    parser.add_argument("--depth", type=float, default=0.02, help="metres beyond the tool tip (default 0.02)")
    parser.add_argument("--keypoints", action="store_true", help="run key-point mode instead of a grasp")
    parser.add_argument("--arm", action="store_true", help="set the executor's armed parameter first")
    parser.add_argument("--power-on", action="store_true", help="power on and release brakes (URSim)")
    return parser.parse_args()


def read_tcp(host: str, power_on: bool) -> list[float]:
    import dashboard_client
    import rtde_receive

    if power_on:
        dashboard = dashboard_client.DashboardClient(host)
        dashboard.connect()
        dashboard.powerOn()
        dashboard.brakeRelease()
        deadline = time.monotonic() + TIMEOUT_S
        while "RUNNING" not in dashboard.robotmode():
            if time.monotonic() > deadline:
                sys.exit(f"ursim_demo: the arm is not running: {dashboard.robotmode()}")
            time.sleep(0.5)
        dashboard.disconnect()
    return list(rtde_receive.RTDEReceiveInterface(host).getActualTCPPose())


def wait(executor: SingleThreadedExecutor, done, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not done():
        if time.monotonic() > deadline:
            sys.exit(f"ursim_demo: timed out waiting for {what}")
        executor.spin_once(timeout_sec=0.05)


def main() -> None:
    args = arguments()
    tcp = args.tcp if args.tcp is not None else read_tcp(args.host, args.power_on)
    hand_eye = load_hand_eye(args.hand_eye)
    tool = ur_to_pose(tcp, hand_eye.base_frame)
    target = tool.translated(args.depth * tool.axis(2))
    # the camera-frame pose whose base-frame image is `target`: invert p_base = R p_camera + t
    rotation, translation = hand_eye.rotation, hand_eye.translation
    inverse = hand_eye.quaternion * np.array([-1.0, -1.0, -1.0, 1.0])
    position_camera = rotation.T @ (target.position - translation)
    quaternion_camera = quaternion_multiply(inverse, target.quaternion)
    offsets = np.linspace(-0.02, 0.02, 5)[:, None] * tool.axis(0)
    path_camera = (target.position + offsets - translation) @ rotation
    print(f"tool at {tool.position.round(4).tolist()} m, grasp target {target.position.round(4).tolist()} m")

    rclpy.init()
    node = rclpy.create_node("ursim_demo")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        grasp_pub = node.create_publisher(PoseStamped, "/suture/grasp_pose", RELIABLE_QOS)
        path_pub = node.create_publisher(Path, "/suture/path", RELIABLE_QOS)

        published = []

        def publish() -> None:
            published.append(True)
            stamp = node.get_clock().now().nanoseconds
            frame = hand_eye.camera_frame
            grasp_pub.publish(to_rclpy(pose_message(position_camera, quaternion_camera, stamp, frame)))
            path_pub.publish(to_rclpy(path_message(path_camera, stamp, frame)))

        node.create_timer(0.1, publish)
        wait(executor, lambda: grasp_pub.get_subscription_count() > 0, "executor_node to subscribe")
        if args.arm:
            client = node.create_client(SetParameters, "/grasp_executor/set_parameters")
            wait(executor, client.service_is_ready, "the executor's parameter service")
            armed = Parameter(
                name="armed", value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True)
            )
            future = client.call_async(SetParameters.Request(parameters=[armed]))
            wait(executor, future.done, "arming")
            if not future.result().results[0].successful:
                sys.exit(f"ursim_demo: arming refused: {future.result().results[0].reason}")
        sent = len(published)
        wait(executor, lambda: len(published) >= sent + 3, "a few fresh poses to go out")
        service = "/grasp_executor/visit_keypoints" if args.keypoints else "/grasp_executor/execute"
        client = node.create_client(Trigger, service)
        wait(executor, client.service_is_ready, service)
        future = client.call_async(Trigger.Request())
        wait(executor, future.done, f"the {service} response")
        response = future.result()
        print(f"{service}: {response.message}")
        sys.exit(0 if response.success else 1)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
